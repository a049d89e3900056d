"""A discarded computation's zero cotangent stays zero (peeljax/_cotangents.py): the reverse pass
through a rejected step attempt that overflowed on its way to a rejected result."""

from __future__ import annotations

import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from peeljax._cotangents import skip_zero_cotangents


def _attempt(x, scale, count):
    """A step that overflows inside (exp(1000) = inf) for x = 1 yet returns a finite candidate
    (exp(x·scale)·0 + x²), with an integer output beside it."""
    big = jnp.exp(x * scale)
    candidate = jnp.where(jnp.isfinite(big), big, 0.0) * 0.0 + x**2
    return candidate, count + 1


def _loss(attempt, x, accept):
    candidate, _ = attempt(x, 1000.0, jnp.asarray(0, jnp.int32))
    return jnp.where(accept, candidate, 3.0 * x)  # the rejected candidate gets a zero cotangent


def test_a_rejected_attempt_that_overflowed_gives_no_nan():
    plain = jax.grad(lambda x: _loss(_attempt, x, False))(1.0)
    assert np.isnan(plain)  # the failure the wrapper exists for: 0·inf in the pullback
    gated = jax.grad(lambda x: _loss(skip_zero_cotangents(_attempt), x, False))(1.0)
    assert float(gated) == 3.0


def test_an_accepted_attempt_keeps_its_derivative_and_outputs():
    x = 0.25  # no overflow: the pullback runs and gives the plain derivative
    plain = jax.grad(lambda x: _loss(_attempt, x, True))(x)
    gated = jax.grad(lambda x: _loss(skip_zero_cotangents(_attempt), x, True))(x)
    assert float(gated) == float(plain) == 0.5
    candidate, count = skip_zero_cotangents(_attempt)(jnp.asarray(x), 1000.0, jnp.asarray(4, jnp.int32))
    assert count.dtype == jnp.int32 and int(count) == 5 and float(candidate) == x**2


def test_inside_a_checkpointed_loop():
    """Inside equinox's checkpointed while loop (the reverse-mode loop of every run), with an
    integer carried: rejected steps (odd i) overflow, accepted ones (even i) square."""

    def run(x, wrapped):
        attempt = skip_zero_cotangents(_attempt) if wrapped else _attempt

        def body(carry):
            i, y = carry
            candidate, _ = attempt(y, jnp.where(i % 2 == 1, 1e4, 0.0), i)
            return i + 1, jnp.where(i % 2 == 0, candidate, y)

        _, y = eqxi.while_loop(lambda c: c[0] < 4, body, (jnp.asarray(0), x), max_steps=8, kind="checkpointed")
        return y

    x = 1.1
    assert np.isnan(jax.grad(lambda x: run(x, False))(x))
    np.testing.assert_allclose(jax.grad(lambda x: run(x, True))(x), 4 * x**3, rtol=1e-14)
