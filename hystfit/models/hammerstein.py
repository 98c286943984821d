"""Hammerstein model: PI static hysteresis followed by an identified linear state space (paper 003)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from .._jit import readonly
from .._lazy import lazy_module
from ..blocks.base import captures_at_one_rate
from ..blocks.lti import (LinearPartFields, LinearSS, Lti, _as_list, _fundamental, _zoh_second_order,  # noqa: F401
                          fit_linear_to_sine,
                          identify_linear_era, is_broadband, measure_gain_phase, ss_columns)
from ..errors import ConfigError, InputError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import play_matrix
from .base import Model
from .separable import linear_in_all
from .pi import PI, PlayOperators

# scipy submodules are imported on first use: keeps start-up fast
signal = lazy_module("scipy.signal")
linalg = lazy_module("scipy.linalg")
optimize = lazy_module("scipy.optimize")



# ----------------------------------------------------------------------------------------------
# Linear part
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# The model (its linear part is the ``lti`` block's code: hystfit.blocks.lti)
# ----------------------------------------------------------------------------------------------


@models.register
@dataclass(frozen=True)
class Hammerstein(Model, LinearPartFields, PlayOperators):
    r"""Hammerstein model: static PI hysteresis, then a fixed, identified linear discrete state space.

    .. math::

        v_k = \sum_{j=0}^{n-1} w_j F_{r_j}[u](k),\qquad
        x_{k+1} = A x_k + B v_k,\quad y_k = C x_k + D v_k + y_0

    (paper 003: play operator and PI eq. 1–3, linear part eq. 5, identified by correlation →
    impulse response → Hankel SVD, eq. 4–12; ``shared/papers/README.md``). The linear part
    starts in the equilibrium of its first input and has unit static gain, G(1) = 1, so the
    weights keep their :class:`PI` meaning (quasi-static loop) and y0 is the output offset.

    The linear part is *structure*, not a parameter: it is identified by a non-search
    procedure (:meth:`from_data`, :func:`identify_linear_era`, :func:`fit_linear_to_sine`) and
    stored in the structure fields below, so it round-trips through JSON
    (:meth:`structure`/:meth:`from_structure`); :meth:`adapt` fills only the PI thresholds.
    With no linear part (``order`` 0, the default) the model is the static PI — which is also
    what a generic fit of ``Hammerstein()`` gives, since :meth:`adapt` sees only the data scale:
    identify the linear part first (:meth:`from_data`) and fit the returned model.

    Structure
    ---------
    n_operators, placement, thresholds_V, nonnegative : the PI part, as in :class:`PI`.
    order : state dimension r of the linear part (0: none, y = v).
    A : r·r entries of A, row-major.   B, C : r entries each.   D : feedthrough (0 in paper 003).
    dt_s : sample period (s) the linear part was identified at; at another rate it is re-discretized
        exactly (:meth:`LinearSS.resampled`).
    linear_method : how the linear part was obtained ("era", "sine-gain-phase", "given", "none").
    singular_values : the leading Hankel singular values of an ERA identification (for reports:
        the gap that chose the order); empty otherwise.
    max_order, n_markov, feedthrough, correlation, era_order : options of the ERA identification
        (:func:`identify_linear_era`, ``era_order`` its forced ``order``), settable with
        ``--model-option``; ``feedthrough`` "auto" (default) keeps the paper's D = 0 unless D
        halves the simulation error.

    Parameters (θ)
    --------------
    w0 … w{n−1} : PI weights (output unit per V).   y0 : output offset (output unit).
    The output is linear in θ for the fixed linear part: :meth:`design_matrix` holds the
    filtered play outputs, so the optimum is one (non-negative) least-squares solve
    (:meth:`fit_weights`, :meth:`separable`).

    Inverse (:meth:`invert`): a stable, non-oscillating inverse of the linear part
    (:meth:`LinearSS.inverse_plan`: well-damped zeros inverted exactly, zeros far outside the
    unit circle reflected with their all-pass delay as a time advance — paper 003 §4.2's
    minimum-phase idea — and zeros near the unit circle, e.g. the z ≈ −1 pair a feedthrough
    brings, handled zero-phase by ZPETC), then the analytic PI inverse (eq. 17–20). The input
    is non-causal by a few samples (preview of the target).
    """

    name = "hammerstein"
    title = "Hammerstein (PI + identified linear state space)"
    reference = "paper 003 eq. 1–3 (PI), eq. 4–12 (correlation, Hankel SVD), §4.2 (stable inverse; ZPETC near the unit circle)"
    equation = "v = Σ_j w_j F_{r_j}[u],  x_{k+1} = A x_k + B v_k,  y_k = C x_k + D v_k + y0  (G(1) = 1)"
    rate_dependent = True
    resolution_option = "n_operators"

    linear_method: str = "none"

    def __post_init__(self) -> None:
        try:
            self.check_linear_part()
        except (ConfigError, ValueError) as exc:
            raise ConfigError(f"hammerstein: {exc}") from None
        try:
            self.pi
        except ConfigError as exc:
            raise ConfigError(f"hammerstein: {str(exc).removeprefix('pi: ')}") from None

    # ------------------------------------------------------------------ structure
    @property
    def pi(self) -> PI:
        """The static part as a classical :class:`PI` (same structure fields)."""
        return PI(self.n_operators, self.placement, self.thresholds_V, self.nonnegative)

    @property
    def lti(self) -> Lti:
        """The linear part as the ``lti`` block (same state space; its simulation, stepping and inverse)."""
        return Lti(order=self.order, A=self.A, B=self.B, C=self.C, D=self.D, dt_s=self.dt_s, method=self.linear_method,
                   singular_values=self.singular_values, max_order=self.max_order, n_markov=self.n_markov,
                   feedthrough=self.feedthrough, correlation=self.correlation, era_order=self.era_order)

    @property
    def linear(self) -> LinearSS:
        """The linear part as a :class:`LinearSS`."""
        return self.lti.linear

    def with_linear(self, lin: LinearSS) -> "Hammerstein":
        """This structure with the linear part ``lin`` (stored as given; normalize it first)."""
        return replace(self, order=int(lin.order), A=tuple(float(x) for x in np.ravel(lin.A)),
                       B=tuple(float(x) for x in lin.B), C=tuple(float(x) for x in lin.C), D=float(lin.D),
                       dt_s=float(lin.dt) if lin.order else None, linear_method=lin.method,
                       singular_values=tuple(float(x) for x in lin.singular_values))

    def structure_summary(self) -> str:
        """One sentence for reports: how the linear part was obtained and its modes (f_n, ζ from the
        discrete poles, p = e^{s·Ts})."""
        if self.order == 0:
            return "Linear part: none (static PI; identify it from captures at ≥ 2 frequencies or a broadband one)."
        how = {"era": "by correlation → impulse response → Hankel SVD (paper 003 eq. 4–12) from a broadband capture",
               "sine-gain-phase": "as a second-order model fitted to the gain and phase measured per frequency "
                                  "(sine-only data: paper 003's Hankel route needs a broadband capture)",
               }.get(self.linear_method, f"({self.linear_method})")
        s = np.log(self.linear.poles().astype(complex)) / self.dt_s
        modes = sorted({(round(abs(p) / (2 * np.pi), 6), round(-p.real / abs(p), 6)) for p in s if abs(p) > 0})
        text = ", ".join(f"f_n {fn:.4g} Hz ζ {z:.3g}" for fn, z in modes)
        note = ""
        if self.linear_method == "sine-gain-phase" and any(fn >= 0.449 / self.dt_s or z <= 0.0101 for fn, z in modes):
            note = (" The mode lies at a limit of the fit (f_n ≤ 0.45·f_s, ζ ≥ 0.01): the captures' frequencies "
                    "are too far below the resonance to determine it; a broadband capture would.")
        return f"Linear part: order {self.order}, identified {how}; modes: {text or 'none'}.{note}"

    @classmethod
    def example(cls, scale: DataScale, fn_Hz: float = 1200.0, zeta: float = 0.15) -> "Hammerstein":
        """A representative structure for documentation and the model contract suite: thresholds
        from ``scale`` and a unit-gain second-order linear part (``fn_Hz``, ``zeta``: a P-721-like
        stage, capped at a tenth of the sample rate), discretized at ``scale.dt`` with a zero-order
        hold. The default ``Hammerstein()`` has no linear part until :meth:`prepare` identifies one.
        """
        fn = min(float(fn_Hz), 0.1 / scale.dt)
        b, a = _zoh_second_order(1.0, fn, float(zeta), scale.dt)
        lin = LinearSS.from_tf(b, a, scale.dt).normalized()
        return cls().adapt(scale).with_linear(lin)

    def prepare(self, captures) -> "Hammerstein":
        """Identify the linear part once from all captures (:meth:`from_data`), unless already set.

        ERA when a capture is broadband, otherwise the second-order fit to the gain/phase measured
        per frequency across the captures. The thresholds are left to :meth:`adapt`, so each
        operating condition gets operators spread over its own input range.
        """
        if self.order > 0 or self.linear_method != "none":
            return self
        caps = captures_at_one_rate(captures, "hammerstein", " before identifying the linear part")
        try:
            fitted = type(self).from_data([c.u for c in caps], [c.y for c in caps], caps[0].dt, self.n_operators,
                                          placement=self.placement, nonnegative=self.nonnegative,
                                          max_order=self.max_order, n_markov=self.n_markov,
                                          feedthrough=self.feedthrough, correlation=self.correlation,
                                          order=self.era_order)
        except InputError as exc:  # the captures' names: the arrays' functions do not know them
            names = ", ".join(Path(c.source).name for c in caps[:4]) + (", …" if len(caps) > 4 else "")
            raise InputError(f"{exc} (captures: {names})") from None
        return replace(fitted, thresholds_V=self.thresholds_V)

    def adapt(self, scale: DataScale) -> "Hammerstein":
        """Fill the PI thresholds from the data; the linear part is left as identified."""
        if self.thresholds_V is not None:
            return self
        return replace(self, thresholds_V=self.pi.adapt(scale).thresholds_V)

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        return self.pi.params(scale)

    # ------------------------------------------------------------------ simulation
    def linear_at(self, dt: float) -> LinearSS:
        """The linear part at sample period ``dt`` (exact re-discretization when it differs from ``dt_s``)."""
        return self.lti.linear_at(dt)

    def design_matrix(self, u: np.ndarray, dt: float) -> np.ndarray:
        """Regressors (N, n + 1): the play outputs filtered by the linear part, and ones (offset).

        y = Φ θ exactly (the linear part is fixed and has unit static gain).
        """
        u = readonly(u)
        F = self.linear_at(dt).filter(play_matrix(u, self.pi.r))
        return np.hstack([F, np.ones((u.shape[0], 1))])

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, self.n_operators + 1)
        return theta @ self.design_matrix(u, dt).T

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        phi_t = np.ascontiguousarray(self.design_matrix(u, dt).T)  # filtered plays, computed once
        d = self.n_operators + 1
        return lambda theta: self.check_theta(theta, d) @ phi_t

    def separable(self):
        """Every parameter is linear (thresholds and linear part fixed): one bounded least-squares solve."""
        return linear_in_all(self.design_matrix, self.n_operators + 1)

    def fit_weights(self, us: Sequence[np.ndarray], ys: Sequence[np.ndarray], dt: float) -> np.ndarray:
        """Least-squares θ = [w, y0] pooled over captures (weights ≥ 0 if ``nonnegative``): the exact optimum."""
        Phi = np.vstack([self.design_matrix(u, dt) for u in _as_list(us)])
        y = np.concatenate(_as_list(ys))
        n = self.n_operators
        lo = np.r_[np.full(n, 0.0 if self.nonnegative else -np.inf), -np.inf]
        hi = np.full(n + 1, np.inf)
        if self.nonnegative and DataScale.from_arrays(_as_list(us), _as_list(ys), [dt] * len(_as_list(us))).sign < 0:
            lo, hi = np.r_[np.full(n, -np.inf), -np.inf], np.r_[np.zeros(n), np.inf]  # falling output: w ≤ 0
        return optimize.lsq_linear(Phi, y, bounds=(lo, hi), method="bvls", tol=1e-12).x

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """[play states (n), linear state deviations (r), first PI output v0] after the first sample u0."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        r = self.pi.r
        plays = np.maximum(u0 - r, np.minimum(u0 + r, 0.0))
        return np.r_[plays, np.zeros(self.order), plays @ t[: self.n_operators]]

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and states (C, n + r + 1): the
        plays, then the ``lti`` block's step (state deviations and the first PI output v0).

        With D = 0 the output at the new sample does not depend on u_new (one-sample delay), so
        the generic per-sample numerical inverse does not apply; :meth:`invert` is analytic.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        state = np.asarray(state, dtype=np.float64)
        u_new = np.atleast_1d(np.asarray(u_new, dtype=np.float64))
        r = self.pi.r
        plays = np.maximum(u_new[:, None] - r[None, :], np.minimum(u_new[:, None] + r[None, :], state[None, :n]))
        y, lin_state = self.lti.step(np.empty(0), state[n:], plays @ t[:n], dt)
        return y + t[n], np.hstack([plays, lin_state])

    # ------------------------------------------------------------------ inverse
    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) for a smooth target: v = G_mp⁻¹[y − y0] (advanced), then u = PI⁻¹[v].

        See :meth:`LinearSS.inverse_filter` for the linear step (exact for a minimum-phase
        part, a low-frequency approximation otherwise) and :meth:`PI.invert` for the analytic
        PI inverse (paper 003 eq. 17–20). ``u_range`` is ignored (both steps are analytic).
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        if t.size != n + 1:
            raise ValueError(f"hammerstein: theta must have {n + 1} entries, got {t.size}")
        v = self.linear_at(dt).inverse_filter(np.asarray(y_target, dtype=np.float64) - t[n])
        return self.pi.invert(np.r_[t[:n], 0.0], v, dt)

    # ------------------------------------------------------------------ identification
    @classmethod
    def from_data(cls, captures_u: Sequence[np.ndarray], captures_y: Sequence[np.ndarray], dt: float,
                  n_operators: int = 10, *, method: str = "auto", max_order: int = 8,
                  n_markov: int | None = None, feedthrough: "bool | str" = "auto", correlation: str = "exact",
                  order: int | None = None, iterations: int | None = None,
                  sine_tol: float = 1e-5, placement: str = "uniform", nonnegative: bool = True) -> "Hammerstein":
        """Identify the linear part from captures and return the model with it fixed (unit static gain).

        Two-step identification in the spirit of paper 003 §3 (static PI, then the linear part
        from the PI output), alternated:

        * ``method="era"`` (chosen by ``"auto"`` when a capture is broadband, :func:`is_broadband`):
          the first pass identifies the linear part from v = u (:func:`identify_linear_era` on
          the broadband captures); each further pass solves the PI weights by least squares
          through that linear part and re-identifies it from v = PI output.
        * ``method="sine"`` (sine-only data): the PI is first fitted statically on the
          lowest-frequency captures (paper 003 identifies it at 1 Hz), then the second-order
          model is fitted to the gain/phase Y/V measured per frequency
          (:func:`fit_linear_to_sine`), weights re-solved, and so on until the model's response
          at the measured frequencies changes by less than ``sine_tol`` (relative) between
          passes. The alternation converges linearly (≈ × 0.6 per pass: the static start
          attributes part of the dynamic lag to the hysteresis), hence up to 60 passes, each
          warm-started.

        The linear part is scaled to unit static gain (the gain goes to the PI weights). The
        returned model's θ still has to be fitted (:meth:`fit_weights` or any optimizer).

        Parameters
        ----------
        captures_u, captures_y : sequences of input (V) and output arrays, one pair per capture.
        dt : common sample period (s).
        n_operators, placement, nonnegative : the PI structure (thresholds from the data range).
        max_order, n_markov, feedthrough, correlation, order : passed to :func:`identify_linear_era`
            (and stored in the returned structure; ``order`` as ``era_order``).
        iterations : number of passes (default 2 for ERA, at most 60 for the sine route).
        """
        us, ys = _as_list(captures_u), _as_list(captures_y)
        if not us or len(us) != len(ys) or any(a.shape != b.shape for a, b in zip(us, ys)):
            raise InputError("hammerstein: need matching, non-empty lists of input and output captures")
        if method not in ("auto", "era", "sine"):
            raise ConfigError(f"hammerstein: method must be 'auto', 'era' or 'sine', got {method!r}")
        scale = DataScale.from_arrays(us, ys, [dt] * len(us))
        base = cls(n_operators, placement, None, nonnegative, max_order=max_order, n_markov=n_markov,
                   feedthrough=feedthrough, correlation=correlation, era_order=order).adapt(scale)
        broad = [is_broadband(u) for u in us]
        if method == "auto":
            method = "era" if any(broad) else "sine"
        if method == "era":
            sel = [i for i, b in enumerate(broad) if b] or list(range(len(us)))
            vs = [us[i] for i in sel]
        else:
            sel = list(range(len(us)))
            freqs = np.array([_fundamental(u) for u in us])
            low = [i for i in sel if freqs[i] <= 1.01 * freqs.min()]
            theta = base.fit_weights([us[i] for i in low], [ys[i] for i in low], dt)  # static PI (order 0)
            vs = [base.pi.design_matrix(us[i], dt)[:, :n_operators] @ theta[:n_operators] for i in sel]
        n_iter = int(iterations) if iterations is not None else (2 if method == "era" else 60)
        model = base
        start = None
        G_prev = None
        for it in range(max(1, n_iter)):
            if method == "era":
                lin = identify_linear_era(vs, [ys[i] for i in sel], dt, max_order=max_order, n_markov=n_markov,
                                          feedthrough=feedthrough, correlation=correlation, order=order)
            else:
                lin = fit_linear_to_sine(vs, [ys[i] for i in sel], dt, start=start)
                start = lin.continuous
            if not lin.is_stable:
                raise InputError(
                    f"hammerstein: the identified linear part is unstable (spectral radius "
                    f"{lin.spectral_radius:.4f}); use a longer or richer capture or a lower max_order")
            model = base.with_linear(lin.normalized())
            if method == "sine":
                G = model.linear.freqresp(np.array([f for f, _ in lin.fit_points]))
                if G_prev is not None and np.max(np.abs(G / G_prev - 1.0)) < sine_tol:
                    break
                G_prev = G
            if it + 1 < n_iter:
                theta = model.fit_weights(us, ys, dt)
                vs = [model.pi.design_matrix(us[i], dt)[:, :n_operators] @ theta[:n_operators] for i in sel]
        return model
