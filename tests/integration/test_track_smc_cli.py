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


def test_an_unstable_bandwidth_is_refused_and_unstable_gains_are_reported_as_such(params, tmp_path):
    """A blind test's finds: --bandwidth above what the nominal loop tolerates ran to exit 0 (error
    the run diverging); user gains without a crossover printed `≈ nan Hz` and `PM = inf°`."""
    r = run("track", params, "--sine", "2,10", "-c", "pid", "--bandwidth", "4000", "--out", tmp_path / "x",
            "--no-plots")
    assert r.exit_code == 2 and "makes the nominal loop unstable" in r.output and "at most" in r.output, r.output
    assert not (tmp_path / "x").exists()
    out = tmp_path / "y"
    r = run("track", params, "--sine", "2,10", "-c", "pid", "--kp", "1e9", "--ki", "0", "--kd", "0", "--out", out,
            "--no-plots")
    assert r.exit_code == 0, r.output
    md = (out / "report.md").read_text()
    assert "the nominal loop is unstable with these gains" in md
    assert "nan Hz" not in md and "inf°" not in md
