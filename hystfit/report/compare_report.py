"""Writes the outputs of ``hystfit compare``: compare.csv, compare.md and the figures.

Tables follow the papers' layouts: 002 Table 3 (a column per model, a row per performance figure,
each worst case with the condition where it occurred), 002 Table 2 (runtime: a row per model and
voltage level, a column per frequency), 004 Table 2 (J over repeated runs, per optimizer; also for
the search alone when a polish follows it), plus a ranking that says where differences are within
the run-to-run spread, or, with single runs, whether they hold condition by condition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import __version__
from ..compare import CellResult, CompareResult, NeighbourTest, Ranking, rank
from ..io import atomic_write_text, write_table
from ..optimizers.base import STOP_RULE_NAMES
from . import plots
from .render import FigureJob, render_figures
from .tables import fmt, markdown_table, metric_columns, metric_legend

HEATMAP_METRICS = (("rmse", "RMSE"), ("mape", "MAPE"), ("smape", "SMAPE"), ("r2", "R²"))


def compare_frame(res: CompareResult) -> pd.DataFrame:
    """One row per model, optimizer, condition and run (failed cells: one row with the error)."""
    rows = []
    mcols = metric_columns(res.unit)
    for c in res.cells:
        base = {"model": c.model, "optimizer": c.optimizer, "condition": c.label, "amplitude_V": c.amplitude_V,
                "frequency_Hz": c.frequency_Hz, "n_params": c.n_params}
        if not c.ok:
            rows.append({**base, "run": np.nan, "error": c.error})
            continue
        for r in c.runs:
            row = {**base, "run": r.run, "seed": r.seed, "best_run": r.run == c.best_run, "objective_mse": r.fun,
                   "j": r.j, "objective_mse_search": r.search_fun, "j_search": r.search_j}
            for k in mcols:
                row[k] = r.metrics.get(k, np.nan)
            row.update({"runtime_s": r.wall_time_s, "evaluations": r.nfev, "search_evaluations": r.search_nfev,
                        "error": ""})
            rows.append(row)
    return pd.DataFrame(rows)


def mean_over_conditions(res: CompareResult) -> list[dict]:
    """Per model × optimizer: the mean RMSE and worst R² over conditions (best run per cell), the
    number of failed cells and the total run time (the console summary of ``hystfit compare``)."""
    u = res.unit
    rows = []
    for m in res.models:
        for o in res.optimizers:
            cells = [c for c in res.cells if c.model == m and c.optimizer == o]
            ok = [c for c in cells if c.ok]
            rows.append({"model": m, "optimizer": o,
                         "mean_rmse": (float(np.mean([c.best.metrics[f"rmse_{u}"] for c in ok])) if ok
                                       else float("nan")),
                         "worst_r2": min((c.best.metrics["r2"] for c in ok), default=float("nan")),
                         "failed_cells": len(cells) - len(ok), "runtime_s": float(sum(c.runtime_s for c in cells))})
    return rows


def _best_cells(res: CompareResult, optimizer: str) -> list[CellResult]:
    return [c for c in res.cells if c.optimizer == optimizer and c.ok]


def _worst(values: list[float], worst) -> int | None:
    """Index of the worst finite value (``worst`` is max or min), None when none is finite."""
    finite = [i for i, v in enumerate(values) if np.isfinite(v)]
    return worst(finite, key=lambda i: values[i]) if finite else None


def model_summary(res: CompareResult, optimizer: str) -> pd.DataFrame:
    """002 Table 3 data: per model, the worst RMSE/MAPE/SMAPE/R² over conditions and where each
    occurred, and per voltage level the maximum error and the condition where it occurred."""
    u = res.unit
    amps = sorted({k[0] for k, _ in res.conditions})
    rows = []
    for m in res.models:
        cells = [c for c in _best_cells(res, optimizer) if c.model == m]
        failed = [c.label for c in res.cells if c.model == m and c.optimizer == optimizer and not c.ok]
        row = {"model": m, "optimizer": optimizer, "parameters": cells[0].n_params if cells else np.nan}
        for key, worst in ((f"rmse_{u}", max), ("mape", max), ("smape", max), ("r2", min)):
            vals = [c.best.metrics.get(key, np.nan) for c in cells]
            i = _worst(vals, worst)
            row[f"worst {key}"] = vals[i] if i is not None else np.nan
            row[f"worst {key} at"] = cells[i].label if i is not None else ""
        for a in amps:
            at_a = [c for c in cells if c.amplitude_V == a]
            errs = [c.best.metrics.get(f"max_error_{u}", np.nan) for c in at_a]
            i = _worst(errs, max)
            row[f"max error {fmt(a)} V ({u})"] = errs[i] if i is not None else np.nan
            row[f"max error {fmt(a)} V at"] = at_a[i].label if i is not None else ""
        row["failed at"] = ", ".join(failed)
        rows.append(row)
    return pd.DataFrame(rows)


def _column_name(model: str, optimizer: str, res: CompareResult) -> str:
    return model if len(res.optimizers) == 1 else f"{model} / {optimizer}"


def _frequency_text(f: float) -> str:
    return f"{fmt(f)} Hz" if np.isfinite(f) else "n/a"


def table3(res: CompareResult) -> pd.DataFrame:
    """002 Table 3 as printed in the paper: one row per performance figure, one column per model
    (per model / optimizer when several optimizers are compared); each worst value carries the
    condition where it occurred, each per-voltage maximum error the frequency."""
    u = res.unit
    amps = sorted({k[0] for k, _ in res.conditions})
    shown = plots.display_unit(u)
    labels = ["parameters", f"maximum RMSE ({shown})", "maximum MAPE", "maximum SMAPE", "minimum R²"]
    labels += [f"maximum error ({shown}) at {fmt(a)} V" for a in amps] + ["failed conditions"]
    table = {"performance": labels}
    for o in res.optimizers:
        summary = model_summary(res, o)
        for _, r in summary.iterrows():
            col = [fmt(r["parameters"]) if np.isfinite(r["parameters"]) else "–"]
            for key in (f"rmse_{u}", "mape", "smape", "r2"):
                v, at = r[f"worst {key}"], r[f"worst {key} at"]
                col.append(f"{fmt(v)} ({at})" if at else "–")
            for a in amps:
                v, at = r[f"max error {fmt(a)} V ({u})"], r[f"max error {fmt(a)} V at"]
                freq = next((c.frequency_Hz for c in res.cells if c.label == at), np.nan)
                col.append(f"{fmt(v)} ({_frequency_text(freq)})" if at else "–")
            col.append(r["failed at"] or "none")
            table[_column_name(r["model"], o, res)] = col
    return pd.DataFrame(table)


def runtime_table(res: CompareResult) -> pd.DataFrame:
    """002 Table 2: identification time (s, median over runs) — one row per model (× optimizer)
    and voltage level, one column per frequency, as the paper prints it."""
    amps = sorted({k[0] for k, _ in res.conditions})
    freqs = sorted({k[1] for k, _ in res.conditions}, key=lambda f: (not np.isfinite(f), f))
    by_key = {(c.model, c.optimizer, c.amplitude_V, c.frequency_Hz): c for c in res.cells}
    rows = []
    for m in res.models:
        for o in res.optimizers:
            for a in amps:
                row = {"model": m} if len(res.optimizers) == 1 else {"model": m, "optimizer": o}
                row["voltage"] = f"0–{fmt(a)} V"
                for f in freqs:
                    c = by_key.get((m, o, a, f))
                    row[_frequency_text(f)] = (float(np.median([r.wall_time_s for r in c.runs]))
                                               if c is not None and c.ok else np.nan)
                rows.append(row)
    return pd.DataFrame(rows)


def _stats(values: list[float], prefix: str, suffix: str = "") -> dict[str, float]:
    a = np.asarray(values, float)
    return {f"{prefix} min{suffix}": float(a.min()), f"{prefix} max{suffix}": float(a.max()),
            f"{prefix} mean{suffix}": float(a.mean()),
            f"{prefix} std{suffix}": float(a.std(ddof=1)) if a.size > 1 else 0.0}


def _cell_table(res: CompareResult, columns) -> pd.DataFrame:
    """One row per successful cell: model, optimizer, condition, runs, then ``columns(cell)``."""
    return pd.DataFrame([{"model": c.model, "optimizer": c.optimizer, "condition": c.label, "runs": len(c.runs),
                          **columns(c)} for c in res.cells if c.ok])


def optimizer_table(res: CompareResult) -> pd.DataFrame:
    """004 Table 2: per model, optimizer and condition, the final J and RMSE over runs
    (min / max / mean / std, after the polish if any), the median time and mean evaluations."""
    u = res.unit

    def columns(c: CellResult) -> dict:
        return {**_stats([r.j for r in c.runs], "J"),
                **_stats([r.metrics.get(f"rmse_{u}", np.nan) for r in c.runs], "RMSE", f" ({u})"),
                "time median (s)": float(np.median([r.wall_time_s for r in c.runs])),
                "evaluations mean": float(np.mean([r.nfev for r in c.runs])),
                "search evaluations mean": float(np.mean([r.search_nfev for r in c.runs]))}

    return _cell_table(res, columns)


def search_table(res: CompareResult) -> pd.DataFrame:
    """The global search alone (before the least-squares polish): J over runs per model, optimizer
    and condition. Equal to :func:`optimizer_table`'s J without a polish, and for ``auto`` and
    ``lsq`` (which are not polished again)."""
    return _cell_table(res, lambda c: {
        **_stats([r.search_j for r in c.runs], "J"),
        "runs the polish improved by > 0.1 %": int(sum(r.j < r.search_j * (1 - 1e-3) for r in c.runs))})


def _note(t: NeighbourTest | None) -> str:
    """The words for a neighbour test of :func:`hystfit.compare.rank`, with the condition-by-condition
    comparison of repeated runs after it."""
    if t is None:
        return ""
    runs, cond = _runs_note(t), _condition_note(t.by_condition)
    if cond and not runs:  # one run per cell: no spread to speak of, the conditions only
        return f" — against `{t.other}`{cond[1:]}"
    return runs + cond


def _condition_note(c: dict | None) -> str:
    if not c:
        return ""
    if c["test"] == "wilcoxon":
        verdict = "consistently below" if c["consistently_below"] else "not consistently below"
        return (f"; by condition (each one's mean over runs) {verdict}: lower at {c['lower_at']} of "
                f"{c['n_conditions']}, Wilcoxon signed-rank p = {c['p_value']:.2g}")
    return f"; by condition (each one's mean over runs) lower at {c['lower_at']} of {c['n_conditions']}"


def _runs_note(t: NeighbourTest) -> str:
    b = f"`{t.other}`"
    if t.verdict == "tied":
        return f" — tied with {b}"
    if t.test == "wilcoxon":
        verdict = "consistently below" if t.verdict == "consistently_below" else "not consistently below"
        return (f" — {verdict} {b} (lower at {t.lower_at} of {t.n_conditions} conditions, "
                f"Wilcoxon signed-rank over conditions p = {t.p_value:.2g})")
    if t.verdict == "lower_count":
        return f" — lower than {b} at {t.lower_at} of {t.n_conditions} conditions"
    if t.test == "mann_whitney":
        verdict = "better than" if t.verdict == "better" else "not distinguishable from"
        return f" — {verdict} {b} (Mann–Whitney U over runs, p = {t.p_value:.2g})"
    if t.verdict == "within_spread":
        return f" — within run-to-run spread of {b} (gap {fmt(t.gap)} ≤ 2σ = {fmt(t.two_sigma)})"
    if t.verdict == "beyond_spread":
        return f" — below {b} by more than twice the run-to-run spread ({fmt(t.gap)} > {fmt(t.two_sigma)})"
    return ""


def _rank_lines(g: Ranking, what: str) -> list[str]:
    """One numbered line per ranked entry: its mean (and median), and how it compares with the next."""
    lines = []
    for r in g.rows:
        med = ""
        if r.median is not None:
            med = f", median {fmt(r.median)}"
            if r.mean > 2 * r.median:
                med += " (the mean is dominated by a few conditions; see the worst cases below)"
        unit = f" {g.unit}" if g.unit else ""
        lines.append(f"{r.position}. `{r.name}`: mean {what} {fmt(r.mean)}{unit}{med}{_note(r.versus_next)}")
    return lines


def _model_ranking_text(g: Ranking) -> list[str]:
    out = [f"Models with `{g.within}`, by mean RMSE over the {g.n_conditions} condition(s):", ""]
    if g.paired:
        out += ["One run per cell: the run-to-run spread is unknown (rerun with `--runs 3` or more to "
                "test it). Neighbours are compared condition by condition instead, which shows whether "
                "one model is consistently better, not whether a rerun would change the order.", ""]
    else:
        out += [f"Each model's mean is over runs of the RMSE averaged over conditions ({g.runs} runs).", ""]
    out += _rank_lines(g, "RMSE")
    if g.not_ranked:
        out += [f"- not ranked (failed on some condition): {', '.join(f'`{m}`' for m in g.not_ranked)}"]
    return out + [""]


def _optimizer_ranking_text(g: Ranking) -> list[str]:
    what = "J of the search (before the polish)" if g.polished else "final J"
    out = [f"Optimizers on `{g.within}`, by mean {what} over runs (averaged over conditions):", ""]
    out += _rank_lines(g, "J") + [""]
    if g.polished:
        spread = g.final_j_spread_pct
        verdict = ("the polish, not the search, sets the final accuracy here; the search decides the "
                   "basin and the time" if spread < 1 else "the search still matters after the polish")
        by = f"{fmt(spread)} %" if spread >= 0.01 else "less than 0.01 %"
        out += [f"After the least-squares polish the mean final J of these optimizers differ by "
                f"{by} (004 Table 2 style table below): {verdict}.", ""]
    return out


def ranking(res: CompareResult) -> list[str]:
    """The ranking section's lines: :func:`hystfit.compare.rank` in words."""
    out = []
    for g in rank(res).groups:
        if g.rows:
            out += _model_ranking_text(g) if g.kind == "models" else _optimizer_ranking_text(g)
    return out or ["One model and one optimizer: nothing to rank.", ""]


