"""Feedforward voltages from an identified look-up table: the inverse of the hysteresis model.

Given a desired displacement y_d(t) (a :class:`Target`), :func:`invert_target` returns the
voltage u(t) to send to the amplifier and a preview of the tracking error it gives, computed by
simulating the identified forward model on that voltage (paper 002 Table 4 figures: maximum
error, RMSE, both also in % of the stroke).

Pipeline (every step is reported in :class:`InversionResult`, nothing is silent):

1. **Target.** A file (:func:`load_target`) or a built-in trajectory: :func:`sine_target`
   (paper 002 eq. 16, y = A/2·sin(2πft − π/2) + A/2, i.e. 0 → A → 0, plus an offset),
   :func:`triangle_target`, :func:`steps_target` and :func:`multi_target` (002's
   10/8/6/4/2 µm at 0.5/1/2/5/10 Hz sequence). A target is split into *segments* of one
   nominal frequency each (one segment for a file).
2. **Table cell per segment.** The look-up table (002 §3.1) is keyed by the drive's
   peak-to-peak voltage and frequency, but the voltage is what we are solving for. We iterate
   (:func:`choose_condition`): guess A₀ = target stroke / table gain, pick the cell(s) for
   (A₀, f), invert, measure the peak-to-peak of the resulting voltage A₁, re-pick, … until the
   amplitude is self-consistent (|A_{i+1} − A_i| ≤ 0.1 % of A) and the cells no longer change.
   A voltage that leaves the identification range of the cells its peak-to-peak picks (a target
   up the stroke: 10…40 V is 30 V peak-to-peak, but the 20 V and 40 V cells of a campaign that
   starts every capture at 0 V saw 0…20 and 0…40 V) asks for the smallest amplitude of a cell
   whose range covers it instead (:func:`_covering_amplitude`): a 5 → 13 µm sine through a creep
   plant's ``pi+creep`` table blended the 20 V and 40 V cells and missed the plant by 0.42 µm; the
   40 V cell alone, 0.043 µm (``python benchmarks/feedforward_plant.py``).
   ``condition=`` forces the condition instead. Segments are settled in time order: a later
   segment's cells continue from the voltage already chosen for the earlier ones (step 4).
3. **Bilinear interpolation** between the (up to four) surrounding cells, linear in amplitude
   and log-frequency (:class:`hystfit.conditions.LookupTable`; a query outside the grid is
   clamped onto its edge, so weights stay continuous and the iteration converges). We blend
   the **inverted voltages** of the cells, u = Σ_c w_c·H_c⁻¹[y_d], rather than numerically
   inverting the blended forward model Σ_c w_c·H_c[u] = y_d. Reasons: (a) every model's own
   inverse is used, exact where it is analytic (PI: paper 003 eq. 17–20; models whose output
   lags the input by a sample, such as ``hammerstein``, have no per-sample numerical inverse at
   all); (b) each cell is inverted once and the result reused across iterations and across
   segments with different weights; (c) the two differ only to second order in the difference
   between neighbouring cells, Σw_cH_c[Σw_dH_d⁻¹y] − y = O(w(1−w)·ΔH²), below the first-order
   error of interpolating the table at all; (d) no root search on a blended map, which need
   not be monotone if one cell is poorly identified. The consequence is measured, not hidden:
   the predicted error is computed with the *blended forward* model (as ``hystfit simulate
   --method interpolate`` predicts), so it includes this blending residual.
4. **Model memory.** Every model's forward simulation starts from its reset state; the
   stage's history before the target is taken to be: at rest at 0 V in that state, then brought
   monotonically to the initial voltage v0 and held (:func:`preroll_voltage`; for PI this is
   exactly its virgin initial state, paper 003 eq. 1–3; a PI or GPI base with blocks rests at v0,
   settled, from the first sample on). Each cell is inverted with that
   pre-roll prepended to the target (the model's output for it) and the pre-roll dropped, and
   the forward preview is simulated with the same pre-roll, so inverse and preview share one
   memory whatever a model's reset convention. Default v0: the voltage at which the model
   rests at the target's first sample (:func:`rest_voltage`), so the target starts smoothly;
   ``initial_voltage=V`` sets it, and a jump from the rest output to y_d[0] is reported.
   At a segment join (``multi`` targets) the new segment's cells are inverted with the voltage
   history of all earlier segments prepended (the cell's own output for it, then the target;
   :func:`invert_cell` with ``history``), so each cell enters the segment with the memory the
   applied voltage gives it, not the memory its own inverse would have built (which differs
   wherever another cell drove the stage before); after the cross-fade at the join (below) they are
   inverted once more from the faded voltage. This costs re-inversions of the history per
   segment and cell (``Model.invert`` cannot resume from a saved state): O(N·S) for S
   segments, nothing for single-segment targets.
5. **Limits.** Voltages outside [vmin, vmax] are clipped (default: the table's identification
   voltage range ± 10 %), then a slew-rate limit |Δu| ≤ S·dt is applied causally, starting
   from the initial voltage. Every clipped or slew-limited span is reported with its time span
   and worst excess.
6. **Preview.** The blended forward model is simulated on the final voltages; the error
   e = y_pred − y_d gives max|e|, RMSE and both in % of the stroke (max y_d − min y_d),
   overall and per segment.

Memory. Every step works on whole arrays with O(N·n) memory (n = a model's state size, ≈ 10
play operators for PI), never on (P, N) populations; each used cell's inverse is kept once and
released before the forward preview. The whole ``hystfit invert`` command (load, inversion of
two PI cells, preview, CSV, report, figures) peaks at ≈ 0.52 GB resident for a 10⁶-sample
target, of which ≈ 0.3 GB is the imported libraries (``/usr/bin/time -v``; checked in
``tests/integration/test_invert_cli.py``); the dynamic models ``pi2``/``hammerstein`` and
Bouc–Wen stay under 0.55 GB too. We do not cut the target into chunks: ``Model.invert`` starts
from the model's reset state and cannot resume another chunk's memory, and the linear memory
already meets the 1 GB budget. The generic numerical inverse (:mod:`hystfit.models.inverse`,
e.g. Bouc–Wen) is a per-sample Python loop: small memory, but ≈ 100–300 µs per sample and
cell (10⁶ samples with Bouc–Wen: ≈ 10 min).
Segment joins: cell weights change linearly over 2 % of the shorter segment after a join, so
the voltage has no jump where neighbouring segments use different cells.

Units: time s, voltage V, displacement in the parameter file's output unit (``um`` below).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from typing import Callable, ClassVar, Sequence

import numpy as np
from ._jit import njit

from .capture import UniformSamples, display_unit
from .conditions import LookupTable, detect_condition
from .errors import ConfigError, InputError
from .io import TARGET_NAMES, Columns, load_table
from .parallel import one_blas_thread
from .results import Cell, ParamsFile

__all__ = [
    "Segment",
    "Target",
    "Span",
    "CellUse",
    "SegmentChoice",
    "IterationStep",
    "Step",
    "InversionResult",
    "sine_target",
    "triangle_target",
    "steps_target",
    "multi_target",
    "target_from_array",
    "check_target_samples",
    "MAX_TARGET_SAMPLES",
    "load_target",
    "default_voltage_limits",
    "select_cells",
    "choose_condition",
    "apply_limits",
    "find_spans",
    "invert_target",
    "InvertLimits",
    "check_invert_options",
    "invert_cell",
    "simulate_cell",
    "preroll_voltage",
    "rest_output",
    "rest_voltage",
    "search_range",
    "blend_segments",
    "tracking_metrics",
    "table_gain",
    "condition_text",
    "MULTI_AMPLITUDES_UM",
    "MULTI_FREQUENCIES_HZ",
]

#: Paper 002's variable-amplitude, variable-frequency sequence (§5, Table 5 "0.5 to 10 Hz").
MULTI_AMPLITUDES_UM: tuple[float, ...] = (10.0, 8.0, 6.0, 4.0, 2.0)
MULTI_FREQUENCIES_HZ: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0)
#: Margin added on both sides of the identification voltage range for the default limits.
LIMIT_MARGIN = 0.10
#: Relative amplitude change under which the condition iteration has converged.
AMPLITUDE_RTOL = 1e-3
#: Progress callback: ``progress(event, info)`` with events "start", "advance", "note".
Progress = Callable[[str, dict], None] | None


# ----------------------------------------------------------------------------------------------
# Targets
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Segment:
    """A part of a target with one nominal frequency (samples ``start`` … ``stop − 1``).

    frequency_Hz : nominal frequency of the segment (Hz); NaN means "detect from the target".
    label : short description, e.g. ``"10 um, 0.5 Hz"``.
    """

    start: int
    stop: int
    frequency_Hz: float
    label: str


@dataclass(frozen=True)
class Step:
    """One step of a step target: at sample ``index`` the target jumps ``from_level`` → ``to_level``.

    ``stop`` is the end (exclusive) of the hold that follows. Levels in the target's unit.
    """

    index: int
    stop: int
    from_level: float
    to_level: float


@dataclass(frozen=True, eq=False)
class Target(UniformSamples):
    """A desired displacement trajectory.

    Attributes
    ----------
    t_s : (N,) time in s from 0, uniform.
    y : (N,) desired displacement in ``unit``.
    dt : sample period (s).
    unit : displacement unit (``um``, ``nm``, ``mm``, ``m``).
    description : human-readable origin, e.g. ``"sine 10 um p-p, 1 Hz, 5 cycles, offset 2 um"``.
    kind : ``"sine"``, ``"triangle"``, ``"steps"``, ``"multi"``, ``"file"`` or ``"array"``.
    segments : parts of one nominal frequency each, covering 0 … N in order.
    steps : for step targets, the steps (for rise/settling metrics); empty otherwise.
    """

    t_s: np.ndarray
    y: np.ndarray
    dt: float
    unit: str
    description: str
    kind: str
    segments: tuple[Segment, ...]
    steps: tuple[Step, ...] = ()
    samples_field: ClassVar[str] = "y"

    @property
    def stroke(self) -> float:
        """max y − min y (``unit``): the denominator of "% of stroke"."""
        return float(self.y.max() - self.y.min())


def _positive(name: str, value: float, source: str = "") -> float:
    """``value`` when finite and > 0; else a one-line error naming it (``source``: the option as the
    user gave it, e.g. ``--sine 5,inf``, said first)."""
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{source + ': ' if source else ''}{name} must be a finite number > 0. Got {value!r} instead.")
    return value


def _finite(name: str, value: float, source: str = "") -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{source + ': ' if source else ''}{name} must be a finite number. Got {value!r} instead.")
    return value


#: Fewest samples per cycle of a built-in periodic trajectory (below it the samples are not the shape).
MIN_SAMPLES_PER_CYCLE = 4
#: Most samples of a built-in trajectory (10⁷: 1000 s at 10 kHz). A typo in the cycles, the hold or
#: ``--fs`` (``--sine 10,20,1e7``) would otherwise ask for billions of samples, and the arrays of
#: the inversion and its preview would exhaust the memory before any output (an OOM kill, not an
#: error). The limit is checked on the sample count before anything is allocated.
MAX_TARGET_SAMPLES = 10_000_000
#: Peak memory of ``hystfit invert`` per target sample (bytes), beyond the ≈ 0.3 GB of imported
#: libraries: a PI table's 10⁷-sample sine (``--sine 10,10,10000 --no-plots``) peaks at 2.31 GB
#: resident (``/usr/bin/time -v``, 2026-11-28; a 2·10⁶-sample one at 0.63 GB, 165 B per sample),
#: ≈ 200 B per sample. Used to say in the error what a limit-sized target costs.
TARGET_BYTES_PER_SAMPLE = 200


def check_target_samples(n: float, fs: float, source: str, fix: str) -> int:
    """``n`` (the sample count of a built-in trajectory, computed in floating point so a huge one
    cannot overflow) as an int, or a one-line ConfigError naming ``source`` (what the user asked
    for, e.g. ``--sine 10,20,1e7``) and ``fix`` when it exceeds :data:`MAX_TARGET_SAMPLES`."""
    # the closing sample of a whole number of cycles (t = duration) rides on top: 1000 s at 10 kHz is
    # 10⁷ + 1 samples, and the limit says 10⁷ samples = 1000 s (a blind test's exactly-1000-s sine was
    # refused as "1e+07 samples … exceed the limit of 1e+07")
    if not (math.isfinite(n) and n <= MAX_TARGET_SAMPLES + 1):
        gb = MAX_TARGET_SAMPLES * TARGET_BYTES_PER_SAMPLE / 1e9
        count = f"{n:.0f}" if math.isfinite(n) and n < 1e15 else f"{n:.3g}"
        raise ConfigError(f"{source}: {count} samples at {fs:g} Hz exceed the limit of {MAX_TARGET_SAMPLES:.0e} "
                          f"samples (≈ {gb:.1f} GB of memory for invert); {fix}")
    return int(n)


def _periodic_n(freq_Hz: float, cycles: float, fs: float, source: str = "") -> int:
    if freq_Hz * MIN_SAMPLES_PER_CYCLE > fs:
        raise ConfigError(f"{freq_Hz:g} Hz sampled at {fs:g} Hz gives fewer than {MIN_SAMPLES_PER_CYCLE} samples per "
                          f"cycle; raise the sample rate (--fs) to at least {MIN_SAMPLES_PER_CYCLE * freq_Hz:g} Hz or "
                          "lower the frequency")
    x = cycles * fs / freq_Hz + 1e-9
    n = check_target_samples(math.floor(x) + 1.0 if math.isfinite(x) else x, fs,
                             source or f"{_fmt(cycles)} cycles at {_fmt(freq_Hz)} Hz",
                             "use fewer cycles or a lower sample rate (--fs)")
    if n < 3:
        raise ConfigError(f"{cycles:g} cycles at {freq_Hz:g} Hz give fewer than 3 samples at {fs:g} Hz; "
                          "raise the sample rate (--fs) or the number of cycles")
    return n


def _fmt(x: float) -> str:
    return f"{x:g}"


def sine_target(amp: float, freq_Hz: float, cycles: float = 5, fs: float = 10_000.0, *, offset: float = 0.0,
                unit: str = "um", source: str = "") -> Target:
    """Sine trajectory of paper 002 eq. 16: y = A/2·sin(2πft − π/2) + A/2 + offset.

    It starts at ``offset`` at rest (zero slope), peaks at ``offset + A`` and returns to
    ``offset`` after every cycle; ``amp`` is the peak-to-peak amplitude A (002's "10 µm").

    Parameters
    ----------
    amp : peak-to-peak amplitude A in ``unit`` (> 0).
    freq_Hz : frequency f (Hz, > 0).
    cycles : number of cycles (> 0); samples 0 … cycles/f inclusive.
    fs : sample rate (Hz).
    offset : displacement at the start and at every minimum (``unit``).
    unit : displacement unit.
    source : what the user asked for (e.g. ``--sine 10,20,5``), named when the trajectory would
        exceed :data:`MAX_TARGET_SAMPLES`.
    """
    amp, freq_Hz, cycles, fs = (_positive(n, v, source) for n, v in
                                (("amplitude", amp), ("frequency (Hz)", freq_Hz), ("cycles", cycles),
                                 ("the sample rate (--fs, Hz)", fs)))
    offset = _finite("--offset", offset, source)
    n = _periodic_n(freq_Hz, cycles, fs, source)
    t = np.arange(n, dtype=np.float64) / fs
    y = offset + 0.5 * amp * np.sin(2.0 * np.pi * freq_Hz * t - 0.5 * np.pi) + 0.5 * amp
    u = display_unit(unit)
    desc = f"sine {_fmt(amp)} {u} p-p, {_fmt(freq_Hz)} Hz, {_fmt(cycles)} cycles, offset {_fmt(offset)} {u}"
    return Target(t, y, 1.0 / fs, unit, desc, "sine", (Segment(0, n, freq_Hz, f"{_fmt(amp)} {unit}, {_fmt(freq_Hz)} Hz"),))


def triangle_target(amp: float, freq_Hz: float, cycles: float = 5, fs: float = 10_000.0, *, offset: float = 0.0,
                    unit: str = "um", source: str = "") -> Target:
    """Triangle trajectory offset → offset + A → offset per cycle (constant speed 2·A·f).

    Parameters as :func:`sine_target`.
    """
    amp, freq_Hz, cycles, fs = (_positive(n, v, source) for n, v in
                                (("amplitude", amp), ("frequency (Hz)", freq_Hz), ("cycles", cycles),
                                 ("the sample rate (--fs, Hz)", fs)))
    offset = _finite("--offset", offset, source)
    n = _periodic_n(freq_Hz, cycles, fs, source)
    t = np.arange(n, dtype=np.float64) / fs
    phase = np.mod(freq_Hz * t, 1.0)
    y = offset + amp * (1.0 - np.abs(2.0 * phase - 1.0))
    u = display_unit(unit)
    desc = f"triangle {_fmt(amp)} {u} p-p, {_fmt(freq_Hz)} Hz, {_fmt(cycles)} cycles, offset {_fmt(offset)} {u}"
    return Target(t, y, 1.0 / fs, unit, desc, "triangle",
                  (Segment(0, n, freq_Hz, f"{_fmt(amp)} {unit}, {_fmt(freq_Hz)} Hz"),))


def steps_target(levels: Sequence[float] = (10.0,), hold_s: float = 0.2, fs: float = 10_000.0, *,
                 offset: float = 0.0, lead_s: float | None = None, unit: str = "um", source: str = "") -> Target:
    """Step-and-hold trajectory (paper 002 Table 6 uses one 10 µm step).

    The target rests at ``offset`` for ``lead_s`` (default ``hold_s / 4``), then jumps to
    ``offset + levels[0]`` and holds it ``hold_s``, then ``offset + levels[1]``, …

    Parameters
    ----------
    levels : step levels relative to ``offset`` (``unit``), at least one; consecutive levels
        must differ.
    hold_s : hold time of every level (s).
    fs : sample rate (Hz).
    offset : rest level before the first step (``unit``).
    lead_s : rest time before the first step (s).
    unit : displacement unit.
    source : what the user asked for (e.g. ``--steps 10@0.2``), named when the trajectory would
        exceed :data:`MAX_TARGET_SAMPLES`.

    Notes
    -----
    The table lookup needs a frequency: a step sequence is treated as the square wave of
    period 2·hold_s, i.e. f = 1/(2·hold_s).
    """
    levels = [_finite("step level", v) for v in levels]
    if not levels:
        raise ConfigError("steps: give at least one level")
    hold_s, fs = _positive("hold_s", hold_s), _positive("fs", fs)
    offset = _finite("offset", offset)
    lead_s = hold_s / 4.0 if lead_s is None else float(lead_s)
    if not (math.isfinite(lead_s) and lead_s >= 0):
        raise ConfigError(f"lead_s must be a finite number >= 0. Got {lead_s!r} instead.")
    # counted in floating point and checked before rounding: a huge hold cannot overflow or allocate
    check_target_samples(round(lead_s * fs) + round(hold_s * fs) * float(len(levels))
                         if math.isfinite(hold_s * fs) and math.isfinite(lead_s * fs) else math.inf, fs,
                         source or f"steps: {len(levels)} level(s), hold {_fmt(hold_s)} s",
                         "use a shorter hold, fewer levels or a lower sample rate (--fs)")
    n_hold = int(round(hold_s * fs))
    n_lead = int(round(lead_s * fs))
    if n_hold < 3:
        raise ConfigError(f"hold_s {hold_s:g} s gives fewer than 3 samples at {fs:g} Hz; raise the hold time or --fs")
    seq = [0.0] + levels
    for i, (a, b) in enumerate(zip(seq, seq[1:])):
        if a == b:
            where = (f"the first level, {b:g}, is the rest level the target starts at (0 above the offset)" if i == 0
                     else f"two consecutive levels are {a:g}")
            raise ConfigError(f"steps: each level must differ from the one before; {where}: drop it")
    n = n_lead + n_hold * len(levels)
    y = np.full(n, offset, dtype=np.float64)
    steps = []
    for i, lev in enumerate(levels):
        k = n_lead + i * n_hold
        y[k:k + n_hold] = offset + lev
        steps.append(Step(k, k + n_hold, offset + seq[i], offset + lev))
    t = np.arange(n, dtype=np.float64) / fs
    f = 1.0 / (2.0 * hold_s)
    desc = (f"steps {', '.join(_fmt(v) for v in levels)} {display_unit(unit)} (relative to {_fmt(offset)} {display_unit(unit)}), "
            f"hold {_fmt(hold_s)} s")
    return Target(t, y, 1.0 / fs, unit, desc, "steps", (Segment(0, n, f, f"steps, hold {_fmt(hold_s)} s"),),
                  tuple(steps))


def multi_target(amps: Sequence[float] = MULTI_AMPLITUDES_UM, freqs_Hz: Sequence[float] = MULTI_FREQUENCIES_HZ,
                 cycles: float = 1, fs: float = 10_000.0, *, offset: float = 0.0, unit: str = "um",
                 source: str = "") -> Target:
    """Variable-amplitude, variable-frequency sequence of eq. 16 sines (paper 002 §5, Table 5).

    Default: 10, 8, 6, 4, 2 µm at 0.5, 1, 2, 5, 10 Hz, ``cycles`` whole cycles each (every
    segment starts and ends at ``offset`` at rest, so the joins are smooth). One segment per
    (amplitude, frequency), so each gets its own table cell. ``source``: what the user asked for
    (e.g. ``--multi``), named when the whole sequence would exceed :data:`MAX_TARGET_SAMPLES`.
    """
    amps, freqs_Hz = list(amps), list(freqs_Hz)
    if not amps or len(amps) != len(freqs_Hz):
        raise ConfigError(f"multi: give as many amplitudes as frequencies (got {len(amps)} and {len(freqs_Hz)})")
    cycles, fs = _positive("cycles", cycles), _positive("fs", fs)
    # the whole sequence checked before any segment is made (the segments share their join samples)
    xs = [cycles * fs / _positive("frequency_Hz", f) + 1e-9 for f in freqs_Hz]
    check_target_samples(sum(math.floor(x) for x in xs) + 1.0 if all(map(math.isfinite, xs)) else math.inf, fs,
                         source or f"multi: {len(xs)} segment(s) of {_fmt(cycles)} cycle(s)",
                         "use a lower sample rate (--fs)" if source else "use fewer cycles or a lower sample rate")
    parts, segs, start = [], [], 0
    for a, f in zip(amps, freqs_Hz):
        s = sine_target(a, f, cycles, fs, offset=offset, unit=unit)
        y = s.y if not parts else s.y[1:]  # the joins coincide (offset at rest): keep one sample
        parts.append(y)
        segs.append(Segment(start, start + y.size, float(f), s.segments[0].label))
        start += y.size
    y = np.concatenate(parts)
    t = np.arange(y.size, dtype=np.float64) / fs
    desc = (f"multi: {', '.join(f'{_fmt(a)} {display_unit(unit)} at {_fmt(f)} Hz' for a, f in zip(amps, freqs_Hz))}; "
            f"{_fmt(cycles)} cycle(s) each, offset {_fmt(offset)} {display_unit(unit)}")
    return Target(t, y, 1.0 / fs, unit, desc, "multi", tuple(segs))


def target_from_array(y: np.ndarray, dt: float, *, unit: str = "um", description: str = "array",
                      frequency_Hz: float | None = None) -> Target:
    """Wrap an array (N,) sampled every ``dt`` s as a one-segment target.

    ``frequency_Hz`` is the nominal frequency for the table lookup (default: the dominant
    frequency of ``y``, :func:`hystfit.conditions.detect_condition`).
    """
    y = np.ascontiguousarray(y, dtype=np.float64).ravel()
    dt = _positive("dt", dt)
    if y.size < 4:
        raise ConfigError(f"a target needs at least 4 samples, got {y.size}")
    if not np.all(np.isfinite(y)):
        raise ConfigError("the target contains NaN or inf")
    f = _target_frequency(y, dt) if frequency_Hz is None else _positive("frequency_Hz", frequency_Hz)
    t = np.arange(y.size, dtype=np.float64) * dt
    return Target(t, y, dt, unit, description, "array", (Segment(0, y.size, f, f"{_fmt(f)} Hz"),))


def _target_frequency(y: np.ndarray, dt: float) -> float:
    """Dominant frequency (Hz) of a target; 1/duration for a constant one."""
    if float(y.max() - y.min()) <= 1e-12 * max(1.0, float(np.abs(y).max())):
        return 1.0 / (y.size * dt)
    return float(detect_condition(y, dt)[1])


#: Column names read as the desired displacement, before the generic output names of captures.
#: names that read as a desired trajectory (the loader's ``target`` role), before the output names
TARGET_ALIASES = TARGET_NAMES


def load_target(path: str | os.PathLike, *, fs: float | None = None, time_col: str | int | None = None,
                target_col: str | int | None = None, unit: str | None = None) -> Target:
    """Read a desired trajectory from a CSV/TXT/TSV/DAT or Parquet file.

    Columns are found by name like captures (case-insensitive, unit suffix allowed): the time
    (``t``, ``time``, ``time_s``, ``time_ms`` …; or ``fs``) and the desired displacement: first
    the names :data:`TARGET_ALIASES` (``target``, ``reference``, ``setpoint``, ``y_d`` …), then the
    output names of captures (``displacement_um``, ``y``, ``position`` …). A voltage column, if
    any, is ignored. ``time_col``/``target_col`` take a name or a 0-based index.

    Parameters
    ----------
    path : the file.
    fs : sample rate (Hz) when the file has no time column.
    time_col, target_col : explicit columns.
    unit : displacement unit when the column name has none (default ``um``).

    Returns
    -------
    Target
        One segment whose frequency is the dominant frequency of the trajectory.

    Raises
    ------
    InputError
        Unreadable file, missing/ambiguous column, non-numeric or non-finite cell, non-uniform time.
    """
    tc = load_table(path, ("time", "target"), columns={"time": time_col, "target": target_col},
                    optional=("time",) if fs is not None else (), fallback={"target": "output"})
    label = tc.label
    y = tc.values("target")
    y_unit = tc.unit("target") or unit or "um"
    if tc.index["time"] is not None:
        t = tc.values("time")
        if t.size < 4:
            raise InputError(f"{label}: only {t.size} data rows; a target needs at least 4 samples")
        dt = tc.sample_period(t)
        if fs is not None and abs(1.0 / dt - fs) > 0.01 * fs:
            raise InputError(f"{label}: the time column gives {1 / dt:.6g} Hz but --fs is {fs:g} Hz; drop --fs")
    else:
        dt = 1.0 / _positive("--fs", fs)
        if y.size < 4:
            raise InputError(f"{label}: only {y.size} data rows; a target needs at least 4 samples")
    tgt = target_from_array(y, dt, unit=y_unit, description=f"file {label} ({tc.describe('target')})")
    return Target(tgt.t_s, tgt.y, tgt.dt, tgt.unit, tgt.description, "file", tgt.segments)


# ----------------------------------------------------------------------------------------------
# Look-up table cells
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CellUse:
    """A table cell used for a segment, with its bilinear weight."""

    index: int
    label: str
    amplitude_V: float
    frequency_Hz: float
    weight: float


@dataclass(frozen=True)
class IterationStep:
    """One pass of the amplitude iteration: the amplitude looked up, the cells, the result."""

    amplitude_V: float
    cells: tuple[CellUse, ...]
    result_pp_V: float


@dataclass(frozen=True)
class SegmentChoice:
    """How the table was used for one segment.

    condition : (amplitude_V, frequency_Hz) finally looked up.
    query : the point actually interpolated (``condition`` clamped onto the grid).
    clamped : True when the condition lay outside the table's grid on some axis.
    cells : cells and weights (Σ weights = 1).
    iterations : the amplitude iteration (empty when forced or for a single-cell table).
    converged : the amplitude is self-consistent (or forced / single cell).
    how : ``"iterated"``, ``"forced"`` or ``"single cell"``.
    note : remark (e.g. alternating cells), may be empty.
    """

    segment: Segment
    condition: tuple[float, float]
    query: tuple[float, float]
    clamped: bool
    cells: tuple[CellUse, ...]
    iterations: tuple[IterationStep, ...]
    converged: bool
    how: str
    note: str = ""


def _usable(pf: ParamsFile) -> list[int]:
    return [i for i, c in enumerate(pf.cells) if math.isfinite(c.amplitude_V) and math.isfinite(c.frequency_Hz)
            and c.frequency_Hz > 0]


def select_cells(pf: ParamsFile, condition: tuple[float, float], method: str = "interpolate"
                 ) -> tuple[tuple[CellUse, ...], tuple[float, float], bool]:
    """Cells and weights for ``condition`` = (amplitude_V peak-to-peak, frequency_Hz): the rule of
    :meth:`hystfit.conditions.LookupTable.select` on the table's cells. A table without usable
    conditions (a global fit) always gives its first cell.

    Returns
    -------
    (cells, query, clamped)
        The used cells (weights > 0 summing to 1), the point looked up, and whether the
        condition was clamped.
    """
    a, f = float(condition[0]), float(condition[1])
    idx = _usable(pf)
    if len(pf.cells) == 1 or not idx:
        if method not in ("interpolate", "nearest"):
            raise ConfigError(f"method {method!r}: choose interpolate or nearest")
        if not (math.isfinite(a) and math.isfinite(f) and f > 0):
            raise ConfigError(f"condition ({a:g} V, {f:g} Hz): needs a finite amplitude and a positive frequency")
        c = pf.cells[0]
        return (CellUse(0, c.label, c.amplitude_V, c.frequency_Hz, 1.0),), (a, f), False
    keys = [(pf.cells[i].amplitude_V, pf.cells[i].frequency_Hz) for i in idx]
    table = LookupTable(keys, [np.array([float(i)]) for i in idx])
    by_key = dict(zip(table.keys, idx))
    used, query, clamped = table.select((a, f), method)
    cells = []
    for k, w in used:
        i = by_key[(float(k[0]), float(k[1]))]
        c = pf.cells[i]
        cells.append(CellUse(i, c.label, c.amplitude_V, c.frequency_Hz, float(w)))
    return tuple(cells), query, clamped


def table_gain(pf: ParamsFile) -> float:
    """Median over cells of (output range / input range) of the identification data (unit/V)."""
    g = [c.scale.gain for c in pf.cells if c.scale.u_range > 0]
    return float(np.median(g)) if g else 1.0


def default_voltage_limits(pf: ParamsFile, margin: float = LIMIT_MARGIN) -> tuple[float, float]:
    """The table's identification voltage range ± ``margin`` × its width (V).

    The union of all cells' input ranges (``data_scale.u_min/u_max``): the range the stage was
    driven over while identifying, where the models are trustworthy.
    """
    lo = min(c.scale.u_min for c in pf.cells)
    hi = max(c.scale.u_max for c in pf.cells)
    span = max(hi - lo, 1e-12)
    return lo - margin * span, hi + margin * span


# ----------------------------------------------------------------------------------------------
# Inverting one cell
# ----------------------------------------------------------------------------------------------

def search_range(pf: ParamsFile, vmin: float, vmax: float) -> tuple[float, float]:
    """Search interval (V) for numerical inverses: [vmin, vmax] and the table's data range, ± their width.

    Deliberately wider than the voltage limits: clipping is done (and reported) afterwards,
    never inside the inverse.
    """
    lo = min(vmin, min(c.scale.u_min for c in pf.cells))
    hi = max(vmax, max(c.scale.u_max for c in pf.cells))
    w = max(hi - lo, 1e-9)
    return lo - w, hi + w


def preroll_voltage(cell: Cell, voltage: float, dt: float) -> np.ndarray:
    """The assumed history before a target: a ramp 0 V → ``voltage`` then a rest at ``voltage``.

    The stage is taken to start from the models' reset state at 0 V and to be brought
    monotonically to the initial voltage, which is what a virgin PI state means (paper 003
    eq. 1–3 initial state) and what identification captures starting at 0 V show. 16 + 4
    samples for a rate-independent model; 50 ms + 50 ms (at least 16 + 4 samples) for a
    rate-dependent one.

    A base that assumes a rest at its first sample (a PI with ``history="relaxed"``,
    :attr:`~hystfit.models.base.Model.starts_at_rest`) rests at ``voltage`` throughout (4 samples):
    that is its history. A base whose first sample from the virgin state is its state after a monotone ramp (PI,
    GPI: :attr:`~hystfit.models.base.Model.first_sample_is_a_ramp`) followed by blocks with memory
    (creep, a stage, a delay) rests at ``voltage`` from the first sample on (4 samples): the
    blocks start at rest at the base's output there, as a stage that rested at the initial
    voltage is — settled. The 50 ms ramp and rest left a creep with time constants of seconds far
    from it: diagnose's ``pi+creep`` of a creep ×2 plant, its feedforward fed to the plant resting at
    the initial voltage, tracked at 0.046 µm; settled, 0.0078 µm (``python
    benchmarks/feedforward_plant.py``).
    """
    model = cell.model
    comp = model.composition
    if _base(model).starts_at_rest:  # a base at rest at its first sample (a relaxed PI): the history is a rest there
        return np.full(4, float(voltage))
    if (model.rate_dependent and comp is not None and not comp[0].rate_dependent
            and comp[0].first_sample_is_a_ramp):
        return np.full(4, float(voltage))
    if cell.model.rate_dependent:
        n_ramp, n_hold = max(16, int(round(0.05 / dt))), max(4, int(round(0.05 / dt)))
    else:
        n_ramp, n_hold = 16, 4
    return np.concatenate([np.linspace(0.0, float(voltage), n_ramp), np.full(n_hold, float(voltage))])


def rest_output(cell: Cell, voltage: float, dt: float) -> float:
    """Output (unit) of the cell's model at rest at ``voltage`` (V) after :func:`preroll_voltage`."""
    return float(cell.model.simulate_one(cell.theta, preroll_voltage(cell, voltage, dt), dt)[-1])


def rest_voltage(cell: Cell, y0: float, dt: float, bracket: tuple[float, float]) -> float:
    """Voltage (V) at which the cell's model rests at output ``y0`` after :func:`preroll_voltage`.

    Brent's method on :func:`rest_output` over ``bracket`` (monotone for an invertible model);
    a level outside the reachable range gives the closest end of the bracket.
    """
    from scipy.optimize import brentq

    lo, hi = bracket

    def f(v: float) -> float:
        with np.errstate(all="ignore"):  # far ends of the bracket may overflow a model: handled below
            return rest_output(cell, v, dt) - y0

    flo, fhi = f(lo), f(hi)
    if not (np.isfinite(flo) and np.isfinite(fhi)) or flo * fhi > 0:
        return lo if abs(flo) <= abs(fhi) else hi
    return float(brentq(f, lo, hi, xtol=1e-10 * max(1.0, abs(hi) + abs(lo)), rtol=4 * np.finfo(float).eps))


def invert_cell(cell: Cell, y: np.ndarray, dt: float, initial_voltage: float,
                u_range: tuple[float, float], history: np.ndarray | None = None) -> np.ndarray:
    """Voltage (N,) making ``cell``'s model follow ``y`` (N,) from rest at ``initial_voltage`` (V).

    The model's own inverse (``model.invert``) is applied to the pre-roll output (the model
    driven by :func:`preroll_voltage`) followed by ``y``; the pre-roll part is dropped. So the
    inverse's memory at the first target sample is that of the stage resting at the initial
    voltage, identical to the memory :func:`simulate_cell` uses for the forward preview.

    ``history`` (M,) continues an earlier part instead: the voltage already chosen before ``y``
    (after the same pre-roll). The model's output for pre-roll + history is prepended to ``y``
    and inverted with it, so the inverse enters ``y`` with the memory that voltage history
    gives this model (exactly for analytic inverses, which return the history itself; to the
    inverse's accuracy otherwise). ``Model.invert`` cannot resume from a saved state, hence
    the re-inversion of the history.

    Raises
    ------
    ConfigError
        The model cannot be inverted (e.g. negative weights) or returns non-finite voltages.
    """
    model, theta = cell.model, cell.theta
    fn = model.natural_frequency_Hz(theta)
    if fn is not None:  # the stage's inverse needs its f_n resolved, as simulate's prediction does
        from .blocks.dynamics import check_below_nyquist

        check_below_nyquist(fn, dt, f"the target sampled at {1.0 / dt:.6g} Hz (--fs): cell {cell.label}")
    pre = preroll_voltage(cell, initial_voltage, dt)
    if history is not None and len(history):
        pre = np.concatenate([pre, np.asarray(history, dtype=np.float64)])
    y_ext = np.concatenate([model.simulate_one(theta, pre, dt), np.asarray(y, dtype=np.float64)])
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # non-finite results are caught below
            u = np.asarray(model.invert(theta, y_ext, dt, u_range=u_range), dtype=np.float64)
    except (ValueError, ZeroDivisionError, FloatingPointError) as exc:
        if isinstance(exc, ConfigError):
            raise ConfigError(f"cell {cell.label}: {exc}") from None
        raise ConfigError(f"cell {cell.label}: the {model.name} model cannot be inverted ({exc})") from None
    if u.shape != y_ext.shape or not np.all(np.isfinite(u)):
        raise ConfigError(f"cell {cell.label}: the {model.name} inverse gave non-finite voltages; the identified "
                          "parameters are not invertible (refit, e.g. with non-negative weights)")
    return u[pre.size:]


def simulate_cell(cell: Cell, u: np.ndarray, dt: float, initial_voltage: float) -> np.ndarray:
    """Forward output (N,) of ``cell`` for voltage ``u`` (N,) after :func:`preroll_voltage` to ``initial_voltage``."""
    pre = preroll_voltage(cell, initial_voltage, dt)
    return cell.model.simulate_one(cell.theta, np.concatenate([pre, np.asarray(u, dtype=np.float64)]), dt)[pre.size:]


class _CellCache:
    """Inverse voltages per cell for one segment (samples 0 … ``stop`` − 1, absolute indices).

    First segment (``history`` None): each cell inverts the target from rest; with
    ``initial_voltage`` None each cell starts from its own rest voltage for the target's first
    sample (:func:`rest_voltage`), so every cell's inverse is consistent with its model. Later
    segments: ``history`` is the voltage already chosen for samples 0 … start − 1 and every
    cell continues from it (:func:`invert_cell`), after the pre-roll to ``initial_voltage``.
    """

    def __init__(self, pf: ParamsFile, target: Target, initial_voltage: float | None,
                 u_range: tuple[float, float], progress: Progress, *, stop: int | None = None,
                 history: np.ndarray | None = None):
        self.pf, self.target, self.v0, self.u_range, self.progress = pf, target, initial_voltage, u_range, progress
        self.stop = target.n if stop is None else int(stop)
        self.history = history
        self.u: dict[int, np.ndarray] = {}
        self.rest: dict[int, float] = {}

    def initial_voltage(self, i: int) -> float:
        if self.v0 is not None:
            return self.v0
        if i not in self.rest:
            self.rest[i] = rest_voltage(self.pf.cells[i], float(self.target.y[0]), self.target.dt, self.u_range)
        return self.rest[i]

    def get(self, i: int) -> np.ndarray:
        """Voltage (stop,) of cell i: the history (if any), then the cell's inverse."""
        if i not in self.u:
            cell, tg = self.pf.cells[i], self.target
            a = 0 if self.history is None else self.history.size
            if self.progress:
                self.progress("note", {"text": f"inverting cell {cell.label} ({self.stop - a} samples"
                                               + (f" after {a} of history)" if a else ")")})
            tail = invert_cell(cell, tg.y[a:self.stop], tg.dt, self.initial_voltage(i), self.u_range, self.history)
            self.u[i] = tail if self.history is None else np.concatenate([self.history, tail])
        return self.u[i]

    def blend(self, cells: Sequence[CellUse], sl: slice) -> np.ndarray:
        out = np.zeros(sl.stop - sl.start)
        for c in cells:
            out += c.weight * self.get(c.index)[sl]
        return out


def choose_condition(pf: ParamsFile, target: Target, segment: Segment, cache: "_CellCache", *,
                     method: str = "interpolate", condition: tuple[float, float] | None = None,
                     max_iterations: int = 25) -> SegmentChoice:
    """Settle the table cell(s) for one segment (see the module docstring, step 2).

    The iteration starts at A₀ = segment stroke / :func:`table_gain`. It stops when the
    amplitude is self-consistent to :data:`AMPLITUDE_RTOL` with unchanged cells, or when a
    cell set recurs (nearest lookup alternating between two cells at a boundary): then the
    set whose own voltage amplitude lies closest to its cells' amplitude is kept and the
    alternation is reported.
    """
    sl = slice(segment.start, segment.stop)
    f = segment.frequency_Hz if math.isfinite(segment.frequency_Hz) else _target_frequency(
        cache.target.y[sl], cache.target.dt)
    if condition is not None:
        cells, query, clamped = select_cells(pf, condition, method)
        return SegmentChoice(segment, (float(condition[0]), float(condition[1])), query, clamped, cells, (), True,
                             "forced")
    if len(pf.cells) == 1 or not _usable(pf):
        cells, query, clamped = select_cells(pf, (1.0, f), method)
        if len(cells) == 1:  # the lookup is that cell's own condition, not the placeholder amplitude asked
            query = (float(cells[0].amplitude_V), float(cells[0].frequency_Hz))
        return SegmentChoice(segment, (float("nan"), f), query, False, cells, (), True, "single cell")
    y = cache.target.y[sl]
    stroke = float(y.max() - y.min())
    a = stroke / table_gain(pf) if stroke > 0 else min(c.amplitude_V for c in pf.cells if math.isfinite(c.amplitude_V))
    choice = _iterate(pf, cache, segment, f, a, method, max_iterations, lambda u: float(np.ptp(u)))
    u = cache.blend(choice.cells, sl)
    cover = _covering_amplitude(pf, u)
    if cover is None or _cells_cover(pf, choice.cells, u):
        return choice
    # the voltage leaves the range a chosen cell was identified on (a target up the stroke): the
    # iteration again, each voltage asking at least for the smallest cell that covers it
    again = _iterate(pf, cache, segment, f, max(cover, choice.condition[0]), method, max_iterations,
                     lambda v: _amplitude_asked(pf, v))
    note = (f"the voltage of {'+'.join(c.label for c in choice.cells)} ({float(np.min(u)):.4g}…{float(np.max(u)):.4g} V) "
            "leaves the range they were identified on; the cells that cover it were looked up instead")
    return replace(again, iterations=choice.iterations + again.iterations, note="; ".join(x for x in (again.note, note) if x))


def _iterate(pf: ParamsFile, cache: "_CellCache", segment: Segment, f: float, a: float, method: str,
             max_iterations: int, asked) -> SegmentChoice:
    """The amplitude iteration of :func:`choose_condition` from ``a``: ``asked(u)`` is the table
    amplitude a voltage ``u`` asks for (its peak-to-peak, or at least a covering cell's)."""
    sl = slice(segment.start, segment.stop)
    steps: list[IterationStep] = []
    seen: dict[tuple, int] = {}
    for _ in range(max_iterations):
        cells, query, clamped = select_cells(pf, (a, f), method)
        pp = asked(cache.blend(cells, sl))
        steps.append(IterationStep(a, cells, pp))
        key = tuple((c.index, round(c.weight, 9)) for c in cells)
        if abs(pp - a) <= AMPLITUDE_RTOL * max(pp, 1e-12) or (len(steps) > 1 and key == _key(steps[-2].cells)):
            # self-consistent, or the same cells again (then the voltage, hence pp, is the same too)
            return SegmentChoice(segment, (a, f), query, clamped, cells, tuple(steps), True, "iterated")
        if key in seen:  # a cycle of cell sets (nearest lookup at a boundary): no self-consistent choice
            cycle = steps[seen[key]:-1]
            best = min(cycle, key=lambda s: abs(s.result_pp_V - _cells_amplitude(s.cells)))
            names = sorted({"+".join(c.label for c in s.cells) for s in cycle})
            note = (f"the amplitude iteration alternated between cells {' / '.join(names)}; kept "
                    f"{'+'.join(c.label for c in best.cells)} (its voltage amplitude {best.result_pp_V:.4g} V is "
                    "closest to its cells' amplitude)")
            _, query, clamped = select_cells(pf, (best.amplitude_V, f), method)
            return SegmentChoice(segment, (best.amplitude_V, f), query, clamped, best.cells, tuple(steps), False,
                                 "iterated", note)
        seen[key] = len(steps) - 1
        a = pp
    last = steps[-1]
    note = f"the amplitude iteration did not settle in {max_iterations} passes (last {last.amplitude_V:.4g} V)"
    _, query, clamped = select_cells(pf, (last.amplitude_V, f), method)
    return SegmentChoice(segment, (last.amplitude_V, f), query, clamped, last.cells, tuple(steps), False,
                         "iterated", note)


def _key(cells: Sequence[CellUse]) -> tuple:
    return tuple((c.index, round(c.weight, 9)) for c in cells)


def _cells_amplitude(cells: Sequence[CellUse]) -> float:
    return float(sum(c.weight * c.amplitude_V for c in cells))


def _cells_cover(pf: ParamsFile, cells: Sequence[CellUse], u: np.ndarray) -> bool:
    """Whether the voltage ``u`` stays within the input range of the cells used, interpolated as
    their amplitudes are (Σ w·u_min … Σ w·u_max, to 2 % of it): a target between two cells'
    amplitudes from the bottom of the stroke is the table's interpolation; one shifted up the
    stroke leaves it. Cells without a known range count as covering."""
    if any(pf.cells[c.index].scale is None for c in cells if c.weight > 0):
        return True
    w = np.array([c.weight for c in cells], float)
    lo_c = float(np.dot(w, [pf.cells[c.index].scale.u_min for c in cells])) / max(float(w.sum()), 1e-300)
    hi_c = float(np.dot(w, [pf.cells[c.index].scale.u_max for c in cells])) / max(float(w.sum()), 1e-300)
    tol = 0.02 * (hi_c - lo_c)
    return float(np.min(u)) >= lo_c - tol and float(np.max(u)) <= hi_c + tol


def _amplitude_asked(pf: ParamsFile, u: np.ndarray) -> float:
    """The table amplitude (V peak-to-peak) the voltage ``u`` asks for: its peak-to-peak, or, when
    that is below it, the smallest amplitude of a cell whose identification range covers ``u``
    (:func:`_covering_amplitude`)."""
    pp = float(np.ptp(u)) if u.size else 0.0
    cover = _covering_amplitude(pf, u)
    return pp if cover is None else max(pp, cover)


def _covering_amplitude(pf: ParamsFile, u: np.ndarray) -> float | None:
    """The smallest amplitude among the cells whose identification input range covers the voltage
    ``u`` (to 2 % of their range), or None when none does or the cells' ranges are unknown: a cell
    identified on 0…20 V extrapolates on 10…40 V, whatever the peak-to-peak says."""
    if not u.size:
        return None
    lo, hi = float(np.min(u)), float(np.max(u))
    amps = []
    for c in pf.cells:
        s = c.scale
        if s is None or not math.isfinite(c.amplitude_V):
            continue
        tol = 0.02 * float(s.u_max - s.u_min)
        if s.u_min <= lo + tol and s.u_max >= hi - tol:
            amps.append(float(c.amplitude_V))
    return min(amps) if amps else None




# ----------------------------------------------------------------------------------------------
# Limits
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Span:
    """A contiguous run of limited samples ``start`` … ``stop − 1``.

    start_s, stop_s : time of the first and last limited sample (s).
    n : number of samples.
    worst_V : largest |desired − applied| voltage in the span (V).
    kind : ``"vmin"``, ``"vmax"`` or ``"slew"``.
    """

    start: int
    stop: int
    start_s: float
    stop_s: float
    n: int
    worst_V: float
    kind: str


def find_spans(mask: np.ndarray, excess: np.ndarray, dt: float, kind: str) -> list[Span]:
    """Contiguous runs of ``mask`` (N,) as :class:`Span` objects (excess (N,) in V)."""
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return []
    d = np.diff(mask.astype(np.int8), prepend=0, append=0)
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return [Span(int(a), int(b), a * dt, (b - 1) * dt, int(b - a), float(np.max(np.abs(excess[a:b]))), kind)
            for a, b in zip(starts, stops)]


@njit(cache=True)
def _rate_limit(u, u0, max_step):
    out = np.empty_like(u)
    prev = u0
    for k in range(u.shape[0]):
        x = u[k]
        if x > prev + max_step:
            x = prev + max_step
        elif x < prev - max_step:
            x = prev - max_step
        out[k] = x
        prev = x
    return out


def apply_limits(u: np.ndarray, dt: float, vmin: float, vmax: float, max_slew: float | None,
                 u_start: float) -> tuple[np.ndarray, list[Span], list[Span]]:
    """Clip to [vmin, vmax] (V), then limit the slew rate to ``max_slew`` (V/s) from ``u_start`` (V).

    Returns
    -------
    (u_applied, clip_spans, slew_spans)
        The applied voltage (N,) and the spans where clipping (kind ``vmin``/``vmax``, excess =
        desired − clipped) and slew limiting (kind ``slew``, excess = clipped − applied) acted.
    """
    u = np.asarray(u, dtype=np.float64)
    uc = np.clip(u, vmin, vmax)
    clip = find_spans(u < vmin, u - uc, dt, "vmin") + find_spans(u > vmax, u - uc, dt, "vmax")
    clip.sort(key=lambda s: s.start)
    if max_slew is None:
        return uc, clip, []
    ua = _rate_limit(np.ascontiguousarray(uc), float(u_start), float(max_slew) * dt)
    diff = uc - ua
    slew = find_spans(np.abs(diff) > 1e-12 * max(1.0, abs(vmax), abs(vmin)), diff, dt, "slew")
    return ua, clip, slew


# ----------------------------------------------------------------------------------------------
# The inversion
# ----------------------------------------------------------------------------------------------


def tracking_metrics(y_pred: np.ndarray, y_d: np.ndarray, unit: str, stroke: float | None = None) -> dict:
    """Paper 002 Table 4 figures of e = y_pred − y_d: max|e|, RMSE, mean, and both in % of the stroke.

    ``stroke`` defaults to max y_d − min y_d (``unit``).
    """
    e = np.asarray(y_pred, float) - np.asarray(y_d, float)
    stroke = float(np.max(y_d) - np.min(y_d)) if stroke is None else float(stroke)
    finite = bool(np.all(np.isfinite(e)))
    rmse = float(np.sqrt(np.mean(e * e))) if finite else float("inf")
    mx = float(np.max(np.abs(e))) if finite else float("inf")
    pct = (lambda x: 100.0 * x / stroke) if stroke > 0 else (lambda x: float("nan"))
    return {f"max_error_{unit}": mx, f"rmse_{unit}": rmse, f"mean_error_{unit}": float(np.mean(e)) if finite else
            float("nan"), "max_error_pct_of_stroke": pct(mx), "rmse_pct_of_stroke": pct(rmse),
            f"stroke_{unit}": stroke, "n_samples": int(e.size)}


@dataclass(frozen=True, eq=False)
class InversionResult:
    """Everything :func:`invert_target` computed (arrays (N,) aligned with ``target.t_s``).

    voltage_V : the voltage to apply (after clipping and slew limiting).
    desired_voltage_V : the blended inverse before any limit.
    predicted : forward-model output for ``voltage_V`` (``unit``).
    metrics : :func:`tracking_metrics` of ``predicted`` against the target.
    metrics_unlimited : the same for ``desired_voltage_V`` (None when no limit acted).
    segment_metrics : per segment, the same metrics.
    choices : the table cells per segment (:class:`SegmentChoice`).
    limits : dict with vmin_V, vmax_V, max_slew_V_per_s and where each came from.
    initial_voltage_V, initial_voltage_source : the stage's rest voltage before the target and
        how it was chosen (``"inverse of the first target sample"`` or ``"given"``).
    clip_spans, slew_spans : where limits acted.
    extrapolation : voltage ranges outside a used cell's identification range.
    notes : further remarks, each a sentence.
    """

    params_path: str
    model_name: str
    unit: str
    target: Target
    method: str
    voltage_V: np.ndarray
    desired_voltage_V: np.ndarray
    predicted: np.ndarray
    metrics: dict
    metrics_unlimited: dict | None
    segment_metrics: tuple[dict, ...]
    choices: tuple[SegmentChoice, ...]
    limits: dict
    initial_voltage_V: float
    initial_voltage_source: str
    clip_spans: tuple[Span, ...]
    slew_spans: tuple[Span, ...]
    extrapolation: tuple[dict, ...]
    notes: tuple[str, ...] = field(default_factory=tuple)
    runtime_s: float = 0.0
    #: per cell label, the RMSE of its model on its own identification data (``params.json``'s
    #: metrics; NaN where a file lacks it): how closely the model reproduces the stage at all
    cell_fit_rmse: dict = field(default_factory=dict)
    #: the history assumed before the target: a rest at the initial voltage (a relaxed PI base,
    #: :attr:`~hystfit.models.base.Model.starts_at_rest`), else a monotone ramp from 0 V to it
    at_rest: bool = False

    @property
    def limited(self) -> bool:
        return bool(self.clip_spans or self.slew_spans)

    def fit_rmse(self, choice: SegmentChoice | None = None) -> float:
        """The RMS of the fit RMSEs of the cells a segment uses (``choice``), weighted by their
        blend weights, or of every segment's by its samples (None): the model's own error against
        the measurements it was identified on. The predicted tracking error only checks that the
        model follows its inverse (≈ 0 for an exact inverse such as PI's); a measured tracking error
        is of this order, more where the target leaves the cells' identified range."""
        if choice is not None:
            # cells whose file does not record their fit are left out, the others' weights renormalised
            known = [(c.weight, self.cell_fit_rmse.get(c.label, math.nan)) for c in choice.cells]
            known = [(w, e) for w, e in known if math.isfinite(e)]
            total = sum(w for w, _ in known)
            return math.sqrt(sum(w * e * e for w, e in known) / total) if total > 0 else math.nan
        n = self.target.n
        parts = [((ch.segment.stop - ch.segment.start) / n, self.fit_rmse(ch)) for ch in self.choices]
        parts = [(w, e) for w, e in parts if math.isfinite(e)]
        total = sum(w for w, _ in parts)
        return math.sqrt(sum(w * e * e for w, e in parts) / total) if total > 0 else math.nan

    def to_table(self) -> Columns:
        """``time_s, voltage_V, predicted_displacement_<unit>``: the file for the amplifier
        (:func:`hystfit.io.write_table` writes it; ``.to_pandas()`` gives a DataFrame)."""
        return Columns({"time_s": self.target.t_s, "voltage_V": self.voltage_V,
                        f"predicted_displacement_{self.unit}": self.predicted})

    def cells_used(self) -> list[tuple[str, float]]:
        """(label, weight) of every cell used, weights averaged over segments by length."""
        tot: dict[str, float] = {}
        n = self.target.n
        for ch in self.choices:
            frac = (ch.segment.stop - ch.segment.start) / n
            for c in ch.cells:
                tot[c.label] = tot.get(c.label, 0.0) + frac * c.weight
        return sorted(tot.items(), key=lambda kv: -kv[1])


def _crossfade(n_a: int, n_b: int) -> int:
    """Samples over which weights change at a segment join (2 % of the shorter segment)."""
    return max(1, int(round(0.02 * min(n_a, n_b))))


def blend_segments(arrays: dict[int, np.ndarray], choices: Sequence[SegmentChoice], n: int) -> np.ndarray:
    """Σ_c w_c(k)·arrays[c][k] with per-segment weights, cross-faded linearly after each join."""
    out = np.zeros(n)
    for ch in choices:
        _blend_into(out, ch.cells, arrays, ch.segment.start, ch.segment.stop)
    for prev, nxt in zip(choices, choices[1:]):
        _crossfade_into(out, prev, arrays, nxt)
    return out


def _blend_into(out: np.ndarray, cells: Sequence[CellUse], arrays: dict[int, np.ndarray], a: int, b: int) -> None:
    """out[a:b] = Σ_c w_c·arrays[c][a:b]."""
    out[a:b] = 0.0
    for c in cells:
        out[a:b] += c.weight * arrays[c.index][a:b]


def _crossfade_into(out: np.ndarray, prev: SegmentChoice, prev_arrays: dict[int, np.ndarray],
                    nxt: SegmentChoice) -> int:
    """Cross-fade ``out`` from ``prev``'s cells to ``nxt``'s after their join, as :func:`blend_segments` does.

    Returns the number of faded samples (0 when both segments use the same cells and weights).
    """
    if {(c.index, c.weight) for c in prev.cells} == {(c.index, c.weight) for c in nxt.cells}:
        return 0
    j = nxt.segment.start
    m = min(_crossfade(prev.segment.stop - prev.segment.start, nxt.segment.stop - j), nxt.segment.stop - j)
    ramp = (np.arange(m) + 1.0) / (m + 1.0)  # weight of the new segment's cells
    old = np.zeros(m)
    for c in prev.cells:
        old += c.weight * prev_arrays[c.index][j:j + m]
    out[j:j + m] = (1.0 - ramp) * old + ramp * out[j:j + m]
    return m


@dataclass(frozen=True)
class InvertLimits:
    """The checked options of :func:`invert_target`: voltage limits (V) and where they came from,
    slew limit (V/s, None: none), the given initial voltage (V, None: the inverse of the first
    target sample) and the forced condition (None: iterate)."""

    vmin_V: float
    vmax_V: float
    vmin_source: str
    vmax_source: str
    max_slew: float | None
    initial_voltage: float | None
    condition: tuple[float, float] | None

    def record(self, pf: ParamsFile) -> dict:
        """The ``limits`` of :class:`InversionResult`."""
        return {"vmin_V": self.vmin_V, "vmax_V": self.vmax_V, "vmin_source": self.vmin_source,
                "vmax_source": self.vmax_source,
                "default_rule": f"identification voltage range {min(c.scale.u_min for c in pf.cells):g}…"
                                f"{max(c.scale.u_max for c in pf.cells):g} V ± {LIMIT_MARGIN * 100:g} %",
                "max_slew_V_per_s": self.max_slew}


#: a target further than this many times the table's identified output span beyond that span is out
#: of reach: no voltage within the limits makes it, and the usual cause is a unit (m for µm)
TARGET_REACH_SPANS = 10.0


def _check_reach(pf: ParamsFile, target: Target) -> None:
    """Refuse a target far outside the outputs the table was identified on (one-line ConfigError):
    a blind test's 2…12 m sine against a table identified in m for a stage of some 20 µm clipped
    at every sample and wrote a voltage that reached nothing, with exit 0."""
    lo = min(float(c.scale.y_min) for c in pf.cells)
    hi = max(float(c.scale.y_max) for c in pf.cells)
    span = hi - lo
    t_lo, t_hi = float(np.min(target.y)), float(np.max(target.y))
    if span > 0 and (t_hi > hi + TARGET_REACH_SPANS * span or t_lo < lo - TARGET_REACH_SPANS * span):
        u = pf.unit
        shift = (" or, for a built-in target, move it there with --offset (e.g. --offset "
                 f"{lo + 0.1 * span:.6g}), or" if target.kind != "file" and t_hi - t_lo <= span else " or")
        raise ConfigError(f"the target spans {t_lo:.4g}…{t_hi:.4g} {u}, far beyond the outputs the table was identified "
                          f"on ({lo:.4g}…{hi:.4g} {u}): no voltage reaches it. Targets are in the table's output unit "
                          f"({u}); convert the target,{shift} identify the model on data that covers it")


def reach_note(pf: ParamsFile, target: Target, margin: float = 0.05) -> str | None:
    """A note when the target leaves the outputs the table was identified on by more than ``margin``
    of their span (closer than :func:`_check_reach` refuses): there the voltages are the models'
    extrapolation or clipped, and a blind test's 0…10 µm target against a table identified on
    −21…−1.2 µm gave only a clipping warning and a 51 % error. None when it stays inside."""
    lo = min(float(c.scale.y_min) for c in pf.cells)
    hi = max(float(c.scale.y_max) for c in pf.cells)
    span = hi - lo
    t_lo, t_hi = float(np.min(target.y)), float(np.max(target.y))
    if not span > 0 or (t_lo >= lo - margin * span and t_hi <= hi + margin * span):
        return None
    u = pf.unit
    if t_hi - t_lo > span:
        fix = "its stroke is larger than the identified one: identify on data that covers it"
    else:
        move = lo - t_lo if t_lo < lo else hi - t_hi
        how = " (--offset for a built-in target)" if target.kind != "file" else ""
        fix = f"move it by {move:+.4g} {u}{how} to stay inside"
    return (f"the target spans {t_lo:.4g}…{t_hi:.4g} {u}, outside the outputs the table was identified on "
            f"({lo:.4g}…{hi:.4g} {u}): there the voltages are the models' extrapolation or clipped; {fix}")


def check_invert_options(pf: ParamsFile, target: Target, method: str, condition, initial_voltage, vmin, vmax,
                         max_slew) -> InvertLimits:
    """The options of :func:`invert_target` checked (one-line ConfigError) and completed with the
    default limits."""
    what = f"the target {target.description.removeprefix('file ')}" if target.kind == "file" else "the target"
    pf.check_unit(target.unit, what, f"convert the target (or name its column e.g. target_{pf.unit})")
    _check_reach(pf, target)
    if method not in ("interpolate", "nearest"):
        raise ConfigError(f"method {method!r}: choose interpolate or nearest")
    dlo, dhi = default_voltage_limits(pf)
    lo = dlo if vmin is None else _finite("--vmin", vmin)
    hi = dhi if vmax is None else _finite("--vmax", vmax)
    if not lo < hi:
        raise ConfigError(f"the voltage limits must satisfy vmin < vmax; got vmin = {lo:g} V, vmax = {hi:g} V")
    if max_slew is not None:
        max_slew = _positive("the slew-rate limit --max-slew (V/s)", max_slew)
    if initial_voltage is not None:
        initial_voltage = _finite("--initial-voltage", initial_voltage)
        if not lo <= initial_voltage <= hi:
            raise ConfigError(f"the initial voltage {initial_voltage:g} V lies outside the voltage limits "
                              f"[{lo:g}, {hi:g}] V; change --initial-voltage or the limits")
    if condition is not None:
        condition = (_positive("condition amplitude (V)", condition[0]), _positive("condition frequency (Hz)",
                                                                                   condition[1]))
    return InvertLimits(lo, hi, "default" if vmin is None else "given", "default" if vmax is None else "given",
                        max_slew, initial_voltage, condition)


@dataclass(frozen=True, eq=False)
class _Desired:
    """Step 1–4 of :func:`invert_target`: the blended inverse, the cells per segment and the rest voltage."""

    voltage: np.ndarray
    choices: tuple[SegmentChoice, ...]
    v0: float


def _desired_voltage(pf: ParamsFile, target: Target, opts: InvertLimits, method: str, progress: Progress) -> _Desired:
    """Segment by segment: the table condition, the cells' inverses blended and cross-faded at the joins."""
    y_d = target.y
    u_range = search_range(pf, opts.vmin_V, opts.vmax_V)
    initial_voltage = opts.initial_voltage
    if progress:
        progress("start", {"total": len(target.segments)})
    choices: list[SegmentChoice] = []
    u_des = np.empty(target.n)
    v0 = float(initial_voltage) if initial_voltage is not None else float("nan")
    prev: tuple[SegmentChoice, dict[int, np.ndarray]] | None = None
    segs = target.segments
    for k, seg in enumerate(segs):
        a, b = seg.start, seg.stop
        nxt = segs[k + 1] if k + 1 < len(segs) else None
        # the cells of this segment are also needed for the cross-fade into the next one
        stop = b if nxt is None else min(target.n, b + _crossfade(b - a, nxt.stop - nxt.start))
        cache = _CellCache(pf, target, initial_voltage if k == 0 else v0, u_range, progress, stop=stop,
                           history=None if k == 0 else u_des[:a])
        ch = choose_condition(pf, target, seg, cache, method=method, condition=opts.condition)
        arrays = {c.index: cache.get(c.index) for c in ch.cells}
        _blend_into(u_des, ch.cells, arrays, a, b)
        m = _crossfade_into(u_des, prev[0], prev[1], ch) if prev is not None else 0
        if m:
            # the cells entered the segment with the faded voltage, not their own: continue from it
            hist = u_des[:a + m]
            for c in ch.cells:
                arrays[c.index] = np.concatenate([hist, invert_cell(pf.cells[c.index], y_d[a + m:stop], target.dt,
                                                                    v0, u_range, hist)])
            _blend_into(u_des, ch.cells, arrays, a + m, b)
        if k == 0 and initial_voltage is None:
            v0 = float(u_des[0])
        del cache
        prev = (ch, arrays)
        choices.append(ch)
        if progress:
            progress("advance", {"label": seg.label})
    return _Desired(u_des, tuple(choices), v0)


@dataclass(frozen=True, eq=False)
class _Preview:
    """Step 5–6 of :func:`invert_target`: the limited voltage, where limits acted, and its forward preview."""

    voltage: np.ndarray
    clip_spans: tuple[Span, ...]
    slew_spans: tuple[Span, ...]
    predicted: np.ndarray
    metrics: dict
    metrics_unlimited: dict | None
    segment_metrics: tuple[dict, ...]


def _preview(pf: ParamsFile, target: Target, opts: InvertLimits, desired: _Desired) -> _Preview:
    """Limits applied, then the table's forward model run on the voltage (and on the unlimited one
    when a limit acted) and scored against the target, as a whole and per segment."""
    y_d, choices, v0 = target.y, desired.choices, desired.v0
    used = sorted({c.index for ch in choices for c in ch.cells})
    u_app, clip_spans, slew_spans = apply_limits(desired.voltage, target.dt, opts.vmin_V, opts.vmax_V,
                                                 opts.max_slew, v0)
    y_pred = blend_segments({i: simulate_cell(pf.cells[i], u_app, target.dt, v0) for i in used}, choices, target.n)
    metrics = tracking_metrics(y_pred, y_d, pf.unit)
    metrics_unlim = None
    if clip_spans or slew_spans:
        y_unl = blend_segments({i: simulate_cell(pf.cells[i], desired.voltage, target.dt, v0) for i in used},
                               choices, target.n)
        metrics_unlim = tracking_metrics(y_unl, y_d, pf.unit)
        del y_unl
    seg_metrics = tuple({"segment": ch.segment.label, "start_s": ch.segment.start * target.dt,
                         "stop_s": (ch.segment.stop - 1) * target.dt,
                         **tracking_metrics(y_pred[ch.segment.start:ch.segment.stop],
                                            y_d[ch.segment.start:ch.segment.stop], pf.unit,
                                            stroke=float(np.ptp(y_d[ch.segment.start:ch.segment.stop])))}
                        for ch in choices)
    return _Preview(u_app, tuple(clip_spans), tuple(slew_spans), y_pred, metrics, metrics_unlim, seg_metrics)


def _inversion_notes(pf: ParamsFile, target: Target, opts: InvertLimits, desired: _Desired,
                     extrap: Sequence[dict]) -> tuple[str, ...]:
    """The remarks of an inversion: a rest voltage outside the limits, a jump at t = 0, the
    segments' notes and clamps, extrapolated cells."""
    lo, hi, v0, initial_voltage = opts.vmin_V, opts.vmax_V, desired.v0, opts.initial_voltage
    y_d = target.y
    notes: list[str] = [n for n in (reach_note(pf, target),) if n]
    if initial_voltage is None and not lo <= v0 <= hi:
        notes.append(f"the stage must rest at {v0:.4g} V for the target's first sample, outside the limits "
                     f"[{lo:.4g}, {hi:.4g}] V")
    if initial_voltage is not None:
        y_rest = sum(c.weight * rest_output(pf.cells[c.index], initial_voltage, target.dt)
                     for c in desired.choices[0].cells)
        jump = float(y_d[0] - y_rest)
        if abs(jump) > 1e-3 * max(target.stroke, 1e-12):
            notes.append(f"at the initial voltage {initial_voltage:g} V the stage rests at {y_rest:.4g} {pf.unit} "
                         f"(model), the target starts at {y_d[0]:.4g} {pf.unit}: a jump of {jump:+.4g} {pf.unit} "
                         "at t = 0")
    for ch in desired.choices:
        if ch.note:
            notes.append(f"segment {ch.segment.label}: {ch.note}")
        if ch.clamped:
            notes.append(f"segment {ch.segment.label}: {clamp_note(ch.condition, ch.query, ch.cells)}")
    notes += [extrapolation_note(x) for x in extrap]
    return tuple(notes)


def _too_fast_for_the_stage(pf: ParamsFile, target: Target, opts: InvertLimits, desired: _Desired,
                            pv: _Preview) -> tuple[str, ...]:
    """A note when the voltage limits cut the feedforward of a model with a stage (a natural
    frequency f_n): the target changes faster than the stage can follow within them — the inverse
    of a resonant stage turns a jump into a voltage impulse. A blind test's step of 10 µm through
    ``pi+…+dynamics`` asked for −14…103 V against limits of −6…66 V; clipped, the feedforward
    overshot 25 % and ff+pid 116 % where pid alone overshot 2 %, with only a count of limited
    samples said. Empty without clipping or without a stage."""
    fns = [fn for i in sorted({c.index for ch in desired.choices for c in ch.cells})
           if (fn := pf.cells[i].model.natural_frequency_Hz(pf.cells[i].theta)) is not None]
    if not fns:
        return ()
    fn, want = min(fns), desired.voltage
    # a spike of the inverse lasts about a stage period; a target beyond the table's reach is clipped
    # for as long as it stays there (said by the limits' own report): only the short spans are the stage's
    clipped = [sp for sp in pv.clip_spans if sp.kind in ("vmin", "vmax") and sp.n * target.dt <= 2.0 / fn]
    if not clipped:
        return ()
    rise_ms = 1e3 * 2.0 / fn  # two periods of the stage: a ramp its inverse follows with a bounded voltage
    how = (f"an instantaneous step needs a voltage impulse, so the feedforward (and ff+pid, smc in track) overshoots "
           f"after each step; give the steps a rise time of a few stage periods (≥ {rise_ms:.2g} ms) in a target "
           "file, or follow them with pid alone" if target.kind == "steps" else
           f"smooth the target's fast changes over a few stage periods (≥ {rise_ms:.2g} ms), or lower its frequency")
    return (f"the target changes faster than the model's stage (f_n = {fn:.4g} Hz) can follow within the voltage "
            f"limits: its inverse asks for {float(want.min()):.4g}…{float(want.max()):.4g} V (limits "
            f"{opts.vmin_V:.4g}…{opts.vmax_V:.4g} V), clipped in {len(clipped)} span(s); {how}",)


@one_blas_thread
def invert_target(pf: ParamsFile, target: Target, *, method: str = "interpolate",
                  condition: tuple[float, float] | None = None, initial_voltage: float | None = None,
                  vmin: float | None = None, vmax: float | None = None, max_slew: float | None = None,
                  progress: Progress = None) -> InversionResult:
    """Feedforward voltage for ``target`` from the look-up table ``pf`` (module docstring, steps 1–6).

    Parameters
    ----------
    pf : parameter file (:func:`hystfit.results.load_params`).
    target : desired trajectory; its unit must be the parameter file's output unit.
    method : ``"interpolate"`` (bilinear between cells) or ``"nearest"``.
    condition : force the table condition (amplitude_V peak-to-peak, frequency_Hz) for every
        segment instead of iterating.
    initial_voltage : voltage (V) the stage rests at before the target; default: the inverse
        of the target's first sample (consistent with the models' reset state).
    vmin, vmax : voltage limits (V); default :func:`default_voltage_limits`.
    max_slew : slew-rate limit (V/s); default none.
    progress : optional callback ``progress(event, info)``.

    Returns
    -------
    InversionResult

    Raises
    ------
    ConfigError
        Unit mismatch, vmin ≥ vmax, non-positive slew rate, initial voltage outside the
        limits, or a model that cannot be inverted.
    """
    t0 = time.perf_counter()
    opts = check_invert_options(pf, target, method, condition, initial_voltage, vmin, vmax, max_slew)
    desired = _desired_voltage(pf, target, opts, method, progress)
    pv = _preview(pf, target, opts, desired)
    extrap = _extrapolation(pf, desired.choices, pv.voltage)
    notes = _inversion_notes(pf, target, opts, desired, extrap) + _too_fast_for_the_stage(pf, target, opts, desired,
                                                                                          pv)
    v0_source = "given" if opts.initial_voltage is not None else "rest voltage of the first target sample"
    return InversionResult(pf.path, pf.model_name, pf.unit, target, method, pv.voltage, desired.voltage, pv.predicted,
                           pv.metrics, pv.metrics_unlimited, pv.segment_metrics, desired.choices, opts.record(pf),
                           desired.v0, v0_source, pv.clip_spans, pv.slew_spans, tuple(extrap), notes,
                           time.perf_counter() - t0, cell_fit_rmse=cell_fit_rmses(pf),
                           at_rest=any(_base(c.model).starts_at_rest for c in pf.cells))


def _base(model):
    """A composite model's base, or the model itself."""
    return model.composition[0] if model.composition is not None else model


def cell_fit_rmses(pf: ParamsFile) -> dict[str, float]:
    """Per cell label, the RMSE of its model on its identification data (NaN where not recorded)."""
    key = f"rmse_{pf.unit}"
    return {c.label: float(c.metrics.get(key, math.nan)) if c.metrics.get(key) is not None else math.nan
            for c in pf.cells}


def clamp_note(condition: tuple[float, float], query: tuple[float, float], cells: Sequence[CellUse] = ()) -> str:
    """The note for a condition outside the table's grid (shared by invert, track and simulate), with
    the cells that point stands for (a blind test read "clamped to 80 V, 10 Hz" and wondered where
    that cell was: the table's grid is the product of its amplitudes and frequencies, and the cell
    used was 88V_10Hz)."""
    used = (f" (cells used: {' + '.join(f'{c.label}×{c.weight:.2f}' for c in sorted(cells, key=lambda c: -c.weight))})"
            if cells else "")
    return (f"condition {condition[0]:.4g} V, {condition[1]:.4g} Hz lies outside the table's grid; clamped to "
            f"{query[0]:.4g} V, {query[1]:.4g} Hz{used}")


def extrapolation_note(x: dict) -> str:
    """The note for one entry of :func:`extrapolated_cells` (shared by invert, track and simulate)."""
    return (f"cell {x['cell']} (identified on {x['identified_V'][0]:.4g}…{x['identified_V'][1]:.4g} V) is used on "
            f"{x['used_V'][0]:.4g}…{x['used_V'][1]:.4g} V: extrapolated")


def _extrapolation(pf: ParamsFile, choices: Sequence[SegmentChoice], u: np.ndarray) -> list[dict]:
    """Used cells driven outside their identification voltage range by more than 2 % of it.

    One entry per cell with the voltage range it is used on (over all segments using it).
    """
    return extrapolated_cells(pf, ((c.index, u[ch.segment.start:ch.segment.stop]) for ch in choices for c in ch.cells))


def extrapolated_cells(pf: ParamsFile, uses) -> list[dict]:
    """Cells driven outside their identification voltage range by more than 2 % of it.

    ``uses``: (cell index, voltages it is applied to) pairs. One entry per cell with the voltage
    range it is used on over all its uses.
    """
    used: dict[int, list[float]] = {}
    for index, seg in uses:
        r = used.setdefault(index, [float("inf"), float("-inf")])
        r[0], r[1] = min(r[0], float(np.min(seg))), max(r[1], float(np.max(seg)))
    out = []
    for i, (ulo, uhi) in sorted(used.items()):
        s = pf.cells[i].scale
        tol = 0.02 * s.u_range
        if ulo < s.u_min - tol or uhi > s.u_max + tol:
            out.append({"cell": pf.cells[i].label, "identified_V": [s.u_min, s.u_max], "used_V": [ulo, uhi]})
    return out


def condition_text(ch: SegmentChoice) -> str:
    """One-line description of the cells used for a segment, e.g. ``40V_10Hz×0.77 + 20V_10Hz×0.23``."""
    return " + ".join(f"{c.label}×{c.weight:.2f}" for c in sorted(ch.cells, key=lambda c: -c.weight))

