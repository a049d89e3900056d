"""Property-based test of the command line (issue 30 item 10): generated command lines for
every subcommand, with damaged data files, must end with exit 0, 2 or 130 and no traceback,
and a refusal (2) must come as one ``peeljax: error: ...`` line before anything heavy runs.

The heavy entry points (the compiled runners of ``peeljax.simulate`` and of the sweeps, the
two fits, the figures, joining other processes) raise :class:`Accepted` here: a case that
reaches one passed every check, and nothing is compiled or integrated. In the interrupt mode
they raise KeyboardInterrupt instead (Ctrl-C during the run: exit 130, one line).

CI runs a fixed, small budget (derandomized, no database, no deadline). A long run:
``PEELJAX_FUZZ_EXAMPLES=10000 pytest -n 0 tests/test_cli_fuzz.py`` (examples per test).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import ERROR_PREFIX
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from peeljax.adhesion import COEFFICIENT_NAMES
from peeljax.cli import build_parser

EXAMPLES = int(os.environ.get("PEELJAX_FUZZ_EXAMPLES", "0")) or None
FUZZ = settings(
    max_examples=EXAMPLES or 40,
    derandomize=EXAMPLES is None,  # CI: the same cases every run
    database=None,  # CI writes nothing
    deadline=None,
    suppress_health_check=list(HealthCheck),
    print_blob=True,
)


class Accepted(BaseException):
    """The input passed every check and reached a heavy entry point (a BaseException: no
    ``except Exception`` of the command line can take it for a refusal)."""


# What runs after validation: (module, name). Each is replaced by a function raising Accepted.
HEAVY = (
    ("peeljax.simulate", "_run"),
    ("peeljax.simulate", "_run_reference"),
    ("peeljax.sweeps.engine", "run_batch"),
    ("peeljax.fit", "fit_adhesion"),
    ("peeljax.fit", "fit_stick_slip"),
    ("peeljax.figures", "write_figures"),
    ("peeljax.cli.attractor_map", "attractor_map"),
    ("peeljax.cli.sweep", "join_processes"),  # for several processes only (see run_guarded)
)


def run_guarded(argv: list[str], workdir: Path, interrupt: bool = False) -> tuple[str, int | None, str, str]:
    """``("accepted" | "exit", code, stdout, stderr)`` of ``peeljax argv`` run in ``workdir``
    with every heavy entry point replaced (raising KeyboardInterrupt with ``interrupt``)."""
    import importlib

    def heavy(*args, **kwargs):
        raise KeyboardInterrupt if interrupt else Accepted

    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(workdir)  # relative paths land in the case's folder
        for module, name in HEAVY:
            mp.setattr(importlib.import_module(module), name, heavy)
        mp.setattr(importlib.import_module("peeljax.simulate"), "KEPT_SIMULATORS", 0)  # (its Simulators skip _run)
        # joining other processes is heavy (it waits on the network); one process joins nothing
        mp.setattr("peeljax.cli.sweep.join_processes", lambda processes, args: None if processes is None else heavy())
        out, err = io.StringIO(), io.StringIO()
        try:
            code = None
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = _main(argv)
        except Accepted:
            return "accepted", None, out.getvalue(), err.getvalue()
    return "exit", code, out.getvalue(), err.getvalue()


def _main(argv):
    from peeljax.cli import main

    return main(argv)


def check_contract(argv, outcome, code, stdout, stderr, interrupt=False) -> None:
    """Exit 0/2/130, no traceback, a refusal as one ``peeljax: error:`` line."""
    shown = f"argv = {argv!r}\nstderr:\n{stderr[-3000:]}\nstdout:\n{stdout[-1000:]}"
    assert "Traceback" not in stderr + stdout, shown
    if outcome == "accepted":
        assert not interrupt
        return
    assert code in (0, 2, 130), shown
    if code == 2:  # lines end at "\n" only (a token may hold U+0085, which splitlines() would split at)
        last = stderr.strip().split("\n")[-1] if stderr.strip() else ""
        assert last.startswith(ERROR_PREFIX) or last.startswith("peeljax ") and ": error: " in last, shown
    if code == 130:
        assert stderr.strip().split("\n")[-1].startswith("peeljax: interrupted"), shown


# ---------------------------------------------------------------------------- the parsers
def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


SUBPARSERS = _subparsers()
COMMANDS = tuple(SUBPARSERS)


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if a.option_strings and not isinstance(a, argparse._HelpAction)]


OPTIONS = {name: _options(parser) for name, parser in SUBPARSERS.items()}

# ---------------------------------------------------------------------------- values
EDGE_NUMBERS = (
    "0", "-0", "1", "-1", "0.5", "2", "3", "1e-300", "5e-324", "1e-12", "1e308", "1e309", "-1e308", "nan", "NaN",
    "inf", "-inf", "Infinity", "1e", "", " ", "0x10", "1_000", "1,2", "1e6", "1000001", "1e7", "10000001",
    "2147483647", "2147483648", "-2147483649", "99999999999999999999999", "0.2:8:40", "1:2:1000001", "-1:2:3",
    "1:1:2", "1:2:x", "1:2", "abc", "--", "-", "１", "0.05", "0.04999", "1e-3", "4.4e-3", "1.1",
)  # fmt: skip
SANE_NUMBERS = ("0.01", "0.1", "0.3", "1", "1.1", "2", "4", "1e-3", "1e-6", "1e-9", "3", "10", "8", "50", "256")

numbers = st.one_of(
    st.sampled_from(EDGE_NUMBERS),
    st.sampled_from(SANE_NUMBERS),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(2**70), 2**70).map(str),
    st.text(max_size=6),
)

CHOICES = {
    "--method": ("default", "alpha", "diffrax", "tsit5", "dopri5", "dopri8", "kvaerno3", "kvaerno5", "euler", ""),
    "--fold": ("jump", "stop", "follow", "none", "JUMP"),
    "--geometry": ("paper", "full", "flat"),
    "--start": ("paper", "steady", "both"),
    "--optimizer": ("adam", "lbfgs", "sgd"),
    "--format": ("png", "svg", "pdf", "PNG", ".png", "xyz", ""),
    "--free": (*COEFFICIENT_NAMES, "c0", "C1", "x"),
    "--quantities": ("v", "F", "alpha", "x", ""),
    "--statistics": ("F_mean", "F_slip", "F_stick", "period", "slip_duration", "F_std", ""),
    "--coordinator": ("localhost:1234", "host", ":0", "h:99999", "[::1]:80", ""),
}
FILE_OPTIONS = ("--data", "--table", "--phi")
OUTPUT_OPTIONS = ("--out", "--plot")


def odd_paths(workdir_names: tuple[str, ...]):
    """Paths an input option may get: the case's files, and odd ones."""
    odd = ("nonexistent.csv", "no/such/folder/x.npz", ".", "/", "/dev/null", "a dir", "spa ce.csv", "ünï©ødé.json",
           "", "/proc/self/status", "a dir/../spa ce.csv")  # fmt: skip
    return st.sampled_from(workdir_names + odd) if workdir_names else st.sampled_from(odd)


