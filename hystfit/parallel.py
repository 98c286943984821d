"""Where cells run: the one executor abstraction of ``identify``, ``compare`` and ``diagnose``.

A *cell* is one independent unit of work (a condition × run of ``identify``, a model × optimizer ×
condition of ``compare``, a base fit of ``diagnose``): ``fn(shared, job)``, where ``shared`` is
data every cell reads (the captures) and ``job`` is small. :func:`run_cells` runs a list of cells on
an :class:`Executor`, reuses the cells a :class:`hystfit.cells.CellStore` already holds (``resume``),
stores each cell as it finishes, and returns the results in the order of the jobs — so the numbers
never depend on the executor, the number of workers or the order in which cells finish.

Two executors:

* :class:`LocalExecutor` — a process pool on this machine whose workers are forked from a fork
  server (multiprocessing's ``forkserver`` on Linux; ``spawn`` elsewhere): a single-threaded
  process that has loaded what cells need once (:mod:`hystfit._pool_preload`). Not forked from
  the command itself, which may run threads (progress bars, a background preparation) and numba's
  thread pool, neither of which survives a fork. ``shared`` is shipped once to each worker (the
  pool's initializer).
* :class:`DaskExecutor` — ``dask.distributed``: a ``LocalCluster`` of ``jobs`` single-threaded
  worker processes, or an existing scheduler (``tcp://host:8786``). ``shared`` is scattered to
  the workers once (``Client.scatter(broadcast=True)``), not once per cell. Optional extra
  ``hystfit[dask]``.

Every worker runs single-threaded kernels (one BLAS/OpenMP/numba thread), so workers × threads
never exceed the cores. A cell that raises (other than a :class:`~hystfit.errors.HystfitError`,
which is the user's and re-raised at once) or whose worker is lost is retried once; if it fails
again the result is a :class:`CellFailed` and the batch goes on.
"""

from __future__ import annotations

import functools
import logging
import multiprocessing as mp
import os
import select
import signal
import sys
import threading
import time
import traceback
import warnings
from abc import ABC, abstractmethod
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Optional, Sequence, TypeVar

from ._blas import BLAS_THREAD_VARS, user_chose_blas_threads  # noqa: F401 - BLAS_THREAD_VARS: its home
from ._process import alive, fork_with_handlers
from .errors import ConfigError, HystfitError

J = TypeVar("J")
R = TypeVar("R")

#: thread-count variables of BLAS/OpenMP/numba, set to 1 for pool workers
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")

#: attempts per cell: the first and one retry
ATTEMPTS = 2

#: executor names accepted by ``--executor``
EXECUTORS = ("local", "dask")

#: install command of the optional Dask extra (named in the error when it is missing)
DASK_INSTALL = 'pip install "hystfit[dask]"'


