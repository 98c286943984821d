"""Second-order stage dynamics: ÿ + 2ζω_n ẏ + ω_n² y = ω_n² x (paper 000's linear subsystem)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from .._jit import njit, readonly
from ..effects import EffectParam
from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import blocks
from .base import Block, frequency_of_excitation, scale_of_views


@njit(cache=True)
def biquad_columns(x, b0, b1, b2, a1, a2):
    """Filter every column of x (N, M) with its own biquad, each starting at rest at x[0, m].

    y[k] = x[0] + e[k],  e[k] = b0 d[k] + b1 d[k−1] + b2 d[k−2] − a1 e[k−1] − a2 e[k−2],
    d[k] = x[k] − x[0], d[<0] = e[<0] = 0 (direct form I on deviations from the first sample).

    For a unit-DC-gain filter this is exactly the response from rest at x[0] (the filter has
    seen x[0] forever), computed without the cancellation of a large offset through poles near
    z = 1. Layout (``shared/PERFORMANCE.md``): time outermost, columns innermost and contiguous.
    A column with non-finite coefficients gives non-finite output (never an exception).

    Parameters
    ----------
    x : (N, M) float64 inputs.  b0, b1, b2, a1, a2 : (M,) coefficients (a0 = 1).

    Returns
    -------
    (N, M) float64 outputs.
    """
    N, M = x.shape
    out = np.empty((N, M))
    if N == 0:
        return out
    x0 = x[0].copy()
    d1 = np.zeros(M)
    d2 = np.zeros(M)
    e1 = np.zeros(M)
    e2 = np.zeros(M)
    for k in range(N):
        for m in range(M):
            d = x[k, m] - x0[m]
            e = b0[m] * d + b1[m] * d1[m] + b2[m] * d2[m] - a1[m] * e1[m] - a2[m] * e2[m]
            d2[m] = d1[m]
            d1[m] = d
            e2[m] = e1[m]
            e1[m] = e
            out[k, m] = e + x0[m]
    return out


def bilinear_biquad(fn_Hz, zeta, dt: float):
    """Prewarped bilinear (Tustin) discretization of ω_n²/(s² + 2ζω_n s + ω_n²), per candidate.

    s = K (1 − z⁻¹)/(1 + z⁻¹), K = ω_n / tan(ω_n Ts/2) (prewarping: the resonance ω_n maps
    exactly). Closed form, a0 = K² + 2ζω_n K + ω_n²:

        a1 = 2(ω_n² − K²)/a0,  a2 = (K² − 2ζω_n K + ω_n²)/a0,  b = g·[1, 2, 1],  g = (1 + a1 + a2)/4

    The numerator is built from the denominator so that the static gain H(1) = 4g/(1 + a1 + a2)
    is 1 to one rounding (analytically it is exactly 1). Candidates with f_n outside (0, f_s/2)
    or ζ < 0 get NaN coefficients (their simulation is non-finite, scored +inf by the objective).

    Returns
    -------
    b0, b1, b2, a1, a2 : (P,) float64 arrays.
    """
    fn = np.atleast_1d(np.asarray(fn_Hz, dtype=np.float64))
    z = np.atleast_1d(np.asarray(zeta, dtype=np.float64))
    with np.errstate(all="ignore"):
        wn = 2.0 * np.pi * fn
        ok = (fn > 0) & (fn * dt < 0.5) & (z >= 0) & np.isfinite(fn) & np.isfinite(z)
        K = wn / np.tan(0.5 * wn * dt)
        a0 = K * K + 2.0 * z * wn * K + wn * wn
        a1 = 2.0 * (wn * wn - K * K) / a0
        a2 = (K * K - 2.0 * z * wn * K + wn * wn) / a0
        g = 0.25 * (1.0 + a1 + a2)
    nan = np.full_like(g, np.nan)
    a1, a2, g = (np.where(ok, c, nan) for c in (a1, a2, g))
    return g, 2.0 * g, g.copy(), a1, a2


@njit(cache=True)
def biquad_shared(x, b0, b1, b2, a1, a2):
    """:func:`biquad_columns` with one biquad (scalar coefficients) for every column of x (N, M):
    the same operations in the same order, so the same numbers; the columns form one vector."""
    N, M = x.shape
    out = np.empty((N, M))
    if N == 0:
        return out
    x0 = x[0].copy()
    d1 = np.zeros(M)
    d2 = np.zeros(M)
    e1 = np.zeros(M)
    e2 = np.zeros(M)
    for k in range(N):
        for m in range(M):
            d = x[k, m] - x0[m]
            e = b0 * d + b1 * d1[m] + b2 * d2[m] - a1 * e1[m] - a2 * e2[m]
            d2[m] = d1[m]
            d1[m] = d
            e2[m] = e1[m]
            e1[m] = e
            out[k, m] = e + x0[m]
    return out


@njit(cache=True)
def biquad_shared_rows(x, rows, out, offset, b0, b1, b2, a1, a2):
    """:func:`biquad_shared` of x (N, M) at the sorted ``rows`` only, written into
    ``out[offset + i, :M]`` for ``rows[i]`` (``out`` may have more columns): the same operations in
    the same order (so the same numbers in those rows), without an (N, M) output. The recurrence
    runs up to the last row asked for.

    Why: a search scores a stage on a design's fit rows, or every fourth of them when it ranks
    its grid (:func:`hystfit.effects.coarse_design`), and forms their Gram product. Writing every
    row and then copying the rows asked for moved the columns through memory three times; the
    columns of a capture are larger than a core's cache, so the filter was bound by memory.
    :func:`biquad_shared` keeps its own loop: with the test for a row asked for, a simulation's few
    columns (M = 4, 20,000 samples) filtered about 2× slower."""
    N, M = x.shape
    n = rows.shape[0]
    if N == 0 or n == 0:
        return
    x0 = x[0].copy()
    d1 = np.zeros(M)
    d2 = np.zeros(M)
    e1 = np.zeros(M)
    e2 = np.zeros(M)
    p = 0
    for k in range(rows[n - 1] + 1):
        take = rows[p] == k
        o = offset + p
        for m in range(M):
            d = x[k, m] - x0[m]
            e = b0 * d + b1 * d1[m] + b2 * d2[m] - a1 * e1[m] - a2 * e2[m]
            d2[m] = d1[m]
            d1[m] = d
            e2[m] = e1[m]
            e1[m] = e
            if take:
                out[o, m] = e + x0[m]
        if take:
            p += 1


@functools.lru_cache(maxsize=4096)
def _stage_coefficients(fn_Hz: float, zeta: float, dt: float) -> tuple[float, ...]:
    """(b0, b1, b2, a1, a2) of :func:`bilinear_biquad` for one (f_n, ζ, dt): a search scores one
    candidate on every capture (and the same candidates again), so each is computed once."""
    return tuple(float(c[0]) for c in bilinear_biquad(fn_Hz, zeta, dt))


def check_below_nyquist(fn_Hz: float, dt: float, what: str) -> None:
    """Refuse a sample period at whose Nyquist frequency 1/(2·dt) the stage f_n = ``fn_Hz`` is not
    resolved (one-line :class:`ConfigError` naming ``what``, f_n, the sample rate and the fix).

    :func:`bilinear_biquad` has no discretization there (prewarping tan(ω_n·dt/2) passes its
    pole) and gives NaN coefficients, so a simulation would be NaN from the first sample: an
    identified model must be refused on such data, not run into empty predictions.
    """
    if not fn_Hz * dt < 0.5:
        raise ConfigError(f"{what}: the stage's natural frequency f_n = {fn_Hz:.6g} Hz is not below the Nyquist "
                          f"frequency {0.5 / dt:.6g} Hz of data sampled at {1.0 / dt:.6g} Hz; use data sampled "
                          f"above {2.0 * fn_Hz:.6g} Hz or identify the model from data at {1.0 / dt:.6g} Hz")


def second_order_at_rest(x: np.ndarray, fn_Hz: float, zeta: float, dt: float) -> np.ndarray:
    """Filter ``x`` ((N,) or (N, m), along axis 0) by the prewarped second-order stage, at rest at x(0).

    Raises :class:`ConfigError` when f_n is not below the Nyquist frequency or ζ < 0.
    """
    if not (0.0 < fn_Hz * dt < 0.5 and zeta >= 0.0):
        raise ConfigError(f"dynamics: f_n = {fn_Hz:g} Hz must lie below the Nyquist frequency {0.5 / dt:g} Hz "
                          f"and ζ = {zeta:g} must be ≥ 0")
    x = np.asarray(x, dtype=np.float64)
    xc = readonly(x[:, None] if x.ndim == 1 else x)
    out = biquad_shared(xc, *_stage_coefficients(float(fn_Hz), float(zeta), float(dt)))
    return out[:, 0] if x.ndim == 1 else out


def invert_second_order(y: np.ndarray, fn_Hz: float, zeta: float, dt: float) -> np.ndarray:
    """The stage input v (N,) that drives the second-order stage along ``y`` (N,).

    v = y + (2ζ/ω_n)·S y + S² y/ω_n² with the bilinear-consistent central differences
    S ≈ (K/4)(y[k+1] − y[k−1]), S² ≈ (K²/4)(y[k+1] − 2y[k] + y[k−1]), K = ω_n/tan(ω_n Ts/2),
    then the dynamic correction c = v − y is sharpened once, c ← 2c − M c with the 3-tap
    smoother M = [1, 2, 1]/4 (M is the cos²(θ/2) factor of the central differences; 2 − M
    inverts it to O(θ⁴)). y is held at y[0] before the first and at y[N−1] after the last sample.

    Why not the discrete filter's exact inverse: the bilinear numerator g(1 + z⁻¹)² has a double
    zero *on* the unit circle (z = −1), so the exact inverse carries an undamped, linearly growing
    alternating mode. Limits: the target must be smooth (content above f_n is amplified by
    (f/f_n)²), one sample of preview (y[k+1]) is used.
    """
    if not (0 < fn_Hz * dt < 0.5 and zeta >= 0):
        raise ConfigError(f"dynamics: cannot invert with fn_Hz={fn_Hz:g} (must lie in (0, fs/2)) and zeta={zeta:g}")
    wn = 2.0 * math.pi * fn_Hz
    K = wn / math.tan(0.5 * wn * dt)
    y = np.asarray(y, dtype=np.float64)
    yp = np.concatenate([[y[0]], y, [y[-1]]])
    d1 = 0.25 * K * (yp[2:] - yp[:-2])
    d2 = 0.25 * K * K * (yp[2:] - 2.0 * y + yp[:-2])
    c = (2.0 * zeta / wn) * d1 + d2 / (wn * wn)
    cp = np.concatenate([[0.0], c, [c[-1]]])  # at rest before (c = 0), held after
    c = 2.0 * c - 0.25 * (cp[2:] + 2.0 * c + cp[:-2])
    c[0] = 0.0  # the filter starts at rest at its first input: y[0] = v[0] whatever comes next
    return y + c


#: how close to a bound of its search range a fitted f_n or ζ is "on" it (relative): a polish that
#: follows the SSE's gradient stops within its tolerance of a bound it is pushed against (ζ
#: 1.9998 for a bound of 2), never exactly on it as a Nelder–Mead clipped into a corner did
EDGE_RTOL = 1e-3

#: the lowest f_n a search range is widened to (:meth:`Dynamics.widened`)
FN_FLOOR_HZ = 1.0


def fn_search_range_of(scale: DataScale) -> tuple[float, float]:
    """:func:`fn_search_range` for identification data: from twice the smooth drives' frequency
    (:func:`~hystfit.blocks.base.frequency_of_excitation`), or with none of them (broadband, steps)
    from 10 / the longest capture's duration; ``diagnose`` sets the same range
    (:meth:`Dynamics.configure`, :func:`~hystfit.blocks.base.scale_of_views`)."""
    f = frequency_of_excitation(scale)
    if not np.isfinite(f) and scale.duration_s:
        f = 10.0 / scale.duration_s
    return fn_search_range(scale.dt, f)


def fn_search_range(dt: float, f_exc_Hz: float) -> tuple[float, float]:
    """Bounds of f_n (Hz): 2× the excitation frequency (a resonance inside the excitation band
    would be obvious in the loops) … 0.45·f_s (below Nyquist); at least a factor 4 wide."""
    hi = 0.45 / dt
    lo = 2.0 * f_exc_Hz if np.isfinite(f_exc_Hz) and f_exc_Hz > 0 else 1.0
    return float(min(max(lo, 1.0), hi / 4.0)), float(hi)


@blocks.register
@dataclass(frozen=True)
class Dynamics(Block):
    r"""Linear stage dynamics after the hysteresis: a second-order low-pass with unit DC gain.

    .. math:: \ddot y + 2\zeta\omega_n\dot y + \omega_n^2 y = \omega_n^2\,x,\qquad \omega_n = 2\pi f_n

    the "electromechanical" linear subsystem of paper 000 (Fig. 3, eq. 20–21), discretized
    exactly for a resonance: bilinear transform prewarped at ω_n (the discrete peak sits at f_n,
    :func:`bilinear_biquad`), started at rest at x(0), filtered by a numba kernel
    (:func:`biquad_columns`, candidates innermost). The virtual actuator's ``dynamics`` switch and
    the ``pi2`` model use the same two functions.

    Why this form: a piezo stage is a mass on a spring; below its first resonance it adds a
    phase lag ≈ 2ζ f/f_n and a gain rise ≈ (1 − 2ζ²)(f/f_n)² that grow with the drive frequency,
    and it rings at f_n after fast input changes — the rate dependence a rate-independent
    hysteresis model cannot show. Two searched parameters, nothing linear (the DC gain belongs
    to the base model).

    Parameters (θ)
    --------------
    fn_Hz : natural frequency f_n (Hz), in [fn_min_Hz, fn_max_Hz].
    zeta : damping ratio ζ (1), in [zeta_min, zeta_max] = [0.02, 2].

    Structure
    ---------
    fn_min_Hz, fn_max_Hz : bounds of f_n (Hz); by default (None) 2× the excitation frequency …
        0.45·f_s, set from the data.

    Inverse: :func:`invert_second_order` (continuous equation with bilinear-consistent
    differences; the target must be smooth).
    """

    name: ClassVar[str] = "dynamics"
    title: ClassVar[str] = "linear stage dynamics (second-order)"
    equation: ClassVar[str] = "y'' + 2ζω_n y' + ω_n² y = ω_n² x"
    reference: ClassVar[str] = "paper 000 (second-order linear subsystem), bilinear transform prewarped at f_n"

    fn_min_Hz: float | None = None
    fn_max_Hz: float | None = None
    zeta_min: float = 0.02
    zeta_max: float = 2.0
    n_fn: int = 16
    n_zeta: int = 8

    # ------------------------------------------------------------------ structure
    def configure(self, views, yhats):
        lo, hi = fn_search_range_of(scale_of_views(views))  # as identify sets it (Dynamics.adapt)
        return replace(self, fn_min_Hz=lo, fn_max_Hz=hi)

    def adapt(self, scale: DataScale) -> "Dynamics":
        lo, hi = fn_search_range_of(scale)
        return replace(self, fn_min_Hz=lo if self.fn_min_Hz is None else self.fn_min_Hz,
                       fn_max_Hz=hi if self.fn_max_Hz is None else self.fn_max_Hz)

    @property
    def fn_range(self) -> tuple[float, float]:
        """(lower, upper) bound of f_n (Hz); 10 Hz … 4 kHz before they are set from the data."""
        return (10.0 if self.fn_min_Hz is None else float(self.fn_min_Hz),
                4000.0 if self.fn_max_Hz is None else float(self.fn_max_Hz))

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        lo, hi = self.fn_range
        return (Param("fn_Hz", "Hz", lo, hi, math.sqrt(lo * hi),
                      "natural frequency f_n of the stage"),
                Param("zeta", "1", self.zeta_min, self.zeta_max, 0.2, "damping ratio ζ of the stage"))

    # ------------------------------------------------------------------ diagnose interface
    def param_table(self):
        return (EffectParam("fn_Hz", "Hz", "searched", "natural frequency of the stage"),
                EffectParam("zeta", "1", "searched", "damping ratio"))

    def searched_bounds(self):
        lo, hi = self.fn_range
        return np.array([lo, self.zeta_min]), np.array([hi, self.zeta_max])

    def search_grid(self):
        fn = np.geomspace(*self.fn_range, self.n_fn)
        z = np.geomspace(self.zeta_min, self.zeta_max, self.n_zeta)
        F, Z = np.meshgrid(fn, z, indexing="ij")
        return np.column_stack([F.ravel(), Z.ravel()])

    def operator(self, x, view, phi):
        return second_order_at_rest(x, float(phi[0]), float(phi[1]), view.dt)

    def operator_rows(self, x, view, phi, rows, out, offset):
        fn, zeta = float(phi[0]), float(phi[1])
        if not (0.0 < fn * view.dt < 0.5 and zeta >= 0.0):
            second_order_at_rest(x[:1], fn, zeta, view.dt)  # its one-line error
        biquad_shared_rows(readonly(x), readonly(rows, np.int64), out, int(offset),
                           *_stage_coefficients(fn, zeta, float(view.dt)))

    def widened(self, phi):
        """With f_n's lower bound a quarter as high (not below :data:`FN_FLOOR_HZ`) when the fit ended on
        it: that bound is twice the fastest drive (:func:`fn_search_range`), a guess that a slower
        stage (a blind test's 400 Hz under a 300 Hz drive, fitted at the 600 Hz bound) proves wrong."""
        lo, hi = self.fn_range
        if float(phi[0]) > lo * (1.0 + EDGE_RTOL) or lo <= FN_FLOOR_HZ * (1.0 + 1e-9):
            return None
        step = 10.0 ** math.floor(math.log10(lo / 4.0) - 2.0)  # three significant digits, rounded down
        return replace(self, fn_min_Hz=max(float(f"{math.floor(lo / 4.0 / step) * step:.3g}"), FN_FLOOR_HZ),
                       fn_max_Hz=hi)

    def handover_options(self, views):
        lo = self.fn_range[0]
        usual = fn_search_range_of(scale_of_views(views))[0]
        return {"fn_min_Hz": lo} if lo < usual * (1.0 - 1e-9) else {}

    def absent_at(self, phi):
        """f_n at the top of its search range (0.45 f_s or the range set), or ζ at the top of its own:
        no resonance inside them. Both are the one direction in which a stage fades into a pure lag
        (its low-frequency group delay 2ζ/ω_n kept while f_n → ∞ or ζ → ∞): a search bounded in ζ
        follows it along ζ's bound to an f_n inside the range (the gradient polish does: sample_data's
        first step, f_n 4433 Hz at ζ = 2, where a Nelder–Mead stuck in the corner at 4500 Hz)."""
        return (float(phi[0]) >= self.fn_range[1] * (1.0 - EDGE_RTOL)
                or float(phi[1]) >= self.zeta_max * (1.0 - EDGE_RTOL))

    def signature(self, yhat, view):
        d1 = np.gradient(np.asarray(yhat, dtype=np.float64), view.dt)
        d2 = np.gradient(d1, view.dt)
        return np.column_stack([d1, d2]), np.zeros((yhat.shape[0], 0))

    def describe(self, phi, shared, local, views, sources=None):
        fn, z = float(phi[0]), float(phi[1])
        fmax = frequency_of_excitation(scale_of_views(views))
        out = {"fn_Hz": fn, "zeta": z,
               "group_delay_low_frequency_us": 1e6 * z / (math.pi * fn),
               "search_fn_Hz": list(self.fn_range), "search_zeta": [self.zeta_min, self.zeta_max]}
        if np.isfinite(fmax):
            r = fmax / fn
            h = 1.0 / complex(1.0 - r * r, 2.0 * z * r)
            out["at_highest_excitation_Hz"] = fmax
            out["phase_lag_at_highest_excitation_deg"] = -math.degrees(math.atan2(h.imag, h.real))
            out["gain_at_highest_excitation"] = abs(h)
        return out

    def natural_frequency_Hz(self, theta):
        return float(np.ravel(theta)[0])

    # ------------------------------------------------------------------ composite interface
    def apply_population(self, x, theta, dt):
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        th = self.population(theta, 2, x.shape[0])
        coef = bilinear_biquad(th[:, 0], th[:, 1], dt)
        return biquad_columns(readonly(x.T), *coef).T

    def invert(self, theta, y, dt):
        t = np.ravel(theta)
        return invert_second_order(y, float(t[0]), float(t[1]), dt)

    def step_init(self, theta, x0, dt):
        return np.array([0.0, 0.0, 0.0, 0.0, float(x0)])  # d[k−1], d[k−2], e[k−1], e[k−2], x0

    def step(self, theta, state, x_new, dt):
        t = np.ravel(theta)
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        d1, d2, e1, e2, x0 = np.asarray(state, dtype=np.float64)
        b0, b1, b2, a1, a2 = _stage_coefficients(float(t[0]), float(t[1]), float(dt))  # cached: the same numbers
        d = x_new - x0
        e = b0 * d + b1 * d1 + b2 * d2 - a1 * e1 - a2 * e2
        C = x_new.size
        new = np.column_stack([d, np.full(C, d1), e, np.full(C, e1), np.full(C, x0)])
        return e + x0, new
