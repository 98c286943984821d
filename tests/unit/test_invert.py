"""Feedforward inversion (hystfit.invert): targets, table cells, round trips, limits, memory."""

import math

import numpy as np
import pytest

from hystfit.errors import ConfigError, InputError
from hystfit.invert import (MAX_TARGET_SAMPLES, apply_limits, check_target_samples, find_spans, invert_target, load_target, multi_target, rest_output,
                            select_cells, sine_target, steps_target, target_from_array, triangle_target)
from hystfit.models.bw import BoucWen
from hystfit.models.pi import PI
from hystfit.params import DataScale
from hystfit.registry import models
from hystfit.results import Cell, ParamsFile
from hystfit.synth import DEFAULT_THRESHOLDS_V, DEFAULT_WEIGHTS_UM_PER_V

DT = 1e-4
PI_THETA = np.r_[DEFAULT_WEIGHTS_UM_PER_V, 0.25]  # the virtual actuator's hysteresis (µm/V, µm)
BW_THETA = np.array([0.2, 0.15, 0.04, 0.01, 0.25])  # Kv, α, β, γ, y0


def scale(u_max=60.0, gain=0.31):
    return DataScale(0.0, u_max, 0.25, 0.25 + gain * u_max, DT, 2 * np.pi * 10 * u_max)


def pi_cell(label="60V_10Hz", amp=60.0, freq=10.0, theta=PI_THETA, thresholds=DEFAULT_THRESHOLDS_V):
    return Cell(label, amp, freq, PI(len(thresholds), thresholds_V=tuple(thresholds)), np.asarray(theta, float),
                scale(amp))


def table(cells, unit="um"):
    return ParamsFile("test.json", cells[0].model.name, unit, "per-condition", tuple(cells), {})


def linear_cell(amp, freq, gain, offset=0.0):
    """A PI cell with the linear operator only: y = gain·u + offset (exact inverse (y − offset)/gain)."""
    return Cell(f"{amp:g}V_{freq:g}Hz", amp, freq, PI(1, thresholds_V=(0.0,)), np.array([gain, offset]),
                scale(amp, gain))


# ------------------------------------------------------------------------------------------ targets


def test_sine_target_is_eq16_from_offset():
    t = sine_target(10.0, 2.0, cycles=3, fs=1000.0, offset=2.0)
    assert t.n == 1501 and t.dt == pytest.approx(1e-3)
    np.testing.assert_allclose(t.y, 2.0 + 5.0 * np.sin(2 * np.pi * 2.0 * t.t_s - np.pi / 2) + 5.0, atol=1e-12)
    assert t.y[0] == pytest.approx(2.0) and t.y.max() == pytest.approx(12.0) and t.stroke == pytest.approx(10.0)
    assert t.y[250] == pytest.approx(12.0)  # peak at half a period
    assert len(t.segments) == 1 and t.segments[0].frequency_Hz == 2.0


def test_triangle_steps_and_multi_targets():
    tri = triangle_target(4.0, 10.0, cycles=2, fs=1000.0, offset=1.0)
    assert tri.y[0] == pytest.approx(1.0) and tri.y[50] == pytest.approx(5.0) and tri.y[100] == pytest.approx(1.0)
    st = steps_target((10.0, 4.0), hold_s=0.1, fs=1000.0, offset=2.0, lead_s=0.02)
    assert st.n == 20 + 200 and st.y[19] == 2.0 and st.y[20] == 12.0 and st.y[120] == 6.0
    assert [(s.index, s.from_level, s.to_level) for s in st.steps] == [(20, 2.0, 12.0), (120, 12.0, 6.0)]
    assert st.segments[0].frequency_Hz == pytest.approx(5.0)  # square wave of period 2·hold
    mt = multi_target(fs=1000.0)
    assert [s.frequency_Hz for s in mt.segments] == [0.5, 1.0, 2.0, 5.0, 10.0]
    assert mt.segments[0].start == 0 and mt.segments[-1].stop == mt.n
    assert all(a.stop == b.start for a, b in zip(mt.segments, mt.segments[1:]))
    for seg, amp in zip(mt.segments, (10, 8, 6, 4, 2)):
        assert np.ptp(mt.y[seg.start:seg.stop]) == pytest.approx(amp, rel=1e-6)
    for seg in mt.segments[1:]:  # smooth joins: every segment starts and ends at rest at the offset
        j = seg.start
        assert mt.y[j - 1] == pytest.approx(0.0, abs=1e-12) and abs(mt.y[j] - mt.y[j - 2]) < 1e-3


