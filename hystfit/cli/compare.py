"""``hystfit compare``: models × optimizers × conditions (× runs), tables and figures as in the papers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional

import typer

from .app import command
from .common import (DataArg, ExecutorArgs, FigureOutputArgs, FitArgs, FitCaptureArgs, Iters, MapeFloor, OutDir,
                     Polish, Pop, Runs, Seed, cell_run, load_for_command, print_table_warnings, start_figures,
                     new_table, print_cell_summary,
                     print_json, progress_bar, stdout, writing)


@dataclass(frozen=True)
class CompareFitArgs(FitArgs):
    """:class:`FitArgs` whose items may be scoped to one model or optimizer (``MODEL.KEY=VALUE``)."""

    bounds: Annotated[Optional[list[str]], typer.Option("--bounds", help="Override a bound: NAME=LOWER:UPPER, or "
                                                        "MODEL.NAME=LOWER:UPPER for one model (repeatable).")] = None
    model_option: Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option "
                                                              "KEY=VALUE for every model, or MODEL.KEY=VALUE for one "
                                                              "(repeatable).")] = None
    opt_option: Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE for "
                                                            "every optimizer, e.g. max_evals=3000, or OPT.KEY=VALUE "
                                                            "for one (repeatable).")] = None


def _names(text: str, what: str) -> list[str]:
    from ..errors import ConfigError

    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError(f"--{what}: give at least one name, comma separated")
    if len(set(names)) != len(names):
        raise ConfigError(f"--{what} {text!r}: a name is repeated")
    return names


@command()
def compare(
    data: DataArg,
    models: Annotated[str, typer.Option("--models", help="Comma-separated model names or expressions (pi,pi+creep+delay), or 'all'.")] = "pi,bw",
    opts: Annotated[str, typer.Option("--opts", help="Comma-separated optimizer names.")] = "auto",
    runs: Runs = 1,
    out: OutDir = Path("hystfit-compare"),
    seed: Seed = 0,
    mape_floor: MapeFloor = 0.01,
    execution: ExecutorArgs = ExecutorArgs(),
    pop: Pop = None,
    iters: Iters = None,
    polish: Polish = True,
    fit: CompareFitArgs = CompareFitArgs(),
    output: FigureOutputArgs = FigureOutputArgs(),
    capture: FitCaptureArgs = FitCaptureArgs(),
) -> None:
    """Compare models and optimizers on the captures: every model × optimizer × condition (× runs).

    Writes OUT/compare.csv (one row per model, optimizer, condition, run), OUT/compare.md (paper-style
    tables and a ranking) and OUT/figures/.
    """
    start_figures(output)
    from ..compare import compare as run_compare
    from ..compare import scoped_options
    from ..io import staged_output_dir
    from ..registry import models as model_registry
    from ..registry import optimizers as optimizer_registry
    from ..report.compare_report import write_compare_outputs
    from ..factory import budget_options, make_model, model_option_names, model_param_names

    model_names = model_registry.names() if models.strip().lower() == "all" else _names(models, "models")
    opt_names = _names(opts, "opts")
    opt_classes = {o: optimizer_registry.get(o) for o in opt_names}
    mopts = scoped_options(fit.model_options(), {m: model_option_names(m) for m in model_names}, "--model-option")
    for m in model_names:  # bad expressions or structure options: exit 2 before any data is read
        make_model(m, mopts[m])
    opt_options = scoped_options(fit.optimizer_options(), {o: c.option_names() for o, c in opt_classes.items()},
                                 "--opt-option")
    for o, c in opt_classes.items():  # --pop/--iters: the same budget for every population search
        if c.takes_budget_flags():
            opt_options[o].update(budget_options(c, pop=pop, iters=iters, max_evals=opt_options[o].get("max_evals")))
    bnds = scoped_options(fit.bound_overrides(), {m: model_param_names(m) for m in model_names}, "--bounds")
    options = capture.load_options()
    quiet, json_out = output.quiet, output.json_out
    with cell_run(out, execution, not quiet) as cr, staged_output_dir(out, output.force, inputs=data, resume=execution.resume) as stage:
        from ..compare import startup_steps

        captures = load_for_command(data, options, output, recursive=capture.recursive,
                                    ahead=startup_steps(jobs=execution.jobs, executor=cr.executor))
        print_table_warnings(captures, fit.per_condition, output)
        with progress_bar(output.chatty, "compare") as cb:
            res = run_compare(captures, model_names, opt_names, runs=runs, seed=seed, jobs=execution.jobs,
                              polish=polish, model_options=mopts, optimizer_options=opt_options, bounds=bnds,
                              global_fit=not fit.per_condition, progress=cb, executor=cr.executor, store=cr.store,
                              resume=execution.resume, mape_floor=mape_floor)
        with writing(out, output):
            write_compare_outputs(res, stage, make_figures=output.plots, n_jobs=execution.jobs)
    print_cell_summary(res.cell_stats, cr.describe(), quiet or json_out)
    some_failed = _failures(res, out)
    if json_out:
        _print_summary_json(res, out, model_names, opt_names, runs, captures)
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


def _print_summary_json(res, out, model_names, opt_names, runs: int, captures=()) -> None:
    from ..report.compare_report import compare_frame
    from .common import capture_notes_json

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
                                "wall_time_s": st.wall_time_s, "executor": res.executor},
                "capture_notes": capture_notes_json(captures)})


def _print_summary_table(res, out) -> None:
    from ..report.compare_report import mean_over_conditions
    from ..report.tables import fmt

    u = res.unit
    t = new_table(title=f"mean over conditions (best run per cell) — written to {out}")
    for col in ("model", "optimizer", f"mean rmse_{u}", "worst r2", "failed cells", "total time s"):
        t.add_column(col, justify="right")
    for row in mean_over_conditions(res):
        t.add_row(row["model"], row["optimizer"], fmt(row["mean_rmse"]), fmt(row["worst_r2"], 5),
                  str(row["failed_cells"]), f"{row['runtime_s']:.2f}")
    stdout.print(t)
