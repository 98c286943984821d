"""The block interface: a physical effect that follows any hysteresis model.

A *block* maps the signal x coming out of the model before it (the base hysteresis model, or
the blocks written before it in a model expression such as ``pi+creep+delay``) to the signal
after it. Each block is one file of this package and serves three users with one implementation:

- **composite models** (:class:`hystfit.models.composite.Composite`): :meth:`Block.params` is the
  block's part of the parameter vector θ (units, data-scaled bounds), :meth:`Block.apply_population`
  applies it to a whole population at once (θ (P, k), x (P, N) → (P, N)), :meth:`Block.invert`
  undoes it for feedforward, :meth:`Block.step_init`/:meth:`Block.step` advance it one sample for
  closed-loop simulation;
- **diagnose** (:mod:`hystfit.diagnose`): the :class:`hystfit.effects.Effect` interface it inherits
  (searched parameters φ, linear coefficients solved exactly, evidence text);
- **the virtual actuator** (:mod:`hystfit.synth`), whose effect switches call the same functions.

In θ a block's entries are its searched parameters φ followed by its shared linear coefficients
(the :class:`hystfit.effects.Effect` layout), so ``apply_population(x, concat(φ, a))`` equals
``Effect.apply(x, view, φ, a, [])`` (checked by the block contract tests). A *nuisance* block
(drift) has no entry in θ: its per-capture coefficients are projected out of every capture's
residual by the identification objective (:meth:`Block.nuisance_basis`).

Units: time s, input V, output in the capture's unit (``out`` in parameter units).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any, ClassVar

import numpy as np

from ..effects import Effect
from ..errors import ConfigError
from ..params import DataScale, Param, structure_kwargs, structure_of


class Block(Effect):
    """Base class of every block (subclasses are frozen dataclasses registered on
    :data:`hystfit.registry.blocks`)."""

    #: one line for ``hystfit models`` and the docs
    reference: ClassVar[str] = ""
    #: True: the block has no θ entries; its per-capture regressors are projected out of the residual
    nuisance: ClassVar[bool] = False
    #: True: diagnose tests it as a candidate unmodelled effect
    candidate: ClassVar[bool] = True

    # ------------------------------------------------------------------ structure
    def prepare(self, captures) -> "Block":
        """Identify structure shared by every operating condition from all captures (the ``lti``
        block's state space); the default has none and returns ``self``."""
        return self

    def shares_structure(self) -> bool:
        """Whether :meth:`prepare` may identify shared structure (the block's class overrides it)."""
        return type(self).prepare is not Block.prepare

    def adapt(self, scale: DataScale) -> "Block":
        """Fill data-dependent structure (search ranges, time constants, normalisation) from the
        identification data's scale; the adapted block is what gets saved."""
        return self

    def structure(self) -> dict[str, Any]:
        """JSON-serialisable constructor arguments (the inverse of :meth:`from_structure`)."""
        return structure_of(self)

    @classmethod
    def from_structure(cls, data: dict[str, Any]) -> "Block":
        kwargs = structure_kwargs(cls, data, lambda unknown, names: (
            f"block {cls.name!r}: unknown option(s) {sorted(unknown)}; valid: {', '.join(sorted(names))}"))
        try:
            return cls(**kwargs)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"block {cls.name!r}: invalid options {data!r} ({exc})") from None

    # ------------------------------------------------------------------ parameters
    @abstractmethod
    def params(self, scale: DataScale) -> tuple[Param, ...]:
        """The block's entries of θ (searched φ, then shared linear coefficients), unprefixed."""

    @property
    def n_theta(self) -> int:
        """Number of θ entries (searched + shared linear)."""
        lo, _ = self.searched_bounds()
        return int(lo.size + self.layout()[0])

    # ------------------------------------------------------------------ simulation
    @abstractmethod
    def apply_population(self, x: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
        """The block's output for a population: x (P, N), θ (P, k) → (P, N) (x is not modified)."""

    def nuisance_basis(self, n: int, dt: float) -> np.ndarray | None:
        """Per-capture regressors (n, k) projected out of the residual (nuisance blocks only)."""
        return None

    def natural_frequency_Hz(self, theta: np.ndarray) -> float | None:
        """f_n (Hz) of the block's second-order stage for θ (k,), None without one
        (:meth:`hystfit.models.base.Model.natural_frequency_Hz`)."""
        return None

    # ------------------------------------------------------------------ inverse and stepping
    @abstractmethod
    def invert(self, theta: np.ndarray, y: np.ndarray, dt: float) -> np.ndarray:
        """The block's input x (N,) whose output follows ``y`` (N,): θ (k,)."""

    def step_init(self, theta: np.ndarray, x0: float, dt: float) -> np.ndarray:
        """The block's memory (S,) at rest at input ``x0`` (its output is then the block applied to
        a constant ``x0``)."""
        return np.empty(0)

    def step(self, theta: np.ndarray, state: np.ndarray, x_new: np.ndarray, dt: float
             ) -> tuple[np.ndarray, np.ndarray]:
        """Advance one sample for candidate inputs x_new (C,): outputs (C,) and states (C, S).

        Stepping a whole signal from :meth:`step_init` at its first sample reproduces
        :meth:`apply_population` from the second sample on (contract-tested)."""
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        y = self.apply_population(x_new[:, None], np.repeat(np.atleast_2d(theta), x_new.size, axis=0), dt)[:, 0]
        return y, np.zeros((x_new.size, 0))

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def population(theta: np.ndarray, k: int, P: int) -> np.ndarray:
        theta = np.asarray(theta, dtype=np.float64)
        theta = theta.reshape(-1, k) if theta.size else np.zeros((P, 0))
        if theta.shape[0] == 1 and P > 1:
            theta = np.repeat(theta, P, axis=0)
        return theta


def frequency_of_excitation(scale: DataScale) -> float:
    """The frequency (Hz) of a sine with the captures' input range and the peak rate of their
    smooth periodic drives (:attr:`DataScale.drive_rate_max`): rate/(π·range) — for a periodic
    drive its fundamental, for a rising-amplitude sine the drive frequency. NaN when no capture
    is driven so (broadband or step captures only). The stage blocks' search ranges start from it.

    A step or a PRBS edge does not count: its rate made this thousands of Hz, and a stage's
    resonance then fell below the search range (where the data scale predates the field, its peak
    rate over all captures still stands in, as it did).
    """
    rate = scale.rate_max if scale.drive_rate_max is None else scale.drive_rate_max
    return float(rate / (np.pi * scale.u_range)) if rate > 0 else float("nan")


def scale_of_views(views) -> DataScale:
    """The :class:`DataScale` of diagnose's capture views (their inputs, outputs, sample periods and
    drive frequencies), as identify makes it of the same captures: a block's structure set from
    the data by :meth:`~hystfit.effects.Effect.configure` (diagnose) is then the one
    :meth:`Block.adapt` sets (identify, the recommended model). Before, diagnose counted periodic
    captures only: on rising-amplitude sines a delay was searched up to 5 ms where the recommended
    model's box ended at 0.42 ms, and the hand-over clipped a 0.46 ms delay (a blind test).

    Views without their input (``CaptureView.u`` None, a caller that has none) stand for a periodic
    drive at their frequency when periodic and for no drive otherwise (as diagnose read them
    before)."""
    us = [v.u if v.u is not None else _periodic_stand_in(v) for v in views]
    return DataScale.from_arrays(us, [v.y for v in views], [v.dt for v in views],
                                 [v.frequency_Hz if v.u is not None or v.periodic else float("nan") for v in views])


def _periodic_stand_in(view) -> np.ndarray:
    """The input :func:`scale_of_views` reads where a view has none: a raised cosine 0…1 at the
    view's frequency when periodic (so the excitation frequency is the largest such frequency,
    exactly), else a constant (no drive)."""
    t = np.asarray(view.t, float)
    f = view.frequency_Hz
    if not (view.periodic and np.isfinite(f) and f > 0):
        return np.zeros_like(t)
    return 0.5 * (1.0 - np.cos(2.0 * np.pi * f * t))


def captures_at_one_rate(captures, who: str, advice: str = "") -> list:
    """The captures with a measured output, checked to share one sample period (the shared
    structure identified from them — a linear stage — is discrete at that rate).

    Raises ConfigError "``who``: the captures have different sample periods (…); resample them to
    one rate``advice``" otherwise.
    """
    caps = [c for c in captures if c.y is not None]
    dts = {round(c.dt, 12) for c in caps}
    if len(dts) != 1:
        raise ConfigError(f"{who}: the captures have different sample periods ({sorted(dts)} s); "
                          f"resample them to one rate{advice}")
    return caps
