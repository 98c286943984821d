"""A warm-up (``Series.skip``, ``--warmup``) leaves the first samples out of every objective path.

The fused error kernels and the normal equations of the separable fits drop the warm-up by
subtracting the error of the prefix alone; that is exact only for causal models (the output up to
k depends on the input up to k). This suite checks it for every registered model, against the
plain definition: Σ_{k ≥ skip} (ŷ_k − y_k)² / (N − skip).
"""

import numpy as np
import pytest

from hystfit.objective import Objective, Series
from hystfit.params import DataScale
from hystfit.registry import models

FS = 5000.0


def _model_and_theta(name):
    t = np.arange(1500) / FS
    u = 20 + 18 * np.sin(2 * np.pi * 12 * t) * np.exp(-t)
    scale = DataScale(u_min=0.0, u_max=40.0, y_min=0.0, y_max=12.0, dt=1 / FS,
                      rate_max=float(np.max(np.abs(np.diff(u)))) * FS)
    cls = models.get(name)
    model = cls.example(scale)
    params = model.params(scale)
    rng = np.random.default_rng(7)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    defaults = np.array([p.default for p in params])
    thetas = np.vstack([defaults, defaults + 0.1 * (hi - lo) * rng.uniform(-1, 1, (2, lo.size))])
    thetas = np.clip(thetas, lo, hi)
    return model, thetas, u, lo, hi


@pytest.mark.parametrize("name", models.names())
def test_warmup_objective_equals_the_definition(name):
    model, thetas, u, lo, hi = _model_and_theta(name)
    y = model.simulate_one(thetas[0], u, 1 / FS) + 0.05 * np.sin(np.arange(u.size))
    skip = 300
    obj = Objective(model, [Series(u, y, 1 / FS, skip)])
    with np.errstate(all="ignore"):
        sims = np.vstack([model.simulate_one(th, u, 1 / FS) for th in thetas])
        expected = np.mean((sims[:, skip:] - y[None, skip:]) ** 2, axis=1)
        got = obj(thetas)
    ok = np.isfinite(expected)
    assert np.allclose(got[ok], expected[ok], rtol=1e-6, atol=1e-12 * max(1.0, float(np.max(y ** 2))))
    assert obj.residuals(thetas[0]).shape == (u.size - skip,)
    if hasattr(model, "separable") and model.separable() is not None:
        from hystfit.optimizers.projection import ProjectedObjective

        sep = model.separable()
        proj = ProjectedObjective(sep, [Series(u, y, 1 / FS, skip)], lo, hi)
        nl = np.asarray(sep.nonlinear, dtype=int)
        full = proj.full(thetas[:, nl] if nl.size else np.empty((1, 0)))
        with np.errstate(all="ignore"):
            mse = proj(thetas[:, nl] if nl.size else np.empty((1, 0)))
            direct = np.array([np.mean((model.simulate_one(th, u, 1 / FS)[skip:] - y[skip:]) ** 2) for th in full])
        fin = np.isfinite(direct)
        assert np.allclose(mse[fin], direct[fin], rtol=1e-5, atol=1e-10 * max(1.0, float(np.max(y ** 2))))
