"""JAX's persistent compilation cache as ``conftest.py`` sets it up for the suite.

One folder for every process of a run (the xdist workers, the processes the tests start), and a
program read back from it computes the same bits as the program XLA has just compiled, so that
the tests comparing bit for bit or to a few ulps behave the same with a cold or a warm cache.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import jax
import numpy as np
import pytest
from jax import monitoring

import peeljax as pj
from conftest import CACHE_MIN_COMPILE_SECONDS

pytestmark = pytest.mark.skipif(
    not jax.config.jax_enable_compilation_cache, reason="JAX_ENABLE_COMPILATION_CACHE=false: no persistent cache"
)

_HITS = [0]


def _count_hits(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _HITS[0] += 1


monitoring.register_event_listener(_count_hits)


def test_one_folder_for_the_workers_and_the_processes_tests_start():
    folder = jax.config.jax_compilation_cache_dir
    assert folder and os.path.isdir(folder)
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == folder  # inherited by subprocesses and xdist workers
    expected = float(os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", CACHE_MIN_COMPILE_SECONDS))
    assert jax.config.jax_persistent_cache_min_compile_time_secs == expected


@pytest.mark.slow
def test_a_program_read_back_gives_the_bits_of_a_fresh_compilation():
    # The paper's uniform mesh (alpha-method steps with Newton's iterations, phi's folds): a loop
    # compiled once (~4 s on 2 quiet cores), named uniquely so that the first compilation is XLA's.
    sim = pj.Simulator(t_final=0.05, dt=0.005)

    name = f"cache_probe_{uuid.uuid4().hex}"

    def program():  # a new function each time: traced, lowered and looked up again, not reused in memory
        def run(V):
            return sim(V, 0.05).ys

        run.__name__ = name
        return jax.jit(run).lower(1.1).compile()

    Vs = [1.1, 2.5]
    hits = _HITS[0]
    try:
        fresh = program()
        assert _HITS[0] == hits  # a new program: compiled by XLA, then written
        expected = [np.asarray(fresh(V)) for V in Vs]

        read_back = program()
        assert _HITS[0] == hits + 1  # read from the folder, not compiled again
        for V, ys in zip(Vs, expected):
            assert np.all(np.isfinite(ys)) and ys.shape == (11, 4)
            np.testing.assert_array_equal(np.asarray(read_back(V)), ys)
    finally:  # the probe is of no use to a later run
        for entry in Path(jax.config.jax_compilation_cache_dir).glob(f"jit_{name}-*"):
            entry.unlink()


# ---------------------------------------------------------------------------- the library's own cache
# Importing peeljax points JAX's persistent compilation cache at the user's cache folder
# (peeljax/_compilation_cache.py). Each case runs a fresh Python with a home of its own.
_PROBE = """
import json, sys
import jax
from jax import monitoring
hits = []
monitoring.register_event_listener(lambda event, **kw: hits.append(event) if event.endswith("cache_hits") else None)
import peeljax as pj
import platformdirs
ys = pj.simulate(V=1.1, tau=0.01, t_final=0.05, dt=0.005).ys if "run" in sys.argv else None
print(json.dumps({
    "folder": jax.config.jax_compilation_cache_dir,
    "expected": platformdirs.user_cache_dir("peeljax", appauthor=False),
    "max_size": jax.config.jax_compilation_cache_max_size,
    "hits": len(hits),
    "ys": None if ys is None else ys.tolist(),
}))
"""


def _probe(tmp_path: Path, *args: str, **environment: str) -> dict:
    import json
    import subprocess
    import sys

    env = {key: value for key, value in os.environ.items() if not key.startswith(("JAX_", "PEELJAX_COMPILATION"))}
    env.update(HOME=str(tmp_path), XDG_CACHE_HOME=str(tmp_path / "cache"), **environment)
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, *args], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


def test_peeljax_keeps_compiled_programs_in_the_user_cache_folder(tmp_path):
    """The platform's user cache folder by default, with a size limit (JAX then locks the folder
    around reads and writes: processes sharing it are safe); a program compiled by one process is
    read back by the next; an entry made unreadable is compiled again, with the same result."""
    first = _probe(tmp_path, "run")
    folder = Path(first["folder"])
    assert folder == Path(first["expected"]) / "jax-compilation-cache" and folder.is_relative_to(tmp_path)
    assert first["max_size"] > 0 and first["hits"] == 0
    entries = [entry for entry in folder.iterdir() if entry.name.endswith("-cache")]
    assert entries
    second = _probe(tmp_path, "run")
    assert second["hits"] >= 1 and second["ys"] == first["ys"]
    for entry in entries:  # truncated, as by a process killed while writing
        entry.write_bytes(entry.read_bytes()[:100])
    third = _probe(tmp_path, "run")
    assert third["hits"] == 0 and third["ys"] == first["ys"]


def test_an_entry_without_its_last_use_does_not_stop_the_cache(tmp_path):
    """An entry left without its record of last use (a process killed between JAX's two writes)
    made every later write fail, so nothing was cached again; importing peeljax restores it."""
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "jit_killed-0123-cache").write_bytes(b"half written")
    first = _probe(tmp_path, "run", PEELJAX_COMPILATION_CACHE=str(folder))
    assert first["folder"] == str(folder) and (folder / "jit_killed-0123-atime").is_file()
    written = [entry for entry in folder.iterdir() if entry.name.endswith("-cache") and "killed" not in entry.name]
    assert written, sorted(entry.name for entry in folder.iterdir())
    second = _probe(tmp_path, "run", PEELJAX_COMPILATION_CACHE=str(folder))
    assert second["hits"] >= 1 and second["ys"] == first["ys"]


def test_the_cache_folder_moves_turns_off_or_is_the_users_own(tmp_path):
    moved = tmp_path / "elsewhere"
    assert _probe(tmp_path, PEELJAX_COMPILATION_CACHE=str(moved))["folder"] == str(moved)
    assert _probe(tmp_path, PEELJAX_COMPILATION_CACHE="off")["folder"] is None
    own = tmp_path / "jax-own"
    assert _probe(tmp_path, JAX_COMPILATION_CACHE_DIR=str(own))["folder"] == str(own)
    assert _probe(tmp_path, JAX_ENABLE_COMPILATION_CACHE="false")["folder"] is None
