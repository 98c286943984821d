"""Process-pool execution shared by ``identify`` and ``compare``.

Workers are spawned (not forked: numba's threading layer is not fork-safe) with one BLAS/OpenMP/
numba thread each, so processes × threads never exceed the cores. Results come back in the order
of the jobs, so the numbers never depend on the number of processes.
"""

from __future__ import annotations

import os
import signal
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Callable, Optional, Sequence, TypeVar

J = TypeVar("J")
R = TypeVar("R")

#: thread-count variables of BLAS/OpenMP/numba, set to 1 for pool workers
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def default_jobs() -> int:
    """All cores available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def single_threaded_children():
    """Spawned workers inherit the environment: one thread each."""
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


def _init_worker() -> None:
    # Ctrl-C reaches the whole process group: the parent alone decides (it terminates the workers),
    # so the workers ignore SIGINT instead of each printing a KeyboardInterrupt traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import numba

        numba.set_num_threads(1)
    except Exception:  # pragma: no cover
        pass


def run_jobs(fn: Callable[[J], R], jobs_in: Sequence[J], n_jobs: int | None,
             on_done: Optional[Callable[[int, R], None]] = None) -> list[R]:
    """``[fn(j) for j in jobs_in]``, in a spawned process pool when ``n_jobs > 1`` (same order, same numbers)."""
    n = default_jobs() if n_jobs is None else max(1, int(n_jobs))
    results: dict[int, R] = {}
    if n == 1 or len(jobs_in) <= 1:
        for i, j in enumerate(jobs_in):
            results[i] = fn(j)
            if on_done:
                on_done(i, results[i])
    else:
        import multiprocessing as mp

        with single_threaded_children():
            ex = ProcessPoolExecutor(max_workers=min(n, len(jobs_in)), mp_context=mp.get_context("spawn"),
                                     initializer=_init_worker)
        try:
            futs = {ex.submit(fn, j): i for i, j in enumerate(jobs_in)}
            for fut in as_completed(futs):
                i = futs[fut]
                results[i] = fut.result()
                if on_done:
                    on_done(i, results[i])
        except BaseException:
            _stop_now(ex)
            raise
        ex.shutdown(wait=True)
    return [results[i] for i in range(len(jobs_in))]


def _stop_now(ex: ProcessPoolExecutor) -> None:
    """Stop a pool at once (Ctrl-C, an error): drop the queued jobs and terminate the running ones.

    ``shutdown(cancel_futures=True)`` alone waits for the jobs already running, which is a whole
    fit each (30-45 s for ``compare``), so the workers are terminated first. ``_processes`` is the
    executor's own table of workers (no public accessor).
    """
    procs = list((getattr(ex, "_processes", None) or {}).values())
    for p in procs:
        try:
            p.terminate()
        except Exception:  # noqa: BLE001 - already gone
            pass
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.join(timeout=1.0)
