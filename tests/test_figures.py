"""``peeljax figures``: every figure and the captions are written; bad input exits 2 before running."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from peeljax.cli import main
from peeljax.figures import CAPTIONS, RUNS

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_figures_writes_every_png_and_captions(tmp_path):
    out = tmp_path / "figs"
    code, stdout, stderr = run_main(["figures", "--out", str(out), "--t-final", "0.2", "--json"])
    assert code == 0, stderr
    facts = json.loads(stdout)
    for name in CAPTIONS:
        path = out / f"{name}.png"
        assert path.read_bytes()[:8] == PNG_MAGIC, name
    captions = (out / "captions.md").read_text(encoding="utf-8")
    assert all(name in captions for name in CAPTIONS)
    # one entry per (V, τ) run; the paper's least τ at V = 1.1 stops early at h = 1/82 s
    assert len(facts["runs"]) == sum(len(spec.taus) for spec in RUNS.values())
    early = facts["runs"]["V=1.1,tau=0.001"]
    assert not early["completed"] and 0.15 < early["t_stop"] < 0.19
    assert not facts["schur_reference"]["completed"]  # diffrax's step collapses near J_t = 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--t-final", "-1"], "t_final must be > 0"),
        (["--t-final", "0.01"], "t_final must be >= 0.05"),
        (["--format", "xyz"], "unknown image format"),
    ],
)
def test_bad_input_exits_2_before_running(tmp_path, argv, message):
    code, stdout, stderr = run_main(["figures", "--out", str(tmp_path / "f"), *argv])
    assert code == 2 and message in stderr and stdout == ""
    assert not (tmp_path / "f").exists()


def test_out_must_not_be_a_file(tmp_path):
    target = tmp_path / "file.txt"
    target.write_text("x")
    code, _, stderr = run_main(["figures", "--out", str(target)])
    assert code == 2 and "not a folder" in stderr
