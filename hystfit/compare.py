"""Comparison orchestration: models × optimizers × conditions (× runs).

Each *cell* (one model, one optimizer, one condition) is an independent job: R seeded runs of
:func:`hystfit.identify.fit_captures`, summarized into a picklable :class:`CellResult`. Cells run
on an executor (:mod:`hystfit.parallel`: serially, a local process pool, or Dask); the numbers do
not depend on it because every run's seed is derived from (seed, cell index, run) and the cell
order is fixed. The captures are shipped to the workers once; a cell names its condition by index.
With a :class:`hystfit.cells.CellStore` each finished cell is stored and ``resume`` reuses it. A
cell that fails is recorded with its error and the comparison goes on.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Optional, Sequence

import numpy as np

from .capture import Capture
from .cells import CellStore, cell_key
from .conditions import condition_label, group_by_condition
from .errors import ConfigError, HystfitError
from ._jit import _load_numba
from .identify import fit_captures, prepare_shared
from .seeds import check_seed
from .metrics import check_mape_floor, compute_metrics_pooled
from .objective import Objective, Series
from .parallel import CellFailed, CellStats, Executor, LocalExecutor, fork_map, one_blas_thread, run_cells
from .params import DataScale, apply_bound_overrides
from .registry import optimizers as optimizer_registry
from .factory import make_model, make_optimizer

Progress = Optional[Callable[[str, dict], None]]


@dataclass(frozen=True)
class CellSpec:
    index: int
    model: str
    optimizer: str
    key: tuple[float, float]
    label: str
    captures: tuple[Capture, ...]
    runs: int
    seed: int
    polish: bool
    model_options: dict
    optimizer_options: dict
    bounds: dict = field(default_factory=dict)  # parameter name → (lower, upper) for this cell's model
    mape_floor: float = 0.01  # MAPE/SMAPE floor, fraction of the stroke (hystfit.metrics)
    condition: int = 0  # index of the condition: ``captures`` is filled from the shared captures on the worker


@dataclass(frozen=True)
class RunMetrics:
    """One run of a cell: ``fun``/``j`` after the polish (if any), ``search_fun``/``search_j`` of the
    global search alone (equal to them without a polish), so optimizers can be compared on their own."""

    run: int
    seed: int
    fun: float
    j: float
    metrics: dict
    wall_time_s: float
    nfev: int
    history_best: np.ndarray
    search_fun: float = np.nan
    search_j: float = np.nan
    search_nfev: int = 0  # evaluations of the optimizer alone (``nfev`` adds the polish)


@dataclass(frozen=True)
class CellResult:
    model: str
    optimizer: str
    amplitude_V: float
    frequency_Hz: float
    label: str
    n_params: int
    runs: tuple[RunMetrics, ...] = ()
    best_run: int = 0
    theta: np.ndarray | None = None
    param_names: tuple[str, ...] = ()
    predictions: tuple[np.ndarray, ...] = ()
    runtime_s: float = 0.0
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def best(self) -> RunMetrics:
        return self.runs[self.best_run]


@dataclass(frozen=True)
class CompareResult:
    models: tuple[str, ...]
    optimizers: tuple[str, ...]
    conditions: tuple[tuple[tuple[float, float], str], ...]
    captures: dict = field(default_factory=dict)  # label -> tuple of captures
    cells: tuple[CellResult, ...] = ()
    runs: int = 1
    seed: int = 0
    unit: str = "um"
    jobs: int = 1
    polish: bool = True
    notes: tuple[str, ...] = ()  # e.g. how a model's shared structure was identified
    optimizer_settings: dict = field(default_factory=dict)  # optimizer → its settings (budget included)
    bounds: dict = field(default_factory=dict)  # model → bound overrides applied to it
    global_fit: bool = False
    self_polishing: tuple[str, ...] = ()  # optimizers that are not polished after (``polishes_itself``)
    cell_stats: CellStats = field(default_factory=CellStats)  # cells computed / reused / failed, wall time
    executor: str = "local"

    def cell(self, model: str, optimizer: str, label: str) -> CellResult | None:
        for c in self.cells:
            if c.model == model and c.optimizer == optimizer and c.label == label:
                return c
        return None


#: (model, optimizer) pairs this process has already fitted once (see :func:`_warm_up`)
_WARMED: set[tuple[str, str]] = set()

#: samples of the warm-up fit
WARM_UP_SAMPLES = 128


def _warm_up(spec: CellSpec, model, opt) -> None:
    """Fit the cell's model with its optimizer once on the first samples of its first capture.

    The first fit of a model/optimizer pair in a process pays one-off costs — loading the compiled
    kernels from numba's cache, lazy imports — that are no part of the identification time the
    runtime table reports (002 Table 2); without this, whichever condition a worker happens to
    fit first looks several times slower. Its result is discarded; errors are left to the real fit.
    """
    key = (spec.model, spec.optimizer)
    if key in _WARMED:
        return
    _WARMED.add(key)
    c = spec.captures[0]
    n = min(c.n, WARM_UP_SAMPLES)
    short = replace(c, t=c.t[:n], u=c.u[:n], y=None if c.y is None else c.y[:n])
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            fit_captures([short], model, opt, seed=spec.seed, polish=spec.polish, bounds=spec.bounds)
    except Exception:  # noqa: BLE001 - a warm-up only; the real fit reports any error
        pass


def run_cell(spec: CellSpec) -> CellResult:
    """Fit one cell (R runs) and summarize it; a :class:`HystfitError` becomes a CellResult with
    ``error`` set (other exceptions are crashes, retried by the executor).

    Run times exclude the one-off start-up costs of the process (:func:`_warm_up`).
    """
    a, f = spec.key
    t0 = time.perf_counter()
    try:
        model = make_model(spec.model, spec.model_options)
        opt = make_optimizer(optimizer_registry.get(spec.optimizer), spec.optimizer_options)
        _warm_up(spec, model, opt)
        fit = fit_captures(spec.captures, model, opt, seed=spec.seed, cell=spec.index, runs=spec.runs,
                           polish=spec.polish, label=spec.label, condition=spec.key, bounds=spec.bounds,
                           mape_floor=spec.mape_floor)
        objective = Objective(fit.model, [Series(c.u, c.y, c.dt, c.warmup_samples) for c in spec.captures])
        sum_y2 = float(sum(np.dot(c.y[c.warmup_samples:], c.y[c.warmup_samples:]) for c in spec.captures))
        to_j = objective.n_total / sum_y2 if sum_y2 > 0 else np.nan  # MSE → J = Σe²/Σy² (004 eq. 16)
        runs = []
        for r in fit.runs:
            preds = objective.predict(r.x)
            m = compute_metrics_pooled([(c.y[c.warmup_samples:], p[c.warmup_samples:])
                                        for c, p in zip(spec.captures, preds)], fit.unit, mape_floor=spec.mape_floor)
            runs.append(RunMetrics(r.run, r.seed, r.fun, r.fun * to_j, m, r.wall_time_s, r.nfev,
                                   np.asarray(r.result.history_best), float(r.result.fun), float(r.result.fun) * to_j,
                                   int(r.result.nfev)))
        return CellResult(spec.model, spec.optimizer, a, f, spec.label, len(fit.params), tuple(runs), fit.best_run,
                          fit.theta, tuple(p.name for p in fit.params), tuple(fit.predictions),
                          time.perf_counter() - t0)
    except HystfitError as exc:  # the model cannot be fitted to these captures: recorded in the cell
        err = str(exc)
    # any other exception is a crash: the executor retries the cell once, then records it (_failed_cell)
    return CellResult(spec.model, spec.optimizer, a, f, spec.label, 0, error=err,
                      runtime_s=time.perf_counter() - t0)


def _cell_job(shared: tuple[tuple[Capture, ...], ...], spec: CellSpec) -> CellResult:
    """Executor entry point: the cell with its captures taken from the shared ones."""
    return run_cell(replace(spec, captures=shared[spec.condition]))


def cell_store_key(spec: CellSpec, settings: Mapping) -> str:
    """What a compare cell's numbers depend on (see :mod:`hystfit.cells`)."""
    return cell_key("compare", captures=spec.captures, model=spec.model, model_options=spec.model_options,
                    optimizer=spec.optimizer, optimizer_settings=settings, bounds=spec.bounds, seed=spec.seed,
                    index=spec.index, runs=spec.runs, polish=spec.polish, condition=list(spec.key),
                    mape_floor=spec.mape_floor)