def default_jobs() -> int:
    """All cores available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def single_threaded_children():
    """Within the block, every thread-count variable (:data:`THREAD_VARS`) is 1: a worker, or the
    pools' fork server, started now inherits that environment and runs one thread of each kind."""
    saved = {k: os.environ.get(k) for k in THREAD_VARS}
    os.environ.update({k: "1" for k in THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


_blas_lock = threading.Lock()
_blas_depth = 0
_blas_limits = None  # threadpoolctl's limits while the outermost block runs


def _new_blas_lock() -> None:  # a child forked while another thread held the lock gets a free one
    global _blas_lock
    _blas_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_new_blas_lock)


def _enter_one_blas_thread() -> None:
    global _blas_depth, _blas_limits
    with _blas_lock:
        if _blas_depth == 0 and not user_chose_blas_threads():
            try:
                import scipy.linalg  # noqa: F401 - scipy's own BLAS loaded now, so that it is limited too
                from threadpoolctl import threadpool_limits

                with warnings.catch_warnings():  # threadpoolctl's notes (two OpenMP runtimes…) are not the call's
                    warnings.simplefilter("ignore")
                    _blas_limits = threadpool_limits(limits=1, user_api="blas")
            except Exception:  # noqa: BLE001 - the limit only saves time: the call runs with the threads as they are
                _blas_limits = None
        _blas_depth += 1  # last: a call that never got here is not counted


def _exit_one_blas_thread() -> None:
    global _blas_depth, _blas_limits
    with _blas_lock:
        _blas_depth -= 1
        if _blas_depth == 0 and _blas_limits is not None:
            limits, _blas_limits = _blas_limits, None
            try:
                limits.restore_original_limits()
            except Exception:  # noqa: BLE001, S110 - as above
                pass


def one_blas_thread(fn: Callable[..., R]) -> Callable[..., R]:
    """Run ``fn`` with one BLAS thread (numpy's and scipy's), as the command line does.

    The command line sets ``OPENBLAS_NUM_THREADS`` and its kin to 1 before numpy loads
    (:mod:`hystfit.cli`); a program that imports hystfit as a library has a BLAS thread per core,
    and hystfit's small matrix products, run beside forked children, then fight over the cores:
    ``diagnose`` on sample_data took about 33 s instead of 8 s, with other numbers than the
    command line's (``python benchmarks/library_threads.py``). The library's entry points (``identify``,
    ``compare``, ``diagnose``, ``fit_recommended``, ``invert_target``, ``track``,
    ``measure_bandwidths``) are wrapped in this: for the duration of the call, and in the children
    it forks, numpy's and scipy's BLAS run one thread (threadpoolctl; ``scipy.linalg`` is imported
    first, as every fit does anyway, so that scipy's own BLAS is loaded and limited too). The
    caller's counts are restored on return. A user who set one of :data:`BLAS_THREAD_VARS` has
    chosen, and is left alone (the command line's own defaults, set after numpy had loaded, are
    not a choice: :mod:`hystfit._blas`). Where the limit cannot be set (threadpoolctl missing or failing),
    the call runs with the threads as they are: it only costs time.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        _enter_one_blas_thread()
        try:
            return fn(*args, **kwargs)
        finally:
            _exit_one_blas_thread()

    return wrapper


@dataclass(frozen=True)
class CellFailed:
    """A cell that failed on every attempt (an exception, or its worker was lost)."""

    error: str
    attempts: int


@dataclass
class CellStats:
    """What a batch did: cells computed here, reused from the store, failed; its wall time."""

    computed: int = 0
    reused: int = 0
    failed: int = 0
    wall_time_s: float = 0.0

    def add(self, other: "CellStats") -> None:
        self.computed += other.computed
        self.reused += other.reused
        self.failed += other.failed
        self.wall_time_s += other.wall_time_s

    @property
    def total(self) -> int:
        return self.computed + self.reused + self.failed


def describe_error(exc: BaseException) -> str:
    """One line: the exception and the function it was raised in."""
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" ({tb[-1].name})" if tb else ""
    return f"{exc.__class__.__name__}: {exc}{where}"


# ------------------------------------------------------------------------------------------ workers
_SHARED: Any = None
_SINGLE_THREADED = False


def _single_threaded() -> None:
    """One numba thread in this worker process (once per process).

    numba guards the start of its threading layer with a multiprocessing lock of the process's
    default start method. In a fork server's (or spawned) worker that is a *named* semaphore,
    registered with multiprocessing's resource tracker; a worker stopped at once (Ctrl-C,
    SIGTERM, :func:`_stop_now`) cannot unregister it, and the tracker then printed "There appear
    to be 2 leaked semaphore objects" after the command's one error line. Made while the default
    is ``fork``, the lock is anonymous (no name, nothing to track or leak)."""
    global _SINGLE_THREADED
    if _SINGLE_THREADED:
        return
    _SINGLE_THREADED = True
    saved = mp.get_start_method(allow_none=True)
    anonymous = "fork" in mp.get_all_start_methods() and saved != "fork"
    try:
        import numba

        if anonymous:
            mp.set_start_method("fork", force=True)
        numba.set_num_threads(1)
    except Exception:  # pragma: no cover - numba without threading layer
        pass
    finally:
        if anonymous:
            mp.set_start_method(saved, force=True)


def _init_worker(shared: Any, client_pid: int | None = None) -> None:
    # Ctrl-C reaches the whole process group: the parent alone decides (it terminates the workers),
    # so the workers ignore SIGINT instead of each printing a KeyboardInterrupt traceback.
    global _SHARED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _single_threaded()
    _SHARED = shared
    if client_pid is not None:
        _end_with(client_pid)


#: seconds between two looks at the command's process where the system cannot notify its end
WATCH_INTERVAL_S = 0.5


def _end_with(pid: int) -> None:
    """End this worker as soon as process ``pid`` (the command whose pool it serves) has ended.

    A pool's workers wait for their next cell on a queue whose writing end each of them holds
    too, and a fork server's workers keep the server alive: when the command is killed (SIGKILL,
    the out-of-memory killer; or SIGTERM outside the console script) nothing else would end them,
    and they stay idle forever with the command's data in memory (hundreds of MB each). A daemon
    thread waits for ``pid``'s end — a pidfd on Linux, otherwise a look every
    :data:`WATCH_INTERVAL_S` — and leaves at once; the fork server leaves when its last worker has."""

    def watch() -> None:
        try:
            fd = os.pidfd_open(pid)
        except (AttributeError, OSError):  # not Linux ≥ 5.3, or the process is already gone
            fd = None
        if fd is not None:
            select.select([fd], [], [])  # readable when the process has ended
        else:
            while alive(pid):
                time.sleep(WATCH_INTERVAL_S)
        os._exit(1)

    threading.Thread(target=watch, name="hystfit-end-with-command", daemon=True).start()



def _call_pool(fn: Callable, job: Any) -> Any:
    return fn(_SHARED, job)


def _hystfit_version() -> str:
    """The running hystfit's version, read at call time (a worker reports its own)."""
    return sys.modules[__package__].__version__


