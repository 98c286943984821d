"""Faster evaluation routes that must give the same numbers, bit for bit, as the plain ones:
the grouped simulation of a separable basis (dahl, lugre), the gPI envelope tables and the
threaded gPI population; and fp's one-response basis on FFT-evaluated captures, which equals the
simulated one to rounding."""

import numpy as np
import pytest

from hystfit.models import gpi as gpi_module
from hystfit.models.dahl import Dahl
from hystfit.models.fp import FractionalZener
from hystfit.models.gpi import GPI, gpi_population, input_levels
from hystfit.models.lugre import LuGre
from hystfit.models.pi2 import PI2
from hystfit.models.separable import separable_by_simulation
from hystfit.params import DataScale

DT = 1e-4


def sampled_sine(cycles=8, per_cycle=400, amp=40.0):
    """A raised cosine sampled on a grid that repeats its values every cycle (as sample_data does)."""
    k = np.arange(cycles * per_cycle + 1)
    return 0.5 * amp * (1.0 - np.cos(2.0 * np.pi * (k % per_cycle) / per_cycle))


def candidates(model, u, y, P, rng):
    ps = model.params(DataScale.from_arrays([u], [y], [DT]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    return lo + (hi - lo) * rng.random((P, len(ps)))


@pytest.mark.parametrize("model", [Dahl(), LuGre()], ids=["dahl", "lugre"])
def test_grouped_basis_equals_the_plain_one_bit_for_bit(model, rng):
    u = sampled_sine()
    y = 0.3 * u + 0.01 * u ** 1.5
    sep = model.separable()
    plain = separable_by_simulation(model, sep.linear, len(sep.linear) + len(sep.nonlinear))
    theta_nl = candidates(model, u, y, 9, rng)[:, list(sep.nonlinear)]
    # (their normal equations come from the state's moments: equal to rounding, test_dahl.py / test_lugre.py)
    for a, b in zip(sep.basis_factory(u, DT)(theta_nl), plain.basis_factory(u, DT)(theta_nl)):
        assert np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("offset", [True, False])
def test_fp_one_response_basis_equals_the_simulated_one_to_rounding(offset, rng):
    """On a capture evaluated by FFT, fp's basis is [v + u_0, x − v, 1] from one response v per
    candidate (L⁻¹[τ^a D^a x] = x − v) and its normal equations are the moments of v: the same
    as the basis simulated column by column, to rounding (a wrong column, sign or offset fails)."""
    model = FractionalZener(offset=offset)
    u = sampled_sine(cycles=3) + 2.0  # starts away from 0 V; 1201 samples, window 1200 > 200: FFT route
    assert model._response(u, DT) is not None and not model.soe_route(u.size, DT)
    y = 0.3 * u + 0.01 * u ** 1.5
    sep = model.separable()
    plain = separable_by_simulation(model, sep.linear, len(sep.linear) + len(sep.nonlinear))
    theta_nl = candidates(model, u, y, 9, rng)[:, list(sep.nonlinear)]
    B = sep.basis_factory(u, DT)(theta_nl)
    Bp, Cp = plain.basis_factory(u, DT)(theta_nl)
    assert np.array_equal(Cp, np.zeros_like(Cp))  # θ_lin = 0 simulates to zero: the basis has no known part
    np.testing.assert_allclose(B, Bp, rtol=0, atol=1e-11 * np.max(np.abs(Bp)))
    G, c, tt = sep.gram_factory(u, DT, y)(theta_nl)
    Gp, cp, ttp = plain.gram_factory(u, DT, y)(theta_nl)
    np.testing.assert_allclose(G, Gp, rtol=1e-10, atol=1e-10 * np.max(np.abs(Gp)))
    np.testing.assert_allclose(c, cp, rtol=1e-10, atol=1e-10 * np.max(np.abs(cp)))
    np.testing.assert_allclose(np.broadcast_to(tt, ttp.shape), ttp, rtol=1e-12)


def test_input_levels_only_for_repeating_inputs(rng):
    u = sampled_sine()
    levels, index = input_levels(u)
    assert levels.size <= gpi_module.LEVELS_MAX_FRACTION * u.size and np.array_equal(levels[index], u)
    noisy = u + 1e-3 * rng.standard_normal(u.size)
    lv, idx = input_levels(noisy)
    assert idx.size == 0 and np.array_equal(lv, noisy)


@pytest.mark.parametrize("threads", [False, True])
def test_gpi_tables_and_threads_give_the_same_numbers(threads, rng, monkeypatch):
    u = sampled_sine()
    theta = candidates(GPI(), u, 0.3 * u, 23, rng)
    cols = [np.ascontiguousarray(theta[:, i]) for i in range(11)]
    a1, a2, a3, a4, b1, b2, b3, b4, _, tau, alpha = cols
    plain = gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, 10)
    assert input_levels(u)[1].size == u.size  # the tables are in use
    if threads:  # every population threaded, tables in blocks of 5 candidates
        monkeypatch.setattr(gpi_module, "PARALLEL_MIN_WORK", 0)
        monkeypatch.setattr(gpi_module, "TABLE_BLOCK_ELEMENTS", 5 * input_levels(u)[0].size)
    tabulated = gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, 10, input_levels(u))
    assert np.array_equal(plain, tabulated, equal_nan=True)
    direct = GPI().simulate(theta, u, DT)
    assert np.array_equal(GPI().simulator(u, DT)(theta), direct)


def test_pi2_tables_give_the_same_numbers(rng):
    model = PI2(identification="joint")
    u = sampled_sine()
    y = 0.3 * u
    theta = candidates(model, u, y, 11, rng)
    sim = model.simulator(u, DT)(theta)
    from hystfit.models import pi2 as pi2_module

    plain = pi2_module.gpi2_run(u, None, theta[:, :12], *model._stage(theta), DT, model.n_operators,
                                pi2_module._OUTPUT).T
    assert np.array_equal(sim, plain, equal_nan=True)
    sse = model.sse_evaluator(u, DT, y)(theta)
    np.testing.assert_allclose(sse, ((plain - y) ** 2).sum(axis=1), rtol=1e-9)


def test_gpi_long_captures_take_the_fused_moments(rng):
    """Long captures: the normal equations of (ρ, y0) from the kernel's moments (the whole population
    at once), equal to the moments of the stored z to rounding; short captures: from z, as before."""
    model = GPI()
    u = sampled_sine(cycles=52, per_cycle=400)  # ≥ FUSED_MIN_SAMPLES
    assert u.size >= gpi_module.FUSED_MIN_SAMPLES
    y = 0.3 * u + 0.1 * rng.standard_normal(u.size)
    sep = model.separable()
    theta_nl = candidates(model, u, y, 7, rng)[:, list(sep.nonlinear)]
    G, c, yy = sep.gram_factory(u, DT, y)(theta_nl)
    B = sep.basis_factory(u, DT)(theta_nl)  # (P, N, 2) from the stored z
    np.testing.assert_allclose(G, np.einsum("pnl,pnk->plk", B, B), rtol=1e-12)
    np.testing.assert_allclose(c, np.einsum("pnl,n->pl", B, y), rtol=1e-12)
    from hystfit.objective import Series

    assert sep.fused([Series(u, y, DT)]) and not sep.fused([Series(u[:5000], y[:5000], DT)])