def scoped_options(items: Mapping[str, object], valid: Mapping[str, Sequence[str]], flag: str) -> dict[str, dict]:
    """Spread ``KEY=VALUE`` items over several models or optimizers, as ``compare`` takes them.

    ``KEY`` applies to every name in ``valid`` (name → the keys it accepts) and must be valid for
    all of them; ``NAME.KEY`` applies to that name only and wins over an unscoped ``KEY``. A key
    that some name accepts as written (a block's ``creep.tau_s`` of ``pi+creep``) is unscoped.
    Unknown scopes and unscoped keys some name lacks are ConfigErrors naming ``flag`` and the fix.
    """
    out: dict[str, dict] = {n: {} for n in valid}
    scoped = []
    for key, val in items.items():
        scope, dot, name = key.partition(".")
        if dot and not any(key in keys for keys in valid.values()):
            if scope not in valid:
                raise ConfigError(f"{flag} {key}: {scope!r} is not one of {', '.join(valid)}; "
                                  f"write NAME.KEY=VALUE with a NAME from that list")
            scoped.append((scope, name, val))
            continue
        lacking = [n for n, keys in valid.items() if key not in keys]
        if lacking:
            having = [n for n in valid if n not in lacking]
            fix = (f"scope it, e.g. {flag} {having[0]}.{key}=…" if having
                   else f"valid for {lacking[0]}: {', '.join(valid[lacking[0]]) or 'none'}")
            raise ConfigError(f"{flag} {key}: {lacking[0]!r} has no {key!r}; {fix}")
        for n in valid:
            out[n][key] = val
    for scope, name, val in scoped:
        out[scope][name] = val
    return out


