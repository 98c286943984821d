"""``hystfit invert``: feedforward voltages for a desired trajectory, with a predicted tracking error.

The target options (a file or ``--sine/--triangle/--steps/--multi``) are shared with
``hystfit track`` (:func:`build_target`).
"""

from __future__ import annotations

import shlex
import shutil
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..errors import ConfigError, OutputError
from .app import command
from .common import (Condition, Method, OutputArgs, OutputUnit, TimeCol, new_table, parse_condition, print_json,
                     progress_bar, start_figures, stderr, stdout, writing)

TargetArg = Annotated[Optional[Path], typer.Argument(
    help="Target file (CSV/TXT/Parquet): time and desired displacement (target, reference, displacement_um, y, ...). "
         "Omit when using --sine, --triangle, --steps or --multi.", show_default=False)]
Sine = Annotated[Optional[str], typer.Option(
    "--sine", help="Sine of paper 002 eq. 16, from OFFSET to OFFSET+AMP: 'AMP,FREQ_HZ[,CYCLES]' (AMP peak-to-peak in "
                   "the parameter file's unit, default 5 cycles).")]
Triangle = Annotated[Optional[str], typer.Option(
    "--triangle", help="Triangle OFFSET → OFFSET+AMP → OFFSET: 'AMP,FREQ_HZ[,CYCLES]'.")]
Steps = Annotated[Optional[str], typer.Option(
    "--steps", help="Step-and-hold levels relative to OFFSET, 'L1,L2,...', optionally followed by '@HOLD_S' (hold "
                    "of each level, default 0.2 s), e.g. '10' (paper 002 Table 6) or '10,4,8@0.1'.")]
Multi = Annotated[bool, typer.Option(
    "--multi", help="Paper 002's sequence: 10/8/6/4/2 at 0.5/1/2/5/10 Hz, one cycle each.")]
Offset = Annotated[float, typer.Option(
    "--offset", help="Start level of a built-in trajectory (parameter file's unit); keep the target inside the "
                     "identified stroke.")]
TargetFs = Annotated[Optional[float], typer.Option(
    "--fs", help="Sample rate (Hz) of a built-in trajectory (default: the identification data's) or of a target file "
                 "without a time column.")]
TargetCol = Annotated[Optional[str], typer.Option("--target-col", help="Target column of a file: name or 0-based index.")]
InitialVoltage = Annotated[Optional[float], typer.Option(
    "--initial-voltage", help="Voltage (V) the stage rests at before the target (default: the rest voltage of the "
                              "target's first sample).")]
Vmin = Annotated[Optional[float], typer.Option("--vmin", help="Lower voltage limit (V); default: identification "
                                                              "range − 10 %.")]
Vmax = Annotated[Optional[float], typer.Option("--vmax", help="Upper voltage limit (V); default: identification "
                                                              "range + 10 %.")]
MaxSlew = Annotated[Optional[float], typer.Option("--max-slew", help="Slew-rate limit of the amplifier (V/s).")]


