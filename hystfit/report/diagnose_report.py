"""Writes the outputs of ``hystfit diagnose``: diagnosis.json, diagnosis.md and figures/.

The Markdown report is written for an engineer who has never heard of hystfit: it says what was
done, what was found where, which effect explains the gap with what evidence, and how much of the
gap it removes on data it was not fitted to. Figures are PNG files written atomically (the same
Agg-only machinery as :mod:`hystfit.report.plots`).
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np

from ..diagnose import Diagnosis, EffectResult, WhereFigureData, noise_floor_doubtful
from ..effects import EFFECTS
from ..io import atomic_write_text
from ..results import dumps, identify_to_dict, json_safe, schema_fields, unit_keys
from . import plots
from .plots import _decimate, _decimate_minmax, _new_figure, _save, _stride, display_unit
from .render import FigureJob, FigureStream
from .tables import fmt
from .diagnose_wording import (DEFINITIONS, doubtful_floor_text, evidence_text, noise_method_text, pointers_text, reconciliation_why,
                               resolution_text, split_description, split_why,
                               converged_text, during_text, joint_text, best_not_named_text, loop_position_text,
                               not_named_reasons, placebo_text, NO_PLACEBO_WHY)

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


def _fig_conditions(path: Path, data: WhereFigureData) -> Path:
    """Excess RMSE (above noise) vs excitation frequency per amplitude, global fit and alone."""
    w = data.where
    unit = data.unit
    panels = [("fitted as configured" if data.mode == "per-condition" else "one model for all captures",
               w["by_condition"])]
    if "by_condition_alone" in w:
        panels.append(("each condition fitted on its own", w["by_condition_alone"]))
    fig = _new_figure(5.2 * len(panels) + 0.6, 4.4)
    axes = fig.subplots(1, len(panels), squeeze=False, sharey=True)[0]  # one scale: the panels compare
    sigma = data.sigma
    freqs = sorted({r["frequency_Hz"] for _, rows in panels for r in rows if np.isfinite(r["frequency_Hz"])})
    for ax, (title, rows) in zip(axes, panels):
        per = [r for r in rows if r["periodic"]]
        amps = sorted({r["amplitude_V"] for r in per})
        for i, a in enumerate(amps):
            pts = sorted((r["frequency_Hz"], r["rmse_out"]) for r in per if r["amplitude_V"] == a)
            f, e = zip(*pts)
            ax.plot(f, e, "o-", color=f"C{i % 10}", label=f"{a:g} V peak-to-peak")
        other = [r for r in rows if not r["periodic"]]
        for r in other:
            ax.plot([r["frequency_Hz"]], [r["rmse_out"]], "s", color="0.3", ms=6)
            ax.annotate(r["label"], (r["frequency_Hz"], r["rmse_out"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.axhline(sigma, color="tab:red", ls="--", lw=1, label=f"noise floor {sigma:.3g} {_u(unit)}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_ticks(ax, freqs)
        ax.set_xlabel("Excitation frequency (Hz)")
        ax.set_ylabel(f"RMSE ({_u(unit)})")
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle("Where: gap per condition (squares: non-periodic captures)")
    return _save(fig, path, plots.DPI)


def _plain_log_ticks(ax, x_ticks: Sequence[float], y_subs: Sequence[float] = (1.0, 2.0, 5.0)) -> None:
    """Log axes labelled with plain numbers: x ticks at ``x_ticks`` (the measured values: 10, 20, …
    Hz, not 2×10¹), y at ``y_subs`` × 10ᵏ, both as %g; no minor ticks.

    A log axis' minor ticks (eight a decade, each a tick object with its line, grid line and
    labels, set up at every draw) were 40 % of the instructions of a where-figure (891 → 527 M for
    the conditions figure, 1178 → 654 M for the bands figure: ``python benchmarks/figure_work.py
    --other TREE``): the labelled ticks at 1, 2 and 5 and their grid lines carry the scale."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullLocator

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    if 0 < len(x_ticks) <= 12:
        ax.xaxis.set_major_locator(FixedLocator(list(x_ticks)))
    else:
        ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(plain)
    ax.yaxis.set_major_locator(LogLocator(base=10.0, subs=tuple(y_subs)))
    ax.yaxis.set_major_formatter(plain)
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_minor_locator(NullLocator())


def _fig_branch_position(path: Path, data: WhereFigureData) -> Path:
    """Branch bars, RMSE along the half-cycle and the residual loop (mean residual vs input level)."""
    w = data.where
    unit = data.unit
    fig = _new_figure(13.0, 4.2)
    ax1, ax2, ax3 = fig.subplots(1, 3)
    names = ["ascending", "descending", "hold"]
    total = sum(w["by_branch"][n]["n_samples"] for n in names)
    if w["by_branch"]["hold"]["n_samples"] < 0.01 * total:
        names = names[:2]  # a few samples at the turning points of a sine, not a hold: not worth a bar
    rm = [w["by_branch"][n]["rmse_out"] for n in names]
    mn = [w["by_branch"][n]["mean_out"] for n in names]
    x = np.arange(len(names))
    ax1.bar(x - 0.2, [0 if not math.isfinite(v) else v for v in rm], 0.4, label="RMSE")
    ax1.bar(x + 0.2, [0 if not math.isfinite(v) else v for v in mn], 0.4, label="mean (model − measured)")
    ax1.axhline(data.sigma, color="tab:red", ls="--", lw=1, label="noise floor")
    ax1.axhline(0, color="0.5", lw=0.6)
    ax1.set_xticks(x, [f"{'input constant' if n == 'hold' else 'input ' + ('rising' if n == 'ascending' else 'falling')}"
                       f"\n{w['by_branch'][n]['n_samples']} samples" for n in names], fontsize=8)
    ax1.set_ylabel(f"Model − measured ({_u(unit)})")
    ax1.set_title("By branch\n(opposite means: the model lags or leads)", fontsize=10)
    ax1.legend(fontsize="small")
    pos = np.linspace(0.05, 0.95, 10)
    for name, col in (("ascending", "C0"), ("descending", "C1")):
        v = [np.nan if q is None else q for q in w["by_loop_position"]["rmse_by_position_out"][name]]
        ax2.plot(pos, v, "o-", color=col, label=f"{name} (input {'rising' if name == 'ascending' else 'falling'})")
    ax2.axvspan(0, 0.1, color="0.85")
    ax2.axvspan(0.9, 1.0, color="0.85")
    ax2.axhline(data.sigma, color="tab:red", ls="--", lw=1)
    ax2.set_xlabel("Position in the half-cycle (0 = last turning point, 1 = next)")
    ax2.set_ylabel(f"RMSE ({_u(unit)})")
    ax2.set_title("By position in the stroke\n(grey: near the turning points)", fontsize=10)
    ax2.legend(fontsize="small")
    for name, col in (("ascending", "C0"), ("descending", "C1")):
        v = [np.nan if q is None else q for q in w["by_level"]["mean_by_level_out"][name]]
        ax3.plot(pos, v, "o-", color=col, label=f"{name} (input {'rising' if name == 'ascending' else 'falling'})")
    ax3.axhline(0, color="0.5", lw=0.6)
    ax3.set_xlabel("Input level (0 = capture minimum, 1 = maximum)")
    ax3.set_ylabel(f"Mean of model − measured ({_u(unit)})")
    ax3.set_title("Mean error vs input level\n(lag: branches opposite; bent output: alike)", fontsize=10)
    ax3.legend(fontsize="small")
    for ax in (ax1, ax2, ax3):
        ax.grid(True, alpha=0.3)
    return _save(fig, path, plots.DPI)


