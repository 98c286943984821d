"""Electromechanical model: PI hysteresis followed by a second-order linear subsystem (paper 000)."""

from __future__ import annotations

import hashlib
import math
import weakref
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from .._jit import njit, prange

from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from ..blocks.dynamics import bilinear_biquad, biquad_columns, invert_second_order
from ._kernels import PARALLEL_MIN_POP, play_matrix, thread_blocks
from .base import Model
from .separable import Separable
from .pi import PI


#: fastmath flags of the fused pi2 kernels: no ``nnan``/``ninf`` (a non-finite candidate must stay inf/NaN)
_PI2_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}


@njit(cache=True, fastmath=_PI2_FASTMATH)
def _pi2_sse_block(F, y, W, c0, b0, b1, b2, a1, a2, out, p0, p1):
    """Σ_k (ŷ_k − y_k)² of the pi2 candidates p0:p1 into ``out[p0:p1]``, without storing ŷ.

    For candidate p (weights w = W[:, p], biquad b0, b1, b2, a1, a2 of :func:`bilinear_biquad`):

        d[k] = Σ_j w_j (F[k, j] − F[0, j])          (PI output v[k] minus its first sample v[0])
        e[k] = b0 d[k] + b1 d[k−1] + b2 d[k−2] − a1 e[k−1] − a2 e[k−2],   d[<0] = e[<0] = 0
        ŷ[k] = e[k] + c0,   c0 = v[0] + y0 = Σ_j w_j F[0, j] + y0

    i.e. :func:`biquad_columns` (the filter at rest at its first input) applied to the PI output
    F·w, plus the offset: the arithmetic of :meth:`PI2.simulate` up to the order of the PI sum.

    Layout (``shared/PERFORMANCE.md``): the time loop is sequential and outermost; inside it every
    loop runs over the block's candidates, contiguous — the weights are copied to a (n, m) array
    (one contiguous row per operator), coefficients and filter states are (m,) arrays — so LLVM
    vectorizes across candidates. Memory O(n·m): the (N, P) outputs are never formed. A candidate
    with non-finite parameters gets a non-finite sum (never an exception).

    Parameters
    ----------
    F : (N, n) play-operator outputs of the capture (θ-independent: computed once per capture).
    y : (N,) measured output.  W : (n, P) weights.  c0 : (P,) at-rest output v[0] + y0.
    b0, b1, b2, a1, a2 : (P,) biquad coefficients (a0 = 1).
    out : (P,) receives the sums of the block.  p0, p1 : the candidate block.
    """
    N, n = F.shape
    m = p1 - p0
    w = np.empty((n, m))
    for j in range(n):
        for i in range(m):
            w[j, i] = W[j, p0 + i]
    B0 = b0[p0:p1].copy()
    B1 = b1[p0:p1].copy()
    B2 = b2[p0:p1].copy()
    A1 = a1[p0:p1].copy()
    A2 = a2[p0:p1].copy()
    C0 = c0[p0:p1].copy()
    F0 = np.zeros(n)
    if N > 0:
        F0[:] = F[0]
    d = np.empty(m)
    d1 = np.zeros(m)
    d2 = np.zeros(m)
    e1 = np.zeros(m)
    e2 = np.zeros(m)
    acc = np.zeros(m)
    for k in range(N):
        x = F[k, 0] - F0[0]
        for i in range(m):
            d[i] = w[0, i] * x
        for j in range(1, n):
            x = F[k, j] - F0[j]
            for i in range(m):
                d[i] += w[j, i] * x
        yk = y[k]
        for i in range(m):
            # states read into locals before any store: no reloads through possibly aliasing arrays
            di = d[i]
            da = d1[i]
            db = d2[i]
            ea = e1[i]
            eb = e2[i]
            e = B0[i] * di + B1[i] * da + B2[i] * db - A1[i] * ea - A2[i] * eb
            d2[i] = da
            d1[i] = di
            e2[i] = ea
            e1[i] = e
            r = e + C0[i] - yk
            acc[i] += r * r
    for i in range(m):
        out[p0 + i] = acc[i]


