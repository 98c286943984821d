"""Options and helpers shared by several commands (parsing and printing only)."""

from __future__ import annotations

import math

import json
import sys
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Iterator, Optional

import typer

from .._process import hold_across_forks
from ..errors import ConfigError
from .app import OptionGroup


_console_lock = threading.Lock()
hold_across_forks(_console_lock)


class _Console:
    """A rich ``Console``, made (and rich imported, ≈ 30 ms) when something is first printed: a
    ``--quiet`` or ``--json`` run prints nothing through it."""

    def __init__(self, **options) -> None:
        self._options = options
        self._console = None

    def rich(self):
        """The rich ``Console`` itself (one, made under a lock: a progress line's timer thread may
        ask for it at the same moment as the command)."""
        if self._console is None:
            with _console_lock:
                return self._made()
        return self._console

    def _made(self):
        if self._console is None:
            from rich.console import Console

            self._console = Console(**self._options)
            lock = getattr(self._console, "_lock", None)  # rich writes under it, from its refresh thread too
            if lock is not None:
                hold_across_forks(lock)
        return self._console

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.rich(), name)


stderr = _Console(stderr=True)
stdout = _Console()


def new_table(**options):
    """A rich ``Table`` (rich is imported on the first table)."""
    from rich.table import Table

    return Table(**options)

DataArg = Annotated[list[Path], typer.Argument(help="Capture files (CSV/TXT/Parquet) or directories of them.",
                                               show_default=False)]
TimeCol = Annotated[Optional[str], typer.Option("--time-col", help="Time column: name or 0-based index.")]
InputCol = Annotated[Optional[str], typer.Option("--input-col", help="Input (voltage) column: name or 0-based index.")]
OutputCol = Annotated[Optional[str], typer.Option("--output-col", help="Output (displacement) column: name or 0-based index.")]
NoHeader = Annotated[bool, typer.Option("--no-header", help="The files have no header row.")]
Fs = Annotated[Optional[float], typer.Option("--fs", help="Sample rate in Hz when there is no time column.")]
DropNonfinite = Annotated[bool, typer.Option("--drop-nonfinite", help="Repair rows with NaN/inf/empty cells instead of "
                                             "refusing the file: drop them at the start and end, interpolate runs of "
                                             "up to 3 inside the data (the sampling stays uniform); a note says which.")]
Condition = Annotated[Optional[str], typer.Option("--condition", help="Force the operating condition 'AMPLITUDE_V,FREQUENCY_HZ'.")]
OutputUnit = Annotated[Optional[str], typer.Option("--output-unit", help="Output unit when the column name has no suffix: nm, um, mm, m.")]
Recursive = Annotated[bool, typer.Option("--recursive", "-r", help="Expand directories recursively.")]
Start = Annotated[Optional[float], typer.Option("--start", help="Use each capture from this time on (s from its "
                                                                "first row), e.g. to skip a mid-loop start.")]
Warmup = Annotated[float, typer.Option("--warmup", min=0.0, help="Seconds at the start of each capture that the fit "
                                                                  "simulates but does not score (the actuator's "
                                                                  "unknown initial state settles), e.g. one cycle.")]
Stop = Annotated[Optional[float], typer.Option("--stop", help="Use each capture up to this time (s from its first "
                                                              "row).")]

# Options several commands share: one name, one meaning, one default, one range (enforced by
# tests/integration/test_option_names.py).


def seed_callback(value: int) -> int:
    """Validate ``--seed`` with the library's own rule and words (:func:`hystfit.seeds.check_seed`)."""
    from ..seeds import check_seed

    try:
        return check_seed(value)
    except ConfigError as exc:
        raise typer.BadParameter(str(exc)) from None


MapeFloor = Annotated[float, typer.Option("--mape-floor", help="MAPE/SMAPE leave out samples with |y_meas| below "
                                          "this fraction of the stroke; 0 = every sample, as paper 002.")]