def _fig_time(path: Path, data: WhereFigureData) -> Path:
    """RMSE and mean residual per tenth of the capture, first cycle vs later."""
    w = data.where["by_time"]
    unit = data.unit
    fig = _new_figure(9.0, 4.0)
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2.2, 1.0]})
    pos = np.linspace(0.05, 0.95, 10)
    r = [np.nan if q is None else q for q in w["rmse_by_tenth_out"]]
    m = [np.nan if q is None else q for q in w["mean_by_tenth_out"]]
    ax1.plot(pos, r, "o-", label="RMSE")
    ax1.plot(pos, m, "s-", label="mean (model − measured)")
    ax1.axhline(data.sigma, color="tab:red", ls="--", lw=1, label="noise floor")
    ax1.axhline(0, color="0.5", lw=0.6)
    ax1.axvline(data.fit_fraction, color="0.4", ls=":", lw=1, label="≈ fit / held-out split")
    ax1.set_xlabel("Time in the capture (fraction of its duration)")
    ax1.set_ylabel(f"Model − measured ({_u(unit)})")
    ax1.legend(fontsize="small")
    n = data.n_captures
    ax1.set_title(f"By time in the capture ({n} capture{'s' if n != 1 else ''} pooled)", fontsize=10)
    ax2.bar([0, 1], [w["first_cycle"]["rmse_out"], w["later"]["rmse_out"]], color=["C2", "C0"])
    ax2.set_xticks([0, 1], ["first cycle", "later"])
    ax2.axhline(data.sigma, color="tab:red", ls="--", lw=1)
    ax2.set_ylabel(f"RMSE ({_u(unit)})")
    ax2.set_title("Start-up vs steady state", fontsize=10)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    return _save(fig, path, plots.DPI)


#: Band names as shown to a reader (keys of ``where.by_band``).
BAND_LABELS = {"drift": "slow (below f0/2)", "low_harmonics": "fundamental and harmonics 2–5",
               "high_harmonics": "harmonics 6–50", "broadband": "fast (above 50·f0)"}


def _harmonic_summary(spectra, max_order: int = 200):
    """From per-capture residual amplitude spectra (harmonic order h = f/f0, amplitude), the median
    over captures of the amplitude at each integer harmonic 1…H, and the median of everything else
    (between the harmonics: what does not repeat every cycle) in log-spaced bins of h."""
    at = {}
    rest_h, rest_a = [], []
    for h, amp, _ in spectra:
        if h.size < 3:
            continue
        dh = h[1] - h[0]
        used = np.zeros(h.size, bool)
        for m in range(1, min(int(h[-1]), max_order) + 1):
            j = int(np.argmin(np.abs(h - m)))
            if abs(h[j] - m) <= 0.5 * dh:
                at.setdefault(m, []).append(amp[j])
                used[j] = True
        sel = ~used & (h > 0)
        rest_h.append(h[sel])
        rest_a.append(amp[sel])
    orders = np.array(sorted(at))
    harm = np.array([np.median(at[m]) for m in orders]) if orders.size else np.empty(0)
    centers, level = np.empty(0), np.empty(0)
    if rest_h:
        rh, ra = np.concatenate(rest_h), np.concatenate(rest_a)
        if rh.size:
            edges = np.geomspace(rh.min(), rh.max() * 1.0001, 41)
            idx = np.digitize(rh, edges) - 1
            ok = [k for k in range(40) if np.any(idx == k)]
            centers = np.array([np.sqrt(edges[k] * edges[k + 1]) for k in ok])
            level = np.array([np.median(ra[idx == k]) for k in ok])
    return orders, harm, centers, level


def _fig_bands(path: Path, data: WhereFigureData) -> Path:
    """Residual RMS per band (with the white-noise expectation) and the typical residual spectrum
    of the periodic captures against harmonic order."""
    b = data.where["by_band"]
    unit = data.unit
    names = ["drift", "low_harmonics", "high_harmonics", "broadband"]
    labels = [BAND_LABELS[n].replace(" (", "\n(").replace(" and ", "\nand ").replace("harmonics 6", "harmonics\n6")
              for n in names]
    fig = _new_figure(11.5, 4.4)
    ax1, ax2 = fig.subplots(1, 2)
    x = np.arange(4)
    ax1.bar(x - 0.2, [b[n]["rms_out"] for n in names], 0.4, label="model − measured")
    ax1.bar(x + 0.2, [b[n]["expected_noise_rms_out"] for n in names], 0.4, label="sensor noise alone (expected)")
    for i, n in enumerate(names):
        ax1.annotate(f"{100 * b[n]['share_above_noise']:.0f} %", (i - 0.2, b[n]["rms_out"]), ha="center",
                     va="bottom", fontsize=8)
    ax1.set_xticks(x, labels, fontsize=8)
    ax1.set_ylabel(f"RMS ({_u(unit)})")
    ax1.set_title("By frequency band, f0 = drive frequency\n(labels: share of the error above noise)", fontsize=10)
    ax1.legend(fontsize="small")
    spectra = data.spectra
    if spectra:
        orders, harm, centers, level = _harmonic_summary(spectra)
        if centers.size:
            ax2.loglog(centers, np.maximum(level, 1e-300), "-", color="0.45", lw=1.2,
                       label="between harmonics (does not repeat every cycle)")
        if orders.size:
            ax2.loglog(orders, np.maximum(harm, 1e-300), "o", ms=3.5, color="C3",
                       label="at harmonics of the drive (repeats every cycle)")
        n_med = float(np.median([h.size * 2 for h, _, _ in spectra]))
        noise = 2.0 * data.sigma / math.sqrt(max(n_med, 1.0)) * math.sqrt(math.log(2.0))
        ax2.axhline(noise, color="tab:red", ls="--", lw=1, label="sensor noise (typical level)")
        for edge in (0.5, 5.5, 50.5):
            ax2.axvline(edge, color="0.4", ls=":", lw=1)
        ax2.legend(fontsize="x-small", loc="lower left")
        _plain_log_ticks(ax2, (), y_subs=(1.0,))
    else:
        ax2.text(0.5, 0.5, "no periodic capture", ha="center", va="center", transform=ax2.transAxes)
    ax2.set_xlabel("Frequency / drive frequency (harmonic order; dotted: band edges)")
    ax2.set_ylabel(f"Error amplitude ({_u(unit)}), median over captures")
    ax2.set_title(f"Spectrum of the error, {len(spectra)} periodic capture{'s' if len(spectra) != 1 else ''}",
                  fontsize=10)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
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
    t_split = c.t[v.fit_end - 1] if v.fit_end else c.t[0]
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
    axr.set_ylabel(f"Model − measured ({_u(unit)})")
    axr.set_xlabel("Time (s)")
    axr.legend(fontsize="small", loc="upper right")
    return _save(fig, path, plots.DPI)


