"""docs/models.md is generated from the registry by docs/make_model_docs.py: run it, check every model."""

import importlib.util
from pathlib import Path

import matplotlib.image as mpimg

from hystfit.registry import models

ROOT = Path(__file__).resolve().parents[2]


def load_script():
    spec = importlib.util.spec_from_file_location("make_model_docs", ROOT / "docs" / "make_model_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


from hystfit.references import cite  # noqa: E402


def test_model_docs_script_covers_every_registered_model(tmp_path):
    load_script().main(["--out", str(tmp_path)])
    md = (tmp_path / "models.md").read_text()
    for name in models.names():
        cls = models.get(name)
        assert f"## `{name}` — {cls.title}" in md
        assert cite(cls.reference) in md  # papers cited in full, never an internal file (issue 14 item 16)
        img = mpimg.imread(tmp_path / "figures" / f"model_{name}.png")
        assert img.shape[0] > 100 and img.shape[1] > 100
    # the committed page is what the script makes today (figures are binary and depend on the
    # matplotlib build, so only their presence is checked, below)
    assert md == (ROOT / "docs" / "models.md").read_text(), "run: python docs/make_model_docs.py"


def test_committed_docs_list_every_model():
    """The committed docs/models.md is current: regenerate it with `python docs/make_model_docs.py`."""
    md = (ROOT / "docs" / "models.md").read_text()
    for name in models.names():
        assert f"## `{name}`" in md, f"docs/models.md lacks {name}: run python docs/make_model_docs.py"
        assert (ROOT / "docs" / "figures" / f"model_{name}.png").exists()


def _documented_commands():
    """Every `hystfit ...` line of the README and the docs (code blocks and synopses)."""
    import re

    for page in (ROOT / "README.md", ROOT / "docs" / "invert.md", ROOT / "docs" / "diagnose.md"):
        lines = page.read_text().splitlines()
        for i, line in enumerate(lines):
            if not line.startswith("hystfit "):
                continue
            text = line.split("#")[0]
            j = i + 1  # synopses continue on indented lines
            while j < len(lines) and lines[j].startswith(" " * 8) and lines[j].strip().startswith(("[", "--")):
                text += " " + lines[j].split("#")[0]
                j += 1
            words = text.split()
            sub = words[1]
            flags = sorted({m.group(1) for m in re.finditer(r"(--[a-z][a-z0-9-]*)", text)})
            yield f"{page.name}:{i + 1}", sub, flags


def test_every_documented_command_uses_existing_options():
    """A flag the README or docs show for a command is one that command accepts (`--help` lists it)."""
    from typer.testing import CliRunner

    from hystfit.cli import app

    runner = CliRunner()
    helps: dict[str, str] = {}
    checked = 0
    for where, sub, flags in _documented_commands():
        if sub not in helps:
            r = runner.invoke(app, [sub, "--help"], env={"COLUMNS": "250", "TERM": "dumb"})
            assert r.exit_code == 0, f"{where}: `hystfit {sub}` is not a command"
            helps[sub] = r.output
        for flag in flags:
            if flag in ("--help",):
                continue
            assert flag in helps[sub], f"{where}: `hystfit {sub}` has no option {flag}"
            checked += 1
    assert checked > 40


def test_the_readme_python_api_example_runs(tmp_path, monkeypatch, capsys):
    """The README's Python API block, as written, from a directory holding sample_data."""
    import json

    readme = (ROOT / "README.md").read_text()
    block = readme.split("## Python API", 1)[1].split("```python", 1)[1].split("```", 1)[0]
    (tmp_path / "sample_data").symlink_to(ROOT / "sample_data")
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "README.md (Python API)", "exec"), {})
    assert "20V_10Hz" in capsys.readouterr().out
    report = tmp_path / "bw-report"
    params = json.loads((report / "params.json").read_text())
    assert params["model"]["name"] == "bw"
    assert (report / "plots" / "overview.png").exists() and len(list((report / "plots").glob("loop_*.png"))) == 24
