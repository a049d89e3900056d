"""What the fit is handed (``peeljax.measurements.records``, ``.stick_slip_table``,
``.statistics``, ``.text_tables``): force records (text and .npz), stick-slip tables,
the statistics of a measured sawtooth, and ``peeljax fit --data`` reading them."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_refused, forbid, run_cli

from peeljax.measurements.records import load_observations
from peeljax.fit import (
    DataFileError,
    StickSlipTable,
    read_force_record,
    read_observations,
    read_stick_slip_table,
    record_statistics,
)
from peeljax.measurements import records
from peeljax.measurements.records import _V_from_name, read_npz
from peeljax.measurements.stick_slip_table import STATISTICS

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------- force records
def test_csv_force_record_with_comments_units_and_V_column(tmp_path):
    path = write(
        tmp_path,
        "run.csv",
        "# a load cell record\n# t [s], F [N]\n\nt [s], F [N],v,alpha,V\n"
        "0.0,250.5,0.1,0.01,1.1\n0.001,251.25,0.2,0.02,1.1\n\n0.002,252,0.3,0.03,1.1\n# end\n",
    )
    o = read_force_record(path)
    assert o.V == 1.1
    np.testing.assert_array_equal(o.t, [0.0, 0.001, 0.002])
    np.testing.assert_array_equal(o.F, [250.5, 251.25, 252.0])
    np.testing.assert_array_equal(o.v, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(o.alpha, [0.01, 0.02, 0.03])
    assert o.t.dtype == o.F.dtype == np.float64
    assert o.series("F")[0].shape == (3,)


def test_whitespace_force_record_without_v_gives_v_none(tmp_path):
    path = write(tmp_path, "peel_V=2.5.txt", "# tab and space separated\nt[s]\tF[N]\n0 1e2\n0.5\t1.5e2\n1.0   175\n")
    o = read_force_record(path)
    assert o.V == 2.5  # from the name
    assert o.v is None and o.alpha is None and o.series("v") is None
    np.testing.assert_array_equal(o.F, [100.0, 150.0, 175.0])


NAMES = [
    ("peel_V=1.1.csv", 1.1),
    ("run_V1.10.txt", 1.1),
    ("V_2.csv", 2.0),
    ("2024-05-01_V0.8_take3.csv", 0.8),
    ("tape V=3 run.dat", 3.0),
    ("peel_V=1.1", 1.1),  # no suffix: the ".1" is not one
    ("TV2.csv", None),
    ("run_v2.csv", None),  # lower case: the peeling velocity (or a version), not V
    ("run.csv", None),
    ("V1.1.5.csv", None),
]


@pytest.mark.parametrize(("name", "V"), NAMES, ids=[n for n, _ in NAMES])
def test_V_from_the_file_name(name, V):
    assert _V_from_name(name) == V


def test_V_twice_differently_in_a_name_is_refused():
    with pytest.raises(DataFileError, match="V twice"):
        _V_from_name("V1_V2.csv")


RECORD = "t,F\n0,1\n1,2\n"


def test_V_sources_must_agree(tmp_path):
    named = write(tmp_path, "peel_V=1.1.csv", RECORD)
    assert read_force_record(named, V=1.1).V == 1.1  # agreeing sources are fine
    with pytest.raises(DataFileError, match=r"V conflicts: 1.1 m/s from the file name, 2 m/s from the V argument"):
        read_force_record(named, V=2.0)
    column = write(tmp_path, "peel_V=1.1_b.csv", "t,F,V\n0,1,1.2\n1,2,1.2\n")
    with pytest.raises(DataFileError, match=r"'V' column.*file name"):
        read_force_record(column)
    plain = write(tmp_path, "plain.csv", "t,F,V\n0,1,1.2\n1,2,1.2\n")
    with pytest.raises(DataFileError, match="V conflicts"):
        read_force_record(plain, V=1.3)
    assert read_force_record(plain).V == 1.2
    with pytest.raises(ValueError, match=r"\(0, inf\)"):
        read_force_record(plain, V=-1.0)
    zero = write(tmp_path, "V_0.csv", RECORD)
    with pytest.raises(DataFileError, match=r"file name must be > 0"):
        read_force_record(zero)


def test_no_V_anywhere_says_the_three_ways(tmp_path):
    path = write(tmp_path, "run.csv", RECORD)
    with pytest.raises(DataFileError) as error:
        read_force_record(path)
    message = str(error.value)
    assert "run.csv" in message and "'V' column" in message and "peel_V=1.1.csv" in message and "--V" in message
    assert read_force_record(path, V=0.7).V == 0.7


# (file content, line, column, words the message must hold)
BAD_RECORDS = {
    "missing F": ("# c\nt,v\n0,1\n1,2\n", 2, "F", ["missing required column 'F'"]),
    "unknown column": ("t,F,force\n0,1,2\n1,2,3\n", 1, "force", ["unknown column 'force'", "t, F, v, alpha, V"]),
    "duplicate column": ("t,F,F\n0,1,2\n1,2,3\n", 1, "F", ["duplicate column 'F'", "columns 2 and 3"]),
    "text in a number": ("t,F\n0,1\n1,abc\n2,3\n", 3, "F", ["not a number: 'abc'"]),
    "NaN": ("t,F\n0,1\n1,nan\n", 3, "F", ["NaN"]),
    "inf": ("t,F\n0,1\n1,2\n2,-inf\n", 4, "F", ["infinite"]),
    "empty cell": ("t,F\n0,1\n1,\n", 3, "F", ["empty cell"]),
    "ragged row": ("t,F\n0,1\n1,2,3\n", 3, None, ["3 cells", "names 2 columns"]),
    "ragged whitespace": ("t F\n0 1\n1\n", 3, None, ["1 cells separated by whitespace"]),
    "non-increasing t": ("t,F\n0,1\n# gap\n1,2\n1,3\n", 5, "t", ["increase strictly", "line 4"]),
    "negative t": ("t,F\n-1,1\n1,2\n", 2, "t", ["negative time"]),
    "negative F": ("t,F\n0,1\n0.5,-5\n1,2\n", 3, "F", [">= 0 N", "tension", "-5", "t = 0.5 s"]),
    "negative v": ("t,F,v\n0,1,0.1\n1,2,-0.2\n", 3, "v", [">= 0 m/s", "peeling velocity"]),
    "alpha in degrees": ("t,F,alpha\n0,1,0.1\n1,2,45\n", 3, "alpha", ["(-pi, pi) rad", "degrees?"]),
    "empty file": ("", None, None, ["empty"]),
    "comments only": ("# nothing\n\n", None, None, ["no header"]),
    "header only": ("# c\nt,F\n", 2, None, ["header only"]),
    "one row": ("t,F\n0,1\n", 2, None, ["at least 2"]),
    "V not constant": ("t,F,V\n0,1,1.1\n1,2,1.2\n", 3, "V", ["constant"]),
    "wrong unit": ("t [ms],F [N]\n0,1\n1,2\n", 1, "t", ["[ms]", "convert"]),
    "semicolons": ("t;F\n0;1\n1;2\n", 1, "t;F", ["semicolons"]),
    "units row": ("t,F\ns,N\n0,1\n1,2\n", 2, "t", ["not a number: 's'", "units under the header", "'t [s]'"]),
    "units row in brackets": ("t F\n[s] [N]\n0 1\n1 2\n", 2, "t", ["not a number: '[s]'", "'t [s]'"]),
    "bad cell after a million": ("t,F\n0,1\n1,2\n2,three\n", 4, "F", ["not a number: 'three'"]),
}


@pytest.mark.parametrize("case", list(BAD_RECORDS))
def test_malformed_force_records_are_refused_naming_file_line_and_column(case, tmp_path):
    text, line, column, words = BAD_RECORDS[case]
    path = write(tmp_path, "peel_V=1.csv", text)
    with pytest.raises(DataFileError) as error:
        read_force_record(path)
    e = error.value
    assert isinstance(e, ValueError)
    assert (e.line, e.column) == (line, column), str(e)
    message = str(e)
    assert message.startswith(str(path)), message
    if line is not None:
        assert f"line {line}" in message
    if column is not None:
        assert f"column {column!r}" in message
    for word in words:
        assert word in message, message


def test_binary_and_zip_files_are_not_read_as_text(tmp_path):
    npz = tmp_path / "data.npz"
    np.savez(npz, t=[0.0, 1.0], v=[1.0, 2.0], V=1.0)
    disguised = tmp_path / "peel_V=1.csv"
    disguised.write_bytes(npz.read_bytes())
    with pytest.raises(DataFileError, match=r"zip \(\.npz\) archive"):
        read_force_record(disguised)
    binary = tmp_path / "peel_V=2.csv"
    binary.write_bytes(b"t,F\n0,\xff\xfe\n")
    with pytest.raises(DataFileError, match="not a UTF-8 text file"):
        read_force_record(binary)
    with pytest.raises(DataFileError, match="no such file"):
        read_force_record(tmp_path / "missing_V=1.csv")


def test_quoted_csv_header_and_a_byte_order_mark(tmp_path):
    path = tmp_path / "V_3.csv"
    path.write_bytes('\ufeff"t","F"\n0,"10"\n1,11\n'.encode())
    o = read_force_record(path)
    assert o.V == 3.0 and list(o.F) == [10.0, 11.0]


# ---------------------------------------------------------------------------- .npz files
def test_read_observations_dispatches_on_the_suffix(tmp_path):
    t = np.linspace(0, 1, 5)
    npz = tmp_path / "many.npz"
    np.savez(npz, V_0=1.1, t_0=t, v_0=t, F_0=t, V_1=4.0, t_1=t[:3], v_1=t[:3])
    observations = read_observations(npz)
    assert [o.V for o in observations] == [1.1, 4.0]
    csv = write(tmp_path, "V_2.csv", RECORD)
    [o] = read_observations(csv)
    assert o.V == 2.0 and o.v is None
    with pytest.raises(DataFileError, match="V conflicts"):
        read_observations(npz, V=1.1)  # 4.0 in the file
    single = tmp_path / "one.npz"
    np.savez(single, V=1.1, t=t, v=t)
    assert read_observations(single, V=1.1)[0].V == 1.1


def test_npz_settings_tau_and_dt(tmp_path):
    t = np.linspace(0, 1, 5)
    path = tmp_path / "a.npz"
    np.savez(path, V=1.1, t=t, v=t, tau=0.0, dt=np.nan)  # simulate --tau 0 under error control
    _, settings = read_npz(path)
    assert settings == {"tau": 0.0}  # tau = 0 (the DAE itself) is kept, NaN dt skipped
    np.savez(path, V=1.1, t=t, v=t, tau=0.05, dt=0.1)
    assert read_npz(path)[1] == {"tau": 0.05, "dt": 0.1}


def test_npz_nan_in_a_quantity_is_a_missing_value(tmp_path):
    t = np.linspace(0, 1, 5)
    path = tmp_path / "stopped.npz"
    np.savez(path, V=1.1, t=t, v=np.where(t > 0.6, np.nan, t), F=np.where(t > 0.6, np.nan, t))
    [o] = read_observations(path)
    assert o.series("v")[0].shape == (3,)  # t = 0, 0.25, 0.5


def _bad_npz(tmp_path):
    t = np.linspace(0, 1, 5)
    cases = {
        "NaN time": ({"V": 1.0, "t": np.where(t > 0.5, np.nan, t), "v": t}, "t", "NaN"),
        "negative time": ({"V": 1.0, "t": t - 0.5, "v": t}, "t", "negative"),
        "NaN t_F": ({"V": 1.0, "t": t, "v": t, "F": t, "t_F": np.where(t > 0.5, np.nan, t)}, "t_F", "NaN"),
        "negative tau": ({"V": 1.0, "t": t, "v": t, "tau": -0.01}, "tau", "[0, inf)"),
        "infinite tau": ({"V": 1.0, "t": t, "v": t, "tau": np.inf}, "tau", "[0, inf)"),
        "NaN tau": ({"V": 1.0, "t": t, "v": t, "tau": np.nan}, "tau", "[0, inf)"),
        "text tau": ({"V": 1.0, "t": t, "v": t, "tau": "0.1"}, "tau", "must be a number"),
        "missing v": ({"V": 1.0, "t": t}, "v", "missing 'v'"),
        "negative V": ({"V": -1.0, "t": t, "v": t}, "V", "(0, inf)"),
        "negative F": ({"V": 1.0, "t": t, "v": t, "F": t - 0.3}, "F", ">= 0 N"),
        "negative v": ({"V": 1.0, "t": t, "v": t - 0.3}, "v", ">= 0 m/s"),
        "alpha in degrees": ({"V": 1.0, "t": t, "v": t, "alpha": 30 * t}, "alpha", "(-pi, pi) rad"),
        "after_jump not booleans": ({"V": 1.0, "t": t, "v": t, "after_jump": t}, "after_jump", "booleans"),
    }
    for name, (arrays, *_) in cases.items():
        np.savez(tmp_path / f"{name}.npz", **arrays)
    return cases


@pytest.mark.parametrize(
    "case",
    [
        "NaN time",
        "negative time",
        "NaN t_F",
        "negative tau",
        "infinite tau",
        "NaN tau",
        "text tau",
        "missing v",
        "negative V",
        "negative F",
        "negative v",
        "alpha in degrees",
        "after_jump not booleans",
    ],
)
def test_bad_npz_refused_naming_file_and_field(case, tmp_path):
    _, field, word = _bad_npz(tmp_path)[case]
    path = tmp_path / f"{case}.npz"
    with pytest.raises(DataFileError) as error:
        read_observations(path)
    message = str(error.value)
    assert error.value.column == field and f"field {field!r}" in message and str(path) in message, message
    assert word in message, message


def test_a_run_file_reads_as_a_record_of_left_limits(tmp_path):
    """A ``simulate --out`` file keeps both sides of every jump (two rows at its time, the second
    in ``after_jump``); as data its rows are the left limits, one per time, so it can be fitted."""
    import peeljax as pj
    from peeljax.run_file import write_run

    sol = pj.simulate(V=1.1, tau=0.0, t_final=0.4, ts=np.linspace(0.0, 0.4, 201))
    assert int(sol.jumps.count) >= 2 and np.any(np.diff(np.asarray(sol.ts)) == 0)
    path = tmp_path / "run.npz"
    write_run(path, sol, V=1.1, tau=0.0)
    (observation,), settings = read_npz(path)
    after = np.asarray(sol.after_jump)
    t_v, v = observation.series("v")
    assert np.all(np.diff(t_v) > 0) and settings["tau"] == 0.0
    # every time of the run once, with the state before the jump at a jump's time
    np.testing.assert_array_equal(t_v, np.unique(np.asarray(sol.ts)))
    for t_jump, v_before in zip(np.asarray(sol.jumps.t)[: int(sol.jumps.count)], np.asarray(sol.jumps.v_before)):
        np.testing.assert_allclose(v[t_v == t_jump], v_before, rtol=1e-12)
    assert np.sum(after) == int(sol.jumps.count)
    t_F, F = observation.series("F")
    np.testing.assert_array_equal(t_F, t_v)
    assert np.all(F > 0)
    # an output time equal to a jump's time: its row holds the state before the jump, as the next
    np.savez(path, V=1.1, t=[0.0, 1.0, 1.0, 1.0, 2.0], v=[0.1, 0.2, 0.2, 3.0, 2.5],
             after_jump=np.array([False, False, False, True, False]))  # fmt: skip
    (observation,), _ = read_npz(path)
    np.testing.assert_array_equal(observation.series("v"), ([0.0, 1.0, 2.0], [0.1, 0.2, 2.5]))


# ---------------------------------------------------------------------------- stick-slip tables
TABLE = """# a lab's table
V [m/s], F_mean [N], F_mean_std, F_slip, F_stick, period [s], period_std
2.0, 250.0, 1.5, 270, 230, 0.05, 0.002
0.5, 240.0, , 265, 215, -, 
1.1, 245.5, 2.0, , 220.25, 0.08,0.01
"""  # noqa: W291 (a cell of spaces: the reader must take it as empty)


def test_read_a_stick_slip_table(tmp_path):
    table = read_stick_slip_table(write(tmp_path, "table.csv", TABLE))
    np.testing.assert_array_equal(table.V, [0.5, 1.1, 2.0])  # sorted
    assert table.statistics == ("F_mean", "F_slip", "F_stick", "period")
    assert len(table) == 3 and table.STATISTICS == STATISTICS
    np.testing.assert_array_equal(table.values["F_mean"], [240.0, 245.5, 250.0])
    np.testing.assert_array_equal(table.values["F_slip"], [265.0, np.nan, 270.0])
    np.testing.assert_array_equal(table.values["period"], [np.nan, 0.08, 0.05])
    assert set(table.std) == {"F_mean", "period"}
    np.testing.assert_array_equal(table.std["F_mean"], [np.nan, 2.0, 1.5])
    np.testing.assert_array_equal(table.std["period"], [np.nan, 0.01, 0.002])
    with pytest.raises(dataclasses_frozen()):
        table.V = np.ones(3)
    with pytest.raises(ValueError, match="read-only"):
        table.values["F_mean"][0] = 1.0


def dataclasses_frozen():
    import dataclasses

    return dataclasses.FrozenInstanceError


def test_whitespace_table_with_dashes(tmp_path):
    table = read_stick_slip_table(
        write(tmp_path, "t.txt", "V F_slip F_stick slip_duration\n1 280 200 -\n2 - 210 0.003\n")
    )
    np.testing.assert_array_equal(table.values["slip_duration"], [np.nan, 0.003])
    assert table.std == {}


def test_table_round_trips_through_csv_and_from_dict(tmp_path):
    rng = np.random.default_rng(3)
    V = np.sort(rng.uniform(0.4, 4.5, 10))
    columns = {
        "V": V,
        "F_mean": rng.uniform(200, 300, 10),
        "F_mean_std": rng.uniform(0.1, 3, 10),
        "F_slip": np.where(np.arange(10) % 3 == 0, np.nan, 400 + rng.normal(size=10)),
        "period": 1 / 3 + rng.uniform(0, 1e-3, 10),
        "slip_duration_std": None,
    }
    del columns["slip_duration_std"]
    table = StickSlipTable.from_dict(**columns)
    path = tmp_path / "out.csv"
    table.to_csv(path)
    again = read_stick_slip_table(path)
    assert again == table  # bit for bit, NaN where not measured
    np.testing.assert_array_equal(again.values["period"], columns["period"])
    assert table.columns() == ["V", "F_mean", "F_mean_std", "F_slip", "period"]
    reversed_ = StickSlipTable.from_dict({k: v[::-1] for k, v in columns.items()})
    assert reversed_ == table  # sorted by V either way
    assert table != StickSlipTable.from_dict(V=V, F_mean=columns["F_mean"])  # the std differs


def test_table_repr_and_str():
    table = StickSlipTable.from_dict(
        V=[1.1, 2.0], F_slip=[280.0, 290.0], F_slip_std=[1.5, None], F_stick=[200.0, np.nan]
    )
    text = str(table)
    assert "V [m/s]" in text and "F_slip [N]" in text and "280 ± 1.5" in text and "290" in text
    assert text.splitlines()[2].rstrip().endswith("-")  # F_stick not measured at V = 2
    assert repr(table).startswith("StickSlipTable(2 V in [1.1, 2] m/s: F_slip, F_stick)")
    long = StickSlipTable.from_dict(V=np.arange(1, 31) / 10, F_mean=np.full(30, 250.0))
    assert len(repr(long).splitlines()) == 1 + 1 + 12  # header line, column heads, 12 rows with the "…"


# (table text, line, column, words)
BAD_TABLES = {
    "no V column": ("F_mean\n250\n", 1, "V", ["missing required column 'V'"]),
    "no statistic": ("V\n1\n", 1, None, ["no statistic column"]),
    "unknown column": ("V,F_max\n1,2\n", 1, "F_max", ["unknown column", "F_slip"]),
    "std without column": ("V,F_mean,F_slip_std\n1,2,3\n", 1, "F_slip_std", ["without its value"]),
    "duplicate V": ("V,F_mean\n1,250\n# c\n2,251\n1.0,252\n", 5, "V", ["given twice", "line 2"]),
    "V <= 0": ("V,F_mean\n1,250\n0,251\n", 3, "V", ["(0, inf)"]),
    "empty V": ("V,F_mean\n1,250\n,251\n", 3, "V", ["required in every row"]),
    "nan literal": ("V,F_mean\n1,nan\n", 2, "F_mean", ["NaN", "empty cell or '-'"]),
    "inf": ("V,F_mean\n1,inf\n", 2, "F_mean", ["infinite"]),
    "text": ("V,F_mean\n1,2x\n", 2, "F_mean", ["not a number: '2x'"]),
    "period <= 0": ("V,period\n1,0.1\n2,0\n", 3, "period", ["> 0"]),
    "std <= 0": ("V,F_mean,F_mean_std\n1,250,-1\n", 2, "F_mean_std", ["> 0"]),
    "std without value": ("V,F_mean,F_mean_std\n1,,1\n", 2, "F_mean_std", ["without its value"]),
    "slip below stick": ("V,F_slip,F_stick\n1,200,250\n", 2, "F_slip", ["must exceed F_stick"]),
    "row without values": ("V,F_mean,F_slip\n1,250,\n2,,-\n", 3, None, ["without any value"]),
    "header only": ("V,F_mean\n", 1, None, ["header only"]),
    "ragged": ("V,F_mean\n1,2,3\n", 2, None, ["3 cells"]),
}


@pytest.mark.parametrize("case", list(BAD_TABLES))
def test_malformed_tables_are_refused_naming_file_line_and_column(case, tmp_path):
    text, line, column, words = BAD_TABLES[case]
    path = write(tmp_path, "table.csv", text)
    with pytest.raises(DataFileError) as error:
        read_stick_slip_table(path)
    e = error.value
    assert (e.line, e.column) == (line, column), str(e)
    assert str(e).startswith(str(path))
    for word in words:
        assert word in str(e), str(e)


@pytest.mark.parametrize(
    ("columns", "words"),
    [
        ({"F_mean": [1.0]}, ["'V'"]),
        ({"V": [1.0], "F_max": [1.0]}, ["unknown column", "F_slip"]),
        ({"V": [1.0]}, ["no statistic"]),
        ({"V": [1.0, 1.0], "F_mean": [1.0, 2.0]}, ["V[1]", "given twice", "index 0"]),
        ({"V": [1.0, 2.0], "period": [0.1, -0.1]}, ["period[1]", "> 0"]),
        ({"V": [1.0, 2.0], "F_mean": [1.0, 2.0, 3.0]}, ["F_mean", "length of V"]),
        ({"V": [1.0], "F_mean": [1.0], "F_slip_std": [1.0]}, ["F_slip_std", "without its value"]),
        ({"V": [1.0], "F_mean": [np.inf]}, ["F_mean[0]", "infinite"]),
        ({"V": [1.0], "F_mean": ["a"]}, ["F_mean", "numbers"]),
    ],
)
def test_from_dict_validates_like_a_file(columns, words):
    with pytest.raises(ValueError) as error:
        StickSlipTable.from_dict(**columns)
    for word in words:
        assert word in str(error.value), str(error.value)


# ---------------------------------------------------------------------------- statistics of a record
def sawtooth(*, F_stick=200.0, F_slip=280.0, stick=0.040, slip=0.004, cycles=12, dt=5e-4, offset=0.010):
    """A piecewise-linear sawtooth sampled every dt: rises from F_stick to F_slip over ``stick``,
    falls back over ``slip``; its maxima at offset + k·(stick + slip) + stick (k ≥ -1) lie on samples."""
    period = stick + slip
    t = np.arange(round((offset + cycles * period) / dt) + 1) * dt
    phase = np.mod(t - offset, period)
    F = np.where(
        phase < stick,
        F_stick + (F_slip - F_stick) * phase / stick,
        F_slip - (F_slip - F_stick) * (phase - stick) / slip,
    )
    peaks = offset + np.arange(-1, cycles) * period + stick
    return t, F, peaks[(peaks >= 0) & (peaks < t[-1])]


def test_statistics_of_an_exact_sawtooth():
    t, F, peaks = sawtooth()
    r = record_statistics(t, F)
    # the first extremum (the record's first sample, on a rise: no true minimum) is left out;
    # every slip is found, the one at 6 ms as well
    assert r["slips"] == peaks.size == 13 and peaks[0] == pytest.approx(0.006)
    np.testing.assert_allclose(r["t_slip"], peaks, atol=1e-12)
    assert r["F_slip"] == pytest.approx(280.0, abs=1e-9) and r["F_slip_std"] == pytest.approx(0.0, abs=1e-9)
    assert r["F_stick"] == pytest.approx(200.0, abs=1e-9)
    assert r["period"] == pytest.approx(0.044, abs=1e-12)
    assert r["slip_duration"] == pytest.approx(0.004, abs=1e-12)
    # the time average of a linear rise and a linear fall is the mid-point (up to the cut ends)
    assert r["F_mean"] == pytest.approx(240.0, abs=1.0)
    inner = record_statistics(t, F, transient=peaks[0])  # from a maximum: whole cycles only
    assert inner["F_mean_std"] == pytest.approx(0.0, abs=1e-9)
    assert r["noise"] < 1e-6 and r["min_drop"] == pytest.approx(0.8)  # 1 % of the 80 N range


def test_statistics_with_noise_recover_the_sawtooth():
    t, F, peaks = sawtooth(cycles=40)
    rng = np.random.default_rng(7)
    sigma = 2.0  # 1 % of the mean force; the drop is 80 N
    noisy = F + rng.normal(scale=sigma, size=F.size)
    r = record_statistics(t, noisy)
    assert r["noise"] == pytest.approx(sigma, rel=0.15)
    assert r["min_drop"] == pytest.approx(10 * r["noise"])
    # the maximum at 6 ms rose only 12 N within the record, less than min_drop: as the first
    # extremum found it is left out (its rise may be cut); every later slip is found
    peaks = peaks[1:]
    assert r["slips"] == peaks.size
    # the noisy maximum may lie a few samples early: the rise is 1 N per sample, the noise 2 N
    assert np.median(np.abs(r["t_slip"] - peaks)) <= 2 * 5e-4 and np.max(np.abs(r["t_slip"] - peaks)) <= 10 * 5e-4
    assert r["F_slip"] == pytest.approx(280.0, abs=2 * sigma)  # the maximum of noisy samples: biased up
    assert r["F_stick"] == pytest.approx(200.0, abs=2 * sigma)
    assert r["period"] == pytest.approx(0.044, abs=2.5e-4)
    assert r["slip_duration"] == pytest.approx(0.004, abs=1e-3)
    assert r["F_mean"] == pytest.approx(240.0, abs=0.5)
    assert 0 < r["F_slip_std"] < 2 * sigma and 0 < r["period_std"] < 1e-3


def _hysteresis_extrema(F, drop):
    """The definition of record_statistics' slips, sample by sample (the hand-written loop that
    scipy.signal.find_peaks replaced): a maximum is confirmed by a fall of more than ``drop``
    below the running maximum, a minimum by a rise of more than ``drop``; the first one found
    is left out."""
    found, i_max, i_min, mode = [], 0, 0, 0  # mode +1: seeking a maximum, -1: a minimum, 0: either
    for i in range(1, F.size):
        if mode >= 0:
            i_max = i if F[i] > F[i_max] else i_max
            if F[i_max] - F[i] > drop:
                found.append((i_max, True))
                mode, i_min = -1, i
                continue
        if mode <= 0:
            i_min = i if F[i] < F[i_min] else i_min
            if F[i] - F[i_min] > drop:
                found.append((i_min, False))
                mode, i_max = 1, i
    found = found[1:]
    return [i for i, up in found if up], [i for i, up in found if not up]


def test_slips_are_the_hysteresis_extrema_also_on_quantized_records():
    """find_peaks by prominence gives the hysteresis definition's extrema exactly, ties included:
    of a flat top its first sample, of equal maxima with a shallow dip between them the first."""
    t = np.arange(12.0)
    F = np.array([0, 5, 5, 5, 0, 4, 6, 5.5, 6, 1, 3, 0])  # a flat top; two equal maxima, dip 0.5
    r = record_statistics(t, F, min_drop=2.0)
    np.testing.assert_array_equal(r["t_slip"], [1.0, 6.0])  # the flat top's first sample; the first 6
    # the first minimum (t = 0) is left out; the rise 1 → 3 is not more than min_drop: 9 is none
    np.testing.assert_array_equal(r["t_stick"], [4.0])
    rng = np.random.default_rng(3)
    for case in range(300):  # quantized random walks and sawtooths: plateaus and equal extrema
        n = int(rng.integers(2, 120))
        walk = np.round(np.cumsum(rng.normal(size=n)) * 2) / 2
        saw = np.round((np.linspace(0, 5, n) % 1.0) * 8 + rng.normal(scale=0.7, size=n))
        F = walk if case % 2 else saw
        drop = float(rng.choice([0.5, 1.0, 2.0, rng.uniform(0.1, 3.0)]))
        r = record_statistics(np.arange(n, dtype=float), F, min_drop=drop)
        up, down = _hysteresis_extrema(F, drop)
        np.testing.assert_array_equal(r["t_slip"], up)
        np.testing.assert_array_equal(r["t_stick"], down)


def test_steady_record_gives_only_F_mean():
    t = np.linspace(0, 2, 4001)
    F = 250.0 + 0.5 * np.sin(3 * t) + np.random.default_rng(0).normal(scale=1.0, size=t.size)
    r = record_statistics(t, F)
    assert r["slips"] == 0 and r["t_slip"].size == 0
    assert r["F_mean"] == pytest.approx(250.0, abs=0.2)
    assert math.isnan(r["F_mean_std"])
    assert not {"F_slip", "F_stick", "period", "slip_duration"} & set(r)


def test_min_drop_and_transient():
    t, F, peaks = sawtooth(cycles=10)
    assert record_statistics(t, F, min_drop=100.0)["slips"] == 0  # larger than the 80 N drops
    # a window starting mid-fall: its first sample is no maximum, and it is not counted as one
    start = peaks[2] + 0.002
    r = record_statistics(t, F, transient=start)
    assert r["slips"] == np.sum(peaks > start) and r["F_slip"] == pytest.approx(280.0, abs=1e-9)
    assert r["window"][0] >= start
    with pytest.raises(ValueError, match="min_drop"):
        record_statistics(t, F, min_drop=0.0)
    with pytest.raises(ValueError, match="fewer than 2 samples"):
        record_statistics(t, F, transient=10.0)
    with pytest.raises(ValueError, match="increase strictly"):
        record_statistics(t[::-1], F)


def test_table_from_force_records_pools_each_V():
    from peeljax.fit import Observation

    t, F, _ = sawtooth(cycles=20)
    rng = np.random.default_rng(1)
    records = [
        Observation(V=2.0, t=t, v=None, F=F + rng.normal(scale=0.5, size=t.size)),
        Observation(V=1.0, t=t, v=None, F=F),
        Observation(V=2.0, t=t, v=None, F=F + 10 + rng.normal(scale=0.5, size=t.size)),
        Observation(V=3.0, t=t, v=None, F=np.full(t.size, 260.0) + rng.normal(scale=0.5, size=t.size)),
    ]
    table = StickSlipTable.from_force_records(records, transient=0.01)
    np.testing.assert_array_equal(table.V, [1.0, 2.0, 3.0])
    assert table.statistics == STATISTICS
    one = record_statistics(t, F, transient=0.01)
    assert table.values["F_slip"][0] == pytest.approx(one["F_slip"])
    assert math.isnan(table.std["F_slip"][0])  # a spread of exactly 0 (noise-free) is not a std
    assert table.values["F_slip"][1] == pytest.approx(285.0, abs=1.0)  # the two records pooled
    assert table.std["F_slip"][1] == pytest.approx(5.0, rel=0.1)
    assert table.values["F_mean"][2] == pytest.approx(260.0, abs=0.1)  # steady: F_mean only
    assert all(math.isnan(table.values[k][2]) for k in ("F_slip", "F_stick", "period", "slip_duration"))
    with pytest.raises(ValueError, match="no force F"):
        StickSlipTable.from_force_records([Observation(V=1.0, t=t, v=F)])


def test_the_example_force_record():
    """docs/examples/peel_V=1.1.csv: V from its name, 0.5 ms sampling, the model's bursts of slips."""
    path = EXAMPLES / "peel_V=1.1.csv"
    o = read_force_record(path)
    assert o.V == 1.1 and o.v is None and o.t.size == 2001
    np.testing.assert_allclose(np.diff(o.t), 5e-4, atol=1e-12)
    r = record_statistics(o.t, o.F, transient=0.3)
    # the comment line states the number of stick → slip jumps in [0, 1] s
    slips_in_file = int(path.read_text().split(" stick -> slip jumps")[0].rsplit(" ", 1)[-1])
    first = float(path.read_text().split("first slip at t = ")[1].split(" s")[0])
    everything = record_statistics(o.t, o.F, transient=first - 0.01)
    assert everything["slips"] == slips_in_file
    assert abs(everything["t_slip"][0] - first) <= 5e-4
    assert 200 < r["F_stick"] < r["F_mean"] < r["F_slip"] < 300
    assert 1e-3 < r["slip_duration"] < 5e-3  # slips take ~2.6 ms at V = 1.1


