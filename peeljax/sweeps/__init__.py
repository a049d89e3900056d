"""Sweeps over (V, τ, model parameters) and the least resolvable τ (issue 3).

* :func:`sweep`: the inputs flattened to one entry per trajectory (:mod:`.grid`), the
  integrator chosen — error control, each lane with its own steps, or the uniform mesh
  (:mod:`.integrators`) —, each chunk of lanes placed on the devices (:mod:`.devices`) and run
  as one compiled program with summaries computed on the fly (:mod:`.engine`), chunks written
  as they finish and resumed (:mod:`.storage`); :mod:`.api` ties these together.
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
