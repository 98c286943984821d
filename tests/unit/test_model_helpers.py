"""The shared homes of models/ and blocks/: structure round trips, the one-rate capture check,
the separable helpers, the inverse from rest, the kernel helpers (block split, sums, gPI)."""

import dataclasses

import numpy as np
import pytest

from hystfit.blocks.base import captures_at_one_rate
from hystfit.params import structure_kwargs, structure_of
from hystfit.blocks.lti import LinearPartFields, Lti
from hystfit.capture import Capture
from hystfit.errors import ConfigError
from hystfit.models._kernels import candidate_block, play_matrix, play_matrix_from, store_sums
from hystfit.models.dahl import Dahl
from hystfit.models.fp import FractionalZener
from hystfit.models.gpi import gpi_operators, gpi_population
from hystfit.models.hammerstein import Hammerstein
from hystfit.models.inverse import invert_from_rest
from hystfit.models.lugre import LuGre
from hystfit.models.nt import NT
from hystfit.models.pi import PI, PlayOperators
from hystfit.models.separable import linear_in_all, scaled_response
from hystfit._jit import njit


def _capture(name, dt, n=64):
    t = np.arange(n) * dt
    u = np.sin(2 * np.pi * t / (n * dt))
    return Capture(name, t, u, 0.5 * u, dt, amplitude_V=1.0, frequency_Hz=1.0 / (n * dt))


def test_captures_at_one_rate():
    a, b = _capture("a", 1e-4), _capture("b", 1e-4)
    assert captures_at_one_rate([a, b], "x") == [a, b]
    with pytest.raises(ConfigError, match=r"^x: the captures have different sample periods .* one rate, or not$"):
        captures_at_one_rate([a, _capture("c", 2e-4)], "x", ", or not")


def test_structure_round_trip_and_unknown_keys():
    m = PI(5, thresholds_V=(0.0, 1.0, 2.0, 3.0, 4.0))
    data = structure_of(m)
    assert data["thresholds_V"] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert PI(**structure_kwargs(PI, data, lambda unknown, names: "")) == m
    with pytest.raises(ConfigError, match="bad: \\['zz'\\]"):
        structure_kwargs(PI, {"zz": 1}, lambda unknown, names: f"bad: {sorted(unknown)}")


def _names(cls):
    return [f.name for f in dataclasses.fields(cls)]


def test_shared_field_definitions():
    names = _names(PlayOperators)
    assert _names(PI) == names + ["history"]  # its own: the play states before the first sample
    linear = _names(LinearPartFields)
    assert _names(Lti) == linear + ["method"]
    assert _names(Hammerstein) == names + linear + ["linear_method"]
    with pytest.raises(ValueError, match=r"needs 4 A, 2 B and 2 C entries \(got 1, 2, 2\)"):
        LinearPartFields(order=2, A=(1.0,), B=(1.0, 1.0), C=(1.0, 1.0), dt_s=1e-4).check_linear_part()
    with pytest.raises(ConfigError, match="hammerstein: the linear part has non-finite entries"):
        Hammerstein(order=1, A=(np.nan,), B=(1.0,), C=(1.0,), dt_s=1e-4)


@pytest.mark.parametrize("cls, without", [(LuGre, 7), (NT, 4), (FractionalZener, 4)])
def test_optional_offset(cls, without):
    assert cls(offset=False).n_params == without and cls(offset=True).n_params == without + 1
    with pytest.raises(ConfigError, match=f"{cls.name}: offset must be true or false"):
        cls(offset=1)


