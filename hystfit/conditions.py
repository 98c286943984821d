"""Operating conditions of captures and the look-up table over them.

An operating condition is the pair ``(amplitude_V, frequency_Hz)``: the peak-to-peak input
voltage (V) and the fundamental frequency of the drive (Hz), both rounded to tidy values so
that captures of the same nominal test share one key. A hysteresis model is identified per
condition; :class:`LookupTable` then finds the cell (or the bilinear blend of cells) for a
new condition.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .capture import Capture
from .errors import ConfigError
from .minimize1d import minimize_bounded

ConditionKey = tuple[float, float]

#: The rule a given operating condition (``--condition``, a sidecar's ``condition``, the loader's
#: option) obeys, in the words of its error messages.
CONDITION_RULE = "amplitude (V) and frequency (Hz) must be finite numbers > 0"


def is_valid_condition(amplitude_V, frequency_Hz) -> bool:
    """Whether a given condition obeys :data:`CONDITION_RULE`.

    One test for every place a condition is given, so they refuse the same values: NaN fails
    ``> 0`` by itself, but inf would pass it and become a cell label (``60V_infHz``), an infinite
    table coordinate and ``inf`` in the reports; zero or a negative value has no meaning.
    """
    try:
        a, f = float(amplitude_V), float(frequency_Hz)
    except (TypeError, ValueError):
        return False
    return math.isfinite(a) and math.isfinite(f) and a > 0 and f > 0

#: Zero-padding factor of the FFT used to locate the input's fundamental.
_PAD = 4
#: Upper bound on the padded FFT length (samples); long captures are padded less.
_MAX_NFFT = 1 << 22
#: Relative tolerance under which a query coordinate counts as lying on a grid line.
_GRID_RTOL = 1e-9


def tidy(x: float, sig: int = 2) -> float:
    """Round ``x`` to ``sig`` significant digits (a "tidy" nominal value).

    Parameters
    ----------
    x : value to round (any unit; used for volts and hertz).
    sig : number of significant digits kept, >= 1.

    Returns
    -------
    float
        e.g. 297.8 → 300.0, 39.7 → 40.0, 10.04 → 10.0, 0.4987 → 0.5; 0 → 0; non-finite values
        are returned unchanged. Idempotent, and within 5 % of ``x`` for ``sig=2``.
    """
    x = float(x)
    if x == 0.0 or not math.isfinite(x):
        return x
    return float(f"{x:.{int(sig)}g}")


#: Third-order difference with unit gain for white noise: (−1, 3, −3, 1)/√20.
_D3 = np.array([-1.0, 3.0, -3.0, 1.0]) / math.sqrt(20.0)


def white_noise_sigma(x: np.ndarray) -> float:
    """The standard deviation of the white, sample-to-sample noise in ``x``: 1.4826·MAD of its
    third-order difference (−1, 3, −3, 1)/√20 (0.0 below 8 samples).

    The difference keeps white noise at unit gain and removes anything smooth (polynomials up to
    degree two vanish: a drive, a loop's error, creep or drift sampled finely); the median ignores
    the few samples where ``x`` has a kink or a step. The one home of this estimate: the input's
    noise (:func:`hystfit.io.idle_samples`, the crossing counts here) and the sensor's noise floor
    of ``diagnose`` (:func:`hystfit.diagnose.estimate_noise`).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.size < 8:
        return 0.0
    d = np.convolve(x, _D3, mode="valid")
    return 1.4826 * float(np.median(np.abs(d - np.median(d))))


def _fundamental_Hz(u: np.ndarray, dt: float) -> float:
    """Frequency (Hz) of the largest non-DC spectral peak of ``u`` sampled every ``dt`` s.

    Mean removed, Hann window, zero-padded FFT, then parabolic interpolation of the log
    magnitude around the peak bin. Bins below one unpadded bin (the DC lobe) are ignored.
    """
    x = np.asarray(u, dtype=np.float64)
    n = x.size
    x = (x - x.mean()) * np.hanning(n)
    nfft = 1 << max(int(math.ceil(math.log2(n * _PAD))), 1)
    nfft = max(min(nfft, _MAX_NFFT), n)
    mag = np.abs(np.fft.rfft(x, nfft))
    first = max(1, int(math.ceil(nfft / n)))
    if first >= mag.size - 1:
        return 1.0 / (n * dt)
    k = first + int(np.argmax(mag[first:]))
    delta = 0.0
    if first < k < mag.size - 1:
        a, b, c = np.log(np.maximum(mag[k - 1:k + 2], 1e-300))
        den = a - 2.0 * b + c
        if den < 0.0:
            delta = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    return (k + delta) / (nfft * dt)


def _sine_fit_residual(x: np.ndarray, tdt: np.ndarray, f: float) -> float:
    """Residual sum of squares of the least-squares fit ``c0 + c1 cos 2πft + c2 sin 2πft`` to ``x``."""
    w = 2.0 * np.pi * f * tdt
    basis = np.column_stack([np.ones_like(w), np.cos(w), np.sin(w)])
    coef = np.linalg.lstsq(basis, x, rcond=None)[0]
    return float(np.sum((x - basis @ coef) ** 2))


def _refine_Hz(u: np.ndarray, dt: float, f0: float) -> float:
    """Refine the FFT estimate ``f0`` (Hz) by the best single-sine least-squares fit within ±25 %.

    Exact for sines and raised cosines even over 1–2 cycles, where the windowed FFT is biased.
    Long inputs are decimated (stride) to at most ~50 000 samples when that keeps ≥ 8 samples
    per period of ``f0``.
    """
    stride = max(1, int(math.ceil(u.size / 50_000)))
    while stride > 1 and f0 * dt * stride > 1.0 / 8:
        stride //= 2
    x = np.asarray(u[::stride], dtype=np.float64)
    tdt = np.arange(x.size, dtype=np.float64) * (dt * stride)
    res = minimize_bounded(lambda f: _sine_fit_residual(x, tdt, f), 0.75 * f0, 1.25 * f0, xatol=1e-6 * f0)
    if res.success and res.fun <= _sine_fit_residual(x, tdt, f0):
        return float(res.x)
    return f0


def detect_condition(u: np.ndarray, dt: float) -> ConditionKey:
    """Detect the operating condition of an input signal.

    Parameters
    ----------
    u : (N,) input voltage (V), N >= 4, not constant.
    dt : sample period (s), > 0.

    Returns
    -------
    (amplitude_V, frequency_Hz)
        ``tidy(max(u) - min(u))`` (peak-to-peak, V) and ``tidy`` of the dominant frequency (Hz)
        of the mean-removed input. For sines, raised cosines 0 → A → 0 and triangles this is the
        drive frequency; for a broadband input it is just the highest spectral peak.
    """
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 1 or u.size < 4:
        raise ConfigError(f"detect_condition needs a 1-D input of at least 4 samples, got shape {u.shape}")
    if not (dt > 0 and math.isfinite(dt)):
        raise ConfigError(f"detect_condition: the sample period must be positive, got {dt!r} s")
    amplitude = tidy(float(u.max() - u.min()))
    f0 = _fundamental_Hz(u, dt)
    return amplitude, tidy(_refine_Hz(u, dt, f0))


#: Ratio between the input's peak-to-peak (or zero-crossing rate) in the first and the last third
#: of a capture above which its amplitude (or frequency) is called non-stationary.
STATIONARY_RATIO = 1.3


#: the samples of a third whose turns :func:`nonstationary_notes` counts (10 s at 10 kHz)
TURN_SAMPLES = 100_000


def _reversal_rate(x: np.ndarray, dt: float) -> tuple[int, float]:
    """(reversals, reversals per second) of ``x``: the turns of its direction by more than a band (a
    Schmitt trigger on the travel back from the last extreme) of eight times its sample noise — the
    robust spread of the third difference, which a finely sampled drive passes almost unchanged;
    the range of many noise samples reaches several of them — and at least 5 % of its range, the
    rate measured between the first and the last turn.

    Turns, not crossings of a level: a sine turns twice a period about any centre, so a rising
    sine about an offset it was ramped to counts its small first cycles as the later ones, and the
    ramp (or a hold) before the first turn does not dilute the rate. (Crossings of a straight-line
    trend counted 5.6 Hz in the first third of a blind test's constant 10 Hz rising sine after a
    0.2 s ramp to its 45 V offset, and warned that the frequency changed.)"""
    x = np.asarray(x, dtype=np.float64)
    if x.size < 3:
        return 0, 0.0
    band = max(8.0 * white_noise_sigma(x), 0.05 * float(np.ptp(x)))
    turns = []
    hi = lo = float(x[0])
    state = 0  # 1 rising, -1 falling, 0 not yet known
    for k, v in enumerate(x.tolist()):
        if state >= 0:
            hi = max(hi, v)
            if hi - v > band:
                if state == 1:
                    turns.append(k)
                state, lo = -1, v
        if state <= 0:
            lo = min(lo, v)
            if v - lo > band:
                if state == -1:
                    turns.append(k)
                state, hi = 1, v
    if len(turns) < 2 or turns[-1] == turns[0]:
        return len(turns), 0.0
    return len(turns), (len(turns) - 1) / ((turns[-1] - turns[0]) * dt)


def is_step_and_hold(u: np.ndarray) -> bool:
    """Whether ``u`` holds levels and jumps between them (a step test, a staircase): at most 1 % of
    its samples jump (a change above six times the noise, :func:`white_noise_sigma` ×√2 for a
    difference, and above 2 % of the input range), at least one does, and between the jumps it stays
    within 5 % of its range (plus ten noise σ). Such an input is not one operating condition by
    design and its levels differ between any two parts of it: it gets no non-stationarity warning.
    A PRBS jumps at a fraction of its clock's ticks (≈ 12 % of the samples at 2.5 kHz sampled at
    10 kHz), a slow sine does not jump: neither is one."""
    u = np.asarray(u, dtype=np.float64)
    if u.size < 30:
        return False
    rng = float(u.max() - u.min())
    if not rng > 0:
        return False
    sigma = white_noise_sigma(u)
    jumps = np.flatnonzero(np.abs(np.diff(u)) > max(6.0 * np.sqrt(2.0) * sigma, 0.02 * rng)) + 1
    if jumps.size == 0 or jumps.size > 0.01 * (u.size - 1):
        return False
    held = 0.05 * rng + 10.0 * sigma
    return all(float(np.ptp(seg)) <= held for seg in np.split(u, jumps) if seg.size)


def amplitude_thirds(u: np.ndarray) -> tuple[float, float] | None:
    """The input's peak-to-peak (V) in the first and in the last third of a capture, or None where
    that says nothing about its amplitude: fewer than 30 samples, or a step-and-hold input
    (:func:`is_step_and_hold`), whose levels differ between its thirds by design."""
    u = np.asarray(u, dtype=np.float64)
    n = u.size
    if n < 30 or is_step_and_hold(u):
        return None
    return float(np.ptp(u[: n // 3])), float(np.ptp(u[n - n // 3:]))


def amplitude_changes(u: np.ndarray) -> bool:
    """Whether the drive's amplitude changes along the capture (a rising-amplitude sine, a decaying
    one, a sweep whose amplitude follows its frequency): the peak-to-peak of its first and last
    third (:func:`amplitude_thirds`) differ by more than :data:`STATIONARY_RATIO`. The one test behind
    the loader's warning (:func:`nonstationary_notes`) and diagnose's split (a capture whose fitted
    part would not reach the amplitudes of its held-out part)."""
    return _thirds_differ(amplitude_thirds(u))


def _thirds_differ(pp: tuple[float, float] | None) -> bool:
    """Whether two peak-to-peaks (:func:`amplitude_thirds`) differ by more than :data:`STATIONARY_RATIO`."""
    if pp is None:
        return False
    lo, hi = min(pp), max(pp)
    return (lo > 0 and hi / lo > STATIONARY_RATIO) or lo == 0 < hi


def nonstationary_notes(u: np.ndarray, dt: float, key: ConditionKey) -> list[str]:
    """Warnings for a capture whose amplitude or frequency changes along it (rising sines, sweeps).

    One condition (a look-up-table cell) stands for one stationary drive. The input's
    peak-to-peak and its rate of turns (:func:`_reversal_rate`) are compared
    between the first and the last third of the capture; a ratio above :data:`STATIONARY_RATIO` means the capture mixes conditions.
    Stationary broadband inputs (PRBS) have the same range and crossing rate in every third and
    are not flagged, and neither is a step-and-hold input (:func:`is_step_and_hold`), whose levels
    differ between its thirds by design.

    Returns
    -------
    list of str
        Empty for a stationary capture; else one line per changing quantity, with the values.
    """
    u = np.asarray(u, dtype=np.float64)
    n = u.size
    pp = amplitude_thirds(u)
    if pp is None:
        return []
    thirds = (u[: n // 3], u[n - n // 3:])
    out = []
    label = condition_label(key)
    if _thirds_differ(pp):  # amplitude_changes(u), its thirds measured once
        out.append(f"the amplitude changes along the capture (peak-to-peak {pp[0]:.3g} V in the first third, "
                   f"{pp[1]:.3g} V in the last): it is not one operating condition, and its label {label} (the full "
                   "range) holds only where the drive is largest; cut a stationary part with --start/--stop or name "
                   "it with --condition")
    # the turns of each third's start and end (at most TURN_SAMPLES: the rate needs a few periods, and
    # a 10⁷-sample capture would cost seconds of this loop)
    turns, rates = zip(*(_reversal_rate(x, dt) for x in (thirds[0][:TURN_SAMPLES], thirds[1][-TURN_SAMPLES:])))
    if min(turns) >= 4 and max(rates) / max(min(rates), 1e-300) > STATIONARY_RATIO:
        out.append(f"the frequency changes along the capture (about {rates[0] / 2:.3g} Hz in the first third, "
                   f"{rates[1] / 2:.3g} Hz in the last, from its turns): it is not one operating condition, "
                   f"and its label {label} is only the strongest spectral line; cut a stationary part with "
                   "--start/--stop or name it with --condition")
    return out


#: a capture whose strongest spectral line carries less than this share of its input's power is
#: broadband: a PRBS 0.4 %, multisines of 40, 5 and 3 equal lines 8, 17 and 33 %; a sine and a
#: raised cosine carry 100 %, a triangle 99 %, a rising-amplitude sine 88 % (hystfit.synth's:
#: ``python benchmarks/blind_cases.py``, case 6)
TONAL_SHARE_MIN = 0.5


def tonal_share(u: np.ndarray) -> float:
    """The share of the (mean-removed, Hann-windowed) input's spectral power within ±2 bins (the
    window's main lobe) of its strongest line: ≈ 1 for one drive frequency, small for a broadband
    input."""
    x = np.asarray(u, dtype=np.float64)
    if x.size < 8:
        return 1.0
    p = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(x.size))) ** 2
    total = float(p[1:].sum())
    if not total > 0:
        return 1.0
    k = 1 + int(np.argmax(p[1:]))
    return float(p[max(k - 2, 1):k + 3].sum()) / total


def broadband_cell_warnings(captures: Sequence[Capture]) -> list[str]:
    """Warnings for broadband captures (:func:`tonal_share` below :data:`TONAL_SHARE_MIN`, a PRBS or a
    multisine, not a step-and-hold input) whose detected condition makes them a cell of a look-up
    table with other conditions: the cell's frequency is only their strongest line, and
    ``simulate``/``invert`` interpolate between cells by frequency as if it were a drive's. One
    line per capture, naming it; none for a table of one condition or a condition given by the
    user (``--condition``, columns)."""
    groups = group_by_condition(captures)
    if len(groups) < 2:
        return []
    return [f"{c.source}: the input is broadband (its strongest line, {c.frequency_Hz:g} Hz, carries "
            f"{100 * share:.2g} % of its power: a PRBS, a multisine, noise), so its look-up-table cell "
            f"{condition_label((c.amplitude_V, c.frequency_Hz))} stands for no drive frequency, and simulate and "
            "invert interpolate across it as if it did; fit it on its own, or name its condition with --condition"
            for c, share in _broadband(captures)]


def _broadband(captures: Sequence[Capture]) -> list[tuple[Capture, float]]:
    """(capture, tonal share) of the captures whose detected condition is a broadband input's
    (:func:`tonal_share` below :data:`TONAL_SHARE_MIN`; not a step-and-hold input, not a condition the
    user gave)."""
    out = []
    for c in captures:
        if c.condition_source != "detected" or is_step_and_hold(c.u):
            continue
        share = tonal_share(c.u)
        if share < TONAL_SHARE_MIN:
            out.append((c, share))
    return out


def broadband_label_notes(captures: Sequence[Capture]) -> list[str]:
    """For a table of one condition (where :func:`broadband_cell_warnings` has nothing to warn of): a
    note per broadband capture that its condition label names its strongest spectral line, not a
    drive frequency (a blind test's lone PRBS was labelled ``60V_210Hz`` without a word)."""
    if len(group_by_condition(captures)) != 1:
        return []
    return [f"{c.source}: the input is broadband (its strongest line, {c.frequency_Hz:g} Hz, carries "
            f"{100 * share:.2g} % of its power), so its label {condition_label((c.amplitude_V, c.frequency_Hz))} "
            "names that line, not a drive frequency; name the condition with --condition if it has one"
            for c, share in _broadband(captures)]


def count_cycles(u: np.ndarray, dt: float, frequency_Hz: float) -> float:
    """Number of input cycles in a capture: duration ``len(u)·dt`` (s) times ``frequency_Hz`` (Hz)."""
    return float(np.asarray(u).shape[0] * dt * frequency_Hz)


def group_by_condition(captures: Sequence[Capture]) -> dict[ConditionKey, list[Capture]]:
    """Pool captures per condition key ``(amplitude_V, frequency_Hz)``.

    Returns a dict ordered by amplitude then frequency; within a key the captures keep their
    input order.
    """
    groups: dict[ConditionKey, list[Capture]] = {}
    for c in captures:
        groups.setdefault((float(c.amplitude_V), float(c.frequency_Hz)), []).append(c)
    return {k: groups[k] for k in sorted(groups)}


def _fmt(x: float) -> str:
    """Shortest plain decimal text of ``x``: 300.0 → "300", 1.5 → "1.5", 0.25 → "0.25"."""
    x = float(x)
    if not math.isfinite(x):
        return str(x)
    return np.format_float_positional(float(f"{x:.12g}"), trim="-")


def condition_label(key: ConditionKey) -> str:
    """Label of a condition key, e.g. ``(40, 10)`` → ``"40V_10Hz"``, ``(300, 1.5)`` → ``"300V_1.5Hz"``."""
    a, f = key
    return f"{_fmt(a)}V_{_fmt(f)}Hz"


class LookupTable:
    """Per-condition items (e.g. fitted parameter vectors) keyed by ``(amplitude_V, frequency_Hz)``.

    Distances and interpolation use the normalized coordinates ``(log10(frequency_Hz),
    amplitude_V / Amax)``, where ``Amax`` is the largest amplitude in the table: one decade of
    frequency weighs as much as the full amplitude range.

    Parameters
    ----------
    keys : condition keys (V, Hz); frequencies must be positive, keys unique.
    values : one array per key.
    """

    def __init__(self, keys: Sequence[ConditionKey], values: Sequence[np.ndarray]):
        if len(keys) != len(values):
            raise ConfigError(f"LookupTable: {len(keys)} keys but {len(values)} values")
        if not keys:
            raise ConfigError("LookupTable: the table is empty; identify at least one condition")
        self.keys: list[ConditionKey] = [(float(a), float(f)) for a, f in keys]
        self.values: list[np.ndarray] = [np.asarray(v) for v in values]
        for a, f in self.keys:
            if not (math.isfinite(a) and math.isfinite(f) and f > 0):
                raise ConfigError(f"LookupTable: key ({a:g} V, {f:g} Hz) needs a finite amplitude "
                                  "and a positive frequency")
        if len(set(self.keys)) != len(self.keys):
            raise ConfigError("LookupTable: duplicate condition keys")
        amax = max(abs(a) for a, _ in self.keys)
        self._amax = amax if amax > 0 else 1.0
        self._index = {k: i for i, k in enumerate(self.keys)}
        self._amps = sorted({a for a, _ in self.keys})
        self._freqs = sorted({f for _, f in self.keys})

    def __len__(self) -> int:
        return len(self.keys)

    def _coords(self, key: ConditionKey) -> tuple[float, float]:
        a, f = float(key[0]), float(key[1])
        if not (math.isfinite(a) and math.isfinite(f) and f > 0):
            raise ConfigError(f"condition ({a:g} V, {f:g} Hz): needs a finite amplitude and a positive frequency")
        return math.log10(f), a / self._amax

    def select(self, key: ConditionKey, method: str = "interpolate"
               ) -> tuple[list[tuple[ConditionKey, float]], ConditionKey, bool]:
        """The one rule that chooses table cells for an operating condition (simulate, invert, track).

        ``interpolate``: the condition is first clamped onto the grid (amplitude and frequency
        separately, so the weights are continuous in the condition), then bilinear in
        (amplitude, log10 frequency) between the surrounding cells; where a needed corner is
        missing the nearest cell is used. ``nearest``: the closest cell in (log10 f, A/A_max).
        Any other method is a :class:`ConfigError` (never a silent fallback).

        Returns
        -------
        (used, query, clamped)
            ``used``: (key, weight) pairs, weights > 0 summing to 1; ``query``: the point looked
            up; ``clamped``: whether the condition lay outside the grid.
        """
        if method not in ("interpolate", "nearest"):
            raise ConfigError(f"method {method!r}: choose interpolate or nearest")
        a, f = float(key[0]), float(key[1])
        self._coords((a, f))  # validates the condition
        qa = min(max(a, self._amps[0]), self._amps[-1])
        qf = min(max(f, self._freqs[0]), self._freqs[-1])
        clamped = (qa != a) or (qf != f)
        if method == "interpolate":
            _, used = self.interpolate((qa, qf))
        else:
            k, _ = self.nearest((a, f))
            used = [(k, 1.0)]
        return [(k, float(w)) for k, w in used], (qa, qf), clamped

    def nearest(self, key: ConditionKey) -> tuple[ConditionKey, np.ndarray]:
        """The table's closest key to ``key`` (V, Hz) and its value; ties go to the first key."""
        x, y = self._coords(key)
        d = [math.hypot(x - math.log10(f), y - a / self._amax) for a, f in self.keys]
        i = int(np.argmin(d))
        return self.keys[i], self.values[i]

    def interpolate(self, key: ConditionKey) -> tuple[np.ndarray, list[tuple[ConditionKey, float]]]:
        """Bilinear blend of the grid cell around ``key`` (V, Hz).

        Linear in amplitude and in log10(frequency). A key on a grid line blends the two cells
        of that edge; an exact hit returns that cell with weight 1. When the key lies outside
        the grid or a needed corner is missing, falls back to :meth:`nearest` (weight 1).

        Returns
        -------
        (value, used)
            The weighted sum of the used cells' values and the list of ``(cell key, weight)``
            with weights > 0 summing to 1.
        """
        self._coords(key)
        a_br = _bracket(self._amps, float(key[0]), lambda v: v)
        f_br = _bracket(self._freqs, float(key[1]), math.log10)
        if a_br is None or f_br is None:
            return self._fallback(key)
        used = [((a, f), wa * wf) for a, wa in a_br for f, wf in f_br if wa * wf > 0]
        if any(k not in self._index for k, _ in used):
            return self._fallback(key)
        vals = [self.values[self._index[k]] for k, _ in used]
        if len({v.shape for v in vals}) > 1:
            raise ConfigError("LookupTable.interpolate: the surrounding cells have values of different shapes; "
                              "use nearest")
        total = sum(w * np.asarray(v, dtype=np.float64) for (_, w), v in zip(used, vals))
        return np.asarray(total), used

    def _fallback(self, key: ConditionKey) -> tuple[np.ndarray, list[tuple[ConditionKey, float]]]:
        k, v = self.nearest(key)
        return v, [(k, 1.0)]


def _bracket(grid: list[float], x: float, transform) -> list[tuple[float, float]] | None:
    """Grid values around ``x`` with linear weights in ``transform`` space, or None if outside.

    A value equal to a grid value (relative tolerance 1e-9) gives ``[(value, 1.0)]``.
    """
    for g in grid:
        if abs(g - x) <= _GRID_RTOL * max(abs(g), abs(x), 1e-300):
            return [(g, 1.0)]
    for lo, hi in zip(grid, grid[1:]):
        if lo < x < hi:
            w = (transform(x) - transform(lo)) / (transform(hi) - transform(lo))
            return [(lo, 1.0 - w), (hi, w)]
    return None
