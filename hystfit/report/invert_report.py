"""Reports of ``hystfit invert``: JSON summary, Markdown report and figures.

The figure helper :func:`tracking_figure` (target vs output, error, voltage with its limits and
the limited spans shaded) is also used by ``hystfit track``. Figures are built with
:class:`matplotlib.figure.Figure` (no pyplot state) and written atomically with
:func:`hystfit.io.atomic_write_bytes`, like :mod:`hystfit.report.plots`.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Sequence

import numpy as np

from ..invert import InversionResult, Span, condition_text
from ..io import atomic_write_text
from ..results import dumps, json_safe, schema_fields
from . import plots
from .plots import MAX_POINTS, _decimate_minmax, display_unit, legend_headroom
from .tables import fmt, notes_and_figures

#: Spans listed in the Markdown report (all are in the JSON up to :data:`MAX_SPANS_JSON`).
MAX_SPANS_MD = 20
MAX_SPANS_JSON = 1000
DPI = 110


# ----------------------------------------------------------------------------------------------
# figures


def _wrap(title: str, width: int = 95) -> str:
    return "\n".join(textwrap.wrap(title, width))


def _save(fig: Figure, path: Path) -> Path:
    return plots._save(fig, Path(path), DPI)


def _draw_tracking(axes, t, r, y, v, *, unit: str, output_label: str, vmin: float | None, vmax: float | None,
                   spans: Sequence[Span], legends: bool = True, rmse_note: str = "") -> None:
    """Fill three axes (displacement, error, voltage) with the samples given (already windowed).

    Long series are decimated keeping each bucket's min and max (:func:`_minmax`), never by plain
    striding, so no peak is lost and no periodic signal is aliased.
    """
    ax, axe, axv = axes
    u = display_unit(unit)
    ax.plot(*_decimate_minmax(t, r), color="0.15", lw=0.9, label="target")
    ax.plot(*_decimate_minmax(t, y), color="tab:red", lw=0.9, alpha=0.85, label=output_label)
    ax.set_ylabel(f"Displacement ({u})")
    ax.grid(True, alpha=0.3)
    e = y - r
    finite = np.isfinite(e)
    rmse = float(np.sqrt(np.mean(e[finite] ** 2))) if finite.any() else float("nan")
    if np.isfinite(rmse):
        axe.axhspan(-rmse, rmse, color="tab:blue", alpha=0.15, lw=0, label=f"±RMSE{rmse_note} = {rmse:.3g} {u}")
    axe.axhline(0.0, color="0.5", lw=0.6)
    axe.plot(*_decimate_minmax(t, e), color="tab:blue", lw=0.7, label=f"{output_label} − target")
    axe.set_ylabel(f"Error ({u})")
    axe.grid(True, alpha=0.3)
    if legends:  # room above the curves for the upper-right legends
        legend_headroom(ax, (r, y), 0.3)
    legend_headroom(axe, (e, np.array([-rmse, rmse])), 0.65)
    axv.plot(*_decimate_minmax(t, v), color="tab:green", lw=0.9, label="voltage")
    label = "voltage limits"
    for lim in (vmin, vmax):
        if lim is not None:
            axv.axhline(lim, color="0.4", lw=0.7, ls="--", label=label)
            label = None
    shown = False
    half = 0.5 * (t[1] - t[0]) if t.size > 1 else 0.0
    for s in spans[:500]:
        if s.stop_s < t[0] or s.start_s > t[-1]:
            continue
        axv.axvspan(s.start_s - half, s.stop_s + half, color="tab:orange", alpha=0.3, lw=0,
                    label=None if shown else "limited")
        shown = True
    axv.set_ylabel("Voltage (V)")
    axv.set_xlabel("Time (s)")
    axv.grid(True, alpha=0.3)
    for a in (axes if legends else (axe,)):  # the error legend carries this panel's RMSE: always shown
        a.legend(loc="upper right", fontsize="small")


def tracking_figure(path, t_s, target, output, voltage_V, *, unit: str = "um", title: str = "",
                    output_label: str = "predicted", vmin: float | None = None, vmax: float | None = None,
                    spans: Sequence[Span] = ()) -> Path:
    """Three panels: target and output, error (output − target) with its ±RMSE band, voltage with limits.

    Parameters
    ----------
    path : PNG file to write.
    t_s : (N,) time (s).
    target, output : (N,) displacement in ``unit``.
    voltage_V : (N,) applied voltage (V).
    unit, title : axis unit and title.
    output_label : legend of ``output`` (e.g. ``"predicted"`` or ``"plant output"``).
    vmin, vmax : voltage limits drawn as dashed lines.
    spans : limited spans, shaded on the voltage panel.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.5, 7.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True, gridspec_kw={"height_ratios": [2.0, 1.2, 1.2]})
    _draw_tracking(axes, np.asarray(t_s, float), np.asarray(target, float), np.asarray(output, float),
                   np.asarray(voltage_V, float), unit=unit, output_label=output_label, vmin=vmin, vmax=vmax,
                   spans=spans)
    if title:
        axes[0].set_title(_wrap(title))
    return _save(fig, Path(path))


