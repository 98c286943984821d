"""Everyday use (issue 14): the defects found by trying every command as a new user would."""

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


def one_error_line(r) -> str:
    """The result's stderr must be exactly one 'hystfit: error:' line (no box, no traceback)."""
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("hystfit: error: "), r.stderr
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return lines[0]


@pytest.fixture(scope="module")
def pi_params(tmp_path_factory):
    d = tmp_path_factory.mktemp("pi")
    r = run("identify", SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f10Hz.csv", "--out", d / "o", "--no-plots", "-q")
    assert r.exit_code == 0, r.output
    return d / "o" / "params.json"


# -- item 8: seeds are validated once, like every other option ------------------------------------

@pytest.mark.parametrize("argv", [
    ("identify", SAMPLE / "a20V_f10Hz.csv"),
    ("compare", SAMPLE / "a20V_f10Hz.csv", "--models", "pi"),
    ("diagnose", SAMPLE / "a20V_f10Hz.csv"),
    ("synth", "capture", "x.csv", "-a", "10", "-f", "10"),
])
def test_negative_seed_is_one_line_and_exit_2(argv, tmp_path):
    r = run(*argv, "--seed", "-5", "--out", tmp_path / "o") if argv[0] != "synth" else run(*argv, "--seed", "-5")
    assert r.exit_code == 2
    assert "--seed" in one_error_line(r)
    assert not (tmp_path / "o").exists()


def test_negative_seed_in_track(pi_params, tmp_path):
    r = run("track", pi_params, "--sine", "5,10", "--seed", "-5", "--out", tmp_path / "t")
    assert r.exit_code == 2 and "--seed" in one_error_line(r)


def test_usage_errors_have_the_same_style_as_other_errors(tmp_path):
    for argv in (("identify", SAMPLE / "a20V_f10Hz.csv", "--no-such-option"), ("identify",),
                 ("identify", SAMPLE / "a20V_f10Hz.csv", "--runs", "0")):
        r = run(*argv)
        assert r.exit_code == 2
        line = one_error_line(r)
        assert "╭" not in line and "hystfit identify --help" in line


def test_version_option():
    from hystfit import __version__

    r = run("--version")
    assert r.exit_code == 0 and r.stdout.strip() == f"hystfit {__version__}"


# -- item 11: an unwritable output location is refused before any work ----------------------------

def test_invert_unwritable_out_is_refused_before_the_inversion(pi_params, tmp_path, monkeypatch):
    import hystfit.invert

    def boom(*a, **k):
        raise AssertionError("the inversion ran before the output location was checked")

    monkeypatch.setattr(hystfit.invert, "invert_target", boom)
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    r = run("invert", pi_params, "--sine", "10,10", "--out", blocker / "v.csv", "--report-dir", tmp_path / "rep",
            "--force")
    assert r.exit_code == 2
    assert "afile" in one_error_line(r)
    assert not (tmp_path / "rep").exists()


def test_synth_capture_unwritable_out_is_refused_before_simulating(tmp_path, monkeypatch):
    import hystfit.synth

    def boom(*a, **k):
        raise AssertionError("the plant was simulated before the output location was checked")

    monkeypatch.setattr(hystfit.synth, "simulate_plant", boom)
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    r = run("synth", "capture", blocker / "c.csv", "-a", "10", "-f", "10", "--force")
    assert r.exit_code == 2 and "afile" in one_error_line(r)


# -- item 7: compare with every cell failed exits 3 with a message --------------------------------

def _failing_fit(*a, **k):
    from hystfit.errors import InputError

    raise InputError("synthetic failure of this cell")


def test_compare_every_cell_failed_exits_3_with_a_message(tmp_path, monkeypatch):
    import hystfit.compare

    monkeypatch.setattr(hystfit.compare, "fit_captures", _failing_fit)
    out = tmp_path / "c"
    r = run("compare", SAMPLE / "a20V_f10Hz.csv", "--models", "pi", "--out", out, "--jobs", "1", "--no-plots", "-q")
    assert r.exit_code == 3
    line = one_error_line(r)
    assert "every cell failed" in line and "synthetic failure" in line
    assert "synthetic failure" in (out / "compare.csv").read_text()  # the record is still written, complete
    r = run("compare", SAMPLE / "a20V_f10Hz.csv", "--models", "pi", "--out", tmp_path / "j", "--jobs", "1",
            "--no-plots", "--json")
    assert r.exit_code == 3 and "every cell failed" in r.stderr


# -- item 9: Ctrl-C during compare stops at once, exit 130, nothing half-written -------------------

@pytest.mark.slow
def test_ctrl_c_during_compare_stops_quickly(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    data = tmp_path / "data"
    data.mkdir()
    for name in ("a20V_f10Hz.csv", "a20V_f20Hz.csv", "a40V_f10Hz.csv", "a40V_f20Hz.csv"):
        shutil.copy(SAMPLE / name, data / name)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", "from hystfit.cli import main; main()", "compare", str(data),
                             "--models", "bw,lugre", "--opts", "pso,de", "--runs", "3", "--jobs", "2", "--out",
                             str(tmp_path / "out"), "--no-plots"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".out.tmp-*")) and time.monotonic() < deadline:  # the work has begun
        time.sleep(0.1)
    time.sleep(4.0)  # the workers are spawned and fitting
    assert proc.poll() is None, proc.communicate()
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    elapsed = time.monotonic() - t0
    assert proc.returncode == 130, err
    assert elapsed < 3.0, f"took {elapsed:.1f} s to stop"
    assert b"Traceback" not in err and b"interrupted" in err
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.tmp-*"))


