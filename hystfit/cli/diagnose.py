"""``hystfit diagnose``: where the model misses, which unmodelled effect causes it, how far it shrinks."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Optional

import typer

from .app import command
from .common import (CaptureArgs, DataArg, ExecutorArgs, FigureOutputArgs, OutDir, PerCondition, Seed, cell_run,
                     jobs_option, load_for_command, new_table, parse_key_values, print_cell_summary, print_json, progress_bar,
                     start_figures, stderr, stdout, writing)


DiagnoseJobs = jobs_option("Parallel processes for the base fits of --per-condition (the numbers do not depend on "
                           "it).", show_default="1")


@dataclass(frozen=True)
class DiagnoseExecutorArgs(ExecutorArgs):
    """:class:`ExecutorArgs` with diagnose's own ``--jobs`` (the base fits of ``--per-condition``; one by default)."""

    jobs: DiagnoseJobs = None


def _parse_effects(value: Optional[str]) -> list[str] | None:
    if value is None:
        return None
    names = [v.strip() for v in value.split(",") if v.strip()]
    if not names:
        from ..errors import ConfigError

        raise ConfigError("--effects: give at least one effect name, e.g. --effects dynamics,creep")
    return names


@command()
def diagnose(
    data: DataArg,
    model: Annotated[str, typer.Option("--model", "-m", help="Base model: a name or BASE+BLOCK+... (see 'hystfit models').")] = "pi",
    opt: Annotated[str, typer.Option("--opt", "-o", help="Optimizer of the base fits (see 'hystfit optimizers').")] = "auto",
    out: OutDir = Path("hystfit-diagnose"),
    per_condition: PerCondition = False,
    effects: Annotated[Optional[str], typer.Option("--effects", help="Candidate effects, comma-separated (default: dynamics,creep,asymmetry,drift,delay).")] = None,
    seed: Seed = 0,
    execution: DiagnoseExecutorArgs = DiagnoseExecutorArgs(),
    fit_fraction: Annotated[float, typer.Option("--fit-fraction", help="Share of every capture used to fit, 0.1–0.9; the rest is held out (where whole captures are held out — rising sines at three or more frequencies — it applies to the captures split in time and to the temporal check).")] = 0.6,
    threshold: Annotated[float, typer.Option("--threshold", help="Minimum held-out reduction for naming an effect.")] = 0.3,
    max_effects: Annotated[int, typer.Option("--max-effects", help="How many effects may be named, in order (>= 1).")] = 3,
    model_option: Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option KEY=VALUE (repeatable).")] = None,
    opt_option: Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE (repeatable).")] = None,
    output: FigureOutputArgs = FigureOutputArgs(),
    capture: CaptureArgs = CaptureArgs(),
) -> None:
    """Diagnose the gap between MODEL and the captures: noise floor, where it lies, which unmodelled
    effect (dynamics, creep, asymmetry, drift, delay) causes it, and how much of it each removes on
    held-out data.

    Writes OUT/diagnosis.json, OUT/diagnosis.md and OUT/figures/.
    """
    start_figures(output, behind=True)  # its selection steps keep every core busy; the figures wait for the gaps
    from ..diagnose import DiagnoseSettings, fit_recommended
    from ..seeds import check_seed
    from ..parallel import CellStats
    from ..diagnose import diagnose as run_diagnose
    from ..io import staged_output_dir
    from ..registry import optimizers
    from ..report.diagnose_report import write_diagnose_outputs
    from ..report.diagnose_report import start_figures as start_diagnose_figures, start_where_figures
    from ..factory import make_model, make_optimizer

    opt_cls = optimizers.get(opt)
    mopts = parse_key_values(model_option or [], "--model-option")
    m = make_model(model, mopts)
    o = make_optimizer(opt_cls, parse_key_values(opt_option or [], "--opt-option"))
    names = _parse_effects(effects)
    settings = DiagnoseSettings(fit_fraction=fit_fraction, threshold=threshold, max_effects=max_effects)
    check_seed(seed)
    options = capture.load_options()
    quiet, json_out, resume = output.quiet, output.json_out, execution.resume
    stats = CellStats()
    with cell_run(out, execution, not quiet) as cr, staged_output_dir(out, output.force, inputs=data, resume=execution.resume) as stage:
        from .._warm import STEPS

        # the base fits and the effects' kernels run here: numba and scipy.optimize load meanwhile
        captures = load_for_command(data, options, output, recursive=capture.recursive, ahead=STEPS)
        early = []  # the where-figures, drawn by the figure server while the effects are tested

        def on_where(where_data) -> None:
            early.append(start_where_figures(where_data, stage / "figures"))

        try:
            with progress_bar(output.chatty, f"diagnose {m.name}") as cb:
                d = run_diagnose(captures, m, o, seed=seed, per_condition=per_condition, effects=names,
                                 settings=settings, progress=cb, executor=cr.pool(default_jobs=1), store=cr.store,
                                 resume=resume, stats=stats, on_where=on_where if output.plots else None)
            d = replace(d, given_options=dict(mopts))
        except BaseException:
            for f in early:
                f.cancel()
            raise
        # the other figures are drawn by the figure server while the recommended model is fitted here
        figures = start_diagnose_figures(d, stage / "figures", early=early[0] if early else None) if output.plots else None
        try:
            with progress_bar(output.chatty and d.hands_over,
                              f"identify {d.recommended_model} on all the data") as cb:
                rec = fit_recommended(captures, d, m, o, seed=seed, model_options=mopts, progress=cb,
                                      executor=cr.executor, store=cr.store, resume=resume)
        except BaseException:
            if figures is not None:
                figures.cancel()
            raise
        with writing(out, output):
            write_diagnose_outputs(d, stage, make_figures=output.plots, recommended=rec, figures=figures)
    if rec is not None:
        stats.add(rec.cell_stats)
    print_cell_summary(stats, cr.describe(), quiet or json_out)
    _print_diagnosis(d, out, quiet, json_out, captures)


