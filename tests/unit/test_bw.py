import numpy as np

from hystfit.models.bw import BoucWen
from hystfit.models._kernels import bouc_wen_population
from hystfit.params import DataScale


def euler_reference(u, a, b, g, sub=400):
    """Fine explicit Euler along a linearly interpolated input (the ODE of paper 004 eq. 2)."""
    h = 0.0
    out = [0.0]
    for k in range(1, len(u)):
        du = (u[k] - u[k - 1]) / sub
        for _ in range(sub):
            h += a * du - b * abs(du) * h - g * du * abs(h)
        out.append(h)
    return np.array(out)


def test_exact_kernel_matches_fine_euler():
    t = np.linspace(0, 1, 400)
    u = 40 * np.sin(2 * np.pi * 2 * t) * np.exp(-t)
    for a, b, g in [(0.5, 0.05, 0.01), (1.0, 0.02, -0.015), (-0.3, 0.1, 0.09), (0.2, 0.0, 0.0)]:
        h = bouc_wen_population(u, np.array([a]), np.array([b]), np.array([g]))[:, 0]
        ref = euler_reference(u, a, b, g)
        assert np.max(np.abs(h - ref)) < 2e-3 * max(np.max(np.abs(ref)), 1e-9)


def test_rate_independence():
    """Bouc-Wen is rate independent: inserting intermediate samples on the same straight input segments
    changes nothing at the original samples (exact integration)."""
    u = np.array([0, 10, 30, 5, 20, -10, 0], float)
    fine = np.interp(np.linspace(0, 6, 6 * 7 + 1), np.arange(7), u)
    args = (np.array([0.7]), np.array([0.04]), np.array([0.01]))
    h = bouc_wen_population(u, *args)[:, 0]
    hf = bouc_wen_population(fine, *args)[::7, 0]
    np.testing.assert_allclose(h, hf, atol=1e-10)


def test_population_columns_equal_single_runs(rng):
    u = np.cumsum(rng.normal(size=300))
    P = 6
    a, b, g = rng.random(P), rng.random(P) * 0.2, (rng.random(P) - 0.5) * 0.2
    H = bouc_wen_population(u, a, b, g)
    for p in range(P):
        np.testing.assert_allclose(H[:, p], bouc_wen_population(u, a[p:p + 1], b[p:p + 1], g[p:p + 1])[:, 0])


def test_simulate_shapes_and_bounds_scale_with_data():
    u = np.linspace(0, 100, 50)
    m = BoucWen()
    sc1 = DataScale.from_arrays([u], [0.3 * u], [1e-3])
    sc2 = DataScale.from_arrays([u / 1000], [300 * u], [1e-3])  # mV-scale input, nm-scale output
    p1, p2 = m.params(sc1), m.params(sc2)
    assert [p.name for p in p1] == ["Kv", "alpha", "beta", "gamma", "y0"]
    assert p2[0].upper / p1[0].upper > 1e5  # gain bound follows output/input range
    y = m.simulate(np.array([[p.default for p in p1]] * 3), u, 1e-3)
    assert y.shape == (3, 50) and np.all(np.isfinite(y))


def test_divergent_parameters_give_nonfinite_not_crash():
    u = np.r_[np.linspace(0, 1000, 200), np.linspace(1000, 0, 200)]
    y = BoucWen().simulate(np.array([[1.0, 1.0, 0.0, 5.0, 0.0]]), u, 1e-3)  # beta - gamma << 0: exponential growth
    assert y.shape == (1, 400)


def test_numerical_inverse_round_trip():
    t = np.arange(3000) * 1e-4
    u = 40 * (1 - np.cos(2 * np.pi * 3 * t))
    m = BoucWen()
    theta = np.array([0.25, 0.15, 0.03, 0.01, 0.2])
    y = m.simulate_one(theta, u, 1e-4)
    u_back = m.invert(theta, y, 1e-4, u_range=(-20.0, 100.0))
    assert np.max(np.abs(u_back - u)) < 1e-6 * 80
    np.testing.assert_allclose(m.simulate_one(theta, u_back, 1e-4), y, atol=1e-6)


def test_step_agrees_with_simulate(rng):
    u = np.cumsum(rng.normal(size=50))
    m = BoucWen()
    theta = np.array([0.3, 0.2, 0.05, -0.02, 0.1])
    y = m.simulate_one(theta, u, 1e-3)
    state = m.initial_state(theta, u[0], 1e-3)
    ys = [theta[0] * u[0] + theta[4]]
    for k in range(1, len(u)):
        yk, st = m.step(theta, state, u[k - 1], np.array([u[k]]), 1e-3)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, atol=1e-12)


