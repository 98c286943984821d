"""creep's population kernel (the composite interface) gives the numbers of the low-pass bank
formula it replaces, bit for bit: out = x; out += c_i·(LP_τi[x] − x) for i = 0, 1, …"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings, strategies as st

from hystfit.blocks.creep import Creep, creep_rows, lowpass_bank


def _bank_formula(x, taus, dt, c):
    p = np.array([math.exp(-dt / tau) for tau in taus])
    out = x.copy()
    if x.shape[1]:
        bank = lowpass_bank(np.ascontiguousarray(x.T), p)
        for i in range(len(taus)):
            out += c[:, i:i + 1] * bank[i].T
    return out


@settings(max_examples=100, deadline=None)
# P up to 21: whole blocks of CREEP_LANES interleaved rows, a short block, and the last rows one at a time
@given(P=st.integers(1, 21), N=st.integers(0, 200), K=st.integers(1, 4), seed=st.integers(0, 2**31))
def test_creep_rows_equals_the_bank_formula(P, N, K, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(P, N))
    taus = tuple(10.0 ** rng.uniform(-3, 1, K))
    c = rng.normal(size=(P, K))
    p = np.array([math.exp(-1e-4 / tau) for tau in taus])
    np.testing.assert_array_equal(creep_rows(x, p, c), _bank_formula(x, taus, 1e-4, c))


def test_apply_population_uses_each_rows_gains():
    rng = np.random.default_rng(0)
    block = Creep(tau_s=(0.01, 0.1, 1.0))
    x = rng.normal(size=(3, 500)).cumsum(axis=1)
    c = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.02, 0.05, 0.01]])
    out = block.apply_population(x, c, 1e-3)
    np.testing.assert_array_equal(out[0], x[0])  # no creep: the input unchanged
    np.testing.assert_array_equal(out, _bank_formula(x, block.taus, 1e-3, c))
    one = block.apply_population(x[1:2], c[1], 1e-3)  # one parameter vector for one row
    np.testing.assert_array_equal(one[0], out[1])