def _fig_loop(path: Path, d: Diagnosis, i: int) -> Path:
    """One periodic capture: the measured and modelled loops, and the error against the input
    (the loops themselves differ by too little to see at full scale)."""
    c = d.figures_data["captures"][i]
    base = d.figures_data["base_predictions"][i]
    expl = d.figures_data["explained_predictions"][i]
    chosen = d.figures_data["chosen"]
    unit = d.unit
    sigma = d.noise["sigma"]
    fig = _new_figure(12.0, 4.8)
    ax1, ax2 = fig.subplots(1, 2)
    u = _decimate(c.u)
    ax1.plot(u, _decimate(c.y), color="0.15", lw=0.9, label="measured")
    ax1.plot(u, _decimate(base), color="tab:red", lw=0.9, alpha=0.85, label=d.base_model)
    if chosen:
        ax1.plot(u, _decimate(expl), color="tab:green", lw=0.9, alpha=0.85, label=f"{d.base_model} + {' + '.join(chosen)}")
    ax1.set_xlabel("Voltage (V)")
    ax1.set_ylabel(f"Displacement ({_u(unit)})")
    ax1.set_title("Loops (they overlap at this scale)", fontsize=10)
    ax1.legend(fontsize="small", loc="upper left")
    ax2.plot(u, _decimate(base - c.y), color="tab:red", lw=0.7, label=f"{d.base_model} − measured")
    if chosen:
        ax2.plot(u, _decimate(expl - c.y), color="tab:green", lw=0.7, label=f"with {' + '.join(chosen)} − measured")
    ax2.axhspan(-sigma, sigma, color="tab:red", alpha=0.12, label=f"± noise floor ({sigma:.3g} {_u(unit)})")
    ax2.axhline(0, color="0.5", lw=0.6)
    ax2.set_xlabel("Voltage (V)")
    ax2.set_ylabel(f"Model − measured ({_u(unit)})")
    ax2.set_title("Error along the loop (what is left to explain)", fontsize=10)
    ax2.legend(fontsize="small", loc="best")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{Path(c.source).name}: the capture the {d.base_model} model misses most", fontsize=11)
    return _save(fig, path, plots.DPI)


def write_figures(d: Diagnosis, fig_dir: Path, n_jobs: int | None = None) -> dict[str, str]:
    """Write every figure into ``fig_dir`` (drawn by ``n_jobs`` processes, default all cores:
    :func:`~hystfit.report.render.render_figures`); returns name → path relative to the report."""
    return start_figures(d, fig_dir, n_jobs).paths()


#: the where-figures: key → (figure function, file name); drawn from a :class:`WhereFigureData`
WHERE_FIGURES = {"conditions": ("_fig_conditions", "where_conditions.png"),
                 "branch": ("_fig_branch_position", "where_branch_position.png"),
                 "time": ("_fig_time", "where_time.png"),
                 "bands": ("_fig_bands", "where_bands.png")}

#: the folder of ``figures/`` that the where-figures started early are drawn into (:func:`start_where_figures`)
EARLY_DIR = ".where-early"


def _where_jobs(data: WhereFigureData, fig_dir: Path) -> dict[str, FigureJob]:
    return {key: FigureJob(f"{__name__}:{fn}", fig_dir / name, (data,)) for key, (fn, name) in WHERE_FIGURES.items()}


class WhereFiguresStarted:
    """The where-figures of the base model's where-analysis, being drawn before the selection is
    done (:func:`start_where_figures`): their data, the figure folder and the stream they are in."""

    def __init__(self, data: WhereFigureData, fig_dir: Path, stream: FigureStream) -> None:
        self.data, self.fig_dir, self.stream = data, fig_dir, stream

    def cancel(self) -> None:
        self.stream.cancel()


def start_where_figures(data: WhereFigureData, fig_dir: Path, n_jobs: int | None = None) -> WhereFiguresStarted:
    """Start drawing the where-figures of ``data`` (:func:`hystfit.diagnose.diagnose`'s ``on_where``)
    by the figure server while this process tests the effects. They go into ``fig_dir/.where-early``:
    :func:`start_figures` moves them into ``fig_dir`` when the final diagnosis has the same
    where-analysis, and draws them again from the final one when not (a refined noise floor)."""
    scratch = fig_dir / EARLY_DIR
    scratch.mkdir(parents=True, exist_ok=True)
    stream = FigureStream(n_jobs)
    stream.add(list(_where_jobs(data, scratch).values()))
    return WhereFiguresStarted(data, fig_dir, stream)


class DiagnoseFigures:
    """The figures of a diagnosis being drawn (:func:`start_figures`); :meth:`paths` waits for
    them, :meth:`cancel` stops the drawing."""

    def __init__(self, keys: list[str], fig_dir: Path, stream: FigureStream, early: int = 0, reuse: bool = False) -> None:
        self.keys, self.fig_dir, self.stream = keys, fig_dir, stream
        self.early, self.reuse = early, reuse  # where-figures drawn early (first in the stream); kept or not

    def paths(self) -> dict[str, str]:
        """Figure name → path relative to the report."""
        made = self.stream.result()
        if self.early:
            drawn, made = made[:self.early], made[self.early:]
            if self.reuse:
                for p in drawn:
                    os.replace(p, self.fig_dir / Path(p).name)
                made = [self.fig_dir / Path(p).name for p in drawn] + made
            shutil.rmtree(self.fig_dir / EARLY_DIR, ignore_errors=True)
        return {key: str(Path(self.fig_dir.name) / Path(p).name) for key, p in zip(self.keys, made)}

    def cancel(self) -> None:
        self.stream.cancel()


def start_figures(d: Diagnosis, fig_dir: Path, n_jobs: int | None = None,
                  early: WhereFiguresStarted | None = None) -> DiagnoseFigures:
    """Start drawing every figure into ``fig_dir``: by the figure server while this process goes
    on (the CLI fits the recommended model meanwhile), else when :meth:`DiagnoseFigures.paths`
    is asked. ``early``: the where-figures already started (:func:`start_where_figures`), kept when
    ``d`` has the same where-analysis (the same bytes as drawing them now), else drawn again."""
    fig_dir.mkdir(parents=True, exist_ok=True)
    here = f"{__name__}:"
    reuse = early is not None and early.data.same_as(d.where_figure_data)
    jobs = {} if reuse else _where_jobs(d.where_figure_data, fig_dir)
    if d.effects:
        jobs["effects"] = FigureJob(here + "_fig_effects", fig_dir / "effects_heldout.png", (d,))
    caps = d.figures_data["captures"]
    for periodic, key in ((True, "explained_periodic"), (False, "explained_other")):
        i = _worst_capture(d, periodic)
        if i is None:
            continue
        stem = _safe(Path(caps[i].source).stem)
        jobs[key] = FigureJob(here + "_fig_explained", fig_dir / f"explained_{stem}.png", (d, i))
        if periodic:
            jobs["loop"] = FigureJob(here + "_fig_loop", fig_dir / f"loop_{stem}.png", (d, i))
    stream = early.stream if early is not None else FigureStream(n_jobs)
    stream.add(list(jobs.values()))
    stream.finish()
    keys = (list(WHERE_FIGURES) if reuse else []) + list(jobs)
    return DiagnoseFigures(keys, fig_dir, stream, len(WHERE_FIGURES) if early is not None else 0, reuse)


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


# ----------------------------------------------------------------------------------------------
# Markdown
# ----------------------------------------------------------------------------------------------


#: A "hold" branch (constant input) gets its own row only with at least this share of the samples:
#: below it, it is the few samples at the turning points of a periodic drive, and a row of
#: statistics over 3 samples reads like a finding.
HOLD_MIN_FRACTION = 0.01