@pytest.mark.parametrize("call", [
    lambda: sine_target(-1, 1), lambda: sine_target(1, 0), lambda: sine_target(1, 1, cycles=0),
    lambda: sine_target(1, 100, cycles=0.01, fs=1000), lambda: sine_target(1, 300, fs=1000),
    lambda: triangle_target(1, 300, fs=1000), lambda: steps_target(()),
    lambda: steps_target((0.0,)), lambda: steps_target((1.0, 1.0)), lambda: multi_target((1, 2), (1,)),
    lambda: sine_target(1, 1, offset=float("nan")), lambda: target_from_array(np.array([1.0, np.nan, 2, 3]), DT),
])
def test_bad_target_parameters_raise_config_error(call):
    with pytest.raises(ConfigError):
        call()


@pytest.mark.parametrize("call", [
    lambda: sine_target(10, 20, cycles=1e7), lambda: triangle_target(10, 20, cycles=1e300),
    lambda: steps_target((10.0, 4.0), hold_s=1e300), lambda: steps_target((10.0,), hold_s=1.0, fs=1e300),
    lambda: multi_target(fs=1e7), lambda: multi_target(cycles=1e300),
])
def test_built_in_targets_over_the_sample_limit_are_refused_before_allocating(call):
    with pytest.raises(ConfigError, match="exceed the limit of 1e\\+07 samples"):
        call()


def test_the_sample_limit_admits_exactly_its_count():
    assert check_target_samples(float(MAX_TARGET_SAMPLES), 1e4, "x", "fix") == MAX_TARGET_SAMPLES
    # 1000 s at 10 kHz with its closing sample (a blind test's --sine 10,10,10000 was refused)
    assert sine_target(10, 10, cycles=10_000).n == MAX_TARGET_SAMPLES + 1
    with pytest.raises(ConfigError, match="^--sine 1,2: 10000002 samples at 10000 Hz exceed .*; fix$"):
        check_target_samples(MAX_TARGET_SAMPLES + 2.0, 1e4, "--sine 1,2", "fix")


def test_load_target_columns_units_and_errors(tmp_path):
    p = tmp_path / "t.csv"
    y = 5 + 5 * np.sin(np.linspace(0, 4 * np.pi, 400))
    p.write_text("time_ms,voltage_V,target_nm\n" + "".join(f"{0.1 * k},{0},{v}\n" for k, v in enumerate(y)))
    t = load_target(p)
    assert t.unit == "nm" and t.dt == pytest.approx(1e-4) and t.kind == "file"
    np.testing.assert_allclose(t.y, y)
    assert t.segments[0].frequency_Hz == pytest.approx(1 / (400 * 1e-4 / 2), rel=0.05)
    q = tmp_path / "noheader.csv"
    q.write_text("".join(f"{v}\n" for v in y))
    with pytest.raises(InputError, match="--fs"):
        load_target(q)
    assert load_target(q, fs=1000.0, target_col=0).dt == pytest.approx(1e-3)
    amb = tmp_path / "amb.csv"
    amb.write_text("t,target,reference\n0,1,1\n1,2,2\n2,3,3\n3,4,4\n")
    with pytest.raises(InputError, match="several target .desired displacement. columns"):
        load_target(amb)
    assert load_target(amb, target_col="reference").y[-1] == 4.0
    bad = tmp_path / "bad.csv"
    bad.write_text("t,target\n0,1\n1,x\n2,3\n3,4\n")
    with pytest.raises(InputError, match="row 3"):
        load_target(bad)
    with pytest.raises(InputError, match="no such file"):
        load_target(tmp_path / "missing.csv")


def test_target_unit_must_match_the_parameter_file():
    with pytest.raises(ConfigError, match="nm"):
        invert_target(table([pi_cell()]), sine_target(1000, 10, unit="nm"))