OUTPUT_PATHS = st.sampled_from(
    ("out.npz", "out.json", "fig.png", "fig.svg", "fig.xyz", "fig", "a dir", "a dir/x.npz", "no/such/x.npz",
     "spa ce.csv/x.png", "ünï©ødé.npz", "", ".", "out.npz.chunks", "x.NPZ", "figs")  # fmt: skip
)


@st.composite
def option_tokens(draw, command: str, files: tuple[str, ...]) -> list[str]:
    """One option of ``command`` and values for it (a random count, now and then)."""
    action = draw(st.sampled_from(OPTIONS[command]))
    flag = draw(st.sampled_from(action.option_strings))
    if action.nargs == 0:
        return [flag]
    if isinstance(action.nargs, int):
        count = action.nargs
    elif action.nargs == "+":
        count = draw(st.integers(1, 3))
    else:
        count = 1
    if draw(st.integers(0, 19)) == 0:
        count = draw(st.integers(0, 4))  # missing or extra values
    if flag in FILE_OPTIONS:
        values = st.one_of(odd_paths(files), st.sampled_from(files)) if files else odd_paths(files)
    elif flag in OUTPUT_OPTIONS or (flag == "--out" and command == "figures"):
        values = OUTPUT_PATHS
    elif flag in CHOICES:
        values = st.one_of(st.sampled_from(CHOICES[flag]), st.text(max_size=5))
    else:
        values = numbers
    tokens = [draw(values) for _ in range(count)]
    if count == 1 and draw(st.integers(0, 9)) == 0:
        return [f"{flag}={tokens[0]}"]
    return [flag, *tokens]


