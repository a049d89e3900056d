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