# ------------------------------------------------------------------------------------------ round trips


def test_round_trip_pi_is_exact_and_memory_consistent():
    pf = table([pi_cell()])
    tgt = sine_target(10.0, 10.0, cycles=3, offset=2.0)
    res = invert_target(pf, tgt)
    # analytic inverse (paper 003 eq. 17-20) → forward(invert(y_d)) = y_d to rounding
    assert res.metrics["max_error_um"] < 1e-9
    assert res.initial_voltage_source.startswith("rest voltage")
    assert rest_output(pf.cells[0], res.initial_voltage_V, DT) == pytest.approx(2.0, abs=1e-9)
    assert res.voltage_V[0] == pytest.approx(res.initial_voltage_V, abs=1e-9)
    assert not res.clip_spans and not res.slew_spans and res.metrics_unlimited is None
    written = res.to_table()
    assert list(written) == ["time_s", "voltage_V", "predicted_displacement_um"]
    assert list(written.to_pandas().columns) == list(written)


def test_round_trip_bw_numerical_inverse():
    cell = Cell("60V_10Hz", 60.0, 10.0, BoucWen(), BW_THETA, scale())
    res = invert_target(table([cell]), sine_target(10.0, 10.0, cycles=2, offset=2.0))
    # generic bracketing inverse (17-point grid, 4 refinements, linear interpolation): stated tolerance 1e-5 of stroke
    assert res.metrics["max_error_um"] < 1e-5 * 10.0


def _default_cell(name):
    """A cell of model ``name`` with its default parameters, set up like the model contract suite."""
    u = 30.0 * (1 - np.cos(2 * np.pi * 10 * np.arange(2001) * DT))
    sc = DataScale.from_arrays([u], [0.3 * u + 0.25], [DT])
    cls = models.get(name)
    model = cls.example(sc)
    theta = np.array([p.default for p in model.params(sc)])
    return Cell("60V_10Hz", 60.0, 10.0, model, theta, sc), u


@pytest.mark.parametrize("name", models.names())
def test_round_trip_every_registered_model_through_the_table(name):
    """forward(invert(y_d)) ≈ y_d within 0.5 % of the stroke for a reachable target starting at rest
    (the model's own output for a raised cosine from 0 V), pre-roll and rest voltage included."""
    cell, u = _default_cell(name)
    y = cell.model.simulate_one(cell.theta, u, DT)
    assert np.all(np.isfinite(y)) and np.ptp(y) > 0, f"{name}: default parameters give no usable output"
    tgt = target_from_array(y[:1500], DT, description=f"{name} output")
    # no escape hatch: a ConfigError ("cannot be inverted") fails the test, every model must invert
    res = invert_target(table([cell]), tgt, vmin=-1e4, vmax=1e4)
    assert res.metrics["max_error_pct_of_stroke"] < 0.5
    assert not res.clip_spans and not res.slew_spans


# ------------------------------------------------------------------------------------------ table cells


def grid_table():
    cells = [linear_cell(a, f, g) for a, f, g in ((20, 10, 0.2), (40, 10, 0.3), (20, 100, 0.25), (40, 100, 0.35))]
    return table(cells)


def test_bilinear_weights_between_four_cells():
    pf = grid_table()
    cells, query, clamped = select_cells(pf, (30.0, math.sqrt(10 * 100)))
    assert not clamped and query == (30.0, pytest.approx(math.sqrt(1000)))
    assert sorted(c.weight for c in cells) == pytest.approx([0.25] * 4)
    cells, _, _ = select_cells(pf, (25.0, 10.0))
    assert {c.label: c.weight for c in cells} == pytest.approx({"20V_10Hz": 0.75, "40V_10Hz": 0.25})
    cells, query, clamped = select_cells(pf, (80.0, 1000.0))
    assert clamped and query == (40.0, 100.0) and [(c.label, c.weight) for c in cells] == [("40V_100Hz", 1.0)]
    cells, query, clamped = select_cells(pf, (30.0, 5.0))  # clamped in frequency only: still blends in amplitude
    assert clamped and {c.label: c.weight for c in cells} == pytest.approx({"20V_10Hz": 0.5, "40V_10Hz": 0.5})
    cells, _, _ = select_cells(pf, (33.0, 12.0), "nearest")
    assert [(c.label, c.weight) for c in cells] == [("40V_10Hz", 1.0)]
    with pytest.raises(ConfigError):
        select_cells(pf, (30.0, 10.0), "cubic")