JUNK = st.sampled_from(("--bogus", "-x", "--t", "--", "extra", "-1", "--V=", "--tau=0", "-h", "--version", "--v"))


# ---------------------------------------------------------------------------- damaged files
def _mutate(draw, raw: bytes) -> bytes:
    """The file as given, or damaged one way."""
    how = draw(st.sampled_from(("keep", "keep", "truncate", "flip", "garbage", "empty", "insert", "bom", "crlf")))
    if how == "truncate" and raw:
        return raw[: draw(st.integers(0, len(raw) - 1))]
    if how == "flip" and raw:
        i = draw(st.integers(0, len(raw) - 1))
        return raw[:i] + bytes([raw[i] ^ draw(st.integers(1, 255))]) + raw[i + 1 :]
    if how == "garbage":
        return draw(st.binary(max_size=200))
    if how == "empty":
        return b""
    if how == "insert" and raw:
        i = draw(st.integers(0, len(raw)))
        return raw[:i] + draw(st.binary(min_size=1, max_size=20)) + raw[i:]
    if how == "bom":
        return b"\xef\xbb\xbf" + raw
    if how == "crlf":
        return raw.replace(b"\n", b"\r\n")
    return raw


CELLS = st.one_of(
    st.sampled_from(("0", "1", "1.5", "nan", "NaN", "inf", "-inf", "", "-", "x", "1e309", "-1", "1,5", '"1"', "0x1")),
    st.floats(allow_nan=True, allow_infinity=True, width=64).map(repr),
)


@st.composite
def text_table(draw, columns: tuple[str, ...], rows: int = 6) -> bytes:
    """A CSV / whitespace table with ``columns`` (a unit, a wrong unit, an unknown column now
    and then), mostly sane numbers, some damaged cells, then damaged bytes."""
    header = list(columns)
    units = {"t": "s", "F": "N", "v": "m/s", "V": "m/s", "alpha": "rad", "period": "s", "F_mean": "N"}
    if draw(st.booleans()):
        header = [f"{c} [{draw(st.sampled_from((units.get(c, 'N'), 'ms', 'kN', '')))}]" for c in header]
    if draw(st.integers(0, 5)) == 0:
        header.append(draw(st.sampled_from(("x", "F", "t", "V", "F_std", "period_std", ";", "a" * 10_000))))
    sep = draw(st.sampled_from((",", " ", "\t", ";", ", ")))
    n = draw(st.integers(0, rows))
    lines = ["# a comment"] if draw(st.booleans()) else []
    lines.append(sep.join(header))
    V = draw(st.sampled_from(("1.1", "2", "4", "0", "-1", "nan")))
    for i in range(n):
        row = []
        for c in header:
            if draw(st.integers(0, 9)) == 0:
                row.append(draw(CELLS))
            elif c.startswith("t"):
                row.append(f"{0.01 * i:g}")
            elif c.startswith("V"):
                row.append(V if "F_mean" not in columns else f"{1 + i:g}")
            elif c.startswith(("period", "slip")):
                row.append(f"{0.02 + 0.001 * i:g}")
            elif c.startswith("alpha"):
                row.append("0.1")
            else:
                row.append(f"{120 + i:g}")
        lines.append(sep.join(row))
    return _mutate(draw, ("\n".join(lines) + "\n").encode())


JSON_VALUES = st.one_of(
    st.sampled_from(("null", "true", "false", '"abc"', "[1]", "{}", "1e999", "-1e999", "NaN", "Infinity", "0", "-1",
                     "1" + "0" * 400, "1e-400", "[]", '""')),  # fmt: skip
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
)


