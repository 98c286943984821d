"""The box-QP of variable projection by active-set enumeration (few linear parameters) against an
independent bounded least-squares solve, and its active sets (every pattern once, in order)."""

import itertools

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from hystfit.optimizers.projection import _active_sets, _enumerate_box_qp, solve_box_qp


@pytest.mark.parametrize("L", [1, 2, 3, 4])
def test_active_sets_cover_every_pattern_in_order(L):
    sets = _active_sets(L)
    assert len(sets) == 3 ** L
    for (free, fixed, at_lo), pattern in zip(sets, itertools.product((0, 1, 2), repeat=L)):
        pat = np.asarray(pattern)
        np.testing.assert_array_equal(free, np.flatnonzero(pat == 0))
        np.testing.assert_array_equal(fixed, np.flatnonzero(pat != 0))
        np.testing.assert_array_equal(at_lo, pat[fixed] == 1)


@pytest.mark.parametrize("L", [1, 2, 3, 4])
def test_enumeration_is_the_bounded_least_squares_optimum(rng, L):
    P, n = 25, L + 4
    A = rng.normal(size=(P, n, L))
    b = 3.0 * rng.normal(size=(P, n))
    lo, hi = -0.3 * np.ones(L), 0.5 * np.ones(L)
    G = np.einsum("pki,pkj->pij", A, A)
    c = np.einsum("pki,pk->pi", A, b)
    x = _enumerate_box_qp(G, c, lo, hi)
    for p in range(P):
        ref = lsq_linear(A[p], b[p], bounds=(lo, hi), method="bvls", tol=1e-14).x
        np.testing.assert_allclose(x[p], ref, atol=1e-8)
    bounded = solve_box_qp(G, c, lo, hi)  # the route variable projection takes
    np.testing.assert_allclose(bounded, x, atol=1e-8)


