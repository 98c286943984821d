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
from ..compare import CellResult, CompareResult
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


def optimizer_table(res: CompareResult) -> pd.DataFrame:
    """004 Table 2: per model, optimizer and condition, the final J and RMSE over runs
    (min / max / mean / std, after the polish if any), the median time and mean evaluations."""
    u = res.unit
    rows = []
    for c in res.cells:
        if not c.ok:
            continue
        row = {"model": c.model, "optimizer": c.optimizer, "condition": c.label, "runs": len(c.runs)}
        row.update(_stats([r.j for r in c.runs], "J"))
        row.update(_stats([r.metrics.get(f"rmse_{u}", np.nan) for r in c.runs], "RMSE", f" ({u})"))
        row["time median (s)"] = float(np.median([r.wall_time_s for r in c.runs]))
        row["evaluations mean"] = float(np.mean([r.nfev for r in c.runs]))
        row["search evaluations mean"] = float(np.mean([r.search_nfev for r in c.runs]))
        rows.append(row)
    return pd.DataFrame(rows)


def search_table(res: CompareResult) -> pd.DataFrame:
    """The global search alone (before the least-squares polish): J over runs per model, optimizer
    and condition. Equal to :func:`optimizer_table`'s J without a polish, and for ``auto`` and
    ``lsq`` (which are not polished again)."""
    rows = []
    for c in res.cells:
        if not c.ok:
            continue
        row = {"model": c.model, "optimizer": c.optimizer, "condition": c.label, "runs": len(c.runs)}
        row.update(_stats([r.search_j for r in c.runs], "J"))
        row["runs the polish improved by > 0.1 %"] = int(sum(r.j < r.search_j * (1 - 1e-3) for r in c.runs))
        rows.append(row)
    return pd.DataFrame(rows)


def _compare_note(a: np.ndarray, b: np.ndarray, paired: bool, name_b: str, what: str) -> str:
    """How group ``a`` (the better mean) compares with the next one, ``b``.

    Unpaired samples (values over runs): the two-sided Mann–Whitney U test with at least 3 values
    per group; with 2, the gap against twice the larger standard deviation; with 1, the spread
    is unknown and the note says so. Paired samples (one value per condition, single runs): the
    Wilcoxon signed-rank test over conditions with at least 6 conditions, else a count of the
    conditions where ``a`` is lower.
    """
    from scipy.stats import mannwhitneyu, wilcoxon

    gap = float(np.mean(b) - np.mean(a))
    if gap <= 1e-6 * max(abs(float(np.mean(a))), 1e-300):
        return f" — tied with `{name_b}`"
    if paired:
        d = b - a
        lower = int(np.sum(d > 0))
        if d.size >= 6 and np.any(d != 0):
            p = float(wilcoxon(a, b).pvalue)
            verdict = "consistently below" if p < 0.05 else "not consistently below"
            return (f" — {verdict} `{name_b}` (lower at {lower} of {d.size} conditions, "
                    f"Wilcoxon signed-rank over conditions p = {p:.2g})")
        return f" — lower than `{name_b}` at {lower} of {d.size} conditions"
    if min(a.size, b.size) >= 3:
        p = float(mannwhitneyu(a, b, alternative="two-sided").pvalue)
        verdict = "better than" if p < 0.05 else "not distinguishable from"
        return f" — {verdict} `{name_b}` (Mann–Whitney U over runs, p = {p:.2g})"
    if min(a.size, b.size) == 2:
        spread = max(np.std(a, ddof=1), np.std(b, ddof=1))
        if gap <= 2 * spread:
            return f" — within run-to-run spread of `{name_b}` (gap {fmt(gap)} ≤ 2σ = {fmt(2 * spread)})"
        return f" — below `{name_b}` by more than twice the run-to-run spread ({fmt(gap)} > {fmt(2 * spread)})"
    return ""


