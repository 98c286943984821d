"""--mape-floor on identify and compare (paper 002 takes MAPE over every sample: --mape-floor 0),
and every metric named in the report."""

import json
from pathlib import Path

import pandas as pd
from typer.testing import CliRunner

from hystfit.cli import app

CAPTURE = Path(__file__).resolve().parents[2] / "sample_data" / "a20V_f10Hz.csv"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def shifted(tmp_path):
    """The sample capture moved down by 3 µm, so its output crosses zero (where MAPE explodes)."""
    d = pd.read_csv(CAPTURE)
    d["displacement_um"] -= 2.9995  # half a digit off the 1 nm grid: no sample exactly 0
    p = tmp_path / "a20V_f10Hz.csv"
    d.to_csv(p, index=False)
    return p


def test_identify_mape_floor_zero_scores_every_sample_and_the_report_names_it(tmp_path):
    capture = shifted(tmp_path)
    r = run("identify", capture, "--out", tmp_path / "a", "--no-plots", "--mape-floor", "0")
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "a" / "params.json").read_text())["conditions"][0]["metrics"]
    assert m["mape_floor"] == 0.0 and m["n_excluded"] == 0 and m["j_model"] > 0
    r = run("identify", capture, "--out", tmp_path / "b", "--no-plots")
    d = json.loads((tmp_path / "b" / "params.json").read_text())["conditions"][0]["metrics"]
    assert d["mape_floor"] == 0.01 and d["n_excluded"] > 0  # samples near 0 µm left out
    assert d["mape"] < m["mape"]  # those samples are where MAPE explodes
    report = (tmp_path / "b" / "report.md").read_text()
    for name in ("`mape`", "`j`", "`j_model`", "`mape_floor`", "`smape`", "`re`"):
        assert name in report


def test_compare_mape_floor_and_bad_values(tmp_path):
    capture = shifted(tmp_path)
    mape = {}
    for floor in ("0", "0.01"):
        r = run("compare", capture, "--models", "pi", "--opts", "auto", "--out", tmp_path / floor, "--no-plots",
                "--jobs", "1", "--mape-floor", floor)
        assert r.exit_code == 0, r.output
        df = pd.read_csv(tmp_path / floor / "compare.csv")
        assert "j_model" in df.columns
        mape[floor] = float(df["mape"].iloc[0])
    assert mape["0"] > mape["0.01"]
    for bad in ("-0.5", "1", "abc"):
        r = run("identify", CAPTURE, "--out", tmp_path / "d", "--no-plots", "--mape-floor", bad)
        assert r.exit_code == 2, r.output
