"""The finite-difference steps of the least-squares polish: each parameter's from its own box.

A step h_j = rel_step·max(|θ_j|, floor_j) with one floor for every parameter, 1e-3·max|θ|, let
the largest parameter set the step of all the others: an output in nm with a sensor offset of
5e6 nm (5 mm) made every step ≥ 5e-3, a thousand times the step of a gpi envelope parameter of
≈ 0.05, and the Jacobian the polish descends along was wrong where the model is nonlinear
(``benchmarks/blind_cases.py`` section 3: gpi 587 nm with the offset against 45 nm without).
The floor is now 1e-3 of each parameter's own box width.
"""

from __future__ import annotations

import numpy as np

from hystfit.models.gpi import GPI
from hystfit.objective import Objective, Series
from hystfit.params import DataScale

# a1 a2 a3 a4 | b1 b2 b3 b4 | rho tau alpha_r y0 (as tests/unit/test_gpi.py)
TRUE = np.array([30.0, 0.05, -1.4, 30.0, 28.0, 0.055, -1.6, 31.0, 0.2, 0.1, 2.5, 1.0])
DT = 1e-3
OFFSET = 5e6


def _capture(offset: float, sigma: float = 0.02):
    t = np.arange(2000) / 2000
    u = 30 * (1 - np.cos(2 * np.pi * 5 * t)) * (0.6 + 0.4 * np.cos(2 * np.pi * t))
    m = GPI()
    y = m.simulate_one(TRUE, u, DT) + sigma * np.random.default_rng(7).standard_normal(u.size) + offset
    scale = DataScale.from_arrays([u], [y], [DT])
    ps = m.params(scale)
    return m, Objective(m, [Series(u, y, DT)]), np.array([p.lower for p in ps]), np.array([p.upper for p in ps])


def _shifted(theta: np.ndarray, offset: float) -> np.ndarray:
    out = np.array(theta, float)
    out[11] += offset
    return out


def test_steps_follow_each_parameters_box_not_the_largest_parameter():
    _, obj, lo, hi = _capture(OFFSET)
    theta = _shifted(TRUE, OFFSET)
    h, pop = Objective._fd_population(theta, 1e-6, hi, lo)
    width = hi - lo
    assert np.all(np.abs(h) <= 1e-6 * np.maximum(np.abs(theta), 1e-3 * width) * (1 + 1e-12))
    assert abs(h[1]) <= 1e-6 * 0.06  # a2 ≈ 0.05: its step is not set by the 5e6 offset (was 5e-3)
    assert np.array_equal(pop[0], theta) and np.allclose(np.diag(pop[1:] - theta), h)


def test_jacobian_does_not_depend_on_a_large_output_offset():
    """The model is y = f(θ′) + y0: a shift of the data and of y0 leaves every other column of the
    Jacobian as it was (up to the rounding of an offset of 5e6)."""
    _, obj0, lo0, hi0 = _capture(0.0)
    _, obj1, lo1, hi1 = _capture(OFFSET)
    J0 = obj0.jacobian(TRUE, upper=hi0, lower=lo0)
    J1 = obj1.jacobian(_shifted(TRUE, OFFSET), upper=hi1, lower=lo1)
    for j in range(11):  # every parameter but y0
        err = np.linalg.norm(J1[:, j] - J0[:, j]) / np.linalg.norm(J0[:, j])
        assert err < 1e-3, f"column {j}: relative difference {err:.3g}"


def test_identify_gpi_in_nm_with_a_5_mm_sensor_offset_fits_as_without(tmp_path):
    """The blind case: a capture in nm, once as measured and once with the sensor's 5e6 nm offset
    added; ``identify --model gpi`` (auto) fits both alike (before the fix: 33.5 against 587 nm)."""
    import json

    import pandas as pd
    from typer.testing import CliRunner

    from hystfit.cli import app

    runner = CliRunner()
    r = runner.invoke(app, ["synth", "capture", str(tmp_path / "rc.csv"), "-a", "60", "-f", "20", "--cycles", "3",
                            "--fs", "5000"])
    assert r.exit_code == 0, r.output
    rc = pd.read_csv(tmp_path / "rc.csv")
    rmse = {}
    for shift in (0.0, OFFSET):
        nm = rc.rename(columns={"displacement_um": "displacement_nm"})
        nm["displacement_nm"] = rc["displacement_um"] * 1000.0 + shift
        path = tmp_path / f"nm_{shift:g}.csv"
        nm.to_csv(path, index=False)
        r = runner.invoke(app, ["identify", str(path), "--model", "gpi", "--out", str(tmp_path / f"out_{shift:g}"),
                                "--no-plots", "--quiet", "--json"])
        assert r.exit_code == 0, r.output
        rmse[shift] = json.loads(r.stdout)["conditions"][0]["metrics"]["rmse_nm"]
    assert rmse[OFFSET] <= 1.1 * rmse[0.0], rmse


def test_the_report_shows_a_large_offset_to_its_standard_error():
    """A blind test's find: report.md showed y0 = 5000247.85 nm (± 1.7) as 5.000e+06."""
    from hystfit.report.identify_report import _value_text

    assert _value_text(5000247.85, 1.707) == "5000247.85"
    assert _value_text(0.2495, 1e-4) == "0.2495" and _value_text(0.3, float("nan")) == "0.3"
