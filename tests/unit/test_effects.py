"""Candidate effects of ``hystfit diagnose``: operators, and each fit recovers its own parameters."""

import numpy as np
import pytest
from scipy import signal

from hystfit.blocks.asymmetry import Asymmetry
from hystfit.blocks.creep import Creep, lowpass_at_rest
from hystfit.blocks.delay import Delay, fractional_delay
from hystfit.blocks.drift import Drift
from hystfit.blocks.dynamics import Dynamics, bilinear_biquad, second_order_at_rest
from hystfit.effects import (EFFECTS, CaptureView, Linearization, Placebo, make_effect, signature_share,
                             solve_coefficients)
from hystfit.errors import ConfigError
from hystfit.synth import raised_cosine, steps

FS = 10_000.0
DT = 1.0 / FS


def second_order_coefficients(fn, zeta, dt):
    b0, b1, b2, a1, a2 = (float(c[0]) for c in bilinear_biquad(fn, zeta, dt))
    if not np.isfinite(a1):
        raise ConfigError(f"f_n = {fn} Hz is not below the Nyquist frequency")
    return np.array([b0, b1, b2]), np.array([1.0, a1, a2])


def _signals():
    """Base outputs (µm) of three captures: two raised cosines and a step-and-hold."""
    out = []
    for a, f in ((10.0, 20.0), (18.0, 80.0)):
        t, u = raised_cosine(a, f, 5, FS)
        out.append((t, u + 0.25, f, True))
    t, u = steps([0.0, 9.0, 18.0, 6.0, 13.0, 0.0], [0.05, 0.6, 0.6, 0.6, 0.6, 0.6], FS)
    out.append((t, u + 0.25, 0.3, False))
    return out


def _views(ys, fit_fraction=1.0):
    vs = []
    for i, ((t, _, f, per), y) in enumerate(zip(_signals(), ys)):
        m = np.zeros(t.size, bool)
        m[: int(round(fit_fraction * t.size))] = True
        vs.append(CaptureView(t, DT, np.asarray(y, float), m, f, per, i))
    return vs


def _noisy(ys, rng, sigma=0.005):
    return [y + sigma * rng.standard_normal(y.size) for y in ys]


# ----------------------------------------------------------------------------------------------
# operators


