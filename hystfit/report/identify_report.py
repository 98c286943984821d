"""Writes the outputs of ``hystfit identify``: params.json, report.csv, report.md and plots/."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import __version__
from ..identify import IdentifyResult, unit_param
from ..io import atomic_write_text, write_table
from ..results import dumps, identify_to_dict
from . import plots
from ..params import AT_BOUND_RTOL
from .render import FigureJob, render_figures
from .tables import fmt, frame, markdown_table, metric_columns, metric_legend

UNIT_DISPLAY = {"um": "µm", "nm": "nm", "mm": "mm", "m": "m"}


def summary_rows(res: IdentifyResult) -> list[dict]:
    rows = []
    for f in res.fits:
        row = {"condition": f.label, "amplitude_V": f.amplitude_V, "frequency_Hz": f.frequency_Hz,
               "captures": len(f.captures), "samples": int(sum(c.n for c in f.captures))}
        for k in metric_columns(res.unit):
            row[k] = f.metrics.get(k, np.nan)
        row["runtime_s"] = f.runtime_s
        row["evaluations"] = f.evaluations
        if res.runs > 1:
            sp = f.spread()
            row[f"rmse_std_{res.unit}"] = sp[f"rmse_std_{res.unit}"]
        rows.append(row)
    return rows


def _plots(res: IdentifyResult, plot_dir: Path, n_jobs: int | None = None) -> dict[str, list[str]]:
    """Draw every figure of the report in parallel; return the files per condition (relative to the report).

    A condition whose optimizer left no iteration history worth drawing (``auto`` on a model with no
    nonlinear parameter solves exactly: one point) gets no convergence figure; the report says why.
    """
    jobs: list[FigureJob] = []
    out: dict[str, list[str]] = {}
    panels = []
    for f in res.fits:
        us = [c.u for c in f.captures]
        ys = [c.y for c in f.captures]
        title = f"{res.model_name} – {f.label}"
        mine = [
            FigureJob("loop_figure", plot_dir / f"loop_{f.label}.png", (us, ys, list(f.predictions)),
                      {"unit": res.unit, "title": title}),
            FigureJob("timeseries_figure", plot_dir / f"timeseries_{f.label}.png",
                      (f.captures[0].t, f.captures[0].y, f.predictions[0]),
                      {"unit": res.unit, "title": f"{title} ({f.captures[0].name})"}),
        ]
        if plots.has_convergence_history(f.best.result.history_best):
            mine.append(FigureJob("convergence_figure", plot_dir / f"convergence_{f.label}.png",
                                  (f.best.result.history_best, f.best.result.history_mean),
                                  {"title": f"{title}: {res.optimizer_name}",
                                   "runs": [r.result.history_best for r in f.runs] if len(f.runs) > 1 else None}))
        jobs += mine
        out[f.label] = [str(Path("plots") / j.path.name) for j in mine]
        r2 = f.metrics.get("r2", np.nan)
        rmse = f.metrics.get(f"rmse_{res.unit}", np.nan)
        panels.append({"title": f.label, "u": us, "y_meas": ys, "y_model": list(f.predictions),
                       "subtitle": f"R²={fmt(r2)} RMSE={fmt(rmse, 3)} {UNIT_DISPLAY.get(res.unit, res.unit)}"})
    jobs.append(FigureJob("overview_figure", plot_dir / "overview.png", (panels,),
                          {"unit": res.unit, "title": f"{res.model_name} identified with {res.optimizer_name}"}))
    render_figures(jobs, n_jobs)
    return out


def _no_convergence_note(f) -> str | None:
    """Why a condition has no convergence figure (None when it has one)."""
    if plots.has_convergence_history(f.best.result.history_best):
        return None
    r = f.best.result
    return (f"No convergence figure: the optimizer left no iteration history to draw ({r.message}; "
            f"{r.nfev} objective evaluation{'s' if r.nfev != 1 else ''}).")


def markdown_report(res: IdentifyResult, plot_files: dict[str, list[str]]) -> str:
    u = res.unit
    lines = [f"# hystfit identification report", "",
             f"- model: `{res.model_name}` — optimizer: `{res.optimizer_name}`"
             f"{' + least-squares polish' if res.polish and res.optimizer_name not in ('lsq', 'auto') else ''}",
             f"- mode: {res.mode}; runs per condition: {res.runs}; seed: {res.seed}; hystfit {__version__}",
             f"- output unit: {u}; input unit: V; time: s",
             f"- runs computed {res.cell_stats.computed}, reused from an interrupted run {res.cell_stats.reused}", ""]
    if res.failed:
        lines += ["## Failed runs (left out)", "", *[f"- {f}" for f in res.failed], ""]
    lines += ["## Metrics per condition", "", markdown_table(frame(summary_rows(res))), "",
              "Formulas (e = model − measured):", "", metric_legend(u), ""]
    for f in res.fits:
        lines += [f"## {f.label}", "",
                  f"Sources: {', '.join(c.source for c in f.captures)}", ""]
        notes = [n for c in f.captures for n in c.notes]
        if notes:
            lines += ["Loading notes: " + "; ".join(notes), ""]
        prow = [{"parameter": p.name, "unit": unit_param(p, u), "value": v, "stderr": se,
                 "lower": p.lower, "upper": p.upper, "at bound": f"**{at}**" if at else ""}
                for p, v, se, at in zip(f.params, f.theta, f.stderr, f.at_bound)]
        lines += [markdown_table(frame(prow)), ""]
        if len(f.runs) > 1:
            sp = f.spread()
            lines += [f"Runs: {sp['runs']}; objective min {fmt(sp['fun_min'])}, max {fmt(sp['fun_max'])}, "
                      f"mean {fmt(sp['fun_mean'])}, std {fmt(sp['fun_std'])}; median time {fmt(sp['time_median_s'])} s", ""]
        for p in plot_files.get(f.label, []):
            lines.append(f"![{Path(p).stem}]({p})")
        note = _no_convergence_note(f) if f.label in plot_files else None
        if note:
            lines += ["", note]
        lines.append("")
    lines += ["Standard errors are asymptotic (σ²(JᵀJ)⁻¹ at the optimum). A parameter \"at bound\" lies within "
              f"{AT_BOUND_RTOL:g} × its search width of that bound: the search stopped there, so it has no standard "
              "error (–); if the bound is not physical, widen it with --bounds NAME=LOWER:UPPER. "
              "A large standard error means the data do not determine that parameter well.", ""]
    return "\n".join(lines)


def bound_notes(res: IdentifyResult) -> list[str]:
    """One line per parameter set with parameters pinned at a search bound (for the console)."""
    out = []
    for f in res.fits:
        pinned = [f"{p.name}={fmt(float(v))} ({at} {fmt(getattr(p, at))})"
                  for p, v, at in zip(f.params, f.theta, f.at_bound) if at]
        if pinned:
            out.append(f"{f.label}: at a search bound: {', '.join(pinned)}")
    return out


def write_identify_outputs(res: IdentifyResult, out_dir: Path, *, make_plots: bool = True,
                           n_jobs: int | None = None) -> dict[str, Path]:
    """Write every output of an identification into ``out_dir`` (which must exist).

    Figures are drawn by ``n_jobs`` processes (default all cores, :func:`~hystfit.report.render.render_figures`);
    the files do not depend on it.
    """
    out_dir = Path(out_dir)
    paths = {"params": out_dir / "params.json", "report_csv": out_dir / "report.csv",
             "report_md": out_dir / "report.md"}
    atomic_write_text(paths["params"], dumps(identify_to_dict(res)))
    write_table(paths["report_csv"], frame(summary_rows(res)))
    plot_files: dict[str, list[str]] = {}
    if make_plots:
        plot_dir = out_dir / "plots"
        plot_dir.mkdir(exist_ok=True)
        plot_files = _plots(res, plot_dir, n_jobs)
        paths["plots"] = plot_dir
    atomic_write_text(paths["report_md"], markdown_report(res, plot_files))
    return paths