#: A detail figure is drawn when the target is longer than this many detail windows.
DETAIL_MIN_WINDOWS = 6
#: Periods of the segment's frequency shown in a detail window.
DETAIL_PERIODS = 3.0


def detail_windows(target) -> list[tuple[int, int, str]]:
    """Sample windows ``(start, stop, label)`` of ≈ 3 periods at the start and at the end of a long target.

    The period is that of the first (last) segment's nominal frequency; a window holds at most
    half of :data:`MAX_POINTS` samples and never more than its segment. Empty when the target is
    shorter than :data:`DETAIL_MIN_WINDOWS` windows: its main figure is readable as it is.
    """
    def length(seg) -> int:
        f = seg.frequency_Hz
        n = int(round(DETAIL_PERIODS / (f * target.dt))) + 1 if math.isfinite(f) and f > 0 else seg.stop - seg.start
        return max(16, min(n, MAX_POINTS // 2, seg.stop - seg.start))

    n0, n1 = length(target.segments[0]), length(target.segments[-1])
    if target.n <= DETAIL_MIN_WINDOWS * max(n0, n1):
        return []
    dt = target.dt
    return [(0, n0, f"start: {0:.4g}–{(n0 - 1) * dt:.4g} s"),
            (target.n - n1, target.n, f"end: {(target.n - n1) * dt:.4g}–{(target.n - 1) * dt:.4g} s")]


def tracking_detail_figure(path, t_s, target, output, voltage_V, windows: Sequence[tuple[int, int, str]], *,
                           unit: str = "um", title: str = "", output_label: str = "predicted",
                           vmin: float | None = None, vmax: float | None = None, spans: Sequence[Span] = ()) -> Path:
    """The panels of :func:`tracking_figure` at full resolution, one column per window (see :func:`detail_windows`)."""
    t, r, y, v = (np.asarray(a, float) for a in (t_s, target, output, voltage_V))
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.6 * len(windows) + 1.0, 7.0), layout="constrained")
    grid = fig.subplots(3, len(windows), squeeze=False, sharex="col",
                        gridspec_kw={"height_ratios": [2.0, 1.2, 1.2]})
    for j, (a, b, label) in enumerate(windows):
        col = grid[:, j]
        _draw_tracking(col, t[a:b], r[a:b], y[a:b], v[a:b], unit=unit, output_label=output_label, vmin=vmin,
                       vmax=vmax, spans=spans, legends=j == len(windows) - 1, rmse_note=" (window)")
        col[0].set_title(label, fontsize="medium")
    if title:
        fig.suptitle(_wrap(title, 110))
    return _save(fig, Path(path))


