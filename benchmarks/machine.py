"""What the benchmark scripts print about the machine they ran on, and the command that made a result.

Every file under ``benchmarks/results/`` and ``benchmarks/studies/results/`` starts with the line
:func:`made_by` writes, naming the command that produced it (``tests/test_compare_script.py`` checks
it), so a table can always be traced to, and remade by, one command.
"""

from __future__ import annotations

import importlib
import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]  # the repository


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo where there is one)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def command(argv=None) -> str:
    """This process's command as typed from the repository root: ``python benchmarks/….py ARGS``."""
    argv = sys.argv if argv is None else argv
    script = Path(argv[0]).resolve()
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(script), *argv[1:]])


def made_by(cmd: str | None = None) -> str:
    """The header line of a result file: ``Made by `COMMAND`.`` (default: this process's command)."""
    return f"Made by `{cmd or command()}`."


def load_average() -> float:
    """The 1-minute load average (nan where the OS has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def write_json(path, data) -> None:
    """``data`` as indented JSON, numpy and JAX arrays and scalars as lists and Python numbers."""
    text = json.dumps(data, default=lambda value: value.tolist(), ensure_ascii=False, indent=1)
    Path(path).write_text(text + "\n", encoding="utf-8")


def write_result(path, text: str, cmd: str | None = None) -> Path:
    """``text`` to ``path`` under its :func:`made_by` header line (a blank line between them)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"{made_by(cmd)}\n\n{text}", encoding="utf-8")
    return path


def versions(*modules) -> str:
    """"python X, jax Y, …": Python's version and each module's (``missing`` where it is not installed)."""
    out = [f"python {platform.python_version()}"]
    for module in modules:
        try:
            out.append(f"{module} {importlib.import_module(module).__version__}")
        except Exception:  # noqa: BLE001
            out.append(f"{module} missing")
    return ", ".join(out)


def timed(call, *args, **kwargs):
    """(``call(*args, **kwargs)``, the wall seconds it took)."""
    started = time.perf_counter()
    answer = call(*args, **kwargs)
    return answer, time.perf_counter() - started


def round_robin(calls, repeats, after_round=None, outputs=None, rotate=False, cpu=None) -> dict:
    """``repeats`` rounds, each calling every one of ``calls`` ({key: callable}) once, so that load on a
    shared machine hits all alike: {key: [seconds]}; ``after_round(times)`` runs after each round,
    ``outputs`` (a dict) keeps each call's last answer, ``rotate`` starts round r at the r-th call, and
    ``cpu`` (a dict) gets {key: [CPU seconds of this process, all threads]}."""
    keys = list(calls)
    times = {key: [] for key in keys}
    for r in range(repeats):
        first = r % len(keys) if rotate else 0
        for key in keys[first:] + keys[:first]:
            started, cpu_started = time.perf_counter(), time.process_time()
            answer = calls[key]()
            times[key].append(time.perf_counter() - started)
            if cpu is not None:
                cpu.setdefault(key, []).append(time.process_time() - cpu_started)
            if outputs is not None:
                outputs[key] = answer
        if after_round is not None:
            after_round(times)
    return times
