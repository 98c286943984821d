"""``hystfit identify``: fit a model per operating condition and write parameters, reports and plots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from .app import app, guarded
from .common import (Condition, DataArg, DropNonfinite, Fs, InputCol, NoHeader, OutputCol, OutputUnit, Recursive,
                     TimeCol, load_options, parse_key_values, print_json, progress_bar, stderr, stdout)


@app.command()
@guarded
def identify(
    data: DataArg,
    model: Annotated[str, typer.Option("--model", "-m", help="Model name (see 'hystfit models').")] = "pi",
    opt: Annotated[str, typer.Option("--opt", "-o", help="Optimizer name (see 'hystfit optimizers'); auto = exact linear solves + search over the nonlinear parameters.")] = "auto",
    out: Annotated[Path, typer.Option("--out", help="Output directory (refused if it exists and is not empty, unless --force).")] = Path("hystfit-out"),
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random choice; each run derives its own.")] = 0,
    pop: Annotated[Optional[int], typer.Option("--pop", help="Population size of population-based optimizers.")] = None,
    iters: Annotated[Optional[int], typer.Option("--iters", help="Iterations of iterative optimizers.")] = None,
    runs: Annotated[int, typer.Option("--runs", help="Independent seeded runs per condition; the best is kept.", min=1)] = 1,
    polish: Annotated[bool, typer.Option("--polish/--no-polish", help="Least-squares polish after the global search.")] = True,
    jobs: Annotated[Optional[int], typer.Option("--jobs", "-j", help="Parallel processes over conditions and runs (default: all cores; the numbers do not depend on it).", min=1)] = None,
    global_fit: Annotated[bool, typer.Option("--global", help="One parameter set for all captures instead of one per condition.")] = False,
    bounds: Annotated[Optional[list[str]], typer.Option("--bounds", help="Override a bound: NAME=LOWER:UPPER (repeatable).")] = None,
    model_option: Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option KEY=VALUE, e.g. n_operators=12 (repeatable).")] = None,
    opt_option: Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE, e.g. stall_iter=50 (repeatable).")] = None,
    plots: Annotated[bool, typer.Option("--plots/--no-plots", help="Write loop, time-series and convergence figures.")] = True,
    json_out: Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no summary table.")] = False,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing non-empty output directory.")] = False,
    time_col: TimeCol = None, input_col: InputCol = None, output_col: OutputCol = None, no_header: NoHeader = False,
    fs: Fs = None, drop_nonfinite: DropNonfinite = False, condition: Condition = None, output_unit: OutputUnit = None,
    recursive: Recursive = False,
) -> None:
    """Identify MODEL on the captures, one parameter set per operating condition (look-up table).

    Writes OUT/params.json, OUT/report.csv, OUT/report.md and OUT/plots/.
    """
    from ..identify import identify as run_identify
    from ..io import load_captures, staged_output_dir
    from ..params import parse_bound_overrides
    from ..registry import models, optimizers
    from ..report.identify_report import summary_rows, write_identify_outputs
    from ..results import identify_to_dict
    from ..setup import make_model, make_optimizer

    model_cls = models.get(model)
    opt_cls = optimizers.get(opt)
    mopts = parse_key_values(model_option or [], "--model-option")
    oopts = parse_key_values(opt_option or [], "--opt-option")
    m = make_model(model_cls, mopts)
    o = make_optimizer(opt_cls, oopts, pop=pop, iters=iters)
    bnds = parse_bound_overrides(bounds or [])
    options = load_options(time_col, input_col, output_col, no_header, fs, drop_nonfinite, condition, output_unit)
    if plots:
        from ..report.render import preload

        preload()  # import matplotlib in a thread while the captures load and the fit runs
    with staged_output_dir(out, force) as stage:
        captures = load_captures(data, options, recursive=recursive)
        if not quiet:
            for c in captures:
                for note in c.notes:
                    stderr.print(f"[dim]{c.name}: {note}[/dim]")
        with progress_bar(not quiet and not json_out, f"identify {model_cls.name} / {opt_cls.name}") as cb:
            res = run_identify(captures, m, o, seed=seed, runs=runs, polish=polish, global_fit=global_fit,
                               bounds=bnds, progress=cb, model_options=mopts, jobs=jobs)
        write_identify_outputs(res, stage, make_plots=plots, n_jobs=jobs)
    if json_out:
        d = identify_to_dict(res)
        print_json({"out": str(out), "model": d["model"]["name"], "optimizer": d["optimizer"]["name"],
                    "seed": seed, "units": d["units"],
                    "conditions": [{"label": c["label"], "amplitude_V": c["amplitude_V"],
                                    "frequency_Hz": c["frequency_Hz"], "metrics": c["metrics"],
                                    "runtime_s": c["runtime_s"], "evaluations": c["evaluations"]}
                                   for c in d["conditions"]]})
        return
    if quiet:
        return
    u = res.unit
    table = Table(title=f"{model_cls.name} / {opt_cls.name} — {len(res.fits)} condition(s), output in {out}")
    for col in ("condition", f"rmse_{u}", "nrmse_pct", "r2", f"max_error_{u}", "runtime_s"):
        table.add_column(col, justify="right")
    for row in summary_rows(res):
        table.add_row(row["condition"], f"{row[f'rmse_{u}']:.4g}", f"{row['nrmse_pct']:.3g}", f"{row['r2']:.5f}",
                      f"{row[f'max_error_{u}']:.4g}", f"{row['runtime_s']:.2f}")
    stdout.print(table)
