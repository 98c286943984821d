"""The selection's candidate refits and placebo fits, and the refit of a resolution check's next
doubling (computed ahead in a forked child), run on several processes
(``hystfit.diagnose.SELECTION_WORKERS``) and give the same diagnosis, number for number, as one."""

import pytest

from hystfit import diagnose as diagnose_module
from hystfit.diagnose import DiagnoseSettings, diagnose, withheld_effect_captures
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit import parallel
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
def test_a_resolution_refit_computed_ahead_gives_the_same_diagnosis(monkeypatch):
    """A four-operator base whose resolution check after the named effect adopts two doublings in a
    row (8 → 16 → 32): the second's refit comes from the child started during the first."""
    from hystfit.diagnose import DiagnoseSettings, diagnose

    caps = withheld_effect_captures("asymmetry", 1.0, 3, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 80.0),
                                    steps_s=0)
    used = []
    result = parallel.ForkedCall.result
    monkeypatch.setattr(parallel.ForkedCall, "result", lambda self: used.append(1) or result(self))

    def document(workers):
        monkeypatch.setattr(diagnose_module, "SELECTION_WORKERS", workers)
        d = diagnose(caps, PI(n_operators=4), Auto(), seed=3, settings=DiagnoseSettings(max_effects=2))
        doc = diagnosis_document(d)
        doc.pop("runtime_s")
        return doc

    one = document(1)
    assert not used
    checks = [s for c in one["resolution_during_selection"] for s in c["steps"]]
    assert sum(s["adopted"] for s in checks) >= 2  # two doublings in a row: the case computed ahead
    assert document(2) == one
    assert used  # the refit computed ahead was used