@pytest.mark.slow
def test_detected_slips_are_the_model_jumps():
    """A peeljax run at V = 1.1 (τ = 0, jumps at the folds): every stick → slip jump after the
    transient is found as a maximum of F within a sample, every slip → stick as a minimum; also
    with noise of 0.1 % of the force (0.25 N, below the smallest re-stick rise of ~6 N / 10)."""
    import peeljax as pj

    dt = 5e-4
    ts = np.arange(round(2.0 / dt) + 1) * dt
    model = pj.PeelingModel()
    sol = pj.simulate(model, V=1.1, tau=0, t_final=2.0, fold="jump", ts=ts, rtol=1e-8, atol=1e-10, max_steps=400_000)
    assert sol.status_name == "completed"
    rows = ~np.asarray(sol.before_jump) & ~np.asarray(sol.after_jump)  # the samples at ts (not the jumps' rows)
    ys = np.asarray(sol.ys)[rows]
    F = np.asarray(model.tension(ys[:, 2], ys[:, 0]))
    n = int(sol.jumps.count)
    jt, up = np.asarray(sol.jumps.t)[:n], np.asarray(sol.jumps.up)[:n]
    transient = 1.0
    ups, downs = jt[up & (jt > transient)], jt[~up & (jt > transient)]
    for noise, samples in ((0.0, 1), (0.25, 4)):
        F_obs = F + np.random.default_rng(0).normal(scale=noise, size=F.size) if noise else F
        r = record_statistics(ts, F_obs, transient=transient)
        assert r["slips"] == ups.size > 30
        assert np.max(np.abs(r["t_slip"] - ups)) <= samples * dt
        stick = r["t_stick"]
        assert stick.size == downs.size and np.max(np.abs(stick - downs)) <= samples * dt
        # the statistics agree with the jumps' own durations
        slip_durations = downs - ups[: downs.size] if downs[0] > ups[0] else downs[1:] - ups[: downs.size - 1]
        assert r["slip_duration"] == pytest.approx(np.mean(slip_durations), abs=samples * dt)
        assert r["period"] == pytest.approx(np.mean(np.diff(ups)), abs=samples * dt / 10)


