"""The figure server of report.render: forked early, it draws the same bytes as this process does."""

import os
from pathlib import Path
import signal

import numpy as np
import pytest

from hystfit.errors import OutputError
from hystfit.report import render
from hystfit.report.render import FigureJob, render_figures

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the figure server needs fork")


def _jobs(out, rng, n=4):
    t = np.arange(4000) / 4000
    jobs = []
    for i in range(n):
        u = 30.0 * (1 - np.cos(2 * np.pi * (2 + i) * t))
        y = 0.1 * u + rng.normal(0, 0.01, t.size)
        jobs.append(FigureJob("loop_figure", out / f"loop_{i}.png", (u, y, y + 0.01), {"title": f"c{i}"}))
        jobs.append(FigureJob("timeseries_figure", out / f"ts_{i}.png", (t, y, y + 0.01), {"unit": "nm"}))
    return jobs


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_server_draws_the_same_bytes_as_this_process(tmp_path, rng, server, n_jobs):
    seed = int(rng.integers(1 << 30))
    here = render._draw_here(_jobs(tmp_path / "here", np.random.default_rng(seed)), 1)
    there = render_figures(_jobs(tmp_path / "there", np.random.default_rng(seed)), n_jobs)
    assert [p.name for p in here] == [p.name for p in there]
    assert [p.read_bytes() for p in here] == [p.read_bytes() for p in there]
    again = render_figures(_jobs(tmp_path / "again", np.random.default_rng(seed)), n_jobs)  # a second batch
    assert [p.name for p in again] == [p.name for p in here]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in again)


def test_pending_figures_are_drawn_by_the_server_while_this_process_goes_on(tmp_path, rng, server):
    """PendingFigures hands its batch to the server at once; a second batch while the first is not
    collected is drawn here (replies never cross); both give the bytes drawn here."""
    seed = int(rng.integers(1 << 30))
    first = render.PendingFigures(_jobs(tmp_path / "first", np.random.default_rng(seed)), 2)
    assert first._server is server and server.pending
    second = render.PendingFigures(_jobs(tmp_path / "second", np.random.default_rng(seed)), 1)
    assert second._server is None  # the server is busy with the first batch
    here = render._draw_here(_jobs(tmp_path / "here", np.random.default_rng(seed)), 1)
    for batch in (second, first):
        paths = batch.result()
        assert [p.read_bytes() for p in paths] == [p.read_bytes() for p in here]
    assert not server.pending
    third = render.PendingFigures(_jobs(tmp_path / "third", rng, 1), 1)
    assert third._server is server  # free again
    third.result()


def test_cancelled_pending_figures_stop_the_server(tmp_path, rng, server):
    pending = render.PendingFigures(_jobs(tmp_path / "x", rng, 4), 1)
    pending.cancel()
    assert render._server is None
    with pytest.raises(ChildProcessError):
        os.waitpid(server.pid, os.WNOHANG)  # reaped
    assert all(p.exists() for p in render.render_figures(_jobs(tmp_path / "y", rng, 1), 1))  # drawn here now


def test_server_error_reaches_the_caller(tmp_path, rng, server):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    jobs = _jobs(tmp_path / "ok", rng, 2)
    jobs.insert(1, FigureJob("loop_figure", blocker / "x.png", (np.arange(10.0), np.arange(10.0)), {}))
    with pytest.raises(OutputError):
        render_figures(jobs, 2)
    assert render_figures(_jobs(tmp_path / "after", rng, 1), 1)[0].exists()  # the server still serves


def test_a_lost_server_means_drawing_here(tmp_path, rng, server):
    os.kill(server.pid, signal.SIGKILL)
    os.waitpid(server.pid, 0)
    paths = render_figures(_jobs(tmp_path / "x", rng, 1), 1)
    assert all(p.exists() for p in paths)


def test_preload_with_other_threads_imports_in_a_thread(monkeypatch):
    render._close_server()
    monkeypatch.setattr(render.threading, "active_count", lambda: 2)
    render.preload()
    assert render._server is None
    render._join_preload()


