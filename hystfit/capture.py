"""The in-memory capture: one voltage → displacement measurement, validated and trimmed."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np


#: how an output unit is written in words, on axes and in reports (the JSON's names keep the code:
#: ``rmse_um``); the one table every module uses (:func:`display_unit`)
UNIT_DISPLAY = {"um": "µm", "nm": "nm", "mm": "mm", "m": "m", "urad": "µrad", "mrad": "mrad", "rad": "rad",
                "deg": "°"}


def display_unit(unit: str) -> str:
    """A unit as written in words: ``"um"`` → ``"µm"``, ``"nm"`` → ``"nm"``, unknown units unchanged."""
    return UNIT_DISPLAY.get(unit, unit)


class UniformSamples:
    """The sample count and rate of a uniformly sampled record (a :class:`Capture`, a feedforward
    target): ``dt`` is its sample period (s), ``samples_field`` names the (N,) array that counts."""

    samples_field: ClassVar[str] = "u"
    dt: float

    @property
    def n(self) -> int:
        return int(getattr(self, self.samples_field).shape[0])

    @property
    def fs(self) -> float:
        return 1.0 / self.dt


@dataclass(frozen=True, eq=False)
class Capture(UniformSamples):
    """One validated capture.

    Attributes
    ----------
    source : file path (as given) plus, for multi-capture files, nothing else; used in messages.
    t : (N,) time in seconds, starting at 0 after the idle trim, uniformly sampled.
    u : (N,) input voltage in volts.
    y : (N,) measured output in ``y_unit`` (None for a target-only/input-only file).
    y_unit : output unit: ``"um"`` (default when the column has no suffix), ``"nm"``, ``"mm"``, ``"m"``.
    dt : sample period in seconds.
    trimmed_s : length of the leading idle segment that was removed (s), 0 when none.
    trimmed_samples : number of samples removed at the start.
    amplitude_V, frequency_Hz : the operating condition (tidy values, see :mod:`hystfit.conditions`).
    condition_source : ``"detected"``, ``"column"`` or ``"option"``.
    notes : human-readable remarks made while loading (trim, dropped rows, assumed unit, ...).
    warmup_samples : leading samples simulated but left out of fits and their metrics (``--warmup``).
    """

    source: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray | None
    dt: float
    y_unit: str = "um"
    trimmed_s: float = 0.0
    trimmed_samples: int = 0
    amplitude_V: float = float("nan")
    frequency_Hz: float = float("nan")
    condition_source: str = "detected"
    notes: tuple[str, ...] = field(default_factory=tuple)
    warmup_samples: int = 0

    @property
    def duration_s(self) -> float:
        return self.n * self.dt

    @property
    def condition(self) -> tuple[float, float]:
        return (self.amplitude_V, self.frequency_Hz)

    @property
    def name(self) -> str:
        return Path(self.source).name
