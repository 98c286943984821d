"""Many figures drawn in parallel: a list of :class:`FigureJob`, one PNG each, the same bytes in any process.

A report collects its figures as jobs (the name of a :mod:`hystfit.report.plots` function, the file,
its arguments) and hands them to :func:`render_figures`, which draws them in a process pool sized
to the cores (or in this process when that cannot pay off) and returns the paths in the order of
the jobs. Each figure depends only on its own arguments, so the files do not depend on the number
of processes.

Workers are forked, not spawned: a spawned worker would spend ≈ 0.5–0.8 s importing numpy and
matplotlib again, more than the figures of a small report take. A figure job touches neither numba
nor BLAS (whose thread pools are not fork-safe), only numpy and matplotlib's Agg canvas, which are
imported before the pool is forked so every child starts with them. Where ``fork`` is not available
the figures are drawn in this process.

A command that will draw calls :func:`preload` first: it forks a figure server that imports
matplotlib on the other core while this process loads and fits, and :func:`render_figures` then
sends the jobs there (the server forks the pool); this process never imports matplotlib. When no
job is waiting yet once its imports are done, the server draws one small figure of each reused
layout (:func:`_warm_up`), so every worker it forks starts with those layouts and with filled text
caches; when jobs are already waiting (a command whose fit was done before matplotlib was
imported), it draws them at once instead, and their own first figures lay the layouts out.

Figures known before the command's work is done (those of a condition as soon as it is fitted)
go into a :class:`FigureStream`: the server draws them one by one while this process still works,
and forks its pool only for the figures left when the stream is finished (:meth:`FigureStream.result`).
"""

from __future__ import annotations

import atexit
import gc
import importlib
import math
import multiprocessing as mp
import os
import signal
import sys
import threading
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from multiprocessing.reduction import ForkingPickler
from pathlib import Path
from typing import Any, Sequence

from .._process import fork_with_handlers

__all__ = ["FigureJob", "FigureStream", "PendingFigures", "preload", "render_figures", "MIN_JOBS_PER_WORKER"]

#: a worker is only started for at least this many figures (≈ 35–65 ms each, against ≈ 30 ms to fork one)
MIN_JOBS_PER_WORKER = 3

_preload_thread: threading.Thread | None = None
_server: "_FigureServer | None" = None
_early = False  # the server was started by preload_early and no command has claimed it yet


@dataclass(frozen=True)
class FigureJob:
    """One figure to draw: ``getattr(plots, function)(path, *args, **kwargs)``.

    Parameters
    ----------
    function : str
        Name of a figure function of :mod:`hystfit.report.plots` (e.g. ``"loop_figure"``), or
        ``"module:function"`` for one elsewhere (e.g. ``"hystfit.report.diagnose_report:_fig_time"``).
    path : Path
        PNG file to write.
    args : tuple
        Positional arguments after the path (arrays are pickled to the worker).
    kwargs : dict
        Keyword arguments.
    """

    function: str
    path: Path
    args: tuple = ()
    kwargs: dict[str, Any] = field(default_factory=dict)


#: what matplotlib imports that hystfit's figures never use: the 3-D toolkit (its registry treats a
#: failed import as "no 3-D projection")
_UNUSED_3D = "mpl_toolkits.mplot3d"


def _import_plotting(lean: bool = False) -> None:
    """Import matplotlib's figure and Agg canvas, hystfit's plots, and load the default font.

    ``lean``: the figure server's own import (a process of hystfit's that draws 2-D PNGs and runs no
    other code), with matplotlib ≥ 3.9 (:func:`_tolerates_no_3d`): without the 3-D toolkit
    (``python benchmarks/bench_startup.py`` compares the two), on the critical path of a command
    whose fit ends first. In any other process (a program that uses hystfit as a library draws here when it
    cannot fork) matplotlib is imported whole.
    """
    if lean and "matplotlib" not in sys.modules and _tolerates_no_3d():
        saved = sys.modules.get(_UNUSED_3D)
        sys.modules[_UNUSED_3D] = None  # type: ignore[assignment] - the import of the toolkit fails at once
        _without_set_signatures()
        for name in _LOADED_ON_USE:
            _load_on_use(name)
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Unable to import Axes3D", category=UserWarning)
                from matplotlib.figure import Figure  # noqa: F401
        finally:
            if saved is None:
                del sys.modules[_UNUSED_3D]
            else:
                sys.modules[_UNUSED_3D] = saved
    from matplotlib import font_manager
    from matplotlib.figure import Figure  # noqa: F401, F811

    from . import canvas, plots  # noqa: F401

    font_manager.get_font(font_manager.findfont(font_manager.FontProperties()))  # the first text loads the font


