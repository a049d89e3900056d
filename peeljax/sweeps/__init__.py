"""Sweeps over (V, τ, model parameters) and the least resolvable τ (issue 3).

* :func:`sweep`: one compiled, ``vmap``ped α-method run per chunk of trajectories, summaries
  computed on the fly (:mod:`peeljax.sweeps.engine`), chunks written as they finish and
  resumed (:mod:`peeljax.sweeps.storage`), sharded over all devices.
* :func:`least_tau`: τ* per V by batched bracketing in log τ (:mod:`peeljax.sweeps.least_tau`).

See ``docs/sweeps.md``.
"""

from .api import PER_TRAJECTORY_KEYS, SweepResult, sweep
from .engine import MODEL_PARAMETERS, BatchSummary, run_batch, slip_velocity
from .least_tau import LeastTau, least_tau

__all__ = [
    "MODEL_PARAMETERS",
    "PER_TRAJECTORY_KEYS",
    "BatchSummary",
    "LeastTau",
    "SweepResult",
    "least_tau",
    "run_batch",
    "slip_velocity",
    "sweep",
]
