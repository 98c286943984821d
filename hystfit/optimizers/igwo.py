"""Improved grey wolf optimizer (paper 004 §2.3): logistic chaos start, nonlinear a, Lévy flight."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box
from .gwo import hunt, schedule_length, update_leaders

_E_MINUS_1 = math.e - 1.0


def mantegna_sigma(beta: float) -> float:
    """Scale σ_u of the numerator of Mantegna's algorithm (paper 004, below eq. 14).

    σ_u = [Γ(1 + β) sin(πβ/2) / (Γ((1 + β)/2) β 2^{(β−1)/2})]^{1/β}; 0.6966 for β = 1.5.
    """
    num = math.gamma(1.0 + beta) * math.sin(math.pi * beta / 2.0)
    den = math.gamma((1.0 + beta) / 2.0) * beta * 2.0 ** ((beta - 1.0) / 2.0)
    return (num / den) ** (1.0 / beta)


def levy_steps(rng: np.random.Generator, shape, beta: float = 1.5, n_sum: int = 1) -> np.ndarray:
    """Lévy-stable steps by Mantegna's algorithm (1994), as paper 004 eq. 13 uses them.

    s = u / |v|^{1/β},  u ~ N(0, σ_u²),  v ~ N(0, 1),  σ_u from :func:`mantegna_sigma`.

    The tails are heavy: P(|s| > x) ∝ x^{−β} for large x, so most steps are small and a few are
    very long.

    With ``n_sum`` > 1 the sum of ``n_sum`` independent Mantegna steps is returned, drawn
    exactly with ``n_sum`` + 1 normals instead of 2·``n_sum``: given the v_k, Σ_k σ_u u_k |v_k|^{−1/β}
    is normal with variance σ_u² Σ_k |v_k|^{−2/β}, so Σ_k s_k = σ_u z (Σ_k |v_k|^{−2/β})^{1/2} with
    z ~ N(0, 1) (for ``n_sum`` = 1 this is Mantegna's formula itself).

    Parameters
    ----------
    rng : numpy.random.Generator
    shape : int or tuple of int
        Shape of the returned array.
    beta : float, default 1.5
        Stability index, 0 < β < 2.
    n_sum : int, default 1
        Number of independent steps summed per entry.

    Returns
    -------
    ndarray of float64, shape ``shape``
    """
    if not 0.0 < beta < 2.0:
        raise ConfigError(f"levy_steps: beta must lie in (0, 2), got {beta:g}")
    if n_sum < 1:
        raise ConfigError(f"levy_steps: n_sum must be ≥ 1, got {n_sum}")
    shape = tuple(int(n) for n in np.atleast_1d(shape))
    n = rng.standard_normal((n_sum + 1,) + shape)
    v = n[1:]
    v *= v
    # v² is floored at 1e-300 only to rule out a division by an exact zero (probability ~ 0)
    np.maximum(v, 1e-300, out=v)
    np.power(v, -1.0 / beta, out=v)           # |v_k|^{−2/β}
    scale = v[0] if n_sum == 1 else v.sum(axis=0)
    np.sqrt(scale, out=scale)
    scale *= mantegna_sigma(beta)
    z = n[0]
    z *= scale
    return z


def nonlinear_convergence_factor(t: float, T: float) -> float:
    """IGWO's convergence factor a = 2 (1 − (e^{t/T} − 1)/(e − 1)) (paper 004 eq. 11, README).

    2 at t = 0, 0 at t = T; decreases slowly early (a(T/2) ≈ 1.245 > 1, the linear value) and
    fast late.
    """
    return 2.0 * (1.0 - (math.exp(min(t / T, 1.0)) - 1.0) / _E_MINUS_1)


def logistic_init(rng: np.random.Generator, n: int, lower: np.ndarray, upper: np.ndarray,
                  mu: float = 4.0) -> np.ndarray:
    """Logistic-map chaotic initial population (paper 004 eq. 10), mapped into the box.

    A chaotic sequence runs along the population: z_1 ~ U(0, 1)^d, z_{i+1} = μ z_i (1 − z_i)
    (each dimension its own sequence); the map sends [0, 1] into [0, μ/4], so
    x_i = lower + z_i / (μ/4) · (upper − lower) lies in the box. μ = 4 is the fully chaotic
    regime (invariant arcsine density, denser towards the faces); below μ ≈ 3.57 the sequence
    settles on a periodic orbit and the pack loses diversity.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the seeds z_1 (deterministic per generator state).
    n : int
        Number of points.
    lower, upper : ndarray, shape (d,)
    mu : float, default 4.0
        Logistic parameter, 0 < μ ≤ 4 (paper 004: F ∈ [2, 4]).

    Returns
    -------
    ndarray, shape (n, d)
    """
    if not 0.0 < mu <= 4.0:
        raise ConfigError(f"logistic_init: mu must lie in (0, 4], got {mu:g}")
    z = np.empty((n, lower.size))
    z[0] = rng.random(lower.size)
    for i in range(1, n):
        z[i] = mu * z[i - 1] * (1.0 - z[i - 1])
    return lower + np.clip(z / (mu / 4.0), 0.0, 1.0) * (upper - lower)


@optimizers.register
@dataclass
class IGWO(Optimizer):
    """Improved grey wolf optimizer (paper 004 §2.3, eq. 10–15; ``shared/papers/README.md``).

    As :class:`~hystfit.optimizers.gwo.GWO` with three changes:

    1. Logistic chaos initialisation: z_{i+1} = μ z_i (1 − z_i) along the pack, mapped into the
       box (:func:`logistic_init`, μ = 4).
    2. Nonlinear convergence factor a = 2 (1 − (e^{t/T} − 1)/(e − 1))
       (:func:`nonlinear_convergence_factor`).
    3. Lévy flight on the three leader-guided positions (eq. 12–14)::

           X_k ← X_k + Γ ⊙ s_k,   s_k Mantegna steps with β = 1.5 (:func:`levy_steps`),
           Γ = levy_scale · (upper − lower) = 0.01 · (upper − lower),
           X  ← (X_1 + X_2 + X_3) / 3.

       The steps enter X only through s_1 + s_2 + s_3, which is drawn directly and exactly
       (``levy_steps(..., n_sum=3)``: 4 normals per coordinate instead of 6; normal variates
       dominate this optimizer's own cost).

    Each iteration X_k = L_k − A_k |C_k L_k − X| as in GWO (:func:`~hystfit.optimizers.gwo.hunt`),
    T the number of position updates (``iters − 1``, shortened by ``max_evals``).

    Parameters
    ----------
    pop : int, default 40
        Pack size (≥ 3).
    iters : int, default 200
        Iterations, the initial evaluation included (``nfev = pop · iters`` when this rule stops).
    mu : float, default 4.0
        Logistic-map parameter (paper 004's F, in [2, 4]; 4 is fully chaotic).
    levy_beta : float, default 1.5
        Lévy stability index β.
    levy_scale : float, default 0.01
        Step size coefficient Γ as a fraction of (upper − lower).
    max_evals, stall_iter, stall_tol, target, time_limit_s
        The common stop rules (:class:`~hystfit.optimizers.base.StopRules`).

    Notes
    -----
    Stop rules: ``iters`` iterations, ``max_evals`` evaluations, no relative improvement above
    ``stall_tol`` for ``stall_iter`` iterations, ``target`` reached, or ``time_limit_s``.

    Bounds: positions that leave the box (Lévy steps occasionally throw far) are *clipped* to the
    violated face, as in GWO and paper 004 (Algorithm 1, step 14).

    Initialisation: logistic chaos; if ``x0`` is given it replaces the first wolf (clipped).

    Precision: the Lévy steps do not shrink as the pack converges (Γ is fixed by the box), so
    the positions keep jittering by about ``levy_scale``·(upper − lower) and the final values
    stay above plain GWO's on smooth problems; hystfit's least-squares polish removes that, or
    lower ``levy_scale``.

    Paper 004's Algorithm 1 applies the Lévy update only when |A| < 1 and is ambiguous about the
    other case; we apply it to every wolf, as the README formulation states.
    """

    name = "igwo"
    title = "Improved grey wolf optimizer (chaos, nonlinear a, Lévy flight)"
    reference = "paper 004 §2.3 eq. 10–15"

    pop: int = 40
    iters: int = 200
    mu: float = 4.0
    levy_beta: float = 1.5
    levy_scale: float = 0.01
    max_evals: int | None = None
    stall_iter: int | None = None
    stall_tol: float = 1e-9
    target: float | None = None
    time_limit_s: float | None = None

    def __post_init__(self) -> None:
        if self.pop < 3 or self.iters < 1:
            raise ConfigError(f"igwo: pop must be ≥ 3 and iters ≥ 1 (got pop={self.pop}, iters={self.iters})")
        if not 0.0 < self.mu <= 4.0:
            raise ConfigError(f"igwo: mu must lie in (0, 4], got {self.mu:g}")
        if not 0.0 < self.levy_beta < 2.0:
            raise ConfigError(f"igwo: levy_beta must lie in (0, 2), got {self.levy_beta:g}")
        if self.levy_scale < 0:
            raise ConfigError(f"igwo: levy_scale must be ≥ 0, got {self.levy_scale:g}")

    def _rules(self) -> StopRules:
        return StopRules(self.iters, self.max_evals, self.stall_iter, self.stall_tol, self.target, self.time_limit_s)

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        d, P = lower.size, self.pop
        T = schedule_length(self.iters, P, self.max_evals)
        step = self.levy_scale * (upper - lower)
        tr = Tracker(objective, self._rules(), callback)
        x = logistic_init(rng, P, lower, upper, self.mu)
        if x0 is not None:
            x[0] = np.clip(np.asarray(x0, float), lower, upper)
        f = tr.evaluate(x)
        leaders, leaders_f = update_leaders(np.empty((0, d)), np.empty(0), x, f)
        if tr.end_iteration(f):
            return tr.result(self.name)
        t = 0
        while True:
            x = hunt(leaders, x, nonlinear_convergence_factor(t, T), rng).sum(axis=0)
            # eq. 12–14: X = Σ_k (X_k + Γ s_k) / 3; the three steps are drawn as their exact sum
            s = levy_steps(rng, x.shape, self.levy_beta, n_sum=3)
            s *= step
            x += s
            x *= 1.0 / 3.0
            np.clip(x, lower, upper, out=x)
            f = tr.evaluate(x)
            leaders, leaders_f = update_leaders(leaders, leaders_f, x, f)
            t += 1
            if tr.end_iteration(f):
                return tr.result(self.name)
