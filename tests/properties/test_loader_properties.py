"""Hypothesis properties of the capture loader, the idle trim and tidy()."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystfit.conditions import tidy
from hystfit.io import idle_samples, load_capture

# (header name, factor from SI to the written unit, output unit)
TIME_NAMES = [("t", 1.0), ("time", 1.0), ("time_s", 1.0), ("Time (s)", 1.0), ("time_ms", 1e3), ("TIME [us]", 1e6),
              ("seconds", 1.0)]
INPUT_NAMES = [("u", 1.0), ("voltage", 1.0), ("voltage_V", 1.0), ("Voltage (mV)", 1e3), ("Vin", 1.0),
               ("drive [kV]", 1e-3), ("u_V", 1.0), ("COMMAND", 1.0)]
OUTPUT_NAMES = [("y", "um"), ("displacement_um", "um"), ("pos [nm]", "nm"), ("Displacement (mm)", "mm"), ("d", "um"),
                ("x_µm", "um"), ("position_m", "m")]


def _round12(a: np.ndarray) -> np.ndarray:
    """Values exactly representable by the '%.12g' text the test writes."""
    return np.array([float(f"{v:.12g}") for v in a])


@st.composite
def captures(draw):
    fs = draw(st.floats(100.0, 20000.0))
    spc = draw(st.floats(16.0, 150.0))  # samples per cycle
    cycles = draw(st.floats(2.5, 6.0))
    f = fs / spc
    amp = draw(st.floats(0.5, 300.0))
    offset = draw(st.floats(-50.0, 50.0))
    kind = draw(st.sampled_from(["sine", "raised_cosine"]))
    phase = draw(st.floats(0.0, 2 * math.pi))
    idle = draw(st.integers(0, 40))
    continuous = draw(st.booleans())  # idle level = first excitation value, or a jump out of it
    n_exc = int(cycles * spc)
    k = np.arange(n_exc)
    if kind == "sine":
        s = offset + amp * np.sin(2 * np.pi * k / spc + phase)
    else:
        s = offset + amp / 2 * (1 - np.cos(2 * np.pi * k / spc))
    level = s[0] if continuous else offset
    u = _round12(np.r_[np.full(idle, level), s])
    t0 = draw(st.floats(0.0, 100.0))
    t = t0 + np.arange(u.size) / fs
    seed = draw(st.integers(0, 2**16))
    y = _round12(0.05 * u + 0.01 * np.random.default_rng(seed).standard_normal(u.size))
    names = (draw(st.sampled_from(TIME_NAMES)), draw(st.sampled_from(INPUT_NAMES)), draw(st.sampled_from(OUTPUT_NAMES)))
    order = draw(st.permutations([0, 1, 2]))
    fmt = draw(st.sampled_from([",", ";", "\t", " ", "parquet"]))
    return dict(fs=fs, f=f, t=t, u=u, y=y, idle=idle, names=names, order=order, fmt=fmt)


def _write(cap: dict, folder: Path) -> Path:
    (tname, tfac), (uname, ufac), (yname, _) = cap["names"]
    cols = [(tname, cap["t"] * tfac), (uname, cap["u"] * ufac), (yname, cap["y"])]
    cols = [cols[i] for i in cap["order"]]
    if cap["fmt"] == "parquet":
        path = folder / "cap.parquet"
        pd.DataFrame({n: v for n, v in cols}).to_parquet(path)
        return path
    sep = cap["fmt"]
    if sep == " ":
        cols = [(n.replace(" ", "_"), v) for n, v in cols]  # whitespace-delimited headers cannot hold blanks
    lines = [sep.join(n for n, _ in cols)]
    lines += [sep.join(f"{v:.12g}" for v in row) for row in zip(*(v for _, v in cols))]
    path = folder / "cap.txt"
    path.write_text("# generated\n" + "\n".join(lines) + "\n", encoding="utf-8")
    return path


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(captures())
def test_random_captures_round_trip(cap):
    with tempfile.TemporaryDirectory() as d:
        c = load_capture(_write(cap, Path(d)))
    u, y, t = cap["u"], cap["y"], cap["t"]
    k = c.trimmed_samples
    scale = float(np.abs(u).max())
    np.testing.assert_allclose(c.u, u[k:], rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(c.y, y[k:], rtol=1e-9, atol=1e-12)
    assert c.y_unit == cap["names"][2][1]
    dt = 1 / cap["fs"]
    assert c.dt == np.float64(c.dt) and abs(c.dt - dt) <= 1e-6 * dt
    np.testing.assert_allclose(c.t, t[k:] - t[k], rtol=0, atol=1e-3 * dt)
    # trimming never removes excitation: every removed sample sits in the idle band of u[0]
    tol = max(1e-9, 1e-3 * float(np.ptp(u)))
    assert np.all(np.abs(u[:k] - u[0]) <= tol)
    if k > cap["idle"]:  # only samples equal to the idle level may go beyond the idle segment
        np.testing.assert_allclose(u[cap["idle"]:k + 1], u[0], rtol=0, atol=1e-9 * max(1.0, scale))
    if cap["idle"] >= 2:
        assert k >= cap["idle"] - 1
    assert c.amplitude_V == tidy(np.ptp(c.u))
    assert abs(c.frequency_Hz - cap["f"]) <= 0.06 * cap["f"]
    assert c.condition_source == "detected"


@settings(max_examples=50, deadline=None)
@given(st.floats(-100, 100), st.integers(0, 30),
       st.lists(st.floats(-100, 100, allow_nan=False), min_size=1, max_size=40))
def test_idle_trim_keeps_every_sample_outside_the_band(level, idle, rest):
    u = np.r_[np.full(idle, level), rest]
    k = idle_samples(u)
    tol = max(1e-9, 1e-3 * float(np.ptp(u)))
    assert 0 <= k < u.size
    assert np.all(np.abs(u[:k] - u[0]) <= tol)
    if idle >= 1 and abs(rest[0] - level) > tol:
        assert k == idle - 1  # keep exactly one idle sample before the jump


@settings(max_examples=50, deadline=None)
@given(st.floats(1e-6, 1e9) | st.floats(-1e9, -1e-6))
def test_tidy_idempotent_and_close(x):
    v = tidy(x)
    assert tidy(v) == v
    assert abs(v - x) <= 0.05 * abs(x)
