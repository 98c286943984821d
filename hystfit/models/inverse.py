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


def refine_inverse(model, theta: np.ndarray, y_target: np.ndarray, dt: float, u_start: np.ndarray, *,
                   gain: float, iterations: int = 60, tol: float = 1e-4,
                   u_range: tuple[float, float] | None = None) -> np.ndarray:
    """Improve an inverse over the whole trajectory by iterative learning on the model itself.

    u ← u + λ·F[e]/gain, e = y_target − simulate(u), with F a zero-phase low-pass filter
    (cut-off at a tenth of the sample rate) and the step λ halved whenever the error grows; the
    best iterate is returned. Used as a safeguard where the per-sample inverse is unstable (a
    rate term whose sign makes the causal recursion diverge, e.g. LuGre with σ2 < 0): the
    trajectory-level iteration needs no causal recursion, only forward simulations. Stops when
    the RMSE falls below ``tol`` × the target's range.

    Parameters
    ----------
    gain : the model's static gain dy/du (output unit per V), sign included.
    """
    from scipy.signal import butter, sosfiltfilt

    y_target = np.asarray(y_target, float)
    u = np.asarray(u_start, float).copy()
    if not np.all(np.isfinite(u)):
        u = (y_target - y_target[0]) / gain
    span = max(float(np.ptp(y_target)), 1e-300)
    sos = butter(2, 0.2, output="sos") if y_target.size > 15 else None

    def err(v):
        with np.errstate(all="ignore"):
            e = y_target - model.simulate_one(theta, v, dt)
        return e, (float(np.sqrt(np.mean(e ** 2))) if np.all(np.isfinite(e)) else np.inf)

    e, best_rmse = err(u)
    best = u.copy()
    lam = 1.0
    for _ in range(iterations):
        if best_rmse <= tol * span:
            break
        step = sosfiltfilt(sos, e) if sos is not None else e
        cand = best + lam * step / gain
        if u_range is not None:
            cand = np.clip(cand, min(u_range), max(u_range))
        e_c, r_c = err(cand)
        if r_c < best_rmse:
            best, best_rmse, e = cand, r_c, e_c
            lam = min(1.0, lam * 1.5)
        else:
            lam *= 0.5
            if lam < 1e-4:
                break
    return best


def invert_from_rest(model, theta: np.ndarray, y_target: np.ndarray, dt: float, gain: float, offset: float,
                     u_range: tuple[float, float] | None = None) -> np.ndarray:
    """:func:`invert_by_stepping` for a model whose :meth:`simulate` starts at rest at the first
    input (zero state, no rate): the first sample is the static inverse u_0 = (y_0 − offset)/gain
    (0 for a zero gain; clipped to ``u_range``), the per-sample search continues from there."""
    y = np.asarray(y_target, float)
    if y.size == 0:
        return np.empty(0)
    u0 = (float(y[0]) - offset) / gain if gain != 0 else 0.0
    if u_range is not None:
        u0 = min(max(u0, min(u_range)), max(u_range))
    return invert_by_stepping(model, theta, y, dt, u_range=u_range, u0=u0)
