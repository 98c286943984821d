"""Hypothesis properties of the play operator and the PI model (rate independence, wiping-out)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hystfit.models import _kernels
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


@settings(max_examples=80, deadline=None)
@given(inputs, thresholds, st.lists(st.floats(-100, 100, allow_nan=False), min_size=6, max_size=6))
def test_numpy_scan_is_bit_identical_to_the_recurrence(u, r, s0):
    """The two routes of play_matrix_from (numpy prefix scan of clamps, numba recurrence) agree bit for bit,
    from any initial state (a wrong composition order or bound would differ at some sample)."""
    state0 = np.array(s0[: len(r)])
    scan = _kernels._play_scan(u.astype(float), r, state0)
    np.testing.assert_array_equal(scan, _kernels._play_recurrence(u.astype(float), r, state0))


def test_play_matrix_routes_small_calls_to_numpy_until_numba_is_loaded(monkeypatch):
    """A small call in a process without numba takes the numpy route; a large one, or any call once
    the numpy budget is spent, takes the recurrence; both give the same outputs."""
    u = np.sin(np.linspace(0, 20, 2001)) * 5
    r = np.linspace(0, 4, 10)
    calls = []
    monkeypatch.setattr(_kernels, "numba_loaded", lambda: False)
    monkeypatch.setattr(_kernels, "_numpy_play_done", 0)
    real_scan, real_rec = _kernels._play_scan, _kernels._play_recurrence
    monkeypatch.setattr(_kernels, "_play_scan", lambda *a: calls.append("scan") or real_scan(*a))
    monkeypatch.setattr(_kernels, "_play_recurrence", lambda *a: calls.append("numba") or real_rec(*a))
    small = play_matrix(u, r)
    monkeypatch.setattr(_kernels, "NUMPY_PLAY_MAX", 100)
    large = play_matrix(u, r)
    monkeypatch.setattr(_kernels, "NUMPY_PLAY_MAX", 10**9)
    monkeypatch.setattr(_kernels, "_numpy_play_done", _kernels.NUMPY_PLAY_BUDGET)
    spent = play_matrix(u, r)
    assert calls == ["scan", "numba", "numba"]
    np.testing.assert_array_equal(small, large)
    np.testing.assert_array_equal(small, spent)