def _figures(res: CompareResult, fig_dir: Path, n_jobs: int | None = None) -> list[str]:
    """Draw the comparison's figures in parallel; return their paths relative to the report.

    Heat maps colour on a log scale (RMSE, MAPE, SMAPE; R² by 1 − R²) with the values written in
    the cells, so one diverged model does not flatten the others into one colour; the R²
    distribution is drawn as 1 − R² on a log axis (R² of good fits all sit at 0.999…). Figures
    that would show nothing are left out: distributions over conditions with a single condition,
    convergence lines of optimizers that left no iteration history (``auto`` solving exactly).
    """
    fig_dir.mkdir(exist_ok=True)
    jobs: list[FigureJob] = []
    u = res.unit
    labels = [lab for _, lab in res.conditions]
    for o in res.optimizers:
        for key, title in HEATMAP_METRICS:
            k = f"{key}_{u}" if key == "rmse" else key
            mat = np.array([[(res.cell(m, o, lab).best.metrics.get(k, np.nan)
                              if res.cell(m, o, lab) and res.cell(m, o, lab).ok else np.nan) for lab in labels]
                            for m in res.models])
            if key == "r2":
                extra = {"color_matrix": 1.0 - mat, "fmt": "{:.5g}", "colorbar_label": "1 − R² (log scale)"}
            else:
                extra = {"colorbar_label": f"{title} ({plots.display_unit(u)}, log scale)" if key == "rmse"
                         else f"{title} (log scale)"}
            jobs.append(FigureJob("heatmap_figure", fig_dir / f"heatmap_{key}_{o}.png",
                                  (mat, list(res.models), labels),
                                  {"title": f"{title} per model and condition ({o})", "log": True, **extra}))
        if len(labels) > 1:
            groups = {m: [1.0 - c.best.metrics.get("r2", np.nan) for c in res.cells
                          if c.model == m and c.optimizer == o and c.ok] for m in res.models}
            jobs.append(FigureJob("boxplot_figure", fig_dir / f"r2_distribution_{o}.png", (groups,),
                                  {"title": f"1 − R² over conditions ({o}); lower is better",
                                   "ylabel": "1 − R² (log scale)", "log": True}))
        for m in res.models:
            cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
            if not cells:
                continue
            worst = max(cells, key=lambda c: c.best.metrics.get(f"rmse_{u}", np.inf))
            caps = res.captures[worst.label]
            jobs.append(FigureJob("parity_figure", fig_dir / f"parity_worst_{m}_{o}.png",
                                  (np.concatenate([c.y for c in caps]), np.concatenate(worst.predictions)),
                                  {"unit": u, "title": f"{m} worst case: {worst.label} ({o})"}))
    for _, lab in res.conditions:
        caps = res.captures[lab]
        o = res.optimizers[0]
        models = {m: res.cell(m, o, lab).predictions[0] for m in res.models
                  if res.cell(m, o, lab) and res.cell(m, o, lab).ok}
        jobs.append(FigureJob("loop_overlay_figure", fig_dir / f"loops_{lab}.png", (caps[0].u, caps[0].y, models),
                              {"unit": u, "title": f"all models at {lab} ({o})"}))
    focus = labels[0]
    for m in res.models:
        hist = {o: [r.history_best for r in res.cell(m, o, focus).runs if plots.has_convergence_history(r.history_best)]
                for o in res.optimizers if res.cell(m, o, focus) and res.cell(m, o, focus).ok}
        hist = {o: h for o, h in hist.items() if h}
        if hist:
            jobs.append(FigureJob("convergence_compare_figure", fig_dir / f"convergence_{m}_{focus}.png", (hist,),
                                  {"title": f"{m} at {focus}: convergence of each optimizer"}))
        if res.runs > 1:
            for lab in labels:
                groups = {o: [r.search_j for r in res.cell(m, o, lab).runs] for o in res.optimizers
                          if res.cell(m, o, lab) and res.cell(m, o, lab).ok}
                what = "J of the search (before the polish)" if res.polish else "final J"
                jobs.append(FigureJob("boxplot_figure", fig_dir / f"fitness_box_{m}_{lab}.png", (groups,),
                                      {"log": True, "title": f"{what} over {res.runs} runs: {m} at {lab}",
                                       "ylabel": "J"}))
    made = render_figures(jobs, n_jobs)
    return [str(Path("figures") / Path(p).name) for p in made]