@njit(cache=True)
def _pi2_sse_serial(F, y, W, c0, b0, b1, b2, a1, a2, out):
    _pi2_sse_block(F, y, W, c0, b0, b1, b2, a1, a2, out, 0, c0.shape[0])


@njit(cache=True, parallel=True)
def _pi2_sse_parallel(F, y, W, c0, b0, b1, b2, a1, a2, out, n_blocks):
    """:func:`_pi2_sse_serial` with ``n_blocks`` candidate blocks spread over threads."""
    P = c0.shape[0]
    size = (P + n_blocks - 1) // n_blocks
    for b in prange(n_blocks):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _pi2_sse_block(F, y, W, c0, b0, b1, b2, a1, a2, out, p0, p1)


@njit(cache=True, fastmath=_PI2_FASTMATH)
def _pi2_gram_block(F, y, b0, b1, b2, a1, a2, G, c, p0, p1):
    """Normal equations of the pi2 linear parameters (w0 … w{n−1}, y0) for the candidate
    dynamics p0:p1, accumulated in the time loop without storing the filtered signals.

    The basis of candidate p at sample k is b_k = [φ_0[k] … φ_{n−1}[k], 1], φ_j the play output
    F[:, j] filtered by the candidate's biquad from rest at its first input (:func:`biquad_columns`):

        x_j[k] = F[k, j] − F[0, j]
        e_j[k] = b0 x_j[k] + b1 x_j[k−1] + b2 x_j[k−2] − a1 e_j[k−1] − a2 e_j[k−2],  x, e = 0 before k = 0
        φ_j[k] = F[0, j] + e_j[k]

    (the constant column of y0 passes the unit-DC-gain filter unchanged). Accumulated:

        G[p] = Σ_k b_k b_kᵀ:  G[p, j, l] = Σ φ_j φ_l,  G[p, j, n] = G[p, n, j] = Σ φ_j,  G[p, n, n] = N
        c[p] = Σ_k b_k y_k:   c[p, j] = Σ φ_j y_k,     c[p, n] = Σ y_k

    Layout (``shared/PERFORMANCE.md``): the time loop is sequential and outermost; inside it every
    loop runs over the block's candidates, contiguous: the output states e_j[k−1], e_j[k−2] and
    the accumulators are (rows, m) arrays with the candidate index last, so LLVM vectorizes
    across candidates. The inputs x_j are shared by every candidate (only the coefficients
    differ), so they are kept once. The filtered rows of 4 consecutive samples are buffered
    ((4, n, m)) and added to the n(n+1)/2 pair accumulators in one pass (a quarter of the
    accumulator loads and stores). Memory O(n²·m) whatever N. Candidates with non-finite
    coefficients get non-finite G, c entries (never an exception).

    Parameters
    ----------
    F : (N, n) play-operator outputs (computed once per capture).  y : (N,) measured output.
    b0, b1, b2, a1, a2 : (P,) biquad coefficients (a0 = 1, :func:`bilinear_biquad`).
    G : (P, n + 1, n + 1) and c : (P, n + 1) receive the rows p0:p1.
    """
    N, n = F.shape
    m = p1 - p0
    U = 4  # samples per pass over the pair accumulators (the update below is written out for 4)
    B0 = b0[p0:p1].copy()
    B1 = b1[p0:p1].copy()
    B2 = b2[p0:p1].copy()
    A1 = a1[p0:p1].copy()
    A2 = a2[p0:p1].copy()
    F0 = np.zeros(n)
    if N > 0:
        F0[:] = F[0]
    x1 = np.zeros(n)  # x_j[k−1], x_j[k−2]: shared by all candidates
    x2 = np.zeros(n)
    e1 = np.zeros((n, m))
    e2 = np.zeros((n, m))
    phi = np.zeros((U, n, m))  # filtered rows of the current group of samples
    npair = n * (n + 1) // 2
    gacc = np.zeros((npair, m))
    sacc = np.zeros((n, m))
    cacc = np.zeros((n, m))
    sy = 0.0
    for k0 in range(0, N, U):
        nt = min(U, N - k0)
        for t in range(nt):
            k = k0 + t
            yk = y[k]
            sy += yk
            for j in range(n):
                x = F[k, j] - F0[j]
                xa = x1[j]
                xb = x2[j]
                f0 = F0[j]
                for i in range(m):
                    ea = e1[j, i]
                    eb = e2[j, i]
                    e = B0[i] * x + B1[i] * xa + B2[i] * xb - A1[i] * ea - A2[i] * eb
                    e2[j, i] = ea
                    e1[j, i] = e
                    ph = e + f0
                    phi[t, j, i] = ph
                    sacc[j, i] += ph
                    cacc[j, i] += ph * yk
                x2[j] = xa
                x1[j] = x
        if nt < U:  # last, partial group: the unused rows contribute exact zeros
            for t in range(nt, U):
                for j in range(n):
                    for i in range(m):
                        phi[t, j, i] = 0.0
        q = 0
        for j in range(n):
            for l in range(j, n):
                for i in range(m):
                    gacc[q, i] += ((phi[0, j, i] * phi[0, l, i] + phi[1, j, i] * phi[1, l, i])
                                   + (phi[2, j, i] * phi[2, l, i] + phi[3, j, i] * phi[3, l, i]))
                q += 1
    for i in range(m):
        p = p0 + i
        q = 0
        for j in range(n):
            for l in range(j, n):
                G[p, j, l] = gacc[q, i]
                G[p, l, j] = gacc[q, i]
                q += 1
            G[p, j, n] = sacc[j, i]
            G[p, n, j] = sacc[j, i]
            c[p, j] = cacc[j, i]
        G[p, n, n] = float(N)
        c[p, n] = sy