def _prepare_shared_structure(captures, model_names, model_options: dict, store=None, resume: bool = False,
                              jobs: int | None = None) -> list[str]:
    """Identify every model's shared structure (a Hammerstein model's stage) once from all captures
    and hand it to the cells as fixed options (``model_options`` updated in place); the notes say
    how it was found. A model that fails here fails in its cells, with its own message. The models
    are prepared side by side (:func:`~hystfit.parallel.fork_map`, up to ``jobs`` processes): pi2's
    stage and the Hammerstein model's linear part no longer wait for each other."""

    def prepare(i: int) -> tuple[dict, str | None] | None:
        m = model_names[i]
        try:
            base = make_model(m, model_options[m])
            prepared = prepare_shared(base, captures, store, resume)
        except HystfitError:
            return None
        return (prepared.as_options(), prepared.structure_summary()) if prepared != base else None

    notes = []
    for m, done in zip(model_names, fork_map(prepare, len(model_names), jobs)):
        if done is not None:
            model_options[m] = done[0]
            if done[1] is not None:
                notes.append(f"`{m}`: {done[1]}")
    return notes


def _shares_structure(name: str, options: dict) -> bool:
    """Whether the model may have shared structure to identify; False for a model that cannot be
    built with these options (it fails in its cells, with its own message, as when preparing)."""
    try:
        return make_model(name, options).shares_structure()
    except HystfitError:
        return False


class _BackgroundPreparation:
    """:func:`_prepare_shared_structure` of some models in a thread of this process, while the
    other models' cells run on the executor's workers; :meth:`result` waits and returns its notes
    (``model_options`` is updated in place then, as the direct call does). The models are prepared
    one after another: a thread must not fork (``fork_map``) beside the executor's threads."""

    def __init__(self, captures, model_names, model_options: dict, store, resume: bool) -> None:
        import threading

        self._options = {m: dict(model_options[m]) for m in model_names}
        self._model_options = model_options
        self._notes: list[str] = []
        self._error: BaseException | None = None

        def work() -> None:
            try:
                self._notes = _prepare_shared_structure(captures, list(model_names), self._options, store, resume,
                                                        jobs=1)
            except BaseException as exc:  # noqa: BLE001 - raised again by result(), in the caller's thread
                self._error = exc

        self._thread = threading.Thread(target=work, name="hystfit-prepare", daemon=True)
        self._thread.start()

    def wait(self) -> None:
        self._thread.join()

    def result(self) -> list[str]:
        self.wait()
        if self._error is not None:
            raise self._error
        self._model_options.update(self._options)
        return self._notes


def _check_bounds(captures, model_names, model_options: dict, bounds: dict) -> None:
    """Bound names are checked before any fit, as identify does: a typo is exit 2, not failed cells."""
    if not all(c.y is not None for c in captures):
        return
    scale = DataScale.from_arrays([c.u for c in captures], [c.y for c in captures], [c.dt for c in captures],
                                  [c.frequency_Hz for c in captures])
    for m in model_names:
        if bounds[m]:
            model = make_model(m, model_options[m]).prepare(captures).adapt(scale)
            try:
                apply_bound_overrides(model.params(scale), bounds[m])
            except ConfigError as exc:
                raise ConfigError(f"model {m!r}: {exc} (a bound for one model only: --bounds MODEL.NAME=LOWER:UPPER)") from None


def startup_steps(*, jobs: int | None = None, executor: Executor | None = None) -> tuple:
    """What :func:`compare` will start first, as steps a caller can run while it reads the captures
    (``hystfit.io.load_captures(..., ahead=...)``): the local pool's fork server
    (:func:`hystfit.parallel.start_pool_server`), unless the cells run here or elsewhere."""
    from .parallel import start_pool_server

    return (start_pool_server,) if executor is None and jobs != 1 else ()


