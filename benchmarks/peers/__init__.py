"""The peers of ``compare.py``, one module per solver family, each built on :class:`Peer`.

A P1/P2 peer is a method with a list of settings (steps N or a tolerance rtol); ``setup(setting)``
builds what a run at that setting needs (outside the timing) and ``run(setting)`` returns v on
``compare_problems.GRID`` (NaN after a stop). The modules also hold each family's
batch runner (P3), gradient (P4) and direct-DAE runner (P5):

* ``peeljax_peer``: peeljax's α-method, uniform mesh and error-controlled (``simulate``, ``sweep``, ``jax.grad``);
* ``numba_peer``: the same α-method as a numba loop (``compiled_loop.py``) and the compiled ψ the other peers use;
* ``diffrax_peer``: diffrax Kvaerno5/Kvaerno3 (one trajectory, under ``jax.vmap``, its adjoint, the index-1 ODE);
* ``scipy_peer``: ``solve_ivp`` Radau and BDF;
* ``sundials_peer``: SUNDIALS CVODE and IDA through scikit-sundae;
* ``casadi_peer``: CasADi's cvodes (ψ from CasADi symbols, forward sensitivities) and idas;
* ``petsc_peer``: PETSc TSALPHA through ``petsc_tsalpha.py`` run by the interpreter that has petsc4py.
* ``jump_peers``: (P6, ``stick_slip.py``) the DAE at τ = 0 through φ's folds: ``run(rtol)`` returns the
  jump times (peeljax, scipy events, diffrax ``Event``, CasADi events, the inertial model).
"""

from __future__ import annotations

import numpy as np


class Peer:
    """A method with a list of settings; ``run(setting)`` returns v on ``GRID`` (NaN after a stop)."""

    name = ""
    setting_name = "rtol"

    def __init__(self, tau: float, settings):
        self.tau = tau
        self.settings = list(settings)

    def prepare(self) -> None:
        """Import, compile or build what every setting's runs share (outside the timed region)."""

    def setup(self, setting) -> None:
        """Build what a run at ``setting`` needs (an integrator, a solver object, a compiled program),
        outside the timed region; ``run`` then only calls it. ``compare.py`` times it apart and reports
        it in its own column, as peeljax's compilation is (``tests/test_peer_setup.py`` checks that
        ``run`` constructs no solver). Default: nothing to build."""

    def run(self, setting) -> np.ndarray:
        raise NotImplementedError

    def run_stats(self, setting) -> dict | None:
        """Counts of the last run at ``setting`` (steps, iterations) for the report, or None."""
        return None

    def info(self) -> dict:
        """What the report says about the peer beside its rows (JSON-able)."""
        return {}

    def close(self) -> None:
        """Release what ``prepare`` started (a subprocess)."""


class NotRun(Exception):
    """A peer that cannot run on this machine (an optional dependency is missing): reported, not fatal."""


def physical_v(v, log_v):
    """v from the integrated fourth component: exp of it when the peer integrates log v."""
    return np.exp(v) if log_v else v


class MaybeLog(Peer):
    """A peer that integrates y, or z = (α, ω, u, log v) when ``log_v`` (v > 0 by construction)."""

    base_name = ""

    def __init__(self, tau, settings, log_v=False):
        super().__init__(tau, settings)
        self.log_v = log_v
        self.name = self.base_name + (" (log v)" if log_v else "")
