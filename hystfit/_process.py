"""Two questions about processes: whether one still exists (the pools' workers,
:func:`hystfit.parallel._end_with`, and the staged output directories of killed commands,
:func:`hystfit.io.staged_output_dir`), and how to fork a child whose own signal handlers are in
place before any signal can reach it (:func:`fork_with_handlers`: the forked children of
:mod:`hystfit.parallel` and the figure server of :mod:`hystfit.report.render`)."""

from __future__ import annotations

import os
import signal
from typing import Callable, Mapping

#: the signals a parent sends its forked children (SIGTERM: stop) or a terminal sends the whole
#: process group (SIGINT: Ctrl-C); held across a fork until the child has its own handlers
HELD_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})

Handler = Callable | int


def fork_with_handlers(handlers: Mapping[int, Handler]) -> int:
    """``os.fork()``, with ``handlers`` (signal → handler, as :func:`signal.signal` takes) installed
    in the child before any of :data:`HELD_SIGNALS` can be delivered to it.

    Without this, a signal sent right after the fork (a parent cancelling the child it has just
    started, a Ctrl-C) runs the *parent's* handler in the child: during the interpreter's own
    after-fork hooks the handler's exception is printed ("Exception ignored in ... _after_fork")
    and dropped, so the child, told to stop, computes on and its parent waits for it (measured: 221
    of 300 children cancelled at once ran on). The signals are blocked across the fork; the child
    installs ``handlers`` and then unblocks them (a signal sent meanwhile is delivered then, to its
    new handler); the parent unblocks them after the fork. Returns the child's pid in the parent
    and 0 in the child, as ``os.fork``; raises ``OSError`` as it does (the parent's mask restored).
    A signal that reached the parent during the fork is handled when the parent unblocks it: if its
    handler raises (Ctrl-C), the child is killed and reaped before the exception leaves here, so no
    child is left that nobody will wait for; a child whose handlers raise before it has begun
    exits at once.
    """
    if not hasattr(signal, "pthread_sigmask"):
        pid = os.fork()
        if pid == 0:
            for signum, handler in handlers.items():
                signal.signal(signum, handler)
        return pid
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS)
    try:
        pid = os.fork()
    except BaseException:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        raise
    if pid == 0:
        try:
            for signum, handler in handlers.items():
                signal.signal(signum, handler)
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        except BaseException:  # stopped before it began (a handler that raises): never return into the caller's code
            os._exit(1)
        return 0
    try:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
    except BaseException:
        # a signal held during the fork is handled here, now, by this process's handler (Ctrl-C,
        # the console script's SIGTERM): the command stops, and the child it will never hear of
        # must not go on computing
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except OSError:
            pass
        raise
    return pid


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (a zombie counts: it has not been reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, owned by another user
        return True
    return True