# ---------------------------------------------------------------------------- the command line
@pytest.fixture
def caught_fit(monkeypatch):
    """fit_adhesion replaced: records what the command line hands it, then stops the command."""
    seen = {}

    class Reached(Exception):
        pass

    def fake(observations, **kwargs):
        seen["observations"], seen["kwargs"] = observations, kwargs
        raise Reached

    monkeypatch.setattr("peeljax.fit.fit_adhesion", fake)
    return seen, Reached


def test_cli_reads_csv_force_records_with_and_without_V(tmp_path, monkeypatch):
    """A record with v and a force record (t, F) in one call: both fitted by fit_records (point
    by point: the force record is too short to stick-slip), the choice said on stderr."""
    seen = {}

    class Reached(Exception):
        pass

    def fake(observations, model=None, **kwargs):
        seen["observations"], seen["kwargs"] = observations, kwargs
        raise Reached

    monkeypatch.setattr("peeljax.fit.fit_records", fake)
    named = write(tmp_path, "peel_V=1.1.csv", "t,F,v\n0,250,0.5\n0.1,251,0.6\n0.2,252,0.7\n")
    plain = write(tmp_path, "run.txt", "t F\n0 260\n0.1 261\n0.3 262\n")
    out = str(tmp_path / "fitted.json")
    with pytest.raises(Reached):
        run_cli(["fit", "--data", str(named), "--data", str(plain), "--V", "1.1", "2.0", "--out", out])
    [a, b] = seen["observations"]
    assert (a.V, b.V) == (1.1, 2.0)
    np.testing.assert_array_equal(a.v, [0.5, 0.6, 0.7])
    assert b.v is None and list(b.F) == [260.0, 261.0, 262.0]
    assert seen["kwargs"]["by"] == "auto" and seen["kwargs"]["tau"] == 0.01


