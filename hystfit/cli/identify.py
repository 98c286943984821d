"""``hystfit identify``: fit a model per operating condition and write parameters, reports and plots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from .app import app, guarded
from .common import (Condition, DataArg, DropNonfinite, ExecutorOpt, FiguresAlias, Force, Fs, InputCol, Iters, Jobs,
                     JsonOut, MapeFloor, NoHeader, OutputCol, OutputUnit, PerCondition, Plots, Pop, Quiet, Recursive,
                     Resume, Runs, Scheduler, Seed, Start, Stop, TimeCol, Warmup, cell_run, load_for_command,
                     load_options, parse_key_values, plots_flag, print_cell_summary, print_json, progress_bar, stderr,
                     stdout, writing)


@app.command()
@guarded
def identify(
    data: DataArg,
    model: Annotated[str, typer.Option("--model", "-m", help="Model: a name or BASE+BLOCK+... (e.g. pi+creep+delay; see 'hystfit models').")] = "pi",
    opt: Annotated[str, typer.Option("--opt", "-o", help="Optimizer name (see 'hystfit optimizers'); auto = exact linear solves + search over the nonlinear parameters.")] = "auto",
    out: Annotated[Path, typer.Option("--out", help="Output directory (refused if it exists and is not empty, unless --force).")] = Path("hystfit-out"),
    seed: Seed = 0,
    mape_floor: MapeFloor = 0.01,
    pop: Pop = None,
    iters: Iters = None,
    runs: Runs = 1,
    polish: Annotated[bool, typer.Option("--polish/--no-polish", help="Least-squares polish after the global search.")] = True,
    jobs: Jobs = None,
    executor: ExecutorOpt = "local",
    scheduler: Scheduler = None,
    resume: Resume = False,
    per_condition: PerCondition = True,
    bounds: Annotated[Optional[list[str]], typer.Option("--bounds", help="Override a bound: NAME=LOWER:UPPER (repeatable).")] = None,
    model_option: Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option KEY=VALUE, e.g. n_operators=12 (repeatable).")] = None,
    opt_option: Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE, e.g. stall_iter=50 (repeatable).")] = None,
    plots: Plots = True,
    json_out: JsonOut = False,
    quiet: Quiet = False,
    force: Force = False,
    figures_alias: FiguresAlias = None,
    time_col: TimeCol = None, input_col: InputCol = None, output_col: OutputCol = None, no_header: NoHeader = False,
    fs: Fs = None, drop_nonfinite: DropNonfinite = False, condition: Condition = None, output_unit: OutputUnit = None,
    recursive: Recursive = False, start: Start = None, stop: Stop = None, warmup: Warmup = 0.0,
) -> None:
    """Identify MODEL on the captures, one parameter set per operating condition (look-up table).

    Writes OUT/params.json, OUT/report.csv, OUT/report.md and OUT/plots/.
    """
    from ..identify import identify as run_identify
    from ..io import staged_output_dir
    from ..params import parse_bound_overrides
    from ..registry import optimizers
    from ..report.identify_report import write_identify_outputs
    from ..factory import make_model, make_optimizer

    opt_cls = optimizers.get(opt)
    mopts = parse_key_values(model_option or [], "--model-option")
    oopts = parse_key_values(opt_option or [], "--opt-option")
    m = make_model(model, mopts)
    o = make_optimizer(opt_cls, oopts, pop=pop, iters=iters)
    bnds = parse_bound_overrides(bounds or [])
    options = load_options(time_col, input_col, output_col, no_header, fs, drop_nonfinite, condition, output_unit,
                           start=start, stop=stop, warmup=warmup)
    make_plots = plots_flag(plots, figures_alias)
    with cell_run(out, executor, jobs, scheduler, resume, not quiet) as cr, staged_output_dir(out, force) as stage:
        captures = load_for_command(data, options, recursive=recursive, quiet=quiet, json_out=json_out,
                                    figures=make_plots)
        with progress_bar(not quiet and not json_out, f"identify {m.name} / {opt_cls.name}") as cb:
            res = run_identify(captures, m, o, seed=seed, runs=runs, polish=polish, global_fit=not per_condition,
                               bounds=bnds, progress=cb, model_options=mopts, jobs=jobs, executor=cr.executor,
                               store=cr.store, resume=resume, mape_floor=mape_floor)
        with writing(out, quiet, json_out, make_plots):
            write_identify_outputs(res, stage, make_plots=make_plots, n_jobs=jobs)
    print_cell_summary(res.cell_stats, cr.describe(), quiet or json_out)
    some_failed = None
    if res.failed:
        from ..errors import CellsFailedError

        some_failed = CellsFailedError(f"{len(res.failed)} run(s) failed and were left out (first: {res.failed[0]}); "
                                       f"the other runs are in {out}, every failure in {out}/report.md")
    if not quiet:
        _print_bound_notes(res)
    if json_out:
        _print_summary_json(res, out, seed)
    elif not quiet:
        _print_summary_table(res, f"{m.name} / {opt_cls.name} — {len(res.fits)} condition(s), output in {out}")
    if some_failed:
        raise some_failed


def _print_bound_notes(res) -> None:
    from ..report.identify_report import bound_notes

    pinned = bound_notes(res)
    if not pinned:
        return
    stderr.print(f"note: {len(pinned)} parameter set(s) have parameters at a search bound (no standard error; "
                 "widen with --bounds NAME=LOWER:UPPER if the bound is not physical; see report.md):",
                 markup=False, highlight=False, soft_wrap=True)
    for line in pinned[:5]:
        stderr.print(f"  {line}", markup=False, highlight=False, soft_wrap=True)
    if len(pinned) > 5:
        stderr.print(f"  … and {len(pinned) - 5} more in report.md", markup=False, highlight=False)


def _print_summary_json(res, out, seed: int) -> None:
    from ..results import identify_to_dict

    d = identify_to_dict(res)
    print_json({"out": str(out), "model": d["model"]["name"], "optimizer": d["optimizer"]["name"],
                "seed": seed, "units": d["units"],
                "conditions": [{"label": c["label"], "amplitude_V": c["amplitude_V"],
                                "frequency_Hz": c["frequency_Hz"], "metrics": c["metrics"],
                                "runtime_s": c["runtime_s"], "evaluations": c["evaluations"]}
                               for c in d["conditions"]],
                "failed": list(res.failed),
                "cell_counts": {"computed": res.cell_stats.computed, "reused": res.cell_stats.reused,
                                "failed": res.cell_stats.failed, "wall_time_s": res.cell_stats.wall_time_s}})


def _print_summary_table(res, title: str) -> None:
    from ..report.identify_report import summary_rows
    from ..report.tables import fmt

    u = res.unit
    table = Table(title=title)
    for col in ("condition", f"rmse_{u}", "nrmse_pct", "r2", f"max_error_{u}", "runtime_s"):
        table.add_column(col, justify="right")
    for row in summary_rows(res):
        table.add_row(row["condition"], f"{row[f'rmse_{u}']:.4g}", f"{row['nrmse_pct']:.3g}", fmt(row['r2'], 5),
                      f"{row[f'max_error_{u}']:.4g}", f"{row['runtime_s']:.2f}")
    stdout.print(table)
