"""The virtual actuator (hystfit.synth) and the ``hystfit synth`` command.

Every effect is checked alone against its physical signature, on small captures (fast).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hystfit import synth as S
from hystfit.errors import ConfigError, OutputError
from hystfit.models._kernels import play_matrix

FS = 10_000.0
LINEAR = S.Plant(thresholds_V=(0.0,), weights_um_per_V=(1.0,), offset_um=0.0)  # y = u (µm per V)
REPO_SAMPLE_DATA = Path(__file__).resolve().parents[2] / "sample_data"


def plant_with(effects: S.Effects, base: S.Plant | None = None) -> S.Plant:
    return (base or S.Plant.default()).with_effects(effects)


def branches(u, y, amplitude, frequency_Hz, n_grid=400):
    """Ascending and descending branch of the last cycle of a 0→A→0 raised cosine on a u-grid."""
    n = int(round(FS / frequency_Hz))
    uu, yy = u[-(n + 1):], y[-(n + 1):]
    kp = int(np.argmax(uu))
    grid = np.linspace(0.02 * amplitude, 0.98 * amplitude, n_grid)
    asc = np.interp(grid, uu[: kp + 1], yy[: kp + 1])
    desc = np.interp(grid, uu[kp:][::-1], yy[kp:][::-1])
    return grid, asc, desc


# ---------------------------------------------------------------------------------------------
# excitations
# ---------------------------------------------------------------------------------------------


def test_raised_cosine_is_0_to_A_to_0_for_five_cycles():
    t, u = S.raised_cosine(40, 10)
    assert t.dtype == np.float64 and u.dtype == np.float64
    assert len(t) == 5001 and t[0] == 0.0 and t[-1] == pytest.approx(0.5)
    assert u[0] == 0.0 and u[-1] == pytest.approx(0.0, abs=1e-12)
    assert u.max() == pytest.approx(40.0) and u.min() >= 0.0
    np.testing.assert_allclose(u, 20.0 * (1 - np.cos(2 * np.pi * 10 * t)), atol=1e-12)
    assert np.diff(t) == pytest.approx(np.full(5000, 1e-4))


def test_sine_and_triangle():
    t, u = S.sine(10, 50, cycles=2, fs_Hz=FS, offset_V=30)
    np.testing.assert_allclose(u, 30 + 10 * np.sin(2 * np.pi * 50 * t), atol=1e-12)
    t, u = S.triangle(20, 10, cycles=3, fs_Hz=FS)
    assert u.min() == pytest.approx(0.0) and u.max() == pytest.approx(20.0)
    rate = np.abs(np.diff(u)) * FS
    # constant |du/dt| = 2·A·f except at the turning samples
    assert np.median(rate) == pytest.approx(2 * 20 * 10)
    assert np.mean(np.isclose(rate, 400.0)) > 0.99


def test_prbs_levels_seeding_and_bandwidth():
    t, u = S.prbs(60, FS, duration_s=3.0, clock_Hz=2500, seed=7)
    assert set(np.unique(u)) == {0.0, 60.0} and u[0] == 0.0
    assert len(t) == 30_000
    np.testing.assert_array_equal(u, S.prbs(60, FS, 3.0, 2500, seed=7)[1])
    assert not np.array_equal(u, S.prbs(60, FS, 3.0, 2500, seed=8)[1])
    # broadband to >= 1 kHz: the power density at 0.9–1.1 kHz is within 3 dB of the 10–200 Hz level
    spec = np.abs(np.fft.rfft(u - u.mean())) ** 2
    f = np.fft.rfftfreq(u.size, 1 / FS)
    low = spec[(f > 10) & (f < 200)].mean()
    high = spec[(f > 900) & (f < 1100)].mean()
    assert high > low / 2


def test_multisine_spans_0_to_A_and_is_seeded():
    freqs = S.multisine_frequencies(1000, 2.0)
    assert freqs[0] == pytest.approx(0.5) and freqs[-1] == pytest.approx(1000)
    np.testing.assert_allclose(freqs * 2.0, np.round(freqs * 2.0))  # periodic in the capture
    t, u = S.multisine(60, freqs, FS, 2.0, seed=3)
    assert u.min() == pytest.approx(0.0) and u.max() == pytest.approx(60.0)
    np.testing.assert_array_equal(u, S.multisine(60, freqs, FS, 2.0, seed=3)[1])
    assert not np.array_equal(u, S.multisine(60, freqs, FS, 2.0, seed=4)[1])
    spec = np.abs(np.fft.rfft(u - u.mean()))
    f = np.fft.rfftfreq(u.size, 1 / FS)
    assert spec[np.argmin(np.abs(f - freqs[-1]))] > 10 * np.median(spec)


def test_steps_hold_each_level():
    t, u = S.steps([0, 30, 10], [0.5, 1.0, 2.0], FS)
    assert len(u) == 35_000
    assert np.all(u[:5000] == 0) and np.all(u[5000:15000] == 30) and np.all(u[15000:] == 10)
    t, u = S.step_pattern(60, 7.7, FS)
    levels = u[np.r_[True, np.diff(u) != 0]]
    np.testing.assert_allclose(levels, [0, 30, 60, 20, 45, 0])
    assert np.all(np.diff(np.flatnonzero(np.r_[True, np.diff(u) != 0]))[1:] >= 1.0 * FS)


@pytest.mark.parametrize(
    "call",
    [
        lambda: S.raised_cosine(-1, 10),
        lambda: S.raised_cosine(10, 0),
        lambda: S.prbs(10, FS, 1.0, clock_Hz=2 * FS),
        lambda: S.steps([], 1.0),
        lambda: S.make_excitation("sine", 10, None),
        lambda: S.make_excitation("chirp", 10, 10),
    ],
)
def test_bad_excitation_arguments_raise_config_error(call):
    with pytest.raises(ConfigError):
        call()


# ---------------------------------------------------------------------------------------------
# effects, plant, determinism
# ---------------------------------------------------------------------------------------------


def test_effects_constructors():
    assert S.Effects.none().enabled == () and S.Effects() == S.Effects.none()
    for name in S.EFFECT_NAMES:
        assert S.Effects.only(name).enabled == (name,)
    assert S.Effects.all().enabled == S.EFFECT_NAMES
    assert S.Effects.default().enabled == ("creep", "dynamics", "noise", "quantization")
    assert S.Effects.parse("none") == S.Effects.none()
    assert S.Effects.parse("creep, delay").enabled == ("creep", "delay")
    e2 = S.Effects.only("noise", strength=2.0)
    assert e2.noise_sigma_um == pytest.approx(2 * S.Effects().noise_sigma_um)
    assert S.Effects.only("creep", 3.0).creep_gain == pytest.approx([0.03] * 4)
    assert S.Effects.only("dynamics", 2.0).dynamics_fn_Hz == pytest.approx(600.0)
    with pytest.raises(ConfigError, match="'none' stands alone; it cannot be combined"):  # a blind test's
        S.Effects.from_names(["none", "noise"])  # "unknown effect 'none' … (or 'none', …)" contradicted itself
    with pytest.raises(ConfigError, match="unknown effect 'wobble'"):
        S.Effects.parse("creep,wobble")
    with pytest.raises(ConfigError):
        S.Effects.only("noise", strength=0.0)
    with pytest.raises(ConfigError):
        S.Effects(creep_tau_s=(1.0,), creep_gain=(0.1, 0.2))


def test_default_plant_is_realistic_and_not_on_hystfits_threshold_grid():
    p = S.Plant.default()
    assert len(p.thresholds_V) == 10 and max(p.thresholds_V) <= 70
    for amplitude in (20, 40, 60):
        grid = {round(j * amplitude / 10, 9) for j in range(1, 11)}
        assert not grid & {round(r, 9) for r in p.thresholds_V[1:]}
    t, u = S.raised_cosine(60, 10)
    y = S.simulate_plant(p, t, u, seed=0)
    last = slice(4000, None)
    stroke = y[last].max() - y[last].min()
    assert 15 <= stroke <= 20 and 0.30 <= stroke / 60 <= 0.35
    _, asc, desc = branches(u, S.simulate_plant(p.with_effects(S.Effects.none()), t, u), 60, 10)
    assert 0.10 <= np.max(desc - asc) / stroke <= 0.15
    e = p.effects
    assert 1000 <= e.dynamics_fn_Hz <= 1500 and 0.1 <= e.dynamics_zeta <= 0.2
    assert 0.005 <= e.noise_sigma_um <= 0.01 and e.quantization_lsb_um == pytest.approx(0.001)


def test_no_effects_is_pure_pi_plus_offset():
    t, u = S.raised_cosine(60, 20)
    p = plant_with(S.Effects.none())
    F = play_matrix(u, np.asarray(p.thresholds_V))
    expected = F @ np.asarray(p.weights_um_per_V) + p.offset_um
    y = S.simulate_plant(p, t, u, seed=1)
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)
    comps = S.simulate_plant_components(p, t, u, seed=1)
    assert list(comps) == [
        "hysteresis", "asymmetry", "creep", "dynamics", "delay", "drift", "noise", "quantization",
        "measurement",
    ]
    for v in comps.values():
        np.testing.assert_array_equal(v, comps["hysteresis"])


def test_determinism_per_seed_and_difference_across_seeds():
    t, u = S.raised_cosine(40, 30)
    p = S.Plant.default()
    y1 = S.simulate_plant(p, t, u, seed=5)
    np.testing.assert_array_equal(y1, S.simulate_plant(p, t, u, seed=5))
    y2 = S.simulate_plant(p, t, u, seed=6)
    assert not np.array_equal(y1, y2)
    assert np.std(y1 - y2) == pytest.approx(np.sqrt(2) * 0.008, rel=0.15)  # only the noise differs
    quiet = plant_with(S.Effects.from_names(["creep", "dynamics"]))
    np.testing.assert_array_equal(S.simulate_plant(quiet, t, u, seed=5), S.simulate_plant(quiet, t, u, seed=6))


def test_output_unit_scales_the_measurement():
    t, u = S.raised_cosine(20, 10)
    p_um = plant_with(S.Effects.from_names(["creep", "dynamics", "quantization"]))
    y_um = S.simulate_plant(p_um, t, u)
    y_nm = S.simulate_plant(replace(p_um, output_unit="nm"), t, u)
    np.testing.assert_allclose(y_nm, 1000 * y_um, rtol=0, atol=1e-9)
    with pytest.raises(ConfigError):
        replace(p_um, output_unit="inch")


# ---------------------------------------------------------------------------------------------
# each effect alone
# ---------------------------------------------------------------------------------------------


def _steady_phasor(t, y, f, n_last):
    """Least-squares amplitude and phase of the f component over the last ``n_last`` samples."""
    tt, yy = t[-n_last:], y[-n_last:]
    X = np.column_stack([np.sin(2 * np.pi * f * tt), np.cos(2 * np.pi * f * tt), np.ones_like(tt)])
    (a, b, _), *_ = np.linalg.lstsq(X, yy, rcond=None)
    return np.hypot(a, b), np.arctan2(b, a)


def test_dynamics_match_the_analytic_second_order_response():
    fn, zeta = 300.0, 0.15
    p = plant_with(S.Effects(dynamics=True, dynamics_fn_Hz=fn, dynamics_zeta=zeta), LINEAR)
    lags = []
    for f in (30.0, 100.0, 250.0):
        t, u = S.sine(1.0, f, cycles=40, fs_Hz=FS)
        y = S.simulate_plant(p, t, u)
        n_last = int(round(10 * FS / f))
        gain, phase = _steady_phasor(t, y, f, n_last)
        H = 1.0 / (1 - (f / fn) ** 2 + 2j * zeta * f / fn)
        assert gain == pytest.approx(abs(H), rel=5e-3)  # bilinear warping: 0.2 % at 250 Hz
        assert phase == pytest.approx(np.angle(H), abs=5e-3)
        lags.append(-phase)
    assert lags[0] < lags[1] < lags[2]
    # and the default plant's 80 Hz loop is wider than its 10 Hz loop because of the dynamics
    widths = []
    for f in (10, 80):
        t, u = S.raised_cosine(60, f)
        p80 = plant_with(S.Effects.only("dynamics"))
        _, asc, desc = branches(u, S.simulate_plant(p80, t, u), 60, f)
        widths.append(np.max(desc - asc))
    assert widths[1] > widths[0] + 0.2


def test_delay_shows_as_cross_correlation_peak():
    t, u = S.prbs(1.0, FS, duration_s=1.0, clock_Hz=2500, seed=2)
    p = plant_with(S.Effects(delay=True, delay_s=37 / FS), LINEAR)
    y = S.simulate_plant(p, t, u)
    x = u - u.mean()
    lags = np.arange(0, 100)
    xc = [np.dot(x[: x.size - k], (y - y.mean())[k:]) for k in lags]
    assert lags[int(np.argmax(xc))] == 37
    # fractional delay: half a sample is the mean of the two neighbours
    p_half = plant_with(S.Effects(delay=True, delay_s=0.5 / FS), LINEAR)
    y_half = S.simulate_plant(p_half, t, u)
    np.testing.assert_allclose(y_half[1:], 0.5 * (u[1:] + u[:-1]), atol=1e-12)
    assert y_half[0] == u[0]


def test_creep_keeps_moving_after_a_step_like_a_logarithm():
    t, u = S.steps([0.0, 30.0], [0.2, 5.0], FS)
    p = plant_with(S.Effects.only("creep"), LINEAR)
    y = S.simulate_plant(p, t, u)
    k0 = int(0.2 * FS)
    step = 30.0

    def at(dt_s):
        return y[k0 + int(round(dt_s * FS))]

    assert y[k0] == pytest.approx(step * (1 + 0.01 * sum(1 - np.exp(-1e-4 / np.array([0.01, 0.1, 1, 10])))))
    assert np.all(np.diff(y[k0:]) >= -1e-12)  # keeps moving, in the direction of the step
    assert at(4.9) - at(0.001) > 0.02 * step
    incs = [at(0.1) - at(0.01), at(1.0) - at(0.1)]  # equal per decade of time
    assert incs[0] == pytest.approx(0.01 * step, rel=0.25)
    assert incs[1] == pytest.approx(incs[0], rel=0.25)
    # without creep the step response is flat
    flat = S.simulate_plant(plant_with(S.Effects.none(), LINEAR), t, u)
    assert np.ptp(flat[k0:]) == 0.0


def test_drift_moves_the_output_at_constant_input():
    t = np.arange(0, 20.0, 1e-3)
    u = np.full_like(t, 30.0)
    e = S.Effects.only("drift")
    y = S.simulate_plant(plant_with(e), t, u)
    y0 = S.simulate_plant(plant_with(S.Effects.none()), t, u)
    assert np.ptp(y0) == 0.0
    expected = e.drift_rate_um_per_s * t + e.drift_amplitude_um * np.sin(2 * np.pi * t / e.drift_period_s)
    np.testing.assert_allclose(y - y0, expected, atol=1e-12)
    assert y[-1] - y[0] > 0.15


def test_asymmetry_breaks_the_point_symmetry_of_pi_loops():
    t, u = S.raised_cosine(60, 10)
    sym = S.simulate_plant(plant_with(S.Effects.none()), t, u)
    asym = S.simulate_plant(plant_with(S.Effects.only("asymmetry")), t, u)
    _, asc_s, desc_s = branches(u, sym, 60, 10)
    _, asc_a, desc_a = branches(u, asym, 60, 10)
    # a PI loop is point-symmetric: asc(u) + desc(A − u) is constant
    assert np.ptp(asc_s + desc_s[::-1]) < 0.01
    assert np.ptp(asc_a + desc_a[::-1]) > 0.3
    # saturating bow (a2 < 0) lifts every point between 0 and the span s
    assert np.all(asc_a >= asc_s - 1e-9) and np.max(asc_a - asc_s) > 0.3
    # the static map keeps z = 0 and z = s and bows the middle by −a2·s/4
    e = S.Effects.only("asymmetry")
    s = e.asymmetry_span_um
    y = S.simulate_plant(plant_with(e, LINEAR), np.arange(3.0), np.array([0.0, s / 2, s]))
    np.testing.assert_allclose(y, [0.0, s / 2 - e.asymmetry_a2 * s / 4, s], atol=1e-12)


def test_quantization_puts_values_on_the_lsb_grid():
    t, u = S.raised_cosine(40, 50)
    for strength in (1.0, 5.0):
        e = S.Effects.from_names(["noise", "quantization"], strength)
        y = S.simulate_plant(plant_with(e), t, u, seed=3)
        steps_ = y / e.quantization_lsb_um
        np.testing.assert_allclose(steps_, np.round(steps_), atol=1e-6)
    y_raw = S.simulate_plant(plant_with(S.Effects.only("noise")), t, u, seed=3)
    assert np.max(np.abs(y_raw / 0.001 - np.round(y_raw / 0.001))) > 0.1


def test_noise_has_the_requested_sigma():
    t, u = S.raised_cosine(40, 10, cycles=6)
    e = S.Effects.only("noise", strength=2.5)
    comps = S.simulate_plant_components(plant_with(e), t, u, seed=11)
    residual = comps["measurement"] - comps["drift"]
    assert residual.std() == pytest.approx(2.5 * 0.008, rel=0.05)
    assert abs(residual.mean()) < 4 * 0.02 / np.sqrt(residual.size)


def test_dynamics_above_nyquist_is_refused():
    t, u = S.raised_cosine(10, 10, fs_Hz=2000)
    # named as the command line has it (a blind test's find: `dynamics_fn_Hz … must lie below the Nyquist …`)
    # and true whether the user chose dynamics or took the defaults (a blind test's --effects dynamics
    # --strength 0.2 was told it was "one of the default effects" and to leave it out for creep and noise)
    with pytest.raises(ConfigError, match=r"the plant's dynamics \(stage resonance f_n = 1200 Hz\) needs a sample "
                                          r"rate above 2400 Hz, got 2000 Hz; raise --fs, or leave dynamics out of "
                                          r"--effects \(it is one of the default effects.*a weaker --strength raises f_n"):
        S.simulate_plant(S.Plant.default(), t, u)


# ---------------------------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------------------------


def test_write_capture_csv_is_reproducible_and_parquet_round_trips(tmp_path):
    t, u = S.raised_cosine(20, 40)
    y = S.simulate_plant(S.Plant.default(), t, u, seed=0)
    a = S.write_capture(tmp_path / "a.csv", t, u, y)
    b = S.write_capture(tmp_path / "b.csv", t, u, y, "um")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_text().splitlines()[0] == "time_s,voltage_V,displacement_um"
    df = pd.read_csv(a)
    np.testing.assert_allclose(df["displacement_um"], y, atol=1e-6)
    pq = S.write_capture(tmp_path / "c.parquet", t, u, y * 1000, "nm")
    dq = pd.read_parquet(pq)
    assert list(dq.columns) == ["time_s", "voltage_V", "displacement_nm"]
    np.testing.assert_array_equal(dq["voltage_V"].to_numpy(), u)
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind
    with pytest.raises(OutputError):
        S.write_capture(a / "inside_a_file.csv", t, u, y)
    with pytest.raises(ConfigError):
        S.write_capture(tmp_path / "d.csv", t, u, y, fmt="xlsx")


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    paths = S.make_campaign(out, seed=0)
    return out, paths


def test_campaign_writes_24_plus_2_files(campaign_dir):
    out, paths = campaign_dir
    names = sorted(p.relative_to(out).as_posix() for p in paths)
    expected = sorted(
        [f"a{a:02d}V_f{f:02d}Hz.csv" for a in (20, 40, 60) for f in range(10, 90, 10)]
        + ["broadband/prbs_60V.csv", "broadband/steps_60V.csv"]
    )
    assert names == expected
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == expected
    for p in paths:
        df = pd.read_csv(p)
        assert list(df.columns) == ["time_s", "voltage_V", "displacement_um"]
        assert df.notna().all().all()
    df = pd.read_csv(out / "a60V_f80Hz.csv")
    assert df["voltage_V"].max() == pytest.approx(60.0, abs=0.02) and df["voltage_V"].iloc[0] == 0.0
    assert df["time_s"].iloc[-1] == pytest.approx(5 / 80)
    df = pd.read_csv(out / "a20V_f10Hz.csv")
    assert len(df) == 5001 and df["voltage_V"].max() == pytest.approx(20.0, abs=1e-6)
    prbs = pd.read_csv(out / "broadband/prbs_60V.csv")
    assert set(prbs["voltage_V"].unique()) == {0.0, 60.0} and 2.0 <= prbs["time_s"].iloc[-1] <= 5.0
    st = pd.read_csv(out / "broadband/steps_60V.csv")
    assert st["voltage_V"].between(0, 60).all() and st["time_s"].iloc[-1] > 5


def test_campaign_is_bit_for_bit_reproducible_and_files_have_own_seeds(campaign_dir, tmp_path):
    out, paths = campaign_dir
    again = S.make_campaign(tmp_path, seed=0)
    for p, q in zip(paths, again):
        assert p.read_bytes() == q.read_bytes(), p.name
    # per-file noise seeds: two captures of the same condition would share noise only if seeded alike
    e = S.Plant.default()
    t, u = S.raised_cosine(20, 10)
    clean = S.simulate_plant(e.with_effects(S.Effects.from_names(["creep", "dynamics"])), t, u)
    n0 = pd.read_csv(out / "a20V_f10Hz.csv")["displacement_um"].to_numpy() - clean
    t, u = S.raised_cosine(20, 20)
    clean = S.simulate_plant(e.with_effects(S.Effects.from_names(["creep", "dynamics"])), t, u)
    n1 = pd.read_csv(out / "a20V_f20Hz.csv")["displacement_um"].to_numpy() - clean
    assert abs(np.corrcoef(n0[: n1.size], n1)[0, 1]) < 0.1


def test_repository_sample_data_matches_the_generator(campaign_dir):
    """sample_data/ must be what ``hystfit synth campaign --out sample_data --seed 0`` writes."""
    out, paths = campaign_dir
    if not (REPO_SAMPLE_DATA / "a20V_f10Hz.csv").exists():
        pytest.skip("sample_data/ not generated")
    for p in paths:
        rel = p.relative_to(out)
        ref = pd.read_csv(REPO_SAMPLE_DATA / rel)
        new = pd.read_csv(p)
        assert list(ref.columns) == list(new.columns)
        np.testing.assert_allclose(ref.to_numpy(), new.to_numpy(), rtol=0, atol=2e-6, err_msg=str(rel))


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cli():
    from typer.testing import CliRunner

    from hystfit.cli import app

    runner = CliRunner()
    return lambda *args: runner.invoke(app, list(args))


def test_cli_capture_prints_only_the_path(cli, tmp_path):
    out = tmp_path / "cap.csv"
    res = cli("synth", "capture", str(out), "--excitation", "triangle", "--amplitude", "30",
              "--frequency", "25", "--effects", "creep,dynamics", "--noise", "0.01", "--seed", "4")
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines() == [str(out)]
    df = pd.read_csv(out)
    assert list(df.columns) == ["time_s", "voltage_V", "displacement_um"]
    assert df["voltage_V"].max() == pytest.approx(30.0)
    # refuses to overwrite without --force, and a bad effect is a one-line error, exit 2
    res = cli("synth", "capture", str(out), "--amplitude", "30", "--frequency", "25")
    assert res.exit_code == 2 and "--force" in res.stderr and res.stdout == ""
    res = cli("synth", "capture", str(tmp_path / "x.csv"), "-a", "30", "-f", "25", "--effects", "warp")
    assert res.exit_code == 2 and "unknown effect 'warp'" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.csv").exists()
    res = cli("synth", "capture", str(tmp_path / "y.csv"), "-a", "30", "-e", "sine")
    assert res.exit_code == 2 and "frequency" in res.stderr


def test_cli_campaign_refuses_non_empty_dir_unless_forced(cli, tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    res = cli("synth", "campaign", "--out", str(tmp_path), "--effects", "none")
    assert res.exit_code == 2 and "not empty" in res.stderr and res.stdout == ""
    res = cli("synth", "campaign", "--out", str(tmp_path), "--effects", "none", "--force")
    assert res.exit_code == 0, res.output
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 26 and all(Path(line).exists() for line in lines)
    assert (tmp_path / "keep.txt").read_text() == "x"
    # --effects none: the files are the pure PI plus offset
    df = pd.read_csv(tmp_path / "a40V_f50Hz.csv")
    p = plant_with(S.Effects.none())
    expected = S.simulate_plant(p, df["time_s"].to_numpy(), df["voltage_V"].to_numpy())
    np.testing.assert_allclose(df["displacement_um"], expected, atol=1e-6)


def test_a_strength_that_breaks_the_asymmetry_names_the_option_not_a_field():
    """A blind test's find: `synth … --effects all --strength 10` answered `asymmetry_a2 must lie
    in (-1, 1)`, a field name the command line never shows."""
    import pytest

    from hystfit.errors import ConfigError
    from hystfit.synth import Effects

    with pytest.raises(ConfigError, match=r"--strength 10 with asymmetry: its bow \|a₂\| = \|-0\.12 × 10\| = 1\.2 "
                                          r"must stay below 1 .*use --strength below 8\.33"):
        Effects.from_names(["asymmetry", "creep"], strength=10.0)
    assert Effects.from_names(["asymmetry"], strength=8.0).asymmetry
    assert Effects.from_names(["creep"], strength=10.0).creep  # no asymmetry: no such bound
