"""`hystfit compare`: tables, figures, failure isolation, and pool = serial numbers."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from hystfit.cli import app
from hystfit.compare import compare
from hystfit.io import load_captures

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"
FILES = [SAMPLE / "a20V_f80Hz.csv", SAMPLE / "a60V_f80Hz.csv"]


@pytest.fixture(scope="module")
def captures():
    return load_captures(FILES)


def test_cli_compare_writes_every_table_and_figure(tmp_path):
    out = tmp_path / "cmp"
    r = CliRunner().invoke(app, ["compare", *map(str, FILES), "--models", "pi,bw", "--opts", "pso,auto",
                                 "--runs", "2", "--pop", "10", "--iters", "8", "--jobs", "1", "--out", str(out),
                                 "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert len(summary["cells"]) == 2 * 2 * 2 and summary["failed"] == []
    df = pd.read_csv(out / "compare.csv")
    assert len(df) == 2 * 2 * 2 * 2  # models × optimizers × conditions × runs
    assert {"model", "optimizer", "condition", "run", "seed", "rmse_um", "mape", "smape", "r2", "j", "runtime_s",
            "evaluations"} <= set(df.columns)
    md = (out / "compare.md").read_text()
    for heading in ("## Ranking", "002 Table 3 style", "002 Table 2 style", "004 Table 2 style"):
        assert heading in md
    figs = {p.name for p in (out / "figures").iterdir()}
    for key in ("rmse", "mape", "smape", "r2"):
        assert f"heatmap_{key}_pso.png" in figs
    assert {"r2_distribution_pso.png", "parity_worst_bw_pso.png", "loops_20V_80Hz.png",
            "convergence_bw_20V_80Hz.png", "fitness_box_bw_60V_80Hz.png"} <= figs


def test_failing_cell_is_reported_and_the_rest_goes_on(captures):
    res = compare(captures, ["pi", "bw"], ["auto"], jobs=1, model_options={"pi": {"n_operators": 0}})
    bad = [c for c in res.cells if not c.ok]
    good = [c for c in res.cells if c.ok]
    assert len(bad) == 2 and all(c.model == "pi" and "n_operators" in c.error for c in bad)
    assert len(good) == 2 and all(c.model == "bw" for c in good)


def test_pool_and_serial_give_the_same_numbers(captures):
    kw = dict(runs=2, seed=3, optimizer_options={"pso": {"pop": 8, "iters": 6}}, polish=False)
    a = compare(captures, ["bw"], ["pso"], jobs=1, **kw)
    b = compare(captures, ["bw"], ["pso"], jobs=2, **kw)
    for ca, cb in zip(a.cells, b.cells):
        assert [r.seed for r in ca.runs] == [r.seed for r in cb.runs]
        np.testing.assert_array_equal(ca.theta, cb.theta)
        assert [r.fun for r in ca.runs] == [r.fun for r in cb.runs]


def test_unknown_names_are_config_errors(tmp_path):
    r = CliRunner().invoke(app, ["compare", str(FILES[0]), "--models", "pi,nosuch", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "unknown model 'nosuch'" in r.stderr
    r = CliRunner().invoke(app, ["compare", str(FILES[0]), "--opts", "pso,pso", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "repeated" in r.stderr
