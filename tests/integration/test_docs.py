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


def test_model_docs_script_covers_every_registered_model(tmp_path):
    load_script().main(["--out", str(tmp_path)])
    md = (tmp_path / "models.md").read_text()
    for name in models.names():
        cls = models.get(name)
        assert f"## `{name}` — {cls.title}" in md
        assert cls.reference in md
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
