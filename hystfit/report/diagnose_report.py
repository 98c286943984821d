"""Writes the outputs of ``hystfit diagnose``: diagnosis.json, diagnosis.md and figures/.

The Markdown report is written for an engineer who has never heard of hystfit: it says what was
done, what was found where, which effect explains the gap with what evidence, and how much of the
gap it removes on data it was not fitted to. Figures are PNG files written atomically (the same
Agg-only machinery as :mod:`hystfit.report.plots`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..diagnose import Diagnosis, EffectResult
from ..effects import EFFECTS
from ..io import atomic_write_text
from ..results import dumps
from . import plots
from .plots import _decimate_minmax, _new_figure, _save, _stride, display_unit
from .tables import fmt

#: What each candidate effect means, in one plain sentence.
PLAIN = {
    "dynamics": "the stage's own mechanics (mass and stiffness): a resonance that makes the response lag and "
                "overshoot more at higher drive frequencies",
    "creep": "slow viscoelastic creep: after a move the actuator keeps drifting in the same direction for "
             "seconds (roughly logarithmically in time)",
    "asymmetry": "a static nonlinearity of the output (saturation or stiffening): ascending and descending "
                 "branches bend differently, more so at large strokes",
    "drift": "a slow output drift that the input does not cause (temperature, sensor): an offset and a ramp "
             "per capture",
    "delay": "a pure time delay between the voltage and the measured displacement (amplifier, DAQ, sensor "
             "filter)",
}


def _u(unit: str) -> str:
    return display_unit(unit)


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------


def _fig_conditions(path: Path, d: Diagnosis) -> Path:
    """Excess RMSE (above noise) vs excitation frequency per amplitude, global fit and alone."""
    w = d.where
    unit = d.unit
    panels = [("fitted as configured" if d.mode == "per-condition" else "one model for all captures",
               w["by_condition"])]
    if "by_condition_alone" in w:
        panels.append(("each condition fitted on its own", w["by_condition_alone"]))
    fig = _new_figure(5.2 * len(panels) + 0.6, 4.4)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    sigma = d.noise["sigma"]
    for ax, (title, rows) in zip(axes, panels):
        per = [r for r in rows if r["periodic"]]
        amps = sorted({r["amplitude_V"] for r in per})
        for i, a in enumerate(amps):
            pts = sorted((r["frequency_Hz"], r["rmse_out"]) for r in per if r["amplitude_V"] == a)
            f, e = zip(*pts)
            ax.plot(f, e, "o-", color=f"C{i % 10}", label=f"{a:g} V")
        other = [r for r in rows if not r["periodic"]]
        for r in other:
            ax.plot([r["frequency_Hz"]], [r["rmse_out"]], "s", color="0.3", ms=6)
            ax.annotate(r["label"], (r["frequency_Hz"], r["rmse_out"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.axhline(sigma, color="tab:red", ls="--", lw=1, label=f"noise floor {sigma:.3g} {_u(unit)}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("Excitation frequency (Hz)")
        ax.set_ylabel(f"RMSE ({_u(unit)})")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle("Where: gap per condition (squares: non-periodic captures)")
    return _save(fig, path, plots.DPI)


def _fig_branch_position(path: Path, d: Diagnosis) -> Path:
    """Branch bars, RMSE along the half-cycle and the residual loop (mean residual vs input level)."""
    w = d.where
    unit = d.unit
    fig = _new_figure(13.0, 4.2)
    ax1, ax2, ax3 = fig.subplots(1, 3)
    names = ["ascending", "descending", "hold"]
    rm = [w["by_branch"][n]["rmse_out"] for n in names]
    mn = [w["by_branch"][n]["mean_out"] for n in names]
    x = np.arange(3)
    ax1.bar(x - 0.2, [0 if not math.isfinite(v) else v for v in rm], 0.4, label="RMSE")
    ax1.bar(x + 0.2, [0 if not math.isfinite(v) else v for v in mn], 0.4, label="mean (model − measured)")
    ax1.axhline(d.noise["sigma"], color="tab:red", ls="--", lw=1, label="noise floor")
    ax1.axhline(0, color="0.5", lw=0.6)
    ax1.set_xticks(x, [f"{n}\n{w['by_branch'][n]['n_samples']} samples" for n in names], fontsize=8)
    ax1.set_ylabel(f"Residual ({_u(unit)})")
    ax1.set_title("By branch", fontsize=10)
    ax1.legend(fontsize="small")
    pos = np.linspace(0.05, 0.95, 10)
    for name, col in (("ascending", "C0"), ("descending", "C1")):
        v = [np.nan if q is None else q for q in w["by_loop_position"]["rmse_by_position_out"][name]]
        ax2.plot(pos, v, "o-", color=col, label=name)
    ax2.axvspan(0, 0.1, color="0.85")
    ax2.axvspan(0.9, 1.0, color="0.85")
    ax2.axhline(d.noise["sigma"], color="tab:red", ls="--", lw=1)
    ax2.set_xlabel("Position in the half-cycle (0 = last turning point, 1 = next)")
    ax2.set_ylabel(f"RMSE ({_u(unit)})")
    ax2.set_title("By loop position (grey: near turning points)", fontsize=10)
    ax2.legend(fontsize="small")
    for name, col in (("ascending", "C0"), ("descending", "C1")):
        v = [np.nan if q is None else q for q in w["by_level"]["mean_by_level_out"][name]]
        ax3.plot(pos, v, "o-", color=col, label=name)
    ax3.axhline(0, color="0.5", lw=0.6)
    ax3.set_xlabel("Input level (0 = capture minimum, 1 = maximum)")
    ax3.set_ylabel(f"Mean residual ({_u(unit)})")
    ax3.set_title("Residual loop (lag: branches opposite; bow: alike)", fontsize=10)
    ax3.legend(fontsize="small")
    for ax in (ax1, ax2, ax3):
        ax.grid(True, alpha=0.3)
    return _save(fig, path, plots.DPI)


def _fig_time(path: Path, d: Diagnosis) -> Path:
    """RMSE and mean residual per tenth of the capture, first cycle vs later."""
    w = d.where["by_time"]
    unit = d.unit
    fig = _new_figure(9.0, 4.0)
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2.2, 1.0]})
    pos = np.linspace(0.05, 0.95, 10)
    r = [np.nan if q is None else q for q in w["rmse_by_tenth_out"]]
    m = [np.nan if q is None else q for q in w["mean_by_tenth_out"]]
    ax1.plot(pos, r, "o-", label="RMSE")
    ax1.plot(pos, m, "s-", label="mean (model − measured)")
    ax1.axhline(d.noise["sigma"], color="tab:red", ls="--", lw=1, label="noise floor")
    ax1.axhline(0, color="0.5", lw=0.6)
    ax1.axvline(d.settings.fit_fraction, color="0.4", ls=":", lw=1, label="≈ fit / held-out split")
    ax1.set_xlabel("Time in the capture (fraction of its duration)")
    ax1.set_ylabel(f"Residual ({_u(unit)})")
    ax1.legend(fontsize="small")
    ax1.set_title("By time in the capture (all captures pooled)", fontsize=10)
    ax2.bar([0, 1], [w["first_cycle"]["rmse_out"], w["later"]["rmse_out"]], color=["C2", "C0"])
    ax2.set_xticks([0, 1], ["first cycle", "later"])
    ax2.axhline(d.noise["sigma"], color="tab:red", ls="--", lw=1)
    ax2.set_ylabel(f"RMSE ({_u(unit)})")
    ax2.set_title("Start-up vs steady state", fontsize=10)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    return _save(fig, path, plots.DPI)


def _fig_bands(path: Path, d: Diagnosis) -> Path:
    """Residual RMS per band (with the white-noise expectation) and residual spectra vs harmonic order."""
    b = d.where["by_band"]
    unit = d.unit
    names = ["drift", "low_harmonics", "high_harmonics", "broadband"]
    labels = ["drift\n< f0/2", "fundamental\n+ harmonics ≤ 5", "harmonics\n6…50", "broadband\n> 50·f0"]
    fig = _new_figure(11.0, 4.2)
    ax1, ax2 = fig.subplots(1, 2)
    x = np.arange(4)
    ax1.bar(x - 0.2, [b[n]["rms_out"] for n in names], 0.4, label="residual")
    ax1.bar(x + 0.2, [b[n]["expected_noise_rms_out"] for n in names], 0.4, label="white noise alone")
    for i, n in enumerate(names):
        ax1.annotate(f"{100 * b[n]['share_above_noise']:.0f} %", (i - 0.2, b[n]["rms_out"]), ha="center",
                     va="bottom", fontsize=8)
    ax1.set_xticks(x, labels, fontsize=8)
    ax1.set_ylabel(f"RMS ({_u(unit)})")
    ax1.set_title("By frequency band (labels: share of the gap above noise)", fontsize=10)
    ax1.legend(fontsize="small")
    spectra = d.figures_data.get("spectra", [])
    for i, (h, amp, src) in enumerate(spectra[:12]):
        sel = h > 0
        ax2.loglog(h[sel], np.maximum(amp[sel], 1e-12), lw=0.7, alpha=0.7, color=f"C{i % 10}",
                   label=Path(src).name if i < 6 else None)
    ax2.axvline(0.5, color="0.4", ls=":", lw=1)
    ax2.axvline(5.5, color="0.4", ls=":", lw=1)
    ax2.axvline(50.5, color="0.4", ls=":", lw=1)
    ax2.set_xlabel("Frequency / excitation frequency (harmonic order)")
    ax2.set_ylabel(f"Residual amplitude ({_u(unit)})")
    ax2.set_title("Residual spectra of the periodic captures", fontsize=10)
    if spectra:
        ax2.legend(fontsize="x-small")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
    return _save(fig, path, plots.DPI)


def _fig_effects(path: Path, d: Diagnosis) -> Path:
    """Held-out RMSE before and after each candidate (step 1), with the noise floor and placebo."""
    rs = list(d.effects)
    unit = d.unit
    fig = _new_figure(10.5, 0.55 * max(len(rs), 1) + 1.8)
    ax = fig.add_subplot()
    y = np.arange(len(rs))[::-1]
    before = rs[0].heldout_rmse_before if rs else float("nan")
    ax.barh(y, [r.heldout_rmse_after for r in rs], color=["C2" if r.eligible else "C7" for r in rs],
            label="after adding the effect")
    ax.scatter([before - r.placebo_improvement for r in rs], y, marker="|", s=300, color="k", zorder=3,
               label="best placebo of the same size")
    ax.axvline(before, color="C3", lw=1.5, label=f"before ({before:.3g} {_u(unit)})")
    ax.axvline(d.noise["sigma"], color="tab:red", ls="--", lw=1, label="noise floor")
    ax.set_yticks(y, [f"{r.effect}  (reduction {r.reduction:.2f})" for r in rs])
    ax.set_xlabel(f"Held-out RMSE ({_u(unit)})")
    ax.set_title("Which effect: held-out RMSE with each candidate added (green = passes the rule)", fontsize=10)
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, path, plots.DPI)


def _worst_capture(d: Diagnosis, periodic: bool) -> int | None:
    caps = d.figures_data["captures"]
    base = d.figures_data["base_predictions"]
    best, idx = -1.0, None
    for i, (c, p) in enumerate(zip(caps, base)):
        if d.captures[i]["periodic"] != periodic:
            continue
        r = float(np.sqrt(np.mean((p - c.y) ** 2)))
        if r > best:
            best, idx = r, i
    return idx


def _fig_explained(path: Path, d: Diagnosis, i: int) -> Path:
    """One capture: measured vs base vs base + named effects, and both residuals (held-out shaded)."""
    c = d.figures_data["captures"][i]
    v = d.figures_data["views"][i]
    base = d.figures_data["base_predictions"][i]
    expl = d.figures_data["explained_predictions"][i]
    chosen = d.figures_data["chosen"]
    unit = d.unit
    fig = _new_figure(9.0, 6.0)
    ax, axr = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [1.6, 1.0]})
    k = _stride(c.n)
    ax.plot(c.t[::k], c.y[::k], color="0.15", lw=0.8, label="measured")
    ax.plot(c.t[::k], base[::k], color="tab:red", lw=0.9, label=f"{d.base_model}")
    if chosen:
        ax.plot(c.t[::k], expl[::k], color="tab:green", lw=0.9, label=f"{d.base_model} + {' + '.join(chosen)}")
    t_split = c.t[v.fit_end - 1]
    for a in (ax, axr):
        a.axvspan(t_split, c.t[-1], color="0.92", zorder=0)
        a.grid(True, alpha=0.3)
    ax.set_ylabel(f"Displacement ({_u(unit)})")
    ax.legend(fontsize="small", loc="upper right")
    ax.set_title(f"{Path(c.source).name}: fitted on the white part, tested on the grey part", fontsize=10)
    tr, rr = _decimate_minmax(c.t, base - c.y)
    axr.plot(tr, rr, color="tab:red", lw=0.6, label=f"{d.base_model} − measured")
    if chosen:
        tr, rr = _decimate_minmax(c.t, expl - c.y)
        axr.plot(tr, rr, color="tab:green", lw=0.6, label="with the effects − measured")
    axr.axhline(0, color="0.5", lw=0.6)
    axr.set_ylabel(f"Residual ({_u(unit)})")
    axr.set_xlabel("Time (s)")
    axr.legend(fontsize="small", loc="upper right")
    return _save(fig, path, plots.DPI)


def write_figures(d: Diagnosis, fig_dir: Path) -> dict[str, str]:
    """Write every figure into ``fig_dir``; returns name → path relative to the report."""
    fig_dir.mkdir(parents=True, exist_ok=True)
    out = {}

    def rel(p: Path) -> str:
        return str(Path(fig_dir.name) / p.name)

    out["conditions"] = rel(_fig_conditions(fig_dir / "where_conditions.png", d))
    out["branch"] = rel(_fig_branch_position(fig_dir / "where_branch_position.png", d))
    out["time"] = rel(_fig_time(fig_dir / "where_time.png", d))
    out["bands"] = rel(_fig_bands(fig_dir / "where_bands.png", d))
    if d.effects:
        out["effects"] = rel(_fig_effects(fig_dir / "effects_heldout.png", d))
    caps = d.figures_data["captures"]
    for periodic, key in ((True, "explained_periodic"), (False, "explained_other")):
        i = _worst_capture(d, periodic)
        if i is None:
            continue
        out[key] = rel(_fig_explained(fig_dir / f"explained_{_safe(Path(caps[i].source).stem)}.png", d, i))
        if periodic:
            models = {d.base_model: d.figures_data["base_predictions"][i]}
            if d.explained_by:
                models[f"{d.base_model} + {' + '.join(d.explained_by)}"] = d.figures_data["explained_predictions"][i]
            out["loop"] = rel(plots.loop_overlay_figure(
                fig_dir / f"loop_{_safe(Path(caps[i].source).stem)}.png", caps[i].u, caps[i].y, models, unit=d.unit,
                title=f"{Path(caps[i].source).name}: measured and modelled loops"))
    return out


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


# ----------------------------------------------------------------------------------------------
# Markdown
# ----------------------------------------------------------------------------------------------


def _table(header: Sequence[str], rows: Sequence[Sequence]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(x if isinstance(x, str) else fmt(x) for x in r) + " |")
    return out


def _params_text(r: EffectResult, unit: str) -> str:
    p = r.params
    u = _u(unit)
    if r.effect == "dynamics":
        return f"f_n = {p['fn_Hz']:.4g} Hz, ζ = {p['zeta']:.3g}"
    if r.effect == "delay":
        return f"T_d = {1e3 * p['delay_ms']:.4g} µs ({p['delay_samples']:.2f} samples)"
    if r.effect == "creep":
        return ", ".join(f"{100 * g:.2g} % @ {t:g} s" for t, g in zip(p["tau_s"], p["gain"]))
    if r.effect == "asymmetry":
        return f"bow {p['mid_stroke_bow_out']:+.3g} {u} mid-stroke, skew {p['a3_out']:+.3g} {u}"
    if r.effect == "drift":
        return f"median abs. rate {p['median_abs_rate_out_per_s']:.3g} {u}/s"
    return ""


#: Why two effects can explain the same data, and what measurement would separate them.
SEPARATE = {
    frozenset({"dynamics", "delay"}): "below its resonance a well-damped stage lags like a pure delay; a step or "
                                      "broadband (PRBS, multisine) capture shows the ringing and the gain rise that "
                                      "only a stage has",
    frozenset({"creep", "drift"}): "both are slow; creep follows the input (it reverses after a step down and "
                                   "scales with the step), drift does not: a step-and-hold capture separates them",
}


def _ambiguity(d: Diagnosis, step: int, indent: str = "") -> list[str]:
    """A note when other effects explain the data as well as the one named at ``step``."""
    if step >= len(d.alternatives) or not d.alternatives[step]:
        return []
    named = d.explained_by[step]
    out = []
    for alt in d.alternatives[step]:
        r = next(x for x in d.steps[step] if x.effect == alt)
        why = SEPARATE.get(frozenset({named, alt}), "these captures do not separate them")
        out += ["", f"{indent}*Equally good:* `{alt}` ({_params_text(r, d.unit)}) removes {100 * r.reduction:.0f} % too; "
                    f"`{named}` is named because it needs fewer parameters. The data cannot tell them apart: {why}."]
    return out


def _verdict_paragraph(d: Diagnosis) -> list[str]:
    u = _u(d.unit)
    g = d.gap
    sigma = d.noise["sigma"]
    lines = []
    head = (f"The `{d.base_model}` model misses the measurement by **{g['rmse_out']:.4g} {u} RMS** "
            f"({g['heldout_rmse_out']:.4g} {u} on held-out data). The sensor noise, estimated from the data, is "
            f"**{sigma:.3g} {u}**: no model can go below that.")
    lines.append(head)
    lines.append("")
    if d.verdict == "none":
        excess = g["heldout_excess_rmse_out"]
        if excess < d.settings.min_excess_ratio * sigma:
            lines.append("**Verdict: none.** The model is already as good as the noise allows; there is no gap "
                         "worth explaining.")
        else:
            best = d.effects[0] if d.effects else None
            lines.append("**Verdict: none.** No candidate effect removes a meaningful share of the gap on held-out "
                         "data" + (f" (the best, `{best.effect}`, removes {100 * best.reduction:.0f} %)" if best else "")
                         + ". The remaining gap lies in the base model's own loop shape (or in an effect not in "
                           "the library): try a more flexible hysteresis model or the per-condition look-up table.")
        return lines
    first = next(r for r in d.effects if r.effect == d.verdict)
    lines.append(f"**Verdict: `{d.verdict}`** — {PLAIN.get(d.verdict, d.verdict)}. Adding it to the model "
                 f"({_params_text(first, d.unit)}) removes **{100 * first.reduction:.0f} %** of the gap above the noise "
                 f"on data the model was not fitted to (held-out RMSE {first.heldout_rmse_before:.4g} → "
                 f"{first.heldout_rmse_after:.4g} {u}).")
    lines += _ambiguity(d, 0)
    if len(d.explained_by) > 1:
        lines.append("")
        lines.append("Then, in order (each tested on top of the ones before it):")
        lines.append("")
        for k, name in enumerate(d.explained_by[1:], start=2):
            r = next(x for x in d.steps[k - 1] if x.effect == name)
            lines.append(f"{k}. `{name}` — {PLAIN.get(name, name)}: {_params_text(r, d.unit)}; removes "
                         f"{100 * r.reduction:.0f} % of what was left (held-out {r.heldout_rmse_before:.4g} → "
                         f"{r.heldout_rmse_after:.4g} {u}).")
            lines += _ambiguity(d, k - 1, indent="   ")
    lines.append("")
    lines.append(f"With {', '.join(f'`{e}`' for e in d.explained_by)} added, the held-out RMSE is "
                 f"{g['heldout_rmse_after_explained_out']:.4g} {u} against a noise floor of {sigma:.3g} {u} "
                 f"({100 * g['heldout_reduction_explained']:.0f} % of the gap above noise explained).")
    return lines


def markdown(d: Diagnosis, figs: dict[str, str]) -> str:
    """The report text (see the module docstring)."""
    u = _u(d.unit)
    s = d.settings
    w = d.where
    sigma = d.noise["sigma"]
    L = [f"# Why the `{d.base_model}` model misses the measurement", ""]
    L += _verdict_paragraph(d)
    L += ["", "## What was done", "",
          f"1. **Fit.** The hysteresis model `{d.base_model}` was identified on the {len(d.captures)} capture(s) "
          f"({'one parameter set per operating condition' if d.mode == 'per-condition' else 'one parameter set for all captures'}; "
          f"optimizer `{d.optimizer}`, seed {d.seed}). The *gap* is what it still misses: e = model − measured.",
          "2. **Noise floor.** The part of the gap no model can remove: the sensor noise, estimated from the data "
          f"themselves ({d.noise['method']}), never from how well a model fits.",
          "3. **Where.** The residual was broken down by operating condition, by branch (input rising or falling), "
          "by position in the loop, by time within the capture and by frequency.",
          "4. **Which.** Each candidate effect was added to the model and the model refitted *together with it* "
          "(the base parameters may move too). Effects in the library: "
          + "; ".join(f"`{n}` — {PLAIN[n]}" for n in EFFECTS) + ".",
          f"5. **How far, honestly.** Every fit used only the first part of each capture ({d.split['description']}). "
          "The score of an effect is its *reduction*: (held-out RMSE before − after) / (before − noise floor), "
          "the share of the gap above the noise that it removes on data it never saw, between 0 and 1.",
          f"6. **Verdict rule.** An effect is named when its reduction is at least {s.threshold:g}, it improves the "
          f"held-out RMSE more than the best of {s.placebo_draws} *placebos* (random augmentations with the same "
          "number of parameters, built from phase-randomized copies of the effects' signatures: what that many "
          "parameters gain by chance), and the gap exceeds the noise floor meaningfully "
          f"(√(before² − floor²) ≥ {s.min_excess_ratio:g}·floor). Among the effects that pass, the largest reduction "
          f"wins, unless one with fewer parameters comes within {s.occam_tolerance:g} of it (the simpler "
          "explanation). The winner is added to the model and the others are tested again on top of it, up to "
          f"{s.max_effects} effects: that is the order in which the effects are named.", ""]

    L += ["## 1. The gap and the noise floor", ""]
    g = d.gap
    rows = [["RMSE, all data (model fitted to all data)", f"{g['rmse_out']:.4g} {u}"],
            ["RMSE on held-out data (model fitted to the first part)", f"{g['heldout_rmse_out']:.4g} {u}"],
            ["Noise floor σ (white sensor noise)", f"{sigma:.3g} {u}"],
            ["Cycle-to-cycle repeatability (cross-check, includes slow noise)",
             "–" if d.noise["repeatability"] is None else f"{d.noise['repeatability']:.3g} {u}"],
            ["Smallest output step (quantization, for reference)", f"{d.noise['quantization_step']:.3g} {u}"],
            ["Gap above noise √(RMSE² − σ²), all data", f"{g['excess_rmse_out']:.4g} {u}"],
            ["Share of the squared gap that is noise", "–" if g["noise_share_of_gap"] is None
             else f"{100 * g['noise_share_of_gap']:.1f} %"]]
    L += _table(["quantity", "value"], rows) + [""]
    if d.noise["repeatability"] is not None and d.noise["repeatability"] > 1.5 * sigma:
        L += [f"The repeatability ({d.noise['repeatability']:.3g} {u}) is well above the white-noise floor: the "
              "noise has slow components, or the process does not repeat from cycle to cycle (creep, drift). "
              "The floor used here is the white part only, so slow noise would count as model gap.", ""]

    L += ["## 2. Where the model misses", "", "Main findings:", ""]
    L += [f"- {p}" for p in w["pointers"]] + [""]
    L += ["### By operating condition", ""]
    rows = [[r["label"], r["rmse_out"], r["excess_rmse_out"], "yes" if r["periodic"] else "no"] for r in w["by_condition"]]
    hdr = ["condition", f"RMSE ({u})", f"above noise ({u})", "periodic"]
    if "by_condition_alone" in w:
        alone = {r["label"]: r for r in w["by_condition_alone"]}
        rows = [r + [alone[r[0]]["rmse_out"]] for r in rows]
        hdr.append(f"RMSE, condition fitted alone ({u})")
    L += _table(hdr, rows) + [""]
    sm = w["summary"]
    exps = []
    for key, what in (("frequency_exponent", "frequency"), ("amplitude_exponent", "amplitude"),
                      ("frequency_exponent_alone", "frequency, conditions fitted alone"),
                      ("amplitude_exponent_alone", "amplitude, conditions fitted alone")):
        if sm.get(key) is not None:
            exps.append(f"{what}: {sm[key]:.2f}")
    if exps:
        L += ["Exponents of the gap above noise, RMSE ∝ f^b · A^c over the periodic conditions — " + "; ".join(exps)
              + ". A model that is wrong in a scale-invariant way misses ∝ A; lag-type effects make b > 0.", ""]
    if "conditions" in figs:
        L += [f"![gap per condition]({figs['conditions']})", ""]
    L += ["### By branch, loop position and level", ""]
    br = w["by_branch"]
    L += _table(["branch", f"RMSE ({u})", f"mean ({u})", "samples"],
                [[n, br[n]["rmse_out"], br[n]["mean_out"], str(br[n]["n_samples"])] for n in ("ascending", "descending", "hold")])
    lp = w["by_loop_position"]
    L += ["", f"Near turning points (within 10 % of the half-cycle stroke): RMSE {lp['near_turning_points']['rmse_out']:.4g} {u}; "
              f"mid-stroke: {lp['mid_stroke']['rmse_out']:.4g} {u}."]
    lv = w["by_level"]
    if "level_dependent_rms_out" in lv:
        L += [f"Mean residual as a function of the input level: the part common to both branches (a static "
              f"shape error) is {lv['level_dependent_rms_out']:.3g} {u} RMS, the part with opposite signs on the two "
              f"branches (a lag or lead) {lv['branch_opposite_rms_out']:.3g} {u}."]
    L += [""]
    if "branch" in figs:
        L += [f"![branch, position and level]({figs['branch']})", ""]
    L += ["### By time within the capture", ""]
    bt = w["by_time"]
    L += [f"First cycle: RMSE {bt['first_cycle']['rmse_out']:.4g} {u} (mean {bt['first_cycle']['mean_out']:+.3g}); "
          f"later: {bt['later']['rmse_out']:.4g} {u} (mean {bt['later']['mean_out']:+.3g}). "
          + (f"Fitted on the first part and tested on the rest, the base model's gap above noise grows by "
             f"{sm['heldout_to_fit_ratio']:.2f}× (above 1: the error builds up with time)."
             if sm.get("heldout_to_fit_ratio") is not None else ""), ""]
    if "time" in figs:
        L += [f"![time]({figs['time']})", ""]
    L += ["### By frequency band", ""]
    bb = w["by_band"]
    L += _table(["band", f"residual RMS ({u})", f"white noise alone ({u})", "share of the gap above noise"],
                [[n.replace("_", " "), bb[n]["rms_out"], bb[n]["expected_noise_rms_out"],
                  f"{100 * bb[n]['share_above_noise']:.0f} %"] for n in ("drift", "low_harmonics", "high_harmonics", "broadband")])
    L += ["", bb["definition"] + ".", ""]
    if "bands" in figs:
        L += [f"![bands]({figs['bands']})", ""]

    L += ["## 3. Which effect: every candidate tested", ""]
    for i, step in enumerate(d.steps):
        title = "Step 1 — on top of the base model" if i == 0 else \
            f"Step {i + 1} — on top of the base model + {' + '.join(d.explained_by[:i])}"
        L += [f"### {title}", ""]
        rows = []
        for r in step:
            rows.append([f"`{r.effect}`", r.heldout_rmse_before, r.heldout_rmse_after, f"{r.reduction:.2f}",
                         r.placebo_improvement, str(r.n_parameters), _params_text(r, d.unit),
                         "**yes**" if r.eligible else "no"])
        L += _table(["effect", f"held-out before ({u})", f"after ({u})", "reduction", f"placebo gain ({u})",
                     "parameters", "fitted values", "passes the rule"], rows) + [""]
        if i == 0:
            L += ["Evidence per effect:", ""]
            for r in step:
                failed = [k.replace("_", " ") for k, ok in r.passes.items() if not ok]
                L += [f"- **{r.effect}** ({PLAIN.get(r.effect, '')}): {r.evidence}."
                      + (f" Fails: {', '.join(failed)}." if failed else "")]
            L += [""]
    if "effects" in figs:
        L += [f"![held-out RMSE per effect]({figs['effects']})", ""]

    L += ["## 4. The model with the named effects", ""]
    for key, text in (("loop", "Loop of the capture the base model misses most"),
                      ("explained_periodic", "Time series of that capture (grey: held out)"),
                      ("explained_other", "The non-periodic capture the base model misses most")):
        if key in figs:
            L += [f"{text}:", "", f"![{key}]({figs[key]})", ""]
    L += ["## Definitions", "",
          "- RMSE = √mean(e²), e = model − measured; held-out RMSE counts only samples after the split.",
          "- Noise floor σ: 1.4826 × median absolute deviation of the third difference (−1, 3, −3, 1)/√20 of the "
          "residual (white noise passes with unit gain, smooth model errors vanish).",
          "- reduction = (before − after)/(before − σ), clipped to [0, 1]; placebo gain = the largest held-out "
          "improvement among random augmentations with the same parameter count.",
          f"- Runtime {d.runtime_s:.1f} s. Machine-readable results: `diagnosis.json`.", ""]
    return "\n".join(L)


def write_diagnose_outputs(d: Diagnosis, out_dir: Path, *, make_figures: bool = True) -> dict[str, Path]:
    """Write diagnosis.json, diagnosis.md and (optionally) figures/ into ``out_dir`` (which must exist)."""
    out_dir = Path(out_dir)
    paths = {"json": out_dir / "diagnosis.json", "md": out_dir / "diagnosis.md"}
    atomic_write_text(paths["json"], dumps(d.to_dict()))
    figs: dict[str, str] = {}
    if make_figures:
        figs = write_figures(d, out_dir / "figures")
        paths["figures"] = out_dir / "figures"
    atomic_write_text(paths["md"], markdown(d, figs))
    return paths
