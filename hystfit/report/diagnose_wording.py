"""The wording of ``hystfit diagnose``: every English sentence of a diagnosis, from its numbers.

:mod:`hystfit.diagnose` computes records — :class:`hystfit.diagnose.Finding` (a strong finding of
the where-analysis: a kind and its numbers), :class:`hystfit.diagnose.Evidence` (an effect's
signature, fitted parameters and held-out numbers), reason codes of the hold-out split and of the
reconciliation — and this module turns them into the sentences of ``diagnosis.json`` (``pointers``,
``evidence``, ``split.why``, ``split.description``, ``noise.method``, the ``definition`` entries,
``reconciliation[].why``; :func:`hystfit.report.diagnose_report.diagnosis_document` places them),
of the console and of ``diagnosis.md``. It reads records and plain
numbers only and imports nothing from :mod:`hystfit.diagnose`.
"""

from __future__ import annotations

import math

from typing import TYPE_CHECKING, Iterable, Sequence

import numpy as np

from .plots import display_unit

if TYPE_CHECKING:  # records only; this module never imports the orchestration at run time
    from ..diagnose import Evidence, Finding

__all__ = [
    "NOISE_METHOD",
    "NOISE_METHOD_REFINED",
    "DEFINITIONS",
    "noise_method_text",
    "split_why",
    "split_description",
    "pointer_text",
    "pointers_text",
    "evidence_text",
    "creep_character",
    "reconciliation_why",
    "not_named_reasons",
    "best_not_named_text",
    "loop_position_text",
]

#: ``noise.method``: how the floor was estimated.
NOISE_METHOD = ("1.4826·MAD of the third difference (−1,3,−3,1)/√20 of the base residual, "
                "median over the captures")
#: appended to :data:`NOISE_METHOD` when the floor was refined with the final model's residual.
NOISE_METHOD_REFINED = ("; per capture the smaller of the estimates from the base model's and from the final "
                        "model's residual (the base residual held fast model error)")

#: ``noise.method`` per method code of :func:`hystfit.diagnose.estimate_noise`.
NOISE_METHODS = {"mad_third_difference": NOISE_METHOD}


def noise_method_text(noise: dict) -> str:
    """How the noise floor was estimated (``noise.method``), from the ``noise`` section's method code
    and its ``refined`` flag."""
    return NOISE_METHODS[noise["method"]] + (NOISE_METHOD_REFINED if noise.get("refined") else "")


def doubtful_floor_text(noise: dict, unit: str) -> str:
    """Why the noise floor cannot be trusted (:func:`hystfit.diagnose.noise_floor_doubtful`), and
    what to do."""
    return (f"the noise floor σ = {noise['sigma']:.3g} {unit} is {noise['sigma'] / noise['repeatability_out']:.0f}× the "
            f"cycle-to-cycle repeatability ({noise['repeatability_out']:.3g} {unit}), and the fastest drive has only "
            f"{noise['samples_per_cycle_min']:.3g} samples per cycle: the floor measures the residual's own change "
            "between samples, not the sensor, and is overestimated. Effects whose gain lies below it go unnamed, and a "
            "verdict that the model is as good as the noise allows does not hold; record at a higher sample rate "
            "(at least 20 samples per cycle)")


#: the ``definition`` entries of the where-analysis sections.
DEFINITIONS = {
    "by_loop_position": "near = within 10 % of the half-cycle stroke from a turning point of the input",
    "by_time": "first cycle = the first period of a periodic capture, else the first 10 % of it",
    "by_band": ("bands relative to each capture's excitation frequency f0: drift < f0/2, low harmonics "
                "f0/2…5.5·f0, high harmonics 5.5·f0…50.5·f0, broadband above; shares of the residual "
                "power above the white-noise expectation"),
    "by_level": "mean residual per tenth of each capture's input range (0 = lowest input), per branch",
}


# ----------------------------------------------------------------------------------------------
# The hold-out split
# ----------------------------------------------------------------------------------------------


