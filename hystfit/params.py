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

    @property
    def u_range(self) -> float:
        return max(self.u_max - self.u_min, 1e-12)

    @property
    def y_range(self) -> float:
        return max(self.y_max - self.y_min, 1e-12)

    @property
    def u_abs_max(self) -> float:
        return max(abs(self.u_min), abs(self.u_max), 1e-12)

    @property
    def gain(self) -> float:
        """Output range / input range: the natural gain scale (e.g. µm/V)."""
        return self.y_range / self.u_range

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
        return cls(float(u_all.min()), float(u_all.max()), float(y_all.min()), float(y_all.max()),
                   float(min(dts)), max(rate, 1e-12), -1.0 if cov < 0 else 1.0, float(duration), drive)


#: a capture counts as smoothly driven at its frequency f while its peak input rate is at most this
#: many times that of a sine over its input range at f (π·f·range; a triangle has 2/π of it, a
#: rising-amplitude sine about 1); a step or a PRBS edge exceeds it by orders of magnitude
SMOOTH_DRIVE_RATE = 3.0


def smooth_drive_rate(us: Sequence[np.ndarray], dts: Sequence[float], frequencies_Hz: Sequence[float]) -> float:
    """The peak input rate (V/s) among the captures whose input is a smooth periodic drive at their
    frequency in ``frequencies_Hz`` (:data:`SMOOTH_DRIVE_RATE`); 0.0 when there is none."""
    best = 0.0
    for u, dt, f in zip(us, dts, frequencies_Hz):
        u = np.asarray(u, float)
        if f is None or not (np.isfinite(f) and f > 0) or u.size < 2:
            continue
        span = float(np.nanmax(u) - np.nanmin(u))
        rate = float(np.nanmax(np.abs(np.diff(u)))) / dt
        if span > 0 and rate <= SMOOTH_DRIVE_RATE * math.pi * float(f) * span:
            best = max(best, rate)
    return best


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