def test_load_observations_mixes_npz_and_text(tmp_path):
    t = np.linspace(0, 1, 5)
    npz = tmp_path / "a.npz"
    np.savez(npz, V=4.0, t=t, v=t, tau=0.05)
    csv = write(tmp_path, "V_2.csv", RECORD)
    observations, defaults = load_observations([str(npz), str(csv)])
    assert [o.V for o in observations] == [4.0, 2.0] and defaults == {"tau": 0.05}
    observations, _ = load_observations([str(csv)], [2.0])
    assert observations[0].V == 2.0


@pytest.fixture
def no_fit(monkeypatch):
    forbid(monkeypatch, "peeljax.fit", "fit_adhesion", reason="fit_adhesion must not run for bad input")


def test_cli_refuses_text_without_V_and_bad_files(tmp_path, no_fit):
    out = ["--out", str(tmp_path / "fitted.json")]
    plain = write(tmp_path, "run.csv", RECORD)
    code, stdout, stderr = run_cli(["fit", "--data", str(plain), *out])
    assert_refused(code, stderr, "--data", "run.csv", "no pull velocity V", "--V", stdout=stdout)
    bad = write(tmp_path, "peel_V=1.1.csv", "t,F\n0,1\n1,oops\n")
    code, stdout, stderr = run_cli(["fit", "--data", str(bad), *out])
    assert_refused(code, stderr, "--data", "peel_V=1.1.csv", "line 3", "column 'F'", "not a number", stdout=stdout)
    code, stdout, stderr = run_cli(["fit", "--data", str(bad), "--V", "2", *out])
    assert_refused(code, stderr, "--data", "line 3", stdout=stdout)  # the file is checked before V
    conflict = write(tmp_path, "peel_V=1.2.csv", RECORD)
    code, stdout, stderr = run_cli(["fit", "--data", str(conflict), "--V", "2", *out])
    assert_refused(code, stderr, "--data", "V conflicts", "file name", stdout=stdout)
    code, stdout, stderr = run_cli(["fit", "--data", str(plain), "--V", "-1", *out])
    assert_refused(code, stderr, "--V", "(0, inf)", stdout=stdout)
    code, stdout, stderr = run_cli(["fit", "--data", str(plain), "--data", str(plain), "--V", "1", "2", "3", *out])
    assert_refused(code, stderr, "--V", "one per file", stdout=stdout)
    t = np.linspace(0, 1, 5)
    npz = tmp_path / "tau.npz"
    np.savez(npz, V=1.0, t=t, v=t, tau=-0.1)
    code, stdout, stderr = run_cli(["fit", "--data", str(npz), *out])
    assert_refused(code, stderr, "--data", "tau.npz", "field 'tau'", stdout=stdout)