def test_second_order_matches_scipy_prewarped_bilinear():
    for fn, zeta, dt in ((1200.0, 0.15, 1e-4), (35.0, 1.4, 2e-4), (4000.0, 0.03, 1e-4)):
        wn = 2 * np.pi * fn
        k = wn / np.tan(wn * dt / 2)
        b_ref, a_ref = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=k / 2)
        b, a = second_order_coefficients(fn, zeta, dt)
        np.testing.assert_allclose(b, b_ref, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(a, a_ref, rtol=1e-12, atol=1e-15)
    with pytest.raises(ConfigError):
        second_order_coefficients(6000.0, 0.1, 1e-4)


def test_operators_start_at_rest_and_keep_dc():
    x = np.full(500, 3.7)
    np.testing.assert_allclose(second_order_at_rest(x, 900.0, 0.2, DT), x, rtol=1e-12)
    np.testing.assert_allclose(lowpass_at_rest(x, 0.1, DT), x, rtol=1e-12)
    np.testing.assert_allclose(fractional_delay(x, 3.3 * DT, DT), x)
    cols = np.column_stack([x, 2 * x])
    np.testing.assert_allclose(second_order_at_rest(cols, 900.0, 0.2, DT)[:, 1], 2 * x, rtol=1e-12)


def test_fractional_delay_of_a_ramp():
    x = np.arange(100.0) * 0.5
    y = fractional_delay(x, 2.5 * DT, DT)
    np.testing.assert_allclose(y[10:], x[10:] - 2.5 * 0.5)
    assert y[0] == x[0] and y[1] == x[0]


def test_prewarping_puts_the_natural_frequency_at_fn():
    """Phase −90° and gain 1/(2ζ) exactly at f_n (the continuous system's values), thanks to prewarping."""
    fn, zeta = 1500.0, 0.05
    b, a = second_order_coefficients(fn, zeta, DT)
    _, h = signal.freqz(b, a, worN=[fn], fs=FS)
    assert np.degrees(np.angle(h[0])) == pytest.approx(-90.0, abs=1e-6)
    assert abs(h[0]) == pytest.approx(1.0 / (2 * zeta), rel=1e-9)


# ----------------------------------------------------------------------------------------------
# each effect recovers its own parameters (base output held fixed)


def test_dynamics_recovers_natural_frequency_and_damping(rng):
    base = [u for _, u, _, _ in _signals()]
    ys = _noisy([second_order_at_rest(b, 900.0, 0.25, DT) for b in base], rng)
    views = _views(ys)
    eff = Dynamics().configure(views, base)
    assert eff.fn_min_Hz == pytest.approx(160.0, rel=1e-3) and eff.fn_max_Hz == pytest.approx(0.45 * FS)  # as identify: the sampled drive rate
    fit = eff.fit(base, views)
    assert fit.phi[0] == pytest.approx(900.0, rel=0.01)
    assert fit.phi[1] == pytest.approx(0.25, rel=0.03)
    p = fit.params(views)
    assert p["fn_Hz"] == fit.phi[0] and p["group_delay_low_frequency_us"] > 0


def test_delay_recovers_the_delay(rng):
    base = [u for _, u, _, _ in _signals()]
    ys = _noisy([fractional_delay(b, 230e-6, DT) for b in base], rng)
    views = _views(ys)
    fit = Delay().configure(views, base).fit(base, views)
    assert fit.phi[0] == pytest.approx(230e-6, abs=3e-6)
    assert fit.params(views)["delay_samples"] == pytest.approx(2.3, abs=0.03)


def test_creep_recovers_its_gains(rng):
    base = [u for _, u, _, _ in _signals()]
    eff = Creep().configure(_views(base), base)
    assert eff.tau_s == (0.01, 0.1, 1.0, 10.0)  # longest capture 3.05 s → up to 10 s
    c_true = np.array([0.012, 0.02, 0.015, 0.0])
    ys = _noisy([eff.apply(b, v, np.empty(0), c_true, np.empty(0)) for b, v in zip(base, _views(base))], rng)
    views = _views(ys)
    fit = eff.fit(base, views)
    np.testing.assert_allclose(fit.shared, c_true, atol=1.5e-3)
    assert np.all(fit.shared >= 0)


def test_creep_gains_stay_non_negative(rng):
    base = [u for _, u, _, _ in _signals()]
    eff = Creep().configure(_views(base), base)
    neg = np.array([0.0, -0.03, 0.0, 0.0])  # "anti-creep": not physical
    ys = [eff.apply(b, v, np.empty(0), neg, np.empty(0)) for b, v in zip(base, _views(base))]
    fit = eff.fit(base, _views(ys))
    assert np.all(fit.shared >= 0)


def test_asymmetry_recovers_its_bow(rng):
    base = [u for _, u, _, _ in _signals()]
    eff = Asymmetry().configure(_views(base), base)
    a_true = np.array([-0.3, 0.1])
    ys = _noisy([eff.apply(b, v, np.empty(0), a_true, np.empty(0)) for b, v in zip(base, _views(base))], rng)
    views = _views(ys)
    eff = Asymmetry().configure(views, base)
    fit = eff.fit(base, views)
    # the recovered map equals the true one (it was configured on a slightly different range)
    s_true = Asymmetry().configure(_views(base), base)
    for b, v in zip(base, views):
        truth = s_true.apply(b, v, np.empty(0), a_true, np.empty(0))
        np.testing.assert_allclose(fit.apply(b, v, v.index), truth, atol=0.01)
    assert fit.params(views)["mid_stroke_bow_out"] > 0


def test_drift_recovers_offset_and_rate_per_capture(rng):
    base = [u for _, u, _, _ in _signals()]
    truth = np.array([[0.05, 0.2], [-0.02, -0.1], [0.01, 0.03]])
    views0 = _views(base)
    ys = _noisy([b + o + r * v.t for b, v, (o, r) in zip(base, views0, truth)], rng)
    views = _views(ys)
    fit = Drift().fit(base, views)
    np.testing.assert_allclose(fit.local[:, 1], truth[:, 1], atol=0.02)  # 0.1-s captures: rate ±0.02 µm/s
    np.testing.assert_allclose(fit.local[2], truth[2], atol=2e-3)         # 3-s capture: tight
    p = fit.params(views, ["a", "b", "c"])
    assert [r["source"] for r in p["per_capture"]] == ["a", "b", "c"]


def test_fit_uses_only_the_fit_samples(rng):
    base = [u for _, u, _, _ in _signals()]
    ys = [fractional_delay(b, 200e-6, DT) for b in base]
    views = _views(ys, fit_fraction=0.5)
    # corrupt the held-out half: the fit must not notice
    bad = [CaptureView(v.t, v.dt, np.where(v.fit, v.y, v.y + 5.0), v.fit, v.frequency_Hz, v.periodic, v.index)
           for v in views]
    f1 = Delay().configure(views, base).fit(base, views)
    f2 = Delay().configure(bad, base).fit(base, bad)
    assert f1.phi[0] == pytest.approx(f2.phi[0], abs=1e-9)


# ----------------------------------------------------------------------------------------------
# joint refit with the base (variable projection + Gauss–Newton step)


def test_joint_fit_moves_the_base_and_finds_the_effect(rng):
    """A linear 'base model' ŷ = B θ fitted without the stage compromises; with the linearization
    the effect and the corrected θ are found together."""
    sigs = _signals()
    Bs = [np.column_stack([u, np.maximum(u - 6.0, 0.0), np.ones_like(u)]) for _, u, _, _ in sigs]
    theta_true = np.array([0.9, 0.3, 0.2])
    ys = _noisy([second_order_at_rest(B @ theta_true, 700.0, 0.3, DT) for B in Bs], rng)
    views = _views(ys)
    theta0 = theta_true * np.array([1.05, 0.9, 1.0]) + np.array([0, 0, 0.05])  # a wrong base
    base = [B @ theta0 for B in Bs]
    lin = Linearization(tuple(Bs), tuple(np.arange(3) for _ in Bs), np.full(3, -np.inf), np.full(3, np.inf))
    eff = Dynamics().configure(views, base)
    fit = eff.fit(base, views, lin)
    np.testing.assert_allclose(theta0 + fit.delta, theta_true, rtol=2e-3, atol=2e-3)
    assert fit.phi[0] == pytest.approx(700.0, rel=0.01)
    assert fit.phi[1] == pytest.approx(0.3, rel=0.03)
    fixed = eff.fit(base, views)  # the base held fixed cannot get there
    assert fixed.sse > 5 * fit.sse


@pytest.mark.parametrize("name", ["creep", "asymmetry"])
def test_tangent_is_the_derivative_of_apply(name, rng):
    base = [u for _, u, _, _ in _signals()]
    views = _views(base)
    eff = make_effect(name).configure(views, base)
    ks, _ = eff.layout()
    coef = np.array([0.01, 0.02, 0.005, 0.01])[:ks] if name == "creep" else np.array([-0.4, 0.2])
    b, v = base[2], views[2]
    x = rng.standard_normal((b.size, 2)) * 0.1
    h = 1e-6
    num = np.column_stack([(eff.apply(b + h * x[:, j], v, np.empty(0), coef, np.empty(0))
                            - eff.apply(b - h * x[:, j], v, np.empty(0), coef, np.empty(0))) / (2 * h)
                           for j in range(2)])
    np.testing.assert_allclose(eff.tangent(x, b, v, np.empty(0), coef, np.empty(0)), num, atol=1e-6)


def test_bounded_solve_respects_base_bounds(rng):
    sigs = _signals()
    Bs = [np.column_stack([u, np.ones_like(u)]) for _, u, _, _ in sigs]
    ys = [B @ np.array([1.0, 0.5]) for B in Bs]
    views = _views(ys)
    base = [B @ np.array([0.8, 0.5]) for B in Bs]
    lin = Linearization(tuple(Bs), tuple(np.arange(2) for _ in Bs), np.array([-np.inf, -np.inf]), np.array([0.1, np.inf]))
    _, _, delta, _ = solve_coefficients(Drift(), np.empty(0), base, views, lin, bounded=True)
    assert delta[0] <= 0.1 + 1e-12
    _, _, delta, _ = solve_coefficients(Drift(), np.empty(0), base, views, lin, bounded=False)
    assert delta[0] == pytest.approx(0.2, abs=1e-6)


# ----------------------------------------------------------------------------------------------
# evidence, placebo, registry


def test_signature_share_points_to_the_right_effect(rng):
    base = [u for _, u, _, _ in _signals()]
    ys = _noisy([fractional_delay(b, 150e-6, DT) for b in base], rng)
    views = _views(ys)
    share_delay, _ = signature_share(Delay().configure(views, base), base, views, 0.005 ** 2)
    share_asym, _ = signature_share(Asymmetry().configure(views, base), base, views, 0.005 ** 2)
    assert share_delay > 0.8 > 0.2 > share_asym


def test_placebo_has_the_requested_size(rng):
    base = [u for _, u, _, _ in _signals()]
    views = _views(base)
    lib = [np.column_stack([b, b ** 2, v.t]) for b, v in zip(base, views)]
    pl = Placebo.build(lib, 2, 1, rng)
    assert pl.layout() == (2, 1) and pl.n_parameters(3) == 5
    Rs, Rl = pl.regressors(base[1], views[1], np.empty(0))
    assert Rs.shape == (base[1].size, 2) and Rl.shape == (base[1].size, 1)


def test_placebo_columns_are_mixed_surrogates():
    """The placebo's regressors are its surrogates of the library mixed by its weights (mixed before
    the inverse transform: equal up to rounding) — the same random phases as :func:`phase_surrogate`."""
    import copy

    from hystfit.effects import phase_surrogate

    gen = np.random.default_rng(3)
    library = [gen.standard_normal((n, 5)) for n in (400, 257)]
    rng = np.random.default_rng(9)
    start = copy.deepcopy(rng)
    pl = Placebo.build(library, 1, 2, rng)
    surrogates = [phase_surrogate(L, start) for L in library]
    W = start.standard_normal((5, 3)) / np.sqrt(5)
    assert np.array_equal(W, pl.weights)
    for S, L, cols in zip(surrogates, library, pl.columns):
        assert cols.shape == (L.shape[0], 3)
        np.testing.assert_allclose(cols, S @ W, rtol=0, atol=1e-12 * np.abs(S @ W).max())


def test_registry_and_parameter_tables():
    assert list(EFFECTS) == ["dynamics", "creep", "asymmetry", "drift", "delay"]
    for name in EFFECTS:
        eff = make_effect(name)
        assert eff.name == name and eff.title and eff.equation
        assert all(p.unit and p.kind in ("searched", "linear", "per-capture", "fixed") for p in eff.param_table())
    with pytest.raises(ConfigError, match="unknown effect"):
        make_effect("thermal")


@pytest.mark.parametrize("bits", [np.random.PCG64, np.random.MT19937])  # advanced in place / drawn
def test_placebo_skip_advances_the_generator_as_build_does(bits):
    """A placebo built from a copy of the generator taken before ``skip`` equals the one ``build``
    draws in turn, and ``skip`` leaves the generator where ``build`` does (cached spectra or not)."""
    import copy

    from hystfit.effects import Placebo, surrogate_spectrum

    gen = np.random.default_rng(5)
    library = [gen.standard_normal((n, 4)) for n in (301, 300, 57)]
    a, b = np.random.Generator(bits(11)), np.random.Generator(bits(11))
    built = [Placebo.build(library, 2, 1, a) for _ in range(3)]
    spectra = [surrogate_spectrum(L) for L in library]
    for want in built:
        start = copy.deepcopy(b)
        Placebo.skip(library, 2, 1, b)
        got = Placebo.build(library, 2, 1, start, spectra)
        assert np.array_equal(got.weights, want.weights)
        assert all(np.array_equal(x, y) for x, y in zip(got.columns, want.columns))
    assert a.random() == b.random()


def test_unit_phasors_are_the_complex_exponential():
    """The placebo's random phases: e^{2πi r} with the numbers of numpy's complex exponential."""
    from hystfit.effects import _unit_phasors

    r = np.random.default_rng(2).random((777, 5))
    assert np.array_equal(_unit_phasors(r), np.exp(2j * np.pi * r))


def test_a_stage_ending_on_its_lowest_f_n_widens_its_range_there_only():
    """Dynamics.widened: f_n's lower bound (twice the fastest drive) a quarter as high, rounded down to
    three digits, when the fit ended on it; not at an inner point, not at the top, not below 1 Hz.
    handover_options names the widened bound only (what the block would not set itself)."""
    from hystfit.blocks.dynamics import FN_FLOOR_HZ, Dynamics, fn_search_range_of
    from hystfit.blocks.base import scale_of_views

    t = np.arange(4000) * 1e-4
    views = [CaptureView(t=t, dt=1e-4, y=np.sin(2 * np.pi * 80 * t), fit=t < 0.25, frequency_Hz=80.0, periodic=True)]
    dyn = Dynamics().configure(views, [v.y for v in views])
    lo, hi = dyn.fn_range
    assert (lo, hi) == fn_search_range_of(scale_of_views(views)) and lo == pytest.approx(160.0, rel=0.01)
    assert dyn.widened(np.array([lo * 1.2, 0.1])) is None and dyn.widened(np.array([hi, 0.1])) is None
    wide = dyn.widened(np.array([lo, 0.1]))
    assert wide.fn_range[1] == hi and wide.fn_range[0] <= lo / 4 and wide.fn_range[0] == pytest.approx(lo / 4, rel=1e-2)
    assert f"{wide.fn_range[0]:g}" == f"{wide.fn_range[0]:.3g}"  # three digits: a readable --model-option
    assert dyn.handover_options(views) == {} and wide.handover_options(views) == {"fn_min_Hz": wide.fn_range[0]}
    floor = Dynamics(fn_min_Hz=FN_FLOOR_HZ, fn_max_Hz=hi)
    assert floor.widened(np.array([FN_FLOOR_HZ, 0.1])) is None
    assert Dynamics(fn_min_Hz=2.0, fn_max_Hz=hi).widened(np.array([2.0, 0.1])).fn_range[0] == FN_FLOOR_HZ


# ----------------------------------------------------------------------------------------------
# the stage's gradient polish


def _stage_problem(rng, fit_fraction=0.6):
    """A stage on a linear base ŷ = B θ that is off (so the joint step δ matters), fitted on the
    first ``fit_fraction`` of each capture: (effect, its scoring design, bounds, log flags)."""
    from hystfit.effects import prepare_design, scoring_design

    sigs = _signals()
    Bs = [np.column_stack([u, np.maximum(u - 6.0, 0.0), np.ones_like(u)]) for _, u, _, _ in sigs]
    theta = np.array([0.9, 0.3, 0.2])
    ys = _noisy([second_order_at_rest(B @ theta, 700.0, 0.3, DT) for B in Bs], rng)
    views = _views(ys, fit_fraction)
    base = [B @ (theta * np.array([1.05, 0.9, 1.0])) for B in Bs]
    lin = Linearization(tuple(Bs), tuple(np.arange(3) for _ in Bs), np.full(3, -np.inf), np.full(3, np.inf))
    eff = Dynamics().configure(views, base)
    scoring = scoring_design(prepare_design(base, views, lin))
    lo, hi = eff.searched_bounds()
    return eff, scoring, lo, hi, eff._log_scaled()


@pytest.mark.parametrize("fit_fraction", [1.0, 0.6])
def test_the_stage_score_gradient_is_the_derivative_of_its_score(rng, fit_fraction):
    """Variable projection: the SSE's gradient at the fixed combination x = X·(1, δ) equals the
    derivative of the score (δ re-solved at every φ), on every sample or on the fit part only."""
    from hystfit.effects import _score_and_gradient, _search_coordinates, filters_columns

    eff, scoring, lo, hi, logs = _stage_problem(rng, fit_fraction)
    assert filters_columns(eff, scoring)
    to_z, from_z = _search_coordinates(lo, hi, logs)
    zlo, zhi = to_z(lo), to_z(hi)
    rows = [np.arange(scoring.X[c].shape[0]) if m is None else np.flatnonzero(m) for c, m, _ in scoring.fitted]
    for phi in (np.array([520.0, 0.45]), np.array([900.0, 0.2])):
        z = to_z(phi)
        sse, grad = _score_and_gradient(eff, scoring, z, from_z, zlo, zhi, rows)
        assert sse == pytest.approx(eff.score(phi, scoring), rel=1e-12)
        h = 1e-5
        num = [(eff.score(from_z(z + h * e), scoring) - eff.score(from_z(z - h * e), scoring)) / (2 * h)
               for e in np.eye(2)]
        np.testing.assert_allclose(grad, num, rtol=1e-4, atol=1e-6 * sse)


def test_the_gradient_polish_ends_where_nelder_mead_does_with_fewer_scores(rng):
    """From a grid point off the optimum, L-BFGS-B on the exact gradient reaches the SSE of a
    Nelder–Mead polish of 200 scores within 1e-6 relative and φ within 0.1 %, scoring far fewer
    candidates."""
    from hystfit.effects import _gradient_polish, _polish

    eff, scoring, lo, hi, logs = _stage_problem(rng)
    x0 = np.array([560.0, 0.5])
    seen_nm: dict = {}

    def score(phi):
        key = np.asarray(phi, float).tobytes()
        if key not in seen_nm:
            seen_nm[key] = eff.score(phi, scoring)
        return seen_nm[key]

    nm = _polish(score, x0, lo, hi, logs, maxfev=200)
    seen: dict = {}
    best = _gradient_polish(eff, scoring, seen, x0, lo, hi, logs)
    assert eff.score(best, scoring) <= eff.score(nm, scoring) * (1 + 1e-6)
    np.testing.assert_allclose(best, nm, rtol=1e-3)
    np.testing.assert_allclose(best, [700.0, 0.3], rtol=0.02)
    assert len(seen) <= 20 < len(seen_nm)


def test_the_gradient_polish_follows_a_bound_out_of_a_corner(rng):
    """Started in the corner of its range (f_n and ζ at their tops, where a Nelder–Mead's simplex is
    clipped flat and stays), the polish moves along ζ's bound to a lower score."""
    from hystfit.effects import _gradient_polish

    eff, scoring, lo, hi, logs = _stage_problem(rng)
    corner = hi.copy()
    best = _gradient_polish(eff, scoring, {}, corner, lo, hi, logs)
    assert eff.score(best, scoring) < eff.score(corner, scoring)
    assert not np.array_equal(best, corner)


def test_a_large_bounded_solve_is_converged():
    """The bounded solve of a base of 160 operators and more (≈ 170 coefficients, ill-conditioned):
    the minimizer within the box (its KKT conditions: no free coefficient's gradient, none at a bound
    pointing inside). trf, used there before, stopped short of it (here, with the suite's one BLAS
    thread, a KKT residual of 1.5·10⁻³ against BVLS's 10⁻¹⁰; on a blind case the SSE jumped 77 → 138 between φ 10⁻⁵ apart, and a real
    2 kHz stage went unnamed)."""
    from hystfit.effects import _scaled_solve

    rng = np.random.default_rng(4)
    n = 170
    A = rng.standard_normal((400, n)) @ np.diag(np.geomspace(1.0, 1e-7, n))  # singular values 1 … 1e-7
    G, x_true = A.T @ A, rng.standard_normal(n)
    b = G @ x_true
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    lo[::2] = 0.0  # half the coefficients nonnegative, the truth violates many of them
    x = _scaled_solve(G, b, lo, hi)
    assert np.all(x >= lo - 1e-12)
    g = G @ x - b
    scale = np.sqrt(np.diag(G)) * np.linalg.norm(b) / np.sqrt(np.diag(G)).max()
    at_lo = x <= lo + 1e-9 * (1 + np.abs(x))
    assert np.all(np.abs(g[~at_lo]) <= 1e-6 * scale[~at_lo])
    assert np.all(g[at_lo] >= -1e-6 * scale[at_lo])