Seed = Annotated[int, typer.Option("--seed", callback=seed_callback,
                                   help="Seed of every random choice (0 … 4294967295); each run derives its own.")]
Pop = Annotated[Optional[int], typer.Option("--pop", min=1, show_default="the optimizer's own, see 'hystfit "
                                            "optimizers'", help="Population size of population-based optimizers "
                                                                "(>= 1).")]
Iters = Annotated[Optional[int], typer.Option("--iters", min=1, show_default="the optimizer's own, see 'hystfit "
                                              "optimizers'", help="Iterations of iterative optimizers (>= 1).")]


def jobs_option(help: str, show_default: str = "all cores"):
    """``--jobs/-j`` (>= 1) with a command's own help and default text."""
    return Annotated[Optional[int], typer.Option("--jobs", "-j", min=1, show_default=show_default, help=help)]


Jobs = jobs_option("Parallel processes (the numbers do not depend on it).")
ExecutorOpt = Annotated[str, typer.Option("--executor", help="Where the cells run: local (a process pool of --jobs "
                                                           "processes) or dask (a Dask LocalCluster of --jobs "
                                                           "workers, or the cluster at --scheduler; needs "
                                                           "pip install \"hystfit\\[dask]\"). The numbers do not "
                                                           "depend on it.")]
Scheduler = Annotated[Optional[str], typer.Option("--scheduler", help="Address of a running Dask scheduler, e.g. "
                                                                      "tcp://host:8786 (with --executor dask).")]
Resume = Annotated[bool, typer.Option("--resume", help="Continue an interrupted run: reuse the cells it stored in "
                                                       "OUT.partial/ (those whose captures and settings are "
                                                       "unchanged) and compute only the rest.")]
Runs = Annotated[int, typer.Option("--runs", min=1, help="Independent seeded runs per condition; the best is kept "
                                                         "(>= 1).")]
Polish = Annotated[bool, typer.Option("--polish/--no-polish", help="Least-squares polish after the global search.")]
Plots = Annotated[bool, typer.Option("--plots/--no-plots", help="Write the figures.")]
FiguresAlias = Annotated[Optional[bool], typer.Option("--figures/--no-figures", hidden=True,
                                                      help="Deprecated spelling of --plots/--no-plots.")]
JsonOut = Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress and no summary table.")]
Force = Annotated[bool, typer.Option("--force", help="Replace an existing output (checked before any work).")]
PerCondition = Annotated[bool, typer.Option("--per-condition/--global",
                                            help="One parameter set per operating condition (look-up table) or "
                                                 "one for all captures.")]
Bounds = Annotated[Optional[list[str]], typer.Option("--bounds", help="Override a bound: NAME=LOWER:UPPER "
                                                                    "(repeatable).")]
ModelOptions = Annotated[Optional[list[str]], typer.Option("--model-option", help="Model structure option KEY=VALUE, "
                                                           "e.g. n_operators=12 (repeatable).")]
OptOptions = Annotated[Optional[list[str]], typer.Option("--opt-option", help="Optimizer setting KEY=VALUE, e.g. "
                                                         "stall_iter=50 (repeatable).")]
OutDir = Annotated[Path, typer.Option("--out", help="Output directory (refused if it exists and is not empty, "
                                                   "unless --force).")]
Method = Annotated[str, typer.Option("--method", help="Look-up-table cells: interpolate (bilinear blend of the "
                                                      "nearest cells) or nearest.")]


class CellRun:
    """The executor and the cell store of one command writing ``out`` (see :func:`cell_run`).

    ``executor`` is None for ``--executor local``: the library then sizes its own pool from
    ``--jobs`` (``identify`` runs exact linear solves in-process, where a pool only adds start-up).
    """

    def __init__(self, executor, store, resume: bool, jobs: Optional[int]) -> None:
        self.executor, self.store, self.resume, self.jobs = executor, store, resume, jobs

    def pool(self, default_jobs: Optional[int] = None):
        """The executor itself: the Dask one, or a local pool of ``--jobs`` (else ``default_jobs``) processes."""
        from ..parallel import LocalExecutor

        return self.executor if self.executor is not None else LocalExecutor(self.jobs or default_jobs)

    def describe(self) -> str:
        if self.executor is not None:
            return self.executor.describe()
        from ..parallel import default_jobs

        return f"local ({self.jobs or default_jobs()} process(es) at most)"


