"""Electromechanical model (paper 000): generalized PI + second-order stage, two-step or joint identification."""

import math

import numpy as np
import pytest
from scipy import signal

from hystfit.capture import Capture
from hystfit.errors import ConfigError
from hystfit.models.gpi import GPI
from hystfit.models.pi2 import PI2, fit_stage_with_classical_pi
from hystfit.params import DataScale
from hystfit.registry import models
from hystfit.factory import make_model

FS = 10_000.0
DT = 1.0 / FS
STAGE = (1200.0, 0.15)  # f_n (Hz), ζ: a P-721-like stage


def raised_cosine(f_Hz, A=60.0, N=2000):
    t = np.arange(N) * DT
    return A * 0.5 * (1 - np.cos(2 * np.pi * f_Hz * t))


def scale_of(us):
    return DataScale.from_arrays(us, [0.2 * u for u in us], [DT] * len(us))


def gpi_truth(scale):
    """A hysteretic generalized PI: the defaults of its parameter table with unequal envelopes."""
    t = np.array([p.default for p in GPI().params(scale)])
    t[4] *= 1.1  # b1: γ_r differs from γ_l
    t[9] *= 1.5  # τ
    return t


def reference_pi2(theta, u, fn, zeta, dt, n=10):
    """Plain Python: generalized plays, density sum, then scipy's prewarped bilinear biquad at rest."""
    a1, a2, a3, a4, b1, b2, b3, b4, rho, tau, alpha, y0 = theta[:12]
    s = [0.0] * n
    z = []
    for uk in u:
        gl = a1 * math.tanh(a2 * uk + a3) + a4
        gr = b1 * math.tanh(b2 * uk + b3) + b4
        tot = 0.0
        for j in range(n):
            r = alpha * j
            s[j] = max(gl - r, min(gr + r, s[j]))
            tot += math.exp(-tau * r) * s[j]
        z.append(rho * tot + y0)
    wn = 2 * math.pi * fn
    k = wn / math.tan(wn * dt / 2)
    b, a = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=k / 2)
    b, a = b / a[0], a / a[0]
    zi = signal.lfilter_zi(b, a) * z[0]
    return signal.lfilter(b, a, z, zi=zi)[0]


def test_parameter_tables_of_both_routes():
    sc = scale_of([raised_cosine(50)])
    assert models.get("pi2") is PI2
    two = [p.name for p in PI2.example(sc).params(sc)]
    joint = [p.name for p in PI2(identification="joint").params(sc)]
    assert two == [p.name for p in GPI().params(sc)]  # the stage is structure in the two-step route
    assert joint == two + ["fn_Hz", "zeta"]
    for bad in ({"identification": "both"}, {"identification": "joint", "fn_Hz": 900.0, "zeta": 0.2},
                {"fn_Hz": 900.0}, {"fn_Hz": -1.0, "zeta": 0.2}):
        with pytest.raises(ConfigError, match="pi2"):
            PI2(**bad)
    with pytest.raises(ConfigError, match="not identified"):
        PI2().simulate_one(np.array([p.default for p in GPI().params(sc)]), raised_cosine(50), DT)


def test_simulate_is_the_generalized_pi_through_the_dynamics_block(rng):
    """pi2 is gpi followed by the dynamics block's stage: same numbers as the expression gpi+dynamics
    (one home for the stage) and as a plain-Python reference."""
    u = raised_cosine(80) + 3 * rng.standard_normal(2000).cumsum() / 40
    sc = scale_of([u])
    theta = gpi_truth(sc)
    m = PI2(fn_Hz=STAGE[0], zeta=STAGE[1])
    y = m.simulate_one(theta, u, DT)
    np.testing.assert_allclose(y, reference_pi2(theta, u, *STAGE, DT), rtol=1e-9, atol=1e-9)
    comp = make_model("gpi+dynamics")
    np.testing.assert_allclose(comp.simulate_one(np.r_[theta, STAGE], u, DT), y, rtol=1e-11, atol=1e-11)
    joint = PI2(identification="joint")
    np.testing.assert_allclose(joint.simulate_one(np.r_[theta, STAGE], u, DT), y, rtol=0, atol=0)