def _numbers(text: str, option: str, n_min: int, n_max: int, example: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise ConfigError(f"{option} {text!r}: expected numbers separated by commas, e.g. {example}") from None
    if not n_min <= len(vals) <= n_max:
        raise ConfigError(f"{option} {text!r}: expected {n_min}–{n_max} numbers, e.g. {example}")
    return vals


def _periodic(text: str, option: str) -> tuple[float, float, float]:
    vals = _numbers(text, option, 2, 3, "10,1 or 10,1,5")
    amp, freq = vals[0], vals[1]
    cycles = vals[2] if len(vals) == 3 else 5.0
    for name, v in (("amplitude", amp), ("frequency", freq), ("cycles", cycles)):
        if not v > 0:
            raise ConfigError(f"{option} {text!r}: the {name} must be > 0")
    return amp, freq, cycles


def build_target(pf, target: Optional[Path], *, sine: Optional[str], triangle: Optional[str], steps: Optional[str],
                 multi: bool, offset: float, fs: Optional[float], time_col: Optional[str], target_col: Optional[str],
                 output_unit: Optional[str]):
    """The :class:`hystfit.invert.Target` selected by the command line (exactly one source)."""
    from .. import invert as inv

    given = [name for name, v in (("TARGET", target), ("--sine", sine), ("--triangle", triangle), ("--steps", steps),
                                  ("--multi", multi or None)) if v is not None]
    if len(given) != 1:
        raise ConfigError("give exactly one target: a TARGET file or one of --sine, --triangle, --steps, --multi"
                          + (f" (got {', '.join(given)})" if given else ""))
    if fs is not None and not fs > 0:
        raise ConfigError(f"--fs {fs:g}: the sample rate must be positive (Hz)")
    if output_unit is not None and output_unit not in ("nm", "um", "mm", "m"):
        raise ConfigError(f"--output-unit {output_unit!r}: choose one of nm, um, mm, m")
    if target is not None:
        from .common import parse_col

        return inv.load_target(target, fs=fs, time_col=parse_col(time_col), target_col=parse_col(target_col),
                               unit=output_unit or pf.unit)
    for opt, val in (("--time-col", time_col), ("--target-col", target_col), ("--output-unit", output_unit)):
        if val is not None:
            raise ConfigError(f"{opt} applies to a TARGET file only")
    rate = fs if fs is not None else 1.0 / min(c.scale.dt for c in pf.cells)
    unit = pf.unit
    if sine is not None:
        a, f, n = _periodic(sine, "--sine")
        return inv.sine_target(a, f, n, rate, offset=offset, unit=unit, source=f"--sine {sine}")
    if triangle is not None:
        a, f, n = _periodic(triangle, "--triangle")
        return inv.triangle_target(a, f, n, rate, offset=offset, unit=unit, source=f"--triangle {triangle}")
    if steps is not None:
        levels_text, _, hold_text = steps.partition("@")
        levels = _numbers(levels_text, "--steps", 1, 1000, "10 or 10,4,8@0.1")
        hold = 0.2
        if hold_text:
            try:
                hold = float(hold_text)
            except ValueError:
                raise ConfigError(f"--steps {steps!r}: the hold after '@' must be a number of seconds") from None
            if not hold > 0:
                raise ConfigError(f"--steps {steps!r}: the hold must be > 0 s")
        return inv.steps_target(levels, hold, rate, offset=offset, unit=unit, source=f"--steps {steps}")
    return inv.multi_target(fs=rate, offset=offset, unit=unit, source="--multi")


def limit_warnings(res) -> list[str]:
    """One stderr line per kind of limiting (never silent)."""
    lines = []
    for spans, what in ((res.clip_spans, "clipped to the voltage limits"), (res.slew_spans, "slew-rate limited")):
        if spans:
            n = sum(s.n for s in spans)
            first = spans[0]
            lines.append(f"warning: {n} sample(s) in {len(spans)} span(s) {what} (first {first.start_s:.6g}–"
                         f"{first.stop_s:.6g} s, worst {first.worst_V:.4g} V); see the report")
    return lines


OUTPUT_SUFFIXES = (".csv", ".tsv", ".txt", ".parquet", ".pq")


@command()
def invert(
    params: Annotated[Path, typer.Argument(help="params.json written by 'hystfit identify'.", show_default=False)],
    out: Annotated[Path, typer.Option("--out", help="Voltage file to write: .csv, .tsv, .txt or .parquet "
                                                    "(time_s, voltage_V, predicted_displacement_<unit>).",
                                      show_default=False)],
    target: TargetArg = None,
    sine: Sine = None, triangle: Triangle = None, steps: Steps = None, multi: Multi = False, offset: Offset = 0.0,
    fs: TargetFs = None, condition: Condition = None, method: Method = "interpolate",
    initial_voltage: InitialVoltage = None, vmin: Vmin = None, vmax: Vmax = None, max_slew: MaxSlew = None,
    report_dir: Annotated[Optional[Path], typer.Option("--report-dir", help="Report directory (default: "
                                                       "<out stem>_report next to the output).")] = None,
    time_col: TimeCol = None, target_col: TargetCol = None, output_unit: OutputUnit = None,
    output: OutputArgs = OutputArgs(),
) -> None:
    """Voltages that make the identified model follow TARGET, and the tracking error they predict.

    Writes OUT and a report directory (report.md, report.json, plots/tracking.png, and
    plots/tracking_detail.png for a long target). Clipping to the voltage limits and slew-rate
    limiting are reported with their time spans. Method and options: docs/invert.md.
    """
    start_figures(output)  # the figure server (forked at the start) draws them: matplotlib loads meanwhile
    from ..invert import invert_target
    from ..io import check_writable_file, staged_output_dir, write_table
    from ..report.invert_report import write_invert_report
    from ..results import load_params

    out = Path(out)
    if out.suffix.lower() not in OUTPUT_SUFFIXES:
        raise ConfigError(f"--out {out}: unsupported file type {out.suffix or '(no suffix)'!r}; use one of "
                          f"{', '.join(OUTPUT_SUFFIXES)}")
    if out.is_dir():
        raise OutputError(f"{out}: is a directory; --out takes a file name such as voltages.csv")
    if out.exists() and not output.force:
        raise OutputError(f"{out}: exists; pass --force to replace it or choose another --out")
    check_writable_file(out)
    if method not in ("interpolate", "nearest"):
        raise ConfigError(f"--method {method!r}: choose interpolate or nearest")
    rdir = Path(report_dir) if report_dir is not None else out.parent / f"{out.stem}_report"
    if rdir.resolve() == out.resolve():
        raise ConfigError("--report-dir must differ from --out")
    pf = load_params(params)
    cond = parse_condition(condition)
    tgt = build_target(pf, target, sine=sine, triangle=triangle, steps=steps, multi=multi, offset=offset, fs=fs,
                       time_col=time_col, target_col=target_col, output_unit=output_unit)
    cmd = command_text("invert", params, target, out=out, sine=sine, triangle=triangle, steps=steps, multi=multi,
                       offset=offset, fs=fs, condition=condition, method=method, initial_voltage=initial_voltage,
                       vmin=vmin, vmax=vmax, max_slew=max_slew, report_dir=report_dir, time_col=time_col,
                       target_col=target_col, output_unit=output_unit)
    existed = rdir.exists()
    with staged_output_dir(rdir, output.force, inputs=[p for p in (params, target) if p is not None]) as stage:
        with progress_bar(output.chatty, "invert") as cb:
            res = invert_target(pf, tgt, method=method, condition=cond, initial_voltage=initial_voltage, vmin=vmin,
                                vmax=vmax, max_slew=max_slew, progress=cb)
        with writing(rdir, output):
            summary = write_invert_report(res, stage, make_plots=output.plots, command=cmd, output_file=str(out))
    try:
        write_table(out, res.to_table())
    except BaseException:
        if not existed:
            shutil.rmtree(rdir, ignore_errors=True)
        raise
    for line in limit_warnings(res):
        stderr.print(line, markup=False, highlight=False)
    if output.json_out:
        print_json(dict(summary, out=str(out), report_dir=str(rdir)))
        return
    if output.quiet:
        return
    from ..invert import condition_text
    from ..report.plots import display_unit
    from ..report.tables import fmt

    u, du = res.unit, display_unit(res.unit)
    t = new_table(title=f"{res.model_name} feedforward → {out} (report: {rdir}); predicted error")
    for i, col in enumerate(("segment", "cells × weight", f"RMSE ({du})", "RMSE %", f"max ({du})", "max %")):
        t.add_column(col, justify="left" if i < 2 else "right")
    rows = list(zip((ch.segment.label for ch in res.choices), (condition_text(ch) for ch in res.choices),
                    res.segment_metrics))
    if len(res.choices) > 1:
        rows.append(("all", "", res.metrics))
    for label, cells, m in rows:
        t.add_row(label, cells, fmt(m[f"rmse_{u}"], 3), fmt(m["rmse_pct_of_stroke"], 3), fmt(m[f"max_error_{u}"], 3),
                  fmt(m["max_error_pct_of_stroke"], 3))
    stdout.print(t)
    stdout.print(f"voltage {res.voltage_V.min():.4g} … {res.voltage_V.max():.4g} V, initial {res.initial_voltage_V:.4g} V; "
                 "predicted error from the identified model (not a measurement)", markup=False, highlight=False)
    floor = res.fit_rmse()
    if floor == floor:  # not NaN: the cells record their fit
        stdout.print(f"the cells used fit their identification data to {fmt(floor, 3)} {du} RMS: a tracking error "
                     "measured on the stage is of that order", markup=False, highlight=False)
    for note in res.notes:
        stderr.print(f"note: {note}", markup=False, highlight=False, style="dim")


def command_text(command: str, params: Path, target: Optional[Path], **options) -> str:
    """A shell command reproducing this run (options at their defaults omitted)."""
    parts = ["hystfit", command, str(params)] + ([str(target)] if target is not None else [])
    defaults = {"offset": 0.0, "method": "interpolate", "multi": False}
    for key, val in options.items():
        if val is None or val is False or defaults.get(key, object()) == val:
            continue
        flag = "--" + key.replace("_", "-")
        parts += [flag] if val is True else [flag, str(val)]
    return " ".join(shlex.quote(p) for p in parts)
