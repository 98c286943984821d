"""The faster operators of diagnose give the numbers of the straightforward ones, bit for bit.

Each fast path (one biquad for every column, the delay by slices, creep's low-pass bank in one
kernel, the Jacobian filled capture by capture, the normal equations summed by slices) is compared
with the formula it replaces, written out here; a changed operation order or an off-by-one index
fails these with exact equality. The finer base of the resolution checks is fitted once per diagnosis.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hystfit.blocks.creep import Creep, lowpass_at_rest
from hystfit.blocks.delay import fractional_delay
from hystfit.blocks.dynamics import bilinear_biquad, biquad_columns, second_order_at_rest
from hystfit.effects import CaptureView, Linearization, make_effect, prepare_design, solve_coefficients
from hystfit.factory import make_model, make_optimizer
from hystfit.objective import Objective, Series
from hystfit.params import DataScale
from hystfit.registry import optimizers


def _gather_delay(x, delay_s, dt):
    """The index-array form: sample k reads x[clip(k − n)] and x[clip(k − n − 1)]."""
    d = max(float(delay_s) / dt, 0.0)
    n = int(math.floor(d))
    f = d - n
    N = x.shape[0]
    idx = np.arange(N) - n
    i0, i1 = np.clip(idx, 0, N - 1), np.clip(idx - 1, 0, N - 1)
    return x[i0] if f == 0.0 else (1.0 - f) * x[i0] + f * x[i1]


@pytest.mark.parametrize("N", [1, 2, 3, 7, 40])
@pytest.mark.parametrize("samples", [0.0, 0.4, 1.0, 1.5, 2.0, 6.25, 39.0, 39.5, 41.0, 100.0])
def test_fractional_delay_equals_the_gather_form(N, samples):
    rng = np.random.default_rng(N)
    for x in (rng.standard_normal(N), rng.standard_normal((N, 3))):
        out = fractional_delay(x, samples * 1e-4, 1e-4)
        ref = _gather_delay(x, samples * 1e-4, 1e-4)
        assert out.shape == ref.shape
        assert np.array_equal(out, ref)


@pytest.mark.parametrize("fn, zeta", [(300.0, 0.05), (1500.0, 0.7), (4000.0, 2.0)])
def test_second_order_at_rest_equals_the_per_column_kernel(fn, zeta):
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal((600, 5)), axis=0)
    dt = 1e-4
    coef = [np.full(5, float(c[0])) for c in bilinear_biquad(fn, zeta, dt)]
    ref = biquad_columns(np.ascontiguousarray(x), *coef)
    assert np.array_equal(second_order_at_rest(x, fn, zeta, dt), ref)
    assert np.array_equal(second_order_at_rest(np.asfortranarray(x), fn, zeta, dt), ref)
    assert np.array_equal(second_order_at_rest(x[:, 2], fn, zeta, dt), ref[:, 2])


@pytest.mark.parametrize("shape, axis", [((800,), 0), ((800, 4), 0), ((3, 800), 1), ((1,), 0)])
def test_creep_bank_equals_lfilter(shape, axis):
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.standard_normal(shape), axis=axis)
    creep = Creep(tau_s=(0.002, 0.01, 0.1, 1.0))
    bank = creep._bank(x, 1e-4, axis)
    assert len(bank) == 4
    for tau, term in zip(creep.taus, bank):
        ref = lowpass_at_rest(x, tau, 1e-4, axis) - x
        assert term.shape == ref.shape
        assert np.array_equal(term, ref)


def test_jacobian_equals_stacked_forward_differences():
    rng = np.random.default_rng(2)
    t = np.arange(700) * 2e-4
    series = []
    for k, (amp, f) in enumerate([(20.0, 10.0), (40.0, 30.0), (30.0, 20.0)]):
        u = amp * 0.5 * (1 - np.cos(2 * np.pi * f * t[: 500 + 100 * k]))
        series.append(Series(u, 0.1 * u + 0.01 * rng.standard_normal(u.size), 2e-4, 5 * k))
    scale = DataScale.from_arrays([s.u for s in series], [s.y for s in series], [s.dt for s in series])
    model = make_model("pi+creep+delay", {"n_operators": 6}).adapt(scale)
    obj = Objective(model, series)
    theta = np.array([p.default for p in model.params(scale)])
    h, pop = obj._fd_population(theta, 1e-6, None)
    ys = np.concatenate([model.simulator(s.u, s.dt)(pop)[:, s.skip:] for s in series], axis=1)
    ref = ((ys[1:] - ys[0]) / h[:, None]).T
    J = obj.jacobian(theta)
    assert J.shape == ref.shape == (obj.n_total, theta.size)
    assert np.array_equal(J, ref)


def test_the_jacobian_of_a_model_linear_in_every_parameter_is_its_basis():
    """pi is linear in every parameter: its Jacobian is its design matrix (warm-ups cut), exact,
    made once and kept read-only — the forward differences agree to their own error."""
    rng = np.random.default_rng(4)
    t = np.arange(900) * 2e-4
    series = [Series(a * 0.5 * (1 - np.cos(2 * np.pi * f * t)), rng.standard_normal(t.size), 2e-4, skip)
              for a, f, skip in ((20.0, 10.0, 0), (40.0, 30.0, 7))]
    scale = DataScale.from_arrays([s.u for s in series], [s.y for s in series], [s.dt for s in series])
    model = make_model("pi", {"n_operators": 8}).adapt(scale)
    obj = Objective(model, series)
    theta = np.array([p.default for p in model.params(scale)])
    J = obj.jacobian(theta)
    want = np.concatenate([model.design_matrix(s.u, s.dt)[s.skip:] for s in series])
    assert np.array_equal(J, want) and not J.flags.writeable
    assert obj.jacobian(2.0 * theta) is J  # the same at every θ
    h, pop = obj._fd_population(theta, 1e-6, None)
    ys = np.concatenate([model.simulator(s.u, s.dt)(pop)[:, s.skip:] for s in series], axis=1)
    np.testing.assert_allclose(J, ((ys[1:] - ys[0]) / h[:, None]).T, rtol=1e-4, atol=1e-4)  # FD: ≈ 4e-6 off
    # with a block it is no longer linear in every parameter: forward differences, as before
    assert Objective(make_model("pi+creep", {"n_operators": 8}).adapt(scale), series)._linear_jacobian() is None


def _views(rng, lengths):
    views, yhats = [], []
    for i, N in enumerate(lengths):
        t = np.arange(N) * 1e-4
        y = np.sin(2 * np.pi * 20 * t) + 0.01 * rng.standard_normal(N)
        views.append(CaptureView(t=t, dt=1e-4, y=y, fit=np.ones(N, bool), frequency_Hz=20.0, periodic=True, index=i))
        yhats.append(np.sin(2 * np.pi * 20 * t - 0.02))
    return views, yhats


@pytest.mark.parametrize("name", ["delay", "dynamics", "creep", "drift"])
def test_normal_equations_by_slices_solve_the_least_squares_problem(name):
    """A global base (every capture on the same consecutive columns, summed by slices) and a base
    whose captures own shifted columns (fancy indexing): both give the unbounded least-squares
    fit of y ≈ T[ŷ + Jδ] + R a that an explicit stacked solve gives."""
    rng = np.random.default_rng(3)
    views, yhats = _views(rng, [300, 350, 420])
    k = 4
    jac = tuple(rng.standard_normal((v.n, k)) for v in views)
    for cols in ([np.arange(k)] * 3, [np.arange(k), np.arange(1, k + 1), np.arange(2, k + 2)]):
        n = int(max(c.max() for c in cols)) + 1
        lin = Linearization(jac, tuple(cols), np.full(n, -np.inf), np.full(n, np.inf))
        eff = make_effect(name).configure(views, yhats)
        phi = eff.search_grid()[len(eff.search_grid()) // 2]
        shared, local, delta, sse = solve_coefficients(eff, phi, design=prepare_design(yhats, views, lin), bounded=False)
        ks, kl = eff.layout()
        C = len(views)
        rows, rhs = [], []
        for c, (v, yh) in enumerate(zip(views, yhats)):
            X = np.hstack([yh[:, None], jac[c]])
            T = np.asarray(eff.operator(X, v, phi))
            Rs, Rl = eff.regressors(yh, v, phi)
            A = np.zeros((v.n, ks + C * kl + n))
            A[:, :ks] = Rs
            A[:, ks + c * kl: ks + (c + 1) * kl] = Rl
            A[:, ks + C * kl + cols[c]] = T[:, 1:]
            rows.append(A)
            rhs.append(v.y - T[:, 0])
        A, b = np.vstack(rows), np.concatenate(rhs)
        x_ref = np.linalg.lstsq(A, b, rcond=None)[0]
        sse_ref = float(np.sum((A @ x_ref - b) ** 2))
        assert sse == pytest.approx(sse_ref, rel=1e-6)
        x = np.concatenate([shared, local.ravel(), delta])
        assert np.allclose(A @ x, A @ x_ref, rtol=0, atol=1e-6 * np.abs(b).max())


def _two_raised_cosines(n: int):
    """Two captures of n samples at 10 kHz: raised cosines of 20 V at 10 and 20 Hz, y = 0.1·u."""
    from hystfit.io import Capture

    t = np.arange(n) * 1e-4
    caps = []
    for f in (10.0, 20.0):
        u = 20.0 * 0.5 * (1 - np.cos(2 * np.pi * f * t))
        caps.append(Capture(t=t, u=u, y=0.1 * u, dt=1e-4, amplitude_V=20.0, frequency_Hz=f, source=f"c{f:g}"))
    return caps


def test_finer_base_is_fitted_once_per_diagnosis(monkeypatch):
    """The resolution checks ask for the same finer base several times: it is fitted the first time
    only, per design (a new diagnosis fits again) and per resolution (another resolution is fitted)."""
    import hystfit.diagnose as D

    calls = []

    def fake_fits(jobs, n_groups, model, optimizer, seed, executor, store, resume, advance, stats=None):
        calls.append(model)
        return [object()]

    monkeypatch.setattr(D, "_base_fits", fake_fits)
    caps = _two_raised_cosines(400)
    design = D._design(caps, D.DiagnoseSettings(), False)
    opt = make_optimizer(optimizers.get("auto"), {})
    m20, m40 = make_model("pi", {"n_operators": 20}), make_model("pi", {"n_operators": 40})
    first = D._fine_base_fits(caps, design, m20, opt, 0, None)
    assert D._fine_base_fits(caps, design, make_model("pi", {"n_operators": 20}), opt, 0, None) is first
    assert len(calls) == 1
    assert D._fine_base_fits(caps, design, m40, opt, 0, None) is not first
    assert D._fine_base_fits(caps, design, m20, opt, 1, None) is not first  # another seed: other fits
    assert D._fine_base_fits(caps, D._design(caps, D.DiagnoseSettings(), False), m20, opt, 0, None) is not first
    assert len(calls) == 4


def test_refits_on_a_finer_base_are_made_once_per_effect_prefix(monkeypatch):
    """The check after the second named effect refits the first on the same finer base as the check
    after the first did: that refit (and the base step under it) is reused, not computed again."""
    from types import SimpleNamespace

    import hystfit.diagnose as D

    steps, augmented = [], []

    def fake_base_step(caps, d, fits, full_pred, sigma, settings):
        steps.append(sigma)
        return D._Base(object(), [np.zeros(c.n) for c in caps], 0.0, 0.0, (), False)

    def fake_augment(state, eff, caps, views, lin_cache, iterations, phi0=None, grid_scores=None):
        augmented.append(eff.name)
        return (state, eff.name), None

    monkeypatch.setattr(D, "_fine_base_fits", lambda *a: [object()])
    monkeypatch.setattr(D, "_base_step", fake_base_step)
    monkeypatch.setattr(D, "_augment", fake_augment)
    monkeypatch.setattr(D, "_linearize", lambda state, caps, views: (None, None))
    monkeypatch.setattr(D, "prepare_design", lambda xs, views, lin: None)
    monkeypatch.setattr(D, "scoring_design", lambda design: None)
    monkeypatch.setattr(D, "_grid_scores", lambda effects, scoring: {})
    monkeypatch.setattr(D, "_predictions", lambda state, caps, views: state)
    caps = _two_raised_cosines(400)
    design = D._design(caps, D.DiagnoseSettings(), False)
    opt = make_optimizer(optimizers.get("auto"), {})
    fine = make_model("pi", {"n_operators": 20})
    settings, gap = D.DiagnoseSettings(), SimpleNamespace(full_pred=None)
    first = D._refit_finer(caps, design, fine, opt, 0, gap, ["creep"], 0.01, settings)
    both = D._refit_finer(caps, design, fine, opt, 0, gap, ["creep", "delay"], 0.01, settings)
    assert augmented == ["creep", "delay"] and len(steps) == 1
    assert both.state[0] is first.state  # delay refitted on the creep refit of the first check
    D._refit_finer(caps, design, fine, opt, 0, gap, ["creep"], 0.02, settings)  # another floor: refitted
    D._refit_finer(caps, design, make_model("pi", {"n_operators": 40}), opt, 0, gap, ["creep"], 0.01, settings)
    assert augmented == ["creep", "delay", "creep", "creep"] and len(steps) == 3


def test_linearized_state_pickles_and_reuses_its_objective():
    """A state whose groups keep their objective (:func:`hystfit.diagnose._group_objective`) still
    pickles — a forked selection worker sends its refitted states back — and a second linearization
    reuses the objective and gives the same Jacobian."""
    import pickle

    import hystfit.diagnose as D

    caps = _two_raised_cosines(600)
    design = D._design(caps, D.DiagnoseSettings(), False)
    scale = DataScale.from_arrays([c.u for c in caps], [c.y for c in caps], [c.dt for c in caps])
    model = make_model("pi", {"n_operators": 5}).adapt(scale)
    params = model.params(scale)
    theta = np.array([p.default for p in params], float)
    g = D._Group("global", (np.nan, np.nan), model, params, theta, np.array([p.lower for p in params]),
                 np.array([p.upper for p in params]), (0, 1))
    state = D._State([g], [], (0, 0))
    views = list(design.views)
    _, lin1 = D._linearize(state, caps, views)
    obj = g.objective[1]
    _, lin2 = D._linearize(state.copy(), caps, views)
    assert state.copy().groups[0].objective[1] is obj
    assert all(np.array_equal(a, b) for a, b in zip(lin1.jac, lin2.jac))
    back = pickle.loads(pickle.dumps(state))
    assert back.groups[0].objective is None and np.array_equal(back.groups[0].theta, theta)