@st.composite
def phi_json(draw) -> bytes:
    names = draw(st.lists(st.sampled_from((*COEFFICIENT_NAMES, "C3", "p_1", "x", "c10")), max_size=5, unique=True))
    values = [draw(st.one_of(JSON_VALUES, st.sampled_from(("1.0", "0.5", "100")))) for _ in names]
    body = "{" + ", ".join(f'"{n}": {v}' for n, v in zip(names, values)) + "}"
    shape = draw(st.sampled_from(("object", "object", "array", "scalar", "nested", "huge")))
    if shape == "array":
        body = f"[{body}]"
    elif shape == "scalar":
        body = draw(JSON_VALUES)
    elif shape == "nested":
        depth = draw(st.sampled_from((10, 1000, 100_000)))
        body = "[" * depth + "]" * depth
    elif shape == "huge":
        body = '{"c1": 1.0, "note": "' + "x" * 2_000_000 + '"}'
    return _mutate(draw, body.encode())


def _npz_bytes(arrays: dict) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _huge_header_npz() -> bytes:
    """An .npz whose ``t`` declares 2**40 float64 entries (8 TB) in its .npy header but holds 16 bytes."""
    header = {"descr": "<f8", "fortran_order": False, "shape": (2**40,)}
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, header)
    member.write(np.zeros(2).tobytes())
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("t.npy", member.getvalue())
        archive.writestr("v.npy", _npy(np.ones(2)))
        archive.writestr("V.npy", _npy(np.float64(1.1)))
    return buffer.getvalue()


def _npy(array) -> bytes:
    member = io.BytesIO()
    np.save(member, array, allow_pickle=False)
    return member.getvalue()


ARRAY_VALUES = st.sampled_from(
    ("good", "nan", "inf", "2d", "short", "str", "bool", "complex", "object", "empty", "negative", "backwards")
)


def _array(kind: str, n: int = 5):
    t = np.linspace(0.0, 0.04, n)
    return {
        "good": t + 0.5,
        "nan": np.full(n, np.nan),
        "inf": np.full(n, np.inf),
        "2d": np.ones((n, 2)),
        "short": np.ones(1),
        "str": np.asarray(["a"] * n),
        "bool": np.ones(n, bool),
        "complex": np.ones(n, complex),
        "object": np.asarray([None] * n, dtype=object),
        "empty": np.zeros(0),
        "negative": -t - 1,
        "backwards": t[::-1],
    }[kind]


@st.composite
def data_npz(draw) -> bytes:
    """A data .npz: t, v, V (+ F, alpha, tau, dt, or the V_0, t_0 layout), fields damaged."""
    if draw(st.integers(0, 15)) == 0:
        return _huge_header_npz()
    suffix = draw(st.sampled_from(("", "", "_0", "_1")))
    arrays = {"t" + suffix: np.linspace(0.0, 0.04, 5), "v" + suffix: np.linspace(1.0, 2.0, 5), "V" + suffix: 1.1}
    for key in draw(st.lists(st.sampled_from(("F", "alpha", "t_F", "tau", "dt")), max_size=3, unique=True)):
        arrays[key + suffix if key not in ("tau", "dt") else key] = (
            np.linspace(100.0, 120.0, 5) if key in ("F", "alpha", "t_F") else np.float64(draw(st.sampled_from(
                (0.0, 0.01, -1.0, np.nan, np.inf))))  # fmt: skip
        )
    for key in draw(st.lists(st.sampled_from(sorted(arrays)), max_size=2, unique=True)):
        kind = draw(st.sampled_from(("drop", "array", "scalar")))
        if kind == "drop":
            del arrays[key]
        elif kind == "array":
            arrays[key] = _array(draw(ARRAY_VALUES))
        else:
            arrays[key] = np.asarray(draw(st.sampled_from((np.nan, -1.0, 0.0, "1.1", True, 1e308, 1 + 2j))))
    if draw(st.integers(0, 5)) == 0:  # F only: a force record in an .npz
        arrays.pop("v" + suffix, None)
    return _mutate(draw, _npz_bytes(arrays))


