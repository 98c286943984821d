"""Writes the outputs of ``hystfit simulate``: predictions, per-capture metrics, plots and report.md."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..io import Columns, atomic_write_text, write_table
from ..predict import Prediction
from ..results import ParamsFile, dumps, json_safe
from .render import FigureJob, render_figures
from .tables import distinct_names, frame, markdown_table, metric_columns, metric_legend


def _stem(pred: Prediction, seen: dict[str, int]) -> str:
    stem = Path(pred.capture.source).stem
    n = seen.get(stem, 0)
    seen[stem] = n + 1
    return stem if n == 0 else f"{stem}_{n}"


def write_simulate_outputs(pf: ParamsFile, preds: Sequence[Prediction], out_dir: Path, *, fmt: str = "csv",
                           make_plots: bool = True) -> list[dict]:
    out_dir = Path(out_dir)
    u = pf.unit
    seen: dict[str, int] = {}
    summary = []
    jobs: list[FigureJob] = []
    if make_plots:
        (out_dir / "plots").mkdir(exist_ok=True)
    for p in preds:
        c = p.capture
        stem = _stem(p, seen)
        cols = {"time_s": c.t, "voltage_V": c.u, f"predicted_displacement_{u}": p.y_model}
        if c.y is not None:
            cols[f"measured_displacement_{u}"] = c.y
            cols[f"residual_{u}"] = p.y_model - c.y
        write_table(out_dir / f"{stem}_prediction.{fmt}", Columns(cols))
        entry = {"capture": c.source, "amplitude_V": c.amplitude_V, "frequency_Hz": c.frequency_Hz,
                 "cells": [list(x) for x in p.cells], "metrics": p.metrics, f"offset_{u}": p.offset,
                 "notes": list(c.notes) + list(p.notes), "prediction_file": f"{stem}_prediction.{fmt}"}
        if p.metrics is not None:
            atomic_write_text(out_dir / f"{stem}_metrics.json", dumps(json_safe(entry)))
            if make_plots:
                title = f"{pf.model_name} prediction – {c.name}"
                jobs += [FigureJob("loop_figure", out_dir / "plots" / f"loop_{stem}.png", (c.u, c.y, p.y_model),
                                   {"unit": u, "title": title}),
                         FigureJob("timeseries_figure", out_dir / "plots" / f"timeseries_{stem}.png",
                                   (c.t, c.y, p.y_model), {"unit": u, "title": title})]
        summary.append(json_safe(entry))
    made = []
    if jobs:  # by the figure server the command line forked at its start (matplotlib loaded there), else here
        made = render_figures(jobs)
    rows = []
    names = distinct_names([s["capture"] for s in summary])
    for s, name in zip(summary, names):
        row = {"capture": name, "amplitude_V": s["amplitude_V"], "frequency_Hz": s["frequency_Hz"],
               "cells": ", ".join(f"{lab}×{w:.2f}" for lab, w in s["cells"])}
        if any(x[f"offset_{u}"] is not None for x in summary):
            row[f"offset_{u}"] = s[f"offset_{u}"]
        for k in metric_columns(u):
            row[k] = (s["metrics"] or {}).get(k, np.nan)
        rows.append(row)
    lines = [f"# hystfit simulate report", "", f"- parameters: `{pf.path}` (model `{pf.model_name}`, {pf.mode})",
             f"- output unit: {u}", "", markdown_table(frame(rows)), ""]
    if any(s[f"offset_{u}"] is not None for s in summary):
        lines += [f"`offset_{u}`: a constant fitted per capture (mean of measured − predicted) and added to the "
                  "prediction before the metrics (--align-offset); without it the offset shows as the bias.", ""]
    noted = [(name, n) for s, name in zip(summary, names) for n in s["notes"]]
    if noted:
        lines += ["## Notes", ""] + [f"- {name}: {n}" for name, n in noted] + [""]
    if made:  # every figure drawn, linked (a blind test found none linked)
        lines += ["## Figures", ""] + [f"![{Path(f).stem}](plots/{Path(f).name})" for f in made] + [""]
    text = "\n".join(lines + ["Formulas:", "", metric_legend(u), ""])
    atomic_write_text(out_dir / "report.md", text)
    return summary