def _optimizer_layout(df: pd.DataFrame) -> pd.DataFrame:
    """One model on one condition: transpose to 004 Table 2's layout (a column per optimizer)."""
    if df.empty or df["model"].nunique() != 1 or df["condition"].nunique() != 1:
        return df
    t = df.drop(columns=["model", "condition"]).set_index("optimizer").T
    t.insert(0, "statistic over runs", t.index)
    return t.reset_index(drop=True).rename_axis(None, axis=1)


def markdown(res: CompareResult, figures: list[str]) -> str:
    u = res.unit
    polished = res.polish and any(o not in res.self_polishing for o in res.optimizers)
    lines = ["# hystfit comparison", "",
             f"- models: {', '.join(f'`{m}`' for m in res.models)}; optimizers: "
             f"{', '.join(f'`{o}`' for o in res.optimizers)}; conditions: {len(res.conditions)}; runs per cell: {res.runs}",
             f"- seed {res.seed} (every run's own seed is in `compare.csv`); parallel jobs {res.jobs} "
             f"({res.executor} executor; cells computed {res.cell_stats.computed}, reused from an interrupted run "
             f"{res.cell_stats.reused}); "
             f"hystfit {__version__}; output unit {u}",
             f"- least-squares polish after global optimizers: "
             f"{'yes (the optimizers are also compared on their search alone, before the polish)' if polished else 'no' if not res.polish else 'not applicable (auto and lsq end with their own local solve)'}",
             f"- fit: {'one parameter set for all captures (--global)' if res.global_fit else 'one parameter set per condition'}"
             + "".join(f"; bounds of `{m}`: " + ", ".join(f"{k} = [{lo:g}, {hi:g}]" for k, (lo, hi) in b.items())
                       for m, b in res.bounds.items() if b)]
    if res.optimizer_settings:
        lines += ["- budgets (each optimizer's settings; the evaluations each run used are in `compare.csv`, "
                  "columns `search_evaluations` and `evaluations` with the polish):"]
        lines += [f"  - `{o}`: " + ", ".join(f"{k}={v}" for k, v in s.items()
                                            if k in ("pop", "iters") + STOP_RULE_NAMES and v is not None
                                            and not (k == "stall_tol" and s.get("stall_iter") is None))
                  for o, s in res.optimizer_settings.items()]
    lines += [""]
    if res.notes:
        lines += ["## Structure identified once from all captures", ""] + [f"- {n}" for n in res.notes] + [""]
    failed = [c for c in res.cells if not c.ok]
    if failed:
        lines += ["## Failed cells", ""] + [f"- `{c.model}` / `{c.optimizer}` / {c.label}: {c.error}" for c in failed] + [""]
    lines += ["## Ranking", ""] + ranking(res)
    lines += ["## Performance comparison of the models (002 Table 3 style)", "",
              "Worst value of each metric over the conditions (best run per cell) and the condition where it "
              "occurred; maximum absolute error per voltage level and the frequency where it occurred.", "",
              markdown_table(table3(res)), ""]
    lines += ["## Identification time in s (002 Table 2 style)", "",
              ("Median over runs of one run's wall time (search + polish) per voltage level and frequency, after one "
               "warm-up fit per process (loading compiled kernels is not counted)."), "",
              markdown_table(runtime_table(res), digits=3), ""]
    ot = optimizer_table(res)
    if not ot.empty and (res.runs > 1 or len(res.optimizers) > 1):
        lines += ["## Optimizers over repeated runs (004 Table 2 style)", "",
                  f"J = Σe²/Σy² (004 eq. 16) and RMSE ({u}) of each run's final parameters"
                  f"{' (after the polish)' if polished else ''}; time = median wall time of a run; "
                  "evaluations = mean objective evaluations per run.", "", markdown_table(_optimizer_layout(ot)), ""]
        if polished:
            lines += ["### The searches alone, before the polish", "",
                      "J of each run's global search result; this is where the optimizers differ.", "",
                      markdown_table(_optimizer_layout(search_table(res))), ""]
    lines += ["## Metrics", "", "Every run's metrics are in `compare.csv`. Formulas (e = model − measured):", "",
              metric_legend(u), "", "## Figures", ""]
    lines += [f"![{Path(f).stem}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def write_compare_outputs(res: CompareResult, out_dir: Path, *, make_figures: bool = True,
                          n_jobs: int | None = None) -> dict[str, Path]:
    """Write compare.csv, compare.md and (with ``make_figures``) figures/, drawn by ``n_jobs`` processes."""
    out_dir = Path(out_dir)
    paths = {"csv": out_dir / "compare.csv", "md": out_dir / "compare.md"}
    write_table(paths["csv"], compare_frame(res))
    figs = _figures(res, out_dir / "figures", n_jobs) if make_figures else []
    atomic_write_text(paths["md"], markdown(res, figs))
    return paths
