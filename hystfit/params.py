"""Parameter specifications: name, unit, bounds, default and meaning of each model parameter.

Bounds may scale with the data: a model builds its table from a :class:`DataScale`
(input/output ranges, sample period), so one command works on µm/V stages and on nm/mV ones.
``--bounds name=lo:hi`` overrides a bound (:func:`apply_bound_overrides`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import ConfigError


@dataclass(frozen=True)
class Param:
    """One model parameter.

    Attributes
    ----------
    name : identifier used in JSON and ``--bounds`` (e.g. ``"w3"``, ``"alpha"``).
    unit : physical unit as text (``"um/V"``, ``"1/V"``, ``"um"``, ``"1"`` for dimensionless).
    lower, upper : search box; ``lower < upper`` is required (never silently swapped).
    default : a sensible starting value inside the box.
    description : one line, the parameter's meaning.
    """

    name: str
    unit: str
    lower: float
    upper: float
    default: float
    description: str = ""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.lower) and np.isfinite(self.upper)):
            raise ConfigError(f"parameter {self.name!r}: bounds must be finite, got [{self.lower}, {self.upper}]")
        if not self.lower < self.upper:
            raise ConfigError(
                f"parameter {self.name!r}: lower bound {self.lower:g} must be below upper bound {self.upper:g}"
            )
        if not self.lower <= self.default <= self.upper:
            object.__setattr__(self, "default", float(min(max(self.default, self.lower), self.upper)))


#: names of a model's output offset parameter (the one :meth:`DataScale.offset_bounds` boxes): the
#: level a per-capture drift offset is measured from (:func:`hystfit.identify.centered_offset`)
OUTPUT_OFFSET_NAMES = ("y0", "d0", "A6")


@dataclass(frozen=True)
class DataScale:
    """Scales of the identification data, from which default bounds are derived.

    All in the captures' units: input in V, output in the capture's output unit, time in s.
    """

    u_min: float
    u_max: float
    y_min: float
    y_max: float
    dt: float
    rate_max: float  # max |du/dt| in V/s
    #: +1 when the output rises with the input (the usual stage), −1 when it falls (an inverted
    #: sensor or a contracting mount): the sign of the pooled input–output covariance. Models
    #: whose gains are constrained to one sign (PI weights, gpi's ρ, fp's E0/E∞) take it from here.
    sign: float = 1.0
    #: duration of the longest capture (s); None in files written before it was recorded
    duration_s: float | None = None
    #: the peak input rate (V/s) of the captures driven by a smooth periodic input (a sine, a raised
    #: cosine, a rising-amplitude sine, a triangle at their stated or detected frequency f: a peak
    #: rate of at most :data:`SMOOTH_DRIVE_RATE` × π·f·range); a capture whose input jumps (steps,
    #: PRBS) does not count. 0 when no capture is driven so; None in files written before it was
    #: recorded (:attr:`rate_max` then stands in, as it did). See
    #: :func:`hystfit.blocks.base.frequency_of_excitation`.
    drive_rate_max: float | None = None
    #: the span of the output that follows the hysteresis (:func:`output_span`): :attr:`y_min`…
    #: :attr:`y_max` without the overshoot and ringing of a stage after a step or a PRBS edge. None
    #: in files written before it was recorded (:attr:`y_min`/:attr:`y_max` then stand in, as they
    #: did). The asymmetry block's middle and half-range come from it.
    y_span_min: float | None = None
    y_span_max: float | None = None

    @property
    def u_range(self) -> float:
        return max(self.u_max - self.u_min, 1e-12)

    @property
    def y_range(self) -> float:
        return max(self.y_max - self.y_min, 1e-12)

    @property
    def y_span(self) -> tuple[float, float]:
        """(:attr:`y_span_min`, :attr:`y_span_max`); the output's range where they were not recorded."""
        if self.y_span_min is None or self.y_span_max is None:
            return self.y_min, self.y_max
        return self.y_span_min, self.y_span_max

    @property
    def u_abs_max(self) -> float:
        return max(abs(self.u_min), abs(self.u_max), 1e-12)

    @property
    def gain(self) -> float:
        """Output range / input range: the natural gain scale (e.g. µm/V)."""
        return self.y_range / self.u_range

    @property
    def input_bias_V(self) -> float:
        """How far the input's range lies from 0 V (V, ≥ 0): :attr:`u_min` for an input that stays
        above 0 V, −:attr:`u_max` for one that stays below, 0 for one through 0 V. A biased drive
        (a sine of ±30 V about 100 V, a stage held at mid-stroke) has 70 V; a drive from or about
        0 V has 0 (and a DAC's few mV above 0 V next to nothing: the scales that use it change
        continuously with it)."""
        return max(self.u_min, -self.u_max, 0.0)

    def offset_bounds(self) -> tuple[float, float]:
        """The search box of a model's output offset (``y0`` and its kin, in the output's unit).

        The output's range widened by its span on either side, and by 2 × :attr:`gain` ×
        :attr:`input_bias_V` more: for a biased input the model's input-proportional part carries
        ≈ gain × the bias (≈ 20 µm at 0.3 µm/V and 70 V), which the offset takes back, and the
        output's own span (≈ 20 µm for ±30 V) is too narrow a margin for it. An input from or
        about 0 V keeps the box it had."""
        extra = self.y_range + 2.0 * self.gain * self.input_bias_V
        return self.y_min - extra, self.y_max + extra

    @classmethod
    def from_arrays(cls, us: Sequence[np.ndarray], ys: Sequence[np.ndarray], dts: Sequence[float],
                    frequencies_Hz: Sequence[float] | None = None) -> "DataScale":
        """The scales of captures given by their inputs ``us`` (V), outputs ``ys`` and sample periods
        ``dts`` (s); ``frequencies_Hz``, the captures' drive frequencies (NaN where none), sets
        :attr:`drive_rate_max` (left None without them)."""
        u_all = np.concatenate([np.asarray(u, float) for u in us])
        y_all = np.concatenate([np.asarray(y, float) for y in ys])
        rate = max(float(np.max(np.abs(np.diff(u)))) / dt if len(u) > 1 else 0.0 for u, dt in zip(us, dts))
        cov = 0.0
        for u, y in zip(us, ys):
            u, y = np.asarray(u, float), np.asarray(y, float)
            if u.size and u.size == y.size:
                cov += float(np.dot(u - u.mean(), y - y.mean()))
        duration = max(len(u) * dt for u, dt in zip(us, dts))
        drive = None if frequencies_Hz is None else smooth_drive_rate(us, dts, frequencies_Hz)
        lo, hi = output_span(us, ys, dts, frequencies_Hz)
        return cls(float(u_all.min()), float(u_all.max()), float(y_all.min()), float(y_all.max()),
                   float(min(dts)), max(rate, 1e-12), -1.0 if cov < 0 else 1.0, float(duration), drive, lo, hi)