def test_forced_condition_blends_the_inverted_voltages():
    pf = grid_table()
    tgt = sine_target(6.0, 10.0, cycles=1, offset=1.0)
    res = invert_target(pf, tgt, condition=(25.0, 10.0))
    (ch,) = res.choices
    assert ch.how == "forced" and not ch.iterations
    expected = 0.75 * tgt.y / 0.2 + 0.25 * tgt.y / 0.3  # Σ w_c·H_c⁻¹[y_d] for pure gains
    np.testing.assert_allclose(res.voltage_V, expected, rtol=1e-9, atol=1e-9)
    # the predicted output blends the forward models: Σ w_c·g_c·u
    np.testing.assert_allclose(res.predicted, (0.75 * 0.2 + 0.25 * 0.3) * expected, rtol=1e-9, atol=1e-9)


def test_amplitude_iteration_converges_and_picks_the_right_cell():
    # 10 um needs 20/40/50/200 V on the 20/40/60/80 V cells; the first guess, stroke / median gain
    # = 10/0.225 = 44 V, is off; only the 40 V cell is self-consistent (its voltage amplitude is 40 V)
    pf = table([linear_cell(20, 10, 0.5), linear_cell(40, 10, 0.25), linear_cell(60, 10, 0.2),
                linear_cell(80, 10, 0.05)])
    tgt = sine_target(10.0, 10.0, cycles=1)
    res = invert_target(pf, tgt, method="nearest")
    (ch,) = res.choices
    assert ch.iterations[0].amplitude_V == pytest.approx(10 / 0.225)
    assert ch.converged and [c.label for c in ch.cells] == ["40V_10Hz"]
    assert np.ptp(res.voltage_V) == pytest.approx(40.0)
    res = invert_target(pf, tgt, method="interpolate")
    (ch,) = res.choices
    # between the 40 and 60 V cells A ↦ 50 − (60 − A)/2 contracts (slope 1/2) to its fixed point 40 V
    assert ch.converged and len(ch.iterations) >= 5
    assert ch.iterations[-1].result_pp_V == pytest.approx(ch.condition[0], rel=1e-3)
    assert ch.condition[0] == pytest.approx(40.0, rel=2e-3)
    assert {c.label for c in ch.cells} <= {"40V_10Hz", "60V_10Hz"}
    assert max(c.weight for c in ch.cells) > 0.99


def test_amplitude_iteration_reports_alternating_cells():
    # the 20 V cell asks for 35 V (→ 40 V cell), the 40 V cell for 25 V (→ 20 V cell): no fixed point
    # (both identified on 0…100 V, so both cover every voltage and only the amplitudes decide)
    from dataclasses import replace

    pf = table([replace(c, scale=scale(100.0, 0.3)) for c in (linear_cell(20, 10, 10 / 35), linear_cell(40, 10, 10 / 25))])
    res = invert_target(pf, sine_target(10.0, 10.0, cycles=1), method="nearest")
    (ch,) = res.choices
    assert not ch.converged and "alternated" in ch.note
    assert any("alternated" in n for n in res.notes)


def test_multi_target_uses_a_cell_per_segment_with_smooth_joins():
    pf = table([linear_cell(a, f, g) for a, f, g in ((20, 1, 0.2), (40, 1, 0.3), (20, 10, 0.25), (40, 10, 0.35))])
    tgt = multi_target(fs=2000.0)
    res = invert_target(pf, tgt, method="nearest")
    labels = [[c.label for c in ch.cells] for ch in res.choices]
    assert labels[0] == ["40V_1Hz"] and labels[-1] == ["20V_10Hz"]
    # exact linear inverses; the only residual is second order in the cross-fade after each join
    # (2 % of the shorter segment), where Σw·g_c·Σw·u_c ≠ y
    fade = np.zeros(tgt.n, bool)
    for seg in tgt.segments[1:]:
        fade[seg.start:seg.start + 30] = True
    err = np.abs(res.predicted - tgt.y)
    assert err[~fade].max() < 1e-9 and err.max() < 1e-4 * tgt.stroke
    assert np.max(np.abs(np.diff(res.voltage_V))) < 0.2