# -- item 5: parameters pinned at a bound are flagged ----------------------------------------------

def test_bound_side_uses_a_relative_tolerance_that_catches_optimizer_landings():
    from hystfit.params import bound_side

    assert bound_side(-269.999, -270.0, 270.0) == "lower"  # was missed with 1e-6 × width
    assert bound_side(1.999, 0.01, 2.0) == "upper"  # pi2's ζ
    assert bound_side(0.0, 0.0, 1.0) == "lower" and bound_side(0.5, 0.0, 1.0) is None
    assert bound_side(0.01, 0.0, 1.0) is None


def test_identify_flags_a_pinned_parameter_in_params_report_and_console(tmp_path):
    out = tmp_path / "o"
    # y0 is about 0.25 µm on this capture: a lower bound of 0.3 pins it
    r = run("identify", SAMPLE / "a20V_f10Hz.csv", "--bounds", "y0=0.3:1", "--out", out, "--no-plots")
    assert r.exit_code == 0, r.output
    p = json.loads((out / "params.json").read_text())
    (y0,) = [q for q in p["conditions"][0]["parameters"] if q["name"] == "y0"]
    assert y0["at_bound"] == "lower" and y0["stderr"] is None
    report = (out / "report.md").read_text()
    assert "| at bound |" in report and "| y0 |" in report and "**lower**" in report
    assert "at a search bound" in r.stderr and "y0=0.3 (lower 0.3)" in r.stderr


def test_report_numbers_show_enough_digits():
    import pandas as pd

    from hystfit.report.tables import fmt, markdown_table

    assert fmt(0.9999961) == "0.999996" and fmt(1.0) == "1"
    table = markdown_table(pd.DataFrame({"condition": ["a"], "samples": [33720], "r2": [0.99999]}))
    assert "| a | 33720 | 0.99999 |" in table


# -- items 2 and 4: simulate says when a capture lies outside the table; bias and --align-offset ----

@pytest.fixture(scope="module")
def grid_params(tmp_path_factory):
    """A 2 × 2 table: 20/40 V × 10/20 Hz."""
    d = tmp_path_factory.mktemp("grid")
    names = ("a20V_f10Hz.csv", "a20V_f20Hz.csv", "a40V_f10Hz.csv", "a40V_f20Hz.csv")
    r = run("identify", *(SAMPLE / n for n in names), "--out", d / "o", "--no-plots", "-q")
    assert r.exit_code == 0, r.output
    return d / "o" / "params.json"


def test_simulate_notes_captures_outside_the_table(grid_params, tmp_path):
    r = run("simulate", grid_params, SAMPLE / "broadband" / "prbs_60V.csv", SAMPLE / "a60V_f80Hz.csv",
            SAMPLE / "a20V_f10Hz.csv", "--out", tmp_path / "s", "--no-plots", "--json")
    assert r.exit_code == 0, r.output
    caps = {Path(c["capture"]).name: c for c in json.loads(r.stdout)["captures"]}
    prbs, a60, a20 = caps["prbs_60V.csv"]["notes"], caps["a60V_f80Hz.csv"]["notes"], caps["a20V_f10Hz.csv"]["notes"]
    assert any("lies outside the table's grid; clamped to 40 V, 20 Hz" in n for n in prbs)
    assert any("trimmed" in n and "idle input" in n for n in prbs)
    assert any("identified on 0…40 V) is used on 0…59.99 V: extrapolated" in n for n in a60)
    assert a20 == []
    assert "prbs_60V.csv: condition 60 V, 150 Hz lies outside" in r.stderr
    report = (tmp_path / "s" / "report.md").read_text()
    assert "## Notes" in report and "extrapolated" in report


