"""Writes the outputs of ``hystfit identify``: params.json, report.csv, report.md and plots/."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import __version__
from ..identify import IdentifyResult, unit_param
from ..io import atomic_write_text, write_table
from ..metrics import mostly_constant
from ..results import dumps, identify_to_dict
from . import plots
from .tables import distinct_names
from ..params import AT_BOUND_RTOL
from .render import FigureJob, FigureStream
from .tables import fmt, frame, markdown_table, metric_columns, metric_legend



def _warmup(res: IdentifyResult) -> bool:
    """Whether any capture of the identification has a warm-up (``--warmup``)."""
    return any(c.warmup_samples for f in res.fits for c in f.captures)


def summary_rows(res: IdentifyResult) -> list[dict]:
    """One row per condition for report.csv, report.md and the console.

    ``samples`` counts the samples the metrics score, as ``metrics.n_samples`` in params.json
    does: with ``--warmup`` the warm-up samples are simulated but not scored, so they are not
    counted there. With a warm-up, ``samples_total`` follows it: every sample, warm-up included.
    """
    rows = []
    warm = _warmup(res)
    for f in res.fits:
        row = {"condition": f.label, "amplitude_V": f.amplitude_V, "frequency_Hz": f.frequency_Hz,
               "captures": len(f.captures), "samples": int(sum(c.n - c.warmup_samples for c in f.captures))}
        if warm:
            row["samples_total"] = int(sum(c.n for c in f.captures))
        for k in metric_columns(res.unit):
            row[k] = f.metrics.get(k, np.nan)
        row["runtime_s"] = f.runtime_s
        row["evaluations"] = f.evaluations
        if res.runs > 1:
            sp = f.spread()
            row[f"rmse_std_{res.unit}"] = sp[f"rmse_std_{res.unit}"]
        rows.append(row)
    return rows


class ConditionFigures:
    """The figures of an identification in ``out_dir/plots``, drawn as each condition is fitted.

    Pass :meth:`add` as ``on_fit`` to :func:`hystfit.identify.identify`: a condition's loop, time
    series and convergence figures go to the figure server (:class:`~hystfit.report.render.FigureStream`)
    as soon as it is fitted and are drawn while the other conditions are; :meth:`result` adds the
    overview of all conditions and waits. Used as a context manager, it stops the drawing when the
    block fails, so nothing is written into ``out_dir`` afterwards. The files do not depend on when
    or where a figure is drawn.

    Parameters
    ----------
    out_dir : Path
        Report directory (must exist); figures go to its ``plots`` folder.
    optimizer_name : str
        Optimizer of the identification (convergence figure titles).
    n_jobs : int, optional
        Processes for the figures left when the fits are done (default all cores).
    n_conditions : int, optional
        Conditions the identification will fit, when known: the figure server lays out their
        overview while it waits for the first fit (:func:`~hystfit.report.plots.prepare_overview`).
    """

    def __init__(self, out_dir: Path, optimizer_name: str, n_jobs: int | None = None, *,
                 n_conditions: int | None = None) -> None:
        self.plot_dir = Path(out_dir) / "plots"
        self.plot_dir.mkdir(exist_ok=True)
        self.optimizer_name = optimizer_name
        self.files: dict[str, list[str]] = {}  # condition → its figures, relative to the report
        self._stream = FigureStream(n_jobs)
        if n_conditions:
            self._stream.prepare("prepare_overview", int(n_conditions), titled=True)

    def __enter__(self) -> "ConditionFigures":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.cancel()

    def add(self, f) -> None:
        """Queue the figures of one fitted condition (a :class:`~hystfit.identify.ConditionFit`).

        Figures are named by the condition's label; a second condition with the same label (two
        keys that differ below the label's 12 significant digits, e.g. 0.7 V and 700 mV × 1e-3)
        keeps the figures of the first one added, as the report lists one figure set per label.
        """
        if f.label in self.files:
            return
        us = [c.u for c in f.captures]
        ys = [c.y for c in f.captures]
        title = f"{f.model.name} – {f.label}"
        mine = [
            FigureJob("loop_figure", self.plot_dir / f"loop_{f.label}.png", (us, ys, list(f.predictions)),
                      {"unit": f.unit, "title": title}),
            FigureJob("timeseries_figure", self.plot_dir / f"timeseries_{f.label}.png",
                      (f.captures[0].t, f.captures[0].y, f.predictions[0]),
                      {"unit": f.unit, "title": f"{title} ({f.captures[0].name})"}),
        ]
        if plots.has_convergence_history(f.best.result.history_best):
            mine.append(FigureJob("convergence_figure", self.plot_dir / f"convergence_{f.label}.png",
                                  (f.best.result.history_best, f.best.result.history_mean),
                                  {"title": f"{title}: {self.optimizer_name}",
                                   "runs": [r.result.history_best for r in f.runs] if len(f.runs) > 1 else None}))
        self.files[f.label] = [str(Path("plots") / j.path.name) for j in mine]
        self._stream.add(mine)

    def result(self, res: IdentifyResult) -> dict[str, list[str]]:
        """Queue the conditions of ``res`` not added yet and the overview, wait for every figure,
        and return the files per condition (relative to the report).

        A condition whose optimizer left no iteration history worth drawing (``auto`` on a model
        with no nonlinear parameter solves exactly: one point) gets no convergence figure; the
        report says why.
        """
        if res.optimizer_name != self.optimizer_name:
            raise ValueError(f"figures titled for optimizer {self.optimizer_name!r}, result of {res.optimizer_name!r}")
        for f in res.fits:
            if f.label not in self.files:
                self.add(f)
        panels = []
        for f in res.fits:
            r2 = f.metrics.get("r2", np.nan)
            rmse = f.metrics.get(f"rmse_{res.unit}", np.nan)
            panels.append({"title": f.label, "u": [c.u for c in f.captures], "y_meas": [c.y for c in f.captures],
                           "y_model": list(f.predictions),
                           "subtitle": f"R²={fmt(r2)} RMSE={fmt(rmse, 3)} {plots.display_unit(res.unit)}"})
        self._stream.add([FigureJob("overview_figure", self.plot_dir / "overview.png", (panels,),
                                    {"unit": res.unit, "title": f"{res.model_name} identified with {res.optimizer_name}"})])
        self._stream.result()
        return {f.label: self.files[f.label] for f in res.fits}

    def cancel(self) -> None:
        """Stop drawing (the server stops; nothing more is written)."""
        self._stream.cancel()


def _no_convergence_note(f) -> str | None:
    """Why a condition has no convergence figure (None when it has one)."""
    if plots.has_convergence_history(f.best.result.history_best):
        return None
    r = f.best.result
    return (f"No convergence figure: the optimizer left no iteration history to draw ({r.message}; "
            f"{r.nfev} objective evaluation{'s' if r.nfev != 1 else ''}).")


def markdown_report(res: IdentifyResult, plot_files: dict[str, list[str]]) -> str:
    u = res.unit
    lines = [f"# hystfit identification report", "",
             f"- model: `{res.model_name}` — optimizer: `{res.optimizer_name}`"
             f"{' + least-squares polish' if res.polish and res.optimizer_name not in ('lsq', 'auto') else ''}",
             f"- mode: {res.mode}; runs per condition: {res.runs}; seed: {res.seed}; hystfit {__version__}",
             f"- output unit: {u}; input unit: V; time: s",
             f"- runs computed {res.cell_stats.computed}, reused from an interrupted run {res.cell_stats.reused}", ""]
    if res.failed:
        lines += ["## Failed runs (left out)", "", *[f"- {f}" for f in res.failed], ""]
    lines += ["## Metrics per condition", "", markdown_table(frame(summary_rows(res))), ""]
    if plot_files:  # the overview of every condition, drawn with the figures (a blind test found it unlinked)
        lines += ["![overview of every condition](plots/overview.png)", ""]
    if _warmup(res):
        lines += ["`samples`: the samples the metrics score (`n_samples` in params.json); `samples_total`: with "
                  "the warm-up samples (--warmup), simulated but not scored.", ""]
    lines += ["Formulas (e = model − measured):", "", metric_legend(u), ""]
    offsets = offset_notes(res)
    if offsets:
        lines += ["## Output offsets", "", *[f"- {n}" for n in offsets], ""]
    for f in res.fits:
        lines += [f"## {f.label}", "",
                  f"Sources: {', '.join(c.source for c in f.captures)}", ""]
        notes = [n for c in f.captures for n in c.notes]
        if notes:
            lines += ["Loading notes: " + "; ".join(notes), ""]
        prow = [{"parameter": p.name, "unit": unit_param(p, u), "value": _value_text(v, se),
                 "stderr": "not determined" if se == np.inf else se,
                 "lower": p.lower, "upper": p.upper, "at bound": f"**{at}**" if at else ""}
                for p, v, se, at in zip(f.params, f.theta, f.stderr, f.at_bound)]
        lines += [markdown_table(frame(prow)), ""]
        if len(f.runs) > 1:
            sp = f.spread()
            lines += [f"Runs: {sp['runs']}; objective min {fmt(sp['fun_min'])}, max {fmt(sp['fun_max'])}, "
                      f"mean {fmt(sp['fun_mean'])}, std {fmt(sp['fun_std'])}; median time {fmt(sp['time_median_s'])} s", ""]
        for p in plot_files.get(f.label, []):
            lines.append(f"![{Path(p).stem}]({p})")
        note = _no_convergence_note(f) if f.label in plot_files else None
        if note:
            lines += ["", note]
        lines.append("")
    lines += ["Standard errors are asymptotic (σ²(JᵀJ)⁻¹ at the optimum). A parameter \"at bound\" lies within "
              f"{AT_BOUND_RTOL:g} × its search width of that bound: the search stopped there, so it has no standard "
              "error (–); if the bound is not physical, widen it with --bounds NAME=LOWER:UPPER. "
              "A large standard error means the data do not determine that parameter well; \"not determined\" "
              "means they do not determine it at all (any value fits as well: its Jacobian column is zero or a "
              "combination of the others', e.g. a stage's f_n far above every drive frequency): read its value as "
              "arbitrary.", ""]
    return "\n".join(lines)


def _value_text(value: float, stderr: float | None) -> str:
    """A fitted value with the digits its standard error resolves (at least :func:`fmt`'s four): an
    output offset of 5000247.85 nm (± 1.7) was shown as 5.000e+06 in a blind test, hiding the 248 nm
    that matter."""
    v = float(value)
    digits = 4
    if stderr is not None and np.isfinite(stderr) and stderr > 0 and np.isfinite(v) and abs(v) > stderr:
        digits = max(digits, int(np.ceil(np.log10(abs(v) / stderr))) + 2)
    if digits > 4 and abs(v) >= 1e4:  # 5000247.85, not 5.00024785e+06
        return f"{v:.{max(0, min(digits, 15) - int(np.floor(np.log10(abs(v)))) - 1)}f}"
    return fmt(v, min(digits, 15))


def bound_notes(res: IdentifyResult) -> list[str]:
    """One line per parameter set with parameters pinned at a search bound (for the console)."""
    out = []
    for f in res.fits:
        pinned = [f"{p.name}={fmt(float(v))} ({at} {fmt(getattr(p, at))})"
                  for p, v, at in zip(f.params, f.theta, f.at_bound) if at]
        if pinned:
            out.append(f"{f.label}: at a search bound: {', '.join(pinned)}")
    return out


def undetermined_notes(res: IdentifyResult) -> list[str]:
    """One line per parameter set with parameters the data do not determine (an infinite standard
    error: a stage's f_n under drives far below it, a delay that a stage already gives) — any value
    of them fits as well (for the console)."""
    out = []
    for f in res.fits:
        loose = [f"{p.name}={fmt(float(v))}" for p, v, se in zip(f.params, f.theta, f.stderr) if se == np.inf]
        if loose:
            out.append(f"{f.label}: not determined by the data: {', '.join(loose)}")
    return out


def offset_notes(res: IdentifyResult) -> list[str]:
    """One line per parameter set of a model fitted without its output offset (``offset=false``,
    lugre's default: paper 002's parameters) whose error is mostly a constant
    (:func:`hystfit.metrics.mostly_constant`): the captures' output does not rest where the model's
    does (a sensor's zero, a stage's rest position), which only an offset takes back. Without the
    note such a fit ends with R² far below 0 and nothing but a bound note (for the console)."""
    out = []
    for f in res.fits:
        base = getattr(f.model, "base", f.model)  # a composite's base model carries the option
        constant = mostly_constant(f.metrics, f.unit) if getattr(base, "offset", None) is False else None
        u = plots.display_unit(f.unit)
        if constant is not None:
            out.append(f"{f.label}: {base.name} is fitted without an output offset (offset=false), and its residual "
                       f"is mostly a constant ({fmt(constant[0])} {u} of RMSE {fmt(constant[1])} {u}): add "
                       "--model-option offset=true")
        elif (split := _split_offsets(f)) is not None:
            blocks = [b.name for b in getattr(f.model, "blocks", ())]
            fix = ("" if "drift" in blocks else
                   f" --model {f.model.name}+drift fits an offset (and a slow ramp) per capture, or fit them apart")
            out.append(f"{f.label}: its captures rest at different output levels — the error of each is mostly a "
                       f"constant, of both signs ({', '.join(f'{n} {b:+.4g} {u}' for n, b in split)}): a sensor "
                       f"zero that moved between recordings?{fix}")
    return out


def _split_offsets(f) -> list[tuple[str, float]] | None:
    """(capture name, bias) of the captures of one parameter set whose error is each mostly a constant
    (:func:`hystfit.metrics.mostly_constant`), when there are at least two and their biases have both
    signs: captures pooled in one fit whose output rests at different levels (a sensor zero that
    moved between recording days), which one shared offset cannot take back; else None."""
    pcs = list(f.per_capture)
    if len(pcs) < 2:
        return None
    names = distinct_names([str(pc.get("source", "")) for pc in pcs])
    found = [(n, c[0]) for n, pc in zip(names, pcs) if (c := mostly_constant(pc, f.unit)) is not None]
    if len(found) < 2 or not (min(b for _, b in found) < 0 < max(b for _, b in found)):
        return None
    return found


def write_identify_outputs(res: IdentifyResult, out_dir: Path, *, make_plots: bool = True,
                           n_jobs: int | None = None, figures: ConditionFigures | None = None) -> dict[str, Path]:
    """Write every output of an identification into ``out_dir`` (which must exist).

    Figures are drawn by ``n_jobs`` processes (default all cores, :func:`~hystfit.report.render.render_figures`);
    the files do not depend on it. ``figures``: the :class:`ConditionFigures` the identification
    already handed its conditions to (their figures drawn while it fitted); by default they are
    all drawn now.
    """
    out_dir = Path(out_dir)
    paths = {"params": out_dir / "params.json", "report_csv": out_dir / "report.csv",
             "report_md": out_dir / "report.md"}
    atomic_write_text(paths["params"], dumps(identify_to_dict(res)))
    write_table(paths["report_csv"], frame(summary_rows(res)))
    plot_files: dict[str, list[str]] = {}
    if make_plots:
        if figures is None:
            figures = ConditionFigures(out_dir, res.optimizer_name, n_jobs)
        elif figures.plot_dir != out_dir / "plots":
            raise ValueError(f"the figures go to {figures.plot_dir}, the report to {out_dir}")
        with figures:
            plot_files = figures.result(res)
        paths["plots"] = figures.plot_dir
    atomic_write_text(paths["report_md"], markdown_report(res, plot_files))
    return paths
