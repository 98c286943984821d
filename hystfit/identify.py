"""Identification orchestration: captures → per-condition (or global) fits → results.

No numerics of its own: the model simulates, the objective scores, the optimizer searches,
:mod:`hystfit.metrics` measures. This module decides *what* is fitted to *which* captures,
derives every run's seed, keeps the best run and reports the spread.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from .capture import Capture
from .conditions import condition_label, group_by_condition
from .cells import CellStore, cell_key
from .seeds import SEED_MAX, check_seed, run_seed  # noqa: F401  (re-exported: hystfit.identify.check_seed)
from .errors import ConfigError, InputError, NoResultError
from .metrics import MAPE_THRESHOLD_FRACTION, check_mape_floor, compute_metrics, compute_metrics_pooled
from .models.base import Model
from .objective import Objective, Series
from .optimizers.base import OptimizeResult, Optimizer
from .optimizers.lsq import polisher
from .parallel import CellFailed, CellStats, Executor, LocalExecutor, default_jobs, one_blas_thread, run_cells
from .params import OUTPUT_OFFSET_NAMES, DataScale, Param, apply_bound_overrides, bound_side, with_output_unit

#: progress(event, info) — events: "start" (total units), "advance" (one run done), "note" (text).
Progress = Optional[Callable[[str, dict], None]]


@dataclass(frozen=True)
class RunRecord:
    """One independent optimizer run (optionally polished)."""

    run: int
    seed: int
    result: OptimizeResult
    polish: OptimizeResult | None
    x: np.ndarray
    fun: float
    rmse: float
    wall_time_s: float

    @property
    def nfev(self) -> int:
        return self.result.nfev + (self.polish.nfev if self.polish is not None else 0)


@dataclass(frozen=True)
class ConditionFit:
    """The identified parameters of one condition (a look-up-table cell) or of the global fit."""

    amplitude_V: float
    frequency_Hz: float
    label: str
    captures: tuple[Capture, ...]
    model: Model
    scale: DataScale
    params: tuple[Param, ...]
    theta: np.ndarray
    stderr: np.ndarray
    metrics: dict[str, float]
    per_capture: tuple[dict, ...]
    predictions: tuple[np.ndarray, ...]
    runs: tuple[RunRecord, ...]
    best_run: int
    runtime_s: float
    unit: str

    @property
    def evaluations(self) -> int:
        return int(sum(r.nfev for r in self.runs))

    @property
    def at_bound(self) -> tuple[str | None, ...]:
        """Per parameter: ``"lower"``/``"upper"`` when the value is pinned at that bound (see :func:`bound_side`)."""
        return tuple(bound_side(float(v), p.lower, p.upper) for p, v in zip(self.params, self.theta))

    @property
    def best(self) -> RunRecord:
        return self.runs[self.best_run]

    def spread(self) -> dict[str, float]:
        funs = np.array([r.fun for r in self.runs])
        rmses = np.array([r.rmse for r in self.runs])
        times = np.array([r.wall_time_s for r in self.runs])
        u = self.unit
        return {
            "runs": len(self.runs),
            "fun_min": float(funs.min()), "fun_max": float(funs.max()),
            "fun_mean": float(funs.mean()), "fun_std": float(funs.std(ddof=1)) if len(funs) > 1 else 0.0,
            f"rmse_min_{u}": float(rmses.min()), f"rmse_max_{u}": float(rmses.max()),
            f"rmse_mean_{u}": float(rmses.mean()),
            f"rmse_std_{u}": float(rmses.std(ddof=1)) if len(rmses) > 1 else 0.0,
            "time_median_s": float(np.median(times)),
        }


@dataclass(frozen=True)
class IdentifyResult:
    model_name: str
    optimizer_name: str
    optimizer_settings: dict
    seed: int
    runs: int
    polish: bool
    mode: str  # "per-condition" or "global"
    unit: str
    fits: tuple[ConditionFit, ...]
    bounds_overrides: dict = field(default_factory=dict)
    model_options: dict = field(default_factory=dict)
    failed: tuple[str, ...] = ()  # "CONDITION run R: error" of every run that failed on every attempt
    cell_stats: CellStats = field(default_factory=CellStats)  # runs computed / reused / failed, wall time
    start: str = "defaults"  # where the runs started: the model's defaults, or the starts given (what they are)

    @property
    def pooled_rmse(self) -> float:
        """The RMSE over every scored sample of every fit (each fit's RMSE weighted by its samples)."""
        sse = n = 0.0
        for f in self.fits:
            k = float(f.metrics["n_samples"])
            sse, n = sse + f.metrics[f"rmse_{self.unit}"] ** 2 * k, n + k
        return math.sqrt(sse / n) if n else float("nan")


def _output_unit(captures: Sequence[Capture]) -> str:
    units = {c.y_unit for c in captures}
    if len(units) > 1:
        detail = ", ".join(f"{c.name}: {c.y_unit}" for c in captures)
        raise InputError(f"captures have different output units ({detail}); convert them to one unit before fitting together")
    return units.pop()


def unit_param(p: Param, unit: str) -> str:
    return with_output_unit(p.unit, unit)


@dataclass(frozen=True)
class _Problem:
    """What every run of one cell shares: the adapted model, its box, the pooled captures and the
    start point of its runs (None: the model's defaults)."""

    captures: tuple[Capture, ...]
    model: Model
    scale: DataScale
    params: tuple[Param, ...]
    lower: np.ndarray
    upper: np.ndarray
    unit: str
    start: np.ndarray | None = None

    def objective(self) -> Objective:
        return Objective(self.model, [Series(c.u, c.y, c.dt, c.warmup_samples) for c in self.captures])


def _problem(captures: Sequence[Capture], model: Model,
             bounds: Mapping[str, tuple[float, float]] | None) -> _Problem:
    for c in captures:
        if c.y is None:
            raise InputError(f"{c.source}: no measured output column; identification needs one (see --output-col)")
    unit = _output_unit(captures)
    scale = DataScale.from_arrays([c.u for c in captures], [c.y for c in captures], [c.dt for c in captures],
                                  [c.frequency_Hz for c in captures])
    model = model.adapt(scale)  # shared structure is prepared once by the caller (prepare_shared)
    params = apply_bound_overrides(model.params(scale), bounds or {})
    return _Problem(tuple(captures), model, scale, params, np.array([p.lower for p in params]),
                    np.array([p.upper for p in params]), unit)


def adapted_model(captures: Sequence[Capture], model: Model) -> tuple[Model, tuple[Param, ...]]:
    """``model`` as :func:`identify` fits it on ``captures`` pooled, adapted to their scale (e.g. PI
    thresholds from their input range), and its parameters (names, units, box, defaults).
    ``model`` is prepared already (:func:`prepare_shared`)."""
    problem = _problem(captures, model, None)
    return problem.model, problem.params


def _run(problem: _Problem, optimizer: Optimizer, seed: int, cell: int, run: int, polish: bool,
         objective: Objective | None = None) -> RunRecord:
    """One seeded optimizer run (plus the least-squares polish) on one cell."""
    objective = objective if objective is not None else problem.objective()
    s = run_seed(seed, cell, run)
    rng = np.random.default_rng(s)
    final = polisher() if polish and not optimizer.polishes_itself else None
    for opt in (optimizer,) if final is None else (optimizer, final):
        opt.load_libraries()  # a one-time import is not the run's time (the command's wall time has it)
    t_run = time.perf_counter()
    # optimizers that declare `uses_start_point` start from (or seed their search with) the cell's
    # start: the one given to identify (``starts``), else the defaults
    x0 = None
    if optimizer.uses_start_point:
        x0 = problem.start if problem.start is not None else np.array([p.default for p in problem.params])
    res = optimizer.minimize(objective, problem.lower, problem.upper, rng=rng, x0=x0)
    pol = None
    x, fun = res.x, res.fun
    if final is not None and np.isfinite(fun):
        pol = final.minimize(objective, problem.lower, problem.upper, rng=rng, x0=res.x)
        if pol.fun <= fun:
            x, fun = pol.x, pol.fun
    x = centered_offset(objective, problem.params, np.asarray(x, float), float(fun))
    return RunRecord(run, s, res, pol, np.asarray(x, float), float(fun), float(np.sqrt(max(fun, 0.0))),
                     time.perf_counter() - t_run)


#: a stage identified from the captures (pi2's two-step route) whose f_n exceeds the fastest drive
#: frequency by more than this factor is hardly excited by them: :func:`slow_drive_note`
SLOW_DRIVE_RATIO = 50.0


def slow_drive_note(model: Model, captures: Sequence[Capture]) -> str | None:
    """A caveat when the shared structure holds a stage (``pi2``'s f_n, identified before the fit)
    far above every capture's drive frequency: a 1 Hz sine excites a 900 Hz stage only through the
    tiny lag it causes, so f_n and ζ are poorly determined (a blind test's pi2 on a 1 Hz capture
    printed "f_n 889.8 Hz" without a word). None otherwise."""
    base = model.composition[0] if model.composition is not None else model
    fn = getattr(base, "fn_Hz", None)
    drives = [c.frequency_Hz for c in captures if np.isfinite(c.frequency_Hz) and c.frequency_Hz > 0]
    if fn is None or not drives or not np.isfinite(fn) or fn <= SLOW_DRIVE_RATIO * max(drives):
        return None
    return (f"the stage's f_n {fn:.4g} Hz is {fn / max(drives):.0f}× the fastest drive ({max(drives):.4g} Hz): so slow "
            "a drive hardly excites it, and f_n and ζ are poorly determined; a faster or broadband capture (a "
            "PRBS, a multisine) determines them")


def centered_offset(objective: Objective, params: Sequence[Param], theta: np.ndarray, fun: float) -> np.ndarray:
    """``theta`` with the base's output offset (``y0`` and kin, :data:`OUTPUT_OFFSET_NAMES`) moved by
    the captures' mean drift offset, when that leaves the fit's cost as it is.

    A ``drift`` block's offset per capture is projected out of the objective (every candidate gets
    each capture's least-squares offset): a constant the base adds then changes nothing, the base's
    offset is free, and a search leaves it anywhere in its box — a blind test's fit ended with
    y0 = −20.7 µm at its bound and +20.9 µm in the drift. The fit is the same, but the model a
    feedforward inverts (without the drift, which it cannot know) was 20 µm off. Moved here, the base
    carries the captures' common level (the sample-weighted mean of their drift offsets, within its
    box) and the drift only their differences: one capture's drift offset becomes 0. Unchanged where
    the offset is not free (a base offset that passes through creep's filter from rest), where the
    model has no drift, or no offset parameter."""
    model = objective.model
    if model is None or model.nuisance_basis(4, 1.0) is None or not np.isfinite(fun):
        return theta
    k = next((i for i, p in enumerate(params) if p.name in OUTPUT_OFFSET_NAMES), None)
    coefs = objective.nuisance_coefficients(theta)
    if k is None or any(c is None or not c.size for c in coefs):
        return theta
    w = np.array([max(s.y.size - s.skip, 0) for s in objective.series], float)
    shift = float(np.dot(w, [c[0] for c in coefs]) / w.sum()) if w.sum() > 0 else 0.0
    moved = theta.copy()
    moved[k] = min(max(theta[k] + shift, params[k].lower), params[k].upper)
    if not np.isfinite(shift) or moved[k] == theta[k]:
        return theta
    with np.errstate(all="ignore"):
        f = float(objective(moved[None, :])[0])
    return moved if np.isfinite(f) and f <= fun * (1.0 + 1e-9) + 1e-300 else theta


def _run_job(shared: tuple, job: tuple[int, int]) -> RunRecord:
    """Executor entry point: shared (problems, optimizer, seed, polish), job (cell, run) → RunRecord."""
    problems, optimizer, seed, polish = shared
    cell, run = job
    return _run(problems[cell], optimizer, seed, cell, run, polish)


def _summarize(problem: _Problem, records: Sequence[RunRecord], label: str | None,
               condition: tuple[float, float] | None, mape_floor: float = MAPE_THRESHOLD_FRACTION,
               objective: Objective | None = None) -> ConditionFit:
    """The :class:`ConditionFit` of ``problem`` from its runs' ``records``. ``objective``: the
    problem's objective when the runs were made in this process with it (its simulators — a PI's
    play operators of every capture — are made once for the runs and the summary; the numbers
    do not depend on it)."""
    captures = problem.captures
    objective = problem.objective() if objective is None else objective
    best = int(np.argmin([rec.fun for rec in records]))
    theta = records[best].x
    if theta.size != len(problem.params) or not np.isfinite(records[best].fun):
        # every candidate overflowed (a blind test's --bounds w1=1e300:1e301): one line, not a shape error
        raise NoResultError(f"{label or 'global'}: no run found a finite cost anywhere in the parameter box: the "
                            "model's output overflows there; narrow the --bounds (or check the data's scale)")
    preds = objective.predict(theta)
    unit = problem.unit
    # metrics over the scored samples, as the objective (a --warmup is left out)
    metrics = compute_metrics_pooled([(c.y[c.warmup_samples:], p[c.warmup_samples:]) for c, p in zip(captures, preds)],
                                     unit, mape_floor=mape_floor)
    per = tuple({"source": c.source, **compute_metrics(c.y[c.warmup_samples:], p[c.warmup_samples:], unit,
                                                       mape_floor=mape_floor),
                 **_nuisance_fields(a, unit)}
                for c, p, a in zip(captures, preds, objective.nuisance_coefficients(theta)))
    stderr = _stderr(objective, theta, problem.lower, problem.upper)
    if condition is None:
        condition = (captures[0].amplitude_V, captures[0].frequency_Hz)
    return ConditionFit(
        amplitude_V=float(condition[0]), frequency_Hz=float(condition[1]),
        label=label or condition_label(condition), captures=tuple(captures), model=problem.model,
        scale=problem.scale, params=problem.params, theta=theta, stderr=stderr, metrics=metrics, per_capture=per,
        predictions=tuple(preds), runs=tuple(records), best_run=best,
        runtime_s=float(sum(r.wall_time_s for r in records)), unit=unit,
    )


def _nuisance_fields(coef: np.ndarray | None, unit: str) -> dict[str, float]:
    """The per-capture drift of a model with a ``drift`` block (offset and rate), named with units."""
    if coef is None or len(coef) < 2:
        return {}
    return {f"drift_offset_{unit}": float(coef[0]), f"drift_rate_{unit}_per_s": float(coef[1])}


def prepare_shared(model: Model, captures: Sequence[Capture], store: CellStore | None = None,
                   resume: bool = False) -> Model:
    """The one step that identifies structure shared by every condition (a Hammerstein model's or an
    ``lti`` block's linear stage, pi2's stage) from *all* the captures; identify, compare and diagnose
    call it once, before any per-condition or per-subset fit (a no-op for a model already prepared).

    With a ``store`` the prepared model is kept like a finished cell (keyed by the captures' content,
    the model and its options, and the hystfit version) and ``resume`` reuses it: an interrupted
    batch does not identify the shared structure again (on 200 captures pi2's stage takes minutes)."""
    if store is None:
        return model.prepare(captures)
    shared = CellStore(store.root / "shared")  # beside the cells, not counted among them
    key = cell_key("prepare", captures=list(captures), model=model.name, model_options=model.as_options())
    if resume:
        kept = shared.get(key)
        if isinstance(kept, Model):
            return kept
    prepared = model.prepare(captures)
    if prepared != model:
        shared.put(key, prepared)
    return prepared


def fit_captures(captures: Sequence[Capture], model: Model, optimizer: Optimizer, *, seed: int, cell: int = 0,
                 runs: int = 1, polish: bool = True, bounds: Mapping[str, tuple[float, float]] | None = None,
                 progress: Progress = None, label: str | None = None,
                 condition: tuple[float, float] | None = None,
                 mape_floor: float = MAPE_THRESHOLD_FRACTION) -> ConditionFit:
    """Fit one parameter set to the pooled ``captures``: ``runs`` seeded runs, best kept.

    Run r uses the seed :func:`run_seed` (seed, cell, r), recorded in the result.
    """
    problem = _problem(captures, prepare_shared(model, captures), bounds)
    objective = problem.objective()
    records = []
    for r in range(runs):
        records.append(_run(problem, optimizer, seed, cell, r, polish, objective))
        if progress:
            progress("advance", {"label": label, "run": r, "rmse": records[-1].rmse})
    return _summarize(problem, records, label, condition, check_mape_floor(mape_floor), objective)


#: a direction of the Jacobi-scaled normal matrix whose eigenvalue is below this share of the largest
#: is not determined by the data (the finite-difference Jacobian's own error is about 1e-6 relative)
UNDETERMINED_RTOL = 1e-10


def _stderr(objective: Objective, theta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Asymptotic standard errors sqrt(diag(σ² (JᵀJ)⁻¹)) of the parameters at the optimum.

    Parameters on a bound get NaN (the linearisation does not hold there). A parameter the data do
    not determine gets +inf: one whose Jacobian column is zero, or that has a share of a direction
    of the Jacobi-scaled normal matrix (unit diagonal) with an eigenvalue below
    :data:`UNDETERMINED_RTOL` of the largest; the others' errors are computed in the determined
    directions. A poorly determined parameter gets a large error — the honest sign. (Before, a
    pseudo-inverse of the unscaled matrix cut the smallest directions to zero *variance*: a blind
    test's stage at 1601 Hz under a 1 Hz drive was reported ± 6·10⁻¹⁰ Hz.)
    """
    try:
        JtJ, rr, m = objective.normal_matrix(theta, upper=upper, lower=lower)
    except Exception:  # pragma: no cover - defensive: a model that cannot be differentiated
        return np.full(theta.shape, np.nan)
    d = JtJ.shape[0]
    if m <= d or not (np.all(np.isfinite(JtJ)) and np.isfinite(rr)):
        return np.full(theta.shape, np.nan)
    sigma2 = rr / (m - d)
    free = np.array([bound_side(float(v), lo, hi) is None for v, lo, hi in zip(theta, lower, upper)], dtype=bool)
    out = np.full(theta.shape, np.nan)
    if free.any():
        out[free] = _free_stderr(JtJ[np.ix_(free, free)], sigma2)
    return out


def _free_stderr(A: np.ndarray, sigma2: float) -> np.ndarray:
    """sqrt(σ² diag(A⁻¹)) for a normal matrix A of the free parameters, +inf where the data do not
    determine a parameter (see :func:`_stderr`)."""
    dg = np.sqrt(np.maximum(np.diag(A), 0.0))
    zero = dg <= 1e-300
    out = np.full(A.shape[0], np.inf)
    live = ~zero
    if not live.any():
        return out
    S = A[np.ix_(live, live)] / dg[live][:, None] / dg[live][None, :]
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > UNDETERMINED_RTOL * max(float(w.max()), 0.0)
    var = ((V[:, keep] ** 2) / w[keep]).sum(axis=1) * sigma2 / dg[live] ** 2
    lost = (V[:, ~keep] ** 2).sum(axis=1) > 1e-6  # a share of an undetermined direction
    out[live] = np.where(lost, np.inf, np.sqrt(var))
    return out


def condition_groups(captures: Sequence[Capture], global_fit: bool = False) -> dict[tuple, list[Capture]]:
    """The parameter sets :func:`identify` fits: condition → its captures (look-up table), or one
    group of every capture for a global fit."""
    return {("all", "all"): list(captures)} if global_fit else group_by_condition(captures)


@one_blas_thread
def identify(captures: Sequence[Capture], model: Model, optimizer: Optimizer, *, seed: int = 0, runs: int = 1,
             polish: bool = True, global_fit: bool = False,
             bounds: Mapping[str, tuple[float, float]] | None = None,
             progress: Progress = None, model_options: Mapping | None = None,
             jobs: int | None = 1, executor: Executor | None = None, store: CellStore | None = None,
             resume: bool = False, mape_floor: float = MAPE_THRESHOLD_FRACTION,
             on_fit: Callable[[ConditionFit], None] | None = None,
             starts: Mapping[str, np.ndarray] | None = None) -> IdentifyResult:
    """Identify ``model`` on ``captures``: one fit per condition (look-up table) or one global fit.

    ``jobs`` > 1 spreads the (condition, run) cells over a process pool (None: all cores), or
    ``executor`` runs them (:mod:`hystfit.parallel`); every run's seed depends only on (seed,
    condition index, run), so the numbers depend on neither. With a ``store`` every finished run is
    stored, and ``resume`` reuses the runs stored there. A run that fails on every attempt is listed
    in ``failed`` and left out of its condition; a condition left without runs is left out; when
    nothing is left, :class:`NoResultError`. ``mape_floor``: MAPE/SMAPE leave out samples with
    |y_meas| below this fraction of the stroke (0: every sample, as paper 002; :mod:`hystfit.metrics`).
    ``on_fit(fit)`` is called in this process as soon as every run of a condition is done, in the
    order conditions finish (e.g. to draw its figures while the others are fitted); the result lists
    the fits in condition order. ``starts``: per cell label (``"global"`` for a global fit, else the
    condition's label) a start θ₀ in the model's parameter order, clipped to the box, that replaces
    the defaults as the start point of an optimizer that takes one (e.g. a fit to polish on more
    data, :func:`hystfit.diagnose.fit_recommended`); cells without one start from the defaults. A
    label that is no cell's, a start of another size or with a value that is not a number, and
    starts for an optimizer that takes no start point are errors. The result's ``start`` is then
    ``"given"`` (the caller may say more).
    """
    check_seed(seed)
    mape_floor = check_mape_floor(mape_floor)
    if not captures:
        raise InputError("no captures to identify")
    unit = _output_unit(captures)
    groups = condition_groups(captures, global_fit)
    if progress:
        progress("start", {"total": len(groups) * runs})
    model = prepare_shared(model, captures, store, resume)  # structure shared by all conditions (e.g. stage dynamics)
    summary = model.structure_summary()
    if progress and summary is not None:  # say how the shared structure was found (e.g. which route)
        progress("note", {"text": f"{model.name}: {summary}"})
    slow = slow_drive_note(model, captures)
    if progress and slow is not None:
        progress("note", {"text": f"{model.name}: {slow}"})
    cells = _cells(groups, model, optimizer, bounds, global_fit, starts)
    work = [(cell, r) for cell in range(len(cells)) for r in range(runs)]
    keys = None if store is None else _store_keys(cells, work, model, optimizer, bounds, seed, polish)
    collect = _Summaries(cells, work, runs, mape_floor, progress, on_fit)
    if jobs is None and executor is None:  # all cores, unless every cell is one exact linear solve
        jobs = _default_jobs(model, optimizer)
    own = executor is None
    executor = LocalExecutor(jobs) if own else executor
    stats = CellStats()
    try:
        records = run_cells(_run_job, work, shared=(tuple(c[0] for c in cells), optimizer, seed, polish),
                            executor=executor, store=store, keys=keys, resume=resume, on_done=collect.done,
                            stats=stats)
    finally:
        if own:
            executor.close()
    failed = [f"{cells[cell][2]} run {r}: {rec.error} (after {rec.attempts} attempts)"
              for (cell, r), rec in zip(work, records) if isinstance(rec, CellFailed)]
    fits = [collect.summaries[cell] for cell in range(len(cells)) if cell in collect.summaries]
    if not fits:
        raise NoResultError(f"every run failed ({len(failed)} of {len(work)}); first error: {failed[0]}")
    return IdentifyResult(
        model_name=model.name, optimizer_name=optimizer.name, optimizer_settings=optimizer.settings(),
        seed=seed, runs=runs, polish=polish, mode="global" if global_fit else "per-condition", unit=unit,
        fits=tuple(fits), bounds_overrides=dict(bounds or {}), model_options=dict(model_options or {}),
        failed=tuple(failed), cell_stats=stats, start="defaults" if not starts else "given",
    )


def _default_jobs(model: Model, optimizer: Optimizer) -> int:
    """Processes of :func:`identify` without ``jobs``: one when every cell is one exact linear solve
    (a pool would only add its start-up), else all cores."""
    sep = model.separable() if optimizer.uses_separable_structure else None
    return 1 if (sep is not None and not sep.nonlinear) else default_jobs()


def startup_steps(model: Model, optimizer: Optimizer, *, jobs: int | None = 1, executor: Executor | None = None,
                  n_cells: int | None = None, polish: bool = True) -> tuple:
    """What :func:`identify` with these arguments will load or start first, as steps a caller can
    run while it reads the captures (``hystfit.io.load_captures(..., ahead=...)``). Fitted in this
    process (one job, one cell, or every cell one exact linear solve): the optimizer's libraries
    and, with the polish, ``scipy.optimize`` — not numba, which a PI fit of short captures never
    loads. In a local pool: its fork server, which loads hystfit, numba and ``scipy.optimize``
    (:func:`hystfit.parallel.start_pool_server`). Nothing for another executor."""
    from ._warm import import_optimize
    from .parallel import start_pool_server

    if executor is not None:
        return ()
    if jobs is None:
        try:
            jobs = _default_jobs(model, optimizer)
        except Exception:  # noqa: BLE001 - a model that cannot say: identify reports what is wrong
            return ()
    if jobs == 1 or (n_cells is not None and n_cells <= 1):
        return (*((optimizer.load_libraries,) if optimizer.libraries else ()), *((import_optimize,) if polish else ()))
    return (start_pool_server,)


def _cells(groups: Mapping[tuple, list[Capture]], model: Model, optimizer: Optimizer,
           bounds: Mapping[str, tuple[float, float]] | None, global_fit: bool,
           starts: Mapping[str, np.ndarray] | None) -> list[tuple[_Problem, tuple[float, float], str]]:
    """The cells of :func:`identify`: per parameter set its problem (with its start, if given), its
    condition and its label; one-line errors for starts that do not fit them."""
    if starts is not None and not optimizer.uses_start_point:
        raise ConfigError(f"identify: {optimizer.name} takes no start point; starts need an optimizer that does "
                          "(e.g. lsq)")
    cells = []
    for key, caps in groups.items():
        if global_fit:
            amps = sorted({c.amplitude_V for c in caps})
            freqs = sorted({c.frequency_Hz for c in caps})
            cond = (float("nan"), float("nan")) if len(amps) * len(freqs) > 1 else (amps[0], freqs[0])
            label = "global"
        else:
            cond, label = key, condition_label(key)
        problem = _problem(caps, model, bounds)
        if starts is not None and label in starts:
            problem = _with_start(problem, label, starts[label], model.name)
        cells.append((problem, cond, label))
    unknown = sorted(set(starts or {}) - {label for _, _, label in cells})
    if unknown:
        raise ConfigError(f"identify: starts for {', '.join(unknown)}, which no cell is; the cells are "
                          f"{', '.join(label for _, _, label in cells)}")
    return cells


def _with_start(problem: _Problem, label: str, start, model_name: str) -> _Problem:
    """``problem`` starting at ``start`` (clipped to its box), or a one-line error for a start of
    another shape or with values that are not numbers."""
    x0 = np.asarray(start, dtype=np.float64)
    if x0.shape != problem.lower.shape:
        raise ConfigError(f"identify: the start of {label} has shape {x0.shape}; {model_name} has "
                          f"{problem.lower.size} parameters ({', '.join(p.name for p in problem.params)})")
    if not np.all(np.isfinite(x0)):
        raise ConfigError(f"identify: the start of {label} has values that are not numbers "
                          f"(at {', '.join(problem.params[i].name for i in np.flatnonzero(~np.isfinite(x0)))})")
    return replace(problem, start=np.clip(x0, problem.lower, problem.upper))


def _store_keys(cells, work, model: Model, optimizer: Optimizer, bounds, seed: int, polish: bool) -> list[str]:
    """The store key of every (cell, run) of ``work``: everything that decides its result."""
    settings = optimizer.settings()
    opts = model.as_options()
    return [cell_key("identify", captures=cells[c][0].captures, model=model.name, model_options=opts,
                     optimizer=optimizer.name, optimizer_settings=settings, bounds=dict(bounds or {}), seed=seed,
                     cell=c, run=r, polish=polish,
                     **({} if cells[c][0].start is None else {"start": [float(v) for v in cells[c][0].start]}))
            for c, r in work]


class _Summaries:
    """The ``on_done`` of :func:`identify`'s cells: reports progress and summarizes a condition as soon
    as all its runs are in (then calls ``on_fit``); ``summaries`` maps cell → :class:`ConditionFit`."""

    def __init__(self, cells, work, runs: int, mape_floor: float, progress: Progress,
                 on_fit: Callable[[ConditionFit], None] | None) -> None:
        self.cells, self.work, self.runs, self.mape_floor = cells, work, runs, mape_floor
        self.progress, self.on_fit = progress, on_fit
        self.finished: dict[int, dict[int, Any]] = {}  # cell → run → record, until the cell is summarized
        self.summaries: dict[int, ConditionFit] = {}

    def done(self, i: int, rec, reused: bool) -> None:
        cell, run = self.work[i]
        if self.progress:
            failed = isinstance(rec, CellFailed)
            self.progress("advance", {"label": f"{self.cells[cell][2]} run {run}", "run": run,
                                      "rmse": None if failed else rec.rmse, "reused": reused, "failed": failed})
        got = self.finished.setdefault(cell, {})
        got[run] = rec
        if len(got) == self.runs:  # the condition is complete: summarize it now
            recs = [got[r] for r in range(self.runs) if not isinstance(got[r], CellFailed)]
            del self.finished[cell]
            if recs:
                problem, cond, label = self.cells[cell]
                self.summaries[cell] = _summarize(problem, recs, label, cond, self.mape_floor)
                if self.on_fit is not None:
                    self.on_fit(self.summaries[cell])