def _call_dask(fn: Callable, shared: Any, job: Any) -> Any:
    _single_threaded()
    return fn(shared, job)


# ---------------------------------------------------------------------------------------- executors
class Executor(ABC):
    """Runs cells ``fn(shared, job)``; yields ``(index, result or CellFailed)`` as cells finish."""

    name: str = ""

    def __init__(self) -> None:
        self.workers = 1

    @abstractmethod
    def run(self, fn: Callable[[Any, J], R], shared: Any,
            items: Sequence[tuple[int, J]]) -> Iterator[tuple[int, R | CellFailed]]:
        """Run every ``(index, job)`` of ``items``; yield each index with its outcome when it finishes."""

    def close(self) -> None:
        """Release the workers (a no-op for executors that hold none between runs)."""

    @contextmanager
    def holding(self):
        """Within the block, consecutive runs with the same ``shared`` object may reuse the workers
        (a local pool is not started twice); they are released when the block ends. A no-op for
        executors whose workers outlive a run anyway (dask)."""
        yield self

    def start(self, shared: Any, n_items: int) -> None:
        """Within :meth:`holding`, start the workers of a coming run now (a no-op here)."""

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> str:
        return f"{self.name} ({self.workers} worker{'s' if self.workers != 1 else ''})"


def _inline(fn: Callable, shared: Any, job: Any) -> Any:
    """One cell in this process, with its retry."""
    for attempt in range(1, ATTEMPTS + 1):
        try:
            return fn(shared, job)
        except HystfitError:
            raise
        except Exception as exc:  # noqa: BLE001 - a crashed cell is retried, then reported in its cell
            if attempt == ATTEMPTS:
                return CellFailed(describe_error(exc), attempt)
    raise AssertionError("unreachable")  # pragma: no cover


class LocalExecutor(Executor):
    """A process pool on this machine (serial in this process for one job or one cell).

    Workers are forked from the fork server of :func:`pool_context` (a fresh interpreter where
    there is none): they start with hystfit, numpy, scipy and numba loaded and set up, which a
    fresh interpreter would do again in each worker (``benchmarks/pool_start.py``).

    At most ``workers`` cells are in flight, so a lost worker (the pool breaks) costs an attempt
    only to the cells that were running; the pool is rebuilt and those cells are retried one at a
    time (so a cell that kills its worker again fails alone), and the batch goes on.
    """

    name = "local"

    def __init__(self, jobs: int | None = None) -> None:
        super().__init__()
        self.workers = default_jobs() if jobs is None else max(1, int(jobs))
        self._held = False
        self._kept: tuple | None = None  # (pool, shared, workers) kept for the next run while held

    @contextmanager
    def holding(self):
        self._held = True
        try:
            yield self
        finally:
            self._held = False
            self._release()

    def start(self, shared: Any, n_items: int) -> None:
        """Within :meth:`holding`: start now the workers a run of ``n_items`` with this ``shared``
        data will use (they import while this process goes on). Their environment is set while
        they start (:func:`single_threaded_children`); a caller that then runs threads beside the
        run changes no environment variable under them. A no-op outside :meth:`holding`, or when
        the run would be serial."""
        n = min(self.workers, n_items)
        if not self._held or self.workers == 1 or n_items <= 1 or self._reusable(shared, n):
            return
        self._release()
        ex = self._pool(n, shared)
        with single_threaded_children():
            for _ in range(n):  # a new pool starts a worker at each submit until it has n
                ex.submit(_call_pool, _started, None)
        self._kept = (ex, shared, n)

    def _reusable(self, shared: Any, n: int) -> bool:
        kept = self._kept
        return (kept is not None and kept[1] is shared and kept[2] >= n
                and not getattr(kept[0], "_broken", False))  # a worker lost while idle breaks the pool

    @staticmethod
    def _pool(n: int, shared: Any):
        return _ProcessPool(max_workers=n, mp_context=pool_context(), initializer=_init_worker,
                            initargs=(shared, os.getpid()))

    def _release(self) -> None:
        kept, self._kept = self._kept, None
        if kept is not None:
            _shut_down(kept[0])

    def run(self, fn, shared, items):
        if self.workers == 1 or len(items) <= 1:
            for i, job in items:
                yield i, _inline(fn, shared, job)
            return

        n = min(self.workers, len(items))
        ex = None
        if self._reusable(shared, n):
            ex, _, n = self._kept  # the workers of the previous run (or of start()), with the same data
            self._kept = None
        else:
            self._release()
        queue = list(items)[::-1]  # pop() takes the next cell in job order
        attempts: dict[int, int] = {}
        lost = "the worker process was lost (killed or out of memory)"
        running: dict = {}
        suspects: set[int] = set()
        try:
            while queue or running:
                fresh = ex is None
                if fresh:
                    ex = self._pool(n, shared)
                while queue and len(running) < n:
                    # a cell that was running when a worker died runs alone: if it kills its worker
                    # again, it alone is to blame and the cells beside it keep their attempts
                    if running and (queue[-1][0] in suspects or any(k in suspects for k, _ in running.values())):
                        break
                    i, job = queue.pop()
                    try:
                        running[_submit(ex, n, fn, job)] = (i, job)
                    except BrokenProcessPool:  # lost before this cell reached it: no attempt charged
                        queue.append((i, job))
                        break
                    except OSError as exc:  # a worker cannot be started (process or memory limits)
                        left = sorted([(i, job), *queue, *running.values()], key=lambda item: item[0])
                        _stop_now(ex)
                        ex, running, queue = None, {}, []
                        warnings.warn(f"hystfit: the worker processes could not be started ({exc}); the "
                                      f"{len(left)} cells left run in this process", RuntimeWarning, stacklevel=2)
                        for k, item in left:  # no attempt charged: the same numbers, one at a time
                            yield k, _inline(fn, shared, item)
                        return
                    attempts[i] = attempts.get(i, 0) + 1
                if not running:  # the pool broke before any cell was submitted to it: a new one
                    _stop_now(ex)
                    ex = None
                    if fresh:  # a new pool that breaks at once cannot run anything
                        raise BrokenProcessPool("the process pool's workers could not be started")
                    continue
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                broken = False
                for fut in done:
                    i, job = running.pop(fut)
                    try:
                        yield i, fut.result()
                    except HystfitError:
                        raise
                    except BrokenProcessPool:
                        broken = True
                        suspects.add(i)
                        if attempts[i] < ATTEMPTS:
                            queue.append((i, job))
                        else:
                            yield i, CellFailed(lost, attempts[i])
                    except Exception as exc:  # noqa: BLE001 - retried, then reported in its cell
                        if attempts[i] < ATTEMPTS:
                            queue.append((i, job))
                        else:
                            yield i, CellFailed(describe_error(exc), attempts[i])
                if broken:  # every cell still in flight died with the pool: one attempt each
                    suspects.update(i for i, _ in running.values())
                    for i, job in running.values():
                        if attempts[i] < ATTEMPTS:
                            queue.append((i, job))
                        else:
                            yield i, CellFailed(lost, attempts[i])
                    running = {}
                    _stop_now(ex)
                    ex = None
        except BaseException:
            if ex is not None:
                _stop_now(ex)
            raise
        if ex is not None:
            if self._held:
                self._kept = (ex, shared, n)
            else:
                _shut_down(ex)

    def close(self) -> None:
        self._release()