@one_blas_thread
def compare(captures: Sequence[Capture], model_names: Sequence[str], optimizer_names: Sequence[str], *,
            runs: int = 1, seed: int = 0, jobs: int | None = None, polish: bool = True,
            model_options: Mapping[str, dict] | None = None, optimizer_options: Mapping[str, dict] | None = None,
            bounds: Mapping[str, Mapping[str, tuple[float, float]]] | None = None, global_fit: bool = False,
            progress: Progress = None, mape_floor: float = 0.01, executor: Executor | None = None,
            store: CellStore | None = None, resume: bool = False) -> CompareResult:
    """Run the cross product models × optimizers × conditions with ``runs`` runs per cell.

    ``model_options`` / ``optimizer_options`` / ``bounds`` are per model or optimizer name (see
    :func:`scoped_options` for spreading command-line items). Every optimizer is built (and its
    options validated) before any fit; its settings, which fix its budget, are recorded in the
    result. ``global_fit`` fits one parameter set to all captures instead of one per condition.

    ``executor`` runs the cells (default: a local pool of ``jobs`` processes); with a ``store``
    every finished cell is stored, and ``resume`` reuses the cells already stored there.
    """
    check_seed(seed)
    mape_floor = check_mape_floor(mape_floor)  # MAPE/SMAPE floor (hystfit.metrics; 0: every sample, as 002)
    if not model_names or not optimizer_names:
        raise ConfigError("compare needs at least one model and one optimizer")
    for m in model_names:
        make_model(m)  # an unknown model or block: one line, exit 2
    optimizer_options = {o: dict((optimizer_options or {}).get(o, {})) for o in optimizer_names}
    settings = {o: make_optimizer(optimizer_registry.get(o), optimizer_options[o]).settings() for o in optimizer_names}
    bounds = {m: dict((bounds or {}).get(m, {})) for m in model_names}
    if runs < 1:
        raise ConfigError(f"--runs must be at least 1, got {runs}")
    units = {c.y_unit for c in captures}
    if len(units) != 1:
        raise ConfigError(f"captures have different output units {sorted(units)}; convert them to one unit first")
    groups, labels = _condition_groups(captures, global_fit)
    conds = tuple((k, labels[k]) for k in groups)
    own = executor is None
    executor = LocalExecutor(jobs) if own else executor
    model_options = {m: dict((model_options or {}).get(m, {})) for m in model_names}
    try:
        plan = _preparation_plan(captures, model_names, model_options, bounds, executor, store, resume, jobs)

        def cell_specs() -> list[CellSpec]:
            return _cell_specs(groups, labels, model_names, optimizer_names, runs, seed, polish, model_options,
                               optimizer_options, bounds, mape_floor)

        specs = cell_specs()  # the later models' cells are specified again once their structure is known
        if progress:
            progress("start", {"total": len(specs)})
        batches = _CellBatches(executor, tuple(tuple(caps) for caps in groups.values()), settings, store, resume,
                               progress, len(specs))
        specs, notes = _run_cells_around_preparation(batches, specs, cell_specs, plan, captures, model_options,
                                                     store, resume)
    finally:
        if own:
            executor.close()
    cells = tuple(_failed_cell(s, r) if isinstance(r, CellFailed) else r for s, r in zip(specs, batches.out))
    stats = batches.stats
    # failed: crashed, or recorded an error (e.g. a model that cannot fit); a reused cell counts as reused
    stats.failed = sum(not c.ok for i, c in enumerate(cells) if i not in batches.reused)
    stats.computed = len(cells) - stats.reused - stats.failed
    return CompareResult(tuple(model_names), tuple(optimizer_names), conds,
                         {lab: tuple(groups[k]) for k, lab in conds}, cells, runs, seed, units.pop(),
                         executor.workers, polish, tuple(notes), settings, bounds, global_fit,
                         tuple(o for o in optimizer_names if optimizer_registry.get(o).polishes_itself), stats,
                         executor.name)


def _condition_groups(captures, global_fit: bool) -> tuple[dict, dict]:
    """The captures of each cell's condition (one group of all captures with ``global_fit``), and
    each condition's label."""
    if global_fit:
        amps = sorted({c.amplitude_V for c in captures})
        freqs = sorted({c.frequency_Hz for c in captures})
        key = (amps[0], freqs[0]) if len(amps) * len(freqs) == 1 else (float("nan"), float("nan"))
        return {key: list(captures)}, {key: "global"}
    groups = group_by_condition(captures)
    return groups, {k: condition_label(k) for k in groups}