#: modules matplotlib imports for what hystfit's figures never draw, made to load on first use in the
#: figure server (:func:`_load_on_use`): the Adobe Glyph List, which ``matplotlib.dviread`` (TeX
#: output) imports whole — 50 ms of the server's import, parsing a 4,500-line table
_LOADED_ON_USE = ("fontTools.agl",)


def _load_on_use(name: str) -> None:
    """Make ``import name`` in this process bind a stand-in module that imports the real one when
    an attribute of it is first read (PEP 562's module ``__getattr__``), then holds the real one's
    names: the same module, later. (:class:`importlib.util.LazyLoader` does not do it on Python
    3.11: the ``import`` statement reads the module's ``__spec__``, which loads it.) Nothing is
    changed when the module is imported already or cannot be found."""
    import importlib
    import importlib.util
    import types

    if name in sys.modules:
        return
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return
    if spec is None:
        return
    stand_in = types.ModuleType(name)
    stand_in.__spec__ = spec

    def load(attr: str):
        if sys.modules.get(name) is stand_in:
            del sys.modules[name]
        real = importlib.import_module(name)  # binds itself on its package, as any import does
        stand_in.__dict__.update({k: v for k, v in vars(real).items() if k != "__getattr__"})
        del stand_in.__dict__["__getattr__"]
        return getattr(real, attr)

    stand_in.__getattr__ = load  # type: ignore[attr-defined]
    sys.modules[name] = stand_in
    parent, _, child = name.rpartition(".")
    if parent:  # as the import system does for a submodule: ``import a.b`` then reads a.b
        setattr(sys.modules[parent], child, stand_in)


def _without_set_signatures() -> None:
    """In the figure server only (:func:`_import_plotting`'s ``lean``): matplotlib gives every
    ``Artist`` subclass, as it is defined, a ``set()`` whose signature and docstring list its
    properties (``Artist._update_set_signature_and_docstring``: an introspection of every setter,
    for ``help()`` and IDEs) — 37 % of the instructions of this import (1876 → 1175 M:
    ``python benchmarks/figure_work.py``), on the critical path of a command whose fit ends before the server can draw.
    A process that only draws PNGs never reads them: ``set(**kwargs)`` works without them, and the
    PNG bytes are the same (tested). Where a matplotlib has no such hook, nothing is changed."""
    import matplotlib.artist as artist

    if callable(getattr(artist.Artist, "_update_set_signature_and_docstring", None)):
        artist.Artist._update_set_signature_and_docstring = classmethod(lambda cls: None)


def _tolerates_no_3d() -> bool:
    """matplotlib ≥ 3.9, whose projection registry imports the 3-D toolkit in a try/except (3.7 and
    3.8.0 import it bare: blocking it there would fail the import). Read from the installed
    distribution's metadata, without importing matplotlib."""
    from importlib import metadata

    try:
        major, minor = (int(x) for x in metadata.version("matplotlib").split(".")[:2])
    except (metadata.PackageNotFoundError, ValueError):
        return False
    return (major, minor) >= (3, 9)