def test_a_job_may_name_a_figure_function_outside_plots(tmp_path, monkeypatch):
    import hystfit.report.plots as plots_module

    calls = []

    def fake(path, *args, **kwargs):
        calls.append((path.name, args, kwargs))
        return path

    monkeypatch.setattr(plots_module, "timeseries_figure", fake)
    jobs = [FigureJob("hystfit.report.plots:timeseries_figure", tmp_path / "a.png", (1,), {"k": 2}),
            FigureJob("timeseries_figure", tmp_path / "b.png", (3,), {})]
    assert render._draw_here(jobs, 1) == [tmp_path / "a.png", tmp_path / "b.png"]
    assert calls == [("a.png", (1,), {"k": 2}), ("b.png", (3,), {})]


def test_a_server_started_before_parsing_is_claimed_by_the_command_not_forked_again(tmp_path, rng, monkeypatch):
    """preload_early (the console script, before parsing) → the command's preload(claim_early=True)
    keeps that server; a later preload replaces it; release_early closes only an unclaimed one."""
    monkeypatch.setattr(render.threading, "active_count", lambda: 1)  # as in the console script
    render._close_server()
    render.preload_early()
    first = render._server
    assert first is not None and render._early
    render.preload(claim_early=True)
    assert render._server is first and not render._early
    render.release_early()  # claimed: left alone
    assert render._server is first
    paths = render_figures(_jobs(tmp_path / "a", rng, 1), 1)
    assert all(p.exists() for p in paths) and first.drawn
    render.preload(claim_early=True)  # nothing early to claim: a fresh server
    assert render._server is not first
    render.preload_early()
    render.release_early()  # unclaimed (e.g. --help): closed without waiting for its imports
    assert render._server is None and not render._early


@pytest.mark.parametrize("words, early", [
    (["identify", "data.csv"], True),
    (["compare", "data.csv", "--models", "pi"], True),
    (["identify", "data.csv", "--no-plots"], False),
    (["identify", "--help"], False),
    (["diagnose", "data.csv"], True),
    (["diagnose", "data.csv", "--no-plots"], False),
    (["invert", "params.json", "traj.csv"], True),  # its tracking figures (invert_report.draw_figures)
    (["invert", "params.json", "traj.csv", "--no-plots"], False),
    (["track", "params.json", "--sine", "8,10"], True),
    (["simulate", "params.json", "data.csv"], True),
    (["simulate", "params.json", "data.csv", "--no-plots"], False),
    ([], False),
])
def test_the_console_script_starts_the_figure_server_only_for_commands_that_draw(monkeypatch, words, early):
    import importlib

    app_module = importlib.import_module("hystfit.cli.app")

    calls = []
    monkeypatch.setattr(render, "preload_early", lambda: calls.append("early"))
    monkeypatch.setattr(render, "release_early", lambda: calls.append("release"))
    monkeypatch.setattr(app_module, "app", lambda **kw: None)
    app_module.main(words)
    assert calls == (["early", "release"] if early else [])


def _wait_for(paths, timeout_s=30.0):
    import time

    deadline = time.monotonic() + timeout_s
    while not all(p.exists() for p in paths):
        assert time.monotonic() < deadline, "the server did not draw the streamed figures"
        time.sleep(0.02)


def test_a_stream_is_drawn_while_this_process_goes_on_and_gives_the_bytes_drawn_here(tmp_path, rng, server):
    """Jobs added to a FigureStream are drawn by the server before the stream is finished; the
    rest after it; the paths come back in the order added, with the bytes drawn here."""
    seed = int(rng.integers(1 << 30))
    jobs = _jobs(tmp_path / "s", np.random.default_rng(seed), 3)
    first, rest = jobs[:2], jobs[2:]
    stream = render.FigureStream(2)
    assert stream._server is server and server.pending
    stream.add(first)
    _wait_for([j.path for j in first])  # drawn before anything else is sent
    stream.add(rest)
    paths = stream.result()
    here = render._draw_here(_jobs(tmp_path / "here", np.random.default_rng(seed), 3), 1)
    assert [p.name for p in paths] == [p.name for p in here]
    assert [p.read_bytes() for p in paths] == [p.read_bytes() for p in here]
    assert not server.pending
    with pytest.raises(RuntimeError):
        stream.add(first)  # finished