@pytest.mark.parametrize("P", [3, 70])  # serial and threaded kernel
def test_fused_kernel_equals_simulation(rng, P):
    u = raised_cosine(40)
    sc = scale_of([u])
    for m in (PI2(fn_Hz=STAGE[0], zeta=STAGE[1]), PI2(identification="joint")):
        ps = m.params(sc)
        lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
        th = lo + (hi - lo) * rng.random((P, len(ps)))
        Y = m.simulate(th, u, DT)
        np.testing.assert_allclose(m.simulator(u, DT)(th), Y, rtol=1e-12, atol=1e-12)
        y = Y[0] + 0.01 * rng.standard_normal(u.size)
        np.testing.assert_allclose(m.sse_evaluator(u, DT, y)(th), ((Y - y) ** 2).sum(axis=1), rtol=1e-9)
        sep = m.separable()
        nl = th[:, list(sep.nonlinear)]
        B = sep.basis_factory(u, DT)(nl)
        G, c, yy = sep.gram_factory(u, DT, y)(nl)
        np.testing.assert_allclose(G, np.einsum("pnl,pnm->plm", B, B), rtol=1e-10)
        np.testing.assert_allclose(c, np.einsum("pnl,n->pl", B, y), rtol=1e-10)
        lin = th[:, list(sep.linear)]
        np.testing.assert_allclose(np.einsum("pnl,pl->pn", B, lin), Y, rtol=1e-10, atol=1e-10)


def test_step_agrees_with_simulate(rng):
    u = raised_cosine(60, N=600) + rng.standard_normal(600).cumsum() / 10
    theta = gpi_truth(scale_of([u]))
    m = PI2(fn_Hz=STAGE[0], zeta=STAGE[1])
    y = m.simulate_one(theta, u, DT)
    state = m.initial_state(theta, u[0], DT)
    out = [y[0]]
    for k in range(1, u.size):
        yk, S = m.step(theta, state, u[k - 1], np.array([u[k]]), DT)
        state = S[0]
        out.append(yk[0])
    np.testing.assert_allclose(out, y, rtol=1e-12, atol=1e-12)


def test_inverse_round_trip_on_a_smooth_target():
    u = raised_cosine(20, N=3000)
    sc = scale_of([u])
    theta = gpi_truth(sc)
    m = PI2(fn_Hz=STAGE[0], zeta=STAGE[1])
    y_d = m.simulate_one(theta, u, DT)
    u_inv = m.invert(theta, y_d, DT)
    err = np.abs(m.simulate_one(theta, u_inv, DT) - y_d)
    assert err[5:-5].max() < 2e-3 * np.ptp(y_d)


def test_two_step_identifies_the_stage_first():
    """Step 1 of paper 000's two-step route finds the stage of a gPI + stage plant (the classical PI
    standing in for the hysteresis) from a 50 Hz and a 200 Hz capture; prepare() stores it."""
    us = [raised_cosine(50, N=2000), raised_cosine(200, N=2000)]
    theta = gpi_truth(scale_of(us))
    truth = PI2(fn_Hz=STAGE[0], zeta=STAGE[1])
    ys = [truth.simulate_one(theta, u, DT) for u in us]
    fn, zeta, rmse = fit_stage_with_classical_pi(us, ys, DT)
    assert fn == pytest.approx(STAGE[0], rel=0.05) and zeta == pytest.approx(STAGE[1], abs=0.02)
    caps = [Capture(source=f"c{i}.csv", t=np.arange(u.size) * DT, u=u, y=y, dt=DT, amplitude_V=60.0,
                    frequency_Hz=f) for i, (u, y, f) in enumerate(zip(us, ys, (50.0, 200.0)))]
    m = PI2().prepare(caps)
    assert (m.fn_Hz, m.zeta) == (fn, zeta) and "two-step" in m.structure_summary()
    assert PI2(identification="joint").prepare(caps) == PI2(identification="joint")


