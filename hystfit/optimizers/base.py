"""The optimizer interface: minimize a vectorized objective over a bounded box.

Every optimizer has the same signature::

    result = Opt(**settings).minimize(objective, lower, upper, rng=rng, x0=None, callback=None)

with ``objective(Θ (P, d)) → (P,)`` (one candidate per row; non-finite values are treated as
+inf) and returns an :class:`OptimizeResult` with scipy's field names plus the histories.
Optimizers know nothing about hysteresis.
"""

from __future__ import annotations

import re
import textwrap
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, ClassVar, Mapping, Optional

import numpy as np

from ..errors import ConfigError, HystfitError

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


#: the stop rules every optimizer shares, in the order they are listed and recorded
STOP_RULE_NAMES = ("max_evals", "stall_iter", "stall_tol", "target", "time_limit_s")


@dataclass(frozen=True)
class Accepts:
    """The values a numeric setting (or stop rule) accepts: a finite number, or a whole number
    with ``whole``, within the bounds given (``at_least``/``above`` below, ``at_most``/``below``
    above), or None with ``nullable``. Declared on a dataclass field with :func:`setting` and
    checked, for every such field at once, by :func:`check_fields`.

    ``example`` is the value the error message suggests, set by ``option`` (default
    ``--opt-option NAME=``); ``what`` says in a few words what the setting is (shown after its
    name), ``null_means`` what None does.
    """

    at_least: float | None = None
    above: float | None = None
    at_most: float | None = None
    below: float | None = None
    whole: bool = False
    nullable: bool = False
    example: Any = None
    option: str = ""
    what: str = ""
    null_means: str = "switch it off"

    def __contains__(self, value: Any) -> bool:
        if value is None:
            return self.nullable
        kinds = (int, np.integer) if self.whole else (int, float, np.integer, np.floating)
        if isinstance(value, bool) or not isinstance(value, kinds) or not np.isfinite(value):
            return False
        return ((self.at_least is None or value >= self.at_least) and (self.above is None or value > self.above)
                and (self.at_most is None or value <= self.at_most) and (self.below is None or value < self.below))

    def describe(self) -> str:
        """E.g. "a whole number ≥ 1 or null", "a finite number in (0, 2)"."""
        low = next(((op, v) for op, v in (("[", self.at_least), ("(", self.above)) if v is not None), None)
        high = next(((op, v) for op, v in (("]", self.at_most), (")", self.below)) if v is not None), None)
        text = "a whole number" if self.whole else "a finite number"
        if low and high:
            text += f" in {low[0]}{low[1]:g}, {high[1]:g}{high[0]}"
        elif low or high:
            op, v = low or high
            text += f" {dict(zip('[(])', '≥>≤<'))[op]} {v:g}"
        return text + (" or null" if self.nullable else "")

    def check(self, name: str, value: Any, prefix: str = "") -> None:
        """ConfigError (one line: the setting, the rule, a fix) unless ``value`` is accepted."""
        if value in self:
            return
        what = f" ({self.what})" if self.what else ""
        fix = "" if self.example is None else f"; set e.g. {self.option or f'--opt-option {name}='}{self.example}"
        if self.nullable:
            fix += f", or {name}=null to {self.null_means}"
        raise ConfigError(f"{prefix}{name}{what} must be {self.describe()}, got {value!r}{fix}")


def setting(default: Any, **accepts: Any) -> Any:
    """A dataclass field with its :class:`Accepts` rule (``example`` defaults to ``default``)."""
    accepts.setdefault("example", default)
    return field(default=default, metadata={"accepts": Accepts(**accepts)})


def check_fields(obj: Any, prefix: str = "") -> None:
    """Check every field of the dataclass instance ``obj`` declared with :func:`setting`."""
    for f in fields(obj):
        rule = f.metadata.get("accepts")
        if rule is not None:
            rule.check(f.name, getattr(obj, f.name), prefix)