def split_why(reason: str, swept_sources: Sequence[str] = ()) -> str:
    """Why the hold-out scheme was chosen (``split.why``), from the reason code of
    :func:`hystfit.diagnose.split_choice`."""
    if reason == "swept":
        return ("the amplitude of " + ", ".join(swept_sources) + " changes within the capture: a temporal split "
                "would test an amplitude extrapolation, so whole captures at interior frequencies are held out")
    if reason == "swept_no_interior":
        return ("the amplitude of " + ", ".join(swept_sources) + " changes within the capture and no capture at an "
                "interior frequency can be held out (per-condition mode, or fewer than three drive frequencies): a "
                "temporal split would test an amplitude extrapolation, so the middle cycles of every capture are "
                "held out (an interpolation)")
    return {"requested": "requested", "stationary": "every capture is stationary"}[reason]


def split_description(kind: str, fit_fraction: float, in_time: Sequence[str] = ()) -> str:
    """What was fitted and what was held out (``split.description``); ``in_time``: the broadband
    captures a ``"capture"`` split divides in time."""
    if kind == "cycles":
        return ("every fit (base, base + effect, placebo) uses the cycles before and after the middle "
                f"{100 * (1 - fit_fraction):.0f} % of each capture's cycles; those middle cycles are held out and only "
                "they score 'heldout_*' (an interpolation in time and, for a rising-amplitude sine, in amplitude; the "
                "model is simulated from the start, so its state everywhere is its own)")
    if kind == "capture":
        text = ("every fit (base, base + effect, placebo) uses the captures at the lowest and highest drive "
                "frequencies; the captures at the frequencies in between are held out whole and "
                + ("" if in_time else "only they ") + "score 'heldout_*' (an interpolation in frequency, at every "
                f"amplitude); only their own per-capture coefficients (a drift's offset and rate) are fitted, on "
                f"their first {100 * fit_fraction:.0f} %")
        if in_time:
            text += ("; " + ", ".join(in_time) + (" has" if len(in_time) == 1 else " have") + " no one drive "
                     f"frequency (broadband) and {'is' if len(in_time) == 1 else 'are'} split in time: the first "
                     f"{100 * fit_fraction:.0f} % fitted, the rest held out and scored too")
        return text
    return ("every fit (base, base + effect, placebo) uses the first part of each capture: whole cycles "
            f"(round({fit_fraction:g} × cycles)) of periodic captures, the first {100 * fit_fraction:.0f} % of the "
            "samples of the others; the remaining samples of every capture are held out and only they score "
            "'heldout_*' (the model is simulated from the start of the capture, so its state at the split is its own)")


# ----------------------------------------------------------------------------------------------
# Where: the findings
# ----------------------------------------------------------------------------------------------


def _how(v: dict) -> str:
    return " when every condition is fitted on its own" if v.get("alone") else ""


def _calibration(v: dict, u: str) -> str:
    return ("per-capture calibration: " + "; ".join(
        f"{name} offset {offset:+.3g} {u}, gain {gain:.4f}" for name, offset, gain in v["captures"])
        + " against the common fit — a sensor re-zeroed or re-scaled between recordings, not an effect of the "
          "actuator: fitted per capture as part of the base before any effect was tested; identify with the "
          "`drift` block (offsets) or align offsets (`simulate --align-offset`)")


def _frequency_trend(band: str, verb: str):
    return lambda v, u: (f"{band} frequencies: the gap above noise {verb} with the excitation frequency{_how(v)} "
                         f"(∝ f^{v['exponent']:.2f})")


def _later_time(v: dict, u: str) -> str:
    return (f"later time: fitted on the first part of each capture, the model misses {v['ratio']:.2f}× more (above "
            "noise) on the later part")


