"""Closed-loop tracking simulation: feedforward, PID, feedforward + PID and sliding-mode control.

:func:`track` runs a sampled control loop at the target's sample rate around a *plant* that is an
identified model: the controller's own look-up table, or another one (``plant_pf``) so the
inverse is tested against a model it was not built from (the realistic case). It reports paper
002's figures (Table 4/5: maximum error, RMSE, both in % of the stroke; Table 6: rise time and
settling time of steps) per controller, and a comparison when several are given.

Loop timing (one sample of computation delay, as in a real digital controller)::

    y[0] = plant at rest at the initial voltage v[0]
    for k = 0 … N−2:
        y_m[k] = y[k] + noise[k]                      measurement (seeded Gaussian, σ = noise)
        c[k]   = controller(r[0..k], y_m[0..k])       command for the next sample
        v[k+1] = limits(c[k])                         clip to [vmin, vmax], then slew limit
        y[k+1] = plant.step(v[k+1])                   the plant's output for the held voltage

so ``voltage_V[k]`` is the voltage whose effect is ``y[k]``, aligned like ``hystfit invert``'s
output. The feedforward uses one sample of preview, v_ff[k+1] = H⁻¹[r][k+1] (the trajectory
is known in advance), so with a perfect model ``ff`` tracks exactly and its output equals the
preview of ``hystfit invert``.

Controllers (V = volts, unit = the parameter file's output unit, Ts = sample period):

``ff``
    c[k] = u_ff[k+1], the look-up-table inverse of :func:`hystfit.invert.invert_target`.
``pid``
    Parallel PID on e = r − y_m, backward-Euler integral, derivative **on the measurement**
    with a first-order filter (no derivative kick on steps):
    I[k] = I[k−1] + Ki·Ts·e[k];  D[k] = a·D[k−1] − b·(y_m[k] − y_m[k−1]),  a = Tf/(Tf+Ts),
    b = Kd/(Tf+Ts);  c[k] = Kp·e[k] + I[k] + D[k]. The integrator starts at the initial
    voltage (bumpless start). Anti-windup by back-calculation, I += (Ts/Tt)·(v − c) when the
    limits act (Åström & Hägglund: Tt = √(Ti·Td) with D, Ti = Kp/Ki without, Ts for pure I),
    or by clamping (integration stops while saturated and the error drives further in).
``ff+pid``
    c[k] = u_ff[k+1] + PID (integrator starting at 0): paper 002 §5's composite control.
``smc``
    Sliding mode with integral augmentation (paper 003 §4.3–4.4) acting on top of the
    inverse feedforward. 003 places the sliding-mode output before the PI inverse (serial
    inverse compensation); we add its correction to the feedforward voltage instead, which to
    first order is the same (the inverse's incremental gain is 1/K) and works for every model's
    inverse, including offline ones. Design (discrete time, :func:`design_smc`): nominal
    linear part x[k+1] = A x[k] + B δ[k], δy = C x (:func:`nominal_plant`), error integral
    p[k+1] = p[k] + Ts·(y_m[k] − r[k]) (003 eq. 26–28, e = y − r), augmented state
    x_d = [x; p] (eq. 29–30), switching function S = M x̂_d (eq. 31) with M from Ackermann's
    formula for sliding surfaces, so the sliding motion (eq. 32–35) has the chosen poles and
    M·B_d = 1 (eq. 36); reaching law S[k+1] = (1 − q·Ts)·S[k] − ε·Ts·tanh(α·S[k]) (eq. 38,
    tanh instead of sgn against chattering), solved for δ (eq. 39); x̂ from a Luenberger
    observer x̂[k+1] = A x̂ + B δ + G (e − C x̂) (eq. 40–42) with G = 0: x̂ is the nominal
    response to the corrections actually applied (exact for the nominal part), and the measured
    error enters through p, which 003 also takes as measured. A non-zero G would feed the
    tracking error itself — feedforward residual, reference steps the voltage limits cut, sensor
    noise — into x̂; with the second-order nominal of a dynamic model that destabilised the loop
    in our tests. The integral is frozen while the voltage is limited (anti-windup). Paper 003's
    design parameters (ε, α, k, sliding and observer poles; a placed observer gain G) are
    options of :func:`design_smc` (``--smc-option``).
``smc-noinv``
    The same sliding mode without inverse compensation (003's comparison): the feedforward is
    replaced by the constant initial voltage.

Bandwidths (:func:`measure_bandwidths`, ``--measure-bandwidth``): tracking (−3 dB of Y/R) and
disturbance rejection (0 dB of Y/D for an output disturbance), paper 003's figures.

Nominal linear part (:func:`nominal_plant`). For a rate-independent model it is the gain and
the loop's one-sample delay: δy[k+1] = K·δc[k] (first order, pole at z = 0), with K the
table's low-frequency gain (stroke / voltage range of the identification data of the cells
used). For a rate-dependent model the normalized step response of the identified model
(rest → full-range voltage step) is fitted by least squares with
δy[k+1] = −a1 δy[k] − a2 δy[k−1] + b0 δc[k] + b1 δc[k−1] + b2 δc[k−2] (second order with one
sample of delay), scaled to the gain K; a fit worse than 10 % NRMSE or an unstable fit falls
back to the static form (reported).

Automatic PID gains (:func:`auto_pid`): integral-dominant PI, the textbook choice for a stage
that is a static gain at low frequency: Ki = s·2π·f_max/K (crossover ≈ s·f_max), Kp = s·0.25/K,
Kd = 0, f_max = fs/20; s ≤ 1 is the largest factor for which the nominal discrete loop has a
gain margin ≥ 2 (6 dB) and a phase margin ≥ 45° (bisection; s = 1 for a static plant:
GM ≈ 2.5, PM ≈ 60°). ``bandwidth_Hz`` replaces s·f_max (margins are then only reported).
The hysteresis changes the incremental gain between the reversal slope and the branch slope
(about ×2 for the sample data); the 6 dB margin covers it.

Speed: the loop is a Python loop over samples with scalar arithmetic and preallocated arrays;
PI plants use a dedicated play-operator stepper (in-place updates, no allocation per sample),
other models their ``initial_state``/``step`` methods. Measured on the sample data (one 2-core
machine): ≈ 15 µs per sample for ff/pid and 25 µs for smc with a PI plant, ≈ 35 µs with a
Bouc–Wen plant, 130–250 µs with ``pi2`` (its ``step`` recomputes its filter each call); the
figure of every run is in ``summary.json`` (``us_per_sample``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from ._lazy import lazy_module
from .capture import display_unit
from .errors import ConfigError
from .seeds import check_seed
from .invert import (CellUse, InversionResult, SegmentChoice, Span, Target, blend_segments, find_spans,
                     invert_target, preroll_voltage, select_cells, sine_target, target_from_array,
                     tracking_metrics)
from .parallel import one_blas_thread
from .models.pi import PI
from .results import Cell, ParamsFile

signal = lazy_module("scipy.signal")  # imported on first use: keeps start-up fast

__all__ = [
    "CONTROLLERS",
    "NominalPlant",
    "PIDGains",
    "SMCDesign",
    "ControllerRun",
    "TrackResult",
    "nominal_plant",
    "auto_pid",
    "loop_margins",
    "design_smc",
    "step_metrics",
    "simulate_loop",
    "track",
    "ControllerDesign",
    "design_controllers",
]

#: Controller names accepted by :func:`track`.
CONTROLLERS = ("ff", "pid", "ff+pid", "smc", "smc-noinv")
#: ``--smc-option`` keys of :func:`design_smc` (paper 003's design parameters)
SMC_OPTIONS = ("eps", "alpha", "k", "sliding_poles", "observer_poles")
#: Highest automatic bandwidth as a fraction of the sample rate.
AUTO_BANDWIDTH_FRACTION = 1.0 / 20.0
#: Required nominal gain margin (factor) and phase margin (degrees) of the automatic tuning.
MIN_GAIN_MARGIN = 2.0
MIN_PHASE_MARGIN_DEG = 45.0


# ----------------------------------------------------------------------------------------------
# Plant: identified models stepped sample by sample
# ----------------------------------------------------------------------------------------------


class _PlayStepper:
    """Classical PI (paper 003 eq. 1–3) stepped with preallocated play-operator states."""

    def __init__(self, model: PI, theta: np.ndarray, dt: float):
        n = model.n_operators
        self.model, self.theta, self.dt = model, theta, dt
        self.r = np.ascontiguousarray(model.r)
        self.w = np.ascontiguousarray(np.asarray(theta, float)[:n])
        self.y0 = float(theta[n])
        self.s = np.zeros(n)
        self.lo = np.empty(n)
        self.hi = np.empty(n)

    def start(self, u0: float) -> float:
        # the model's own state after the first sample: a ramp from 0 V, or a rest at u0 (a relaxed
        # history — a review's find: the stepper always ramped, 22.5 µm off a relaxed plant at 50 V)
        self.s[:] = self.model.initial_state(self.theta, u0, self.dt)
        return float(self.s @ self.w) + self.y0

    def advance(self, u: float) -> float:
        s = self.s
        np.subtract(u, self.r, out=self.lo)
        np.add(u, self.r, out=self.hi)
        np.minimum(self.hi, s, out=s)
        np.maximum(self.lo, s, out=s)
        return float(s @ self.w) + self.y0


class _ModelStepper:
    """Any model with ``initial_state``/``step`` (state after the first sample, hystfit's contract)."""

    def __init__(self, model, theta: np.ndarray, dt: float):
        self.model, self.theta, self.dt = model, np.asarray(theta, float).ravel(), float(dt)
        self.buf = np.empty(1)
        self.state = None
        self.u_prev = 0.0

    def start(self, u0: float) -> float:
        self.state = np.asarray(self.model.initial_state(self.theta, float(u0), self.dt), dtype=np.float64)
        self.u_prev = float(u0)
        return float("nan")  # the first output comes from the pre-roll's later samples

    def advance(self, u: float) -> float:
        self.buf[0] = u
        y, st = self.model.step(self.theta, self.state, self.u_prev, self.buf, self.dt)
        self.state = st[0]
        self.u_prev = u
        return float(y[0])


def _stepper(cell: Cell, dt: float):
    model = cell.model
    if isinstance(model, PI):
        return _PlayStepper(model, cell.theta, dt)
    try:
        model.initial_state(np.asarray(cell.theta, float), 0.0, dt)
    except ConfigError:
        raise ConfigError(f"model {model.name!r} (cell {cell.label}) cannot be stepped sample by sample, which the "
                          "closed-loop plant needs; use --plant with a parameter file of another model") from None
    return _ModelStepper(model, cell.theta, dt)


class _Plant:
    """Blend of cells' models stepped together: y[k] = Σ_c w_c[k]·y_c[k] (weights per segment).

    Every cell starts at rest at the initial voltage after the same pre-roll (0 V → v0) that
    :func:`hystfit.invert.simulate_cell` uses, so the ``ff`` loop reproduces the preview.
    """

    def __init__(self, pf: ParamsFile, choices: Sequence[SegmentChoice], n: int, dt: float):
        self.cells = sorted({c.index for ch in choices for c in ch.cells})
        self.steppers = [_stepper(pf.cells[i], dt) for i in self.cells]
        self.pf, self.dt = pf, dt
        if len(self.cells) == 1:
            self.weights = None
        else:
            ones = np.ones(n)
            zeros = np.zeros(n)
            self.weights = np.vstack([blend_segments({j: (ones if j == i else zeros) for j in self.cells},
                                                      choices, n) for i in self.cells])
        self.labels = [pf.cells[i].label for i in self.cells]

    def start(self, v0: float) -> float:
        ys = []
        for i, st in zip(self.cells, self.steppers):
            pre = preroll_voltage(self.pf.cells[i], v0, self.dt)
            y = st.start(float(pre[0]))
            for u in pre[1:]:
                y = st.advance(float(u))
            ys.append(y)
        return self._mix(0, ys)

    def _mix(self, k: int, ys: list[float]) -> float:
        if self.weights is None:
            return ys[0]
        return float(sum(w * y for w, y in zip(self.weights[:, k], ys)))

    def advance(self, k: int, u: float) -> float:
        """Output at sample k for the voltage held from k−1 to k."""
        if self.weights is None:
            return self.steppers[0].advance(u)
        return self._mix(k, [st.advance(u) for st in self.steppers])


# ----------------------------------------------------------------------------------------------
# Nominal linear part
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class NominalPlant:
    """Linear model of the stage seen by the feedback: command c[k] (V) → output y[k+1] (unit).

    num, den : discrete transfer function in z (descending powers), sample period ``dt``;
        it includes the loop's one-sample delay.
    A, B, C : a state-space realization x[k+1] = A x[k] + B c[k], δy[k] = C x[k].
    gain : low-frequency gain K (unit/V).
    kind : ``"static"`` (K·z⁻¹) or ``"second-order"`` (fitted step response).
    fit_nrmse_pct : NRMSE (%) of the fitted step response (0 for static).
    description : one line.
    """

    num: np.ndarray
    den: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    dt: float
    gain: float
    kind: str
    fit_nrmse_pct: float
    description: str
    unit: str = ""  # the output unit K is per volt of (its words: :func:`_per_volt`)

    @property
    def order(self) -> int:
        return int(self.A.shape[0])

    def frequency_response(self, w_rad_s: np.ndarray) -> np.ndarray:
        """P(e^{jωTs}) at angular frequencies ω (rad/s)."""
        z = np.exp(1j * np.asarray(w_rad_s, float) * self.dt)
        return np.polyval(self.num, z) / np.polyval(self.den, z)

    def poles(self) -> np.ndarray:
        return np.roots(self.den)


def _realize(num: np.ndarray, den: np.ndarray):
    A, B, C, _ = signal.tf2ss(num, den)
    return A, B[:, 0], C[0]


def _per_volt(unit: str) -> str:
    """The unit of a gain K: ``µm/V`` for a table in um (``per V`` without a unit; a blind test read
    "static gain 0.3178 per V" in a report whose every other number had its unit)."""
    return f"{display_unit(unit)}/V" if unit else "per V"


def _static(gain: float, dt: float, note: str = "", unit: str = "") -> NominalPlant:
    num, den = np.array([gain]), np.array([1.0, 0.0])
    A, B, C = _realize(num, den)
    desc = f"static gain {gain:.4g} {_per_volt(unit)} with one sample of delay (K·z⁻¹){note}"
    return NominalPlant(num, den, A, B, C, dt, gain, "static", 0.0, desc, unit)


def _weighted_cells(pf: ParamsFile, choices: Sequence[SegmentChoice]) -> list[tuple[Cell, float]]:
    """Cells with weights averaged over segments by length."""
    total = sum(ch.segment.stop - ch.segment.start for ch in choices)
    acc: dict[int, float] = {}
    for ch in choices:
        frac = (ch.segment.stop - ch.segment.start) / total
        for c in ch.cells:
            acc[c.index] = acc.get(c.index, 0.0) + frac * c.weight
    return [(pf.cells[i], w) for i, w in sorted(acc.items(), key=lambda kv: -kv[1])]


def nominal_plant(pf: ParamsFile, choices: Sequence[SegmentChoice], dt: float) -> NominalPlant:
    """The nominal linear part of the controller's table (module docstring, "Nominal linear part").

    Parameters
    ----------
    pf : the controller's parameter file.
    choices : the cells used for the target (:class:`hystfit.invert.SegmentChoice`).
    dt : loop sample period (s).
    """
    cells = _weighted_cells(pf, choices)
    # signed: a stage whose displacement falls with the voltage (inverted sensor) has K < 0, and the
    # feedback gains, which divide by K, change sign with it
    gain = float(sum(w * c.scale.gain * (-1.0 if c.scale.sign < 0 else 1.0) for c, w in cells))
    if not (math.isfinite(gain) and gain != 0):
        raise ConfigError(f"{pf.path}: the identification data give no usable gain ({gain:g}); the feedback "
                          "needs a stage whose displacement follows the voltage")
    cell = cells[0][0]
    if not cell.model.rate_dependent:
        return _static(gain, dt, unit=pf.unit)
    s = cell.scale
    n_rest = max(20, int(round(0.01 / dt)))
    n_step = max(64, int(round(0.05 / dt)))
    lo, hi = s.u_min + 0.25 * s.u_range, s.u_min + 0.75 * s.u_range
    pre = preroll_voltage(cell, lo, dt)
    u = np.concatenate([pre, np.full(n_rest, lo), np.full(n_step, hi)])
    y = cell.model.simulate_one(cell.theta, u, dt)[pre.size:]
    if not np.all(np.isfinite(y)) or abs(y[-1] - y[0]) <= 1e-12:
        return _static(gain, dt, "; the step response of the model was unusable, static form used", pf.unit)
    v = np.r_[np.zeros(n_rest), np.ones(n_step)]
    yn = (y - y[0]) / (np.mean(y[-max(4, n_step // 10):]) - y[0])
    k = np.arange(3, yn.size)
    X = np.column_stack([-yn[k - 1], -yn[k - 2], v[k], v[k - 1], v[k - 2]])
    coef, *_ = np.linalg.lstsq(X, yn[k], rcond=None)
    a1, a2, b0, b1, b2 = coef
    den2 = np.array([1.0, a1, a2])
    dc = (b0 + b1 + b2) / np.sum(den2)
    stable = np.all(np.abs(np.roots(den2)) < 0.9999) and np.isfinite(dc) and dc > 0
    if stable:
        sim = signal.lfilter([b0, b1, b2], den2, v)
        nrmse = float(100.0 * np.sqrt(np.mean((sim - yn) ** 2)) / max(np.ptp(yn), 1e-12))
    else:
        nrmse = float("inf")
    if not stable or nrmse > 10.0:
        return _static(gain, dt, f"; the second-order fit of the model's step response was "
                                 f"{'unstable' if not stable else f'poor ({nrmse:.3g} % NRMSE)'}, static form used",
                       pf.unit)
    num = np.array([b0, b1, b2]) * (gain / dc)
    den = np.array([1.0, a1, a2, 0.0])
    A, B, C = _realize(num, den)
    desc = (f"second-order fit of the {cell.model.name} model's step response (cell {cell.label}, "
            f"NRMSE {nrmse:.2g} %), gain {gain:.4g} {_per_volt(pf.unit)}, one sample of delay")
    return NominalPlant(num, den, A, B, C, dt, gain, "second-order", nrmse, desc, pf.unit)


# ----------------------------------------------------------------------------------------------
# PID
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PIDGains:
    """PID gains and their origin (units: V/unit, V/(unit·s), V·s/unit, s).

    kp, ki, kd : proportional, integral and derivative gains.
    tf_s : time constant of the derivative's first-order filter.
    tt_s : back-calculation tracking time constant.
    anti_windup : ``"backcalc"`` or ``"clamp"``.
    rule : how the gains were obtained.
    bandwidth_Hz : approximate closed-loop bandwidth (crossover K·Ki/2π) on the nominal plant.
    gain_margin, phase_margin_deg : nominal loop margins (inf when there is no crossing).
    """

    kp: float
    ki: float
    kd: float
    tf_s: float
    tt_s: float
    anti_windup: str
    rule: str
    bandwidth_Hz: float
    gain_margin: float
    phase_margin_deg: float


def _pid_tf(kp: float, ki: float, kd: float, tf: float, dt: float):
    """Error path C_e(z) = Kp + Ki·Ts·z/(z−1) and measurement path C_d(z) = Kd(z−1)/((Tf+Ts)z − Tf)."""
    ce_num = np.polyadd(np.polymul([kp], [1.0, -1.0]), [ki * dt, 0.0])
    ce_den = np.array([1.0, -1.0])
    cd_num = np.array([kd, -kd])
    cd_den = np.array([tf + dt, -tf])
    return (ce_num, ce_den), (cd_num, cd_den)


def loop_margins(nominal: NominalPlant, kp: float, ki: float, kd: float = 0.0, tf: float | None = None,
                 n: int = 4000) -> tuple[float, float, float]:
    """Gain margin (factor), phase margin (deg) and crossover (Hz) of the nominal PID loop.

    Loop L(z) = (C_e(z) + C_d(z))·P(z) on a log grid from 10⁻⁴·Nyquist to Nyquist; a margin
    without a crossing is inf.
    """
    dt = nominal.dt
    tf = 4 * dt if tf is None else tf
    (en, ed), (dn, dd) = _pid_tf(kp, ki, kd, tf, dt)
    w = np.pi / dt * np.logspace(-4, 0, n)
    z = np.exp(1j * w * dt)
    L = (np.polyval(en, z) / np.polyval(ed, z) + np.polyval(dn, z) / np.polyval(dd, z)) * nominal.frequency_response(w)
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    gm = float("inf")
    # phase crossings of −180° (mod 360°)
    k = np.floor((ph + np.pi) / (2 * np.pi))
    cross = np.flatnonzero(np.diff(k) != 0)
    if cross.size:
        gm = float(1.0 / np.max(mag[cross]))
    if ph[-1] <= -np.pi + 1e-9 and mag[-1] > 0:  # Nyquist itself on the −180° line
        gm = min(gm, float(1.0 / mag[-1]))
    pm, fc = float("inf"), float("nan")
    gc = np.flatnonzero((mag[:-1] >= 1.0) & (mag[1:] < 1.0))
    if gc.size:
        i = gc[0]
        pm = float(np.degrees(np.pi + ph[i]) % 360.0)
        pm = pm - 360.0 if pm > 180.0 else pm
        fc = float(w[i] / (2 * np.pi))
    return gm, pm, fc


def margins_text(gain_margin: float, phase_margin_deg: float) -> str:
    """The nominal loop's margins in words: a margin :func:`loop_margins` found no crossing for
    (inf) is said so, not printed as ``inf°``."""
    gm = f"GM = {gain_margin:.3g}" if math.isfinite(gain_margin) else "GM = ∞ (the phase never reaches −180°)"
    pm = (f"PM = {phase_margin_deg:.3g}°" if math.isfinite(phase_margin_deg)
          else "PM: none (the loop gain does not fall through 1 below Nyquist)")
    return f"{gm}, {pm}"


def auto_pid(nominal: NominalPlant, bandwidth_Hz: float | None = None, anti_windup: str = "backcalc") -> PIDGains:
    """Integral-dominant PI from the nominal plant (the rule in the module docstring)."""
    dt, K = nominal.dt, nominal.gain
    f_max = AUTO_BANDWIDTH_FRACTION / dt

    def gains(s: float) -> tuple[float, float]:
        return s * 0.25 / K, s * 2 * np.pi * f_max / K

    def ok(s: float) -> bool:
        kp, ki = gains(s)
        gm, pm, _ = loop_margins(nominal, kp, ki)
        return gm >= MIN_GAIN_MARGIN and pm >= MIN_PHASE_MARGIN_DEG

    def largest_ok() -> float:
        """The largest s ≤ 1 whose nominal loop has the automatic rule's margins (0: none)."""
        if ok(1.0):
            return 1.0
        lo_s, hi_s = 0.0, 1.0
        for _ in range(40):
            mid = 0.5 * (lo_s + hi_s)
            lo_s, hi_s = (mid, hi_s) if ok(mid) else (lo_s, mid)
        return lo_s

    if bandwidth_Hz is not None:
        bw = float(bandwidth_Hz)
        if not (math.isfinite(bw) and 0 < bw < 0.5 / dt):
            raise ConfigError(f"--bandwidth {bw:g} Hz must lie in (0, {0.5 / dt:g}) Hz (below Nyquist)")
        s = bw / f_max
        gm, pm, _ = loop_margins(nominal, *gains(s))
        if not (gm > 1.0 and pm > 0.0):  # the nominal loop is unstable: its run would only diverge
            best = largest_ok() * f_max
            hint = (f"at most {best:.3g} Hz keeps GM ≥ {MIN_GAIN_MARGIN:g} and PM ≥ {MIN_PHASE_MARGIN_DEG:g}° "
                    "(leave --bandwidth out to get it)" if best > 0 else "give --kp/--ki instead")
            raise ConfigError(f"--bandwidth {bw:g} Hz makes the nominal loop unstable ({margins_text(gm, pm)}); {hint}")
        rule = (f"Ki = 2π·{bw:g} Hz / K, Kp = 0.25/K·({bw:g}/{f_max:g}), K = {K:.4g} {_per_volt(nominal.unit)} (given bandwidth)")
    else:
        s = largest_ok()
        if s <= 0:
            raise ConfigError("automatic PID tuning found no stable gains for the nominal plant; give --kp/--ki")
        rule = (f"integral-dominant PI: Ki = s·2π·{f_max:g} Hz / K, Kp = s·0.25/K, Kd = 0, K = {K:.4g} {_per_volt(nominal.unit)}, "
                f"s = {s:.3g} (largest ≤ 1 with nominal GM ≥ {MIN_GAIN_MARGIN:g} and PM ≥ {MIN_PHASE_MARGIN_DEG:g}°)")
    kp, ki = gains(s)
    gm, pm, _ = loop_margins(nominal, kp, ki)
    tt = max(kp / ki, dt) if kp != 0 else dt  # K < 0 makes both gains negative; their ratio stays positive
    return PIDGains(kp, ki, 0.0, 4 * dt, tt, anti_windup, rule, s * f_max, gm, pm)


def given_pid(nominal: NominalPlant, kp: float, ki: float, kd: float, tf_s: float | None = None,
              anti_windup: str = "backcalc") -> PIDGains:
    """User gains, with the derivative filter and anti-windup time constant completed and margins computed.

    Tf = Td/10 (Td = Kd/Kp), at least 2·Ts, when not given (4·Ts when Kp = 0);
    Tt = √(Ti·Td) with D, Ti = Kp/Ki without, Ts for pure I.
    """
    dt = nominal.dt
    for name, v in (("--kp", kp), ("--ki", ki), ("--kd", kd)):
        if not (math.isfinite(v) and v >= 0):
            raise ConfigError(f"{name} {v:g}: PID gains must be finite and >= 0")
    if kp == ki == kd == 0:
        raise ConfigError("--kp, --ki and --kd are all 0: give at least one non-zero gain")
    if tf_s is None:
        tf_s = max(2 * dt, (kd / kp) / 10.0) if kp > 0 else 4 * dt
    if ki > 0 and kp > 0:
        ti = kp / ki
        tt = math.sqrt(ti * kd / kp) if kd > 0 else ti
    else:
        tt = dt
    rule = "given"
    if nominal.gain < 0:  # a stage whose displacement falls with the voltage: the loop needs gains of K's sign
        kp, ki, kd = -kp, -ki, -kd
        rule = "given (applied with the sign of K < 0: the displacement falls with the voltage)"
    gm, pm, fc = loop_margins(nominal, kp, ki, kd, tf_s)
    return PIDGains(kp, ki, kd, tf_s, max(tt, dt), anti_windup, rule, fc, gm, pm)


# ----------------------------------------------------------------------------------------------
# Sliding mode
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SMCDesign:
    """Discrete integral sliding-mode controller (paper 003 eq. 25–42).

    A, B, C : nominal linear part (:class:`NominalPlant`); Mx (n,), Mp : switching function
    S = Mx·x̂ + Mp·p (V); G (n,) : observer gain; q (1/s), eps (V/s), alpha (1/V) : reaching
    law S⁺ = (1 − q·Ts)·S − ε·Ts·tanh(α·S); sliding_poles, observer_poles : placed poles (z);
    bandwidth_Hz : the sliding-motion bandwidth.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    Mx: np.ndarray
    Mp: float
    G: np.ndarray
    q: float
    eps: float
    alpha: float
    sliding_poles: np.ndarray
    observer_poles: np.ndarray
    bandwidth_Hz: float
    dt: float

    def describe(self) -> str:
        obs = ("observer poles (G = 0: the nominal plant's)" if not np.any(self.G) else
               "observer poles (003 eq. 40–42, placed)")
        return (f"sliding poles {_poles(self.sliding_poles)} (z), {obs} "
                f"{_poles(self.observer_poles)} (z), k = q = {self.q:.4g} 1/s, "
                f"ε = {self.eps:.4g} V/s, α = {self.alpha:.4g} 1/V, bandwidth {self.bandwidth_Hz:.4g} Hz")


def _poles(p: np.ndarray) -> str:
    """Poles as text, real ones without their zero imaginary part (−0 printed as 0)."""
    out = []
    for z in np.asarray(p, dtype=complex):
        re_, im = float(z.real) + 0.0, float(z.imag)
        out.append(f"{re_:.4g}" if abs(im) < 1e-12 else f"{re_:.4g}{im:+.4g}j")
    return ", ".join(out) if out else "none"


def _ackermann_row(A: np.ndarray, B: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """e_nᵀ·Ctrb(A, B)⁻¹·poly(A): Ackermann's row for a polynomial ``poly`` (descending powers)."""
    n = A.shape[0]
    ctrb = np.column_stack([np.linalg.matrix_power(A, i) @ B for i in range(n)])
    if np.linalg.cond(ctrb) > 1e12:
        raise ConfigError("the nominal plant with the integral is not controllable; the sliding surface cannot "
                          "be designed")
    e = np.linalg.solve(ctrb.T, np.eye(n)[-1])
    P = np.zeros_like(A)
    for c in poly:
        P = P @ A + c * np.eye(n)
    return e @ P


def _damped(p: complex, dt: float, zeta_min: float = 0.7) -> complex:
    """A discrete pole with the damping of its continuous image raised to ≥ ``zeta_min`` (same |s|)."""
    if abs(p) < 1e-9:
        return 0.0
    s = np.log(complex(p)) / dt
    wn = abs(s)
    zeta = -s.real / wn if wn > 0 else 1.0
    if zeta >= zeta_min:
        return p
    sd = wn * complex(-zeta_min, math.copysign(math.sqrt(1 - zeta_min ** 2), s.imag))
    return complex(np.exp(sd * dt))


def _sliding_poles(plant_poles: Sequence[complex], zs: float, dt: float) -> list[complex]:
    """The plant's poles as sliding poles: complex pairs damped to ζ ≥ 0.7 (conjugates kept
    together), stable non-negative real poles kept, negative real poles (ringing at the
    Nyquist frequency) moved to 0, poles on or outside the unit circle replaced by ``zs``."""
    out: list[complex] = []
    for p in plant_poles:
        p = complex(p)
        if abs(p) >= 0.9999:
            out.append(zs)
        elif abs(p.imag) <= 1e-9 * max(1.0, abs(p)):
            out.append(max(p.real, 0.0))
        elif p.imag > 0:
            d = _damped(p, dt)
            out += [d, d.conjugate()]
    return out


def _pole_list(name: str, value, count: int) -> np.ndarray:
    """``--smc-option NAME=[...]``: ``count`` discrete poles (numbers or strings like "0.9+0.1j"),
    inside the unit circle, complex ones with their conjugates."""
    try:
        vals = [complex(str(v).replace(" ", "")) for v in (value if isinstance(value, (list, tuple)) else [value])]
    except ValueError:
        raise ConfigError(f"--smc-option {name}={value!r}: poles must be numbers or strings like \"0.9+0.1j\"") from None
    if len(vals) != count:
        raise ConfigError(f"--smc-option {name}: {count} pole(s) are needed for this nominal plant, got {len(vals)}")
    p = np.array(vals, dtype=complex)
    if np.any(np.abs(p) >= 1.0):
        raise ConfigError(f"--smc-option {name}: discrete poles must lie inside the unit circle, got {_poles(p)}")
    if not np.allclose(np.sort_complex(p), np.sort_complex(p.conj()), atol=1e-9):
        raise ConfigError(f"--smc-option {name}: complex poles need their conjugates, got {_poles(p)}")
    return p


def design_smc(nominal: NominalPlant, bandwidth_Hz: float, voltage_span: float, *, eps: float | None = None,
               alpha: float | None = None, k: float | None = None, sliding_poles=None,
               observer_poles=None) -> SMCDesign:
    """Integral sliding-mode design on the nominal plant (paper 003 eq. 25–42).

    Defaults (the module docstring): sliding poles z_s = exp(−2π·f_s·Ts) for the integral mode
    and the nominal plant's own poles except the delay pole at 0 (:func:`_sliding_poles`);
    observer gain G = 0, so the observer's poles are the nominal plant's (deadbeat for the static
    form); reaching law with boundary layer φ = 0.2 % of the voltage span, α = 1/φ,
    ε = 0.2·φ/Ts, k = q = min(2·2π·f_s, 0.5/Ts).

    Settable (``--smc-option``, paper 003's design parameters): ``eps`` ε (V/s) and ``k`` (1/s) of
    the reaching law S⁺ = (1 − k·Ts)·S − ε·Ts·tanh(α·S) (003 eq. 38, tanh for sgn), ``alpha``
    α (1/V), ``sliding_poles`` (n discrete poles of the sliding motion of the (n + 1)-state
    augmented plant, eq. 32–35, placed by Ackermann's formula for sliding surfaces; the
    remaining eigenvalue, 0, is the surface itself), ``observer_poles`` (n discrete poles of the Luenberger observer
    x̂⁺ = A x̂ + B δ + G (e − C x̂), eq. 40–42: G placed by Ackermann's formula on (Aᵀ, Cᵀ)).
    """
    dt = nominal.dt
    A, B, C = nominal.A, nominal.B, nominal.C
    n = A.shape[0]
    Ad = np.zeros((n + 1, n + 1))
    Ad[:n, :n] = A
    Ad[n, :n] = dt * C
    Ad[n, n] = 1.0
    Bd = np.r_[B, 0.0]
    zs = math.exp(-2 * math.pi * bandwidth_Hz * dt)
    if sliding_poles is None:
        plant_poles = sorted(np.roots(nominal.den), key=abs)[1:]  # drop the delay pole at 0
        poles = np.array([zs] + _sliding_poles(plant_poles, zs, dt), dtype=complex)
    else:
        poles = _pole_list("sliding_poles", sliding_poles, n)
    poly = np.real_if_close(np.poly(poles), tol=1e6).real
    M = _ackermann_row(Ad, Bd, poly)
    MB = float(M @ Bd)
    M = M / MB
    if observer_poles is None:
        G = np.zeros(n)  # observer of the correction channel: the nominal model itself (see the module docstring)
        obs = np.linalg.eigvals(A)
    else:
        obs = _pole_list("observer_poles", observer_poles, n)
        try:
            G = _ackermann_row(A.T, C.astype(float), np.real_if_close(np.poly(obs), tol=1e6).real)
        except ConfigError:
            raise ConfigError("--smc-option observer_poles: the nominal plant is not observable; the observer "
                              "cannot be placed") from None
    phi = 0.002 * voltage_span
    alpha_ = 1.0 / phi if alpha is None else float(alpha)
    eps_ = 0.2 * phi / dt if eps is None else float(eps)
    q = min(2 * 2 * math.pi * bandwidth_Hz, 0.5 / dt) if k is None else float(k)
    for name, v, ok in (("eps", eps_, eps_ >= 0), ("alpha", alpha_, alpha_ > 0), ("k", q, 0 <= q * dt < 2)):
        if not (math.isfinite(v) and ok):
            raise ConfigError(f"--smc-option {name}={v:g}: " + {"eps": "must be ≥ 0 (V/s)", "alpha": "must be > 0 (1/V)",
                                                                 "k": f"must be in [0, {2 / dt:g}) 1/s (|1 − k·Ts| < 1)"}[name])
    return SMCDesign(A, B, C, M[:n], float(M[n]), np.asarray(G, float), q, eps_, alpha_, poles, np.asarray(obs),
                     bandwidth_Hz, dt)


# ----------------------------------------------------------------------------------------------
# The loop
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ControllerRun:
    """One closed-loop simulation (arrays (N,) on the target's time base).

    reference : the target (unit); output : true plant output (unit); measured : output + noise; voltage_V : applied voltage
    (voltage_V[k] is held from k−1 to k); command_V : controller output before limits;
    error : output − reference; metrics : :func:`hystfit.invert.tracking_metrics` of the true
    output; steps : :func:`step_metrics` per step for step targets; limit_spans : where the
    limits acted; runtime_s : loop time; details : controller settings.
    """

    controller: str
    reference: np.ndarray
    output: np.ndarray
    measured: np.ndarray
    voltage_V: np.ndarray
    command_V: np.ndarray
    metrics: dict
    steps: tuple[dict, ...]
    limit_spans: tuple[Span, ...]
    runtime_s: float
    details: dict

    @property
    def error(self) -> np.ndarray:
        """output − reference (unit)."""
        return self.output - self.reference


def simulate_loop(plant: _Plant, r: np.ndarray, v0: float, controller: str, *, ff: np.ndarray | None,
                  pid: PIDGains | None, smc: SMCDesign | None, vmin: float, vmax: float,
                  max_slew: float | None, noise: np.ndarray, dt: float,
                  disturbance: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Run the sampled loop of the module docstring; returns (y, y_meas, voltage, command, limited mask).

    ``disturbance`` (N,), optional: an output disturbance added to the plant's output (so to y
    and to the measurement), for the disturbance-rejection bandwidth. ``smc-noinv`` is the
    sliding mode without inverse compensation: the feedforward is replaced by the constant
    initial voltage v0, so the sliding-mode correction alone moves the stage.
    Scalar Python arithmetic with preallocated arrays; the plant is stepped once per sample.
    """
    N = r.shape[0]
    y = np.empty(N)
    ym = np.empty(N)
    volt = np.empty(N)
    cmd = np.empty(N)
    limited = np.zeros(N, dtype=bool)
    dist = disturbance if disturbance is not None else np.zeros(N)
    y[0] = plant.start(v0) + dist[0]
    volt[0] = cmd[0] = v0
    step_max = float("inf") if max_slew is None else max_slew * dt
    use_ff = controller in ("ff", "ff+pid", "smc")
    ffa = ff if use_ff else None
    # PID state
    if pid is not None:
        kp, ki, kd = pid.kp, pid.ki, pid.kd
        a_d = pid.tf_s / (pid.tf_s + dt)
        b_d = kd / (pid.tf_s + dt)
        aw = dt / pid.tt_s
        clamp = pid.anti_windup == "clamp"
        integ = 0.0 if use_ff else v0
        dterm = 0.0
    # SMC state
    if smc is not None:
        A, B, C, G, Mx = smc.A, smc.B, smc.C, smc.G, smc.Mx
        Mp, q_ts, e_ts, alpha = smc.Mp, 1.0 - smc.q * dt, smc.eps * dt, smc.alpha
        MxA = Mx @ A
        MxB = float(Mx @ B)
        MxG = float(Mx @ G)
        xh = np.zeros(A.shape[0])
        p = 0.0
    prev_ym = None
    vprev = v0
    for k in range(N - 1):
        m = y[k] + noise[k]
        ym[k] = m
        rk = r[k]
        u_ff = ffa[k + 1] if ffa is not None else (v0 if controller == "smc-noinv" else 0.0)
        if controller == "ff":
            c = u_ff
        elif smc is not None:
            e = m - rk
            innov = e - float(C @ xh)
            S = float(Mx @ xh) + Mp * p
            s_next = q_ts * S - e_ts * math.tanh(alpha * S)
            p_next = p + dt * e
            delta = (s_next - float(MxA @ xh) - float(MxG) * innov - Mp * p_next) / MxB
            c = u_ff + delta
        else:
            e = rk - m
            integ += ki * dt * e
            if prev_ym is not None and kd != 0.0:
                dterm = a_d * dterm - b_d * (m - prev_ym)
            c = u_ff + kp * e + integ + dterm
        v = c
        if v > vmax:
            v = vmax
        elif v < vmin:
            v = vmin
        if v > vprev + step_max:
            v = vprev + step_max
        elif v < vprev - step_max:
            v = vprev - step_max
        if v != c:
            limited[k + 1] = True
        if pid is not None and controller != "ff":
            if clamp:
                if v != c and (c - v) * (ki * (rk - m)) > 0:
                    integ -= ki * dt * (rk - m)
            else:
                integ += aw * (v - c)
        if smc is not None:
            d_app = v - u_ff
            xh = A @ xh + B * d_app + G * innov
            p = p if v != c else p_next
        prev_ym = m
        cmd[k + 1] = c
        volt[k + 1] = v
        vprev = v
        y[k + 1] = plant.advance(k + 1, v) + dist[k + 1]
    ym[N - 1] = y[N - 1] + noise[N - 1]
    return y, ym, volt, cmd, limited


def step_metrics(target: Target, y: np.ndarray) -> list[dict]:
    """Rise and settling of every step of a step target (paper 002 Table 6 and the usual definitions).

    For a step L0 → L1 at t0 (response until the next step), with s = (y − L0)/(L1 − L0):
    ``t90_s`` = first time s ≥ 0.9 after t0 (002's Tr); ``rise_time_s`` = t(s ≥ 0.9) − t(s ≥ 0.1)
    (10→90 %); ``settling_time_5pct_s`` / ``settling_time_2pct_s`` = time after which
    |s − 1| stays ≤ 5 % / 2 % until the end of the hold (002's Ts uses ±5 %; NaN when not
    settled); ``overshoot_pct`` = 100·max(0, max s − 1); ``steady_state_error_<unit>`` = mean of
    y − L1 over the last 10 % of the hold; ``e_max_settled_<unit>`` and ``rmse_settled_<unit>`` =
    max |y − L1| and sqrt(mean (y − L1)²) *after the transient*, from the ±5 % settling time to the
    end of the hold (paper 002 Table 6's emax and RMSE of a step: 0.042 and 0.009 µm, far below
    the step's transient; NaN when not settled). The trajectory's own max error and RMSE
    (:func:`~hystfit.invert.tracking_metrics`, over every sample) include the transient.
    """
    out = []
    dt = target.dt
    for st in target.steps:
        seg = y[st.index:st.stop]
        span = st.to_level - st.from_level
        s = (seg - st.from_level) / span
        t = np.arange(seg.size) * dt

        def first(cond):
            idx = np.flatnonzero(cond)
            return float(t[idx[0]]) if idx.size else float("nan")

        def settle(band):
            out_of = np.flatnonzero(np.abs(s - 1.0) > band)
            if out_of.size == 0:
                return 0.0
            if out_of[-1] == s.size - 1:
                return float("nan")
            return float(t[out_of[-1] + 1])

        t10, t90 = first(s >= 0.1), first(s >= 0.9)
        tail = seg[-max(1, seg.size // 10):]
        ts5 = settle(0.05)
        if math.isfinite(ts5):
            e_set = seg[int(round(ts5 / dt)):] - st.to_level
            e_max_set, rmse_set = float(np.max(np.abs(e_set))), float(np.sqrt(np.mean(e_set ** 2)))
        else:
            e_max_set = rmse_set = float("nan")
        out.append({"t_s": st.index * dt, "from": st.from_level, "to": st.to_level, "t90_s": t90,
                    "rise_time_s": t90 - t10, "settling_time_5pct_s": ts5,
                    "settling_time_2pct_s": settle(0.02), "overshoot_pct": 100.0 * max(0.0, float(s.max()) - 1.0),
                    f"steady_state_error_{target.unit}": float(np.mean(tail) - st.to_level),
                    f"e_max_settled_{target.unit}": e_max_set, f"rmse_settled_{target.unit}": rmse_set})
    return out


# ----------------------------------------------------------------------------------------------
# Orchestration
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TrackResult:
    """The closed-loop comparison.

    target, unit; inversion : the feedforward (:class:`hystfit.invert.InversionResult`);
    plant_path, plant_cells : the plant's parameter file and cells per segment; nominal :
    :class:`NominalPlant`; pid : gains used by ``pid``/``ff+pid`` (None if neither ran); smc :
    :class:`SMCDesign` (None unless ``smc`` ran); runs : one :class:`ControllerRun` per
    controller; noise_std, seed : measurement noise (unit) and its seed; limits : as in the
    inversion; notes.
    """

    params_path: str
    plant_path: str
    model_name: str
    plant_model_name: str
    unit: str
    target: Target
    inversion: InversionResult
    plant_cells: tuple[tuple[str, tuple[CellUse, ...]], ...]
    nominal: NominalPlant
    pid: PIDGains | None
    smc: SMCDesign | None
    runs: tuple[ControllerRun, ...]
    noise_std: float
    seed: int
    limits: dict
    notes: tuple[str, ...] = ()

    def table(self) -> list[dict]:
        """One row per controller: paper 002 Table 4/5 figures (and Table 6 for steps)."""
        rows = []
        u = self.unit
        for run in self.runs:
            m = run.metrics
            row = {"controller": run.controller, f"max_error_{u}": m[f"max_error_{u}"], f"rmse_{u}": m[f"rmse_{u}"],
                   "max_error_pct": m["max_error_pct_of_stroke"], "rmse_pct": m["rmse_pct_of_stroke"]}
            if run.steps:
                row["t90_s"] = float(np.nanmean([s["t90_s"] for s in run.steps]))
                row["rise_time_s"] = float(np.nanmean([s["rise_time_s"] for s in run.steps]))
                for key in ("settling_time_5pct_s", "settling_time_2pct_s"):
                    vals = [s[key] for s in run.steps]
                    row[key] = float("nan") if any(not np.isfinite(v) for v in vals) else float(np.mean(vals))
                row["overshoot_pct"] = float(np.max([s["overshoot_pct"] for s in run.steps]))
                for key in (f"e_max_settled_{u}", f"rmse_settled_{u}"):  # worst step (NaN: one did not settle)
                    vals = [s[key] for s in run.steps]
                    row[key] = float("nan") if any(not np.isfinite(v) for v in vals) else float(np.max(vals))
            row["limited_pct"] = 100.0 * sum(s.n for s in run.limit_spans) / max(1, self.target.n - 1)
            rows.append(row)
        return rows


def check_smc_options(options: dict | None) -> dict:
    """``--smc-option`` keys checked against :data:`SMC_OPTIONS` (values are checked by :func:`design_smc`)."""
    options = dict(options or {})
    bad = [k for k in options if k not in SMC_OPTIONS]
    if bad:
        raise ConfigError(f"--smc-option {bad[0]!r}: unknown; valid options: {', '.join(SMC_OPTIONS)}")
    for key in ("eps", "alpha", "k"):
        if key in options and (isinstance(options[key], bool) or not isinstance(options[key], (int, float))):
            raise ConfigError(f"--smc-option {key}={options[key]!r}: must be a number")
    return options


def parse_controllers(text: str | Sequence[str]) -> list[str]:
    """``"pid,ff"`` → ``["pid", "ff"]`` (validated, duplicates refused)."""
    names = [s.strip().lower() for s in (text.split(",") if isinstance(text, str) else text)]
    bad = [n for n in names if n not in CONTROLLERS]
    if not names or bad or "" in names:
        raise ConfigError(f"--controller {text!r}: choose from {', '.join(CONTROLLERS)} (comma-separated)")
    if len(set(names)) != len(names):
        raise ConfigError(f"--controller {text!r}: a controller is listed twice")
    return names


def _check_track_options(controllers: Sequence[str], *, anti_windup: str, noise_std: float, seed: int,
                         max_slew: float | None, kp, ki, kd, bandwidth_Hz, smc_options, pf: ParamsFile,
                         plant_pf: ParamsFile) -> None:
    """The options of :func:`track` that :func:`invert_target` does not check (one-line ConfigError)."""
    if anti_windup not in ("backcalc", "clamp"):
        raise ConfigError(f"anti-windup {anti_windup!r}: choose backcalc or clamp")
    if not (math.isfinite(noise_std) and noise_std >= 0):
        raise ConfigError(f"--noise {noise_std!r}: the noise σ must be a finite number >= 0")
    check_seed(seed)
    if max_slew is not None and not (math.isfinite(float(max_slew)) and float(max_slew) > 0):
        raise ConfigError(f"--max-slew {max_slew!r}: the slew-rate limit must be a finite number > 0 (V/s)")
    for flag, g in (("--kp", kp), ("--ki", ki), ("--kd", kd)):
        if g is not None and not (math.isfinite(g) and g >= 0):
            raise ConfigError(f"{flag} {g:g}: PID gains must be finite and >= 0")
    gains_given = any(g is not None for g in (kp, ki, kd))
    if gains_given and not any(c in ("pid", "ff+pid") for c in controllers):
        raise ConfigError("--kp/--ki/--kd apply to the pid and ff+pid controllers; add one to the controllers")
    if smc_options and not any(c.startswith("smc") for c in controllers):
        raise ConfigError("--smc-option applies to the smc and smc-noinv controllers; add one to the controllers")
    if gains_given and bandwidth_Hz is not None and not any(c.startswith("smc") for c in controllers):
        raise ConfigError("--bandwidth sets automatic gains (and the sliding mode); drop it or drop --kp/--ki/--kd")
    pf.check_unit(plant_pf.unit, f"the plant {plant_pf.path}",
                  f"identify the plant from captures in {pf.unit} (or the controller's model from captures in "
                  f"{plant_pf.unit})")


def _plant_choices(pf: ParamsFile, plant_pf: ParamsFile, inv: InversionResult, method: str) -> list[SegmentChoice]:
    """The plant's cells per segment: the feedforward's own, or ``plant_pf``'s at the conditions it settled on."""
    if plant_pf is pf:
        return list(inv.choices)
    out = []
    for ch in inv.choices:
        cells, query, clamped = select_cells(plant_pf, ch.condition if all(map(math.isfinite, ch.condition))
                                             else (1.0, ch.condition[1]), method)
        out.append(SegmentChoice(ch.segment, ch.condition, query, clamped, cells, (), True, "plant"))
    return out


@dataclass(frozen=True, eq=False)
class ControllerDesign:
    """The controllers of one :func:`track` run, designed on the nominal plant (None: not needed)."""

    nominal: NominalPlant
    pid: PIDGains | None
    smc: SMCDesign | None


def design_controllers(nominal: NominalPlant, controllers: Sequence[str], voltage_span: float, *, kp=None,
                       ki=None, kd=None, bandwidth_Hz: float | None = None, anti_windup: str = "backcalc",
                       smc_options: dict | None = None) -> ControllerDesign:
    """The PID (given gains, or :func:`auto_pid`) and the sliding mode (:func:`design_smc`) the
    ``controllers`` need; the sliding mode's bandwidth defaults to the automatic PID's."""
    pid = None
    if any(c in ("pid", "ff+pid") for c in controllers):
        pid = (given_pid(nominal, kp or 0.0, ki or 0.0, kd or 0.0, anti_windup=anti_windup)
               if any(g is not None for g in (kp, ki, kd)) else auto_pid(nominal, bandwidth_Hz, anti_windup))
    smc = None
    if any(c.startswith("smc") for c in controllers):
        bw = bandwidth_Hz if bandwidth_Hz is not None else auto_pid(nominal).bandwidth_Hz
        smc = design_smc(nominal, bw, voltage_span, **check_smc_options(smc_options))
    return ControllerDesign(nominal, pid, smc)


def _run_details(name: str, design: ControllerDesign) -> dict:
    """The ``details`` of a :class:`ControllerRun`: feedforward use and the controller's design."""
    pid, smc = design.pid, design.smc
    details: dict = {"uses_feedforward": name not in ("pid", "smc-noinv")}
    if name in ("pid", "ff+pid") and pid is not None:
        details["pid"] = {"kp": pid.kp, "ki": pid.ki, "kd": pid.kd, "tf_s": pid.tf_s, "tt_s": pid.tt_s,
                          "anti_windup": pid.anti_windup, "rule": pid.rule, "bandwidth_Hz": pid.bandwidth_Hz,
                          "gain_margin": pid.gain_margin, "phase_margin_deg": pid.phase_margin_deg}
    if name.startswith("smc") and smc is not None:
        details["smc"] = {"design": smc.describe(), "Mx": smc.Mx.tolist(), "Mp": smc.Mp, "G": smc.G.tolist(),
                          "q_per_s": smc.q, "eps_V_per_s": smc.eps, "alpha_per_V": smc.alpha,
                          "bandwidth_Hz": smc.bandwidth_Hz}
    return details


def _run_controller(name: str, plant: _Plant, target: Target, inv: InversionResult, design: ControllerDesign, *,
                    max_slew: float | None, noise: np.ndarray, disturbance: np.ndarray | None,
                    unit: str) -> ControllerRun:
    """One closed loop of :func:`track` simulated and scored."""
    dt = target.dt
    t0 = time.perf_counter()
    with np.errstate(all="ignore"):  # a diverging plant model is reported by track, not warned about
        y, ym, volt, cmd, limited = simulate_loop(
            plant, target.y, inv.initial_voltage_V, name, ff=inv.desired_voltage_V,
            pid=design.pid if name in ("pid", "ff+pid") else None,
            smc=design.smc if name.startswith("smc") else None, vmin=inv.limits["vmin_V"],
            vmax=inv.limits["vmax_V"], max_slew=max_slew, noise=noise, dt=dt, disturbance=disturbance)
    wall = time.perf_counter() - t0
    spans = find_spans(limited, cmd - volt, dt, "limit")
    return ControllerRun(name, target.y, y, ym, volt, cmd, tracking_metrics(y, target.y, unit),
                         tuple(step_metrics(target, y)) if target.steps else (), tuple(spans), wall,
                         _run_details(name, design))


@one_blas_thread
def track(pf: ParamsFile, target: Target, controllers: Sequence[str] = ("ff+pid",), *,
          plant_pf: ParamsFile | None = None, method: str = "interpolate",
          condition: tuple[float, float] | None = None, initial_voltage: float | None = None,
          vmin: float | None = None, vmax: float | None = None, max_slew: float | None = None,
          noise_std: float = 0.0, seed: int = 0, kp: float | None = None, ki: float | None = None,
          kd: float | None = None, bandwidth_Hz: float | None = None, anti_windup: str = "backcalc",
          smc_options: dict | None = None, disturbance: np.ndarray | None = None, progress=None) -> TrackResult:
    """Simulate the closed loop for each controller (module docstring).

    Parameters
    ----------
    pf : the controller's look-up table (feedforward inverse, nominal plant).
    target : reference trajectory (unit of ``pf``).
    controllers : names from :data:`CONTROLLERS`.
    plant_pf : the plant's table (default ``pf``); its cells are chosen at the conditions the
        feedforward settled on.
    method, condition, initial_voltage, vmin, vmax : as :func:`hystfit.invert.invert_target`.
    max_slew : slew-rate limit (V/s) of the amplifier, applied inside the loop.
    noise_std : measurement noise σ (unit), Gaussian from ``np.random.default_rng(seed)``.
    kp, ki, kd : PID gains (V/unit, V/(unit·s), V·s/unit); any given ⇒ the others default to 0;
        none ⇒ :func:`auto_pid`.
    bandwidth_Hz : bandwidth for the automatic PID and the sliding mode.
    anti_windup : ``"backcalc"`` or ``"clamp"``.
    smc_options : :data:`SMC_OPTIONS` for :func:`design_smc` (``smc``, ``smc-noinv``).
    disturbance : optional output disturbance (N,) in the unit of ``pf``, added to the plant output.
    """
    controllers = parse_controllers(list(controllers))
    plant_pf = pf if plant_pf is None else plant_pf
    _check_track_options(controllers, anti_windup=anti_windup, noise_std=noise_std, seed=seed, max_slew=max_slew,
                         kp=kp, ki=ki, kd=kd, bandwidth_Hz=bandwidth_Hz, smc_options=smc_options, pf=pf,
                         plant_pf=plant_pf)
    inv = invert_target(pf, target, method=method, condition=condition, initial_voltage=initial_voltage,
                        vmin=vmin, vmax=vmax, max_slew=None, progress=progress)
    max_slew = None if max_slew is None else float(max_slew)
    plant_choices = _plant_choices(pf, plant_pf, inv, method)
    design = design_controllers(nominal_plant(pf, inv.choices, target.dt), controllers,
                                inv.limits["vmax_V"] - inv.limits["vmin_V"], kp=kp, ki=ki, kd=kd,
                                bandwidth_Hz=bandwidth_Hz, anti_windup=anti_windup, smc_options=smc_options)
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(target.n) * noise_std if noise_std > 0 else np.zeros(target.n)
    notes = list(inv.notes)
    runs = []
    if progress:
        progress("start", {"total": len(controllers)})
    for name in controllers:
        run = _run_controller(name, _Plant(plant_pf, plant_choices, target.n, target.dt), target, inv, design,
                              max_slew=max_slew, noise=noise, disturbance=disturbance, unit=pf.unit)
        if not np.all(np.isfinite(run.output)):
            notes.append(f"{name}: the closed loop diverged (non-finite output)")
        else:
            lost = lost_loop_note(run, target, design.nominal)
            if lost is not None:
                notes.append(lost)
        runs.append(run)
        if progress:
            progress("advance", {"label": name})
    plant_cells = tuple((ch.segment.label, ch.cells) for ch in plant_choices)
    return TrackResult(pf.path, plant_pf.path, pf.model_name, plant_pf.model_name, pf.unit, target, inv, plant_cells,
                       design.nominal, design.pid, design.smc, tuple(runs), float(noise_std), int(seed),
                       dict(inv.limits, max_slew_V_per_s=max_slew), tuple(notes))


#: a feedback loop whose error exceeds this share of the target's stroke (RMS) does not hold it
LOST_LOOP_RMS_SHARE = 0.5


def lost_loop_note(run: ControllerRun, target, nominal) -> str | None:
    """A note when a feedback controller's simulated loop does not hold the target — its RMS error
    above :data:`LOST_LOOP_RMS_SHARE` of the stroke, or pinned at the voltage limits most of the
    time — with the likely cause: the loop is unstable on this plant, the automatic tuning's nominal
    plant missing its dynamics. A blind test's ``pid`` and ``ff+pid`` on a stage with a lightly
    damped resonance ran to 1030 % of the stroke, and the report said only that the voltage limits
    had acted, beside the nominal design's margins (GM 2.5, PM 94°). None for ``ff`` (no loop)."""
    if run.controller == "ff":
        return None
    stroke = float(np.ptp(target.y)) or 1.0
    rms = float(np.sqrt(np.mean(run.error ** 2)))
    limited = 100.0 * sum(s.n for s in run.limit_spans) / max(1, target.n - 1)
    if rms <= LOST_LOOP_RMS_SHARE * stroke and limited <= 50.0:
        return None
    what = getattr(nominal, "description", None)
    return (f"warning: {run.controller}: the closed loop does not hold the target (RMS error {100 * rms / stroke:.0f} % of the "
            f"stroke, at the voltage limits {limited:.0f} % of the time): it is unstable on this plant — the "
            f"tuning's margins hold for its nominal plant{f' ({what})' if what else ''}, not for the plant's own "
            "dynamics; lower --bandwidth or give --kp/--ki, or use -c smc")


# ----------------------------------------------------------------------------------------------
# Bandwidths (paper 003's tracking and disturbance-rejection figures)
# ----------------------------------------------------------------------------------------------

#: cycles simulated per frequency; the first ones are left out of the gain (start transient)
BANDWIDTH_CYCLES, BANDWIDTH_SKIP_CYCLES = 6, 2


def _gain_at(x: np.ndarray, f_Hz: float, dt: float, skip: int) -> complex:
    """Complex amplitude of x at f (least squares on sin, cos and an offset over x[skip:])."""
    k = np.arange(skip, x.shape[0]) * dt
    X = np.column_stack([np.ones_like(k), np.cos(2 * np.pi * f_Hz * k), np.sin(2 * np.pi * f_Hz * k)])
    c, *_ = np.linalg.lstsq(X, x[skip:], rcond=None)
    return complex(c[1], -c[2])


def _crossing(freqs: np.ndarray, mags: np.ndarray, level: float, below: bool) -> float:
    """The lowest frequency where |·| crosses ``level`` (going below it if ``below``, else above),
    interpolated linearly in (log f, dB); 0.0 when the lowest grid frequency is already past it
    (e.g. |S| = 1 everywhere: feedforward alone rejects nothing), NaN when it never crosses on
    the grid (the bandwidth lies beyond it)."""
    db, ldb = 20 * np.log10(np.maximum(mags, 1e-300)), 20 * math.log10(level)
    if (below and db[0] < ldb) or (not below and db[0] >= ldb - 1e-9):
        return 0.0
    for i in range(1, freqs.size):
        a, b = db[i - 1] - ldb, db[i] - ldb
        if (below and a >= 0 > b) or (not below and a < 0 <= b):
            w = a / (a - b)
            return float(math.exp(math.log(freqs[i - 1]) + w * (math.log(freqs[i]) - math.log(freqs[i - 1]))))
    return float("nan")


@one_blas_thread
def measure_bandwidths(pf: ParamsFile, controllers: Sequence[str], *, amplitude: float, offset: float, fs: float,
                       freqs_Hz: Sequence[float] | None = None, **track_options) -> dict:
    """Tracking (−3 dB) and disturbance-rejection (0 dB) bandwidths of each controller, by simulation.

    Tracking: the reference is paper 002's sine of ``amplitude`` (peak to peak) about ``offset``
    at each frequency; T(f) = Y(f)/R(f) at the fundamental, over the cycles after the first
    :data:`BANDWIDTH_SKIP_CYCLES`; the bandwidth is the lowest frequency where |T| falls below
    1/√2 (−3 dB). Disturbance rejection: the reference is constant (at ``offset`` + amplitude/2)
    and a sinusoidal output disturbance of amplitude/2 is added to the plant output;
    S(f) = Y(f)/D(f); the bandwidth is the lowest frequency where |S| reaches 1 (0 dB: the
    loop no longer attenuates the disturbance) — paper 003's two figures. Interpolated in
    (log f, dB); NaN (reported as "beyond the grid") when no crossing lies on the grid.
    ``freqs_Hz`` defaults to 12 log-spaced frequencies from fs/2000 to fs/5. The loops are
    those of :func:`track` (same plant, limits, noise, gains): ``track_options`` go there.
    """
    freqs = np.asarray(freqs_Hz if freqs_Hz is not None else np.geomspace(fs / 2000, fs / 5, 12), dtype=float)
    if freqs.size < 2 or not np.all(np.isfinite(freqs)) or np.any(freqs <= 0) or np.any(freqs >= fs / 2):
        raise ConfigError(f"bandwidth frequencies must be ≥ 2 values in (0, {fs / 2:g}) Hz")
    freqs = np.sort(freqs)
    T = {c: [] for c in controllers}
    S = {c: [] for c in controllers}
    for f in freqs:
        tgt = sine_target(amplitude, float(f), BANDWIDTH_CYCLES, fs, offset=offset, unit=pf.unit)
        skip = int(round(BANDWIDTH_SKIP_CYCLES * fs / f))
        res = track(pf, tgt, controllers, **track_options)
        R = _gain_at(tgt.y, f, tgt.dt, skip)
        for run in res.runs:
            T[run.controller].append(abs(_gain_at(run.output, f, tgt.dt, skip) / R))
        const = target_from_array(np.full(tgt.n, offset + 0.5 * amplitude), tgt.dt, unit=pf.unit,
                                  description="constant", frequency_Hz=float(f))
        d = 0.5 * amplitude * np.sin(2 * np.pi * f * np.arange(tgt.n) * tgt.dt)
        res = track(pf, const, controllers, disturbance=d, **track_options)
        D = _gain_at(d, f, tgt.dt, skip)
        for run in res.runs:
            S[run.controller].append(abs(_gain_at(run.output, f, tgt.dt, skip) / D))
    out = {"freqs_Hz": freqs.tolist(), "amplitude": amplitude, "offset": offset, "controllers": {}}
    for c in controllers:
        t, s = np.array(T[c]), np.array(S[c])
        out["controllers"][c] = {"tracking_gain": t.tolist(), "sensitivity_gain": s.tolist(),
                                 "tracking_bandwidth_Hz": _crossing(freqs, t, 1 / math.sqrt(2), True),
                                 "disturbance_bandwidth_Hz": _crossing(freqs, s, 1.0, False)}
    return out