def _print_diagnosis(d, out: Path, quiet: bool, json_out: bool, captures=()) -> None:
    """The console's part of a diagnosis: a caution on a doubtful noise floor (stderr), then the JSON
    summary (``--json``) or the effects' table, the where-pointers and the next step (stdout)."""
    from ..diagnose import noise_floor_doubtful
    from ..report.diagnose_report import diagnosis_document, fit_fraction_text, next_step_line, not_tested_text
    from ..report.diagnose_wording import doubtful_floor_text, placebo_text, pointers_text
    from ..report.plots import display_unit

    if noise_floor_doubtful(d.noise) and not quiet:  # the verdict rests on the floor: said before it
        stderr.print(f"warning: {doubtful_floor_text(d.noise, display_unit(d.unit))}", markup=False, highlight=False,
                     soft_wrap=True)
    if not quiet:  # what the hold-out could not test, what --fit-fraction applied to: never silently
        for text in (fit_fraction_text(d), not_tested_text(d) if d.split.get("not_tested") else None):
            if text is not None:
                stderr.print(f"note: {text}", markup=False, highlight=False, soft_wrap=True)
    if json_out:
        from .common import capture_notes_json

        print_json({**diagnosis_document(d), "params": str(out / "params.json") if d.hands_over else None,
                    "capture_notes": capture_notes_json(captures)})
        return
    if quiet:
        return
    u = d.unit  # the columns' names, as identify's (rmse_um); the title in words (µm)
    named = ", ".join(d.explained_by) or "none"
    table = new_table(title=f"{d.base_model}: held-out gap per added effect, step by step (noise floor "
                            f"{d.noise['sigma']:.3g} {display_unit(u)}) — explained by: {named}")
    for col in ("step", "effect", f"before_{u}", f"after_{u}", "reduction", f"placebo_{u}", "passes"):
        table.add_column(col, justify="right", no_wrap=True)
    # every step of the selection: step k tests each remaining effect on top of the k − 1 named before
    # it (a table of step 1 alone contradicted a second named effect: "passes no" beside its name)
    for k, results in enumerate(d.steps or (d.effects,), start=1):
        pick = d.explained_by[k - 1] if k <= len(d.explained_by) else None
        for r in results:
            table.add_row(str(k), r.effect, f"{r.heldout_rmse_before:.4g}", f"{r.heldout_rmse_after:.4g}",
                          f"{r.reduction:.2f}", placebo_text(r.placebo_improvement),
                          "named" if r.effect == pick else "yes" if r.eligible else "no", end_section=r is results[-1])
    stdout.print(table)
    for p in pointers_text(d.findings, d.unit):
        stdout.print(f"where: {p}")
    stdout.print(f"explained by (in order): {', '.join(d.explained_by) or 'none'}; report: {out / 'diagnosis.md'}")
    stdout.print(next_step_line(d, out))
