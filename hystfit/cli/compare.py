"""``hystfit compare``: models × optimizers × conditions (× runs), tables and figures as in the papers."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from .app import app, guarded
from .common import (Condition, DataArg, DropNonfinite, ExecutorOpt, FiguresAlias, Force, Fs, InputCol, Iters, Jobs,
                     JsonOut, MapeFloor, NoHeader, OutputCol, OutputUnit, PerCondition, Plots, Pop, Quiet, Recursive,
                     Resume, Runs, Scheduler, Seed, Start, Stop, TimeCol, Warmup, cell_run, load_for_command,
                     load_options, parse_key_values, plots_flag, print_cell_summary, print_json, progress_bar,
                     stdout, writing)


def _names(text: str, what: str) -> list[str]:
    from ..errors import ConfigError

    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError(f"--{what}: give at least one name, comma separated")
    if len(set(names)) != len(names):
        raise ConfigError(f"--{what} {text!r}: a name is repeated")
    return names


@app.command()
@guarded
def compare(
    data: DataArg,
    models: Annotated[str, typer.Option("--models", help="Comma-separated model names or expressions (pi,pi+creep+delay), or 'all'.")] = "pi,bw",
    opts: Annotated[str, typer.Option("--opts", help="Comma-separated optimizer names.")] = "auto",
    runs: Runs = 1,
    out: Annotated[Path, typer.Option("--out", help="Output directory (refused if it exists and is not empty, unless --force).")] = Path("hystfit-compare"),
    seed: Seed = 0,
    mape_floor: MapeFloor = 0.01,
    jobs: Jobs = None,
    executor: ExecutorOpt = "local",
    scheduler: Scheduler = None,
    resume: Resume = False,
    pop: Pop = None,
    iters: Iters = None,
    polish: Annotated[bool, typer.Option("--polish/--no-polish", help="Least-squares polish after the global search.")] = True,
    per_condition: PerCondition = True,
    bounds: Annotated[Optional[list[str]], typer.Option("--bounds", help="Override a bound: NAME=LOWER:UPPER, or MODEL.NAME=LOWER:UPPER for one model (repeatable).")] = None,
    model_option: Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option KEY=VALUE for every model, or MODEL.KEY=VALUE for one (repeatable).")] = None,
    opt_option: Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE for every optimizer, e.g. max_evals=3000, or OPT.KEY=VALUE for one (repeatable).")] = None,
    plots: Plots = True,
    json_out: JsonOut = False,
    quiet: Quiet = False,
    force: Force = False,
    figures_alias: FiguresAlias = None,
    time_col: TimeCol = None, input_col: InputCol = None, output_col: OutputCol = None, no_header: NoHeader = False,
    fs: Fs = None, drop_nonfinite: DropNonfinite = False, condition: Condition = None, output_unit: OutputUnit = None,
    recursive: Recursive = False, start: Start = None, stop: Stop = None, warmup: Warmup = 0.0,
) -> None:
    """Compare models and optimizers on the captures: every model × optimizer × condition (× runs).

    Writes OUT/compare.csv (one row per model, optimizer, condition, run), OUT/compare.md (paper-style
    tables and a ranking) and OUT/figures/.
    """
    from ..compare import compare as run_compare
    from ..compare import scoped_options
    from ..io import staged_output_dir
    from ..registry import models as model_registry
    from ..registry import optimizers as optimizer_registry
    from ..report.compare_report import write_compare_outputs
    from ..params import parse_bound_overrides
    from ..factory import budget_options, make_model, model_option_names, model_param_names

    model_names = model_registry.names() if models.strip().lower() == "all" else _names(models, "models")
    opt_names = _names(opts, "opts")
    opt_classes = {o: optimizer_registry.get(o) for o in opt_names}
    mopts = scoped_options(parse_key_values(model_option or [], "--model-option"),
                           {m: model_option_names(m) for m in model_names}, "--model-option")
    for m in model_names:  # bad expressions or structure options: exit 2 before any data is read
        make_model(m, mopts[m])
    opt_options = scoped_options(parse_key_values(opt_option or [], "--opt-option"),
                                 {o: c.option_names() for o, c in opt_classes.items()}, "--opt-option")
    for o, c in opt_classes.items():  # --pop/--iters: the same budget for every population search
        if c.takes_budget_flags():
            opt_options[o].update(budget_options(c, pop=pop, iters=iters, max_evals=opt_options[o].get("max_evals")))
    bnds = parse_bound_overrides(bounds or [])
    bnds = scoped_options(bnds, {m: model_param_names(m) for m in model_names}, "--bounds")
    options = load_options(time_col, input_col, output_col, no_header, fs, drop_nonfinite, condition, output_unit,
                           start=start, stop=stop, warmup=warmup)
    make_plots = plots_flag(plots, figures_alias)
    with cell_run(out, executor, jobs, scheduler, resume, not quiet) as cr, staged_output_dir(out, force) as stage:
        captures = load_for_command(data, options, recursive=recursive, quiet=quiet, json_out=json_out,
                                    figures=make_plots)
        with progress_bar(not quiet and not json_out, "compare") as cb:
            res = run_compare(captures, model_names, opt_names, runs=runs, seed=seed, jobs=jobs, polish=polish,
                              model_options=mopts, optimizer_options=opt_options, bounds=bnds,
                              global_fit=not per_condition, progress=cb, executor=cr.executor, store=cr.store,
                              resume=resume, mape_floor=mape_floor)
        with writing(out, quiet, json_out, make_plots):
            write_compare_outputs(res, stage, make_figures=make_plots, n_jobs=jobs)
    print_cell_summary(res.cell_stats, cr.describe(), quiet or json_out)
    some_failed = _failures(res, out)
    if json_out:
        _print_summary_json(res, out, model_names, opt_names, runs)
    elif not quiet:
        _print_summary_table(res, out)
    if some_failed:
        raise some_failed


def _failures(res, out):
    """NoResultError when every cell failed (raised), CellsFailedError when some did (returned)."""
    from ..errors import CellsFailedError, NoResultError

    failed = [c for c in res.cells if not c.ok]
    if not failed:
        return None
    first = f"{failed[0].model}/{failed[0].optimizer}/{failed[0].label}: {failed[0].error}"
    if len(failed) == len(res.cells):
        raise NoResultError(f"every cell failed ({len(failed)} of {len(failed)}); first error: {first} "
                            f"(all errors in {out}/compare.csv)")
    return CellsFailedError(f"{len(failed)} of {len(res.cells)} cells failed (first: {first}); the other cells "
                            f"are in {out}, every error in {out}/compare.csv")


def _print_summary_json(res, out, model_names, opt_names, runs: int) -> None:
    from ..report.compare_report import compare_frame

    df = compare_frame(res)
    u = res.unit
    st = res.cell_stats
    ok = df[df["error"] == ""] if "error" in df else df
    best = ok[ok["best_run"] == True] if "best_run" in ok else ok  # noqa: E712
    print_json({"out": str(out), "models": model_names, "optimizers": opt_names, "runs": runs,
                "cells": [{k: (None if isinstance(v, float) and v != v else v) for k, v in row.items()}
                          for row in best[["model", "optimizer", "condition", "amplitude_V", "frequency_Hz",
                                           f"rmse_{u}", "r2", "j", "runtime_s", "evaluations"]].to_dict("records")],
                "failed": [{"model": c.model, "optimizer": c.optimizer, "condition": c.label, "error": c.error}
                           for c in res.cells if not c.ok],
                "cell_counts": {"computed": st.computed, "reused": st.reused, "failed": st.failed,
                                "wall_time_s": st.wall_time_s, "executor": res.executor}})


def _print_summary_table(res, out) -> None:
    from ..report.compare_report import mean_over_conditions
    from ..report.tables import fmt

    u = res.unit
    t = Table(title=f"mean over conditions (best run per cell) — written to {out}")
    for col in ("model", "optimizer", f"mean rmse_{u}", "worst r2", "failed cells", "total time s"):
        t.add_column(col, justify="right")
    for row in mean_over_conditions(res):
        t.add_row(row["model"], row["optimizer"], fmt(row["mean_rmse"]), fmt(row["worst_r2"], 5),
                  str(row["failed_cells"]), f"{row['runtime_s']:.2f}")
    stdout.print(t)
