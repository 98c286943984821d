"""Captures read by a forked child while the command loads what its fit needs (cli.common.load_for_command)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from hystfit import _warm
from hystfit.cli import common
from hystfit.errors import InputError
from hystfit.io import LoadOptions, load_captures

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"
OUT = common.OutputArgs(quiet=True)


def _same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.source == y.source and x.notes == y.notes
        assert (x.amplitude_V, x.frequency_Hz, x.dt) == (y.amplitude_V, y.frequency_Hz, y.dt)
        for name in ("t", "u", "y"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name))
            assert getattr(x, name).flags.writeable == getattr(y, name).flags.writeable, name


def test_the_child_reads_the_same_captures_while_the_steps_run_here(monkeypatch):
    forked, ran = [], []
    from hystfit import parallel

    real = parallel.fork_call

    def counting_fork_call(fn, *a, **k):
        got = real(fn, *a, **k)
        forked.append(got is not None)
        return got

    monkeypatch.setattr(parallel, "fork_call", counting_fork_call)
    monkeypatch.setattr(threading, "active_count", lambda: 1)  # whatever threads earlier tests left
    got = common.load_for_command([SAMPLE], LoadOptions(), OUT, recursive=False,
                                  ahead=(lambda: ran.append(os.getpid()),))
    _same(got, load_captures([SAMPLE], LoadOptions()))
    assert any(not c.y.flags.writeable for c in got)  # the fast reader's read-only arrays, kept
    if hasattr(os, "fork") and parallel.fork_workers() > 1:
        assert forked == [True]
    assert ran in ([], [os.getpid()])  # here, and only while the child read (it may have been done first)


def test_an_error_reading_is_raised_here_with_the_loaders_message_read_once(tmp_path, monkeypatch):
    from hystfit import io

    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,voltage_V,displacement_um\n0,1,2\n0.001,x,3\n")
    with pytest.raises(InputError) as plain:
        load_captures([bad], LoadOptions())
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    here = []
    real = io.load_capture
    monkeypatch.setattr(io, "load_capture", lambda *a, **k: (here.append(os.getpid()), real(*a, **k))[1])
    with pytest.raises(InputError) as aside:
        common.load_for_command([bad], LoadOptions(), OUT, recursive=False, ahead=(lambda: None,))
    assert str(aside.value) == str(plain.value)
    from hystfit import parallel

    if hasattr(os, "fork") and parallel.fork_workers() > 1:
        assert here == []  # read by the child only: its error came back, the file was not read again


def test_large_captures_or_threads_are_read_here(monkeypatch):
    from hystfit import parallel

    calls = []
    monkeypatch.setattr(parallel, "fork_call", lambda *a, **k: calls.append(1))
    monkeypatch.setattr(common, "LOAD_ASIDE_MAX_BYTES", 0)
    _same(common.load_for_command([SAMPLE], LoadOptions(), OUT, recursive=False, ahead=(lambda: None,)),
          load_captures([SAMPLE], LoadOptions()))
    monkeypatch.setattr(common, "LOAD_ASIDE_MAX_BYTES", 1 << 40)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, daemon=True)
    t.start()
    try:
        common.load_for_command([SAMPLE], LoadOptions(), OUT, recursive=False, ahead=(lambda: None,))
    finally:
        stop.set()
        t.join()
    common.load_for_command([SAMPLE], LoadOptions(), OUT, recursive=False)  # nothing to load ahead
    assert calls == []


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


def test_the_pool_preload_and_the_command_share_one_list_of_steps():
    assert _warm.STEPS == (*_warm.KERNELS, _warm.import_optimize)


def test_identify_loads_ahead_where_it_fits_and_starts_the_pool_server_where_a_pool_fits(monkeypatch):
    from hystfit import parallel
    from hystfit.cli.identify import _ahead
    from hystfit.factory import make_model, make_optimizer
    from hystfit.registry import optimizers

    started = []
    monkeypatch.setattr(parallel, "start_pool_server", lambda: started.append(1))
    auto, pso = make_optimizer(optimizers.get("auto"), {}), make_optimizer(optimizers.get("pso"), {})
    pi, bw = make_model("pi", {}), make_model("bw", {})
    one = [str(SAMPLE / "a20V_f10Hz.csv")]
    # PI with auto: one exact linear solve per condition, here: its libraries and the polish's
    assert _ahead(pi, auto, None, None, [SAMPLE], 1, True, False) == (auto.load_libraries, _warm.import_optimize)
    assert _ahead(pi, pso, None, None, one, 1, False, False) == ()  # nothing a PSO fit is sure to load
    assert started == []
    # bw on 24 conditions: a pool of all cores, whose fork server starts now
    if parallel.default_jobs() > 1:
        assert _ahead(bw, auto, None, None, [SAMPLE], 1, True, False) == ()
        assert started == [1]
    # one capture file: one cell, fitted here whatever the model
    assert _ahead(bw, auto, None, None, one, 1, True, False) == (auto.load_libraries, _warm.import_optimize)
    assert _ahead(bw, auto, 1, None, [SAMPLE], 1, True, False) != ()  # --jobs 1