#: One sentence per finding kind: a function of the finding's numbers and the displayed unit.
_FINDINGS = {
    "frequency_grows": _frequency_trend("high", "grows"),
    "frequency_shrinks": _frequency_trend("low", "shrinks"),
    "amplitude_large": lambda v, u: (f"large amplitudes: the gap grows with the square of the amplitude or faster"
                                     f"{_how(v)} (∝ A^{v['exponent']:.2f}; a scale-invariant loop-shape error grows "
                                     "∝ A)"),
    "later_time_swept": lambda v, u: (_later_time(v, u) + " — but the drive amplitude changes within the captures, "
                                      "so this compares small loops with large ones; it is not by itself evidence of "
                                      "creep or drift"),
    "later_time": _later_time,
    "heldout_cycles": lambda v, u: (f"held-out cycles: fitted on the cycles before and after them, the model misses "
                                    f"{v['ratio']:.2f}× more (above noise) on the middle cycles of each capture"),
    "heldout_captures": lambda v, u: (f"held-out captures: fitted on the other drive frequencies, the model misses "
                                      f"{v['ratio']:.2f}× more (above noise) on the interior frequencies it did not "
                                      "see"),
    "low_frequency_share": lambda v, u: (f"low frequencies: {100 * v['share']:.0f} % of the residual power above noise "
                                         "lies below half the excitation frequency (slow trends)"),
    "high_frequency_share": lambda v, u: (f"high frequencies: {100 * v['share']:.0f} % of the residual power above "
                                          "noise lies above the fifth harmonic of the excitation (sharp features: "
                                          "turning points, steps, ringing)"),
    "long_captures": lambda v, u: (f"long captures: the longest captures miss {v['ratio']:.1f}× more (above noise) "
                                   "than the others"),
    "level_dependent": lambda v, u: (f"displacement level: the error follows the input level the same way on both "
                                     f"branches ({v['level_rms']:.3g} {u} RMS, against {v['opposite_rms']:.3g} {u} "
                                     "with opposite signs on the two branches): a static output nonlinearity"),
    "branch_opposite": lambda v, u: (f"branches: at the same input level the error has opposite signs on the two "
                                     f"branches ({v['opposite_rms']:.3g} {u} RMS, against {v['level_rms']:.3g} {u} "
                                     "common to both): the loop is too narrow or too wide, a lag or lead"),
    "branch_bias": lambda v, u: (f"branches: the model sits {v['ascending_mean']:+.3g} {u} on the ascending and "
                                 f"{v['descending_mean']:+.3g} {u} on the descending branch on average (opposite "
                                 "biases: lag or branch asymmetry)"),
    "turning_points": lambda v, u: (f"turning points: the error near turning points is {v['ratio']:.1f}× the "
                                    "mid-stroke error"),
    "mid_stroke": lambda v, u: f"mid-stroke: the error mid-stroke is {v['ratio']:.1f}× the error near turning points",
    "start_up": lambda v, u: f"start-up: the first cycle misses {v['ratio']:.1f}× more than the later ones",
    "no_concentration": lambda v, u: ("no concentration: the residual is spread evenly over conditions, branches, time "
                                      "and frequency"),
    "calibration": _calibration,
}


def pointer_text(finding: "Finding", unit: str) -> str:
    """One finding of the where-analysis as a plain sentence (``where.pointers``)."""
    return _FINDINGS[finding.kind](finding.values, display_unit(unit))


def pointers_text(findings: Iterable["Finding"], unit: str) -> list[str]:
    """The findings as sentences, in order."""
    return [pointer_text(f, unit) for f in findings]


# ----------------------------------------------------------------------------------------------
# Which: the evidence of an effect
# ----------------------------------------------------------------------------------------------


def creep_character(tau_s: Sequence[float], gain: Sequence[float], drive_Hz: float | None) -> str:
    """What the fitted creep chain *is*, from where its gain sits: a relaxation within about one
    drive period is rate dependence (the loop widens with frequency); one over many periods is slow
    creep (the output keeps moving after a move)."""
    g = np.asarray(gain, float)
    t = np.asarray(tau_s, float)
    if g.size == 0 or not np.any(g > 0):
        return "no creep gain fitted"
    tau = float(np.exp(np.sum(g * np.log(t)) / np.sum(g)))  # gain-weighted (geometric) mean time constant
    if drive_Hz is not None and np.isfinite(drive_Hz) and drive_Hz > 0 and tau <= 2.0 / drive_Hz:
        return (f"most of the gain relaxes within τ ≈ {1e3 * tau:.3g} ms, about {tau * drive_Hz:.2g} drive period(s): "
                "a relaxation on the scale of the drive period — rate dependence of the loop rather than slow creep")
    return f"most of the gain relaxes over τ ≈ {tau:.3g} s: slow creep (the output keeps moving after a move)"


