"""pi2's fused kernel on a periodic input: once the operator states repeat, the gPI output is taken
from the last period instead of computed — every mode gives the numbers of the full computation."""

import numpy as np
import pytest

from hystfit.models import pi2 as pi2_module
from hystfit.models.gpi import input_levels, input_period
from hystfit.models.pi2 import PI2
from hystfit.params import DataScale

DT = 1e-4


def periodic_input(cycles=6, per_cycle=300, amp=40.0, phase=0.3):
    """A sampled sine starting mid-stroke (the operators leave their virgin state during the first
    cycle), repeating its values exactly every ``per_cycle`` samples."""
    k = np.arange(cycles * per_cycle + 1)
    return 0.5 * amp * (1.0 + np.sin(2.0 * np.pi * (k % per_cycle) / per_cycle + phase))


@pytest.mark.parametrize("mode", [pi2_module._OUTPUT, pi2_module._SSE, pi2_module._MOMENTS])
def test_the_period_repeat_gives_the_full_computation_bit_for_bit(rng, mode):
    u = periodic_input()
    y = 0.3 * u + 0.05 * rng.standard_normal(u.size)
    model = PI2(identification="joint")
    ps = model.params(DataScale.from_arrays([u], [y], [DT]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + (hi - lo) * rng.random((23, len(ps)))
    theta[3, 0] = np.nan  # a non-finite candidate: its states never compare equal
    levels = input_levels(u)
    period = input_period(levels)
    assert period == 300
    fn, zeta = model._stage(theta)
    full = pi2_module.gpi2_run(u, y, theta[:, :12], fn, zeta, DT, model.n_operators, mode, levels)
    repeated = pi2_module.gpi2_run(u, y, theta[:, :12], fn, zeta, DT, model.n_operators, mode, levels, period)
    assert np.array_equal(full, repeated, equal_nan=True)
    finite = np.ones(theta.shape[0], dtype=bool)
    finite[3] = False
    rest = pi2_module.gpi2_run(u, y, theta[finite, :12], fn[finite], zeta[finite], DT, model.n_operators, mode,
                               levels, period)  # all states repeat: the copy is taken
    assert np.array_equal(rest, full[:, finite] if mode == pi2_module._OUTPUT else full[finite])


def _joint_population(rng, P: int):
    """A periodic input, an output, the joint pi2 model and P random parameter rows inside its
    bounds, with their stages (natural frequency, damping)."""
    u = periodic_input()
    y = 0.3 * u
    model = PI2(identification="joint")
    ps = model.params(DataScale.from_arrays([u], [y], [DT]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + (hi - lo) * rng.random((P, len(ps)))
    fn, zeta = model._stage(theta)
    return u, y, model, theta, fn, zeta


def test_the_model_routes_pass_the_period(rng):
    """simulator, SSE evaluator and the normal equations all take the repeat, with the same numbers."""
    u, y, model, theta, fn, zeta = _joint_population(rng, 9)
    plain = pi2_module.gpi2_run(u, None, theta[:, :12], fn, zeta, DT, model.n_operators, pi2_module._OUTPUT).T
    assert np.array_equal(model.simulator(u, DT)(theta), plain)
    sse = pi2_module.gpi2_run(u, y, theta[:, :12], fn, zeta, DT, model.n_operators, pi2_module._SSE)[:, 0]
    assert np.array_equal(model.sse_evaluator(u, DT, y)(theta), sse)


def test_the_threaded_variant_repeats_per_block_with_the_same_numbers(rng, monkeypatch):
    u, y, model, theta, fn, zeta = _joint_population(rng, 17)
    levels = input_levels(u)
    args = (u, y, theta[:, :12], fn, zeta, DT, model.n_operators, pi2_module._MOMENTS, levels)
    serial = pi2_module.gpi2_run(*args)
    monkeypatch.setattr(pi2_module, "thread_blocks", lambda P, min_pop, max_blocks: 3)  # three candidate blocks
    assert np.array_equal(pi2_module.gpi2_run(*args, input_period(levels)), serial)