def _one_set_at_a_time(G, c, lo, hi):
    """The enumeration as it was written before its sets were batched: each active set solved on
    its own, the feasible one of lowest objective kept (strict <, so the first on a tie)."""
    P, L = c.shape
    best, best_f = np.full((P, L), np.nan), np.full(P, np.inf)
    tol = 1e-12 * (hi - lo)
    for free, fixed, at_lo in _active_sets(L):
        x = np.empty((P, L))
        x[:, fixed] = np.where(at_lo, lo[fixed], hi[fixed])
        feasible = np.ones(P, dtype=bool)
        if free.size:
            rhs = c[:, free] - np.einsum("pij,pj->pi", G[:, free][:, :, fixed], x[:, fixed])
            try:
                x[:, free] = np.linalg.solve(G[:, free][:, :, free], rhs[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                x[:, free] = np.stack([np.linalg.lstsq(g[np.ix_(free, free)], v, rcond=None)[0]
                                       for g, v in zip(G, rhs)])
            feasible = np.all(x[:, free] >= (lo - tol)[free], axis=1) & np.all(x[:, free] <= (hi + tol)[free], axis=1)
        x = np.clip(x, lo, hi)
        f = np.einsum("pi,pij,pj->p", x, G, x) - 2.0 * np.einsum("pi,pi->p", c, x)
        take = feasible & np.isfinite(f) & (f < best_f)
        best[take], best_f[take] = x[take], f[take]
    return best


@pytest.mark.parametrize("L", [1, 2, 3, 4])
@pytest.mark.parametrize("P", [1, 2, 7, 60])
def test_batched_sets_give_the_one_set_at_a_time_numbers_bit_for_bit(rng, L, P):
    for _ in range(40):
        A = rng.normal(size=(P, L + 2, L)) * 10.0 ** rng.uniform(-4, 4, size=(P, 1, L))
        if rng.random() < 0.3:
            A[:, :, -1] = A[:, :, 0]  # collinear columns: singular G, tied objectives
        G = np.einsum("pki,pkj->pij", A, A)
        if rng.random() < 0.7:
            G = G + 1e-12 * np.trace(G, axis1=1, axis2=2)[:, None, None] / L * np.eye(L)  # solve_box_qp's ridge
        c = np.einsum("pki,pk->pi", A, rng.normal(size=(P, L + 2)))
        lo, hi = -10.0 ** rng.uniform(-3, 2, size=L), 10.0 ** rng.uniform(-3, 2, size=L)
        with np.errstate(all="ignore"):
            got, ref = _enumerate_box_qp(G, c, lo, hi), _one_set_at_a_time(G, c, lo, hi)
        np.testing.assert_array_equal(got, ref)


def test_a_tie_between_sets_keeps_the_first_set():
    """Collinear columns: two active sets reach the same objective; the first in order wins."""
    G = np.array([[[0.03128779329330486, 0.06257558658660972], [0.06257558658660972, 0.12515117317321944]]])
    c = np.array([[0.0040180713719820335, 0.008036142743964067]])
    lo, hi = np.array([-0.01586349182520126, -0.17499565007751597]), np.array([1.0630498131442649e-02, 400.43])
    np.testing.assert_array_equal(_enumerate_box_qp(G, c, lo, hi), _one_set_at_a_time(G, c, lo, hi))


def test_many_candidates_are_enumerated_in_blocks(rng, monkeypatch):
    import hystfit.optimizers.projection as projection

    A = rng.normal(size=(50, 5, 3))
    G, c = np.einsum("pki,pkj->pij", A, A), np.einsum("pki,pk->pi", A, 3.0 * rng.normal(size=(50, 5)))
    lo, hi = -0.2 * np.ones(3), 0.3 * np.ones(3)
    whole = _enumerate_box_qp(G, c, lo, hi)
    monkeypatch.setattr(projection, "ENUMERATE_BLOCK_ROWS", 27 * 8)  # blocks of 8 candidates
    np.testing.assert_array_equal(_enumerate_box_qp(G, c, lo, hi), whole)


def test_a_zero_curvature_parameter_is_solved_as_lapack_does():
    """A free parameter with G_ii = 0 (no ridge): the singular 1 × 1 system by least squares, as before."""
    G = np.array([[[0.0, 0.0], [0.0, 2.0]], [[1.0, 0.5], [0.5, 2.0]]])
    c = np.array([[0.3, -1.0], [0.2, 5.0]])
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    with np.errstate(all="ignore"):
        np.testing.assert_array_equal(_enumerate_box_qp(G, c, lo, hi), _one_set_at_a_time(G, c, lo, hi))


@pytest.mark.parametrize("P", [1, 2, 9, 60])
def test_two_parameters_compiled_give_the_numpy_enumeration_bit_for_bit(rng, P):
    """gpi's and pi2's (ρ, y0): the compiled enumeration against the batched numpy one, ties included."""
    from hystfit.optimizers.projection import _enumerate_two

    for _ in range(300):
        A = rng.normal(size=(P, 4, 2)) * 10.0 ** rng.uniform(-4, 4, size=(P, 1, 2))
        if rng.random() < 0.3:
            A[:, :, 1] = A[:, :, 0] * rng.choice([1.0, -2.0])  # collinear columns: tied objectives
        G = np.einsum("pki,pkj->pij", A, A)
        G = G + 1e-12 * np.trace(G, axis1=1, axis2=2)[:, None, None] / 2 * np.eye(2)  # solve_box_qp's ridge
        c = np.einsum("pki,pk->pi", A, rng.normal(size=(P, 4)))
        lo, hi = -10.0 ** rng.uniform(-3, 2, size=2), 10.0 ** rng.uniform(-3, 2, size=2)
        if rng.random() < 0.3:
            lo[0] = 0.0
        x_free = np.linalg.solve(G, c[:, :, None])[:, :, 0]
        np.testing.assert_array_equal(_enumerate_two(G, c, x_free, lo, hi), _enumerate_box_qp(G, c, lo, hi))