def _cell_specs(groups, labels, model_names, optimizer_names, runs, seed, polish, model_options, optimizer_options,
                bounds, mape_floor) -> list[CellSpec]:
    """Every cell, condition by condition, model by model, optimizer by optimizer."""
    specs = []
    for ci, (key, caps) in enumerate(groups.items()):
        for m in model_names:
            for oi, o in enumerate(optimizer_names):
                # the cell index (for seeds) depends on the condition and optimizer only, so every
                # model sees the same seeds on a condition, and the numbers never depend on --jobs
                specs.append(CellSpec(ci * 1000 + oi, m, o, key, labels[key], tuple(caps), runs, seed, polish,
                                      dict(model_options.get(m, {})), dict(optimizer_options[o]), dict(bounds[m]),
                                      mape_floor, ci))
    return specs


@dataclass(frozen=True)
class _PreparationPlan:
    """Which models' cells wait for shared structure (``later``), and whether it is identified
    beside the other cells (``overlap``) or was identified already (``notes``)."""

    later: tuple[str, ...]
    overlap: bool
    notes: tuple[str, ...] = ()


def _preparation_plan(captures, model_names, model_options: dict, bounds: dict, executor: Executor, store,
                      resume: bool, jobs: int | None) -> _PreparationPlan:
    """Structure shared by all conditions (e.g. a Hammerstein model's stage dynamics) is identified
    once from all captures and handed to every cell as fixed structure. With cells in worker
    processes, the models without any (most) do not wait for it: their cells run while it is
    identified in a thread, and the cells of the models with it follow on the same workers. A bound
    override on such a model is checked against the prepared model first (a typo is exit 2 before
    any fit), so then the structure is identified here, before any cell, as it is when there is
    nothing to overlap. Bounds of the models that do not wait are checked here in every case."""
    later = tuple(m for m in model_names if _shares_structure(m, model_options[m]))
    overlap = (executor.workers > 1 and bool(later) and len(later) < len(model_names)
               and not any(bounds[m] for m in later))
    if overlap:
        _check_bounds(captures, [m for m in model_names if m not in later], model_options, bounds)
        return _PreparationPlan(later, True)
    notes = _prepare_shared_structure(captures, model_names, model_options, store, resume, jobs)
    _check_bounds(captures, model_names, model_options, bounds)
    return _PreparationPlan((), False, tuple(notes))


class _CellBatches:
    """Batches of a compare's cells on one executor: results by cell index (``out``), the indices
    reused from the store (``reused``), counts (``stats``), progress reported as cells finish."""

    def __init__(self, executor: Executor, shared: tuple, settings: Mapping, store, resume: bool,
                 progress: Progress, n: int) -> None:
        self.executor, self.shared, self.settings = executor, shared, settings
        self.store, self.resume, self.progress = store, resume, progress
        self.out: list = [None] * n
        self.reused: set[int] = set()
        self.stats = CellStats()

    def run(self, specs: Sequence[CellSpec], indices: list[int]) -> None:
        keys = ([cell_store_key(specs[i], self.settings[specs[i].optimizer]) for i in indices]
                if self.store is not None else None)

        def done(k: int, res, reused: bool) -> None:
            i = indices[k]
            if reused:
                self.reused.add(i)
            if self.progress:
                s = specs[i]
                self.progress("advance", {"label": f"{s.model}/{s.optimizer}/{s.label}", "reused": reused,
                                          "failed": isinstance(res, CellFailed) or not res.ok})

        got = run_cells(_cell_job, [replace(specs[i], captures=()) for i in indices], shared=self.shared,
                        executor=self.executor, store=self.store, keys=keys, resume=self.resume, on_done=done,
                        stats=self.stats)
        for i, r in zip(indices, got):
            self.out[i] = r


def _run_cells_around_preparation(batches: _CellBatches, specs: list[CellSpec], cell_specs: Callable,
                                  plan: _PreparationPlan, captures, model_options: dict, store,
                                  resume: bool) -> tuple[list[CellSpec], tuple[str, ...]]:
    """Every cell, with the shared structure identified beside the first batch when ``plan`` says
    so; returns the final cell specifications and the notes on the structure."""
    first = [i for i, s in enumerate(specs) if s.model not in plan.later]
    preparing = None
    notes = plan.notes
    try:
        with batches.executor.holding():
            if plan.overlap:
                # the workers start (their environment set) and numba loads here before the thread
                # runs: nothing the thread reads changes under it (numba reads its thread count
                # from the environment when it is imported)
                batches.executor.start(batches.shared, len(first))
                _load_numba()
                preparing = _BackgroundPreparation(captures, plan.later, model_options, store, resume)
            batches.run(specs, first)
            if preparing is not None:
                notes = tuple(preparing.result())
                specs = cell_specs()
                batches.run(specs, [i for i, s in enumerate(specs) if s.model in plan.later])
    except BaseException as exc:
        # a failed compare leaves nothing running behind it (the thread may write the store);
        # Ctrl-C does not wait for it: the thread is a daemon and the command ends
        if preparing is not None and not isinstance(exc, KeyboardInterrupt):
            preparing.wait()
        raise
    return specs, notes


