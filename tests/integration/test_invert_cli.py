"""``hystfit invert`` and ``hystfit track`` through typer's CliRunner: every option, outputs, errors."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from hystfit.cli import app

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """A 2 × 2 PI table (20/40 V × 10/20 Hz) and a one-cell Bouc–Wen table from the sample data."""
    d = tmp_path_factory.mktemp("tables")
    data = d / "data"
    data.mkdir()
    for name in ("a20V_f10Hz.csv", "a40V_f10Hz.csv", "a20V_f20Hz.csv", "a40V_f20Hz.csv"):
        shutil.copy(SAMPLE / name, data / name)
    r = run("identify", data, "--out", d / "pi", "--no-plots", "--quiet", "--jobs", "1")
    assert r.exit_code == 0, r.output
    r = run("identify", data / "a40V_f10Hz.csv", "--model", "bw", "--out", d / "bw", "--no-plots", "--quiet",
            "--jobs", "1")
    assert r.exit_code == 0, r.output
    return {"pi": d / "pi" / "params.json", "bw": d / "bw" / "params.json"}


def assert_error(r, needle, *not_written):
    assert r.exit_code == 2, r.output
    assert needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("hystfit: error:")
    assert "Traceback" not in r.output
    for p in not_written:
        assert not Path(p).exists(), p


# ------------------------------------------------------------------------------------------ invert


def test_invert_sine_writes_voltages_report_and_plots(tables, tmp_path):
    out = tmp_path / "v.csv"
    r = run("invert", tables["pi"], "--sine", "10,10,3", "--offset", "2", "--out", out)
    assert r.exit_code == 0, r.output
    df = pd.read_csv(out)
    assert list(df.columns) == ["time_s", "voltage_V", "predicted_displacement_um"]
    assert len(df) == 3001 and df["time_s"].iloc[1] == pytest.approx(1e-4)
    target = 2 + 5 * (1 - np.cos(2 * np.pi * 10 * df["time_s"]))
    assert np.max(np.abs(df["predicted_displacement_um"] - target)) < 0.05
    rep = tmp_path / "v_report"
    assert {p.name for p in rep.iterdir()} == {"report.md", "report.json", "plots"}
    assert (rep / "plots" / "tracking.png").stat().st_size > 10_000
    summary = json.loads((rep / "report.json").read_text())
    assert summary["schema"] == "hystfit.invert" and summary["model"] == "pi"
    assert summary["segments"][0]["converged"] and summary["segments"][0]["how"] == "iterated"
    assert {c["label"] for c in summary["segments"][0]["cells"]} <= {"20V_10Hz", "40V_10Hz"}
    assert summary["limits"]["vmin_V"] == pytest.approx(-4.0) and summary["limits"]["vmax_V"] == pytest.approx(44.0)
    md = (rep / "report.md").read_text()
    assert "hystfit invert" in md and "--sine 10,10,3" in md and "% of stroke" in md and "40V_10Hz" in md
    assert "segment" in r.stdout  # the summary table


def test_invert_json_quiet_parquet_and_report_dir(tables, tmp_path):
    r = run("invert", tables["pi"], "--triangle", "8,20,2", "--offset", "3", "--out", tmp_path / "v.parquet",
            "--report-dir", tmp_path / "rep", "--json", "--no-plots")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["out"].endswith("v.parquet") and s["report_dir"].endswith("rep")
    assert s["target"]["kind"] == "triangle" and s["predicted_tracking"]["rmse_pct_of_stroke"] < 1
    assert len(pd.read_parquet(tmp_path / "v.parquet")) == s["target"]["samples"]
    assert not (tmp_path / "rep" / "plots").exists() and (tmp_path / "rep" / "report.md").exists()
    r = run("invert", tables["pi"], "--steps", "10,4@0.05", "--offset", "2", "--out", tmp_path / "s.csv", "--quiet")
    assert r.exit_code == 0 and r.stdout == ""
    r = run("invert", tables["pi"], "--multi", "--offset", "2", "--fs", "2000", "--out", tmp_path / "m.tsv",
            "--json", "--no-plots")
    s = json.loads(r.stdout)
    assert [seg["frequency_Hz"] for seg in s["segments"]] == [0.5, 1, 2, 5, 10] and s["target"]["fs_Hz"] == 2000


def test_invert_target_file_columns_and_units(tables, tmp_path):
    t = np.arange(2000) * 1e-4
    y = 3 + 4 * (1 - np.cos(2 * np.pi * 10 * t))
    f = tmp_path / "target.csv"
    pd.DataFrame({"time_ms": t * 1e3, "voltage_V": 0.0, "target_um": y}).to_csv(f, index=False)
    r = run("invert", tables["pi"], f, "--out", tmp_path / "v.csv", "--json", "--no-plots")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["target"]["kind"] == "file" and s["target"]["fs_Hz"] == pytest.approx(1e4)
    g = tmp_path / "plain.txt"
    g.write_text("\n".join(f"{v:.9g} {v:.9g}" for v in y) + "\n")
    r = run("invert", tables["pi"], g, "--fs", "10000", "--target-col", "1", "--out", tmp_path / "w.csv", "--quiet")
    assert r.exit_code == 0, r.output
    h = tmp_path / "named.csv"
    pd.DataFrame({"clock": t, "ref": y}).to_csv(h, index=False)
    r = run("invert", tables["pi"], h, "--time-col", "clock", "--target-col", "ref", "--out", tmp_path / "x.csv",
            "--quiet")
    assert r.exit_code == 0, r.output
    k = tmp_path / "unitless.csv"
    pd.DataFrame({"t": t, "setpoint": y * 1e3}).to_csv(k, index=False)
    r = run("invert", tables["pi"], k, "--output-unit", "nm", "--out", tmp_path / "nm.csv")
    assert_error(r, "nm", tmp_path / "nm.csv", tmp_path / "nm_report")


def test_invert_condition_method_initial_voltage_and_limits(tables, tmp_path):
    base = ("invert", tables["pi"], "--sine", "10,10,2", "--offset", "2", "--json", "--no-plots")
    s = json.loads(run(*base, "--condition", "40,10", "--out", tmp_path / "a.csv").stdout)
    seg = s["segments"][0]
    assert seg["how"] == "forced" and [c["label"] for c in seg["cells"]] == ["40V_10Hz"]
    s = json.loads(run(*base, "--method", "nearest", "--out", tmp_path / "b.csv").stdout)
    assert s["method"] == "nearest" and len(s["segments"][0]["cells"]) == 1
    s = json.loads(run(*base, "--initial-voltage", "0", "--out", tmp_path / "c.csv").stdout)
    assert s["initial_voltage"] == {"V": 0.0, "source": "given"} and any("jump" in n for n in s["notes"])
    r = run(*base, "--vmin", "0", "--vmax", "30", "--out", tmp_path / "d.csv")
    assert r.exit_code == 0
    s = json.loads(r.stdout)
    assert s["clipping"]["spans"] >= 2 and s["limits"]["vmax_source"] == "given"
    assert s["predicted_tracking_without_limits"] is not None
    assert "clipped to the voltage limits" in r.stderr and "first" in r.stderr
    v = pd.read_csv(tmp_path / "d.csv")["voltage_V"]
    assert v.max() <= 30 + 1e-12 and v.min() >= 0
    r = run(*base, "--max-slew", "500", "--out", tmp_path / "e.csv")
    s = json.loads(r.stdout)
    assert s["slew_limiting"]["spans"] >= 1 and "slew-rate limited" in r.stderr
    assert np.max(np.abs(np.diff(pd.read_csv(tmp_path / "e.csv")["voltage_V"]))) <= 500 * 1e-4 * (1 + 1e-9)


def test_invert_refuses_to_overwrite_without_force(tables, tmp_path):
    out = tmp_path / "v.csv"
    out.write_text("keep\n")
    r = run("invert", tables["pi"], "--sine", "10,10", "--offset", "2", "--out", out)
    assert_error(r, "--force", tmp_path / "v_report")
    assert out.read_text() == "keep\n"
    r = run("invert", tables["pi"], "--sine", "10,10", "--offset", "2", "--out", out, "--force", "--quiet")
    assert r.exit_code == 0 and out.read_text().startswith("time_s,")
    (tmp_path / "w_report").mkdir()
    (tmp_path / "w_report" / "x").write_text("x")
    r = run("invert", tables["pi"], "--sine", "10,10", "--offset", "2", "--out", tmp_path / "w.csv")
    assert_error(r, "--force", tmp_path / "w.csv")


@pytest.mark.parametrize("args,needle", [
    ((), "exactly one target"),
    (("--sine", "10,10", "--multi"), "exactly one target"),
    (("--sine", "10"), "--sine"),
    (("--sine", "a,b"), "--sine"),
    (("--sine", "-10,10"), "amplitude"),
    (("--sine", "10,5000"), "samples per cycle"),
    # a built-in target over the sample limit is refused before anything is allocated (the 1e7-cycle typo
    # asked for 10⁹ samples and was OOM-killed; the 1e300 ones overflowed the count into a traceback)
    (("--sine", "10,20,1e7", "--offset", "2"), "--sine 10,20,1e7: 5000000001 samples at 10000 Hz exceed the limit "
                                               "of 1e+07 samples"),
    (("--triangle", "10,10,1e300"), "--triangle 10,10,1e300: 1e+303 samples"),
    (("--steps", "10,4@1e300"), "use a shorter hold, fewer levels or a lower sample rate (--fs)"),
    (("--multi", "--fs", "1e300"), "--multi: "),
    (("--triangle", "10,0"), "frequency"),
    (("--steps", "10@x"), "hold"),
    (("--steps", "10,10"), "differ"),
    (("--sine", "10,10", "--method", "cubic"), "--method"),
    (("--sine", "10,10", "--vmin", "5", "--vmax", "5"), "vmin < vmax"),
    (("--sine", "10,10", "--initial-voltage", "500"), "initial voltage"),
    (("--sine", "10,10", "--max-slew", "0"), "slew"),
    (("--sine", "10,10", "--condition", "40"), "--condition"),
    (("--sine", "10,10", "--fs", "-1"), "--fs"),
    (("--sine", "10,10", "--time-col", "t"), "TARGET file"),
    (("--sine", "10,10", "--output-unit", "furlong"), "--output-unit"),
    (("missing.csv",), "no such file"),
])
def test_invert_bad_input_exit_2_one_line_nothing_written(tables, tmp_path, args, needle):
    out = tmp_path / "v.csv"
    r = run("invert", tables["pi"], *args, "--out", out)
    assert_error(r, needle, out, tmp_path / "v_report")


def test_invert_bad_params_and_output_names(tables, tmp_path):
    assert_error(run("invert", tmp_path / "nope.json", "--sine", "10,10", "--out", tmp_path / "v.csv"),
                 "no such parameter file", tmp_path / "v.csv")
    assert_error(run("invert", tables["pi"], "--sine", "10,10", "--out", tmp_path / "v.xlsx"), "unsupported",
                 tmp_path / "v.xlsx")
    r = run("invert", tables["pi"], "--sine", "10,10")
    assert r.exit_code == 2 and "--out" in r.output


@pytest.mark.slow
def test_invert_a_million_samples_peaks_under_1_GB_resident(tables, tmp_path, peak_rss_code):
    """The whole command (load, invert two cells, preview, CSV, report, figure) on a 10⁶-sample target,
    in a fresh process whose peak resident set size (what /usr/bin/time -v reports) is read at exit."""
    out = tmp_path / "v.csv"
    code = peak_rss_code
    r = subprocess.run([sys.executable, "-c", code, "invert", str(tables["pi"]), "--sine", "10,10,1000", "--offset", "2",
                        "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    peak_kB = int(r.stderr.split("peak_kB")[1].split()[0])  # Linux: kilobytes
    assert peak_kB < 1_000_000, f"peak RSS {peak_kB / 1e3:.0f} MB"
    df = pd.read_csv(out)
    assert len(df) == 1_000_001 and list(df.columns) == ["time_s", "voltage_V", "predicted_displacement_um"]
    summary = json.loads((tmp_path / "v_report" / "report.json").read_text())
    assert summary["target"]["samples"] == 1_000_001 and summary["predicted_tracking"]["rmse_pct_of_stroke"] < 1


# ------------------------------------------------------------------------------------------ track


def test_track_compares_controllers_and_writes_outputs(tables, tmp_path):
    out = tmp_path / "tr"
    r = run("track", tables["pi"], "--sine", "10,10,2", "--offset", "2", "--controller", "pid,ff,ff+pid,smc",
            "--plant", tables["bw"], "--noise", "0.008", "--seed", "3", "--out", out)
    assert r.exit_code == 0, r.output
    names = {p.name for p in out.iterdir()}
    assert {"pid.csv", "ff.csv", "ff_plus_pid.csv", "smc.csv", "summary.json", "report.md", "plots"} <= names
    assert {"errors.png", "pid.png", "smc.png"} <= {p.name for p in (out / "plots").iterdir()}
    s = json.loads((out / "summary.json").read_text())
    assert s["plant_model"] == "bw" and s["noise"] == {"sigma_um": 0.008, "seed": 3}
    rows = {row["controller"]: row for row in s["comparison"]}
    assert set(rows) == {"pid", "ff", "ff+pid", "smc"}
    assert rows["ff+pid"]["rmse_pct"] < rows["ff"]["rmse_pct"]
    df = pd.read_csv(out / "ff_plus_pid.csv")
    assert list(df.columns) == ["time_s", "reference_um", "displacement_um", "measured_um", "voltage_V", "command_V",
                                "error_um"]
    md = (out / "report.md").read_text()
    assert "another model" in md and "Kp =" in md and "sliding" in md
    assert "ff+pid" in r.stdout


def test_track_steps_given_gains_json_parquet_and_options(tables, tmp_path):
    r = run("track", tables["pi"], "--steps", "10@0.05", "--offset", "2", "--controller", "pid,ff+pid", "--kp", "0.5",
            "--ki", "5000", "--kd", "0.0001", "--anti-windup", "clamp", "--vmax", "38", "--max-slew", "2e5",
            "--format", "parquet", "--no-plots", "--json", "--out", tmp_path / "t")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    pid = s["runs"][0]["details"]["pid"]
    assert (pid["kp"], pid["ki"], pid["kd"], pid["anti_windup"], pid["rule"]) == (0.5, 5000, 0.0001, "clamp", "given")
    assert "t90_s" in s["comparison"][0] and s["runs"][0]["steps"][0]["to"] == pytest.approx(12.0)
    assert s["limits"]["max_slew_V_per_s"] == 2e5 and s["limits"]["vmax_V"] == 38
    assert (tmp_path / "t" / "pid.parquet").exists() and not (tmp_path / "t" / "plots").exists()
    r = run("track", tables["pi"], "--multi", "--fs", "2000", "--offset", "2", "--controller", "smc", "--bandwidth",
            "50", "--method", "nearest", "--condition", "40,10", "--initial-voltage", "5", "--quiet",
            "--out", tmp_path / "u")
    assert r.exit_code == 0 and r.stdout == "", r.output
    s = json.loads((tmp_path / "u" / "summary.json").read_text())
    assert s["runs"][0]["details"]["smc"]["bandwidth_Hz"] == 50 and s["initial_voltage"]["V"] == 5
    t = np.arange(1000) * 1e-4
    f = tmp_path / "ref.csv"
    pd.DataFrame({"t": t, "reference_um": 3 + 3 * (1 - np.cos(2 * np.pi * 20 * t))}).to_csv(f, index=False)
    r = run("track", tables["pi"], f, "--controller", "ff", "--out", tmp_path / "v", "--json", "--no-plots")
    assert r.exit_code == 0 and json.loads(r.stdout)["target"]["kind"] == "file"
    g = tmp_path / "ref2.csv"
    pd.DataFrame({"clock_ms": t * 1e3, "wanted": 3 + 3 * (1 - np.cos(2 * np.pi * 20 * t))}).to_csv(g, index=False)
    r = run("track", tables["pi"], g, "--time-col", "clock_ms", "--target-col", "wanted", "--output-unit", "um",
            "--controller", "ff", "--out", tmp_path / "w", "--json", "--no-plots")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["target"]["fs_Hz"] == pytest.approx(1e4)
    r = run("track", tables["pi"], "--triangle", "8,20,2", "--offset", "2", "--vmin", "-2", "--controller", "pid",
            "--out", tmp_path / "x", "--json", "--no-plots")
    s = json.loads(r.stdout)
    assert s["target"]["kind"] == "triangle" and s["limits"]["vmin_V"] == -2
    r = run("track", tables["pi"], "--sine", "10,10", "--out", tmp_path / "v")
    assert_error(r, "--force")
    r = run("track", tables["pi"], "--sine", "10,10", "--offset", "2", "--controller", "ff", "--out", tmp_path / "v",
            "--force", "--quiet", "--no-plots")
    assert r.exit_code == 0


@pytest.mark.parametrize("args,needle", [
    (("--controller", "lqr"), "--controller"),
    (("--controller", "pid,pid"), "twice"),
    (("--noise", "-1"), "--noise"),
    (("--anti-windup", "none"), "--anti-windup"),
    (("--format", "xlsx"), "--format"),
    (("--bandwidth", "0"), "--bandwidth"),
    (("--controller", "ff", "--kp", "1"), "--kp"),
    (("--kp", "-1"), "--kp"),
    (("--plant", "nope.json"), "no such parameter file"),
    (("--method", "cubic"), "--method"),
    (("--vmin", "10", "--vmax", "0"), "vmin < vmax"),
])
def test_track_bad_input_exit_2_one_line_nothing_written(tables, tmp_path, args, needle):
    out = tmp_path / "tr"
    r = run("track", tables["pi"], "--sine", "10,10,1", "--offset", "2", *args, "--out", out)
    assert_error(r, needle, out)
    assert not any(p.name.startswith(".tr.tmp") for p in tmp_path.iterdir())


@pytest.mark.parametrize("target", [("--sine", "10,10,1e7"), ("--steps", "10@1e300")])
def test_track_refuses_a_built_in_target_over_the_sample_limit(tables, tmp_path, target):
    out = tmp_path / "tr"
    r = run("track", tables["pi"], *target, "--offset", "2", "--out", out)
    assert_error(r, f"{' '.join(target)}: ", out)
    assert "exceed the limit of 1e+07 samples" in r.stderr


def test_simulate_refuses_a_capture_in_another_unit_than_the_parameters(tables, tmp_path):
    """The µm table on the same capture in nm: refused as invert refuses an nm target (it gave an RMSE of
    thousands "um", exit 0, and a prediction file labelling the nm data as µm)."""
    d = pd.read_csv(SAMPLE / "a20V_f10Hz.csv")
    nm = tmp_path / "nm.csv"
    pd.DataFrame({"time_s": d.time_s, "voltage_V": d.voltage_V, "displacement_nm": d.displacement_um * 1e3}).to_csv(
        nm, index=False)
    out = tmp_path / "sim"
    r = run("simulate", tables["pi"], SAMPLE / "a20V_f10Hz.csv", nm, "--out", out, "--no-plots")
    assert_error(r, f"nm.csv: the measured output is in nm but {tables['pi']} is in um; convert it to um", out)
    assert not any(p.name.startswith(".sim") for p in tmp_path.iterdir())
    # an input-only capture has no output unit to disagree with
    pd.DataFrame({"time_s": d.time_s, "voltage_V": d.voltage_V}).to_csv(tmp_path / "u.csv", index=False)
    r = run("simulate", tables["pi"], tmp_path / "u.csv", "--out", out, "--no-plots", "--quiet")
    assert r.exit_code == 0, r.output
    # the same check (one home, ParamsFile.check_unit) still refuses an nm target in invert
    pd.DataFrame({"time_s": d.time_s, "target_nm": d.displacement_um * 1e3}).to_csv(tmp_path / "t.csv", index=False)
    assert_error(run("invert", tables["pi"], tmp_path / "t.csv", "--out", tmp_path / "v.csv"),
                 "t.csv (column 'target_nm') is in nm", tmp_path / "v.csv")  # the target's file named


def test_invert_track_and_simulate_load_neither_pandas_nor_matplotlib_in_the_commands_process(tables, tmp_path):
    """The voltages, runs and predictions are written without pandas, and the figures are drawn by the figure
    server the console script forks at its start (matplotlib loads there meanwhile)."""
    probe = ("import atexit, sys\n"
             "atexit.register(lambda: print('LOADED', 'pandas' in sys.modules, 'matplotlib' in sys.modules))\n"
             "from hystfit.cli import main\n"
             "main()\n")
    for args, figure in ((["invert", tables["pi"], "--sine", "10,10,3", "--offset", "2", "--out", tmp_path / "v.csv"],
                          tmp_path / "v_report" / "plots" / "tracking.png"),
                         (["track", tables["pi"], "--sine", "10,10,2", "--offset", "2", "--controller", "ff,pid",
                           "--out", tmp_path / "tr"], tmp_path / "tr" / "plots" / "errors.png"),
                         (["simulate", tables["pi"], SAMPLE / "a20V_f10Hz.csv", "--out", tmp_path / "sim"],
                          tmp_path / "sim" / "plots" / "loop_a20V_f10Hz.png")):
        proc = subprocess.run([sys.executable, "-c", probe, *map(str, args)], capture_output=True, text=True,
                              timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert "LOADED False False" in proc.stdout.splitlines(), (args[0], proc.stdout[-300:])
        assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, words", [
    (("--sine", "5,inf"), "--sine 5,inf: frequency (Hz) must be a finite number > 0"),
    (("--sine", "5,10", "--vmin", "nan"), "--vmin must be a finite number"),
    (("--sine", "5,10", "--fs", "inf"), "--sine 5,10: the sample rate (--fs, Hz) must be a finite number > 0"),
])
def test_invert_bad_numbers_name_their_option(tables, tmp_path, args, words):
    """A blind test's find: "vmin must be a finite number", "frequency_Hz must be …": the option the
    user typed is named now."""
    r = run("invert", tables["pi"], "--out", tmp_path / "v.csv", *args)
    assert r.exit_code == 2 and words in r.stderr and "Traceback" not in r.output, r.output


def test_invert_says_how_well_the_cells_fit_the_stage_and_which_cells_a_clamp_used(tables, tmp_path):
    """A blind test's find: invert's predicted tracking error is the model following its own inverse
    (≈ 1e-15 µm for PI), where tracking on the stage was 0.47 µm, and nothing said how far the model
    was from the stage. The summary, the report and the console now give the cells' fit RMSE on
    their identification data (weighted by the blend) as the floor of a measured error; a condition
    clamped onto the grid names the cells that stand for it."""
    params = json.loads(tables["pi"].read_text())
    fit = {c["label"]: c["metrics"]["rmse_um"] for c in params["conditions"]}
    r = run("invert", tables["pi"], "--sine", "8,10,3", "--offset", "3", "--out", tmp_path / "v.csv", "--json",
            "--no-plots")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    seg = s["segments"][0]
    want = float(np.sqrt(sum(c["weight"] * fit[c["label"]] ** 2 for c in seg["cells"])))
    assert seg["cells_fit_rmse_um"] == pytest.approx(want, rel=1e-12) and s["cells_fit_rmse_um"] == pytest.approx(want)
    assert s["predicted_tracking"]["rmse_um"] < 0.1 * want  # the inversion alone: far below the model's own error
    r = run("invert", tables["pi"], "--sine", "60,10,3", "--offset", "3", "--out", tmp_path / "w.csv",
            "--report-dir", tmp_path / "rep", "--no-plots")
    assert r.exit_code == 0, r.output
    assert "the cells used fit their identification data to" in r.output
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "cell fit RMSE" in md and "reproduce their identification data to" in md
    clamp = [n for n in json.loads((tmp_path / "rep" / "report.json").read_text())["notes"] if "clamped to" in n]
    assert clamp and "(cells used: 40V_10Hz" in clamp[0]


def test_a_relaxed_history_is_identified_and_inverted_as_a_rest(tmp_path):
    """A blind test's rig-like capture: the stage rested at 50 V with its loops closed there, then a
    sine whose amplitude rises from 0 about it. PI with the default history (a ramp from 0 V) fitted
    it 5–10× worse than the data allow; ``--model-option history=relaxed`` fits it to the noise, and
    its feedforward assumes that rest (a constant pre-roll), which the report says."""
    from hystfit.models.pi import PI
    from hystfit.params import DataScale
    from hystfit.synth import write_capture

    dt = 1e-4
    t = np.arange(0, 2.0, dt)
    u = 50.0 + np.clip(t / 1.8, 0, 1) * 40.0 * np.sin(2 * np.pi * 10 * t)
    truth = PI(n_operators=10, history="relaxed").adapt(DataScale.from_arrays([u], [u], [dt]))
    th = np.r_[0.3 * np.exp(-truth.r / 15.0), 3.0]
    y = truth.simulate_one(th, u, dt) + 0.02 * np.random.default_rng(0).standard_normal(t.size)
    write_capture(tmp_path / "rig.csv", t, u, y)
    rmse = {}
    for history in ("ramp", "relaxed"):
        r = run("identify", tmp_path / "rig.csv", "--model-option", f"history={history}", "--out",
                tmp_path / history, "--no-plots", "--quiet", "--json")
        assert r.exit_code == 0, r.output
        rmse[history] = json.loads(r.stdout)["conditions"][0]["metrics"]["rmse_um"]
    assert rmse["relaxed"] < 0.03 and rmse["ramp"] > 3 * rmse["relaxed"], rmse
    params = tmp_path / "relaxed" / "params.json"
    assert json.loads(params.read_text())["model"]["options"] == {"history": "relaxed"}
    r = run("invert", params, "--sine", "20,10,3", "--offset", "15", "--out", tmp_path / "v.csv",
            "--report-dir", tmp_path / "rep", "--no-plots", "--quiet")
    assert r.exit_code == 0, r.output
    assert "history assumed: at rest at it" in (tmp_path / "rep" / "report.md").read_text()
    # on the plant resting at the first voltage with its loops closed there, the voltages track the target's
    # shape; the level is another matter: the plays whose threshold the capture's ±40 V never reached stayed
    # at 50 V, indistinguishable from the offset, and at another rest voltage they add another constant
    v = pd.read_csv(tmp_path / "v.csv")
    err = truth.simulate_one(th, v["voltage_V"].to_numpy(), dt) - v["predicted_displacement_um"].to_numpy()
    assert np.std(err) < 0.05, np.std(err)
    # track steps the identified plant from the same rest (a review's find: its PI stepper always ramped
    # from 0 V, 22.5 µm off a relaxed plant at 50 V): feedforward through its own model tracks exactly
    r = run("track", params, "--sine", "20,10,3", "--offset", "15", "-c", "ff", "--out", tmp_path / "trk",
            "--no-plots", "--quiet")
    assert r.exit_code == 0, r.output
    (ff,) = json.loads((tmp_path / "trk" / "summary.json").read_text())["runs"]
    assert ff["metrics"]["rmse_um"] < 1e-6, ff["metrics"]
