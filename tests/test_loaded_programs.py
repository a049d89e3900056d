"""What ``conftest.py``'s guard on memory mappings counts on: emptying JAX's caches unloads programs.

Each compiled CPU program holds memory mappings while JAX's caches keep it; a test worker that
never let go of them would pass Linux's limit and crash (see ``conftest.pytest_runtest_teardown``).
"""

from __future__ import annotations

import gc
import sys

import jax
import jax.numpy as jnp
import pytest

from conftest import _mappings


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="memory mappings are counted in Linux's /proc")
def test_emptying_jaxs_caches_unloads_the_compiled_programs():
    gc.collect()
    assert _mappings()[1] > 0
    for n in range(1, 25):  # 24 programs: one per shape
        jax.jit(lambda x: jnp.cumsum(jnp.sin(x)))(jnp.ones(n)).block_until_ready()
    loaded, _ = _mappings()
    jax.clear_caches()
    gc.collect()
    after, _ = _mappings()
    assert loaded - after > 24  # at least one mapping a program let go (about three measured)