def test_params_json_of_the_classical_pi2_still_loads_as_pi_plus_dynamics():
    """A params.json written by the classical-PI pi2 (hystfit before the generalized PI; saved by
    `hystfit identify sample_data/a20V_f80Hz.csv --model pi2 --seed 0`) predicts as it did."""
    from pathlib import Path

    from hystfit.io import load_capture
    from hystfit.results import load_params

    root = Path(__file__).resolve().parents[2]
    pf = load_params(Path(__file__).parent / "data" / "pi2_classical_params.json")
    cell = pf.cells[0]
    assert cell.model.name == "pi+dynamics" and cell.theta.size == 13
    cap = load_capture(root / "sample_data" / "a20V_f80Hz.csv")
    rmse = float(np.sqrt(np.mean((cell.predict(cap.u, cap.dt) - cap.y) ** 2)))
    assert rmse == pytest.approx(pf.cells[0].metrics["rmse_um"], rel=1e-9)


def test_centred_stage_columns_are_numpys_centred_filter_bit_for_bit():
    """Step 1's fused filter-and-centre kernel gives F − F.mean(axis=0) of the filtered columns exactly."""
    from hystfit.blocks.dynamics import biquad_columns, bilinear_biquad
    from hystfit.models import pi2 as pi2_module

    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=(1500, 7)), axis=0)
    for fn, zeta in ((300.0, 0.05), (2000.0, 1.5)):
        coef = [np.full(7, c[0]) for c in bilinear_biquad(fn, zeta, 1e-4)]
        filtered = biquad_columns(x, *coef)
        expected = filtered - filtered.mean(axis=0)
        got = pi2_module._centred_stage_columns(x, *coef)
        assert np.array_equal(got.view(np.uint64), expected.view(np.uint64))


def test_stage_coefficients_are_the_discretization_of_each_stage():
    """The remembered stage coefficients are bilinear_biquad's, per stage and population size (a
    stale entry for another f_n, ζ, dt or P would fail)."""
    from hystfit.blocks.dynamics import bilinear_biquad
    from hystfit.models import pi2 as pi2_module

    for fn, zeta, dt, P in ((1200.0, 0.15, 1e-4, 3), (1200.0, 0.15, 1e-4, 5), (900.0, 0.15, 1e-4, 3),
                            (1200.0, 0.3, 1e-4, 3), (1200.0, 0.15, 2e-4, 3), (1200.0, 0.15, 1e-4, 3)):
        got = pi2_module._stage_coefficients(np.full(P, fn), np.full(P, zeta), dt, P)
        for g, e in zip(got, bilinear_biquad(np.full(P, fn), np.full(P, zeta), dt)):
            assert g.shape == (P,) and np.array_equal(g, e)
    fns = np.array([500.0, 1500.0, 4000.0])  # the joint route: one stage per candidate
    got = pi2_module._stage_coefficients(fns, np.array([0.1, 0.5, 1.0]), 1e-4, 3)
    for g, e in zip(got, bilinear_biquad(fns, np.array([0.1, 0.5, 1.0]), 1e-4)):
        assert np.array_equal(g, e)


def test_a_stage_far_above_the_drive_gets_a_caveat():
    """A blind test's find: pi2 on a 1 Hz capture printed "f_n 889.8 Hz" without a word on how
    little so slow a drive determines it."""
    from types import SimpleNamespace

    from hystfit.identify import slow_drive_note

    model = SimpleNamespace(composition=None, fn_Hz=889.8)
    note = slow_drive_note(model, [SimpleNamespace(frequency_Hz=1.0)])
    assert note is not None and "890× the fastest drive (1 Hz)" in note and "poorly determined" in note
    assert slow_drive_note(model, [SimpleNamespace(frequency_Hz=1.0), SimpleNamespace(frequency_Hz=80.0)]) is None
    assert slow_drive_note(SimpleNamespace(composition=None, fn_Hz=None), [SimpleNamespace(frequency_Hz=1.0)]) is None
    assert slow_drive_note(SimpleNamespace(composition=None), [SimpleNamespace(frequency_Hz=1.0)]) is None
