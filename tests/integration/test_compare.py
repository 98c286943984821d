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
    assert {"j_search", "objective_mse_search"} <= set(df.columns)
    assert (df["j"] <= df["j_search"] * (1 + 1e-9)).all()  # the polish never makes a run worse
    auto = df[df["optimizer"] == "auto"]
    np.testing.assert_allclose(auto["j"], auto["j_search"], rtol=1e-9)  # auto is not polished again
    assert df.groupby(["model", "optimizer", "condition"])["seed"].nunique().eq(2).all()  # a seed per run
    md = (out / "compare.md").read_text()
    for heading in ("## Ranking", "002 Table 3 style", "002 Table 2 style", "004 Table 2 style",
                    "The searches alone, before the polish"):
        assert heading in md
    # 002 Table 3 as printed: a row per performance figure, a column per model / optimizer, and
    # every worst case names where it occurred
    assert "| performance | pi / pso | bw / pso | pi / auto | bw / auto |" in md
    assert "| maximum error (µm) at 60 V | " in md and "(80 Hz)" in md
    # 002 Table 2 as printed: a row per model and voltage level, a column per frequency
    assert "| model | optimizer | voltage | 80 Hz |" in md and "| pi | pso | 0–20 V |" in md
    # 004 Table 2: min / max / mean / std of J and RMSE over runs, median time
    assert "| model | optimizer | condition | runs | J min | J max | J mean | J std | RMSE min (um) |" in md
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


def test_report_tables_and_ranking_from_known_cells():
    """The tables and the ranking are computed from the cells, so build cells with known numbers."""
    from hystfit.compare import CellResult, CompareResult, RunMetrics
    from hystfit.report.compare_report import optimizer_table, ranking, runtime_table, table3

    def cell(model, opt, a, f, rmses, js, times, search=None, r2=0.99):
        runs = tuple(RunMetrics(i, 100 + i, j, j, {"rmse_um": r, "r2": r2, "mape": r, "smape": r,
                                                   "max_error_um": 3 * r}, t, 10, np.empty(0),
                                search[i] if search else j, search[i] if search else j)
                     for i, (r, j, t) in enumerate(zip(rmses, js, times)))
        best = int(np.argmin(js))
        return CellResult(model, opt, a, f, f"{a:g}V_{f:g}Hz", 5, runs, best)

    conds = [((20.0, 10.0), "20V_10Hz"), ((20.0, 80.0), "20V_80Hz"), ((60.0, 10.0), "60V_10Hz"),
             ((60.0, 80.0), "60V_80Hz")]
    cells = []
    for (a, f), _ in conds:
        worse = 1.5 if (a, f) == (60.0, 80.0) else 1.0
        cells.append(cell("m1", "o1", a, f, [0.1 * worse], [1.0], [0.5]))
        cells.append(cell("m2", "o1", a, f, [0.2], [2.0], [1.0 if f == 10 else 2.0]))
    res = CompareResult(("m1", "m2"), ("o1",), tuple(conds), {}, tuple(cells), runs=1)
    t3 = table3(res)
    assert list(t3.columns) == ["performance", "m1", "m2"]
    row = dict(zip(t3["performance"], t3["m1"]))
    assert row["maximum RMSE (µm)"] == "0.15 (60V_80Hz)"
    assert row["maximum error (µm) at 20 V"] == "0.3 (10 Hz)"  # first of the tied conditions
    assert row["maximum error (µm) at 60 V"] == "0.45 (80 Hz)"
    rt = runtime_table(res)
    assert list(rt.columns) == ["model", "voltage", "10 Hz", "80 Hz"]
    assert rt.loc[(rt.model == "m2") & (rt.voltage == "0–60 V"), "80 Hz"].item() == 2.0
    text = "\n".join(ranking(res))
    assert "run-to-run spread is unknown" in text
    assert "1. `m1`" in text and "lower than `m2` at 4 of 4 conditions" in text

    # with ≥ 6 conditions the paired comparison is a Wilcoxon signed-rank test over conditions
    conds8 = [((a, f), f"{a:g}V_{f:g}Hz") for a in (20.0, 60.0) for f in (10.0, 20.0, 40.0, 80.0)]
    cells = [cell(m, "o1", a, f, [r + 0.01 * f / 80], [1.0], [1.0]) for (a, f), _ in conds8
             for m, r in (("m1", 0.1), ("m2", 0.105 if f < 80 else 0.09), ("m3", 0.3))]
    text = "\n".join(ranking(CompareResult(("m1", "m2", "m3"), ("o1",), tuple(conds8), {}, tuple(cells), runs=1)))
    assert "not consistently below `m2` (lower at 6 of 8 conditions, Wilcoxon signed-rank" in text
    assert "consistently below `m3` (lower at 8 of 8 conditions" in text

    # repeated runs: the optimizer table's statistics, and a ranking by the search's J
    js = {"o1": [1.0, 2.0, 3.0], "o2": [1.1, 2.1, 3.1]}
    cells = [cell("m1", o, 60.0, 80.0, [0.1, 0.2, 0.3], [1.0] * 3, [1.0, 2.0, 9.0], search=js[o]) for o in js]
    res = CompareResult(("m1",), ("o1", "o2"), (((60.0, 80.0), "60V_80Hz"),), {}, tuple(cells), runs=3)
    ot = optimizer_table(res)
    first = ot.iloc[0]
    assert (first["RMSE min (um)"], first["RMSE max (um)"]) == (0.1, 0.3)
    assert first["RMSE mean (um)"] == pytest.approx(0.2) and first["RMSE std (um)"] == pytest.approx(0.1)
    assert first["time median (s)"] == 2.0
    text = "\n".join(ranking(res))
    assert "J of the search (before the polish)" in text
    # three runs against three: the U test cannot reach 0.05 (least p 0.1), the spread decides
    assert "within run-to-run spread of `o2`" in text and "Mann–Whitney" not in text
    assert "differ by less than 0.01 %" in text