@dataclass(frozen=True)
class ExecutorArgs(OptionGroup):
    """Where the cells run and whether an interrupted run continues: ``--jobs`` … ``--resume``."""

    jobs: Jobs = None
    executor: ExecutorOpt = "local"
    scheduler: Scheduler = None
    resume: Resume = False


@contextmanager
def cell_run(out: Path, run: ExecutorArgs, enabled: bool = True) -> Iterator[CellRun]:
    """Start the executor and open the cell store ``OUT.partial`` around a command's work.

    Without ``--resume`` stored cells are not read (a forgotten ``--resume`` must not throw away an
    interrupted run's work: a note says they are there), only written. On success (the block
    returns: the outputs are published) the store is removed; on Ctrl-C, an error or a kill it
    stays, and a line says how to continue.
    """
    from ..cells import CellStore, partial_dir
    from ..parallel import make_executor

    executor, jobs, scheduler, resume = run.executor, run.jobs, run.scheduler, run.resume
    store = CellStore(partial_dir(out))
    if enabled and len(store):
        _line(f"resuming: {len(store)} stored cell(s) in {store.root}" if resume else
              f"note: {store.root} holds {len(store)} cell(s) of an interrupted run; they are recomputed "
              "(stop and add --resume to reuse them)")
    ex = make_executor(executor, jobs, scheduler)
    if ex.name == "local":
        ex = None
    try:
        yield CellRun(ex, store, resume, jobs)
    except BaseException:
        kept = len(store)
        if kept:
            _line(f"note: {kept} finished cell(s) kept in {store.root}; rerun the same command with --resume "
                  "to continue")
        raise
    finally:
        if ex is not None:
            ex.close()
    store.clear()


def print_cell_summary(stats, executor_text: str, quiet: bool) -> None:
    """The final line: wall time, cells computed, reused, failed (stderr)."""
    if quiet:
        return
    _line(f"cells: {stats.computed} computed, {stats.reused} reused, {stats.failed} failed in "
          f"{stats.wall_time_s:.1f} s on {executor_text}")


def parse_col(value: Optional[str]) -> str | int | None:
    if value is None:
        return None
    v = value.strip()
    return int(v) if v.isdigit() else v


def parse_condition(value: Optional[str]) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        a, f = (float(x) for x in value.split(","))
    except ValueError:
        raise ConfigError(f"--condition {value!r}: expected AMPLITUDE_V,FREQUENCY_HZ, e.g. 40,10") from None
    from ..conditions import CONDITION_RULE, is_valid_condition

    if not is_valid_condition(a, f):
        raise ConfigError(f"--condition {value!r}: {CONDITION_RULE}, e.g. 40,10")
    return (a, f)