#: a capture counts as smoothly driven at its frequency f while its peak input rate is at most this
#: many times that of a sine over its input range at f (π·f·range; a triangle has 2/π of it, a
#: rising-amplitude sine about 1); a step or a PRBS edge exceeds it by orders of magnitude
SMOOTH_DRIVE_RATE = 3.0


def _smooth_drive(u: np.ndarray, dt: float, frequency_Hz: float | None) -> float | None:
    """The peak input rate (V/s) of ``u`` when it is a smooth periodic drive at ``frequency_Hz``
    (:data:`SMOOTH_DRIVE_RATE`), else None."""
    u = np.asarray(u, float)
    f = frequency_Hz
    if f is None or not (np.isfinite(f) and f > 0) or u.size < 2:
        return None
    span = float(np.nanmax(u) - np.nanmin(u))
    rate = float(np.nanmax(np.abs(np.diff(u)))) / dt
    return rate if span > 0 and rate <= SMOOTH_DRIVE_RATE * math.pi * float(f) * span else None


def smooth_drive_rate(us: Sequence[np.ndarray], dts: Sequence[float], frequencies_Hz: Sequence[float]) -> float:
    """The peak input rate (V/s) among the captures whose input is a smooth periodic drive at their
    frequency in ``frequencies_Hz`` (:data:`SMOOTH_DRIVE_RATE`); 0.0 when there is none."""
    rates = [_smooth_drive(u, dt, f) for u, dt, f in zip(us, dts, frequencies_Hz)]
    return max([r for r in rates if r is not None], default=0.0)


#: the samples within this fraction of the input range from the input's lowest or highest value
#: are "at an extreme" (:func:`output_span`); on a sine that is 9 % of each period
EXTREME_INPUT_BAND = 0.02