def test_free_exponent_n1_matches_default_and_n2_differs():
    t = np.arange(2000) * 1e-4
    u = 30 * (1 - np.cos(2 * np.pi * 5 * t))
    sc = DataScale.from_arrays([u], [0.3 * u], [1e-4])
    m1 = BoucWen()
    mn = BoucWen(free_exponent=True).adapt(sc)
    assert mn.h_ref == sc.y_range and [p.name for p in mn.params(sc)][-1] == "n"
    th = np.array([0.25, 0.15, 0.03, 0.01, 0.2])
    y1 = m1.simulate_one(th, u, 1e-4)
    yn = mn.simulate_one(np.r_[th, 1.0], u, 1e-4)
    np.testing.assert_allclose(yn, y1, atol=1e-7 * np.ptp(y1))
    y2 = mn.simulate_one(np.r_[th, 2.0], u, 1e-4)
    assert np.all(np.isfinite(y2)) and np.max(np.abs(y2 - y1)) > 1e-3
    assert mn.separable() is None and m1.separable() is not None
    # structure round-trips through JSON
    assert BoucWen.from_structure(mn.structure()) == mn


# --- exact per-candidate reference for the compiled population kernels -------------------------

def _exact_segment(g, v, a, c):
    """g(v) of dg/dv = a − c·g from g(0) = g, exactly (expm1: no cancellation for small c·v)."""
    from math import expm1

    x = c * v
    if x == 0.0:
        return g + a * v
    em1 = expm1(-x)
    return g * (1.0 + em1) + a * v * (-em1 / x)


def _exact_step(h, du, a, b, g):
    """One sample of ḣ = α u̇ − β|u̇|h − γ u̇|h| along a straight input segment, straightforwardly:
    in g = sgn(Δu)·h the regime c = β ± γ is fixed until g reaches 0, where it is split."""
    from math import log1p

    v = abs(du)
    s = 1.0 if du > 0 else -1.0
    G = s * h
    cp, cn = b + g, b - g
    c = cp if (G > 0 or (G == 0 and a >= 0)) else cn
    G1 = _exact_segment(G, v, a, c)
    if G != 0 and (G > 0) != (G1 > 0):  # reaches 0 at v* (G·e^{−cv*} + a(1 − e^{−cv*})/c = 0)
        vz = -G / a if c == 0.0 else -log1p(c * G / (a - c * G)) / c
        vz = min(max(vz, 0.0), v)
        G1 = _exact_segment(0.0, v - vz, a, cp if a >= 0 else cn)
    return s * G1


def _exact_states(u, a, b, g):
    h, out = 0.0, [0.0]
    for k in range(1, len(u)):
        if u[k] != u[k - 1]:
            h = _exact_step(h, u[k] - u[k - 1], a, b, g)
        out.append(h)
    return np.array(out)


