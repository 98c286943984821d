"""Generalized Prandtl–Ishlinskii model (paper 000; Al Janaideh, Rakheja & Su 2009)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from .._jit import njit, prange, readonly

from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import candidate_block, store_sums, thread_blocks
from .base import Model
from .inverse import invert_by_stepping
from .pi import PI
from .separable import scaled_response

#: |tanh argument| at which an envelope counts as saturated (tanh(6) = 1 − 1.2e-5): the default
#: search range of the numerical inverse ends there.
_TANH_SATURATION = 6.0


@njit(cache=True, inline="always")
def _tanh(x):
    """tanh(x) = 1 − 2/(e^{2x} + 1): exact to ~1e-16 absolute, about twice as fast as libm tanh in
    the population loop (e^{2x} overflowing to inf gives 1, underflowing to 0 gives −1)."""
    return 1.0 - 2.0 / (math.exp(2.0 * x) + 1.0)


@njit(cache=True, inline="always")
def gpi_operators(alpha, tau, n, p0, p1):
    """Thresholds r_j = α j and density weights e^{−τ r_j} (n, m) of the candidates p0:p1 of a
    population kernel (:func:`gpi_population`, :func:`hystfit.models.pi2._gpi2_block`)."""
    m = p1 - p0
    r = np.empty((n, m))
    q = np.empty((n, m))
    for j in range(n):
        for i in range(m):
            p = p0 + i
            r[j, i] = alpha[p] * j
            q[j, i] = math.exp(-tau[p] * alpha[p] * j)
    return r, q


@njit(cache=True, inline="always")
def gpi_envelopes(uk, a1, a2, a3, a4, b1, b2, b3, b4, p0, gl, gr):
    """The envelopes γ_l(u_k), γ_r(u_k) of the candidates p0:p0 + len(gl) into ``gl``, ``gr``."""
    for i in range(gl.shape[0]):
        p = p0 + i
        gl[i] = a1[p] * _tanh(a2[p] * uk + a3[p]) + a4[p]
        gr[i] = b1[p] * _tanh(b2[p] * uk + b3[p]) + b4[p]


@njit(cache=True, inline="always")
def gpi_play(r, q, s, GL, GR, row, z, n, m):
    """Advance the operator states ``s`` (n, m) by one sample whose envelopes are row ``row`` of
    ``GL``, ``GR`` (:func:`gpi_envelope_rows`): s_j = max(γ_l − r_j, min(γ_r + r_j, s_j)), and
    z = Σ_j q_j s_j into ``z`` (j in order). With :func:`gpi_envelopes`, the one home of the gPI
    recurrence of the population kernels (gpi, pi2; candidates innermost). ``n``, ``m``: the
    operators and candidates (passed, not read off four arrays' shapes: the loops then compile
    without the checks that the arrays agree)."""
    for i in range(m):
        z[i] = 0.0
    for j in range(n):
        for i in range(m):
            v = max(GL[row, i] - r[j, i], min(GR[row, i] + r[j, i], s[j, i]))
            s[j, i] = v
            z[i] += q[j, i] * v


#: samples whose envelopes an untabulated input has computed at a time, ahead of the time loop
#: (:func:`gpi_envelopes_ahead`)
ENVELOPE_CHUNK = 256


@njit(cache=True, inline="always")
def gpi_envelope_rows(index, levels, N, a1, a2, a3, a4, b1, b2, b3, b4, p0, p1):
    """The envelope rows a population kernel reads (:func:`gpi_play`): when ``index`` (each sample's
    input level) is given, the table per level of :func:`gpi_envelope_table` (sample k reads row
    index[k]); else two buffers of :data:`ENVELOPE_CHUNK` rows that :func:`gpi_envelopes_ahead`
    fills (sample k reads row k − c0 of its chunk c0:c1).

    Why rows and not one envelope per sample computed in the time loop: a loop with the
    exponentials of the envelopes in it compiles without keeping the states in registers nor
    vectorizing over candidates (measured: the gPI kernel 1.5–3.5× slower at 1–50 candidates)."""
    if index.shape[0] > 0:
        return gpi_envelope_table(levels, a1, a2, a3, a4, b1, b2, b3, b4, p0, p1)
    rows = min(N, ENVELOPE_CHUNK)
    return np.empty((rows, p1 - p0)), np.empty((rows, p1 - p0))


@njit(cache=True, error_model="numpy", inline="always")
def gpi_envelopes_ahead(u, index, c0, c1, a1, a2, a3, a4, b1, b2, b3, b4, p0, GL, GR, gl, gr):
    """For an untabulated input (``index`` empty), rows 0:c1 − c0 of ``GL``, ``GR`` ← the envelopes
    of samples c0:c1 (:func:`gpi_envelopes`, the expression of the table: bit for bit the same);
    a tabulated input's rows are all there already."""
    if index.shape[0] == 0:
        for k in range(c0, c1):
            gpi_envelopes(u[k], a1, a2, a3, a4, b1, b2, b3, b4, p0, gl, gr)
            for i in range(gl.shape[0]):
                GL[k - c0, i] = gl[i]
                GR[k - c0, i] = gr[i]