def test_the_old_module_peeljax_fit_data_warns_on_use_and_re_exports_the_same_names():
    import importlib

    import peeljax.fit as fit

    data = importlib.import_module("peeljax.fit.data")
    with pytest.warns(DeprecationWarning, match="peeljax.fit.data is deprecated: import StickSlipTable from peeljax.measurements"):
        assert data.StickSlipTable is fit.StickSlipTable
    with pytest.warns(DeprecationWarning):
        for name in ("DataFileError", "read_force_record", "read_observations", "read_stick_slip_table", "record_statistics"):
            assert getattr(data, name) is getattr(fit, name)
        assert data.STATISTICS == STATISTICS and data.read_npz is read_npz


@pytest.mark.parametrize("old, new", [
    ("peeljax.fit.measured_statistics", "peeljax.measurements.statistics"),
    *[(f"peeljax.fit.{name}", f"peeljax.measurements.{name}")
      for name in ("records", "statistics", "stick_slip_table", "text_tables", "observations", "instrument")],
])  # fmt: skip
def test_an_old_module_path_warns_on_use_and_re_exports(old, new):
    import importlib

    old_module, new_module = importlib.import_module(old), importlib.import_module(new)
    for name in new_module.__all__:
        message = f"{old} is deprecated: import {name} from {new} ({old} is removed in peeljax 0.3.0)"
        with pytest.warns(DeprecationWarning, match=re.escape(message)):
            assert getattr(old_module, name) is getattr(new_module, name)
    assert set(new_module.__all__) <= set(dir(old_module))


