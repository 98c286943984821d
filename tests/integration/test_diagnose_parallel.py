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


def test_placebos_are_fitted_for_the_contenders_only_and_change_no_verdict(monkeypatch):
    """A candidate whose held-out reduction is below half the threshold cannot be named (alone or in a
    look-ahead pair), so its placebo is not fitted: its placebo numbers are NaN, ``beats_placebo`` is
    None (JSON null), the report's cell is "–". Every other number, and the verdict, are those of a
    diagnosis that fits every layout's placebos (each placebo is drawn from its own generator). A
    candidate whose layout (parameter count) a contender shares keeps that layout's placebo."""
    import math

    from hystfit.diagnose import CONTENDER_SHARE

    caps = withheld_effect_captures("delay", 1.0, 3, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 80.0),
                                    steps_s=0)
    settings = DiagnoseSettings(max_effects=2)
    lazy = diagnose(caps, PI(), Auto(), seed=3, settings=settings)
    monkeypatch.setattr(diagnose_module, "_contends", lambda *args: True)
    full = diagnose(caps, PI(), Auto(), seed=3, settings=settings)
    assert lazy.explained_by == full.explained_by == ("delay",)
    skipped = 0
    for mine, every in zip(lazy.steps, full.steps):
        assert [r.effect for r in mine] == [r.effect for r in every]
        for a, b in zip(mine, every):
            assert (a.heldout_rmse_after, a.reduction, a.eligible) == (b.heldout_rmse_after, b.reduction, b.eligible)
            if a.reduction >= CONTENDER_SHARE * settings.threshold or not math.isnan(a.placebo_improvement):
                # a contender, or a candidate whose placebo layout a contender shares: the same placebo
                # (what an effect adds, ``effect_above_noise``, is computed for contenders only, as placebos)
                same = {k: v for k, v in a.passes.items() if k != "effect_above_noise"}
                assert a.placebo_improvement == b.placebo_improvement and same == {
                    k: v for k, v in b.passes.items() if k != "effect_above_noise"}
            else:
                skipped += 1
                assert math.isnan(a.placebo_reduction) and a.passes["beats_placebo"] is None
                assert math.isfinite(b.placebo_improvement)
    assert skipped >= 2
    doc = diagnosis_document(lazy)
    cold = [e for e in doc["effects"] if math.isnan(next(r for r in lazy.effects if r.effect == e["effect"])
                                                    .placebo_improvement)]
    assert cold and all(e["placebo_improvement_um"] is None and e["placebo_reduction"] is None for e in cold)
    assert all("no placebo fitted" in e["evidence"] for e in cold)


def test_a_resolution_refit_is_kept_per_start(monkeypatch):
    """A resolution check's refits are cached per base, floor, effects *and their starts* (the φ of
    each on the coarser base): a refit of the same effects from another start is computed, not the
    cached one returned. Keyed without the starts, a check on one process reused a refit started
    from the 10-operator base's φ where two processes recomputed it from the 20-operator base's
    (a review's find: numbers 1e-8 apart between one process and two)."""
    caps = withheld_effect_captures("delay", 1.0, 3, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 80.0),
                                    steps_s=0)
    monkeypatch.setattr(diagnose_module, "SELECTION_WORKERS", 1)
    real = diagnose_module._refit_finer
    calls = []
    monkeypatch.setattr(diagnose_module, "_refit_finer", lambda *a, **k: calls.append((a, k)) or real(*a, **k))
    diagnose(caps, PI(), Auto(), seed=3, settings=DiagnoseSettings(max_effects=1))
    started = [(a, k) for a, k in calls if len(a) > 10 and a[10]]
    assert started, "no resolution refit with a start: the case no longer tests this"
    a, k = started[0]
    augments = []
    real_augment = diagnose_module._augment
    monkeypatch.setattr(diagnose_module, "_augment", lambda *x, **y: augments.append(1) or real_augment(*x, **y))
    real(*a, **k)  # the same start: the cached refit
    assert not augments
    name, (phi, effect) = next(iter(a[10].items()))
    real(*a[:10], {name: (phi * 1.01, effect)}, **k)
    assert augments  # another start: refitted
