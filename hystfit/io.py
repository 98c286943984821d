"""Reading captures (CSV/TXT/TSV/DAT and Parquet) and writing outputs atomically.

Loading turns a file into a validated :class:`~hystfit.capture.Capture`:

1. optional sidecar ``<file>.hystfit.json`` supplies default :class:`LoadOptions`;
2. the table is read (delimiter sniffed, ``#`` comment lines and a preamble before the header
   skipped (:func:`_preamble`), header auto-detected);
3. the time / input / output columns are chosen by option (name or 0-based index) or by name
   (aliases, case-insensitive, optional unit suffix such as ``_mV``, `` [um]``, ``(s)``), then
   by the unit in brackets of a name no alias matches (``Spannung [V]``: :func:`_unit_column`);
4. cells are checked (numbers, finite), units converted (time → s, input → V; the output
   keeps its unit: nm, um, mm or m);
5. time must strictly increase and be uniform (jitter ≤ 0.1 % of the step);
6. a leading idle segment (constant input) is trimmed and time re-zeroed;
7. the operating condition comes from ``amplitude_V``/``frequency_Hz`` columns, the
   ``condition`` option, or :func:`hystfit.conditions.detect_condition`;
8. at least ``min_cycles`` input cycles must remain.

Every problem is an :class:`~hystfit.errors.InputError` whose one-line message names the file,
the row (1-based line of the file; data row for Parquet) or column, the rule and the remedy.

pandas (≈ 0.3 s to import) is imported only by the readers that need it — text with non-numeric
cells or below :data:`FAST_READ_BYTES`, Parquet — and by :func:`write_table`: a plain numeric
capture is read by pyarrow straight into float64 columns (:func:`_read_text_fast`).
"""

from __future__ import annotations

import dataclasses
import io as _stdio
import json
import math
import csv
import os
import re
import secrets
import shutil
import tempfile
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, ContextManager, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ._process import alive
from .capture import Capture, display_unit
from .conditions import (CONDITION_RULE, count_cycles, detect_condition, is_valid_condition, nonstationary_notes,
                         white_noise_sigma)
from .errors import ConfigError, InputError, OutputError

CAPTURE_SUFFIXES = (".csv", ".txt", ".tsv", ".dat", ".parquet", ".pq")
PARQUET_SUFFIXES = (".parquet", ".pq")
#: files a folder may hold that look like measurements hystfit cannot read: skipped, with a note
#: (a blind test's folder with an .xlsx and a .gz beside its CSVs said nothing about them)
UNREADABLE_DATA_SUFFIXES = (".xlsx", ".xls", ".ods", ".gz", ".zip", ".bz2", ".xz", ".7z", ".mat", ".h5", ".hdf5",
                            ".npy", ".npz", ".feather", ".tdms")
SIDECAR_SUFFIX = ".hystfit.json"
OUTPUT_UNITS = ("nm", "um", "mm", "m")

# ----------------------------------------------------------------------------------------------
# Column names: aliases and units
# ----------------------------------------------------------------------------------------------

_ALIASES: dict[str, frozenset[str]] = {
    "time": frozenset({"t", "time", "times", "timestamp", "elapsed", "elapsed_time", "time_elapsed", "seconds",
                       "secs", "sec"}),
    "input": frozenset({"u", "v", "voltage", "volt", "volts", "input", "vin", "v_in", "u_in", "uin", "drive",
                        "command", "cmd", "excitation", "input_voltage", "voltage_in", "drive_voltage",
                        "applied_voltage", "v_drive", "u_drive", "voltage_input", "piezo_voltage", "v_piezo",
                        "u_piezo", "voltage_piezo", "control_voltage", "actuator_voltage"}),
    "output": frozenset({"y", "x", "d", "displacement", "disp", "position", "pos", "output", "out", "y_out",
                         "yout", "stroke", "deflection", "extension", "elongation", "measured_displacement",
                         "sensor", "sensor_output", "measured_position", "actual_position", "distance", "z"}),
    "amplitude": frozenset({"amplitude", "amp", "amplitude_pp", "amp_pp", "vpp"}),
    # a desired trajectory (feedforward targets); the output names are accepted after these
    "target": frozenset({"target", "reference", "ref", "setpoint", "set_point", "desired", "y_d", "yd", "y_ref",
                         "yref", "r", "trajectory", "target_displacement", "desired_displacement",
                         "reference_displacement", "command_displacement", "demand"}),
    "frequency": frozenset({"frequency", "freq"}),
}
#: Multiplier to SI (s, V, Hz) per unit text (lower case). Output units are kept, not converted.
_UNITS: dict[str, dict[str, float | str]] = {
    "time": {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6, "ns": 1e-9},
    "input": {"v": 1.0, "mv": 1e-3, "kv": 1e3},
    "output": {"nm": "nm", "um": "um", "µm": "um", "μm": "um", "mm": "mm", "m": "m"},
    "target": {"nm": "nm", "um": "um", "µm": "um", "μm": "um", "mm": "mm", "m": "m"},
    "amplitude": {"v": 1.0, "mv": 1e-3, "kv": 1e3, "vpp": 1.0},
    "frequency": {"hz": 1.0, "khz": 1e3},
}
#: Aliases that carry their unit in the name itself.
_IMPLIED_UNIT = {"seconds": "s", "secs": "s", "sec": "s", "vpp": "v"}
#: names that read as a desired trajectory (``target`` role of :func:`load_table`)
TARGET_NAMES = _ALIASES["target"]
_FLAGS = {"time": "--time-col", "input": "--input-col", "output": "--output-col", "target": "--target-col"}
_WHAT = {"time": "time", "input": "input (voltage)", "output": "output (displacement)",
         "target": "target (desired displacement)"}
_MISSING_CELLS = frozenset({"", "nan", "-nan", "+nan", "na", "n/a", "#n/a", "null", "none"})

_DECIMAL_COMMA_RE = r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?"
#: a number an English export writes with a thousands separator ("1,234", "-12,345,678")
_THOUSANDS_COMMA_RE = r"[-+]?[1-9]\d{0,2}(?:,\d{3})+"
_BRACKET_RE = re.compile(r"^(.*?)\s*[\[\(\{]\s*([^\]\)\}]*?)\s*[\]\)\}]\s*$")
_SUFFIX_RE = re.compile(r"^(.*?)[_\s]+([A-Za-zµμ]+)$")
#: the quantity/unit form of DIN 1313 and ISO 80000-1 (``Weg/mm``, ``U / mV``, ``t/s``)
_SLASH_RE = re.compile(r"^(.*?\S)\s*/\s*([A-Za-zµμ]+)$")


def _norm(text: str) -> str:
    """Lower case, trimmed, inner blanks/dashes → ``_``, no leading/trailing ``_``."""
    return re.sub(r"[\s\-]+", "_", str(text).strip().lower()).strip("_")


def _interpretations(name: str) -> list[tuple[str, str | None]]:
    """Possible ``(base, unit)`` readings of a column name, most literal first."""
    out: list[tuple[str, str | None]] = [(_norm(name), None)]
    m = _BRACKET_RE.match(str(name).strip())
    if m:
        out.append((_norm(m.group(1)), m.group(2).strip().lower()))
    m = _SUFFIX_RE.match(str(name).strip())
    if m:
        out.append((_norm(m.group(1)), m.group(2).lower()))
    m = _SLASH_RE.match(str(name).strip())
    if m:
        out.append((_norm(m.group(1)), m.group(2).lower()))
    return out


def _is_candidate(name: str, role: str) -> bool:
    """True when ``name`` reads as an alias of ``role`` with no unit or a known unit."""
    return any(base in _ALIASES[role] and (unit is None or unit in _UNITS[role])
               for base, unit in _interpretations(name))


def _unit_of(name: str | None, role: str) -> str | None:
    """The unit text (lower case) a column name gives for ``role``, or None."""
    if name is None:
        return None
    for base, unit in _interpretations(name):
        if unit is not None and unit in _UNITS[role]:
            return unit
        if unit is None and base in _IMPLIED_UNIT and base in _ALIASES[role]:
            return _IMPLIED_UNIT[base]
    return None


def _bad_unit_hint(names: Sequence[str], role: str) -> str:
    """Text naming columns whose base is an alias of ``role`` but whose unit is unknown."""
    bad = [n for n in names if not _is_candidate(n, role)
           and any(b in _ALIASES[role] and u is not None for b, u in _interpretations(n))]
    if not bad:
        return ""
    units = ", ".join(k for k in _UNITS[role] if k.isascii())
    return f" ({', '.join(repr(n) for n in bad)}: unit not recognised, known units: {units})"


# ----------------------------------------------------------------------------------------------
# Options and sidecars
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoadOptions:
    """How to read captures (CLI flags; defaults mean "detect").

    Attributes
    ----------
    time_col, input_col, output_col : column name or 0-based index (int or digit string); None
        auto-detects by name.
    no_header : the file has no header row (columns must then be given by index).
    fs : sample rate (Hz) for files without a time column.
    drop_nonfinite : repair rows with NaN/inf/empty cells instead of refusing the file: drop them at
        the start and end, interpolate short runs inside the data (see :func:`_nonfinite`).
    condition : ``(amplitude_V, frequency_Hz)`` forced by ``--condition`` (V peak-to-peak, Hz).
    output_unit : output unit (nm, um, mm, m) when the output column name has no unit suffix.
    require_output : False for input-only / target files (the output column is then optional).
    min_cycles : minimum number of input cycles after trimming.
    start_s, stop_s : keep only the window [start_s, stop_s) of the capture, in seconds from its
        first row (``--start``/``--stop``); None = from the start / to the end.
    warmup_s : seconds at the start of each capture (after the idle trim and the window) that fits
        simulate but do not score (``--warmup``): the actuator's unknown initial state settles.
    """

    time_col: str | int | None = None
    input_col: str | int | None = None
    output_col: str | int | None = None
    no_header: bool = False
    fs: float | None = None
    drop_nonfinite: bool = False
    condition: tuple[float, float] | None = None
    output_unit: str | None = None
    require_output: bool = True
    min_cycles: float = 2.0
    start_s: float | None = None
    stop_s: float | None = None
    warmup_s: float = 0.0


_SIDECAR_KEYS = ("no_header", "time_col", "input_col", "output_col", "fs", "output_unit", "condition",
                 "drop_nonfinite")
#: Documentation keys a sidecar may carry; ignored (as is any key starting with ``_``).
_SIDECAR_INFO_KEYS = frozenset({"comment", "comments", "source", "notes", "description", "license", "attribution"})


def sidecar_path(path: str | os.PathLike) -> Path:
    """The sidecar of a capture: ``<file>.hystfit.json`` next to it."""
    return Path(str(path) + SIDECAR_SUFFIX)


def _sidecar_value(sc: Path, key: str, val):
    """Validate one sidecar value; returns it in LoadOptions form or raises InputError."""
    def bad(rule: str) -> InputError:
        return InputError(f"{sc}: key {key!r}: {rule} (got {json.dumps(val)}); fix or delete the sidecar")

    if val is None:
        if key in ("no_header", "drop_nonfinite"):
            raise bad("must be true or false")
        return None
    if key in ("no_header", "drop_nonfinite"):
        if not isinstance(val, bool):
            raise bad("must be true or false")
        return val
    if key.endswith("_col"):
        if isinstance(val, bool) or not isinstance(val, (int, str)) or (isinstance(val, int) and val < 0):
            raise bad("must be a column name or a 0-based index")
        if isinstance(val, str):
            if not val.strip():
                raise bad("must be a column name or a 0-based index")
            return int(val.strip()) if val.strip().isdigit() else val
        return val
    if key == "fs":
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not (math.isfinite(val) and val > 0):
            raise bad("must be a positive sample rate in Hz")
        return float(val)
    if key == "output_unit":
        unit = _UNITS["output"].get(str(val).strip().lower()) if isinstance(val, str) else None
        if unit is None:
            raise bad("must be one of nm, um, mm, m")
        return unit
    # condition
    ok = isinstance(val, list) and len(val) == 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in val) and is_valid_condition(*val)
    if not ok:
        raise bad(f"must be [amplitude_V, frequency_Hz]: {CONDITION_RULE}")
    return (float(val[0]), float(val[1]))