def _wide_range_capture(rng, N=500):
    """Input whose per-sample steps span 1e-3 … 3 (with holds and many reversals): with β, γ inside
    the model's bounds every per-sample regime of the kernel occurs (series of degree 7 and 11,
    scaling and squaring) and states cross zero often."""
    steps = np.exp(rng.uniform(np.log(1e-3), np.log(3.0), N - 1))
    steps *= np.where((np.arange(N - 1) // 37) % 2 == 0, 1.0, -1.0) * np.where(rng.random(N - 1) < 0.8, 1.0, -1.0)
    steps[rng.random(N - 1) < 0.02] = 0.0
    return np.r_[0.0, np.cumsum(steps)]


def _assert_within(actual, expected, tol):
    """|actual − expected| ≤ tol elementwise (tol broadcast), with the worst ratio in the message."""
    err = np.abs(actual - expected)
    assert np.all(err <= tol), f"max error / tolerance = {np.max(err / tol):.3g}"


def test_population_kernels_match_exact_reference_in_every_regime(rng):
    from hystfit.models import _kernels as kern
    from hystfit.models._kernels import bouc_wen_moments, bouc_wen_output, bouc_wen_sse

    u = _wide_range_capture(rng)
    N, span = len(u), float(np.ptp(u))
    P = 80  # ≥ PARALLEL_MIN_POP: the threaded variant when numba has several threads
    kv = rng.uniform(-1, 1, P)
    a = rng.uniform(-1, 1, P)
    b = rng.uniform(0.0, 50.0 / span, P)  # BoucWen.params bounds for this input range
    g = rng.uniform(-50.0 / span, 50.0 / span, P)
    a[0], b[1], g[1], b[2], g[2] = 0.0, 0.0, 0.0, 0.3 / span, -0.3 / span  # α = 0; β = γ = 0; β + γ = 0
    y0 = rng.uniform(-5, 5, P)
    y = 0.2 * u + rng.normal(size=N)

    H = np.array([_exact_states(u, a[p], b[p], g[p]) for p in range(P)]).T  # (N, P)
    # the per-sample series/squaring choice is made per block by max|c|·|Δu|: all regimes occur
    x = np.abs(np.diff(u)) * np.max(np.maximum(np.abs(b + g), np.abs(b - g)))
    assert np.any((x > 0) & (x <= kern._BW_SERIES_MAX))
    assert np.any((x > kern._BW_SERIES_MAX) & (x <= kern._BW_SERIES11_MAX))
    assert np.any(x > kern._BW_SERIES11_MAX)
    assert np.sum(H[:-1] * H[1:] < 0) > 100  # many zero crossings (the exact redo)
    assert np.all(np.isfinite(H))

    scale = np.max(np.abs(H), axis=0) + 1e-300
    for sel in (slice(None), slice(3, 8)):  # threaded and serial
        h = bouc_wen_population(u, a[sel], b[sel], g[sel])
        _assert_within(h, H[:, sel], 1e-12 * scale[sel])
    Y = kv * u[:, None] + H + y0
    out = bouc_wen_output(u, kv, a, b, g, y0)
    _assert_within(out, Y, 1e-12 * np.max(np.abs(Y), axis=0))
    sse = bouc_wen_sse(u, y, kv, a, b, g, y0)
    np.testing.assert_allclose(sse, np.sum((Y - y[:, None]) ** 2, axis=0), rtol=1e-12, atol=0)
    G = np.array([_exact_states(u, 1.0, b[p], g[p]) for p in range(P)]).T  # unit gain
    M = bouc_wen_moments(u, y, b, g)
    ref = np.stack([np.sum(G * G, 0), G.T @ u, np.sum(G, 0), G.T @ y], axis=1)
    A = np.abs(G)
    size = np.stack([np.sum(G * G, 0), A.T @ np.abs(u), np.sum(A, 0), A.T @ np.abs(y)], axis=1)
    _assert_within(M, ref, 1e-12 * size + 1e-300)


def test_population_kernels_nonfinite_parameters_stay_with_their_candidate(rng):
    from hystfit.models._kernels import bouc_wen_moments, bouc_wen_sse

    u = _wide_range_capture(rng, 200)
    P = 70
    a, b, g = rng.uniform(-1, 1, P), rng.uniform(0, 0.5, P), rng.uniform(-0.5, 0.5, P)
    kv, y0, y = rng.uniform(size=P), rng.uniform(size=P), rng.normal(size=len(u))
    ref = bouc_wen_sse(u, y, kv, a, b, g, y0)
    bad = {5: ("a", np.nan), 17: ("b", np.nan), 30: ("g", np.inf), 41: ("b", -np.inf), 66: ("a", np.inf)}
    for p, (name, val) in bad.items():
        {"a": a, "b": b, "g": g}[name][p] = val
    for sel in (slice(None), slice(0, 20)):  # threaded and serial
        sse = bouc_wen_sse(u, y, kv[sel], a[sel], b[sel], g[sel], y0[sel])
        h = bouc_wen_population(u, a[sel], b[sel], g[sel])
        idx = np.arange(P)[sel]
        isbad = np.isin(idx, list(bad))
        assert not np.any(np.isfinite(sse[isbad])) and np.all(np.isfinite(sse[~isbad]))
        assert np.all(~np.all(np.isfinite(h[:, isbad]), axis=0))
        np.testing.assert_allclose(sse[~isbad], ref[sel][~isbad], rtol=1e-12)
    M = bouc_wen_moments(u, y, b, g)  # α does not enter the unit-gain moments
    assert np.all(np.isfinite(M[[5, 66]])) and not np.any(np.isfinite(M[[17, 30, 41]]).all(axis=1))