def _rank_text(names: list[str], samples: list[np.ndarray], what: str, unit: str, *, paired: bool = False,
               medians: list[float] | None = None) -> list[str]:
    """Rank by the mean of each group's samples; between neighbours say whether the difference is
    beyond the spread (:func:`_compare_note`)."""
    means = [float(np.mean(s)) for s in samples]
    order = np.argsort(means, kind="stable")
    lines = []
    for pos, i in enumerate(order):
        note = ""
        if pos + 1 < len(order):
            j = order[pos + 1]
            note = _compare_note(np.asarray(samples[i], float), np.asarray(samples[j], float), paired, names[j], what)
        med = ""
        if medians is not None:
            med = f", median {fmt(medians[i])}"
            if means[i] > 2 * medians[i]:
                med += " (the mean is dominated by a few conditions; see the worst cases below)"
        lines.append(f"{pos + 1}. `{names[i]}`: mean {what} {fmt(means[i])}{(' ' + unit) if unit else ''}{med}{note}")
    return lines


def ranking(res: CompareResult) -> list[str]:
    u = res.unit
    out = []
    if len(res.models) > 1:
        for o in res.optimizers:
            names, samples, medians = [], [], []
            for m in res.models:
                cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
                if len(cells) != len(res.conditions):
                    continue
                names.append(m)
                best = np.array([c.best.metrics[f"rmse_{u}"] for c in cells])
                medians.append(float(np.median(best)))
                if res.runs > 1:  # per run: the RMSE averaged over conditions
                    nr = min(len(c.runs) for c in cells)
                    samples.append(np.array([np.mean([c.runs[r].metrics[f"rmse_{u}"] for c in cells])
                                             for r in range(nr)]))
                else:  # one value per condition, paired across models by condition
                    samples.append(best)
            skipped = [m for m in res.models if m not in names]
            if names:
                out += [f"Models with `{o}`, by mean RMSE over the {len(res.conditions)} condition(s):", ""]
                if res.runs == 1:
                    out += ["One run per cell: the run-to-run spread is unknown (rerun with `--runs 3` or more to "
                            "test it). Neighbours are compared condition by condition instead, which shows whether "
                            "one model is consistently better, not whether a rerun would change the order.", ""]
                else:
                    out += [f"Each model's mean is over runs of the RMSE averaged over conditions "
                            f"({res.runs} runs).", ""]
                out += _rank_text(names, samples, "RMSE", u, paired=res.runs == 1, medians=medians)
                if skipped:
                    out += [f"- not ranked (failed on some condition): {', '.join(f'`{m}`' for m in skipped)}"]
                out += [""]
    if len(res.optimizers) > 1:
        polished = res.polish and any(o not in res.self_polishing for o in res.optimizers)
        for m in res.models:
            names, samples = [], []
            for o in res.optimizers:
                cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
                if len(cells) != len(res.conditions):
                    continue
                names.append(o)
                nr = min(len(c.runs) for c in cells)
                samples.append(np.array([np.mean([c.runs[r].search_j for c in cells]) for r in range(nr)]))
            if names:
                what = "J of the search (before the polish)" if polished else "final J"
                out += [f"Optimizers on `{m}`, by mean {what} over runs (averaged over conditions):", ""]
                out += _rank_text(names, samples, "J", "") + [""]
                if polished:
                    fin = [np.mean([c.runs[r].j for c in res.cells if c.model == m and c.optimizer == o and c.ok
                                    for r in range(len(c.runs))]) for o in names]
                    spread = 100 * (max(fin) - min(fin)) / min(fin) if min(fin) > 0 else np.nan
                    verdict = ("the polish, not the search, sets the final accuracy here; the search decides the "
                               "basin and the time" if spread < 1 else "the search still matters after the polish")
                    by = f"{fmt(spread)} %" if spread >= 0.01 else "less than 0.01 %"
                    out += [f"After the least-squares polish the mean final J of these optimizers differ by "
                            f"{by} (004 Table 2 style table below): {verdict}.", ""]
    if not out:
        out = ["One model and one optimizer: nothing to rank.", ""]
    return out


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
