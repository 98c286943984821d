"""Comparison orchestration: models × optimizers × conditions (× runs).

Each *cell* (one model, one optimizer, one condition) is an independent job: R seeded runs of
:func:`hystfit.identify.fit_captures`, summarized into a picklable :class:`CellResult`. Cells run
serially or in a process pool (``jobs``); the numbers do not depend on ``jobs`` because every
run's seed is derived from (seed, cell index, run) and the cell order is fixed. A cell that fails
is recorded with its error and the comparison goes on.
"""

from __future__ import annotations

import time
import traceback
import warnings
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Optional, Sequence

import numpy as np

from .capture import Capture
from .conditions import condition_label, group_by_condition
from .errors import ConfigError, HystfitError
from .identify import check_seed, fit_captures
from .metrics import compute_metrics_pooled
from .objective import Objective, Series
from .parallel import default_jobs, run_jobs
from .registry import models as model_registry
from .registry import optimizers as optimizer_registry
from .setup import make_model, make_optimizer

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
            fit_captures([short], model, opt, seed=spec.seed, polish=spec.polish)
    except Exception:  # noqa: BLE001 - a warm-up only; the real fit reports any error
        pass


def run_cell(spec: CellSpec) -> CellResult:
    """Fit one cell (R runs) and summarize it; errors become a CellResult with ``error`` set.

    Run times exclude the one-off start-up costs of the process (:func:`_warm_up`).
    """
    a, f = spec.key
    t0 = time.perf_counter()
    try:
        model = make_model(model_registry.get(spec.model), spec.model_options)
        opt = make_optimizer(optimizer_registry.get(spec.optimizer), spec.optimizer_options)
        _warm_up(spec, model, opt)
        fit = fit_captures(spec.captures, model, opt, seed=spec.seed, cell=spec.index, runs=spec.runs,
                           polish=spec.polish, label=spec.label, condition=spec.key)
        objective = Objective(fit.model, [Series(c.u, c.y, c.dt, c.warmup_samples) for c in spec.captures])
        sum_y2 = float(sum(np.dot(c.y[c.warmup_samples:], c.y[c.warmup_samples:]) for c in spec.captures))
        to_j = objective.n_total / sum_y2 if sum_y2 > 0 else np.nan  # MSE → J = Σe²/Σy² (004 eq. 16)
        runs = []
        for r in fit.runs:
            preds = objective.predict(r.x)
            m = compute_metrics_pooled([(c.y[c.warmup_samples:], p[c.warmup_samples:])
                                        for c, p in zip(spec.captures, preds)], fit.unit)
            runs.append(RunMetrics(r.run, r.seed, r.fun, r.fun * to_j, m, r.wall_time_s, r.nfev,
                                   np.asarray(r.result.history_best), float(r.result.fun), float(r.result.fun) * to_j))
        return CellResult(spec.model, spec.optimizer, a, f, spec.label, len(fit.params), tuple(runs), fit.best_run,
                          fit.theta, tuple(p.name for p in fit.params), tuple(fit.predictions),
                          time.perf_counter() - t0)
    except HystfitError as exc:
        err = str(exc)
    except Exception as exc:  # a failing model/optimizer must not stop the comparison
        err = f"{exc.__class__.__name__}: {exc} ({traceback.extract_tb(exc.__traceback__)[-1].name})"
    return CellResult(spec.model, spec.optimizer, a, f, spec.label, 0, error=err,
                      runtime_s=time.perf_counter() - t0)


def compare(captures: Sequence[Capture], model_names: Sequence[str], optimizer_names: Sequence[str], *,
            runs: int = 1, seed: int = 0, jobs: int | None = None, polish: bool = True,
            model_options: Mapping[str, dict] | None = None, optimizer_options: Mapping[str, dict] | None = None,
            progress: Progress = None) -> CompareResult:
    """Run the cross product models × optimizers × conditions with ``runs`` runs per cell."""
    check_seed(seed)
    if not model_names or not optimizer_names:
        raise ConfigError("compare needs at least one model and one optimizer")
    for m in model_names:
        model_registry.get(m)
    for o in optimizer_names:
        optimizer_registry.get(o)
    if runs < 1:
        raise ConfigError(f"--runs must be at least 1, got {runs}")
    units = {c.y_unit for c in captures}
    if len(units) != 1:
        raise ConfigError(f"captures have different output units {sorted(units)}; convert them to one unit first")
    groups = group_by_condition(captures)
    conds = tuple((k, condition_label(k)) for k in groups)
    # structure shared by all conditions (e.g. a Hammerstein model's stage dynamics) is identified
    # once from all captures here and handed to every cell as fixed structure
    model_options = {m: dict((model_options or {}).get(m, {})) for m in model_names}
    notes = []
    for m in model_names:
        try:
            base = make_model(model_registry.get(m), model_options[m])
            prepared = base.prepare(captures)
            if prepared is not base:
                model_options[m] = prepared.structure()
                summary = getattr(prepared, "structure_summary", None)
                if summary is not None:
                    notes.append(f"`{m}`: {summary()}")
        except HystfitError:
            pass  # reported by the cells themselves
    specs = []
    for ci, (key, caps) in enumerate(groups.items()):
        for mi, m in enumerate(model_names):
            for oi, o in enumerate(optimizer_names):
                # the cell index (for seeds) depends on the condition and optimizer only, so every
                # model sees the same seeds on a condition, and the numbers never depend on --jobs
                specs.append(CellSpec(ci * 1000 + oi, m, o, key, condition_label(key), tuple(caps), runs, seed, polish,
                                      dict((model_options or {}).get(m, {})),
                                      dict((optimizer_options or {}).get(o, {}))))
    jobs = default_jobs() if jobs is None else max(1, int(jobs))
    if progress:
        progress("start", {"total": len(specs)})

    def done(i: int, _res) -> None:
        if progress:
            s = specs[i]
            progress("advance", {"label": f"{s.model}/{s.optimizer}/{s.label}"})

    cells = tuple(run_jobs(run_cell, specs, jobs, done))
    return CompareResult(tuple(model_names), tuple(optimizer_names), conds,
                         {lab: tuple(groups[k]) for k, lab in conds}, cells, runs, seed, units.pop(), jobs, polish,
                         tuple(notes))
