"""The fast reader of large numeric text captures gives exactly what the general reader gives, or declines."""

import numpy as np
import pytest

import hystfit.io as hio
from hystfit.errors import InputError


def _text(n=3000, sep=",", header=True):
    t = np.arange(n) * 1e-4
    u = 30 - 30 * np.cos(2 * np.pi * 10 * t)
    y = 0.1 * u + 0.8 * np.sin(2 * np.pi * 10 * t)
    body = "".join(f"{a:.4f}{sep}{b:.6f}{sep}{c:.6f}\n" for a, b, c in zip(t, u, y))
    return (f"time_s{sep}voltage_V{sep}displacement_um\n" if header else "") + body


def _load_both(path, monkeypatch):
    out = []
    for threshold in (1, 1 << 62):  # fast path tried on every file, then never
        monkeypatch.setattr(hio, "FAST_READ_BYTES", threshold)
        try:
            c = hio.load_capture(path)
            out.append(("ok", c.t.tobytes(), c.u.tobytes(), c.y.tobytes(), c.notes, c.amplitude_V, c.frequency_Hz))
        except InputError as exc:
            out.append(("error", str(exc)))
    return out


CASES = {
    "plain": lambda s: s,
    "crlf": lambda s: s.replace("\n", "\r\n"),
    "semicolon": lambda s: s.replace(",", ";"),
    "missing words": lambda s: s.replace("\n0.0100,0.", "\n0.0100,NaN", 1).replace("\n0.0200,0.", "\n0.0200,null", 1),
    "empty cell": lambda s: s.replace("\n0.0100,0.", "\n0.0100,", 1),
    "blank line": lambda s: s.replace("\n0.0100,", "\n\n0.0100,", 1),
    "comment line": lambda s: s.replace("\n0.0100,", "\n# note\n0.0100,", 1),
    "empty row": lambda s: s.replace("\n0.0100,", "\n,,\n0.0100,", 1),
    "trailing empty row": lambda s: s + ",,\n",
    "text cell": lambda s: s.replace("\n0.0100,", "\n0.0100x,", 1),
    "ragged row": lambda s: s.replace("\n0.0100,", "\n0.0100,1,", 1),
    "decimal commas": lambda s: s.replace(",", ";").replace(".", ","),
    "padded cells": lambda s: s.replace(",", ", "),
    "no header": lambda s: s.split("\n", 1)[1],
    # an oscilloscope's and a LabVIEW file's preamble before the table's header
    "preamble": lambda s: "Model,DSO-X 1234\nRecord Length,3000,Points\nSample Interval,0.0001,s\n" + s,
    "tab preamble": lambda s: "LabVIEW Measurement\nDate\t2026/11/27\n***End_of_Header***\n" + s.replace(",", "\t"),
    "preamble with a comment": lambda s: "Model,DSO-X 1234\n# exported\nRecord Length,3000,Points\n" + s,
    "preamble, no header": lambda s: "Model,DSO-X 1234\nRecord Length,3000,Points\n" + s.split("\n", 1)[1],
    # the names, then their units (DIAdem, LabVIEW and spreadsheet exports)
    "unit row": lambda s: "Time,Voltage,Position\ns,V,um\n" + s.split("\n", 1)[1],
    "preamble and unit row": lambda s: "Model,X\nTime,Voltage,Position\n[s],[V],[um]\n" + s.split("\n", 1)[1],
    # an index column without values, as a real rig's export has (shared/data smarthysteresis)
    "empty first column": lambda s: "idx," + s.replace("\n", "\n,").rstrip(","),
    "missing cells here and there": lambda s: "\n".join(
        ln.replace(",", ",,", 1).replace(",,", ",", 1) if i % 97 else ln.rsplit(",", 1)[0] + ","
        for i, ln in enumerate(s.split("\n"))),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_fast_reader_matches_the_general_reader(case, tmp_path, monkeypatch):
    path = tmp_path / "cap.csv"
    path.write_text(CASES[case](_text()))
    fast, general = _load_both(path, monkeypatch)
    assert fast == general


def test_fast_reader_is_used_on_large_plain_files_and_declines_otherwise(tmp_path, monkeypatch):
    monkeypatch.setattr(hio, "FAST_READ_BYTES", 1)
    plain = tmp_path / "plain.csv"
    plain.write_text(_text())
    table = hio._read_text_fast(plain, "plain.csv", False)
    assert table is not None and table.names == ["time_s", "voltage_V", "displacement_um"]
    assert all(c.dtype == np.float64 for c in table.cols) and table.rows[0] == 2
    for case in ("comment line", "text cell", "ragged row", "blank line", "decimal commas"):
        p = tmp_path / "x.csv"
        p.write_text(CASES[case](_text()))
        assert hio._read_text_fast(p, "x.csv", False) is None, case
    monkeypatch.setattr(hio, "FAST_READ_BYTES", 1 << 20)
    assert hio._read_text_fast(plain, "plain.csv", False) is None  # small: the general reader


def test_a_plain_numeric_capture_is_read_without_pandas(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "cap.csv"
    path.write_text(_text())
    code = ("import sys\n"
            "from hystfit.io import load_capture\n"
            f"c = load_capture({str(path)!r})\n"
            "print(c.n, 'pandas' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split()
    assert out == ["3000", "False"]


def test_float64_column_matches_pyarrow_to_numpy():
    import pyarrow as pa

    cases = [pa.chunked_array([pa.array([1.5, -0.0, 3.0])]),
             pa.chunked_array([pa.array([1.0, None, 3.0]), pa.array([4.0, 5.0, None]).slice(1)]),
             pa.chunked_array([pa.array([0.25, 7.0, None, 9.0]).slice(1, 2)])]
    for col in cases:
        got = hio._float64_column(col)
        want = col.to_numpy()
        assert got.dtype == np.float64 and got.tobytes() == want.tobytes()


def test_present_matches_pyarrow_validity_on_slices_and_chunks():
    import pyarrow as pa
    import pyarrow.compute as pc

    rng = np.random.default_rng(5)
    values = [None if m else float(v) for m, v in zip(rng.random(301) < 0.3, rng.normal(size=301))]
    arr = pa.array(values, type=pa.float64())
    cases = [arr, arr.slice(3), arr.slice(7, 200), pa.chunked_array([arr.slice(0, 17), arr.slice(17, 101), arr.slice(200)]),
             pa.array([1.0, 2.0]), pa.chunked_array([pa.array([1.0]), pa.array([None], type=pa.float64())])]
    for col in cases:
        want = np.asarray(pc.is_valid(col).to_pylist(), dtype=bool)
        np.testing.assert_array_equal(hio._present(col), want)


def test_a_capture_with_missing_cells_is_read_without_pyarrow_compute(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "cap.csv"
    path.write_text(CASES["empty first column"](_text()))
    code = ("import sys\n"
            "from hystfit.io import load_capture\n"
            f"c = load_capture({str(path)!r})\n"
            "print(c.n, 'pyarrow.compute' in sys.modules, 'pandas' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split()
    assert out == ["3000", "False", "False"]