def _failed_cell(spec: CellSpec, failure: CellFailed) -> CellResult:
    """A cell whose every attempt crashed (or whose worker was lost), recorded with its error."""
    return CellResult(spec.model, spec.optimizer, spec.key[0], spec.key[1], spec.label, 0,
                      error=f"{failure.error} (after {failure.attempts} attempts)")


# ----------------------------------------------------------------------------------------------
# Ranking: which model (per optimizer) and which optimizer (per model) is ahead, and whether the
# difference to the next one holds beyond the run-to-run spread. report/compare_report renders it.

#: significance level of the neighbour tests (two-sided)
RANK_ALPHA = 0.05
#: paired samples: the Wilcoxon signed-rank test needs at least this many conditions
WILCOXON_MIN_CONDITIONS = 6
#: unpaired samples: the Mann–Whitney U test needs at least this many runs per group
MANN_WHITNEY_MIN_RUNS = 3


def _json_number(v):
    return None if isinstance(v, float) and v != v else v


@dataclass(frozen=True)
class NeighbourTest:
    """How a ranked entry (the lower mean) compares with the next one, ``other``.

    ``verdict`` is one of: ``tied`` (means equal to 1e-6 relative); paired samples (one value per
    condition): ``consistently_below`` / ``not_consistently_below`` (Wilcoxon signed-rank over
    conditions, ``p_value``) or ``lower_count`` (too few conditions for the test: only
    ``lower_at`` of ``n_conditions``); unpaired samples (values over runs): ``better`` /
    ``not_distinguishable`` (two-sided Mann–Whitney U, ``p_value``) where enough runs let it reach
    the level (:func:`mann_whitney_can_pass`), else, from two runs, ``within_spread`` /
    ``beyond_spread`` (``gap`` against ``two_sigma``, twice the larger standard deviation), with one
    run ``unknown_spread``. ``gap`` and ``two_sigma`` are in the
    ranking's unit; NaN/None where they do not apply.
    """

    other: str
    verdict: str
    gap: float
    test: str = ""  # "wilcoxon", "mann_whitney" or "" (no test)
    p_value: float = float("nan")
    lower_at: int | None = None  # paired: conditions where this entry is lower
    n_conditions: int | None = None
    two_sigma: float = float("nan")
    #: repeated runs: the same two entries paired by condition (each condition's mean over runs),
    #: :func:`by_condition` — what the runs' spread hides when one is lower at every condition
    by_condition: dict | None = None

    def to_dict(self) -> dict:
        return {k: _json_number(getattr(self, k)) for k in self.__dataclass_fields__}


def by_condition(a: np.ndarray, b: np.ndarray, alpha: float = RANK_ALPHA) -> dict:
    """Entries ``a`` (the lower mean) and ``b`` paired by condition (per condition, the mean over
    runs): at how many conditions ``a`` is lower, and from :data:`WILCOXON_MIN_CONDITIONS` conditions
    the Wilcoxon signed-rank test (``p_value``, ``consistently_below``). A blind test's optimizer
    compare called the search J of `auto` and `pso` "within run-to-run spread" (3 runs × 4
    conditions) where `pso` was worse in every one of the 12 runs × conditions."""
    from scipy.stats import wilcoxon

    d = np.asarray(b, float) - np.asarray(a, float)
    out = {"lower_at": int(np.sum(d > 0)), "n_conditions": int(d.size), "test": "", "p_value": None,
           "consistently_below": None}
    if d.size >= WILCOXON_MIN_CONDITIONS and np.any(d != 0):
        p = float(wilcoxon(a, b).pvalue)
        # two-sided: significant in either direction; below only where the typical difference is
        # (a review's find: lower at 2 of 20 conditions, much lower there, was "consistently below")
        out.update(test="wilcoxon", p_value=_json_number(p), consistently_below=bool(p < alpha and np.median(d) > 0))
    return out


@dataclass(frozen=True)
class RankRow:
    """One ranked entry: its place (1 = lowest mean), the mean (and for models the median of the
    best-run RMSE over conditions) in the ranking's unit, and the test against the next entry."""

    position: int
    name: str
    mean: float
    n_samples: int
    median: float | None = None
    versus_next: NeighbourTest | None = None

    def to_dict(self) -> dict:
        return {"position": self.position, "name": self.name, "mean": _json_number(self.mean),
                "median": _json_number(self.median), "n_samples": self.n_samples,
                "versus_next": self.versus_next.to_dict() if self.versus_next is not None else None}


