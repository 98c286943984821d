"""Improved grey wolf optimizer (paper 004 §2.3): chaos initialisation (eq. 10), nonlinear a, Lévy flight."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import setting
from .gwo import GWO

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


def chaos_init(rng: np.random.Generator, n: int, lower: np.ndarray, upper: np.ndarray,
               chaos_factor: float = 2.0) -> np.ndarray:
    """Logistic chaos initial pack of paper 004 eq. 10, placed in the box as eq. 3 places ``rand``.

    Eq. 10 reads ``P = F · rand(Np, d) · (1 − rand(Np, d))``: two *independent* uniform arrays
    r1, r2 ~ U(0, 1)^(n×d) (two ``rand`` calls), P = F r1 (1 − r2). "We employ it … to replace
    the random initialization", i.e. P takes the place of ``rand(Np, d)`` in eq. 3::

        X = lower + P · (upper − lower),   then clipped into the box (Algorithm 1, step 14).

    P ranges over [0, F], so the coordinates with P > 1 land on the upper face: a fraction
    1 − 1/F − ln(F)/F (0.153 for 004's F = 2, 0.403 for F = 4); the rest has the density
    ln(F/p)/F of p = P on [0, 1], highest towards the lower face. 004 chooses F = 2 (§3.2, Fig. 5b).

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws r1 then r2 (deterministic per generator state).
    n : int
        Number of wolves.
    lower, upper : ndarray, shape (d,)
    chaos_factor : float, default 2.0
        The adjustment factor F, > 0 (004: "typically ranges from 2 to 4").

    Returns
    -------
    ndarray, shape (n, d)
    """
    if not (np.isfinite(chaos_factor) and chaos_factor > 0.0):
        raise ConfigError(f"chaos_init: chaos_factor must be a positive number, got {chaos_factor:g}")
    r = rng.random((2, n, lower.size))
    p = chaos_factor * r[0] * (1.0 - r[1])
    return np.clip(lower + p * (upper - lower), lower, upper)


@optimizers.register
@dataclass
class IGWO(GWO):
    """Improved grey wolf optimizer (paper 004 §2.3, eq. 10–15; ``shared/papers/README.md``).

    As :class:`~hystfit.optimizers.gwo.GWO` with three changes:

    1. Logistic chaos initialisation (eq. 10): P = F · r1 ⊙ (1 − r2) with r1, r2 ~ U(0, 1)^(Np×d)
       independent, placed in the box as eq. 3 places ``rand``: X = lower + P ⊙ (upper − lower),
       clipped into the box (:func:`chaos_init`). F = ``chaos_factor`` = 2, 004's choice (§3.2):
       about 15 % of the coordinates start on the upper face, the rest mostly in the lower part.
    2. Nonlinear convergence factor a = 2 (1 − (e^{t/T} − 1)/(e − 1))
       (:func:`nonlinear_convergence_factor`).
    3. Lévy flight on the three leader-guided positions (eq. 12–14)::

           X_k ← X_k + Γ ⊙ s_k,   s_k Mantegna steps with β = ``levy_beta`` = 1.5 (:func:`levy_steps`),
           Γ = ``levy_scale`` · (upper − lower) = 0.01 · (upper − lower),
           X  ← (X_1 + X_2 + X_3) / 3.

       The steps enter X only through s_1 + s_2 + s_3, which is drawn directly and exactly
       (``levy_steps(..., n_sum=3)``: 4 normals per coordinate instead of 6; normal variates
       dominate this optimizer's own cost).

    Each iteration X_k = L_k − A_k |C_k L_k − X| as in GWO (:func:`~hystfit.optimizers.gwo.hunt`),
    T the number of position updates (``iters − 1``, shortened by ``max_evals``).

    Parameters
    ----------
    pop : int, default 40
        Pack size (≥ 3); 004 settles on 60 and T = 50 iterations (§3.2).
    {iters_param}
    chaos_factor : float, default 2.0
        The adjustment factor F of eq. 10 (> 0; 004: "typically ranges from 2 to 4", chooses 2).
    levy_beta : float, default 1.5
        Lévy stability index β, 0 < β < 2.
    levy_scale : float, default 0.01
        Step size coefficient Γ as a fraction of (upper − lower) (≥ 0; 0 switches the flight off).
    {stop_rule_params}

    Notes
    -----
    {iterated_stop_rules}

    Bounds: positions that leave the box (Lévy steps occasionally throw far) are *clipped* to the
    violated face, as in GWO and paper 004 (Algorithm 1, step 14).

    Initialisation: eq. 10 (:func:`chaos_init`); if ``x0`` is given it replaces the first wolf
    (clipped).

    Where this differs from paper 004, and why:

    * Eq. 10 is not a chaotic *sequence*: both factors are fresh uniform draws (two ``rand``
      calls), so "chaos" is only the name. We implement the equation as written, not the
      formulation of ``shared/papers/README.md`` (the logistic map iterated along the pack, its
      range [0, μ/4] stretched onto the box), which hystfit 0.1.0 used: with 004's F = 2 that
      sequence converges to its fixed point 1/2, i.e. the upper face, for 93 % of the coordinates.
      The choice of one independent pair (r1, r2) per coordinate follows MATLAB's semantics of
      the two ``rand(Np, d)`` calls in the equation.
    * Γ: 004 gives no value; a fixed fraction of the box width makes the step independent of
      parameter units. The steps do not shrink as the pack converges, so the positions keep
      jittering by about ``levy_scale``·(upper − lower) and the final values stay above plain
      GWO's on smooth problems; hystfit's least-squares polish removes that, or lower ``levy_scale``.
    * Algorithm 1 applies the Lévy update only when |A| < 1 and is ambiguous about the other
      case; we apply it to every wolf, as the README formulation states.
    """

    name = "igwo"
    title = "Improved grey wolf optimizer (chaos, nonlinear a, Lévy flight)"
    reference = "paper 004 §2.3 eq. 10–15"

    chaos_factor: float = setting(2.0, above=0, what="F of paper 004 eq. 10, which uses 2")
    levy_beta: float = setting(1.5, above=0, below=2)
    levy_scale: float = setting(0.01, at_least=0)

    def initial_population(self, rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        return chaos_init(rng, self.pop, lower, upper, self.chaos_factor)

    def convergence_factor(self, t: float, T: float) -> float:
        return nonlinear_convergence_factor(t, T)

    def perturb(self, x_sum: np.ndarray, lower: np.ndarray, upper: np.ndarray, rng: np.random.Generator) -> None:
        # eq. 12–14: X = Σ_k (X_k + Γ s_k) / 3; the three steps are drawn as their exact sum
        s = levy_steps(rng, x_sum.shape, self.levy_beta, n_sum=3)
        s *= self.levy_scale * (upper - lower)
        x_sum += s
