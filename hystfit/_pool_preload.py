"""What every worker of a local process pool needs, loaded once by the pool's fork server.

:class:`hystfit.parallel.LocalExecutor` starts its workers (on Linux) with multiprocessing's
``forkserver`` method: a server process is started (a fresh interpreter) the first time a pool
needs a worker, imports this module, and from then on forks each worker from itself. So every worker starts with
what is loaded here (hystfit's cell functions, numba and its own set-up at the first compiled
kernel, ``scipy.optimize``) instead of a fresh interpreter loading it again. ``python
benchmarks/pool_start.py`` (two workers, two ``bw`` cells, development machine with 2 cores):
0.92 s of wall time and 1.30 s of CPU, against 1.22 s and 2.19 s with spawned workers.

This module is imported only by that server (``multiprocessing.set_forkserver_preload``); nothing
in it runs in the command's own process. The server runs no other thread and no numba thread pool,
so forking it is safe whatever the command does meanwhile (progress bars, background threads).
The numbers of a cell do not depend on it: a worker computes exactly what a fresh one would.
"""

from __future__ import annotations

import os
import sys
import traceback

from . import compare, diagnose, identify  # noqa: F401 - the cell functions and all they import


def _late_worker_hook(exc_type, exc, tb) -> None:
    """``sys.excepthook`` of the server and its children. A worker whose start the command asked
    for just before it stopped (Ctrl-C, SIGTERM, an error) is forked after the command has let go
    of its pool: reading what the command sent it then fails inside multiprocessing's own start-up
    (the data cut short, the pool's semaphores already gone), which would print a traceback on the
    command's stderr after its one error line. A worker that fails before it ever runs hystfit's
    code leaves silently — the command, if it is still there, sees a lost worker and says so in
    its own words; any other error is printed as before."""
    frames = traceback.extract_tb(tb)
    starting = any(f.name == "_main" and f.filename.endswith(os.path.join("multiprocessing", "spawn.py"))
                   for f in frames)
    if not starting:
        sys.__excepthook__(exc_type, exc, tb)


sys.excepthook = _late_worker_hook


from ._warm import load_ahead  # noqa: E402

load_ahead()  # numba, its set-up at the first cached kernel, scipy.optimize: once, before any worker