@dataclass(frozen=True)
class StopRules:
    """The stop rules shared by every optimizer, validated once, here.

    Attributes
    ----------
    max_evals : int ≥ 1 or None
        Evaluation budget: stop once this many candidates have been evaluated (checked after
        each iteration, so a population optimizer may overshoot by less than one population).
    stall_iter : int ≥ 1 or None
        Stall window: stop when the best value has not improved by more than ``stall_tol``
        (relative) for this many iterations.
    stall_tol : float ≥ 0
        Relative improvement the stall rule asks for.
    target : float or None
        Stop as soon as the best value is ≤ ``target``.
    time_limit_s : float > 0 or None
        Wall-clock limit in seconds (checked after each iteration).

    Status codes of :class:`OptimizeResult`: 0 budget (iterations/evaluations) reached, 1 stall,
    2 target value reached, 3 time limit, 4 callback asked to stop, 5 converged (local).
    Bad values raise :class:`~hystfit.errors.ConfigError` (one line: the option, the rule, the fix).
    """

    max_evals: int | None = setting(None, whole=True, at_least=1, nullable=True, example=1000,
                                    what="evaluation budget")
    stall_iter: int | None = setting(None, whole=True, at_least=1, nullable=True, example=30,
                                     what="stall window in iterations")
    stall_tol: float = setting(1e-9, at_least=0, example="1e-6")
    target: float | None = setting(None, nullable=True, example="1e-3")
    time_limit_s: float | None = setting(None, above=0, nullable=True, example=60, what="seconds")

    def __post_init__(self) -> None:
        check_fields(self, "stop rule ")


#: docstring paragraphs shared by the optimizers, written once here (a mixin adds its own as
#: ``doc_sections``). A class docstring names one by a line holding only ``{name}``, indented where
#: the paragraph goes; :func:`fill_doc` puts it in when the class is made. ``{unit}`` is the
#: class's ``iteration_unit``.
DOC_SECTIONS = {
    "iters_param": (
        "iters : int, default 200\n"
        "    Iterations, the initial evaluation included (``nfev = pop · iters`` when this rule stops)."),
    "stop_rule_params": (
        "max_evals, stall_iter, stall_tol, target, time_limit_s\n"
        "    The common stop rules (:class:`~hystfit.optimizers.base.StopRules`)."),
    "iterated_stop_rules": (
        "Stop rules: ``iters`` {unit}, ``max_evals`` evaluations, no relative improvement above\n"
        "``stall_tol`` for ``stall_iter`` {unit}, ``target`` reached, or ``time_limit_s``."),
}
_DOC_MARK = re.compile(r"^( *)\{(\w+)\}$", re.M)


def fill_doc(doc: str, sections: Mapping[str, str] = DOC_SECTIONS, unit: str = "iterations") -> str:
    """``doc`` with each line ``{name}`` replaced by ``sections[name]`` (indented as the line,
    ``{unit}`` → ``unit``); an unknown name is a KeyError."""
    return _DOC_MARK.sub(lambda m: textwrap.indent(sections[m.group(2)].format(unit=unit), m.group(1)), doc)


def stop_field(**defaults: Any) -> Any:
    """The ``stop`` field of an optimizer dataclass, with that optimizer's default rules."""
    return field(default=StopRules(**defaults), kw_only=True)


class Tracker:
    """Counts evaluations, keeps the best point and the histories, and applies the stop rules.

    ``max_iter`` is the optimizer's own iteration count (``iters``), if it has one.
    """

    def __init__(self, objective: Objective, rules: StopRules, callback: Callback = None,
                 max_iter: int | None = None) -> None:
        self.objective = objective
        self.rules = rules
        self.max_iter = max_iter
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
        if self.max_iter is not None and self.nit >= self.max_iter:
            return self._stop(0, f"iteration budget {self.max_iter} reached")
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


