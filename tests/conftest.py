"""Fixtures and helpers shared by the test modules (import the helpers: ``from conftest import run_cli``)."""

from __future__ import annotations

import contextlib
import gc
import importlib
import io
import json
import os
from pathlib import Path
from types import ModuleType

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

from peeljax.homogenized import Evaluation

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ERROR_PREFIX = "peeljax: error: "  # what the command line's refusals of bad input start with


# ---------------------------------------------------------------------------- two tiers
# `python -m pytest -q` is the fast tier, what a developer runs after every change; the tests
# marked `slow` join with --slow or PEELJAX_SLOW_TESTS=1 (CI runs `--slow -m slow` after the fast
# tier). Not an `addopts` -m: a user's own -m naming `slow` selects on it as written, and a test
# named by its node id (`file.py::test`) runs whatever its tier.
SLOW_TESTS_VARIABLE = "PEELJAX_SLOW_TESTS"


def pytest_addoption(parser):
    parser.addoption(
        "--slow", action="store_true", default=False,
        help=f"run the slow tier too (the tests marked slow; also {SLOW_TESTS_VARIABLE}=1)",
    )  # fmt: skip


def slow_tier_selected(config) -> bool:
    """Whether the run includes the tests marked ``slow`` (the option, the variable or a -m naming them)."""
    wanted = os.environ.get(SLOW_TESTS_VARIABLE, "").strip().lower() not in ("", "0", "false", "no")
    return config.getoption("--slow") or wanted or "slow" in (config.option.markexpr or "")


def pytest_collection_modifyitems(config, items):
    if not slow_tier_selected(config):
        _deselect_slow(config, items)
    if hasattr(config, "workerinput"):  # an xdist worker: every worker orders its collection alike
        _longest_first(items)


def _deselect_slow(config, items):
    named = [(Path(arg.split("::", 1)[0]).resolve(), arg.split("::", 1)[1]) for arg in config.args if "::" in arg]

    def is_named(item) -> bool:
        test = item.nodeid.split("::", 1)[-1]
        return any(item.path.resolve() == path and test.startswith(name) for path, name in named)

    slow = [item for item in items if item.get_closest_marker("slow") and not is_named(item)]
    if slow:
        chosen = set(map(id, slow))
        items[:] = [item for item in items if id(item) not in chosen]
        config.hook.pytest_deselected(items=slow)


# ---------------------------------------------------------------------------- longest first
# The workers (`--dist worksteal`) each take half of the collection and an idle one steals from the
# other's queue; a long test that starts last keeps one worker busy alone (the slow tier once ran
# 43 min on 2 cores for 30 min of CPU per core). The test files whose tests were measured long
# (LONG_TEST_SECONDS or more, setup included) run first, the longest in all first; a file's tests
# stay together and in their order (its module fixtures compile once per worker: taking a file's
# long tests out alone set those fixtures up again, +1 min of the fast tier measured).
# The record: `python tests/ci_time.py --long-tests tests/durations.json …` updates it.
DURATIONS_FILE = Path(__file__).with_name("durations.json")
LONG_TEST_SECONDS = 20.0


def _longest_first(items):
    try:
        seconds = json.loads(DURATIONS_FILE.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    per_file: dict[str, float] = {}
    for item in items:
        measured = float(seconds.get(item.nodeid, 0.0))
        if measured >= LONG_TEST_SECONDS:
            file = item.nodeid.split("::", 1)[0]
            per_file[file] = per_file.get(file, 0.0) + measured
    if per_file:  # a stable sort: the other files, and every file's tests, keep their order
        items.sort(key=lambda item: -per_file.get(item.nodeid.split("::", 1)[0], 0.0))


def pytest_report_header(config):
    if not slow_tier_selected(config):
        return f"the fast tier: tests marked slow are deselected (--slow or {SLOW_TESTS_VARIABLE}=1 runs them)"


# ---------------------------------------------------------------------------- JAX's persistent compilation cache
# XLA's compilation is most of the suite's time. A program whose compilation took at least this
# long is written to one folder and read back (milliseconds) by the other xdist worker, by the
# processes the tests start (CLI runs, notebook kernels: they inherit the folder through the
# environment) and by the next run. A program read back gives the same bits as a fresh
# compilation (tests/test_compilation_cache.py). Smaller programs compile in about the time a
# cache entry takes to key, write and read.
CACHE_MIN_COMPILE_SECONDS = 0.1
# A size limit turns on JAX's file lock around each read and write of the cache (filelock): without
# it a worker could read an entry another process was still writing, and a truncated executable
# crashed a worker (a segmentation fault in CI). Large enough that nothing is evicted in a run.
CACHE_MAX_BYTES = 16 * 2**30


def pytest_configure(config):
    """One folder for JAX's persistent compilation cache in every process of the run, set before anything compiles.

    The folder is ``JAX_COMPILATION_CACHE_DIR`` when set (``.ci/run`` gives each run an empty
    one, as a fresh clone has), else ``.pytest_cache/d/jax-compilation-cache``, kept between runs
    (``python -m pytest --cache-clear -n 0`` empties it). ``JAX_ENABLE_COMPILATION_CACHE=false``
    compiles every program.
    """
    if not jax.config.jax_enable_compilation_cache:
        return
    # the suite's own folder, not the user cache folder importing peeljax points JAX at
    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(config.cache.mkdir("jax-compilation-cache"))
    os.environ["JAX_COMPILATION_CACHE_DIR"] = folder  # the xdist workers and the processes tests start
    seconds = os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(CACHE_MIN_COMPILE_SECONDS))
    limit = os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(CACHE_MAX_BYTES))
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(seconds))
    jax.config.update("jax_compilation_cache_max_size", int(limit))


