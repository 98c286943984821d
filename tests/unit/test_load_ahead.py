"""Captures read by a forked child while the caller loads what its fit needs (io.load_captures(ahead=...)),
and what identify and compare name as those steps (startup_steps)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from hystfit import _warm, io, parallel
from hystfit.errors import InputError
from hystfit.io import LoadOptions, load_captures

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"
CAN_FORK = hasattr(os, "fork") and parallel.fork_workers() > 1


def _same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.source == y.source and x.notes == y.notes
        assert (x.amplitude_V, x.frequency_Hz, x.dt) == (y.amplitude_V, y.frequency_Hz, y.dt)
        for name in ("t", "u", "y"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name))
            assert getattr(x, name).flags.writeable == getattr(y, name).flags.writeable, name


def _counting_forks(monkeypatch) -> list:
    forked = []
    real = parallel.fork_call

    def counting(fn, *a, **k):
        got = real(fn, *a, **k)
        forked.append(got is not None)
        return got

    monkeypatch.setattr(parallel, "fork_call", counting)
    monkeypatch.setattr(threading, "active_count", lambda: 1)  # whatever threads earlier tests left
    monkeypatch.setattr(io, "LOAD_ASIDE_MIN_BYTES", 0)  # the tests' small files are read aside too
    return forked


def test_the_child_reads_the_same_captures_while_the_steps_run_here(monkeypatch):
    forked = _counting_forks(monkeypatch)
    ran = []
    got = load_captures([SAMPLE], LoadOptions(), ahead=(lambda: ran.append(os.getpid()),))
    _same(got, load_captures([SAMPLE], LoadOptions()))
    assert any(not c.y.flags.writeable for c in got)  # the fast reader's read-only arrays, kept
    if CAN_FORK:
        assert forked == [True]
    assert ran in ([], [os.getpid()])  # here, never in the child (it may have been done first)


def test_an_error_reading_is_raised_here_with_the_loaders_message_read_once(tmp_path, monkeypatch):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,voltage_V,displacement_um\n0,1,2\n0.001,x,3\n")
    with pytest.raises(InputError) as plain:
        load_captures([bad], LoadOptions())
    forked = _counting_forks(monkeypatch)
    here = []
    real = io.load_capture
    monkeypatch.setattr(io, "load_capture", lambda *a, **k: (here.append(os.getpid()), real(*a, **k))[1])
    with pytest.raises(InputError) as aside:
        load_captures([bad], LoadOptions(), ahead=(lambda: None,))
    assert str(aside.value) == str(plain.value)
    if CAN_FORK:
        assert forked == [True] and here == []  # read by the child only: its error came back, no second read


def test_large_captures_threads_or_no_steps_mean_reading_here(monkeypatch):
    calls = []
    monkeypatch.setattr(parallel, "fork_call", lambda *a, **k: calls.append(1))
    monkeypatch.setattr(io, "LOAD_ASIDE_MAX_BYTES", 0)
    _same(load_captures([SAMPLE], LoadOptions(), ahead=(lambda: None,)), load_captures([SAMPLE], LoadOptions()))
    monkeypatch.setattr(io, "LOAD_ASIDE_MAX_BYTES", 1 << 40)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, daemon=True)
    t.start()
    try:
        load_captures([SAMPLE], LoadOptions(), ahead=(lambda: None,))
    finally:
        stop.set()
        t.join()
    load_captures([SAMPLE], LoadOptions())  # nothing to do meanwhile
    assert calls == []


def test_a_parquet_file_counts_as_its_uncompressed_size(tmp_path):
    csv, pq = tmp_path / "a.csv", tmp_path / "a.parquet"
    csv.write_bytes(b"x" * 1000)
    pq.write_bytes(b"x" * 1000)
    assert io._load_bytes([csv]) == 1000
    assert io._load_bytes([pq]) == 1000 * io.PARQUET_EXPANSION
    assert io._load_bytes([tmp_path / "missing.csv"]) > io.LOAD_ASIDE_MAX_BYTES


def test_load_ahead_runs_the_steps_in_order_until_stopped_and_skips_failing_ones():
    ran = []

    def fails():
        ran.append("fails")
        raise RuntimeError("a step that fails is left to the fit")

    steps = (lambda: ran.append(1), fails, lambda: ran.append(2), lambda: ran.append(3))
    _warm.load_ahead(steps)
    assert ran == [1, "fails", 2, 3]
    ran.clear()
    _warm.load_ahead(steps, stop=lambda: len(ran) >= 2)
    assert ran == [1, "fails"]


def test_the_pools_fork_server_preload_loads_numba_and_scipy_optimize():
    """hystfit._pool_preload runs _warm.load_ahead(): a fresh process that imports it has numba set up
    (a cached kernel loaded) and scipy.optimize imported."""
    probe = ("import sys, hystfit._pool_preload, hystfit._jit as j; "
             "print(j.numba_loaded(), 'scipy.optimize' in sys.modules, 'numba.core.typing' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], check=True, capture_output=True, text=True, timeout=300)
    assert out.stdout.split() == ["True", "True", "True"]


def test_identify_and_compare_name_what_they_load_or_start_first():
    from hystfit.compare import startup_steps as compare_steps
    from hystfit.factory import make_model, make_optimizer
    from hystfit.identify import startup_steps
    from hystfit.registry import optimizers

    auto, pso = make_optimizer(optimizers.get("auto"), {}), make_optimizer(optimizers.get("pso"), {})
    pi, bw = make_model("pi", {}), make_model("bw", {})
    here = (auto.load_libraries, _warm.import_optimize)
    # PI with auto: one exact linear solve per condition, fitted here: its libraries and the polish's
    assert startup_steps(pi, auto, jobs=None) == here
    assert startup_steps(pi, pso, jobs=None, n_cells=1, polish=False) == ()  # nothing a PSO fit is sure to load
    # bw on many conditions: a pool of all cores, whose fork server starts
    if parallel.default_jobs() > 1:
        assert startup_steps(bw, auto, jobs=None) == (parallel.start_pool_server,)
    assert startup_steps(bw, auto, jobs=None, n_cells=1) == here  # one cell: fitted here
    assert startup_steps(bw, auto, jobs=1) == here
    assert startup_steps(bw, auto, jobs=2, executor=object()) == ()  # another executor: nothing here
    assert compare_steps(jobs=None) == (parallel.start_pool_server,)
    assert compare_steps(jobs=1) == () and compare_steps(jobs=2, executor=object()) == ()


def _threads_since_now(monkeypatch) -> None:
    """``threading.active_count`` as if this process ran only the threads started from now on (the
    earlier tests' leftovers do not count)."""
    monkeypatch.setattr(io, "LOAD_ASIDE_MIN_BYTES", 0)
    before = set(threading.enumerate())
    monkeypatch.setattr(threading, "active_count",
                        lambda: 1 + sum(t.is_alive() and t not in before for t in threading.enumerate()))


@pytest.mark.skipif(not CAN_FORK, reason="the captures are read here without fork")
def test_meanwhile_is_entered_after_the_fork_so_its_thread_does_not_prevent_it(monkeypatch):
    _threads_since_now(monkeypatch)
    events = []
    real = parallel.fork_call
    monkeypatch.setattr(parallel, "fork_call", lambda fn, *a, **k: (events.append(("fork", threading.active_count())),
                                                                    real(fn, *a, **k))[1])

    @contextlib.contextmanager
    def progress_line():  # a thread, as a progress line's timer or spinner has
        stop = threading.Event()
        t = threading.Thread(target=stop.wait, daemon=True)
        t.start()
        events.append("entered")
        try:
            yield
        finally:
            stop.set()
            t.join()
            events.append("left")

    ran = []
    got = load_captures([SAMPLE], LoadOptions(), ahead=(lambda: ran.append(1),), meanwhile=progress_line)
    _same(got, load_captures([SAMPLE], LoadOptions()))
    assert events[:3] == [("fork", 1), "entered", "left"]
    assert ran in ([], [1])


def test_meanwhile_is_left_and_the_child_stopped_when_the_reading_fails(tmp_path, monkeypatch):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,voltage_V,displacement_um\n0,1,2\n0.001,x,3\n")
    _threads_since_now(monkeypatch)
    states = []

    @contextlib.contextmanager
    def progress_line():
        states.append("entered")
        yield
        states.append("left")

    def interrupted():
        raise KeyboardInterrupt

    with pytest.raises(InputError):
        load_captures([bad], LoadOptions(), ahead=(lambda: None,), meanwhile=progress_line)
    assert states == ["entered", "left"]  # the loader's error is raised once the reading is over
    states.clear()
    calls = []
    real = parallel.fork_call

    def recording(fn, *a, **k):
        got = real(fn, *a, **k)
        if got is not None:
            cancel = got.cancel
            got.cancel = lambda: (calls.append("cancel"), cancel())[1]
        return got

    monkeypatch.setattr(parallel, "fork_call", recording)
    with pytest.raises(KeyboardInterrupt):
        load_captures([SAMPLE], LoadOptions(), ahead=(interrupted,), meanwhile=progress_line)
    assert states == ["entered"]  # left by the interruption
    if CAN_FORK:
        assert calls == ["cancel"]  # the child reading aside is stopped, not waited for


@pytest.mark.skipif(not CAN_FORK, reason="the captures are read here without fork")
def test_a_chatty_command_reads_its_captures_aside_too(monkeypatch):
    """The command's "loading the captures" line (a timer thread on a pipe, a spinner on a terminal)
    used to be started before the fork, and its thread then kept the captures from being read aside
    (the load-ahead of every command run without --quiet or --json)."""
    from hystfit.cli.common import OutputArgs, load_for_command

    _threads_since_now(monkeypatch)
    forked = []
    real = parallel.fork_call
    monkeypatch.setattr(parallel, "fork_call", lambda fn, *a, **k: (lambda got: (forked.append(got is not None), got)[1])(
        real(fn, *a, **k)))
    got = load_for_command([str(SAMPLE)], LoadOptions(), OutputArgs(), recursive=False, ahead=(lambda: None,))
    assert forked == [True]
    _same(got, load_captures([SAMPLE], LoadOptions()))


def test_tiny_files_are_read_here(tmp_path, monkeypatch):
    """Hand-made files under LOAD_ASIDE_MIN_BYTES (the general reader's): read at once here, where
    a mistake is reported sooner than by a child sharing the cores with the steps."""
    calls = []
    monkeypatch.setattr(parallel, "fork_call", lambda *a, **k: calls.append(1))
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    tiny = tmp_path / "tiny.csv"
    tiny.write_text("time_s,voltage_V,displacement_um\n" + "".join(f"{i * 1e-3},{i % 7},{i % 5}\n" for i in range(40)))
    assert tiny.stat().st_size < io.LOAD_ASIDE_MIN_BYTES
    ran = []
    load_captures([tiny], LoadOptions(), ahead=(lambda: ran.append(1),))
    assert calls == [] and ran == []  # read here; the steps are left to the caller's code


def test_load_ahead_abandons_the_step_under_way_at_its_next_import(tmp_path, monkeypatch):
    import importlib

    for i in range(5):
        (tmp_path / f"_hystfit_probe_mod_{i}.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    imported, asked_elsewhere = [], []

    def step():
        for i in range(5):
            importlib.import_module(f"_hystfit_probe_mod_{i}")
            imported.append(i)

    def abandon():
        if threading.current_thread() is not threading.main_thread():
            asked_elsewhere.append(1)
        return len(imported) >= 2

    meta_before = list(sys.meta_path)
    with pytest.raises(_warm.Abandoned):
        _warm.load_ahead((step, lambda: imported.append("next step")), abandon=abandon)
    assert imported == [0, 1]  # the third import raised: the step and the ones after it abandoned
    assert sys.meta_path == meta_before and asked_elsewhere == []
    for i in range(5):
        sys.modules.pop(f"_hystfit_probe_mod_{i}", None)
    _warm.load_ahead((step,), abandon=lambda: False)  # never abandoned: every import made
    assert imported[2:] == [0, 1, 2, 3, 4]
    for i in range(5):
        sys.modules.pop(f"_hystfit_probe_mod_{i}", None)


@contextlib.contextmanager
def _importing_step(tmp_path, monkeypatch, prefix: str, n: int, seconds: float):
    """(a step importing ``n`` fresh modules that each sleep ``seconds``, the indices it imported);
    the modules are forgotten afterwards."""
    import importlib

    for i in range(n):
        (tmp_path / f"{prefix}_{i}.py").write_text(f"import time\ntime.sleep({seconds})\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    imported: list = []

    def step():
        for i in range(n):
            importlib.import_module(f"{prefix}_{i}")
            imported.append(i)

    try:
        yield step, imported
    finally:
        for i in range(n):
            sys.modules.pop(f"{prefix}_{i}", None)


@pytest.mark.skipif(not CAN_FORK, reason="the captures are read here without fork")
def test_a_refused_capture_read_aside_abandons_the_steps_and_is_reported_at_once(tmp_path, monkeypatch):
    _counting_forks(monkeypatch)
    bad = tmp_path / "bad.csv"
    bad.write_text(CASES_BAD_LARGE)
    n = 500  # ≈ 5 s of imports, as loading numba and scipy.optimize is
    with _importing_step(tmp_path, monkeypatch, "_hystfit_slow_mod", n, 0.01) as (slow_step, imported):
        with pytest.raises(InputError, match="not a number"):
            load_captures([bad], LoadOptions(), ahead=(slow_step,), abandon_on_error=True)
        assert len(imported) < n  # abandoned when the child reported the error, not finished


@pytest.mark.skipif(not CAN_FORK, reason="the captures are read here without fork")
def test_without_abandon_a_step_under_way_is_finished(tmp_path, monkeypatch):
    """A program that goes on after the error (a library caller, CliRunner): an import cut short
    would leave half-loaded modules for its next fit, so the step under way is finished."""
    _counting_forks(monkeypatch)
    bad = tmp_path / "bad.csv"
    bad.write_text(CASES_BAD_LARGE)
    n = 30
    with _importing_step(tmp_path, monkeypatch, "_hystfit_done_mod", n, 0.02) as (step, imported):
        with pytest.raises(InputError, match="not a number"):
            load_captures([bad], LoadOptions(), ahead=(step, lambda: imported.append("next")))
        assert imported[:n] == list(range(n))  # the step under way finished


@pytest.mark.skipif(not CAN_FORK, reason="the captures are read here without fork")
def test_a_child_that_sends_nothing_is_read_again_here_once_outside_the_imports(tmp_path, monkeypatch):
    """The child died (or its loader raised something other than a HystfitError): nothing is sent,
    the captures are read here — once, after the steps, never inside one of their imports (where a
    read that imports would ask the child again and again: the review found it spinning)."""
    import importlib
    import signal as _signal

    _counting_forks(monkeypatch)
    (tmp_path / "_hystfit_one_mod.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    reads = []
    real = io._read
    monkeypatch.setattr(io, "_read", lambda *a, **k: (reads.append(os.getpid()), real(*a, **k))[1])
    real_fork_call = parallel.fork_call

    here = os.getpid()

    def dies_in_the_child():  # and does nothing when the parent computes the call itself
        if os.getpid() != here:
            os.kill(os.getpid(), _signal.SIGKILL)

    def killed(fn, *a, **k):
        call = real_fork_call(lambda: (dies_in_the_child(), fn())[1], *a, **k)
        return call

    monkeypatch.setattr(parallel, "fork_call", killed)

    def step():
        import time as _t

        _t.sleep(0.3)  # the child is dead by now
        importlib.import_module("_hystfit_one_mod")

    try:
        got = load_captures([SAMPLE], LoadOptions(), ahead=(step,), abandon_on_error=True)
        _same(got, load_captures([SAMPLE], LoadOptions()))
        assert reads.count(os.getpid()) == 2  # this test's own plain read, and one here for the dead child
    finally:
        sys.modules.pop("_hystfit_one_mod", None)


CASES_BAD_LARGE = "time_s,voltage_V,displacement_um\n" + "".join(
    f"{i * 1e-4:.4f},{i % 97 * 0.1:.3f},{i % 89 * 0.01:.3f}\n" for i in range(3000)).replace("\n0.0100,", "\n0.0100x,", 1)
