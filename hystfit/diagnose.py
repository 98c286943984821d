"""``hystfit diagnose``: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks.

The procedure (issue 7), for captures and a base model of any kind:

1. **Gap.** Fit the base model (one parameter set over all captures, or one per condition) and
   estimate the sensor noise floor from the data themselves (:func:`estimate_noise`): the part
   of the gap no model can remove.
2. **Where.** Break the residual down by condition, branch, loop position, time in the capture
   and frequency band (:func:`where_analysis`).
3. **Which.** For every candidate effect of :mod:`hystfit.effects`, measure its signature in the
   residual and refit base + effect jointly (variable projection with a Gauss–Newton step of the
   base parameters, checked by a true re-simulation).
4. **How far.** Every fit uses the first part of each capture only (whole cycles for periodic
   captures, :attr:`DiagnoseSettings.fit_fraction`); the rest is held out. The held-out RMSE
   before and after, the fraction of the gap above the noise floor removed
   (``reduction = (before − after)/(before − floor)`` in [0, 1]), and the same for placebo
   augmentations of equal size. The verdict rule is :func:`choose_effect`. The effects are then
   added greedily (the best one becomes part of the model and the others are tested again), so
   the effects that explain the gap are named *in order*.

Everything is deterministic for a given seed. This module never prints; progress goes through
an optional callback ``progress(event, info)`` (events ``start``, ``advance``, ``note``). It
computes numbers and records (:class:`Finding`, :class:`Evidence`, :class:`SplitChoice`, reason
codes, a noise-method code) and holds no prose: every sentence of a diagnosis (``where.pointers``,
``evidence``, ``split.why``, ...) is worded from them by :mod:`hystfit.report.diagnose_wording`, and
the JSON document (``diagnosis.json``) is built by
:func:`hystfit.report.diagnose_report.diagnosis_document` (data flow one way: orchestration → report).
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable, ClassVar, Optional, Sequence

import numpy as np

from .capture import Capture
from .cells import cell_key
from .conditions import (amplitude_changes, condition_label, detect_condition, group_by_condition, is_step_and_hold,
                         white_noise_sigma)
from .effects import (EFFECTS, CaptureView, Effect, EffectFit, Inserted, Linearization, Placebo, _unit_phasors,
                      make_effect, COARSE_KEEP_MIN, COARSE_KEEP_SHARE, coarse_design, prepare_design, ranked_on_rows,
                      scoring_design, signature_share, solve_coefficients, surrogate_spectrum)
from .errors import ConfigError, InputError, NoResultError
from .factory import make_model
from .identify import adapted_model, condition_groups, fit_captures, identify, prepare_shared
from .models.base import Model
from .objective import Objective, Series
from .optimizers.base import Optimizer
from .optimizers.lsq import polisher
from ._warm import STEPS as WARM_STEPS, load_ahead
from .parallel import (CellFailed, ForkedExecutor, LocalExecutor, fork_call, fork_map, fork_workers, one_blas_thread,
                       run_cells)
from .seeds import check_seed
from .synth import Effects, Plant, raised_cosine, simulate_plant, step_pattern

__all__ = [
    "DiagnoseSettings",
    "EffectResult",
    "Diagnosis",
    "diagnose",
    "choose_effect",
    "estimate_noise",
    "where_analysis",
    "fit_masks",
    "is_periodic",
    "withheld_effect_captures",
    "one_effect",
    "Finding",
    "Evidence",
    "SplitChoice",
    "split_choice",
    "findings",
]

Progress = Optional[Callable[[str, dict], None]]

#: processes that refit the candidates and placebos of a selection step (:func:`hystfit.parallel.fork_map`;
#: None: every core). The numbers do not depend on it.
SELECTION_WORKERS: int | None = None


# ----------------------------------------------------------------------------------------------
# Settings and results
# ----------------------------------------------------------------------------------------------


#: hold-out schemes of :class:`DiagnoseSettings` (``split``)
SPLITS = ("auto", "temporal", "capture", "cycles")


#: the command-line flags of the settings ``diagnose`` has one for (its errors name the flag)
SETTING_FLAGS = {"fit_fraction": "--fit-fraction", "threshold": "--threshold", "max_effects": "--max-effects"}


@dataclass(frozen=True)
class DiagnoseSettings:
    """The knobs of the diagnosis, with the reasons for their defaults.

    Attributes
    ----------
    fit_fraction : share of every capture used to fit (the rest is held out), 0.6. Periodic
        captures are cut at a whole cycle (round(0.6 × cycles), at least 1, at most all but one),
        so the held-out part is the last cycles; others at 60 % of their samples. A temporal split
        is the one split that is honest for every effect: creep and drift must be *extrapolated*
        into later time (a flexible trend that only interpolates would look good), and per-capture
        parameters (drift) exist for every held-out sample.
    threshold : minimum held-out ``reduction`` for a verdict, 0.3. Below a third of the gap above
        noise an effect is at most a minor contributor: naming it as *the* cause would send an
        engineer after the wrong fix. (The withheld-effect suite shows the true effect removes
        ≥ 0.8 when present, wrong candidates mostly < 0.3.)
    occam_tolerance : two effects whose reductions differ by less than this (0.05) explain the
        data equally well; the one with fewer parameters is named (a pure delay is also fitted by a
        well-damped stage filter, never the other way round).
    min_excess_ratio : the held-out gap must exceed the noise floor by a meaningful amount before
        anything is named: sqrt(before² − floor²) ≥ 0.25·floor (a model error a quarter of the
        noise: below that the model is as good as the sensor allows). The same bar holds for what
        a named effect adds to the held-out prediction (its RMS, ``passes.effect_above_noise``): a
        blind test's 1.3 nm bow under 8 nm noise removed 36 % of a small gap and was named.
    placebo_draws : random placebo augmentations per parameter layout, 5 (random mixtures of
        phase-randomized surrogates of the effects' signatures, :class:`hystfit.effects.Placebo`);
        an effect must improve the held-out RMSE more than the best of them — what that many
        parameters gain by chance — by at least ``placebo_margin`` of the gap.
    placebo_margin : 0.02: the share of the held-out gap above the noise (before − σ) by which an
        effect's improvement must exceed the best placebo's. Without it the comparison can be a
        knife edge where every augmentation removes the same generic remainder (measured: a second
        effect "named" for beating a placebo by 0.001 nm of a 4.3 nm gap, on a base whose
        resolution had been converged).
    max_effects : how many effects the greedy forward selection may name, 3.
    split : how fit and held-out samples are chosen: ``"temporal"`` (the first part of every
        capture is fitted, the rest held out), ``"capture"`` (whole captures are held out: those
        whose drive frequency lies strictly between the others', so the held-out data are an
        *interpolation* in frequency; global mode only) or ``"auto"`` (default): ``"capture"`` when a
        capture's amplitude or frequency changes within it (a rising-amplitude sine, a sweep — a
        temporal split would fit small loops and test on large ones, an amplitude extrapolation
        that penalises every amplitude-dependent effect) and an interior capture exists; ``"cycles"``
        when a capture's amplitude or frequency changes but no interior capture can be held out
        (per-condition mode, or fewer than three drive frequencies); otherwise ``"temporal"``. When
        ``"auto"`` chose ``"capture"`` or ``"cycles"``, the temporal split is run as well and its
        verdict reported beside (``split.other_scheme``). ``"cycles"``: the middle ``1 − fit_fraction``
        of every capture's cycles is held out and the cycles before and after it are fitted — for a
        rising-amplitude sine an interpolation in amplitude and time. Its first-step reductions are
        smaller than the capture split's when several effects act at once (the base's error in the
        middle cycles is larger); the two-effect look-ahead of the selection is what lets it name
        them (docs/diagnose.md).
    iterations : Gauss–Newton iterations of the joint base + effect refit, 2 (the second is skipped
        when the linearization was exact, e.g. PI).
    resolution_check : True (default): when a gap above the noise remains after the named effects and
        the base has a resolution (:meth:`hystfit.models.base.Model.refined`, e.g. the number of play
        operators), refit the base at twice the resolution with the same effects; when that removes at
        least ``resolution_threshold`` of the held-out excess mean square, the base's resolution — not a missing
        effect — is what the coarse base lacked: the finer base is adopted (``resolution`` section;
        the recommended model carries the option) and the selection goes on from it with the effects
        not yet named. An effect is otherwise judged against a gap that the base's own
        discretization error dilutes. The same check also runs before any effect is tested
        (:func:`converge_resolution`) and after each named effect (``_Refiner``); False switches all
        of them off.
    resolution_threshold : 0.2: every resolution check doubles the base's resolution as long as each
        doubling removes at least this share of the held-out excess mean square (held-out
        RMSE² − floor²), and none runs once √(RMSE² − floor²) is within the floor. Mean squares, not RMSEs: a discretization error and an unmodelled effect add
        in quadrature, so the RMSE share understates the discretization's part when an effect is
        present (a 124 µm plant with a 700 Hz stage and creep: ten → twenty operators remove 43 % of
        the excess mean square but 25 % of the RMSE gap). More resolution of the same model is not
        an effect claim; the held-out data decide it.
    """

    fit_fraction: float = 0.6
    threshold: float = 0.3
    occam_tolerance: float = 0.05
    min_excess_ratio: float = 0.25
    placebo_draws: int = 5
    max_effects: int = 3
    iterations: int = 2
    split: str = "auto"
    resolution_check: bool = True
    resolution_threshold: float = 0.2
    placebo_margin: float = 0.02

    def __post_init__(self) -> None:
        checks = [("fit_fraction", 0.1 <= self.fit_fraction <= 0.9, "in [0.1, 0.9]"),
                  ("threshold", 0.0 < self.threshold < 1.0, "in (0, 1)"),
                  ("occam_tolerance", 0.0 <= self.occam_tolerance < 1.0, "in [0, 1)"),
                  ("min_excess_ratio", self.min_excess_ratio >= 0.0, ">= 0"),
                  ("placebo_draws", self.placebo_draws >= 1, ">= 1"),
                  ("max_effects", self.max_effects >= 1, ">= 1"),
                  ("iterations", self.iterations >= 1, ">= 1"),
                  ("resolution_threshold", 0.0 < self.resolution_threshold < 1.0, "in (0, 1)"),
                  ("placebo_margin", 0.0 <= self.placebo_margin < 1.0, "in [0, 1)"),
                  ("split", self.split in SPLITS, f"one of {', '.join(SPLITS)}")]
        for name, ok, rule in checks:
            if not ok:  # named as the command line has it where it has it (a blind test's find)
                shown = SETTING_FLAGS.get(name, name)
                raise ConfigError(f"diagnose: {shown} must be {rule}. Got {getattr(self, name)!r} instead.")


@dataclass(frozen=True)
class Finding:
    """One strong finding of :func:`where_analysis`: its ``kind`` (a code such as
    ``"frequency_grows"``, ``"branch_opposite"``, ``"calibration"``) and the numbers behind it. The
    sentence of ``where.pointers`` is :func:`hystfit.report.diagnose_wording.pointer_text`."""

    kind: str
    values: dict = field(default_factory=dict, hash=False)


@dataclass(frozen=True)
class Evidence:
    """The evidence of one candidate effect, as numbers: how much of the residual above noise its
    signature explains, its fitted parameters (:meth:`EffectFit.params`), the held-out RMSE before
    and after (output unit), its reduction, the best placebo's improvement, and the shape of the gap
    that points at it (from ``where.summary``). Its sentence (``evidence`` of diagnosis.json) is
    :func:`hystfit.report.diagnose_wording.evidence_text`."""

    effect: str
    signature_share: float
    params: dict = field(hash=False)
    heldout_before: float
    heldout_after: float
    reduction: float
    placebo: float
    frequency_exponent: float | None = None
    amplitude_exponent: float | None = None
    low_frequency_share: float = 0.0
    long_capture_ratio: float | None = None
    heldout_to_fit_ratio: float | None = None
    drive_frequency_Hz: float | None = None

    @classmethod
    def from_summary(cls, effect: str, summary: dict, **numbers) -> "Evidence":
        """The record with the gap's shape taken from a where-analysis ``summary``."""
        keys = ("frequency_exponent", "amplitude_exponent", "low_frequency_share", "long_capture_ratio",
                "heldout_to_fit_ratio", "drive_frequency_Hz")
        return cls(effect, **numbers, **{k: summary.get(k) for k in keys})


@dataclass(frozen=True)
class EffectResult:
    """One candidate effect tested on top of the current model (one step of the selection).

    RMSE values are in the output unit; ``improvement`` = before − after (held out); ``evidence``
    is the :class:`Evidence` record (worded by :func:`hystfit.report.diagnose_wording.evidence_text`).
    """

    effect: str
    title: str
    step: int
    heldout_rmse_before: float
    heldout_rmse_after: float
    fit_rmse_before: float
    fit_rmse_after: float
    reduction: float
    placebo_improvement: float
    placebo_improvement_mean: float
    placebo_reduction: float
    n_parameters: int
    signature_share: float
    signature_r2: float
    params: dict
    evidence: Evidence | None
    passes: dict
    fit: EffectFit = field(repr=False, compare=False, default=None)
    joint: dict | None = None  # the two-effect look-ahead that named it (:func:`_look_ahead`), else None
    #: RMS of the effect's own part of the prediction on held-out samples (output unit; :func:`_own_rms`)
    own_rms: float = math.nan

    @property
    def improvement(self) -> float:
        return self.heldout_rmse_before - self.heldout_rmse_after

    @property
    def eligible(self) -> bool:
        """Passes every rule; or, named by the look-ahead, every rule but the reduction, which it
        reaches together with the effect named on top of it (``joint``)."""
        if self.joint is not None:
            return all(ok for k, ok in self.passes.items() if k != "reduction_at_least_threshold")
        return all(self.passes.values())


@dataclass(frozen=True, eq=False)
class WhereFigureData:
    """What the where-figures of a diagnosis show (:mod:`hystfit.report.diagnose_report`): the
    where-analysis' sections, the noise floor they were computed with, the output unit, the mode,
    the fit fraction, the number of captures and the residual spectra of the periodic captures.
    Known as soon as the base model's where-analysis is done (:func:`diagnose`'s ``on_where``), so
    the figures can be drawn while the selection runs; :attr:`Diagnosis.where_figure_data` is the
    final one (the same object's data unless the noise floor was refined)."""

    where: dict
    sigma: float
    unit: str
    mode: str
    fit_fraction: float
    n_captures: int
    spectra: list = field(repr=False)

    def same_as(self, other: "WhereFigureData") -> bool:
        """Whether ``other`` draws the same figures: the same where-analysis (the same ``where``
        object: a refined noise floor makes a new one) at the same floor, unit, mode and split."""
        return (self.where is other.where and self.sigma == other.sigma and self.unit == other.unit
                and self.mode == other.mode and self.fit_fraction == other.fit_fraction
                and self.n_captures == other.n_captures)


def where_figure_data(where: dict, sigma: float, unit: str, mode: str, settings: "DiagnoseSettings",
                      n_captures: int, spectra) -> WhereFigureData:
    """The :class:`WhereFigureData` of a where-analysis."""
    return WhereFigureData(where, float(sigma), unit, mode, float(settings.fit_fraction), int(n_captures),
                           list(spectra))


@dataclass(frozen=True)
class Diagnosis:
    """The outcome of :func:`diagnose`: numbers, codes and records only. The JSON contract
    (``diagnosis.json``, with the prose fields worded) is
    :func:`hystfit.report.diagnose_report.diagnosis_document`. ``noise["method"]`` is a code
    (:data:`NOISE_METHOD_CODE`); ``split`` holds the numbers of the hold-out and ``split_choice`` its
    record (reason code); ``findings`` are the where-analysis' findings (``where.pointers``)."""

    base_model: str
    optimizer: str
    mode: str
    unit: str
    seed: int
    settings: DiagnoseSettings
    noise: dict
    gap: dict
    where: dict
    effects: tuple[EffectResult, ...]          # step 1, best first
    steps: tuple[tuple[EffectResult, ...], ...]  # every step of the greedy selection, best first
    verdict: str
    explained_by: tuple[str, ...]
    alternatives: tuple[tuple[str, ...], ...]  # per step: other eligible effects as good as the one named
    split: dict
    captures: tuple[dict, ...]
    runtime_s: float
    figures_data: dict = field(repr=False, compare=False, default_factory=dict)
    findings: tuple[Finding, ...] = field(repr=False, compare=False, default=())  # where.pointers as records
    resolution: dict | None = None  # the base-resolution check (:func:`resolution_check`), None when not run
    split_choice: SplitChoice | None = field(repr=False, compare=False, default=None)  # the hold-out, as a record
    resolution_before_effects: dict | None = None  # :func:`converge_resolution`, None when not run
    base_resolution: dict | None = None  # {"option", "given", "final"}: the base's resolution at the end
    resolution_during_selection: tuple[dict, ...] = ()  # the checks after each named effect (:class:`_Refiner`)
    #: the final model fitted on the fit part (base parameters per group, the named effects):
    #: the start of :func:`fit_recommended`; None when nothing was named
    final_state: object = field(repr=False, compare=False, default=None)
    #: ``--model-option`` values of the named effects' blocks (``dynamics.fn_min_Hz``): a search range
    #: the diagnosis widened (:meth:`hystfit.effects.Effect.handover_options`)
    block_options: dict = field(default_factory=dict)
    #: the ``--model-option`` values the base was given (the command line's): the hand-over and the
    #: next-step command use them with :attr:`recommended_options` (a blind test's ``history=relaxed``
    #: was in params.json but not in the command printed to identify the model anew)
    given_options: dict = field(default_factory=dict)

    @property
    def where_figure_data(self) -> WhereFigureData:
        """The data of the where-figures of this diagnosis (:class:`WhereFigureData`)."""
        return where_figure_data(self.where, self.noise["sigma"], self.unit, self.mode, self.settings,
                                 len(self.captures), self.figures_data.get("spectra", []))

    @property
    def reconciliation(self) -> list[dict]:
        """Where the residual's shape points at an effect that the refit then rejects, and why: per
        step-1 candidate whose first-order signature explains at least a quarter of the gap above
        the noise but that was not named — its held-out reduction, and whether the named effects
        already explain what its signature matched (a shared shape) or the pattern does not carry
        over to held-out data: ``reason`` is ``"shared_shape"``, ``"not_carried_over"`` or ``"other_rule"``
        (worded by :func:`hystfit.report.diagnose_wording.reconciliation_why`)."""
        out = []
        for r in self.effects:
            if r.effect in self.explained_by or not (r.signature_share >= 0.25):
                continue
            explained = bool(self.explained_by) and any(
                q.effect == r.effect and q.reduction < r.reduction - 0.1
                for step in self.steps[1:] for q in step)
            reason = ("shared_shape" if explained else "not_carried_over" if r.reduction < self.settings.threshold
                      else "other_rule")
            out.append({"effect": r.effect, "signature_share": r.signature_share, "reduction": r.reduction,
                        "reason": reason})
        return out

    @property
    def recommended_model(self) -> str:
        """The model expression to identify next: the base followed by the named effects as blocks,
        in the order a signal meets them (:data:`SIGNAL_ORDER`)."""
        return recommend_expression(self.base_model, self.explained_by)

    @property
    def recommended_options(self) -> dict:
        """``--model-option`` values the recommended model needs beyond the caller's: the finer
        resolution the diagnosis ended on, when a resolution check adopted one (before the effects,
        after an effect or after the last; e.g. ``{"n_operators": 20}``), and the named effects'
        search ranges it widened (:attr:`block_options`, e.g. ``{"dynamics.fn_min_Hz": 40.0}``)."""
        r = self.base_resolution
        out = {r["option"]: r["final"]} if r is not None and r["final"] != r["given"] else {}
        return {**out, **self.block_options}

    @property
    def hands_over(self) -> bool:
        """Whether the recommended model differs from the base as given — an effect was named, or a
        resolution check adopted a finer base — so that it is fitted on all the data and written
        to ``params.json`` (:func:`fit_recommended`). A blind test's find: with no effect named but
        20 operators recommended over the given 10, nothing was written."""
        return bool(self.explained_by or self.recommended_options)

    @property
    def final_parameters(self) -> dict[str, dict]:
        """Per named effect, its parameters in the final model — every named effect and the base
        fitted together on the fit part, the start of the hand-over (``params.json``). A step's
        own numbers are those of the effect added at that step; a later effect can move them (a
        blind test's creep read 1.7 % at 0.01 s at its step, 0 % in the final model, as in truth)."""
        st, views = self.final_state, self.figures_data.get("views")
        if st is None or views is None:
            return {}
        sources = [c.source for c in self.figures_data.get("captures", ())]
        return {link.effect.name: link.params(views, sources) for link in st.chain if link.effect.name in self.explained_by}

    @property
    def stopped_at_max_effects(self) -> dict | None:
        """When the selection named ``settings.max_effects`` effects and, in its last step, another
        candidate also passed every rule without being an equally good alternative to the one named
        there: ``{"max_effects", "also_passing"}`` — a further effect may remain, and only a larger
        ``--max-effects`` tests it (a blind test's plant with five effects stopped at three while a
        real asymmetry passed, 12× the noise left, and nothing said so). None otherwise."""
        if len(self.explained_by) < self.settings.max_effects or not self.steps:
            return None
        last = self.steps[-1]
        twins = set(self.alternatives[-1]) if len(self.alternatives) >= len(self.steps) else set()
        also = [r.effect for r in last if r.eligible and r.effect not in self.explained_by and r.effect not in twins]
        return {"max_effects": self.settings.max_effects, "also_passing": also} if also else None

    @property
    def heldout_rmse_named(self) -> float:
        """Held-out RMSE of the base with every named effect (the last named step); the base's own
        held-out RMSE when none is named."""
        final = self.gap.get("heldout_rmse_after_explained_out")
        if final is not None and self.explained_by:  # the final model (on the finer base when it was adopted)
            return float(final)
        if not self.explained_by or len(self.steps) < len(self.explained_by):
            return self.effects[0].heldout_rmse_before if self.effects else float("nan")
        last = self.explained_by[-1]
        for r in self.steps[len(self.explained_by) - 1]:
            if r.effect == last:
                return r.heldout_rmse_after
        return float("nan")


