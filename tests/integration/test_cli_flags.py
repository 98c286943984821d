"""Command-line flags that the other CLI tests leave out, each checked for its visible effect."""

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hystfit.cli import app

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def nested(tmp_path_factory):
    """Two captures, one of them in a subdirectory (what --recursive is for)."""
    d = tmp_path_factory.mktemp("nested")
    shutil.copy(SAMPLE / "a20V_f10Hz.csv", d / "a20V_f10Hz.csv")
    (d / "sub").mkdir()
    shutil.copy(SAMPLE / "a40V_f10Hz.csv", d / "sub" / "a40V_f10Hz.csv")
    return d


def test_identify_recursive_polish_and_optimizer_options(nested, tmp_path):
    r = run("identify", nested, "--out", tmp_path / "flat", "--no-plots", "--json", "--quiet")
    assert r.exit_code == 0, r.output
    assert [c["label"] for c in json.loads(r.stdout)["conditions"]] == ["20V_10Hz"]
    r = run("identify", nested, "--recursive", "--model", "bw", "--opt", "pso", "--pop", "20", "--iters", "10",
            "--opt-option", "max_evals=100", "--no-polish", "--no-plots", "--out", tmp_path / "rec", "--quiet")
    assert r.exit_code == 0, r.output
    params = json.loads((tmp_path / "rec" / "params.json").read_text())
    assert [c["label"] for c in params["conditions"]] == ["20V_10Hz", "40V_10Hz"]
    assert params["optimizer"]["polish"] is False and params["optimizer"]["settings"]["max_evals"] == 100
    for c in params["conditions"]:
        assert c["evaluations"] <= 100 + 20 and not c["runs"][0]["polished"]
    r = run("identify", nested / "a20V_f10Hz.csv", "--model", "bw", "--opt", "pso", "--pop", "20", "--iters", "10",
            "--polish", "--no-plots", "--out", tmp_path / "pol", "--quiet")
    assert r.exit_code == 0, r.output
    params = json.loads((tmp_path / "pol" / "params.json").read_text())
    assert params["optimizer"]["polish"] is True and params["conditions"][0]["runs"][0]["polished"]
    assert not (tmp_path / "rec" / "plots").exists()
    r = run("identify", nested, "--opt-option", "no_such_setting=1", "--out", tmp_path / "bad")
    assert r.exit_code == 2 and "no_such_setting" in r.output and not (tmp_path / "bad").exists()


def test_compare_without_polish_and_figures(tmp_path):
    r = run("compare", SAMPLE / "a20V_f10Hz.csv", "--models", "pi,bw", "--opts", "pso", "--pop", "20", "--iters",
            "10", "--no-polish", "--no-figures", "--jobs", "1", "--out", tmp_path / "c", "--quiet")
    assert r.exit_code == 0, r.output
    md = (tmp_path / "c" / "compare.md").read_text()
    assert "polish after global optimizers: no" in md
    assert not (tmp_path / "c" / "figures").exists()


def test_diagnose_per_condition_without_figures(tmp_path):
    data = [SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a20V_f80Hz.csv", SAMPLE / "a60V_f10Hz.csv", SAMPLE / "a60V_f80Hz.csv"]
    r = run("diagnose", *data, "--model", "pi", "--per-condition", "--effects", "delay,creep", "--opt-option",
            "restarts=1", "--no-figures", "--out", tmp_path / "d", "--quiet")
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert d["mode"] == "per-condition" and {e["effect"] for e in d["effects"]} == {"delay", "creep"}
    assert not (tmp_path / "d" / "figures").exists()


def test_simulate_recursive(nested, tmp_path):
    r = run("identify", nested, "--recursive", "--no-plots", "--out", tmp_path / "id", "--quiet")
    assert r.exit_code == 0, r.output
    r = run("simulate", tmp_path / "id" / "params.json", nested, "--recursive", "--no-plots", "--out",
            tmp_path / "sim", "--json")
    assert r.exit_code == 0, r.output
    names = {p.name for p in (tmp_path / "sim").iterdir()}
    assert {"a20V_f10Hz_prediction.csv", "a40V_f10Hz_prediction.csv"} <= names


@pytest.mark.slow
def test_identify_a_million_samples_peaks_under_1_GB_resident(tmp_path, peak_rss_code):
    """Issue 5: a 10⁶-sample capture identifies (load, Bouc–Wen fit with auto and its polish,
    standard errors, reports) in a fresh process whose peak resident set size stays under 1 GB."""
    import subprocess
    import sys

    from hystfit.synth import Effects, Plant, raised_cosine, simulate_plant, write_capture

    t, u = raised_cosine(60, 10, fs_Hz=10_000, cycles=1000)  # 1,000,001 samples
    plant = Plant.default().with_effects(Effects.from_names(["noise"]))
    cap = write_capture(tmp_path / "big.parquet", t, u, simulate_plant(plant, t, u, seed=0))
    code = peak_rss_code
    r = subprocess.run([sys.executable, "-c", code, "identify", str(cap), "--model", "bw", "--no-plots", "--json",
                        "--quiet", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    peak_kB = int(r.stderr.split("peak_kB")[1].split()[0])
    assert peak_kB < 1_000_000, f"peak RSS {peak_kB / 1e3:.0f} MB"
    cond = json.loads(r.stdout)["conditions"][0]
    assert cond["metrics"]["n_samples"] == 1_000_001 and cond["metrics"]["r2"] > 0.999


@pytest.mark.parametrize("command", ["identify", "compare", "diagnose", "batch"])
def test_help_shows_the_dask_extra_in_its_install_command(command):
    """A blind test's find: rich took ``[dask]`` in the help for markup and printed pip install "hystfit"."""
    r = runner.invoke(app, [command, "--help"], env={"COLUMNS": "250"})
    assert r.exit_code == 0, r.output
    assert 'pip install "hystfit[dask]"' in " ".join(r.output.split()), r.output


def test_synth_says_that_strength_scales_the_noise_too(tmp_path):
    """A blind test's find: --strength 20 made the sensor noise 20× as large, without a word."""
    args = ["synth", "capture", str(tmp_path / "s.csv"), "-e", "rising-sine", "-a", "60", "-f", "20", "--cycles", "5",
            "--effects", "drift,noise", "--strength", "5", "--force"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "note: --strength 5 scales the sensor noise too" in r.stderr and "--noise SIGMA" in r.stderr
    r = runner.invoke(app, args + ["--noise", "0.008"])
    assert r.exit_code == 0 and "scales the sensor noise" not in r.stderr


@pytest.mark.parametrize("pair", [("--per-condition", "--global"), ("--plots", "--no-plots"), ("--global", "--per-condition")])
def test_both_halves_of_an_on_off_pair_are_a_usage_error(tmp_path, pair):
    """A blind test's find: ``identify --per-condition --global`` fitted globally without a word (the last
    one won). Both halves of a pair on one command line are one error line, exit 2, nothing written."""
    from typer.testing import CliRunner

    from hystfit.cli import app

    r = CliRunner().invoke(app, ["identify", str(SAMPLE / "a20V_f10Hz.csv"), *pair, "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    on, off = sorted(pair, key=lambda f: f in ("--global", "--no-plots"))  # said as the option declares them
    assert f"{on} and {off} contradict each other; give one of them (see 'hystfit identify --help')" in r.output
    assert not (tmp_path / "o").exists()
