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