# ------------------------------------------------------------------------------------------ limits


def test_find_spans_and_apply_limits_report_exact_spans():
    u = np.array([0.0, 1.0, 5.0, 6.0, 2.0, -3.0, -4.0, 0.0, 0.0])
    out, clip, slew = apply_limits(u, 0.5, -2.0, 4.0, None, 0.0)
    np.testing.assert_array_equal(out, [0, 1, 4, 4, 2, -2, -2, 0, 0])
    assert [(s.kind, s.start, s.stop, s.n, s.start_s, s.stop_s, s.worst_V) for s in clip] == [
        ("vmax", 2, 4, 2, 1.0, 1.5, 2.0), ("vmin", 5, 7, 2, 2.5, 3.0, 2.0)]
    assert slew == []
    out, clip, slew = apply_limits(np.array([0.0, 0.0, 10.0, 10.0, 10.0, 0.0]), 0.1, -100, 100, 40.0, 0.0)
    np.testing.assert_allclose(out, [0, 0, 4, 8, 10, 6])  # |Δu| ≤ 40 V/s · 0.1 s
    assert clip == [] and [(s.start, s.stop, s.worst_V) for s in slew] == [(2, 4, 6.0), (5, 6, 6.0)]
    assert find_spans(np.zeros(3, bool), np.zeros(3), 1.0, "x") == []


def test_clipping_is_reported_with_time_spans_and_its_cost():
    pf = table([pi_cell()])
    tgt = sine_target(10.0, 10.0, cycles=2, offset=2.0)
    free = invert_target(pf, tgt)
    vmax = float(free.voltage_V.max()) - 3.0
    res = invert_target(pf, tgt, vmax=vmax)
    assert res.voltage_V.max() <= vmax + 1e-12 and res.limits["vmax_source"] == "given"
    assert len(res.clip_spans) == 2 and all(s.kind == "vmax" for s in res.clip_spans)
    over = free.voltage_V > vmax
    for s in res.clip_spans:
        assert over[s.start:s.stop].all() and not over[s.start - 1] and not over[s.stop]
        assert s.start_s == pytest.approx(s.start * DT) and s.worst_V == pytest.approx(3.0, abs=0.01)
    assert res.metrics_unlimited["max_error_um"] < 1e-9 < res.metrics["max_error_um"]


def test_slew_limit_starts_from_the_initial_voltage():
    pf = table([pi_cell()])
    tgt = sine_target(10.0, 20.0, cycles=1, offset=2.0)
    res = invert_target(pf, tgt, max_slew=1500.0, initial_voltage=0.0)
    assert np.max(np.abs(np.diff(np.r_[0.0, res.voltage_V]))) <= 1500.0 * DT * (1 + 1e-9)
    assert res.slew_spans and res.slew_spans[0].start == 0  # the target starts away from 0 V: slewed from rest
    assert any("jump" in n for n in res.notes)


def test_limit_and_initial_voltage_validation():
    pf = table([pi_cell()])
    tgt = sine_target(10.0, 10.0, cycles=1)
    for kw in ({"vmin": 5.0, "vmax": 5.0}, {"max_slew": 0.0}, {"initial_voltage": 100.0}, {"vmin": float("nan")},
               {"method": "cubic"}, {"condition": (-1.0, 10.0)}):
        with pytest.raises(ConfigError):
            invert_target(pf, tgt, **kw)
    lo, hi = invert_target(pf, tgt).limits["vmin_V"], invert_target(pf, tgt).limits["vmax_V"]
    assert (lo, hi) == (pytest.approx(-6.0), pytest.approx(66.0))  # 0…60 V ± 10 %


