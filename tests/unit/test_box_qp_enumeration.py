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
