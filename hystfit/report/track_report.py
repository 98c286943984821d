"""Reports of ``hystfit track``: per-controller time series, comparison table, JSON, Markdown, figures."""

from __future__ import annotations

import math
from pathlib import Path

from ..invert import condition_text
from ..io import Columns, atomic_write_text, write_table
from ..results import dumps, json_safe, schema_fields
from ..track import TrackResult, margins_text
from .invert_report import detail_windows, draw_figures, figure_job, invert_summary, span_dicts, span_table
from .plots import display_unit
from .tables import fmt, notes_and_figures


def _file_stem(name: str) -> str:
    return name.replace("+", "_plus_")


def track_summary(res: TrackResult) -> dict:
    """JSON-safe summary (NaN/inf → null)."""
    u = res.unit
    inv = invert_summary(res.inversion)
    runs = []
    for run in res.runs:
        runs.append({"controller": run.controller, "metrics": run.metrics, "steps": list(run.steps),
                     "limited": {"spans": len(run.limit_spans), "samples": sum(s.n for s in run.limit_spans),
                                 "list": span_dicts(run.limit_spans)},
                     "voltage": {"min_V": float(run.voltage_V.min()), "max_V": float(run.voltage_V.max())},
                     "runtime_s": run.runtime_s, "us_per_sample": 1e6 * run.runtime_s / max(1, res.target.n),
                     "details": run.details})
    nom = res.nominal
    return json_safe({
        **schema_fields("track"),
        "params": res.params_path, "plant": res.plant_path, "model": res.model_name,
        "plant_model": res.plant_model_name, "units": {"output": u, "input": "V", "time": "s"},
        "target": inv["target"], "initial_voltage": inv["initial_voltage"], "limits": res.limits,
        "noise": {f"sigma_{u}": res.noise_std, "seed": res.seed},
        "controller_cells": inv["segments"],
        "plant_cells": [{"segment": seg, "cells": [[c.label, c.weight] for c in cells]}
                        for seg, cells in res.plant_cells],
        "nominal_plant": {"kind": nom.kind, "description": nom.description, f"gain_{u}_per_V": nom.gain,
                          "num": nom.num.tolist(), "den": nom.den.tolist(), "dt_s": nom.dt,
                          "fit_nrmse_pct": nom.fit_nrmse_pct},
        "comparison": res.table(),
        "runs": runs,
        "notes": list(res.notes),
    })


def _md_table(cols: list[str], rows: list[list[str]]) -> list[str]:
    return (["| " + " | ".join(cols) + " |", "|" + "|".join(["---"] + ["---:"] * (len(cols) - 1)) + "|"]
            + ["| " + " | ".join(r) + " |" for r in rows])


def track_markdown(res: TrackResult, figures: list[str], command: str | None = None) -> str:
    u = res.unit
    du = display_unit(u)
    tg = res.target
    inv = res.inversion
    L = ["# hystfit track report", ""]
    if command:
        L += ["Command:", "", f"```\n{command}\n```", ""]
    L += [f"- controller's table: `{res.params_path}` (model `{res.model_name}`)",
          f"- plant: `{res.plant_path}` (model `{res.plant_model_name}`)"
          + (" — the same table (the inverse sees its own model)" if res.plant_path == res.params_path else
             " — another model: the realistic test of the inverse"),
          f"- target: {tg.description}; {tg.n} samples at {tg.fs:g} Hz; stroke {tg.stroke:.4g} {du}",
          f"- loop at the sample rate, one sample of computation delay; measurement noise σ = {res.noise_std:g} {du} "
          f"(seed {res.seed}); voltage limits [{res.limits['vmin_V']:.6g}, {res.limits['vmax_V']:.6g}] V, slew "
          + (f"{res.limits['max_slew_V_per_s']:g} V/s" if res.limits.get("max_slew_V_per_s") else "unlimited"),
          f"- initial voltage {inv.initial_voltage_V:.6g} V ({inv.initial_voltage_source})",
          f"- nominal linear part: {res.nominal.description}"]
    if res.pid is not None:
        p = res.pid
        L.append(f"- PID: Kp = {p.kp:.4g} V/{du}, Ki = {p.ki:.4g} V/({du}·s), Kd = {p.kd:.4g} V·s/{du}, "
                 f"derivative filter {p.tf_s:.3g} s, anti-windup {p.anti_windup} (Tt = {p.tt_s:.3g} s); {p.rule}; "
                 + (f"nominal bandwidth ≈ {p.bandwidth_Hz:.4g} Hz, " if math.isfinite(p.bandwidth_Hz) else
                    "no nominal bandwidth (no gain crossover below Nyquist), ")
                 + margins_text(p.gain_margin, p.phase_margin_deg)
                 + ("" if p.gain_margin > 1.0 and p.phase_margin_deg > 0.0 else
                    " — **the nominal loop is unstable with these gains**"))
    if res.smc is not None:
        L.append(f"- sliding mode (paper 003 eq. 25–42; smc on top of the feedforward, smc-noinv without the "
                 f"inverse compensation): {res.smc.describe()}")
    L += ["", "## Comparison", "",
          f"Errors e = plant output − reference (true output, without the measurement noise); % of stroke = "
          f"100·x / (max r − min r). limited %: share of samples where the voltage limits acted.", ""]
    (track_cols, step_cols), (track_rows, step_rows) = comparison_headers(res), comparison_text_rows(res)
    L += _md_table(track_cols, track_rows)
    if tg.steps:
        L += ["", "### Steps (paper 002 Table 6)", "",
              "t90 = time from the step to 90 % of it (002's Tr); settling = time after which the output stays "
              "within ±5 % / ±2 % of the step (– = not settled within the hold); overshoot in % of the step "
              "(largest over the steps); times are means over the steps. e_max settled / RMSE settled = max |e| "
              "and sqrt(mean e²) after the transient, from the ±5 % settling time to the end of each hold (002 "
              "Table 6's emax and RMSE of a step; worst step; – = not settled), unlike the trajectory's max and "
              "RMSE above, which include the transients. Per step, also the 10 → 90 % rise time and the "
              "steady-state error: `summary.json`, `runs[].steps`.", ""]
        L += _md_table(step_cols, step_rows)
    L += ["", "## Table cells", "", "| segment | controller cells | plant cells |", "|---|---|---|"]
    for ch, (seg, pcells) in zip(inv.choices, res.plant_cells):
        L.append(f"| {seg} | {condition_text(ch)} | {' + '.join(f'{c.label}×{c.weight:.2f}' for c in pcells)} |")
    for run in res.runs:
        if run.limit_spans:
            L += ["", f"### {run.controller}: voltage limited", ""] + span_table(run.limit_spans)
    L += notes_and_figures(res.notes, figures)
    return "\n".join(L)


