"""Operating conditions: tidy values, detection, grouping, labels and the look-up table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hystfit.capture import Capture
from hystfit.conditions import (
    LookupTable,
    condition_label,
    count_cycles,
    detect_condition,
    group_by_condition,
    tidy,
)
from hystfit.errors import ConfigError


@pytest.mark.parametrize("x, expected", [
    (297.8, 300.0), (39.7, 40.0), (10.04, 10.0), (1.004, 1.0), (0.4987, 0.5), (0.0, 0.0),
    (150.0, 150.0), (1.5, 1.5), (-39.7, -40.0), (12345.0, 12000.0), (0.0123, 0.012),
])
def test_tidy(x, expected):
    assert tidy(x) == expected


def test_tidy_sig_and_nonfinite():
    assert tidy(297.8, sig=3) == 298.0
    assert math.isnan(tidy(float("nan")))
    assert tidy(float("inf")) == float("inf")


def _signal(kind, amp, f, fs, cycles, phase=0.0):
    t = np.arange(int(round(cycles * fs / f))) / fs
    if kind == "sine":
        return amp / 2 * np.sin(2 * np.pi * f * t + phase)
    if kind == "raised_cosine":
        return amp / 2 * (1 - np.cos(2 * np.pi * f * t))
    frac = np.mod(f * t + phase / (2 * np.pi), 1.0)
    return amp * (1 - np.abs(1 - 2 * frac))  # triangle 0 → amp → 0


@pytest.mark.parametrize("kind", ["sine", "raised_cosine", "triangle"])
@pytest.mark.parametrize("amp, f, fs, cycles", [
    (300.0, 1.0, 5000.0, 6.7), (40.0, 10.0, 10000.0, 5.0), (20.0, 80.0, 10000.0, 5.0),
    (60.0, 37.0, 2000.0, 3.3), (120.0, 0.5, 200.0, 2.0), (5.0, 250.0, 50000.0, 10.0), (1.5, 1.5, 1000.0, 2.5),
])
def test_detect_condition(kind, amp, f, fs, cycles):
    u = _signal(kind, amp, f, fs, cycles, phase=0.7)
    a, freq = detect_condition(u, 1 / fs)
    assert freq == tidy(f)
    assert a == tidy(np.ptp(u))
    assert a == pytest.approx(amp, rel=0.05)


def test_detect_condition_with_offset_noise_and_short_record():
    rng = np.random.default_rng(3)
    fs, f = 10000.0, 23.0
    t = np.arange(int(1.2 * fs / f)) / fs  # 1.2 cycles: the sine fit still finds the frequency
    u = 50 + 20 * np.sin(2 * np.pi * f * t) + 0.05 * rng.standard_normal(t.size)
    a, freq = detect_condition(u, 1 / fs)
    assert freq == 23.0 and a == pytest.approx(40.0, abs=1.0)


def test_detect_condition_broadband_returns_a_peak():
    rng = np.random.default_rng(7)
    u = np.repeat(rng.integers(0, 2, 1000), 4) * 60.0
    a, f = detect_condition(u, 1e-4)
    assert a == 60.0 and 0 < f < 5000


def test_detect_condition_rejects_bad_arguments():
    with pytest.raises(ConfigError):
        detect_condition(np.zeros(3), 1e-3)
    with pytest.raises(ConfigError):
        detect_condition(np.arange(10.0), 0.0)


def test_count_cycles():
    assert count_cycles(np.zeros(5000), 2e-4, 1.0) == pytest.approx(1.0)
    assert count_cycles(np.zeros(33716), 2e-4, 1.0) == pytest.approx(6.7432)


def _cap(name, a, f):
    z = np.zeros(4)
    return Capture(source=name, t=z, u=z, y=z, dt=1e-3, amplitude_V=a, frequency_Hz=f)


def test_group_by_condition_orders_keys_and_pools():
    caps = [_cap("a", 40, 20), _cap("b", 20, 80), _cap("c", 40, 10), _cap("d", 40, 20), _cap("e", 20, 10)]
    groups = group_by_condition(caps)
    assert list(groups) == [(20.0, 10.0), (20.0, 80.0), (40.0, 10.0), (40.0, 20.0)]
    assert [c.source for c in groups[(40.0, 20.0)]] == ["a", "d"]
    assert group_by_condition([]) == {}


@pytest.mark.parametrize("key, label", [
    ((40, 10), "40V_10Hz"), ((300.0, 1.5), "300V_1.5Hz"), ((0.5, 0.25), "0.5V_0.25Hz"),
    ((37.5, 1000.0), "37.5V_1000Hz"),
])
def test_condition_label(key, label):
    assert condition_label(key) == label


# ----------------------------------------------------------------------------------------------
# LookupTable
# ----------------------------------------------------------------------------------------------

AMPS = (20.0, 40.0, 60.0)
FREQS = (10.0, 20.0, 40.0)


def _plane(a, f):
    """A function linear in amplitude and in log10(frequency): bilinear blending reproduces it."""
    return np.array([1.0 + 0.5 * a, 3.0 * math.log10(f), a * math.log10(f)])


@pytest.fixture
def grid_table():
    keys = [(a, f) for a in AMPS for f in FREQS]
    return LookupTable(keys, [_plane(a, f) for a, f in keys])


def test_exact_hit(grid_table):
    v, used = grid_table.interpolate((40.0, 20.0))
    assert used == [((40.0, 20.0), 1.0)]
    np.testing.assert_allclose(v, _plane(40, 20))
    key, v = grid_table.nearest((40.0, 20.0))
    assert key == (40.0, 20.0)


def test_bilinear_inside_a_cell(grid_table):
    v, used = grid_table.interpolate((30.0, 14.0))
    assert {k for k, _ in used} == {(20.0, 10.0), (20.0, 20.0), (40.0, 10.0), (40.0, 20.0)}
    assert sum(w for _, w in used) == pytest.approx(1.0)
    np.testing.assert_allclose(v, _plane(30.0, 14.0), rtol=1e-12)
    weights = dict(used)
    wf = math.log10(14 / 10) / math.log10(2)
    assert weights[(20.0, 10.0)] == pytest.approx(0.5 * (1 - wf))


def test_on_a_grid_line_blends_two_cells(grid_table):
    v, used = grid_table.interpolate((60.0, 30.0))
    assert {k for k, _ in used} == {(60.0, 20.0), (60.0, 40.0)}
    np.testing.assert_allclose(v, _plane(60.0, 30.0), rtol=1e-12)


def test_outside_falls_back_to_nearest(grid_table):
    v, used = grid_table.interpolate((70.0, 20.0))
    assert used == [((60.0, 20.0), 1.0)]
    np.testing.assert_allclose(v, _plane(60, 20))
    v, used = grid_table.interpolate((30.0, 100.0))
    assert len(used) == 1 and used[0][1] == 1.0 and used[0][0][1] == 40.0


def test_incomplete_grid_falls_back_to_nearest():
    keys = [(20.0, 10.0), (20.0, 20.0), (40.0, 10.0)]  # (40, 20) missing
    table = LookupTable(keys, [np.array([i], float) for i in range(3)])
    v, used = table.interpolate((35.0, 12.0))
    assert used == [((40.0, 10.0), 1.0)] and v.tolist() == [2.0]


def test_nearest_uses_log_frequency_and_relative_amplitude():
    table = LookupTable([(20.0, 10.0), (60.0, 10.0), (20.0, 100.0)], [np.zeros(1), np.ones(1), 2 * np.ones(1)])
    # the log-frequency midpoint of 10 and 100 Hz is 31.6 Hz
    assert table.nearest((20.0, 29.0))[0] == (20.0, 10.0)
    assert table.nearest((20.0, 33.0))[0] == (20.0, 100.0)
    # amplitude distances are relative to Amax = 60 V
    assert table.nearest((35.0, 30.0))[0] == (20.0, 10.0)
    assert table.nearest((45.0, 10.0))[0] == (60.0, 10.0)


def test_table_validation():
    with pytest.raises(ConfigError):
        LookupTable([], [])
    with pytest.raises(ConfigError):
        LookupTable([(1.0, 1.0)], [])
    with pytest.raises(ConfigError):
        LookupTable([(1.0, 1.0), (1.0, 1.0)], [np.zeros(1), np.zeros(1)])
    with pytest.raises(ConfigError):
        LookupTable([(1.0, 0.0)], [np.zeros(1)])
    with pytest.raises(ConfigError):
        LookupTable([(1.0, 1.0)], [np.zeros(1)]).nearest((1.0, -1.0))


def test_lookup_table_select_is_the_one_rule_for_simulate_invert_and_track():
    """(100 V, 35 Hz) on a 20/40/60 V × 10…80 Hz table: clamped to 60 V and blended between 30 and
    40 Hz — the same cells for every command (they all call this rule)."""
    import pytest as _pytest

    from hystfit.conditions import LookupTable
    from hystfit.errors import ConfigError

    keys = [(a, f) for a in (20.0, 40.0, 60.0) for f in (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)]
    table = LookupTable(keys, [np.zeros(1)] * len(keys))
    used, query, clamped = table.select((100.0, 35.0), "interpolate")
    assert clamped and query == (60.0, 35.0)
    w = {k: wt for k, wt in used}
    assert set(w) == {(60.0, 30.0), (60.0, 40.0)}
    assert sum(w.values()) == _pytest.approx(1.0)
    assert w[(60.0, 40.0)] == _pytest.approx(np.log10(35 / 30) / np.log10(40 / 30))
    assert table.select((100.0, 35.0), "nearest")[0] == [((60.0, 40.0), 1.0)]
    with _pytest.raises(ConfigError, match="choose interpolate or nearest"):
        table.select((40.0, 35.0), "cubic")


def test_step_and_hold_inputs_are_told_from_prbs_and_slow_drives():
    """A step test holds levels that differ between any two parts of it by design: it is not warned
    as a capture whose amplitude changes (sample_data's steps_60V.csv was). A PRBS jumps too often,
    slow sines and triangles never jump."""
    from hystfit import synth
    from hystfit.conditions import is_step_and_hold, nonstationary_notes

    r = np.random.default_rng(0)
    _, steps = synth.step_pattern(60.0)
    for u in (steps, steps + 0.01 * r.standard_normal(steps.size), np.repeat(np.arange(10.0), 1000)):
        assert is_step_and_hold(u)
    assert nonstationary_notes(steps, 1e-4, (60.0, 0.32)) == []
    assert nonstationary_notes(steps[::-1][: steps.size // 2], 1e-4, (60.0, 0.32)) == []
    others = [synth.prbs(60.0)[1], synth.rising_sine(60.0, 20.0, 50, 10_000)[1],
              synth.raised_cosine(60.0, 0.1, 3, 10_000)[1], synth.triangle(60.0, 0.5, 3, 10_000)[1]]
    _, slow = synth.raised_cosine(60.0, 1.0, 5, 10_000)
    others += [slow, slow + 0.01 * r.standard_normal(slow.size)]
    assert not any(is_step_and_hold(u) for u in others)


def test_tonal_share_tells_one_drive_frequency_from_a_broadband_input():
    from hystfit import synth
    from hystfit.conditions import TONAL_SHARE_MIN, tonal_share

    fs = 10_000
    tonal = [synth.sine(30, 23.7, 5, fs), synth.raised_cosine(60, 20, 1.5, fs), synth.triangle(60, 7, 4, fs),
             synth.rising_sine(60, 20, 50, fs)]
    broad = [synth.prbs(60, fs, 3.0, 2500.0, seed=1), synth.multisine(60, [10, 40, 160], fs, 3.0),
             synth.multisine(60, synth.multisine_frequencies(1000.0, 3.0), fs, 3.0)]
    assert all(tonal_share(u) > 0.85 for _, u in tonal)
    assert all(tonal_share(u) < 0.35 for _, u in broad)
    assert 0.35 < TONAL_SHARE_MIN < 0.85


def test_a_broadband_capture_in_a_look_up_table_is_warned_about():
    """Found by a blind test: a multisine among sines became the cell 60V_16Hz without a word, and
    simulate blended it into a 20 Hz prediction (RMSE 0.33 against 0.04 µm without it)."""
    from dataclasses import replace

    from hystfit import synth
    from hystfit.capture import Capture
    from hystfit.conditions import broadband_cell_warnings, detect_condition

    def cap(name, t, u):
        a, f = detect_condition(u, t[1] - t[0])
        return Capture(source=name, t=t, u=u, y=0.3 * u, dt=t[1] - t[0], amplitude_V=a, frequency_Hz=f)

    sines = [cap("a60f10.csv", *synth.raised_cosine(60, 10, 3)), cap("a60f40.csv", *synth.raised_cosine(60, 40, 3))]
    ms = cap("ms.csv", *synth.multisine(60, synth.multisine_frequencies(1000.0, 3.0)))
    got = broadband_cell_warnings(sines + [ms])
    assert len(got) == 1 and got[0].startswith("ms.csv: the input is broadband") and "--condition" in got[0]
    assert broadband_cell_warnings(sines) == []  # tonal cells only
    assert broadband_cell_warnings([ms]) == []  # no table to interpolate in
    assert broadband_cell_warnings(sines + [replace(ms, condition_source="option")]) == []  # named by the user
    # a lone broadband capture: no warning, but its label is said to name a spectral line (a blind test's
    # lone PRBS was labelled 60V_210Hz without a word)
    from hystfit.conditions import broadband_label_notes

    (note,) = broadband_label_notes([ms])
    assert note.startswith("ms.csv: the input is broadband") and "not a drive frequency" in note and " 0 %" not in note
    assert broadband_label_notes(sines[:1]) == [] and broadband_label_notes(sines + [ms]) == []