#: the modules the pools' fork server imports, in order, before it forks any worker: Ctrl-C ignored
#: first (:mod:`hystfit._pool_signals`), then what every worker needs
POOL_PRELOAD = ("hystfit._pool_signals", "hystfit._pool_preload")


def pool_context():
    """The multiprocessing context of :class:`LocalExecutor`'s pools: ``forkserver`` on Linux, with
    :data:`POOL_PRELOAD` loaded by the server, else ``spawn`` (on macOS, as Python itself chooses,
    because system frameworks there, Accelerate's BLAS among them, are not safe in a forked child;
    Windows has no fork).

    The fork server is one process per Python process, started (a fresh interpreter, with this
    process's environment and ``sys.path`` at that moment) when the first pool starts its first
    worker; :func:`single_threaded_children` is in force then, so the server and every worker
    forked from it run one BLAS/OpenMP/numba thread. It ignores Ctrl-C and ends with this process,
    however this process ends (killed too: each worker leaves when this process has ended,
    :func:`_end_with`, and the server when its last worker has): a long Python session (a notebook)
    keeps it idle in between, ≈ 190 MB resident on Linux, about half of it shared libraries.

    Where the fork server cannot start, ``spawn`` is used instead (the same numbers, slower
    workers): its socket lives in the temporary directory, and a Unix socket's path is limited to
    107 bytes, which a long ``TMPDIR`` (a cluster job's scratch directory) exceeds.
    """
    if not sys.platform.startswith("linux") or "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(list(POOL_PRELOAD))
    return ctx if _fork_server_running() else mp.get_context("spawn")


def start_pool_server() -> None:
    """Start the local pools' fork server now (:func:`pool_context`; nothing where there is none, or
    when it runs already): it loads :data:`POOL_PRELOAD` — hystfit, numba and its set-up,
    ``scipy.optimize`` — while this process goes on, e.g. reads the captures, instead of after."""
    pool_context()


