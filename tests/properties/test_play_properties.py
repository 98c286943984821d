"""Hypothesis properties of the play operator and the PI model (rate independence, wiping-out)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hystfit.models._kernels import play_matrix

inputs = st.lists(st.floats(-100, 100, allow_nan=False), min_size=2, max_size=60).map(np.array)
thresholds = st.lists(st.floats(0, 50, allow_nan=False), min_size=1, max_size=6).map(lambda r: np.array(sorted(r)))


@settings(max_examples=60, deadline=None)
@given(inputs, thresholds, st.integers(1, 6))
def test_rate_independence(u, r, k):
    """Resampling the same input path (k points per segment) leaves the output at the original samples unchanged."""
    n = len(u)
    fine = np.interp(np.linspace(0, n - 1, (n - 1) * k + 1), np.arange(n), u)
    np.testing.assert_allclose(play_matrix(fine, r)[::k], play_matrix(u, r), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(inputs, inputs, thresholds)
def test_wiping_out(h1, h2, r):
    """After the input sweeps to a new maximum and then a new minimum beyond all earlier values
    (by more than 2r), the output no longer depends on the earlier history."""
    lo = min(h1.min(), h2.min()) - 2 * r.max() - 1
    hi = max(h1.max(), h2.max()) + 2 * r.max() + 1
    tail = np.array([hi, lo, 0.3 * hi, 0.1 * lo, 0.0])
    a = play_matrix(np.r_[h1, tail], r)[-len(tail):]
    b = play_matrix(np.r_[h2, tail], r)[-len(tail):]
    np.testing.assert_allclose(a, b, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(inputs, thresholds)
def test_output_stays_within_band(u, r):
    F = play_matrix(u, r)
    assert np.all(F >= u[:, None] - r[None, :] - 1e-12)
    assert np.all(F <= u[:, None] + r[None, :] + 1e-12)
