"""The shortcuts of :func:`hystfit.effects.solve_coefficients` give the normal equations of the direct
form: a delay's Gram products from its whole-sample knots (:func:`hystfit.effects._knot_gram`) and an
identity-operator effect's from the design's shared block (:func:`hystfit.effects._plain_gram`), on
partly fitted captures and on repeated calls (the cached products)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from hystfit.blocks.creep import Creep
from hystfit.blocks.delay import Delay
from hystfit.blocks.drift import Drift
from hystfit.effects import CaptureView, Linearization, Placebo, prepare_design, solve_coefficients


@dataclass(frozen=True)
class _DirectDelay(Delay):
    """The delay without its knots: every candidate's Gram products from its own operator output."""

    def operator_knots(self, phi, view):
        return None


@dataclass(frozen=True)
class _DirectCreep(Creep):
    """Creep with an explicit identity operator: the generic [R | T] path."""

    def operator(self, x, view, phi):
        return x


@dataclass(frozen=True)
class _DirectDrift(Drift):
    def operator(self, x, view, phi):
        return x


def _problem(rng, lengths=(300, 351, 420, 280), k=5):
    views, yhats, jac = [], [], []
    for i, N in enumerate(lengths):
        t = np.arange(N) * 1e-4
        fit = np.ones(N, bool) if i < 3 else np.zeros(N, bool)  # the last capture held out whole
        if i == 1:
            fit[200:] = False  # a capture fitted on its first part only
        if i == 2:
            fit[150:260] = False  # held out in the middle
        y = np.sin(2 * np.pi * 40 * t - 0.05) + 0.01 * rng.standard_normal(N)
        views.append(CaptureView(t=t, dt=1e-4, y=y, fit=fit, frequency_Hz=40.0, periodic=True, index=i))
        yhats.append(np.sin(2 * np.pi * 40 * t))
        jac.append(rng.standard_normal((N, k)))
    lin = Linearization(tuple(jac), tuple(np.arange(k) for _ in lengths), np.full(k, -np.inf), np.full(k, np.inf))
    return views, yhats, lin


def _same(a, b):
    for x, y in zip(a[:3], b[:3]):
        np.testing.assert_allclose(x, y, rtol=1e-7, atol=1e-9)
    assert a[3] == pytest.approx(b[3], rel=1e-9, abs=1e-9)


def test_delay_knots_give_the_direct_normal_equations():
    rng = np.random.default_rng(4)
    views, yhats, lin = _problem(rng)
    fast, slow = Delay().configure(views, yhats), _DirectDelay().configure(views, yhats)
    design = prepare_design(yhats, views, lin)
    for samples in (0.0, 0.3, 1.0, 2.5, 2.5, 3.0, 4.75, 0.3):  # repeated values: the cached products
        phi = np.array([samples * 1e-4])
        got = solve_coefficients(fast, phi, design=design, bounded=False)
        want = solve_coefficients(slow, phi, design=prepare_design(yhats, views, lin), bounded=False)
        _same(got, want)
    assert design.knots  # the knots were used


@pytest.mark.parametrize("fast_cls, slow_cls", [(Creep, _DirectCreep), (Drift, _DirectDrift)])
def test_identity_effects_share_the_design_block(fast_cls, slow_cls):
    rng = np.random.default_rng(5)
    views, yhats, lin = _problem(rng)
    design = prepare_design(yhats, views, lin)
    fast, slow = fast_cls().configure(views, yhats), slow_cls().configure(views, yhats)
    for bounded in (False, True):
        got = solve_coefficients(fast, np.empty(0), design=design, bounded=bounded)
        want = solve_coefficients(slow, np.empty(0), design=prepare_design(yhats, views, lin), bounded=bounded)
        _same(got, want)
    assert design.plain  # the shared block was used


def test_placebos_share_the_design_block():
    rng = np.random.default_rng(6)
    views, yhats, lin = _problem(rng)
    library = [np.column_stack([np.sin(v.t * 300.0), v.t, v.t ** 2]) for v in views]
    design = prepare_design(yhats, views, lin)
    for n_shared, n_local in ((2, 0), (0, 2), (1, 1)):
        pl = Placebo.build(library, n_shared, n_local, rng)
        direct = _DirectPlacebo(columns=pl.columns, weights=pl.weights, n_shared=n_shared, n_local=n_local)
        _same(solve_coefficients(pl, np.empty(0), design=design, bounded=False),
              solve_coefficients(direct, np.empty(0), design=prepare_design(yhats, views, lin), bounded=False))


@dataclass(frozen=True)
class _DirectPlacebo(Placebo):
    def operator(self, x, view, phi):
        return x


