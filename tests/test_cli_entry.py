"""The ``peeljax`` script's entry point (``peeljax_cli``): Ctrl-C while Python still imports
JAX exits 130 with the command's one line, as in every later phase (tests/test_cli_interrupt.py).

Before it, the script imported the package (and JAX, 1.5–3 s) before any handler of peeljax's
was in place: SIGINT then gave an ImportError or KeyboardInterrupt traceback, or was swallowed.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import peeljax_cli

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("delay", [0.2, 0.6])
def test_ctrl_c_while_importing_exits_130_with_one_line(delay, tmp_path):
    process = subprocess.Popen(
        [sys.executable, "-c", "import peeljax_cli, sys; sys.exit(peeljax_cli.main())", "simulate", "--V", "1.1",
         "--tau", "0", "--t-final", "2000", "--out", str(tmp_path / "x.npz")],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("peeljax: interrupted"), err
    assert not (tmp_path / "x.npz").exists()


def test_the_entry_point_runs_the_command_line(capsys):
    assert peeljax_cli.main(["orbit", "--V", "-1"]) == 2
    assert "--V" in capsys.readouterr().err