@dataclass(frozen=True)
class CaptureArgs(OptionGroup):
    """How to read the captures: ``--time-col`` … ``--stop``, as given on the command line."""

    time_col: TimeCol = None
    input_col: InputCol = None
    output_col: OutputCol = None
    no_header: NoHeader = False
    fs: Fs = None
    drop_nonfinite: DropNonfinite = False
    condition: Condition = None
    output_unit: OutputUnit = None
    recursive: Recursive = False
    start: Start = None
    stop: Stop = None

    @property
    def warmup_s(self) -> float:
        return 0.0

    def load_options(self, require_output: bool = True):
        """The loader's :class:`~hystfit.io.LoadOptions`; one-line errors for values it cannot take."""
        from ..io import LoadOptions

        start, stop, fs = self.start, self.stop, self.fs
        # finite: inf and nan passed the comparisons below (or typer's min=0) and overflowed in the
        # loader with a traceback (a blind test's find)
        if start is not None and not (math.isfinite(start) and start >= 0):
            raise ConfigError(f"--start {start:g}: must be a finite number >= 0 s (time from the capture's first row)")
        if stop is not None and not math.isfinite(stop):
            raise ConfigError(f"--stop {stop:g}: must be a finite time after --start; leave it out to keep the capture "
                              "to its end")
        if stop is not None and not stop > (start or 0.0):
            raise ConfigError(f"--stop {stop:g}: must be after --start ({start or 0:g} s)")
        if fs is not None and not (math.isfinite(fs) and fs > 0):
            raise ConfigError(f"--fs {fs:g}: the sample rate must be a finite number > 0 (Hz)")
        if not (math.isfinite(self.warmup_s) and self.warmup_s >= 0):
            raise ConfigError(f"--warmup {self.warmup_s:g}: must be a finite number >= 0 s")
        if self.output_unit is not None and self.output_unit not in ("nm", "um", "mm", "m"):
            raise ConfigError(f"--output-unit {self.output_unit!r}: choose one of nm, um, mm, m")
        return LoadOptions(time_col=parse_col(self.time_col), input_col=parse_col(self.input_col),
                           output_col=parse_col(self.output_col), no_header=self.no_header, fs=fs,
                           drop_nonfinite=self.drop_nonfinite, condition=parse_condition(self.condition),
                           output_unit=self.output_unit, require_output=require_output, start_s=start, stop_s=stop,
                           warmup_s=self.warmup_s)


@dataclass(frozen=True)
class FitCaptureArgs(CaptureArgs):
    """:class:`CaptureArgs` and ``--warmup``, for the commands that fit."""

    warmup: Warmup = 0.0

    @property
    def warmup_s(self) -> float:
        return self.warmup


@dataclass(frozen=True)
class FitArgs(OptionGroup):
    """The fit's structure and settings: ``--per-condition``, ``--bounds``, ``--model-option``,
    ``--opt-option``, as given (see the methods for them parsed)."""

    per_condition: PerCondition = True
    bounds: Bounds = None
    model_option: ModelOptions = None
    opt_option: OptOptions = None

    def model_options(self) -> dict[str, object]:
        return parse_key_values(self.model_option or [], "--model-option")

    def optimizer_options(self) -> dict[str, object]:
        return parse_key_values(self.opt_option or [], "--opt-option")

    def bound_overrides(self) -> dict:
        from ..params import parse_bound_overrides

        return parse_bound_overrides(self.bounds or [])


@dataclass(frozen=True)
class OutputArgs(OptionGroup):
    """What a command writes and prints: ``--plots``, ``--json``, ``--quiet``, ``--force``."""

    plots: Plots = True
    json_out: JsonOut = False
    quiet: Quiet = False
    force: Force = False

    @property
    def chatty(self) -> bool:
        """Progress and phase lines on stderr (neither ``--quiet`` nor ``--json``)."""
        return not self.quiet and not self.json_out


@dataclass(frozen=True)
class FigureOutputArgs(OutputArgs):
    """:class:`OutputArgs` and the deprecated spelling ``--figures/--no-figures`` (hidden), which,
    when given, sets ``plots``."""

    figures_alias: FiguresAlias = None

    def __post_init__(self) -> None:
        if self.figures_alias is not None:
            object.__setattr__(self, "plots", self.figures_alias)


