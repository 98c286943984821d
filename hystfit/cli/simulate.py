"""``hystfit simulate``: predictions of an identified model on other captures, with metrics where measured."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .app import command
from .common import (CaptureArgs, DataArg, Method, OutputArgs, new_table, phase, print_json, print_note, start_figures,
                     stdout, writing)


@command()
def simulate(
    params: Annotated[Path, typer.Argument(help="params.json written by 'hystfit identify'.", show_default=False)],
    data: DataArg,
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path("hystfit-sim"),
    method: Method = "interpolate",
    align_offset: Annotated[bool, typer.Option("--align-offset", help="Fit and add a constant offset per capture "
                                               "(e.g. a sensor zero that moved between recording days); reported "
                                               "in the table, report.md and the JSON.")] = False,
    fmt: Annotated[str, typer.Option("--format", help="Prediction file format: csv or parquet.")] = "csv",
    output: OutputArgs = OutputArgs(),
    capture: CaptureArgs = CaptureArgs(),
) -> None:
    """Predict the output of captures with the identified look-up table (out-of-sample validation).

    Writes per capture OUT/<name>_prediction.csv (time_s, voltage_V, predicted, measured, residual),
    OUT/<name>_metrics.json where the capture has a measured output, plots, and OUT/report.md.
    """
    start_figures(output)  # the figure server (forked at the start) draws them: matplotlib loads meanwhile
    from ..errors import ConfigError
    from ..io import load_captures, staged_output_dir
    from ..report.simulate_report import write_simulate_outputs
    from ..predict import predict_capture
    from ..report.tables import distinct_names
    from ..report.tables import fmt as num
    from ..results import load_params

    if method not in ("nearest", "interpolate"):
        raise ConfigError(f"--method {method!r}: choose interpolate or nearest")
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"--format {fmt!r}: choose csv or parquet")
    pf = load_params(params)
    options = capture.load_options(require_output=False)
    with staged_output_dir(out, output.force, inputs=[params, *data]) as stage:
        with phase(output.chatty, "loading the captures"):
            captures = load_captures(data, options, recursive=capture.recursive)
        with phase(output.chatty, f"predicting {len(captures)} capture(s)"):
            preds = [predict_capture(pf, c, method, align_offset=align_offset) for c in captures]
        with writing(out, output):
            summary = write_simulate_outputs(pf, preds, stage, fmt=fmt, make_plots=output.plots)
    for s in summary:
        for note in s["notes"]:
            print_note(Path(s["capture"]).name, note)
    if output.json_out:
        print_json({"out": str(out), "params": str(params), "captures": summary})
        return
    if output.quiet:
        return
    u = pf.unit
    t = new_table(title=f"{pf.model_name}: predictions written to {out}")
    cols = ["capture", "cells", f"rmse_{u}", f"bias_{u}", "r2", f"max_error_{u}"] + ([f"offset_{u}"] if align_offset
                                                                                   else [])
    for i, col in enumerate(cols):
        t.add_column(col, justify="right", no_wrap=i == 0, overflow="fold")
    for s, name in zip(summary, distinct_names([x["capture"] for x in summary])):
        m = s.get("metrics") or {}
        t.add_row(name, ", ".join(f"{lab}×{w:.2f}" for lab, w in s["cells"]), num(m.get(f"rmse_{u}")),
                  num(m.get(f"bias_{u}")), num(m.get("r2"), 5), num(m.get(f"max_error_{u}")),
                  *([num(s[f"offset_{u}"])] if align_offset else []))
    stdout.print(t)