def shown_branches(by_branch: dict) -> list[str]:
    """Branch names worth a row: ascending, descending, and hold when it is a real hold."""
    total = sum(by_branch[n]["n_samples"] for n in ("ascending", "descending", "hold"))
    hold = by_branch["hold"]["n_samples"] >= HOLD_MIN_FRACTION * total
    return ["ascending", "descending"] + (["hold"] if hold else [])


def _table(header: Sequence[str], rows: Sequence[Sequence]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(x if isinstance(x, str) else fmt(x) for x in r) + " |")
    return out


def _params_text(r: EffectResult, unit: str) -> str:
    return _parameters_text(r.effect, r.params, unit)


def _parameters_text(effect: str, p: dict, unit: str) -> str:
    """An effect's fitted parameters (``EffectFit.params``) in a few words."""
    u = _u(unit)
    if effect == "dynamics":
        return f"f_n = {p['fn_Hz']:.4g} Hz, ζ = {p['zeta']:.3g}"
    if effect == "delay":
        return f"T_d = {1e3 * p['delay_ms']:.4g} µs ({p['delay_samples']:.2f} samples)"
    if effect == "creep":
        return ", ".join(f"{100 * g:.2g} % @ {t:g} s" for t, g in zip(p["tau_s"], p["gain"]))
    if effect == "asymmetry":
        bow = p["mid_stroke_bow_out"]
        return (f"mid-stroke {abs(bow):.3g} {u} {'above' if bow > 0 else 'below'} the straight line through the "
                f"stroke ends, skew {p['a3_out']:+.3g} {u}")
    if effect == "drift":
        return f"median abs. rate {p['median_abs_rate_out_per_s']:.3g} {u}/s"
    return ""


#: Why two effects can explain the same data, and what measurement would separate them.
SEPARATE = {
    frozenset({"dynamics", "delay"}): "below its resonance a well-damped stage lags like a pure delay; a step or "
                                      "broadband (PRBS, multisine) capture shows the ringing and the gain rise that "
                                      "only a stage has",
    frozenset({"creep", "drift"}): "both are slow; creep follows the input (it reverses after a step down and "
                                   "scales with the step), drift does not: a step-and-hold capture separates them",
    frozenset({"creep", "delay"}): "at a single drive frequency every lag looks alike; captures at several frequencies "
                                   "separate them (a delay's lag grows in proportion to the frequency, creep's shrinks) "
                                   "and so does a step-and-hold capture (creep keeps moving for seconds after the step)",
    frozenset({"creep", "dynamics"}): "at a single drive frequency every lag looks alike; captures at several "
                                      "frequencies separate them (a stage's lag grows with the frequency, creep's "
                                      "shrinks) and so does a step-and-hold capture (ringing vs a slow creep)",
}

#: What an engineer can do about each effect once it is named.
NEXT = {
    "dynamics": "identify with the `dynamics` block (`--model BASE+dynamics`: the second-order stage after the "
                "hysteresis; `+lti` with broadband captures), or keep the drive well below the resonance",
    "creep": "identify with the `creep` block (`--model BASE+creep`; the fitted time constants and gains above are "
             "its structure and a starting point); the feedforward then inverts it",
    "asymmetry": "identify with the `asymmetry` block (`--model BASE+asymmetry`, a static output bow), or use a "
                 "hysteresis model with asymmetric branches (`gpi`)",
    "drift": "identify with the `drift` block (`--model BASE+drift`: a per-capture offset and rate, reported, "
             "never predicted), re-zero the sensor before each capture, or let the set-up reach thermal equilibrium",
    "delay": "identify with the `delay` block (`--model BASE+delay`); the feedforward then shifts the command "
             "earlier by the fitted delay",
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
        r_named = next(x for x in d.steps[step] if x.effect == named)
        because = ("it needs fewer parameters" if r_named.n_parameters < r.n_parameters
                   else "it removes slightly more")
        out += ["", f"{indent}*Equally good:* `{alt}` ({_params_text(r, d.unit)}) removes {100 * r.reduction:.0f} % "
                    f"(within {d.settings.occam_tolerance:g} of `{named}`); `{named}` is named because {because}. "
                    f"The data cannot tell them apart: {why}."]
    return out


def _verdict_paragraph(d: Diagnosis) -> list[str]:
    u = _u(d.unit)
    g = d.gap
    sigma = d.noise["sigma"]
    lines = []
    conv = d.resolution_before_effects
    if conv is not None and conv.get("to") != conv.get("from"):
        # the held-out number is the finer base's: say which model each number is of (a blind test read
        # 0.2046 µm "RMS" and 0.01161 µm "held-out" as one model's)
        opt = conv["option"]
        head = (f"The `{d.base_model}` model as given ({opt} = {conv['from']}) misses the measurement by "
                f"**{g['rmse_out']:.4g} {u} RMS**; at the resolution the held-out data support ({opt} = {conv['to']}, "
                f"see *The model to use next*), by {g['heldout_rmse_out']:.4g} {u} on held-out data.")
    else:
        head = (f"The `{d.base_model}` model misses the measurement by **{g['rmse_out']:.4g} {u} RMS** "
                f"({g['heldout_rmse_out']:.4g} {u} on held-out data).")
    head += f" The sensor noise, estimated from the data, is **{sigma:.3g} {u}**: no model can go below that."
    lines.append(head)
    lines.append("")
    if d.verdict == "none":
        excess = g["heldout_excess_rmse_out"]
        if excess < d.settings.min_excess_ratio * sigma:
            lines.append("**Verdict: none.** The model is already as good as the noise allows; there is no gap "
                         "worth explaining.")
        else:
            # The best candidate's failed checks, not the threshold alone: one that removes more than
            # the threshold was turned down by the placebo or the noise floor, and the verdict says so.
            best = d.effects[0] if d.effects else None
            lines.append("**Verdict: none.** No candidate effect passes the verdict rule (item 6 of *What was "
                         "done*) on held-out data"
                         + (": " + best_not_named_text(best.effect, best.passes, best.reduction, best.improvement,
                                                       best.placebo_improvement, d.settings.threshold, d.unit)
                            if best else "")
                         + (". The remaining gap lies in the base model's own loop shape (or in an effect not in "
                            "the library): try a more flexible hysteresis model or the per-condition look-up table."
                            if excess >= sigma else
                            # a blind test's noise-only plant: 1.13× the floor held out, told to change its model
                            f". What remains is small — √(held-out² − floor²) = {excess / sigma:.2f} × the noise floor "
                            "— the model is close to what the noise allows; a more flexible hysteresis model or the "
                            "per-condition look-up table may take a little more of it."))
            fc = d.where["summary"].get("first_cycle_ratio")
            if fc is not None and fc > 1.5:
                lines += ["", f"Note: the first cycle of the captures misses {fc:.1f}× more than the later ones "
                              "(section 2, *By time*). A model started from rest cannot know the state the actuator "
                              "was in before the capture began (an earlier move, a jump onto the running drive); "
                              "that start-up error is not one of the candidate effects. Captures that start from a "
                              "known state (e.g. after a slow ramp from 0 V) avoid it."]
        return lines
    first = next(r for r in d.effects if r.effect == d.verdict)
    lines.append(f"**Verdict: `{d.verdict}`** — {PLAIN.get(d.verdict, d.verdict)}. Adding it to the model "
                 f"({_params_text(first, d.unit)}) removes **{100 * first.reduction:.0f} %** of the gap above the noise "
                 f"on data the model was not fitted to (held-out RMSE {first.heldout_rmse_before:.4g} → "
                 f"{first.heldout_rmse_after:.4g} {u})."
                 # below the threshold alone: named by the look-ahead (a blind test read "removes 27 %" beside the
                 # 30 % rule, without the reason)
                 + (joint_text(first.effect, first.joint, d.unit) if first.joint is not None else ""))
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
                 f"(a reduction of {100 * g['heldout_reduction_explained']:.0f} %: held-out RMSE before − after over "
                 "before − noise floor, as every reduction here).")
    final = d.final_parameters
    if final:
        lines.append("")
        lines.append("In that model, every named effect fitted together with the base (what params.json starts "
                     "from; each step's numbers above are those of the effect it added, which later ones can move): "
                     + "; ".join(f"`{e}` {_parameters_text(e, final[e], d.unit)}" for e in d.explained_by if e in final)
                     + ".")
    lines += ["", "*What to do:*", ""] + [f"- `{e}`: {NEXT[e]}." for e in d.explained_by if e in NEXT]
    return lines