@dataclass(frozen=True)
class Ranking:
    """One ranking: the models with one optimizer (``kind="models"``, by the RMSE in ``unit``) or
    the optimizers on one model (``kind="optimizers"``, by the J of the search alone — the final J
    when no polish follows, ``polished`` False).

    ``paired``: the samples are one value per condition (single runs), else one per run (the
    metric averaged over conditions). ``not_ranked``: entries that failed on some condition.
    ``final_j_spread_pct``: optimizers with a polish, how far apart their mean final J are (% of
    the lowest).
    """

    kind: str
    within: str
    metric: str  # "rmse" or "search_j"
    unit: str  # of mean, median, gap ("" for J)
    n_conditions: int
    runs: int
    paired: bool
    rows: tuple[RankRow, ...]
    not_ranked: tuple[str, ...] = ()
    polished: bool = False
    final_j_spread_pct: float | None = None

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d.update(rows=[r.to_dict() for r in self.rows], not_ranked=list(self.not_ranked),
                 final_j_spread_pct=_json_number(self.final_j_spread_pct))
        return d


@dataclass(frozen=True)
class CompareRanking:
    """The result of :func:`rank`: the model rankings (one per optimizer, when several models were
    compared), then the optimizer rankings (one per model, when several optimizers were)."""

    groups: tuple[Ranking, ...]
    alpha: float = RANK_ALPHA

    def to_dict(self) -> dict:
        return {"alpha": self.alpha, "groups": [g.to_dict() for g in self.groups]}


def mann_whitney_can_pass(n1: int, n2: int, alpha: float = RANK_ALPHA) -> bool:
    """Whether a two-sided Mann–Whitney U test of ``n1`` against ``n2`` runs can give p < ``alpha`` at
    all: its smallest p, for two groups that do not overlap, is 2 / C(n1 + n2, n1) — 0.1 for 3 runs
    against 3, so with ``--runs 3`` every pair was "not distinguishable", even runs that all gave
    the same RMSE 27 % apart (a blind test's compare). 4 against 4 can (0.029)."""
    return 2.0 / math.comb(int(n1) + int(n2), int(n1)) < alpha


def neighbour_test(a: np.ndarray, b: np.ndarray, paired: bool, other: str,
                   alpha: float = RANK_ALPHA) -> NeighbourTest:
    """Compare group ``a`` (the lower mean) with the next one ``b`` (see :class:`NeighbourTest`)."""
    from scipy.stats import mannwhitneyu, wilcoxon

    gap = float(np.mean(b) - np.mean(a))
    if gap <= 1e-6 * max(abs(float(np.mean(a))), 1e-300):
        return NeighbourTest(other, "tied", gap)
    if paired:
        d = b - a
        lower = int(np.sum(d > 0))
        if d.size >= WILCOXON_MIN_CONDITIONS and np.any(d != 0):
            p = float(wilcoxon(a, b).pvalue)  # two-sided: "below" only where the typical difference says so
            verdict = "consistently_below" if p < alpha and np.median(d) > 0 else "not_consistently_below"
            return NeighbourTest(other, verdict, gap, "wilcoxon", p, lower, int(d.size))
        return NeighbourTest(other, "lower_count", gap, lower_at=lower, n_conditions=int(d.size))
    if min(a.size, b.size) >= MANN_WHITNEY_MIN_RUNS and mann_whitney_can_pass(a.size, b.size, alpha):
        p = float(mannwhitneyu(a, b, alternative="two-sided").pvalue)
        return NeighbourTest(other, "better" if p < alpha else "not_distinguishable", gap, "mann_whitney", p)
    if min(a.size, b.size) >= 2:  # too few runs for the test to reach alpha at all: the spread decides
        two_sigma = 2 * max(np.std(a, ddof=1), np.std(b, ddof=1))
        return NeighbourTest(other, "within_spread" if gap <= two_sigma else "beyond_spread", gap,
                             two_sigma=float(two_sigma))
    return NeighbourTest(other, "unknown_spread", gap)