@njit(cache=True)
def _pi2_gram_serial(F, y, b0, b1, b2, a1, a2, G, c):
    _pi2_gram_block(F, y, b0, b1, b2, a1, a2, G, c, 0, b0.shape[0])


@njit(cache=True, parallel=True)
def _pi2_gram_parallel(F, y, b0, b1, b2, a1, a2, G, c, n_blocks):
    """:func:`_pi2_gram_serial` with ``n_blocks`` candidate blocks spread over threads."""
    P = b0.shape[0]
    size = (P + n_blocks - 1) // n_blocks
    for b in prange(n_blocks):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _pi2_gram_block(F, y, b0, b1, b2, a1, a2, G, c, p0, p1)


#: the Gram kernel does ~n²/2 = 50 multiply-adds per candidate and sample where the sum-of-squares
#: kernel does ~n + 5: it is worth threading from this population on (blocks of ≥ 8 candidates,
#: one AVX-512 vector), where :data:`~hystfit.models._kernels.PARALLEL_MIN_POP` applies to the latter
GRAM_PARALLEL_MIN_POP = 16


def _f64(x):
    return np.ascontiguousarray(x, dtype=np.float64)


def pi2_sse(F, y, W, c0, b0, b1, b2, a1, a2):
    """Σ_k (ŷ_k − y_k)² per candidate (P,) from the fused kernel :func:`_pi2_sse_block`, threaded
    over candidate blocks for populations ≥ :data:`~hystfit.models._kernels.PARALLEL_MIN_POP`.

    F (N, n) play outputs, y (N,), W (n, P) weights, c0 (P,) = Σ_j w_j F[0, j] + y0,
    b0 … a2 (P,) biquad coefficients. The (N, P) outputs are never stored."""
    F, y, W, c0 = _f64(F), _f64(y), _f64(W), _f64(c0)
    co = [_f64(a) for a in (b0, b1, b2, a1, a2)]
    out = np.empty(c0.shape[0])
    nb = thread_blocks(c0.shape[0], PARALLEL_MIN_POP, 32)
    if nb:
        _pi2_sse_parallel(F, y, W, c0, *co, out, nb)
    else:
        _pi2_sse_serial(F, y, W, c0, *co, out)
    return out