@st.composite
def case_files(draw) -> dict[str, bytes]:
    """The data files of one case (written in its folder)."""
    files = {}
    kinds = draw(st.lists(st.sampled_from(("force", "table", "phi", "npz", "npz_sim")), min_size=1, max_size=3))
    for i, kind in enumerate(kinds):
        if kind == "force":
            name = draw(st.sampled_from((f"peel_V=1.1_{i}.csv", f"rec{i}.csv", f"run_V2 {i}.txt", f"f{i}.dat")))
            columns = draw(st.sampled_from((("t", "F"), ("t", "F", "V"), ("t", "F", "v"), ("t", "v", "alpha"),
                                            ("F", "t"), ("t",))))  # fmt: skip
            files[name] = draw(text_table(columns))
        elif kind == "table":
            columns = draw(st.sampled_from((("V", "F_mean", "period"), ("V", "F_mean", "F_mean_std", "period"),
                                            ("V", "F_slip", "F_stick", "slip_duration"), ("V",), ("F_mean",))))  # fmt: skip
            files[f"table{i}.csv"] = draw(text_table(columns))
        elif kind == "phi":
            files[f"phi{i}.json"] = draw(phi_json())
        else:
            files[f"data{i}.npz" if kind == "npz" else f"data{i}.NPZ"] = draw(data_npz())
    return files


def _good_files() -> dict[str, bytes]:
    """Files that pass their readers, so that cases get past them to the options' checks."""
    t = np.linspace(0.0, 1.0, 201)
    saw = 130.0 + 10.0 * ((7.0 * t) % 1.0)  # a sawtooth: slips the statistics can find
    record = "t,F\n" + "".join(f"{a:.6g},{b:.6g}\n" for a, b in zip(t, saw))
    table = "V,F_mean,F_mean_std,period\n1.1,130,1,0.02\n2,135,1,0.03\n4,140,1,0.04\n"
    return {"good_V=1.1.csv": record.encode(), "good_table.csv": table.encode(),
            "good.npz": _npz_bytes({"t": t, "v": 1.0 + t, "V": 1.1, "tau": 0.01}),
            "good_phi.json": json.dumps({"c1": 410.0}).encode()}  # fmt: skip


GOOD_FILES = _good_files()


def write_case(folder: Path, files: dict[str, bytes]) -> None:
    (folder / "a dir").mkdir()
    (folder / "spa ce.csv").write_bytes(b"t,F\n0,1\n0.1,2\n")
    for name, raw in {**GOOD_FILES, **files}.items():
        (folder / name).write_bytes(raw)


@st.composite
def command_lines(draw, files: tuple[str, ...]) -> list[str]:
    command = draw(st.sampled_from(COMMANDS))
    argv = [command]
    if command == "fit" and files and draw(st.booleans()):  # reach the readers most of the time
        flag = "--table" if draw(st.booleans()) else "--data"
        good = "good_table.csv" if flag == "--table" else draw(st.sampled_from(("good_V=1.1.csv", "good.npz")))
        argv += [flag, draw(st.one_of(st.just(good), st.sampled_from(files)))]
        if flag == "--data":
            argv += ["--out", "fitted.json"]
    for _ in range(draw(st.sampled_from((0, 1, 1, 2, 2, 3, 5)))):  # few options: more cases pass them all
        argv += draw(option_tokens(command, files))
    if draw(st.integers(0, 9)) == 0:
        argv.insert(draw(st.integers(0, len(argv))), draw(JUNK))
    return argv


def _case_folder(base: Path) -> Path:
    return Path(tempfile.mkdtemp(dir=base))


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


# ---------------------------------------------------------------------------- the properties
@FUZZ
@given(data=st.data())
def test_command_lines_end_cleanly(base, data):
    """Any command line, with damaged files in its folder: exit 0/2/130 or accepted, no traceback."""
    files = data.draw(case_files(), label="files")
    folder = _case_folder(base)
    write_case(folder, files)
    argv = data.draw(command_lines((*files, *GOOD_FILES)), label="argv")
    interrupt = data.draw(st.integers(0, 9), label="interrupt") == 0
    outcome, code, out, err = run_guarded(argv, folder, interrupt)
    event(f"{argv[0] if argv else '-'}: {'accepted' if outcome == 'accepted' else f'exit {code}'}")
    check_contract(argv, outcome, code, out, err, interrupt)


def _sweep_argv(out: str) -> list[str]:
    return ["sweep", "--V", "1.1", "--tau", "0.01", "--t-final", "0.1", "--chunk", "1", "--out", out, "--no-progress"]