def error_comparison_figure(path, t_s, errors: dict, *, unit: str = "um", title: str = "") -> Path:
    """Tracking errors of several controllers on one axis (min/max decimated)."""
    t = np.asarray(t_s, float)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.5, 3.8), layout="constrained")
    ax = fig.subplots()
    for i, (lab, e) in enumerate(errors.items()):
        te, ee = _decimate_minmax(t, np.asarray(e, float))
        ax.plot(te, ee, lw=0.7, label=lab, color=f"C{i}")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_ylabel(f"Error ({display_unit(unit)})")
    ax.set_xlabel("Time (s)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    if title:
        ax.set_title(_wrap(title))
    return _save(fig, Path(path))


# ----------------------------------------------------------------------------------------------
# summaries


def span_dicts(spans: Sequence[Span], limit: int = MAX_SPANS_JSON) -> list[dict]:
    return [{"kind": s.kind, "start_s": s.start_s, "stop_s": s.stop_s, "samples": s.n, "worst_V": s.worst_V}
            for s in spans[:limit]]


def invert_summary(res: InversionResult) -> dict:
    """JSON-safe summary of an inversion (NaN/inf → null)."""
    tg = res.target
    u = res.unit
    segs = []
    for ch, m in zip(res.choices, res.segment_metrics):
        segs.append({"segment": ch.segment.label, "start_s": ch.segment.start * tg.dt,
                     "stop_s": (ch.segment.stop - 1) * tg.dt, "frequency_Hz": ch.condition[1],
                     "condition": {"amplitude_V": ch.condition[0], "frequency_Hz": ch.condition[1]},
                     "lookup": {"amplitude_V": ch.query[0], "frequency_Hz": ch.query[1], "clamped": ch.clamped},
                     "how": ch.how, "converged": ch.converged, "note": ch.note,
                     "cells": [{"label": c.label, "amplitude_V": c.amplitude_V, "frequency_Hz": c.frequency_Hz,
                                "weight": c.weight} for c in ch.cells],
                     "iterations": [{"amplitude_V": it.amplitude_V, "cells": [[c.label, c.weight] for c in it.cells],
                                     "result_pp_V": it.result_pp_V} for it in ch.iterations],
                     "metrics": m, f"cells_fit_rmse_{u}": res.fit_rmse(ch)})
    v = res.voltage_V
    return json_safe({
        **schema_fields("invert"),
        "params": res.params_path, "model": res.model_name, "units": {"output": u, "input": "V", "time": "s"},
        "target": {"description": tg.description, "kind": tg.kind, "samples": tg.n, "fs_Hz": tg.fs,
                   "duration_s": tg.n * tg.dt, f"stroke_{u}": tg.stroke, f"min_{u}": float(tg.y.min()),
                   f"max_{u}": float(tg.y.max())},
        "method": res.method,
        "initial_voltage": {"V": res.initial_voltage_V, "source": res.initial_voltage_source},
        "voltage": {"min_V": float(v.min()), "max_V": float(v.max()), "pp_V": float(v.max() - v.min()),
                    "max_slew_V_per_s": float(np.max(np.abs(np.diff(v)))) / tg.dt if v.size > 1 else 0.0},
        "limits": res.limits,
        "clipping": {"spans": len(res.clip_spans), "samples": sum(s.n for s in res.clip_spans),
                     "list": span_dicts(res.clip_spans), "truncated": len(res.clip_spans) > MAX_SPANS_JSON},
        "slew_limiting": {"spans": len(res.slew_spans), "samples": sum(s.n for s in res.slew_spans),
                          "list": span_dicts(res.slew_spans), "truncated": len(res.slew_spans) > MAX_SPANS_JSON},
        "cells_used": [[lab, w] for lab, w in res.cells_used()],
        "segments": segs,
        "predicted_tracking": res.metrics,
        "predicted_tracking_without_limits": res.metrics_unlimited,
        # the cells' own error on their identification data: the floor of a measured tracking error
        f"cells_fit_rmse_{u}": res.fit_rmse(),
        "extrapolation": list(res.extrapolation),
        "notes": list(res.notes),
        "runtime_s": res.runtime_s,
    })


def _metric_lines(m: dict, unit: str) -> list[str]:
    u = display_unit(unit)
    return [f"- max |e| = {fmt(m[f'max_error_{unit}'])} {u} ({fmt(m['max_error_pct_of_stroke'], 3)} % of stroke)",
            f"- RMSE = {fmt(m[f'rmse_{unit}'])} {u} ({fmt(m['rmse_pct_of_stroke'], 3)} % of stroke)",
            f"- mean error = {fmt(m[f'mean_error_{unit}'])} {u}; stroke = {fmt(m[f'stroke_{unit}'])} {u}; "
            f"{m['n_samples']} samples"]


def span_table(spans: Sequence[Span], limit: int = MAX_SPANS_MD) -> list[str]:
    if not spans:
        return ["none"]
    lines = ["| kind | from (s) | to (s) | samples | worst excess (V) |", "|---|---:|---:|---:|---:|"]
    for s in spans[:limit]:
        lines.append(f"| {s.kind} | {s.start_s:.6g} | {s.stop_s:.6g} | {s.n} | {s.worst_V:.4g} |")
    if len(spans) > limit:
        lines.append(f"\n… and {len(spans) - limit} more (all in report.json)")
    return lines


def invert_markdown(res: InversionResult, figures: Sequence[str], command: str | None = None,
                    output_file: str | None = None) -> str:
    tg, u = res.target, res.unit
    du = display_unit(u)
    L = ["# hystfit invert report", ""]
    if command:
        L += ["Command:", "", f"```\n{command}\n```", ""]
    L += [f"- parameters: `{res.params_path}` (model `{res.model_name}`), output unit {du}",
          f"- target: {tg.description}; {tg.n} samples at {tg.fs:g} Hz ({tg.n * tg.dt:.6g} s), stroke "
          f"{tg.stroke:.4g} {du}"]
    if output_file:
        L.append(f"- voltage file: `{output_file}` (`time_s, voltage_V, predicted_displacement_{u}`)")
    L += [f"- table lookup: {res.method}; initial voltage {res.initial_voltage_V:.6g} V "
          f"({res.initial_voltage_source}; history assumed: "
          + ("at rest at it, every loop of the hysteresis closed there (the model's history `relaxed`))"
             if res.at_rest else "from the models' reset state at 0 V, brought monotonically to it)"),
          f"- voltage limits [{res.limits['vmin_V']:.6g}, {res.limits['vmax_V']:.6g}] V "
          f"(vmin {res.limits['vmin_source']}, vmax {res.limits['vmax_source']}; default rule: "
          f"{res.limits['default_rule']}); slew-rate limit: "
          + (f"{res.limits['max_slew_V_per_s']:g} V/s" if res.limits["max_slew_V_per_s"] else "none"),
          f"- applied voltage {res.voltage_V.min():.6g} … {res.voltage_V.max():.6g} V", "",
          "## Predicted tracking error", "",
          "Forward model (the blend of the cells used) simulated on the applied voltage; e = predicted − target "
          "(paper 002 Table 4 figures; % of stroke = 100·x / (max target − min target)).", ""]
    L += _metric_lines(res.metrics, u)
    floor = res.fit_rmse()
    if math.isfinite(floor):
        L += ["", f"This is the model following its own inverse: it checks the inversion, not the stage (an exact "
              f"inverse, as PI's, gives ≈ 0). The cells used reproduce their identification data to "
              f"**{fmt(floor)} {du} RMS** ({fmt(100.0 * floor / tg.stroke, 3) if tg.stroke > 0 else '–'} % of "
              "stroke; weighted by the blend, column *cell fit RMSE* below): a tracking error measured on the stage is "
              "of that order — less where the target stays where the cells fit best, more where it leaves their "
              "identified range or history."]
    if res.metrics_unlimited is not None:
        L += ["", "Without the voltage limits (what the limits cost):", ""] + _metric_lines(res.metrics_unlimited, u)
    L += ["", "## Table cells", "",
          "| segment | condition (V, Hz) | looked up (V, Hz) | cells × weight | how | iterations | converged | "
          f"RMSE ({du}) | RMSE % | cell fit RMSE ({du}) |", "|---|---|---|---|---|---:|---|---:|---:|---:|"]
    for ch, m in zip(res.choices, res.segment_metrics):
        cond = "–" if not math.isfinite(ch.condition[0]) else f"{ch.condition[0]:.4g}, {ch.condition[1]:.4g}"
        L.append(f"| {ch.segment.label} | {cond} | {ch.query[0]:.4g}, {ch.query[1]:.4g}{' (clamped)' if ch.clamped else ''}"
                 f" | {condition_text(ch)} | {ch.how} | {len(ch.iterations)} | {'yes' if ch.converged else 'no'} | "
                 f"{fmt(m[f'rmse_{u}'])} | {fmt(m['rmse_pct_of_stroke'], 3)} | {fmt(res.fit_rmse(ch))} |")
    L += ["", "The amplitude iteration: guess the drive's peak-to-peak voltage from the stroke and the table's gain, "
          "invert with the cells for it, measure the voltage's peak-to-peak, repeat until it is self-consistent "
          "(0.1 %). Bilinear interpolation blends the cells' inverted voltages (see `hystfit/invert.py`).", ""]
    L += ["## Voltage limits", "", f"Clipped to [vmin, vmax]: {len(res.clip_spans)} span(s), "
          f"{sum(s.n for s in res.clip_spans)} samples", ""] + span_table(res.clip_spans)
    L += ["", f"Slew-rate limited: {len(res.slew_spans)} span(s), {sum(s.n for s in res.slew_spans)} samples", ""]
    L += span_table(res.slew_spans)
    L += notes_and_figures(res.notes, figures)
    return "\n".join(L)


def figure_job(function: str, path: Path, *args, **kwargs):
    """A :class:`~hystfit.report.render.FigureJob` of one of this module's figure functions."""
    from .render import FigureJob

    return FigureJob(f"{__name__}:{function}", Path(path), args, kwargs)


def draw_figures(jobs) -> list[Path]:
    """Draw ``jobs`` (:func:`figure_job`): by the figure server the command line forked at its start, which
    imported matplotlib meanwhile (≈ 0.9 s this process does not spend), else here
    (:func:`hystfit.report.render.render_figures`)."""
    from .render import render_figures

    return render_figures(jobs)


def write_invert_report(res: InversionResult, report_dir: Path, *, make_plots: bool = True,
                        command: str | None = None, output_file: str | None = None) -> dict:
    """Write ``report.md``, ``report.json`` and ``plots/tracking.png`` into ``report_dir``; return the summary."""
    report_dir = Path(report_dir)
    figures = []
    if make_plots:
        kw = dict(unit=res.unit, title=f"{res.model_name} feedforward – {res.target.description}",
                  vmin=res.limits["vmin_V"], vmax=res.limits["vmax_V"], spans=list(res.clip_spans) + list(res.slew_spans))
        tg = res.target
        jobs = [figure_job("tracking_figure", report_dir / "plots" / "tracking.png", tg.t_s, tg.y, res.predicted,
                     res.voltage_V, **kw)]
        figures.append("plots/tracking.png")
        windows = detail_windows(tg)
        if windows:
            jobs.append(figure_job("tracking_detail_figure", report_dir / "plots" / "tracking_detail.png", tg.t_s, tg.y,
                             res.predicted, res.voltage_V, windows, **kw))
            figures.append("plots/tracking_detail.png")
        draw_figures(jobs)
    summary = invert_summary(res)
    summary["command"] = command
    summary["output_file"] = output_file
    atomic_write_text(report_dir / "report.json", dumps(json_safe(summary)))
    atomic_write_text(report_dir / "report.md", invert_markdown(res, figures, command, output_file))
    return summary