class _FigureServer:
    """A forked process that imports matplotlib at once, then draws each batch of jobs it is sent.

    Forked by :func:`preload` before the captures are loaded, it imports matplotlib on another core
    while this process loads and fits (a thread would take turns with the fit for the interpreter
    lock), and this process never imports matplotlib at all. It draws one stream of jobs at a time
    (:class:`FigureStream`): jobs one by one as they are sent, then, when the stream is finished,
    those left as :func:`render_figures` would draw them here (its own pool, forked from the server,
    so its workers start with matplotlib). The server ignores SIGINT and leaves when this process
    closes its end of the pipe or exits; it never returns into the caller's code (``os._exit``).
    """

    def __init__(self) -> None:
        self.drawn = False  # a stream was opened: the server is past its imports
        self.pending = False  # a stream was opened and its figures not yet collected
        self.conn, child = mp.Pipe()
        _widen_send_buffer(self.conn)
        for stream in (sys.stdout, sys.stderr):  # nothing buffered here is written twice
            stream.flush()
        try:
            # the server ignores Ctrl-C and stops on SIGTERM, from the first instant (a close right
            # after the fork must not run this process's handler in it)
            self.pid = fork_with_handlers({signal.SIGINT: signal.SIG_IGN, signal.SIGTERM: _stop_serving})
        except OSError:
            self.conn.close()
            child.close()
            raise
        if self.pid == 0:  # the server
            code = 0
            try:
                self.conn.close()
                _detach_output()
                _serve(child)
            except BaseException:  # noqa: BLE001 - the parent falls back to drawing itself
                code = 1
            finally:
                os._exit(code)
        child.close()

    def open_stream(self) -> bool:
        """Start a stream (False when the server is still busy with one whose figures were not
        collected: the caller draws here instead)."""
        if self.pending or self.conn.closed:
            return False
        self.drawn = self.pending = True
        return True

    def send(self, message: tuple) -> bool:
        """Send one message of the open stream and return at once (False when the server is gone)."""
        try:
            data = ForkingPickler.dumps(message)
        except Exception:  # noqa: BLE001 - a job that does not pickle: nothing sent, the caller draws here
            return False
        try:
            self.conn.send_bytes(data)
        except (OSError, EOFError, ValueError):
            self.close()
            return False
        return True

    def collect(self) -> list[Path] | None:
        """Wait for the figures of the finished stream: their paths, or None when the server is gone."""
        self.pending = False
        try:
            status, value = self.conn.recv()
        except (OSError, EOFError):
            self.close()
            return None
        except BaseException:  # Ctrl-C while the server draws: stop it, do not wait for the batch
            self.close(stop=True)
            raise
        if status == "error":
            raise value
        return value

    def close(self, stop: bool = False, wait: bool = True) -> None:
        """Close the pipe (the server leaves) and reap the server; ``stop`` terminates it first.
        ``wait=False`` (this process is exiting) waits only for a server that has drawn (it is
        idle and leaves at once), not for one still importing or warming up (an error, ``--help``):
        that one leaves on its own when it next reads the closed pipe."""
        self.conn.close()
        if not (wait or stop or self.drawn):
            return
        try:
            if stop:
                os.kill(self.pid, signal.SIGTERM)
            os.waitpid(self.pid, 0)
        except (ChildProcessError, ProcessLookupError):  # already gone
            pass


#: bytes this process may have sent to the figure server before a send waits for it to read
SEND_BUFFER_BYTES = 4 << 20


def _widen_send_buffer(conn) -> None:
    """Let ``conn`` (this process's end of the figure server's socket pair) hold
    :data:`SEND_BUFFER_BYTES` of jobs not yet read, within the system's limit (Linux:
    ``net.core.wmem_max``). The server reads between two figures, so with the default buffer
    (≈ 200 kB on Linux, one or two conditions' arrays) a send could wait for the figure being drawn
    while this process had fits to do. Nothing changes where the option is refused."""
    import socket

    try:
        with socket.socket(fileno=os.dup(conn.fileno())) as sock:  # the same socket; closing the copy keeps it
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
    except (OSError, ValueError):
        pass


def _stop_serving(signum, frame) -> None:
    """The figure server's SIGTERM (:meth:`_FigureServer.close` with ``stop``, e.g. the caller's
    Ctrl-C while the pool draws): its pool's workers are killed and reaped before it leaves, so
    no figure is written after the caller's wait for the server returns."""
    children = mp.active_children()
    for child in children:
        child.kill()
    for child in children:
        child.join()
    os._exit(1)