def _grows_in_time(ev: "Evidence") -> list[str]:
    r = ev.heldout_to_fit_ratio
    return [f"the gap grows {r:.2f}× into later time"] if r is not None and r > 1.15 else []


def _slow_share(ev: "Evidence") -> str:
    return (f"{100 * ev.low_frequency_share:.0f} % of the residual power above noise is below half the excitation "
            "frequency")


def _with_frequency(ev: "Evidence") -> list[str]:
    b = ev.frequency_exponent
    return [f"the gap grows with frequency as f^{b:.2f}"] if b is not None else []


def _dynamics(ev: "Evidence", sig: str, u: str) -> list[str]:
    p = ev.params
    lag = (f" ({p['phase_lag_at_highest_excitation_deg']:.2f}° lag at {p['at_highest_excitation_Hz']:g} Hz)"
           if "phase_lag_at_highest_excitation_deg" in p else "")
    lo, hi = (p.get("search_fn_Hz") or [None, None])[:2]
    edge = ""  # a fit that ends on its search range's edge found no interior optimum (a blind test's 4500 Hz)
    z_lo, z_hi = (p.get("search_zeta") or [None, None])[:2]
    from ..blocks.dynamics import EDGE_RTOL

    if hi is not None and p["fn_Hz"] >= hi * (1 - EDGE_RTOL):
        edge = f", at the top of its search range ({lo:.4g}…{hi:.4g} Hz): the data show no resonance inside it"
    elif z_hi is not None and p["zeta"] >= z_hi * (1 - EDGE_RTOL):
        edge = (f", ζ at the top of its search range ({z_lo:.3g}…{z_hi:.3g}): overdamped, the data show no "
                "resonance, only a lag")
    elif lo is not None and p["fn_Hz"] <= lo * (1 + EDGE_RTOL):
        edge = f", at the bottom of its search range ({lo:.4g}…{hi:.4g} Hz)"
    return [f"{sig} (lag ∝ dŷ/dt plus gain rise ∝ d²ŷ/dt²)", *_with_frequency(ev),
            f"fitted stage: f_n = {p['fn_Hz']:.4g} Hz, ζ = {p['zeta']:.3g}{lag}{edge}"]


def _delay(ev: "Evidence", sig: str, u: str) -> list[str]:
    p = ev.params
    return [f"{sig} (lag ∝ dŷ/dt)", *_with_frequency(ev),
            f"fitted delay {p['delay_ms'] * 1e3:.4g} µs ({p['delay_samples']:.2f} samples)"]


def _creep(ev: "Evidence", sig: str, u: str) -> list[str]:
    p = ev.params
    long = ([f"longest captures miss {ev.long_capture_ratio:.1f}× more"]
            if ev.long_capture_ratio is not None and ev.long_capture_ratio > 1.2 else [])
    return [f"{sig} (slow low-pass responses of the output)", _slow_share(ev), *long, *_grows_in_time(ev),
            "fitted gains " + ", ".join(f"{100 * g:.2g} % at τ = {t:g} s" for t, g in zip(p["tau_s"], p["gain"]))
            + f" (total {100 * p['total_gain']:.2g} %)",
            creep_character(p["tau_s"], p["gain"], ev.drive_frequency_Hz)]


def _asymmetry(ev: "Evidence", sig: str, u: str) -> list[str]:
    p = ev.params
    c = ev.amplitude_exponent
    bow = p["mid_stroke_bow_out"]
    return [f"{sig} (residual ∝ ŷ², ŷ³)", *([f"the gap grows with amplitude as A^{c:.2f}"] if c is not None else []),
            f"fitted bow: mid-stroke {abs(bow):.3g} {u} {'above' if bow > 0 else 'below'} the straight line through "
            f"the stroke ends ({p['bow_pct_of_stroke']:.2g} % of the stroke)"]


