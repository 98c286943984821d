"""``Linearization.reduced``: the directions of the base step that the fit samples determine."""

from __future__ import annotations

import numpy as np

from hystfit.effects import CaptureView, Linearization


def _views(rng, sizes):
    views = []
    for i, n in enumerate(sizes):
        fit = np.ones(n, bool)
        fit[int(0.7 * n):] = False  # the held-out tail is not looked at
        views.append(CaptureView(np.arange(n) * 1e-3, 1e-3, rng.standard_normal(n), fit, 10.0, True, i))
    return views


def test_reduced_keeps_the_column_space_and_the_unbounded_fit():
    rng = np.random.default_rng(3)
    views = _views(rng, (400, 300))
    base = rng.standard_normal((700, 12))
    J_all = np.hstack([base, base[:, :6] @ rng.standard_normal((6, 8))])  # 20 columns, rank 12
    J_all *= np.geomspace(1e-3, 1e3, 20)  # badly scaled columns: the reduction scales them first
    jac = (J_all[:400], J_all[400:])
    cols = (np.arange(20), np.arange(20))
    lin = Linearization(jac, cols, np.zeros(20), np.full(20, np.inf))
    red = lin.reduced(views)
    assert red.n == 12 and np.all(np.isinf(red.lower)) and np.all(np.isinf(red.upper))
    fit_rows = [np.flatnonzero(v.fit) for v in views]
    full = np.vstack([J[r] for J, r in zip(jac, fit_rows)])
    small = np.vstack([J[r] for J, r in zip(red.jac, fit_rows)])
    y = np.concatenate([v.y[r] for v, r in zip(views, fit_rows)])

    def sse(A):
        x, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sum((y - A @ x) ** 2))

    assert abs(sse(small) - sse(full)) <= 1e-8 * sse(full)
    # dropping a determined direction would show: one column fewer is worse
    assert sse(small[:, 1:]) > sse(full) * (1 + 1e-6)


def test_reduced_ignores_held_out_samples():
    """A column that only moves held-out samples is not a direction the fit samples determine."""
    rng = np.random.default_rng(4)
    views = _views(rng, (500,))
    J = rng.standard_normal((500, 5))
    J[:, 4] = 0.0
    J[400:, 4] = 1.0  # only after the fit part (which ends at 350)
    lin = Linearization((J,), (np.arange(5),), np.zeros(5), np.full(5, np.inf))
    assert lin.reduced(views).n == 4
