"""Fractional Zener on long captures: the sum-of-exponentials (SOE) evaluation and its error bound."""

import numpy as np
import pytest

from hystfit.models import fp as fp_module
from hystfit.models.fp import (SOE_MIN_SAMPLES, SOE_WEIGHT_L1, FractionalZener, gl_filter_population, gl_weights,
                               soe_weights)
from hystfit.objective import Objective, Series
from hystfit.optimizers.projection import ProjectedObjective

DT = 1e-4


def long_input(n, rng):
    t = np.arange(n) * DT
    return 30.0 - 30.0 * np.cos(2 * np.pi * 10.0 * t) + 0.3 * rng.standard_normal(n)


@pytest.mark.parametrize("L", [201, 2_000, 10_000, 50_000])
def test_soe_weights_l1_error_within_the_stated_bound(L):
    a = np.linspace(0.01, 0.99, 15)
    w, wh = gl_weights(a, L), soe_weights(a, L)
    np.testing.assert_allclose(wh[:2], w[:2], rtol=0, atol=1e-15)  # ŵ_0 = 1 and ŵ_1 = −a are exact
    err = np.abs(wh[2:] - w[2:]).sum(axis=0)
    assert np.all(err <= SOE_WEIGHT_L1), err.max()


def test_soe_output_within_the_propagated_bound_of_the_exact_recurrence(rng):
    """‖ŷ − y‖∞ ≤ |E0 − E∞|·b·ε/(1 + b·s_L)·‖v̂‖∞ with ε the weights' ℓ1 error and s_L = Σ_{j≤L} w_j
    (the exact windowed GL recurrence as reference; 1e-10 relative for the rounding)."""
    model = FractionalZener(memory_s=0.05)  # L = 500: the exact O(N·L) recurrence stays cheap
    n = SOE_MIN_SAMPLES + 5_000
    u = long_input(n, rng)
    L = model.memory_samples(DT)
    assert model.soe_route(n, DT)
    theta = np.array([[0.5, 0.3, 0.01, 0.4, 1.0], [0.6, 0.1, 0.002, 0.85, -1.0], [0.5, 0.45, 0.05, 0.05, 0.0],
                      [0.4, 0.9, 0.3, 0.6, 0.2]])
    y_soe = model.simulator(u, DT)(theta)
    x = u - u[0]
    for row, y_hat in zip(theta, y_soe):
        E0, Ei, tau, a, y0 = row
        b = (tau / DT) ** a
        w = gl_weights(np.array([a]), L)
        exact = gl_filter_population(x, w, np.ones(1), np.array([b]), np.array([E0]),
                                     np.array([Ei * b]))[:, 0] + E0 * u[0] + y0
        eps = np.abs(soe_weights(np.array([a]), L)[2:, 0] - w[2:, 0]).sum()
        s_L = w[:, 0].sum()
        v_hat = fp_module.soe_run(x, None, np.array([a]), np.array([b]), L, fp_module._SOE_OUTPUT)[:, 0]
        bound = abs(E0 - Ei) * b * eps / (1.0 + b * s_L) * np.abs(v_hat).max()
        err = np.abs(y_hat - exact).max()
        assert err <= bound + 1e-10 * np.abs(exact).max(), (err, bound)
        assert err < 1e-6 * np.abs(exact).max()


def test_short_captures_keep_the_exact_evaluation(rng):
    model = FractionalZener()
    n = SOE_MIN_SAMPLES - 1
    u = long_input(n, rng)
    assert not model.soe_route(n, DT) and model.soe_route(SOE_MIN_SAMPLES, DT)
    assert not FractionalZener(memory_s=0.02).soe_route(10 * SOE_MIN_SAMPLES, DT)  # 200 terms: recurrence
    theta = np.array([[0.5, 0.3, 0.01, 0.4, 1.0]])
    y = model.simulate(theta, u, DT)[0]
    sse = model.sse_evaluator(u, DT, y + 0.1)(theta)
    assert sse[0] == pytest.approx(0.01 * n, rel=1e-12)


def test_long_route_normal_equations_and_sse_match_the_simulated_basis(rng):
    model = FractionalZener(memory_s=0.1)
    n = SOE_MIN_SAMPLES + 1_000
    u = long_input(n, rng)
    theta = np.array([[0.5, 0.3, 0.01, 0.4, 1.0], [0.2, 0.25, 0.004, 0.7, -0.5]])
    y = model.simulate(theta[:1], u, DT)[0] + 0.05 * rng.standard_normal(n)
    sep = model.separable()
    B = sep.basis_factory(u, DT)(theta[:, 2:4])  # (P, N, 3)
    np.testing.assert_allclose(np.einsum("pnl,pl->pn", B, theta[:, [0, 1, 4]]), model.simulate(theta, u, DT),
                               rtol=0, atol=1e-12)
    G, c, yy = sep.gram_factory(u, DT, y)(theta[:, 2:4])
    np.testing.assert_allclose(G, np.einsum("pnl,pnk->plk", B, B), rtol=1e-12)
    np.testing.assert_allclose(c, np.einsum("pnl,n->pl", B, y), rtol=1e-12)
    assert yy == pytest.approx(float(y @ y), rel=1e-15)
    simulated = ((model.simulate(theta, u, DT) - y) ** 2).sum(axis=1)
    np.testing.assert_allclose(model.sse_evaluator(u, DT, y)(theta), simulated, rtol=0, atol=1e-9 * yy)
    series = [Series(u, y, DT)]
    assert sep.fused(series) and not sep.fused([Series(u[:1000], y[:1000], DT)])
    obj = Objective(model, series)
    proj = ProjectedObjective(sep, series, np.full(5, -1e3), np.full(5, 1e3))
    assert proj(theta[:, 2:4])[0] <= obj(theta[:1])[0] * (1 + 1e-9)  # the exact linear part does no worse
