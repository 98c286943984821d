"""Generic per-sample numerical inverse of a model with memory.

At sample k the model's memory is known (it was advanced with the inputs already chosen), so
the output at k is a function of the single unknown u_k. For hysteresis models this one-step
map is monotone in u_k (increasing for positive gain). We bracket the target on a coarse grid
of candidates (one vectorized :meth:`Model.step` call), refine the bracket a few times
(each a vectorized call) and finish with linear interpolation inside the final bracket; the
memory is then advanced with the chosen u_k. A target outside the reachable range gives the
bound that comes closest (saturation), never an exception.
"""

from __future__ import annotations

import numpy as np


def invert_by_stepping(model, theta: np.ndarray, y_target: np.ndarray, dt: float, *,
                       u_range: tuple[float, float] | None = None, u0: float | None = None,
                       grid: int = 17, refinements: int = 4) -> np.ndarray:
    """Input u (N,) such that ``model.simulate_one(theta, u, dt) ≈ y_target``.

    Parameters
    ----------
    model : a model implementing ``initial_state`` and ``step``.
    theta : (d,) parameter vector.
    y_target : (N,) desired output (model output unit).
    dt : sample period (s).
    u_range : (lo, hi) search interval in V; default ±max(|y|)/gain-ish wide window derived
        from a probe of the model (±1e3 V when nothing better is known).
    u0 : input at the first sample; default: solved like every other sample from the reset state.
    grid, refinements : candidates per bracketing call and number of refinement calls; the
        final resolution is (hi − lo)/(grid−1)^(refinements+1) before interpolation.
    """
    y_target = np.asarray(y_target, dtype=np.float64)
    N = y_target.shape[0]
    lo, hi = u_range if u_range is not None else _default_range(model, theta, y_target, dt)
    u = np.empty(N)
    state = None
    u_prev = 0.0 if u0 is None else float(u0)
    for k in range(N):
        if state is None:
            state = model.initial_state(theta, u_prev, dt)
        a, b = lo, hi
        best_u, best_state = None, None
        for _ in range(refinements + 1):
            cand = np.linspace(a, b, grid)
            y, states = model.step(theta, state, u_prev, cand, dt)
            e = y - y_target[k]
            e = np.where(np.isfinite(e), e, np.inf)
            best_u, best_state, a, b = _bracket(cand, e, states)
            if a == b:
                break
        if a != b:
            # linear interpolation inside the final bracket, then one exact step
            ya, _ = model.step(theta, state, u_prev, np.array([a, b]), dt)
            ea, eb = ya[0] - y_target[k], ya[1] - y_target[k]
            if np.isfinite(ea) and np.isfinite(eb) and ea != eb and ea * eb <= 0:
                best_u = a - ea * (b - a) / (eb - ea)
            _, st = model.step(theta, state, u_prev, np.array([best_u]), dt)
            best_state = st[0]
        u[k] = best_u
        state = best_state
        u_prev = best_u
    return u


def _bracket(cand: np.ndarray, e: np.ndarray, states: np.ndarray):
    """Return the best candidate, its state and a bracket [a, b] around the sign change of e."""
    i_best = int(np.argmin(np.abs(e)))
    if e[i_best] == 0:
        return cand[i_best], states[i_best], cand[i_best], cand[i_best]
    sign = np.sign(e)
    change = np.flatnonzero(sign[:-1] * sign[1:] < 0)
    if change.size == 0:  # unreachable inside the range: saturate at the closest candidate
        return cand[i_best], states[i_best], cand[i_best], cand[i_best]
    j = change[np.argmin(np.abs(change - i_best))]
    return cand[i_best], states[i_best], cand[j], cand[j + 1]


def _default_range(model, theta, y_target, dt) -> tuple[float, float]:
    scale = getattr(model, "_inverse_range", None)
    if scale is not None:
        return scale(theta, y_target)
    return (-1e3, 1e3)