def test_simulate_reports_bias_and_aligns_an_offset_on_request(grid_params, tmp_path):
    import pandas as pd

    df = pd.read_csv(SAMPLE / "a20V_f20Hz.csv")
    ycol = [c for c in df.columns if c not in ("time_s", "voltage_V")][0]
    df[ycol] += 3.0  # a sensor zero that moved by 3 µm between recording days
    shifted = tmp_path / "shifted_20V_20Hz.csv"
    df.to_csv(shifted, index=False)
    r = run("simulate", grid_params, shifted, "--out", tmp_path / "a", "--no-plots", "--json",
            "--condition", "20,20")
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)["captures"][0]["metrics"]
    assert m["bias_um"] == pytest.approx(-3.0, abs=0.05) and m["rmse_um"] > 2.9
    notes = json.loads(r.stdout)["captures"][0]["notes"]  # a blind test's find: no hint of --align-offset
    assert any("the error is mostly a constant" in n and "--align-offset" in n for n in notes), notes
    assert any("a sensor zero that moved" in n for n in notes)
    r0 = run("simulate", grid_params, SAMPLE / "a20V_f20Hz.csv", "--out", tmp_path / "c", "--no-plots", "--json")
    assert not any("mostly a constant" in n for n in json.loads(r0.stdout)["captures"][0]["notes"])
    # a blind test's find: outside the table's range (clamped, extrapolated) the same note blamed the
    # sensor; the extrapolation shifts the prediction as much, and --align-offset would hide it
    df60 = pd.read_csv(SAMPLE / "a60V_f20Hz.csv")
    df60[ycol] += 3.0
    df60.to_csv(tmp_path / "shifted_60V_20Hz.csv", index=False)
    r60 = run("simulate", grid_params, tmp_path / "shifted_60V_20Hz.csv", "--out", tmp_path / "d", "--no-plots",
              "--json")
    n60 = json.loads(r60.stdout)["captures"][0]["notes"]
    assert any("mostly a constant" in n and "outside its cells' range" in n for n in n60), n60
    r = run("simulate", grid_params, shifted, "--out", tmp_path / "b", "--no-plots", "--json", "--align-offset",
            "--condition", "20,20")
    assert r.exit_code == 0, r.output
    c = json.loads(r.stdout)["captures"][0]
    assert c["offset_um"] == pytest.approx(3.0, abs=0.05)
    assert c["metrics"]["rmse_um"] < 0.1 and abs(c["metrics"]["bias_um"]) < 1e-9
    assert "offset_um" in (tmp_path / "b" / "report.md").read_text()
    assert "--align-offset" in r.stderr


def test_identify_notes_captures_of_one_condition_resting_at_different_levels(tmp_path):
    """A blind test's find: two recordings of one condition whose sensor zero moved by 2 µm were
    pooled into one fit (RMSE ≈ 1 µm against ≈ 0.01 µm alone) without a word."""
    import pandas as pd

    df = pd.read_csv(SAMPLE / "a20V_f20Hz.csv")
    ycol = [c for c in df.columns if c not in ("time_s", "voltage_V")][0]
    (tmp_path / "pool").mkdir()
    for name, shift in (("day1_20V_20Hz.csv", 1.0), ("day2_20V_20Hz.csv", -1.0)):
        day = df.copy()
        day[ycol] += shift
        day.to_csv(tmp_path / "pool" / name, index=False)
    r = run("identify", tmp_path / "pool", "--out", tmp_path / "o", "--no-plots")
    assert r.exit_code == 0, r.output
    err = " ".join(r.stderr.split())
    assert "rest at different output levels" in err and "day1_20V_20Hz.csv -1 µm" in err and "--model pi+drift" in err
    assert "## Output offsets" in (tmp_path / "o" / "report.md").read_text()
    r = run("identify", SAMPLE / "a20V_f20Hz.csv", SAMPLE / "a20V_f10Hz.csv", "--global", "--out", tmp_path / "g",
            "--no-plots")
    assert r.exit_code == 0 and "different output levels" not in r.stderr


