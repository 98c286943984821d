"""One contract suite over every registered block (:mod:`hystfit.blocks`).

Shapes, determinism, the diagnose (effect) form equals the population form, separable exactness
(linear coefficients solved exactly recover the truth), inverse round trip, stepping equals the
population form, and each block equals the virtual actuator's switch of the same effect.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hystfit import synth
from hystfit.effects import CaptureView
from hystfit.params import DataScale
from hystfit.registry import blocks
from test_model_contract import _read_only  # noqa: E402 - one helper for both contracts (this folder is on sys.path)

DT = 1e-4
BLOCKS = blocks.names()


def _signal(n: int = 3000) -> np.ndarray:
    """A smooth displacement-like signal (µm): a raised cosine plus a slower component."""
    t = np.arange(n) * DT
    return 0.25 + 9.0 * (1.0 - np.cos(2 * np.pi * 20.0 * t)) + 1.5 * np.sin(2 * np.pi * 7.0 * t)


def _scale(x: np.ndarray) -> DataScale:
    u = x * 3.0
    return DataScale.from_arrays([u], [x], [DT])


def _adapted(name: str, x: np.ndarray):
    if name == "lti":  # identified structure: a 1.5 kHz, ζ 0.3 stage (ZOH), as prepare() would store it
        from hystfit.blocks.lti import LinearSS, _zoh_second_order

        lin = LinearSS.from_tf(*_zoh_second_order(1.0, 1500.0, 0.3, DT), DT).normalized()
        return blocks.get(name)(order=int(lin.order), A=tuple(np.ravel(lin.A)), B=tuple(np.ravel(lin.B)),
                                C=tuple(np.ravel(lin.C)), D=float(lin.D), dt_s=DT, method="given").adapt(_scale(x))
    return blocks.get(name)().adapt(_scale(x))


def _theta(block, x: np.ndarray, rng) -> np.ndarray:
    """A plausible parameter vector strictly inside the block's bounds."""
    ps = block.params(_scale(x))
    lo = np.array([p.lower for p in ps])
    hi = np.array([p.upper for p in ps])
    return lo + (0.2 + 0.3 * rng.random(lo.size)) * (hi - lo) if lo.size else np.empty(0)


def test_registry_lists_the_issue_blocks():
    assert {"delay", "dynamics", "creep", "asymmetry", "drift"} <= set(BLOCKS)