def _fork_server_running() -> bool:
    """Start the pools' fork server if it is not running (with :func:`single_threaded_children` in
    force, as for a worker); False when it cannot start (an OSError: e.g. its socket's path too
    long, no usable temporary directory)."""
    from multiprocessing import forkserver

    try:
        with single_threaded_children():
            forkserver.ensure_running()
    except OSError:
        return False
    return True


def _started(shared: Any, job: Any) -> None:
    """The job :meth:`LocalExecutor.start` submits: each submit starts a worker."""


def _submit(ex, n: int, fn: Callable, job: Any):
    """``ex.submit`` of one cell. A pool starts a worker (and the fork server its first one) inside
    ``submit`` while it has fewer than ``n``: only then is the environment set for it
    (:func:`single_threaded_children`), so no variable changes under other threads of this process
    once the workers run. ``_processes`` is
    the executor's own table of workers (no public accessor)."""
    if len(getattr(ex, "_processes", None) or {}) < n:
        with single_threaded_children():
            return ex.submit(_call_pool, fn, job)
    return ex.submit(_call_pool, fn, job)


class _ProcessPool:
    """Lazy import wrapper: ``concurrent.futures.ProcessPoolExecutor``."""

    def __new__(cls, **kw):

        return ProcessPoolExecutor(**kw)


def _stop_now(ex) -> None:
    """Stop a pool at once (Ctrl-C, an error): drop the queued jobs and terminate the running ones.

    ``shutdown(cancel_futures=True)`` alone waits for the jobs already running, which is a whole
    fit each (30-45 s for ``compare``), so the workers are terminated first. ``_processes`` is the
    executor's own table of workers (no public accessor).

    The pool's manager thread is then joined (``_executor_manager_thread``, private too): it closes
    the pipe that wakes it up, and Python's exit handler of ``concurrent.futures``
    (``_python_exit``, 3.11) writes to that pipe without a lock. Left running, it raced the exit of
    an interrupted command: now and then ``OSError: [Errno 9] Bad file descriptor`` and a traceback
    after the command's own error line. Its workers terminated, the thread ends within
    milliseconds; the timeout only bounds a pathological case.
    """
    procs = list((getattr(ex, "_processes", None) or {}).values())
    manager = getattr(ex, "_executor_manager_thread", None)
    for p in procs:
        try:
            p.terminate()
        except Exception:  # noqa: BLE001 - already gone
            pass
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.join(timeout=1.0)
    if manager is not None and manager is not threading.current_thread():
        manager.join(timeout=5.0)


def _shut_down(ex) -> None:
    """The end of a pool whose jobs are done: ``shutdown(wait=True)``, or :func:`_stop_now` if that
    wait is interrupted (Ctrl-C just as the last job ends), so that no manager thread is left
    closing its pipe while the command exits."""
    try:
        ex.shutdown(wait=True)
    except BaseException:
        _stop_now(ex)
        raise


@contextmanager
def _sigint_ignored():
    """SIGINT ignored while child processes are started (they inherit it); a no-op off the main thread."""

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


def _import_distributed():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ConfigError(f"--executor dask: dask.distributed is not installed; install the optional extra with "
                          f"{DASK_INSTALL} (or use --executor local)") from None
    return distributed


class DaskExecutor(Executor):
    """``dask.distributed``: a LocalCluster of ``jobs`` single-threaded worker processes, or the
    scheduler at ``scheduler`` (``tcp://host:8786``). The workers need hystfit importable."""

    name = "dask"

    def __init__(self, jobs: int | None = None, scheduler: str | None = None) -> None:
        super().__init__()
        distributed = _import_distributed()

        import dask

        self.cluster = None
        self.scheduler = scheduler
        if scheduler:
            try:
                self.client = distributed.Client(scheduler, timeout="15s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc}); start one with 'dask scheduler' "
                                  "and 'dask worker ADDRESS', or leave out --scheduler for a local cluster") from None
            self._check_workers(scheduler)
            self.workers = max(1, sum(w.get("nthreads", 1)
                                      for w in self.client.scheduler_info().get("workers", {}).values()))
        else:
            self.workers = default_jobs() if jobs is None else max(1, int(jobs))
            # no dashboard, so no statistical profiler either (it samples every worker's stack 100 times a
            # second); the worker processes start with SIGINT ignored (inherited): Ctrl-C reaches the whole
            # process group, and the driver alone stops the cluster, as for the local pool
            with single_threaded_children(), dask.config.set({"distributed.worker.profile.enabled": False}), \
                    _sigint_ignored():
                self.cluster = distributed.LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                                        dashboard_address=None, silence_logs=logging.ERROR)
            self.client = distributed.Client(self.cluster)

    def _check_workers(self, scheduler: str) -> None:
        """Every worker of an existing cluster runs this hystfit version (the cells' code and keys)."""
        __version__ = _hystfit_version()
        try:
            versions = self.client.run(_hystfit_version)
        except Exception as exc:  # noqa: BLE001 - e.g. hystfit not importable on a worker
            self.client.close()
            raise ConfigError(f"--scheduler {scheduler}: a worker cannot run hystfit ({describe_error(exc)}); "
                              f"install hystfit {__version__} on every worker (pip install \"hystfit[dask]\")") from None
        other = sorted({v for v in versions.values() if v != __version__})
        if other:
            self.client.close()
            raise ConfigError(f"--scheduler {scheduler}: workers run hystfit {', '.join(other)}, this is "
                              f"{__version__}; install the same version on every worker")

    def run(self, fn, shared, items):
        from distributed import as_completed

        if not items:
            return
        shared_f = self.client.scatter(shared, broadcast=True, hash=False) if shared is not None else None
        futs = {}
        try:
            for i, job in items:
                f = self.client.submit(_call_dask, fn, shared_f, job, pure=False, retries=ATTEMPTS - 1)
                futs[f] = i
            for f in as_completed(list(futs)):
                i = futs[f]
                try:
                    yield i, f.result()
                except HystfitError:
                    raise
                except Exception as exc:  # noqa: BLE001 - retried by dask, then reported in its cell
                    yield i, CellFailed(describe_error(exc), ATTEMPTS)
                f.release()
        except BaseException:
            self.client.cancel(list(futs))
            raise

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def describe(self) -> str:
        where = self.scheduler or "a local cluster"
        return f"dask on {where} ({self.workers} worker thread{'s' if self.workers != 1 else ''})"