@FUZZ
@given(data=st.data())
def test_sweep_resume_from_damaged_files(base, data):
    """A sweep's --out resumed from a damaged chunk, meta.json or merged output: refused (2) or
    recomputed (accepted), never a traceback; also after Ctrl-C with a damaged meta.json."""
    folder = _case_folder(base)
    argv = _sweep_argv("out.npz")
    first = run_guarded(argv, folder)  # writes out.npz.chunks/meta.json, then reaches the runner
    assert first[0] == "accepted", first
    chunks = folder / "out.npz.chunks"
    meta = json.loads((chunks / "meta.json").read_text())
    target = data.draw(st.sampled_from(("chunk", "meta", "merged", "meta_dir")), label="target")
    if target == "chunk":
        good = {"V": np.ones(1), "t_stop": np.ones(1)}
        (chunks / "chunk_00000.npz").write_bytes(data.draw(st.one_of(st.just(_npz_bytes(good)), data_npz())))
    elif target == "meta":
        value = data.draw(st.sampled_from(("1", "Infinity", "-1", "1e999", '"x"', "null", "[]", "1.5")), label="n")
        text = json.dumps({**meta, "n_chunks": 0}).replace('"n_chunks": 0', f'"n_chunks": {value}')
        raw = data.draw(st.sampled_from((text.encode(), b"", b"{", b"\xff\xfe", b"[1, 2]", b'{"format": 1}')))
        (chunks / "meta.json").write_bytes(raw)
    elif target == "merged":
        (folder / "out.npz").write_bytes(data.draw(data_npz()))
    else:
        (chunks / "meta.json").unlink()
        (chunks / "meta.json").mkdir()
    interrupt = data.draw(st.booleans(), label="interrupt")
    outcome, code, out, err = run_guarded(argv, folder, interrupt)
    check_contract(argv, outcome, code, out, err, interrupt)


# ---------------------------------------------------------------------------- regressions
# Each input the fuzzer found a bug with, pinned (see the module docstring for the contract).
def _first_sweep(folder: Path) -> Path:
    """A sweep's --out started in ``folder`` (meta.json written, then the runner reached); its chunk folder."""
    assert run_guarded(_sweep_argv("out.npz"), folder)[0] == "accepted"
    return folder / "out.npz.chunks"


def _refused(result, *words) -> str:
    outcome, code, out, err = result
    assert outcome == "exit" and code == 2 and "Traceback" not in err, result
    line = err.strip().splitlines()[-1]
    assert line.startswith(ERROR_PREFIX) and all(w in line for w in words), line
    return line


def test_resume_from_an_output_with_a_huge_header_is_refused(tmp_path):
    """Was: numpy allocated the 8 TiB the .npy header declares (ArrayMemoryError, a traceback)."""
    _first_sweep(tmp_path)
    (tmp_path / "out.npz").write_bytes(_huge_header_npz())
    _refused(run_guarded(_sweep_argv("out.npz"), tmp_path), "'out.npz'", "damaged", "declares")


@pytest.mark.parametrize("damage", ["huge header", "corrupt member"])
def test_fit_data_damaged_npz_is_refused(tmp_path, damage):
    """Was: a traceback (ArrayMemoryError; zipfile.BadZipFile 'Bad CRC-32') from reading the arrays."""
    if damage == "huge header":
        raw = _huge_header_npz()
    else:
        raw = bytearray(_npz_bytes({"t": np.linspace(0, 1, 50), "v": np.ones(50), "V": 1.1}))
        i = raw.index(b"v.npy")  # the local header of v, its data further on: flip a data byte
        raw[i + 200] ^= 0xFF
        raw = bytes(raw)
    (tmp_path / "d.npz").write_bytes(raw)
    argv = ["fit", "--data", "d.npz", "--out", "fitted.json"]
    _refused(run_guarded(argv, tmp_path), "--data", "d.npz", "damaged")


def test_resume_with_meta_json_a_folder_is_refused(tmp_path):
    """Was: exit 1, "could not write --out 'out.npz' (Is a directory)": it was a read, of meta.json."""
    chunks = _first_sweep(tmp_path)
    (chunks / "meta.json").unlink()
    (chunks / "meta.json").mkdir()
    _refused(run_guarded(_sweep_argv("out.npz"), tmp_path), "meta.json", "cannot be read")