def _drift(ev: "Evidence", sig: str, u: str) -> list[str]:
    return [f"{sig} (an offset and a ramp per capture)", *_grows_in_time(ev), _slow_share(ev),
            f"fitted rates: median absolute rate {ev.params['median_abs_rate_out_per_s']:.3g} {u}/s"]


#: The effect-specific part of the evidence (effects not listed get the held-out numbers only).
_EVIDENCE = {"dynamics": _dynamics, "delay": _delay, "creep": _creep, "asymmetry": _asymmetry, "drift": _drift}


def evidence_text(ev: "Evidence", unit: str) -> str:
    """Plain-language evidence of one effect: signature, where-pointer, parameters, held-out numbers."""
    u = display_unit(unit)
    sig = f"its signature explains {100 * ev.signature_share:.0f} % of the residual above noise"
    parts = _EVIDENCE[ev.effect](ev, sig, u) if ev.effect in _EVIDENCE else []
    placebo = (f"best placebo of the same size improves by {ev.placebo:.3g} {u}" if math.isfinite(ev.placebo)
               else f"no placebo fitted: {NO_PLACEBO_WHY}")
    parts.append(f"held out: RMSE {ev.heldout_before:.4g} → {ev.heldout_after:.4g} {u} (reduction "
                 f"{ev.reduction:.2f}; {placebo})")
    return "; ".join(parts)


#: why a candidate has no placebo (:data:`hystfit.diagnose.CONTENDER_SHARE`)
NO_PLACEBO_WHY = ("it removes less than half the threshold of the gap (or the gap is within the noise), so it "
                  "cannot be named and no placebo could change its verdict")


def placebo_text(gain: float) -> str:
    """A placebo's held-out gain in a table cell: its value, or "–" where none was fitted."""
    return f"{gain:.3g}" if math.isfinite(gain) else "–"


def reconciliation_why(reason: str, reduction: float, threshold: float) -> str:
    """Why an effect whose shape the residual shows was not named (``reconciliation[].why``)."""
    if reason == "shared_shape":
        return ("its shape is shared with the effect(s) named first, which remove it: refitted on top of them it "
                "gains less")
    if reason == "not_carried_over":
        return (f"the refit does not carry the pattern over to held-out data (reduction {reduction:.2f} < "
                f"{threshold:g})")
    return "it passes the reduction but fails another rule (placebo or noise floor)"


def _pct(x: float, digits: int = 0) -> str:
    return f"{100 * x:.{digits}f} %"


def _pct_pair(x: float, threshold: float) -> tuple[str, str]:
    """``x`` and ``threshold`` as percentages with as many decimals as it takes for a reduction that
    misses the threshold not to print as equal to it (29.8 % against 30 %, not 30 % against 30 %)."""
    d = 0
    while d < 3 and x < threshold and round(100 * x, d) >= round(100 * threshold, d):
        d += 1
    return _pct(x, d), _pct(threshold, d)


