"""``parallel.fork_map``: the items of a batch spread over this process and forked children, the
results in index order and equal to the serial loop's, whatever the number of processes."""

import multiprocessing as mp
import os

import numpy as np
import pytest

from hystfit import parallel
from hystfit.errors import InputError
from hystfit.parallel import fork_map, fork_workers

pytestmark = pytest.mark.skipif(fork_workers(2) < 2, reason="needs fork")


def _item(i: int) -> tuple[int, float]:
    """Data only this process holds (the children see it by fork) and a little work."""
    x = np.random.default_rng(i).standard_normal(2000)
    return i, float(np.sort(x) @ np.arange(x.size))


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_results_in_order_and_equal_to_the_serial_loop(workers):
    assert fork_map(_item, 17, workers) == [_item(i) for i in range(17)]


def _a_child_takes_part(result):
    """``fn(i) = result(i)``, except that the parent's first item waits until a child has claimed
    one (so a child computes some items however fast the parent is)."""
    parent = os.getpid()
    child_ran = mp.get_context("fork").Event()

    def fn(i):
        if os.getpid() != parent:
            child_ran.set()
        elif i == 0:
            child_ran.wait(60)
        return result(i)

    return fn


def test_children_compute_items():
    parent = os.getpid()
    pids = fork_map(_a_child_takes_part(lambda i: os.getpid()), 10, 2)
    assert set(pids) - {parent}, "no item ran in a child"
    assert fork_map(lambda i: os.getpid(), 5, 1) == [os.getpid()] * 5


def test_an_item_that_raises_raises_here():
    def fn(i):
        if i == 3:
            raise InputError("item 3 is bad")
        return i

    with pytest.raises(InputError, match="item 3 is bad"):
        fork_map(fn, 8, 2)


def test_an_item_a_child_cannot_return_is_computed_here():
    parent = os.getpid()

    def fn(i):
        if os.getpid() != parent and i % 2:
            os._exit(3)  # the child dies on its first odd item
        return i * i

    assert fork_map(fn, 12, 2) == [i * i for i in range(12)]


def test_results_that_do_not_pickle_are_computed_here_with_a_warning():
    fn = _a_child_takes_part(lambda i: (i, lambda: i))  # a lambda does not pickle
    with pytest.warns(RuntimeWarning, match="could not be sent back"):
        out = fork_map(fn, 6, 2)
    assert [o[0] for o in out] == list(range(6))


def test_one_process_inside_a_pool_worker(monkeypatch):
    monkeypatch.setattr(parallel, "_SINGLE_THREADED", True)
    assert fork_workers(4) == 1
    assert fork_map(lambda i: os.getpid(), 6, 4) == [os.getpid()] * 6


def _refuse_fork():
    import errno

    raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")


def test_a_fork_the_system_refuses_leaves_the_items_to_this_process(monkeypatch):
    """Process or memory limits (a cluster's login node): no child, the same results, nothing raised."""
    monkeypatch.setattr(os, "fork", _refuse_fork)
    assert fork_map(_item, 9, 3) == [_item(i) for i in range(9)]


# ------------------------------------------------------------------------ fork_call


def _alive(pid: int) -> bool:
    from hystfit._process import alive

    return alive(pid)


def test_fork_call_computes_in_a_child_and_returns_the_result():
    parent = os.getpid()
    call = parallel.fork_call(lambda: (os.getpid(), _item(5)))
    assert call is not None
    pid, value = call.result()
    assert pid != parent and value == _item(5)


def test_fork_call_cancel_stops_the_child_at_once():
    import time

    call = parallel.fork_call(lambda: time.sleep(60))
    child = call.pid
    assert _alive(child)
    t = time.perf_counter()
    call.cancel()
    assert time.perf_counter() - t < 5.0
    assert not _alive(child)
    call.cancel()  # a second cancel does nothing


def test_a_fork_call_computing_takes_one_core_from_fork_map():
    """While a fork_call child computes, fork_map beside it uses one process less (it would only take
    that child's core); its core is given back when the result is taken or the child stopped."""
    import time

    assert fork_workers(2) == 2
    call = parallel.fork_call(lambda: (time.sleep(0.2), _item(3))[1])
    assert fork_workers(2) == 1 and fork_workers(3) == 2
    assert fork_map(_item, 4, 2) == [_item(i) for i in range(4)]  # the same results, in this process
    assert call.result() == _item(3)
    assert fork_workers(2) == 2
    call = parallel.fork_call(lambda: time.sleep(60))
    assert fork_workers(2) == 1
    call.cancel()
    call.cancel()
    assert fork_workers(2) == 2


def test_fork_call_that_raises_raises_here():
    def fn():
        raise InputError("bad")

    call = parallel.fork_call(fn)
    with pytest.raises(InputError, match="bad"):
        call.result()