def test_interrupt_with_a_damaged_meta_json_says_what_is_saved(tmp_path):
    """Was: Ctrl-C, then OverflowError (int(Infinity)) from the chunk count of meta.json: a traceback."""
    chunks = _first_sweep(tmp_path)
    meta = (chunks / "meta.json").read_text()
    (chunks / "meta.json").write_text(meta.replace('"n_chunks": 1', '"n_chunks": Infinity'))
    outcome, code, out, err = run_guarded(_sweep_argv("out.npz"), tmp_path, interrupt=True)
    assert (outcome, code) == ("exit", 130) and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith("peeljax: interrupted: 0 chunks saved"), err


def _flagged_npz(flag: str) -> bytes:
    """A good data .npz whose zip directory says of ``V.npy``: encrypted, or compressed by an unknown method."""
    raw = bytearray(_npz_bytes({"t": np.linspace(0, 1, 5), "v": np.ones(5), "V": 1.1}))
    entry = raw.index(b"PK\x01\x02", raw.index(b"PK\x01\x02") + 1)  # the second directory entry: v.npy
    entry = raw.index(b"PK\x01\x02", entry + 1)  # the third: V.npy
    if flag == "encrypted":
        raw[entry + 8] |= 0x01
    else:
        raw[entry + 10] = 99
    return bytes(raw)


@pytest.mark.parametrize("flag", ["encrypted", "unknown compression"])
def test_npz_with_damaged_zip_flags_is_refused(tmp_path, flag):
    """Was: zipfile's RuntimeError ("encrypted, password required") or NotImplementedError
    ("compression method is not supported") as a traceback, for --data and for a resumed --out."""
    (tmp_path / "d.npz").write_bytes(_flagged_npz(flag))
    _refused(run_guarded(["fit", "--data", "d.npz", "--out", "fitted.json"], tmp_path), "--data", "d.npz", "damaged")
    _first_sweep(tmp_path)
    (tmp_path / "out.npz").write_bytes(_flagged_npz(flag))
    _refused(run_guarded(_sweep_argv("out.npz"), tmp_path), "'out.npz'", "damaged")


def test_csv_with_a_huge_quoted_cell_is_refused(tmp_path):
    """Was: _csv.Error "field larger than field limit (131072)" as a traceback (a quoted cell
    over 128 KiB, e.g. a JSON file given as --data)."""
    (tmp_path / "big.csv").write_text('t,F\n"' + "1" * 200_000 + '",1\n0.1,2\n')
    _refused(run_guarded(["fit", "--data", "big.csv", "--V", "1.1", "--out", "f.json"], tmp_path),
             "--data", "big.csv", "line 2", "not a CSV line")  # fmt: skip
    (tmp_path / "table.csv").write_text('V,F_mean\n"' + "1" * 200_000 + '",1\n2,3\n')
    _refused(run_guarded(["fit", "--table", "table.csv"], tmp_path), "--table", "table.csv", "line 2")


@pytest.mark.parametrize("command", ["simulate", "sweep", "tau-star"])
def test_subnormal_dt_is_refused(tmp_path, command):
    """Was: OverflowError (round(t_final/dt) of inf) as a traceback, for --dt 2.2e-313."""
    _refused(run_guarded([command, "--dt", "2.2250738585e-313"], tmp_path), "dt", "the limit is 1e8 steps")


@pytest.mark.parametrize("command", ["simulate", "sweep"])
def test_subnormal_save_dt_is_refused(tmp_path, command):
    """Was: OverflowError (floor(t_final/save_dt) of inf) as a traceback, for --save-dt 5e-324."""
    _refused(run_guarded([command, "--save-dt", "5e-324"], tmp_path), "--save-dt", "the limit is 1e7")


def test_phi_nested_too_deeply_is_refused(tmp_path):
    """Was: RecursionError from json's decoder as a traceback, for --phi of [[[[...]]]] 100 000 deep."""
    (tmp_path / "phi.json").write_text("[" * 100_000 + "]" * 100_000)
    _refused(run_guarded(["sweep", "--phi", "phi.json"], tmp_path), "--phi", "phi.json", "nested too deeply")
