"""Standard errors of identified parameters (:func:`hystfit.identify._stderr`): honest where the data
do not determine a parameter.

A blind test's find: a stage at f_n = 1601 Hz fitted to 1 Hz drives (where it changes nothing) was
reported ± 5.8·10⁻¹⁰ Hz. The pseudo-inverse of the *unscaled* normal matrix cut its tiny direction
to zero variance. The errors now come from the Jacobi-scaled matrix, and a parameter with a share
of a direction the data do not determine (a zero column, an exact combination of others) is
"not determined": +inf, written null with ``determined: false``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from hystfit.cli import app
from hystfit.identify import _free_stderr
from hystfit.synth import write_capture


def test_a_weakly_excited_parameter_gets_a_large_error_not_a_tiny_one():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((1000, 3))
    J[:, 2] *= 1e-9  # a column a billion times smaller: determined, poorly
    A = J.T @ J
    want = np.sqrt(np.diag(np.linalg.inv(A)))
    got = _free_stderr(A, 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert got[2] > 1e6
    assert np.sqrt(np.diag(np.linalg.pinv(A)))[2] < 1e-3  # what the pseudo-inverse said


def test_undetermined_parameters_are_infinite_and_the_others_keep_their_errors():
    rng = np.random.default_rng(1)
    a, b, c = rng.standard_normal((3, 500))
    zero = _free_stderr(np.column_stack([a, b, np.zeros(500)]).T @ np.column_stack([a, b, np.zeros(500)]), 2.0)
    J2 = np.column_stack([a, b])
    np.testing.assert_allclose(zero[:2], np.sqrt(2.0 * np.diag(np.linalg.inv(J2.T @ J2))), rtol=1e-9)
    assert zero[2] == np.inf
    J = np.column_stack([a, b, a + b, c])  # the first three: one direction they cannot tell apart
    got = _free_stderr(J.T @ J, 1.0)
    assert np.isinf(got[:3]).all() and np.isfinite(got[3])


def test_params_json_and_the_report_say_not_determined(tmp_path):
    """A PI with 12 operators on a drive that reaches only the first few thresholds' span twice: the
    identified model's params.json marks the parameters it cannot determine (``determined: false``,
    ``stderr`` null) apart from those at a bound, and report.md's table says "not determined"."""
    t = np.arange(4000) / 1000.0
    u = 20.0 + 2.0 * np.sin(2 * np.pi * 5 * t)  # a small loop about 20 V: most plays never turn
    y = 0.5 * u + 0.05 * np.sin(2 * np.pi * 5 * t - 0.2) + 0.001 * np.random.default_rng(2).standard_normal(t.size)
    write_capture(tmp_path / "a20V_f5Hz.csv", t, u, y)
    out = tmp_path / "o"
    r = CliRunner().invoke(app, ["identify", str(tmp_path / "a20V_f5Hz.csv"), "--model", "pi", "--model-option",
                                 "nonnegative=false", "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    params = json.loads((out / "params.json").read_text())["conditions"][0]["parameters"]
    loose = [p for p in params if not p["determined"]]
    assert loose and all(p["stderr"] is None and p["at_bound"] is None for p in loose)
    assert all(p["determined"] for p in params if p["at_bound"])
    assert any(p["stderr"] is not None for p in params)
    assert "not determined" in (out / "report.md").read_text()
    assert "not determine" in r.output