def make_executor(kind: str = "local", jobs: int | None = None, scheduler: str | None = None) -> Executor:
    """The executor named by ``--executor`` (``local`` or ``dask``), sized by ``--jobs``."""
    kind = (kind or "local").strip().lower()
    if kind not in EXECUTORS:
        raise ConfigError(f"--executor {kind!r}: choose one of {', '.join(EXECUTORS)}")
    if scheduler and kind != "dask":
        raise ConfigError(f"--scheduler {scheduler}: needs --executor dask")
    if kind == "dask":
        return DaskExecutor(jobs, scheduler)
    return LocalExecutor(jobs)


# ----------------------------------------------------------------------------------------- batches
#: tests set this to stop a batch (KeyboardInterrupt) after that many cells were computed and stored
STOP_AFTER_CELLS: Optional[int] = None


def run_cells(fn: Callable[[Any, J], R], jobs: Sequence[J], *, shared: Any = None,
              executor: Executor | None = None, store=None, keys: Sequence[str] | None = None,
              resume: bool = False, on_done: Optional[Callable[[int, Any, bool], None]] = None,
              stats: CellStats | None = None) -> list[R | CellFailed]:
    """``[fn(shared, j) for j in jobs]`` on ``executor`` (default: this process), in job order.

    With a ``store`` (a :class:`hystfit.cells.CellStore`) and ``keys`` (one per job), every cell
    is stored as it finishes; with ``resume`` the cells already stored under their key are reused
    and not computed. Failed cells (:class:`CellFailed`) are not stored. ``on_done(index, result,
    reused)`` is called in this process as each cell finishes; ``stats`` counts what happened.
    """
    t0 = time.perf_counter()
    stats = stats if stats is not None else CellStats()
    start = CellStats(stats.computed, stats.reused, stats.failed)
    results: dict[int, Any] = {}
    todo = []
    for i, job in enumerate(jobs):
        if store is not None and resume:
            hit = store.get(keys[i])
            if hit is not None:
                results[i] = hit
                stats.reused += 1
                if on_done:
                    on_done(i, hit, True)
                continue
        todo.append((i, job))
    ex = executor if executor is not None else LocalExecutor(1)
    outcomes = ex.run(fn, shared, todo)
    try:
        for i, out in outcomes:
            results[i] = out
            if isinstance(out, CellFailed):
                stats.failed += 1
            else:
                stats.computed += 1
                if store is not None:
                    store.put(keys[i], out)
            if on_done:
                on_done(i, out, False)
            if STOP_AFTER_CELLS is not None and stats.computed - start.computed >= STOP_AFTER_CELLS:
                raise KeyboardInterrupt(f"test hook: stopped after {STOP_AFTER_CELLS} cells")
    finally:
        outcomes.close()  # stops the workers at once when this loop is left by an exception (Ctrl-C)
        stats.wall_time_s += time.perf_counter() - t0
    return [results[i] for i in range(len(jobs))]


# ------------------------------------------------------------------------------------ forked maps
#: children of :func:`fork_call` computing now (started and neither waited for nor stopped)
_IN_FLIGHT = 0


def fork_workers(workers: int | None = None) -> int:
    """Processes :func:`fork_map` uses: ``workers``, by default all cores, less one per child of
    :func:`fork_call` still computing (it has a core already: a fork_map beside it would only take
    that core's time from it) — one inside a pool worker (it already has its core) or where
    ``fork`` is not available."""
    if _SINGLE_THREADED or "fork" not in mp.get_all_start_methods():
        return 1
    return max(1, (default_jobs() if workers is None else int(workers)) - _IN_FLIGHT)


