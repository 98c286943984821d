"""Every file of tests/corpus/ gives one error line naming it, exit code 2, nothing written."""

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hystfit.cli import app

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "corpus"
CASES = json.loads((CORPUS / "cases.json").read_text())
runner = CliRunner()


def test_every_corpus_file_has_a_case_and_every_case_a_file():
    files = {p.name for p in CORPUS.iterdir() if p.name not in ("cases.json", "README.md")}
    assert files == set(CASES)


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("p") / "o"
    r = runner.invoke(app, ["identify", str(ROOT / "sample_data" / "a20V_f10Hz.csv"), "--out", str(out),
                            "--no-plots", "-q"])
    assert r.exit_code == 0, r.output
    return out / "params.json"


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_gives_one_line(name, params_file, tmp_path):
    case = CASES[name]
    path = CORPUS / name
    out = tmp_path / "out"
    if case["command"] == "simulate":
        argv = ["simulate", str(path), str(ROOT / "sample_data" / "a20V_f10Hz.csv")]
    else:
        argv = [case["command"], str(path)]
    r = runner.invoke(app, argv + case["args"] + ["--out", str(out)])
    assert r.exit_code == 2, (r.output, r.exception)
    # a progress line ("loading the captures …") appears when the load takes a while (a busy machine)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.endswith(" …")]
    assert len(lines) == 1 and lines[0].startswith("hystfit: error: "), r.stderr
    assert name in lines[0], lines[0]
    assert case["expect"] in lines[0], lines[0]
    assert not out.exists()
