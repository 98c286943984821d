"""Differential evolution: scipy's ``differential_evolution``, vectorized, behind the common interface."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import Callback, IteratedSearch, Objective, OptimizeResult, Tracker, check_box, setting



def _rng_keyword(differential_evolution) -> str:
    """scipy ≥ 1.15 takes the generator as ``rng``; older releases as ``seed`` (which accepts a Generator too)."""
    return "rng" if "rng" in inspect.signature(differential_evolution).parameters else "seed"

_STRATEGIES = ("best1bin", "best1exp", "rand1bin", "rand1exp", "rand2bin", "rand2exp", "randtobest1bin",
               "randtobest1exp", "currenttobest1bin", "currenttobest1exp", "best2exp", "best2bin")
_INITS = ("latinhypercube", "sobol", "halton", "random")


class _StopRun(Exception):
    """Raised from inside scipy's loop when a hystfit stop rule fires on the initial population."""


@optimizers.register
@dataclass
class DE(IteratedSearch):
    """Differential evolution (Storn & Price 1997) via ``scipy.optimize.differential_evolution``.

    Default strategy ``best1bin``: for each member x_i, a mutant v = x_best + F (x_r1 − x_r2)
    with F ~ U(``mutation_min``, ``mutation_max``) drawn per generation (dither), binomial
    crossover with probability ``recombination`` (one gene always from the mutant), and greedy
    selection: the trial replaces x_i when it is not worse.

    The whole generation is one objective call (``vectorized=True``, ``updating='deferred'``);
    scipy hands the population over as (d, S) and this wrapper transposes it to hystfit's
    (S, d). ``polish=False``: hystfit polishes with :class:`~hystfit.optimizers.lsq.LSQ` itself.

    Parameters
    ----------
    pop : int, default 40
        Requested population size; scipy's ``popsize = ceil(pop / d)`` multiplies the dimension,
        so the population is ``ceil(pop / d) · d`` ≥ pop (and ≥ 5).
    iters : int, default 200
        Generations, the initial population included (scipy's ``maxiter = iters − 1``):
        ``nfev = members · iters`` when this rule stops.
    strategy : str, default "best1bin"
        scipy's mutation strategy.
    mutation_min, mutation_max : float, default 0.5, 1.0
        Range of the differential weight F (dither); equal values give a constant F.
    recombination : float, default 0.7
        Crossover probability CR.
    init : str, default "latinhypercube"
        scipy's initial population: "latinhypercube", "sobol", "halton" or "random".
    tol : float, default 0.0
        scipy's own convergence test std(E) ≤ tol·|mean(E)| on the population values E
        (status 5 when it fires); 0 leaves only hystfit's stop rules (and a fully collapsed
        population).
    {stop_rule_params}

    Notes
    -----
    Stop rules: ``iters`` generations, ``max_evals`` evaluations (checked after each generation,
    so the budget can be overshot by less than one generation), no relative improvement above
    ``stall_tol`` for ``stall_iter`` generations, ``target`` reached, ``time_limit_s``, or scipy's
    ``tol``. Evaluations go through the :class:`~hystfit.optimizers.base.Tracker`, so ``nfev``
    counts candidates (scipy's own ``nfev`` counts vectorized calls); the per-generation history
    is recorded in scipy's ``callback(intermediate_result)`` (best so far, mean of the population
    values after selection).

    Bounds: scipy works in the unit cube; a mutant component outside it is replaced by a uniform
    random value in the box (scipy's rule), so every candidate lies in the box.

    Initialisation: scipy's ``init`` scheme, drawn from ``rng``; if ``x0`` is given it replaces
    the first member (clipped into the box). Seeding: the generator itself is handed to scipy.

    Cost: scipy's loop costs about 1 ms per generation outside the objective
    (``shared/PERFORMANCE.md``: 0.2–0.3 s for 300 generations of 200), an order of magnitude
    above the native optimizers; use it for comparison, not as the engine.
    """

    name = "de"
    iteration_unit = "generations"
    title = "Differential evolution (scipy)"
    reference = "Storn & Price 1997; scipy.optimize.differential_evolution"
    libraries = ("scipy.optimize",)
    min_pop = 1

    strategy: str = "best1bin"
    mutation_min: float = 0.5
    mutation_max: float = 1.0
    recombination: float = setting(0.7, at_least=0, at_most=1)
    init: str = "latinhypercube"
    tol: float = setting(0.0, at_least=0)

    def check_settings(self) -> None:
        super().check_settings()
        if self.strategy not in _STRATEGIES:
            raise ConfigError(f"de: unknown strategy {self.strategy!r}; choose one of {', '.join(_STRATEGIES)}")
        if self.init not in _INITS:
            raise ConfigError(f"de: unknown init {self.init!r}; choose one of {', '.join(_INITS)}")
        if not 0 <= self.mutation_min <= self.mutation_max < 2:
            raise ConfigError(f"de: need 0 ≤ mutation_min ≤ mutation_max < 2 "
                              f"(got {self.mutation_min:g}, {self.mutation_max:g})")

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        d = lower.size
        tr = Tracker(objective, self.stop, callback, self.iters)
        state = {"initial": True, "stopped": False}

        def func(x_t: np.ndarray) -> np.ndarray:
            # scipy passes (d, S); hystfit objectives take (S, d)
            f = tr.evaluate(np.ascontiguousarray(x_t.T))
            if state["initial"]:           # the initial population is iteration 1
                state["initial"] = False
                if tr.end_iteration(f):
                    state["stopped"] = True
                    raise _StopRun
            return f

        def on_generation(intermediate_result) -> bool:
            stop = tr.end_iteration(np.asarray(intermediate_result.population_energies))
            state["stopped"] = stop
            return stop

        mutation = (self.mutation_min if self.mutation_min == self.mutation_max
                    else (self.mutation_min, self.mutation_max))
        from scipy.optimize import differential_evolution  # deferred: keeps start-up fast

        kwargs = {_rng_keyword(differential_evolution): rng}
        if x0 is not None:
            kwargs["x0"] = np.clip(np.asarray(x0, float).ravel(), lower, upper)
        try:
            sol = differential_evolution(
                func, list(zip(lower, upper)), strategy=self.strategy, maxiter=max(self.iters - 1, 0),
                popsize=math.ceil(self.pop / d), tol=self.tol, atol=0.0, mutation=mutation,
                recombination=self.recombination, callback=on_generation, polish=False, init=self.init,
                updating="deferred", vectorized=True, **kwargs)
        except _StopRun:
            sol = None
        if sol is not None and not state["stopped"]:
            # scipy ended on its own criterion (tol) before any hystfit rule fired
            tr.status, tr.message = 5, f"scipy: {sol.message}"
        return tr.result(self.name)
