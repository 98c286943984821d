"""The virtual actuator: a simulated piezo stage with switchable non-ideal effects, and excitations.

A :class:`Plant` is a classical Prandtl–Ishlinskii (PI) hysteresis (paper 003 eq. 1–3, as pinned
down in ``../shared/papers/README.md``) followed by optional effects (:class:`Effects`), applied in
this fixed order::

    u ─► PI hysteresis ─► asymmetry ─► creep ─► dynamics ─► delay ─► drift ─► (+offset, unit)
      ─► sensor noise ─► quantization ─► y

Every effect is off in :meth:`Effects.none` (then ``y = Σ_j w_j F_{r_j}[u] + offset`` exactly) and
each has a realistic default strength (:meth:`Effects.only`, :meth:`Effects.from_names`).
:meth:`Plant.default` is a documented stage comparable to the ones of papers 000 (second-order
linear subsystem after the hysteresis, P-721-like) and 002 (0→A→0 excitation, 20/40/60 V).

The excitation generators return ``(t_s, u_V)`` float64 arrays; random ones take a seed and use
their own ``np.random.default_rng(seed)`` (never the global RNG). :func:`make_campaign` writes
paper 002's campaign (§3.1: raised cosine 0→A→0, A ∈ {20, 40, 60} V, f ∈ {10, …, 80} Hz, five
cycles) plus two broadband captures. This module never prints.

Units: time s, voltage V, displacement µm inside the plant (``*_um`` fields); the measurement is
converted to ``Plant.output_unit`` at the end (sensor noise and LSB are converted with it).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, replace
from io import BytesIO
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from .errors import ConfigError
from .io import atomic_write_bytes
from .blocks.asymmetry import bow
from .blocks.creep import Creep
from .blocks.delay import fractional_delay
from .blocks.dynamics import Dynamics
from .models._kernels import play_matrix

__all__ = [
    "EFFECT_NAMES",
    "EXCITATIONS",
    "OUTPUT_UNITS",
    "Effects",
    "Plant",
    "raised_cosine",
    "sine",
    "triangle",
    "prbs",
    "multisine",
    "steps",
    "make_excitation",
    "simulate_plant",
    "simulate_plant_components",
    "write_capture",
    "campaign_conditions",
    "make_campaign",
]

#: Effect names, in the order they are applied.
EFFECT_NAMES: tuple[str, ...] = (
    "asymmetry",
    "creep",
    "dynamics",
    "delay",
    "drift",
    "noise",
    "quantization",
)

#: Output units and their factor from µm.
OUTPUT_UNITS: dict[str, float] = {"um": 1.0, "nm": 1e3, "mm": 1e-3, "m": 1e-6}

#: Excitation names accepted by :func:`make_excitation` (and the CLI).
EXCITATIONS: tuple[str, ...] = ("raised-cosine", "sine", "triangle", "rising-sine", "prbs", "multisine", "steps")

#: Effects of :meth:`Plant.default`.
DEFAULT_PLANT_EFFECTS: tuple[str, ...] = ("creep", "dynamics", "noise", "quantization")


# ----------------------------------------------------------------------------------------------
# Excitations
# ----------------------------------------------------------------------------------------------


def _check_positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ConfigError(f"{name} must be a finite number > 0. Got {value!r} instead.")
    return value


def _check_nonneg(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value < 0.0:
        raise ConfigError(f"{name} must be a finite number >= 0. Got {value!r} instead.")
    return value


def _periodic_time(frequency_Hz: float, cycles: float, fs_Hz: float) -> np.ndarray:
    """Sample times 0 … cycles/f inclusive (the last sample is the end of the last cycle when
    fs/f·cycles is an integer), spaced 1/fs."""
    frequency_Hz = _check_positive("frequency_Hz", frequency_Hz)
    cycles = _check_positive("cycles", cycles)
    fs_Hz = _check_positive("fs_Hz", fs_Hz)
    n = int(math.floor(cycles * fs_Hz / frequency_Hz + 1e-9)) + 1
    if n < 3:
        raise ConfigError(
            f"{cycles:g} cycles at {frequency_Hz:g} Hz give fewer than 3 samples at fs {fs_Hz:g} Hz: "
            "raise fs_Hz or cycles."
        )
    return np.arange(n, dtype=np.float64) / fs_Hz


def _duration_time(duration_s: float, fs_Hz: float) -> np.ndarray:
    duration_s = _check_positive("duration_s", duration_s)
    fs_Hz = _check_positive("fs_Hz", fs_Hz)
    n = int(round(duration_s * fs_Hz))
    if n < 3:
        raise ConfigError(f"duration {duration_s:g} s at fs {fs_Hz:g} Hz gives fewer than 3 samples.")
    return np.arange(n, dtype=np.float64) / fs_Hz


def _periodic_wave(amplitude_V: float, frequency_Hz: float, cycles: float, fs_Hz: float,
                   shape: Callable[[np.ndarray, float], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The time base t ∈ [0, cycles/f] of a periodic excitation and ``u = shape(t, A)`` on it
    (A checked to be ≥ 0)."""
    amplitude_V = _check_nonneg("amplitude_V", amplitude_V)
    t = _periodic_time(frequency_Hz, cycles, fs_Hz)
    return t, shape(t, amplitude_V)


