"""Fixtures shared by the test modules."""

from __future__ import annotations

import importlib

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

from peeljax.homogenized import Evaluation


@pytest.fixture
def no_compilation(monkeypatch):
    """Fail the test if anything reaches a compiled runner of ``peeljax.simulate`` or of the sweeps."""

    def forbidden(*args, **kwargs):
        raise AssertionError("compiled before the input was checked")

    simulate_module = importlib.import_module("peeljax.simulate")  # peeljax.simulate is the function
    for name in ("_run_alpha", "_run_adaptive", "_run_reference"):
        monkeypatch.setattr(simulate_module, name, forbidden)
    engine = importlib.import_module("peeljax.sweeps.engine")
    for name in ("run_batch", "run_batch_adaptive"):
        monkeypatch.setattr(engine, name, forbidden)


class LinearODE(eqx.Module):
    """y' = λ·y, componentwise (no Schur complement: J = −1, F̃·f = 0)."""

    lam: jax.Array
    tau: float = 0.5

    def evaluate(self, y):
        return Evaluation(psi=self.lam * y, J=jnp.asarray(-1.0), drive=jnp.asarray(0.0))

    def __call__(self, y):
        return self.evaluate(y).psi