# ---------------------------------------------------------------------------- memory mappings of loaded programs
# Every program XLA compiles for the CPU stays loaded, as about three memory mappings, while JAX's
# caches hold it. A worker that runs half the suite loads tens of thousands of programs and would
# pass Linux's limit on a process's mappings (vm.max_map_count, 65 530 by default); past it the
# next compilation or cache write crashes the worker (a segmentation fault or an abort, in
# whichever test comes next: three fresh-clone CI runs lost a worker in test_stuck_tape so). Once
# a process holds half the limit, JAX's caches are emptied when it moves on to another test module
# (a module's own tests may count on what its fixtures compiled; the most one module added here
# was 5 000 mappings); a program needed again is read back from the persistent cache.
MAPPINGS_FRACTION = 0.5
DEFAULT_MAX_MAP_COUNT = 65_530  # Linux's, where a container hides /proc/sys


def _mappings() -> tuple[int, int] | None:
    """``(mappings this process holds, the system's limit)``, or ``None`` where Linux's /proc is absent."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            held = sum(1 for _ in maps)
    except OSError:
        return None
    try:
        with open("/proc/sys/vm/max_map_count") as limit:
            return held, int(limit.read())
    except (OSError, ValueError):
        return held, DEFAULT_MAX_MAP_COUNT


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item, nextitem):
    if nextitem is not None and getattr(nextitem, "module", None) is getattr(item, "module", None):
        return
    mappings = _mappings()
    if mappings is not None and mappings[0] > MAPPINGS_FRACTION * mappings[1]:
        jax.clear_caches()
        gc.collect()


# ---------------------------------------------------------------------------- forbidding computation
def forbid(monkeypatch, module: str | ModuleType, *names: str, reason: str) -> None:
    """Replace each of ``module``'s ``names`` by a function that fails the test with ``reason``."""

    def forbidden(*args, **kwargs):
        raise AssertionError(reason)

    if isinstance(module, str):
        module = importlib.import_module(module)
    for name in names:
        monkeypatch.setattr(module, name, forbidden)


@pytest.fixture(autouse=True)
def _simulate_keeps_no_simulator_from_other_tests():
    """Each test starts with none of the Simulators simulate keeps (peeljax.simulate._kept_simulator):
    a test that patches what simulate's own route calls sees its own calls take that route."""
    simulate_module = importlib.import_module("peeljax.simulate")
    simulate_module._KEPT_SIMULATORS.clear()
    simulate_module._SEEN_ONCE.clear()


@pytest.fixture
def no_compilation(monkeypatch):
    """Fail the test if anything reaches a compiled runner of ``peeljax.simulate`` or of the sweeps."""
    reason = "compiled before the input was checked"
    # the module, not the function peeljax.simulate
    forbid(monkeypatch, "peeljax.simulate", "_run", "_run_reference", reason=reason)
    monkeypatch.setattr(importlib.import_module("peeljax.simulate"), "KEPT_SIMULATORS", 0)  # (its Simulators skip _run)
    forbid(monkeypatch, "peeljax.sweeps.engine", "run_batch", reason=reason)


# ---------------------------------------------------------------------------- the command line
def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``peeljax.cli.main(argv)`` in-process: ``(exit code, stdout, stderr)`` (usable in module fixtures)."""
    from peeljax.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def run_cli_writing(folder: Path, argv: list[str]) -> dict:
    """``argv`` run once with ``--out`` and ``--plot`` files in ``folder`` and ``--json``.

    Returns ``{"code", "stdout", "stderr", "npz", "png"}`` for a module fixture's tests to share.
    """
    npz, png = folder / "out.npz", folder / "out.png"
    code, out, err = run_cli([*argv, "--out", str(npz), "--plot", str(png), "--json"])
    return {"code": code, "stdout": out, "stderr": err, "npz": npz, "png": png}


def assert_refused(code: int, stderr: str, *words: str, stdout: str | None = None) -> str:
    """Exit status 2 with stderr's last line ``peeljax: error: …`` naming every word; returns that line.

    With ``stdout`` given, it must be empty: nothing but the refusal is printed.
    """
    assert code == 2, stderr
    if stdout is not None:
        assert stdout == ""
    message = stderr.strip().splitlines()[-1]
    assert message.startswith(ERROR_PREFIX), message
    for word in words:
        assert word in message, message
    return message


# ---------------------------------------------------------------------------- models
class LinearODE(eqx.Module):
    """y' = λ·y, componentwise (no Schur complement: J = −1, F̃·f = 0)."""

    lam: jax.Array
    tau: float = 0.5

    def evaluate(self, y):
        return Evaluation(psi=self.lam * y, J=jnp.asarray(-1.0), drive=jnp.asarray(0.0))

    def __call__(self, y):
        return self.evaluate(y).psi