def raised_cosine(
    amplitude_V: float, frequency_Hz: float, cycles: float = 5, fs_Hz: float = 10_000
) -> tuple[np.ndarray, np.ndarray]:
    """Raised cosine 0 → A → 0 (paper 002 §3.1): u = A/2 · (1 − cos 2πft), t ∈ [0, cycles/f].

    Parameters
    ----------
    amplitude_V : peak voltage A (V), ≥ 0; the input spans 0 … A.
    frequency_Hz : f (Hz).  cycles : number of periods (5 in 002).  fs_Hz : sampling rate (Hz).
    """
    return _periodic_wave(amplitude_V, frequency_Hz, cycles, fs_Hz,
                          lambda t, a: 0.5 * a * (1.0 - np.cos(2.0 * np.pi * frequency_Hz * t)))


def rising_sine(
    amplitude_V: float, frequency_Hz: float, cycles: float = 50, fs_Hz: float = 10_000,
    start_fraction: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Rising-amplitude raised cosine: every cycle starts at the lower rail 0 V and its crest rises
    linearly with time from ``start_fraction``·A to A, reached at the last cycle's peak,
    u = c(t)/2 · (1 − cos 2πft), c(t) = A·min(s + (1 − s)·t/T', 1), T' = (cycles − ½)/f.

    The excitation of rig captures that sweep the loop size in one recording (small loops first,
    the largest last): every amplitude is present, but not stationary within the capture.
    """
    amplitude_V = _check_nonneg("amplitude_V", amplitude_V)
    if not 0.0 <= start_fraction <= 1.0:
        raise ConfigError(f"start_fraction must lie in [0, 1]. Got {start_fraction!r}.")

    def shape(t: np.ndarray, a: float) -> np.ndarray:
        T = max(cycles - 0.5, 0.5) / frequency_Hz
        crest = a * np.minimum(start_fraction + (1.0 - start_fraction) * t / T, 1.0)
        return 0.5 * crest * (1.0 - np.cos(2.0 * np.pi * frequency_Hz * t))

    return _periodic_wave(amplitude_V, frequency_Hz, cycles, fs_Hz, shape)


def sine(
    amplitude_V: float, frequency_Hz: float, cycles: float = 5, fs_Hz: float = 10_000, offset_V: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Sine u = offset_V + A sin 2πft (bipolar about ``offset_V``), t ∈ [0, cycles/f]."""
    return _periodic_wave(amplitude_V, frequency_Hz, cycles, fs_Hz,
                          lambda t, a: float(offset_V) + a * np.sin(2.0 * np.pi * frequency_Hz * t))


def triangle(
    amplitude_V: float, frequency_Hz: float, cycles: float = 5, fs_Hz: float = 10_000, offset_V: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle 0 → A → 0 (the raised cosine's constant-rate counterpart): u = offset_V + A·(1 −
    |1 − 2·frac(ft)|), so |du/dt| = 2Af everywhere; t ∈ [0, cycles/f]."""
    def shape(t: np.ndarray, a: float) -> np.ndarray:
        phase = np.mod(frequency_Hz * t, 1.0)
        return float(offset_V) + a * (1.0 - np.abs(1.0 - 2.0 * phase))

    return _periodic_wave(amplitude_V, frequency_Hz, cycles, fs_Hz, shape)


def prbs(
    amplitude_V: float,
    fs_Hz: float = 10_000,
    duration_s: float = 3.0,
    clock_Hz: float = 2_500.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Random binary sequence with levels 0 and A, a new random bit every 1/clock_Hz seconds.

    Not smoothed: its power spectrum is A²/4 · sinc²(f/clock) (first null at the clock frequency,
    −3 dB at ≈ 0.44·clock), so the default clock 2.5 kHz is broadband to ≈ 1.1 kHz and still
    excites a 1–1.5 kHz resonance. The first bit is 0 V (the stage starts at rest). Bits come from
    ``np.random.default_rng(seed)``; this is a seeded random binary signal, not an LFSR m-sequence.
    """
    amplitude_V = _check_nonneg("amplitude_V", amplitude_V)
    clock_Hz = _check_positive("clock_Hz", clock_Hz)
    t = _duration_time(duration_s, fs_Hz)
    if clock_Hz > fs_Hz:
        raise ConfigError(f"clock_Hz ({clock_Hz:g}) must not exceed fs_Hz ({fs_Hz:g}).")
    rng = np.random.default_rng(seed)
    bit_index = np.floor(t * clock_Hz + 1e-9).astype(np.int64)
    bits = rng.integers(0, 2, size=int(bit_index[-1]) + 1)
    bits[0] = 0
    u = amplitude_V * bits[bit_index].astype(np.float64)
    return t, u


def multisine_frequencies(max_frequency_Hz: float, duration_s: float, count: int = 40) -> np.ndarray:
    """``count`` log-spaced frequencies from 1/duration to ``max_frequency_Hz``, each snapped to a
    multiple of 1/duration (so the multisine is periodic in the capture), duplicates removed."""
    max_frequency_Hz = _check_positive("max_frequency_Hz", max_frequency_Hz)
    duration_s = _check_positive("duration_s", duration_s)
    f0 = 1.0 / duration_s
    if max_frequency_Hz < f0:
        raise ConfigError(
            f"multisine: the highest frequency ({max_frequency_Hz:g} Hz) is below 1/duration "
            f"({f0:g} Hz); raise --frequency or --duration."
        )
    k = np.unique(np.round(np.geomspace(1.0, max_frequency_Hz / f0, int(count))).astype(np.int64))
    return k.astype(np.float64) * f0


def multisine(
    amplitude_V: float,
    freqs_Hz: Sequence[float],
    fs_Hz: float = 10_000,
    duration_s: float = 3.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Sum of equal-amplitude sines at ``freqs_Hz`` with random phases (uniform in [0, 2π) from
    ``np.random.default_rng(seed)``), scaled affinely so that u spans exactly 0 … A."""
    amplitude_V = _check_nonneg("amplitude_V", amplitude_V)
    fs_Hz = _check_positive("fs_Hz", fs_Hz)
    freqs = np.asarray(freqs_Hz, dtype=np.float64).ravel()
    if freqs.size == 0 or not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ConfigError("multisine: freqs_Hz must be a non-empty list of finite frequencies > 0.")
    if np.any(freqs >= fs_Hz / 2):
        raise ConfigError(f"multisine: every frequency must be below fs/2 = {fs_Hz / 2:g} Hz.")
    t = _duration_time(duration_s, fs_Hz)
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=freqs.size)
    s = np.zeros_like(t)
    for f, p in zip(freqs, phases):
        s += np.sin(2.0 * np.pi * f * t + p)
    span = s.max() - s.min()
    u = amplitude_V * (s - s.min()) / span if span > 0 else np.zeros_like(t)
    return t, u


def steps(
    levels_V: Sequence[float], hold_s: float | Sequence[float] = 1.5, fs_Hz: float = 10_000
) -> tuple[np.ndarray, np.ndarray]:
    """Step-and-hold: u = levels_V[i] for hold_s[i] seconds, one level after the other.

    ``hold_s`` is one duration for every level or one per level (s).
    """
    fs_Hz = _check_positive("fs_Hz", fs_Hz)
    levels = np.asarray(levels_V, dtype=np.float64).ravel()
    if levels.size == 0 or not np.all(np.isfinite(levels)):
        raise ConfigError("steps: levels_V must be a non-empty list of finite voltages.")
    holds = np.broadcast_to(np.asarray(hold_s, dtype=np.float64), levels.shape)
    if holds.shape != levels.shape:
        raise ConfigError("steps: hold_s must be one duration or one per level.")
    counts = [int(round(_check_positive("hold_s", h) * fs_Hz)) for h in holds]
    if min(counts) < 1:
        raise ConfigError("steps: every hold must last at least one sample.")
    u = np.repeat(levels, counts)
    t = np.arange(u.size, dtype=np.float64) / fs_Hz
    return t, u


#: Step pattern (fractions of the amplitude) used by the campaign and ``make_excitation("steps")``:
#: rest, half, full (major ascent), a third (descent), three quarters (minor loop), rest.
STEP_FRACTIONS: tuple[float, ...] = (0.0, 0.5, 1.0, 1.0 / 3.0, 0.75, 0.0)
#: Length of the leading rest at 0 V of the step pattern (s).
STEP_LEAD_S = 0.2


def step_pattern(amplitude_V: float, duration_s: float = 7.7, fs_Hz: float = 10_000):
    """:data:`STEP_FRACTIONS` × A: a 0.2 s rest, then five levels sharing the remaining time."""
    amplitude_V = _check_nonneg("amplitude_V", amplitude_V)
    duration_s = _check_positive("duration_s", duration_s)
    n_held = len(STEP_FRACTIONS) - 1
    hold = (duration_s - STEP_LEAD_S) / n_held
    if hold <= 0:
        raise ConfigError(f"steps: duration_s must exceed {STEP_LEAD_S} s.")
    holds = (STEP_LEAD_S,) + (hold,) * n_held
    return steps([amplitude_V * f for f in STEP_FRACTIONS], holds, fs_Hz)


def make_excitation(
    kind: str,
    amplitude_V: float,
    frequency_Hz: float | None = None,
    *,
    cycles: float = 5,
    fs_Hz: float = 10_000,
    duration_s: float | None = None,
    seed: int = 0,
    offset_V: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """One excitation by name (see :data:`EXCITATIONS`), with the meaning of the shared options:

    - ``raised-cosine``, ``sine``, ``triangle``: ``frequency_Hz`` required, ``cycles`` periods.
    - ``rising-sine``: :func:`rising_sine`, a raised cosine whose crest rises linearly from 2 % of
      ``amplitude_V`` to ``amplitude_V`` over ``cycles`` periods (``frequency_Hz`` required).
    - ``prbs``: ``frequency_Hz`` = bit clock (default 2.5 kHz), ``duration_s`` (default 3 s).
    - ``multisine``: ``frequency_Hz`` = highest component (default 1 kHz), 40 log-spaced
      components (:func:`multisine_frequencies`), ``duration_s`` (default 3 s).
    - ``steps``: :func:`step_pattern`, ``duration_s`` total (default 7.7 s: 1.5 s per level).
    """
    kind = kind.strip().lower().replace("_", "-")
    if kind in ("raised-cosine", "sine", "triangle", "rising-sine"):
        if frequency_Hz is None:
            raise ConfigError(f"excitation {kind!r} needs a frequency (--frequency HZ).")
        if kind == "rising-sine":
            return rising_sine(amplitude_V, frequency_Hz, cycles, fs_Hz)
        if kind == "raised-cosine":
            return raised_cosine(amplitude_V, frequency_Hz, cycles, fs_Hz)
        fn = sine if kind == "sine" else triangle
        return fn(amplitude_V, frequency_Hz, cycles, fs_Hz, offset_V=offset_V)
    if kind == "prbs":
        return prbs(amplitude_V, fs_Hz, duration_s or 3.0, frequency_Hz or 2_500.0, seed)
    if kind == "multisine":
        duration = duration_s or 3.0
        freqs = multisine_frequencies(frequency_Hz or 1_000.0, duration)
        return multisine(amplitude_V, freqs, fs_Hz, duration, seed)
    if kind == "steps":
        return step_pattern(amplitude_V, duration_s or 7.7, fs_Hz)
    raise ConfigError(f"unknown excitation {kind!r}; choose one of: {', '.join(EXCITATIONS)}.")


# ----------------------------------------------------------------------------------------------
# Effects and plant
# ----------------------------------------------------------------------------------------------


def _as_float_tuple(values: Iterable[float]) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(values, dtype=np.float64).ravel())


@dataclass(frozen=True)
class Effects:
    """Non-ideal effects of the virtual actuator: an on/off flag and strength parameters for each.

    The parameter defaults are the realistic strengths used by :meth:`Plant.default` and
    :meth:`only` (strength 1); every flag defaults to off, so ``Effects()`` is :meth:`none`.
    Displacements are in µm (converted with the measurement to ``Plant.output_unit``).

    Attributes
    ----------
    asymmetry : bool
        Static output bow z ← z + a₂·z·(z − s)/s applied to the hysteresis output z (offset
        excluded). It keeps z = 0 and z = s fixed and bends the curve in between by up to
        −a₂·s/4 (at z = s/2); a₂ < 0 is saturating (concave). It breaks the point symmetry of PI
        loops, so ascending and descending branches differ in shape. Monotone for |a₂| < 1.
    asymmetry_a2 : float
        a₂, dimensionless. Default −0.12 (+0.63 µm bow at z = s/2 for s = 21 µm).
    asymmetry_span_um : float
        s (µm), the output range the bow refers to. Default 21 µm (the default plant's hysteresis
        output reaches 20.7 µm at 60 V, offset excluded).
    creep : bool
        Sum of first-order viscoelastic (Kelvin–Voigt) creep terms driven by the (bowed)
        hysteresis output z: y = z + Σᵢ gᵢ xᵢ, τᵢ ẋᵢ = z − xᵢ, xᵢ(0) = z(0) (at rest).
        After a step Δz the output keeps moving by Δz·Σ gᵢ(1 − e^{−t/τᵢ}); with one term per
        decade and equal gains that is ≈ g per decade of time: logarithmic-like creep.
        The quasi-static gain grows by the factor 1 + Σ gᵢ.
    creep_tau_s : tuple of float
        τᵢ (s). Default (0.01, 0.1, 1, 10).
    creep_gain : tuple of float
        gᵢ, fraction of the step. Default 0.01 each (1 % per decade, 4 % in total).
    dynamics : bool
        Second-order stage y'' + 2ζω_n y' + ω_n² y = ω_n² z (paper 000's linear subsystem, unit DC
        gain), solved exactly in discrete time: bilinear transform prewarped at ω_n
        (the ``dynamics`` block, :mod:`hystfit.blocks.dynamics`), starting at rest at z(0).
    dynamics_fn_Hz : float
        Natural frequency f_n = ω_n/2π (Hz). Default 1200 Hz.
    dynamics_zeta : float
        Damping ratio ζ. Default 0.15 (phase lag ≈ 2ζ f/f_n rad: 1.1° at 80 Hz).
    delay : bool
        Pure time delay y(t) ← y(t − T_d), fractional samples by linear interpolation; the first
        value is held for t < T_d.
    delay_s : float
        T_d (s). Default 150 µs (1.5 samples at 10 kHz: amplifier plus sensor electronics).
    drift : bool
        Slow thermal drift, not driven by the input: y ← y + v·(t − t₀) + D·sin(2π(t − t₀)/P).
    drift_rate_um_per_s : float
        v (µm/s). Default 0.01 µm/s.
    drift_amplitude_um : float
        D (µm). Default 0.02 µm.
    drift_period_s : float
        P (s). Default 300 s (a five-minute thermal cycle).
    noise : bool
        Additive white Gaussian sensor noise, σ, from ``np.random.default_rng(seed)``.
    noise_sigma_um : float
        σ (µm). Default 0.008 µm.
    quantization : bool
        Sensor quantization y ← LSB·round(y/LSB), after the noise (the ADC sees the noisy signal).
    quantization_lsb_um : float
        LSB (µm). Default 0.001 µm (1 nm).
    """

    asymmetry: bool = False
    asymmetry_a2: float = -0.12
    asymmetry_span_um: float = 21.0
    creep: bool = False
    creep_tau_s: tuple[float, ...] = (0.01, 0.1, 1.0, 10.0)
    creep_gain: tuple[float, ...] = (0.01, 0.01, 0.01, 0.01)
    dynamics: bool = False
    dynamics_fn_Hz: float = 1200.0
    dynamics_zeta: float = 0.15
    delay: bool = False
    delay_s: float = 150e-6
    drift: bool = False
    drift_rate_um_per_s: float = 0.01
    drift_amplitude_um: float = 0.02
    drift_period_s: float = 300.0
    noise: bool = False
    noise_sigma_um: float = 0.008
    quantization: bool = False
    quantization_lsb_um: float = 0.001

    def __post_init__(self) -> None:
        object.__setattr__(self, "creep_tau_s", _as_float_tuple(self.creep_tau_s))
        object.__setattr__(self, "creep_gain", _as_float_tuple(self.creep_gain))
        if len(self.creep_tau_s) != len(self.creep_gain):
            raise ConfigError(
                f"creep_tau_s and creep_gain must have the same length "
                f"({len(self.creep_tau_s)} != {len(self.creep_gain)})."
            )
        for tau in self.creep_tau_s:
            _check_positive("creep_tau_s", tau)
        for g in self.creep_gain:
            _check_nonneg("creep_gain", g)
        a2 = float(self.asymmetry_a2)
        if not math.isfinite(a2) or abs(a2) >= 1.0:
            raise ConfigError(f"asymmetry_a2 must lie in (-1, 1) (monotone bow). Got {a2!r}.")
        _check_positive("asymmetry_span_um", self.asymmetry_span_um)
        _check_positive("dynamics_fn_Hz", self.dynamics_fn_Hz)
        _check_positive("dynamics_zeta", self.dynamics_zeta)
        _check_nonneg("delay_s", self.delay_s)
        for name in ("drift_rate_um_per_s", "drift_amplitude_um"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ConfigError(f"{name} must be finite. Got {value!r}.")
        _check_positive("drift_period_s", self.drift_period_s)
        _check_nonneg("noise_sigma_um", self.noise_sigma_um)
        _check_positive("quantization_lsb_um", self.quantization_lsb_um)

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def none(cls) -> "Effects":
        """Every effect off: the plant is the pure PI hysteresis plus offset."""
        return cls()

    @classmethod
    def from_names(cls, names: Iterable[str], strength: float = 1.0) -> "Effects":
        """Turn on exactly the effects in ``names`` at their default strength scaled by ``strength``.

        ``strength`` (> 0) multiplies: a₂ (asymmetry), every creep gain, the delay, the drift rate
        and amplitude, σ and the LSB; for ``dynamics`` it divides the natural frequency
        (strength 2 → f_n/2: twice the low-frequency phase lag), ζ unchanged.
        """
        strength = _check_positive("strength", strength)
        names = [n.strip().lower() for n in names if n.strip()]
        unknown = [n for n in names if n not in EFFECT_NAMES]
        if unknown and unknown[0] in ("none", "all", "default"):  # a keyword, valid alone only (a blind test)
            raise ConfigError(f"--effects: {unknown[0]!r} stands alone; it cannot be combined with other effects "
                              f"({', '.join(names)}); give it alone or list the effects ({', '.join(EFFECT_NAMES)})")
        if unknown:
            raise ConfigError(
                f"unknown effect {unknown[0]!r}; choose from: {', '.join(EFFECT_NAMES)} "
                "(or 'none', 'all', 'default')."
            )
        base = cls()
        changes: dict[str, object] = {n: True for n in names}
        if "asymmetry" in names and not abs(base.asymmetry_a2 * strength) < 1.0:
            raise ConfigError(f"--strength {strength:g} with asymmetry: its bow |a₂| = |{base.asymmetry_a2:g} × "
                              f"{strength:g}| = {abs(base.asymmetry_a2 * strength):g} must stay below 1 (a monotone "
                              f"output); use --strength below {1.0 / abs(base.asymmetry_a2):.3g}, or leave "
                              "asymmetry out")
        if strength != 1.0:
            scaled = {
                "asymmetry": {"asymmetry_a2": base.asymmetry_a2 * strength},
                "creep": {"creep_gain": tuple(g * strength for g in base.creep_gain)},
                "dynamics": {"dynamics_fn_Hz": base.dynamics_fn_Hz / strength},
                "delay": {"delay_s": base.delay_s * strength},
                "drift": {
                    "drift_rate_um_per_s": base.drift_rate_um_per_s * strength,
                    "drift_amplitude_um": base.drift_amplitude_um * strength,
                },
                "noise": {"noise_sigma_um": base.noise_sigma_um * strength},
                "quantization": {"quantization_lsb_um": base.quantization_lsb_um * strength},
            }
            for n in names:
                changes.update(scaled[n])
        return cls(**changes)  # type: ignore[arg-type]

    @classmethod
    def only(cls, name: str, strength: float = 1.0) -> "Effects":
        """Exactly one effect on, at its realistic default scaled by ``strength``."""
        return cls.from_names([name], strength)

    @classmethod
    def all(cls, strength: float = 1.0) -> "Effects":
        """Every effect on at its default strength scaled by ``strength``."""
        return cls.from_names(EFFECT_NAMES, strength)

    @classmethod
    def default(cls) -> "Effects":
        """The effects of :meth:`Plant.default`: creep, dynamics, noise, quantization."""
        return cls.from_names(DEFAULT_PLANT_EFFECTS)

    @classmethod
    def parse(cls, spec: str, strength: float = 1.0) -> "Effects":
        """``"none"``, ``"all"``, ``"default"`` or a comma-separated list of effect names."""
        strength = _check_positive("strength", strength)
        words = [w.strip().lower() for w in spec.split(",") if w.strip()]
        if words in (["none"], []):
            return cls.none()
        if words == ["all"]:
            return cls.all(strength)
        if words == ["default"]:
            return cls.from_names(DEFAULT_PLANT_EFFECTS, strength)
        return cls.from_names(words, strength)

    def with_noise(self, sigma_um: float) -> "Effects":
        """A copy with sensor noise σ = ``sigma_um`` (µm); σ = 0 turns the noise off."""
        sigma_um = _check_nonneg("noise_sigma_um", sigma_um)
        return replace(self, noise=sigma_um > 0, noise_sigma_um=sigma_um)

    @property
    def enabled(self) -> tuple[str, ...]:
        """Names of the effects that are on, in application order."""
        return tuple(n for n in EFFECT_NAMES if getattr(self, n))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["creep_tau_s"] = list(self.creep_tau_s)
        d["creep_gain"] = list(self.creep_gain)
        return d


#: Thresholds of the default plant (V, absolute). Deliberately not on hystfit's default grid
#: r_j = j·max|u|/10 for 20, 40 or 60 V captures (multiples of 2, 4, 6 V), so identification is honest.
DEFAULT_THRESHOLDS_V: tuple[float, ...] = (0.0, 2.5, 5.5, 9.0, 13.0, 17.5, 22.5, 27.5, 33.5, 45.0)
#: Weights of the default plant (µm/V); w₀ is the linear (r = 0) term. Σw = 0.383 µm/V.
DEFAULT_WEIGHTS_UM_PER_V: tuple[float, ...] = (
    0.205, 0.038, 0.033, 0.028, 0.023, 0.018, 0.014, 0.011, 0.008, 0.005,
)
#: Sensor offset of the default plant (µm).
DEFAULT_OFFSET_UM = 0.25


@dataclass(frozen=True)
class Plant:
    """The virtual actuator: PI hysteresis followed by :class:`Effects`.

    Hysteresis (paper 003 eq. 1–3; ``../shared/papers/README.md``):
    H[u](k) = Σ_j w_j F_{r_j}[u](k), F_r the play operator with initial state
    max(u₀ − r, min(u₀ + r, 0)) (computed by :func:`hystfit.models._kernels.play_matrix`).
    Measurement: y = effects(H[u]) + offset, in ``output_unit``.

    Attributes
    ----------
    thresholds_V : play-operator thresholds r_j (V), ≥ 0; r = 0 is the linear term.
    weights_um_per_V : weights w_j (µm/V).
    offset_um : constant sensor offset (µm), added after every effect except noise/quantization.
    effects : the non-ideal effects (:class:`Effects`).
    output_unit : unit of the measurement, one of ``um``, ``nm``, ``mm``, ``m``.
    """

    thresholds_V: tuple[float, ...] = DEFAULT_THRESHOLDS_V
    weights_um_per_V: tuple[float, ...] = DEFAULT_WEIGHTS_UM_PER_V
    offset_um: float = DEFAULT_OFFSET_UM
    effects: Effects = field(default_factory=Effects)
    output_unit: str = "um"

    def __post_init__(self) -> None:
        r = _as_float_tuple(self.thresholds_V)
        w = _as_float_tuple(self.weights_um_per_V)
        object.__setattr__(self, "thresholds_V", r)
        object.__setattr__(self, "weights_um_per_V", w)
        if len(r) == 0 or len(r) != len(w):
            raise ConfigError(
                f"thresholds_V and weights_um_per_V must be non-empty and of equal length "
                f"({len(r)} != {len(w)})."
            )
        if not all(math.isfinite(x) and x >= 0 for x in r):
            raise ConfigError(f"thresholds_V must be finite and >= 0. Got {r}.")
        if not all(math.isfinite(x) for x in w):
            raise ConfigError(f"weights_um_per_V must be finite. Got {w}.")
        if not math.isfinite(float(self.offset_um)):
            raise ConfigError(f"offset_um must be finite. Got {self.offset_um!r}.")
        if self.output_unit not in OUTPUT_UNITS:
            raise ConfigError(
                f"output_unit must be one of {', '.join(OUTPUT_UNITS)}. Got {self.output_unit!r}."
            )
        if not isinstance(self.effects, Effects):
            raise ConfigError("effects must be an Effects instance.")

    @classmethod
    def default(cls) -> "Plant":
        """A realistic open-loop piezo stage (values in ``sample_data/README.md``).

        PI with 10 operators at absolute thresholds 0…45 V (:data:`DEFAULT_THRESHOLDS_V`,
        :data:`DEFAULT_WEIGHTS_UM_PER_V`): periodic 0→60→0 V loop stroke 18.7 µm from the
        hysteresis (0.31 µm/V; 18.8 µm in a 5-cycle capture with creep), loop width 12.7 % of the
        stroke at 60 V (12.8 % at 40 V, 10.8 % at 20 V), widening to ≈ 15 % at 80 Hz through the
        dynamics; offset 0.25 µm. Effects: creep (1 %/decade, τ = 0.01…10 s), dynamics
        (f_n = 1.2 kHz, ζ = 0.15), sensor noise σ = 0.008 µm, quantization 1 nm.
        """
        return cls(effects=Effects.default())

    def with_effects(self, effects: Effects) -> "Plant":
        return replace(self, effects=effects)

    def to_dict(self) -> dict:
        return {
            "thresholds_V": list(self.thresholds_V),
            "weights_um_per_V": list(self.weights_um_per_V),
            "offset_um": float(self.offset_um),
            "output_unit": self.output_unit,
            "effects": self.effects.to_dict(),
        }


# ----------------------------------------------------------------------------------------------
# Simulation
# ----------------------------------------------------------------------------------------------


def _check_signals(t, u) -> tuple[np.ndarray, np.ndarray, float]:
    t = np.ascontiguousarray(t, dtype=np.float64).ravel()
    u = np.ascontiguousarray(u, dtype=np.float64).ravel()
    if t.shape != u.shape:
        raise ConfigError(f"t and u must have the same length ({t.size} != {u.size}).")
    if t.size < 2:
        raise ConfigError("need at least 2 samples.")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
        raise ConfigError("t and u must be finite.")
    d = np.diff(t)
    dt = float(d.mean())
    # the linear stages are discretized with the mean period: allow 0.1 % jitter (rounded time stamps)
    if dt <= 0 or np.max(np.abs(d - dt)) > 1e-3 * dt:
        raise ConfigError("t must be increasing and uniformly sampled (period jitter ≤ 0.1 %).")
    return t, u, dt


def simulate_plant_components(
    plant: Plant, t: np.ndarray, u: np.ndarray, seed: int = 0
) -> dict[str, np.ndarray]:
    """Simulate the plant and return the signal after every stage.

    Keys, in application order: ``hysteresis``, ``asymmetry``, ``creep``, ``dynamics``,
    ``delay``, ``drift``, ``noise``, ``quantization``, and ``measurement`` (= the last one).
    Each is the displacement after that stage (identical to the previous one when the effect is
    off), in ``plant.output_unit``, offset included. Noise comes from
    ``np.random.default_rng(seed)`` and is drawn only when the noise effect is on.
    """
    t, u, dt = _check_signals(t, u)
    e = plant.effects
    r = np.asarray(plant.thresholds_V, dtype=np.float64)
    w = np.asarray(plant.weights_um_per_V, dtype=np.float64)
    factor = OUTPUT_UNITS[plant.output_unit]
    offset = float(plant.offset_um)

    def out(z: np.ndarray) -> np.ndarray:
        y = z + offset
        return y * factor if factor != 1.0 else y

    comps: dict[str, np.ndarray] = {}
    F = play_matrix(u, r)
    z = np.zeros_like(u)  # µm, offset excluded; summed in a fixed order (no BLAS: same bits everywhere)
    for j in range(w.size):
        z += w[j] * F[:, j]
    comps["hysteresis"] = out(z)

    if e.asymmetry:  # the asymmetry block with its ends at z = 0 and z = s (m = h = s/2)
        s = float(e.asymmetry_span_um)
        z = bow(z, float(e.asymmetry_a2) * s / 4.0, 0.0, 0.5 * s, 0.5 * s)
    comps["asymmetry"] = out(z)

    if e.creep:  # z + Σ g_i LP_τi[z] is the creep block on (1 + G)z with gains g_i/(1 + G)
        g = np.asarray(e.creep_gain, dtype=np.float64)
        G = float(g.sum())
        z = Creep(tau_s=e.creep_tau_s).apply_population(((1.0 + G) * z)[None, :], (g / (1.0 + G))[None, :], dt)[0]
    comps["creep"] = out(z)

    if e.dynamics:
        fn, zeta = float(e.dynamics_fn_Hz), float(e.dynamics_zeta)
        if not fn * dt < 0.5:
            raise ConfigError(f"the plant's dynamics (stage resonance f_n = {fn:g} Hz) needs a sample rate above "
                              f"{2 * fn:g} Hz, got {1 / dt:g} Hz; raise --fs, or leave dynamics out of --effects (it "
                              "is one of the default effects: --effects creep,noise,quantization leaves it out; a "
                              "weaker --strength raises f_n)")
        z = Dynamics().apply_population(z[None, :], np.array([[fn, zeta]]), dt)[0]
    comps["dynamics"] = out(z)

    if e.delay and e.delay_s > 0:
        z = fractional_delay(z, float(e.delay_s), dt)
    comps["delay"] = out(z)

    if e.drift:
        tr = t - t[0]
        z = z + float(e.drift_rate_um_per_s) * tr + float(e.drift_amplitude_um) * np.sin(
            2.0 * np.pi * tr / float(e.drift_period_s)
        )
    comps["drift"] = out(z)

    y = comps["drift"]
    if e.noise and e.noise_sigma_um > 0:
        rng = np.random.default_rng(seed)
        y = y + rng.standard_normal(y.size) * (float(e.noise_sigma_um) * factor)
    comps["noise"] = y

    if e.quantization:
        lsb = float(e.quantization_lsb_um) * factor
        y = np.round(y / lsb) * lsb
    comps["quantization"] = y
    comps["measurement"] = y
    return comps


def simulate_plant(plant: Plant, t: np.ndarray, u: np.ndarray, seed: int = 0) -> np.ndarray:
    """The measured displacement of ``plant`` driven by ``u`` at times ``t`` (uniform), in
    ``plant.output_unit``. Deterministic for a given ``seed`` (see
    :func:`simulate_plant_components` for the stages)."""
    return simulate_plant_components(plant, t, u, seed)["measurement"]


# ----------------------------------------------------------------------------------------------
# Writing captures and the campaign
# ----------------------------------------------------------------------------------------------


def _capture_frame(t, u, y, output_unit: str):
    import pandas as pd

    if output_unit not in OUTPUT_UNITS:
        raise ConfigError(f"output_unit must be one of {', '.join(OUTPUT_UNITS)}. Got {output_unit!r}.")
    t = np.asarray(t, dtype=np.float64).ravel()
    u = np.asarray(u, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if not (t.size == u.size == y.size):
        raise ConfigError(f"t, u and y must have the same length ({t.size}, {u.size}, {y.size}).")
    return pd.DataFrame({"time_s": t, "voltage_V": u, f"displacement_{output_unit}": y})


def write_capture(
    path: str | os.PathLike,
    t: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    output_unit: str = "um",
    fmt: str | None = None,
    *,
    float_format: str = "%.9g",
) -> Path:
    """Write one capture with columns ``time_s, voltage_V, displacement_<unit>``, atomically.

    ``fmt`` is ``"csv"`` or ``"parquet"``; None picks it from the suffix (``.parquet``/``.pq`` →
    Parquet, anything else → CSV). CSV uses ``float_format`` ('%.9g': 9 significant digits, far
    below the 1 nm LSB) and ``\\n`` line ends, so the same data always gives the same bytes.
    Returns the path written.
    """
    path = Path(path)
    if fmt is None:
        fmt = "parquet" if path.suffix.lower() in (".parquet", ".pq") else "csv"
    fmt = fmt.lower()
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"unknown capture format {fmt!r}; choose 'csv' or 'parquet'.")
    frame = _capture_frame(t, u, y, output_unit)
    if fmt == "csv":
        data = frame.to_csv(index=False, float_format=float_format, lineterminator="\n").encode("utf-8")
    else:
        buf = BytesIO()
        frame.to_parquet(buf, index=False)
        data = buf.getvalue()
    atomic_write_bytes(path, data)  # temp file + os.replace; OutputError when it cannot write
    return path


#: Paper 002 §3.1 campaign conditions.
CAMPAIGN_AMPLITUDES_V: tuple[int, ...] = (20, 40, 60)
CAMPAIGN_FREQUENCIES_HZ: tuple[int, ...] = (10, 20, 30, 40, 50, 60, 70, 80)
CAMPAIGN_CYCLES = 5
CAMPAIGN_FS_HZ = 10_000.0
CAMPAIGN_BROADBAND_AMPLITUDE_V = 60.0
CAMPAIGN_PRBS_DURATION_S = 3.0
CAMPAIGN_PRBS_CLOCK_HZ = 2_500.0
CAMPAIGN_STEPS_DURATION_S = 7.7


def campaign_conditions() -> list[tuple[str, dict]]:
    """The campaign's files in write order: (relative path, description) pairs.

    Index i in this list gives the file's noise seed ``seed·1000 + i`` and (for the PRBS)
    excitation seed ``seed·1000 + 500 + i``.
    """
    items: list[tuple[str, dict]] = []
    for a in CAMPAIGN_AMPLITUDES_V:
        for f in CAMPAIGN_FREQUENCIES_HZ:
            items.append(
                (f"a{a:02d}V_f{f:02d}Hz.csv", {"kind": "raised-cosine", "amplitude_V": a, "frequency_Hz": f})
            )
    a = CAMPAIGN_BROADBAND_AMPLITUDE_V
    items.append((f"broadband/prbs_{a:02.0f}V.csv", {"kind": "prbs", "amplitude_V": a}))
    items.append((f"broadband/steps_{a:02.0f}V.csv", {"kind": "steps", "amplitude_V": a}))
    return items


def make_campaign(
    out_dir: str | os.PathLike, plant: Plant | None = None, seed: int = 0
) -> list[Path]:
    """Write paper 002's campaign measured on ``plant`` (default :meth:`Plant.default`).

    - 24 raised-cosine captures 0→A→0, A ∈ {20, 40, 60} V × f ∈ {10, 20, …, 80} Hz, 5 cycles,
      10 kHz, at ``out_dir/a{A:02d}V_f{F:02d}Hz.csv``;
    - ``out_dir/broadband/prbs_60V.csv``: random binary 0/60 V, bit clock 2.5 kHz, 3 s;
    - ``out_dir/broadband/steps_60V.csv``: 0.2 s at 0 V, then 30, 60, 20, 45, 0 V held 1.5 s each.

    File i (order of :func:`campaign_conditions`) uses noise seed ``seed·1000 + i`` and the PRBS
    excitation seed ``seed·1000 + 500 + i``. Existing files are overwritten (atomically); nothing
    else in ``out_dir`` is touched. Output is bit-for-bit reproducible for a given plant and seed.
    Returns the written paths in that order.
    """
    plant = Plant.default() if plant is None else plant
    seed = int(seed)
    if seed < 0:
        raise ConfigError(f"seed must be >= 0. Got {seed}.")
    out = Path(out_dir)
    written: list[Path] = []
    for i, (rel, cond) in enumerate(campaign_conditions()):
        file_seed = seed * 1000 + i
        kind = cond["kind"]
        if kind == "raised-cosine":
            t, u = raised_cosine(cond["amplitude_V"], cond["frequency_Hz"], CAMPAIGN_CYCLES, CAMPAIGN_FS_HZ)
        elif kind == "prbs":
            t, u = prbs(
                cond["amplitude_V"],
                CAMPAIGN_FS_HZ,
                CAMPAIGN_PRBS_DURATION_S,
                CAMPAIGN_PRBS_CLOCK_HZ,
                seed=seed * 1000 + 500 + i,
            )
        else:
            t, u = step_pattern(cond["amplitude_V"], CAMPAIGN_STEPS_DURATION_S, CAMPAIGN_FS_HZ)
        y = simulate_plant(plant, t, u, seed=file_seed)
        written.append(write_capture(out / rel, t, u, y, plant.output_unit, "csv"))
    return written