def test_given_initial_voltage_sets_the_memory():
    pf = table([pi_cell()])
    tgt = sine_target(6.0, 10.0, cycles=2, offset=8.0)
    res = invert_target(pf, tgt, initial_voltage=40.0)  # the stage came down from 0→40 V: different memory
    assert res.initial_voltage_V == 40.0 and res.initial_voltage_source == "given"
    assert res.metrics["max_error_um"] < 1e-3  # only the first sample's jump from rest differs
    default = invert_target(pf, tgt)
    assert abs(default.voltage_V[100] - res.voltage_V[100]) > 0.1  # hysteresis: the history matters


# ------------------------------------------------------------------------------------------ figures


def test_detail_windows_only_for_long_targets():
    from hystfit.report.invert_report import detail_windows

    assert detail_windows(sine_target(10.0, 5.0, cycles=5)) == []  # 5 cycles: the main figure is readable
    long = sine_target(10.0, 10.0, cycles=1000)
    (a0, b0, lab0), (a1, b1, lab1) = detail_windows(long)
    assert (a0, b0) == (0, 3001) and (a1, b1) == (long.n - 3001, long.n)  # 3 periods of 10 Hz at 10 kHz
    assert lab0.startswith("start") and lab1.startswith("end: 99.7")
    slow = sine_target(10.0, 0.01, cycles=20, fs=1000.0)  # 3 periods = 300 001 samples: capped at 10 000
    assert [b - a for a, b, _ in detail_windows(slow)] == [10_000, 10_000]


def test_invert_report_draws_a_detail_figure_for_a_long_target(tmp_path):
    from hystfit.report.invert_report import write_invert_report

    pf = table([pi_cell()])
    res = invert_target(pf, sine_target(10.0, 80.0, cycles=40, offset=2.0))
    write_invert_report(res, tmp_path)
    assert (tmp_path / "plots" / "tracking_detail.png").stat().st_size > 10_000
    assert "plots/tracking_detail.png" in (tmp_path / "report.md").read_text()


def test_segments_continue_from_the_voltage_history():
    """A later segment's cell enters with the memory the applied voltage gave it, not its own history.

    Two PI cells with different thresholds: the 1 Hz cell drives the 0.5–2 Hz segments, the 10 Hz
    cell the 5 and 10 Hz ones (nearest lookup). The 10 Hz cell's inverse must continue from the
    1 Hz cell's voltage, so where it alone acts (after the cross-fade) its forward model on the
    applied voltage reproduces the target to rounding.
    """
    uniform = tuple(4.0 * j for j in range(10))
    pf = table([pi_cell("40V_1Hz", 40.0, 1.0),
                pi_cell("40V_10Hz", 40.0, 10.0, theta=np.r_[np.asarray(DEFAULT_WEIGHTS_UM_PER_V) * 1.1, 0.3],
                        thresholds=uniform)])
    tgt = multi_target(fs=2000.0, offset=2.0)
    res = invert_target(pf, tgt, method="nearest")
    assert [[c.label for c in ch.cells] for ch in res.choices] == [["40V_1Hz"]] * 3 + [["40V_10Hz"]] * 2
    s4, s5 = tgt.segments[3], tgt.segments[4]
    fade = max(1, round(0.02 * min(tgt.segments[2].stop - tgt.segments[2].start, s4.stop - s4.start)))
    err = np.abs(res.predicted - tgt.y)
    assert err[s4.start + fade:s5.stop].max() < 1e-9 * tgt.stroke
    assert err[:tgt.segments[2].stop].max() < 1e-9 * tgt.stroke  # the first cell alone, from rest


def test_check_invert_options_completes_the_default_limits():
    from hystfit.invert import InvertLimits, check_invert_options, default_voltage_limits

    pf = table([pi_cell()])
    tgt = sine_target(10.0, 10.0, cycles=2, fs=1e4)
    opts = check_invert_options(pf, tgt, "interpolate", None, None, None, 50.0, None)
    lo, _ = default_voltage_limits(pf)
    assert isinstance(opts, InvertLimits)
    assert (opts.vmin_V, opts.vmax_V, opts.vmin_source, opts.vmax_source) == (lo, 50.0, "default", "given")
    assert opts.record(pf)["max_slew_V_per_s"] is None and "± 10 %" in opts.record(pf)["default_rule"]
    with pytest.raises(ConfigError, match="vmin < vmax"):
        check_invert_options(pf, tgt, "interpolate", None, None, 5.0, 1.0, None)
    with pytest.raises(ConfigError, match="choose interpolate or nearest"):
        check_invert_options(pf, tgt, "cubic", None, None, None, None, None)