def test_shared_structure_is_identified_once_and_reported(tmp_path):
    """hammerstein's linear part comes from all captures (sine-only here: the gain/phase route), is
    handed to every cell, and compare.md says how it was found."""
    from hystfit.report.compare_report import write_compare_outputs

    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a20V_f80Hz.csv"])
    res = compare(caps, ["hammerstein"], ["auto"], jobs=1)
    assert all(c.ok for c in res.cells) and len(res.notes) == 1
    assert "gain and phase measured per frequency" in res.notes[0]
    write_compare_outputs(res, tmp_path, make_figures=False)
    md = (tmp_path / "compare.md").read_text()
    assert "## Structure identified once from all captures" in md and res.notes[0] in md


def test_shared_structures_are_prepared_side_by_side_with_the_serial_numbers(monkeypatch):
    """pi2's stage and hammerstein's linear part are identified in separate processes (fork_map with
    --jobs workers) and hand the cells exactly what a serial preparation hands them."""
    import hystfit.compare as cmp

    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f40Hz.csv", SAMPLE / "a60V_f80Hz.csv"])
    names = ["pi2", "pi", "hammerstein"]
    workers = []
    real = cmp.fork_map
    monkeypatch.setattr(cmp, "fork_map", lambda fn, n, w: workers.append(w) or real(fn, n, w))
    serial = {m: {} for m in names}
    notes_serial = cmp._prepare_shared_structure(caps, names, serial, jobs=1)
    forked = {m: {} for m in names}
    notes_forked = cmp._prepare_shared_structure(caps, names, forked, jobs=2)
    assert workers == [1, 2]
    assert serial == forked and notes_serial == notes_forked
    assert serial["pi"] == {} and serial["pi2"] and serial["hammerstein"] and len(notes_serial) == 2


def test_cells_of_models_without_shared_structure_run_while_it_is_identified(monkeypatch):
    """pi's cells (in worker processes) do not wait for pi2's stage: the preparation (in a thread)
    waits here until a pi cell has finished, which times out if the cells waited for it; the numbers
    equal the sequential path's (one process: every model prepared first)."""
    import threading

    import hystfit.compare as cmp
    from hystfit.models.base import Model

    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f40Hz.csv"])
    names, opts = ["pi2", "pi"], {"pi2": {"n_operators": 6}}
    pi_done = threading.Event()
    seen = []
    real = cmp.prepare_shared

    def waiting_prepare(model, captures, store=None, resume=False):
        seen.append(pi_done.wait(30))
        return real(model, captures, store, resume)

    def progress(kind, info):
        if kind == "advance" and info["label"].startswith("pi/"):
            pi_done.set()

    monkeypatch.setattr(cmp, "prepare_shared", waiting_prepare)
    overlapped = compare(caps, names, ["auto"], jobs=2, model_options=opts, progress=progress)
    assert seen == [True] and all(c.ok for c in overlapped.cells)
    monkeypatch.setattr(cmp, "prepare_shared", real)
    monkeypatch.setattr(Model, "shares_structure", lambda self: False)  # nothing overlaps: prepared first
    sequential = compare(caps, names, ["auto"], jobs=1, model_options=opts)
    assert overlapped.notes == sequential.notes and len(overlapped.notes) == 1
    assert [t.name for t in threading.enumerate() if t.name == "hystfit-prepare"] == []
    for a, b in zip(overlapped.cells, sequential.cells):
        assert (a.model, a.label) == (b.model, b.label)
        assert a.runs[0].fun == b.runs[0].fun and np.array_equal(a.theta, b.theta)