def pi2_gram(F, y, b0, b1, b2, a1, a2):
    """Normal equations (G (P, n + 1, n + 1), c (P, n + 1)) of the pi2 linear parameters for
    each candidate's biquad, from the fused kernel :func:`_pi2_gram_block` (threaded over
    candidate blocks for populations ≥ :data:`GRAM_PARALLEL_MIN_POP`). O(P·n²) memory."""
    F, y = _f64(F), _f64(y)
    co = [_f64(a) for a in (b0, b1, b2, a1, a2)]
    P, L = co[0].shape[0], F.shape[1] + 1
    G = np.empty((P, L, L))
    c = np.empty((P, L))
    nb = thread_blocks(P, GRAM_PARALLEL_MIN_POP, 8)
    if nb:
        _pi2_gram_parallel(F, y, *co, G, c, nb)
    else:
        _pi2_gram_serial(F, y, *co, G, c)
    return G, c


#: play-operator matrices in use, keyed by the content of the input and the thresholds, held
#: weakly: an entry lives as long as a closure that uses it (see :func:`shared_play_matrix`)
_PLAYS: "weakref.WeakValueDictionary[tuple, np.ndarray]" = weakref.WeakValueDictionary()


def shared_play_matrix(u: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`~hystfit.models._kernels.play_matrix` (N, n) of one capture, computed once and shared.

    The simulator, the fused sum of squares and the normal equations of one capture each need
    the θ-independent play matrix (80 MB for 10⁶ samples and 10 operators); they share one
    read-only copy. The key is a digest of the input's bytes (plus N and the thresholds), so an
    input changed in place gets its own matrix, never a stale one.
    """
    u = np.ascontiguousarray(u, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    key = (hashlib.blake2b(memoryview(u).cast("B"), digest_size=20).digest(), u.shape[0], r.tobytes())
    F = _PLAYS.get(key)
    if F is None:
        F = play_matrix(u, r)
        F.flags.writeable = False
        _PLAYS[key] = F
    return F


@models.register
@dataclass(frozen=True)
class PI2(Model):
    r"""Electromechanical model: classical PI hysteresis driving a second-order linear subsystem.

    .. math::

        \ddot y + 2\zeta\omega_n \dot y + \omega_n^2 y = \omega_n^2\, g\, H[u],\qquad
        H[u] = \sum_{j=0}^{n-1} w_j F_{r_j}[u],\qquad \omega_n = 2\pi f_n

        y_{\text{meas}} = y + y_0

    (paper 000, Fig. 3 and eq. 20–21: "a second-order linear subsystem preceded by a hysteresis
    nonlinearity"; formulation of ``shared/papers/README.md``, with the classical PI of paper
    003 eq. 1–3 as H, reused from :class:`hystfit.models.pi.PI`).

    Structure
    ---------
    n_operators, placement, thresholds_V, nonnegative : the PI part, as in :class:`PI`
    (thresholds filled from the identification data by :meth:`adapt`).

    Parameters (θ), in this order
    -----------------------------
    w0 … w{n−1} : PI weights including the static gain g (output unit per V). g is folded into
        the weights: g·w_j is all the data can determine (only products appear), so a separate
        g would be an exactly non-identifiable direction. Because the filter's static gain is 1,
        the weights keep the meaning they have in :class:`PI` (quasi-static loop).
    y0 : output offset (output unit), added after the filter (equivalent: unit static gain).
    fn_Hz : natural frequency f_n (Hz). Bounds from the data: lower min(max(5·f_exc, 0.002·f_s),
        0.05·f_s) with f_exc = rate_max/(π·input range) (the frequency of a sine with the
        captures' range and peak rate), upper 0.45·f_s. A resonance inside the excitation band
        would be an implausible explanation of a piezo loop (a low-pass with strong damping
        mimics the rate-dependent widening of the loop), hence the lower bound.
    zeta : damping ratio ζ (1), in [0.01, 2].

    Solution of the linear part. Paper 000 replaces RK4 by a fast exact solution ("symmetric
    solutions"); we discretize the transfer function once per candidate and filter exactly:
    prewarped bilinear (Tustin) transform (:func:`bilinear_biquad`), state at rest at the
    first sample. Bilinear rather than zero-order hold because (a) it is the trapezoidal rule:
    for the sampled, smooth PI output it is second-order accurate and adds no half-sample
    delay (ZOH would, i.e. a phase error of ω·Ts/2 — 0.75 µm on a 60 µm, 80 Hz loop at
    10 kHz), (b) prewarping places the resonance exactly, (c) it is unconditionally stable,
    and (d) it is what hystfit's virtual actuator uses (:mod:`hystfit.synth`), so the model
    can represent that plant exactly. The population is filtered by a numba biquad kernel,
    time outermost, candidates innermost (:func:`biquad_columns`). The identification objective
    does not store the (P, N) outputs: :meth:`sse_evaluator` forms the PI output, filters it and
    accumulates the squared error in one time loop (:func:`pi2_sse`).

    Exploited structure: for fixed (f_n, ζ) the output is linear in (w, y0) —
    :meth:`design_matrix` (filtered play outputs and ones), and :meth:`separable` for the
    ``auto`` optimizer (only f_n and ζ are searched; the normal equations of (w, y0) come from
    the fused kernel :func:`pi2_gram`, O(P·n²) memory whatever the capture length).

    Inverse (:meth:`invert`): dynamic inversion of the linear part, then the analytic PI inverse
    (paper 003 eq. 17–20). The discrete filter's exact inverse is unusable: the bilinear
    numerator g(1 + z⁻¹)² has a double zero *on* the unit circle (z = −1), so the exact inverse
    carries an undamped, linearly growing alternating mode. We invert the continuous equation
    v = y + (2ζ/ω_n) ẏ + ÿ/ω_n² with derivatives consistent with the bilinear map,
    s ≈ (K/4)(q − q⁻¹), s² ≈ (K²/4)(q − 2 + q⁻¹) (q the one-sample advance; both equal the
    exact bilinear operator times cos²(θ/2) at normalized frequency θ), plus one correction
    step that removes the cos²(θ/2) factor to O(θ⁴). Limits: the target must be smooth
    (the inverse amplifies content above f_n by (f/f_n)²; noise or steps in y_d give large
    voltage spikes), the input uses one sample of preview (y_d[k+1]), and the signal is taken
    at rest before the first sample and held after the last.
    """

    name = "pi2"
    title = "PI hysteresis + second-order dynamics (electromechanical)"
    reference = "paper 000 (second-order linear subsystem preceded by hysteresis); PI of paper 003 eq. 1–3"
    equation = "y'' + 2ζω_n y' + ω_n² y = ω_n² Σ_j w_j F_{r_j}[u],  y_meas = y + y0,  ω_n = 2π f_n"
    rate_dependent = True

    n_operators: int = 10
    placement: str = "uniform"
    thresholds_V: tuple[float, ...] | None = None
    nonnegative: bool = True

    def __post_init__(self) -> None:
        try:
            self.pi
        except ConfigError as exc:
            raise ConfigError(f"pi2: {str(exc).removeprefix('pi: ')}") from None

    # ------------------------------------------------------------------ structure
    @property
    def pi(self) -> PI:
        """The hysteresis part as a classical :class:`PI` (same structure fields)."""
        return PI(self.n_operators, self.placement, self.thresholds_V, self.nonnegative)

    def adapt(self, scale: DataScale) -> "PI2":
        if self.thresholds_V is not None:
            return self
        return replace(self, thresholds_V=self.pi.adapt(scale).thresholds_V)

    @property
    def n_params(self) -> int:
        return self.n_operators + 3

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        fs = 1.0 / scale.dt
        f_exc = scale.rate_max / (math.pi * scale.u_range)
        f_lo = min(max(5.0 * f_exc, 0.002 * fs), 0.05 * fs)
        f_hi = 0.45 * fs
        return self.pi.params(scale) + (
            Param("fn_Hz", "Hz", f_lo, f_hi, math.sqrt(f_lo * f_hi), "natural frequency f_n of the linear subsystem"),
            Param("zeta", "1", 0.01, 2.0, 0.2, "damping ratio ζ of the linear subsystem"),
        )

    # ------------------------------------------------------------------ simulation
    def _filter(self, v: np.ndarray, fn: np.ndarray, zeta: np.ndarray, dt: float) -> np.ndarray:
        """Filter the columns of v (N, M) with per-column (f_n, ζ) (M,): (N, M)."""
        b0, b1, b2, a1, a2 = bilinear_biquad(fn, zeta, dt)
        return biquad_columns(np.ascontiguousarray(v), b0, b1, b2, a1, a2)

    def design_matrix(self, u: np.ndarray, dt: float, fn_Hz: float, zeta: float) -> np.ndarray:
        """Regressors (N, n + 1) for fixed (f_n, ζ): filtered play outputs and a column of ones.

        y = Φ·[w0 … w{n−1}, y0] exactly (the filter is linear and has unit static gain), so the
        weights follow from (non-negative) least squares for every candidate dynamics.
        """
        u = np.ascontiguousarray(u, dtype=np.float64)
        F = play_matrix(u, self.pi.r)
        n = self.n_operators
        Ff = self._filter(F, np.full(n, float(fn_Hz)), np.full(n, float(zeta)), dt)
        return np.hstack([Ff, np.ones((u.shape[0], 1))])

    def _simulate_from_plays(self, theta: np.ndarray, F: np.ndarray, dt: float) -> np.ndarray:
        n = self.n_operators
        theta = self.check_theta(theta, n + 3)
        v = np.ascontiguousarray(F @ theta[:, :n].T)  # (N, P) hysteresis outputs
        y = self._filter(v, theta[:, n + 1], theta[:, n + 2], dt)
        y += theta[:, n][None, :]
        return y.T

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        u = np.ascontiguousarray(u, dtype=np.float64)
        return self._simulate_from_plays(theta, play_matrix(u, self.pi.r), dt)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        F = shared_play_matrix(u, self.pi.r)  # once per capture
        return lambda theta: self._simulate_from_plays(theta, F, dt)

    def sse_evaluator(self, u: np.ndarray, dt: float, y: np.ndarray):
        """Σ_k (ŷ_k − y_k)² per candidate from the fused kernel :func:`pi2_sse` (PI sum, biquad and
        squared error inside one time loop): the (P, N) outputs are never stored. The play-operator
        matrix is computed once per capture (shared with the simulator, :func:`shared_play_matrix`).
        Non-finite candidates give inf/NaN (never an exception)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        y = np.ascontiguousarray(y, dtype=np.float64)
        n = self.n_operators
        F = shared_play_matrix(u, self.pi.r)  # once per capture
        F0 = F[0].copy() if F.shape[0] else np.zeros(n)

        def sse(theta):
            theta = self.check_theta(theta, n + 3)
            with np.errstate(all="ignore"):
                b0, b1, b2, a1, a2 = bilinear_biquad(theta[:, n + 1], theta[:, n + 2], dt)
                c0 = theta[:, :n] @ F0 + theta[:, n]  # at-rest output v[0] + y0
                return pi2_sse(F, y, theta[:, :n].T, c0, b0, b1, b2, a1, a2)

        return sse

    def separable(self):
        """Weights and y0 enter linearly; only (f_n, ζ) are searched (variable projection).

        ``gram_factory``: the normal equations Σ_k b_k b_kᵀ, Σ_k b_k y_k of the basis
        b_k = [filtered plays, 1] straight from the fused kernel :func:`pi2_gram` (O(P·n²) memory,
        ``gram_fused=True``). ``basis_factory``: the basis itself, (P, N, n + 1), for callers that
        need it (filtered candidate by candidate; the play matrix is fetched on first use)."""
        n = self.n_operators

        def gram_factory(u, dt, y):
            u = np.ascontiguousarray(u, dtype=np.float64)
            y = np.ascontiguousarray(y, dtype=np.float64)
            F = shared_play_matrix(u, self.pi.r)  # once per capture
            yy = float(y @ y)

            def gram(theta_nl):
                theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
                G, c = pi2_gram(F, y, *bilinear_biquad(theta_nl[:, 0], theta_nl[:, 1], dt))
                return G, c, yy

            return gram

        def factory(u, dt):
            u = np.ascontiguousarray(u, dtype=np.float64)
            plays = []  # the play matrix, computed on the first call only

            def basis(theta_nl):
                if not plays:
                    plays.append(shared_play_matrix(u, self.pi.r))
                F = plays[0]
                theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
                P, N = theta_nl.shape[0], F.shape[0]
                coef = bilinear_biquad(theta_nl[:, 0], theta_nl[:, 1], dt)
                B = np.empty((P, N, n + 1))
                for p in range(P):  # one candidate at a time: no (N, P·n) copy of the plays
                    B[p, :, :n] = biquad_columns(F, *(np.full(n, a[p]) for a in coef))
                B[:, :, n] = 1.0
                return B

            return basis

        return Separable(tuple(range(n + 1)), (n + 1, n + 2), factory, gram_factory, gram_fused=True)

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """[play states (n), d[k−1], d[k−2], e[k−1], e[k−2], v0] after the first sample u0.

        The filter memory is that of :func:`biquad_columns` (deviations from the first PI
        output v0, all zero at rest); stepping from here reproduces :meth:`simulate` from the
        second sample on.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        r = self.pi.r
        plays = np.maximum(u0 - r, np.minimum(u0 + r, 0.0))
        return np.r_[plays, 0.0, 0.0, 0.0, 0.0, plays @ t[: self.n_operators]]

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and states (C, n + 5)."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        state = np.asarray(state, dtype=np.float64)
        u_new = np.atleast_1d(np.asarray(u_new, dtype=np.float64))
        r = self.pi.r
        plays = np.maximum(u_new[:, None] - r[None, :], np.minimum(u_new[:, None] + r[None, :], state[None, :n]))
        d1, d2, e1, e2, v0 = state[n:n + 5]
        b0, b1, b2, a1, a2 = (float(c[0]) for c in bilinear_biquad(t[n + 1], t[n + 2], dt))
        d = plays @ t[:n] - v0
        e = b0 * d + b1 * d1 + b2 * d2 - a1 * e1 - a2 * e2
        C = u_new.shape[0]
        new = np.hstack([plays, d[:, None], np.full((C, 1), d1), e[:, None], np.full((C, 1), e1), np.full((C, 1), v0)])
        return e + v0 + t[n], new

    # ------------------------------------------------------------------ inverse
    def invert_dynamics(self, theta: np.ndarray, y_target: np.ndarray, dt: float) -> np.ndarray:
        """Hysteresis output v (N,) that drives the linear part along ``y_target`` (offset included):
        the ``dynamics`` block's inverse (:func:`hystfit.blocks.dynamics.invert_second_order`)."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        try:
            return invert_second_order(y_target, float(t[n + 1]), float(t[n + 2]), dt)
        except ConfigError as exc:
            raise ConfigError(f"pi2: {str(exc).removeprefix('dynamics: ')}") from None

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) for a smooth target ``y_target``: dynamic inversion, then the PI inverse.

        See the class docstring for the method and its limits (smooth target, one sample of
        preview). ``u_range`` is accepted for interface compatibility and ignored: both steps
        are analytic.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        if t.size != n + 3:
            raise ValueError(f"pi2: theta must have {n + 3} entries, got {t.size}")
        v = self.invert_dynamics(t, y_target, dt)
        return self.pi.invert(t[: n + 1], v, dt)
