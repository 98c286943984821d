"""docs/architecture.md: a newcomer adds a model and a block by following the page (its code runs)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import hystfit.registry as registry
from hystfit import synth
from hystfit.capture import Capture
from hystfit.identify import identify
from hystfit.registry import Registry
from hystfit.factory import make_model, make_optimizer

DOC = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"


def _example(heading: str) -> str:
    text = DOC.read_text()
    section = text.split(f"## {heading}", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, f"no python example under '{heading}'"
    return blocks[0]


@pytest.fixture
def fresh_registries(monkeypatch):
    """The page's examples register into fresh registries (the built-in ones stay untouched)."""
    registry._load_builtin()
    models = Registry("model")
    for n in registry.models.names():
        models.register(registry.models.get(n))
    blocks = Registry("block")
    for n in registry.blocks.names():
        blocks.register(registry.blocks.get(n))
    monkeypatch.setattr(registry, "models", models)
    monkeypatch.setattr(registry, "blocks", blocks)
    return models, blocks


def _captures(gain=1.0):
    t, u = synth.raised_cosine(50.0, 20.0, 3, 10_000)
    y = synth.simulate_plant(synth.Plant.default().with_effects(synth.Effects(noise=True)), t, u) * gain
    return [Capture(source="c.csv", t=t, u=u, y=y, dt=1e-4, amplitude_V=50.0, frequency_Hz=20.0)]


def test_the_model_example_adds_a_working_model(fresh_registries):
    models, _ = fresh_registries
    exec(compile(_example("Adding a model"), "architecture.md", "exec"), {})
    assert "linear" in models.names()
    res = identify(_captures(), make_model("linear"), make_optimizer(registry.optimizers.get("auto")))
    fit = res.fits[0]
    assert fit.metrics["r2"] > 0.9  # a straight line through a hysteresis loop
    u = np.linspace(0, 50, 100)
    np.testing.assert_allclose(fit.model.invert(fit.theta, fit.model.simulate_one(fit.theta, u, 1e-4), 1e-4), u)


def test_the_block_example_adds_a_working_block(fresh_registries):
    _, blocks = fresh_registries
    exec(compile(_example("Adding a block"), "architecture.md", "exec"), {})
    assert "gain" in blocks.names()
    model = make_model("pi+gain", {"thresholds_V": list(synth.DEFAULT_THRESHOLDS_V)})
    res = identify(_captures(gain=1.05), model, make_optimizer(registry.optimizers.get("auto")))
    vals = dict(zip([p.name for p in res.fits[0].params], res.fits[0].theta))
    assert "gain.g" in vals and res.fits[0].metrics["rmse_um"] < 0.02