def _ranked_rows(names: list[str], samples: list[np.ndarray], paired: bool, alpha: float,
                 medians: list[float] | None = None, conditions: list[np.ndarray] | None = None
                 ) -> tuple[RankRow, ...]:
    """Order by the mean of each group's samples (stable); test each against the next, and with
    ``conditions`` (repeated runs: per entry, each condition's mean over runs) compare the two
    condition by condition too (:func:`by_condition`)."""
    means = [float(np.mean(s)) for s in samples]
    order = np.argsort(means, kind="stable")
    rows = []
    for pos, i in enumerate(order):
        test = None
        if pos + 1 < len(order):
            j = order[pos + 1]
            test = neighbour_test(np.asarray(samples[i], float), np.asarray(samples[j], float), paired, names[j],
                                  alpha)
            if conditions is not None and test.verdict != "tied" and len(conditions[i]) > 1:
                test = replace(test, by_condition=by_condition(conditions[i], conditions[j], alpha))
        rows.append(RankRow(pos + 1, names[i], means[i], len(samples[i]),
                            medians[i] if medians is not None else None, test))
    return tuple(rows)


def _complete_cells(res: CompareResult, model: str, optimizer: str) -> list[CellResult] | None:
    """The successful cells of (model, optimizer), None unless every condition succeeded."""
    cells = [c for c in res.cells if c.model == model and c.optimizer == optimizer and c.ok]
    return cells if len(cells) == len(res.conditions) else None


def _model_ranking(res: CompareResult, optimizer: str, alpha: float) -> Ranking:
    """The models with ``optimizer`` by RMSE: per run the RMSE averaged over conditions, or with
    single runs the best RMSE per condition (paired across models by condition)."""
    u = res.unit
    names, samples, medians, per_condition = [], [], [], []
    for m in res.models:
        cells = _complete_cells(res, m, optimizer)
        if cells is None:
            continue
        names.append(m)
        best = np.array([c.best.metrics[f"rmse_{u}"] for c in cells])
        medians.append(float(np.median(best)))
        if res.runs > 1:
            nr = min(len(c.runs) for c in cells)
            samples.append(np.array([np.mean([c.runs[r].metrics[f"rmse_{u}"] for c in cells]) for r in range(nr)]))
            per_condition.append(np.array([np.mean([r.metrics[f"rmse_{u}"] for r in c.runs[:nr]]) for c in cells]))
        else:
            samples.append(best)
    return Ranking("models", optimizer, "rmse", u, len(res.conditions), res.runs, res.runs == 1,
                   _ranked_rows(names, samples, res.runs == 1, alpha, medians, per_condition if res.runs > 1 else None),
                   tuple(m for m in res.models if m not in names))


def _optimizer_ranking(res: CompareResult, model: str, alpha: float) -> Ranking:
    """The optimizers on ``model`` by the search's J per run (averaged over conditions); with a
    polish after the search, also how far apart the mean final J are."""
    polished = res.polish and any(o not in res.self_polishing for o in res.optimizers)
    names, samples, per_condition = [], [], []
    for o in res.optimizers:
        cells = _complete_cells(res, model, o)
        if cells is None:
            continue
        names.append(o)
        nr = min(len(c.runs) for c in cells)
        samples.append(np.array([np.mean([c.runs[r].search_j for c in cells]) for r in range(nr)]))
        per_condition.append(np.array([np.mean([r.search_j for r in c.runs[:nr]]) for c in cells]))
    spread = None
    if polished and names:
        fin = [np.mean([r.j for c in res.cells if c.model == model and c.optimizer == o and c.ok for r in c.runs])
               for o in names]
        spread = float(100 * (max(fin) - min(fin)) / min(fin)) if min(fin) > 0 else float("nan")
    return Ranking("optimizers", model, "search_j", "", len(res.conditions), res.runs, False,
                   _ranked_rows(names, samples, False, alpha, conditions=per_condition),
                   tuple(o for o in res.optimizers if o not in names),
                   polished, spread)


def rank(result: CompareResult, *, alpha: float = RANK_ALPHA) -> CompareRanking:
    """Rank the models per optimizer and the optimizers per model of a comparison.

    Models (when more than one was compared) are ranked by RMSE: with repeated runs by the mean
    over runs of the RMSE averaged over conditions, neighbours compared by the Mann–Whitney U
    test over runs; with single runs by the mean over conditions of the best run's RMSE,
    neighbours compared condition by condition (Wilcoxon signed-rank test from 6 conditions).
    Optimizers (when more than one was compared) are ranked by the mean J of their search over
    runs, averaged over conditions. A model or optimizer that failed on some condition is listed
    in ``not_ranked``. ``alpha`` is the significance level of the tests.

    Returns
    -------
    CompareRanking
        Frozen; ``to_dict()`` gives its JSON form (NaN as None).
    """
    groups = []
    if len(result.models) > 1:
        groups += [_model_ranking(result, o, alpha) for o in result.optimizers]
    if len(result.optimizers) > 1:
        groups += [_optimizer_ranking(result, m, alpha) for m in result.models]
    return CompareRanking(tuple(groups), alpha)