def not_named_reasons(passes: dict, reduction: float, improvement: float, placebo: float, threshold: float,
                      unit: str) -> list[str]:
    """Why an effect was not named, one plain clause per check of the verdict rule it failed
    (:attr:`hystfit.diagnose.EffectResult.passes`), with the numbers the check compared; empty when it
    failed none. Worded from the checks themselves so that the report never gives a reason the
    effect did not fail (a reduction above the threshold explained by the threshold)."""
    u = display_unit(unit)
    out = []
    if not passes.get("reduction_at_least_threshold", True):
        got, need = _pct_pair(reduction, threshold)
        out.append(f"it removes only {got} of the gap above the noise on held-out data, less than the {need} the "
                   "rule asks for")
    if passes.get("beats_placebo") is False:  # None: not fitted (the candidate does not contend)
        if improvement > 0:
            than = "smaller than" if improvement <= placebo else "not clearly more than"
            out.append(f"its held-out improvement ({improvement:.3g} {u}) is {than} what random corrections with as "
                       f"many adjustable parameters gain by chance (the best of them: {placebo:.3g} {u}), so the gain "
                       "may be chance rather than this effect")
        else:
            out.append(f"it does not improve the held-out RMSE ({improvement:+.3g} {u}; the best random correction "
                       f"with as many adjustable parameters: {placebo:+.3g} {u})")
    if not passes.get("gap_above_noise", True):
        out.append("the gap it was tested on is too close to the sensor noise to tell any effect from noise")
    if passes.get("effect_above_noise") is False:
        out.append("what it adds to the prediction on held-out data is below a quarter of the noise floor: too small "
                   "to tell from the sensor noise, as a gap that small would be (whatever share of the gap it removes)")
    if passes.get("inside_search_range") is False:
        out.append("its fit ends on the edge of its search range where the effect is absent (a stage: f_n or ζ at the top "
                   "of its range, no resonance inside it); what it gains there is another shape's, e.g. a small lag")
    return out


def best_not_named_text(effect: str, passes: dict, reduction: float, improvement: float, placebo: float,
                        threshold: float, unit: str) -> str:
    """The best candidate of a verdict "none" and why it was not named (:func:`not_named_reasons`).

    A best candidate that removes at least the threshold failed another check (placebo or noise
    floor): the sentence says so, instead of blaming a threshold it reached."""
    reasons = not_named_reasons(passes, reduction, improvement, placebo, threshold, unit)
    if passes.get("reduction_at_least_threshold", True):
        got, need = _pct_pair(reduction, threshold)
        head = f"the best, `{effect}`, removes {got} of the gap above the noise (the rule asks for at least {need})"
        return head + (", but " + "; and ".join(reasons) if reasons else "")
    return f"the best, `{effect}`, falls short: " + "; and ".join(reasons)


def loop_position_text(near: dict, mid: dict, unit: str) -> str:
    """The near-turning-points / mid-stroke sentence of diagnosis.md (``where.by_loop_position``).

    A part with no samples has no RMSE (NaN in the record, null in the JSON): it is said in words,
    with why — an input that jumps from level to level (PRBS, steps) never passes through the middle
    of a stroke, so every moving sample sits at a turning point; one that never moves has neither."""
    u = display_unit(unit)

    def has(part: dict) -> bool:
        return bool(part.get("n_samples", 1)) and part["rmse_out"] is not None and np.isfinite(part["rmse_out"])

    if has(near) and has(mid):
        return (f"Near turning points (within 10 % of the half-cycle stroke): RMSE {near['rmse_out']:.4g} {u}; "
                f"mid-stroke: {mid['rmse_out']:.4g} {u}.")
    if not has(near) and not has(mid):
        return ("No samples near turning points or at mid-stroke: the input never moves, so there is no stroke "
                "to locate the error in.")
    if has(near):
        return (f"Near turning points (within 10 % of the half-cycle stroke): RMSE {near['rmse_out']:.4g} {u}; "
                "no samples at mid-stroke: the input never passes through the middle 80 % of a stroke (it jumps "
                "from one level to the next within a sample, as a PRBS or step input does), so the error cannot be "
                "split by loop position.")
    return (f"No samples near turning points (within 10 % of the half-cycle stroke); mid-stroke: RMSE "
            f"{mid['rmse_out']:.4g} {u}.")


