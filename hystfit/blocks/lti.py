"""Linear time-invariant stage identified from data: the Hankel/ERA state space of paper 003.

One home for the identified linear part: :class:`LinearSS` (a SISO discrete state space with
filtering, frequency response, minimum-phase inversion), its identification
(:func:`identify_linear_era`: correlation → impulse response → Hankel SVD, paper 003 eq. 4–12;
:func:`fit_linear_to_sine`: second-order fit to measured gain/phase for sine-only data), and the
``lti`` block that puts it after any hysteresis model (``pi+lti`` … ``gpi+lti``). The Hammerstein
model (:mod:`hystfit.models.hammerstein`) uses the same code.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from .._jit import njit, readonly
from .._lazy import lazy_module
from ..errors import ConfigError, InputError
from ..params import DataScale, Param
from ..registry import blocks
from .base import Block, captures_at_one_rate

# scipy submodules are imported on first use: keeps start-up fast
signal = lazy_module("scipy.signal")
linalg = lazy_module("scipy.linalg")
optimize = lazy_module("scipy.optimize")

#: relative tolerance on the sample period when a linear part identified at one rate is used at another
DT_RTOL = 1e-6
#: zeros with |z| above this (or oscillating, Re z < 0 and |z| > 1/2) are not inverted exactly
#: (:meth:`LinearSS.inverse_plan`)
ACCEPTABLE_RADIUS = 0.99


@njit(cache=True)
def ss_columns(A, B, C, D, gdc, x):
    """Discrete state space applied to every column of x (N, M), each from rest at x[0, m].

    s_{k+1} = A s_k + B d_k,  y_k = G(1)·x_0 + C s_k + D d_k,  d_k = x_k − x_0,  s_0 = 0

    which is exactly the response of x_{k+1} = A x_k + B v_k, y_k = C x_k + D v_k started in
    the equilibrium of the constant input x_0 (G(1) = C (I − A)⁻¹ B + D is passed as ``gdc``),
    computed on deviations so that a large offset does not pass through the poles.
    Layout: time outermost, columns innermost.

    Parameters
    ----------
    A : (r, r), B, C : (r,), D, gdc : float, x : (N, M).

    Returns
    -------
    (N, M) outputs.
    """
    N, M = x.shape
    r = A.shape[0]
    out = np.empty((N, M))
    if N == 0:
        return out
    x0 = x[0].copy()
    s = np.zeros((r, M))
    sn = np.zeros((r, M))
    d = np.empty(M)
    for k in range(N):
        for m in range(M):
            d[m] = x[k, m] - x0[m]
            out[k, m] = gdc * x0[m] + D * d[m]
        for i in range(r):
            ci = C[i]
            for m in range(M):
                out[k, m] += ci * s[i, m]
        for i in range(r):
            bi = B[i]
            for m in range(M):
                sn[i, m] = bi * d[m]
            for j in range(r):
                aij = A[i, j]
                for m in range(M):
                    sn[i, m] += aij * s[j, m]
        for i in range(r):
            for m in range(M):
                s[i, m] = sn[i, m]
    return out


@dataclass(frozen=True, eq=False)
class LinearSS:
    """A SISO discrete state space x_{k+1} = A x_k + B v_k, y_k = C x_k + D v_k at period ``dt``.

    ``order`` 0 is the identity (no dynamics: y = v). ``singular_values`` are the Hankel
    singular values of an ERA identification (empty otherwise); ``method`` says how the model
    was obtained ("era", "sine-gain-phase", "given", "identity"); ``fit_points`` holds the
    measured (frequency Hz, complex gain) pairs of a sine fit and ``continuous`` its fitted
    continuous-time (K, f_n Hz, ζ).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    dt: float
    order: int
    singular_values: np.ndarray = field(default_factory=lambda: np.empty(0))
    method: str = "given"
    D: float = 0.0
    fit_points: tuple = ()
    continuous: tuple = ()

    @classmethod
    def identity(cls, dt: float | None = None) -> "LinearSS":
        return cls(np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(dt or 0.0), 0, method="identity")

    @classmethod
    def from_tf(cls, b: np.ndarray, a: np.ndarray, dt: float, method: str = "given") -> "LinearSS":
        """From a transfer function b(z⁻¹)/a(z⁻¹) (scipy ``lfilter`` convention)."""
        with warnings.catch_warnings():  # leading zero numerator coefficients (D = 0) are expected
            warnings.simplefilter("ignore", signal.BadCoefficients)
            A, B, C, D = signal.tf2ss(np.asarray(b, float), np.asarray(a, float))
        return cls(A, B.ravel(), C.ravel(), float(dt), A.shape[0], method=method, D=float(D.ravel()[0]))

    # ------------------------------------------------------------------ properties
    def dc_gain(self) -> float:
        """G(1) = C (I − A)⁻¹ B + D (1 for the identity)."""
        if self.order == 0:
            return 1.0
        return float(self.C @ np.linalg.solve(np.eye(self.order) - self.A, self.B) + self.D)

    def normalized(self) -> "LinearSS":
        """The same dynamics scaled to unit static gain (C and D divided by G(1))."""
        g = self.dc_gain()
        if not np.isfinite(g) or g <= 0:
            raise InputError(
                f"the identified linear part has static gain {g:g} (must be positive and finite to carry the "
                "PI weights); use a longer or richer capture, or a lower max_order")
        if self.order == 0:
            return self
        return replace(self, C=self.C / g, D=self.D / g)

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A) if self.order else np.empty(0, complex)

    @property
    def spectral_radius(self) -> float:
        p = self.poles()
        return float(np.max(np.abs(p))) if p.size else 0.0

    @property
    def is_stable(self) -> bool:
        return self.spectral_radius < 1.0

    def tf(self) -> tuple[np.ndarray, np.ndarray]:
        """Transfer function (b, a), coefficients of z⁻¹ (length order + 1 each; b[0] = D)."""
        if self.order == 0:
            return np.array([1.0]), np.array([1.0])
        den = np.real(np.poly(self.A))
        num = np.real(np.poly(self.A - np.outer(self.B, self.C))) - den + self.D * den
        return num, den

    def freqresp(self, f_Hz: np.ndarray) -> np.ndarray:
        """Complex frequency response G(e^{iωT}) at frequencies ``f_Hz``."""
        f = np.atleast_1d(np.asarray(f_Hz, dtype=np.float64))
        if self.order == 0:
            return np.ones(f.shape, complex)
        z = np.exp(2j * np.pi * f * self.dt)
        eye = np.eye(self.order)
        return np.array([self.C @ np.linalg.solve(zk * eye - self.A, self.B) + self.D for zk in z])

    def impulse(self, n: int) -> np.ndarray:
        """Markov parameters h(0) = D, h(k) = C A^{k−1} B, k = 1 … n−1 (the identity: 1, 0, 0, …)."""
        h = np.zeros(n)
        if n == 0:
            return h
        if self.order == 0:
            h[0] = 1.0
            return h
        h[0] = self.D
        x = self.B.astype(np.float64)
        for k in range(1, n):
            h[k] = self.C @ x
            x = self.A @ x
        return h

    # ------------------------------------------------------------------ filtering
    def filter(self, x: np.ndarray) -> np.ndarray:
        """Response to x (N,) or to every column of x (N, M), from rest at the first sample."""
        x = np.asarray(x, dtype=np.float64)
        if self.order == 0:
            return x.copy()
        X = readonly(x[:, None] if x.ndim == 1 else x)
        Y = ss_columns(readonly(self.A), readonly(self.B), readonly(self.C),
                       float(self.D), self.dc_gain(), X)
        return Y[:, 0] if x.ndim == 1 else Y

    # ------------------------------------------------------------------ inversion
    def inverse_plan(self, radius: float = ACCEPTABLE_RADIUS) -> "InversePlan":
        """How :meth:`inverse_filter` inverts this part: its zeros sorted into three kinds.

        With b(z⁻¹) = z^{−d}·b_t(z⁻¹) (leading coefficients below 1e-9 of the largest are the pure
        delay d) and the zeros z_i of b_t:

        * **acceptable** — |z| ≤ ``radius`` (0.99) and not oscillating (Re z ≥ 0, or |z| ≤ 1/2): inverted
          exactly; the inverse's modes are then stable and slower than f_s/4 or decay ≥ 2× per
          sample.
        * **reflected** — outside the unit circle (|z| > 1/``radius``) with an acceptable mirror
          image 1/z̄: replaced by 1/z̄ (the magnitude response is kept, |e^{iω} − z| =
          |z|·|e^{iω} − 1/z̄|) and the removed all-pass approximated by its group delay at DC,
          ``tau_allpass`` = Σ [Re 1/(1 − z'_i) − Re 1/(1 − z_i)] samples, a time advance
          (paper 003 §4.2 drops right-half-plane zeros instead; reflection keeps the magnitude).
        * **zero-phase** — all the others: on or near the unit circle (the z ≈ −1 zeros of a
          bilinear stage or of a fast zero-order hold), or inside but oscillating (Re z < 0,
          |z| > 1/2), whose exact inverse would alternate sign sample to sample. They are not
          inverted: ZPETC (Tomizuka 1987) applies b_u(z)/b_u(1)² instead, b_u(z⁻¹) = Π(1 − z_i z⁻¹)
          over these zeros — a non-causal FIR of their count in samples — so the plant times the
          feedforward is b_u(z⁻¹)·b_u(z)/b_u(1)² = |b_u(e^{iω})|²/b_u(1)²: no phase error, unit
          static gain, and a gain that falls to zero where b_u vanishes (Nyquist for z = −1)
          instead of an inverse that blows up there. Gain error at low frequency O(ω²).

        The static gain is kept exactly: b_a(1)·b_u(1) = b_t(1).
        """
        b, a = self.tf()
        big = np.max(np.abs(b))
        if not np.isfinite(big) or big == 0:
            raise ConfigError("the linear part has a zero numerator; it cannot be inverted")
        d = 0
        while d < b.size - 1 and abs(b[d]) <= 1e-9 * big:
            d += 1
        bt = b[d:]
        z = np.roots(bt) if bt.size > 1 else np.empty(0, complex)

        def acceptable(x):
            return (np.abs(x) <= radius) & ((x.real >= 0) | (np.abs(x) <= 0.5))

        with np.errstate(divide="ignore", invalid="ignore"):
            mirror = 1.0 / np.conj(z)
        keep = acceptable(z)
        refl = ~keep & (np.abs(z) > 1.0 / radius) & acceptable(mirror)
        zp = ~keep & ~refl
        tau = float(np.sum(np.real(1.0 / (1.0 - mirror[refl])) - np.real(1.0 / (1.0 - z[refl]))))
        b_u = np.real(np.poly(z[zp])) if np.any(zp) else np.array([1.0])
        za = np.r_[z[keep], mirror[refl]]
        b_a = np.real(np.poly(za)) if za.size else np.array([1.0])
        s_t, s_a, s_u = float(np.sum(bt)), float(np.sum(b_a)), float(np.sum(b_u))
        if s_t == 0 or s_a == 0 or s_u == 0:
            raise ConfigError("the linear part has a zero at z = 1 (no static gain); it cannot be inverted")
        b_a = b_a * (s_t / (s_a * s_u))
        return InversePlan(b_a=b_a, a=a, delay=d, tau_allpass=tau, b_u=b_u, zeros=z, kinds=tuple(
            "acceptable" if k else ("reflected" if r else "zero-phase") for k, r in zip(keep, refl)))

    def inverse_filter(self, y: np.ndarray, radius: float = ACCEPTABLE_RADIUS) -> np.ndarray:
        """Input v (N,) whose response follows y (N,): a stable, non-oscillating inverse (:meth:`inverse_plan`).

        v = (a / b_a)[ b_u(z)/b_u(1)² [y advanced by d + τ_allpass samples] ]: the fractional
        advance by linear interpolation, y held after its last sample, the inverse filter at
        rest at its first input. Exact for a part whose zeros are all acceptable; otherwise
        zero-phase (ZPETC) for the zeros near the unit circle and a low-frequency delay for the
        reflected ones. The output is non-causal by d + τ + (number of zero-phase zeros)
        samples: a preview of the target.
        """
        y = np.asarray(y, dtype=np.float64)
        if self.order == 0:
            return y.copy()
        plan = self.inverse_plan(radius)
        N = y.shape[0]
        k = np.arange(N, dtype=np.float64)
        w = np.interp(k + plan.delay + plan.tau_allpass, k, y)
        s = plan.b_u.size - 1
        if s:
            padded = np.r_[w, np.full(s, w[-1])]
            w = sum(c * padded[j: j + N] for j, c in enumerate(plan.b_u)) / float(np.sum(plan.b_u)) ** 2
        zi = signal.lfilter_zi(plan.a, plan.b_a) * w[0]
        v, _ = signal.lfilter(plan.a, plan.b_a, w, zi=zi)
        return v

    # ------------------------------------------------------------------ other sample rates
    def to_continuous(self, method: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The continuous state space (A_c, B_c, C_c, D_c) this discrete part is the image of.

        ``method``: "zoh" — sampled behind a zero-order hold (A = e^{A_c T}; the matrix logarithm
        of [[A, B], [0, 1]] = T·[[A_c, B_c], [0, 0]]); "bilinear" — the Tustin image
        (A_c = (2/T)(A − I)(A + I)⁻¹, scipy's bilinear realization inverted exactly); "auto" —
        zero-order hold for a strictly proper part (D = 0: paper 003's form, a sample-and-hold
        drive) and bilinear when it has feedthrough (a smooth, not held, input; hystfit's
        virtual actuator's stage is bilinear). Refused when no real continuous system maps to it
        (a pole on the negative real axis: z ≈ −1 for bilinear, any z < 0 for zero-order hold).
        """
        method = self._continuous_method(method)
        r, T = self.order, self.dt
        A, B, C = self.A, self.B.reshape(r, 1), self.C.reshape(1, r)
        if method == "zoh":
            M = np.zeros((r + 1, r + 1))
            M[:r, :r], M[:r, r:] = A, B
            M[r, r] = 1.0
            if np.any((np.abs(self.poles().imag) < 1e-12) & (self.poles().real <= 0)):
                raise ConfigError(f"the linear part has a pole on the negative real axis ({self._pole_text()}): "
                                  "it is not a zero-order-hold sample of a continuous system; it cannot be resampled")
            L = linalg.logm(M)
            L = np.real(L) / T
            return L[:r, :r], L[:r, r], self.C.copy(), float(self.D)
        eye = np.eye(r)
        if np.min(np.abs(self.poles() + 1.0)) < 1e-9:
            raise ConfigError(f"the linear part has a pole at z = −1 ({self._pole_text()}): it is not the bilinear "
                              "image of a continuous system; it cannot be resampled")
        Ac = (2.0 / T) * np.linalg.solve((A + eye).T, (A - eye).T).T
        ima = eye - 0.5 * T * Ac
        Bc = ima @ B / T
        Cc = C @ ima
        Dc = float(self.D - 0.5 * (Cc @ B)[0, 0])  # scipy: D = D_c + ½·C_c·B (B discrete)
        return Ac, Bc.ravel(), Cc.ravel(), Dc

    def _continuous_method(self, method: str) -> str:
        if method not in ("auto", "zoh", "bilinear"):
            raise ConfigError(f"resampling method must be 'auto', 'zoh' or 'bilinear', got {method!r}")
        if method == "auto":
            return "zoh" if self.D == 0.0 else "bilinear"
        return method

    def _pole_text(self) -> str:
        return ", ".join(f"{p:.4g}" for p in self.poles())

    def resampled(self, dt: float, method: str = "auto") -> "LinearSS":
        """The same continuous system (:meth:`to_continuous`) discretized at period ``dt`` by the same
        method: exact re-discretization, so a part identified at 5 kHz simulates and inverts at
        10 kHz. The static gain is kept exactly. Returns ``self`` when ``dt`` equals its period."""
        if self.order == 0:
            return replace(self, dt=float(dt))
        if abs(dt - self.dt) <= DT_RTOL * self.dt:
            return self
        method = self._continuous_method(method)
        Ac, Bc, Cc, Dc = self.to_continuous(method)
        r = self.order
        A, B, C, D, _ = signal.cont2discrete((Ac, Bc.reshape(r, 1), Cc.reshape(1, r), np.array([[Dc]])), float(dt),
                                             method=method)
        return replace(self, A=np.asarray(A), B=np.asarray(B).ravel(), C=np.asarray(C).ravel(), dt=float(dt),
                       D=float(np.asarray(D).ravel()[0]))


@dataclass(frozen=True, eq=False)
class InversePlan:
    """:meth:`LinearSS.inverse_plan`: v = (a/b_a)[b_u(z)/b_u(1)² [y(k + delay + tau_allpass)]]."""

    b_a: np.ndarray
    a: np.ndarray
    delay: int
    tau_allpass: float
    b_u: np.ndarray
    zeros: np.ndarray
    kinds: tuple[str, ...]


def _correlations(v: np.ndarray, y: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """Sums S_uu(k) = Σ_{i≥k} v_i v_{i−k} and S_yu(k) = Σ_{i≥k} y_i v_{i−k}, k = 0 … M (paper 003 eq. 4, times N)."""
    N = v.shape[0]
    nfft = 1 << int(math.ceil(math.log2(2 * N)))
    Fv = np.fft.rfft(v, nfft)
    Fy = np.fft.rfft(y, nfft)
    ruu = np.fft.irfft(Fv * np.conj(Fv), nfft)[: M + 1]
    ryu = np.fft.irfft(Fy * np.conj(Fv), nfft)[: M + 1]
    return ruu, ryu


def _windowed_normal_equations(v: np.ndarray, y: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Normal equations of eq. 6 over the samples where every lag exists (covariance method).

    G[j, k] = Σ_{i=M}^{N−1} (v_{i−j} − m_j)(v_{i−k} − m_k),  g[k] = Σ_{i=M}^{N−1} (y_i − ȳ)(v_{i−k} − m_k),
    j, k = 0 … M, with m_j, ȳ the window means (an exact per-capture intercept). Built in
    O(N·M) by cumulative lagged products, G[j, j+ℓ] = c_ℓ(N−1−j) − c_ℓ(M−1−j),
    c_ℓ(p) = Σ_{q≤p} v_q v_{q−ℓ}.
    """
    N = v.shape[0]
    L = N - M
    G = np.empty((M + 1, M + 1))
    j = np.arange(M + 1)
    for ell in range(M + 1):
        prod = v[ell:] * v[: N - ell]  # index q − ell for q = ell … N−1
        cs = np.concatenate([[0.0], np.cumsum(prod)])  # cs[t] = Σ of the first t products
        jj = j[: M + 1 - ell]
        # Σ_{q = M−j}^{N−1−j} v_q v_{q−ell}  →  products at positions q − ell
        vals = cs[N - jj - ell] - cs[M - jj - ell]
        G[jj, jj + ell] = vals
        G[jj + ell, jj] = vals
    csv = np.concatenate([[0.0], np.cumsum(v)])
    s = csv[N - j] - csv[M - j]  # Σ_{i=M}^{N−1} v_{i−j}
    yw = y[M:]
    g = np.array([np.dot(yw, v[M - k: N - k]) for k in range(M + 1)])
    G -= np.outer(s, s) / L
    g -= s * (yw.sum() / L)
    return G, g, L


def _as_list(x) -> list[np.ndarray]:
    if isinstance(x, np.ndarray) and x.ndim == 1:
        return [np.asarray(x, dtype=np.float64)]
    return [np.asarray(a, dtype=np.float64).ravel() for a in x]


def identify_linear_era(v, y, dt: float, max_order: int = 8, n_markov: int | None = None, *,
                        order: int | None = None, feedthrough: "bool | str" = "auto", correlation: str = "exact",
                        ridge: float = 1e-9) -> LinearSS:
    r"""Linear discrete state space from input/output data by correlation analysis + Hankel SVD (paper 003 §2.3).

    1. Correlations (eq. 4), pooled over captures, means removed:
       R_uu(k) = (1/N) Σ_{i=k}^{N−1} v_i v_{i−k},  R_yu(k) = (1/N) Σ_{i=k}^{N−1} y_i v_{i−k}.
    2. Impulse response α from eq. 6, Σ_j α(j) R_uu(k − j) = R_yu(k), k = 0 … M.
       ``correlation="toeplitz"`` is the paper's route: eq. 4's correlations over the whole
       record and a symmetric Toeplitz (Levinson) solve. Its correlations mix samples whose
       lags fall before the record's start, an error of order (impulse-response length)/N
       that the paper avoids with a periodic input ("N … in one period"); on a 1 s,
       10 kHz non-periodic PRBS it is ≈ 1.5 % of the impulse response and buries the weak
       modes. ``correlation="exact"`` (default) sums eq. 4 only over the samples where every
       lag exists (the covariance method: the exact least-squares impulse response of the
       record, window means removed per capture) and solves the (non-Toeplitz) normal
       equations by Cholesky. Both add ``ridge`` × the mean diagonal to the diagonal.
    3. Hankel matrices H = [α(i + j − 1)] and H₁ = [α(i + j)] (eq. 7, 11), i, j = 1 … M/2; SVD
       H = U Σ Vᵀ (eq. 9); order r at the singular-value gap: the largest ratio σ_i/σ_{i+1},
       i ≤ ``max_order`` (unless ``order`` is given).
    4. C = first row of U₁Σ₁^{1/2}, B = first column of Σ₁^{1/2}V₁ᵀ (eq. 10),
       A = Σ₁^{−1/2} U₁ᵀ H₁ V₁ Σ₁^{−1/2} (eq. 12).

    Feedthrough. Paper 003 assumes D = 0 and sums eq. 6 from j = 1 (``feedthrough=False``).
    ``feedthrough=True`` starts the sum at j = 0 and estimates D = α(0) too: the sampled response
    of a continuous stage to a smooth (not sample-and-hold) input — and hystfit's virtual
    actuator, whose dynamics are a bilinear filter — has a first Markov parameter of ~10 % of
    the static gain, which D = 0 cannot represent. ``feedthrough="auto"`` (default) keeps the
    paper's D = 0 unless the data demand D: both are realized from the same normal equations,
    each is simulated on the captures (from rest, means removed), and D is kept only when it at
    least halves the sum of squared errors (:data:`FEEDTHROUGH_SSE_RATIO`; an unstable or
    non-finite D = 0 realization counts as infinite error). Measured on
    ``sample_data/broadband`` (PRBS + steps from v = u): RMSE 6.7 µm with D = 0 (a spurious
    mode at z ≈ −1 from the PRBS's spectral nulls; alternating with the PI weights does not
    remove it) against 0.099 µm with D, so D is kept there; on zero-order-hold data α(0) ≈ 0
    and D = 0 is kept. A feedthrough brings zeros near z = −1; :meth:`LinearSS.inverse_filter`
    handles them without an oscillating inverse.

    Parameters
    ----------
    v : (N,) intermediate input (the PI output, or simply u), or a sequence of captures.
    y : (N,) output, or a sequence matching ``v``.
    dt : sample period (s).
    max_order : largest order considered at the gap (default 8).
    n_markov : number M of Markov parameters (even; default min(1000, N_min/3)). They must cover
        the decay of the impulse response (the Hankel matrices are M/2 × M/2).
    order : force the order instead of the gap rule.
    feedthrough : True (estimate D = α(0)), False (the paper's D = 0) or "auto" (default: D = 0
        unless D halves the simulation error, see above).
    correlation : "exact" (default) or "toeplitz" (paper 003 eq. 4 + Levinson), see step 2.
    ridge : Tikhonov regularization relative to the mean input power (guards against spectral
        nulls of the input, e.g. at the clock frequency of a PRBS: the response there is
        undetermined; keep the compared band where the input has energy).

    Order selection needs the weakest retained mode above the noise floor of the Hankel
    singular values: the gap rule picks too low an order when a weak mode (paper 003 eq. 16's
    6th, σ₆/σ₁ ≈ 1.6 %) drowns in the noise amplified at the input's spectral nulls.

    Returns
    -------
    :class:`LinearSS` with ``method="era"`` and the Hankel singular values.
    """
    vs, ys = _as_list(v), _as_list(y)
    if len(vs) != len(ys) or any(a.shape != b.shape for a, b in zip(vs, ys)):
        raise InputError("identify_linear_era: v and y must be arrays (or lists of arrays) of matching lengths")
    n_min = min(a.shape[0] for a in vs)
    M = int(n_markov) if n_markov is not None else min(1000, n_min // 3)
    M -= M % 2
    if M < 4 or M >= n_min:
        raise InputError(f"identify_linear_era: need 4 ≤ n_markov < capture length (got n_markov={M}, N={n_min})")
    if not 1 <= max_order < M // 2:
        raise ConfigError(f"identify_linear_era: max_order must be in [1, {M // 2 - 1}], got {max_order}")
    if not (isinstance(feedthrough, bool) or feedthrough == "auto"):
        raise ConfigError(f"identify_linear_era: feedthrough must be true, false or 'auto', got {feedthrough!r}")
    if correlation not in ("exact", "toeplitz"):
        raise ConfigError(f"identify_linear_era: correlation must be 'exact' or 'toeplitz', got {correlation!r}")
    solve_d, solve_0 = (_toeplitz_solvers if correlation == "toeplitz" else _exact_solvers)(vs, ys, M, ridge)
    if feedthrough is True:
        return _realize(solve_d(), dt, max_order, order)
    lin0 = _realize(solve_0(), dt, max_order, order)
    if feedthrough is False:
        return lin0
    lin_d = _realize(solve_d(), dt, max_order, order)
    sse_d, sse_0 = _simulation_sse(lin_d, vs, ys), _simulation_sse(lin0, vs, ys)
    return lin_d if sse_d < FEEDTHROUGH_SSE_RATIO * sse_0 else lin0


def _toeplitz_solvers(vs, ys, M: int, ridge: float):
    """Step 2 of :func:`identify_linear_era` by paper 003's route: eq. 4's correlations over the
    whole records, pooled, and a symmetric Toeplitz (Levinson) solve. Returns the solves of the
    impulse response α(0) … α(M) with D = α(0) estimated and with α(0) = 0 (functions: each is
    done only when needed)."""
    ruu = np.zeros(M + 1)
    ryu = np.zeros(M + 1)
    n_tot = 0
    for a, b in zip(vs, ys):
        r1, r2 = _correlations(a - a.mean(), b - b.mean(), M)
        ruu += r1
        ryu += r2
        n_tot += a.shape[0]
    ruu /= n_tot
    ryu /= n_tot
    if not ruu[0] > 0:
        raise InputError("identify_linear_era: the input is constant; the linear part needs an excitation")
    col = ruu.copy()
    col[0] *= 1.0 + ridge
    solve_d = lambda: linalg.solve_toeplitz(col, ryu)  # noqa: E731  α(0) … α(M)
    solve_0 = lambda: np.r_[0.0, linalg.solve_toeplitz(col[:M], ryu[1:])]  # noqa: E731  α(0) = 0
    return solve_d, solve_0


def _exact_solvers(vs, ys, M: int, ridge: float):
    """Step 2 of :func:`identify_linear_era` by the covariance method: the exact least-squares
    normal equations of the records (:func:`_windowed_normal_equations`, pooled), solved by
    Cholesky. Returns the two solves like :func:`_toeplitz_solvers`."""
    G = np.zeros((M + 1, M + 1))
    g = np.zeros(M + 1)
    for a, b in zip(vs, ys):
        G1, g1, _ = _windowed_normal_equations(a, b, M)
        G += G1
        g += g1
    if not G[0, 0] > 0:
        raise InputError("identify_linear_era: the input is constant; the linear part needs an excitation")
    G[np.diag_indices_from(G)] += ridge * np.trace(G) / (M + 1)
    solve_d = lambda: linalg.solve(G, g, assume_a="pos")  # noqa: E731
    solve_0 = lambda: np.r_[0.0, linalg.solve(G[1:, 1:], g[1:], assume_a="pos")]  # noqa: E731
    return solve_d, solve_0


#: ``feedthrough="auto"`` keeps D only when it multiplies the simulation SSE by less than this
FEEDTHROUGH_SSE_RATIO = 0.5


def _simulation_sse(lin: LinearSS, vs, ys) -> float:
    """Σ over captures of the squared error of lin's response to v (from rest, means removed); inf
    when the realization is unstable or the response not finite."""
    if not lin.is_stable:
        return math.inf
    total = 0.0
    with np.errstate(all="ignore"):
        for a, b in zip(vs, ys):
            e = lin.filter(a - a.mean())
            e = (e - e.mean()) - (b - b.mean())
            total += float(e @ e)
    return total if math.isfinite(total) else math.inf


def _realize(alpha: np.ndarray, dt: float, max_order: int, order: int | None) -> LinearSS:
    """Hankel SVD realization (paper 003 eq. 7–12) of the Markov parameters α(0) … α(M)."""
    M = alpha.size - 1
    n = M // 2
    idx = np.arange(n)
    H = alpha[1 + idx[:, None] + idx[None, :]]
    H1 = alpha[2 + idx[:, None] + idx[None, :]]
    U, s, Vt = np.linalg.svd(H)
    if order is None:
        k = min(max_order, s.size - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = s[:k] / s[1:k + 1]
        ratio = np.where(np.isfinite(ratio), ratio, np.inf)
        r = int(np.argmax(ratio)) + 1
    else:
        r = int(order)
        if not 1 <= r < n:
            raise ConfigError(f"identify_linear_era: order must be in [1, {n - 1}], got {order}")
    if not s[r - 1] > 0:
        raise InputError("identify_linear_era: the impulse response is zero; no linear dynamics can be identified")
    sq = np.sqrt(s[:r])
    C = U[0, :r] * sq
    B = sq * Vt[:r, 0]
    A = (U[:, :r].T @ H1 @ Vt[:r].T) / np.outer(sq, sq)
    return LinearSS(A, B, C, float(dt), r, singular_values=s[: min(s.size, 4 * max_order)].copy(), method="era",
                    D=float(alpha[0]))


# ---------------------------------------------------------------------------------------------- sine fit


def _fundamental(x: np.ndarray) -> float:
    """Dominant frequency of x in cycles/sample (Hann-windowed FFT peak, parabolic interpolation in log power)."""
    N = x.shape[0]
    X = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(N))) ** 2
    X[0] = 0.0
    k = int(np.argmax(X))
    if 1 <= k < X.size - 1 and X[k - 1] > 0 and X[k + 1] > 0:
        la, lb, lc = np.log(X[k - 1]), np.log(X[k]), np.log(X[k + 1])
        den = la - 2 * lb + lc
        k = k + (0.5 * (la - lc) / den if den != 0 else 0.0)
    return k / N


def _harmonic_phasors(x: np.ndarray, f: float, harmonics: int) -> np.ndarray:
    """Complex amplitudes X of the fundamental of each column of x (L, m):
    x ≈ c + Re(X e^{i2πfk}) + harmonics, by one least-squares solve."""
    k = np.arange(x.shape[0], dtype=np.float64)
    cols = [np.ones_like(k)]
    for h in range(1, harmonics + 1):
        ph = 2 * np.pi * h * f * k
        cols += [np.cos(ph), np.sin(ph)]
    X = np.stack(cols, axis=1)
    coef = np.linalg.solve(X.T @ X, X.T @ x)  # near-orthogonal basis over whole periods: well conditioned
    return coef[1] - 1j * coef[2]


def measure_gain_phase(v, y, dt: float, skip: float = 0.05) -> list[tuple[float, complex]]:
    """Frequency (Hz) and complex gain Y/V at the fundamental of each (v, y) capture.

    The fundamental is the FFT peak of v. The analysis window leaves out the start (the larger
    of the ``skip`` fraction and one period: the first cycle of a hysteretic signal is the
    virgin curve, and the linear part's start transient decays there) and spans a whole number
    of periods; both signals are fitted there by least squares with an offset and up to 5
    harmonics, so the harmonics of the hysteretic signal do not leak into the fundamental.
    """
    out = []
    for a, b in zip(_as_list(v), _as_list(y)):
        f = _fundamental(a)
        if not 0 < f < 0.5:
            raise InputError("linear part from sines: a capture has no oscillation to measure a gain/phase from")
        N = a.shape[0]
        i0 = max(int(skip * N), int(math.ceil(1.0 / f)))
        periods = math.floor((N - i0) * f)
        if periods < 1:
            raise InputError(
                f"linear part from sines: a capture holds {N * f:.2f} periods; at least 2 are needed (the first "
                "is skipped)")
        i1 = i0 + int(round(periods / f))
        harmonics = max(1, min(5, int(0.45 / f)))
        Vc, Yc = _harmonic_phasors(np.stack([a[i0:i1], b[i0:i1]], axis=1), f, harmonics)
        # phasors refer to sample i0 for both signals, so the ratio is unaffected
        if abs(Vc) == 0:
            raise InputError("linear part from sines: zero input amplitude at the fundamental")
        out.append((f / dt, Yc / Vc))
    return out


def _zoh_second_order(K: float, fn: float, zeta: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH discretization (b, a) of K ω_n²/(s² + 2ζω_n s + ω_n²)."""
    wn = 2 * np.pi * fn
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", signal.BadCoefficients)
        b, a, _ = signal.cont2discrete(([K * wn * wn], [1.0, 2 * zeta * wn, wn * wn]), dt, method="zoh")
    return np.asarray(b, float).ravel(), np.asarray(a, float).ravel()


def _zoh_second_order_response(K: float, fn: float, zeta: float, dt: float, f: np.ndarray) -> np.ndarray:
    """Frequency response of :func:`_zoh_second_order` in closed form (no matrix exponential).

    G(s)/s = K [1/s + Σ_i c_i/(s − p_i)], c_i = ω_n²/(p_i (p_i − p_j)), so the ZOH equivalent is
    H(z) = K [1 + (1 − z⁻¹) Σ_i c_i/(1 − e^{p_i T} z⁻¹)] (ζ = 1 is nudged by 1e-9 to keep the poles distinct).
    """
    wn = 2 * np.pi * fn
    if abs(zeta - 1.0) < 1e-9:
        zeta = 1.0 + (1e-9 if zeta >= 1.0 else -1e-9)
    root = np.sqrt(complex(zeta * zeta - 1.0))
    p1, p2 = wn * (-zeta + root), wn * (-zeta - root)
    c1 = wn * wn / (p1 * (p1 - p2))
    c2 = wn * wn / (p2 * (p2 - p1))
    zi = np.exp(-2j * np.pi * f * dt)  # z⁻¹
    return K * (1.0 + (1.0 - zi) * (c1 / (1.0 - np.exp(p1 * dt) * zi) + c2 / (1.0 - np.exp(p2 * dt) * zi)))


def fit_linear_to_sine(v, y, dt: float, *, fn_bounds_Hz: tuple[float, float] | None = None,
                       zeta_bounds: tuple[float, float] = (0.01, 2.0),
                       start: tuple[float, float, float] | None = None) -> LinearSS:
    r"""Second-order linear part fitted to the gain/phase measured by sine captures at several frequencies.

    For sine-only data (no broadband capture) the correlation/Hankel route of paper 003 has no
    spectrum to work with; instead the complex gain G(f_i) = Y(f_i)/V(f_i) is measured at the
    fundamental of each capture (:func:`measure_gain_phase`, v the PI output or u) and the
    zero-order-hold discretization of K ω_n²/(s² + 2ζω_n s + ω_n²) is fitted to it (least
    squares on G_model/G_meas − 1, real and imaginary parts; grid start over f_n × ζ). ZOH keeps
    D = 0 like the ERA model; its half-sample delay is absorbed by ζ at the measured frequencies.

    ``start`` = (K, f_n Hz, ζ) replaces the grid start (warm start of an iteration).

    Needs captures at ≥ 2 distinct frequencies (3 real unknowns, 2 equations per frequency;
    captures at the same frequency are averaged). With all frequencies far below the resonance
    only the low-frequency behaviour (≈ phase lag 2ζf/f_n) is determined; f_n and ζ separately
    are then weakly identified — the model still reproduces the measured band.

    Returns
    -------
    :class:`LinearSS` with ``method="sine-gain-phase"``, ``fit_points`` = the measured (f, G) and
    ``continuous`` = the fitted (K, f_n Hz, ζ).
    """
    pts = measure_gain_phase(v, y, dt)
    freqs = np.array([p[0] for p in pts])
    G = np.array([p[1] for p in pts])
    # average captures at the same frequency (within 1 %)
    order_ = np.argsort(freqs)
    groups: list[list[int]] = []
    for i in order_:
        if groups and abs(freqs[i] - freqs[groups[-1][0]]) <= 0.01 * freqs[groups[-1][0]]:
            groups[-1].append(i)
        else:
            groups.append([i])
    f_u = np.array([freqs[g].mean() for g in groups])
    G_u = np.array([G[g].mean() for g in groups])
    if f_u.size < 2:
        raise InputError(
            "linear part from sines: every capture has the same drive frequency; the linear part needs sines at "
            "≥ 2 frequencies, or one broadband capture (a PRBS, a multisine, a chirp; a step pattern's power falls "
            "as 1/f² and excites too few frequencies)")
    fs = 1.0 / dt
    lo_f, hi_f = fn_bounds_Hz if fn_bounds_Hz is not None else (min(2.0 * f_u.max(), 0.4 * fs), 0.45 * fs)

    def resid(x):
        Gm = _zoh_second_order_response(math.exp(x[0]), math.exp(x[1]), x[2], dt, f_u)
        e = Gm / G_u - 1.0
        return np.r_[e.real, e.imag]

    K0 = float(np.median(np.abs(G_u)))
    if start is not None:
        x_start = np.array([math.log(start[0]), math.log(start[1]), float(start[2])])
    else:
        best = None
        for fn0 in np.geomspace(lo_f, hi_f, 12):
            for z0 in (0.05, 0.2, 0.5, 1.0):
                x = np.array([math.log(K0), math.log(fn0), z0])
                c = float(np.sum(resid(x) ** 2))
                if best is None or c < best[0]:
                    best = (c, x)
        x_start = best[1]
    lb = np.array([math.log(K0) - 3.0, math.log(lo_f), zeta_bounds[0]])
    ub = np.array([math.log(K0) + 3.0, math.log(hi_f), zeta_bounds[1]])
    x0 = np.clip(x_start, lb + 1e-9 * (ub - lb), ub - 1e-9 * (ub - lb))
    sol = optimize.least_squares(resid, x0, bounds=(lb, ub), method="trf", x_scale="jac")
    K, fn, z = math.exp(sol.x[0]), math.exp(sol.x[1]), float(sol.x[2])
    b, a = _zoh_second_order(K, fn, z, dt)
    lin = LinearSS.from_tf(b, a, dt, method="sine-gain-phase")
    return replace(lin, fit_points=tuple((float(f), complex(g)) for f, g in zip(f_u, G_u)), continuous=(K, fn, z))


def check_era_options(max_order, n_markov, feedthrough, correlation, era_order) -> None:
    """One check of the ERA identification options for the ``lti`` block and the Hammerstein model."""
    def positive_int(x):
        return isinstance(x, int) and not isinstance(x, bool) and x >= 1

    if not positive_int(max_order):
        raise ConfigError(f"max_order must be a positive integer, got {max_order!r}")
    if n_markov is not None and not (positive_int(n_markov) and n_markov >= 4):
        raise ConfigError(f"n_markov must be an integer ≥ 4 (or null: automatic), got {n_markov!r}")
    if era_order is not None and not positive_int(era_order):
        raise ConfigError(f"era_order must be a positive integer (or null: the singular-value gap), got {era_order!r}")
    if not (isinstance(feedthrough, bool) or feedthrough == "auto"):
        raise ConfigError(f"feedthrough must be true, false or 'auto', got {feedthrough!r}")
    if correlation not in ("exact", "toeplitz"):
        raise ConfigError(f"correlation must be 'exact' or 'toeplitz', got {correlation!r}")


@dataclass(frozen=True)
class LinearPartFields:
    """The structure fields of an identified linear part, defined once for the ``lti`` block and
    the Hammerstein model: the stored state space (``order``, ``A`` row-major, ``B``, ``C``,
    ``D``, its sample period ``dt_s``, the Hankel ``singular_values`` it was cut from) and the
    options of its identification by ERA (:func:`identify_linear_era`). Each class adds the
    field naming how the part was obtained (``method``, ``linear_method``)."""

    order: int = 0
    A: tuple[float, ...] = ()
    B: tuple[float, ...] = ()
    C: tuple[float, ...] = ()
    D: float = 0.0
    dt_s: float | None = None
    singular_values: tuple[float, ...] = ()
    max_order: int = 8
    n_markov: int | None = None
    feedthrough: "bool | str" = "auto"
    correlation: str = "exact"
    era_order: int | None = None

    def check_linear_part(self) -> None:
        """The one check of these fields: ConfigError for an ERA option
        (:func:`check_era_options`), ValueError for an inconsistent state space."""
        check_era_options(self.max_order, self.n_markov, self.feedthrough, self.correlation, self.era_order)
        r = self.order
        if not isinstance(r, int) or isinstance(r, bool) or r < 0:
            raise ValueError(f"order must be a non-negative integer, got {r!r}")
        if len(self.A) != r * r or len(self.B) != r or len(self.C) != r:
            raise ValueError(f"a linear part of order {r} needs {r * r} A, {r} B and {r} C entries "
                             f"(got {len(self.A)}, {len(self.B)}, {len(self.C)})")
        vals = np.r_[np.asarray(self.A, float), np.asarray(self.B, float), np.asarray(self.C, float), float(self.D)]
        if not np.all(np.isfinite(vals)):
            raise ValueError("the linear part has non-finite entries")
        if r > 0 and not (self.dt_s is not None and self.dt_s > 0):
            raise ValueError("a linear part needs its sample period dt_s > 0")


def is_broadband(u: np.ndarray, min_bins: int = 64, level: float = 1e-3) -> bool:
    """True when the input excites many frequencies (PRBS, multisine, chirp), not a few lines.

    Counts the bins of the Hann-windowed power spectrum of u − mean above ``level`` × its peak:
    a sine or raised cosine has ≈ 4 (the main lobe), a triangle ≈ 12 (three harmonics), a
    40-line multisine ≈ 120 and a PRBS thousands; ≥ ``min_bins`` counts as broadband. A step pattern
    (power ∝ 1/f²) has far fewer: too few to identify a linear stage from. (Whether a capture is one drive
    frequency, a look-up table's question, is :func:`hystfit.conditions.tonal_share`'s.)
    """
    u = np.asarray(u, dtype=np.float64)
    if u.shape[0] < 4 * min_bins:
        return False
    X = np.abs(np.fft.rfft((u - u.mean()) * np.hanning(u.shape[0]))) ** 2
    X[0] = 0.0
    peak = X.max()
    return bool(peak > 0 and np.count_nonzero(X > level * peak) >= min_bins)


@blocks.register
@dataclass(frozen=True)
class Lti(Block, LinearPartFields):
    r"""An identified linear stage after the hysteresis: paper 003's discrete state space.

    .. math:: s_{k+1} = A s_k + B x_k,\qquad y_k = C s_k + D x_k \quad (G(1) = 1)

    identified once from all the captures before the fit (:meth:`prepare`): correlation →
    impulse response → Hankel SVD (ERA, :func:`identify_linear_era`, paper 003 eq. 4–12) on the
    broadband captures (PRBS, multisine, chirp), with the input voltage as the stage input (the
    first pass of paper 003's two-step procedure), scaled to unit static gain so the base model
    keeps the quasi-static gain. Structure, not parameters: it adds no entry to θ, and the base
    model's parameters are fitted through it. Sine-only data cannot determine it (one frequency
    per capture): use the ``dynamics`` block there.

    Structure
    ---------
    order, A, B, C, D, dt_s, method, singular_values : the identified state space (set by
        :meth:`prepare`; ``order`` 0 before), its sample period and how it was found.
    max_order, n_markov, feedthrough, correlation, era_order : identification options
        (:func:`identify_linear_era`; ``era_order`` is its ``order``: force the order instead of
        the singular-value gap). ``feedthrough`` is "auto" by default: the paper's D = 0 unless
        D halves the simulation error (on the sample PRBS/steps captures it does: D = 0
        identifies a spurious mode at z ≈ −1 from v = u, RMSE 6.7 µm against 0.099 µm with D).

    Other sample rates: the stage is re-discretized exactly (:meth:`LinearSS.resampled`: zero-
    order hold for D = 0, bilinear with a feedthrough), so a stage identified at 5 kHz
    simulates and inverts at 10 kHz.

    Inverse: a stable, non-oscillating inverse (:meth:`LinearSS.inverse_filter`: exact for
    well-damped zeros, reflection for zeros far outside the unit circle, zero-phase ZPETC for
    zeros near it).
    """

    name: ClassVar[str] = "lti"
    title: ClassVar[str] = "identified linear stage (ERA state space)"
    equation: ClassVar[str] = "s_{k+1} = A s_k + B x_k,  y_k = C s_k + D x_k,  G(1) = 1"
    reference: ClassVar[str] = "paper 003 eq. 4–12 (correlation, Hankel SVD), §4.2 (stable inverse; ZPETC near the unit circle)"
    candidate: ClassVar[bool] = False

    method: str = "none"

    def __post_init__(self) -> None:
        self.check_linear_part()

    # ------------------------------------------------------------------ structure
    @property
    def linear(self) -> LinearSS:
        r = self.order
        if r == 0:
            return LinearSS.identity(self.dt_s)
        return LinearSS(np.asarray(self.A, float).reshape(r, r), np.asarray(self.B, float),
                        np.asarray(self.C, float), float(self.dt_s), r,
                        singular_values=np.asarray(self.singular_values, float), method=self.method,
                        D=float(self.D))

    def prepare(self, captures) -> "Lti":
        """Identify the state space from the broadband captures (unless already identified)."""
        if self.order > 0:
            return self
        caps = captures_at_one_rate(captures, "lti")
        broad = [c for c in caps if is_broadband(c.u)]
        if not broad:
            raise ConfigError("lti: no broadband capture (a PRBS, a multisine, a chirp) to identify the linear stage "
                              "from; sine captures determine one frequency each, and a step pattern's power falls "
                              "as 1/f² (too few frequencies) — use the dynamics block instead")
        lin = identify_linear_era([c.u for c in broad], [c.y for c in broad], broad[0].dt,
                                  max_order=self.max_order, n_markov=self.n_markov, order=self.era_order,
                                  feedthrough=self.feedthrough, correlation=self.correlation)
        if not lin.is_stable:
            raise InputError(f"lti: the identified linear stage is unstable (spectral radius "
                             f"{lin.spectral_radius:.4f}); use a longer or richer capture or a lower max_order")
        lin = lin.normalized()
        return replace(self, order=int(lin.order), A=tuple(np.ravel(lin.A).tolist()), B=tuple(np.ravel(lin.B).tolist()),
                       C=tuple(np.ravel(lin.C).tolist()), D=float(lin.D), dt_s=float(lin.dt), method=lin.method,
                       singular_values=tuple(np.asarray(lin.singular_values, float).tolist()))

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        return ()

    def linear_at(self, dt: float) -> LinearSS:
        """The stage at sample period ``dt`` (exact re-discretization when it differs from ``dt_s``)."""
        return self.linear.resampled(dt) if self.order else self.linear

    # ------------------------------------------------------------------ diagnose interface (not a candidate)
    def operator(self, x, view, phi):
        return self.linear_at(view.dt).filter(x)

    def describe(self, phi, shared, local, views, sources=None):
        return {"order": self.order, "method": self.method}

    # ------------------------------------------------------------------ composite interface
    def apply_population(self, x, theta, dt):
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        return self.linear_at(dt).filter(np.ascontiguousarray(x.T)).T

    def invert(self, theta, y, dt):
        return self.linear_at(dt).inverse_filter(np.asarray(y, dtype=np.float64))

    def step_init(self, theta, x0, dt):
        return np.r_[np.zeros(self.order), float(x0)]  # state deviations, first input

    def step(self, theta, state, x_new, dt):
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        state = np.asarray(state, dtype=np.float64)
        r = self.order
        x0 = state[r]
        if r == 0:
            return x_new.copy(), np.full((x_new.size, 1), x0)
        lin = self.linear_at(dt)
        s = state[:r]
        d = x_new - x0
        y = lin.dc_gain() * x0 + lin.C @ s + lin.D * d
        s_new = (lin.A @ s)[None, :] + d[:, None] * lin.B[None, :]
        return y, np.hstack([s_new, np.full((x_new.size, 1), x0)])