def test_simulate_says_an_inverted_output_runs_opposite_not_that_a_zero_moved(grid_params, tmp_path):
    """A blind test's find: a capture recorded with the output's sign inverted was blamed on a sensor
    zero that moved (a hint of --align-offset, which cannot fix it)."""
    import pandas as pd

    df = pd.read_csv(SAMPLE / "a20V_f20Hz.csv")
    ycol = [c for c in df.columns if c not in ("time_s", "voltage_V")][0]
    df[ycol] = -df[ycol]
    inverted = tmp_path / "inverted_20V_20Hz.csv"
    df.to_csv(inverted, index=False)
    r = run("simulate", grid_params, inverted, SAMPLE / "a20V_f20Hz.csv", "--out", tmp_path / "s", "--no-plots",
            "--json")
    assert r.exit_code == 0, r.output
    notes = [c["notes"] for c in json.loads(r.stdout)["captures"]]
    assert any("runs opposite to the prediction (correlation -1.00)" in n and "negate" in n for n in notes[0])
    assert not any("mostly a constant" in n for n in notes[0])
    assert not any("opposite" in n for n in notes[1])


def test_console_tables_show_distinct_path_suffixes():
    from hystfit.report.tables import distinct_names

    assert distinct_names(["day1/cap.csv", "day2/cap.csv", "x/other.csv"]) == ["day1/cap.csv", "day2/cap.csv",
                                                                               "other.csv"]


# -- item 6: a one-sample jump / mid-loop start is reported; --start/--stop window a capture --------

REAL = SAMPLE / "real" / "hysteresis_v_150_1hz.csv"


def test_real_capture_start_jump_is_reported():
    from hystfit.io import load_capture

    c = load_capture(REAL)
    (note,) = [n for n in c.notes if "starts mid-loop" in n]
    assert "jumps from 0 to -87.1 V in one sample (row 16287)" in note and "--start" in note


def test_smooth_starts_are_not_flagged():
    from hystfit.io import load_capture

    for name in ("a20V_f10Hz.csv", "a60V_f80Hz.csv"):
        assert not any("mid-loop" in n for n in load_capture(SAMPLE / name).notes)


def test_start_stop_window_a_capture(tmp_path):
    from hystfit.errors import InputError
    from hystfit.io import LoadOptions, load_capture

    c = load_capture(REAL, LoadOptions(start_s=4.5, stop_s=9.0))
    assert c.n == pytest.approx(22500, abs=2) and c.trimmed_samples == 0
    assert any("kept 4.5…9 s" in n for n in c.notes)
    assert any("--start window begins while the input moves" in n for n in c.notes)
    with pytest.raises(InputError, match="keep 0 samples"):
        load_capture(REAL, LoadOptions(start_s=20.0))
    r = run("identify", REAL, "--start", "5", "--stop", "2", "--out", tmp_path / "o")
    assert r.exit_code == 2 and "--stop 2: must be after --start" in one_error_line(r)
    r = run("identify", REAL, "--start", "4.5", "--out", tmp_path / "w", "--no-plots", "--json")
    assert r.exit_code == 0, r.output
    full = run("identify", REAL, "--out", tmp_path / "f", "--no-plots", "--json")
    max_w = json.loads(r.stdout)["conditions"][0]["metrics"]["max_error_um"]
    max_f = json.loads(full.stdout)["conditions"][0]["metrics"]["max_error_um"]
    assert max_w < 0.2 * max_f  # the jump set the max error


# -- item 3: captures whose amplitude or frequency changes are not called one condition ------------

def _write(path, t, u, y):
    import pandas as pd

    pd.DataFrame({"time_s": t, "voltage_V": u, "displacement_um": y}).to_csv(path, index=False)
    return path