@dataclass
class Optimizer(ABC):
    """Base class; concrete optimizers are dataclasses whose fields are their settings.

    Every optimizer holds its stop rules as one :class:`StopRules` value, ``stop`` (keyword-only;
    a class with other defaults declares ``stop: StopRules = stop_field(...)``). On the command
    line and in :meth:`from_options` the rules are set by their own names (``max_evals=3000``),
    and :meth:`settings` lists them flat next to the optimizer's own settings.

    Contracts the orchestration reads instead of names (class attributes):

    ``uses_start_point``
        The search starts from (or seeds itself with) ``x0``, the model's default parameters;
        the others search the box from their own initialisation.
    ``polishes_itself``
        The result is already a least-squares solution (or polished by the optimizer itself):
        no least-squares polish after it.
    ``uses_separable_structure``
        Solves the parameters a model declares linear exactly (variable projection); a model
        with no nonlinear parameter is then one exact solve.
    ``applied_stop_rules``
        The stop rules the optimizer honours; setting another one is a ConfigError.
    ``required_stop_rules``
        The stop rules that must not be switched off (null), each with the reason.
    ``libraries``
        Modules the optimizer imports on first use (``scipy.optimize``, ≈ 0.3 s): the
        orchestration loads them (:meth:`load_libraries`) before it starts a run's clock, so a
        run's ``runtime_s`` is the search, not a one-time import (the command's time includes it).

    Docstrings name the paragraphs they share (``doc_sections`` of the class and its bases,
    :data:`DOC_SECTIONS` here) by a line ``{name}``; ``iteration_unit`` is what one iteration is
    called there ("iterations", GA: "generations").
    """

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    reference: ClassVar[str] = ""
    uses_start_point: ClassVar[bool] = False
    polishes_itself: ClassVar[bool] = False
    uses_separable_structure: ClassVar[bool] = False
    applied_stop_rules: ClassVar[tuple[str, ...]] = STOP_RULE_NAMES
    required_stop_rules: ClassVar[Mapping[str, str]] = {}
    iteration_unit: ClassVar[str] = "iterations"
    doc_sections: ClassVar[Mapping[str, str]] = DOC_SECTIONS
    libraries: ClassVar[tuple[str, ...]] = ()

    stop: StopRules = stop_field()

    def load_libraries(self) -> None:
        """Import :attr:`libraries` now (once per process; see the class description)."""
        import importlib

        for name in self.libraries:
            importlib.import_module(name)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__doc__:
            sections: dict[str, str] = {}
            for klass in reversed(cls.__mro__):
                sections.update(vars(klass).get("doc_sections", {}))
            cls.__doc__ = fill_doc(cls.__doc__, sections, cls.iteration_unit)

    def __post_init__(self) -> None:
        if not isinstance(self.stop, StopRules):
            raise ConfigError(f"{self.name}: stop must be a StopRules value, got {type(self.stop).__name__}")
        default = self.default_stop()
        ignored = [k for k in STOP_RULE_NAMES
                   if k not in self.applied_stop_rules and getattr(self.stop, k) != getattr(default, k)]
        if ignored:
            raise ConfigError(f"optimizer {self.name!r} does not apply the stop rule {ignored[0]}; "
                              f"it applies {', '.join(self.applied_stop_rules) or 'none'}")
        rules = {f.name: f.metadata["accepts"] for f in fields(StopRules)}
        for k, why in self.required_stop_rules.items():
            replace(rules[k], nullable=False, example=getattr(default, k), what=why).check(
                k, getattr(self.stop, k), f"{self.name}: ")
        check_fields(self, f"{self.name}: ")
        self.check_settings()

    def check_settings(self) -> None:
        """Validate what the settings' own rules (:func:`setting`) cannot: rules that involve
        several settings or the class (ConfigError); the stop rules and each setting declared
        with :func:`setting` are already valid."""

    @abstractmethod
    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        """Minimize ``objective`` over the box [lower, upper]."""

    # ---------------------------------------------------------------- settings, flat
    @classmethod
    def takes_budget_flags(cls) -> bool:
        """Whether ``--pop`` / ``--iters`` apply (population searches); see :func:`hystfit.factory.budget_options`."""
        return False

    @classmethod
    def default_stop(cls) -> StopRules:
        return next(f.default for f in fields(cls) if f.name == "stop")  # type: ignore[arg-type]

    @classmethod
    def own_setting_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls) if f.name != "stop")  # type: ignore[arg-type]

    @classmethod
    def option_names(cls) -> tuple[str, ...]:
        """Every KEY accepted by ``--opt-option KEY=VALUE``: own settings, then the stop rules."""
        return cls.own_setting_names() + cls.applied_stop_rules

    @classmethod
    def setting_docs(cls) -> list[tuple[str, Any]]:
        """(name, default) of every option, flat."""
        stop = cls.default_stop()
        own = {f.name: f.default for f in fields(cls)}  # type: ignore[arg-type]
        return [(k, own[k]) for k in cls.own_setting_names()] + [(k, getattr(stop, k)) for k in cls.applied_stop_rules]

    def settings(self) -> dict[str, Any]:
        """The settings as recorded in params.json: own settings, then the applied stop rules."""
        out = {k: getattr(self, k) for k in self.own_setting_names()}
        out.update((k, getattr(self.stop, k)) for k in self.applied_stop_rules)
        return out

    @classmethod
    def from_options(cls, options: Mapping[str, Any] | None = None) -> "Optimizer":
        """Build from flat KEY=VALUE options (own settings and stop rules by name), validated."""
        options = dict(options or {})
        valid = cls.option_names()
        unknown = [k for k in options if k not in valid]
        if unknown:
            key = unknown[0]
            why = ("a stop rule it does not apply" if key in STOP_RULE_NAMES else "unknown option")
            raise ConfigError(f"optimizer {cls.name!r}: {why} {key!r}; valid options: {', '.join(valid) or 'none'}")
        rules = {k: options.pop(k) for k in list(options) if k in STOP_RULE_NAMES}
        try:
            if rules:
                options["stop"] = replace(cls.default_stop(), **rules)
            return cls(**options)
        except HystfitError:
            raise
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"optimizer {cls.name!r}: invalid options {dict(options)!r} ({exc})") from None