def test_linear_in_all_and_scaled_response():
    u = np.linspace(-1, 1, 50)
    sep = linear_in_all(lambda u, dt: np.column_stack([u, np.ones_like(u)]), 2)
    assert sep.linear == (0, 1) and sep.nonlinear == ()
    assert sep.basis_factory(u, 1.0)(np.empty((1, 0))).shape == (1, 50, 2)

    def response(u, dt):
        return lambda th: np.tanh(np.outer(u, np.atleast_2d(th)[:, 0]))  # (N, P)

    def moments(u, dt, y):
        def m(th):
            z = response(u, dt)(th)
            return (z * z).sum(axis=0), z.sum(axis=0), y @ z
        return m

    y = 2.0 * np.tanh(3.0 * u) + 0.5
    th = np.array([[3.0], [1.0]])
    for sep in (scaled_response((0, 2), (1,), response), scaled_response((0, 2), (1,), response, moments)):
        B = sep.basis_factory(u, 1.0)(th)
        G, c, yy = sep.gram_factory(u, 1.0, y)(th)
        np.testing.assert_allclose(G, np.einsum("pnl,pnm->plm", B, B), rtol=1e-12)
        np.testing.assert_allclose(c, np.einsum("pnl,n->pl", B, y), rtol=1e-12)
        assert yy == pytest.approx(y @ y)
        np.testing.assert_allclose(np.linalg.solve(G[0], c[0]), [2.0, 0.5], rtol=1e-10)
    assert scaled_response((0, 2), (1,), response, moments).gram_fused


def test_invert_from_rest():
    m = Dahl()
    th = np.array([1.0, 2.0, 0.5, 1.0, 0.1])
    assert invert_from_rest(m, th, np.empty(0), 1e-3, th[0], th[4]).size == 0
    u = 0.8 * np.sin(np.linspace(0, 4 * np.pi, 200))
    y = m.simulate_one(th, u, 1e-3)
    back = invert_from_rest(m, th, y, 1e-3, th[0], th[4], u_range=(-2.0, 2.0))
    np.testing.assert_allclose(m.simulate_one(th, back, 1e-3), y, atol=1e-3)


@njit(cache=True)
def _blocks(P, n_blocks):
    out = np.empty((n_blocks, 2), dtype=np.int64)
    for b in range(n_blocks):
        out[b, 0], out[b, 1] = candidate_block(b, n_blocks, P)
    return out


@njit(cache=True)
def _store(P, p0):
    out = np.zeros((P, 3))
    a = np.arange(2.0)
    store_sums(out, p0, (a, a + 10.0, a + 20.0), 2)
    return out


def test_kernel_helpers():
    assert _blocks(10, 3).tolist() == [[0, 4], [4, 8], [8, 10]]
    assert _blocks(2, 4).tolist() == [[0, 1], [1, 2], [2, 2], [3, 2]]
    out = _store(4, 1)
    assert out[1:3].tolist() == [[0.0, 10.0, 0.0], [1.0, 11.0, 0.0]] and not out[0].any() and not out[3].any()
    u = np.array([0.0, 1.0, -0.5, 2.0])
    r = np.array([0.0, 0.3, 1.0])
    np.testing.assert_array_equal(play_matrix(u, r), play_matrix_from(u, r, np.zeros(3)))


def test_gpi_operators_and_population():
    alpha, tau = np.array([0.5, 2.0]), np.array([0.1, 0.0])
    r, q = gpi_operators(alpha, tau, 3, 0, 2)
    np.testing.assert_allclose(r, [[0, 0], [0.5, 2.0], [1.0, 4.0]])
    np.testing.assert_allclose(q, np.exp(-tau * r))
    # the recurrence written out in Python
    u = np.array([0.0, 1.0, 3.0, -2.0, 0.5])
    a = [np.array([1.0, 2.0]), np.array([0.5, 0.2]), np.array([0.1, 0.0]), np.array([0.0, 0.3])]
    b = [np.array([1.5, 1.0]), np.array([0.4, 0.6]), np.array([0.0, -0.1]), np.array([0.2, 0.0])]
    z = gpi_population(u, *a, *b, tau, alpha, 3)
    for p in range(2):
        s = np.zeros(3)
        for k, uk in enumerate(u):
            gl = a[0][p] * np.tanh(a[1][p] * uk + a[2][p]) + a[3][p]
            gr = b[0][p] * np.tanh(b[1][p] * uk + b[2][p]) + b[3][p]
            s = np.maximum(gl - r[:, p], np.minimum(gr + r[:, p], s))
            assert z[k, p] == pytest.approx(q[:, p] @ s, rel=1e-12, abs=1e-14)
