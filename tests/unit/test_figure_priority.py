"""identify and diagnose let their figure server draw in the gaps their computing leaves (:func:`hystfit.report.render.yield_cores`):
the server's priority is lowered, the figures are the same bytes."""

import os

import numpy as np
import pytest
from typer.testing import CliRunner

from hystfit.cli import app
from hystfit.report import render
from hystfit.report.render import FigureJob

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or not hasattr(os, "setpriority"),
                                reason="the figure server needs fork, its priority setpriority")


def _job(out):
    t = np.arange(2000) / 2000
    u = 30.0 * (1 - np.cos(2 * np.pi * 3 * t))
    return FigureJob("loop_figure", out, (u, 0.1 * u, 0.1 * u + 0.01), {"title": "c"})


def test_yield_cores_lowers_the_servers_priority_and_the_figures_are_the_same(tmp_path, server):
    before, mine = os.getpriority(os.PRIO_PROCESS, server.pid), os.getpriority(os.PRIO_PROCESS, 0)
    assert render.yield_cores(3)
    assert os.getpriority(os.PRIO_PROCESS, server.pid) == min(before + 3, 19)
    assert os.getpriority(os.PRIO_PROCESS, 0) == mine  # this process computes on as it did
    drawn = render.render_figures([_job(tmp_path / "server.png")])
    render._close_server()
    here = render.render_figures([_job(tmp_path / "here.png")])
    assert drawn[0].read_bytes() == here[0].read_bytes()


def test_yield_cores_without_a_server_or_with_nothing_to_yield(server):
    pid = server.pid
    before = os.getpriority(os.PRIO_PROCESS, pid)
    assert not render.yield_cores(0)
    assert os.getpriority(os.PRIO_PROCESS, pid) == before
    render._close_server()
    assert not render.yield_cores(5)


class _Stop(Exception):
    pass


@pytest.mark.parametrize("command", ["diagnose", "identify"])
@pytest.mark.parametrize("flags,expected", [([], [render.FIGURES_NICE]), (["--no-plots"], [])])
def test_the_command_lets_its_figures_wait_for_idle_cores(monkeypatch, tmp_path, command, flags, expected):
    """With figures, the command lowers its figure server's priority before it loads and computes
    (here stopped right after, at the loading)."""
    calls = []
    monkeypatch.setattr(render, "yield_cores", calls.append)

    def stop(*args, **kwargs):
        raise _Stop

    monkeypatch.setattr(f"hystfit.cli.{command}.load_for_command", stop)
    r = CliRunner().invoke(app, [command, str(tmp_path), "--out", str(tmp_path / "out"), "--quiet", *flags])
    assert isinstance(r.exception, _Stop), r.output
    assert calls == expected
    render._close_server()