def _claim_next(claim) -> int:
    """The next unclaimed item of :func:`fork_map` (a shared counter, incremented under its lock)."""
    with claim.get_lock():
        i = claim.value
        claim.value += 1
    return i


def _private_numba_init_lock() -> None:
    """In a forked child: numba's lock around the start of its threading layer made this process's own.

    numba makes that lock once per process, a multiprocessing RLock, and takes it at every
    ``set_num_threads`` (:func:`_single_threaded`) and kernel launch. A forked child inherits the
    parent's, one semaphore shared by the parent and all its children: a child stopped while it
    holds it (:meth:`ForkedCall.cancel`, the SIGTERM of :func:`fork_map`, SIGKILL) leaves it held
    for ever, and every later child — and the parent — waits on it without end. The lock guards
    the start of threads in one process; a child's own is all it needs."""
    mod = sys.modules.get("numba.np.ufunc.parallel")
    if mod is not None and getattr(mod, "_backend_init_process_lock", None) is not None:
        mod._backend_init_process_lock = threading.RLock()


def _fork_child(fn: Callable[[int], Any], n: int, claim, conn, kernels: bool = True) -> None:
    """A child of :func:`fork_map`: claims items until none is left, then sends ``{index: result}``.
    SIGTERM (the parent stopping it) ends it at once, whatever handler the parent had (set by
    :func:`_fork_one` before any signal reaches the child). ``kernels``:
    its items may run numba kernels (one numba thread; False: numba is left as it is, not imported)."""
    _private_numba_init_lock()
    if kernels:
        _single_threaded()
    done: dict[int, Any] = {}
    try:
        while (i := _claim_next(claim)) < n:
            done[i] = fn(i)
    except BaseException:  # noqa: BLE001 - whatever this child did not return, the parent computes (and raises)
        pass
    try:
        conn.send(done)
    except BaseException as exc:  # noqa: BLE001 - results that do not pickle: the parent is told why
        try:
            conn.send(f"{type(exc).__name__}: {exc}")
        except BaseException:  # noqa: BLE001 - the pipe is gone: the parent recomputes all
            pass


def _fork_one(fn: Callable[[int], Any], n: int, claim, kernels: bool = True) -> tuple[int, Any]:
    """Fork one child of :func:`fork_map`; its pid and the parent's end of its pipe."""
    recv, send = mp.get_context("fork").Pipe(duplex=False)
    for stream in (sys.stdout, sys.stderr):  # nothing buffered here is written twice
        stream.flush()
    parent = os.getpid()
    try:
        # SIGTERM (the parent stopping it) ends the child at once, whatever handler the parent has
        pid = fork_with_handlers({signal.SIGINT: signal.SIG_IGN, signal.SIGTERM: signal.SIG_DFL})
    except OSError:
        recv.close()
        send.close()
        raise
    if pid == 0:
        code = 0
        try:
            recv.close()
            _end_with(parent)  # a parent killed outright (SIGKILL) does not leave its children computing
            _fork_child(fn, n, claim, send, kernels)
        except BaseException:  # noqa: BLE001 - never return into the caller's code
            code = 1
        finally:
            os._exit(code)
    send.close()
    return pid, recv


class ForkedCall:
    """``fn()`` computed in a forked child while this process goes on (:func:`fork_call`):
    :meth:`result` waits for it — computing it here when the child could not return it, so an
    exception is raised here as in a plain call —, :meth:`cancel` stops the child when its result
    is not needed after all. Use one or the other, once (:meth:`sent` may look before)."""

    _NOTHING = object()

    def __init__(self, fn: Callable[[], R], pid: int, conn) -> None:
        global _IN_FLIGHT
        self.fn, self.pid, self.conn = fn, pid, conn
        self._message: Any = ForkedCall._NOTHING
        _IN_FLIGHT += 1

    def _receive(self) -> Any:
        """The child's message, read once: ``{0: value}``, the text of a result that did not pickle,
        or ``{}`` (it died)."""
        if self._message is ForkedCall._NOTHING:
            try:
                got = self.conn.recv()
            except (EOFError, OSError):  # the child died
                got = {}
            except BaseException:  # Ctrl-C or SIGTERM while waiting: stop the child, do not wait for its work
                self._end(stop=True)
                raise
            self._message = got
            self._end(stop=False)
        return self._message

    def result(self) -> R:
        got = self._receive()
        if isinstance(got, str):  # the same numbers, computed twice: a bug to see, not to hide
            warnings.warn(f"fork_call: the child's result could not be sent back ({got}); it is computed again "
                          f"in this process", RuntimeWarning, stacklevel=2)
        return got[0] if isinstance(got, dict) and 0 in got else self.fn()

    def sent(self) -> tuple[bool, Any]:
        """``(True, value)`` once the child has sent its result; ``(False, None)`` while it has not,
        or when it sent none (it died, its result did not pickle: :meth:`result` computes it then).
        Never waits, never computes here: safe anywhere, e.g. inside an import."""
        if self._message is ForkedCall._NOTHING and not self.ready():
            return False, None
        got = self._receive()
        return (True, got[0]) if isinstance(got, dict) and 0 in got else (False, None)

    def ready(self) -> bool:
        """The child has sent its result (or died): :meth:`result` will not wait."""
        if self._message is not ForkedCall._NOTHING:
            return True
        try:
            return self.pid is None or self.conn.poll()
        except (EOFError, OSError):
            return True

    def cancel(self) -> None:
        self._end(stop=True)

    def _end(self, stop: bool) -> None:
        global _IN_FLIGHT
        if self.pid is None:
            return
        pid, self.pid = self.pid, None
        _IN_FLIGHT -= 1
        self.conn.close()
        try:
            if stop:
                os.kill(pid, signal.SIGTERM)
            os.waitpid(pid, 0)
        except (ChildProcessError, ProcessLookupError):
            pass


