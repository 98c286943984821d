"""``hystfit identify``: fit a model per operating condition and write parameters, reports and plots."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import typer

from .app import command
from .common import (DataArg, ExecutorArgs, FigureOutputArgs, FitArgs, FitCaptureArgs, Iters, MapeFloor, OutDir,
                     Polish, Pop, Runs, Seed, cell_run, load_for_command, print_table_warnings, start_figures,
                     new_table, print_cell_summary,
                     print_json, progress_bar, stderr, stdout, writing)


@command()
def identify(
    data: DataArg,
    model: Annotated[str, typer.Option("--model", "-m", help="Model: a name or BASE+BLOCK+... (e.g. pi+creep+delay; see 'hystfit models').")] = "pi",
    opt: Annotated[str, typer.Option("--opt", "-o", help="Optimizer name (see 'hystfit optimizers'); auto = exact linear solves + search over the nonlinear parameters.")] = "auto",
    out: OutDir = Path("hystfit-out"),
    seed: Seed = 0,
    mape_floor: MapeFloor = 0.01,
    pop: Pop = None,
    iters: Iters = None,
    runs: Runs = 1,
    polish: Polish = True,
    execution: ExecutorArgs = ExecutorArgs(),
    fit: FitArgs = FitArgs(),
    output: FigureOutputArgs = FigureOutputArgs(),
    capture: FitCaptureArgs = FitCaptureArgs(),
) -> None:
    """Identify MODEL on the captures, one parameter set per operating condition (look-up table).

    Writes OUT/params.json, OUT/report.csv, OUT/report.md and OUT/plots/.
    """
    start_figures(output, behind=True)  # the fits come first; the figures take the other core and the gaps
    from ..identify import condition_groups, identify as run_identify, startup_steps
    from ..io import staged_output_dir
    from ..registry import optimizers
    from ..report.identify_report import ConditionFigures, write_identify_outputs
    from ..factory import make_model, make_optimizer

    opt_cls = optimizers.get(opt)
    mopts = fit.model_options()
    m = make_model(model, mopts)
    o = make_optimizer(opt_cls, fit.optimizer_options(), pop=pop, iters=iters)
    bnds = fit.bound_overrides()
    options = capture.load_options()
    quiet, json_out = output.quiet, output.json_out
    with cell_run(out, execution, not quiet) as cr, \
            staged_output_dir(out, output.force, inputs=data, resume=execution.resume) as stage:
        one_cell = not fit.per_condition or (len(data) == 1 and Path(data[0]).is_file())  # × runs
        captures = load_for_command(data, options, output, recursive=capture.recursive,
                                    ahead=startup_steps(m, o, jobs=execution.jobs, executor=cr.executor,
                                                        n_cells=runs if one_cell else None, polish=polish))
        print_table_warnings(captures, fit.per_condition, output)
        # each condition's figures are drawn while the next conditions are fitted
        n_conditions = len(condition_groups(captures, not fit.per_condition))
        with (ConditionFigures(stage, o.name, execution.jobs, n_conditions=n_conditions) if output.plots
              else nullcontext()) as figures:
            with progress_bar(output.chatty, f"identify {m.name} / {opt_cls.name}") as cb:
                res = run_identify(captures, m, o, seed=seed, runs=runs, polish=polish,
                                   global_fit=not fit.per_condition, bounds=bnds, progress=cb, model_options=mopts,
                                   jobs=execution.jobs, executor=cr.executor, store=cr.store, resume=execution.resume,
                                   mape_floor=mape_floor, on_fit=figures.add if figures is not None else None)
            with writing(out, output):
                write_identify_outputs(res, stage, make_plots=output.plots, n_jobs=execution.jobs, figures=figures)
    print_cell_summary(res.cell_stats, cr.describe(), quiet or json_out)
    some_failed = None
    if res.failed:
        from ..errors import CellsFailedError

        some_failed = CellsFailedError(f"{len(res.failed)} run(s) failed and were left out (first: {res.failed[0]}); "
                                       f"the other runs are in {out}, every failure in {out}/report.md")
    if not quiet:
        _print_bound_notes(res)
        _print_undetermined_notes(res)
        _print_offset_notes(res)
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


def _print_undetermined_notes(res) -> None:
    from ..report.identify_report import undetermined_notes

    loose = undetermined_notes(res)
    if not loose:
        return
    stderr.print(f"note: {len(loose)} parameter set(s) have parameters the data do not determine (any value fits "
                 "as well: no standard error; read them as arbitrary, or capture data that excite them; "
                 "see report.md):", markup=False, highlight=False, soft_wrap=True)
    for line in loose[:5]:
        stderr.print(f"  {line}", markup=False, highlight=False, soft_wrap=True)
    if len(loose) > 5:
        stderr.print(f"  … and {len(loose) - 5} more in report.md", markup=False, highlight=False)


def _print_offset_notes(res) -> None:
    from ..report.identify_report import offset_notes

    lines = offset_notes(res)
    if not lines:
        return
    stderr.print(f"note: {len(lines)} parameter set(s) miss an output offset:", markup=False, highlight=False)
    for line in lines[:5]:
        stderr.print(f"  {line}", markup=False, highlight=False, soft_wrap=True)
    if len(lines) > 5:
        stderr.print(f"  … and {len(lines) - 5} more", markup=False, highlight=False)


def _print_summary_json(res, out, seed: int) -> None:
    from ..results import identify_to_dict
    from .common import capture_notes_json

    d = identify_to_dict(res)
    captures = list({id(c): c for f in res.fits for c in f.captures}.values())
    print_json({"out": str(out), "model": d["model"]["name"], "optimizer": d["optimizer"]["name"],
                "seed": seed, "units": d["units"],
                "conditions": [{"label": c["label"], "amplitude_V": c["amplitude_V"],
                                "frequency_Hz": c["frequency_Hz"], "metrics": c["metrics"],
                                "runtime_s": c["runtime_s"], "evaluations": c["evaluations"]}
                               for c in d["conditions"]],
                "failed": list(res.failed),
                "cell_counts": {"computed": res.cell_stats.computed, "reused": res.cell_stats.reused,
                                "failed": res.cell_stats.failed, "wall_time_s": res.cell_stats.wall_time_s},
                "capture_notes": capture_notes_json(captures)})


def _print_summary_table(res, title: str) -> None:
    from ..report.identify_report import summary_rows
    from ..report.tables import fmt

    u = res.unit
    table = new_table(title=title)
    for col in ("condition", f"rmse_{u}", "nrmse_pct", "r2", f"max_error_{u}", "runtime_s"):
        table.add_column(col, justify="right")
    for row in summary_rows(res):
        table.add_row(row["condition"], f"{row[f'rmse_{u}']:.4g}", f"{row['nrmse_pct']:.3g}", fmt(row['r2'], 5),
                      f"{row[f'max_error_{u}']:.4g}", f"{row['runtime_s']:.2f}")
    stdout.print(table)
