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

import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Optional, Sequence

import numpy as np

from .capture import Capture
from .cells import CellStore, cell_key
from .conditions import condition_label, group_by_condition
from .errors import ConfigError, HystfitError
from .identify import check_seed, fit_captures, prepare_shared
from .metrics import check_mape_floor, compute_metrics_pooled
from .objective import Objective, Series
from .parallel import CellFailed, CellStats, Executor, LocalExecutor, run_cells
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


def _prepare_shared_structure(captures, model_names, model_options: dict) -> list[str]:
    """Identify every model's shared structure (a Hammerstein model's stage) once from all captures
    and hand it to the cells as fixed options (``model_options`` updated in place); the notes say
    how it was found. A model that fails here fails in its cells, with its own message."""
    notes = []
    for m in model_names:
        try:
            base = make_model(m, model_options[m])
            prepared = prepare_shared(base, captures)
            if prepared is not base:
                model_options[m] = prepared.as_options()
                summary = getattr(prepared, "structure_summary", None)
                if summary is not None:
                    notes.append(f"`{m}`: {summary()}")
        except HystfitError:
            pass
    return notes


def _check_bounds(captures, model_names, model_options: dict, bounds: dict) -> None:
    """Bound names are checked before any fit, as identify does: a typo is exit 2, not failed cells."""
    if not all(c.y is not None for c in captures):
        return
    scale = DataScale.from_arrays([c.u for c in captures], [c.y for c in captures], [c.dt for c in captures])
    for m in model_names:
        if bounds[m]:
            model = make_model(m, model_options[m]).prepare(captures).adapt(scale)
            try:
                apply_bound_overrides(model.params(scale), bounds[m])
            except ConfigError as exc:
                raise ConfigError(f"model {m!r}: {exc} (a bound for one model only: --bounds MODEL.NAME=LOWER:UPPER)") from None


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
    if global_fit:
        amps = sorted({c.amplitude_V for c in captures})
        freqs = sorted({c.frequency_Hz for c in captures})
        key = (amps[0], freqs[0]) if len(amps) * len(freqs) == 1 else (float("nan"), float("nan"))
        groups, labels = {key: list(captures)}, {key: "global"}
    else:
        groups = group_by_condition(captures)
        labels = {k: condition_label(k) for k in groups}
    conds = tuple((k, labels[k]) for k in groups)
    # structure shared by all conditions (e.g. a Hammerstein model's stage dynamics) is identified
    # once from all captures here and handed to every cell as fixed structure
    model_options = {m: dict((model_options or {}).get(m, {})) for m in model_names}
    notes = _prepare_shared_structure(captures, model_names, model_options)
    _check_bounds(captures, model_names, model_options, bounds)
    specs = []
    for ci, (key, caps) in enumerate(groups.items()):
        for mi, m in enumerate(model_names):
            for oi, o in enumerate(optimizer_names):
                # the cell index (for seeds) depends on the condition and optimizer only, so every
                # model sees the same seeds on a condition, and the numbers never depend on --jobs
                specs.append(CellSpec(ci * 1000 + oi, m, o, key, labels[key], tuple(caps), runs, seed, polish,
                                      dict((model_options or {}).get(m, {})), dict(optimizer_options[o]),
                                      dict(bounds[m]), mape_floor, ci))
    keys = [cell_store_key(s, settings[s.optimizer]) for s in specs] if store is not None else None
    if progress:
        progress("start", {"total": len(specs)})

    reused_cells = set()

    def done(i: int, res, reused: bool) -> None:
        if reused:
            reused_cells.add(i)
        if progress:
            s = specs[i]
            progress("advance", {"label": f"{s.model}/{s.optimizer}/{s.label}", "reused": reused,
                                 "failed": isinstance(res, CellFailed) or not res.ok})

    own = executor is None
    executor = LocalExecutor(jobs) if own else executor
    stats = CellStats()
    shared = tuple(tuple(caps) for caps in groups.values())
    try:
        out = run_cells(_cell_job, [replace(s, captures=()) for s in specs], shared=shared, executor=executor,
                        store=store, keys=keys, resume=resume, on_done=done, stats=stats)
    finally:
        if own:
            executor.close()
    cells = tuple(_failed_cell(s, r) if isinstance(r, CellFailed) else r for s, r in zip(specs, out))
    # failed: crashed, or recorded an error (e.g. a model that cannot fit); a reused cell counts as reused
    stats.failed = sum(not c.ok for i, c in enumerate(cells) if i not in reused_cells)
    stats.computed = len(cells) - stats.reused - stats.failed
    return CompareResult(tuple(model_names), tuple(optimizer_names), conds,
                         {lab: tuple(groups[k]) for k, lab in conds}, cells, runs, seed, units.pop(),
                         executor.workers, polish, tuple(notes), settings, bounds, global_fit,
                         tuple(o for o in optimizer_names if optimizer_registry.get(o).polishes_itself), stats,
                         executor.name)


def _failed_cell(spec: CellSpec, failure: CellFailed) -> CellResult:
    """A cell whose every attempt crashed (or whose worker was lost), recorded with its error."""
    return CellResult(spec.model, spec.optimizer, spec.key[0], spec.key[1], spec.label, 0,
                      error=f"{failure.error} (after {failure.attempts} attempts)")