def test_a_stream_runs_preparations_when_idle_and_ignores_their_errors(tmp_path, rng, server):
    marker = tmp_path / "prepared"
    stream = render.FigureStream(1)
    stream.prepare("hystfit.report.plots:prepare_overview", -3)  # raises: ignored
    stream.prepare("hystfit.io:atomic_write_bytes", marker, b"x")  # any function, by name
    _wait_for([marker])
    stream.add(_jobs(tmp_path / "a", rng, 1))
    assert all(p.exists() for p in stream.result())


def test_the_first_failing_job_of_a_stream_is_raised_also_when_drawn_early(tmp_path, rng, server):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    bad = FigureJob("loop_figure", blocker / "x.png", (np.arange(10.0), np.arange(10.0)), {})
    stream = render.FigureStream(2)
    stream.add([bad])
    ok = _jobs(tmp_path / "ok", rng, 2)
    stream.add(ok[:1])
    _wait_for([ok[0].path])  # the failing job was drawn (and failed) before: kept until the end
    stream.add(ok[1:])
    with pytest.raises(OutputError):
        stream.result()
    assert render_figures(_jobs(tmp_path / "after", rng, 1), 1)[0].exists()  # the server still serves


def test_a_cancelled_stream_stops_the_server_and_writes_nothing_more(tmp_path, rng, server):
    jobs = _jobs(tmp_path / "c", rng, 20)
    stream = render.FigureStream(1)
    stream.add(jobs)
    stream.cancel()
    assert render._server is None
    drawn = {p for p in (tmp_path / "c").glob("*.png")} if (tmp_path / "c").exists() else set()
    import time

    time.sleep(0.3)
    after = {p for p in (tmp_path / "c").glob("*.png")} if (tmp_path / "c").exists() else set()
    assert after == drawn and len(after) < len(jobs)
    with pytest.raises(ChildProcessError):
        os.waitpid(server.pid, os.WNOHANG)  # reaped


def test_without_a_server_a_stream_draws_everything_at_the_end(tmp_path, rng):
    render._close_server()
    stream = render.FigureStream(1)
    assert stream._server is None
    jobs = _jobs(tmp_path / "n", rng, 2)
    stream.add(jobs[:2])
    stream.prepare("prepare_overview", 4)  # nothing happens here
    assert not any(j.path.exists() for j in jobs)
    stream.add(jobs[2:])
    assert [p.name for p in stream.result()] == [j.path.name for j in jobs]


def test_relative_paths_are_drawn_where_this_process_works_not_where_the_server_started(tmp_path, rng, server,
                                                                                         monkeypatch):
    """The server keeps the working directory it was forked in; a job's relative path means this
    process's directory when the job is added (the README's Python API writes to "bw-report")."""
    here = tmp_path / "now_here"
    here.mkdir()
    monkeypatch.chdir(here)
    jobs = [FigureJob(j.function, Path("rel") / j.path.name, j.args, j.kwargs) for j in _jobs(tmp_path, rng, 1)]
    stream = render.FigureStream(1)
    assert stream._server is server
    stream.add(jobs)
    paths = stream.result()
    assert paths == [j.path for j in jobs]  # as given
    assert all((here / p).exists() for p in paths)


def _slow_figure(path, seconds):
    """A stand-in figure function that takes ``seconds`` (drawn by the server's pool)."""
    import time

    time.sleep(seconds)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x")
    return path


def test_cancelling_while_the_pool_draws_stops_the_pool_too(tmp_path, server):
    """Ctrl-C after the stream was finished: the server's pool, not only the server, is gone when
    cancel returns — no figure appears afterwards (the staged output is removed next)."""
    import time

    jobs = [FigureJob(f"{__name__}:_slow_figure", tmp_path / "s" / f"{i}.png", (0.4,)) for i in range(12)]
    stream = render.FigureStream(2)
    stream.add(jobs)
    stream.finish()  # the rest goes to a pool of two
    time.sleep(1.0)
    stream.cancel()
    drawn = set((tmp_path / "s").glob("*.png")) if (tmp_path / "s").exists() else set()
    time.sleep(1.5)
    after = set((tmp_path / "s").glob("*.png")) if (tmp_path / "s").exists() else set()
    assert after == drawn and len(after) < len(jobs)


