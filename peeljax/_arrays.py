"""The converter of every float parameter of peeljax's modules.

A Python or NumPy number becomes a NumPy float64 array, on the host and at once: building
``jnp.asarray(0.1)`` dispatches a device operation (tens of µs each), and a call of
:func:`peeljax.simulate` builds about twenty such parameters. JAX arrays and tracers (inside
``jit``/``vmap``/``grad``) stay JAX arrays. Both kinds are array leaves for JAX and equinox.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["float_array", "optional_float_array"]


def float_array(value):
    """``value`` as a float64 array: NumPy for host numbers, JAX for JAX arrays and tracers."""
    if isinstance(value, jax.Array):
        return value if value.dtype == jnp.float64 else jnp.asarray(value, dtype=float)
    return np.asarray(value, dtype=float)


def optional_float_array(value):
    """None stays None (an option left at its default); anything else is :func:`float_array`."""
    return None if value is None else float_array(value)
