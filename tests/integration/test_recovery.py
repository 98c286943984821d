"""Recovery: simulate a model with known parameters plus noise, identify it, check RMSE and θ.

Tolerances: RMSE ≤ 1.1 × the noise σ (a fit at the noise floor), and each identifiable parameter
within the stated relative tolerance of the truth.
"""

import numpy as np
import pytest

from hystfit.capture import Capture
from hystfit.identify import fit_captures
from hystfit.models.bw import BoucWen
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit.optimizers.pso import PSO
from hystfit.params import DataScale

FS = 10_000.0
SIGMA = 0.01  # µm


def capture(u, y, name="synthetic.csv"):
    t = np.arange(u.size) / FS
    return Capture(source=name, t=t, u=u, y=y, dt=1 / FS, amplitude_V=float(np.ptp(u)), frequency_Hz=10.0)


def raised_cosine(amplitude, f=10.0, cycles=3):
    t = np.arange(int(cycles * FS / f) + 1) / FS
    return 0.5 * amplitude * (1 - np.cos(2 * np.pi * f * t))


def decaying_input():
    """A raised cosine with decaying amplitude: produces minor loops, so higher thresholds are identifiable."""
    t = np.arange(int(0.6 * FS)) / FS
    return 30 * (1 - np.cos(2 * np.pi * 10 * t)) * np.exp(-t / 0.3)


PI_TRUE = np.array([0.20, 0.05, 0.04, 0.03, 0.025, 0.02, 0.015, 0.01, 0.006, 0.003, 0.4])


@pytest.mark.parametrize("optimizer", [Auto(), PSO(pop=40, iters=150)], ids=["auto", "pso+polish"])
def test_pi_recovery(optimizer, rng):
    u = decaying_input()
    scale = DataScale.from_arrays([u], [u], [1 / FS])
    truth = PI(10).adapt(scale)
    y = truth.simulate_one(PI_TRUE, u, 1 / FS) + rng.normal(0, SIGMA, u.size)
    fit = fit_captures([capture(u, y)], PI(10), optimizer, seed=1, polish=True)
    assert fit.model.thresholds_V == truth.thresholds_V
    rmse = fit.metrics["rmse_um"]
    assert rmse <= 1.1 * SIGMA
    # weights of operators the input exercises are well determined: within 0.005 µm/V absolute
    np.testing.assert_allclose(fit.theta[:10], PI_TRUE[:10], atol=0.005)
    assert abs(fit.theta[10] - PI_TRUE[10]) < 0.02


BW_TRUE = np.array([0.25, 0.12, 0.03, 0.01, 0.3])


@pytest.mark.parametrize("optimizer", [Auto(), PSO(pop=30, iters=120)], ids=["auto", "pso+polish"])
def test_bw_recovery(optimizer, rng):
    u = np.r_[raised_cosine(60, cycles=2), raised_cosine(30, cycles=2)[1:]]
    y = BoucWen().simulate_one(BW_TRUE, u, 1 / FS) + rng.normal(0, SIGMA, u.size)
    fit = fit_captures([capture(u, y)], BoucWen(), optimizer, seed=2, polish=True)
    assert fit.metrics["rmse_um"] <= 1.1 * SIGMA
    # all five parameters are identifiable from loops of two amplitudes: within 5 % (y0 within 0.01 µm)
    np.testing.assert_allclose(fit.theta[:4], BW_TRUE[:4], rtol=0.05)
    assert abs(fit.theta[4] - BW_TRUE[4]) < 0.01
    # the reported standard errors are honest: the truth lies within 5 standard errors
    assert np.all(np.abs(fit.theta - BW_TRUE) <= 5 * fit.stderr + 1e-12)


def test_pooled_captures_of_one_condition(rng):
    """Two captures of one condition are fitted jointly, each simulated from a reset state."""
    u = raised_cosine(40)
    scale = DataScale.from_arrays([u], [u], [1 / FS])
    truth = PI(8).adapt(scale)
    th = np.r_[0.2, np.full(7, 0.02), 0.1]
    caps = [capture(u, truth.simulate_one(th, u, 1 / FS) + rng.normal(0, SIGMA, u.size), f"c{i}.csv") for i in range(2)]
    fit = fit_captures(caps, PI(8), Auto(), seed=0)
    assert len(fit.per_capture) == 2 and len(fit.predictions) == 2
    assert fit.metrics["rmse_um"] <= 1.1 * SIGMA
    assert fit.metrics["n_samples"] == 2 * u.size


def test_runs_are_seeded_and_reproducible(rng):
    u = raised_cosine(60, cycles=2)
    y = BoucWen().simulate_one(BW_TRUE, u, 1 / FS) + rng.normal(0, SIGMA, u.size)
    a = fit_captures([capture(u, y)], BoucWen(), PSO(pop=10, iters=20), seed=5, runs=3, polish=False)
    b = fit_captures([capture(u, y)], BoucWen(), PSO(pop=10, iters=20), seed=5, runs=3, polish=False)
    assert [r.seed for r in a.runs] == [r.seed for r in b.runs]
    assert len({r.seed for r in a.runs}) == 3
    np.testing.assert_array_equal(a.theta, b.theta)
    sp = a.spread()
    assert sp["runs"] == 3 and sp["fun_min"] <= sp["fun_mean"] <= sp["fun_max"]


def test_identify_pool_equals_serial(rng):
    """Conditions × runs spread over processes give exactly the serial numbers (seeds per condition and run)."""
    from hystfit.identify import identify

    caps = []
    for a in (30.0, 60.0):
        u = raised_cosine(a, cycles=2)
        caps.append(Capture(source=f"c{a}.csv", t=np.arange(u.size) / FS, u=u,
                            y=BoucWen().simulate_one(BW_TRUE, u, 1 / FS) + rng.normal(0, SIGMA, u.size),
                            dt=1 / FS, amplitude_V=a, frequency_Hz=10.0))
    kw = dict(seed=4, runs=2, polish=True)
    a = identify(caps, BoucWen(), PSO(pop=10, iters=15), jobs=1, **kw)
    b = identify(caps, BoucWen(), PSO(pop=10, iters=15), jobs=2, **kw)
    for fa, fb in zip(a.fits, b.fits):
        np.testing.assert_array_equal(fa.theta, fb.theta)
        assert [r.seed for r in fa.runs] == [r.seed for r in fb.runs]
        assert fa.metrics == fb.metrics
