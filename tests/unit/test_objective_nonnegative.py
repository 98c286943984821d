"""An exact fit of noiseless data scores 0, never a (slightly) negative MSE, and its RMSE is 0.

The PI objective's sum of squares is a quadratic form (``linear_sse_evaluator``); with a skipped
warm-up (``--warmup``) it is the form over the whole capture less the form over the skipped prefix. At the true
parameters of a noiseless capture both are rounding noise of ‖y‖² and their difference fell below
0 (the test asserts that some trials do), which printed ``RuntimeWarning: invalid value encountered in sqrt``
and gave a NaN RMSE.
"""

from __future__ import annotations

import warnings

import numpy as np

from hystfit.identify import _problem, _run
from hystfit.objective import Objective, Series
from hystfit.models.pi import PI
from hystfit.optimizers.base import OptimizeResult
from hystfit.params import DataScale
from hystfit.capture import Capture

DT = 1e-4


def _noiseless(trial: int):
    rng = np.random.default_rng(trial)
    t = np.arange(3000) * DT
    u = 30 + 25 * np.sin(2 * np.pi * 7 * t) * np.minimum(1, t * 3)
    scale = DataScale.from_arrays([u], [u], [DT])
    m = PI(6).adapt(scale)
    theta = rng.uniform(0.1, 1, (1, len(m.params(scale))))
    return m, u, m.simulator(u, DT)(theta)[0], theta


def test_exact_fit_with_a_skipped_prefix_scores_zero_not_negative():
    below = 0
    for trial in range(12):
        m, u, y, theta = _noiseless(trial)
        o = Objective(m, [Series(u, y, DT, 777)])
        below += int(o._sse(theta)[0] < 0)  # the quadratic forms' difference, before the clamp
        mse = o(theta)[0]
        assert mse >= 0.0 and mse < 1e-12
    assert below > 0, "no trial rounds below 0: the test no longer exercises the clamp"


class _Negative:
    """An optimizer whose best value rounds below 0, as a Gram-based one can."""

    polishes_itself = True
    uses_start_point = False

    def load_libraries(self) -> None:
        pass

    def minimize(self, objective, lower, upper, rng, x0=None):
        x = (lower + upper) / 2
        return OptimizeResult(x=x, fun=-3e-18, nfev=1, nit=1, success=True, status=0, message="stub")


def test_run_reports_rmse_zero_for_a_fun_rounded_below_zero():
    m, u, y, _ = _noiseless(0)
    cap = Capture(source="noiseless.csv", t=np.arange(u.size) * DT, u=u, y=y, dt=DT)
    problem = _problem([cap], PI(6), None)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = _run(problem, _Negative(), seed=0, cell=0, run=0, polish=False)
    assert rec.rmse == 0.0