def _serve(conn) -> None:
    """The server's loop: import matplotlib and warm up (:func:`_warm_up`), then draw each stream:
    ``("add", jobs)`` queues jobs, ``("prepare", (function, args, kwargs))`` a preparation
    (drawn when no job waits), ``("finish", n_jobs)`` draws what is left and replies with every
    job's path, in order, or the first job's error. Between messages the queue is drawn one job at
    a time, so a job sent while this process works is drawn while it works."""
    # what is imported lives as long as the server: no collection while matplotlib is imported (one
    # full collection walked its objects, ≈ 70 ms beside the command's own start-up on the other
    # core), then out of the garbage collector's walks. A figure makes thousands of small objects,
    # and each full collection walked matplotlib's and numpy's modules too: ≈ 20 % of drawing a
    # diagnosis' figures (benchmarks/diagnose_phases.py --mode figures)
    gc.disable()
    try:
        _import_plotting(lean=True)
        if not conn.poll():  # idle: warm up now; with jobs already waiting, their own first figures do it
            _warm_up()
    finally:
        gc.freeze()
        gc.enable()
    stream = _ServerStream()
    while True:
        if stream.waiting() and not conn.poll():
            stream.draw_next()
            continue
        try:
            kind, payload = conn.recv()
        except EOFError:
            return
        if kind == "add":
            stream.jobs += payload
        elif kind == "prepare":
            stream.preparations.append(payload)
        else:  # "finish"
            try:
                reply = ("ok", stream.finish(payload))
            except Exception as exc:  # noqa: BLE001 - raised again in the caller
                reply = ("error", exc)
            stream = _ServerStream()
            try:
                conn.send(reply)
            except Exception as exc:  # noqa: BLE001 - e.g. an exception that does not pickle
                conn.send(("error", RuntimeError(f"drawing the figures failed: {exc!r}")))


class _ServerStream:
    """The figure server's side of one :class:`FigureStream`."""

    def __init__(self) -> None:
        self.jobs: list[FigureJob | None] = []  # a job drawn one by one is dropped (its arrays freed)
        self.outcomes: list[Path | Exception] = []  # of the jobs drawn one by one, in order
        self.preparations: list[tuple[str, tuple, dict]] = []

    def waiting(self) -> bool:
        return len(self.outcomes) < len(self.jobs) or bool(self.preparations)

    def draw_next(self) -> None:
        """Draw the next queued job, or else run the next preparation."""
        if len(self.outcomes) < len(self.jobs):
            i = len(self.outcomes)
            job, self.jobs[i] = self.jobs[i], None
            self.outcomes.append(_outcome(job))
            return
        function, args, kwargs = self.preparations.pop(0)
        try:
            _function(function)(*args, **kwargs)
        except Exception:  # noqa: BLE001, S110 - a preparation only saves time; the figure is drawn anyway
            pass

    def finish(self, n_jobs: int | None) -> list[Path]:
        """Draw the jobs left (a pool as :func:`render_figures`); every path, or the first error."""
        return _paths(self.outcomes + _outcomes(self.jobs[len(self.outcomes):], n_jobs))


def preload(claim_early: bool = False) -> None:
    """Start importing matplotlib away from this process's work (≈ 0.3–0.5 s), e.g. while a fit runs.

    Where ``fork`` is available and this process runs no other thread (a fork copies locks held by
    other threads), a figure server is forked (:class:`_FigureServer`) and :func:`render_figures`
    hands its jobs to it; otherwise matplotlib is imported in a background thread here. Calling it
    again replaces a server that has not drawn yet, except that ``claim_early`` keeps the one
    :func:`preload_early` started for this command.
    """
    global _preload_thread, _server, _early
    if claim_early and _early and _server is not None:
        _early = False
        return
    _early = False
    _close_server()
    if "fork" in mp.get_all_start_methods() and threading.active_count() == 1:
        try:
            _server = _FigureServer()
            return
        except OSError:  # a fork refused (process or memory limits): matplotlib is imported here
            _server = None
    if _preload_thread is None:
        _preload_thread = threading.Thread(target=_import_plotting, name="hystfit-preload-matplotlib", daemon=True)
        _preload_thread.start()


def preload_early() -> None:
    """:func:`preload` from the console script, before the command line is parsed (≈ 0.3 s earlier
    than the command could), for a command that will probably draw; the command claims the server
    (``preload(claim_early=True)``) or :func:`release_early` closes it unused."""
    global _early
    preload()
    _early = _server is not None


def release_early() -> None:
    """Close a server :func:`preload_early` started that no command claimed (``--help``, an error)."""
    global _early
    if _early:
        _early = False
        _close_server(wait=False)


#: how far a command that computes on every core while its figures are drawn lowers the figure
#: server's priority (:func:`yield_cores`, through ``cli.common.start_figures(behind=True)``):
#: identify and diagnose. +5 gained as much as +10 or +19 in alternate runs of both, and leaves the
#: figures half a normal share on a machine busy with other work
FIGURES_NICE = 5