class ForkedExecutor(Executor):
    """Cells on this process and forked children (:func:`fork_map`), each with the retry of a cell
    run here: for a short batch of cells that read data already in this process, where starting a
    pool would cost more than the cells (no fork server, no pickled shared data; each child
    returns its results at the end). The results come in job order once every cell is done, the
    same numbers as one process gives."""

    name = "forked"

    def __init__(self, workers: int | None = None) -> None:
        super().__init__()
        self.workers = fork_workers(workers)

    def run(self, fn, shared, items):
        items = list(items)
        out = fork_map(lambda k: _inline(fn, shared, items[k][1]), len(items), self.workers)
        for (i, _), res in zip(items, out):
            yield i, res


def fork_call(fn: Callable[[], R], workers: int | None = None, *, kernels: bool = True) -> ForkedCall | None:
    """Start ``fn()`` (deterministic, reading data already in this process) in a forked child, or
    None where :func:`fork_map` with ``workers`` would not fork (one process inside pool workers,
    no ``fork``, one worker, a fork the system refuses): then the caller computes it itself when
    it needs it. ``kernels=False``: ``fn`` runs no numba kernel, and the child does not set numba
    up (nor import it, when this process has not)."""
    if fork_workers(workers) <= 1:
        return None
    try:
        claim = mp.get_context("fork").Value("l", 0)  # a semaphore: none where /dev/shm is missing
        pid, conn = _fork_one(lambda i: fn(), 1, claim, kernels)
    except (OSError, ImportError):
        return None
    return ForkedCall(fn, pid, conn)


def fork_map(fn: Callable[[int], R], n: int, workers: int | None = None) -> list[R]:
    """``[fn(i) for i in range(n)]``, spread over this process and forked children.

    Meant for short batches of independent, deterministic items that read large data already in
    this process (the forked children see it without copying or pickling): this process and up to
    ``fork_workers(workers) − 1`` children claim the next unclaimed index in turn (so the items
    balance themselves; put the longest first), each child returns its results at the end, and the
    list is in index order — the results never depend on the number of processes. An item a child
    did not return (it raised, or died) is computed here, so its exception, if any, is raised here
    as in a serial loop; results that do not pickle are computed here too, with a RuntimeWarning
    (the work is done twice). Serial for one worker or one item; a fork the system refuses
    (process or memory limits) leaves fewer children, or none.
    """
    k = min(fork_workers(workers), n)
    if k <= 1:
        return [fn(i) for i in range(n)]
    claim = mp.get_context("fork").Value("l", 0)
    children = []
    for _ in range(k - 1):
        try:
            children.append(_fork_one(fn, n, claim))
        except OSError:  # a fork refused (process or memory limits): fewer processes, the same results
            break
    results: dict[int, Any] = {}
    try:
        while (i := _claim_next(claim)) < n:
            results[i] = fn(i)
        for pid, conn in children:
            try:
                got = conn.recv()
            except (EOFError, OSError):  # the child died: its items are computed below
                continue
            if isinstance(got, str):  # the same numbers, computed twice: a bug to see, not to hide
                warnings.warn(f"fork_map: a child's results could not be sent back ({got}); "
                              f"its items are computed again in this process", RuntimeWarning, stacklevel=2)
            else:
                results.update(got)
    finally:
        for pid, conn in children:
            conn.close()
            try:
                if len(results) < n:  # left early (an exception here): do not wait for the child's items
                    os.kill(pid, signal.SIGTERM)
                os.waitpid(pid, 0)
            except (ChildProcessError, ProcessLookupError):
                pass
    return [results[i] if i in results else fn(i) for i in range(n)]