def resolution_text(r: dict, unit: str) -> str:
    """The base-resolution check (:func:`hystfit.diagnose.resolution_check`) in one paragraph."""
    u = display_unit(unit)
    before, after = r["heldout_rmse_before_out"], r["heldout_rmse_after_out"]
    with_effects = f" with {' + '.join(r['effects'])}" if r["effects"] else ""
    head = (f"Resolution of the base: {r['option']} {r['from']} → {r['to']}{with_effects} takes the held-out RMSE "
            f"from {before:.4g} to {after:.4g} {u} ({100 * r['reduction_mean_square']:.0f} % of the held-out mean "
            f"square above the noise; a doubling is adopted from {100 * r['threshold']:.0f} %).")
    steps = r.get("steps", [])
    if len(steps) > 1:
        head += " Doubled while each doubling passed: " + "; ".join(
            f"{x['from']} → {x['to']} {100 * x['reduction_mean_square']:.0f} %" + (" (adopted)" if x["adopted"] else " (kept)")
            for x in steps) + "."

    if r["adopted"]:
        return (head + f" The coarse base's own discretization was a large part of what remained, so the finer base "
                f"is adopted: the effects after step {len(r['effects'])} were tested on it, and the recommended model "
                f"uses --model-option {r['option']}={r['to']}.")
    return head + " The base's resolution is not what limits the model; it is kept."


def converged_text(r: dict, unit: str, final: int | None = None) -> str:
    """The base's resolution converged before any effect was tested
    (:func:`hystfit.diagnose.converge_resolution`) in one paragraph; ``final``: the resolution the
    diagnosis ended on (a check after a named effect may refine it further: then the recommended
    model uses that one — a blind test's report said 20 here and 80 in its last line)."""
    u = display_unit(unit)
    tried = "; ".join(f"{x['from']} → {x['to']}: held-out RMSE {x['heldout_rmse_before_out']:.4g} → "
                      f"{x['heldout_rmse_after_out']:.4g} {u}, {100 * x['reduction_mean_square']:.0f} %"
                      + (" (adopted)" if x["adopted"] else " (kept the coarser)") for x in r["steps"])
    head = (f"Resolution of the base before any effect is tested ({r['option']}, doubled while a doubling removes "
            f"at least {100 * r['threshold']:.0f} % of the held-out mean square above the noise): {tried}.")
    if r["to"] == r["from"]:
        return head + f" The base's {r['option']} = {r['from']} is kept."
    if final is not None and final != r["to"]:
        return (head + f" The first effects are tested on the base with {r['option']} = {r['to']}; a later check "
                f"refined it to {final} (below), which the recommended model uses (--model-option "
                f"{r['option']}={final}).")
    return (head + f" The effects are tested on the base with {r['option']} = {r['to']}, and the recommended model "
            f"uses --model-option {r['option']}={r['to']}.")


def joint_text(effect: str, joint: dict, unit: str) -> str:
    """Why ``effect`` was named although it removes less than the threshold alone (the two-effect
    look-ahead, :func:`hystfit.diagnose._look_ahead`)."""
    u = display_unit(unit)
    return (f" Named together with `{joint['with']}`: alone it removes less than the threshold, but each of the two "
            f"passes the rule on top of the other — `{joint['with']}` in the next step, and this one removes "
            f"{joint['reduction_on_top_of_other']:.2f} of the gap `{joint['with']}` leaves alone (threshold "
            f"{joint['threshold']:.2f}); together they remove {joint['reduction']:.2f} of this step's gap (held-out "
            f"RMSE {joint['heldout_rmse_after']:.4g} {u}). Two effects of similar size share a gap.")


def during_text(checks, unit: str) -> str:
    """The resolution checks after each named effect (:class:`hystfit.diagnose._Refiner`) in one
    paragraph; empty when none ran."""
    if not checks:
        return ""
    u = display_unit(unit)
    parts = [f"after {' + '.join(x['effects'])}: {x['option']} {x['from']} → {x['to']}, held-out "
             f"{x['heldout_rmse_before_out']:.4g} → {x['heldout_rmse_after_out']:.4g} {u} "
             f"({100 * x['reduction_mean_square']:.0f} %, {'adopted' if x['adopted'] else 'kept the coarser'})"
             for x in checks]
    return ("Resolution of the base during the selection (after each named effect, doubled while a doubling "
            "removes at least " f"{100 * checks[0]['threshold']:.0f} % of the held-out mean square above the noise): "
            + "; ".join(parts) + ". The next effects were tested on the base adopted.")