def yield_cores(nice: int) -> bool:
    """Let the figure server (when one runs) draw on the cores this process's work leaves idle: its
    nice value raised by ``nice`` (its pool's workers inherit it), so while this process and its
    forked children fit on every core the server takes a small share of a core instead of a third
    of each, and draws in the gaps (a serial step, a wait for the last item of a round, a fit on one
    core). For a command whose figures can wait for its computing (identify, diagnose).
    The priority is never raised again (an unprivileged process cannot): on a machine busy with other
    work the figures draw more slowly. False where there is no server or the system refuses."""
    if _server is None or nice <= 0:
        return False
    try:
        os.setpriority(os.PRIO_PROCESS, _server.pid, os.getpriority(os.PRIO_PROCESS, _server.pid) + int(nice))
    except (AttributeError, OSError):  # no setpriority (Windows), or refused
        return False
    return True


def _close_server(wait: bool = True) -> None:
    global _server
    if _server is not None:
        _server.close(wait=wait)
        _server = None


atexit.register(_close_server, wait=False)


def _detach_output() -> None:
    """Point the server's stdout and stderr at the null device: it reports through its pipe, and a
    caller reading this process's output must not wait for a server that outlives it."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for fd in (1, 2):
        os.dup2(devnull, fd)
    os.close(devnull)


def _join_preload() -> None:
    if _preload_thread is not None:
        _preload_thread.join()
    _import_plotting()


def _default_workers() -> int:
    from ..parallel import default_jobs

    return default_jobs()


def render_figures(jobs: Sequence[FigureJob], n_jobs: int | None = None) -> list[Path]:
    """Draw every job's figure; return the paths written, in the order of ``jobs``.

    Parameters
    ----------
    jobs : sequence of FigureJob
    n_jobs : int, optional
        Processes; default all cores. Fewer are used when there are few figures (at least
        :data:`MIN_JOBS_PER_WORKER` each), and none when only one would run.

    Raises
    ------
    Whatever the figure function raises (the first failing job in order), e.g. ``OutputError``.
    """
    return PendingFigures(jobs, n_jobs).result()


class FigureStream:
    """Figures handed to the figure server as they become known, drawn there one by one while this
    process goes on (e.g. fits the next condition); :meth:`result` draws what is left (a pool, as
    :func:`render_figures`) and returns every path in the order the jobs were added.

    Without a server, or while it draws another stream, the jobs are kept and :meth:`result` draws
    them here. :meth:`cancel` stops a server still drawing them (the caller failed or was
    interrupted), so nothing is written after it returns.

    Parameters
    ----------
    n_jobs : int, optional
        Processes for the figures left when the stream is finished, as in :func:`render_figures`.
    """

    def __init__(self, n_jobs: int | None = None) -> None:
        self.jobs: list[FigureJob] = []  # as added
        self._there: list[FigureJob] = []  # the same, at absolute paths
        self.n_jobs = n_jobs
        self._finished = False
        self._server = _server if (_server is not None and _server.open_stream()) else None

    def add(self, jobs: Sequence[FigureJob]) -> None:
        """Queue ``jobs`` (the server starts drawing them at once). Relative paths are taken from
        this process's working directory when added (the server has its own)."""
        if self._finished:
            raise RuntimeError("the figure stream is finished")
        jobs = list(jobs)
        there = [replace(j, path=Path(os.path.abspath(j.path))) for j in jobs]
        self.jobs += jobs
        self._there += there
        if jobs and self._server is not None and not self._server.send(("add", there)):
            self.cancel()  # drawn here: a server left with part of a stream would serve no one else

    def prepare(self, function: str, *args: Any, **kwargs: Any) -> None:
        """Let the server call ``function(*args, **kwargs)`` of :mod:`hystfit.report.plots` (or
        ``"module:function"``) when no job waits, e.g. :func:`~hystfit.report.plots.prepare_overview`:
        work that makes a later figure cheaper. Nothing happens without a server."""
        if self._server is not None and not self._finished and not self._server.send(("prepare", (function, args, kwargs))):
            self.cancel()

    def finish(self) -> None:
        """No more jobs: the server draws those left (a pool), and this process may go on."""
        if not self._finished:
            self._finished = True
            if self._server is not None and not self._server.send(("finish", self.n_jobs)):
                self.cancel()

    def result(self) -> list[Path]:
        """Every job's path in order, once all are drawn (:meth:`finish` first if not yet).

        Raises
        ------
        Whatever the figure function raises (the first failing job in order), e.g. ``OutputError``.
        """
        self.finish()
        server, self._server = self._server, None
        if server is not None:
            drawn = server.collect()
            if drawn is None:
                drawn = _draw_here(self._there, self.n_jobs)
        else:
            drawn = _draw_here(self._there, self.n_jobs)
        # the paths as added (drawn at absolute ones)
        return [j.path if Path(d) == t.path else d for d, j, t in zip(drawn, self.jobs, self._there)]

    def cancel(self) -> None:
        """Stop a server still drawing this stream's figures (it and its pool are gone when this
        returns; the jobs not drawn yet are not drawn)."""
        global _server
        server, self._server = self._server, None
        if server is not None:
            server.close(stop=True)
            if _server is server:
                _server = None