def parse_key_values(items: list[str], what: str) -> dict[str, object]:
    """Parse ``["n_operators=12", "placement=quadratic"]`` with JSON-ish values."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{what} {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = json.loads(val)
        except json.JSONDecodeError:
            out[key.strip()] = val
    return out


#: On a pipe, at most one progress line per this many seconds (plus the last).
PLAIN_PROGRESS_INTERVAL_S = 1.0
#: A step says what it is doing once it has taken this long (quick steps and early errors stay quiet).
PROGRESS_DELAY_S = 1.0


@contextmanager
def progress_bar(enabled: bool, description: str) -> Iterator:
    """Progress on stderr; yields a ``progress(event, info)`` callback for the library.

    On a terminal a rich bar; on a pipe or file (CI logs, ``2> log``) plain lines once the work has
    taken :data:`PROGRESS_DELAY_S` — the start, then ``k/N`` with the last item and the elapsed time
    at most once a second, and the end — so a long run is never silent and a short one stays quiet.
    """
    if not enabled:
        yield None
        return
    if not stderr.is_terminal:
        plain = _PlainProgress(description)
        try:
            yield plain
        finally:
            plain.close()
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    TextColumn("{task.fields[last]}"), console=stderr.rich(), transient=True)
    task = None

    def callback(event: str, info: dict) -> None:
        nonlocal task
        if event == "start":
            task = prog.add_task(description, total=info.get("total"), last="")
        elif event == "advance" and task is not None:
            prog.update(task, advance=1, last=_cell_text(info))
        elif event == "note":
            prog.console.print(info.get("text", ""))

    with prog:
        yield callback


def _cell_text(info: dict) -> str:
    """The last cell's label, marked when it was reused from the store or failed."""
    text = str(info.get("label") or "")
    if info.get("failed"):
        text += " (failed)"
    elif info.get("reused"):
        text += " (reused)"
    return text


def _line(text: str) -> None:
    stderr.print(text, markup=False, highlight=False, soft_wrap=True)


class _PlainProgress:
    """The ``progress(event, info)`` callback for a pipe: plain lines, see :func:`progress_bar`."""

    def __init__(self, description: str) -> None:
        import threading
        import time

        self._time = time.monotonic
        self.description = description
        self.total = None
        self.done = 0
        self.t0 = self.last = self._time()
        self.spoken = False
        self._lock = threading.Lock()
        self._timer = threading.Timer(PROGRESS_DELAY_S, self._started)
        self._timer.daemon = True
        self._timer.start()

    def _started(self) -> None:
        with self._lock:
            if not self.spoken:
                self.spoken = True
                self.last = self._time()
                steps = f" ({self.done}/{self.total} done)" if self.total else ""
                _line(f"{self.description}: running{steps}")

    def __call__(self, event: str, info: dict) -> None:
        now = self._time()
        if event == "start":  # a new phase (invert's segments, then track's controllers): counted afresh
            self.total, self.done = info.get("total"), 0
        elif event == "advance":
            self.done += 1
            final = self.total is not None and self.done >= self.total
            with self._lock:
                due = now - self.t0 >= PROGRESS_DELAY_S and (final or now - self.last >= PLAIN_PROGRESS_INTERVAL_S)
                if due:
                    self.spoken, self.last = True, now
                    of = f"/{self.total}" if self.total else ""
                    label = f" {_cell_text(info)}" if info.get("label") else ""
                    _line(f"{self.description}: {self.done}{of}{label} ({now - self.t0:.1f} s)")
        elif event == "note":
            _line(str(info.get("text", "")))

    def close(self) -> None:
        self._timer.cancel()


@contextmanager
def phase(enabled: bool, text: str) -> Iterator[None]:
    """Say what a step that may take a while is doing (loading files, writing figures) on stderr
    once it has taken :data:`PROGRESS_DELAY_S`: a spinner on a terminal, one line on a pipe."""
    if not enabled:
        yield
        return
    if not stderr.is_terminal:
        import threading

        timer = threading.Timer(PROGRESS_DELAY_S, _line, args=(f"{text} …",))
        timer.daemon = True
        timer.start()
        try:
            yield
        finally:
            timer.cancel()
        return
    with stderr.status(text):
        yield


