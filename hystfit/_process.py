"""Two questions about processes: whether one still exists (the pools' workers,
:func:`hystfit.parallel._end_with`, and the staged output directories of killed commands,
:func:`hystfit.io.staged_output_dir`), and how to fork a child whose own signal handlers are in
place before any signal can reach it and no registered lock is held by another thread
(:func:`fork_with_handlers`, :func:`hold_across_forks`: the forked children of
:mod:`hystfit.parallel` and the figure server of :mod:`hystfit.report.render`)."""

from __future__ import annotations

import gc
import os
import signal
import threading
from typing import Callable, Mapping

#: the signals a parent sends its forked children (SIGTERM: stop) or a terminal sends the whole
#: process group (SIGINT: Ctrl-C); held across a fork until the child has its own handlers
HELD_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})

Handler = Callable | int

#: locks held across every :func:`fork_with_handlers` (:func:`hold_across_forks`)
_held_across_forks: list = []


def hold_across_forks(lock) -> None:
    """Hold ``lock`` (a ``threading.Lock``/``RLock``) across every fork of :func:`fork_with_handlers`.

    A fork copies the locks other threads hold at that moment, held, into a child that has no such
    threads: the child's first use of one waits forever. The command line's consoles register
    theirs (:mod:`hystfit.cli.common`): a progress bar redraws itself from its own thread, writing to
    stderr under its console's lock, while the command forks; holding that lock over the fork means
    no stream is in the middle of a write when the child is made, so a child that writes (a
    warning) cannot hang on the stream's lock (CPython does not reset it: python/cpython#84579)."""
    if all(held is not lock for held in _held_across_forks):
        _held_across_forks.append(lock)


def _fork_frozen() -> int:
    """``os.fork()`` with this process's objects frozen out of the garbage collector across it
    (:func:`gc.freeze`, as Python's documentation advises for a fork without exec): they stay so in
    the child, whose first full collection walked them all (≈ 70 ms after diagnose's imports) and
    copied every page it wrote; this process unfreezes them right after. A process that has frozen
    objects itself (the console script after loading, a pre-forking server) is left as it is: a
    freeze here would keep its garbage of the moment (e.g. an earlier batch job's) for good."""
    if gc.get_freeze_count():
        return os.fork()
    gc.freeze()
    pid = -1
    try:
        pid = os.fork()
    finally:
        if pid != 0:
            gc.unfreeze()
    return pid


def fork_with_handlers(handlers: Mapping[int, Handler]) -> int:
    """``os.fork()``, with ``handlers`` (signal → handler, as :func:`signal.signal` takes) installed
    in the child before any of :data:`HELD_SIGNALS` can be handled in it.

    Without this, a signal sent right after the fork (a parent cancelling the child it has just
    started, a Ctrl-C) runs the *parent's* handler in the child: during the interpreter's own
    after-fork hooks the handler's exception is printed ("Exception ignored in ... _after_fork")
    and dropped, so the child, told to stop, computes on and its parent waits for it (measured: 221
    of 300 children cancelled at once ran on).

    Across the fork the signals are blocked (the child inherits the block: a signal sent to it is
    kept pending until its own handlers are in place, then delivered to them) and, in this process,
    their handlers only note them: a signal that reaches this process during the fork (through
    another thread too, which the block does not cover) raises nothing between ``os.fork`` and the
    moment the child's pid is known. Afterwards this process's handlers are put back and each noted
    signal is handled by them; if one raises (Ctrl-C, the console script's SIGTERM), the child is
    killed and reaped before the exception leaves here, so no child is left that nobody will wait
    for. A child whose handlers raise before it has begun exits at once. Returns the child's pid in
    the parent and 0 in the child, as ``os.fork``; raises ``OSError`` as it does (the handlers and
    mask put back). Outside the main thread (where handlers cannot be set) only the block is used.
    The locks of :func:`hold_across_forks` are held across the fork and free in both processes after it.
    The fork itself is :func:`_fork_frozen`'s.
    """
    main = threading.current_thread() is threading.main_thread()
    held = []  # first, before the signals are held: a wait for a stuck writer can be interrupted
    try:
        for lock in list(_held_across_forks):  # in one order: no two forking threads wait on each other
            lock.acquire()
            held.append(lock)
    except BaseException:
        for lock in reversed(held):
            lock.release()
        raise
    noted: list[int] = []
    saved: dict[int, Handler] = {}
    blocking = hasattr(signal, "pthread_sigmask")
    try:
        if main:
            for signum in HELD_SIGNALS:
                current = signal.getsignal(signum)
                if current is not None:  # None: a handler not set from Python, left alone
                    saved[signum] = current
                    signal.signal(signum, lambda n, frame: noted.append(n))
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS) if blocking else None
    except BaseException:  # a signal before the stand-ins were all in place: nothing forked yet
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        for lock in reversed(held):
            lock.release()
        raise

    def put_back() -> None:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        if blocking:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)  # a pending signal is handled here
        for signum in noted:
            handler = saved.get(signum)
            if callable(handler):
                handler(signum, None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), signum)

    try:
        pid = _fork_frozen()
    except BaseException:
        for lock in reversed(held):
            lock.release()
        put_back()
        raise
    for lock in reversed(held):  # in the child too: its copies, held by its one thread, this one
        lock.release()
    if pid == 0:
        try:
            for signum, handler in {**saved, **handlers}.items():
                signal.signal(signum, handler)
            if blocking:
                signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        except BaseException:  # stopped before it began: never return into the caller's code
            os._exit(1)
        return 0
    try:
        put_back()
    except BaseException:
        # a signal of the fork's moment, handled now by this process's handler, stops the command:
        # the child it will never hear of must not go on computing
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