class PendingFigures(FigureStream):
    """Figures all known at once, handed to the figure server to be drawn while this process goes on
    (a finished :class:`FigureStream`); :meth:`result` waits for them."""

    def __init__(self, jobs: Sequence[FigureJob], n_jobs: int | None = None) -> None:
        super().__init__(n_jobs)
        self.add(jobs)
        self.finish()


def _function(name: str):
    """A figure function by name: ``"loop_figure"`` (of :mod:`hystfit.report.plots`) or ``"module:function"``."""
    module, _, function = name.rpartition(":")
    return getattr(importlib.import_module(module or f"{__package__}.plots"), function)


def _render(job: FigureJob) -> Path:
    return Path(_function(job.function)(job.path, *job.args, **job.kwargs))


def _outcome(job: FigureJob) -> Path | Exception:
    try:
        return _render(job)
    except Exception as exc:  # noqa: BLE001 - handed to the caller by _paths
        return exc


def _paths(outcomes: Sequence[Path | Exception]) -> list[Path]:
    """The paths, or the first job's error, in order."""
    for o in outcomes:
        if isinstance(o, Exception):
            raise o
    return list(outcomes)


def _draw_here(jobs: list[FigureJob], n_jobs: int | None) -> list[Path]:
    """:func:`render_figures` in this process: a forked pool, or serially when that cannot pay off."""
    return _paths(_outcomes(jobs, n_jobs))


def _outcomes(jobs: list[FigureJob], n_jobs: int | None) -> list[Path | Exception]:
    """Each job's path or error, drawn in this process's forked pool, or serially when that cannot pay off."""
    _join_preload()
    n = _default_workers() if n_jobs is None else max(1, int(n_jobs))
    n = min(n, math.ceil(len(jobs) / MIN_JOBS_PER_WORKER))
    if n <= 1 or "fork" not in mp.get_all_start_methods():
        return [_outcome(j) for j in jobs]
    from concurrent.futures.process import BrokenProcessPool

    try:
        with ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("fork")) as ex:
            # the biggest figures first, so that no worker is left with a long one at the end
            order = sorted(range(len(jobs)), key=lambda i: -_weight(jobs[i]))
            futs = {i: ex.submit(_outcome, jobs[i]) for i in order}
            return [futs[i].result() for i in range(len(jobs))]
    except (OSError, BrokenProcessPool):  # a fork refused (process or memory limits), a worker killed
        return [_outcome(j) for j in jobs]  # drawn here (a figure drawn twice has the same bytes)


def _warm_up() -> None:
    """Draw a small loop and time-series figure, as a report titles them, and throw them away.

    This lays out the reused figures (:func:`hystfit.report.plots._template`) and fills the font,
    text-layout and text-image caches (:mod:`hystfit.report.canvas`) once, in the figure server,
    while the caller loads and fits: every worker the server forks afterwards starts with them,
    instead of paying for them on its first figure of each kind. Pixels do not depend on these
    caches (tested).
    """
    import io

    import numpy as np

    from . import plots

    t = np.linspace(0.0, 1.0, 200)
    u = 10.0 * (1.0 - np.cos(2 * np.pi * t))
    # into memory: a server stopped during its warm-up (SIGTERM, SIGKILL) leaves nothing on disk
    plots.loop_figure(io.BytesIO(), u, 0.1 * u, 0.1 * u + 0.01, title="warm-up")
    plots.timeseries_figure(io.BytesIO(), t, 0.1 * u, 0.1 * u + 0.01, title="warm-up")


def _weight(job: FigureJob) -> int:
    """Rough cost of a job: panels of an overview count as figures."""
    if job.function == "overview_figure" and job.args:
        return 10 * len(job.args[0])
    return 10
