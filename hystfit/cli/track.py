"""``hystfit track``: closed-loop tracking simulation (ff, pid, ff+pid, smc) with a comparison table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..errors import ConfigError
from .app import command
from .common import (Condition, OutDir, OutputArgs, OutputUnit, Seed, TimeCol, new_table, parse_condition, parse_key_values,
                     phase, print_json, progress_bar, start_figures, stderr, stdout, writing)

# --noise is in µm (as in 'hystfit synth'); the loop runs in the parameter file's unit.
UM_PER_UNIT_INV = {"nm": 1e3, "um": 1.0, "mm": 1e-3, "m": 1e-6}
from .invert import (InitialVoltage, MaxSlew, Method, Multi, Offset, Sine, Steps, TargetArg, TargetCol, TargetFs,
                     Triangle, Vmax, Vmin, build_target, command_text)


@command()
def track(
    params: Annotated[Path, typer.Argument(help="params.json of the controller's model (feedforward inverse, "
                                                "nominal plant).", show_default=False)],
    target: TargetArg = None,
    controller: Annotated[str, typer.Option("--controller", "-c", help="ff, pid, ff+pid, smc or smc-noinv (sliding "
                                                                       "mode without inverse compensation); a comma "
                                                                       "list compares them, e.g. pid,ff,ff+pid.")] = "ff+pid",
    plant: Annotated[Optional[Path], typer.Option("--plant", help="params.json of the plant (default: PARAMS "
                                                                  "itself); another model tests the inverse "
                                                                  "realistically.")] = None,
    noise: Annotated[float, typer.Option("--noise", help="Measurement noise σ in µm (Gaussian), as in 'hystfit synth'; "
                                                         "converted to the parameter file's unit.")] = 0.0,
    seed: Seed = 0,
    kp: Annotated[Optional[float], typer.Option("--kp", help="Proportional gain (V per unit); with --ki/--kd "
                                                             "replaces the automatic tuning.")] = None,
    ki: Annotated[Optional[float], typer.Option("--ki", help="Integral gain (V per unit·s).")] = None,
    kd: Annotated[Optional[float], typer.Option("--kd", help="Derivative gain (V·s per unit), on the filtered "
                                                             "measurement.")] = None,
    bandwidth: Annotated[Optional[float], typer.Option("--bandwidth", help="Closed-loop bandwidth (Hz) of the "
                                                                           "automatic PID and of the sliding mode "
                                                                           "(default: automatic, ≤ fs/20).")] = None,
    anti_windup: Annotated[str, typer.Option("--anti-windup", help="backcalc or clamp.")] = "backcalc",
    smc_option: Annotated[Optional[list[str]], typer.Option("--smc-option", help="Sliding-mode design KEY=VALUE "
                                                                                 "(paper 003): eps (V/s), alpha (1/V), "
                                                                                 "k (1/s), sliding_poles=[z,...], "
                                                                                 "observer_poles=[z,...] (repeatable).")] = None,
    measure_bandwidth: Annotated[bool, typer.Option("--measure-bandwidth", help="Also measure each controller's "
                                                                               "tracking (−3 dB) and disturbance-"
                                                                               "rejection (0 dB) bandwidth (paper 003) "
                                                                               "with sines of the target's amplitude; "
                                                                               "writes OUT/bandwidth.json.")] = False,
    sine: Sine = None, triangle: Triangle = None, steps: Steps = None, multi: Multi = False, offset: Offset = 0.0,
    fs: TargetFs = None, condition: Condition = None, method: Method = "interpolate",
    initial_voltage: InitialVoltage = None, vmin: Vmin = None, vmax: Vmax = None, max_slew: MaxSlew = None,
    time_col: TimeCol = None, target_col: TargetCol = None, output_unit: OutputUnit = None,
    out: OutDir = Path("hystfit-track"),
    fmt: Annotated[str, typer.Option("--format", help="Time-series file format: csv or parquet.")] = "csv",
    output: OutputArgs = OutputArgs(),
) -> None:
    """Simulate the closed loop around an identified plant and compare controllers (paper 002 Tables 4–6).

    Writes OUT/<controller>.csv (time, reference, displacement, measured, voltage, command, error),
    OUT/summary.json, OUT/report.md and OUT/plots/. Method and options: docs/invert.md.
    """
    start_figures(output)  # the figure server (forked at the start) draws them: matplotlib loads meanwhile
    from ..io import staged_output_dir
    from ..report.track_report import write_track_outputs
    from ..results import load_params
    from ..track import check_smc_options, measure_bandwidths, parse_controllers, track as run_track

    names = parse_controllers(controller)
    smc_opts = check_smc_options(parse_key_values(smc_option or [], "--smc-option"))
    _check_options(names, fmt, anti_windup, method, noise, bandwidth, (kp, ki, kd))
    pf = load_params(params)
    plant_pf = load_params(plant) if plant is not None else None
    cond = parse_condition(condition)
    tgt = build_target(pf, target, sine=sine, triangle=triangle, steps=steps, multi=multi, offset=offset, fs=fs,
                       time_col=time_col, target_col=target_col, output_unit=output_unit)
    cmd = command_text("track", params, target, controller=controller, plant=plant, noise=noise or None,
                       seed=seed or None, kp=kp, ki=ki, kd=kd, bandwidth=bandwidth,
                       anti_windup=None if anti_windup == "backcalc" else anti_windup, sine=sine,
                       triangle=triangle, steps=steps, multi=multi, offset=offset, fs=fs, condition=condition,
                       method=method, initial_voltage=initial_voltage, vmin=vmin, vmax=vmax, max_slew=max_slew,
                       time_col=time_col, target_col=target_col, output_unit=output_unit, out=out,
                       smc_option=" ".join(smc_option or []) or None, measure_bandwidth=measure_bandwidth)
    with staged_output_dir(out, output.force, inputs=[p for p in (params, target, plant) if p is not None]) as stage:
        with progress_bar(output.chatty, "track") as cb:
            res = run_track(pf, tgt, names, plant_pf=plant_pf, method=method, condition=cond,
                            initial_voltage=initial_voltage, vmin=vmin, vmax=vmax, max_slew=max_slew,
                            noise_std=noise * UM_PER_UNIT_INV[pf.unit], seed=seed, kp=kp, ki=ki, kd=kd, bandwidth_Hz=bandwidth,
                            anti_windup=anti_windup, smc_options=smc_opts, progress=cb)
        bw = None
        if measure_bandwidth:
            with phase(output.chatty, "measuring the bandwidths"):
                bw = measure_bandwidths(pf, names, amplitude=float(tgt.y.max() - tgt.y.min()), offset=float(tgt.y.min()),
                                        fs=1.0 / tgt.dt, plant_pf=plant_pf, method=method, condition=cond,
                                        vmin=vmin, vmax=vmax, max_slew=max_slew,
                                        noise_std=noise * UM_PER_UNIT_INV[pf.unit], seed=seed, kp=kp, ki=ki, kd=kd,
                                        bandwidth_Hz=bandwidth, anti_windup=anti_windup, smc_options=smc_opts)
        with writing(out, output):
            summary = write_track_outputs(res, stage, make_plots=output.plots, fmt_ext=fmt, command=cmd, bandwidth=bw)
            if bw is not None:
                summary["bandwidth"] = bw
    for run in res.runs:
        if run.limit_spans:
            n = sum(s.n for s in run.limit_spans)
            stderr.print(f"warning: {run.controller}: the voltage limits acted on {n} sample(s) in "
                         f"{len(run.limit_spans)} span(s); see the report", markup=False, highlight=False)
    for note in res.notes:  # a loop that does not hold the target: said even with --json or --quiet
        if note.startswith("warning: "):
            stderr.print(note, markup=False, highlight=False, soft_wrap=True)
    if output.json_out:
        print_json(dict(summary, out=str(out)))
        return
    if output.quiet:
        return
    _print_tables(res, bw, out)
    for note in res.notes:
        if not note.startswith("warning: "):
            stderr.print(f"note: {note}", markup=False, highlight=False, style="dim")


def _check_options(names, fmt: str, anti_windup: str, method: str, noise: float, bandwidth, gains) -> None:
    """One-line errors (exit 2) for option values the library would not accept or would ignore."""
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"--format {fmt!r}: choose csv or parquet")
    if anti_windup not in ("backcalc", "clamp"):
        raise ConfigError(f"--anti-windup {anti_windup!r}: choose backcalc or clamp")
    if method not in ("interpolate", "nearest"):
        raise ConfigError(f"--method {method!r}: choose interpolate or nearest")
    if not noise >= 0:
        raise ConfigError(f"--noise {noise:g}: the noise σ must be >= 0 (µm)")
    if bandwidth is not None and not bandwidth > 0:
        raise ConfigError(f"--bandwidth {bandwidth:g}: must be > 0 Hz")
    if any(g is not None for g in gains) and not any(n in ("pid", "ff+pid") for n in names):
        raise ConfigError("--kp/--ki/--kd apply to the pid and ff+pid controllers; add one to --controller")


def _print_tables(res, bw, out) -> None:
    """The comparison tables (tracking, steps, bandwidths) on stdout."""
    from ..report.track_report import comparison_headers, comparison_text_rows

    titles = (f"tracking error, plant {res.plant_model_name} ({res.plant_path}); outputs in {out}",
              "step response (paper 002 Table 6; – = not settled)")
    for title, cols, rows in zip(titles, comparison_headers(res), comparison_text_rows(res)):
        if not cols:
            continue
        t = new_table(title=title)
        for i, c in enumerate(cols):
            t.add_column(c, justify="left" if i == 0 else "right", no_wrap=i == 0)
        for row in rows:
            t.add_row(*row)
        stdout.print(t)
    if bw is not None:
        t = new_table(title="bandwidths (paper 003; 0 = none on the grid, – = beyond it)")
        for i, c in enumerate(("controller", "tracking −3 dB (Hz)", "disturbance rejection 0 dB (Hz)")):
            t.add_column(c, justify="left" if i == 0 else "right")
        for c, v in bw["controllers"].items():
            t.add_row(c, *(f"{x:.4g}" if x == x else "–" for x in (v["tracking_bandwidth_Hz"],
                                                                     v["disturbance_bandwidth_Hz"])))
        stdout.print(t)
