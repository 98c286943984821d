"""Metrics against values computed by hand on tiny arrays (e = y_model − y_meas)."""

import math
import warnings

import numpy as np
import pytest

from hystfit.metrics import (
    METRICS,
    compute_metrics,
    check_mape_floor,
    compute_metrics_pooled,
    describe_metrics,
    metric_key,
)

# y_meas = [0, 1, 2, 4], y_model = [0.5, 1, 2.5, 3]  →  e = [0.5, 0, 0.5, -1], Σe² = 1.5
Y_MEAS = [0.0, 1.0, 2.0, 4.0]
Y_MODEL = [0.5, 1.0, 2.5, 3.0]


def test_hand_computed_values():
    m = compute_metrics(Y_MEAS, Y_MODEL, unit="um")
    assert m["rmse_um"] == pytest.approx(math.sqrt(1.5 / 4), rel=1e-12)
    assert m["nrmse_pct"] == pytest.approx(100 * math.sqrt(1.5 / 4) / 4.0, rel=1e-12)  # stroke 4
    # 1 % of stroke = 0.04: y = 0 is excluded, kept |e|/|y| = 0/1, 0.5/2, 1/4
    assert m["n_excluded"] == 1
    assert m["n_samples"] == 4
    assert m["n_excluded_pct"] == pytest.approx(25.0)
    assert m["mape"] == pytest.approx((0 + 0.25 + 0.25) / 3, rel=1e-12)
    # SMAPE kept: 0/1, 0.5/((2.5+2)/2) = 2/9, 1/((3+4)/2) = 2/7
    assert m["smape"] == pytest.approx((0 + 2 / 9 + 2 / 7) / 3, rel=1e-12)
    # ȳ = 1.75, Σ(y − ȳ)² = 8.75
    assert m["r2"] == pytest.approx(1 - 1.5 / 8.75, rel=1e-12)
    # Σy² = 21
    assert m["j"] == pytest.approx(1.5 / 21, rel=1e-12)
    assert m["re"] == pytest.approx(math.sqrt(1.5 / 21), rel=1e-12)
    assert m["max_error_um"] == pytest.approx(1.0)


def test_mape_threshold_is_one_percent_of_stroke_inclusive():
    # stroke = 100 → threshold |y| ≥ 1.0; 0.999 is excluded, ±1.0 are kept, sign does not matter
    y = np.array([-50.0, 50.0, 1.0, 0.999, -1.0])
    m = compute_metrics(y, y + 0.1)
    assert m["n_excluded"] == 1
    assert m["mape"] == pytest.approx(np.mean([0.1 / 50, 0.1 / 50, 0.1 / 1.0, 0.1 / 1.0]), rel=1e-12)
    smape_terms = [0.1 / ((49.9 + 50) / 2), 0.1 / ((50.1 + 50) / 2), 0.1 / ((1.1 + 1) / 2), 0.1 / ((0.9 + 1) / 2)]
    assert m["smape"] == pytest.approx(np.mean(smape_terms), rel=1e-12)


def test_mape_without_exclusion_would_explode():
    # a tiny |y_meas| (well under 1 % of the stroke) must not dominate MAPE
    y = np.array([1e-9, 10.0, 20.0])
    m = compute_metrics(y, y + 0.01)
    assert m["n_excluded"] == 1
    assert m["mape"] == pytest.approx(np.mean([0.01 / 10, 0.01 / 20]))


def test_perfect_model():
    y = np.array([-1.0, 0.0, 2.0, 3.5])
    m = compute_metrics(y, y.copy())
    assert m["rmse_um"] == 0.0
    assert m["max_error_um"] == 0.0
    assert m["r2"] == 1.0
    assert m["mape"] == 0.0 and m["smape"] == 0.0
    assert m["re"] == 0.0 and m["j"] == 0.0 and m["nrmse_pct"] == 0.0


def test_error_sign_convention_does_not_matter_for_symmetric_metrics_but_smape_uses_model():
    y = np.array([1.0, 2.0, 3.0])
    hi, lo = compute_metrics(y, y + 0.5), compute_metrics(y, y - 0.5)
    assert hi["rmse_um"] == pytest.approx(lo["rmse_um"])
    assert hi["mape"] == pytest.approx(lo["mape"])
    assert hi["smape"] < lo["smape"]  # |y_model| in the denominator


def test_pooled_equals_concatenated(rng):
    pairs = [(rng.normal(size=n) * 5 + 3, rng.normal(size=n)) for n in (50, 7, 120)]
    pooled = compute_metrics_pooled(pairs, unit="nm")
    concat = compute_metrics(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]), "nm")
    assert pooled.keys() == concat.keys()
    for k in concat:
        assert pooled[k] == pytest.approx(concat[k], rel=1e-14), k
    # pooling is not the mean of per-capture values
    per = [compute_metrics(a, b, "nm")["rmse_nm"] for a, b in pairs]
    assert pooled["rmse_nm"] != pytest.approx(np.mean(per))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_model_is_infinitely_bad_without_warnings(bad):
    y = np.array([0.0, 1.0, 2.0, 3.0])
    yp = y.copy()
    yp[2] = bad
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = compute_metrics(y, yp)
    for k in ("rmse_um", "nrmse_pct", "mape", "smape", "re", "j", "max_error_um"):
        assert m[k] == math.inf, k
    assert m["r2"] == -math.inf
    assert m["n_samples"] == 4


