"""Many figures drawn in parallel: a list of :class:`FigureJob`, one PNG each, the same bytes in any process.

A report collects its figures as jobs (the name of a :mod:`hystfit.report.plots` function, the file,
its arguments) and hands them to :func:`render_figures`, which draws them in a process pool sized
to the cores (or in this process when that cannot pay off) and returns the paths in the order of
the jobs. Each figure depends only on its own arguments, so the files do not depend on the number
of processes.

Workers are forked, not spawned: a spawned worker would spend ≈ 0.5–0.8 s importing numpy and
matplotlib again, more than the figures of a small report take. A figure job touches neither numba
nor BLAS (whose thread pools are not fork-safe), only numpy and matplotlib's Agg canvas, which are
imported in the parent first (:func:`preload`) so every child starts with them. Where ``fork`` is
not available the figures are drawn in this process.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import threading
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

__all__ = ["FigureJob", "preload", "render_figures", "MIN_JOBS_PER_WORKER"]

#: a worker is only started for at least this many figures (≈ 60–100 ms each, against ≈ 30 ms to fork one)
MIN_JOBS_PER_WORKER = 3

_preload_thread: threading.Thread | None = None


@dataclass(frozen=True)
class FigureJob:
    """One figure to draw: ``getattr(plots, function)(path, *args, **kwargs)``.

    Parameters
    ----------
    function : str
        Name of a figure function of :mod:`hystfit.report.plots` (e.g. ``"loop_figure"``).
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


def _import_plotting() -> None:
    from matplotlib import font_manager
    from matplotlib.backends import backend_agg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401

    from . import plots  # noqa: F401

    font_manager.get_font(font_manager.findfont(font_manager.FontProperties()))  # the first text loads the font


def preload() -> None:
    """Start importing matplotlib in a background thread (≈ 0.3–0.5 s), e.g. while a fit runs.

    The fitting code waits on its process pool or runs numba kernels that release the CPU to that
    thread in between; :func:`render_figures` joins the thread before drawing. Calling it twice is harmless.
    """
    global _preload_thread
    if _preload_thread is None:
        _preload_thread = threading.Thread(target=_import_plotting, name="hystfit-preload-matplotlib", daemon=True)
        _preload_thread.start()


def _join_preload() -> None:
    if _preload_thread is not None:
        _preload_thread.join()
    _import_plotting()


def _render(job: FigureJob) -> Path:
    from . import plots

    return Path(getattr(plots, job.function)(job.path, *job.args, **job.kwargs))


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
    jobs = list(jobs)
    _join_preload()
    n = _default_workers() if n_jobs is None else max(1, int(n_jobs))
    n = min(n, math.ceil(len(jobs) / MIN_JOBS_PER_WORKER))
    if n <= 1 or "fork" not in mp.get_all_start_methods():
        return [_render(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("fork")) as ex:
        # the biggest figures first, so that no worker is left with a long one at the end
        order = sorted(range(len(jobs)), key=lambda i: -_weight(jobs[i]))
        futs = {i: ex.submit(_render, jobs[i]) for i in order}
        return [futs[i].result() for i in range(len(jobs))]


def _weight(job: FigureJob) -> int:
    """Rough cost of a job: panels of an overview count as figures."""
    if job.function == "overview_figure" and job.args:
        return 10 * len(job.args[0])
    return 10
