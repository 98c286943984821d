"""``hystfit compare``: models × optimizers × conditions (× runs), tables and figures as in the papers."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from .app import app, guarded
from .common import (Condition, DataArg, DropNonfinite, Fs, InputCol, NoHeader, OutputCol, OutputUnit, Recursive,
                     TimeCol, load_options, print_json, progress_bar, stdout)


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
    models: Annotated[str, typer.Option("--models", help="Comma-separated model names, or 'all'.")] = "pi,bw",
    opts: Annotated[str, typer.Option("--opts", help="Comma-separated optimizer names.")] = "auto",
    runs: Annotated[int, typer.Option("--runs", help="Independent seeded runs per cell.", min=1)] = 1,
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path("hystfit-compare"),
    seed: Annotated[int, typer.Option("--seed", help="Base seed; every run derives its own.")] = 0,
    jobs: Annotated[Optional[int], typer.Option("--jobs", "-j", help="Parallel processes (default: all cores).", min=1)] = None,
    pop: Annotated[Optional[int], typer.Option("--pop", help="Population size for optimizers that have one.")] = None,
    iters: Annotated[Optional[int], typer.Option("--iters", help="Iterations for optimizers that have them.")] = None,
    polish: Annotated[bool, typer.Option("--polish/--no-polish", help="Least-squares polish after global searches.")] = True,
    figures: Annotated[bool, typer.Option("--figures/--no-figures", help="Write the figures.")] = True,
    json_out: Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no summary table.")] = False,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing non-empty output directory.")] = False,
    time_col: TimeCol = None, input_col: InputCol = None, output_col: OutputCol = None, no_header: NoHeader = False,
    fs: Fs = None, drop_nonfinite: DropNonfinite = False, condition: Condition = None, output_unit: OutputUnit = None,
    recursive: Recursive = False,
) -> None:
    """Compare models and optimizers on the captures: every model × optimizer × condition (× runs).

    Writes OUT/compare.csv (one row per model, optimizer, condition, run), OUT/compare.md (paper-style
    tables and a ranking) and OUT/figures/.
    """
    from ..compare import compare as run_compare
    from ..io import load_captures, staged_output_dir
    from ..registry import models as model_registry
    from ..registry import optimizers as optimizer_registry
    from ..report.compare_report import compare_frame, write_compare_outputs
    from ..setup import make_optimizer

    model_names = model_registry.names() if models.strip().lower() == "all" else _names(models, "models")
    opt_names = _names(opts, "opts")
    for m in model_names:
        model_registry.get(m)
    opt_options = {}
    for o in opt_names:
        cls = optimizer_registry.get(o)
        inst = make_optimizer(cls, {}, pop=pop if pop is not None and "pop" in cls.__dataclass_fields__ else None,
                              iters=iters if iters is not None and "iters" in cls.__dataclass_fields__ else None)
        opt_options[o] = {k: v for k, v in inst.settings().items() if k in ("pop", "iters") and
                          ((k == "pop" and pop is not None) or (k == "iters" and iters is not None))}
    options = load_options(time_col, input_col, output_col, no_header, fs, drop_nonfinite, condition, output_unit)
    if figures:
        from ..report.render import preload

        preload()  # import matplotlib in a thread while the captures load and the fits run
    with staged_output_dir(out, force) as stage:
        captures = load_captures(data, options, recursive=recursive)
        with progress_bar(not quiet and not json_out, "compare") as cb:
            res = run_compare(captures, model_names, opt_names, runs=runs, seed=seed, jobs=jobs, polish=polish,
                              optimizer_options=opt_options, progress=cb)
        write_compare_outputs(res, stage, make_figures=figures, n_jobs=jobs)
    df = compare_frame(res)
    u = res.unit
    if json_out:
        ok = df[df["error"] == ""] if "error" in df else df
        best = ok[ok["best_run"] == True] if "best_run" in ok else ok  # noqa: E712
        print_json({"out": str(out), "models": model_names, "optimizers": opt_names, "runs": runs,
                    "cells": [{k: (None if isinstance(v, float) and v != v else v) for k, v in row.items()}
                              for row in best[["model", "optimizer", "condition", "amplitude_V", "frequency_Hz",
                                               f"rmse_{u}", "r2", "j", "runtime_s", "evaluations"]].to_dict("records")],
                    "failed": [{"model": c.model, "optimizer": c.optimizer, "condition": c.label, "error": c.error}
                               for c in res.cells if not c.ok]})
        return
    if quiet:
        return
    t = Table(title=f"mean over conditions (best run per cell) — written to {out}")
    for col in ("model", "optimizer", f"mean rmse_{u}", "worst r2", "failed cells", "total time s"):
        t.add_column(col, justify="right")
    for m in model_names:
        for o in opt_names:
            cells = [c for c in res.cells if c.model == m and c.optimizer == o]
            okc = [c for c in cells if c.ok]
            rm = sum(c.best.metrics[f"rmse_{u}"] for c in okc) / len(okc) if okc else float("nan")
            r2 = min((c.best.metrics["r2"] for c in okc), default=float("nan"))
            t.add_row(m, o, f"{rm:.4g}", f"{r2:.5f}", str(len(cells) - len(okc)), f"{sum(c.runtime_s for c in cells):.2f}")
    stdout.print(t)