def output_span(us: Sequence[np.ndarray], ys: Sequence[np.ndarray], dts: Sequence[float],
                frequencies_Hz: Sequence[float] | None = None,
                masks: Sequence[np.ndarray] | None = None) -> tuple[float, float]:
    """The span (lowest, highest) of the output that follows the hysteresis: the output's range
    over the captures driven smoothly (a sine, a raised cosine, a triangle, a rising-amplitude sine
    at its frequency in ``frequencies_Hz``; :data:`SMOOTH_DRIVE_RATE`), widened to the output's
    levels where the input is at its extremes — per capture, the median of the output over its
    samples within :data:`EXTREME_INPUT_BAND` of the input range from the lowest or the highest
    input of all the captures. ``masks``: per capture, the samples to use (default: all); whether a
    capture is driven smoothly is judged on all of its input.

    Why: a stage after the hysteresis overshoots after a step and rings on a PRBS; the output's
    own range then holds excursions the hysteresis — the signal a block after it sees — never
    makes (the blind campaign, seed 9090 at strength 2 with its 600 Hz stage: the 0…60 V PRBS
    spans −24.7…48.6 µm, the raised cosines 0.19…21.2 µm). A smooth drive excites no ringing, so
    its output's range is the hysteresis's span, the start from rest included; the levels at the
    input's extremes add what only the steps or the PRBS reach (a hysteresis output is at its
    extreme where its input is: a play operator at the input's maximum sits at u_max − r whatever
    came before; at the minimum it depends on whether the input has been up before, so a capture
    that starts from rest is lower there once), taken as the median over the time the input dwells
    there — the settled level, whatever the stage rings. Without a smooth capture (steps, PRBS, a capture that jumps onto its
    drive, no drive frequency known) the levels alone give the span.
    """
    us = [np.asarray(u, float) for u in us]
    ys = [np.asarray(y, float) for y in ys]
    freqs = [None] * len(us) if frequencies_Hz is None else list(frequencies_Hz)
    masks = [None] * len(us) if masks is None else list(masks)
    lows, highs, parts = [], [], []
    for u, y, dt, f, m in zip(us, ys, dts, freqs, masks):
        if u.size != y.size:
            continue
        smooth = _smooth_drive(u, dt, f) is not None
        if m is not None:
            u, y = u[m], y[m]
        ok = np.isfinite(u) & np.isfinite(y)
        u, y = u[ok], y[ok]
        if not u.size:
            continue
        parts.append((u, y))
        if smooth:
            lows.append(float(y.min()))
            highs.append(float(y.max()))
    if not parts:
        y_all = np.concatenate(ys)
        return float(np.nanmin(y_all)), float(np.nanmax(y_all))
    u_lo = min(float(u.min()) for u, _ in parts)
    u_hi = max(float(u.max()) for u, _ in parts)
    band = EXTREME_INPUT_BAND * (u_hi - u_lo)
    for u, y in parts:
        for at in (u <= u_lo + band, u >= u_hi - band):
            if at.any():
                level = float(np.median(y[at]))
                lows.append(level)
                highs.append(level)
    return min(lows), max(highs)


#: A value within this fraction of its search width from a bound is "at the bound": the search
#: stopped there (optimizers that clip or reflect land a few 1e-4 of the width inside), so the
#: data did not determine it, it has no standard error, and the bound may need widening.
AT_BOUND_RTOL = 1e-3


def bound_side(value: float, lower: float, upper: float, rtol: float = AT_BOUND_RTOL) -> str | None:
    """``"lower"``/``"upper"`` when ``value`` lies within ``rtol × (upper − lower)`` of that bound, else None."""
    tol = rtol * (upper - lower)
    if value - lower <= tol:
        return "lower"
    if upper - value <= tol:
        return "upper"
    return None


#: the placeholder for the capture's output unit in parameter units (``"out/V"``) and result keys
OUTPUT_UNIT_PLACEHOLDER = "out"


def with_output_unit(text: str, unit: str) -> str:
    """A unit text with the placeholder replaced: ``with_output_unit("out/V", "um")`` → ``"um/V"``."""
    return text.replace(OUTPUT_UNIT_PLACEHOLDER, unit)


def parse_bound_overrides(items: Sequence[str]) -> dict[str, tuple[float, float]]:
    """Parse ``["alpha=0.1:10", "w0=0:2"]`` into ``{"alpha": (0.1, 10.0), ...}``."""
    out: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, rng = item.partition("=")
        lo, sep2, hi = rng.partition(":")
        try:
            if not (sep and sep2 and name.strip()):
                raise ValueError
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise ConfigError(f"--bounds {item!r}: expected NAME=LOWER:UPPER, e.g. alpha=0.1:10") from None
    return out


def apply_bound_overrides(params: Sequence[Param], overrides: Mapping[str, tuple[float, float]]) -> tuple[Param, ...]:
    """Return ``params`` with bounds replaced by ``overrides`` (unknown names are an error)."""
    by_name = {p.name: p for p in params}
    for name in overrides:
        if name not in by_name:
            raise ConfigError(
                f"--bounds: unknown parameter {name!r}; this model has {', '.join(by_name)}"
            )
    out = []
    for p in params:
        if p.name in overrides:
            lo, hi = overrides[p.name]
            if not lo < hi:
                raise ConfigError(f"--bounds {p.name}={lo:g}:{hi:g}: lower must be below upper")
            p = replace(p, lower=lo, upper=hi, default=min(max(p.default, lo), hi))
        out.append(p)
    return tuple(out)


def structure_of(obj) -> dict[str, Any]:
    """The constructor arguments of a frozen dataclass (a model or a block), JSON-serialisable:
    tuples as lists; fields that are not constructor arguments or not compared are left out."""
    out = {}
    for f in dataclasses.fields(obj):
        if not f.init or not f.compare:
            continue
        v = getattr(obj, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def structure_kwargs(cls, data: dict[str, Any], unknown_message) -> dict[str, Any]:
    """The keyword arguments that rebuild ``cls`` from :func:`structure_of`'s ``data`` (lists as
    tuples). Keys that are not fields of ``cls``: ConfigError(``unknown_message(unknown, names)``)."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(unknown_message(unknown, names))
    return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