# ---------------------------------------------------------------------------- speed and memory
def _record(path: Path, n: int, comment: str = "") -> Path:
    t = np.arange(n) * 1e-3
    body = np.column_stack([t, 250 + np.sin(t), 1.1 + 0.1 * np.cos(t)])
    with open(path, "w") as stream:
        stream.write(f"# a long record{comment}\nt [s], F [N], v [m/s]\n")
        np.savetxt(stream, body, fmt="%.6f", delimiter=",")
    return path


def test_a_good_record_is_parsed_by_numpys_reader_and_equals_the_scan(tmp_path, monkeypatch):
    """The C reader (numpy.loadtxt) reads a good file; the line-by-line scan, which words the
    refusals, reads the same numbers; trailing comments are comments in both."""
    import peeljax.measurements.text_tables as text_tables

    path = _record(tmp_path / "peel_V=1.1.csv", 2000)
    with open(path, "a") as stream:
        stream.write("2.0, 250.5, 1.2  # a comment after the numbers\n\n")
    scanned = text_tables._scan(str(path), records.FORCE_COLUMNS, ("t", "F"), "force record", False)
    forbid(monkeypatch, text_tables, "_scan", reason="a good file is read by numpy.loadtxt, not scanned")
    fast = read_force_record(path)
    assert fast.t.size == 2001 and fast.t[-1] == 2.0 and fast.v[-1] == 1.2
    for name in ("t", "F", "v"):
        np.testing.assert_array_equal(getattr(fast, name), scanned.columns[name])
    assert list(scanned.lines[:2]) == [3, 4]  # line numbers: the comment and the header come first