@pytest.mark.parametrize("name", BLOCKS)
def test_params_shapes_and_determinism(name, rng):
    x = _signal()
    b = _adapted(name, x)
    ps = b.params(_scale(x))
    assert len(ps) == b.n_theta
    assert all(p.lower < p.upper for p in ps)
    th = np.vstack([_theta(b, x, rng) for _ in range(4)]) if ps else np.zeros((4, 0))
    X = np.vstack([x, 1.1 * x, x + 0.3, 0.9 * x])
    y1 = b.apply_population(X, th, DT)
    y2 = b.apply_population(X.copy(), th.copy(), DT)
    assert y1.shape == X.shape
    np.testing.assert_array_equal(y1, y2)
    # each row depends only on its own parameters
    np.testing.assert_allclose(b.apply_population(X[2:3], th[2:3], DT)[0], y1[2], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", [n for n in BLOCKS if not blocks.get(n).nuisance])
def test_effect_form_equals_population_form(name, rng):
    """Diagnose's E_φ,a[ŷ] and the composite's apply_population are one implementation."""
    x = _signal()
    b = _adapted(name, x)
    th = _theta(b, x, rng)
    m = b.searched_bounds()[0].size
    view = CaptureView(np.arange(x.size) * DT, DT, x, np.ones(x.size, bool))
    e = b.apply(x, view, th[:m], th[m:], np.empty(0))
    np.testing.assert_allclose(b.apply_population(x[None, :], th[None, :], DT)[0], e, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", [n for n in BLOCKS if blocks.get(n)().layout()[0] > 0])
def test_linear_coefficients_are_solved_exactly(name, rng):
    """With the searched parameters at the truth, the linear coefficients come out exact (no noise)."""
    x = _signal()
    b = _adapted(name, x)
    th = _theta(b, x, rng)
    m = b.searched_bounds()[0].size
    y = b.apply_population(x[None, :], th[None, :], DT)[0]
    view = CaptureView(np.arange(x.size) * DT, DT, y, np.ones(x.size, bool))
    from hystfit.effects import solve_coefficients

    shared, _, _, sse = solve_coefficients(b, th[:m], [x], [view])
    np.testing.assert_allclose(shared, th[m:], rtol=1e-6, atol=1e-9)
    assert sse < 1e-12 * float(y @ y)


@pytest.mark.parametrize("name", BLOCKS)
def test_inverse_round_trip(name, rng):
    """invert then apply gives the target back (smooth target; delay: away from the held end)."""
    x = _signal(4000)
    b = _adapted(name, x)
    th = _theta(b, x, rng)
    target = _signal(4000)
    u = b.invert(th, target, DT)
    y = b.apply_population(u[None, :], th[None, :], DT)[0]
    k = slice(60, 3800)  # after the first T_d (≤ 50 samples), where a delay holds its first value
    # dynamics: O(θ⁴) continuous-time inversion; delay: linear interpolation both ways (exact for
    # whole samples, O(dt²·y'') for fractional ones)
    # lti: the ZOH stage's sampling zero is not inverted (ZPETC), an O(ω²) phase-free residual
    tol = {"dynamics": 2e-3, "delay": 1e-4, "lti": 2e-3}.get(name, 1e-9)
    np.testing.assert_allclose(y[k], target[k], atol=tol * np.ptp(target))


@pytest.mark.parametrize("name", BLOCKS)
def test_stepping_reproduces_the_population_form(name, rng):
    x = _signal(800)
    b = _adapted(name, x)
    th = _theta(b, x, rng)
    ref = b.apply_population(x[None, :], th[None, :], DT)[0]
    state = b.step_init(th, float(x[0]), DT)
    out = [ref[0]]
    for k in range(1, x.size):
        yk, st = b.step(th, state, np.array([x[k]]), DT)
        out.append(float(yk[0]))
        state = st[0]
    np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-10)


def exercise_kernels(name: str) -> None:
    """Block ``name``'s kernels with writable data (a model's output) and read-only data (a capture
    read from CSV): the population form, the diagnose (effect) form and the inverse."""
    rng = np.random.default_rng(6)
    x = _signal(1500)
    b = _adapted(name, x)
    th = _theta(b, x, rng)
    m = b.searched_bounds()[0].size
    X = np.vstack([x, 1.1 * x])
    TH = np.vstack([th, th])
    for xx, XX, tt in ((x, X, TH), (_read_only(x), _read_only(X), _read_only(TH))):
        b.apply_population(XX, tt, DT)
        view = CaptureView(np.arange(x.size) * DT, DT, xx, np.ones(x.size, bool))
        if not b.nuisance:
            b.apply(xx, view, th[:m], th[m:], np.empty(0))
        b.invert(th, xx, DT)


def test_kernels_are_compiled_once_for_read_only_and_writable_data(kernel_twins):
    """Every block's kernels take read-only and writable arrays without a second compilation, in
    a fresh process (no other test's direct kernel calls count)."""
    code = (f"import sys\nsys.path.insert(0, {str(Path(__file__).parent)!r})\n"
            "from test_block_contract import BLOCKS, exercise_kernels\n"
            "for name in BLOCKS:\n    exercise_kernels(name)\n")
    assert kernel_twins(code) == []


def _plant_with(**effects) -> synth.Plant:
    return synth.Plant.default().with_effects(synth.Effects(**effects))


def test_blocks_equal_the_virtual_actuator_switches():
    """Each switch of the virtual actuator is the block of the same name, to rounding."""
    t, u = synth.raised_cosine(50.0, 30.0, 3, 10_000)
    comps = synth.simulate_plant_components(_plant_with(asymmetry=True, creep=True, dynamics=True, delay=True), t, u)
    off = float(synth.Plant.default().offset_um)
    z = comps["hysteresis"] - off
    e = synth.Effects()
    s = e.asymmetry_span_um
    za = blocks.get("asymmetry")(center=s / 2, half_range=s / 2).apply_population(
        z[None], np.array([[e.asymmetry_a2 * s / 4, 0.0]]), DT)[0]
    np.testing.assert_allclose(za, comps["asymmetry"] - off, atol=1e-12)
    g = np.array(e.creep_gain)
    G = g.sum()
    zc = blocks.get("creep")(tau_s=e.creep_tau_s).apply_population(((1 + G) * za)[None], (g / (1 + G))[None], DT)[0]
    np.testing.assert_allclose(zc, comps["creep"] - off, atol=1e-12)
    zd = blocks.get("dynamics")().apply_population(zc[None], np.array([[e.dynamics_fn_Hz, e.dynamics_zeta]]), DT)[0]
    np.testing.assert_allclose(zd, comps["dynamics"] - off, atol=1e-12)
    zl = blocks.get("delay")().apply_population(zd[None], np.array([[e.delay_s]]), DT)[0]
    np.testing.assert_allclose(zl, comps["delay"] - off, atol=1e-12)


def test_drift_is_a_nuisance_with_offset_and_rate():
    b = blocks.get("drift")()
    assert b.nuisance and b.n_theta == 0
    R = b.nuisance_basis(5, 0.5)
    np.testing.assert_allclose(R, [[1, 0], [1, 0.5], [1, 1.0], [1, 1.5], [1, 2.0]])