@njit(cache=True, inline="always")
def gpi_envelope_table(levels, a1, a2, a3, a4, b1, b2, b3, b4, p0, p1):
    """γ_l, γ_r (U, m) of the candidates p0:p1 at each distinct input level: the same expression as
    :func:`gpi_envelopes`, so a tabulated envelope is bit-identical to one computed per sample."""
    U = levels.shape[0]
    m = p1 - p0
    GL = np.empty((U, m))
    GR = np.empty((U, m))
    gl = np.empty(m)
    gr = np.empty(m)
    for lv in range(U):
        gpi_envelopes(levels[lv], a1, a2, a3, a4, b1, b2, b3, b4, p0, gl, gr)
        for i in range(m):
            GL[lv, i] = gl[i]
            GR[lv, i] = gr[i]
    return GL, GR


@njit(cache=True)
def same_state(s, s_prev):
    """True when every operator state equals the one a period earlier (== : a ±0 difference changes
    no later output, every NaN differs)."""
    for j in range(s.shape[0]):
        for i in range(s.shape[1]):
            if s[j, i] != s_prev[j, i]:
                return False
    return True


@njit(cache=True)
def copy_state(dst, src):
    """dst[:, :] = src, element by element: numpy's slice assignment makes numba compile its error
    message for mismatched shapes (the shapes as text: numba's string machinery, ≈ 8 s of CPU in
    a first run after installing, more than the rest of the gPI kernel)."""
    for j in range(src.shape[0]):
        for i in range(src.shape[1]):
            dst[j, i] = src[j, i]


@njit(cache=True)
def _gpi_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, out, p0, p1, period):
    """z of :func:`gpi_population` for the candidates p0:p1: into out (N, P), or — when ``y`` is
    non-empty — its moments Σz², Σz, Σz·y into out[p, 0:3] (no (N, P) array). With ``index`` (N,)
    non-empty, u_k = levels[index[k]] and the envelopes are tabulated per level (two exp per
    candidate and level instead of per sample); otherwise computed :data:`ENVELOPE_CHUNK` samples
    at a time ahead of the time loop (:func:`gpi_envelope_rows`). With ``period``
    T > 0 (the input repeats every T samples, :func:`input_period`) and z stored, the states are
    compared every T samples: once they equal those one period earlier, the rest of z repeats and
    is copied (the same numbers, not computed again)."""
    N = u.shape[0]
    m = p1 - p0
    s = np.zeros((n, m))
    r, q = gpi_operators(alpha, tau, n, p0, p1)
    gl = np.empty(m)
    gr = np.empty(m)
    acc = np.empty(m)
    sums = np.zeros((3, m))
    moments = y.shape[0] > 0
    tabulated = index.shape[0] > 0
    GL, GR = gpi_envelope_rows(index, levels, N, a1, a2, a3, a4, b1, b2, b3, b4, p0, p1)
    repeats = period > 0 and not moments
    s_prev = np.empty((n, m) if repeats else (0, 0))
    for c0 in range(0, N, ENVELOPE_CHUNK):
        c1 = min(N, c0 + ENVELOPE_CHUNK)
        gpi_envelopes_ahead(u, index, c0, c1, a1, a2, a3, a4, b1, b2, b3, b4, p0, GL, GR, gl, gr)
        for k in range(c0, c1):
            if repeats and k > 0 and k % period == 0:
                if k >= 2 * period and same_state(s, s_prev):
                    for kk in range(k, N):
                        for i in range(m):
                            out[kk, p0 + i] = out[kk - period, p0 + i]
                    return
                copy_state(s_prev, s)
            gpi_play(r, q, s, GL, GR, index[k] if tabulated else k - c0, acc, n, m)
            if moments:
                yk = y[k]
                for i in range(m):
                    sums[0, i] += acc[i] * acc[i]
                    sums[1, i] += acc[i]
                    sums[2, i] += acc[i] * yk
            else:
                for i in range(m):
                    out[k, p0 + i] = acc[i]
    if moments:
        store_sums(out, p0, (sums[0], sums[1], sums[2]), 3)


