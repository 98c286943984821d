"""Goodness-of-fit metrics of a model output against a measured output.

All metrics use the error ``e = y_model − y_meas`` (model minus measurement) and are computed in
float64 over every sample, or over several captures pooled together
(:func:`compute_metrics_pooled`).

=============  ==================================================  ===========  ================
key            formula                                             unit         source
=============  ==================================================  ===========  ================
rmse_<unit>    sqrt(mean(e²))                                      output unit  003 eq. 15
nrmse_pct      100 · RMSE / (max y_meas − min y_meas)              %
mape           mean(|e| / |y_meas|) over the kept samples          fraction     002 §3.2
smape          mean(|e| / ((|y_model| + |y_meas|)/2)), kept        fraction     002 §3.2
r2             1 − Σe² / Σ(y_meas − mean y_meas)²                  –            002 §3.2
re             sqrt(Σe² / Σy_meas²)                                –            003 eq. 14
j              Σe² / Σy_meas²                                      –            004 eq. 16
j_model        Σe² / Σy_model²                                     –            004 eq. 16 (as printed)
max_error_<u>  max |e|                                             output unit
n_samples      number of samples                                   count
n_excluded     samples left out of MAPE and SMAPE                  count
mape_floor     the floor used (fraction of the stroke)             fraction
=============  ==================================================  ===========  ================

MAPE and SMAPE explode where the measured output crosses zero, so by default only samples with
``|y_meas| >= 1 % of the stroke`` (stroke = max y_meas − min y_meas) and ``|y_meas| > 0`` are kept;
``n_excluded`` and ``n_excluded_pct`` report how many were left out. ``mape_floor`` sets the
fraction (``--mape-floor``); 0 keeps every sample, as paper 002 does (a sample with y_meas = 0
then makes MAPE infinite).

Paper 004's fitness J (eq. 16) divides Σe² by the sum of the squared *model* output ŷ (its
text calls it a relative mean squared error); ``j`` uses the measurement, which does not move
with the candidate, ``j_model`` the model output as printed. They differ by the factor
Σy_meas²/Σy_model² ≈ 1 for a good fit.

Conventions
-----------
* A model output containing NaN or ±inf (a diverged simulation), or one so large that Σe²
  overflows, is *infinitely bad*, never an exception (and no floating-point warning): every
  error metric (RMSE, NRMSE, MAPE, SMAPE, RE, J, max error) is ``inf`` and R² is ``-inf``, so
  results still sort correctly (best first) and JSON writers turn them into null.
* A metric whose normaliser is zero is undefined and returned as NaN: NRMSE and R² when the
  measured output is constant, RE and J when it is identically zero, MAPE and SMAPE when no sample
  is kept.
* ``y_meas`` must be finite (the loader guarantees this); equal shapes are required.
  Both violations raise :class:`ValueError`.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from .capture import display_unit
from .errors import ConfigError

__all__ = [
    "METRICS",
    "MAPE_THRESHOLD_FRACTION",
    "MetricSpec",
    "compute_metrics",
    "compute_metrics_pooled",
    "check_mape_floor",
    "describe_metrics",
    "metric_key",
]

#: samples with |y_meas| below this fraction of the stroke are excluded from MAPE and SMAPE
MAPE_THRESHOLD_FRACTION = 0.01


class MetricSpec(NamedTuple):
    """Description of one metric for report legends.

    Attributes
    ----------
    name : str
        Base name; the dictionary key is ``metric_key(name, unit)``.
    formula : str
        The formula as a person reads it, with ``e = y_model − y_meas``.
    unit_kind : str
        ``"output"`` (carries the output unit, the key gets a ``_<unit>`` suffix), ``"%"``,
        ``"fraction"``, ``"1"`` (dimensionless) or ``"count"``.
    """

    name: str
    formula: str
    unit_kind: str


#: every metric :func:`compute_metrics` returns, in report order
METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("rmse", "RMSE = sqrt(mean(e²)), e = y_model − y_meas (003 eq. 15)", "output"),
    MetricSpec("bias", "bias = mean(e), the constant part of the error (e.g. a sensor offset between recording "
                       "days); RMSE² = bias² + variance of e", "output"),
    MetricSpec("nrmse_pct", "NRMSE = 100·RMSE / (max y_meas − min y_meas)", "%"),
    MetricSpec("mape", "MAPE = mean(|e| / |y_meas|) over samples with |y_meas| ≥ mape_floor·stroke (002 uses "
                       "every sample: mape_floor 0)", "fraction"),
    MetricSpec("smape", "SMAPE = mean(|e| / ((|y_model| + |y_meas|)/2)) over the same samples (002)",
               "fraction"),
    MetricSpec("r2", "R² = 1 − Σe² / Σ(y_meas − ȳ_meas)²", "1"),
    MetricSpec("re", "RE = sqrt(Σe² / Σy_meas²) (003 eq. 14)", "1"),
    MetricSpec("j", "J = Σe² / Σy_meas² (004 eq. 16 with the measurement as denominator)", "1"),
    MetricSpec("j_model", "J_model = Σe² / Σy_model² (004 eq. 16 as printed: the model output as denominator)", "1"),
    MetricSpec("max_error", "max |e|", "output"),
    MetricSpec("n_samples", "number of samples", "count"),
    MetricSpec("n_excluded", "samples with |y_meas| < mape_floor·stroke (or = 0 when mape_floor > 0), left out of "
                             "MAPE and SMAPE", "count"),
    MetricSpec("n_excluded_pct", "100 · n_excluded / n_samples", "%"),
    MetricSpec("mape_floor", "the MAPE/SMAPE floor as a fraction of the stroke (default 0.01; 0: every sample)",
               "fraction"),
)

_BY_NAME = {m.name: m for m in METRICS}


#: an error whose mean (bias) is at least this share of its RMSE is mostly a constant (the mean's
#: square is then ≥ 25 % of the mean squared error): an output offset the model does not carry
MOSTLY_CONSTANT_SHARE = 0.5


def mostly_constant(metrics: dict, unit: str) -> tuple[float, float] | None:
    """(bias, RMSE) of ``metrics`` (:func:`compute_metrics`' keys in ``unit``) when the error is mostly a
    constant (:data:`MOSTLY_CONSTANT_SHARE`), else None: the one test behind identify's note on a
    missing output offset and simulate's on ``--align-offset``."""
    bias, rmse = metrics.get(metric_key("bias", unit)), metrics.get(metric_key("rmse", unit))
    if bias is None or not rmse or not (math.isfinite(bias) and math.isfinite(rmse)):
        return None
    return (float(bias), float(rmse)) if abs(bias) >= MOSTLY_CONSTANT_SHARE * rmse else None


#: a measured output whose correlation with the prediction is below −this runs opposite to it
#: (an inverted sensor sign): :func:`runs_opposite`
OPPOSITE_CORRELATION = 0.5


def runs_opposite(y_meas, y_model) -> float | None:
    """The correlation of the measured output with the prediction when it is below
    −:data:`OPPOSITE_CORRELATION` (the measurement moves against the model: an output of the other
    sign, e.g. a sensor mounted the other way or a channel recorded inverted), else None. The test
    behind simulate's note on an inverted output, which a constant offset (:func:`mostly_constant`)
    cannot explain."""
    ym, yp = _as_pair(y_meas, y_model)
    ok = np.isfinite(ym) & np.isfinite(yp)
    if not ok.any():
        return None
    a, b = ym[ok] - ym[ok].mean(), yp[ok] - yp[ok].mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    if den == 0.0:
        return None
    r = float(a @ b) / den
    return r if r < -OPPOSITE_CORRELATION else None


def metric_key(name: str, unit: str) -> str:
    """Dictionary / column key of a metric.

    Parameters
    ----------
    name : str
        A base name from :data:`METRICS` (``"rmse"``, ``"r2"``, ...).
    unit : str
        Output unit (``"um"``, ``"nm"``, ...).

    Returns
    -------
    str
        ``f"{name}_{unit}"`` for metrics in the output unit (``"rmse"`` → ``"rmse_um"``), otherwise
        ``name`` unchanged.

    Raises
    ------
    ValueError
        If ``name`` is not a known metric.
    """
    return f"{name}_{unit}" if _spec(name).unit_kind == "output" else name


def describe_metrics(unit: str, names: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """Legend rows ``(column key, formula text)`` for a report.

    Parameters
    ----------
    unit : str
        Output unit; used in the keys and shown after output-unit formulas (``"um"`` as ``µm``).
    names : sequence of str, optional
        Base names to describe, in this order; all of :data:`METRICS` by default.

    Returns
    -------
    list of (str, str)
    """
    shown = display_unit(unit)
    specs = METRICS if names is None else [_spec(n) for n in names]
    suffix = {"output": f" [{shown}]", "%": " [%]", "fraction": " [fraction]", "1": "", "count": ""}
    return [(metric_key(s.name, unit), s.formula + suffix[s.unit_kind]) for s in specs]


def _spec(name: str) -> MetricSpec:
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown metric {name!r}; known metrics: {', '.join(_BY_NAME)}") from None


def _as_pair(y_meas, y_model, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    ym = np.asarray(y_meas, dtype=float)
    yp = np.asarray(y_model, dtype=float)
    if ym.shape != yp.shape:
        raise ValueError(f"y_meas{where} has shape {ym.shape} but y_model{where} has shape {yp.shape}; "
                         "they must be equal")
    return ym.ravel(), yp.ravel()


def compute_metrics(y_meas, y_model, unit: str = "um", *, mape_floor: float = MAPE_THRESHOLD_FRACTION
                    ) -> dict[str, float]:
    """All fit metrics of one model output against one measured output.

    Parameters
    ----------
    y_meas : array_like, shape (N,)
        Measured output in ``unit``; must be finite.
    y_model : array_like, shape (N,)
        Model output in ``unit``. NaN or ±inf anywhere makes every error metric ``inf`` and R²
        ``-inf`` (see the module docstring); this never raises.
    unit : str, default "um"
        Output unit, appended to the keys of metrics that carry it.
    mape_floor : float, default 0.01
        Samples with |y_meas| below this fraction of the stroke are left out of MAPE and SMAPE
        (0: every sample, as paper 002).

    Returns
    -------
    dict
        ``rmse_<unit>``, ``nrmse_pct``, ``mape``, ``smape``, ``r2``, ``re``, ``j``,
        ``max_error_<unit>`` (floats), ``n_samples``, ``n_excluded`` (ints) and ``n_excluded_pct``.

    Raises
    ------
    ValueError
        If the shapes differ, there are no samples, or ``y_meas`` is not finite.

    Examples
    --------
    >>> m = compute_metrics([1.0, 2.0, 3.0], [1.0, 2.0, 4.0], unit="nm")
    >>> round(m["rmse_nm"], 6), m["max_error_nm"]
    (0.57735, 1.0)
    """
    ym, yp = _as_pair(y_meas, y_model)
    return _metrics(ym, yp, unit, mape_floor)


def compute_metrics_pooled(pairs: Sequence[tuple[np.ndarray, np.ndarray]], unit: str = "um", *,
                           mape_floor: float = MAPE_THRESHOLD_FRACTION) -> dict[str, float]:
    """Metrics over several captures of one condition, pooled sample by sample.

    The captures are concatenated and measured as one series, so the result equals
    ``compute_metrics(concatenate(y_meas_i), concatenate(y_model_i))``; in particular the stroke
    used for NRMSE and the MAPE exclusion is that of all captures together.

    Parameters
    ----------
    pairs : sequence of (y_meas, y_model)
        One pair of equal-shape arrays per capture.
    unit : str, default "um"
        Output unit.

    Returns
    -------
    dict
        As :func:`compute_metrics`.

    Raises
    ------
    ValueError
        If ``pairs`` is empty or a pair has mismatched shapes (the message names its index).
    """
    pairs = list(pairs)
    if not pairs:
        raise ValueError("compute_metrics_pooled needs at least one (y_meas, y_model) pair; got none")
    ms, ps = zip(*(_as_pair(a, b, f"[{i}]") for i, (a, b) in enumerate(pairs)))
    return _metrics(np.concatenate(ms), np.concatenate(ps), unit, mape_floor)


def check_mape_floor(mape_floor: float) -> float:
    """The MAPE floor as a float in [0, 1), or :class:`~hystfit.errors.ConfigError`."""
    try:
        f = float(mape_floor)
    except (TypeError, ValueError):
        raise ConfigError(f"--mape-floor must be a number in [0, 1), got {mape_floor!r}") from None
    if not 0.0 <= f < 1.0:
        raise ConfigError(f"--mape-floor must be in [0, 1) (a fraction of the stroke; 0: every sample), got {f:g}")
    return f


def _metrics(ym: np.ndarray, yp: np.ndarray, unit: str, mape_floor: float = MAPE_THRESHOLD_FRACTION
             ) -> dict[str, float]:
    n = ym.size
    if n == 0:
        raise ValueError("cannot compute metrics of an empty series (0 samples)")
    if not np.all(np.isfinite(ym)):
        bad = int(np.count_nonzero(~np.isfinite(ym)))
        raise ValueError(f"y_meas contains {bad} non-finite value(s); measured data must be finite")

    stroke = float(ym.max() - ym.min())
    abs_meas = np.abs(ym)
    if mape_floor > 0:
        keep = (abs_meas >= mape_floor * stroke) & (abs_meas > 0)
    else:  # paper 002: every sample (y_meas = 0 makes the ratio infinite)
        keep = np.ones(n, dtype=bool)
    n_kept = int(np.count_nonzero(keep))
    n_excluded = n - n_kept
    sum_sq_meas = float(np.dot(ym, ym))
    ss_tot = float(np.sum((ym - ym.mean()) ** 2))

    with np.errstate(all="ignore"):  # huge-but-finite outputs may overflow; handled below
        e = yp - ym
        sse = float(np.dot(e, e))
        bias = float(np.mean(e))
    if not np.isfinite(sse):
        # NaN/inf in the model output, or an output so large that Σe² overflows: infinitely bad
        inf = float("inf")
        rmse = nrmse = mape = smape = re = j = j_model = max_err = inf
        r2 = -inf
        bias = bias if math.isfinite(bias) else float("nan")
    else:
        rmse = float(np.sqrt(sse / n))
        abs_e = np.abs(e)
        max_err = float(abs_e.max())
        nrmse = 100.0 * rmse / stroke if stroke > 0 else float("nan")
        r2 = 1.0 - sse / ss_tot if ss_tot > 0 else float("nan")
        j = sse / sum_sq_meas if sum_sq_meas > 0 else float("nan")
        re = float(np.sqrt(j))
        sum_sq_model = float(np.dot(yp, yp))
        j_model = sse / sum_sq_model if sum_sq_model > 0 else float("nan")
        if n_kept:
            ek, mk, pk = abs_e[keep], abs_meas[keep], np.abs(yp[keep])
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):  # beyond 1e308 or /0: inf
                mape = float(np.mean(np.where(mk > 0, ek / mk, np.where(ek > 0, np.inf, 0.0))))
                sden = 0.5 * (pk + mk)
                smape = float(np.mean(np.where(sden > 0, ek / sden, np.where(ek > 0, np.inf, 0.0))))
        else:
            mape = smape = float("nan")

    out: dict[str, float] = {}
    out[metric_key("rmse", unit)] = rmse
    out[metric_key("bias", unit)] = bias
    out["nrmse_pct"] = nrmse
    out["mape"] = mape
    out["smape"] = smape
    out["r2"] = r2
    out["re"] = re
    out["j"] = j
    out["j_model"] = j_model
    out[metric_key("max_error", unit)] = max_err
    out["n_samples"] = n
    out["n_excluded"] = n_excluded
    out["n_excluded_pct"] = 100.0 * n_excluded / n
    out["mape_floor"] = float(mape_floor)
    return out