def test_rising_amplitude_and_sweep_are_warned(tmp_path):
    import numpy as np

    from hystfit.io import load_capture

    dt = 1e-4
    t = np.arange(0, 1, dt)
    crest = (4 + 176 * t) * (0.5 - 0.5 * np.cos(2 * np.pi * 20 * t))
    c = load_capture(_write(tmp_path / "crest.csv", t, crest, 0.1 * crest))
    (w,) = [n for n in c.notes if n.startswith("warning: the amplitude changes")]
    assert "label 180V_20Hz (the full range)" in w and "--start/--stop" in w
    sweep = 10 * np.sin(2 * np.pi * (5 * t + 20 * t ** 2))
    c = load_capture(_write(tmp_path / "sweep.csv", t, sweep, 0.1 * sweep))
    assert any(n.startswith("warning: the frequency changes") for n in c.notes)
    r = run("identify", tmp_path / "crest.csv", "--out", tmp_path / "o", "--no-plots")
    assert r.exit_code == 0 and "warning: crest.csv: the amplitude changes" in r.stderr


def test_a_rising_amplitude_sine_is_not_called_a_frequency_change(tmp_path):
    """A one-sided rising sine 0 → A(t) at one frequency: each third is measured about its own
    centre, so only the amplitude is warned about, with or without noise on the drive (a sweep
    still is: the test above)."""
    import numpy as np

    from hystfit.io import load_capture

    dt = 1e-4
    t = np.arange(0, 1.25, dt)
    crest = 90 * (t / t[-1]) * (0.5 - 0.5 * np.cos(2 * np.pi * 40 * t))
    noisy = crest + 0.05 * np.random.default_rng(0).standard_normal(t.size)
    # a blind test's rig-like drive: a 0.2 s ramp from 0 V to a 45 V offset, then a sine whose amplitude
    # rises from 0 about it (counted by mean crossings, its first third read 5.6 Hz of a constant 10 Hz)
    tr = np.arange(0, 3.0, dt)
    offset = np.where(tr < 0.2, 45.0 * tr / 0.2, 45.0)
    ramped = offset + 40.0 * np.clip((tr - 0.2) / 2.8, 0, 1) * np.sin(2 * np.pi * 10 * np.clip(tr - 0.2, 0, None))
    for name, u in (("rising.csv", crest), ("rising_noisy.csv", noisy), ("ramped.csv", ramped)):
        tt = tr if name == "ramped.csv" else t
        notes = load_capture(_write(tmp_path / name, tt, u, 0.1 * u)).notes
        assert any(n.startswith("warning: the amplitude changes") for n in notes), name
        assert not any(n.startswith("warning: the frequency changes") for n in notes), (name, notes)


def test_stationary_captures_are_not_warned():
    from hystfit.io import load_capture

    for name in ("a20V_f10Hz.csv", "a60V_f80Hz.csv", "broadband/prbs_60V.csv", "broadband/steps_60V.csv",
                 "real/hysteresis_v_150_1hz.csv"):
        assert not any(n.startswith("warning:") for n in load_capture(SAMPLE / name).notes), name


# -- item 16: the papers are cited, not a file a clone does not have --------------------------------

def test_models_listing_and_readme_cite_the_papers_not_an_internal_file():
    r = run("models", "--json")
    assert r.exit_code == 0 and "shared/papers" not in r.stdout
    assert "Micromachines 2025" in r.stdout or "Actuators 2026" in r.stdout
    r = run("optimizers", "--json")
    assert r.exit_code == 0 and "shared/papers" not in r.stdout
    readme = (ROOT / "README.md").read_text()
    assert "shared/papers" not in readme and "## References" in readme and "doi:10.3390/mi16050492" in readme
    assert "shared/papers" not in (ROOT / "docs" / "models.md").read_text()


# -- item 12: a piped stderr is never silent -------------------------------------------------------