def test_fork_call_whose_child_dies_is_computed_here():
    parent = os.getpid()

    def fn():
        if os.getpid() != parent:
            os._exit(3)
        return 42

    assert parallel.fork_call(fn).result() == 42


def test_fork_call_forks_nothing_where_fork_map_would_not(monkeypatch):
    assert parallel.fork_call(lambda: 1, workers=1) is None
    monkeypatch.setattr(parallel, "_SINGLE_THREADED", True)
    assert parallel.fork_call(lambda: 1) is None


def test_fork_call_a_fork_the_system_refuses_gives_none(monkeypatch):
    monkeypatch.setattr(os, "fork", _refuse_fork)
    assert parallel.fork_call(lambda: 1) is None


_POISONED_LOCK = """
import os, signal, time, multiprocessing as mp
import numba
from numba.np.ufunc import parallel as threading_layer
from hystfit.parallel import fork_call, fork_map
numba.get_num_threads()
lock = mp.get_context("fork").RLock()
threading_layer._backend_init_process_lock = lock
held = mp.get_context("fork").Event()
pid = os.fork()
if pid == 0:  # a child that holds the inherited lock when it is killed
    lock.acquire()
    held.set()
    time.sleep(60)
    os._exit(0)
assert held.wait(30)
os.kill(pid, signal.SIGKILL)
os.waitpid(pid, 0)
assert fork_map(lambda i: i * i, 6, 2) == [i * i for i in range(6)]
assert fork_call(lambda: 7).result() == 7
print("ok")
"""


def test_a_child_stopped_holding_numbas_start_lock_blocks_no_later_child():
    """numba takes a lock shared with forked children at every set_num_threads: a child stopped
    while it held it (a cancelled fork_call, SIGKILL) must not leave every later child (and the
    parent) waiting for ever. In a process of its own: before the fix it hung."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _POISONED_LOCK], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_fork_call_interrupted_while_waiting_stops_the_child():
    """Ctrl-C (or the command's SIGTERM) while this process waits for the result: the child is
    stopped at once, not waited for."""
    import signal
    import time

    call = parallel.fork_call(lambda: time.sleep(60))
    child = call.pid

    def interrupt(*_):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 0.3)
    t = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            call.result()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert time.perf_counter() - t < 10.0
    assert not _alive(child)


_KILLED_PARENT = """
import sys, time
from hystfit.parallel import fork_call, fork_map
if sys.argv[1] == "call":
    call = fork_call(lambda: time.sleep(60))
    print(call.pid, flush=True)
    time.sleep(60)
else:
    print("started", flush=True)
    fork_map(lambda i: time.sleep(60), 2, 2)
"""


@pytest.mark.parametrize("how", ["call", "map"])
def test_forked_children_leave_when_their_parent_is_killed(how):
    """SIGKILL runs no handler in the parent: its fork_call and fork_map children see its end
    themselves (:func:`hystfit.parallel._end_with`) instead of computing on for nothing."""
    import signal
    import subprocess
    import sys
    import time

    p = subprocess.Popen([sys.executable, "-c", _KILLED_PARENT, how], stdout=subprocess.PIPE, text=True,
                         start_new_session=True)
    p.stdout.readline()
    time.sleep(1.0)  # the children run
    group = p.pid  # its own session and process group
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=30)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        os.killpg(group, signal.SIGKILL)
        pytest.fail("a forked child outlived its killed parent by 10 s")


def test_a_forked_child_keeps_its_parents_objects_frozen_and_the_parent_does_not():
    """fork_with_handlers freezes this process's objects across the fork: the child's collections
    leave them out (its freeze count is theirs), this process's are back in its collections at once.
    A process that had frozen objects itself is left as it is: what it made since (e.g. an earlier
    batch job's garbage) is not frozen for good by a fork (a review's find: 67 MB after 8 jobs)."""
    import gc
    import os
    import signal

    from hystfit._process import fork_with_handlers

    def child_count() -> int:
        r, w = os.pipe()
        pid = fork_with_handlers({signal.SIGINT: signal.SIG_IGN})
        if pid == 0:
            os.write(w, str(gc.get_freeze_count()).encode())
            os._exit(0)
        os.close(w)
        got = int(os.read(r, 64).decode())
        os.close(r)
        os.waitpid(pid, 0)
        return got

    was = gc.get_freeze_count()
    gc.unfreeze()
    try:
        assert child_count() > 1000 and gc.get_freeze_count() == 0
        gc.freeze()
        before = gc.get_freeze_count()  # (a frozen object freed meanwhile leaves the count)
        made_since = [{"i": i} for i in range(5000)]
        assert child_count() > 0.9 * before and 0.9 * before < gc.get_freeze_count() <= before
        assert made_since
    finally:
        gc.unfreeze()
        if was:
            gc.freeze()
