"""What the benchmark scripts print about the machine they ran on, and the command that made a result.

Every file under ``benchmarks/results/`` and ``benchmarks/studies/results/`` starts with the line
:func:`made_by` writes, naming the command that produced it (``tests/test_compare_script.py`` checks
it), so a table can always be traced to, and remade by, one command.
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import sys
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
