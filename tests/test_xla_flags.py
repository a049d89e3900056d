"""peeljax's XLA:CPU flags (small while loops compiled as one call; no MLIR fusion emitters): set, merged, or left alone."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import peeljax

OPTION = "xla_cpu_small_while_loop_byte_threshold=1000000000"


@pytest.mark.parametrize(
    "before, expected",
    [
        ("", f"--xla_backend_extra_options={OPTION}"),
        ("--xla_force_host_platform_device_count=4", f"--xla_force_host_platform_device_count=4 --xla_backend_extra_options={OPTION}"),
        ("--xla_backend_extra_options=foo=1", f"--xla_backend_extra_options=foo=1,{OPTION}"),
        ("--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5", "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5"),
    ],
)
def test_flag_is_added_or_merged(monkeypatch, before, expected):
    monkeypatch.delenv("PEELJAX_KEEP_XLA_FLAGS", raising=False)
    monkeypatch.setenv("XLA_FLAGS", before)
    peeljax._small_while_loop_flag()
    assert os.environ["XLA_FLAGS"] == expected


def test_opt_out_keeps_flags(monkeypatch):
    monkeypatch.setenv("PEELJAX_KEEP_XLA_FLAGS", "1")
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/nowhere")
    peeljax._small_while_loop_flag()
    assert os.environ["XLA_FLAGS"] == "--xla_dump_to=/nowhere"


def test_import_sets_the_flag_in_a_fresh_process():
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PEELJAX_KEEP_XLA_FLAGS")}
    code = "import os, peeljax; print(os.environ['XLA_FLAGS'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert OPTION in out
    import importlib.metadata

    knows_the_option = tuple(int(x) for x in importlib.metadata.version("jaxlib").split(".")[:2]) >= (0, 6)
    assert ("--xla_cpu_use_fusion_emitters=false" in out) == knows_the_option


@pytest.mark.parametrize(
    "jaxlib, before, expected",
    [
        ("0.10.2", "", "--xla_cpu_use_fusion_emitters=false"),
        ("0.6.0", "--xla_dump_to=/x", "--xla_dump_to=/x --xla_cpu_use_fusion_emitters=false"),
        ("0.5.3", "", ""),  # the option does not exist there: XLA would abort on it
        ("0.10.2", "--xla_cpu_use_fusion_emitters=true", "--xla_cpu_use_fusion_emitters=true"),
    ],
)
def test_fusion_emitters_flag_only_where_jaxlib_knows_it(monkeypatch, jaxlib, before, expected):
    import importlib.metadata

    monkeypatch.delenv("PEELJAX_KEEP_XLA_FLAGS", raising=False)
    monkeypatch.setenv("XLA_FLAGS", before)
    monkeypatch.setattr(importlib.metadata, "version", lambda name: jaxlib)
    peeljax._fusion_emitters_flag()
    assert os.environ["XLA_FLAGS"] == expected


@pytest.mark.parametrize("jax_first", [True, False])
def test_an_import_after_the_backend_started_says_the_flags_do_not_apply(jax_first):
    """Imported after JAX's CPU backend started, peeljax's flags cannot apply (runs several times
    slower, one device): a RuntimeWarning says so; imported first, nothing is said."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PEELJAX_KEEP_XLA_FLAGS")}
    code = ("import jax; jax.devices(); " if jax_first else "") + "import peeljax"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    said = "imported after JAX's CPU backend had started" in done.stderr
    assert said == jax_first, done.stderr