def print_capture_notes(captures) -> None:
    """The loader's notes (trims, repairs, mid-loop starts, assumed units), one line each on stderr."""
    from ..report.tables import distinct_names

    for c, name in zip(captures, distinct_names([c.source for c in captures])):
        for note in c.notes:
            print_note(name, note)


def capture_notes_json(captures) -> list[dict]:
    """The loader's notes for ``--json`` (a script reads no stderr, and ``--quiet`` silences it):
    ``[{"source": NAME, "notes": [...]}]`` for the captures that have any, named as on stderr."""
    from ..report.tables import distinct_names

    return [{"source": name, "notes": list(c.notes)}
            for c, name in zip(captures, distinct_names([c.source for c in captures])) if c.notes]


def print_note(name: str, note: str) -> None:
    """One note about the capture ``name`` on stderr: ``warning: NAME: …`` for a note that is a
    warning (starts with ``warning: ``), else ``note: NAME: …``."""
    if note.startswith("warning: "):
        stderr.print(f"warning: {name}: {note[9:]}", markup=False, highlight=False, soft_wrap=True)
    else:
        stderr.print(f"note: {name}: {note}", markup=False, highlight=False, soft_wrap=True, style="dim")


def print_table_warnings(captures, per_condition: bool, output: OutputArgs) -> None:
    """Before a look-up table is fitted (``per_condition``): a warning per broadband capture that
    would be one of its cells (:func:`hystfit.conditions.broadband_cell_warnings`)."""
    if not per_condition or output.quiet:
        return
    from ..conditions import broadband_cell_warnings, broadband_label_notes

    for line in broadband_cell_warnings(captures):
        stderr.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)
    for line in broadband_label_notes(captures):
        stderr.print(f"note: {line}", markup=False, highlight=False, soft_wrap=True, style="dim")


def start_figures(output: FigureOutputArgs, *, behind: bool = False) -> None:
    """With figures ahead, start the figure server (matplotlib imported on the other core) before
    the command imports its own modules, loads and fits: first thing in a command that draws.
    ``behind``: the command's own work comes first — the server runs at a lower priority
    (:func:`hystfit.report.render.yield_cores` by ``render.FIGURES_NICE``) and draws on the cores
    the work leaves idle."""
    if output.plots:
        from ..report import render

        render.preload(claim_early=True)
        if behind:
            render.yield_cores(render.FIGURES_NICE)


def load_for_command(data, options, output: OutputArgs, *, recursive: bool, ahead=()):
    """The captures of a command (``options``: :meth:`CaptureArgs.load_options`): loaded with a
    progress line when slow, the loader's notes printed. ``ahead``: what the command loads or
    starts while a forked child reads them (:func:`hystfit.io.load_captures`; the progress line's
    thread starts after that fork, which it would otherwise prevent).

    In the console script's process (:func:`~hystfit.cli.app.process_ends_with_command`) what it
    has imported and read by then lives until the command ends: it is frozen out of the garbage
    collector (:func:`gc.freeze`), whose full collections would walk numba's, scipy's and the
    captures' objects again and again (a diagnosis of sample_data ran three, 18 ms each) — once per
    process: a batch's later jobs do not freeze the earlier jobs' garbage with theirs. Never in a
    program that calls the CLI and goes on (a test suite's ``CliRunner``)."""
    import gc

    from ..io import load_captures
    from .app import process_ends_with_command

    captures = load_captures(data, options, recursive=recursive, ahead=ahead,
                             meanwhile=lambda: phase(output.chatty, "loading the captures"),
                             abandon_on_error=process_ends_with_command())
    if process_ends_with_command() and not gc.get_freeze_count():
        gc.freeze()
    if not output.quiet:
        print_capture_notes(captures)
    return captures


def writing(out, output: OutputArgs):
    """The phase line of writing a command's outputs."""
    return phase(output.chatty, f"writing {out}" + (" (figures)" if output.plots else ""))


def print_json(data: dict) -> None:
    sys.stdout.write(json.dumps(data, indent=2, allow_nan=False) + "\n")
