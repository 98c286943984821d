"""Predictions for new captures from a saved look-up table (out-of-sample validation).

For a capture at condition (A, f) the table cells are chosen by
:func:`hystfit.invert.select_cells` — the same selector ``invert`` and ``track`` use: ``nearest``
takes the closest cell; ``interpolate`` blends the *outputs* of the (up to four) surrounding
cells' models bilinearly, a condition outside the grid first clamped onto it. Blending outputs
rather than parameter vectors is exact for models that are linear in their parameters and well
defined for all others, even when cells have different structures (e.g. PI thresholds adapted to
each amplitude).

Every prediction carries notes on what a reader must know to trust it, in the words ``invert``
uses: a condition outside the table's grid (clamped), cells driven outside the voltage range
they were identified on (extrapolated).

``align_offset``: a constant offset between the recording days of the identification and of the
validation captures (sensor zero, mount) dominates the RMSE although the model is right. With it,
the offset c = mean(y_meas − y_model) is fitted per capture and added to the prediction (the
least-squares optimum of a constant); it is reported, never silent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .blocks.dynamics import check_below_nyquist
from .capture import Capture
from .invert import CellUse, clamp_note, extrapolated_cells, extrapolation_note, select_cells
from .metrics import compute_metrics, mostly_constant, runs_opposite
from .results import ParamsFile


@dataclass(frozen=True)
class Prediction:
    """The prediction of one capture.

    cells : (cell label, weight) pairs used.
    metrics : against the measured output (None for an input-only capture).
    offset : the fitted constant added to the model output (output unit), None without ``align_offset``.
    notes : clamped condition, extrapolated cells (one line each).
    """

    capture: Capture
    y_model: np.ndarray
    cells: tuple[tuple[str, float], ...]  # (cell label, weight)
    metrics: dict | None
    offset: float | None = None
    notes: tuple[str, ...] = ()


def predict_capture(pf: ParamsFile, capture: Capture, method: str = "interpolate", *,
                    align_offset: bool = False) -> Prediction:
    """Predict ``capture``'s output with the table ``pf``; see the module docstring.

    A measured output in another unit than the parameter file's is refused
    (:meth:`ParamsFile.check_unit`, as ``invert`` refuses such a target): the metrics would
    compare numbers in two units and the prediction file would label the capture's output with
    the parameter file's unit. An input-only capture has no output unit to check.
    """
    if capture.y is not None:
        pf.check_unit(capture.y_unit, f"{capture.source}: the measured output",
                      f"convert it to {pf.unit} (a column named e.g. displacement_{pf.unit}) or simulate with "
                      f"parameters identified from captures in {capture.y_unit}")
    if _has_condition(capture):
        cells, query, clamped = select_cells(pf, capture.condition, method)
    else:
        cells, query, clamped = _no_condition(pf)
    for c in cells:  # a stage the capture's rate does not resolve: refused in words, not NaN predictions
        fn = pf.cells[c.index].model.natural_frequency_Hz(pf.cells[c.index].theta)
        if fn is not None:
            check_below_nyquist(fn, capture.dt, f"{capture.source}: cell {c.label}")
    y = sum(c.weight * pf.cells[c.index].predict(capture.u, capture.dt) for c in cells)
    y = np.asarray(y, float)
    notes = []
    if clamped:
        notes.append(clamp_note(capture.condition, query, cells))
    extrapolated = [extrapolation_note(x) for x in extrapolated_cells(pf, ((c.index, capture.u) for c in cells))]
    notes += extrapolated
    offset = None
    if align_offset and capture.y is not None:
        offset = float(np.mean(capture.y - y))
        y = y + offset
        notes.append(f"offset {offset:+.4g} {pf.unit} fitted to this capture and added to the prediction "
                     "(--align-offset)")
    metrics = compute_metrics(capture.y, y, pf.unit) if capture.y is not None else None
    opposite = runs_opposite(capture.y, y) if capture.y is not None else None
    constant = mostly_constant(metrics, pf.unit) if metrics is not None and not align_offset else None
    if opposite is not None:  # no offset explains a measurement that moves against the prediction
        notes.append(f"the measured output runs opposite to the prediction (correlation {opposite:.2f}): an output "
                     "of the other sign (a sensor mounted the other way, a channel recorded inverted)? negate the "
                     "output column, or identify on captures of this sign")
    elif constant is not None:
        bias, rmse = constant
        notes.append(_constant_note(pf, bias, rmse, outside=bool(clamped or extrapolated)))
    return Prediction(capture, y, tuple((c.label, c.weight) for c in cells), metrics, offset, tuple(notes))


def _constant_note(pf: ParamsFile, bias: float, rmse: float, *, outside: bool) -> str:
    """The note on an error that is mostly a constant: a sensor zero that moved since the
    identification is one cause (``--align-offset`` fits it); a table used outside its cells'
    range (``outside``: clamped or extrapolated, said above) and a model with slow states that start
    from rest at the capture's first sample (creep: a capture cut from a longer recording starts
    with them unknown) shift the prediction as much, and aligning the offset would hide that model
    error (two blind-test cases: an extrapolated cell, and pi+creep on the second half of a
    recording)."""
    u = pf.unit
    head = f"the error is mostly a constant (bias {bias:+.4g} {u} of RMSE {rmse:.4g} {u})"
    slow = any("creep" in [b.name for b in getattr(c.model, "blocks", ())] for c in pf.cells)
    if outside:
        return (f"{head}: the table is used outside its cells' range here (see above), which shifts a prediction "
                "as much; check inside the identified range before blaming a sensor zero (--align-offset fits a "
                "constant per capture)")
    if slow:
        return (f"{head}: the model's creep starts from rest at the capture's first sample (a capture cut from a "
                "longer recording starts with it unknown), which shifts a prediction for its slowest time constant; "
                "or a sensor zero moved since the identification (--align-offset fits it per capture)")
    return f"{head}: a sensor zero that moved since the identification? --align-offset fits it per capture"


def _has_condition(capture: Capture) -> bool:
    a, f = capture.condition
    return bool(np.isfinite(a) and np.isfinite(f) and f > 0)


def _no_condition(pf: ParamsFile):
    """A capture without an operating condition (e.g. broadband): the table's first cell, as before."""

    c = pf.cells[0]
    return (CellUse(0, c.label, c.amplitude_V, c.frequency_Hz, 1.0),), (c.amplitude_V, c.frequency_Hz), False
