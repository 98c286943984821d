"""Predictions for new captures from a saved look-up table (out-of-sample validation).

For a capture at condition (A, f) the table cell is chosen by :class:`~hystfit.conditions.LookupTable`:
``nearest`` takes the closest cell; ``interpolate`` blends the *outputs* of the (up to four)
surrounding cells' models bilinearly. Blending outputs rather than parameter vectors is exact
for models that are linear in their parameters and well defined for all others, even when
cells have different structures (e.g. PI thresholds adapted to each amplitude).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .capture import Capture
from .conditions import LookupTable
from .metrics import compute_metrics
from .results import Cell, ParamsFile


@dataclass(frozen=True)
class Prediction:
    capture: Capture
    y_model: np.ndarray
    cells: tuple[tuple[str, float], ...]  # (cell label, weight)
    metrics: dict | None


def _table(pf: ParamsFile) -> LookupTable:
    keys = [(c.amplitude_V, c.frequency_Hz) for c in pf.cells]
    return LookupTable(keys, [np.array([i], float) for i in range(len(pf.cells))])


def choose_cells(pf: ParamsFile, condition: tuple[float, float], method: str = "nearest") -> list[tuple[Cell, float]]:
    """Cells and weights used for ``condition`` (a global fit has one cell, weight 1)."""
    usable = [c for c in pf.cells if np.isfinite(c.amplitude_V) and np.isfinite(c.frequency_Hz)]
    if len(pf.cells) == 1 or not usable:
        return [(pf.cells[0], 1.0)]
    table = _table(ParamsFile(pf.path, pf.model_name, pf.unit, pf.mode, tuple(usable), pf.raw))
    if method == "interpolate":
        _, used = table.interpolate(condition)
    else:
        key, _ = table.nearest(condition)
        used = [(key, 1.0)]
    by_key = {(c.amplitude_V, c.frequency_Hz): c for c in usable}
    return [(by_key[tuple(k)], float(w)) for k, w in used if w > 0]


def predict_capture(pf: ParamsFile, capture: Capture, method: str = "nearest") -> Prediction:
    cells = choose_cells(pf, capture.condition, method)
    y = sum(w * cell.predict(capture.u, capture.dt) for cell, w in cells)
    metrics = compute_metrics(capture.y, y, pf.unit) if capture.y is not None else None
    return Prediction(capture, np.asarray(y, float), tuple((c.label, w) for c, w in cells), metrics)