def test_a_failed_overlapped_compare_leaves_no_preparation_running(monkeypatch):
    """A bound typo on a model without shared structure is exit 2 before the preparation starts;
    a failure during the cells waits for the preparation before it is raised."""
    import threading
    import time

    import hystfit.compare as cmp
    from hystfit.errors import ConfigError

    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f40Hz.csv"])
    started = []
    real = cmp._BackgroundPreparation
    monkeypatch.setattr(cmp, "_BackgroundPreparation", lambda *a: started.append(1) or real(*a))
    with pytest.raises(ConfigError, match="nonexistent"):
        compare(caps, ["pi2", "pi"], ["auto"], jobs=2, bounds={"pi": {"nonexistent": (0.0, 1.0)}})
    assert started == []

    def failing_run_cells(*a, **k):
        raise RuntimeError("a batch failed")

    real_prepare = cmp.prepare_shared
    finished = []

    def slow_prepare(*a, **k):  # still running when the batch fails
        time.sleep(1.0)
        result = real_prepare(*a, **k)
        finished.append(1)
        return result

    monkeypatch.setattr(cmp, "prepare_shared", slow_prepare)
    monkeypatch.setattr(cmp, "run_cells", failing_run_cells)
    with pytest.raises(RuntimeError, match="a batch failed"):
        compare(caps, ["pi2", "pi"], ["auto"], jobs=2, model_options={"pi2": {"n_operators": 6}})
    assert started == [1] and finished == [1]  # waited for, not left behind
    assert not [t for t in threading.enumerate() if t.name == "hystfit-prepare"]


# ------------------------------------------------------------------ issue 13: compare takes identify's flags
def test_every_population_search_gets_the_same_budget_and_the_csv_says_so(tmp_path):
    """--pop 8 --iters 5 is 40 evaluations for every search; ipso (no iteration count) used to
    ignore --iters and ran to its 60,000-evaluation default."""
    out = tmp_path / "cmp"
    r = CliRunner().invoke(app, ["compare", str(FILES[0]), "--models", "bw", "--opts", "pso,ipso,gwo,igwo",
                                 "--pop", "8", "--iters", "5", "--opt-option", "stall_iter=null", "--no-polish",
                                 "--jobs", "1", "--no-figures", "--out", str(out), "--quiet"])
    assert r.exit_code == 0, r.output
    df = pd.read_csv(out / "compare.csv")
    assert (df["search_evaluations"] == 40).all(), df[["optimizer", "search_evaluations"]]
    assert (df["evaluations"] == df["search_evaluations"]).all()  # no polish
    md = (out / "compare.md").read_text()
    assert "- `ipso`: pop=8, max_evals=40" in md and "- `pso`: pop=8, iters=5" in md


def test_bounds_model_and_optimizer_options_reach_the_cells(captures):
    res = compare(captures, ["bw", "pi"], ["pso"], jobs=1, polish=False,
                  optimizer_options={"pso": {"pop": 6, "iters": 3, "max_evals": 12}},
                  model_options={"pi": {"n_operators": 4}}, bounds={"bw": {"Kv": (0.0, 0.05)}})
    bw = [c for c in res.cells if c.model == "bw"]
    pi = [c for c in res.cells if c.model == "pi"]
    assert all(c.ok for c in res.cells)
    assert all(0.0 <= c.theta[c.param_names.index("Kv")] <= 0.05 for c in bw)
    default_pi = compare(captures, ["pi"], ["pso"], jobs=1, polish=False,
                         optimizer_options={"pso": {"pop": 6, "iters": 2}}).cells[0]
    assert all(c.n_params == default_pi.n_params - 6 for c in pi)  # 4 play operators instead of 10
    assert all(r.search_nfev == 12 for c in res.cells for r in c.runs)
    assert res.optimizer_settings["pso"]["max_evals"] == 12 and res.bounds["bw"] == {"Kv": (0.0, 0.05)}


def test_global_fit_is_one_cell_over_all_captures(captures):
    res = compare(captures, ["bw"], ["pso"], jobs=1, polish=False, global_fit=True,
                  optimizer_options={"pso": {"pop": 6, "iters": 3}})
    assert [lab for _, lab in res.conditions] == ["global"] and len(res.cells) == 1
    assert len(res.cells[0].predictions) == len(captures) and res.global_fit


@pytest.mark.parametrize("args,message", [
    (["--opt-option", "max_evals=-5"], "stop rule max_evals"),
    (["--opt-option", "vmax_frac=0.3"], "scope it, e.g. --opt-option pso.vmax_frac"),
    (["--opt-option", "nosuch.pop=3"], "'nosuch' is not one of pso, gwo"),
    (["--opt-option", "pso.nosuch=3"], "unknown option 'nosuch'"),
    (["--bounds", "alpha=0:1"], "'pi' has no 'alpha'"),
    (["--bounds", "bw.nosuch=0:1"], "unknown parameter 'nosuch'"),
    (["--model-option", "pi.n_operators=0"], "n_operators"),
    (["--model-option", "n_operators=4"], "'bw' has no 'n_operators'"),
])
def test_bad_compare_options_are_one_line_config_errors(tmp_path, args, message):
    r = CliRunner().invoke(app, ["compare", str(FILES[0]), "--models", "pi,bw", "--opts", "pso,gwo", "--pop", "6",
                                 "--iters", "2", "--jobs", "1", "--no-figures", "--out", str(tmp_path / "o"), *args])
    assert r.exit_code == 2, r.output
    assert message in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
    assert not (tmp_path / "o").exists()
