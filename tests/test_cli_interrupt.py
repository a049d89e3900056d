"""Ctrl-C (a real SIGINT) to real ``peeljax`` processes: exit 130 and one line in every phase.

Before: SIGINT while XLA compiled waited for the compilation, then the interpreter's exit ran
JAX's clean-up under the still-running program and crashed (exit 139); a SIGINT that Python
raised inside JAX's garbage-collection callback was swallowed and the run went on (exit 0).

The phases are told apart by JAX's own compile events (``jax.monitoring``), printed as
``MARK`` lines by a driver that then runs ``peeljax.cli.main`` as the ``peeljax`` script does.
The three processes run at once (one compilation's wall time for the test).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

# A run of ~10 s after compiling (3.7e5 jumps, 4.9e6 step attempts): interrupted in every phase.
LONG_RUN = ["simulate", "--V", "1.1", "--tau", "0", "--t-final", "5000", "--save-dt", "0.025",
            "--max-jumps", "1000000"]  # fmt: skip

# peeljax.cli.main with JAX's compile events on stderr: "MARK lowered" when the integration loop
# has been lowered and XLA starts compiling it, "MARK compiled" when XLA has compiled it. The loop
# is told by its name (peeljax.run_program's kept program "simulate"): its lowering time (0.2-0.5 s) overlaps the small programs' at a high load.
DRIVER = """
import sys
import peeljax
import jax.monitoring
large = set()
def mark(event, duration, fun_name="", **kwargs):
    event = event.rsplit("/", 1)[-1]
    if event == "jaxpr_to_mlir_module_duration" and fun_name == "jit(simulate)":
        large.add(fun_name)
        print("MARK lowered", file=sys.stderr, flush=True)
    elif event == "backend_compile_duration" and fun_name in large:
        print("MARK compiled", file=sys.stderr, flush=True)
jax.monitoring.register_event_duration_secs_listener(mark)
from peeljax.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


class Interrupted:
    """A process that gets SIGINT ``delay`` seconds after the first stderr line that ``when``
    accepts: its stderr lines, and the seconds from the signal to its exit."""

    def __init__(self, argv: list[str], when, delay: float, cwd: Path):
        # XLA must really compile (a program read from the suite's compilation cache skips that phase)
        env = dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false")
        self.process = subprocess.Popen(
            argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL, env=env
        )
        self.when, self.delay = when, delay
        self.lines: list[str] = []
        self.sent_at = self.ended_at = None
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:  # the only reader of stderr: lines in order, none lost
        for line in self.process.stderr:
            self.lines.append(line.rstrip("\n"))
            if self.sent_at is None and self.when(line):
                time.sleep(self.delay)
                self.sent_at = time.monotonic()
                self.process.send_signal(signal.SIGINT)
        self.process.wait()
        self.ended_at = time.monotonic()

    def finish(self, timeout: float) -> tuple[int, str, float]:
        """(exit status, stdout, seconds from SIGINT to exit); killed after ``timeout`` seconds."""
        self.reader.join(timeout)
        if self.reader.is_alive():
            self.process.kill()
            self.reader.join()
        stdout = self.process.stdout.read()
        self.process.stdout.close()
        after = self.ended_at - self.sent_at if self.sent_at is not None else float("nan")
        return self.process.returncode, stdout, after


@pytest.mark.slow
def test_sigint_while_tracing_compiling_and_running_exits_130_in_one_line(tmp_path):
    driver = [sys.executable, "-c", DRIVER]
    phases = {
        # Python at work (tracing the loop): the script itself, SIGINT once it has announced the run
        "tracing": Interrupted(
            [sys.executable, "-m", "peeljax.cli", *LONG_RUN, "--out", str(tmp_path / "tracing.npz")],
            lambda line: line.startswith("peeljax: default stepper run"), 0.3, REPO,
        ),
        # XLA compiling the loop (the main thread in C++): SIGINT once the loop is lowered
        "compiling": Interrupted(
            [*driver, *LONG_RUN, "--out", str(tmp_path / "compiling.npz")], lambda line: line == "MARK lowered\n", 0.2, REPO
        ),
        # the compiled loop running (minutes to go): SIGINT a second after its compilation ended
        "running": Interrupted(
            [*driver, *LONG_RUN, "--out", str(tmp_path / "running.npz")], lambda line: line == "MARK compiled\n", 1.0, REPO
        ),
    }  # fmt: skip
    for phase, run in phases.items():
        code, stdout, after = run.finish(timeout=300)
        shown = f"{phase}: exit {code}, {after:.2f} s after SIGINT\n" + "\n".join(run.lines)
        assert run.sent_at is not None, shown  # the phase was reached
        assert code == 130, shown
        said = [line for line in run.lines if not line.startswith("MARK ") and "still running" not in line]
        assert said[-1] == "peeljax: interrupted", shown
        assert len(said) == 2 and said[0].startswith("peeljax: default stepper run"), shown  # no traceback
        assert stdout == "", shown
        assert after < 6.0, shown  # the watcher answers within a second (slack for a loaded machine)
        assert not (tmp_path / f"{phase}.npz").exists(), shown
