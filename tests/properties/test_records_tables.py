"""Report tables written without pandas (:class:`hystfit.io.Records`, :class:`hystfit.io.Columns`) are the
text pandas writes."""

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from hystfit.io import Columns, Records, write_table
from hystfit.report.tables import markdown_table

KEYS = ["condition", "rmse_um", "evaluations", "flag", "note"]
cell = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-10**12, 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1e6, 1e6).map(np.float64),
    st.integers(0, 10**6).map(np.int64),
    st.text(alphabet='ab ,;"\t\n|µ', max_size=6),
)
row = st.dictionaries(st.sampled_from(KEYS), cell, max_size=len(KEYS))
# columns of one type (the common case of a report), with missing keys
typed = st.sampled_from([st.floats(-1e9, 1e9), st.integers(0, 10**9), st.booleans(), st.text(max_size=4)]).flatmap(
    lambda s: st.lists(st.dictionaries(st.sampled_from(KEYS), s, max_size=3), min_size=1, max_size=6))


def _pandas_csv(rows, sep=","):
    return pd.DataFrame(list(rows)).to_csv(index=False, sep=sep, lineterminator="\n")


@settings(max_examples=200, deadline=None)
@given(st.lists(row, min_size=1, max_size=6), st.sampled_from([",", "\t"]))
def test_records_csv_is_the_text_pandas_writes(rows, sep):
    assume(any(rows))  # a report table has columns
    assert Records(tuple(rows)).to_csv(sep) == _pandas_csv(rows, sep)


@settings(max_examples=100, deadline=None)
@given(typed)
def test_records_markdown_is_the_markdown_of_the_dataframe(rows):
    rec = Records(tuple(rows))
    if not rec.columns:
        return
    assert markdown_table(rec) == markdown_table(pd.DataFrame(rows))


def test_a_report_table_keeps_counts_integer_and_floats_exact(tmp_path):
    rows = [{"condition": "60V_10Hz", "rmse_um": 0.1 + 0.2, "evaluations": 60000, "stderr": None},
            {"condition": "a,b", "rmse_um": np.float64(1 / 3), "evaluations": 1, "stderr": math.nan}]
    write_table(tmp_path / "r.csv", Records(tuple(rows)))
    text = (tmp_path / "r.csv").read_text()
    assert text == _pandas_csv(rows)
    assert text.splitlines()[1] == "60V_10Hz,0.30000000000000004,60000,"
    assert text.splitlines()[2] == '"a,b",0.3333333333333333,1,'
    write_table(tmp_path / "r.parquet", Records(tuple(rows)))
    back = pd.read_parquet(tmp_path / "r.parquet")
    assert list(back.columns) == ["condition", "rmse_um", "evaluations", "stderr"] and back["evaluations"].tolist() == [60000, 1]


column_values = st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6).map(float)),
                         min_size=0, max_size=40)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 4).flatmap(lambda k: st.tuples(st.lists(st.text(alphabet='ab ,;"\t_µ', min_size=1, max_size=5),
                                                              min_size=k, max_size=k, unique=True),
                                                     st.lists(column_values, min_size=k, max_size=k))),
       st.sampled_from([",", "\t"]))
def test_columns_csv_is_the_text_pandas_writes(named, sep):
    names, values = named
    n = min(len(v) for v in values)
    cols = {name: np.asarray(v[:n], dtype=float) for name, v in zip(names, values)}
    want = pd.DataFrame(cols).to_csv(index=False, sep=sep, lineterminator="\n")
    assert Columns(cols).to_csv(sep) == want


def test_columns_write_csv_tsv_and_parquet(tmp_path):
    t = np.arange(5) * 1e-4
    cols = Columns({"time_s": t, "voltage_V": np.array([0.0, -0.0, np.nan, 1e-5, 3.25])})
    for name in ("a.csv", "a.tsv", "a.parquet"):
        write_table(tmp_path / name, cols)
    back = pd.read_parquet(tmp_path / "a.parquet")
    assert list(back.columns) == ["time_s", "voltage_V"] and back["time_s"].tolist() == t.tolist()
    assert (tmp_path / "a.csv").read_text() == pd.DataFrame(dict(cols)).to_csv(index=False, lineterminator="\n")
    assert (tmp_path / "a.tsv").read_text().splitlines()[0] == "time_s\tvoltage_V"
    with pytest.raises(ValueError, match="differ in length"):
        Columns({"a": [1.0, 2.0], "b": [1.0]})


def test_columns_are_written_in_pieces_as_one_text(tmp_path, monkeypatch):
    monkeypatch.setattr(Columns, "ROWS_PER_PIECE", 7)
    rng = np.random.default_rng(2)
    v = rng.normal(size=50)
    v[[0, 6, 7, 49]] = np.nan
    cols = Columns({"time_s": np.arange(50) * 1e-4, "y_um": v})
    pieces = list(cols.csv_pieces())
    assert len(pieces) == 1 + 8  # the header, then 50 rows 7 at a time
    write_table(tmp_path / "a.csv", cols)
    assert (tmp_path / "a.csv").read_text() == "".join(pieces) == pd.DataFrame(dict(cols)).to_csv(
        index=False, lineterminator="\n")
