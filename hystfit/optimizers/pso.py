"""Particle swarm optimization with linearly decreasing inertia (paper 001 eq. 4–5)."""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Mapping

import numpy as np

from ..registry import optimizers
from .base import IteratedSearch, PopulationLoop, Tracker, reflect


def fly(x: np.ndarray, v: np.ndarray, vmax: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """One move of the swarm: v clamped to ±vmax (in place), x + v as a new array (the objective
    may keep the previous one); a coordinate that leaves the box is reflected back inside and its
    velocity component reversed (in place). Used by ``pso-cf`` and ``ipso``; :class:`PSO` reflects
    every coordinate (its numbers predate this helper)."""
    np.clip(v, -vmax, vmax, out=v)
    x = x + v
    out = (x < lower) | (x > upper)
    if out.any():
        x = reflect(x, lower, upper)
        np.negative(v, out=v, where=out)
    return x


def update_personal_bests(pbest: np.ndarray, pbest_f: np.ndarray, x: np.ndarray, f: np.ndarray) -> None:
    """Replace (in place) the personal bests that ``x`` improves on."""
    better = f < pbest_f
    pbest[better] = x[better]
    pbest_f[better] = f[better]


class Swarm(PopulationLoop):
    """Mixin: the loop shared by the particle swarms (pso, pso-cf, ipso); each supplies its
    velocity rule (:meth:`velocity`) and a ``vmax_frac`` setting.

    After the evaluated initial positions (:class:`PopulationLoop`), the velocities are drawn
    uniform in ±V_max, V_max = ``vmax_frac``·(upper − lower), and the personal bests start at the
    initial positions. Each iteration: new velocities (:meth:`velocity`), the move
    (:meth:`move`, by default :func:`fly`), one evaluation, the personal bests updated, the stop
    rules checked.
    """

    #: the docstring paragraphs on bounds and initialisation of the swarms that move with :func:`fly`
    doc_sections: ClassVar[Mapping[str, str]] = {"swarm_notes": (
        "Bounds: a particle that leaves the box is *reflected* back inside and the offending\n"
        "velocity component reversed (:func:`~hystfit.optimizers.pso.fly`).\n\n"
        "Initialisation: uniform in the box, velocities uniform in ±V_max; if ``x0`` is given it\n"
        "replaces the first particle (clipped into the box).")}

    def search(self, tr: Tracker, x: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rng: np.random.Generator) -> None:
        vmax = self.vmax_frac * (upper - lower)  # type: ignore[attr-defined]
        v = (rng.random(x.shape) * 2 - 1) * vmax
        pbest, pbest_f = x.copy(), f.copy()
        while True:
            v = self.velocity(tr.nit, x, v, pbest, pbest_f, rng)
            x, v = self.move(x, v, vmax, lower, upper)
            f = tr.evaluate(x)
            update_personal_bests(pbest, pbest_f, x, f)
            if tr.end_iteration(f):
                return

    @abstractmethod
    def velocity(self, nit: int, x: np.ndarray, v: np.ndarray, pbest: np.ndarray, pbest_f: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
        """The new velocities (a new array) after ``nit`` iterations, from positions ``x``,
        velocities ``v`` and the personal bests ``pbest`` (values ``pbest_f``)."""

    def move(self, x: np.ndarray, v: np.ndarray, vmax: np.ndarray, lower: np.ndarray,
             upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The new positions (a new array) and velocities after the move with velocities ``v``."""
        return fly(x, v, vmax, lower, upper), v


@optimizers.register
@dataclass
class PSO(Swarm, IteratedSearch):
    """Global-best PSO with inertia weight (paper 001 eq. 4–5; ``shared/papers/README.md``).

    v ← W v + φ1 r1 (p_i − x) + φ2 r2 (p_g − x),  x ← x + v,
    W decreasing linearly from ``w_start`` (0.9) to ``w_end`` (0.4) over ``iters`` iterations,
    φ1 = φ2 = 2, velocity clamped to ``vmax_frac``·(upper − lower).

    Bounds: a particle that leaves the box is *reflected* back inside and the offending velocity
    component reversed (periodic wrapping, pyswarms' default, is known to ruin PI fits).

    Settings: ``pop`` (40) particles, ``iters`` (200) iterations, ``w_start``/``w_end`` (0.9/0.4),
    ``phi1``/``phi2`` (2.0/2.0) cognitive and social acceleration, ``vmax_frac`` (0.2).

    {iterated_stop_rules}

    Initialisation: uniform in the box; if ``x0`` is given it replaces the first particle.
    """

    name = "pso"
    title = "Particle swarm (inertia weight)"
    reference = "paper 001 eq. 4–5"

    w_start: float = 0.9
    w_end: float = 0.4
    phi1: float = 2.0
    phi2: float = 2.0
    vmax_frac: float = 0.2

    def velocity(self, nit: int, x: np.ndarray, v: np.ndarray, pbest: np.ndarray, pbest_f: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
        w = self.w_start + (self.w_end - self.w_start) * min(nit / max(self.iters - 1, 1), 1.0)
        r1 = rng.random(x.shape)
        r2 = rng.random(x.shape)
        g = int(np.argmin(pbest_f))
        return w * v + self.phi1 * r1 * (pbest - x) + self.phi2 * r2 * (pbest[g] - x)

    def move(self, x: np.ndarray, v: np.ndarray, vmax: np.ndarray, lower: np.ndarray,
             upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # every coordinate goes through reflect (not only those that left the box, as in fly)
        np.clip(v, -vmax, vmax, out=v)
        x_new = x + v
        out = (x_new < lower) | (x_new > upper)
        return reflect(x_new, lower, upper), np.where(out, -v, v)