def test_the_memory_a_file_needs_is_estimated_before_reading_and_refused_when_too_much(tmp_path, monkeypatch):
    import peeljax.measurements.text_tables as text_tables

    path = _record(tmp_path / "peel_V=1.1.csv", 20_000)
    head = path.read_text()[: 1 << 16]
    need, rows = text_tables.estimated_bytes(path.stat().st_size, head, 2, 3)
    assert rows == pytest.approx(20_000, rel=0.02)  # from the size and the first rows' length
    assert need == pytest.approx(20_000 * 3 * 8 * 1.25, rel=0.02)
    forbid(monkeypatch, np, "loadtxt", reason="a file too large for the memory must not be read")
    with pytest.raises(DataFileError) as error:
        read_force_record(path, memory_limit=need / 2)
    message = str(error.value)
    assert message.startswith(str(path)) and "too large to read" in message
    assert re.search(r"about (19|20),\d{3} rows of 3 numbers", message), message
    assert f"{need / 1e9:.3g} GB" in message and "memory limit" in message
    monkeypatch.setattr(text_tables, "default_memory_limit", lambda: need / 2)  # the command line's limit
    code, stdout, stderr = run_cli(["fit", "--data", str(path), "--out", str(tmp_path / "fitted.json")])
    assert_refused(code, stderr, "--data", str(path), "too large to read", "GB", stdout=stdout)


