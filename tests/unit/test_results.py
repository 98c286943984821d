"""params.json: the type written is the type read back (ParamsFile ↔ dict), for plain and composite models."""

import json

import numpy as np
import pytest

from hystfit import synth
from hystfit.capture import Capture
from hystfit.registry import optimizers
from hystfit.factory import make_model, make_optimizer
from hystfit.identify import identify
from hystfit.results import SCHEMA_VERSION, Cell, ParamRecord, ParamsFile, dumps, load_params


@pytest.fixture(scope="module")
def fitted():
    plant = synth.Plant.default().with_effects(synth.Effects(delay=True, delay_s=5e-4))
    caps = []
    for i, f in enumerate((10.0, 40.0)):
        t, u = synth.raised_cosine(40.0, f, 3, 5_000)
        y = synth.simulate_plant(plant, t, u, seed=i)
        caps.append(Capture(source=f"a40V_f{f:g}Hz.csv", t=t, u=u, y=y, dt=t[1] - t[0], y_unit="um",
                            amplitude_V=40.0, frequency_Hz=f))
    out = {}
    for expr in ("pi", "pi+delay"):
        out[expr] = identify(caps, make_model(expr), make_optimizer(optimizers.get("auto")), seed=3)
    return out


@pytest.mark.parametrize("expr", ["pi", "pi+delay"])
def test_round_trip_is_exact(fitted, expr, tmp_path):
    res = fitted[expr]
    pf = ParamsFile.from_result(res)
    d = pf.to_dict()
    assert d["schema_version"] == SCHEMA_VERSION and d["model"]["name"] == expr
    back = ParamsFile.from_dict(json.loads(dumps(d)))
    assert isinstance(back, ParamsFile) and all(isinstance(c, Cell) for c in back.cells)
    assert all(isinstance(p, ParamRecord) for p in back.cells[0].parameters)
    assert back.to_dict() == json.loads(dumps(d))
    path = tmp_path / "params.json"
    path.write_text(dumps(d))
    loaded = load_params(path)
    assert loaded.path == str(path) and loaded.to_dict() == back.to_dict()
    for fit, cell in zip(res.fits, loaded.cells):
        np.testing.assert_array_equal(cell.theta, fit.theta)
        assert cell.metrics == json.loads(dumps({"m": fit.metrics}))["m"]
        u = fit.captures[0].u
        np.testing.assert_allclose(cell.predict(u, fit.scale.dt), fit.model.simulate_one(fit.theta, u, fit.scale.dt))


def test_from_dict_names_the_field(fitted):
    d = ParamsFile.from_result(fitted["pi"]).to_dict()
    d["conditions"][0]["parameters"] = d["conditions"][0]["parameters"][:-1]
    with pytest.raises(ValueError, match=r"conditions\[0\]\.parameters has"):
        ParamsFile.from_dict(d)
    d = ParamsFile.from_result(fitted["pi"]).to_dict()
    d["units"]["output"] = "furlong"
    with pytest.raises(ValueError, match="units.output"):
        ParamsFile.from_dict(d)