def test_captures_and_targets_count_samples_one_way():
    from hystfit.capture import Capture, UniformSamples

    tgt = sine_target(10.0, 10.0, cycles=2, fs=1e4)
    cap = Capture("c.csv", t=np.arange(5) * 1e-3, u=np.zeros(5), y=None, dt=1e-3)
    assert isinstance(tgt, UniformSamples) and isinstance(cap, UniformSamples)
    assert (tgt.n, tgt.fs) == (tgt.y.size, pytest.approx(1e4)) and (cap.n, cap.fs) == (5, pytest.approx(1e3))


def test_a_target_far_beyond_the_identified_outputs_is_refused_naming_the_unit():
    """A blind test's find: a table in m and `--sine 10,20 --offset 2`, a 2…12 m target for a stage of
    some 20 µm, clipped at every sample with exit 0."""
    from hystfit.errors import ConfigError
    from hystfit.invert import invert_target, sine_target

    pf = table([pi_cell()], unit="m")  # outputs 0.25…18.85 in the table's unit
    with pytest.raises(ConfigError, match=r"the target spans 2…2002 m, far beyond the outputs the table was "
                                          r"identified on \(0\.25…18\.85 m\).*Targets are in the table's output unit \(m\)"):
        invert_target(pf, sine_target(2000.0, 20.0, 1, 10_000.0, offset=2.0, unit="m"))
    res = invert_target(pf, sine_target(25.0, 20.0, 1, 10_000.0, offset=2.0, unit="m"))  # beyond, but within reach
    assert res.voltage_V.size > 0
    # a stroke that fits, only far off (a sensor offset of 5e6 nm, a blind test's find): --offset is named
    with pytest.raises(ConfigError, match=r"move it there with --offset \(e\.g\. --offset 2\.11\)"):
        invert_target(pf, sine_target(10.0, 20.0, 1, 10_000.0, offset=5e6, unit="m"))


def test_a_steps_target_starting_at_its_rest_level_is_explained():
    """A blind test's find: `--steps 0,5,10,15@0.05` answered `got 0 twice` for a 0 given once: the
    target rests at 0 above its offset before the first level."""
    from hystfit.errors import ConfigError
    from hystfit.invert import steps_target

    with pytest.raises(ConfigError, match=r"the first level, 0, is the rest level the target starts at"):
        steps_target([0.0, 5.0, 10.0], 0.05)
    with pytest.raises(ConfigError, match=r"two consecutive levels are 5"):
        steps_target([5.0, 5.0, 10.0], 0.05)


def test_a_target_up_the_stroke_uses_the_cells_that_cover_its_voltage():
    """A blind test's find: a 5 → 13 µm sine needs 10…40 V, 30 V peak-to-peak, and blended the 20 V
    and 40 V cells of a campaign whose captures all start at 0 V (identified on 0…20 and 0…40 V):
    extrapolated, 20–30× the predicted error on the plant. The voltage leaving a chosen cell's
    range asks for the smallest cell that covers it; a target from the bottom is unchanged."""
    pf = table([linear_cell(a, 10, 0.25) for a in (20, 40, 60)])
    up = invert_target(pf, sine_target(7.5, 10.0, cycles=2, offset=2.5), method="interpolate")
    (ch,) = up.choices
    u = up.voltage_V
    assert 9.0 < u.min() and u.max() < 41.0 and np.ptp(u) == pytest.approx(30.0, rel=1e-3)
    assert [c.label for c in ch.cells] == ["40V_10Hz"] and "cover it" in ch.note
    assert not any("extrapolated" in n for n in up.notes)
    low = invert_target(pf, sine_target(7.5, 10.0, cycles=2), method="interpolate")
    (ch0,) = low.choices
    assert "cover" not in ch0.note and ch0.condition[0] == pytest.approx(30.0, rel=2e-3)