@pytest.mark.parametrize("n_base", [8, 30])  # a design scored as it is, and one in its reduced directions
def test_compacted_columns_give_the_direct_scores(n_base):
    """A stage's scores on :func:`hystfit.effects.scoring_design` — whose captures' columns are compacted
    where base parameters leave them zero (a PI operator above a capture's amplitude) — equal, up to
    rounding, those of the same design without the compaction."""
    from hystfit.blocks.dynamics import Dynamics
    from hystfit.effects import _Design, scoring_design

    rng = np.random.default_rng(7)
    views, yhats, lin = _problem(rng, k=n_base)
    jac = []
    for c, J in enumerate(lin.jac):
        J = J.copy()
        J[:, n_base // 2 + c:] = 0.0  # parameters this capture does not reach
        jac.append(J)
    lin = Linearization(tuple(jac), lin.cols, lin.lower, lin.upper)
    design = prepare_design(yhats, views, lin)
    scoring = scoring_design(design)
    assert scoring.compact and any(z is not None for z in scoring.compact)
    plain = _Design(scoring.views, scoring.X, scoring.yy, scoring.cols, scoring.lin, fitted=scoring.fitted,
                    index=scoring.index)
    dyn = Dynamics().configure(views, yhats)
    for phi in dyn.search_grid()[::9]:
        got = solve_coefficients(dyn, phi, design=scoring, bounded=False)
        want = solve_coefficients(dyn, phi, design=plain, bounded=False)
        _same(got, want)
        assert dyn.score(phi, scoring) == pytest.approx(dyn.score(phi, plain), rel=1e-9)


def test_a_stage_grid_ranked_on_a_subsample_of_rows_scores_its_best_points_exactly(monkeypatch):
    """A stage's search grid on many fit samples is ranked on every 4th row (coarse_design); only the
    best points of that ranking are scored on every row (the rest NaN), with the exact scores, and
    the fit starts from the best scored point: here, as in most cases, the best of the whole grid,
    so the fitted φ is the one of the exact grid. A delay (knots) and creep (regressors) are not
    ranked this way."""
    import hystfit.effects as eff
    from hystfit.blocks.dynamics import Dynamics
    from hystfit.diagnose import _Ranked, _exact_grid_scores, _grid_scores
    from hystfit.effects import coarse_design, ranked_on_rows, scoring_design

    rng = np.random.default_rng(3)
    views, yhats, lin = _problem(rng, lengths=(3000, 3300, 2900, 2000), k=6)
    design = prepare_design(yhats, views, lin)
    scoring = scoring_design(design)
    dyn = Dynamics().configure(views, yhats)
    rows = sum(int(v.fit.sum()) for v in views)
    monkeypatch.setattr(eff, "COARSE_MIN_ROWS", rows + 1)
    assert not ranked_on_rows(dyn, scoring)  # too few rows: the exact grid
    exact = _grid_scores([dyn], scoring)["dynamics"]
    assert not np.isnan(exact).any()
    monkeypatch.setattr(eff, "COARSE_MIN_ROWS", rows // 2)
    assert ranked_on_rows(dyn, scoring)
    assert not ranked_on_rows(Delay().configure(views, yhats), scoring)
    assert not ranked_on_rows(Creep().configure(views, yhats), scoring)
    coarse = coarse_design(scoring)
    assert coarse is coarse_design(scoring)  # made once
    assert [int(m.sum()) for _, m, _ in coarse.fitted] == [len(range(0, int(v.fit.sum()), 4)) for v in views
                                                          if v.fit.any()]
    ranked = _grid_scores([dyn], scoring)["dynamics"]
    kept = ~np.isnan(ranked)
    assert 4 <= kept.sum() < 0.2 * ranked.size
    np.testing.assert_array_equal(ranked[kept], exact[kept])
    # the best points scored later, by the refit (one round of forked processes less): the same scores
    later = _grid_scores([dyn], scoring, exact_later=True)["dynamics"]
    assert isinstance(later, _Ranked) and later.size == ranked.size
    np.testing.assert_array_equal(np.flatnonzero(kept), later.best)
    np.testing.assert_array_equal(_exact_grid_scores(dyn, scoring, later), ranked)
    assert _exact_grid_scores(dyn, scoring, exact) is exact
    assert np.nanargmin(ranked) == np.argmin(exact)
    a = dyn.fit(yhats, views, lin, design=design, grid_scores=exact)
    b = dyn.fit(yhats, views, lin, design=design, grid_scores=ranked)
    np.testing.assert_array_equal(a.phi, b.phi)
    assert b.evaluations < a.evaluations


def test_designs_of_one_column_layout_share_their_solve_indices():
    """The index sets of the normal equations depend on the column layout only: a fit's true re-solves
    (a new design per step length) reuse those of the first design of that layout, the same solve."""
    from hystfit.effects import _INDICES, _solve_indices

    rng = np.random.default_rng(5)
    views, yhats, lin = _problem(rng)
    a = prepare_design(yhats, views, lin)
    b = prepare_design([y + 1.0 for y in yhats], views, lin)
    assert _solve_indices(a, 2, 1) is _solve_indices(b, 2, 1)
    assert _solve_indices(a, 0, 2) is not _solve_indices(a, 2, 1)
    plain = prepare_design(yhats, views)  # no base step: another layout
    assert _solve_indices(plain, 2, 1) is not _solve_indices(a, 2, 1)
    eff = Drift().configure(views, yhats)
    shared = solve_coefficients(eff, np.empty(0), design=b)
    _INDICES.clear()
    alone = solve_coefficients(eff, np.empty(0), design=prepare_design([y + 1.0 for y in yhats], views, lin))
    for x, y in zip(shared, alone):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("mask_kind", ["all", "prefix", "hole", "short_runs"])
def test_delayed_grams_from_the_fit_runs_equal_the_delayed_rows_products(mask_kind):
    """:class:`hystfit.effects._ShiftedRuns`: the Gram products of X delayed by n whole samples over the
    fit samples, from one Gram per run of fit samples plus O(n) boundary rows, equal the products of
    the delayed rows (``shift_rows``) for every mask a split makes, and delays longer than a run."""
    from hystfit.blocks.delay import shift_rows
    from hystfit.effects import _ShiftedRuns

    rng = np.random.default_rng(3)
    N, w = 400, 5
    X, y_all = rng.standard_normal((N, w)), rng.standard_normal(N)
    k = np.arange(N)
    mask = {"all": None, "prefix": k < 240, "hole": (k < 150) | (k >= 250),
            "short_runs": ((k >= 10) & (k < 13)) | (k >= 300)}[mask_kind]
    y = y_all if mask is None else y_all[mask]
    runs = _ShiftedRuns(X, mask, y)
    for n in (0, 1, 2, 5, 37, 60):
        B = shift_rows(X, n) if mask is None else shift_rows(X, n)[mask]
        B1 = shift_rows(X, n + 1) if mask is None else shift_rows(X, n + 1)[mask]
        Q, v = runs.gram(n)
        np.testing.assert_allclose(Q, B.T @ B, rtol=1e-11, atol=1e-9)
        np.testing.assert_allclose(v, B.T @ y, rtol=1e-11, atol=1e-9)
        np.testing.assert_allclose(runs.lag_one(n), B.T @ B1, rtol=1e-11, atol=1e-9)


def test_the_stage_filter_at_some_rows_equals_the_whole_filter_there():
    """:func:`hystfit.blocks.dynamics.biquad_shared_rows`: the rows asked for, bit for bit those of the
    whole filter, written at the offset into a wider array whose other entries it leaves alone."""
    from hystfit._jit import readonly
    from hystfit.blocks.dynamics import _stage_coefficients, biquad_shared, biquad_shared_rows

    rng = np.random.default_rng(11)
    x = readonly(rng.standard_normal((500, 7)).cumsum(axis=0))
    coef = _stage_coefficients(900.0, 0.07, 1e-4)
    whole = biquad_shared(x, *coef)
    for rows in (np.arange(500), np.arange(0, 500, 4), np.array([3, 4, 250, 499]), np.array([0]),
                 np.empty(0, np.int64)):
        out = np.full((rows.size + 5, 9), -7.0)
        biquad_shared_rows(x, readonly(rows, np.int64), out, 2, *coef)
        np.testing.assert_array_equal(out[2:2 + rows.size, :7], whole[rows])
        assert (out[:2] == -7.0).all() and (out[2 + rows.size:] == -7.0).all() and (out[:, 7:] == -7.0).all()


def _direct(effect, phi, design):
    """The normal equations of an effect without regressors, capture by capture as their definition
    reads (T = T_φ[X] on each capture's fit rows), solved as :func:`solve_coefficients` solves them."""
    from hystfit.effects import _scaled_solve

    n = design.lin.n
    G, b, s0 = np.zeros((n, n)), np.zeros(n), 0.0
    for c, mask, y in design.fitted:
        T = effect.operator(design.X[c], design.views[c], phi)
        T = T if mask is None else T[mask]
        cols = np.asarray(design.cols[c], int)
        G[np.ix_(cols, cols)] += T[:, 1:].T @ T[:, 1:]
        b[cols] += T[:, 1:].T @ y - T[:, 1:].T @ T[:, 0]
        s0 += float(y @ y) - 2.0 * float(T[:, 0] @ y) + float(T[:, 0] @ T[:, 0])
    x = _scaled_solve(G, b)
    return x, max(s0 - 2.0 * float(x @ b) + float(x @ G @ x), 0.0)


@pytest.mark.parametrize("batch_bytes", [None, 1])  # one batch per block, and one capture per batch
def test_captures_batched_into_one_gram_product_give_the_per_capture_normal_equations(monkeypatch, batch_bytes):
    """:func:`hystfit.effects._batches`: captures of the same block of the normal equations (two
    groups of base columns here, as two conditions fitted apart), of the same compaction and — for a
    delay — the same knots are summed in one Gram product; captures of another sample period (other
    knots) or compaction are not mixed in. The solve equals the capture-by-capture one up to rounding."""
    import hystfit.effects as eff
    from hystfit.blocks.dynamics import Dynamics
    from hystfit.effects import _batches, _solve_indices, scoring_design

    if batch_bytes is not None:
        monkeypatch.setattr(eff, "BATCH_BYTES", batch_bytes)
        monkeypatch.setattr(eff, "RETAINED_BYTES", 0)  # and no array kept: each made per call (a review's find)
    rng = np.random.default_rng(12)
    k = 6
    views, yhats, jac, cols = [], [], [], []
    for i, (N, dt) in enumerate([(300, 1e-4), (351, 1e-4), (420, 2e-4), (280, 1e-4), (333, 1e-4), (290, 1e-4)]):
        t = np.arange(N) * dt
        fit = np.ones(N, bool)
        fit[int(0.6 * N):] = False
        y = np.sin(2 * np.pi * 40 * t - 0.05) + 0.01 * rng.standard_normal(N)
        views.append(CaptureView(t=t, dt=dt, y=y, fit=fit, frequency_Hz=40.0, periodic=True, index=i))
        yhats.append(np.sin(2 * np.pi * 40 * t))
        J = rng.standard_normal((N, k))
        if i in (1, 4):
            J[:, k - 2:] = 0.0  # parameters these captures do not reach: compacted columns
        jac.append(J)
        cols.append(np.arange(k) + (k if i >= 3 else 0))  # two groups of base parameters
    lin = Linearization(tuple(jac), tuple(cols), np.full(2 * k, -np.inf), np.full(2 * k, np.inf))
    design = prepare_design(yhats, views, lin)
    for effect, des in ((Dynamics().configure(views, yhats), scoring_design(design)),
                        (Delay().configure(views, yhats), design)):
        batches = _batches(des, _solve_indices(des, 0, 0))
        assert sorted(c for bt in batches for c in bt.members) == list(range(6))
        if batch_bytes is None:
            assert len(batches) < 6 and all(len({des.cols[c].tobytes() for c in bt.members}) == 1 for bt in batches)
        else:
            assert len(batches) == 6
        plain = eff._Design(des.views, des.X, des.yy, des.cols, des.lin, fitted=des.fitted, index=des.index)
        for phi in effect.search_grid()[::7]:
            if effect.name == "dynamics" and phi[0] * 2e-4 >= 0.5:
                continue  # above the Nyquist frequency of the slower capture
            got = solve_coefficients(effect, phi, design=des, bounded=False)
            x, sse = _direct(effect, phi, plain)
            np.testing.assert_allclose(got[2], x, rtol=1e-7, atol=1e-9)
            assert got[3] == pytest.approx(sse, rel=1e-9, abs=1e-9)
            again = solve_coefficients(effect, phi, design=des, bounded=False)  # the cached products and buffers
            np.testing.assert_array_equal(again[2], got[2])
        kept = sum(a.nbytes for bt in batches for a in bt.buffers.values())
        assert kept == des.batches.get("retained", 0)
        if effect.name == "dynamics":  # the stage's filtered rows: kept within the budget, none without one
            assert (kept == 0) == (batch_bytes is not None)


def test_the_default_operator_rows_are_the_operator_at_those_rows():
    """:meth:`hystfit.effects.Effect.operator_rows` (an operator without its own): the rows asked for of
    :meth:`~hystfit.effects.Effect.operator`, into the first columns of a wider array."""
    rng = np.random.default_rng(13)
    views, yhats, lin = _problem(rng)
    d = _DirectDelay().configure(views, yhats)
    x = rng.standard_normal((300, 4))
    rows = np.array([0, 5, 6, 299])
    out = np.zeros((6, 6))
    d.operator_rows(x, views[0], np.array([2.5e-4]), rows, out, 1)
    np.testing.assert_array_equal(out[1:5, :4], d.operator(x, views[0], np.array([2.5e-4]))[rows])
    assert not out[0].any() and not out[5].any() and not out[:, 4:].any()