#: The order in which a signal meets the effects after the hysteresis (that of the virtual
#: actuator, :func:`hystfit.synth.simulate_plant_components`): a recommended model is written so.
SIGNAL_ORDER = ("asymmetry", "creep", "dynamics", "delay", "drift")


def recommend_expression(base_model: str, named: Sequence[str]) -> str:
    """``base_model`` (a name or an expression) followed by the ``named`` effects it lacks, the new
    ones in :data:`SIGNAL_ORDER`."""
    parts = [p.strip() for p in base_model.split("+")]
    present = set(parts[1:])
    new = [e for e in SIGNAL_ORDER if e in set(named) and e not in present]
    new += [e for e in named if e not in SIGNAL_ORDER and e not in present]
    return "+".join(parts + new)


def recommended_starts(captures: Sequence[Capture], d: "Diagnosis", model: Model,
                       rtol: float = 1e-2) -> dict[str, np.ndarray] | None:
    """Per cell of the recommended model's identification (``"global"``, or each condition's label),
    its start θ₀ from the diagnosis's own final model (:attr:`Diagnosis.final_state`, fitted on the fit
    part): the base's parameters of that cell's group, then each block's searched parameters φ and
    shared coefficients as the named effect's fit (nuisance blocks: their defaults), clipped to the
    box of ``model`` adapted to the cell's data.

    ``model`` is the recommended model, prepared (:func:`hystfit.identify.prepare_shared`). A start
    must *be* the diagnosis's model: ``model`` at θ₀ has, on all the cell's samples, an RMSE within
    ``rtol`` of the diagnosis's final predictions (whatever could make it another model shows
    there: blocks in another order than the effects were named where the order matters, a block
    whose structure the data set differently — creep's time constants from one condition's
    duration, the asymmetry's centre from a wider output range —, PI thresholds from a larger
    input range, a per-capture calibration the diagnosis fitted and the model lacks). None when
    any cell has no such start, or nothing was named, or a block is not among the named effects
    (e.g. a composite base given to diagnose: its blocks were fitted with the base)."""
    state = d.final_state
    if state is None or model.composition is None:
        return None
    fitted = {f.effect.name: f for f in state.chain}
    by_label = {g.label: g for g in state.groups}
    preds = {id(c): p for c, p in zip(d.figures_data.get("captures", ()),
                                       d.figures_data.get("explained_predictions", ()))}
    out = {}
    for key, caps in condition_groups(captures, d.mode != "per-condition").items():
        label = "global" if d.mode != "per-condition" else condition_label(key)
        g = by_label.get(label)
        adapted, params = adapted_model(caps, model)
        blocks = adapted.composition[1]
        n_base = len(params) - sum(b.n_theta for b in blocks)
        if g is None or g.theta.size != n_base or any(id(c) not in preds for c in caps):
            return None
        parts, at = [np.asarray(g.theta, float)], n_base
        for b in blocks:
            own, at = params[at:at + b.n_theta], at + b.n_theta
            if b.nuisance:
                parts.append(np.array([p.default for p in own], float))
                continue
            f = fitted.get(b.name)
            th = None if f is None else np.concatenate([np.asarray(f.phi, float), np.asarray(f.shared, float)])
            if th is None or th.size != len(own):
                return None
            parts.append(th)
        theta = np.clip(np.concatenate(parts), [p.lower for p in params], [p.upper for p in params])
        if not _reproduces(adapted, theta, caps, [preds[id(c)] for c in caps], rtol):
            return None
        out[label] = theta
    return out


def _reproduces(model: Model, theta: np.ndarray, caps: Sequence[Capture], preds: Sequence[np.ndarray],
                rtol: float) -> bool:
    """Whether ``model`` at ``theta`` fits ``caps`` (every sample after the warm-up) at most ``rtol``
    worse in RMSE than the predictions ``preds``."""
    objective = Objective(model, [Series(c.u, c.y, c.dt, c.warmup_samples) for c in caps])
    with np.errstate(all="ignore"):
        mse = float(objective(theta[None, :])[0])
    sse = n = 0.0
    for c, p in zip(caps, preds):
        e = np.asarray(p, float)[c.warmup_samples:] - c.y[c.warmup_samples:]
        sse, n = sse + float(e @ e), n + e.size
    return bool(np.isfinite(mse) and n > 0 and mse <= (1.0 + rtol) ** 2 * (sse / n))


@one_blas_thread
def fit_recommended(captures: Sequence[Capture], d: "Diagnosis", model: Model, optimizer: Optimizer, *,
                    seed: int, model_options: dict | None = None, progress=None, executor=None, store=None,
                    resume: bool = False):
    """Identify the recommended model on all the data (globally, or per condition as the diagnosis
    was made), so the diagnosis hands over a model that ``simulate``/``invert``/``track`` accept.

    With ``auto`` (the default optimizer) every cell starts from the diagnosis's own fit of the
    recommended model on the fit part, when that fit is the recommended model
    (:func:`recommended_starts`), and is polished on all the data (the least-squares polish of
    ``auto``, :func:`hystfit.optimizers.lsq.polisher`; the result's ``start`` says so):
    ``auto``'s staged start (the base, then each block searched on a grid) would repeat the
    diagnosis's work (on sample_data the start's RMSE on all the data is 1.6 % above the
    polished fit's, ``benchmarks/diagnose_handover.py``). Where there is no such start, and with
    any other optimizer, the recommended model is identified from scratch by ``optimizer``.

    Returns the :class:`hystfit.identify.IdentifyResult`, or None when the recommended model is the
    base as given (:attr:`Diagnosis.hands_over`).
    """

    if not d.hands_over:
        return None
    opts = {**dict(model_options or {}), **d.recommended_options}
    rec = make_model(d.recommended_model, opts)
    starts = None
    if optimizer.name == "auto":
        rec = prepare_shared(rec, captures, store, resume)
        starts = recommended_starts(captures, d, rec)
    res = identify(captures, rec, optimizer if starts is None else polisher(close_start=True), seed=seed,
                   global_fit=d.mode != "per-condition", model_options=opts, progress=progress, executor=executor,
                   store=store, resume=resume, starts=starts)
    return res if starts is None else replace(res, start=HANDED_OVER_START)


#: the ``start`` of the recommended model's fit (``params.json``'s ``optimizer.start``) when it was
#: polished from the diagnosis's own fit (:func:`recommended_starts`)
HANDED_OVER_START = "diagnosis: its final model fitted on the fit part"


# ----------------------------------------------------------------------------------------------
# Captures: periodicity, split
# ----------------------------------------------------------------------------------------------


def is_periodic(u: np.ndarray, dt: float, frequency_Hz: float, tol: float = 0.02) -> bool:
    """Whether ``u`` (V) repeats with period 1/frequency_Hz (s) over at least two periods.

    Compares u(t + P) with u(t) (linear interpolation for a fractional period): periodic when
    99 % of the differences are below ``tol`` × the input range (a few samples may differ: a
    capture that starts with a jump from the idle level onto the running drive is still periodic).
    """
    u = np.asarray(u, float)
    if not (np.isfinite(frequency_Hz) and frequency_Hz > 0):
        return False
    P = 1.0 / (frequency_Hz * dt)
    n = u.shape[0]
    if n < 2 * P + 1 or P < 4:
        return False
    k = np.arange(int(n - P - 1))
    shifted = np.interp(k + P, np.arange(n), u)
    rng = float(u.max() - u.min())
    return bool(rng > 0 and np.quantile(np.abs(shifted - u[k]), 0.99) <= tol * rng)


def fit_masks(captures: Sequence[Capture], periodic: Sequence[bool], fraction: float) -> list[np.ndarray]:
    """Per capture, the boolean mask of the samples used to fit (the rest is held out).

    Periodic captures: the first round(fraction × cycles) whole cycles (at least one, at most all
    but one); other captures: the first ``fraction`` of their samples.
    """
    masks = []
    for c, per in zip(captures, periodic):
        n = c.n
        if per:
            P = 1.0 / (c.frequency_Hz * c.dt)
            cycles = (n - 1) / P
            k = int(np.clip(round(fraction * cycles), 1, max(math.floor(cycles) - 1, 1)))
            n_fit = int(round(k * P)) + 1
        else:
            n_fit = int(round(fraction * n))
        n_fit = int(np.clip(n_fit, 2, n - 2))
        m = np.zeros(n, bool)
        m[:n_fit] = True
        masks.append(m)
    return masks


def interior_masks(captures: Sequence[Capture], periodic: Sequence[bool], fraction: float) -> list[np.ndarray]:
    """Per capture, the fit mask of the ``"cycles"`` split: the middle ``1 − fraction`` of the whole
    cycles (periodic captures; of the samples otherwise) is held out, the parts before and after it
    are fitted. At least one cycle (two samples) stays on each side."""
    masks = []
    for c, per in zip(captures, periodic):
        n = c.n
        if per:
            P = 1.0 / (c.frequency_Hz * c.dt)
            cycles = max(math.floor((n - 1) / P), 3)
            k_out = int(np.clip(round((1.0 - fraction) * cycles), 1, cycles - 2))
            k0 = (cycles - k_out) // 2
            a, b = int(round(k0 * P)), int(round((k0 + k_out) * P))
        else:
            a = int(round(0.5 * fraction * n))
            b = a + int(round((1.0 - fraction) * n))
        a, b = int(np.clip(a, 2, n - 4)), int(np.clip(b, a + 1, n - 2))
        m = np.ones(n, bool)
        m[a:b] = False
        masks.append(m)
    return masks


def heldout_captures(captures: Sequence[Capture], tonal: Sequence[bool] | None = None) -> list[bool]:
    """The captures a ``"capture"`` split holds out: among the ``tonal`` ones (default: all), those
    whose drive frequency lies strictly between the lowest and the highest tonal one (relative
    margin 1 %); all False when there is none.

    ``tonal`` marks the captures driven at one frequency (periodic, or a sine whose amplitude
    changes: :func:`is_periodic`, :func:`hystfit.conditions.amplitude_changes`). A broadband capture's "frequency" (a PRBS, a
    step pattern, a multisine: its strongest spectral line, :func:`hystfit.conditions.detect_condition`)
    says nothing about where it lies between the sines: counted, a step pattern at 0.32 Hz and a
    PRBS at ≈ 470 Hz made every sine interior, and every sine was held out (the model was fitted on the
    broadband captures alone and judged on sines only)."""
    tonal = [True] * len(captures) if tonal is None else list(tonal)
    f = np.array([c.frequency_Hz for c, t in zip(captures, tonal) if t], float)
    if not np.all(np.isfinite(f)) or f.size < 3:
        return [False] * len(captures)
    lo, hi = float(f.min()), float(f.max())
    return [bool(t and lo * 1.01 < c.frequency_Hz < hi / 1.01) for c, t in zip(captures, tonal)]


@dataclass(frozen=True)
class SplitChoice:
    """The hold-out scheme (see :attr:`DiagnoseSettings.split`): ``kind`` (``"temporal"``,
    ``"capture"`` or ``"cycles"``), the held-out flag per capture, the ``reason`` (``"requested"``,
    ``"swept"``, ``"stationary"`` or ``"swept_no_interior"``) and the sources of the captures whose amplitude changes
    within them (:func:`hystfit.report.diagnose_wording.split_why` words it)."""

    kind: str
    held_out: tuple[bool, ...]
    reason: str
    swept_sources: tuple[str, ...] = ()


def split_choice(captures: Sequence[Capture], swept: Sequence[bool], settings: "DiagnoseSettings",
                 per_condition: bool, tonal: Sequence[bool] | None = None) -> SplitChoice:
    """The hold-out of a diagnosis (see :attr:`DiagnoseSettings.split`); ``tonal`` as in
    :func:`heldout_captures` (the captures a ``"capture"`` split interpolates between)."""
    held = heldout_captures(captures, tonal)
    possible = (not per_condition) and any(held) and not all(held)
    none = (False,) * len(captures)
    if settings.split == "temporal":
        return SplitChoice("temporal", none, "requested")
    if settings.split == "cycles":
        return SplitChoice("cycles", none, "requested")
    if settings.split == "capture":
        if not possible:
            raise ConfigError("diagnose: split 'capture' needs, in global mode, captures at three or more drive "
                              "frequencies (sines, triangles or rising sines; PRBS and step captures have none): the "
                              "interior ones are held out; use split 'temporal' or 'auto'")
        return SplitChoice("capture", tuple(held), "requested")
    if not any(swept):
        return SplitChoice("temporal", none, "stationary")
    sources = tuple(c.name for c, s in zip(captures, swept) if s)
    if possible:
        return SplitChoice("capture", tuple(held), "swept", sources)
    return SplitChoice("cycles", none, "swept_no_interior", sources)


def choose_split(captures: Sequence[Capture], swept: Sequence[bool], settings: "DiagnoseSettings",
                 per_condition: bool, tonal: Sequence[bool] | None = None) -> tuple[str, list[bool], str]:
    """(kind, held-out flags per capture, reason code) of the hold-out: :func:`split_choice` as a tuple."""
    s = split_choice(captures, swept, settings, per_condition, tonal)
    return s.kind, list(s.held_out), s.reason


@dataclass(frozen=True)
class _Calibration(Effect):
    """Per-capture offset and gain against the first capture: y_c = ŷ_c + o_c + g_c·ŷ_c (c ≥ 1).

    Not a candidate effect of the actuator: when the captures disagree by a re-zeroed or re-scaled
    sensor (:func:`capture_calibration`), it is part of the base before any effect is tested, so an
    effect is never named for what a calibration explains."""

    name: ClassVar[str] = "calibration"
    title: ClassVar[str] = "per-capture sensor offset and gain"
    equation: ClassVar[str] = "y_c = ŷ_c + o_c + g_c·ŷ_c (first capture the reference)"

    def layout(self):
        return 0, 2

    def regressors(self, yhat, view, phi):
        yh = np.asarray(yhat, float)
        n = yh.shape[0]
        if view.index == 0:
            return np.zeros((n, 0)), np.zeros((n, 2))
        return np.zeros((n, 0)), np.column_stack([np.ones(n), yh])

    def tangent(self, x, yhat, view, phi, shared, local):
        g = 0.0 if view.index == 0 else float(local[1])
        return x * (1.0 + g)

    def describe(self, phi, shared, local, views, sources=None):
        local = np.asarray(local, float).reshape(-1, 2)
        names = list(sources) if sources is not None else [f"capture{i}" for i in range(local.shape[0])]
        return {"per_capture": [{"source": s, "offset_out": float(o), "gain": 1.0 + float(g)}
                                for s, (o, g) in zip(names, local)]}


def capture_calibration(captures: Sequence[Capture], predictions: Sequence[np.ndarray], sigma: float) -> list[dict]:
    """Per capture, the offset and gain that map the common fit onto it (y ≈ o + g·ŷ, least squares),
    and whether captures *of the same operating condition* disagree by more than the data can
    explain: offsets more than 5 noise floors apart or gains more than 1 % apart, when the capture's
    RMSE improves by more than 20 % with its own offset and gain. Only repeated conditions can show
    a calibration: between different conditions a gain difference is the actuator's own rate or
    amplitude dependence. A sensor re-zeroed or re-calibrated between recordings shows up here, as
    such, instead of being read as an effect of the actuator."""
    out = []
    for c, p in zip(captures, predictions):
        p = np.asarray(p, float)
        A = np.column_stack([np.ones_like(p), p - p.mean()])
        coef = np.linalg.lstsq(A, c.y - p.mean(), rcond=None)[0]
        r0 = float(np.sqrt(np.mean((c.y - p) ** 2)))
        r1 = float(np.sqrt(np.mean((c.y - p.mean() - A @ coef) ** 2)))
        out.append({"offset_out": float(coef[0]), "gain": float(coef[1]), "rmse_with_calibration_out": r1,
                    "calibration_differs": False, "_better": r1 < 0.8 * r0})
    key = [(round(c.amplitude_V, 6), round(c.frequency_Hz, 6)) for c in captures]
    for i, a in enumerate(out):
        for j, b in enumerate(out):
            if i != j and key[i] == key[j] and (abs(a["offset_out"] - b["offset_out"]) > 5.0 * sigma
                                                or abs(a["gain"] / b["gain"] - 1.0) > 0.01):
                a["calibration_differs"] = a["calibration_differs"] or a["_better"] or b["_better"]
    for a in out:
        a.pop("_better")
    return out