def _figure_calling(path, make_bytes):
    """A stand-in figure function whose argument (a function) need not pickle."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(make_bytes())
    return path


def test_a_job_that_does_not_pickle_is_drawn_here(tmp_path, rng, server):
    """A job the server cannot be sent (a lambda among its arguments) must not fail the command:
    the stream stops the server and draws every job, the ones sent before it too, in this process."""
    jobs = _jobs(tmp_path, rng, 1)
    odd = FigureJob(f"{__name__}:_figure_calling", tmp_path / "odd.png", (lambda: b"drawn here",))
    stream = render.FigureStream(1)
    assert stream._server is server
    stream.add(jobs)
    stream.add([odd])
    assert stream._server is None
    paths = stream.result()
    assert paths == [j.path for j in jobs] + [odd.path]
    assert all(p.exists() for p in paths) and odd.path.read_bytes() == b"drawn here"


def test_the_servers_socket_holds_megabytes_of_jobs_before_a_send_waits(server):
    """The server reads between two figures: this process's send buffer is widened (within the
    system's limit) so that queuing a condition's arrays does not wait for the figure being drawn."""
    import socket

    with socket.socket(fileno=os.dup(server.conn.fileno())) as sock:
        size = sock.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF)
    try:
        limit = int(Path("/proc/sys/net/core/wmem_max").read_text())
    except OSError:
        pytest.skip("no net.core.wmem_max to compare with")
    assert size >= min(render.SEND_BUFFER_BYTES, limit) > 212_992 or limit <= 212_992


def test_a_server_killed_during_its_warm_up_leaves_nothing_on_disk(tmp_path, monkeypatch):
    """The warm-up draws into memory: a server stopped in the middle of it (here killed at its
    second figure) leaves no file or directory behind, neither in the temporary directory nor
    where the command works."""
    import tempfile

    from hystfit.report import plots

    scratch, cwd = tmp_path / "tmp", tmp_path / "cwd"
    scratch.mkdir()
    cwd.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    monkeypatch.chdir(cwd)
    monkeypatch.setattr(plots, "timeseries_figure", lambda *a, **k: os.kill(os.getpid(), signal.SIGKILL))
    render._close_server()
    server = render._FigureServer()
    try:
        _, status = os.waitpid(server.pid, 0)
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    finally:
        server.conn.close()
    assert list(scratch.iterdir()) == [] and list(cwd.iterdir()) == []


def test_a_figure_can_be_written_to_a_file_object_with_the_bytes_of_a_file(tmp_path):
    import io

    from hystfit.report import plots

    u = np.linspace(0.0, 20.0, 300)
    buf = io.BytesIO()
    assert plots.loop_figure(buf, u, 0.1 * u, 0.1 * u + 0.01, title="t") is buf
    path = plots.loop_figure(tmp_path / "loop.png", u, 0.1 * u, 0.1 * u + 0.01, title="t")
    assert buf.getvalue() == path.read_bytes() and buf.getvalue()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["loop.png"]


def _refuse_fork():
    import errno

    raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")


def test_a_fork_the_system_refuses_means_the_figures_are_drawn_here_with_the_same_bytes(tmp_path, rng, monkeypatch):
    """Process or memory limits: no figure server and no pool can be forked; preload and
    render_figures go on in this process and write the bytes a pool writes."""
    seed = int(rng.integers(1 << 30))
    render._close_server()
    pooled = render._draw_here(_jobs(tmp_path / "pool", np.random.default_rng(seed), n=6), 2)
    monkeypatch.setattr(os, "fork", _refuse_fork)
    try:
        render.preload()
        assert render._server is None
        here = render_figures(_jobs(tmp_path / "here", np.random.default_rng(seed), n=6), 2)
    finally:
        render._close_server()
    assert [p.read_bytes() for p in here] == [p.read_bytes() for p in pooled]


@pytest.mark.parametrize("jobs_waiting", [True, False], ids=["jobs-waiting", "idle"])
def test_the_server_warms_up_only_when_no_job_waits(tmp_path, rng, monkeypatch, jobs_waiting):
    """A server whose imports end with jobs already sent (a one-condition command: its fit is
    done first) draws them at once: their own first figures lay the templates out. An idle one
    warms up (the Quickstart's server, while the first conditions are fitted). The same bytes."""
    import multiprocessing as mp
    import time

    imported = mp.get_context("fork").Event()
    marker = tmp_path / "warmed-up"
    importing = render._import_plotting
    monkeypatch.setattr(render, "_import_plotting", lambda lean=False: (imported.wait(60), importing(lean)))
    monkeypatch.setattr(render, "_warm_up", lambda: marker.touch())
    seed = int(rng.integers(1 << 30))
    render._close_server()
    render._server = render._FigureServer()
    try:
        if not jobs_waiting:
            imported.set()
            for _ in range(600):
                if marker.exists():
                    break
                time.sleep(0.1)
        stream = render.FigureStream(1)
        stream.add(_jobs(tmp_path / "s", np.random.default_rng(seed), n=2))
        stream.finish()
        imported.set()
        paths = stream.result()
    finally:
        render._close_server()
    assert marker.exists() == (not jobs_waiting)
    here = render._draw_here(_jobs(tmp_path / "h", np.random.default_rng(seed), n=2), 1)
    assert [p.read_bytes() for p in paths] == [p.read_bytes() for p in here]


LEAN_PROBE = r"""
import hashlib, io, sys
import numpy as np
from hystfit.report import render
render._import_plotting(lean=sys.argv[1] == "lean")
three_d = "mpl_toolkits.mplot3d" in sys.modules
from hystfit.report import plots
t = np.linspace(0.0, 0.2, 2001)
u = 30.0 * (1.0 - np.cos(2 * np.pi * 10.0 * t))
y = 0.3 * u + 0.5 * np.sin(2 * np.pi * 10.0 * t)
digests = []
for draw in (lambda f: plots.loop_figure(f, u, y, y + 0.01, title="20V_10Hz"),
             lambda f: plots.timeseries_figure(f, t, y, y + 0.01, title="20V_10Hz"),
             lambda f: plots.convergence_figure(f, np.geomspace(1.0, 1e-3, 50), title="pso")):
    buf = io.BytesIO()
    draw(buf)
    digests.append(hashlib.sha256(buf.getvalue()).hexdigest())
import matplotlib.patches
signed = hasattr(matplotlib.patches.Rectangle.set, "__signature__")
glyphs_loaded = "toUnicode" in vars(sys.modules["fontTools.agl"])  # TeX's glyph list, read only for TeX
import fontTools.agl
from fontTools.agl import AGL2UV
works = fontTools.agl.toUnicode("Aacute") == "\u00c1" and AGL2UV["A"] == 0x41
print(three_d, "mpl_toolkits.mplot3d" in sys.modules, signed, glyphs_loaded, works, *digests)
"""


def test_the_servers_lean_import_draws_the_same_bytes_without_the_3d_toolkit():
    """The figure server imports matplotlib (≥ 3.9) without mplot3d (render._import_plotting(lean=True)):
    the same PNG bytes as a whole import, and no 3-D toolkit imported by drawing either. Fresh
    processes: this one has matplotlib imported. A warning of the blocked import is an error here."""
    import os
    import subprocess
    import sys

    def run(way):
        out = subprocess.run([sys.executable, "-c", LEAN_PROBE, way], check=True, capture_output=True, text=True,
                             timeout=300, env={**os.environ, "PYTHONWARNINGS": "error::UserWarning"}).stdout
        return out.split()

    lean, whole = run("lean"), run("whole")
    assert whole[:5] == ["True", "True", "True", "True", "True"]
    # lean: neither the 3-D toolkit nor the artists' generated set() signatures (_without_set_signatures),
    # and the glyph list of TeX output not loaded by drawing (render._load_on_use), yet there when read
    assert lean[:5] == (["False", "False", "False", "False", "True"] if render._tolerates_no_3d()
                        else ["True", "True", "True", "True", "True"])
    assert lean[5:] == whole[5:]


def test_the_lean_import_is_only_used_where_matplotlib_tolerates_it(monkeypatch):
    from importlib import metadata

    for version, ok in (("3.7.5", False), ("3.8.0", False), ("3.9.0", True), ("3.11.2", True), ("4.0.0rc1", True),
                        ("unknown", False)):
        monkeypatch.setattr(metadata, "version", lambda name, v=version: v)
        assert render._tolerates_no_3d() is ok, version