def _gpi_serial(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, out, period, block):
    """:func:`_gpi_block` over consecutive blocks of ``block`` candidates (bounds the tables), in
    this thread. Not a kernel of its own: a compiled caller would optimise and generate the machine
    code of the whole gPI kernel once more (numba links a kernel's callees into it)."""
    P = a1.shape[0]
    for p0 in range(0, P, block):
        _gpi_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, out, p0, min(P, p0 + block),
                   period)


@njit(cache=True, parallel=True)
def _gpi_parallel(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, out, period, n_blocks):
    """:func:`_gpi_block` over ``n_blocks`` candidate blocks spread over threads."""
    for b in prange(n_blocks):
        p0, p1 = candidate_block(b, n_blocks, a1.shape[0])
        if p0 < p1:
            _gpi_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, out, p0, p1, period)


#: an input with at most this fraction of distinct values has its envelopes tabulated per value
#: (sampled sines repeat their values every cycle: sample_data has 10 samples per distinct value;
#: measured: 2× faster there, but slower than computing them at 0.4 — the table lookups then cost
#: more than the exponentials they save)
LEVELS_MAX_FRACTION = 0.2
#: table entries (levels × candidates) per block of a tabulated evaluation (2 × 16 MB)
TABLE_BLOCK_ELEMENTS = 2_000_000
#: samples × candidates from which the population is split over numba threads
PARALLEL_MIN_WORK = 5_000_000
#: the global search of optimizer ``auto`` simulates at most about this many samples per capture:
#: longer captures are searched on every k-th sample and the turning points
#: (:meth:`GPI.search_samples`), then polished on all samples
SEARCH_MAX_SAMPLES = 20_000
#: captures of at least this many samples get their normal equations (ρ, y0) from the kernel's
#: moments (whole population at once, O(n·P) memory); shorter ones from the stored z, as before
FUSED_MIN_SAMPLES = 20_000


