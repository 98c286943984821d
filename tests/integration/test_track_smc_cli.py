"""hystfit track: paper 003's sliding-mode options, smc-noinv and the measured bandwidths from the command line."""

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hystfit.cli import app

CAPTURE = Path(__file__).resolve().parents[2] / "sample_data" / "a20V_f10Hz.csv"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    out = tmp_path_factory.mktemp("id") / "pi"
    r = run("identify", CAPTURE, "--out", out, "--no-plots", "--quiet")
    assert r.exit_code == 0, r.output
    return out / "params.json"


def test_smc_options_noinv_and_bandwidths(params, tmp_path):
    out = tmp_path / "trk"
    r = run("track", params, "--sine", "2,10", "--offset", "2", "-c", "pid,smc,smc-noinv", "--smc-option",
            "observer_poles=[0.5]", "--smc-option", "eps=100", "--measure-bandwidth", "--out", out, "--no-plots")
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    smc = next(x for x in s["runs"] if x["controller"] == "smc")["details"]["smc"]
    assert smc["eps_V_per_s"] == 100.0 and smc["G"] != [0.0]
    bw = json.loads((out / "bandwidth.json").read_text())
    assert set(bw["controllers"]) == {"pid", "smc", "smc-noinv"} and "--measure-bandwidth" in bw["command"]
    assert bw["controllers"]["pid"]["tracking_bandwidth_Hz"] > 50.0
    assert "tracking −3 dB" in r.output


@pytest.mark.parametrize("args, word", [(("--smc-option", "gain=3"), "unknown"),
                                        (("--smc-option", "eps=-1"), "eps"),
                                        (("--smc-option", "sliding_poles=[2]"), "unit circle")])
def test_bad_smc_options_are_one_line_errors(params, tmp_path, args, word):
    r = run("track", params, "--sine", "2,10", "-c", "smc", *args, "--out", tmp_path / "x", "--no-plots")
    assert r.exit_code == 2 and word in r.output, r.output