@dataclass
class PopulationSearch(Optimizer):
    """An optimizer that evaluates ``pop`` candidates per iteration (``--pop`` applies)."""

    min_pop: ClassVar[int] = 2

    pop: int = 40

    def check_settings(self) -> None:
        Accepts(whole=True, at_least=self.min_pop, example=40, option="--pop ").check("pop", self.pop, f"{self.name}: ")

    @classmethod
    def takes_budget_flags(cls) -> bool:
        return True

    def max_iterations(self) -> int | None:
        """The iteration count the tracker stops at (None: no preset count)."""
        return None


@dataclass
class IteratedSearch(PopulationSearch):
    """A population search with a preset iteration count ``iters`` (the initial population is
    iteration 1, so ``nfev = pop · iters`` when that rule stops a plain population search)."""

    iters: int = 200

    def check_settings(self) -> None:
        super().check_settings()
        Accepts(whole=True, at_least=1, example=200, option="--iters ").check("iters", self.iters, f"{self.name}: ")

    def max_iterations(self) -> int | None:
        return self.iters


class PopulationLoop(ABC):
    """Mixin: the loop start-up shared by the native population searches (pso, pso-cf, ipso, ga,
    gwo, igwo), for classes that also derive from :class:`PopulationSearch`.

    :meth:`minimize` checks the box, opens the :class:`Tracker` with the stop rules and the
    iteration count, draws the initial population (:meth:`initial_population`: uniform in the box,
    paper 004 eq. 3, unless overridden), puts ``x0`` (clipped) in place of the first member,
    evaluates it as iteration 1 and, unless a stop rule already fired, hands over to
    :meth:`search`, which iterates until ``tr.end_iteration`` says stop.
    """

    def initial_population(self, rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        return lower + rng.random((self.pop, lower.size)) * (upper - lower)  # type: ignore[attr-defined]

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        tr = Tracker(objective, self.stop, callback, self.max_iterations())  # type: ignore[attr-defined]
        x = self.initial_population(rng, lower, upper)
        if x0 is not None:
            x[0] = np.clip(np.asarray(x0, float), lower, upper)
        f = tr.evaluate(x)
        if not tr.end_iteration(f):
            self.search(tr, x, f, lower, upper, rng)
        return tr.result(self.name)  # type: ignore[attr-defined]

    @abstractmethod
    def search(self, tr: Tracker, x: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rng: np.random.Generator) -> None:
        """Iterate from the evaluated initial population ``x`` (values ``f``) until
        ``tr.end_iteration`` returns True; everything to report is in ``tr``."""