def test_a_record_denser_than_the_fit_can_hold_is_refused_and_decimated_on_request(tmp_path, caught_fit):
    """More samples than MAX_FIT_SAMPLES: exit 2 naming the file, the estimate and the
    --decimate that thins it, before compiling; with --decimate the fit gets the kept samples."""
    seen, Reached = caught_fit
    n = records.MAX_FIT_SAMPLES + 5000
    path = _record(tmp_path / "peel_V=1.1.csv", n)
    out = ["--out", str(tmp_path / "fitted.json")]
    code, stdout, stderr = run_cli(["fit", "--data", str(path), *out])
    message = assert_refused(code, stderr, "--data", str(path), f"{n} samples", "0.001 s apart", "--decimate 2",
                             "far denser", "GB", stdout=stdout)  # fmt: skip
    assert "observations" not in seen, message
    with pytest.raises(Reached):
        run_cli(["fit", "--data", str(path), "--decimate", "2", *out])
    [kept] = seen["observations"]
    assert kept.t.size == kept.v.size == kept.F.size == -(-n // 2) and kept.t.flags.c_contiguous
    np.testing.assert_array_equal(kept.t, read_force_record(path).t[::2])
    code, stdout, stderr = run_cli(["fit", "--data", str(path), "--decimate", "0", *out])
    assert_refused(code, stderr, "--decimate", "[1, inf)", stdout=stdout)
    code, stdout, stderr = run_cli(["fit", "--table", str(EXAMPLES / "stick_slip_table.csv"), "--decimate", "2", *out])
    assert_refused(code, stderr, "--decimate", "--table", stdout=stdout)


def test_an_npz_too_large_for_the_memory_is_refused_before_its_arrays_are_read(tmp_path, monkeypatch):
    from peeljax import _memory

    t = np.linspace(0, 1, 1000)
    path = tmp_path / "big.npz"
    np.savez(path, V=1.1, t=t, v=t)
    monkeypatch.setattr(_memory, "memory_limit", lambda: 10_000.0)  # the arrays take 16 008 bytes
    with pytest.raises(DataFileError, match=r"big.npz: too large to read: its arrays take 1.6e-05 GB once read"):
        read_npz(path)
    monkeypatch.setattr(_memory, "memory_limit", lambda: 20_000.0)
    assert read_npz(path)[0][0].t.size == 1000
