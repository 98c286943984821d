"""Tables for reports: per-condition metric rows, CSV frames and Markdown rendering."""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Sequence

import numpy as np

from ..io import Records
from ..metrics import describe_metrics, metric_key

#: metric columns shown in per-condition reports, in order
REPORT_METRICS = ("rmse", "bias", "nrmse_pct", "mape", "smape", "r2", "re", "j", "j_model", "max_error")


def metric_columns(unit: str) -> list[str]:
    return [metric_key(m, unit) for m in REPORT_METRICS]


def fmt(x, digits: int = 4) -> str:
    """Compact number formatting for Markdown tables.

    Counts (integers) are written in full (``33720``, not ``3.372e+04``); a number that would round
    to ±1 without being ±1 (an R² of 0.999996) gets the digits that show how far from 1 it is.
    """
    if x is None:
        return "–"
    if isinstance(x, str):
        return x
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x)).lower()
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if not np.isfinite(x):
        return "inf" if x > 0 else ("-inf" if x < 0 else "–")
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-3:
        return f"{x:.{digits - 1}e}"
    text = f"{x:.{digits}g}"
    while abs(float(text)) == 1.0 and abs(x) != 1.0 and digits < 12:
        digits += 1
        text = f"{x:.{digits}g}"
    return text


def markdown_table(table: "Records | pandas.DataFrame", digits: int = 4) -> str:
    """A Markdown table of :class:`~hystfit.io.Records` or a DataFrame: numeric columns right-aligned."""
    if isinstance(table, Records):
        cols = table.columns
        numeric = [table.kind(c) != "object" for c in cols]
        values = [table.cells(c) for c in cols]
    else:
        import pandas as pd

        cols = list(table.columns)
        numeric = [pd.api.types.is_numeric_dtype(table[c]) for c in cols]
        values = [table[c].tolist() for c in cols]
    lines = ["| " + " | ".join(str(c) for c in cols) + " |",
             "|" + "|".join("---:" if num else "---" for num in numeric) + "|"]
    # per column: integer counts stay integers (a missing value makes a whole count column float, as
    # in pandas, so count columns are recognised by name too)
    columns = [[int(v) if _is_count(c) and isinstance(v, float) and v.is_integer() else v for v in vals]
               for c, vals in zip(cols, values)]
    for row in zip(*columns):
        lines.append("| " + " | ".join(v if isinstance(v, str) else fmt(v, digits) for v in row) + " |")
    return "\n".join(lines)


def _is_count(column) -> bool:
    name = str(column)
    return name.startswith("n_") and not name.endswith("_pct") or name in ("evaluations", "nfev", "samples",
                                                                           "samples_total", "runs", "iterations")


def metric_legend(unit: str) -> str:
    return "\n".join(f"- `{key}`: {formula}" for key, formula in describe_metrics(unit))


def frame(rows: Sequence[dict]) -> Records:
    """A report table of ``rows`` (no pandas: :class:`~hystfit.io.Records`)."""
    return Records(tuple(rows))


def distinct_names(paths: Sequence[str]) -> list[str]:
    """The shortest path suffix of each path that tells it from the others (for console tables).

    ``["a/x/cap.csv", "b/x/cap.csv", "c.csv"]`` → ``["a/x/cap.csv", "b/x/cap.csv", "c.csv"]``;
    ``["day1/cap.csv", "day2/cap.csv"]`` → ``["day1/cap.csv", "day2/cap.csv"]``.
    """

    parts = [PurePath(p).parts for p in paths]
    out = []
    for i, pp in enumerate(parts):
        k = 1
        while k < len(pp) and any(j != i and qq[-k:] == pp[-k:] for j, qq in enumerate(parts)):
            k += 1
        out.append("/".join(pp[-k:]))
    return out


def notes_and_figures(notes: Sequence[str], figures: Sequence[str]) -> list[str]:
    """The closing sections of a report: its notes, its figures (when any), and a final empty line."""
    lines = (["", "## Notes", ""] + [f"- {n}" for n in notes]) if notes else []
    if figures:
        lines += ["", "## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figures]
    return lines + [""]
