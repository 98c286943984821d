"""Writes the outputs of ``hystfit compare``: compare.csv, compare.md and the figures.

Tables follow the papers: 002 Table 3 (per-model worst cases), 002 Table 2 (runtime per model and
condition), 004 Table 2 (optimizer statistics over repeated runs), plus a ranking that says where
differences are within the run-to-run spread.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import __version__
from ..compare import CellResult, CompareResult
from ..io import atomic_write_text, write_table
from . import plots
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
                   "j": r.j}
            for k in mcols:
                row[k] = r.metrics.get(k, np.nan)
            row.update({"runtime_s": r.wall_time_s, "evaluations": r.nfev, "error": ""})
            rows.append(row)
    return pd.DataFrame(rows)


def _best_cells(res: CompareResult, optimizer: str) -> list[CellResult]:
    return [c for c in res.cells if c.optimizer == optimizer and c.ok]


def model_summary(res: CompareResult, optimizer: str) -> pd.DataFrame:
    """002 Table 3: per model, the worst RMSE/MAPE/SMAPE/R² over conditions (and where), max error per voltage."""
    u = res.unit
    amps = sorted({k[0] for k, _ in res.conditions})
    rows = []
    for m in res.models:
        cells = [c for c in _best_cells(res, optimizer) if c.model == m]
        if not cells:
            rows.append({"model": m, "parameters": "–", "note": "failed on every condition"})
            continue
        mets = [c.best.metrics for c in cells]
        row = {"model": m, "parameters": cells[0].n_params}
        for key, worst in ((f"rmse_{u}", max), ("mape", max), ("smape", max), ("r2", min)):
            vals = [mm.get(key, np.nan) for mm in mets]
            finite = [v for v in vals if np.isfinite(v)]
            if finite:
                w = worst(finite)
                row[f"worst {key}"] = w
                row[f"worst {key} at"] = cells[vals.index(w)].label
        for a in amps:
            errs = [c.best.metrics.get(f"max_error_{u}", np.nan) for c in cells if c.amplitude_V == a]
            row[f"max error {fmt(a)} V ({u})"] = max(errs) if errs else np.nan
        failed = [c.label for c in res.cells if c.model == m and c.optimizer == optimizer and not c.ok]
        if failed:
            row["note"] = f"failed at {', '.join(failed)}"
        rows.append(row)
    return pd.DataFrame(rows)


def runtime_table(res: CompareResult, optimizer: str) -> pd.DataFrame:
    """002 Table 2: identification time (s, median over runs) per model × condition."""
    rows = []
    for m in res.models:
        row = {"model": m}
        for _, lab in res.conditions:
            c = res.cell(m, optimizer, lab)
            row[lab] = float(np.median([r.wall_time_s for r in c.runs])) if c and c.ok else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def optimizer_table(res: CompareResult) -> pd.DataFrame:
    """004 Table 2: per model, optimizer and condition, J over runs (min / max / mean / std) and time."""
    u = res.unit
    rows = []
    for c in res.cells:
        if not c.ok:
            continue
        js = np.array([r.j for r in c.runs])
        rm = np.array([r.metrics.get(f"rmse_{u}", np.nan) for r in c.runs])
        rows.append({"model": c.model, "optimizer": c.optimizer, "condition": c.label, "runs": len(c.runs),
                     "J min": js.min(), "J max": js.max(), "J mean": js.mean(),
                     "J std": js.std(ddof=1) if js.size > 1 else 0.0,
                     f"RMSE mean ({u})": rm.mean(), "time median (s)": float(np.median([r.wall_time_s for r in c.runs])),
                     "evaluations mean": float(np.mean([r.nfev for r in c.runs]))})
    return pd.DataFrame(rows)


def _rank_text(names: list[str], means: list[float], samples: list[np.ndarray], what: str, unit: str) -> list[str]:
    """Rank by mean; between neighbours, say whether the difference is beyond run-to-run variation.

    With at least 3 values per group the two-sided Mann–Whitney U test decides (p < 0.05);
    with fewer, the gap is compared with twice the larger standard deviation; a single run per
    group has no spread to compare with, and the text says so.
    """
    from scipy.stats import mannwhitneyu

    order = np.argsort(means)
    lines = []
    for pos, i in enumerate(order):
        note = ""
        if pos + 1 < len(order):
            j = order[pos + 1]
            a, b = np.asarray(samples[i], float), np.asarray(samples[j], float)
            gap = means[j] - means[i]
            if gap <= 1e-6 * max(abs(means[i]), 1e-300):
                note = f" — tied with `{names[j]}`"
            elif min(a.size, b.size) >= 3:
                p = float(mannwhitneyu(a, b, alternative="two-sided").pvalue)
                verdict = "better than" if p < 0.05 else "not distinguishable from"
                note = f" — {verdict} `{names[j]}` (Mann–Whitney U over runs, p = {p:.2g})"
            elif min(a.size, b.size) >= 2:
                spread = max(np.std(a, ddof=1), np.std(b, ddof=1))
                if gap <= 2 * spread:
                    note = f" — within run-to-run spread of `{names[j]}` (gap {fmt(gap)} ≤ 2σ = {fmt(2 * spread)})"
            else:
                note = " (single run: run-to-run spread unknown)"
        lines.append(f"{pos + 1}. `{names[i]}`: mean {what} {fmt(means[i])} {unit}{note}")
    return lines


def ranking(res: CompareResult) -> list[str]:
    u = res.unit
    out = []
    if len(res.models) > 1:
        for o in res.optimizers:
            names, means, samples = [], [], []
            for m in res.models:
                cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
                if len(cells) != len(res.conditions):
                    continue
                names.append(m)
                means.append(float(np.mean([c.best.metrics[f"rmse_{u}"] for c in cells])))
                # per run: the RMSE averaged over conditions
                nr = min(len(c.runs) for c in cells)
                samples.append(np.array([np.mean([c.runs[r].metrics[f"rmse_{u}"] for c in cells]) for r in range(nr)]))
            if names:
                out += [f"Models with `{o}`, by mean RMSE (best run per condition) over the "
                        f"{len(res.conditions)} condition(s):", ""]
                out += _rank_text(names, means, samples, "RMSE", u) + [""]
    if len(res.optimizers) > 1:
        for m in res.models:
            names, means, samples = [], [], []
            for o in res.optimizers:
                cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
                if len(cells) != len(res.conditions):
                    continue
                names.append(o)
                nr = min(len(c.runs) for c in cells)
                per_run = np.array([np.mean([c.runs[r].j for c in cells]) for r in range(nr)])
                means.append(float(per_run.mean()))
                samples.append(per_run)
            if names:
                out += [f"Optimizers on `{m}`, by mean final J over runs (averaged over conditions):", ""]
                out += _rank_text(names, means, samples, "J", "") + [""]
    if not out:
        out = ["One model and one optimizer: nothing to rank.", ""]
    return out


def _figures(res: CompareResult, fig_dir: Path) -> list[str]:
    fig_dir.mkdir(exist_ok=True)
    made = []
    u = res.unit
    labels = [lab for _, lab in res.conditions]
    for o in res.optimizers:
        for key, title in HEATMAP_METRICS:
            k = f"{key}_{u}" if key == "rmse" else key
            mat = np.array([[(res.cell(m, o, lab).best.metrics.get(k, np.nan)
                              if res.cell(m, o, lab) and res.cell(m, o, lab).ok else np.nan) for lab in labels]
                            for m in res.models])
            made.append(plots.heatmap_figure(fig_dir / f"heatmap_{key}_{o}.png", mat, list(res.models), labels,
                                             title=f"{title} per model and condition ({o})",
                                             colorbar_label=f"{title} ({u})" if key == "rmse" else title,
                                             cmap="viridis_r" if key == "r2" else "viridis"))
        groups = {m: [c.best.metrics.get("r2", np.nan) for c in res.cells if c.model == m and c.optimizer == o and c.ok]
                  for m in res.models}
        made.append(plots.boxplot_figure(fig_dir / f"r2_distribution_{o}.png", groups,
                                         title=f"R² over conditions ({o})", ylabel="R²"))
        for m in res.models:
            cells = [c for c in res.cells if c.model == m and c.optimizer == o and c.ok]
            if not cells:
                continue
            worst = max(cells, key=lambda c: c.best.metrics.get(f"rmse_{u}", np.inf))
            caps = res.captures[worst.label]
            made.append(plots.parity_figure(fig_dir / f"parity_worst_{m}_{o}.png",
                                            np.concatenate([c.y for c in caps]), np.concatenate(worst.predictions),
                                            unit=u, title=f"{m} worst case: {worst.label} ({o})"))
    for _, lab in res.conditions:
        caps = res.captures[lab]
        o = res.optimizers[0]
        models = {m: res.cell(m, o, lab).predictions[0] for m in res.models
                  if res.cell(m, o, lab) and res.cell(m, o, lab).ok}
        made.append(plots.loop_overlay_figure(fig_dir / f"loops_{lab}.png", caps[0].u, caps[0].y, models, unit=u,
                                              title=f"all models at {lab} ({o})"))
    focus = labels[0]
    for m in res.models:
        hist = {o: [r.history_best for r in res.cell(m, o, focus).runs] for o in res.optimizers
                if res.cell(m, o, focus) and res.cell(m, o, focus).ok}
        if hist:
            made.append(plots.convergence_compare_figure(fig_dir / f"convergence_{m}_{focus}.png", hist,
                                                         title=f"{m} at {focus}: convergence of each optimizer"))
        if res.runs > 1:
            for lab in labels:
                groups = {o: [r.j for r in res.cell(m, o, lab).runs] for o in res.optimizers
                          if res.cell(m, o, lab) and res.cell(m, o, lab).ok}
                made.append(plots.boxplot_figure(fig_dir / f"fitness_box_{m}_{lab}.png", groups, log=True,
                                                 title=f"final J over {res.runs} runs: {m} at {lab}", ylabel="J"))
    return [str(Path("figures") / Path(p).name) for p in made]


def markdown(res: CompareResult, figures: list[str]) -> str:
    u = res.unit
    lines = ["# hystfit comparison", "",
             f"- models: {', '.join(f'`{m}`' for m in res.models)}; optimizers: "
             f"{', '.join(f'`{o}`' for o in res.optimizers)}; conditions: {len(res.conditions)}; runs per cell: {res.runs}",
             f"- seed {res.seed}; parallel jobs {res.jobs}; hystfit {__version__}; output unit {u}",
             f"- least-squares polish after global optimizers: {'yes (differences between optimizers then show mostly in time; use --no-polish to compare the searches themselves)' if res.polish else 'no'}",
             ""]
    failed = [c for c in res.cells if not c.ok]
    if failed:
        lines += ["## Failed cells", ""] + [f"- `{c.model}` / `{c.optimizer}` / {c.label}: {c.error}" for c in failed] + [""]
    lines += ["## Ranking", ""] + ranking(res)
    for o in res.optimizers:
        lines += [f"## Worst cases per model (002 Table 3 style), optimizer `{o}`", "",
                  "Worst value of each metric over all conditions, and the condition where it occurred; maximum "
                  "absolute error per voltage level.", "", markdown_table(model_summary(res, o)), ""]
        lines += [f"## Identification time per model and condition in s (002 Table 2 style), optimizer `{o}`", "",
                  markdown_table(runtime_table(res, o), digits=3), ""]
    ot = optimizer_table(res)
    if not ot.empty and (res.runs > 1 or len(res.optimizers) > 1):
        lines += ["## Optimizers over repeated runs (004 Table 2 style)", "",
                  "J = Σe²/Σy² (004 eq. 16) of each run's final parameters.", "", markdown_table(ot), ""]
    lines += ["## Metrics", "", "Every run's metrics are in `compare.csv`. Formulas (e = model − measured):", "",
              metric_legend(u), "", "## Figures", ""]
    lines += [f"![{Path(f).stem}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def write_compare_outputs(res: CompareResult, out_dir: Path, *, make_figures: bool = True) -> dict[str, Path]:
    out_dir = Path(out_dir)
    paths = {"csv": out_dir / "compare.csv", "md": out_dir / "compare.md"}
    write_table(paths["csv"], compare_frame(res))
    figs = _figures(res, out_dir / "figures") if make_figures else []
    atomic_write_text(paths["md"], markdown(res, figs))
    return paths
