"""The selection's candidate refits and placebo fits run on several processes
(``hystfit.diagnose.SELECTION_WORKERS``) and give the same diagnosis, number for number, as one."""

import pytest

from hystfit import diagnose as diagnose_module
from hystfit.diagnose import DiagnoseSettings, diagnose, withheld_effect_captures
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit.parallel import fork_workers
from hystfit.report.diagnose_report import diagnosis_document


def _document(monkeypatch, workers: int, caps) -> dict:
    monkeypatch.setattr(diagnose_module, "SELECTION_WORKERS", workers)
    doc = diagnosis_document(diagnose(caps, PI(), Auto(), seed=3, settings=DiagnoseSettings(max_effects=2)))
    doc.pop("runtime_s")
    return doc


@pytest.mark.skipif(fork_workers(2) < 2, reason="needs fork")
def test_workers_do_not_change_the_diagnosis(monkeypatch):
    caps = withheld_effect_captures("delay", 1.0, 3, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 80.0),
                                    steps_s=0)
    one = _document(monkeypatch, 1, caps)
    assert one["explained_by"]  # a step with a winner and a second step: states handed between processes
    assert _document(monkeypatch, 2, caps) == one


@pytest.mark.skipif(fork_workers(2) < 2, reason="needs fork")
def test_the_resolution_checks_refitted_ahead_give_the_same_diagnosis(monkeypatch):
    """While a resolution check runs, the next doubling's refit is computed ahead in a child; a
    chain of adopted checks then uses it: the same diagnosis as every refit in this process."""
    from pathlib import Path

    from hystfit import parallel
    from hystfit.io import load_captures

    sample = Path(__file__).resolve().parents[2] / "sample_data"
    caps = load_captures([sample / f"a40V_f{f}Hz.csv" for f in (10, 40, 80)])
    used = []
    real = parallel.Ahead.result

    def result(self):
        used.append(self._pid is not None)  # a child computed it
        return real(self)

    monkeypatch.setattr(parallel.Ahead, "result", result)
    ahead = diagnosis_document(diagnose(caps, PI(), Auto(), seed=0))
    assert any(used), "no check used a refit computed ahead: the data need a chain of adopted checks"
    monkeypatch.setattr(diagnose_module, "_refit_ahead", lambda *a, **k: None)
    here = diagnosis_document(diagnose(caps, PI(), Auto(), seed=0))
    for doc in (ahead, here):
        doc.pop("runtime_s")
    assert ahead == here
