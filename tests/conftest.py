"""Fixtures shared by the test modules."""

from __future__ import annotations

import importlib

import pytest


@pytest.fixture
def no_compilation(monkeypatch):
    """Fail the test if anything reaches a compiled runner of ``peeljax.simulate``."""

    def forbidden(*args, **kwargs):
        raise AssertionError("compiled before the input was checked")

    simulate_module = importlib.import_module("peeljax.simulate")  # peeljax.simulate is the function
    for name in ("_run_alpha", "_run_adaptive", "_run_reference"):
        monkeypatch.setattr(simulate_module, name, forbidden)
