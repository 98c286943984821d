"""The optimizer interface: minimize a vectorized objective over a bounded box.

Every optimizer has the same signature::

    result = Opt(**settings).minimize(objective, lower, upper, rng=rng, x0=None, callback=None)

with ``objective(Θ (P, d)) → (P,)`` (one candidate per row; non-finite values are treated as
+inf) and returns an :class:`OptimizeResult` with scipy's field names plus the histories.
Optimizers know nothing about hysteresis.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields
from typing import Any, Callable, ClassVar, Optional

import numpy as np

from ..errors import ConfigError

Objective = Callable[[np.ndarray], np.ndarray]
#: callback(iteration, best_value, mean_value) → True to stop early.
Callback = Optional[Callable[[int, float, float], Optional[bool]]]


@dataclass(frozen=True)
class OptimizeResult:
    """Result of one optimization run (scipy.optimize vocabulary plus histories)."""

    x: np.ndarray
    fun: float
    nfev: int
    nit: int
    success: bool
    status: int
    message: str
    history_best: np.ndarray = field(default_factory=lambda: np.empty(0))
    history_mean: np.ndarray = field(default_factory=lambda: np.empty(0))
    wall_time_s: float = 0.0
    optimizer: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "x": [float(v) for v in self.x], "fun": float(self.fun), "nfev": int(self.nfev),
            "nit": int(self.nit), "success": bool(self.success), "status": int(self.status),
            "message": self.message, "wall_time_s": float(self.wall_time_s), "optimizer": self.optimizer,
        }


@dataclass
class StopRules:
    """The common stop rules. Status codes: 0 budget (iterations/evaluations) reached,
    1 stall, 2 target value reached, 3 time limit, 4 callback asked to stop, 5 converged (local)."""

    max_iter: int | None = None
    max_evals: int | None = None
    stall_iter: int | None = None
    stall_tol: float = 1e-9
    target: float | None = None
    time_limit_s: float | None = None


class Tracker:
    """Counts evaluations, keeps the best point and the histories, and applies the stop rules."""

    def __init__(self, objective: Objective, rules: StopRules, callback: Callback = None) -> None:
        self.objective = objective
        self.rules = rules
        self.callback = callback
        self.nfev = 0
        self.nit = 0
        self.best_x: np.ndarray | None = None
        self.best_f = np.inf
        self.hist_best: list[float] = []
        self.hist_mean: list[float] = []
        self.t0 = time.perf_counter()
        self._stall_ref = np.inf
        self._stall_count = 0
        self.status = 0
        self.message = ""

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        f = np.asarray(self.objective(X), dtype=np.float64).reshape(-1)
        if f.shape[0] != X.shape[0]:
            raise ValueError(f"objective returned {f.shape[0]} values for {X.shape[0]} candidates")
        f = np.where(np.isfinite(f), f, np.inf)
        self.nfev += X.shape[0]
        i = int(np.argmin(f))
        if f[i] < self.best_f:
            self.best_f = float(f[i])
            self.best_x = X[i].copy()
        return f

    def end_iteration(self, f_population: np.ndarray) -> bool:
        """Record one iteration; return True when a stop rule fires."""
        self.nit += 1
        finite = f_population[np.isfinite(f_population)]
        mean = float(finite.mean()) if finite.size else np.inf
        self.hist_best.append(self.best_f)
        self.hist_mean.append(mean)
        r = self.rules
        if self.callback is not None and self.callback(self.nit, self.best_f, mean):
            return self._stop(4, "stopped by callback")
        if r.target is not None and self.best_f <= r.target:
            return self._stop(2, f"target value {r.target:g} reached")
        if r.stall_iter is not None:
            ref = self._stall_ref
            if not np.isfinite(ref) or self.best_f < ref - r.stall_tol * max(abs(ref), 1e-300):
                self._stall_ref = self.best_f
                self._stall_count = 0
            else:
                self._stall_count += 1
                if self._stall_count >= r.stall_iter:
                    return self._stop(1, f"no relative improvement above {r.stall_tol:g} in {r.stall_iter} iterations")
        if r.max_iter is not None and self.nit >= r.max_iter:
            return self._stop(0, f"iteration budget {r.max_iter} reached")
        if r.max_evals is not None and self.nfev >= r.max_evals:
            return self._stop(0, f"evaluation budget {r.max_evals} reached")
        if r.time_limit_s is not None and time.perf_counter() - self.t0 >= r.time_limit_s:
            return self._stop(3, f"time limit {r.time_limit_s:g} s reached")
        return False

    def _stop(self, status: int, message: str) -> bool:
        self.status, self.message = status, message
        return True

    def result(self, name: str) -> OptimizeResult:
        x = self.best_x if self.best_x is not None else np.empty(0)
        return OptimizeResult(
            x=np.asarray(x, float), fun=float(self.best_f), nfev=self.nfev, nit=self.nit,
            success=bool(np.isfinite(self.best_f)), status=self.status,
            message=self.message or "finished", history_best=np.asarray(self.hist_best),
            history_mean=np.asarray(self.hist_mean), wall_time_s=time.perf_counter() - self.t0,
            optimizer=name,
        )


def check_box(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lower = np.asarray(lower, dtype=np.float64).ravel()
    upper = np.asarray(upper, dtype=np.float64).ravel()
    if lower.shape != upper.shape or lower.size == 0:
        raise ConfigError("lower and upper bounds must be non-empty and of equal length")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise ConfigError("bounds must be finite")
    bad = np.flatnonzero(lower >= upper)
    if bad.size:
        raise ConfigError(f"lower bound must be below upper bound (dimension {int(bad[0])})")
    return lower, upper


def reflect(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Reflect points that left the box back inside it (mirror at the violated face, repeatedly)."""
    width = upper - lower
    y = (x - lower) / width
    y = np.abs(y)                      # mirror at the lower face
    y = np.mod(y, 2.0)                 # period 2 of the mirror pattern
    y = np.where(y > 1.0, 2.0 - y, y)  # mirror at the upper face
    return lower + y * width


class Optimizer(ABC):
    """Base class; concrete optimizers are dataclasses whose fields are their settings."""

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    reference: ClassVar[str] = ""
    population_based: ClassVar[bool] = True

    @abstractmethod
    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        """Minimize ``objective`` over the box [lower, upper]."""

    def settings(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]

    @classmethod
    def setting_docs(cls) -> list[tuple[str, Any]]:
        return [(f.name, f.default) for f in fields(cls)]  # type: ignore[arg-type]