def test_overflowing_model_output_is_infinitely_bad_without_warnings():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = compute_metrics(y, np.array([0.0, 1e300, -1e300, 3.0]))
    assert m["rmse_um"] == math.inf and m["j"] == math.inf and m["r2"] == -math.inf


def test_undefined_normalisers_give_nan():
    m = compute_metrics([2.0, 2.0, 2.0], [2.0, 2.5, 2.0])  # constant measurement
    assert math.isnan(m["nrmse_pct"]) and math.isnan(m["r2"])
    assert m["rmse_um"] == pytest.approx(math.sqrt(0.25 / 3))
    z = compute_metrics([0.0, 0.0], [0.1, 0.0])  # identically zero measurement
    assert math.isnan(z["re"]) and math.isnan(z["j"]) and math.isnan(z["mape"]) and math.isnan(z["smape"])
    assert z["n_excluded"] == 2


def test_shape_and_input_errors():
    with pytest.raises(ValueError, match="shape"):
        compute_metrics([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ValueError, match=r"y_meas\[1\]"):
        compute_metrics_pooled([([1.0, 2.0], [1.0, 2.0]), ([1.0, 2.0], [1.0])])
    with pytest.raises(ValueError, match="at least one"):
        compute_metrics_pooled([])
    with pytest.raises(ValueError, match="empty"):
        compute_metrics([], [])
    with pytest.raises(ValueError, match="non-finite"):
        compute_metrics([1.0, np.nan], [1.0, 1.0])


def test_keys_carry_the_unit():
    m = compute_metrics(Y_MEAS, Y_MODEL, unit="nm")
    assert "rmse_nm" in m and "max_error_nm" in m
    assert "rmse_um" not in m and "rmse" not in m
    assert metric_key("rmse", "nm") == "rmse_nm"
    assert metric_key("max_error", "um") == "max_error_um"
    for unitless in ("nrmse_pct", "mape", "smape", "r2", "re", "j", "n_samples", "n_excluded"):
        assert metric_key(unitless, "nm") == unitless
    with pytest.raises(ValueError, match="unknown metric"):
        metric_key("rmsee", "um")


def test_every_returned_key_is_described_and_vice_versa():
    m = compute_metrics(Y_MEAS, Y_MODEL, unit="nm")
    legend = describe_metrics("nm")
    assert [k for k, _ in legend] == list(m)
    assert len(METRICS) == len(m)
    text, text_um = dict(legend), dict(describe_metrics("um"))
    assert "[µm]" in text_um["rmse_um"] and "[nm]" in text["max_error_nm"]
    assert "003" in text["re"] and "004" in text["j"]
    assert describe_metrics("um", ["r2", "rmse"]) == [("r2", text["r2"]), ("rmse_um", text_um["rmse_um"])]


def test_docstring_examples_run():
    import doctest

    import hystfit.metrics

    result = doctest.testmod(hystfit.metrics, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_mape_floor_zero_keeps_every_sample_as_paper_002():
    y_meas, y_model = [0.5, 1.0, 2.0, 4.0], [1.0, 1.0, 2.5, 3.0]  # |e| = 0.5, 0, 0.5, 1
    m = compute_metrics(y_meas, y_model, mape_floor=0.0)
    assert m["n_excluded"] == 0 and m["mape_floor"] == 0.0
    assert m["mape"] == pytest.approx((1.0 + 0 + 0.25 + 0.25) / 4, rel=1e-12)
    d = compute_metrics(y_meas, y_model)  # default floor 1 %·stroke = 0.035: still every sample here
    assert d["mape_floor"] == 0.01 and d["n_excluded"] == 0
    m = compute_metrics(y_meas, y_model, mape_floor=0.2)  # 0.2·3.5 = 0.7: the first sample is left out
    assert m["n_excluded"] == 1 and m["mape"] == pytest.approx((0 + 0.25 + 0.25) / 3, rel=1e-12)
    z = compute_metrics([0.0, 1.0, 2.0], [0.1, 1.0, 2.0], mape_floor=0.0)
    assert z["mape"] == math.inf and z["n_excluded"] == 0  # y_meas = 0 with an error: MAPE has no finite value
    for bad in (-0.1, 1.0, "x"):
        with pytest.raises(Exception, match="mape-floor"):
            check_mape_floor(bad)


def test_j_model_divides_by_the_model_output_as_004_prints_it():
    m = compute_metrics(Y_MEAS, Y_MODEL)
    assert m["j_model"] == pytest.approx(1.5 / (0.25 + 1 + 6.25 + 9), rel=1e-12)
    assert m["j"] == pytest.approx(1.5 / 21, rel=1e-12)
    legend = dict(describe_metrics("um"))
    assert "y_model" in legend["j_model"] and "mape_floor" in legend["mape"]


def test_mostly_constant_is_one_test_for_identify_and_simulate():
    """Bias at least half the RMSE: identify's missing-offset note and simulate's --align-offset note."""
    from hystfit.metrics import mostly_constant

    assert mostly_constant({"bias_um": -30.8, "rmse_um": 31.7}, "um") == (-30.8, 31.7)
    assert mostly_constant({"bias_um": 0.01, "rmse_um": 0.04}, "um") is None
    assert mostly_constant({"bias_nm": 30.0, "rmse_nm": 31.0}, "um") is None  # another unit's keys
    assert mostly_constant({"bias_um": float("nan"), "rmse_um": 1.0}, "um") is None