def _md_intro(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: title, verdict and what was done."""
    s = d.settings
    n_caps = len(d.captures)
    L = [f"# Why the `{d.base_model}` model misses the measurement", ""]
    L += _verdict_paragraph(d)
    L += ["", "## What was done", "",
          f"1. **Fit.** The hysteresis model `{d.base_model}` was identified on the {n_caps} "
          f"capture{'s' if n_caps != 1 else ''} "
          f"({'one parameter set per operating condition' if d.mode == 'per-condition' else 'one parameter set for all captures' if n_caps > 1 else 'one parameter set'}; "
          f"optimizer `{d.optimizer}`, seed {d.seed}). The *gap* (or *error*) is what it still misses: "
          "e = model − measured, summarized as the RMSE (root mean square).",
          "2. **Noise floor.** The part of the gap no model can remove: the sensor noise, estimated from the "
          "sample-to-sample scatter of the error itself (a smooth model error does not scatter from one sample to "
          "the next; see *Definitions*), never from how well a model fits.",
          "3. **Where.** The error was broken down by operating condition, by branch (input rising or falling), "
          "by position in the loop, by time within the capture and by frequency.",
          "4. **Which.** Each candidate effect was added to the model and the model refitted *together with it* "
          "(the hysteresis parameters may move too). Effects in the library: "
          + "; ".join(f"`{n}` — {PLAIN[n]}" for n in EFFECTS) + ".",
          (("5. **How far, honestly.** Every fit used only the captures at the lowest and highest drive frequencies; "
            "the captures in between (" + ", ".join(f"`{Path(x).name}`" for x in d.split.get("heldout_captures", [])) + ") were "
            f"held out whole — {split_why_text(d)}. ")
           if d.split.get("kind") == "capture" else
           ("5. **How far, honestly.** Every fit used only the first part of each capture: the first "
            f"round({s.fit_fraction:g} × number of cycles) whole cycles of a periodic capture, the first "
            f"{100 * s.fit_fraction:.0f} % of the samples of any other. "))
          + "The rest (*held-out* data) was never used to "
          "fit anything and is where every effect is scored. The score is the *reduction*: "
          "(held-out RMSE before − after) / (before − noise floor), the share of the gap above the noise that the "
          "effect removes on data it never saw, between 0 (nothing) and 1 (everything down to the noise).",
          f"6. **Verdict rule.** An effect is named when (a) its reduction is at least {s.threshold:g}; (b) it "
          f"improves the held-out RMSE more than the best of {s.placebo_draws} *placebos* — corrections with the "
          "same number of adjustable parameters but random shapes that have nothing to do with the input, which "
          "shows what that many extra parameters gain by chance; and (c) the gap is meaningfully above the noise "
          f"(√(before² − floor²) ≥ {s.min_excess_ratio:g} × floor); (d) what it adds to the held-out prediction is "
          f"itself at least {s.min_excess_ratio:g} × floor (RMS); and (e) its fit does not end on the edge of "
          "its search range where the effect is absent (a stage with f_n or ζ at the top of its range). An effect short of "
          "(a) alone is named *together with* another when each, on top of the other, passes the rule (the "
          "two-effect look-ahead: their parts of the gap add in quadrature, so each alone can stay below the "
          "threshold). Among the effects that pass, the largest "
          f"reduction wins, unless one with fewer parameters comes within {s.occam_tolerance:g} of it (the simpler "
          "explanation). The winner is added to the model and the others are tested again on top of it, up to "
          f"{s.max_effects} effects: that is the order in which the effects are named.", ""]
    other = d.split.get("other_scheme")
    if other is not None:
        L += [f"The {other['kind']} split (first part of each capture fitted, the rest held out) names "
              f"{', '.join(other['explained_by']) or 'nothing'}: "
              + ("the two hold-outs agree." if other["agrees"] else
                 "the hold-outs disagree; the verdict above comes from the hold-out that interpolates "
                 "(held-out frequencies inside the fitted ones at every amplitude), the temporal one tests an "
                 "amplitude extrapolation on these captures."), ""]

    return L


def _md_gap(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: 1. the gap and the noise floor."""
    u = _u(d.unit)
    sigma = d.noise["sigma"]
    L = ["## 1. The gap and the noise floor", ""]
    g = d.gap
    rows = [["RMSE, all data (model fitted to all data)", f"{g['rmse_out']:.4g} {u}"],
            ["RMSE on held-out data (model fitted to the first part)", f"{g['heldout_rmse_out']:.4g} {u}"],
            ["Noise floor σ (white sensor noise)", f"{sigma:.3g} {u}"],
            ["Cycle-to-cycle repeatability (cross-check, includes slow noise)",
             "–" if d.noise["repeatability_out"] is None else f"{d.noise['repeatability_out']:.3g} {u}"],
            ["Smallest output step (quantization, for reference)", f"{d.noise['quantization_step_out']:.3g} {u}"],
            ["Gap above noise √(RMSE² − σ²), all data", f"{g['excess_rmse_out']:.4g} {u}"],
            ["Share of the squared gap that is noise", "–" if g["noise_share_of_gap"] is None
             else f"{100 * g['noise_share_of_gap']:.1f} %"]]
    L += _table(["quantity", "value"], rows) + [""]
    if d.noise["repeatability_out"] is not None and d.noise["repeatability_out"] > 1.5 * sigma:
        L += [f"The repeatability ({d.noise['repeatability_out']:.3g} {u}) is well above the white-noise floor: the "
              "noise has slow components, or the process does not repeat from cycle to cycle (creep, drift). "
              "The floor used here is the white part only, so slow noise would count as model gap.", ""]
    if noise_floor_doubtful(d.noise):
        text = doubtful_floor_text(d.noise, u)
        L += [f"**Caution:** {text[0].upper()}{text[1:]}.", ""]

    return L


def _md_where(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: 2. where the model misses."""
    u = _u(d.unit)
    w = d.where
    L = ["## 2. Where the model misses", "", "Main findings:", ""]
    L += [f"- {p}" for p in pointers_text(d.findings, d.unit)] + [""]
    L += ["### By operating condition", ""]
    rows = [[f"{r['amplitude_V']:g} V, {r['frequency_Hz']:g} Hz", r["rmse_out"], r["excess_rmse_out"],
             "yes" if r["periodic"] else "no"] for r in w["by_condition"]]
    hdr = ["input peak-to-peak, drive frequency", f"RMSE ({u})", f"above noise ({u})", "periodic input"]
    if "by_condition_alone" in w:
        alone = {r["label"]: r for r in w["by_condition_alone"]}
        rows = [r + [alone[c["label"]]["rmse_out"]] for r, c in zip(rows, w["by_condition"])]
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
        L += ["How the gap above noise grows with the drive frequency f and amplitude A (exponents b, c of "
              "RMSE ∝ f^b · A^c over the periodic conditions) — " + "; ".join(exps)
              + ". A model whose loop shape is wrong in the same way at every amplitude misses ∝ A (c ≈ 1); a "
                "static bend of the output grows faster (c ≥ 2); lags (stage dynamics, delay) make b > 0.", ""]
    if "conditions" in figs:
        L += [f"![gap per condition]({figs['conditions']})", ""]
    L += ["### By branch, loop position and level", ""]
    br = w["by_branch"]
    shown = shown_branches(br)
    L += _table(["branch", f"RMSE ({u})", f"mean of model − measured ({u})", "samples"],
                [[{"ascending": "ascending (input rising)", "descending": "descending (input falling)",
                   "hold": "hold (input constant)"}[n], br[n]["rmse_out"], br[n]["mean_out"], str(br[n]["n_samples"])]
                 for n in shown])
    if "hold" not in shown and br["hold"]["n_samples"]:
        L += ["", f"({br['hold']['n_samples']} samples with a constant input — the turning points of a periodic drive, "
                  "not a hold — are left out of this table.)"]
    lp = w["by_loop_position"]
    L += ["", loop_position_text(lp["near_turning_points"], lp["mid_stroke"], d.unit)]
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
    L += [f"First cycle: RMSE {bt['first_cycle']['rmse_out']:.4g} {u} (mean {bt['first_cycle']['mean_out']:+.3g} {u}); "
          f"later: {bt['later']['rmse_out']:.4g} {u} (mean {bt['later']['mean_out']:+.3g} {u}). "
          + (f"Fitted on the first part and tested on the rest, the base model's gap above noise on the held-out part "
             f"is {sm['heldout_to_fit_ratio']:.2f}× that on the fitted part "
             + ("(above 1: the error builds up with time, as creep or drift would make it)."
                if sm["heldout_to_fit_ratio"] > 1.0 else
                "(below 1: the later part is predicted better than the fitted part is matched, so nothing builds up "
                "with time; a large start-up error in the fitted part does this).")
             if sm.get("heldout_to_fit_ratio") is not None else ""), ""]
    if "time" in figs:
        L += [f"![time]({figs['time']})", ""]
    L += ["### By frequency band", ""]
    bb = w["by_band"]
    L += _table(["band (f0 = drive frequency)", f"error RMS ({u})", f"sensor noise alone ({u})",
                 "share of the gap above noise"],
                [[BAND_LABELS[n], bb[n]["rms_out"], bb[n]["expected_noise_rms_out"],
                  f"{100 * bb[n]['share_above_noise']:.0f} %"] for n in ("drift", "low_harmonics", "high_harmonics", "broadband")])
    L += ["", "Slow error (below half the drive frequency) comes from trends: creep, drift. Error at the fundamental "
              "and the first harmonics is a loop of the wrong width or shape. Sharp features — turning points, "
              "steps, ringing of a stage — put it into the higher harmonics. Error at the harmonics repeats every "
              "cycle; error between them does not.", ""]
    if "bands" in figs:
        L += [f"![bands]({figs['bands']})", ""]

    return L


def _md_effects(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: 3. which effect."""
    u = _u(d.unit)
    L = ["## 3. Which effect: every candidate tested", ""]
    if d.resolution_before_effects is not None:
        final = d.base_resolution["final"] if d.base_resolution else None
        L += [converged_text(d.resolution_before_effects, d.unit, final), ""]
    for i, step in enumerate(d.steps):
        title = "Step 1 — on top of the base model" if i == 0 else \
            f"Step {i + 1} — on top of the base model + {' + '.join(d.explained_by[:i])}"
        L += [f"### {title}", ""]
        rows = []
        for r in step:
            rows.append([f"`{r.effect}`", r.heldout_rmse_before, r.heldout_rmse_after, f"{r.reduction:.2f}",
                         placebo_text(r.placebo_improvement), str(r.n_parameters), _params_text(r, d.unit),
                         "**yes**" if r.eligible else "no"])
        L += _table(["effect", f"held-out before ({u})", f"after ({u})", "reduction", f"placebo gain ({u})",
                     "parameters", "fitted values", "passes the rule"], rows) + [""]
        if i > 0:
            L += [joint_text(r.effect, r.joint, d.unit).strip() for r in step if r.joint is not None]
            L += [""] if any(r.joint is not None for r in step) else []
        if i == 0:
            L += ["Evidence per effect:", ""]
            for r in step:
                failed = not_named_reasons(r.passes, r.reduction, r.improvement, r.placebo_improvement,
                                           d.settings.threshold, d.unit)
                L += [f"- **{r.effect}** ({PLAIN.get(r.effect, '')}): {evidence_text(r.evidence, d.unit)}."
                      + (joint_text(r.effect, r.joint, d.unit) if r.joint is not None
                         else f" Not named: {'; and '.join(failed)}." if failed else "")]
            L += ["", "(*Signature*: the shape this effect would add to the error to first order — e.g. a lag adds "
                      "a copy of the velocity; its share is how much of the error above the noise that shape alone "
                      "matches, before any refit.)"]
            L += [""]
    if d.resolution_during_selection:
        L += [during_text(d.resolution_during_selection, d.unit), ""]
    if d.resolution is not None:
        L += [resolution_text(d.resolution, d.unit), ""]
    rec = reconciliation_document(d)
    if rec:
        L += ["Where the error's shape and the refit disagree:", ""]
        for c in rec:
            L += [f"- the error's shape points at `{c['effect']}` (its signature matches {100 * c['signature_share']:.0f} % "
                  f"of the gap above the noise), but it is not named: {c['why']}."]
        L += [""]
    if "effects" in figs:
        L += [f"![held-out RMSE per effect]({figs['effects']})", ""]

    return L


def _md_model(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: 4. the model with the named effects."""
    L = ["## 4. The model with the named effects", ""]
    for key, text in (("loop", "Loop of the capture the base model misses most"),
                      ("explained_periodic", "Time series of that capture (grey: held out)"),
                      ("explained_other", "The non-periodic capture the base model misses most")):
        if key in figs:
            L += [f"{text}:", "", f"![{key}]({figs[key]})", ""]
    return L


def _md_definitions(d: Diagnosis, figs: dict[str, str]) -> list[str]:
    """Report section: definitions."""
    L = ["## Definitions", "",
          "- RMSE = √mean(e²), e = model − measured; held-out RMSE counts only the samples after the split.",
          "- Noise floor σ: the scatter of e from one sample to the next. Technically 1.4826 × the median absolute "
          "deviation of the third difference (−1, 3, −3, 1)/√20 of e: white sensor noise passes it unchanged, a "
          "smooth model error (and creep or drift) cancels out, and the median ignores the few kinks at turning "
          "points. Cross-check: the cycle-to-cycle repeatability of the measurement.",
          "- Gap above noise = √(RMSE² − σ²): the part of the RMSE that is not sensor noise.",
          "- reduction = (before − after)/(before − σ), clipped to [0, 1]; placebo gain = the largest held-out "
          "improvement among random corrections with the same number of parameters (random mixtures of the "
          "effects' shapes with their timing scrambled: same smoothness, no relation to the input); – where "
          f"none was fitted: {NO_PLACEBO_WHY}.",
          "- Parameters: the number of numbers fitted for the effect (a per-capture effect such as drift has two per "
          "capture).",
          f"- Runtime {d.runtime_s:.1f} s. Machine-readable results: `diagnosis.json`.", ""]
    return L

def markdown(d: Diagnosis, figs: dict[str, str]) -> str:
    """The report text (see the module docstring), section by section."""
    L: list[str] = []
    for section in (_md_intro, _md_gap, _md_where, _md_effects, _md_model, _md_definitions):
        L += section(d, figs)
    return "\n".join(L)

#: a step-1 effect that removes at least this share of the held-out gap above the noise is worth a
#: word when nothing is named (:func:`_short_of_the_rule`)
NOTABLE_REDUCTION = 0.1


def _short_of_the_rule(d: Diagnosis) -> str | None:
    """The last line when nothing was named but an effect removed a notable share of a gap well above
    the noise — short of the user's ``--threshold`` or of a placebo — or when ``--effects`` left some
    out: a blind test's ``--threshold 0.9`` was told "the base's resolution limits it" while delay
    removed 81 % of a gap 11× the noise. None otherwise."""
    tested = {r.effect for r in d.effects}
    left_out = [e for e in EFFECTS if e not in tested and e not in d.split.get("not_tested", ())]
    best = max((r for r in d.effects if r.passes.get("gap_above_noise", False)), key=lambda r: r.reduction,
               default=None)
    u, s = _u(d.unit), d.settings
    why = []
    if best is not None and best.reduction >= NOTABLE_REDUCTION:
        rule = ("below --threshold " f"{s.threshold:g}" if best.reduction < s.threshold
                else "no better than a placebo of its size")
        why.append(f"the best, {best.effect}, removes {best.reduction:.0%} of the held-out gap above the noise, "
                   f"{rule}")
        if s.max_effects < 2 and best.reduction < s.threshold:
            # the two-effect look-ahead needs a second step (a blind test's strong creep + asymmetry plant
            # got nothing named with --max-effects 1, the gap 40× the noise)
            why.append("two effects may share the gap, each alone below the threshold: --max-effects 2 or more lets "
                       "the look-ahead test them together")
    if left_out:
        why.append(f"not tested (--effects): {', '.join(left_out)}")
    if not why:
        return None
    return (f"next: no effect named (held-out RMSE {d.heldout_rmse_named:.4g} {u}, noise floor "
            f"{d.noise['sigma']:.3g} {u}); " + "; ".join(why))


def _option_text(v) -> str:
    """A ``--model-option`` value as the command line reads it (a list as JSON, e.g. [0.01,0.1])."""
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(f"{x:g}" if isinstance(x, float) else str(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v).lower() if isinstance(v, bool) else str(v)


def next_step_line(d: Diagnosis, out_dir: Path | str | None = None) -> str:
    """The report's last line: the effects named, the held-out error of the base with all of
    them, and what to run next."""
    u = _u(d.unit)  # in words: µm (the JSON's names keep um)
    # the options the base was given, then those the diagnosis adds: the model the hand-over fitted
    opts = "".join(f" --model-option {k}={_option_text(v)}" for k, v in {**d.given_options,
                                                                          **d.recommended_options}.items())
    # identify fits per condition by default; the hand-over is global unless the diagnosis was not
    # (a blind test's "identify it anew" built a look-up table where params.json held one set)
    scope = "" if d.mode == "per-condition" else " --global"
    if not d.explained_by:
        short = _short_of_the_rule(d)
        if short is not None:
            return short
        if opts:
            params = f"{out_dir}/params.json" if out_dir is not None else "params.json"
            return (f"next: no effect named; the base's resolution limits it (held-out RMSE "
                    f"{d.heldout_rmse_named:.4g} {u} with{opts}). {d.base_model}{opts} fitted on all the data is in "
                    f"{params}: hystfit invert {params} --sine AMPLITUDE,FREQUENCY --out v.csv, or identify it anew "
                    f"with --model {d.base_model}{opts}{scope}")
        return (f"next: no effect named; {d.base_model} is as good as any augmentation on held-out data "
                f"(held-out RMSE {d.heldout_rmse_named:.4g} {u}).")
    params = f"{out_dir}/params.json" if out_dir is not None else "params.json"
    capped = d.stopped_at_max_effects
    more = ("" if capped is None else
            f" The selection stopped at --max-effects {capped['max_effects']} while {', '.join(capped['also_passing'])} "
            f"also passed the rule in its last step: rerun with --max-effects {capped['max_effects'] + 1} to test "
            "it on top.")
    return (f"next: named {', '.join(d.explained_by)}; held-out RMSE of {d.recommended_model}{opts} "
            f"{d.heldout_rmse_named:.4g} {u}.{more} {d.recommended_model} fitted on all the data is in {params}: "
            f"hystfit invert {params} --sine AMPLITUDE,FREQUENCY --out v.csv, or identify it anew with "
            f"--model {d.recommended_model}{opts}{scope}")


# ----------------------------------------------------------------------------------------------
# The JSON document
# ----------------------------------------------------------------------------------------------


def _insert(d: dict, key: str, value, after: str | None) -> dict:
    """``d`` with ``key: value`` placed right after the entry ``after`` (first when None): the prose
    fields sit where the contract of diagnosis.json has always had them."""
    items = list(d.items())
    i = 0 if after is None else [k for k, _ in items].index(after) + 1
    return dict(items[:i] + [(key, value)] + items[i:])


#: The where-analysis sections with a ``definition`` entry, and the entry it follows (None: first).
_DEFINITION_AFTER = {"by_loop_position": "mid_stroke", "by_level": None, "by_time": "later", "by_band": "broadband"}


def where_document(d: Diagnosis) -> dict:
    """The ``where`` section of diagnosis.json (before the unit renaming): the numbers of
    :attr:`Diagnosis.where` with each section's ``definition`` and the findings worded as ``pointers``."""
    w = {k: _insert(v, "definition", DEFINITIONS[k], _DEFINITION_AFTER[k]) if k in _DEFINITION_AFTER else v
         for k, v in d.where.items()}
    w["pointers"] = pointers_text(d.findings, d.unit)
    return w


def split_why_text(d: Diagnosis) -> str:
    """Why the hold-out scheme was chosen (``split.why``), from the diagnosis' :class:`SplitChoice`."""
    why = split_why(d.split_choice.reason, d.split_choice.swept_sources)
    if d.split.get("not_tested"):
        why += "; " + not_tested_text(d)
    ff = fit_fraction_text(d)
    if ff is not None:
        why += "; " + ff
    return why


def fit_fraction_text(d: Diagnosis) -> str | None:
    """Under the capture split, what a ``--fit-fraction`` other than the default applies to (a blind
    test's 0.1 and 0.9 gave the same verdict without a word); None otherwise."""
    from ..diagnose import DiagnoseSettings

    if d.split["kind"] != "capture" or d.settings.fit_fraction == DiagnoseSettings().fit_fraction:
        return None
    return (f"--fit-fraction {d.settings.fit_fraction:g} applies to the captures split in time, to the part of the "
            "captures held out whole on which their own per-capture coefficients are fitted, and to the temporal "
            "check; the verdict's hold-out is whole captures (those at interior frequencies)")


def not_tested_text(d: Diagnosis) -> str:
    """Why the effects of ``split.not_tested`` were not tested by this hold-out
    (:func:`hystfit.diagnose.untestable_effects`)."""
    names = ", ".join(d.split["not_tested"])
    return (f"{names} is not tested: its trend in time is also a trend in amplitude on these captures, and no "
            "held-out sample tells the two apart")


def split_document(d: Diagnosis) -> dict:
    """The ``split`` section of diagnosis.json: the numbers of :attr:`Diagnosis.split` with ``why``
    and ``description`` worded."""
    kind = d.split["kind"]
    out = _insert(d.split, "why", split_why_text(d), "kind")
    return _insert(out, "description", split_description(kind, d.settings.fit_fraction,
                                                         d.split.get("split_in_time_captures", ())),
                   "heldout_captures" if kind == "capture" else "fit_fraction")


def reconciliation_document(d: Diagnosis) -> list[dict]:
    """``reconciliation`` of diagnosis.json: :attr:`Diagnosis.reconciliation` with each reason
    code worded as ``why``."""
    return [{**{k: v for k, v in c.items() if k != "reason"},
             "why": reconciliation_why(c["reason"], c["reduction"], d.settings.threshold)}
            for c in d.reconciliation]


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def effect_document(r: EffectResult, unit: str) -> dict:
    """One tested effect in diagnosis.json (``effects``, ``steps[].effects``), its evidence worded."""
    u = unit
    return {"effect": r.effect, "title": r.title,
            f"heldout_rmse_before_{u}": _num(r.heldout_rmse_before),
            f"heldout_rmse_after_{u}": _num(r.heldout_rmse_after),
            "reduction": _num(r.reduction),
            f"improvement_{u}": _num(r.improvement),
            f"placebo_improvement_{u}": _num(r.placebo_improvement),
            f"own_rms_heldout_{u}": _num(r.own_rms),
            "placebo_reduction": _num(r.placebo_reduction),
            f"fit_rmse_before_{u}": _num(r.fit_rmse_before),
            f"fit_rmse_after_{u}": _num(r.fit_rmse_after),
            "n_parameters": r.n_parameters,
            "signature_share": _num(r.signature_share),
            "evidence": evidence_text(r.evidence, u),
            "params": json_safe(unit_keys(r.params, u)),
            "passes": dict(r.passes), "eligible": r.eligible,
            "named_together_with": _joint_document(r.joint, u)}


def _joint_document(joint: dict | None, unit: str) -> dict | None:
    """The two-effect look-ahead that named an effect (``named_together_with``), or None."""
    if joint is None:
        return None
    return {"effect": joint["with"], f"heldout_rmse_after_both_{unit}": _num(joint["heldout_rmse_after"]),
            "reduction_of_both": _num(joint["reduction"]),
            "reduction_on_top_of_other": _num(joint["reduction_on_top_of_other"]), "threshold": joint["threshold"]}


def diagnosis_document(d: Diagnosis) -> dict:
    """The JSON document ``diagnosis.json`` (schema ``hystfit.diagnosis`` v1; unit-bearing names end
    in the output unit): the diagnosis' numbers and codes with every prose field worded by
    :mod:`hystfit.report.diagnose_wording`. Written by :func:`write_diagnose_outputs` and printed by
    ``hystfit diagnose --json``."""
    u = d.unit
    s = d.settings
    return json_safe({
        **schema_fields("diagnosis"),
        "base_model": d.base_model, "optimizer": d.optimizer, "mode": d.mode,
        "seed": d.seed, "units": {"input": "V", "output": u, "time": "s"},
        f"noise_floor_{u}": d.noise["sigma"],
        "noise": unit_keys({**d.noise, "method": noise_method_text(d.noise)}, u),
        "gap": unit_keys(d.gap, u),
        "where": unit_keys(where_document(d), u),
        "effects": [effect_document(r, u) for r in d.effects],
        "verdict": d.verdict,
        "explained_by": list(d.explained_by),
        "steps": [{"step": i + 1, "named": d.explained_by[i] if i < len(d.explained_by) else None,
                   "equally_good": list(d.alternatives[i]) if i < len(d.alternatives) else [],
                   "effects": [effect_document(r, u) for r in step]} for i, step in enumerate(d.steps)],
        "split": split_document(d),
        "rule": {"threshold": s.threshold, "occam_tolerance": s.occam_tolerance,
                 "min_excess_ratio": s.min_excess_ratio, "placebo_draws": s.placebo_draws,
                 "placebo_margin": s.placebo_margin, "max_effects": s.max_effects,
                 "resolution_threshold": s.resolution_threshold},
        "captures": [unit_keys(c, u) for c in d.captures],
        "runtime_s": d.runtime_s,
        "recommended_model": d.recommended_model,
        "reconciliation": reconciliation_document(d),
        f"heldout_rmse_with_named_effects_{u}": _num(d.heldout_rmse_named),
        "recommended_model_options": d.recommended_options,
        "stopped_at_max_effects": d.stopped_at_max_effects,
        "final_parameters": {e: unit_keys(p, u) for e, p in d.final_parameters.items()},
        "resolution": unit_keys(d.resolution, u) if d.resolution is not None else None,
        "resolution_before_effects": _converged_document(d.resolution_before_effects, u),
        "base_resolution": d.base_resolution,
        "resolution_during_selection": [unit_keys(c, u) for c in d.resolution_during_selection],
    })


def _converged_document(r: dict | None, unit: str) -> dict | None:
    """``resolution_before_effects`` of diagnosis.json (:func:`hystfit.diagnose.converge_resolution`)."""
    if r is None:
        return None
    return {**{k: v for k, v in r.items() if k != "steps"}, "steps": [unit_keys(x, unit) for x in r["steps"]]}


def write_diagnose_outputs(d: Diagnosis, out_dir: Path, *, make_figures: bool = True,
                           recommended=None, figures: DiagnoseFigures | None = None) -> dict[str, Path]:
    """Write diagnosis.json, diagnosis.md, (optionally) figures/ and — when effects were named and
    ``recommended`` (their model fitted on all the data) is given — params.json (the same schema as
    ``hystfit identify`` writes) into ``out_dir`` (which must exist). ``figures``: the figures
    already being drawn into ``out_dir/figures`` (:func:`start_figures`), waited for here."""
    out_dir = Path(out_dir)
    paths = {"json": out_dir / "diagnosis.json", "md": out_dir / "diagnosis.md"}
    atomic_write_text(paths["json"], dumps(diagnosis_document(d)))
    figs: dict[str, str] = {}
    if figures is not None or make_figures:
        figs = figures.paths() if figures is not None else write_figures(d, out_dir / "figures")
        paths["figures"] = out_dir / "figures"
    md = markdown(d, figs)
    if recommended is not None:
        paths["params"] = out_dir / "params.json"
        atomic_write_text(paths["params"], dumps(identify_to_dict(recommended)))
        rms = ", ".join(f"{f.label}: {f.metrics[f'rmse_{d.unit}']:.4g} {_u(d.unit)}" for f in recommended.fits)
        what = ("the base followed by the named effects, in the order a signal meets them" if d.explained_by else
                "the base at the resolution the held-out data support: "
                + ", ".join(f"{k} = {v}" for k, v in d.recommended_options.items()))
        md += (f"\n## The model to use next\n\n`{d.recommended_model}` ({what}) was identified on all the data and "
               f"written to `params.json` (fit RMSE {rms}).\n")
    md += f"\n{next_step_line(d)}\n"
    atomic_write_text(paths["md"], md)
    return paths
