"""Bouc–Wen with a free exponent n (kernel in hystfit.models.bw)."""

import numpy as np

from hystfit.models._kernels import bouc_wen_population
from hystfit.models.bw import bouc_wen_n_population, bouc_wen_n_step


def euler_reference(u, a, b, g, n, sub=2000):
    """Plain-Python fine explicit Euler of paper 004 eq. 2 along the linearly interpolated input."""
    h = 0.0
    out = [0.0]
    for k in range(1, len(u)):
        du = (u[k] - u[k - 1]) / sub
        for _ in range(sub):
            h += a * du - b * abs(du) * abs(h) ** (n - 1) * h - g * du * abs(h) ** n
        out.append(h)
    return np.array(out)


def _run(u, a, b, g, n):
    return bouc_wen_n_population(u, np.array([a]), np.array([b]), np.array([g]), np.array([n]))[:, 0]


def test_matches_fine_euler_for_several_exponents():
    t = np.linspace(0, 1, 120)
    u = 40 * np.sin(2 * np.pi * 2 * t) * np.exp(-t)  # large steps per sample: sub-stepping is exercised
    cases = [(0.5, 0.05, 0.01, 1.0), (0.8, 0.01, 0.004, 1.5), (1.0, 2e-3, -1e-3, 2.0), (-0.3, 4e-4, 3e-4, 3.0)]
    for a, b, g, n in cases:
        h = _run(u, a, b, g, n)
        ref = euler_reference(u, a, b, g, n)
        # Euler with 2000 sub-steps per sample is itself accurate to ~1e-4 of the amplitude
        assert np.max(np.abs(h - ref)) < 1e-3 * np.max(np.abs(ref)), (a, b, g, n)


def test_n1_agrees_with_exact_kernel(rng):
    u = np.cumsum(rng.normal(scale=3.0, size=400))
    P = 5
    a, b, g = rng.random(P), rng.random(P) * 0.2, (rng.random(P) - 0.5) * 0.2
    exact = bouc_wen_population(u, a, b, g)
    sub = bouc_wen_n_population(u, a, b, g, np.ones(P))
    np.testing.assert_allclose(sub, exact, rtol=0, atol=1e-6 * np.max(np.abs(exact)))


def test_rate_independent_and_population_columns(rng):
    u = np.array([0, 10, 30, 5, 20, -10, 0], float)
    fine = np.interp(np.linspace(0, 6, 6 * 9 + 1), np.arange(7), u)
    args = (np.array([0.7]), np.array([0.004]), np.array([0.001]), np.array([2.0]))
    np.testing.assert_allclose(bouc_wen_n_population(u, *args)[:, 0],
                               bouc_wen_n_population(fine, *args)[::9, 0], atol=1e-6 * 40)
    P = 4
    a, b, g, n = rng.random(P), rng.random(P) * 0.01, rng.random(P) * 0.005, 1 + 2 * rng.random(P)
    H = bouc_wen_n_population(fine, a, b, g, n)
    for p in range(P):
        single = bouc_wen_n_population(fine, a[p:p + 1], b[p:p + 1], g[p:p + 1], n[p:p + 1])[:, 0]
        np.testing.assert_array_equal(H[:, p], single)


def test_step_agrees_with_population(rng):
    u = np.cumsum(rng.normal(size=60))
    a, b, g, n = 0.4, 0.02, 0.01, 1.7
    H = _run(u, a, b, g, n)
    h = 0.0
    for k in range(1, len(u)):
        h = bouc_wen_n_step(h, u[k - 1], np.array([u[k], u[k] + 1.0]), a, b, g, n)[0]
        assert h == H[k]


def test_divergent_parameters_give_nonfinite_not_crash():
    u = np.r_[np.linspace(0, 100, 50), np.linspace(100, 0, 50)]
    h = _run(u, 1.0, -0.5, -0.5, 2.0)  # β + γ < 0: finite-time blow-up
    assert h.shape == (100,) and not np.all(np.isfinite(h))