def write_track_outputs(res: TrackResult, out_dir: Path, *, make_plots: bool = True, fmt_ext: str = "csv",
                        command: str | None = None, bandwidth: dict | None = None) -> dict:
    """Write ``<controller>.csv`` (or .parquet), ``summary.json``, ``report.md`` and figures into ``out_dir``;
    with ``bandwidth`` (:func:`hystfit.track.measure_bandwidths`) also ``bandwidth.json``."""
    out_dir = Path(out_dir)
    if bandwidth is not None:
        atomic_write_text(out_dir / "bandwidth.json", dumps(json_safe(dict(bandwidth, command=command))))
    u = res.unit
    tg = res.target
    figures: list[str] = []
    windows = detail_windows(tg) if make_plots else []
    jobs = []
    for run in res.runs:
        stem = _file_stem(run.controller)
        write_table(out_dir / f"{stem}.{fmt_ext}", Columns({
            "time_s": tg.t_s, f"reference_{u}": tg.y, f"displacement_{u}": run.output,
            f"measured_{u}": run.measured, "voltage_V": run.voltage_V, "command_V": run.command_V,
            f"error_{u}": run.error}))
        if make_plots:
            kw = dict(unit=u, title=f"{run.controller} – {tg.description}", output_label="plant output",
                      vmin=res.limits["vmin_V"], vmax=res.limits["vmax_V"], spans=run.limit_spans)
            jobs.append(figure_job("tracking_figure", out_dir / "plots" / f"{stem}.png", tg.t_s, tg.y, run.output,
                             run.voltage_V, **kw))
            figures.append(f"plots/{stem}.png")
            if windows:
                jobs.append(figure_job("tracking_detail_figure", out_dir / "plots" / f"{stem}_detail.png", tg.t_s, tg.y,
                                 run.output, run.voltage_V, windows, **kw))
                figures.append(f"plots/{stem}_detail.png")
    if make_plots and len(res.runs) > 1:
        jobs.insert(0, figure_job("error_comparison_figure", out_dir / "plots" / "errors.png", tg.t_s,
                            {r.controller: r.error for r in res.runs}, unit=u, title=f"tracking error – {tg.description}"))
        figures.insert(0, "plots/errors.png")
    if jobs:
        draw_figures(jobs)
    summary = track_summary(res)
    summary["command"] = command
    atomic_write_text(out_dir / "summary.json", dumps(json_safe(summary)))
    atomic_write_text(out_dir / "report.md", track_markdown(res, figures, command))
    return summary


def comparison_headers(res: TrackResult) -> tuple[list[str], list[str]]:
    """Column headers of :func:`comparison_text_rows`: (tracking table, step table — empty without steps)."""
    du = display_unit(res.unit)
    track_cols = ["controller", f"max ({du})", f"RMSE ({du})", "max %", "RMSE %", "limited %"]
    step_cols = ["controller", "t90 (ms)", "settle ±5 % (ms)", "settle ±2 % (ms)", "overshoot %",
                 f"e_max settled ({du})", f"RMSE settled ({du})"] \
        if res.target.steps else []
    return track_cols, step_cols


def comparison_text_rows(res: TrackResult) -> tuple[list[list[str]], list[list[str]]]:
    """Rows for the console: (tracking figures, step figures) as short text (3 digits, step times in ms)."""
    u = res.unit

    def ms(x):
        return fmt(None if x is None else 1e3 * x, 3)

    track_rows, step_rows = [], []
    for row in res.table():
        track_rows.append([row["controller"], fmt(row[f"max_error_{u}"], 3), fmt(row[f"rmse_{u}"], 3),
                           fmt(row["max_error_pct"], 3), fmt(row["rmse_pct"], 3), fmt(row["limited_pct"], 3)])
        if "t90_s" in row:
            step_rows.append([row["controller"], ms(row["t90_s"]), ms(row["settling_time_5pct_s"]),
                              ms(row["settling_time_2pct_s"]), fmt(row["overshoot_pct"], 3),
                              fmt(row[f"e_max_settled_{u}"], 3), fmt(row[f"rmse_settled_{u}"], 3)])
    return track_rows, step_rows