def test_progress_on_a_pipe_is_plain_lines(pi_params, tmp_path, monkeypatch):
    import hystfit.cli.common as common

    monkeypatch.setattr(common, "PROGRESS_DELAY_S", 0.0)  # every step "long"
    r = run("identify", SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f10Hz.csv", "--out", tmp_path / "o", "--no-plots")
    assert r.exit_code == 0, r.output
    err = r.stderr
    assert "loading the captures …" in err and "identify pi / auto: running" in err
    assert "identify pi / auto: 2/2" in err and f"writing {tmp_path / 'o'} …" in err
    assert "\x1b[" not in err  # no terminal control sequences in a log
    r = run("invert", pi_params, "--sine", "10,10", "--out", tmp_path / "v.csv")
    assert r.exit_code == 0, r.output
    assert "invert: running" in r.stderr and "writing" in r.stderr
    # track counts its controllers afresh after invert's segments (a blind test saw "track: 5/4 smc")
    r = run("track", pi_params, "--sine", "10,10", "--controller", "ff,pid,ff+pid", "--out", tmp_path / "t",
            "--no-plots")
    assert r.exit_code == 0, r.output
    assert "track: 3/3 ff+pid" in r.stderr and "4/3" not in r.stderr, r.stderr


def test_diagnose_report_leaves_out_a_hold_branch_of_a_few_samples():
    from hystfit.report.diagnose_report import shown_branches

    br = {"ascending": {"n_samples": 5000}, "descending": {"n_samples": 5000}, "hold": {"n_samples": 3}}
    assert shown_branches(br) == ["ascending", "descending"]
    br["hold"]["n_samples"] = 2000  # a step-and-hold capture
    assert shown_branches(br) == ["ascending", "descending", "hold"]


def test_quick_steps_and_early_errors_stay_quiet_on_a_pipe(tmp_path):
    r = run("identify", SAMPLE / "a20V_f10Hz.csv", "--bounds", "zz=0:1", "--out", tmp_path / "o")
    assert r.exit_code == 2 and one_error_line(r)


def test_warmup_is_simulated_but_not_scored(tmp_path):
    r = run("identify", REAL, "--warmup", "1", "--out", tmp_path / "w", "--no-plots", "--json")
    assert r.exit_code == 0, r.output
    full = run("identify", REAL, "--out", tmp_path / "f", "--no-plots", "--json")
    mw = json.loads(r.stdout)["conditions"][0]["metrics"]
    mf = json.loads(full.stdout)["conditions"][0]["metrics"]
    assert mf["n_samples"] - mw["n_samples"] == 5000  # 1 s at 5 kHz left out of the objective and the metrics
    assert mw["max_error_um"] < 0.2 * mf["max_error_um"]
    assert "warm-up: the first 1 s (5000 samples) are simulated but not scored" in r.stderr
    # report.csv / report.md count the scored samples as params.json does (they said the total), and name the total
    import csv

    rw = next(csv.DictReader((tmp_path / "w" / "report.csv").open()))
    rf = next(csv.DictReader((tmp_path / "f" / "report.csv").open()))
    assert int(rw["samples"]) == mw["n_samples"] and int(rw["samples_total"]) == mf["n_samples"]
    assert int(rf["samples"]) == mf["n_samples"] and "samples_total" not in rf  # no warm-up, no second count
    md = (tmp_path / "w" / "report.md").read_text()
    assert "| samples | samples_total |" in md and f"| {mw['n_samples']} | {mf['n_samples']} |" in md
    assert "`samples`: the samples the metrics score (`n_samples` in params.json)" in md
    r = run("identify", REAL, "--warmup", "100", "--out", tmp_path / "x")
    assert r.exit_code == 2 and "--warmup 100 s leaves" in one_error_line(r)


def test_library_refuses_bad_seeds_like_the_cli():
    from hystfit.compare import compare
    from hystfit.errors import ConfigError
    from hystfit.identify import identify
    from hystfit.io import load_capture
    from hystfit.models.pi import PI
    from hystfit.optimizers.auto import Auto

    caps = [load_capture(SAMPLE / "a20V_f10Hz.csv")]
    for bad in (-5, 2 ** 32, 1.5, True):
        with pytest.raises(ConfigError, match="seed must be an integer"):
            identify(caps, PI(), Auto(), seed=bad)
        with pytest.raises(ConfigError, match="seed must be an integer"):
            compare(caps, ["pi"], ["auto"], seed=bad)


def test_simulate_tells_captures_with_the_same_name_apart(grid_params, tmp_path):
    for day in ("day1", "day2"):
        (tmp_path / day).mkdir()
        shutil.copy(SAMPLE / "a20V_f10Hz.csv", tmp_path / day / "cap.csv")
    r = run("simulate", grid_params, tmp_path / "day1" / "cap.csv", tmp_path / "day2" / "cap.csv", "--out",
            tmp_path / "s", "--no-plots")
    assert r.exit_code == 0, r.output
    assert "day1/cap.csv" in r.stdout and "day2/cap.csv" in r.stdout
    report = (tmp_path / "s" / "report.md").read_text()
    assert "| day1/cap.csv |" in report and "| day2/cap.csv |" in report
