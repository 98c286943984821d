"""The population delay of composites: rows sharing a delay (a finite-difference Jacobian's
population has at most two) take slices, with the numbers of the per-row gather, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystfit.blocks.delay import delay_population


def _gather(x, delay_s, dt):
    """The per-row form: (1 − f)·x[k − n] + f·x[k − n − 1], indices clamped at 0."""
    P, N = x.shape
    d = np.maximum(np.asarray(delay_s, float) / dt, 0.0)
    n = np.floor(d).astype(np.int64)
    f = d - n
    idx = np.arange(N)[None, :] - n[:, None]
    x0 = np.take_along_axis(x, np.clip(idx, 0, N - 1), axis=1)
    x1 = np.take_along_axis(x, np.clip(idx - 1, 0, N - 1), axis=1)
    return (1.0 - f)[:, None] * x0 + f[:, None] * x1


@settings(max_examples=200, deadline=None)
@given(P=st.integers(2, 6), N=st.integers(1, 60), samples=st.floats(0.0, 80.0), seed=st.integers(0, 2**31))
def test_one_delay_for_every_row_equals_the_gather(P, N, samples, seed):
    x = np.random.default_rng(seed).normal(size=(P, N))
    out = delay_population(x, np.full(P, samples * 1e-4), 1e-4)
    np.testing.assert_array_equal(out, _gather(x, np.full(P, samples * 1e-4), 1e-4))


@settings(max_examples=200, deadline=None)
@given(P=st.integers(2, 8), N=st.integers(1, 60), seed=st.integers(0, 2**31),
       delays=st.lists(st.floats(0.0, 80.0), min_size=1, max_size=6))
def test_a_few_distinct_delays_equal_the_gather(P, N, seed, delays):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(P, N))
    per_row = np.asarray(delays)[rng.integers(0, len(delays), P)] * 1e-4
    np.testing.assert_array_equal(delay_population(x, per_row, 1e-4), _gather(x, per_row, 1e-4))


def test_rows_with_different_delays_and_a_non_finite_delay():
    x = np.random.default_rng(1).normal(size=(3, 50))
    delays = np.array([0.0, 2.5e-4, 7e-4])
    np.testing.assert_array_equal(delay_population(x, delays, 1e-4), _gather(x, delays, 1e-4))
    out = delay_population(x, np.array([np.nan, np.nan, np.nan]), 1e-4)
    assert np.all(np.isnan(out))  # a non-finite delay is a failed candidate, never a delay of 0


@pytest.mark.parametrize("samples", [0.0, 3.0, 3.25, 200.0])
def test_non_finite_samples_pass_through_the_row_kernel_as_through_the_gather(samples):
    """The rows of a shared delay take one pass of a kernel (``_shift_rows_into``): the products and
    the sum of the gather per sample, so also an infinite sample gives what the gather gives (with
    f = 0, 1·inf + 0·inf = NaN, not inf) — a finite-difference population of a Jacobian, one row's
    delay perturbed."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(9, 40))
    x[2, 5], x[4, 0], x[6, 11] = np.inf, -np.inf, np.nan
    delays = np.full(9, samples * 1e-4)
    delays[7] *= 1.0 + 1e-6
    with np.errstate(invalid="ignore"):  # 0·inf, on purpose
        expected = _gather(x, delays, 1e-4)
        np.testing.assert_array_equal(delay_population(x, delays, 1e-4), expected)
        xt = np.asfortranarray(x)  # any memory layout
        np.testing.assert_array_equal(delay_population(xt, delays, 1e-4), expected)