def _apply_sidecar(path: Path, options: LoadOptions) -> tuple[LoadOptions, list[str]]:
    """Merge ``<file>.hystfit.json`` under ``options`` (non-default options win)."""
    sc = sidecar_path(path)
    if not sc.is_file():
        return options, []
    try:
        data = json.loads(sc.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else str(exc).splitlines()[0]
        raise InputError(f"{sc}: cannot read the sidecar as JSON ({reason}); fix or delete it") from None
    if not isinstance(data, dict):
        raise InputError(f"{sc}: the sidecar must be a JSON object of settings; fix or delete it")
    defaults = LoadOptions()
    updates = {}
    for key, val in data.items():
        if key.startswith("_") or key in _SIDECAR_INFO_KEYS:
            continue
        if key not in _SIDECAR_KEYS:
            raise InputError(f"{sc}: key {key!r} is not a sidecar setting; use {', '.join(_SIDECAR_KEYS)}")
        v = _sidecar_value(sc, key, val)
        if getattr(options, key) == getattr(defaults, key):
            updates[key] = v
    note = [f"settings from {sc.name}: {', '.join(sorted(updates))}"] if updates else []
    return dataclasses.replace(options, **updates), note


# ----------------------------------------------------------------------------------------------
# Paths
# ----------------------------------------------------------------------------------------------


def _is_capture_file(p: Path) -> bool:
    name = p.name
    if name.startswith(".") or name.lower().startswith("readme") or name.lower().endswith(".json"):
        return False
    return p.is_file() and p.suffix.lower() in CAPTURE_SUFFIXES


def expand_paths(paths: Sequence[str | os.PathLike], recursive: bool = False) -> list[Path]:
    """Files to load, in order.

    Parameters
    ----------
    paths : files (taken as given) and directories (expanded to their capture files, sorted;
        README, ``*.json`` sidecars and hidden entries skipped).
    recursive : also descend into sub-directories (hidden ones skipped).

    Raises
    ------
    InputError
        No paths, a missing path, or a directory without capture files.
    """
    if not paths:
        raise InputError("no capture files given; pass one or more files or directories")
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = _dir_captures(p, recursive)
            if not found:
                kinds = ", ".join(CAPTURE_SUFFIXES)
                hint = "" if recursive else " (pass --recursive to look in sub-directories)"
                raise InputError(f"{p}: directory contains no capture file ({kinds}){hint}")
            out.extend(found)
        elif p.exists():
            out.append(p)
        else:
            raise InputError(f"{p}: no such file or directory; check the path")
    seen: set[Path] = set()
    unique = []
    for p in out:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def _dir_captures(d: Path, recursive: bool) -> list[Path]:
    if not recursive:
        return sorted(p for p in d.iterdir() if _is_capture_file(p))
    found = []
    for p in d.rglob("*"):
        rel = p.relative_to(d).parts
        if any(part.startswith(".") for part in rel[:-1]):
            continue
        if _is_capture_file(p):
            found.append(p)
    return sorted(found)


# ----------------------------------------------------------------------------------------------
# Reading tables
# ----------------------------------------------------------------------------------------------


@dataclass
class _Table:
    """A raw table: column cells plus the 1-based file line (text) or data row (Parquet) of each row.

    A column is a pandas Series (the general text reader: strings; Parquet: as stored) or, from the
    fast reader, a float64 numpy array with NaN for missing cells (:func:`_cell` reads either).
    """

    label: str
    names: list[str] | None
    cols: list
    rows: np.ndarray
    header_auto: bool = False
    #: a cell "1,5" may be a decimal comma (European locale exports): the text reader's cells, where
    #: the delimiter is not a comma or the cell was quoted in a comma-separated file
    comma_decimal_ok: bool = False
    #: the delimiter is a comma: a cell with a comma was quoted, and "1,234" may also be an English
    #: thousands separator (:func:`_numeric` then asks)
    comma_delimited: bool = False
    #: what the reader did that the user should know (a preamble skipped), for the capture's notes
    notes: tuple[str, ...] = ()

    @property
    def ncols(self) -> int:
        return len(self.cols)

    def col_label(self, i: int) -> str:
        return f"column {self.names[i]!r}" if self.names is not None else f"column {i}"

    def listing(self) -> str:
        if self.names is None:
            return f"{self.ncols} unnamed columns (0-based indices 0–{self.ncols - 1})"
        return "columns: " + ", ".join(f"{i}:{n!r}" for i, n in enumerate(self.names))

    def is_empty(self, i: int) -> bool:
        s = self.cols[i]
        if isinstance(s, np.ndarray):
            return bool(np.isnan(s).all())
        if s.dtype.kind in "fiub":
            return bool(s.isna().all())
        return bool(s.isna().all() or (s.astype(str).str.strip() == "").all())


def _decode(raw: bytes, label: str) -> str:
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    if b"\x00" in raw[:8192]:
        raise InputError(f"{label}: looks like a binary file, not text; pass a CSV/TXT/TSV/DAT or Parquet capture")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _sniff(lines: list[str]) -> str | None:
    """Delimiter of the data lines: tab, ';' or ',' when present on every line, else whitespace (None)."""
    body = lines[1:] or lines
    for cand in ("\t", ";", ","):
        counts = {ln.count(cand) for ln in body}
        if min(counts) > 0 and len(counts) == 1:
            return cand
    for cand in ("\t", ";", ","):
        if all(ln.count(cand) > 0 for ln in lines):
            return cand
    return None


def _is_number_or_empty(cell: str) -> bool:
    cell = cell.strip()
    if not cell:
        return True
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _unit_row(cells: Sequence[str]) -> bool:
    """Whether a row under the names is their units (``s, V, um`` or ``[s], [V], [µm]``): every
    non-empty cell a unit some role knows, in brackets or not, and at least one."""
    known = {u for units in _UNITS.values() for u in units}
    texts = [c.strip().strip('"').strip() for c in cells]
    texts = [t[1:-1].strip() if len(t) > 1 and t[0] in "[({" and t[-1] in "])}" else t for t in texts]
    return any(texts) and all(not t or t.lower() in known for t in texts)


def _with_units(names: Sequence[str], units: Sequence[str]) -> list[str]:
    """Names and a unit row merged as ``name [unit]`` (a name without a unit stays as it is)."""
    out = []
    for n, u in zip(names, units):
        u = u.strip().strip('"').strip()
        u = u[1:-1].strip() if len(u) > 1 and u[0] in "[({" and u[-1] in "])}" else u
        out.append(f"{n.strip()} [{u}]" if u else n.strip())
    return out


#: most lines a preamble may have, and the lines of the table after it that decide its shape
PREAMBLE_MAX_LINES = 100
_PREAMBLE_TABLE_LINES = 20


def _preamble(lines: list[str]) -> int:
    """How many leading lines of a text capture are a preamble (0 for none): the block of text a
    DAQ program, an oscilloscope or a LabVIEW measurement file writes before its table (operator,
    date, ``Record Length,10000,Points``, ``***End_of_Header***``).

    ``lines``: the file's first lines, blank and ``#`` comment lines removed. The table's shape is
    that of its last line, a data row: a number of cells, every one a number (a decimal comma too
    where the delimiter is not a comma) or empty. Its header is the last line before it with as
    many cells, none of them a number (with the line before it when the header holds only units: the
    names, then their units, ``Time;Voltage`` over ``s;V``); everything before the header is the
    preamble, when it holds
    no data row and is at most :data:`PREAMBLE_MAX_LINES` lines. So a bad row among the data (a
    text cell, a ragged or an all-text row) is never taken for a preamble: it is read as part of
    the table, whose reader names it by its line in the file — after the header (still a table),
    or with data rows before it (no preamble).

    A table without a header after a preamble (a logger that writes its settings, then bare rows of
    numbers) is recognized too when every preamble line holds a text cell: ``header`` is then False
    and the columns are chosen by index (``--time-col`` …), as in any headerless file.

    Returns
    -------
    (lines, header)
        The preamble's length (0: none) and whether the table after it starts with a header.
    """
    head = lines[: PREAMBLE_MAX_LINES + 1 + _PREAMBLE_TABLE_LINES]
    if len(head) < 3:
        return 0, True
    delim = _sniff(head[-_PREAMBLE_TABLE_LINES:])

    def cells(line: str) -> list[str]:
        if delim is None:
            return [c.strip().strip('"') for c in line.split()]
        # quotes respected: a comma-separated export quotes its decimal-comma cells ("0,25")
        return [c.strip().strip('"') for c in next(csv.reader([line], delimiter=delim), [])]

    def number(cell: str) -> bool:
        # a decimal comma: where the delimiter is a comma, a cell holding one was quoted
        return bool(cell) and _is_number_or_empty(cell.replace(",", ".") if delim is not None else cell)

    rows = [cells(ln) for ln in head]
    width = len(rows[-1])

    def data_row(c: list[str]) -> bool:
        return len(c) == width and all(not x or number(x) for x in c) and any(c)

    def header_row(c: list[str]) -> bool:
        return len(c) == width and any(c) and not any(number(x) for x in c)

    if width < 2 or not data_row(rows[-1]):
        return 0, True
    h = max((i for i, c in enumerate(rows[:-1]) if header_row(c)), default=0)
    if h == 0 and header_row(rows[0]):
        return 0, True  # the header is the first line: no preamble
    if h == 0:  # no header: the table is the data rows after the last line that is not one
        k = max((i for i, c in enumerate(rows[:-1]) if not data_row(c)), default=-1) + 1
        # every preamble line starts with text (a key, a title): a bad data row (a number, then a
        # text cell; a ragged row of numbers) is not one, and stays the table's, named by its error
        text = all(c[0] and not number(c[0]) for c in rows[:k])
        return (k, False) if 0 < k <= PREAMBLE_MAX_LINES and text else (0, True)
    if h >= 1 and _unit_row(rows[h]) and header_row(rows[h - 1]) and not _unit_row(rows[h - 1]):
        h -= 1  # names, then their units: the header is two lines
    if h > PREAMBLE_MAX_LINES or any(data_row(c) for c in rows[:h]):
        return 0, True
    return h, True


#: text captures at least this large are first read by pyarrow's multi-threaded CSV parser, straight
#: to float64 (:func:`_read_text_fast`); smaller ones, and any file it declines, by the general reader.
#: A typical capture (5,000 rows, ≈ 120 kB) is read in ≈ 8 ms less, and a command whose captures
#: all take this path never imports pandas (≈ 0.3 s; short captures of 15–30 kB too, hence 4 kB);
#: the tiny hand-made files of the bad-input corpus still meet the general reader first.
FAST_READ_BYTES = 1 << 12
#: cells read as missing by the fast reader: :data:`_MISSING_CELLS` in the spellings files use
_FAST_NULLS = sorted({v for c in _MISSING_CELLS for v in (c, c.upper(), c.title(), c.capitalize())} | {"NaN", "N/A"})


def _read_text_fast(path: Path, label: str, no_header: bool) -> _Table | None:
    """The table of a large, plain, all-numeric delimited file, read by pyarrow; None to use the general reader.

    Reads only what the general reader would read the same way: a UTF-8 file without byte-order
    mark, one ``,``/``;``/tab delimiter, no blank or comment line, every cell a number or a
    missing-value word (:data:`_MISSING_CELLS`), no trailing empty row. Anything else (text
    cells, padded cells, ragged rows, decimal commas) makes pyarrow fail and the general reader
    run, which words every error: behaviour and messages do not depend on this path, only the
    time (10⁷ rows: ≈ 3 s instead of ≈ 130 s) and memory (float64 columns instead of strings).
    """
    try:
        if path.stat().st_size < FAST_READ_BYTES:
            return None
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return None
    if head.startswith((b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff")) or b"\x00" in head or head.lstrip()[:1] == b"#":
        return None
    if b"\r" in head.replace(b"\r\n", b""):
        return None
    try:
        lines = head.decode("utf-8").split("\n")[:-1][:51]  # the last piece may be cut
    except UnicodeDecodeError:
        return None
    lines = [ln.rstrip("\r") for ln in lines]
    if len(lines) < 2 or any(not ln.strip() for ln in lines):
        return None
    skip, headed = _preamble(lines)
    if no_header and headed:
        skip = 0  # --no-header: a header row found after a preamble is read as the user says (an error)
    if skip and skip + 3 > len(lines):
        return None  # a long preamble: the general reader reads enough lines to find the table
    lines = lines[skip:]
    delim = _sniff(lines[:50])
    if delim is None:
        return None

    first = next(csv.reader([lines[0]], delimiter=delim))
    ncols = len(first)
    header = not no_header and not all(_is_number_or_empty(c) for c in first)
    if skip and header != headed:
        return None
    if ncols < 2:
        return None
    try:
        import pyarrow as pa
        from pyarrow import csv as pcsv

        names = [f"c{i}" for i in range(ncols)]
        # blank lines are kept as rows of missing cells (declined below), so row numbers stay line
        # numbers; a comment line fails as a ragged row or as a cell that is not a number
        tab = pcsv.read_csv(path, read_options=pcsv.ReadOptions(column_names=names,
                                                                 skip_rows=skip + (1 if header else 0),
                                                                 block_size=1 << 24),
                            parse_options=pcsv.ParseOptions(delimiter=delim, ignore_empty_lines=False),
                            convert_options=pcsv.ConvertOptions(column_types={n: pa.float64() for n in names},
                                                                null_values=_FAST_NULLS, strings_can_be_null=False))
    except Exception:  # pyarrow.ArrowInvalid and kin: not plain numeric text, the general reader decides
        return None
    n = tab.num_rows
    if n == 0:
        return None
    if tab.column(0).null_count and all(tab.column(i).null_count for i in range(1, ncols)):
        all_null = np.ones(n, dtype=bool)
        for i in range(ncols):
            all_null &= ~_present(tab.column(i))
        if all_null.any():
            return None  # a blank line or an empty row: the general reader skips, trims or reports it
    cols = [_float64_column(tab.column(i)) for i in range(ncols)]
    del tab
    rows = np.arange(1, n + 1, dtype=np.int64) + skip + (1 if header else 0)
    return _Table(label, [c.strip() for c in first] if header else None, cols, rows,
                  header_auto=not no_header and not header, comma_decimal_ok=delim != ",",
                  notes=(_preamble_note(1, skip, skip + 1, header),) if skip else ())


def _float64_column(column) -> np.ndarray:
    """A pyarrow float64 column as a numpy array, NaN for a missing cell — without pandas, which
    pyarrow's own ``to_numpy`` imports (≈ 0.3 s), nor ``pyarrow.compute`` (≈ 0.5 s)."""
    arr = column.chunk(0) if column.num_chunks == 1 else column.combine_chunks()
    values = np.frombuffer(arr.buffers()[1], dtype=np.float64, count=len(arr), offset=8 * arr.offset)
    if arr.null_count:
        values = values.copy()  # a missing cell's slot holds no defined value: NaN written there
        values[~_present(arr)] = np.nan
    return values


def _present(column) -> np.ndarray:
    """Where a pyarrow array or column has a value (not a missing cell): its validity bitmaps read
    as numpy booleans (one bit per cell, least significant bit first, from the array's offset)."""
    chunks = column.chunks if hasattr(column, "chunks") else [column]
    parts = []
    for arr in chunks:
        bitmap = arr.buffers()[0]
        if bitmap is None or not arr.null_count:
            parts.append(np.ones(len(arr), dtype=bool))
            continue
        bits = np.unpackbits(np.frombuffer(bitmap, dtype=np.uint8), bitorder="little")
        parts.append(bits[arr.offset: arr.offset + len(arr)].astype(bool))
    return np.concatenate(parts) if len(parts) != 1 else parts[0]


def _read_text(path: Path, label: str, no_header: bool) -> _Table:
    fast = _read_text_fast(path, label, no_header)
    if fast is not None:
        return fast
    import pandas as pd

    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{label}: cannot read the file ({exc.strerror or exc}); "
                         "check the path and permissions") from None
    if not raw.strip():
        raise InputError(f"{label}: the file is empty; pass a capture with a header row and data rows")
    numbered = [(i + 1, ln) for i, ln in enumerate(_decode(raw, label).splitlines())
                if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise InputError(f"{label}: the file has only comments or blank lines, no data; pass a capture with data rows")
    lines = [ln for _, ln in numbered]
    notes: tuple[str, ...] = ()
    skip, headed = _preamble(lines)
    if no_header and headed:
        skip = 0  # --no-header: a header row found after a preamble is read as the user says (an error)
    if skip:
        notes = (_preamble_note(numbered[0][0], numbered[skip - 1][0], numbered[skip][0], headed),)
        numbered, lines = numbered[skip:], lines[skip:]
    delim = _sniff(lines[:50])
    text = "\n".join(ln.strip() if delim is None else ln for ln in lines)
    try:
        df = pd.read_csv(_stdio.StringIO(text), sep=delim if delim is not None else r"\s+", header=None, dtype=str,
                         na_filter=False, keep_default_na=False, skipinitialspace=True, skip_blank_lines=False,
                         engine="c")
    except pd.errors.ParserError as exc:
        raise _parser_error(label, exc, numbered) from None
    rows = np.array([n for n, _ in numbered], dtype=np.int64)
    first = [str(c) for c in df.iloc[0]]
    header_auto = not no_header and all(_is_number_or_empty(c) for c in first)
    names = None
    if not no_header and not header_auto:
        names = [c.strip() for c in first]
        df, rows = df.iloc[1:], rows[1:]
        if len(df) > 1 and _unit_row([str(c) for c in df.iloc[0]]):  # the names, then their units
            names = _with_units(names, [str(c) for c in df.iloc[0]])
            notes = notes + (f"line {rows[0]} holds the columns' units: read as {', '.join(map(repr, names))}",)
            df, rows = df.iloc[1:], rows[1:]
        if df.empty:
            raise InputError(f"{label}: the file has a header row but no data rows; pass a capture with data")
    # rows with every cell empty at the end of the file (a trailing ",,," line) are not data
    empty = (df.apply(lambda col: col.str.strip()) == "").all(axis=1).to_numpy()
    n_keep = len(empty)
    while n_keep > 1 and empty[n_keep - 1]:
        n_keep -= 1
    if n_keep < len(empty):
        df, rows = df.iloc[:n_keep], rows[:n_keep]
    cols = [df[c].reset_index(drop=True) for c in df.columns]
    return _Table(label, names, cols, rows, header_auto, comma_decimal_ok=True, comma_delimited=delim == ",",
                  notes=notes)


def _preamble_note(first: int, last: int, header: int, headed: bool = True) -> str:
    """The note of a skipped preamble (file lines, 1-based); ``header``: the table's first line,
    its header unless ``headed`` is False."""
    lines = f"lines {first}–{last}" if last > first else f"line {first}"
    table = (f"the header is line {header}" if headed else
             f"the table starts at line {header}, without a header row (columns by index)")
    return f"skipped the preamble before the table ({lines}); {table}"


def _parser_error(label: str, exc: Exception, numbered: list[tuple[int, str]]) -> InputError:
    m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
    if m:
        want, line, got = int(m.group(1)), int(m.group(2)), int(m.group(3))
        row = numbered[line - 1][0] if 0 < line <= len(numbered) else line
        return InputError(f"{label}: row {row}: {got} fields but the first row has {want} (every row needs the "
                          f"same number of columns); fix the row or remove it")
    reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    return InputError(f"{label}: cannot parse the file as delimited text ({reason}); check the file format")


def _index_as_column(df):
    """A DataFrame written by pandas with its time as the index (``df.set_index('time_s')``, a
    DatetimeIndex or TimedeltaIndex of a logger) with that index as its first column: named as it
    was, ``time`` when it is an unnamed time axis. A plain row number (RangeIndex) is left out."""
    import pandas as pd

    idx = df.index
    if isinstance(idx, pd.RangeIndex) or isinstance(idx, pd.MultiIndex):
        return df
    timeaxis = isinstance(idx, (pd.DatetimeIndex, pd.TimedeltaIndex))
    if idx.name is None and not timeaxis:
        return df
    name = str(idx.name) if idx.name is not None else "time"
    if name in map(str, df.columns):
        return df
    out = df.reset_index(drop=True)
    out.insert(0, name, idx.to_numpy())
    return out


def _as_seconds(col):
    """A time column of datetimes or durations as seconds (float) since its first sample; any
    other column as it is."""
    import pandas as pd

    if pd.api.types.is_timedelta64_dtype(col):
        return col.dt.total_seconds()
    if pd.api.types.is_datetime64_any_dtype(col):
        return (col - col.iloc[0]).dt.total_seconds()
    return col


def _read_parquet(path: Path, label: str) -> _Table:
    import pandas as pd

    try:
        import pyarrow.parquet as pq

        names = pq.read_schema(path).names
    except Exception:  # a corrupt file: read_parquet below says so
        names = []
    twice = sorted({n for n in names if names.count(n) > 1 and not n.startswith("__index_level_")})
    if twice:  # pyarrow's own message was "Multiple matches for FieldRef.Name(…)", a blind test's find
        raise InputError(f"{label}: the Parquet file has {len(twice)} column name(s) used twice ("
                         f"{', '.join(map(repr, twice))}); give every column its own name")
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises many types for corrupt files
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{label}: cannot read the Parquet file ({reason}); "
                         "check that it is a valid Parquet file") from None
    if df.shape[1] == 0:
        raise InputError(f"{label}: the Parquet file has no columns; "
                         "pass a capture with time, input and output columns")
    if df.shape[0] == 0:
        raise InputError(f"{label}: the Parquet file has columns but no data rows; pass a capture with data")
    df = _index_as_column(df)
    cols = [_as_seconds(df.iloc[:, i].reset_index(drop=True)) for i in range(df.shape[1])]
    return _Table(label, [str(c) for c in df.columns], cols, np.arange(1, df.shape[0] + 1, dtype=np.int64))


def _read_table(path: Path, label: str, no_header: bool) -> _Table:
    if path.is_dir():
        raise InputError(f"{label}: is a directory; pass capture files, or use load_captures to expand directories")
    if not path.exists():
        raise InputError(f"{label}: no such file; check the path")
    suffix = path.suffix.lower()
    if suffix in PARQUET_SUFFIXES:
        return _read_parquet(path, label)
    if suffix in CAPTURE_SUFFIXES:
        return _read_text(path, label, no_header)
    raise InputError(f"{label}: unsupported file type {suffix or '(no suffix)'!r}; "
                     f"use one of {', '.join(CAPTURE_SUFFIXES)}")


def _cell(column, k: int):
    """Cell ``k`` of a table column (a pandas Series or a numpy array)."""
    return column[k] if isinstance(column, np.ndarray) else column.iloc[k]


def _cell_text(table: _Table, col: int, k: int) -> str:
    text = str(_cell(table.cols[col], k))
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _time_values(table: _Table, col: int, notes: list[str]) -> np.ndarray:
    """The time column as numbers (:func:`_numeric`), or, when its cells are date-times (a logger's
    ``2026-11-28 10:00:00.000200``, ISO 8601), as seconds since its first one, said in a note. A
    column of neither keeps :func:`_numeric`'s error, naming the first bad cell."""
    try:
        return _numeric(table, col)
    except InputError:
        s = table.cols[col]
        if isinstance(s, np.ndarray) or s.dtype.kind in "fiub":
            raise
        import pandas as pd

        text = s.astype(str).str.strip()
        if not re.match(r"\d{4}-\d{2}-\d{2}[T ]\d", str(text.iloc[0])):
            raise
        stamps = pd.to_datetime(text, format="ISO8601", errors="coerce")
        bad = np.flatnonzero(stamps.isna().to_numpy())
        if bad.size:
            k = int(bad[0])
            raise InputError(f"{table.label}: row {table.rows[k]}, {table.col_label(col)}: {_cell_text(table, col, k)} "
                             "is not a date-time like the column's others (ISO 8601, e.g. 2026-11-28 10:00:00.0002); "
                             "fix the cell or remove the row")
        notes.append(f"{table.col_label(col)} holds date-times: time in seconds since {text.iloc[0]}")
        return (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy(dtype=np.float64)


def _numeric(table: _Table, col: int) -> np.ndarray:
    """Column ``col`` as float64 (NaN for empty/missing cells); non-numeric text → InputError."""
    s = table.cols[col]
    if isinstance(s, np.ndarray):  # float64 from the fast reader: a read-only view, as pandas gives
        view = s.view()
        view.flags.writeable = False
        return view
    if s.dtype.kind == "b":  # true/false (a Parquet bool column): no measurement (a blind test's 0/1 V "voltage")
        raise InputError(f"{table.label}: {table.col_label(col)} holds true/false values, not numbers; choose "
                         "another column (--input-col, --output-col, --time-col) or write the values as numbers")
    if s.dtype.kind in "fiu":
        return s.to_numpy(dtype=np.float64, na_value=np.nan)
    import pandas as pd

    text = s.astype(str).str.strip()
    num = pd.to_numeric(text, errors="coerce")
    bad = np.flatnonzero((num.isna() & ~text.str.lower().isin(_MISSING_CELLS) & s.notna()).to_numpy())
    decimal = text.str.fullmatch(_DECIMAL_COMMA_RE).iloc[bad].to_numpy() if bad.size else np.zeros(0, bool)
    if bad.size and table.comma_decimal_ok and decimal.all():
        # a ';'/tab/space-separated export with decimal commas (e.g. "0,25"), or a comma-separated one
        # that quotes them ("0,25","1,5"): read ',' as the decimal mark — unless every such cell of a
        # comma-separated file could be an English thousands separator ("1,234": 1.234 or 1234?)
        if table.comma_delimited and text.iloc[bad].str.fullmatch(_THOUSANDS_COMMA_RE).all():
            k = int(bad[0])
            raise InputError(f"{table.label}: row {table.rows[k]}, {table.col_label(col)}: {_cell_text(table, col, k)} "
                             "is ambiguous: a quoted number with a comma in a comma-separated file is read as a "
                             "decimal comma, but every such cell of this column could also be an English thousands "
                             "separator (1.234 or 1234?); write the numbers with '.' as the decimal mark and no "
                             "thousands separator, or use ';' as the delimiter")
        text = text.str.replace(",", ".", regex=False)
        num = pd.to_numeric(text, errors="coerce")
        bad = np.flatnonzero((num.isna() & ~text.str.lower().isin(_MISSING_CELLS) & s.notna()).to_numpy())
    elif bad.size and table.comma_decimal_ok and decimal.any():
        # decimal commas, but some cells are not read so (a blind test's "5.261,0": a '.' thousands
        # separator): name the first of those, not the first decimal-comma cell
        k = int(bad[~decimal][0])
        cell = str(text.iloc[k])
        hint = (" (the column's other cells use decimal commas; a '.' thousands separator is not read: remove it)"
                if re.fullmatch(r"[-+]?\d{1,3}(\.\d{3})+,\d+", cell) else " (the column's other cells use decimal commas)")
        raise InputError(f"{table.label}: row {table.rows[k]}, {table.col_label(col)}: {_cell_text(table, col, k)} "
                         f"is not a number{hint}; fix the cell or remove the row")
    if bad.size:
        k = int(bad[0])
        cell = str(text.iloc[k])
        hint = (" (decimal commas are read only when the delimiter is not a comma: use '.' or ';')"
                if re.fullmatch(r"[-+]?\d+,\d+", cell) else "")
        if k == 0 and table.names is None and not table.header_auto:
            hint += " (is the first row a header? then do not pass --no-header)"
        raise InputError(f"{table.label}: row {table.rows[k]}, {table.col_label(col)}: {_cell_text(table, col, k)} "
                         f"is not a number{hint}; fix the cell or remove the row")
    return num.to_numpy(dtype=np.float64, na_value=np.nan)


# ----------------------------------------------------------------------------------------------
# Column selection
# ----------------------------------------------------------------------------------------------


def _resolve_spec(table: _Table, spec: str | int, role: str) -> int:
    """Column index of an explicit ``--<role>-col`` value (name or 0-based index)."""
    flag = _FLAGS[role]
    if isinstance(spec, str) and spec.strip().isdigit():
        spec = int(spec.strip())
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        if not 0 <= spec < table.ncols:
            raise InputError(f"{table.label}: {flag} {spec}: no such column; the file has {table.ncols} columns "
                             f"(0-based indices 0–{table.ncols - 1})")
        return int(spec)
    if table.names is None:
        raise InputError(f"{table.label}: {flag} {spec!r}: the file has no header row, so give the column as a "
                         f"0-based index (0–{table.ncols - 1})")
    hits = [i for i, n in enumerate(table.names) if n == spec]
    if not hits:
        hits = [i for i, n in enumerate(table.names) if n.lower() == str(spec).strip().lower()]
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise InputError(f"{table.label}: {flag} {spec!r}: several columns have this name (indices "
                         f"{', '.join(map(str, hits))}); pass {flag} as a 0-based index")
    raise InputError(f"{table.label}: {flag} {spec!r}: no such column; {table.listing()}")


def _auto_column(table: _Table, role: str, taken: set[int]) -> list[int]:
    """Indices of non-empty, not-yet-taken columns whose names read as ``role``."""
    if table.names is None:
        return []
    return [i for i, n in enumerate(table.names)
            if i not in taken and _is_candidate(n, role) and not table.is_empty(i)]


def _unit_column(table: _Table, role: str, taken: set[int]) -> list[int]:
    """Indices of non-empty, not-yet-taken columns whose name gives a unit of ``role`` in brackets
    (``Spannung [V]``, ``Ch1 (mV)``, ``Weg [µm]``, ``Zeit [s]``) or after a slash (DIN 1313:
    ``Weg/mm``, ``U/mV``) but reads as no role's alias: the columns a name in another language, or a
    channel name, leaves to their unit."""
    if table.names is None:
        return []
    out = []
    for i, n in enumerate(table.names):
        m = _BRACKET_RE.match(str(n).strip()) or _SLASH_RE.match(str(n).strip())
        if i in taken or m is None or m.group(2).strip().lower() not in _UNITS[role] or table.is_empty(i):
            continue
        if any(_is_candidate(n, other) for other in _ALIASES):
            continue  # an alias of some role (amplitude [V], frequency [Hz] …): its name decides
        out.append(i)
    return out


def _headerless_error(table: _Table, role: str, roles: Sequence[str] = ("time", "input", "output")) -> InputError:
    if table.header_auto:
        first = int(table.rows[0]) if len(table.rows) else 1
        where = "the first row" if first == 1 else f"line {first}, the table's first row,"
        why, alt = f"{where} is all numbers, so the file is read as having no header row", "add a header row"
    else:
        why, alt = "the file has no header row (--no-header)", "add a header row and drop --no-header"
    flags = [_FLAGS[r] for r in ("time", "input", "output", "target") if r in roles]
    listed = ", ".join(flags[:-1]) + " and " + flags[-1] if len(flags) > 1 else flags[0]
    return InputError(f"{table.label}: {why}: pass {listed} as 0-based indices "
                      f"(0–{table.ncols - 1}; missing: {_FLAGS[role]}), or {alt}")


def _select_roles(table: _Table, roles: Sequence[str], specs: Mapping[str, str | int | None],
                  optional: Sequence[str] = (), fallback: Mapping[str, str] | None = None,
                  notes: list[str] | None = None, unit_optional: Sequence[str] = ()) -> dict[str, int | None]:
    """Column index per role: explicit specs first (a name or 0-based index), then by name (alias
    and unit) in the order of ``roles``; each column serves one role. ``optional`` roles may be
    absent (None); ``fallback`` lets a role accept another role's names when none of its own is
    found. A role none of whose names is found takes the one column whose name gives its unit in
    brackets (:func:`_unit_column`; said in ``notes``), once every role has had its names — an
    ``optional`` role only when it is in ``unit_optional`` (the measured output of a capture that
    may have none: ``simulate`` finds ``Weg [µm]`` as ``identify`` does; the time column of a
    file read with ``--fs`` is not looked for). Every failure is one line naming the file, the
    column and the fix."""
    chosen: dict[str, int | None] = {}
    for role in roles:
        if specs.get(role) is not None:
            chosen[role] = _resolve_spec(table, specs[role], role)
    seen: dict[int, str] = {}
    for role, i in chosen.items():
        if i in seen:
            raise InputError(f"{table.label}: {table.col_label(i)} is selected both as {seen[i]} "
                             f"({_FLAGS[seen[i]]}) and as {role} ({_FLAGS[role]}); select different columns")
        seen[i] = role
    for by_unit in (False, True):
        for role in roles:
            if role in chosen or (by_unit and role in optional and role not in unit_optional):
                continue  # an optional role (--fs given: no time column needed) is found by its names only
            if by_unit:
                found = _unit_column(table, role, set(seen))
            else:
                found = _auto_column(table, role, set(seen))
                if not found and role in (fallback or {}):
                    found = _auto_column(table, fallback[role], set(seen))
            if len(found) > 1:
                cands = ", ".join(repr(table.names[i]) for i in found)
                how = " (by the unit in their names)" if by_unit else ""
                raise InputError(f"{table.label}: several {_WHAT[role]} columns{how}: {cands}; pass {_FLAGS[role]} "
                                 f"with the one to use")
            if found:
                chosen[role] = found[0]
                seen[found[0]] = role
                if by_unit and notes is not None:
                    notes.append(f"{_WHAT[role]} is {table.col_label(found[0])}, by the unit in its name "
                                 f"(pass {_FLAGS[role]} to choose another)")
    for role in roles:
        if role in chosen:
            continue
        chosen[role] = None
        if role in optional:
            continue
        if table.names is None and role != "time":
            raise _headerless_error(table, role, roles)
        raise _missing_column_error(table, role, seen)
    return chosen


def _select_columns(table: _Table, opts: LoadOptions, notes: list[str] | None = None) -> dict[str, int | None]:
    """Column index per role of a capture (time/input/output/amplitude/frequency); None when absent."""
    optional = [r for r, absent in (("time", opts.fs is not None), ("output", not opts.require_output)) if absent]
    chosen = _select_roles(table, ("input", "output", "time"),
                           {"time": opts.time_col, "input": opts.input_col, "output": opts.output_col}, optional,
                           notes=notes, unit_optional=("output",))
    taken = {i for i in chosen.values() if i is not None}
    for role in ("amplitude", "frequency"):
        found = _auto_column(table, role, taken)
        if len(found) > 1:
            cands = ", ".join(repr(table.names[i]) for i in found)
            raise InputError(f"{table.label}: several {role} columns: {cands}; keep only one")
        chosen[role] = found[0] if found else None
    return chosen


def _missing_column_error(table: _Table, role: str, seen: Mapping[int, str] | None = None) -> InputError:
    """The one-line error for a required column not found; ``seen``: column → the role already given
    to it (a column named for this role but taken by another's flag is said to be taken)."""
    for i, other in (seen or {}).items():
        if table.names is not None and other != role and _is_candidate(table.names[i], role):
            return InputError(f"{table.label}: column {i} {table.names[i]!r} reads as the {_WHAT[role]}, but it is "
                              f"taken as the {_WHAT[other]} ({_FLAGS[other]}); check {_FLAGS[other]}, or pass "
                              f"{_FLAGS[role]} for the {_WHAT[role]}")
    if role == "time":
        if table.names is None:
            return InputError(f"{table.label}: the file has no header row and no time column was given: pass "
                              f"--time-col INDEX (0–{table.ncols - 1}), or --fs HZ if the file has no time column")
        hint = _bad_unit_hint(table.names, role)
        return InputError(f"{table.label}: no time column found ({table.listing()}){hint}; "
                          f"pass --time-col NAME, or --fs HZ if the file has no time column")
    if role == "target":
        return InputError(f"{table.label}: no target (desired displacement) column found ({table.listing()}); "
                          "name it e.g. 'target_um' or 'displacement_um', or pass --target-col")
    examples = {"input": "voltage_V", "output": "displacement_um"}[role]
    empty = [i for i, n in enumerate(table.names or []) if _is_candidate(n, role) and table.is_empty(i)]
    if empty:  # the column is there, its cells are not: say so, not that it is missing
        i = empty[0]
        return InputError(f"{table.label}: column {i} {table.names[i]!r}, the {_WHAT[role]}, is empty (no cell has a "
                          f"value); check the export, or pass {_FLAGS[role]} NAME for another column")
    return InputError(f"{table.label}: no {_WHAT[role]} column found ({table.listing()})"
                      f"{_bad_unit_hint(table.names or [], role)}; pass {_FLAGS[role]} NAME or a 0-based index, "
                      f"or name the column e.g. {examples!r}")


@dataclass(frozen=True)
class TableColumns:
    """A file read as a table, with the columns of the requested roles found (:func:`load_table`).

    ``index`` maps each role to its 0-based column (None when an optional role is absent).
    """

    path: str
    table: _Table
    index: Mapping[str, int | None]

    @property
    def label(self) -> str:
        return self.table.label

    def describe(self, role: str) -> str:
        """The column of ``role`` as the messages name it (``column 'target_um'`` or ``column 2``)."""
        return self.table.col_label(self.index[role])

    def unit(self, role: str) -> str | None:
        """The unit the column's name gives (normalized: ``um``, ``ms`` …), None when it gives none."""
        u = _col_unit(self.table, self.index[role], role)
        if u is not None and isinstance(_UNITS[role][u], str):
            return str(_UNITS[role][u])
        return u

    def values(self, role: str) -> np.ndarray:
        """The column as float64, in SI for time/input (s, V) and as written for outputs/targets; a
        non-finite cell is an :class:`InputError` naming its row and column."""
        i = self.index[role]
        x = _numeric(self.table, i)
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            k = int(bad[0])
            raise InputError(f"{self.label}: row {self.table.rows[k]}, {self.table.col_label(i)}: not a finite "
                             "number; fix or remove the row")
        if role in ("time", "input"):
            x = x * _scale(self.table, i, role)
        return x

    def sample_period(self, t: np.ndarray) -> float:
        """dt (s) of a strictly increasing, uniform time column (one-line error otherwise)."""
        return _check_time(self.table, self.index["time"], t, self.table.rows)


def load_table(path: str | os.PathLike, roles: Sequence[str], *, columns: Mapping[str, str | int | None] | None = None,
               optional: Sequence[str] = (), fallback: Mapping[str, str] | None = None,
               no_header: bool = False) -> TableColumns:
    """Read a CSV/TXT/TSV/DAT or Parquet file and find the column of every role — the one reader
    and column matching behind captures (:func:`load_capture`) and feedforward targets
    (:func:`hystfit.invert.load_target`).

    Parameters
    ----------
    roles : e.g. ``("time", "target")``; names by alias and unit suffix (``time_ms``,
        ``target_um``), case-insensitive; each column serves one role.
    columns : explicit columns per role (a name or a 0-based index), as ``--time-col`` etc.
    optional : roles that may be absent (their index is None).
    fallback : role → another role whose names are accepted when none of its own is found
        (``{"target": "output"}``: a target file may name its column ``displacement_um``).
    """
    table = _read_table(Path(path), str(path), no_header)
    chosen = _select_roles(table, roles, dict(columns or {}), optional, fallback)
    return TableColumns(str(path), table, chosen)


# ----------------------------------------------------------------------------------------------
# Validation steps
# ----------------------------------------------------------------------------------------------


#: Longest run of consecutive non-finite rows inside the data that ``--drop-nonfinite`` repairs by
#: linear interpolation (dropping them would make the sampling non-uniform).
MAX_INTERPOLATED_RUN = 3
#: above this share of a capture's rows interpolated by --drop-nonfinite, the note is a warning
MAX_INTERPOLATED_SHARE = 0.01


def _nonfinite(table: _Table, arrays: dict[str, tuple[int, np.ndarray]], drop: bool,
               notes: list[str]) -> tuple[np.ndarray | None, dict[str, tuple[int, np.ndarray]]]:
    """Handle NaN/inf/empty cells: refuse them, or (``drop``) repair them.

    Returns the row mask to keep (None: keep all) and the arrays, repaired. With ``drop``, rows
    before the first and after the last complete row are dropped (a ragged start or end), and
    runs of up to :data:`MAX_INTERPOLATED_RUN` bad rows inside the data are filled by linear
    interpolation of each column between its neighbours, so the sampling stays uniform. Longer
    runs inside the data are refused: a gap that long is not a glitch.
    """
    bad = np.zeros(table.rows.size, dtype=bool)
    for _, a in arrays.values():
        bad |= ~np.isfinite(a)
    if not bad.any():
        return None, arrays
    k = int(np.flatnonzero(bad)[0])
    if not drop:
        col = next(c for c, a in arrays.values() if not np.isfinite(a[k]))
        raise InputError(f"{table.label}: row {table.rows[k]}, {table.col_label(col)}: {_cell_text(table, col, k)} "
                         f"is not a finite number (NaN, inf or empty); fix or remove the row, or pass --drop-nonfinite")
    if bad.all():
        raise InputError(f"{table.label}: every row has a NaN, inf or empty cell in the selected columns; "
                         f"check the column selection")
    good = np.flatnonzero(~bad)
    first, last = int(good[0]), int(good[-1])
    inner = bad.copy()
    inner[:first] = False
    inner[last + 1:] = False
    if inner.any():
        edges = np.diff(np.concatenate(([0], inner.astype(np.int8), [0])))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        longest = int(np.argmax(stops - starts))
        if stops[longest] - starts[longest] > MAX_INTERPOLATED_RUN:
            raise InputError(f"{table.label}: rows {table.rows[starts[longest]]}–{table.rows[stops[longest] - 1]}: "
                             f"{stops[longest] - starts[longest]} consecutive rows with NaN/inf/empty cells inside "
                             f"the data, more than the {MAX_INTERPOLATED_RUN} --drop-nonfinite interpolates; split "
                             "the file at the gap into two captures")
        repaired = {}
        for role, (col, a) in arrays.items():
            a = a.copy()
            fix = inner & ~np.isfinite(a)
            if fix.any():
                ok = np.flatnonzero(np.isfinite(a))
                a[fix] = np.interp(np.flatnonzero(fix), ok, a[ok])
            repaired[role] = (col, a)
        arrays = repaired
        i0 = int(np.flatnonzero(inner)[0])
        share = float(inner.sum()) / inner.size
        runs = f"in {starts.size} run(s) of at most {int(np.max(stops - starts))}, " if starts.size < inner.sum() else ""
        line = (f"interpolated {int(inner.sum())} row(s) with NaN/inf/empty cells inside the data ({runs}first: "
                f"row {table.rows[i0]}) linearly between their neighbours")
        if share > MAX_INTERPOLATED_SHARE:  # made-up samples: smooth, noiseless, not measured
            line = (f"warning: {line}: {100 * share:.0f} % of the capture is interpolated, not measured; fits, "
                    "metrics and diagnose's noise floor treat those rows as data (the floor comes out too low); "
                    "repair the recording or cut a complete part with --start/--stop")
        notes.append(line)
    edge = bad & ~inner
    if not edge.any():
        return None, arrays
    e0 = int(np.flatnonzero(edge)[0])
    notes.append(f"dropped {int(edge.sum())} row(s) with NaN/inf/empty cells at the start or end "
                 f"(first: row {table.rows[e0]})")
    return ~edge, arrays


def _time_resolution(t: np.ndarray) -> float:
    """The resolution the time stamps are stored with (s): the float32 spacing at the largest |t| when
    every stamp is a float32 value (a DAQ that logs single precision: at 20 s its stamps are 1.9 µs
    apart, 2 % of a 10 kHz step), else float64's rounding (16 ε·|t|)."""
    big = float(max(abs(t[0]), abs(t[-1])))
    if np.array_equal(t, t.astype(np.float32).astype(np.float64)):
        return 2.0 * float(np.spacing(np.float32(big)))
    return 16 * float(np.finfo(float).eps) * big


class _TimeColumnError(InputError):
    """A time column that cannot give the sampling: ``what`` is wrong with it (without the file's
    label and the fix), for :func:`_time_axis`'s note when ``--fs`` takes over."""

    def __init__(self, label: str, what: str, fix: str) -> None:
        super().__init__(f"{label}: {what}; {fix}")
        self.label, self.what, self.fix = label, what, fix

    def __reduce__(self):  # a capture read aside reports its error across processes (pickled)
        return type(self), (self.label, self.what, self.fix)


def _check_time(table: _Table, col: int, t: np.ndarray, rows: np.ndarray) -> float:
    """Validate strictly increasing, uniform time (s); returns dt = span / (N − 1) in s.

    Uniform: every step within 0.1 % of the median step, plus the resolution the stamps are stored
    with (:func:`_time_resolution`). Stamps rounded coarser than the sampling (``%.3f`` at 10 kHz:
    runs of equal values) are said as such, with the remedy ``--fs``.
    """
    d = np.diff(t)
    back = np.flatnonzero(~(d > 0))
    name = table.col_label(col)
    if back.size:
        k = int(back[0]) + 1
        if np.all(d >= 0) and np.count_nonzero(d == 0) >= 0.25 * d.size:  # rounded, not shuffled
            res = float(np.min(d[d > 0])) if np.any(d > 0) else float("nan")
            raise _TimeColumnError(table.label, f"{name}: the time stamps repeat (row {rows[k]} has the previous "
                                   f"row's {t[k]:.9g} s, and {np.count_nonzero(d == 0)} rows do): they are rounded to "
                                   f"{res:.3g} s, coarser than the sampling", "pass --fs HZ to take the sample rate "
                                   "instead of the time column, or export the time with more digits")
        raise _TimeColumnError(table.label, f"row {rows[k]}, {name}: time {t[k]:.9g} s is not after the previous "
                               f"row's {t[k - 1]:.9g} s (time must strictly increase)",
                               "sort the rows or remove duplicates")
    med = float(np.median(d))
    tol = 1e-3 * med + _time_resolution(t)
    off = np.flatnonzero(np.abs(d - med) > tol)
    if off.size:
        k = int(off[0]) + 1
        rel = abs(d[k - 1] - med) / med * 100
        raise _TimeColumnError(table.label, f"row {rows[k]}, {name}: the time step {d[k - 1]:.6g} s differs from "
                               f"the median step {med:.6g} s by {rel:.3g} % (limit 0.1 %): the sampling is not "
                               "uniform (gap or jitter)", "resample the capture to a uniform rate")
    return float((t[-1] - t[0]) / (t.size - 1))


#: samples at the start of a capture whose noise and median are the idle level's when the input is noisy
IDLE_LEVEL_SAMPLES = 64
#: a noisy input leaves its idle level when it is this many noise standard deviations away from it
IDLE_NOISE_BAND = 6.0


def idle_samples(u: np.ndarray) -> int:
    """Number of leading samples of an idle (constant) input to drop before the excitation.

    The excitation starts at the first sample with ``|u − level| > tol``, ``tol = max(1e-9 V,
    1e-3·(max u − min u), 6σ)``. σ is the noise of the first :data:`IDLE_LEVEL_SAMPLES` samples
    (1.4826·MAD of their first differences / √2: a measured amplifier output, not a commanded
    value, is noisy) when they all lie within 6σ of their median, which is then the level, and
    their third differences give the same σ within a factor 2
    (:func:`hystfit.conditions.white_noise_sigma`: white noise does, a coarsely sampled drive not);
    otherwise (a noise-free input, one that moves at once, a step among them) σ = 0 and the level
    is ``u[0]``, as for every input before. The
    kept part starts one sample before the input first leaves the idle level: for a noisy input at
    the last sample within σ of the level; otherwise at the last sample before that point equal to
    ``u[0]`` (to 1e-12 relative) when there is such a sample after ``u[0]``, or (a slow start such
    as a raised cosine) at the start of the monotone ramp into the first moving sample.

    Parameters
    ----------
    u : (N,) input (V).

    Returns
    -------
    int
        Samples to drop (0 when the input moves from the start or never moves).
    """
    u = np.asarray(u, dtype=np.float64)
    head = u[:IDLE_LEVEL_SAMPLES]
    level = float(np.median(head))
    # the noise of a flat start: 1.4826·MAD of its first differences / √2 (0 for an exact level); white
    # noise gives the same from the third differences, a drive (its curvature) far less
    step = np.diff(head)
    sigma = 1.4826 * float(np.median(np.abs(step - np.median(step)))) / math.sqrt(2.0) if step.size else 0.0
    if (head.size < IDLE_LEVEL_SAMPLES or float(np.max(np.abs(head - level))) > IDLE_NOISE_BAND * sigma
            or not 0.5 * sigma <= white_noise_sigma(head) <= 2.0 * sigma):
        sigma, level = 0.0, u[0]  # no flat noisy start (noise-free, or moving at once): the level is u[0]
    dev = np.abs(u - level)
    tol = max(1e-9, 1e-3 * float(u.max() - u.min()), IDLE_NOISE_BAND * sigma)
    moving = np.flatnonzero(dev > tol)
    if moving.size == 0:
        return 0
    i = int(moving[0])
    if sigma > 0.0:  # a noisy level: the last sample within one σ of it
        near = np.flatnonzero(dev[:i] <= sigma)
        return int(near[-1]) if near.size else 0
    eps = 1e-12 * max(1.0, float(np.abs(u).max()))
    exact = np.flatnonzero(dev[:i] <= eps)
    j = int(exact[-1])
    if j > 0:
        return j
    k = i - 1
    while k > 0 and dev[k - 1] < dev[k]:
        k -= 1
    return k


def _condition_from_columns(table: _Table, chosen: dict) -> tuple[float | None, float | None]:
    """Constant ``amplitude_V``/``frequency_Hz`` column values (V, Hz), None where absent."""
    out: list[float | None] = []
    for role in ("amplitude", "frequency"):
        col = chosen[role]
        if col is None:
            out.append(None)
            continue
        v = _numeric(table, col)
        unit = _unit_of(table.names[col], role)
        v = v * (_UNITS[role][unit] if unit else 1.0)
        fin = np.flatnonzero(np.isfinite(v))
        if not fin.size:
            raise InputError(f"{table.label}: {table.col_label(col)} has no numeric value; "
                             "fill it or remove the column")
        vals = v[fin]
        change = np.flatnonzero(np.abs(vals - vals[0]) > 1e-9 * max(abs(vals[0]), 1e-300))
        if change.size:
            r = table.rows[int(fin[change[0]])]
            raise InputError(f"{table.label}: row {r}, {table.col_label(col)}: the {role} changes within the file "
                             f"({vals[0]:g} → {vals[change[0]]:g}) but must be constant; split the file per condition")
        if not vals[0] > 0:
            raise InputError(f"{table.label}: {table.col_label(col)}: the {role} must be positive, got {vals[0]:g}; "
                             f"fix the column")
        out.append(float(vals[0]))
    return out[0], out[1]


# ----------------------------------------------------------------------------------------------
# load_capture
# ----------------------------------------------------------------------------------------------


def _col_unit(table: _Table, col: int | None, role: str) -> str | None:
    """Unit text the column's name gives for ``role`` (None: no name or no unit)."""
    return _unit_of(table.names[col], role) if (col is not None and table.names is not None) else None


def _scale(table: _Table, col: int | None, role: str) -> float:
    """Factor to SI (s or V) for a time/input column."""
    unit = _col_unit(table, col, role)
    return float(_UNITS[role][unit]) if unit else 1.0


def _output_unit(table: _Table, col: int | None, opts: LoadOptions, notes: list[str]) -> str:
    unit = _col_unit(table, col, "output")
    if unit is not None:
        u = str(_UNITS["output"][unit])
        if opts.output_unit is not None and opts.output_unit != u:
            notes.append(f"--output-unit {opts.output_unit} ignored: {table.col_label(col)} says {u}")
        return u
    if opts.output_unit is not None:
        return str(_UNITS["output"].get(opts.output_unit.lower(), opts.output_unit))
    if col is not None:
        notes.append(f"output unit not given by {table.col_label(col)}; assumed um "
                     "(pass --output-unit or name the column e.g. displacement_nm)")
    return "um"


def _time_axis(table: _Table, chosen: dict, t: np.ndarray | None, rows: np.ndarray, opts: LoadOptions,
               notes: list[str]) -> float:
    """Sample period dt (s) from the time column or ``fs``."""
    if t is None:
        return 1.0 / float(opts.fs)
    if t.size < 2:
        raise InputError(f"{table.label}: only {t.size} data row; a capture needs many samples")
    try:
        dt = _check_time(table, chosen["time"], t, rows)
    except _TimeColumnError as exc:
        if opts.fs is None:
            raise
        # --fs given: it takes over from a time column that cannot give the sampling
        notes.append(f"{exc.what}: the time column is not used, the sample rate is --fs {opts.fs:g} Hz")
        return 1.0 / float(opts.fs)
    if opts.fs is not None and abs(1.0 / dt - opts.fs) > 0.01 * opts.fs:
        raise InputError(f"{table.label}: {table.col_label(chosen['time'])} gives a sample rate of {1 / dt:.6g} Hz "
                         f"but --fs is {opts.fs:g} Hz; drop --fs or fix the time unit (e.g. name the column time_ms)")
    if _col_unit(table, chosen["time"], "time") is None and 1.0 / dt < 100:
        notes.append(f"sample rate {1 / dt:.3g} Hz with time assumed in seconds; if the time is in ms, "
                     "name the column time_ms")
    return dt


def load_capture(path: str | os.PathLike, options: LoadOptions = LoadOptions()) -> Capture:
    """Load and validate one capture file.

    Parameters
    ----------
    path : CSV/TXT/TSV/DAT or Parquet file; ``str(path)`` becomes ``Capture.source``.
    options : see :class:`LoadOptions`; a sidecar ``<file>.hystfit.json`` fills options left at
        their defaults.

    Returns
    -------
    Capture
        t (s, from 0, uniform), u (V), y (in ``y_unit``) as C-contiguous float64 arrays, with the
        operating condition, trim information and notes.

    Raises
    ------
    InputError
        Any unreadable, malformed or unsuitable file (one-line message naming file, row/column,
        rule and remedy).
    """
    p = Path(path)
    label = str(path)
    opts, notes = _apply_sidecar(p, options)
    table = _read_table(p, label, opts.no_header)
    notes.extend(table.notes)
    chosen = _select_columns(table, opts, notes)
    arrays = {r: (chosen[r], _time_values(table, chosen[r], notes) if r == "time" else _numeric(table, chosen[r]))
              for r in ("time", "input", "output") if chosen[r] is not None}
    keep, arrays = _nonfinite(table, arrays, opts.drop_nonfinite, notes)
    rows = table.rows if keep is None else table.rows[keep]
    data = {r: (a if keep is None else a[keep]) for r, (_, a) in arrays.items()}
    t = data["time"] * _scale(table, chosen["time"], "time") if "time" in data else None
    u = data["input"] * _scale(table, chosen["input"], "input")
    y = data.get("output")
    y_unit = _output_unit(table, chosen["output"], opts, notes) if y is not None else (opts.output_unit or "um")
    if y is None and table.names is not None and len(table.names) > sum(i is not None for i in chosen.values()):
        # a capture that may have no measured output (simulate) but has columns left: perhaps it is one of them
        notes.append(f"no measured output column found ({table.listing()}): predictions only, no metrics; pass "
                     "--output-col NAME to compare with a measured output")
    dt = _time_axis(table, chosen, t, rows, opts, notes)
    u, y, rows, windowed = _window(table, opts, notes, u, y, rows, dt)
    return _finish(table, chosen, opts, notes, u, y, dt, y_unit, rows, windowed)


def _window(table: _Table, opts: LoadOptions, notes: list[str], u: np.ndarray, y: np.ndarray | None,
            rows: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, bool]:
    """Keep the samples with time (from the first row) in [start_s, stop_s)."""
    if opts.start_s is None and opts.stop_s is None:
        return u, y, rows, False
    n = u.size
    duration = n * dt
    # in floats, clipped to the capture before rounding: a huge --start/--stop would overflow an int
    i0 = 0 if opts.start_s is None else int(math.ceil(min(opts.start_s / dt, n + 1.0) - 1e-9))
    i1 = n if opts.stop_s is None else int(math.ceil(min(opts.stop_s / dt, n + 1.0) - 1e-9))
    i1 = min(n, i1)
    if i1 - i0 < 4:
        stop = opts.stop_s if opts.stop_s is not None else duration
        raise InputError(f"{table.label}: --start/--stop keep {max(i1 - i0, 0)} samples of this {duration:.6g} s "
                         f"capture (window {opts.start_s or 0:g}…{stop:.6g} s from its first row); choose a window "
                         "inside the capture")
    notes.append(f"kept {i0 * dt:.6g}…{i1 * dt:.6g} s of {duration:.6g} s (--start/--stop; rows {rows[i0]}–"
                 f"{rows[i1 - 1]})")
    return u[i0:i1], (None if y is None else y[i0:i1]), rows[i0:i1], i0 > 0


#: A first input step larger than this share of the input range (and than JUMP_MEDIAN_FACTOR ×
#: the median step) is a one-sample jump: the capture starts mid-loop.
JUMP_RANGE_FRACTION = 0.05
JUMP_MEDIAN_FACTOR = 20.0


def start_jump(u: np.ndarray) -> float:
    """The first input step u[1] − u[0] (V) when it is a one-sample jump, else 0.

    A jump is larger than :data:`JUMP_RANGE_FRACTION` of the input range and than
    :data:`JUMP_MEDIAN_FACTOR` × the median non-zero step: the recording (or the window) began in
    the middle of a loop, e.g. 0 → −87 V at the start of ``sample_data/real``.
    """
    if u.size < 3:
        return 0.0
    d = np.abs(np.diff(u))
    moving = d[d > 0]
    if moving.size == 0:
        return 0.0
    step = float(u[1] - u[0])
    ptp = float(u.max() - u.min())
    if abs(step) > JUMP_RANGE_FRACTION * ptp and abs(step) > JUMP_MEDIAN_FACTOR * float(np.median(moving)):
        return step
    return 0.0


#: an input whose peak-to-peak is at most this share of its level (60 µV of ripple on 30 V) is
#: constant: no DAC resolves it (16 bits over 100 V: 1.5 mV), it is noise on a held voltage
CONSTANT_INPUT_FRACTION = 1e-5
#: an output whose peak-to-peak is at most this share of its level (0 included) did not move: a
#: disconnected sensor, a column of its zero; the finest interferometer resolves ≈ 1e-9 of its range
CONSTANT_OUTPUT_FRACTION = 1e-9


#: the largest |input| (V) a capture may hold: piezo drives stay within a few kV; 10⁶ V is a wrong
#: column or unit (a blind test's 1e20 V capture ran into LAPACK errors written on stdout)
MAX_PLAUSIBLE_INPUT_V = 1e6
#: the largest |output| a capture may hold, in its own unit: 10⁹ nm is a metre; more is a wrong column
MAX_PLAUSIBLE_OUTPUT = 1e9


def _finish(table: _Table, chosen: dict, opts: LoadOptions, notes: list[str], u: np.ndarray,
            y: np.ndarray | None, dt: float, y_unit: str, rows: np.ndarray | None = None,
            windowed: bool = False) -> Capture:
    """Trim the idle start, check excitation and length, settle the condition, build the Capture."""
    label = table.label
    ptp = float(u.max() - u.min()) if u.size else 0.0
    level = float(np.max(np.abs(u))) if u.size else 0.0
    if level > MAX_PLAUSIBLE_INPUT_V:
        raise InputError(f"{label}: {table.col_label(chosen['input'])}: input up to {level:.3g} V, beyond any actuator "
                         f"drive (the limit is {MAX_PLAUSIBLE_INPUT_V:g} V); check the input column (--input-col) and its "
                         "unit (a name such as voltage_mV says it)")
    y_level = float(np.max(np.abs(y))) if y is not None and y.size else 0.0
    if y_level > MAX_PLAUSIBLE_OUTPUT:
        raise InputError(f"{label}: {table.col_label(chosen['output'])}: output up to {y_level:.3g} "
                         f"{display_unit(y_unit)}, beyond any stage's stroke in any unit (the limit is "
                         f"{MAX_PLAUSIBLE_OUTPUT:g}); check the output column (--output-col) and its unit")
    if ptp <= max(1e-9, CONSTANT_INPUT_FRACTION * level):
        within = f" within {ptp:.3g} V" if ptp > 0 else ""
        raise InputError(f"{label}: {table.col_label(chosen['input'])}: the input is constant{within} ({u[0]:g} V), "
                         "there is no excitation; check the input column (--input-col)")
    if y is not None and y.size and float(np.ptp(y)) <= CONSTANT_OUTPUT_FRACTION * float(np.max(np.abs(y))):
        unit = display_unit(y_unit)
        raise InputError(f"{label}: {table.col_label(chosen['output'])}: the output is constant ({y[0]:g} {unit}) "
                         "while the input moves: the sensor recorded nothing to identify from; check the output "
                         "column (--output-col) or the sensor")
    start = idle_samples(u)
    if start:
        u = u[start:]
        y = y[start:] if y is not None else None
        notes.append(f"trimmed {start * dt:.6g} s ({start} samples) of idle input before the excitation")
    if u.size < 4:
        raise InputError(f"{label}: only {u.size} samples of excitation; a capture needs at least "
                         f"{opts.min_cycles:g} input cycles")
    jump = start_jump(u)
    where = f" (row {rows[start + 1]})" if rows is not None and rows.size > start + 1 else ""
    if jump:
        notes.append(f"starts mid-loop: the input jumps from {u[0]:.4g} to {u[1]:.4g} V in one sample{where}, so the "
                     "actuator's hysteresis state at the start is unknown and the first samples carry the largest "
                     "errors (rate-dependent models spike); --warmup SECONDS leaves them out of the fit while the model's "
                     "state settles, --start SECONDS cuts them off")
    elif windowed and not start:
        notes.append(f"starts mid-loop: the --start window begins while the input moves ({u[0]:.4g} V), so the "
                     "actuator's hysteresis state at the start is unknown; start the window at a rest or turning point")
    for what, x, unit in (("input", u, "V"), ("output", y, display_unit(y_unit))):
        if x is not None:
            notes += _glitch_notes(what, x, unit, rows, start)
    if y is not None:
        notes += _saturation_notes(u, y, display_unit(y_unit))
    amp, freq, source = _condition(table, chosen, opts, notes, u, dt)
    cycles = count_cycles(u, dt, freq)
    if cycles < opts.min_cycles:
        fix = ("widen the --start/--stop window" if windowed or opts.start_s is not None or opts.stop_s is not None
               else "record a longer capture")
        shown = math.floor(cycles * 100.0) / 100.0  # never rounded up to the minimum it is short of (1.9996 → "2")
        raise InputError(f"{label}: only {shown:g} input cycles of {freq:g} Hz after trimming, the minimum is "
                         f"{opts.min_cycles:g}; {fix}")
    warm = int(round(opts.warmup_s / dt)) if opts.warmup_s else 0
    if warm > u.size - max(4, u.size // 4):
        raise InputError(f"{label}: --warmup {opts.warmup_s:g} s leaves {max(u.size - warm, 0)} of {u.size} samples "
                         f"({u.size * dt:.6g} s) to fit; a warm-up may take at most three quarters of a capture")
    if warm:
        notes.append(f"warm-up: the first {warm * dt:.6g} s ({warm} samples) are simulated but not scored (--warmup)")
    return Capture(source=label, t=np.arange(u.size, dtype=np.float64) * dt, u=np.ascontiguousarray(u, np.float64),
                   y=None if y is None else np.ascontiguousarray(y, np.float64), dt=float(dt), y_unit=y_unit,
                   trimmed_s=start * dt, trimmed_samples=int(start), amplitude_V=float(amp), frequency_Hz=float(freq),
                   condition_source=source, notes=tuple(notes), warmup_samples=warm)


#: a sample further than this many times the bulk's span (without its 0.1 % or 3 most extreme
#: samples at either end) beyond
#: the bulk is a glitch: 1000 V in one row of a 0…60 V drive, a sensor's dropout to 1e6
GLITCH_SPANS = 1.0
#: the bulk's percentiles are taken of at most this many samples (strided): a 10⁷-row capture
#: costs a comparison per sample, not a sort
GLITCH_SAMPLE = 100_000


#: an output held at its extreme while the input sweeps at least this share of its range is clipped
SATURATION_INPUT_SHARE = 0.2


def _saturation_notes(u: np.ndarray, y: np.ndarray, unit: str) -> list[str]:
    """A warning when the output sits exactly at its maximum (or minimum) while the input moves over
    a fifth of its range or more (:data:`SATURATION_INPUT_SHARE`): a sensor or an amplifier at the
    end of its range. A turning point's dwell, where the output repeats its extreme for a few
    samples, has the input still near its own extreme there. The runs of the extreme value are
    found in one pass; the widest input span over one of them decides."""
    if y.size < 20:
        return []
    span_u = float(np.ptp(u))
    if not span_u > 0:
        return []
    out = []
    need = None
    for side, level in (("maximum", float(y.max())), ("minimum", float(y.min()))):
        idx = np.flatnonzero(y == level)  # the runs from the samples at the level only: O(their count)
        if idx.size < 3:
            continue
        cut = np.flatnonzero(np.diff(idx) != 1) + 1
        starts = idx[np.concatenate(([0], cut))]
        stops = idx[np.concatenate((cut - 1, [idx.size - 1]))] + 1
        if need is None:
            # a run can only span that much input if it lasts long enough at the input's fastest
            # rate: the short runs of a quantized sensor at its extreme are not looked at
            d = np.diff(u)
            need = max(3.0, SATURATION_INPUT_SHARE * span_u / max(float(d.max()), -float(d.min()), 1e-300))
        long = stops - starts >= need
        if not long.any():
            continue
        widest = max(float(np.ptp(u[a:b])) for a, b in zip(starts[long], stops[long]))
        if widest >= SATURATION_INPUT_SHARE * span_u:
            out.append(f"warning: the output stays at its {side}, {level:.6g} {unit}, for {idx.size} samples "
                       f"({100 * idx.size / y.size:.0f} %) while the input moves over up to {widest:.3g} V: a sensor or "
                       "amplifier at the end of its range? Clipped samples are not the actuator's motion; cut them "
                       "off with --start/--stop or record within the sensor's range")
    return out


def _glitch_notes(what: str, x: np.ndarray, unit: str, rows: np.ndarray | None, start: int) -> list[str]:
    """A warning when a few samples of ``x`` lie far outside the rest (at most 0.1 % of them, or 3,
    each more than :data:`GLITCH_SPANS` × the bulk's span beyond it): a glitch sets the condition's
    amplitude (1000 V for a 60 V drive) and the fit's scale, silently. Rows named as in the file."""
    if x.size < 20:
        return []
    bulk = x[::max(1, x.size // GLITCH_SAMPLE)]
    k = max(3, math.ceil(0.001 * bulk.size))  # the few extreme samples a glitch may be are left out of the bulk
    part = np.partition(bulk, (k, bulk.size - 1 - k))
    lo, hi = float(part[k]), float(part[bulk.size - 1 - k])
    span = hi - lo
    if not span > 0:
        return []
    far = np.flatnonzero((x < lo - GLITCH_SPANS * span) | (x > hi + GLITCH_SPANS * span))
    if far.size == 0 or far.size > max(3, 0.001 * x.size):
        return []
    at = [int(rows[start + i]) if rows is not None and rows.size > start + i else int(start + i) + 1 for i in far[:3]]
    where = ", ".join(f"row {r} ({float(x[i]):.6g} {unit})" for r, i in zip(at, far[:3]))
    more = f" and {far.size - 3} more" if far.size > 3 else ""
    return [f"warning: {far.size} {what} sample(s) lie far outside the rest ({float(lo):.4g}…{float(hi):.4g} {unit}): "
            f"{where}{more}: a glitch? It sets the capture's range and its fit; drop or repair the row(s), or cut "
            "them off with --start/--stop"]


def _condition(table, chosen, opts, notes, u, dt) -> tuple[float, float, str]:
    """(amplitude_V, frequency_Hz, source): columns, then the ``condition`` option, then detection."""
    col_a, col_f = _condition_from_columns(table, chosen)
    if col_a is not None or col_f is not None:
        if opts.condition is not None:
            notes.append("--condition ignored: the file has amplitude/frequency columns")
        det = detect_condition(u, dt) if col_a is None or col_f is None else (None, None)
        return (col_a if col_a is not None else det[0]), (col_f if col_f is not None else det[1]), "column"
    if opts.condition is not None:
        if len(opts.condition) != 2 or not is_valid_condition(*opts.condition):
            raise ConfigError(f"condition {tuple(opts.condition)!r}: {CONDITION_RULE}, e.g. (40, 10)")
        return float(opts.condition[0]), float(opts.condition[1]), "option"
    a, f = detect_condition(u, dt)
    notes += [f"warning: {w}" for w in nonstationary_notes(u, dt, (a, f))]
    return a, f, "detected"


#: captures of at most this many bytes in all are read by a forked child while this process runs
#: the ``ahead`` steps of :func:`load_captures`; larger ones are read here (their transfer would cost
#: more than it saves, and memory twice). A Parquet file counts :data:`PARQUET_EXPANSION` times its
#: size: it is compressed.
LOAD_ASIDE_MAX_BYTES = 64 << 20
PARQUET_EXPANSION = 8
#: ... and smaller ones are read here too: hand-made files (the general reader's, with pandas), read
#: at once, where a mistake is reported sooner here than by a child sharing the cores with the steps
LOAD_ASIDE_MIN_BYTES = FAST_READ_BYTES


def load_captures(paths: Sequence[str | os.PathLike], options: LoadOptions = LoadOptions(),
                  recursive: bool = False, *, ahead: Sequence = (),
                  meanwhile: Callable[[], ContextManager] = nullcontext, abandon_on_error: bool = False) -> list[Capture]:
    """Load every capture of :func:`expand_paths` ``(paths, recursive)`` with ``options``.

    ``ahead``: steps (callables, e.g. of :mod:`hystfit._warm`) that the caller would run next —
    loading what its first fit needs, starting a pool. Then a forked child reads the captures (from
    :data:`LOAD_ASIDE_MIN_BYTES` to :data:`LOAD_ASIDE_MAX_BYTES`) while this process runs the steps, until the captures are
    read (:func:`hystfit._warm.load_ahead`): the two overlap instead of following each other. The
    same captures as read here (the child's, pickled, with the same read-only arrays); the
    loader's error, if any, is raised here; with ``abandon_on_error`` (only where the process ends
    with the command: the steps' imports are abandoned half-done) as soon as the child reports it. Where the child cannot be forked, or this process runs
    threads, they are read here and the steps are left to the caller's code.

    ``meanwhile()``: a context entered while the captures are read (e.g. a progress line), after
    the child is forked: a thread it starts is not copied into the child (a fork copies the locks
    other threads hold, such as a stream's, and with it the child could hang on its first write).
    """
    import threading

    files = expand_paths(paths, recursive)
    aside = None
    if ahead and threading.active_count() == 1 and LOAD_ASIDE_MIN_BYTES <= _load_bytes(files) <= LOAD_ASIDE_MAX_BYTES:
        from .parallel import fork_call

        aside = fork_call(lambda: _read(files, options), kernels=False)
    try:
        with meanwhile():
            if aside is None:
                got = _read(files, options)
            else:
                got = _read_aside(aside, ahead, abandon_on_error)
    except BaseException:
        if aside is not None:  # the child stopped (nothing once its result is in)
            aside.cancel()
        raise
    if isinstance(got, Exception):
        raise got
    captures, read_only = got
    for c, names in zip(captures, read_only):  # as read here: a pickled array comes back writeable
        for name in names:
            getattr(c, name).flags.writeable = False
    return _note_unreadable(paths, recursive, files, captures)


def _note_unreadable(paths, recursive: bool, files: Sequence[Path], captures: list) -> list:
    """``captures`` with a note on the first one read from each folder of ``paths`` that also holds
    files that look like measurements hystfit cannot read (:data:`UNREADABLE_DATA_SUFFIXES`)."""
    out = list(captures)
    for raw in paths:
        d = Path(raw)
        if not d.is_dir():
            continue
        found = d.rglob("*") if recursive else d.iterdir()
        odd = sorted(p.name for p in found if p.is_file() and not p.name.startswith(".")
                     and any(p.name.lower().endswith(s) for s in UNREADABLE_DATA_SUFFIXES))
        first = next((i for i, f in enumerate(files) if d.resolve() in f.resolve().parents), None)
        if odd and first is not None and first < len(out):
            shown = ", ".join(odd[:5]) + (f" and {len(odd) - 5} more" if len(odd) > 5 else "")
            note = (f"{d} also holds {shown}, not read (captures are {', '.join(CAPTURE_SUFFIXES)}); convert them "
                    "to CSV or Parquet to use them")
            out[first] = replace(out[first], notes=tuple(out[first].notes) + (note,))
    return out


def _read_aside(aside, ahead: Sequence, abandon: bool):
    """What the child ``aside`` read, while this process runs the steps ``ahead`` until it has.

    ``abandon``: the process ends when the command does (the console script), so the steps may be
    abandoned in the middle of an import as soon as the child reports the loader's error (the
    command ends with it; finishing the imports would only delay it). Elsewhere (a program calling
    hystfit, a test suite's ``CliRunner``) an import cut short would leave half-loaded modules for
    the process's next fit: the steps then stop only between one another."""
    from ._warm import Abandoned, load_ahead

    def refused() -> bool:
        sent, value = aside.sent()  # never computed here: this runs inside the steps' imports
        return sent and isinstance(value, Exception)

    try:
        load_ahead(ahead, stop=aside.ready, abandon=refused if abandon else None)
    except Abandoned:
        pass
    return aside.result()


def _read(files: Sequence[Path], options: LoadOptions):
    """(the captures of ``files``, per capture the names of its read-only arrays), or the
    :class:`~hystfit.errors.HystfitError` that stopped the reading (a value: it crosses a pipe)."""
    from .errors import HystfitError

    try:
        captures = [load_capture(p, options) for p in files]
    except HystfitError as exc:
        return exc
    return captures, [[f.name for f in dataclasses.fields(c)
                       if isinstance(getattr(c, f.name), np.ndarray) and not getattr(c, f.name).flags.writeable]
                      for c in captures]


def _load_bytes(files: Sequence[Path]) -> int:
    try:
        return sum(p.stat().st_size * (PARQUET_EXPANSION if p.suffix.lower() in PARQUET_SUFFIXES else 1)
                   for p in files)
    except OSError:  # the loader says what is wrong with the file
        return LOAD_ASIDE_MAX_BYTES + 1


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()


def atomic_write_bytes(path: str | os.PathLike, data: "bytes | Iterable[bytes]", *, sync: bool = True) -> None:
    """Write ``data`` (bytes, or pieces of them written one after the other: a large table need not
    be held whole in memory) to ``path`` via a temporary file in the same directory and ``os.replace``.

    Readers see the old file or the complete new one, never a partial file. Parent directories
    are created. Raises :class:`OutputError` when the location cannot be written.

    ``sync``: the file's data reach the disk (``fsync``) before it replaces ``path``, so that after
    a crash ``path`` holds the old file or the new one, not an empty one. The wait for the disk is
    most of a small file's cost (``python benchmarks/write_cost.py``); figures, which a command
    redraws from its numbers, are written without it (as plotting libraries write theirs), the
    numbers themselves with it.
    """
    p = Path(path)
    tmp = None
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
        with os.fdopen(fd, "wb") as fh:
            if isinstance(data, (bytes, bytearray, memoryview)):
                fh.write(data)
            else:
                for piece in data:
                    fh.write(piece)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, p)
        tmp = None
    except OSError as exc:
        raise OutputError(f"{p}: cannot write the file ({exc.strerror or exc}); check the directory and "
                          "permissions, or choose another --out") from None
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def check_writable_file(path: str | os.PathLike) -> None:
    """Refuse, before any work, a file location that :func:`atomic_write_bytes` could not write.

    Probes the nearest existing ancestor directory of ``path`` by creating and removing a temporary
    file there (permissions alone do not tell: root, read-only mounts). Creates nothing that stays.

    Raises
    ------
    OutputError
        ``path`` is a directory, an ancestor is not a directory, or the directory is not writable.
    """
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{p}: is a directory; choose a file name")
    parent = p.parent if str(p.parent) else Path(".")
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{p}: {parent} is not a directory; choose another location")
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".probe", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{p}: cannot write here ({exc.strerror or exc}); check the directory and permissions, "
                          "or choose another location") from None


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8, line ends as given) atomically; see :func:`atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode("utf-8"))


@dataclass(frozen=True)
class Records:
    """A small output table as rows of dicts, written without pandas (≈ 0.3 s to import).

    Columns are the keys in order of first appearance and a missing key is a missing value, as in
    ``pandas.DataFrame(rows)``; each column gets the kind pandas would infer (:meth:`kind`), so the
    CSV text of :meth:`to_csv` is the same as ``DataFrame(rows).to_csv(index=False)`` (tested). A
    report's per-condition and per-parameter tables are this; large tables stay DataFrames.
    """

    rows: tuple[dict, ...]

    @property
    def columns(self) -> list[str]:
        return list(dict.fromkeys(k for row in self.rows for k in row))

    def column(self, name: str) -> list:
        return [row.get(name) for row in self.rows]

    def kind(self, name: str) -> str:
        """``"bool"``, ``"int"``, ``"float"`` (ints among floats or missing values) or ``"object"``."""
        values = self.column(name)
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, (bool, np.bool_)) for v in present):
            return "bool" if len(present) == len(values) else "object"
        if any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating))
               for v in present) or not present:
            return "object"
        if len(present) == len(values) and all(isinstance(v, (int, np.integer)) for v in present):
            return "int"
        return "float"

    def cells(self, name: str) -> list:
        """The column's values as pandas holds them: ints as float in a float column, missing as NaN."""
        kind, values = self.kind(name), self.column(name)
        if kind == "float":
            return [math.nan if v is None else float(v) for v in values]
        if kind == "int":
            return [int(v) for v in values]
        if kind == "bool":
            return [bool(v) for v in values]
        return values

    def to_csv(self, sep: str = ",") -> str:
        cols = self.columns
        text = [_csv_cell(v) for v in cols]
        table = [self.cells(c) for c in cols]
        buf = _stdio.StringIO()
        writer = csv.writer(buf, delimiter=sep, lineterminator="\n", quoting=csv.QUOTE_MINIMAL)
        writer.writerow(text)
        for row in zip(*table):
            writer.writerow([_csv_cell(v) for v in row])
        return buf.getvalue()

    def to_pandas(self) -> "pandas.DataFrame":
        import pandas as pd

        return pd.DataFrame(list(self.rows))


class Columns(dict):
    """A numeric output table as named columns (name → 1-D float array, in order), written without
    pandas (≈ 0.3–0.7 s to import): a feedforward voltage, a tracking run, a prediction. The CSV text
    of :meth:`to_csv` is that of ``DataFrame(columns).to_csv(index=False)`` (tested): each value
    shortest-exact (``repr``), a missing value (NaN) empty."""

    def __init__(self, columns: Mapping[str, object]) -> None:
        super().__init__((str(k), np.ascontiguousarray(v, dtype=np.float64).ravel()) for k, v in columns.items())
        sizes = {v.size for v in self.values()}
        if len(sizes) > 1:
            raise ValueError(f"Columns: the columns differ in length ({sorted(sizes)})")

    #: rows formatted at a time by :meth:`csv_pieces` (a few MB of text)
    ROWS_PER_PIECE = 1 << 16

    def csv_pieces(self, sep: str = ","):
        """The CSV text of :meth:`to_csv` in pieces: the header, then :data:`ROWS_PER_PIECE` rows at a
        time (a 10⁶-row table is never held whole as text)."""
        buf = _stdio.StringIO()
        csv.writer(buf, delimiter=sep, lineterminator="\n", quoting=csv.QUOTE_MINIMAL).writerow(list(self))
        yield buf.getvalue()
        empty = '""' if len(self) == 1 else ""  # a row of one empty cell is quoted, not a blank line (csv, pandas)
        n = len(next(iter(self.values()))) if self else 0
        for start in range(0, n, self.ROWS_PER_PIECE):
            part = [col[start: start + self.ROWS_PER_PIECE] for col in self.values()]
            cells = [[(empty if text == "nan" else text) for text in map(repr, c.tolist())] if np.isnan(c).any()
                     else list(map(repr, c.tolist())) for c in part]
            yield "".join(line + "\n" for line in map(sep.join, zip(*cells)))

    def to_csv(self, sep: str = ",") -> str:
        return "".join(self.csv_pieces(sep))

    def to_pandas(self) -> "pandas.DataFrame":
        import pandas as pd

        return pd.DataFrame(dict(self))


def _csv_cell(v) -> str:
    """One cell as ``DataFrame.to_csv`` writes it: missing values empty, floats shortest-exact."""
    if v is None or (isinstance(v, (float, np.floating)) and math.isnan(v)):
        return ""
    if isinstance(v, (float, np.floating)) and not isinstance(v, bool):
        return repr(float(v))
    return str(v)


def write_table(path: str | os.PathLike, table: "Records | Columns | pandas.DataFrame") -> None:
    """Write ``table`` atomically: Parquet for ``.parquet``/``.pq``, tab-separated for ``.tsv``, else CSV.

    Text tables have a header row, no index, ``\\n`` line ends and full float precision.
    :class:`Records` and :class:`Columns` are written without importing pandas unless the file is Parquet.
    """
    p = Path(path)
    if p.suffix.lower() in PARQUET_SUFFIXES:
        df = table.to_pandas() if isinstance(table, (Records, Columns)) else table
        buf = _stdio.BytesIO()
        df.to_parquet(buf, index=False)
        atomic_write_bytes(p, buf.getvalue())
        return
    sep = "\t" if p.suffix.lower() == ".tsv" else ","
    if isinstance(table, Columns):
        atomic_write_bytes(p, (piece.encode("utf-8") for piece in table.csv_pieces(sep)))
    elif isinstance(table, Records):
        atomic_write_text(p, table.to_csv(sep))
    else:
        atomic_write_text(p, table.to_csv(index=False, sep=sep, lineterminator="\n"))


def _refuse_dangerous(out: Path) -> None:
    """Refuse to replace the working directory, one of its parents, the home or root directory."""
    target = out.resolve()
    cwd = Path.cwd().resolve()
    if target == cwd or target in cwd.parents or target == Path.home().resolve() or target == Path(target.anchor):
        raise OutputError(f"{out}: refusing to replace this directory (it is the working directory, a parent of "
                          "it, the home or the root directory); choose another --out")


def _check_out(out: Path, force: bool, inputs: Sequence[str | os.PathLike] = (), resume: bool = False) -> bool:
    """Validate ``out`` before work; returns True when it exists (and may be replaced)."""
    if not out.exists():
        return False
    if not out.is_dir():
        raise OutputError(f"{out}: exists and is not a directory; choose another --out")
    if any(out.iterdir()) and not force:
        if resume:  # a finished run: --resume continues an interrupted one only (a blind test's confusion)
            raise OutputError(f"{out}: exists and is not empty: a finished output has nothing to resume (--resume "
                              f"continues an interrupted run from its cells in {out.name}.partial); pass --force to "
                              "compute it again, or choose another --out")
        raise OutputError(f"{out}: output directory exists and is not empty; pass --force to replace it "
                          "or choose another --out")
    _refuse_dangerous(out)
    _refuse_inputs(out, inputs)
    _refuse_foreign(out)
    return True


#: files one of hystfit's commands writes at the top of its output folder (identify, simulate,
#: track: report.md; identify, diagnose: params.json; diagnose: diagnosis.json; compare: compare.csv;
#: invert's report folder: report.json; track: summary.json)
OUTPUT_MARKERS = ("params.json", "report.md", "diagnosis.json", "compare.csv", "report.json", "summary.json")


def _refuse_foreign(out: Path) -> None:
    """Refuse to replace (``--force``) a non-empty folder that holds none of the files hystfit writes
    (:data:`OUTPUT_MARKERS`): a blind test's ``--out keep --force`` deleted ``keep/file.txt``, a
    folder hystfit had never written. Its output folders are replaced as before."""
    entries = list(out.iterdir())
    if entries and not any((out / m).is_file() for m in OUTPUT_MARKERS):
        first = sorted(e.name for e in entries)[0]
        raise OutputError(f"{out}: holds files hystfit did not write (e.g. {first}) and none of its outputs; --force "
                          "replaces only a hystfit output folder: choose another --out, or empty the folder yourself")


def _refuse_inputs(out: Path, inputs: Sequence[str | os.PathLike]) -> None:
    """Refuse to replace ``out`` when it is, or holds, one of the command's ``inputs`` (captures, a
    parameter or target file): ``--force`` replaces the whole directory, and a blind test's
    ``identify d --out d --force`` deleted the captures it had just fitted."""
    target = out.resolve()
    for p in inputs:
        q = Path(p).resolve()
        if q == target or target in q.parents:
            raise OutputError(f"{out}: holds the input {p}; replacing it (--force) would delete it; choose another "
                              "--out")


@contextmanager
def staged_output_dir(out: str | os.PathLike, force: bool, inputs: Sequence[str | os.PathLike] = (),
                      resume: bool = False) -> Iterator[Path]:
    """Stage an output directory and publish it only if the block succeeds.

    Parameters
    ----------
    out : final output directory.
    force : allow replacing an existing non-empty ``out``.
    inputs : the command's input files and folders: an ``out`` that is or holds one is never
        replaced (:class:`OutputError` on entry).
    resume : the command was asked to resume: a finished ``out`` is said to be finished.

    Yields
    ------
    Path
        A fresh sibling directory ``out.parent/.<name>.tmp-<pid>-<rand>@<host>`` to write into.
        On normal exit it becomes ``out`` (an existing ``out`` is replaced: only when empty or
        ``force``); on an exception it is deleted and ``out`` is untouched. Staging directories
        of ``out`` that a killed command left (this host's, whose process has ended:
        :func:`remove_stale_stages`) are removed first.

    Raises
    ------
    OutputError
        On entry, before any work: ``out`` exists and is non-empty without ``force``, is not a
        directory, holds an input, or cannot be created; on exit if publishing fails.
    """
    out = Path(out)
    if not out.name or out.name in (".", ".."):
        out = out.resolve()
    _check_out(out, force, inputs, resume)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_stages(out)
        stage = out.parent / f".{out.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}@{_host()}"
        stage.mkdir()
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output directory ({exc.strerror or exc}); check the "
                          "permissions or choose another --out") from None
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    try:
        _publish(stage, out, force)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


def _host() -> str:
    """Where this process's PID means something, as it may stand in a file name: the machine's
    name, and on Linux its PID namespace (two containers on one machine can share the name but
    not their PIDs)."""
    name = re.sub(r"[^A-Za-z0-9._-]", "_", os.uname().nodename if hasattr(os, "uname") else "") or "host"
    try:
        ns = re.sub(r"\D", "", os.readlink("/proc/self/ns/pid"))
    except OSError:
        return name
    return f"{name}~{ns}" if ns else name


def remove_stale_stages(out: Path) -> list[Path]:
    """Remove the staging directories of ``out`` (:func:`staged_output_dir`) that a command killed
    before it could clean up (SIGKILL, the out-of-memory killer, a power cut) left beside it:
    those named for this host (and PID namespace) whose process no longer exists. Another host's
    (a cluster's shared file system: its process may still be writing) and unnamed older ones are
    left alone, and so are the ``.<name>.old-…`` directories of an interrupted replacement (they
    may hold the only copy of the previous results). Returns what was removed; a directory that
    cannot be listed or removed is left as it is."""
    pattern = re.compile(rf"^\.{re.escape(out.name)}\.tmp-(\d+)-[0-9a-f]+@(.+)$")
    host = _host()
    removed = []
    try:
        siblings = list(out.parent.iterdir())
    except OSError:
        return removed
    for p in siblings:
        m = pattern.match(p.name)
        if m is None or m.group(2) != host or int(m.group(1)) == os.getpid() or alive(int(m.group(1))):
            continue
        shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    return removed


def _publish(stage: Path, out: Path, force: bool) -> None:
    """Move ``stage`` to ``out``, replacing an empty (or, with ``force``, any) existing ``out``."""
    try:
        if not _check_out(out, force):
            os.rename(stage, out)
            return
        old = out.parent / f".{out.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        os.rename(out, old)
        try:
            os.rename(stage, out)
        except OSError:
            os.rename(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot publish the output directory ({exc.strerror or exc}); choose another "
                          "--out") from None
