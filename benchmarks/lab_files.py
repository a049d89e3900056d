"""Lab files at C speed within memory: a force record read by NumPy's C reader, and the long record
of the issue (6e6 rows of t, F, v) through ``peeljax fit --data``.

Two measurements, written to ``benchmarks/results/lab_files.md``:

1. **Parsing** a record of ``--rows`` rows (default 5e5) both ways, round-robin in one process:
   :func:`peeljax.fit.read_force_record` (``numpy.loadtxt``) and the line-by-line scan that words the
   refusals (``peeljax.fit.text_tables._scan``, what every file went through before): the median
   wall time of ``--repeats`` and the peak of the memory Python and NumPy allocate (tracemalloc),
   each against the file's size.
2. **The long record**: ``--big-rows`` rows (default 6e6, about 140 MB) written to a temporary folder
   (never the repository) and run as ``/usr/bin/time -v peeljax fit --data FILE --out FITTED.json``:
   its exit status, wall time, peak resident memory against the file size, and the last line it
   printed. The target: exit 0 or 2 within 60 s, no traceback, peak ≤ 3× the file size.

The machine's load (``os.getloadavg``) is printed beside the timings: these 2 cores are shared.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_model, write_result  # noqa: E402

from peeljax.fit import read_force_record  # noqa: E402
from peeljax.fit import text_tables  # noqa: E402
from peeljax.fit.records import FORCE_COLUMNS  # noqa: E402

RESULT = Path(__file__).resolve().parent / "results" / "lab_files.md"


def make_record(path: Path, rows: int) -> Path:
    """A sawtooth force record of ``rows`` rows, 1e-5 s apart (t, F, v), as a lab might write it."""
    with open(path, "w") as stream:
        stream.write("t [s],F [N],v [m/s]\n")
        block = 1_000_000
        for start in range(0, rows, block):
            t = np.arange(start, min(rows, start + block)) * 1e-5
            F = 245 + 15 * ((t / 0.0273) % 1.0)
            v = 1.1 + 0.5 * np.sin(2 * np.pi * t / 0.0273)
            np.savetxt(stream, np.column_stack([t, F, v]), fmt=["%.5f", "%.3f", "%.4f"], delimiter=",")
    return path


def _measure(read) -> tuple[float, float]:
    tracemalloc.start()
    begin = time.perf_counter()
    read()
    wall = time.perf_counter() - begin
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return wall, peak


def parsing(folder: Path, rows: int, repeats: int) -> str:
    path = make_record(folder / "peel_V=1.1.csv", rows)
    size = path.stat().st_size
    readers = {
        "numpy.loadtxt (read_force_record)": lambda: read_force_record(path),
        "line-by-line scan (text_tables._scan)": lambda: text_tables._scan(
            str(path), FORCE_COLUMNS, ("t", "F"), "force record", False
        ),
    }
    times = {name: [] for name in readers}
    peaks = {name: 0.0 for name in readers}
    for _ in range(repeats):  # round-robin: both sides see the same load
        for name, read in readers.items():
            wall, peak = _measure(read)
            times[name].append(wall)
            peaks[name] = max(peaks[name], peak)
    lines = [
        f"### Parsing {rows:,} rows (t, F, v; {size / 1e6:.1f} MB), median of {repeats}, load {os.getloadavg()[0]:.1f}",
        "",
        "| reader | wall [s] | MB/s | peak allocated [MB] | peak / file size |",
        "|---|---:|---:|---:|---:|",
    ]
    for name in readers:
        wall = statistics.median(times[name])
        lines.append(
            f"| {name} | {wall:.3g} | {size / 1e6 / wall:.3g} | {peaks[name] / 1e6:.3g} | {peaks[name] / size:.2f} |"
        )
    fast, slow = (statistics.median(times[name]) for name in readers)
    lines += ["", f"The scan takes {slow / fast:.3g}x the C reader's time.", ""]
    return "\n".join(lines)


def long_record(folder: Path, rows: int) -> str:
    path = make_record(folder / "peel_V=1.1_long.csv", rows)
    size = path.stat().st_size
    out = folder / "fitted.json"
    command = ["/usr/bin/time", "-v", "peeljax", "fit", "--data", str(path), "--out", str(out)]
    load = os.getloadavg()[0]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    err = done.stderr
    peak_kb = float(re.search(r"Maximum resident set size \(kbytes\): (\d+)", err).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", err).group(1)
    status = int(re.search(r"Exit status: (\d+)", err).group(1))
    said = [line for line in err.splitlines() if line.startswith("peeljax")]
    traceback = "Traceback" in err
    return "\n".join(
        [
            f"### `peeljax fit --data` on {rows:,} rows ({size / 1e6:.1f} MB), load {load:.1f}",
            "",
            f"- exit status {status}, wall {wall} (m:ss), traceback: {'yes' if traceback else 'no'}",
            f"- peak resident memory {peak_kb * 1024 / 1e6:.0f} MB = {peak_kb * 1024 / size:.2f}x the file size "
            "(the Python process with JAX imported included)",
            f"- last line: `{said[-1] if said else '(none)'}`",
            "",
        ]
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=500_000, help="rows of the parsing comparison")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--big-rows", dest="big_rows", type=int, default=6_000_000, help="rows of the long record")
    parser.add_argument("--no-write", dest="write", action="store_false", help="print only")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        text = f"CPU: {cpu_model()}, {os.cpu_count()} cores (shared: the load is the 1-minute load average)\n\n"
        text += parsing(Path(folder), args.rows, args.repeats)
        text += "\n" + long_record(Path(folder), args.big_rows)
    print(text)
    if args.write:
        write_result(RESULT, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