def input_levels(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(levels (U,), index (N,)) with u = levels[index] when u has few distinct values
    (≤ :data:`LEVELS_MAX_FRACTION` of N), else (u, empty): the envelope tables' input."""
    u = readonly(u)
    levels, index = np.unique(u, return_inverse=True)
    if levels.shape[0] > LEVELS_MAX_FRACTION * u.shape[0]:
        return u, np.empty(0, dtype=np.int64)
    return np.ascontiguousarray(levels), np.ascontiguousarray(index.ravel(), dtype=np.int64)


def input_period(levels: tuple[np.ndarray, np.ndarray]) -> int:
    """The smallest T ≤ N/2 with index[k + T] = index[k] for every k (the tabulated input of
    :func:`input_levels` repeats exactly every T samples), else 0 (also for an untabulated input)."""
    index = levels[1]
    N = index.shape[0]
    if N < 2:
        return 0
    for T in np.flatnonzero(index[1:N // 2 + 1] == index[0]) + 1:
        if np.array_equal(index[T:], index[:-T]):
            return int(T)
    return 0


def gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, n, levels=None, y=None, period=0):
    """Density-weighted sum of generalized play operators for a population of candidates.

    s_j(k) = max(γ_l(u_k) − r_j, min(γ_r(u_k) + r_j, s_j(k−1))),  s_j(−1) = 0 (virgin state),
    γ_l(u) = a1 tanh(a2 u + a3) + a4,  γ_r(u) = b1 tanh(b2 u + b3) + b4,  r_j = α j,

    z(k) = Σ_{j=0}^{n−1} e^{−τ r_j} s_j(k)

    (the model output is y = ρ z + y0, see :class:`GPI`). The first sample is the README's
    initial state max(γ_l(u_0) − r, min(γ_r(u_0) + r, 0)).

    Layout (``shared/PERFORMANCE.md``): time loop outermost and sequential, candidates innermost
    and contiguous; thresholds and density weights are per candidate (α and τ vary). Envelopes
    are tabulated per distinct input value when ``levels`` = :func:`input_levels` (u) says so;
    large populations on long inputs are split over numba threads. Each candidate's arithmetic is
    the same on every route, so the result does not depend on it.

    Parameters
    ----------
    u : (N,) input (V).
    a1 … b4, tau, alpha : (P,) envelope, density-decay and threshold-step parameters.
    n : number of operators.
    levels : optional :func:`input_levels` (u), computed once per capture by the caller.
    y : optional (N,) target: then the moments Σz², Σz, Σz·y (P, 3) are returned instead of z,
        summed in time order in the kernel (memory O(n·P)).
    period : optional :func:`input_period` (levels): once the operator states repeat, z is copied
        a period on instead of computed (bit-identical; only when z is returned).

    Returns
    -------
    (N, P) array z (envelope units, V), the caller transposes; or (P, 3) moments.
    """
    u = readonly(u)
    lv, index = levels if levels is not None else (u, np.empty(0, dtype=np.int64))
    lv, index = readonly(lv), readonly(index, np.int64)  # one compiled form (see readonly)
    P = a1.shape[0]
    yk = readonly(y if y is not None else np.empty(0))
    out = np.empty((u.shape[0], P)) if y is None else np.empty((P, 3))
    args = (u, lv, index, yk, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, int(n), out, int(period))
    nb = thread_blocks(P, 2, 4) if u.shape[0] * P >= PARALLEL_MIN_WORK else 0
    block = max(1, TABLE_BLOCK_ELEMENTS // max(lv.shape[0], 1)) if index.shape[0] else P
    if nb:  # at least one block per thread, and blocks no larger than the table bound
        _gpi_parallel(*args, max(nb, -(-P // block)))
    else:
        _gpi_serial(*args, max(block, 1))
    return out


def search_indices(u: np.ndarray, step: int) -> np.ndarray:
    """Sorted indices of one sample in every block of ``step`` samples, each turning point (a sample
    where the input stops rising or falling, pauses included), the first and the last sample.

    The sample of block i sits at offset ⌊step · frac(i·φ)⌋ (φ the golden ratio), not at the block's
    start: on a periodic capture whose period is a multiple of ``step`` (a 10 Hz sine at 10 kHz, step
    50) every ``step``-th sample would see the same few phases of every cycle — an aliased loop of
    20 points — while these offsets spread over every phase.

    With increasing envelopes (a1·a2 > 0, b1·b2 > 0: the default bounds) a play operator moves
    monotonically between turning points, so simulating the kept samples alone gives the same
    operator states — and outputs, bit for bit — at those samples as simulating them all."""
    u = np.asarray(u, dtype=np.float64)
    n = u.shape[0]
    step = max(int(step), 1)
    d = np.sign(np.diff(u))
    turns = np.flatnonzero(d[1:] * d[:-1] <= 0) + 1
    blocks = np.arange(0, n, step)
    offsets = np.floor(step * ((np.arange(blocks.size) * _GOLDEN) % 1.0)).astype(np.int64)
    picked = np.minimum(blocks + offsets, n - 1)
    return np.union1d(np.union1d(picked, turns), [0, n - 1])


#: the golden ratio's fractional part: offsets i·φ mod 1 fill [0, 1) evenly for any number of blocks
_GOLDEN = 0.6180339887498949


@models.register
@dataclass(frozen=True)
class GPI(Model):
    r"""Generalized Prandtl–Ishlinskii hysteresis: play operators on two tanh envelope functions.

    .. math::

        s_r[u](k) = \max\big(\gamma_l(u_k) - r,\ \min(\gamma_r(u_k) + r,\ s_r[u](k-1))\big),
        \qquad s_r[u](-1) = 0

        \gamma_l(u) = a_1 \tanh(a_2 u + a_3) + a_4,\qquad
        \gamma_r(u) = b_1 \tanh(b_2 u + b_3) + b_4

        y(k) = \sum_{j=0}^{n-1} p(r_j)\, s_{r_j}[u](k) + y_0,\qquad
        p(r) = \rho\, e^{-\tau r},\qquad r_j = \alpha_r\, j

    (paper 000, whose equations are images in our copy; formulation pinned down in
    ``shared/papers/README.md`` after Al Janaideh, Rakheja & Su 2009). The first sample is
    max(γ_l(u_0) − r, min(γ_r(u_0) + r, 0)), as for the classical play operator (003 eq. 2).
    γ_l bounds the operator from below (it drives the output on rising input), γ_r from above
    (falling input); with γ_l = γ_r = γ the model is the classical PI of γ(u).

    Units: the envelopes γ map volts to a *generalized input* measured in V (γ(u) ≈ u for
    a1·a2 = 1, a3 = −a2·u_c, a4 = u_c): thresholds r_j and α_r are in V, τ in 1/V, ρ in output
    unit per V.

    Structure
    ---------
    n_operators : number of generalized play operators n (r_0 = 0 is the envelope itself), default 10.
    search_max_samples : on a longer capture optimizer ``auto`` runs its global search on about this
        many samples plus the turning points (:meth:`search_samples`), then polishes on every
        sample; default 20,000; 0 searches every sample. On the virtual actuator's 10⁶-sample capture
        (``benchmarks/memory.py``) the subsample takes 24–40 s and reaches an RMSE of 0.050–0.058 µm
        (seeds 0–2); the search on every sample reaches 0.0395 µm (seed 0) in ≈ 335 s.

    Parameters (θ), in the order a1, a2, a3, a4, b1, b2, b3, b4, rho, tau, alpha_r, y0
    ----------------------------------------------------------------------------------
    a1, b1 : envelope amplitudes (V), > 0.   a2, b2 : envelope input scales (1/V), > 0.
    a3, b3 : envelope shifts (tanh argument offset, 1).   a4, b4 : envelope offsets (V).
    rho : density scale ρ = p(0), output unit per V (≥ 0; the weight of the r = 0 operator).
    tau : density decay τ (1/V, ≥ 0): the weight of operator j is ρ e^{−τ α_r j}.
    alpha_r : threshold step α_r (V): r_j = α_r·j.
    y0 : output offset (output unit).

    The offset y0 is ours (the README's formulation has none): real captures carry an arbitrary
    sensor zero. Without y0 an offset could only be produced through a4, b4 — multiplied by
    Σ_j p(r_j) and entangled with the operators' virgin state — which couples the offset to the
    hysteresis shape. With y0 the offset is one linear parameter (solved exactly by variable
    projection, :meth:`separable`).

    Bounds scale with the data (``DataScale``): with h = half the input range and u_c its
    centre, tanh arguments scale with 1/h (a2, b2 ∈ [0.05, 4]/h; a3, b3 ∈ ±(4 + 4|u_c|/h)),
    amplitudes and offsets with h (a1, b1 ∈ [0.2, 10]·h; a4, b4 ∈ u_c ± 3h), α_r ∈
    [0.01, 2]·(input range)/n, τ ∈ [0, 10]·n/(input range), ρ ∈ [0, 3]·gain (gain = output
    range/input range). Every θ inside the box gives a finite output: |tanh| ≤ 1 and
    e^{−τ r} ≤ 1.

    Identifiability. The output is exactly invariant under (a1, a4, b1, b4, α_r) → c·(…),
    (ρ, τ) → (…)/c for any c > 0 (all envelopes, thresholds and play outputs scale by c), so
    one of these is not identifiable: fix it (narrow bounds on a1, say) or compare only the
    invariants a2, a3, b2, b3, τ·α_r, ρ·a1, b1/a1, α_r/a1. A common shift of a4 and b4 changes
    the output only through the virgin operator states, i.e. it is nearly confounded with y0.
    The least-squares landscape has local minima: threshold-step aliasing (α_r → 2α_r with
    ρ → 2ρ reuses every other threshold) is a typical one — use global-search restarts
    (``--opt-option restarts=3`` with ``auto``: three searches, each polished, the best kept;
    ``benchmarks/restarts.py``).

    Inverse. With equal envelopes (a_i = b_i) the model is the classical PI of γ(u): its exact
    inverse is the inverse PI (paper 003 eq. 17–20) followed by γ⁻¹(v) = (atanh((v − a4)/a1) − a3)/a2.
    Otherwise the input is found per sample by :func:`hystfit.models.inverse.invert_by_stepping`:
    for fixed operator memory the output is non-decreasing in u_k when a1·a2 > 0, b1·b2 > 0 and
    ρ ≥ 0 (README). Targets beyond the saturated envelopes saturate.
    """

    name = "gpi"
    title = "Generalized Prandtl–Ishlinskii (tanh envelopes, exponential density)"
    reference = "paper 000 (generalized PI of Al Janaideh, Rakheja & Su 2009); shared/papers/README.md"
    equation = ("y = Σ_j ρ e^{−τ r_j} s_{r_j}[u] + y0,  s_r = max(γ_l(u) − r, min(γ_r(u) + r, s_r(k−1))),  "
                "γ_l = a1 tanh(a2 u + a3) + a4,  γ_r = b1 tanh(b2 u + b3) + b4,  r_j = α_r j")
    rate_dependent = False
    first_sample_is_a_ramp = True  # initial_state: the play states after u0 from the virgin state
    resolution_option = "n_operators"

    n_operators: int = 10
    search_max_samples: int = SEARCH_MAX_SAMPLES

    def __post_init__(self) -> None:
        if not isinstance(self.n_operators, int) or isinstance(self.n_operators, bool) or not 1 <= self.n_operators <= 200:
            raise ConfigError(f"gpi: n_operators must be an integer in [1, 200], got {self.n_operators!r}")
        m = self.search_max_samples
        if not isinstance(m, int) or isinstance(m, bool) or m < 0:
            raise ConfigError(f"gpi: search_max_samples must be an integer ≥ 0 (0: search every sample), got {m!r}")

    # ------------------------------------------------------------------ parameters
    def params(self, scale: DataScale) -> tuple[Param, ...]:
        n = self.n_operators
        U = scale.u_range
        h = 0.5 * U
        uc = 0.5 * (scale.u_min + scale.u_max)
        g = scale.gain
        a2_def = 0.5 / h
        a3_lim = 4.0 + 4.0 * abs(uc) / h
        ps = []
        for side, what in (("a", "γ_l (rising-input envelope)"), ("b", "γ_r (falling-input envelope)")):
            ps += [
                Param(f"{side}1", "V", 0.2 * h, 10.0 * h, 2.0 * h, f"amplitude of {what}"),
                Param(f"{side}2", "1/V", 0.05 / h, 4.0 / h, a2_def, f"input scale of {what}"),
                Param(f"{side}3", "1", -a3_lim, a3_lim, -a2_def * uc, f"tanh-argument shift of {what}"),
                Param(f"{side}4", "V", scale.u_min - U, scale.u_max + U, uc, f"offset of {what}"),
            ]
        ps += [
            (Param("rho", "out/V", 0.0, 3.0 * g, 0.5 * g, "density scale ρ = p(0), weight of the r = 0 operator")
             if scale.sign > 0 else  # an output that falls with the input (inverted sensor): ρ ≤ 0
             Param("rho", "out/V", -3.0 * g, 0.0, -0.5 * g, "density scale ρ = p(0), weight of the r = 0 operator")),
            Param("tau", "1/V", 0.0, 10.0 * n / U, 0.6 * n / U, "density decay τ: p(r) = ρ·exp(−τ r)"),
            Param("alpha_r", "V", 0.01 * U / n, 2.0 * U / n, 0.5 * U / n, "threshold step α_r: r_j = α_r·j"),
            Param("y0", "out", *scale.offset_bounds(),
                  0.5 * (scale.y_min + scale.y_max) if scale.y_min > 0 or scale.y_max < 0 else 0.0, "output offset"),
        ]
        return tuple(ps)

    # ------------------------------------------------------------------ simulation
    def _z(self, theta: np.ndarray, u: np.ndarray, levels=None, y=None, period: int = 0) -> np.ndarray:
        """Unit-density output z (N, P) = Σ_j e^{−τ r_j} s_j (y = ρ z + y0), or with a target ``y``
        its moments (P, 3); ``levels`` = :func:`input_levels` (u), ``period`` its :func:`input_period`."""
        c = [np.ascontiguousarray(theta[:, i]) for i in range(11)]
        a1, a2, a3, a4, b1, b2, b3, b4, _, tau, alpha = c
        return gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, self.n_operators, levels, y, period)

    def _output(self, theta: np.ndarray, u: np.ndarray, levels=None, period: int = 0) -> np.ndarray:
        theta = self.check_theta(theta, 12)
        z = self._z(theta, u, levels, period=period)  # (N, P)
        return (z * theta[:, 8][None, :] + theta[:, 11][None, :]).T

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self._output(theta, readonly(u))

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        u = readonly(u)
        levels = input_levels(u)  # once per capture, shared by every call
        period = input_period(levels)
        return lambda theta: self._output(theta, u, levels, period)

    def separable(self):
        """ρ and y0 enter linearly: y = ρ·z(a, b, τ, α_r) + y0; the other ten are searched."""
        nl = (0, 1, 2, 3, 4, 5, 6, 7, 9, 10)

        def full(theta_nl):
            theta_nl = np.atleast_2d(theta_nl)
            th = np.zeros((theta_nl.shape[0], 12))
            th[:, nl] = theta_nl
            return th

        def response(u, dt):
            levels = input_levels(u)  # once per capture, shared by every call
            period = input_period(levels)
            return lambda theta_nl: self._z(full(theta_nl), u, levels, period=period)  # (N, P)

        def moments(u, dt, y):
            if not fused(len(u), dt):
                return None  # short captures: moments from z (numpy), as they always were
            u = readonly(u)
            levels = input_levels(u)

            def sums(theta_nl):
                M = self._z(full(theta_nl), u, levels, y)
                return M[:, 0], M[:, 1], M[:, 2]

            return sums

        def fused(n_samples, dt):
            return n_samples >= FUSED_MIN_SAMPLES

        return scaled_response((8, 11), nl, response, moments, fused_for=fused)

    def search_samples(self, u: np.ndarray) -> np.ndarray | None:
        """Indices of the samples on which optimizer ``auto`` runs its global search on a capture
        longer than ``search_max_samples`` (None: shorter, or 0: all samples): one sample in every
        block of k, k = ⌈N / search_max_samples⌉, plus the turning points (:func:`search_indices`). The model
        is rate-independent, so the outputs at the kept samples are exactly those of the whole
        capture: the search minimizes the mean squared error over a time-uniform subsample (the
        polish then uses every sample)."""
        n = np.asarray(u).shape[0]
        cap = self.search_max_samples
        if cap == 0 or n <= cap:
            return None
        return search_indices(u, -(-n // cap))

    # ------------------------------------------------------------------ stepping
    def _unpack(self, theta: np.ndarray):
        t = np.asarray(theta, dtype=np.float64).ravel()
        if t.size != 12:
            raise ValueError(f"gpi: theta must have 12 entries, got {t.size}")
        return t

    def _operators(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Thresholds r_j (V) and weights p(r_j) = ρ e^{−τ r_j} (out/V) of one parameter vector."""
        r = t[10] * np.arange(self.n_operators, dtype=np.float64)
        with np.errstate(over="ignore"):
            p = t[8] * np.exp(-t[9] * r)
        return r, p

    @staticmethod
    def _envelopes(t: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.asarray(u, dtype=np.float64)
        return (t[0] * np.tanh(t[1] * u + t[2]) + t[3], t[4] * np.tanh(t[5] * u + t[6]) + t[7])

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """Operator states (n,) after the first sample u0 from the virgin state (the reset of :meth:`simulate`).

        Applying the same input again leaves them unchanged, so stepping from here reproduces
        :meth:`simulate` from the second sample on.
        """
        t = self._unpack(theta)
        r, _ = self._operators(t)
        gl, gr = self._envelopes(t, np.array([float(u0)]))
        return np.maximum(gl[0] - r, np.minimum(gr[0] + r, 0.0))

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and operator states (C, n)."""
        t = self._unpack(theta)
        r, p = self._operators(t)
        gl, gr = self._envelopes(t, np.atleast_1d(u_new))
        s = np.maximum(gl[:, None] - r[None, :], np.minimum(gr[:, None] + r[None, :], np.asarray(state, float)[None, :]))
        return s @ p + t[11], s

    # ------------------------------------------------------------------ inverse
    def envelopes_equal(self, theta: np.ndarray, rtol: float = 1e-12) -> bool:
        """True when γ_l = γ_r (a_i = b_i to ``rtol``): the analytic inverse applies."""
        t = self._unpack(theta)
        a, b = t[0:4], t[4:8]
        return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(a), np.abs(b)) + 1e-300))

    def _inverse_range(self, theta: np.ndarray, y_target: np.ndarray) -> tuple[float, float]:
        """Input interval on which both envelopes are unsaturated (|tanh argument| ≤ 6)."""
        t = self._unpack(theta)
        ends = [(s * _TANH_SATURATION - t[c3]) / t[c2] for c2, c3 in ((1, 2), (5, 6)) for s in (-1.0, 1.0)]
        return float(min(ends)), float(max(ends))

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) whose simulated output follows ``y_target`` (N,).

        Exact for equal envelopes (inverse PI of paper 003 eq. 17–20 on the generalized input,
        then γ⁻¹ by atanh; generalized inputs beyond the envelope's open range are clipped to it,
        i.e. the input saturates far out). Otherwise per-sample numerical inversion on
        :meth:`step` over ``u_range`` (default: where the envelopes are unsaturated), starting
        from the virgin operator state like :meth:`simulate`.
        """
        t = self._unpack(theta)
        if not (t[0] * t[1] > 0 and t[4] * t[5] > 0 and t[8] != 0):
            raise ConfigError("gpi: the inverse needs increasing envelopes (a1·a2 > 0, b1·b2 > 0) and rho ≠ 0")
        y_target = np.asarray(y_target, dtype=np.float64)
        if self.envelopes_equal(t):
            return self._invert_equal(t, y_target)
        return invert_by_stepping(_VirginStart(self), t, y_target, dt,
                                  u_range=u_range or self._inverse_range(t, y_target))

    def _invert_equal(self, t: np.ndarray, y_target: np.ndarray) -> np.ndarray:
        r, p = self._operators(t)
        if t[10] > 0 and self.n_operators > 1:
            pi = PI(self.n_operators, thresholds_V=tuple(float(x) for x in r))
            v = pi.invert(np.r_[p, t[11]], y_target, 1.0)
        else:  # all thresholds zero: y = (Σ p) γ(u) + y0
            v = (y_target - t[11]) / np.sum(p)
        x = np.clip((v - t[3]) / t[0], -1.0 + 1e-12, 1.0 - 1e-12)
        return (np.arctanh(x) - t[2]) / t[1]


class _VirginStart:
    """Adapter for :func:`invert_by_stepping`: the first sample is stepped from the virgin state.

    ``GPI.initial_state(θ, u0)`` is the memory *after* a first sample u0 (so stepping reproduces
    ``simulate`` from sample 1); the inverse must choose sample 0 itself, from the all-zero
    operator states that :meth:`GPI.simulate` starts from.
    """

    def __init__(self, model: GPI) -> None:
        self.model = model

    def initial_state(self, theta, u0, dt):
        return np.zeros(self.model.n_operators)

    def step(self, theta, state, u_prev, u_new, dt):
        return self.model.step(theta, state, u_prev, u_new, dt)