def _truncate(c: Capture, n: int) -> Capture:
    return replace(c, t=c.t[:n], u=c.u[:n], y=c.y[:n])


def _fit_segments(c: Capture, fit: np.ndarray) -> list[Capture]:
    """The captures a base fit on the samples ``fit`` of ``c`` pools: one per run of fitted samples,
    each simulated from the capture's start and scored from the run's start (a warm-up), so the
    model's state at every fitted sample is its own — exact for any model."""
    idx = np.flatnonzero(np.diff(np.concatenate([[0], fit.astype(np.int8), [0]])))
    out = []
    for start, stop in zip(idx[::2], idx[1::2]):
        if stop - start >= 2:
            out.append(replace(_truncate(c, int(stop)), warmup_samples=max(int(start), int(c.warmup_samples))))
    return out


# ----------------------------------------------------------------------------------------------
# Noise floor
# ----------------------------------------------------------------------------------------------

#: ``noise.method`` of :func:`estimate_noise`: 1.4826·MAD of the third difference of the base residual,
#: median over the captures (worded by :func:`hystfit.report.diagnose_wording.noise_method_text`; with
#: ``noise.refined`` the floor was refined with the final model's residual).
NOISE_METHOD_CODE = "mad_third_difference"

def estimate_noise(captures: Sequence[Capture], residuals: Sequence[np.ndarray],
                   periodic: Sequence[bool]) -> dict:
    """Sensor noise floor estimated from the data (output unit), never from the model fit quality.

    Two estimates:

    - ``sigma`` (the floor used everywhere): the robust scale 1.4826·MAD of the third-order
      difference (−1, 3, −3, 1)/√20 of the base model's residual per capture, then the median
      over the captures (the sensor is the same for all; a broadband capture whose residual rings
      at a resonance would bias a pooled estimate up).
      The difference removes anything smooth (the model error of a slowly varying loop, drift,
      creep: polynomials up to degree two vanish) and keeps white noise at unit gain; the median
      ignores the few samples where the residual has a kink (turning points, steps). It measures
      the white, sample-to-sample part of the noise.
    - ``repeatability`` (a cross-check, periodic captures with an integer number of samples per
      period and at least three cycles): the measured output one period apart, y(t + P) − y(t),
      after the first cycle, with its slow part (moving average over a period) removed, divided
      by √2. It also contains low-frequency noise and anything else that does not repeat from
      cycle to cycle, so it is an upper bound; a value well above ``sigma`` says the noise is
      coloured or the process does not repeat.

    Returns
    -------
    dict
        ``sigma``, ``method``, ``per_capture_out`` (list of per-capture σ), ``repeatability_out`` (or
        None), ``quantization_step_out`` (the smallest nonzero step between output samples, for
        reference); all in the output unit (``_out`` becomes the unit in the JSON).
    """
    per = []
    for r in residuals:
        r = np.asarray(r, float)
        if r.size < 8:
            per.append(float("nan"))
            continue
        per.append(white_noise_sigma(r))
    finite = [v for v in per if math.isfinite(v)]
    sigma = float(np.median(finite)) if finite else 0.0
    rep = []
    for c, is_per in zip(captures, periodic):
        if not is_per:
            continue
        P = 1.0 / (c.frequency_Hz * c.dt)
        Pi = int(round(P))
        if abs(P - Pi) > 1e-6 * P or c.n < 3 * Pi + 1:
            continue
        e = c.y[2 * Pi:] - c.y[Pi:-Pi]
        if e.size < Pi + 1:
            continue
        kern = np.ones(Pi) / Pi
        slow = np.convolve(e, kern, mode="same")
        core = (e - slow)[Pi // 2: e.size - Pi // 2]
        rep.append((float(np.sum(core ** 2)) / 2.0 / (1.0 - 1.0 / Pi), core.size))
    repeat = math.sqrt(sum(s for s, _ in rep) / sum(n for _, n in rep)) if rep else None
    steps = np.concatenate([np.abs(np.diff(c.y)) for c in captures])
    steps = steps[steps > 0]
    q = float(steps.min()) if steps.size else 0.0
    spc = [1.0 / (c.frequency_Hz * c.dt) for c, is_per in zip(captures, periodic)
           if is_per and c.frequency_Hz > 0 and math.isfinite(c.frequency_Hz)]
    return {"sigma": sigma, "method": NOISE_METHOD_CODE,
            "per_capture_out": per, "repeatability_out": repeat, "quantization_step_out": q,
            "samples_per_cycle_min": min(spc) if spc else None}


#: fewer samples per drive cycle than this, and a white-noise floor over
#: :data:`DOUBTFUL_FLOOR_RATIO` × the cycle-to-cycle repeatability: the floor is doubtful
COARSE_SAMPLES_PER_CYCLE = 20.0
DOUBTFUL_FLOOR_RATIO = 3.0


def noise_floor_doubtful(noise: dict) -> bool:
    """Whether the white-noise floor of :func:`estimate_noise` is probably overestimated: a periodic
    drive with fewer than :data:`COARSE_SAMPLES_PER_CYCLE` samples per cycle, where the third
    difference of the residual measures the residual's own change between samples, not the sensor
    (a 500 Hz drive at 5 kHz: σ 0.37 µm against a repeatability of 0.014 µm on the virtual stage,
    ``python benchmarks/blind_cases.py``, case 4), and a floor
    over :data:`DOUBTFUL_FLOOR_RATIO` × the repeatability, which does not see that change. Either
    alone is no sign: a well-sampled slow drive can repeat far more closely than its white noise
    (quantized outputs), and a coarse drive of a smooth residual can still give the right floor."""
    spc, rep = noise.get("samples_per_cycle_min"), noise.get("repeatability_out")
    return (spc is not None and spc < COARSE_SAMPLES_PER_CYCLE and rep is not None
            and noise["sigma"] > DOUBTFUL_FLOOR_RATIO * rep)


# ----------------------------------------------------------------------------------------------
# Where
# ----------------------------------------------------------------------------------------------


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def _excess(rmse: float, sigma: float) -> float:
    return math.sqrt(max(rmse * rmse - sigma * sigma, 0.0)) if math.isfinite(rmse) else float("nan")


def _reversals(u: np.ndarray) -> np.ndarray:
    """Indices where the input changes direction (the turning points), plus both ends."""
    du = np.diff(u)
    moving = np.flatnonzero(du != 0)
    if moving.size == 0:
        return np.array([0, u.size - 1])
    s = np.sign(du[moving])
    flips = moving[1:][s[1:] != s[:-1]]
    return np.unique(np.concatenate([[0], flips, [u.size - 1]]))


def _loop_position(u: np.ndarray) -> np.ndarray:
    """Position of every sample within its half-cycle: 0 at the previous turning point, 1 at the
    next one (by input value, so a raised cosine and a triangle agree); NaN on holds."""
    u = np.asarray(u, float)
    rev = _reversals(u)
    pos = np.full(u.size, np.nan)
    for a, b in zip(rev[:-1], rev[1:]):
        span = u[b] - u[a]
        if span != 0:
            pos[a:b + 1] = (u[a:b + 1] - u[a]) / span
    du = np.diff(u, prepend=u[0])
    pos[du == 0] = np.nan
    return np.clip(pos, 0.0, 1.0)


def _bands(r: np.ndarray, dt: float, f0: float) -> dict:
    """Residual power (mean square, out²) per band relative to the excitation frequency f0:
    ``drift`` below f0/2, ``low_harmonics`` f0/2 … 5.5·f0, ``high_harmonics`` 5.5·f0 … 50.5·f0,
    ``broadband`` above; each with the fraction of the frequency axis it covers (for the
    expected white-noise share)."""
    r = np.asarray(r, float)
    n = r.size
    R = np.fft.rfft(r)
    p = np.abs(R) ** 2
    p[1:] *= 2.0
    if n % 2 == 0:
        p[-1] /= 2.0
    p /= n * n  # Σ p = mean(r²)
    f = np.fft.rfftfreq(n, dt)
    edges = {"drift": (0.0, 0.5 * f0), "low_harmonics": (0.5 * f0, 5.5 * f0),
             "high_harmonics": (5.5 * f0, 50.5 * f0), "broadband": (50.5 * f0, np.inf)}
    out = {}
    nyq = 0.5 / dt
    for k, (a, b) in edges.items():
        sel = (f >= a) & (f < b)
        out[k] = (float(p[sel].sum()), float((min(b, nyq) - min(a, nyq)) / nyq))
    return out


def _capture_rows(caps: Sequence[Capture], res: Sequence[np.ndarray], periodic: Sequence[bool],
                  sigma: float) -> list[dict]:
    """``by_capture``: RMSE, excess over noise and mean of the residual per capture."""
    rows = []
    for c, r, per in zip(caps, res, periodic):
        rm = _rms(r)
        rows.append({"source": c.source, "amplitude_V": c.amplitude_V, "frequency_Hz": c.frequency_Hz,
                     "duration_s": c.duration_s, "periodic": bool(per), "rmse_out": rm,
                     "excess_rmse_out": _excess(rm, sigma), "mean_out": float(np.mean(r))})
    return rows


def _condition_rows(caps: Sequence[Capture], res: Sequence[np.ndarray], periodic: Sequence[bool],
                    sigma: float) -> list[dict]:
    """``by_condition``: RMSE and excess over noise per amplitude × frequency (sorted)."""
    groups: dict = {}
    for i, c in enumerate(caps):
        groups.setdefault((float(c.amplitude_V), float(c.frequency_Hz)), []).append(i)
    rows = []
    for (a, f), idx in sorted(groups.items()):
        rm = _rms(np.concatenate([res[i] for i in idx]))
        rows.append({"label": condition_label((a, f)), "amplitude_V": a, "frequency_Hz": f,
                     "rmse_out": rm, "excess_rmse_out": _excess(rm, sigma), "n_captures": len(idx),
                     "periodic": bool(all(periodic[i] for i in idx))})
    return rows


_BRANCHES = ("ascending", "descending")


def _directions(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, whether the input rises (ascending) or falls (descending) into it."""
    du = np.diff(u, prepend=u[0])
    tol = 1e-9 * max(float(np.ptp(u)), 1e-12)
    return du > tol, du < -tol


def _branch_section(caps: Sequence[Capture], res: Sequence[np.ndarray]) -> dict:
    """``by_branch``: RMSE, mean and samples of the residual while the input rises, falls or holds."""
    br = {"ascending": [], "descending": [], "hold": []}
    for c, r in zip(caps, res):
        asc, desc = _directions(c.u)
        br["ascending"].append(r[asc])
        br["descending"].append(r[desc])
        br["hold"].append(r[~(asc | desc)])
    return {k: {"rmse_out": _rms(np.concatenate(v)) if v else float("nan"),
                "mean_out": float(np.mean(np.concatenate(v))) if sum(x.size for x in v) else float("nan"),
                "n_samples": int(sum(x.size for x in v))} for k, v in br.items()}


def _level_section(caps: Sequence[Capture], res: Sequence[np.ndarray]) -> dict:
    """``by_level``: the mean residual per tenth of each capture's input range and branch (the
    "residual loop"), split into the part common to both branches and the part of opposite sign."""
    level_sum = {k: np.zeros(10) for k in _BRANCHES}
    level_n = {k: np.zeros(10) for k in _BRANCHES}
    for c, r in zip(caps, res):
        asc, desc = _directions(c.u)
        lv = np.clip(((c.u - c.u.min()) / max(float(np.ptp(c.u)), 1e-300) * 10).astype(int), 0, 9)
        for name, sel in (("ascending", asc), ("descending", desc)):
            np.add.at(level_sum[name], lv[sel], r[sel])
            np.add.at(level_n[name], lv[sel], 1)
    by_level = {"mean_by_level_out": {k: [float(q / n) if n else None for q, n in zip(level_sum[k], level_n[k])]
                                      for k in level_sum}}
    asc, desc = (np.array([np.nan if v is None else v for v in by_level["mean_by_level_out"][k]]) for k in _BRANCHES)
    both = np.isfinite(asc) & np.isfinite(desc)
    if both.sum() >= 3:
        common = 0.5 * (asc[both] + desc[both])
        common = common - common.mean()  # a constant offset is not a level dependence
        by_level["level_dependent_rms_out"] = _rms(common)
        by_level["branch_opposite_rms_out"] = _rms(0.5 * (asc[both] - desc[both]))
    return by_level


def _loop_section(caps: Sequence[Capture], res: Sequence[np.ndarray]) -> dict:
    """``by_loop_position``: near turning points vs mid-stroke, and the RMSE per tenth of the half-cycle."""
    pos_sq = {k: np.zeros(10) for k in _BRANCHES}
    pos_n = {k: np.zeros(10) for k in _BRANCHES}
    near, mid = [], []
    for c, r in zip(caps, res):
        asc, desc = _directions(c.u)
        pos = _loop_position(c.u)
        ok = np.isfinite(pos)
        near.append(r[ok & ((pos < 0.1) | (pos > 0.9))])
        mid.append(r[ok & (pos >= 0.1) & (pos <= 0.9)])
        b = np.clip((pos[ok] * 10).astype(int), 0, 9)
        for name, sel in (("ascending", asc[ok]), ("descending", desc[ok])):
            np.add.at(pos_sq[name], b[sel], r[ok][sel] ** 2)
            np.add.at(pos_n[name], b[sel], 1)
    nr, mr = np.concatenate(near), np.concatenate(mid)
    return {"near_turning_points": {"rmse_out": _rms(nr), "n_samples": int(nr.size)},
            "mid_stroke": {"rmse_out": _rms(mr), "n_samples": int(mr.size)},
            "rmse_by_position_out": {k: [float(math.sqrt(q / n)) if n else None for q, n in zip(pos_sq[k], pos_n[k])]
                                     for k in pos_sq}}


def _time_section(caps: Sequence[Capture], res: Sequence[np.ndarray], periodic: Sequence[bool]) -> dict:
    """``by_time``: the first cycle vs later, and mean and RMSE per tenth of the capture."""
    first, later = [], []
    tenth_sum, tenth_sq, tenth_n = np.zeros(10), np.zeros(10), np.zeros(10)
    for c, r, per in zip(caps, res, periodic):
        n1 = int(round(1.0 / (c.frequency_Hz * c.dt))) if per else int(round(0.1 * c.n))
        n1 = int(np.clip(n1, 1, c.n - 1))
        first.append(r[:n1])
        later.append(r[n1:])
        tb = np.clip((np.arange(c.n) * 10) // c.n, 0, 9)
        np.add.at(tenth_sum, tb, r)
        np.add.at(tenth_sq, tb, r * r)
        np.add.at(tenth_n, tb, 1)
    fr, lr = np.concatenate(first), np.concatenate(later)
    return {"first_cycle": {"rmse_out": _rms(fr), "mean_out": float(np.mean(fr)), "n_samples": int(fr.size)},
            "later": {"rmse_out": _rms(lr), "mean_out": float(np.mean(lr)), "n_samples": int(lr.size)},
            "mean_by_tenth_out": [float(s / n) if n else None for s, n in zip(tenth_sum, tenth_n)],
            "rmse_by_tenth_out": [float(math.sqrt(q / n)) if n else None for q, n in zip(tenth_sq, tenth_n)]}


def _drive_frequency(c: Capture) -> float:
    """The capture's excitation frequency, or one period per capture when it has none."""
    return c.frequency_Hz if np.isfinite(c.frequency_Hz) and c.frequency_Hz > 0 else 1.0 / c.duration_s


def _band_section(caps: Sequence[Capture], res: Sequence[np.ndarray], sigma: float) -> dict:
    """``by_band``: residual RMS per band of :func:`_bands`, the white-noise expectation and the
    share of the power above it."""
    band_tot = {"drift": 0.0, "low_harmonics": 0.0, "high_harmonics": 0.0, "broadband": 0.0}
    band_noise = dict.fromkeys(band_tot, 0.0)
    n_all = 0
    for c, r in zip(caps, res):
        for k, (pw, frac) in _bands(r, c.dt, _drive_frequency(c)).items():
            band_tot[k] += pw * c.n
            band_noise[k] += sigma * sigma * frac * c.n
        n_all += c.n
    above = {k: max(band_tot[k] - band_noise[k], 0.0) for k in band_tot}
    tot_above = sum(above.values())
    by_band = {k: {"rms_out": math.sqrt(band_tot[k] / n_all), "expected_noise_rms_out": math.sqrt(band_noise[k] / n_all),
                   "share_above_noise": (above[k] / tot_above) if tot_above > 0 else 0.0} for k in band_tot}
    return by_band


def _spectra(caps: Sequence[Capture], res: Sequence[np.ndarray], periodic: Sequence[bool]) -> list:
    """Per periodic capture: (frequency / f0, residual amplitude spectrum, source), for the figures."""
    out = []
    for c, r, per in zip(caps, res, periodic):
        if per:
            n = r.size
            out.append((np.fft.rfftfreq(n, c.dt) / _drive_frequency(c), np.abs(np.fft.rfft(r)) * 2.0 / n, c.source))
    return out


def where_analysis(captures: Sequence[Capture], residuals: Sequence[np.ndarray], sigma: float,
                   periodic: Sequence[bool], residuals_alone: Sequence[np.ndarray] | None = None
                   ) -> tuple[dict, dict]:
    """Break the base model's residual e = model − measured down (output unit).

    Returns
    -------
    (where, data)
        ``where``: JSON-ready numbers — ``by_condition`` (RMSE and excess over noise per amplitude ×
        frequency), ``by_capture``, ``by_branch`` (ascending / descending / hold: RMSE and mean),
        ``by_loop_position`` (within 10 % of the half-cycle stroke from a turning point vs
        mid-stroke, and RMSE per tenth of the half-cycle), ``by_time`` (first cycle vs later, RMSE
        and mean per tenth of the capture), ``by_band`` (share of the residual power above the
        white-noise expectation in the drift band below f0/2, the fundamental and low harmonics up
        to 5.5 f0, the high harmonics up to 50.5 f0, and broadband above), and ``summary``
        (exponents of the gap vs frequency and amplitude, low/high frequency shares, long-capture
        ratio, first-cycle ratio). ``data`` holds arrays for the figures and the ``findings``
        (:func:`findings`; :func:`hystfit.report.diagnose_wording.pointers_text` words them as the
        ``pointers`` of diagnosis.json). Sections hold numbers only (their ``definition`` sentences
        are :data:`hystfit.report.diagnose_wording.DEFINITIONS`).

        With ``residuals_alone`` (the residuals of the base model fitted to each condition on its
        own), ``by_condition_alone`` and the ``*_alone`` exponents describe the gap *within* a
        condition: a global model spreads a condition-dependent error over all conditions (it
        compromises), a model fitted per condition shows where the loop shape itself is wrong.
        ``by_level`` is the mean residual per tenth of each capture's input range on each
        branch: the "residual loop" (a lag draws an ellipse, a bow an arch).
    """
    caps = list(captures)
    res = [np.asarray(r, float) for r in residuals]
    by_capture = _capture_rows(caps, res, periodic, sigma)
    by_condition = _condition_rows(caps, res, periodic, sigma)
    alone = [np.asarray(r, float) for r in residuals_alone] if residuals_alone is not None else None
    by_condition_alone = _condition_rows(caps, alone, periodic, sigma) if alone is not None else None
    by_branch, by_level = _branch_section(caps, res), _level_section(caps, res)
    by_loop, by_time = _loop_section(caps, res), _time_section(caps, res, periodic)
    by_band = _band_section(caps, res, sigma)
    summary = _summary(by_condition, by_capture, by_band, by_time, sigma)
    summary["level_dependent_rms_out"] = by_level.get("level_dependent_rms_out")
    summary["branch_opposite_rms_out"] = by_level.get("branch_opposite_rms_out")
    if by_condition_alone is not None:
        summary["frequency_exponent_alone"], summary["amplitude_exponent_alone"] = \
            _loglog_fit(by_condition_alone, sigma)
    where = {"by_condition": by_condition, "by_capture": by_capture, "by_branch": by_branch,
             "by_loop_position": by_loop, "by_level": by_level, "by_time": by_time, "by_band": by_band}
    if by_condition_alone is not None:
        where["by_condition_alone"] = by_condition_alone
    where["summary"] = summary
    found = findings(summary, by_branch, by_loop, sigma)
    return where, {"spectra": _spectra(caps, res, periodic), "findings": found}


def _loglog_fit(rows: list[dict], sigma: float) -> tuple[float | None, float | None]:
    """Exponents b, c of excess RMSE ≈ k·f^b·A^c over periodic conditions (None when undetermined)."""
    pts = [(r["frequency_Hz"], r["amplitude_V"], r["excess_rmse_out"]) for r in rows
           if r["periodic"] and r["frequency_Hz"] > 0 and r["amplitude_V"] > 0]
    if len(pts) < 2:
        return None, None
    f, a, e = (np.array(x, float) for x in zip(*pts))
    e = np.maximum(e, 0.05 * max(sigma, 1e-300))
    cols, names = [np.ones_like(f)], []
    if np.unique(f).size >= 2:
        cols.append(np.log(f))
        names.append("f")
    if np.unique(a).size >= 2:
        cols.append(np.log(a))
        names.append("a")
    if len(names) == 0 or len(pts) < len(cols):
        return None, None
    X = np.column_stack(cols)
    coef = np.linalg.lstsq(X, np.log(e), rcond=None)[0]
    out = dict(zip(names, coef[1:]))
    return (float(out["f"]) if "f" in out else None), (float(out["a"]) if "a" in out else None)


def _summary(by_condition, by_capture, by_band, by_time, sigma) -> dict:
    bf, ba = _loglog_fit(by_condition, sigma)
    durations = np.array([c["duration_s"] for c in by_capture])
    ratio = None
    if durations.size >= 2 and durations.max() > 2.0 * np.median(durations):
        longest = durations >= 0.5 * durations.max()
        ex = np.array([c["excess_rmse_out"] for c in by_capture])
        rest = ex[~longest]
        if rest.size:
            ratio = float(np.max(ex[longest]) / max(np.median(rest), 1e-3 * max(sigma, 1e-300)))
    worst = max(by_condition, key=lambda r: r["rmse_out"]) if by_condition else None
    fc = by_time["first_cycle"]["rmse_out"]
    lt = by_time["later"]["rmse_out"]
    return {"frequency_exponent": bf, "amplitude_exponent": ba,
            "low_frequency_share": by_band["drift"]["share_above_noise"],
            "high_frequency_share": by_band["high_harmonics"]["share_above_noise"] + by_band["broadband"]["share_above_noise"],
            "long_capture_ratio": ratio,
            "first_cycle_ratio": float(fc / lt) if lt > 0 else None,
            "worst_condition": worst["label"] if worst else None}


#: A gap growing at least this fast with the amplitude points to a static output nonlinearity: the
#: error of a scale-invariant loop shape grows ∝ A, a quadratic bow ∝ A².
AMPLITUDE_EXPONENT_LARGE = 2.0


def _trend_findings(summary: dict) -> list[Finding]:
    """How the gap grows with frequency and amplitude (globally and per condition alone), and into
    held-out time or captures."""
    out = []
    for suffix in ("", "_alone"):
        alone = suffix == "_alone"
        bf, ba = summary.get("frequency_exponent" + suffix), summary.get("amplitude_exponent" + suffix)
        if bf is not None and bf > 0.15:
            out.append(Finding("frequency_grows", {"exponent": bf, "alone": alone}))
        elif bf is not None and bf < -0.15:
            out.append(Finding("frequency_shrinks", {"exponent": bf, "alone": alone}))
        if ba is not None and ba >= AMPLITUDE_EXPONENT_LARGE:
            out.append(Finding("amplitude_large", {"exponent": ba, "alone": alone}))
    ratio = summary.get("heldout_to_fit_ratio")
    if ratio is not None and ratio > 1.15 and summary.get("split", "temporal") == "temporal":
        out.append(Finding("later_time_swept" if summary.get("amplitude_changes_within_capture") else "later_time",
                           {"ratio": ratio}))
    elif ratio is not None and ratio > 1.15 and summary.get("split") == "cycles":
        out.append(Finding("heldout_cycles", {"ratio": ratio}))
    elif ratio is not None and ratio > 1.15:
        out.append(Finding("heldout_captures", {"ratio": ratio}))
    if summary["low_frequency_share"] > 0.25:
        out.append(Finding("low_frequency_share", {"share": summary["low_frequency_share"]}))
    if summary["high_frequency_share"] > 0.3:
        out.append(Finding("high_frequency_share", {"share": summary["high_frequency_share"]}))
    if summary["long_capture_ratio"] is not None and summary["long_capture_ratio"] > 1.5:
        out.append(Finding("long_captures", {"ratio": summary["long_capture_ratio"]}))
    return out


def _shape_findings(summary: dict, by_branch: dict, by_loop: dict, sigma: float) -> list[Finding]:
    """Where in the loop the error sits: by input level, by branch, near turning points, at start-up."""
    out = []
    lv, bo = summary.get("level_dependent_rms_out"), summary.get("branch_opposite_rms_out")
    if lv is not None and bo is not None and max(lv, bo) > 2.0 * sigma:
        if lv > 1.5 * bo:
            out.append(Finding("level_dependent", {"level_rms": lv, "opposite_rms": bo}))
        elif bo > 1.5 * lv:
            out.append(Finding("branch_opposite", {"level_rms": lv, "opposite_rms": bo}))
    a, d = by_branch["ascending"], by_branch["descending"]
    if a["n_samples"] and d["n_samples"] and math.isfinite(a["mean_out"]) and math.isfinite(d["mean_out"]):
        if not any(f.kind == "branch_opposite" for f in out) and a["mean_out"] * d["mean_out"] < 0 and \
                abs(a["mean_out"] - d["mean_out"]) > max(2.0 * sigma, 0.25 * max(a["rmse_out"], d["rmse_out"])):
            out.append(Finding("branch_bias", {"ascending_mean": a["mean_out"], "descending_mean": d["mean_out"]}))
    n, m = by_loop["near_turning_points"]["rmse_out"], by_loop["mid_stroke"]["rmse_out"]
    if math.isfinite(n) and math.isfinite(m) and m > 0:
        if n > 1.3 * m:
            out.append(Finding("turning_points", {"ratio": n / m}))
        elif m > 1.3 * n:
            out.append(Finding("mid_stroke", {"ratio": m / n}))
    if summary["first_cycle_ratio"] is not None and summary["first_cycle_ratio"] > 1.5:
        out.append(Finding("start_up", {"ratio": summary["first_cycle_ratio"]}))
    return out


def findings(summary: dict, by_branch: dict, by_loop: dict, sigma: float) -> list[Finding]:
    """The strong findings of :func:`where_analysis` (thresholds in the code); ``no_concentration``
    when there is none."""
    out = _trend_findings(summary) + _shape_findings(summary, by_branch, by_loop, sigma)
    return out or [Finding("no_concentration")]


# ----------------------------------------------------------------------------------------------
# Base model + chain of effects: predictions, linearization, refits
# ----------------------------------------------------------------------------------------------


@dataclass
class _Group:
    label: str
    condition: tuple[float, float]
    model: Model
    params: tuple
    theta: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    indices: tuple[int, ...]
    objective: tuple | None = field(default=None, repr=False, compare=False)  # (lengths, Objective): _group_objective
    #: capture index → (its input, the model's :meth:`~hystfit.models.base.Model.head_simulator` of it):
    #: copies of a state share it (:func:`_base_predictions` simulates every state of a fit on the same inputs)
    simulators: dict = field(default_factory=dict, repr=False, compare=False)

    def __getstate__(self) -> dict:
        """Pickled without its objective and simulators (they hold the model's compiled simulators and
        design matrices; a forked worker returns its states to this process, which makes them again
        when it needs them)."""
        return {**self.__dict__, "objective": None, "simulators": {}}


def _group_objective(g: _Group, captures, lengths: Sequence[int]) -> Objective:
    """The objective of group ``g`` over the first ``lengths`` samples of its captures, made once per
    group and lengths (the model and the data do not change while θ moves; copies of a state share it)."""
    key = tuple(int(lengths[i]) for i in g.indices)
    if g.objective is None or g.objective[0] != key:
        series = [Series(captures[i].u[:lengths[i]], captures[i].y[:lengths[i]], captures[i].dt) for i in g.indices]
        g.objective = (key, Objective(g.model, series))
    return g.objective[1]


@dataclass
class _State:
    """Base parameters per group plus the chain of effects added so far."""

    groups: list[_Group]
    chain: list[EffectFit]
    group_of: tuple[int, ...]

    def copy(self) -> "_State":
        return _State([replace(g, theta=g.theta.copy()) for g in self.groups],
                      [replace(f, shared=f.shared.copy(), local=f.local.copy()) for f in self.chain], self.group_of)


def _base_prediction(state: _State, captures: Sequence[Capture], i: int, n: int) -> np.ndarray:
    """The base's prediction of capture ``i`` over its first ``n`` samples (its group's simulator of
    that capture made once and kept on the group)."""
    g = state.groups[state.group_of[i]]
    c = captures[i]
    with np.errstate(all="ignore"):
        u, sim = g.simulators.get(i, (None, None))
        if u is not c.u:
            sim = g.model.head_simulator(c.u, c.dt)
            g.simulators[i] = (c.u, sim)
        return sim(g.theta, n)


def _base_predictions(state: _State, captures: Sequence[Capture], lengths: Sequence[int] | None = None) -> list:
    return [_base_prediction(state, captures, i, c.n if lengths is None else lengths[i])
            for i, c in enumerate(captures)]


def _predictions(state: _State, captures, views, lengths=None) -> list:
    base = _base_predictions(state, captures, lengths)
    out = []
    for i, (x, v) in enumerate(zip(base, views)):
        vv = v if x.shape[0] == v.n else v.head(x.shape[0])
        for link in state.chain:
            x = link.apply(x, vv, i)
        out.append(x)
    return out


def _layout(state: _State, n_captures: int) -> tuple[list[int], list[tuple[int, int]], int]:
    """Column offsets: per group (base θ), per chain link (shared, local); total columns."""
    off = 0
    g_off = []
    for g in state.groups:
        g_off.append(off)
        off += g.theta.size
    l_off = []
    for link in state.chain:
        ks, kl = link.effect.layout()
        l_off.append((off, off + ks))
        off += ks + kl * n_captures
    return g_off, l_off, off


def _linearize(state: _State, captures, views) -> tuple[list[np.ndarray], Linearization]:
    """The current model's output over each capture's fit part and its Jacobian w.r.t. every
    base parameter and every chain coefficient (pushed through the chain's tangents)."""
    C = len(captures)
    lengths = [max(v.fit_end, 2) for v in views]
    g_off, l_off, n = _layout(state, C)
    lower = np.empty(n)
    upper = np.empty(n)
    jac_rows: dict[int, list] = {}
    for gi, g in enumerate(state.groups):
        sl = slice(g_off[gi], g_off[gi] + g.theta.size)
        lower[sl] = g.lower - g.theta
        upper[sl] = g.upper - g.theta
        J = _group_objective(g, captures, lengths).jacobian(g.theta, upper=g.upper, lower=g.lower)
        start = 0
        for i in g.indices:
            jac_rows[i] = J[start:start + lengths[i]]
            start += lengths[i]
    for li, link in enumerate(state.chain):
        sl_lo, sl_hi, ll_lo, ll_hi = link.effect.coefficient_bounds()
        s0, l0 = l_off[li]
        ks, kl = link.effect.layout()
        lower[s0:s0 + ks] = sl_lo - link.shared
        upper[s0:s0 + ks] = sl_hi - link.shared
        for c in range(C):
            a = l0 + c * kl
            lower[a:a + kl] = ll_lo - link.local[c]
            upper[a:a + kl] = ll_hi - link.local[c]
    base = _base_predictions(state, captures, lengths)
    xs, jacs, cols = [], [], []
    for i in range(C):
        v = views[i].head(lengths[i])
        gi = state.group_of[i]
        J = jac_rows[i]
        col = list(range(g_off[gi], g_off[gi] + state.groups[gi].theta.size))
        x = base[i]
        for li, link in enumerate(state.chain):
            Rs, Rl = link.effect.regressors(x, v, link.phi)
            J = link.tangent(J, x, v, i)
            x = link.apply(x, v, i)
            ks, kl = link.effect.layout()
            s0, l0 = l_off[li]
            J = np.hstack([J, Rs, Rl])
            col += list(range(s0, s0 + ks)) + list(range(l0 + i * kl, l0 + (i + 1) * kl))
        xs.append(x)
        jacs.append(np.ascontiguousarray(J))
        cols.append(np.asarray(col, int))
    return xs, Linearization(tuple(jacs), tuple(cols), lower, upper)


def _step(state: _State, delta: np.ndarray, alpha: float, n_captures: int) -> _State:
    """A copy of ``state`` moved by α·δ (clipped to every bound)."""
    new = state.copy()
    if delta.size == 0 or alpha == 0.0:
        return new
    g_off, l_off, _ = _layout(state, n_captures)
    for gi, g in enumerate(new.groups):
        d = delta[g_off[gi]:g_off[gi] + g.theta.size]
        g.theta = np.clip(g.theta + alpha * d, g.lower, g.upper)
    for li, link in enumerate(new.chain):
        ks, kl = link.effect.layout()
        s0, l0 = l_off[li]
        slo, shi, llo, lhi = link.effect.coefficient_bounds()
        shared = np.clip(link.shared + alpha * delta[s0:s0 + ks], slo, shi)
        local = np.clip(link.local + alpha * delta[l0:l0 + n_captures * kl].reshape(n_captures, kl), llo, lhi)
        new.chain[li] = replace(link, shared=shared, local=local)
    return new


def _sse(preds, views, which: str) -> tuple[float, int]:
    """Sum of squared errors of ``preds`` against the measured outputs over the ``"fit"`` or the
    held-out (``"test"``) samples; ``"test_diff"``: of ``preds`` themselves (differences of two
    predictions) over the held-out samples."""
    s, n = 0.0, 0
    for p, v in zip(preds, views):
        m = v.fit if which == "fit" else ~v.fit
        m = m[: p.shape[0]]
        e = p[: m.size][m] if which == "test_diff" else p[: m.size][m] - v.y[: m.size][m]
        s += float(e @ e)
        n += int(m.sum())
    return s, n


def _rmse(preds, views, which: str) -> float:
    s, n = _sse(preds, views, which)
    return math.sqrt(s / n) if n else float("nan")


def _insertion(chain: Sequence[EffectFit], effect: Effect) -> int:
    """Where ``effect`` joins ``chain``: before the first link a signal meets after it in the plant's
    order (:data:`SIGNAL_ORDER`, the order of the recommended model) when its operator is the
    identity (a static map or added regressors: asymmetry, creep), else at the end. Where the order
    matters it is the plant's: a bow after a resonant stage bends the ringing, one before it the
    hysteresis output. Effects with an operator (dynamics, delay) are linear and time-invariant,
    as are the links after them, so appending them is the same model."""
    if type(effect).operator is not Effect.operator or effect.name not in SIGNAL_ORDER:
        return len(chain)
    rank = SIGNAL_ORDER.index(effect.name)
    for i, link in enumerate(chain):
        if link.effect.name in SIGNAL_ORDER and SIGNAL_ORDER.index(link.effect.name) > rank:
            return i
    return len(chain)


def _chain_signals(state: _State, captures, views, pos: int, lengths: Sequence[int]) -> tuple[list, tuple]:
    """The predictions of ``state`` over the first ``lengths`` samples of every capture and, per
    capture, the signal that enters link ``pos`` of its chain with each later link and its input."""
    preds, signals = [], []
    for i, (x, v) in enumerate(zip(_base_predictions(state, captures, lengths), views)):
        vv = v if x.shape[0] == v.n else v.head(x.shape[0])
        for link in state.chain[:pos]:
            x = link.apply(x, vv, i)
        at, later = x, []
        for link in state.chain[pos:]:
            later.append((link, x))
            x = link.apply(x, vv, i)
        preds.append(x)
        signals.append((at, tuple(later)))
    return preds, tuple(signals)


#: how many times :func:`_augment` widens a search range whose bound the fit ended on
WIDENINGS = 2


def _augment(state: _State, effect: Effect, captures, views, lin_cache: tuple, iterations: int,
             phi0: np.ndarray | None = None, grid_scores: np.ndarray | None = None) -> tuple[_State, EffectFit]:
    """Fit ``effect`` on top of ``state`` jointly with the base and the earlier effects
    (:func:`_augment_once`); when the fit ends on a bound of its search range that the data's scale
    chose (:meth:`~hystfit.effects.Effect.widened`: a stage's lowest f_n), again on the wider range —
    at most :data:`WIDENINGS` times, each kept when its fit-part SSE is not larger. The fit's
    ``effect`` is then the widened one (its range is in its parameters and in the options of the
    recommended model, :meth:`Diagnosis.recommended_options`)."""
    new, fit = _augment_once(state, effect, captures, views, lin_cache, iterations, phi0, grid_scores)
    for _ in range(WIDENINGS):
        wider = fit.effect.widened(fit.phi)
        if wider is None:
            break
        new_w, fit_w = _augment_once(state, wider, captures, views, lin_cache, iterations)
        if not fit_w.sse <= fit.sse:
            break
        new, fit = new_w, fit_w
    return new, fit


def _augment_once(state: _State, effect: Effect, captures, views, lin_cache: tuple, iterations: int,
                  phi0: np.ndarray | None = None, grid_scores: np.ndarray | None = None) -> tuple[_State, EffectFit]:
    """Fit ``effect`` on top of ``state`` jointly with the base and the earlier effects.

    Each iteration: search φ with the linear coefficients and a Gauss–Newton step δ of every
    earlier parameter solved exactly (:meth:`Effect.fit` with the linearization), then a true
    re-simulation at α·δ for α ∈ {1, ½, 0} with the new coefficients re-solved on the true
    output; the best true fit-sample SSE wins (α = 0 is the effect on the fixed base, so the
    result is never worse than that). A second iteration re-linearizes at the new point.
    ``effect`` joins the chain where a signal meets it in the plant (:func:`_insertion`).
    ``lin_cache``: (predictions, linearization) of ``state``, optionally with their
    :func:`hystfit.effects.prepare_design` third (made once for every effect fitted on them).
    ``grid_scores``: the scores of the effect's search grid on that design, when already computed.
    """
    C = len(captures)
    xs, lin = lin_cache[:2]
    design = lin_cache[2] if len(lin_cache) > 2 else None
    best_state, best_fit, best_sse = None, None, math.inf
    cur = state
    phi_start = phi0
    pos = _insertion(state.chain, effect)
    inserted = pos < len(state.chain)
    for it in range(iterations):
        if it > 0:
            xs, lin = _linearize(cur, captures, views)
        fitted = effect
        if inserted:
            fitted = Inserted(effect, _chain_signals(cur, captures, views, pos, [x.shape[0] for x in xs])[1])
        fit = fitted.fit(xs, views, lin, phi0=phi_start, local_search=(it > 0 or phi0 is not None),
                         design=design if it == 0 else None, grid_scores=grid_scores if it == 0 else None)
        improved = False
        exact = False
        for alpha in (1.0, 0.5, 0.0):
            cand = _step(cur, fit.delta, alpha, C)
            heads = [v.head(max(v.fit_end, 1)) for v in views]
            lengths = [h.n for h in heads]
            if inserted:
                preds, signals = _chain_signals(cand, captures, views, pos, lengths)
                fitted = Inserted(effect, signals)
            else:
                preds = _predictions(cand, captures, views, lengths)
            sh, lo, _, sse = solve_coefficients(fitted, fit.phi, preds, heads, None, bounded=True)
            f2 = EffectFit(effect, fit.phi, sh, lo, np.empty(0), sse, fit.evaluations)
            if sse < best_sse:
                best_sse = sse
                best_state = cand
                best_fit = f2
                improved = True
            if alpha == 1.0 and sse <= fit.sse * (1.0 + 1e-3) + 1e-300:
                exact = True  # the linear model predicted the true fit: nothing to gain from a shorter step
                break
        if not improved or exact:
            break
        cur = best_state
        phi_start = best_fit.phi
    new = best_state.copy()
    new.chain.insert(pos, best_fit)
    if any(v.local is not None for v in views):
        new = _fill_local(new, captures, views)
        best_fit = new.chain[pos]
    return new, best_fit


def _predict_capture(state: _State, captures, views, i: int) -> np.ndarray:
    """``_predictions(state, ...)[i]``, capture ``i`` alone."""
    x = _base_prediction(state, captures, i, captures[i].n)
    for link in state.chain:
        x = link.apply(x, views[i], i)
    return x


def _fill_local(state: _State, captures, views) -> _State:
    """``state`` with the per-capture coefficients of the captures held out whole solved on their
    own first part (``CaptureView.local``), link by link in chain order, everything else fixed: the
    model is affine in them (additive regressors, passed through linear later links), so the
    columns are the predictions' differences for unit coefficients, exactly. Their held-out
    samples then see, e.g., their own drift offset and rate — as a temporal split gives every
    capture — while nothing shared is fitted on them. Coefficients are clipped to their bounds."""
    out = state.copy()
    for li, link in enumerate(out.chain):
        kl = link.effect.layout()[1]
        if not kl:
            continue
        local = link.local.copy()
        for i, v in enumerate(views):
            if v.local is None or not v.local.any():
                continue
            local[i] = 0.0
            out.chain[li] = replace(link, local=local.copy())
            p0 = _predict_capture(out, captures, views, i)
            cols = []
            for j in range(kl):
                unit = local.copy()
                unit[i, j] = 1.0
                out.chain[li] = replace(link, local=unit)
                cols.append(_predict_capture(out, captures, views, i) - p0)
            m = v.local[: p0.shape[0]]
            A = np.column_stack(cols)[m]
            a = np.linalg.lstsq(A, (v.y[: p0.shape[0]] - p0)[m], rcond=None)[0]
            _, _, lo, hi = link.effect.coefficient_bounds()
            local[i] = np.clip(a, lo, hi)
            link = replace(link, local=local.copy())
            out.chain[li] = link
    return out


# ----------------------------------------------------------------------------------------------
# Verdict
# ----------------------------------------------------------------------------------------------


def choose_effect(results: Sequence[EffectResult], settings: DiagnoseSettings) -> EffectResult | None:
    """The effect to name, or None.

    Eligible effects pass all of: held-out ``reduction`` ≥ ``threshold``; held-out improvement
    above the best placebo of the same size; the held-out gap exceeds the noise floor by
    ``min_excess_ratio`` (:class:`DiagnoseSettings`). Among them the largest reduction wins,
    except that an eligible effect with fewer parameters within ``occam_tolerance`` of it is
    preferred (the simpler explanation of equally good evidence).
    """
    ok = [r for r in results if r.eligible]
    if not ok:
        return None
    best = max(ok, key=lambda r: r.reduction)
    close = [r for r in ok if r.reduction >= best.reduction - settings.occam_tolerance]
    return min(close, key=lambda r: (r.n_parameters, -r.reduction))


# ----------------------------------------------------------------------------------------------
# The diagnosis
# ----------------------------------------------------------------------------------------------


def _library(effects: Sequence[Effect], xs: Sequence[np.ndarray], views: Sequence[CaptureView]) -> list[np.ndarray]:
    """Placebo library: every effect's signature columns over the whole capture, each scaled to
    unit RMS over the fit samples (columns without variation dropped)."""
    per_cap = []
    for x, v in zip(xs, views):
        cols = []
        for e in effects:
            Ss, Sl = e.signature(x, v)
            cols += [Ss, Sl]
        t = v.t - v.t[0]
        cols.append(np.column_stack([t, t * t]))
        per_cap.append(np.hstack(cols))
    fitstack = np.vstack([L[v.fit] for L, v in zip(per_cap, views)])
    scale = np.sqrt(np.mean((fitstack - fitstack.mean(axis=0)) ** 2, axis=0))
    keep = scale > 1e-12 * max(scale.max(), 1e-300)
    return [L[:, keep] / scale[keep] for L in per_cap]


def _base_fit_job(shared: tuple, job: tuple):
    """Executor entry point: one base fit (captures, cell, label, condition) of the diagnosis."""
    model, optimizer, seed = shared
    caps, cell, label, cond = job
    return fit_captures(list(caps), model, optimizer, seed=seed, cell=cell, label=label, condition=cond)


def _base_fits(jobs: list, n_groups: int, model: Model, optimizer: Optimizer, seed: int, executor, store,
               resume: bool, advance: Callable[[str], None], stats=None) -> list:
    """The base fits of :func:`diagnose` as cells of ``executor`` (resumable with ``store``), in job order."""

    keys = None
    if store is not None:
        opts, settings = model.as_options(), optimizer.settings()
        keys = [cell_key("diagnose-base", captures=caps, model=model.name, model_options=opts,
                         optimizer=optimizer.name, optimizer_settings=settings, seed=seed, cell=cell)
                for caps, cell, _, _ in jobs]

    def done(i: int, res, reused: bool) -> None:
        if i < 2 * n_groups:
            what = "base fit" if i < n_groups else "base fit (fit part)"
            advance(f"{what} {jobs[i][2]}" + (" (reused)" if reused else ""))

    if (len(jobs) > 1 and fork_workers(SELECTION_WORKERS) > 1
            and (executor is None or (isinstance(executor, LocalExecutor) and executor.workers == 1))):
        # cells of this process only, one after the other: on every core instead, in forked children
        # that read the captures already here (the same fits; stored, when stored, once all are
        # done); what the fits load (numba, scipy.optimize) is loaded here first, once, not in each child
        load_ahead(WARM_STEPS)
        executor = ForkedExecutor(SELECTION_WORKERS)
    fits = run_cells(_base_fit_job, jobs, shared=(model, optimizer, seed), executor=executor, store=store, keys=keys,
                     resume=resume, on_done=done, stats=stats)
    for (_, _, label, _), f in zip(jobs, fits):
        if isinstance(f, CellFailed):
            raise NoResultError(f"diagnose: the base fit of {label} failed on every attempt: {f.error}")
    return fits


def _checked_inputs(captures: Sequence[Capture], effects: Sequence[str] | None) -> tuple[list, str, list[str]]:
    """The captures (each with a measured output, one output unit), their unit and the candidate
    effect names — or a one-line InputError/ConfigError."""
    caps = list(captures)
    if not caps:
        raise InputError("diagnose: no captures")
    for c in caps:
        if c.y is None:
            raise InputError(f"{c.source}: no measured output column; the diagnosis needs one (see --output-col)")
    units = {c.y_unit for c in caps}
    if len(units) > 1:
        raise InputError("diagnose: captures have different output units "
                         f"({', '.join(f'{c.name}: {c.y_unit}' for c in caps)}); convert them to one unit")
    names = list(EFFECTS) if effects is None else [make_effect(n).name for n in effects]
    if len(set(names)) != len(names):
        raise ConfigError(f"diagnose: an effect is listed twice in {', '.join(names)}")
    return caps, units.pop(), names


def _groups(caps: Sequence[Capture], per_condition: bool) -> tuple[list, list, list, list[int]]:
    """The base model's parameter groups: one per condition, or one for all captures.

    Returns (capture indices per group, labels, condition keys, group of each capture)."""
    if per_condition:
        keyed = group_by_condition(caps)
        order = {id(c): i for i, c in enumerate(caps)}
        group_idx = [tuple(order[id(c)] for c in v) for v in keyed.values()]
        labels = [condition_label(k) for k in keyed]
        conds = list(keyed)
    else:
        group_idx = [tuple(range(len(caps)))]
        labels = ["global"]
        conds = [(float("nan"), float("nan"))]
    group_of = [0] * len(caps)
    for gi, idx in enumerate(group_idx):
        for i in idx:
            group_of[i] = gi
    return group_idx, labels, conds, group_of


def untestable_effects(d: "_Design", names: Sequence[str]) -> tuple[str, ...]:
    """Candidates the hold-out cannot test: ``drift`` when the middle cycles of captures whose
    amplitude changes within them are held out (the ``cycles`` split with every capture swept).
    There time and amplitude rise together, so a per-capture trend in time is also a trend in
    amplitude: it would take the amplitude dependence of the level that the base and the other
    effects leave (measured: named third after asymmetry and delay on rising sines with no drift),
    and no held-out sample can tell the two apart. (The capture split tests it: a capture held out
    whole fits its own offset and rate on its first part, :func:`_fill_local`; before, they were
    fitted on none of its samples, and a blind test's drift at 5–100× was never named, creep in
    its place.)"""
    if "drift" not in names:
        return ()
    if d.split.kind == "cycles" and d.swept and all(d.swept):
        return ("drift",)
    return ()


def _split_info(split: SplitChoice, caps, views, swept, settings) -> dict:
    """The numbers of the ``split`` section of diagnosis.json: the hold-out scheme and per capture what
    was held out (``why`` and ``description`` are worded from :class:`SplitChoice` by the report)."""
    per_cap = [{"source": c.source, "fit_samples": int(v.fit.sum()), "heldout_samples": int((~v.fit).sum()),
                "amplitude_changes": bool(sw), "heldout_whole": bool(h),
                "own_coefficients_samples": int(v.local.sum()) if v.local is not None else 0,
                "split_time_s": float(c.t[v.fit_end - 1]) if v.fit_end else None}
               for c, v, sw, h in zip(caps, views, swept, split.held_out)]
    out = {"kind": split.kind}
    if split.kind == "capture":
        out["heldout_captures"] = [c.source for c, h in zip(caps, split.held_out) if h]
        # broadband captures (no one drive frequency) are split in time (:func:`_design`)
        out["split_in_time_captures"] = [c.source for c, v in zip(caps, views) if 0 < int(v.fit.sum()) < c.n]
    out["fit_fraction"] = settings.fit_fraction
    out["per_capture"] = per_cap
    return out


def _base_fit_jobs(caps, views, group_idx, labels, conds, by_cond) -> list[tuple]:
    """The base fits as executor cells: per group on everything, per group on the fit part, and (with
    ``by_cond``) per condition alone."""
    jobs = [(tuple(caps[i] for i in idx), gi, labels[gi], conds[gi]) for gi, idx in enumerate(group_idx)]
    jobs += [(tuple(seg for i in idx for seg in _fit_segments(caps[i], views[i].fit)), gi, labels[gi], conds[gi])
             for gi, idx in enumerate(group_idx)]
    if by_cond is not None:
        jobs += [(tuple(cs), 1000 + ci, condition_label(key), key) for ci, (key, cs) in enumerate(by_cond.items())]
    return jobs


def _per_capture(fits, group_idx, n: int) -> list[np.ndarray]:
    """The predictions of group fits, in capture order."""
    out = [None] * n
    for f, idx in zip(fits, group_idx):
        for k, i in enumerate(idx):
            out[i] = np.asarray(f.predictions[k], float)
    return out


def _residuals_alone(caps, by_cond, fits) -> list[np.ndarray]:
    """Per capture the residual of the base fitted to its condition alone."""
    out = [None] * len(caps)
    order = {id(c): i for i, c in enumerate(caps)}
    for (key, cs), f in zip(by_cond.items(), fits):
        for c, p in zip(cs, f.predictions):
            out[order[id(c)]] = np.asarray(p, float) - c.y
    return out


def _configured(names: Sequence[str], pred0, views) -> list[Effect]:
    """The candidate effects, configured on the fit part of the captures that have one."""
    fitted = [i for i, v in enumerate(views) if v.fit_end >= 2]
    vs = [views[i] for i in fitted]
    heads = [pred0[i][: views[i].fit_end] for i in fitted]
    return [make_effect(n).configure(vs, heads) for n in names]


def _other_scheme(other: "Diagnosis", chosen: Sequence[str], kind: str) -> dict:
    """How the other split's diagnosis compares with the one that decided."""
    return {"kind": kind, "verdict": other.verdict, "explained_by": list(other.explained_by),
            "agrees": tuple(sorted(other.explained_by)) == tuple(sorted(chosen)),
            "reductions": {r.effect: r.reduction for r in other.effects}}


def _gap(rmse_full: float, before0: float, fit_before0: float, final_after: float, sigma: float) -> dict:
    """The ``gap`` section: RMSE on all and on held-out data, above the noise, after the named effects."""
    return {"rmse_out": rmse_full, "heldout_rmse_out": before0, "fit_rmse_out": fit_before0,
            "excess_rmse_out": _excess(rmse_full, sigma), "heldout_excess_rmse_out": _excess(before0, sigma),
            "noise_share_of_gap": (sigma / rmse_full) ** 2 if rmse_full > 0 else None,
            "heldout_rmse_after_explained_out": final_after,
            "heldout_reduction_explained": float(np.clip((before0 - final_after) / (before0 - sigma), 0, 1))
            if before0 > sigma else 0.0}


def _refined_floor(caps, preds, periodic, noise: dict, sigma: float) -> tuple[list[float], float]:
    """Per capture the smaller of the noise estimates from the base model's and from the final
    model's residual, and their median (the refined floor)."""
    final_res = [p - c.y for p, c in zip(preds, caps)]
    per_final = estimate_noise(caps, final_res, periodic)["per_capture_out"]
    per = [min(a, b) if math.isfinite(b) else a for a, b in zip(noise["per_capture_out"], per_final)]
    finite = [v for v in per if math.isfinite(v)]
    return per, (float(np.median(finite)) if finite else sigma)


def _calibration_finding(caps, calib: Sequence[dict]) -> Finding:
    """The per-capture offsets and gains of the captures whose calibration differs."""
    return Finding("calibration", {"captures": [(c.name, cal["offset_out"], cal["gain"])
                                                for c, cal in zip(caps, calib) if cal["calibration_differs"]]})


@dataclass(frozen=True, eq=False)
class _StepContext:
    """What every candidate of one selection step is tested against: the current model, its held-out
    and fit RMSE, its linearization and the placebo library (with its spectra), for one noise floor."""

    state: _State
    preds: list
    before: float
    fit_before: float
    lin_cache: tuple
    library: list
    sigma: float
    summary: dict
    spectra: tuple = ()


def _reduction(before: float, after: float, sigma: float) -> float:
    """The share of the held-out gap above the noise (before − σ) that going from ``before`` to
    ``after`` removes, clipped to [0, 1]; 0 when there is no gap. Every reduction of the diagnosis."""
    return float(np.clip((before - after) / (before - sigma), 0.0, 1.0)) if before > sigma else 0.0


#: a candidate whose held-out reduction reaches this share of ``threshold`` contends: it can be named
#: (alone at the threshold, or as the first of a look-ahead pair, :func:`_look_ahead`); only the
#: contenders' placebos are fitted (:func:`_run_candidates`), since no other candidate's verdict
#: depends on its placebo
CONTENDER_SHARE = 0.5


def _contends(reduction: float, before: float, sigma: float, settings: "DiagnoseSettings") -> bool:
    """Whether a candidate with this held-out ``reduction`` of the gap ``before`` (over the floor
    ``sigma``) can be named at all, so that its placebo decides (see :data:`CONTENDER_SHARE`)."""
    return reduction >= CONTENDER_SHARE * settings.threshold and \
        _excess(before, sigma) >= settings.min_excess_ratio * sigma


def _above_noise(own_rms: float, sigma: float, settings: "DiagnoseSettings") -> bool | None:
    """Whether what an effect adds to the held-out prediction (RMS) reaches ``min_excess_ratio`` ×
    the floor; None where it was not computed (a candidate that does not contend)."""
    return None if math.isnan(own_rms) else bool(own_rms >= settings.min_excess_ratio * sigma)


def _placebo_layout(eff: Effect) -> tuple[int, int]:
    """The parameter layout of ``eff``'s placebos: (searched + shared, per capture)."""
    ks, kl = eff.layout()
    return ks + eff.searched_bounds()[0].size, kl


def _placebo_draws(ctx: _StepContext, effects: Sequence[Effect], settings: "DiagnoseSettings",
                   rng) -> list[tuple[tuple[int, int], np.random.Generator]]:
    """The step's placebos, ``settings.placebo_draws`` per layout in the order the layouts are first
    met: per placebo its layout and a copy of ``rng`` where its draw starts. ``rng`` is advanced past
    them all, exactly as drawing them one after the other would (so each can be built anywhere)."""
    draws, seen = [], set()
    for eff in effects:
        key = _placebo_layout(eff)
        if key in seen:
            continue
        seen.add(key)
        for _ in range(settings.placebo_draws):
            draws.append((key, copy.deepcopy(rng)))
            Placebo.skip(ctx.library, key[0], key[1], rng)
    return draws


def _placebo_gain(ctx: _StepContext, key: tuple[int, int], start, caps, views) -> float:
    """Held-out improvement of the random placebo of layout ``key`` drawn from the generator ``start``
    (a copy is drawn from; ``start`` is left as it is)."""
    pl = Placebo.build(ctx.library, key[0], key[1], copy.deepcopy(start), ctx.spectra)
    st_p, _ = _augment(ctx.state, pl, caps, views, ctx.lin_cache, 1)
    return ctx.before - _rmse(_predictions(st_p, caps, views), views, "test")


@dataclass(frozen=True, eq=False)
class _Refit:
    """A candidate refitted on top of the current model: the model with it, its predictions, its
    held-out and fit RMSE, and how much of the base residual its signature explains."""

    state: _State
    fit: EffectFit
    preds: list
    after: float
    fit_after: float
    share: float
    r2: float
    own_rms: float = math.inf  # RMS of the effect's own part of the held-out prediction (NaN: not computed)


def _own_rms(state: _State, fit: EffectFit, preds: list, caps, views) -> float:
    """RMS, over the held-out samples, of what the link ``fit`` adds to the prediction of ``state``:
    its predictions less those of the same state without that link (the base and the other
    links as refitted with it)."""
    at = next((i for i, link in enumerate(state.chain) if link is fit), None)
    if at is None:
        at = next((i for i, link in enumerate(state.chain) if link.effect.name == fit.effect.name), None)
    if at is None:
        return math.inf
    without = state.copy()
    del without.chain[at]
    return _rmse([p - q for p, q in zip(preds, _predictions(without, caps, views))], views, "test_diff")


def _refit_effect(ctx: _StepContext, eff: Effect, caps, views, settings: "DiagnoseSettings",
                  grid_scores: np.ndarray | None = None) -> _Refit:
    """``eff`` refitted on top of the current model (jointly with it) and scored on held-out data
    (``grid_scores``: the scores of its search grid, when already computed)."""
    st_e, efit = _augment(ctx.state, eff, caps, views, ctx.lin_cache, settings.iterations, grid_scores=grid_scores)
    preds_e = _predictions(st_e, caps, views)
    fitted = [i for i, v in enumerate(views) if v.fit_end >= 3]
    share, r2 = signature_share(eff, [ctx.preds[i][: views[i].fit_end] for i in fitted],
                                [views[i].head(views[i].fit_end) for i in fitted], ctx.sigma * ctx.sigma)
    after = _rmse(preds_e, views, "test")
    # what it adds to the prediction: only where a verdict can depend on it (a contender), as its placebos
    own = (_own_rms(st_e, efit, preds_e, caps, views)
           if _contends(_reduction(ctx.before, after, ctx.sigma), ctx.before, ctx.sigma, settings) else math.nan)
    return _Refit(st_e, efit, preds_e, after, _rmse(preds_e, views, "fit"), share, r2, own)


def _test_effect(ctx: _StepContext, eff: Effect, refit: _Refit, placebo: tuple[float, float] | None, step: int, caps,
                 views, settings: "DiagnoseSettings") -> EffectResult:
    """The :class:`EffectResult` of ``eff`` refitted on top of the current model, judged against the
    (best, mean) held-out improvement of its placebos; ``placebo`` None: not fitted (``eff`` does
    not contend, :func:`_contends`): its placebo numbers are NaN and ``beats_placebo`` None."""
    pl_best, pl_mean = placebo if placebo is not None else (math.nan, math.nan)
    before, sigma, after = ctx.before, ctx.sigma, refit.after
    denom = before - sigma
    red = _reduction(before, after, sigma)
    pl_red = math.nan if placebo is None else float(np.clip(pl_best / denom, 0.0, 1.0)) if denom > 0 else 0.0
    params = refit.fit.params(views, [c.source for c in caps])
    passes = {"reduction_at_least_threshold": red >= settings.threshold,
              "beats_placebo": None if placebo is None else (before - after) - pl_best > settings.placebo_margin * denom,
              "gap_above_noise": _excess(before, sigma) >= settings.min_excess_ratio * sigma,
              "inside_search_range": not eff.absent_at(refit.fit.phi),
              "effect_above_noise": _above_noise(getattr(refit, "own_rms", math.inf), sigma, settings)}
    ev = Evidence.from_summary(eff.name, ctx.summary, signature_share=refit.share, params=params,
                               heldout_before=before, heldout_after=after, reduction=red, placebo=pl_best)
    return EffectResult(eff.name, eff.title, step + 1, before, after, ctx.fit_before, refit.fit_after, red, pl_best,
                        pl_mean, pl_red, refit.fit.n_parameters, refit.share, refit.r2, params, ev, passes, refit.fit,
                        own_rms=float(getattr(refit, "own_rms", math.nan)))


@dataclass(frozen=True, eq=False)
class _Ranked:
    """A search grid of ``size`` points ranked on a subsample of rows whose ``best`` points (indices
    into the grid) are still to be scored on every row (:func:`_grid_scores` with ``exact_later``;
    :func:`_exact_grid_scores` scores them)."""

    size: int
    best: np.ndarray


def _exact_grid_scores(effect: Effect, scoring, got) -> np.ndarray | None:
    """The grid scores of ``effect`` as :func:`_grid_scores` gives them, from what it gave with
    ``exact_later``: a :class:`_Ranked` grid's best points scored on every row of ``scoring`` here
    (the same numbers as scored over the processes), NaN elsewhere; anything else as it is."""
    if not isinstance(got, _Ranked):
        return got
    g = np.full(got.size, np.nan)
    grid = np.asarray(effect.search_grid(), float)
    g[got.best] = np.array([effect.score(c, scoring) for c in grid[got.best]])
    return g


#: effects whose search has run in this process (its kernels are loaded)
_SEARCHED_HERE: set = set()


def _load_kernels(searched: Sequence[Effect], design_of) -> None:
    """Before the first forked scoring of a search grid: one grid point of each effect scored here,
    so that the numba kernels its score runs are loaded in this process, once, and not again in
    every forked child (≈ 30–60 ms each); and the placebos' phase kernel. Changes no number (a
    delay's knot Gram products it computes are kept in the design as the search would keep them)."""
    if fork_workers(SELECTION_WORKERS) <= 1:
        return
    for e in searched:
        if e.name not in _SEARCHED_HERE:
            e.score(np.asarray(e.search_grid(), float)[0], design_of(e))
            _SEARCHED_HERE.add(e.name)
    if "placebo" not in _SEARCHED_HERE:
        _unit_phasors(np.zeros((1, 1)))
        _SEARCHED_HERE.add("placebo")


def _grid_scores(effects: Sequence[Effect], scoring, exact_later: bool = False) -> dict:
    """Per effect with searched parameters, the :meth:`~hystfit.effects.Effect.score` of every
    candidate of its search grid on ``scoring`` (a :func:`scoring_design`): each grid split over
    :data:`SELECTION_WORKERS` processes (the same numbers on any number), the largest grids first.

    A stage's grid on many fit samples (:func:`~hystfit.effects.ranked_on_rows`) is ranked on a
    subsample of rows first (:func:`~hystfit.effects.coarse_design`); only its best points
    (:data:`~hystfit.effects.COARSE_KEEP_SHARE`, at least :data:`~hystfit.effects.COARSE_KEEP_MIN`)
    are scored on every row, the others are NaN (not scored): the search starts from the best
    of the scored ones, which is the best of the whole grid unless the subsample ranked it out.
    ``exact_later``: those best points are not scored here but given as a :class:`_Ranked` (the
    refit of the effect scores them, :func:`_exact_grid_scores`, in the processes that refit the
    candidates: one round of forked processes less)."""
    searched = sorted((e for e in effects if e.searched_bounds()[0].size), key=lambda e: -e.searched_bounds()[0].size)
    if not searched:
        return {}
    coarse = {e.name for e in searched if ranked_on_rows(e, scoring)}
    grids = {e.name: np.asarray(e.search_grid(), float) for e in searched}

    def scored(points: dict[str, np.ndarray], design_of) -> dict[str, np.ndarray]:
        chunks = [(e, part) for e in searched if e.name in points
                  for part in np.array_split(np.arange(len(points[e.name])), fork_workers(SELECTION_WORKERS)) if part.size]
        out = fork_map(lambda i: np.array([chunks[i][0].score(c, design_of(chunks[i][0]))
                                           for c in points[chunks[i][0].name][chunks[i][1]]]),
                       len(chunks), SELECTION_WORKERS)
        return {name: np.concatenate([r for (e, _), r in zip(chunks, out) if e.name == name]) for name in points}

    _load_kernels(searched, lambda e: coarse_design(scoring) if e.name in coarse else scoring)
    first = scored(grids, lambda e: coarse_design(scoring) if e.name in coarse else scoring)
    if not coarse:
        return first
    best = {}
    for name in coarse:
        ranking = np.argsort(first[name], kind="stable")
        k = max(COARSE_KEEP_MIN, int(math.ceil(COARSE_KEEP_SHARE * ranking.size)))
        best[name] = np.sort(ranking[:k])
    if exact_later:
        return {name: _Ranked(grids[name].shape[0], best[name]) if name in best else g for name, g in first.items()}
    exact = scored({name: grids[name][idx] for name, idx in best.items()}, lambda e: scoring)
    for name, idx in best.items():
        g = np.full(grids[name].shape[0], np.nan)
        g[idx] = exact[name]
        first[name] = g
    return first


def _run_candidates(ctx: _StepContext, remaining: Sequence[Effect], step: int, caps, views,
                    settings: "DiagnoseSettings", rng) -> tuple[list[EffectResult], dict]:
    """Every remaining candidate refitted and judged against its placebos. The refits, then the
    placebo fits are independent: each round runs on :data:`SELECTION_WORKERS` processes and gives
    the same numbers on any number. First the search grids of the effects with searched parameters
    are scored (:func:`_grid_scores`, split over the processes); then, longest first, the searches
    of those effects go on from their grid scores (:meth:`hystfit.effects.Effect.fit`'s
    ``grid_scores``: a polish, one evaluation after the other) while the other
    processes refit the effects without searched parameters. Then the placebos of the layouts of
    the candidates that contend (:func:`_contends`) are fitted; a layout no contender has gets none
    (its candidates' placebo numbers are NaN: no verdict depends on them). Each placebo is drawn
    from its own copy of ``rng`` (:func:`_placebo_draws`), so one left out changes no other. The
    results in the order of ``remaining``, and per effect the (state, predictions) of the model
    with it."""
    draws = _placebo_draws(ctx, remaining, settings, rng)
    searched = sorted((e for e in remaining if e.searched_bounds()[0].size), key=lambda e: -e.searched_bounds()[0].size)
    others = [e for e in remaining if not e.searched_bounds()[0].size]
    scoring = scoring_design(ctx.lin_cache[2])  # every worker shares it
    grids = _grid_scores(searched, scoring, exact_later=True) if searched else {}

    def refit(i: int) -> _Refit:
        if i < len(searched):
            eff = searched[i]
            return _refit_effect(ctx, eff, caps, views, settings, _exact_grid_scores(eff, scoring, grids[eff.name]))
        return _refit_effect(ctx, others[i - len(searched)], caps, views, settings)

    refits = dict(zip((e.name for e in searched + others), fork_map(refit, len(searched) + len(others),
                                                                      SELECTION_WORKERS)))
    contending = {_placebo_layout(e) for e in remaining
                  if _contends(_reduction(ctx.before, refits[e.name].after, ctx.sigma), ctx.before, ctx.sigma, settings)}
    draws = [d for d in draws if d[0] in contending]
    out = fork_map(lambda i: _placebo_gain(ctx, draws[i][0], draws[i][1], caps, views), len(draws), SELECTION_WORKERS)
    gains: dict[tuple[int, int], list[float]] = {}
    for (key, _), g in zip(draws, out):
        gains.setdefault(key, []).append(g)
    placebo = {key: (max(g), float(np.mean(g))) for key, g in gains.items()}
    results = [_test_effect(ctx, e, refits[e.name], placebo.get(_placebo_layout(e)), step, caps, views, settings)
               for e in remaining]
    return results, {e.name: (refits[e.name].state, refits[e.name].preds) for e in remaining}


@dataclass(frozen=True, eq=False)
class _Selection:
    """The greedy selection for one noise floor: every step's results (best first), the effects
    named in order, the equally good alternatives per step, the final model's predictions and its
    state (base parameters and named effects, fitted on the fit part; None where not kept)."""

    steps: tuple[tuple[EffectResult, ...], ...]
    chosen: tuple[str, ...]
    alternatives: tuple[tuple[str, ...], ...]
    preds: list
    state: "_State | None" = None


def _step_results(state, preds_state, remaining, step: int, caps, views, all_effects, sigma: float, where: dict,
                  settings: "DiagnoseSettings", rng, on_tested=None) -> tuple[list[EffectResult], dict, float]:
    """One step of the selection: every ``remaining`` candidate refitted on top of ``state`` and
    scored against its placebos (:func:`_run_candidates`); ``preds_state`` is
    ``_predictions(state, caps, views)``. The results (best first), the (state, predictions) of
    each, and the held-out RMSE before the step."""
    library = _library(all_effects, preds_state, views)
    xs, lin = _linearize(state, caps, views)
    ctx = _StepContext(state, preds_state, _rmse(preds_state, views, "test"), _rmse(preds_state, views, "fit"),
                       (xs, lin, prepare_design(xs, views, lin)), library, sigma, where["summary"],
                       tuple(surrogate_spectrum(L) for L in library))
    results, states = _run_candidates(ctx, remaining, step, caps, views, settings, rng)
    if on_tested is not None:
        for eff in remaining:
            on_tested(eff)
    results.sort(key=lambda r: (-r.reduction, r.n_parameters))
    return results, states, ctx.before


def _look_ahead(results: list[EffectResult], states: dict, before: float, sigma: float, run_step) -> tuple | None:
    """Two effects that pass the rule each on top of the other where neither passes it alone.

    When no candidate of a step reaches the reduction threshold, the gap may hold two effects of
    similar size: each removes only part of it (the parts add in quadrature, so half of the excess
    mean square is less than a third of the RMSE gap). The candidates that beat their placebo and
    reach half the threshold are tried, best first, as the first of two: the next step is run on
    top of it with the usual rules. The pair is named when that step names an effect and the first,
    in turn, removes at least the threshold of the gap the second leaves alone (its single result of
    this step): each of the two passes the rule on top of the other. Returns (first's result with
    ``joint`` set, the next step's results, states and pick), or None."""
    thr = run_step.settings.threshold
    alone = {r.effect: r for r in results}
    firsts = [r for r in results if r.passes["beats_placebo"] and r.passes["gap_above_noise"]
              and r.passes.get("inside_search_range", True) and r.reduction >= CONTENDER_SHARE * thr][:2]
    for r in firsts:
        nxt, nxt_states, _ = run_step(states[r.effect], r.effect)
        pick = choose_effect(nxt, run_step.settings)
        if pick is None or pick.effect not in alone:
            continue
        after, after_second = pick.heldout_rmse_after, alone[pick.effect].heldout_rmse_after
        on_top = _reduction(after_second, after, sigma)
        if on_top >= thr:
            both = _reduction(before, after, sigma)
            joint = {"with": pick.effect, "heldout_rmse_after": after, "reduction": both,
                     "reduction_on_top_of_other": on_top, "threshold": thr}
            return replace(r, joint=joint), nxt, nxt_states, pick
    return None


class _RunStep:
    """The next selection step from a given (state, predictions), for the look-ahead."""

    def __init__(self, remaining, step, caps, views, all_effects, sigma, where, settings, rng):
        self.args = (step, caps, views, all_effects, sigma, where, settings, rng)
        self.remaining, self.settings = remaining, settings

    def __call__(self, state_preds, named: str):
        step, caps, views, all_effects, sigma, where, settings, rng = self.args
        left = [e for e in self.remaining if e.name != named]
        return _step_results(*state_preds, left, step + 1, caps, views, all_effects, sigma, where, settings, rng)


def _select_effects(sigma: float, where: dict, *, state0, pred0, caps, views, cands, all_effects,
                    settings: "DiagnoseSettings", seed: int, advance, count_progress: bool,
                    first_step: int = 0, refine=None) -> _Selection:
    """The greedy selection of effects for one noise floor (the fits do not depend on it, the
    reductions and the verdict do). ``pred0``: ``_predictions(state0, caps, views)``. ``first_step``: steps
    already taken (a continuation). A step that names nothing is given the two-effect look-ahead
    (:func:`_look_ahead`). ``refine(state, preds, chosen)``: called after an effect is named (not
    between the two of a look-ahead pair) while more steps remain; (state, preds) of the model with
    the named effects on a finer base when the base's resolution limits it, else None."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7] + ([first_step] if first_step else [])))
    steps, chosen, alternatives = [], [], []
    state, preds_state = state0, pred0
    remaining = list(cands)
    pending = None  # the next step's results, already run by the look-ahead
    for step in range(settings.max_effects):
        if not remaining:
            break
        if pending is not None:
            results, states, pick = pending
            pending = None
        else:
            tick = (lambda eff: advance(f"effect {eff.name}")) if step == 0 and count_progress else None
            results, states, before = _step_results(state, preds_state, remaining, first_step + step, caps, views,
                                                    all_effects, sigma, where, settings, rng, tick)
            pick = choose_effect(results, settings)
            if pick is None and step + 1 < settings.max_effects and len(remaining) > 1:
                run = _RunStep(remaining, first_step + step, caps, views, all_effects, sigma, where, settings, rng)
                ahead = _look_ahead(results, states, before, sigma, run)
                if ahead is not None:
                    pick, nxt, nxt_states, nxt_pick = ahead
                    results = [pick if r.effect == pick.effect else r for r in results]
                    pending = (nxt, nxt_states, nxt_pick)
        steps.append(tuple(results))
        if pick is None:
            break
        top = max(r.reduction for r in results if r.eligible)
        alternatives.append(tuple(r.effect for r in results if r.eligible and r is not pick
                                  and r.reduction >= top - settings.occam_tolerance))
        chosen.append(pick.effect)
        state, preds_state = states[pick.effect]
        remaining = [e for e in remaining if e.name != pick.effect]
        if refine is not None and pending is None and remaining and step + 1 < settings.max_effects:
            finer = refine(state, preds_state, chosen)
            if finer is not None:
                state, preds_state = finer
    return _Selection(tuple(steps), tuple(chosen), tuple(alternatives), preds_state, state)


@dataclass(frozen=True, eq=False)
class _Design:
    """How the captures are used: per capture periodic and amplitude-swept flags, the hold-out
    split, the views (fit masks), and the base model's parameter groups."""

    periodic: tuple[bool, ...]
    swept: tuple[bool, ...]
    split: SplitChoice
    views: tuple[CaptureView, ...]
    group_idx: tuple[tuple[int, ...], ...]
    labels: tuple[str, ...]
    conds: tuple[tuple[float, float], ...]
    group_of: tuple[int, ...]
    fine_fits: dict = field(default_factory=dict, repr=False)  # finer base → its fits on the fit part
    #: (finer base, floor, the effects refitted on it in order) → the state: :func:`_refit_finer`
    fine_states: dict = field(default_factory=dict, repr=False)


def _fine_key(fine: Model, optimizer: Optimizer, seed: int):
    """The key of :func:`_fine_base_fits`'s cache (None for a model that cannot be a key)."""
    key = (fine, optimizer.name, repr(optimizer.settings()), int(seed))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _fine_base_fits(caps, d: _Design, fine: Model, optimizer: Optimizer, seed: int, executor) -> list:
    """The base at the finer resolution ``fine`` fitted on the fit part, once per diagnosis: the
    resolution checks before and after each named effect refit the same base at the same resolution
    (same captures, optimizer and seed: the same fits), so each resolution is fitted the first time
    only. A model that cannot be a key (not hashable) is fitted every time."""
    G = len(d.group_idx)
    key = _fine_key(fine, optimizer, seed)
    if key is None or key not in d.fine_fits:
        jobs = _base_fit_jobs(caps, d.views, d.group_idx, d.labels, d.conds, None)[G:]
        fits = _base_fits(jobs, 0, fine, optimizer, seed, executor, None, False, lambda label: None)
        if key is None:
            return fits
        d.fine_fits[key] = fits
    return d.fine_fits[key]


def _design(caps: Sequence[Capture], settings: "DiagnoseSettings", per_condition: bool) -> _Design:
    """Periodicity, sweeps, the split and the fit masks of the captures, and the parameter groups."""
    periodic = [is_periodic(c.u, c.dt, c.frequency_Hz) for c in caps]
    swept = [amplitude_changes(c.u) for c in caps]
    # driven at one frequency: periodic, or a sine whose amplitude changes — never a step pattern,
    # whose "cycles" at its strongest spectral line can look swept on a long capture
    tonal = [(p or s) and not is_step_and_hold(c.u) for c, p, s in zip(caps, periodic, swept)]
    split = split_choice(caps, swept, settings, per_condition, tonal)
    local = [None] * len(caps)
    if split.kind == "capture":
        # the tonal captures are fitted or held out whole; a broadband one (PRBS, steps) is split in
        # time as in the temporal scheme: its first part fitted, the rest held out. A capture held
        # out whole fits its own per-capture coefficients (drift's offset and rate) on its first
        # part and nothing else there (_fill_local): fitted on none of its samples, a drift was
        # never named under this split
        temporal = fit_masks(caps, periodic, settings.fit_fraction)
        masks = [np.full(c.n, not h) if t else m for c, h, t, m in zip(caps, split.held_out, tonal, temporal)]
        local = [m if h and t else None for h, t, m in zip(split.held_out, tonal, temporal)]
    elif split.kind == "cycles":
        masks = interior_masks(caps, periodic, settings.fit_fraction)
    else:
        masks = fit_masks(caps, periodic, settings.fit_fraction)
    views = [CaptureView(c.t, c.dt, c.y, m, float(c.frequency_Hz), p, i, c.u, loc)
             for i, (c, m, p, loc) in enumerate(zip(caps, masks, periodic, local))]
    group_idx, labels, conds, group_of = _groups(caps, per_condition)
    return _Design(tuple(periodic), tuple(swept), split, tuple(views), tuple(group_idx), tuple(labels),
                   tuple(conds), tuple(group_of))


@dataclass(frozen=True, eq=False)
class _Gap:
    """Step 1: the base model fitted on everything — predictions, residuals (also of every condition
    fitted alone), the noise floor and the RMSE over all samples."""

    full_pred: list
    residuals: list
    residuals_alone: list | None
    noise: dict
    rmse_full: float


def _gap_step(caps, d: _Design, base_fits: list, by_cond: dict | None) -> _Gap:
    """The gap of the base model fitted on everything and the noise floor under it."""
    G = len(d.group_idx)
    full_pred = _per_capture(base_fits[:G], d.group_idx, len(caps))
    residuals = [p - c.y for p, c in zip(full_pred, caps)]
    noise = estimate_noise(caps, residuals, d.periodic)
    rmse_full = math.sqrt(sum(float(r @ r) for r in residuals) / sum(r.size for r in residuals))
    alone = _residuals_alone(caps, by_cond, base_fits[2 * G:]) if by_cond is not None else None
    return _Gap(full_pred, residuals, alone, noise, rmse_full)


@dataclass(frozen=True, eq=False)
class _Base:
    """Step 2: the base model fitted on the fit part (with the per-capture calibration when the
    captures disagree), its predictions and its held-out and fit RMSE."""

    state: _State
    preds: list
    before: float
    fit_before: float
    calibration: tuple[dict, ...]
    calibrated: bool


def _base_step(caps, d: _Design, fits: list, full_pred: list, sigma: float, settings: "DiagnoseSettings") -> _Base:
    """The starting point of the selection: the base fitted on the fit part (plus the calibration)."""
    views = list(d.views)
    groups = [_Group(d.labels[gi], d.conds[gi], f.model, f.params, np.asarray(f.theta, float).copy(),
                     np.array([p.lower for p in f.params]), np.array([p.upper for p in f.params]), idx)
              for gi, (idx, f) in enumerate(zip(d.group_idx, fits))]
    state0 = _State(groups, [], d.group_of)
    calib = capture_calibration(caps, full_pred, sigma)
    calibrated = len(caps) > 1 and any(c["calibration_differs"] for c in calib)
    if calibrated:  # the sensor's per-capture offset and gain are part of the base, never an effect
        state0, _ = _augment(state0, _Calibration(), caps, views, _linearize(state0, caps, views), settings.iterations)
    pred0 = _predictions(state0, caps, views)
    return _Base(state0, pred0, _rmse(pred0, views, "test"), _rmse(pred0, views, "fit"), tuple(calib), calibrated)


def _complete_where(where: dict, sigma: float, caps, d: _Design, base: _Base) -> list[Finding]:
    """The split-dependent part of the where-analysis summary, and its findings (returned)."""
    s = where["summary"]
    ex_fit = _excess(base.fit_before, sigma)
    s["heldout_to_fit_ratio"] = _excess(base.before, sigma) / ex_fit if ex_fit > 0 else None
    s["split"] = d.split.kind
    freqs = [c.frequency_Hz for c in caps if np.isfinite(c.frequency_Hz) and c.frequency_Hz > 0]
    s["drive_frequency_Hz"] = float(np.median(freqs)) if freqs else None
    s["amplitude_changes_within_capture"] = bool(any(d.swept))
    return findings(s, where["by_branch"], where["by_loop_position"], sigma)


@dataclass(frozen=True, eq=False)
class _Outcome:
    """Steps 3–4 for the final noise floor: the floor, the where-analysis, its findings and figure
    data, and the selection."""

    sigma: float
    where: dict
    findings: list
    fig_where: dict
    selection: _Selection


def _where_and_select(caps, d: _Design, gap: _Gap, base: _Base, first: tuple[dict, dict], select) -> _Outcome:
    """The where-analysis and the selection, redone with a refined noise floor when the named effects
    show that the base residual overstated it.

    The floor was estimated from the base model's residual. Where that residual holds fast model
    error (a ringing stage the base cannot draw), the scatter estimate of those captures is
    inflated; the model with the named effects removes it. Re-estimate from the better of the two
    residuals per capture and, when the floor drops by more than 5 %, redo the where-analysis and
    the selection with it (the fits are the same; reductions and the verdict depend on it).
    ``first`` is the where-analysis with the base model's floor."""
    noise = gap.noise
    sigma = noise["sigma"]
    where, fig_where = first
    found = _complete_where(where, sigma, caps, d, base)
    sel = select(sigma, where, True)
    if sel.chosen:
        per, refined = _refined_floor(caps, sel.preds, d.periodic, noise, sigma)
        noise["sigma_base_model_out"] = sigma
        noise["sigma_final_model_out"] = refined
        if refined < 0.95 * sigma:
            noise.update(sigma=refined, per_capture_out=per, refined=True)  # ``refined`` qualifies ``method``
            sigma = refined
            where, fig_where = where_analysis(caps, gap.residuals, sigma, d.periodic, gap.residuals_alone)
            found = _complete_where(where, sigma, caps, d, base)
            sel = select(sigma, where, False)
    noise.setdefault("refined", False)
    return _Outcome(sigma, where, found, fig_where, sel)


@dataclass(frozen=True, eq=False)
class _Resolution:
    """The base-resolution check: its numbers (the JSON ``resolution`` section) and the finer base
    with the named effects refitted on it (where the selection continues when it is adopted)."""

    info: dict
    state: _State
    preds: list
    model: Model | None = None  # the finer base when adopted


def resolution_check(caps, d: _Design, model: Model, optimizer: Optimizer, seed: int, gap: _Gap, sel: _Selection,
                     sigma: float, settings: "DiagnoseSettings", executor=None, refit=None) -> _Resolution | None:
    """Is the base's resolution, rather than a missing effect, what limits the model with the named
    effects? The base at twice its resolution (:meth:`Model.refined`) is fitted on the fit part, the
    named effects are refitted on it in the order they were named, and the held-out RMSE is compared
    with the coarse base's. None when the base has no resolution option or the held-out excess
    √(RMSE² − floor²) is within the noise floor; otherwise the check's numbers and ``adopted``: the
    finer base removes at least ``settings.resolution_threshold`` of the held-out excess mean square
    (the rule of :func:`converge_resolution`). ``refit``: that finer model's :func:`_refit_finer`
    when already computed (e.g. by a forked child, :func:`resolution_check_converged`)."""
    fine = model.refined()
    before = _rmse(sel.preds, d.views, "test")
    if fine is None or not _excess(before, sigma) > sigma:  # as in converge_resolution
        return None
    if refit is None:
        refit = _refit_finer(caps, d, fine, optimizer, seed, gap, sel.chosen, sigma, settings, executor,
                             searched_starts(sel.state))
    else:
        key = _fine_key(fine, optimizer, seed)
        if key is not None:
            d.fine_fits.setdefault(key, refit.fits)  # as if fitted here
    after = _rmse(refit.preds, d.views, "test")
    (opt, n_from), (_, n_to) = _resolution_of(model), _resolution_of(fine)
    info = {"option": opt, "from": n_from, "to": n_to, "effects": list(sel.chosen),
            "heldout_rmse_before_out": before, "heldout_rmse_after_out": after, **_shares(before, after, sigma),
            "threshold": settings.resolution_threshold}
    info["adopted"] = bool(info["reduction_mean_square"] >= settings.resolution_threshold)
    return _Resolution(info, refit.state, refit.preds, fine)


@dataclass(frozen=True, eq=False)
class _FinerRefit:
    """The base at a finer resolution fitted on the fit part with the named effects refitted on it:
    the model's state, its predictions and the finer base's fits (the cache of :func:`_fine_base_fits`)."""

    state: _State
    preds: list
    fits: list


def searched_starts(state: "_State | None") -> dict[str, tuple[np.ndarray, Effect]]:
    """Per effect of ``state``'s chain with searched parameters, its φ and the effect as fitted (its
    range, widened or not): where the refit of that effect on a finer base starts
    (:func:`_refit_finer`, :func:`_started`)."""
    if state is None:
        return {}
    return {link.effect.name: (np.asarray(link.phi, float).copy(), link.effect) for link in state.chain
            if np.size(link.phi)}


def _started(eff: Effect, start) -> tuple[Effect, np.ndarray | None, tuple]:
    """The effect a finer base's refit fits, its start φ and the start's part of the refit's cache
    key (:func:`_refit_finer`): ``start`` is (φ, the coarse link's effect) or None. Where φ lies
    outside ``eff``'s search range the coarse link's effect (its range widened there) is refitted
    instead, so the start is searched around, not clipped onto a bound and searched again."""
    if start is None:
        return eff, None, ()
    phi, coarse = start
    lo, hi = eff.searched_bounds()
    if np.any(phi < lo) or np.any(phi > hi):
        eff = coarse
    return eff, phi, (phi.tobytes(), tuple(np.asarray(eff.searched_bounds(), float).ravel()))


def _refit_finer(caps, d: _Design, fine: Model, optimizer: Optimizer, seed: int, gap: _Gap, chosen: Sequence[str],
                 sigma: float, settings: "DiagnoseSettings", executor=None, starts: dict | None = None) -> _FinerRefit:
    """The work of a :func:`resolution_check` of the base ``fine``: its fits on the fit part, then
    the ``chosen`` effects refitted on it in order. An effect with searched parameters φ searches
    around its φ on the coarser base (``starts``, :func:`searched_starts` of the selection's state:
    the plant's stage or delay does not move with the base's resolution; :func:`_started`) — a
    local search and its polish, which widen the range as a full search would where they end on a
    bound the data chose (:func:`_augment`); without a start, its whole search grid, scored over
    the processes. The refits are kept per (base, floor, effects so far, their starts): the same
    numbers whichever check, process or child computed them first."""
    fits = _fine_base_fits(caps, d, fine, optimizer, seed, executor)
    key = _fine_key(fine, optimizer, seed)
    # the states of the checks before (the same base, floor and first effects: the same refits) are
    # not computed again: the check after the second named effect starts from the first's refit
    states = d.fine_states if key is not None else {}
    at = (key, float(sigma), ())
    if at not in states:
        base = _base_step(caps, d, fits, gap.full_pred, sigma, settings)
        states[at] = (base.state, base.preds)
    state, base_preds = states[at]
    views = list(d.views)
    started = ()
    for k, eff in enumerate(_configured(list(chosen), base_preds, views)):
        eff, start, start_key = _started(eff, (starts or {}).get(eff.name))
        started += (start_key,)
        at = (key, float(sigma), tuple(chosen[:k + 1]), started)
        if at not in states:
            xs, lin = _linearize(state, caps, views)
            design = prepare_design(xs, views, lin)
            if start is not None:
                states[at] = _augment(state, eff, caps, views, (xs, lin, design), settings.iterations, phi0=start)[0]
            else:
                grids = _grid_scores([eff], scoring_design(design))  # split over the processes
                states[at] = _augment(state, eff, caps, views, (xs, lin, design), settings.iterations,
                                      grid_scores=grids.get(eff.name))[0]
        state = states[at]
    return _FinerRefit(state, _predictions(state, caps, views), fits)


def _speculate(caps, d: _Design, model: Model, optimizer: Optimizer, seed: int, gap: _Gap, sel: "_Selection",
               sigma: float, settings: "DiagnoseSettings", executor):
    """The :func:`_refit_finer` of the doubling after the one of ``model`` (``model`` refined twice)
    for the selection ``sel`` (its named effects, started from their φ in its state),
    started in a forked child while this process checks the first doubling (:func:`fork_call`), or
    None: no such resolution, one process, or base fits that would run on a pool or a cluster
    (a forked child must not share them)."""
    fine = model.refined()
    finer = fine.refined() if fine is not None else None
    inline = executor is None or (isinstance(executor, LocalExecutor) and (executor.workers == 1
                                                                           or len(d.group_idx) <= 1))
    if finer is None or not inline:
        return None
    starts = searched_starts(sel.state)
    return fork_call(lambda: _refit_finer(caps, d, finer, optimizer, seed, gap, sel.chosen, sigma, settings, executor,
                                          starts),
                     SELECTION_WORKERS)


def _shares(before: float, after: float, sigma: float) -> dict:
    """How much of the held-out gap above the floor a change removes: ``reduction`` of the RMSE gap
    (before − σ) and ``reduction_mean_square`` of the excess mean square (before² − σ²), the rule
    of every resolution check (errors add in quadrature), each clipped to [0, 1]."""
    ms = before ** 2 - sigma ** 2
    return {"reduction": _reduction(before, after, sigma),
            "reduction_mean_square": float(np.clip((before ** 2 - after ** 2) / ms, 0.0, 1.0)) if ms > 0 else 0.0}


def resolution_check_converged(caps, d: _Design, model: Model, optimizer: Optimizer, seed: int, gap: _Gap,
                               sel: _Selection, sigma: float, settings: "DiagnoseSettings",
                               executor=None) -> _Resolution | None:
    """:func:`resolution_check`, repeated on the finer base while it is adopted: the base with the
    named effects at the resolution the data support before the selection goes on. The section
    keeps the first check's ``from`` and held-out RMSE before; ``to``, the held-out RMSE after and
    the reduction are those of the last adopted doubling, and ``steps`` lists every check.

    While a doubling is checked here, the refit of the next one (which does not depend on this
    check's outcome, only whether it is needed does) is computed in a forked child
    (:func:`_speculate`) and used when the doubling is adopted; it is stopped when not. The same
    numbers as one check after the other."""
    if model.refined() is None or not _excess(_rmse(sel.preds, d.views, "test"), sigma) > sigma:
        return None  # as resolution_check would say at once: nothing to compute ahead
    ahead = _speculate(caps, d, model, optimizer, seed, gap, sel, sigma, settings, executor)
    try:
        res = resolution_check(caps, d, model, optimizer, seed, gap, sel, sigma, settings, executor)
        if res is None:
            return None
        info, steps = dict(res.info), [dict(res.info)]
        cur, fine = res, model.refined()
        while cur.info["adopted"] and fine is not None:
            if fine.refined() is None or not _excess(_rmse(cur.preds, d.views, "test"), sigma) > sigma:
                break  # resolution_check would say None at once: the refit ahead is not needed
            refit, ahead = (ahead.result() if ahead is not None else None), None
            if refit is not None:  # the check of the doubling after it: its refit is started now
                ahead = _speculate(caps, d, fine, optimizer, seed, gap, sel, sigma, settings, executor)
            nxt = resolution_check(caps, d, fine, optimizer, seed, gap, replace(sel, preds=cur.preds), sigma, settings,
                                   executor, refit=refit)
            if nxt is None:
                break
            steps.append(dict(nxt.info))
            if not nxt.info["adopted"]:
                break
            cur, fine = nxt, fine.refined()
    finally:
        if ahead is not None:
            ahead.cancel()
    before, after = info["heldout_rmse_before_out"], cur.info["heldout_rmse_after_out"]
    info.update(to=cur.info["to"], heldout_rmse_after_out=after, steps=steps, **_shares(before, after, sigma))
    return _Resolution(info, cur.state, cur.preds, cur.model if cur.info["adopted"] else model)


def _resolution_of(model: Model) -> tuple[str, int]:
    """The base's resolution option and its value (of the composite's base when composite)."""
    base = model.composition[0] if model.composition is not None else model
    return base.resolution_option, int(getattr(base, base.resolution_option))


def converge_resolution(caps, d: _Design, model: Model, optimizer: Optimizer, seed: int, gap: _Gap, base: _Base,
                        sigma: float, settings: "DiagnoseSettings", executor=None) -> tuple[Model, _Base, dict | None]:
    """The base at the resolution its data support, before any effect is tested.

    The base (its :meth:`Model.refined` resolution doubled) is refitted on the fit part as long as
    each doubling removes at least ``settings.resolution_threshold`` of the held-out excess mean
    square (RMSE² − floor²) and the held-out excess √(RMSE² − floor²) is larger than the floor (a
    base whose own error is below the sensor's noise cannot hide an effect that the selection's
    rules would name; refining further only makes every later refit slower). Returns the model and base step the
    selection starts from and the ``resolution_before_effects`` section (None when the base has no
    resolution option, the check is off or no gap remains): every doubling tried, with its held-out
    RMSE and reduction, and the resolution adopted."""
    if not settings.resolution_check or model.refined() is None:
        return model, base, None
    option, start = _resolution_of(model)
    steps, cur, cur_base = [], model, base
    while (fine := cur.refined()) is not None and _excess(cur_base.before, sigma) > sigma:
        fits = _fine_base_fits(caps, d, fine, optimizer, seed, executor)
        fine_base = _base_step(caps, d, fits, gap.full_pred, sigma, settings)
        if (key := _fine_key(fine, optimizer, seed)) is not None:  # where a check's refits on it start
            d.fine_states.setdefault((key, float(sigma), ()), (fine_base.state, fine_base.preds))
        red = _shares(cur_base.before, fine_base.before, sigma)["reduction_mean_square"]
        adopted = red >= settings.resolution_threshold
        steps.append({"from": _resolution_of(cur)[1], "to": _resolution_of(fine)[1],
                      "heldout_rmse_before_out": cur_base.before, "heldout_rmse_after_out": fine_base.before,
                      "reduction_mean_square": red, "adopted": bool(adopted)})
        if not adopted:
            break
        cur, cur_base = fine, fine_base
    if not steps:
        return model, base, None
    info = {"option": option, "from": start, "to": _resolution_of(cur)[1], "threshold": settings.resolution_threshold,
            "steps": steps}
    return cur, cur_base, info


def _continue_on_finer_base(res: _Resolution, sel: _Selection, select_from) -> _Selection:
    """The selection after an adopted resolution check: the steps that named effects on the coarse
    base, then the greedy selection continued from the finer base with the effects not yet named
    (the coarse base's last, unsuccessful step is superseded by it)."""
    k = len(sel.chosen)
    more = select_from(res.state, res.preds, list(sel.chosen), k)
    if more is None:
        return _Selection(sel.steps[:k], sel.chosen, sel.alternatives[:k], res.preds, res.state)
    return _Selection(sel.steps[:k] + more.steps, sel.chosen + more.chosen, sel.alternatives[:k] + more.alternatives,
                      more.preds, more.state)


def _base_resolution(given: Model, final: Model) -> dict | None:
    """The base's resolution option as given and as the diagnosis ended on it (None without one)."""
    if given.refined() is None and final is given:
        return None
    (opt, a), (_, b) = _resolution_of(given), _resolution_of(final)
    return {"option": opt, "given": a, "final": b}


class _ResolutionChecks:
    """Every resolution check of one diagnosis after the effects start (:func:`resolution_check_converged`):
    one per (base, floor, named effects) — the check after the last named effect is also the check
    after the selection — the refiners of the selections, and the final check."""

    def __init__(self, caps, d: _Design, optimizer: Optimizer, seed: int, gap: _Gap, settings: "DiagnoseSettings",
                 executor=None) -> None:
        self.args = (caps, d, optimizer, seed, gap)
        self.settings, self.executor = settings, executor
        self.refiners: list[_Refiner] = []
        self.checked: dict = {}

    def check(self, m: Model, sel: _Selection, sigma: float) -> _Resolution | None:
        if m.refined() is None:  # no resolution to refine (or at its maximum)
            return None
        key = (_resolution_of(m), sigma, sel.chosen)
        if key not in self.checked:
            caps, d, optimizer, seed, gap = self.args
            self.checked[key] = resolution_check_converged(caps, d, m, optimizer, seed, gap, sel, sigma, self.settings,
                                                           self.executor)
        return self.checked[key]

    def refiner(self, start: Model, sigma: float) -> _Refiner | None:
        """A new refiner for a selection that starts on ``start`` (None when the checks are off)."""
        if not self.settings.resolution_check:
            return None
        self.refiners.append(_Refiner(start, lambda m, sel: self.check(m, sel, sigma)))
        return self.refiners[-1]

    def finish(self, model: Model, sel: _Selection, sigma: float, select_from):
        """The check after the selection and, when it is adopted, the selection continued from the
        finer base (``select_from(state, preds, named, first_step, refine)``). Returns the final
        selection, the base it ended on, the check (or None) and the checks during the selection."""
        n = len(self.refiners)
        final = self.refiners[-1].model if n else model
        res = self.check(final, sel, sigma) if self.settings.resolution_check else None
        if res is not None and res.info["adopted"]:
            final = res.model
            sel = _continue_on_finer_base(res, sel, lambda st, pr, named, k: select_from(
                st, pr, named, k, self.refiner(res.model, sigma)))
            final = self.refiners[-1].model if len(self.refiners) > n else final
        ran = [c for r in self.refiners[max(n - 1, 0):] for c in r.checks]  # the last selection's and its continuation's
        return sel, final, res, tuple(c for c in ran if res is None or c is not res.info)


class _Refiner:
    """The base's resolution converged after each named effect (the ``refine`` hook of
    :func:`_select_effects`): ``check(model, selection)`` is :func:`resolution_check_converged`;
    ``model`` is the base the selection is on, ``checks`` the sections of every check run."""

    def __init__(self, model: Model, check) -> None:
        self.model, self.check, self.checks = model, check, []

    def __call__(self, state, preds, chosen):
        res = self.check(self.model, _Selection((), tuple(chosen), (), preds, state))
        if res is None:
            return None
        self.checks.append(res.info)
        if not res.info["adopted"]:
            return None
        self.model = res.model
        return res.state, res.preds


def _block_options(sel: _Selection, views: Sequence[CaptureView]) -> dict:
    """``--model-option`` values the named effects' blocks need (their widened search ranges), as
    ``block.option``: :attr:`Diagnosis.block_options`."""
    if sel.state is None or not sel.chosen:
        return {}
    fitted = [v for v in views if v.fit_end >= 2]
    out = {}
    for link in sel.state.chain:
        if link.effect.name in sel.chosen:
            out.update({f"{link.effect.name}.{k}": float(v) for k, v in link.effect.handover_options(fitted).items()})
    return out


def _capture_info(caps, d: _Design, calib: Sequence[dict]) -> tuple[dict, ...]:
    """The ``captures`` section: condition, sampling, periodicity, sweep and calibration per capture."""
    return tuple({"source": c.source, "amplitude_V": c.amplitude_V, "frequency_Hz": c.frequency_Hz,
                  "samples": c.n, "dt_s": c.dt, "duration_s": c.duration_s, "periodic": bool(p),
                  "amplitude_changes": bool(sw), **cal}
                 for c, p, sw, cal in zip(caps, d.periodic, d.swept, calib))


def _all_base_fits(caps, d: _Design, model: Model, optimizer: Optimizer, seed: int, per_condition: bool, executor,
                   store, resume: bool, advance, stats) -> tuple[list, _Gap]:
    """The base fits as the cells of ``executor`` — per group on everything, per group on the fit
    part, and (global mode, several conditions) per condition alone — and the gap of the first."""
    by_cond = group_by_condition(caps)
    alone = by_cond if not per_condition and len(by_cond) > 1 else None
    jobs = _base_fit_jobs(caps, d.views, d.group_idx, d.labels, d.conds, alone)
    base_fits = _base_fits(jobs, len(d.group_idx), model, optimizer, seed, executor, store, resume, advance, stats)
    return base_fits, _gap_step(caps, d, base_fits, alone)


def _split_section(caps, d: _Design, settings: "DiagnoseSettings", untested, chosen, temporal) -> dict:
    """The ``split`` section; when ``auto`` chose a capture or cycles split, with the verdict of the
    temporal split beside it (``temporal()``: that diagnosis), for agreement."""
    split = _split_info(d.split, caps, d.views, d.swept, settings)
    if untested:
        split["not_tested"] = list(untested)
    if d.split.kind in ("capture", "cycles") and settings.split == "auto":
        split["other_scheme"] = _other_scheme(temporal(), chosen, "temporal")
    return split


@one_blas_thread
def diagnose(captures: Sequence[Capture], model: Model, optimizer: Optimizer, *, seed: int = 0,
             per_condition: bool = False, effects: Sequence[str] | None = None,
             settings: DiagnoseSettings = DiagnoseSettings(), progress: Progress = None,
             executor=None, store=None, resume: bool = False, stats=None,
             on_where: Callable[[WhereFigureData], None] | None = None) -> Diagnosis:
    """Diagnose the gap between ``model`` and the captures (see the module docstring).

    Parameters
    ----------
    captures : validated captures with measured outputs, one output unit.
    model : the base model (any registered model; it is adapted to the data).
    optimizer : optimizer of the base fits (``auto`` recommended).
    seed : seed of the base fits and of the placebo draws.
    per_condition : one base parameter set per condition (look-up table) instead of one for all.
    effects : candidate effect names (default: all of :data:`hystfit.effects.EFFECTS`).
    settings : :class:`DiagnoseSettings`.
    progress : optional callback ``progress(event, info)``.
    executor : :class:`hystfit.parallel.Executor` of the base fits (default: this process).
    store, resume : a :class:`hystfit.cells.CellStore` keeping the base fits; ``resume`` reuses them.
    stats : a :class:`hystfit.parallel.CellStats` that counts the base fits computed, reused, failed.
    on_where : called with the :class:`WhereFigureData` of the base model's where-analysis as soon
        as it is done (before the effects are tested), e.g. to draw its figures meanwhile. The
        final diagnosis's :attr:`Diagnosis.where_figure_data` is the same unless the noise floor
        was refined (:meth:`WhereFigureData.same_as` tells).

    Returns
    -------
    Diagnosis
    """
    t_start = time.perf_counter()
    check_seed(seed)
    caps, unit, names = _checked_inputs(captures, effects)
    model = given = prepare_shared(model, caps, store, resume)  # shared structure from all captures, once
    d = _design(caps, settings, per_condition)
    G = len(d.group_idx)
    if progress:
        progress("start", {"total": 2 * G + 1 + len(names) + 1})

    def advance(label: str) -> None:
        if progress:
            progress("advance", {"label": label})

    base_fits, gap = _all_base_fits(caps, d, model, optimizer, seed, per_condition, executor, store, resume,
                                    advance, stats)  # 1. gap: base fitted on everything
    first = where_analysis(caps, gap.residuals, gap.noise["sigma"], d.periodic, gap.residuals_alone)
    if on_where is not None:
        on_where(where_figure_data(first[0], gap.noise["sigma"], unit, "per-condition" if per_condition else "global",
                                   settings, len(caps), first[1]["spectra"]))
    advance("where")
    base = _base_step(caps, d, base_fits[G:2 * G], gap.full_pred, gap.noise["sigma"], settings)  # 2. fit part
    model, base, converged = converge_resolution(caps, d, model, optimizer, seed, gap, base, gap.noise["sigma"],
                                                 settings, executor)  # 2b. the base's own resolution first
    untested = untestable_effects(d, names)
    cands = _configured([n for n in names if n not in untested], base.preds, d.views)  # configured on the fit data
    all_effects = _configured(list(EFFECTS), base.preds, d.views)

    checks = _ResolutionChecks(caps, d, optimizer, seed, gap, settings, executor)

    def select(sigma: float, where: dict, count_progress: bool) -> _Selection:
        return _select_effects(sigma, where, state0=base.state, pred0=base.preds, caps=caps, views=list(d.views),
                               cands=cands, all_effects=all_effects, settings=settings, seed=seed,
                               advance=advance, count_progress=count_progress, refine=checks.refiner(model, sigma))

    out = _where_and_select(caps, d, gap, base, first, select)  # 3. where and 4. which, how far
    advance("verdict")

    def select_from(state, preds, named, first_step, refine):  # the selection continued on a finer base
        left = [e for e in cands if e.name not in named]
        if not left or first_step >= settings.max_effects:
            return None
        return _select_effects(out.sigma, out.where, state0=state, pred0=preds, caps=caps, views=list(d.views),
                               cands=left, all_effects=all_effects, seed=seed, advance=advance,
                               count_progress=False, first_step=first_step,
                               settings=replace(settings, max_effects=settings.max_effects - first_step),
                               refine=refine)

    sel, final, res, during = checks.finish(model, out.selection, out.sigma, select_from)
    resolution = res.info if res is not None else None
    split = _split_section(caps, d, settings, untested, sel.chosen, lambda: diagnose(
        caps, given, optimizer, seed=seed, per_condition=per_condition, effects=effects,
        settings=replace(settings, split="temporal")))
    found = list(out.findings)
    if base.calibrated:
        found.append(_calibration_finding(caps, base.calibration))
    figures_data = {"captures": caps, "views": list(d.views), "full_predictions": gap.full_pred,
                    "residuals": gap.residuals, "base_predictions": base.preds, "explained_predictions": sel.preds,
                    "chosen": list(sel.chosen), "spectra": out.fig_where["spectra"], "group_labels": list(d.labels)}
    return Diagnosis(base_model=model.name, optimizer=optimizer.name,
                     mode="per-condition" if per_condition else "global", unit=unit, seed=int(seed),
                     settings=settings, noise=gap.noise, where=out.where,
                     gap=_gap(gap.rmse_full, base.before, base.fit_before, _rmse(sel.preds, d.views, "test"), out.sigma),
                     effects=sel.steps[0] if sel.steps else (), steps=sel.steps,
                     verdict=sel.chosen[0] if sel.chosen else "none", explained_by=sel.chosen,
                     alternatives=sel.alternatives, split=split, captures=_capture_info(caps, d, base.calibration),
                     runtime_s=time.perf_counter() - t_start, figures_data=figures_data, findings=tuple(found),
                     resolution=resolution, split_choice=d.split, resolution_before_effects=converged,
                     base_resolution=_base_resolution(given, final), resolution_during_selection=during,
                     final_state=sel.state if sel.chosen else None,
                     block_options=_block_options(sel, list(d.views)))


# ----------------------------------------------------------------------------------------------
# The withheld-effect proof data
# ----------------------------------------------------------------------------------------------


def one_effect(effect: str, strength: float = 1.0, defaults=None):
    """:class:`hystfit.synth.Effects` with exactly ``effect`` on (``"none"``: nothing), its strength
    parameters taken from ``defaults`` (an ``Effects`` whose flags are ignored; default: the virtual
    actuator's realistic values) and scaled by ``strength`` with the rule of
    :meth:`hystfit.synth.Effects.from_names`: ``strength`` multiplies a₂, the creep gains, the delay
    and the drift rate and amplitude, and divides the stage's natural frequency. With the default
    ``defaults`` this equals ``Effects.only(effect, strength)``.
    """

    base = Effects() if defaults is None else defaults
    flags = {n: False for n in ("asymmetry", "creep", "dynamics", "delay", "drift", "noise", "quantization")}
    if effect == "none":
        return replace(base, **flags)
    if effect not in EFFECTS:
        raise ConfigError(f"unknown effect {effect!r}: choose from {', '.join(EFFECTS)} or none")
    if not (math.isfinite(strength) and strength > 0):
        raise ConfigError(f"strength must be a positive number. Got {strength!r} instead.")
    s = float(strength)
    scaled = {"asymmetry": {"asymmetry_a2": base.asymmetry_a2 * s},
              "creep": {"creep_gain": tuple(g * s for g in base.creep_gain)},
              "dynamics": {"dynamics_fn_Hz": base.dynamics_fn_Hz / s},
              "delay": {"delay_s": base.delay_s * s},
              "drift": {"drift_rate_um_per_s": base.drift_rate_um_per_s * s,
                        "drift_amplitude_um": base.drift_amplitude_um * s}}[effect]
    return replace(base, **{**flags, effect: True, **scaled})


def withheld_effect_captures(effect: str, strength: float = 1.0, seed: int = 0, *,
                             amplitudes_V: Sequence[float] = (30.0, 60.0),
                             frequencies_Hz: Sequence[float] = (10.0, 40.0, 80.0),
                             cycles: int = 5, fs_Hz: float = 10_000.0, steps_s: float = 3.0,
                             noise_um: float = 0.008, plant=None) -> list[Capture]:
    """Captures of the virtual actuator with exactly one effect on (or none), for the proof.

    ``effect`` is one of :data:`hystfit.effects.EFFECTS` or ``"none"``; ``strength`` scales its
    default (:func:`one_effect`). The plant is ``plant`` (a :class:`hystfit.synth.Plant`: its
    hysteresis, offset and output unit, and in its ``effects`` the strength parameters of every
    effect, whose flags are ignored), by default :meth:`hystfit.synth.Plant.default`'s hysteresis
    and realistic effect strengths, with that one effect on plus white sensor noise
    σ = ``noise_um`` µm. Captures: raised cosines 0→A→0 for every amplitude × frequency
    (``cycles`` periods) and one step-and-hold capture of ``steps_s`` seconds at the largest
    amplitude (slow effects need long data), in the plant's output unit.
    Each capture draws its noise from its own seed derived from ``seed``.
    """

    plant = Plant() if plant is None else plant
    e = one_effect(effect, strength, plant.effects)
    if noise_um > 0:
        e = e.with_noise(noise_um)
    plant = plant.with_effects(e)
    unit = plant.output_unit
    out = []
    k = 0
    for a in amplitudes_V:
        for f in frequencies_Hz:
            t, u = raised_cosine(a, f, cycles, fs_Hz)
            y = simulate_plant(plant, t, u, seed=int(seed) * 1000 + k)
            out.append(Capture(source=f"synth_{effect}_{a:g}V_{f:g}Hz", t=t, u=u, y=y, dt=1.0 / fs_Hz, y_unit=unit,
                               amplitude_V=float(a), frequency_Hz=float(f), condition_source="option"))
            k += 1
    if steps_s > 0:
        t, u = step_pattern(max(amplitudes_V), steps_s, fs_Hz)
        y = simulate_plant(plant, t, u, seed=int(seed) * 1000 + k)
        a, f = detect_condition(u, 1.0 / fs_Hz)
        out.append(Capture(source=f"synth_{effect}_steps", t=t, u=u, y=y, dt=1.0 / fs_Hz, y_unit=unit, amplitude_V=a,
                           frequency_Hz=f, condition_source="detected"))
    return out
