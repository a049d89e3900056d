"""Sweeps over (V, τ, model parameters) and the least resolvable τ (issue 3).

* :func:`sweep`: the inputs flattened to one entry per trajectory (:mod:`.grid`), the
  integrator chosen — error control, each lane with its own steps, or the uniform mesh
  (:mod:`.integrators`) —, each chunk of lanes placed on the devices (:mod:`.devices`) and run
  as one compiled program with summaries computed on the fly (:mod:`.engine`), chunks written
  as they finish and resumed (:mod:`.storage`); :mod:`.api` ties these together.
* :func:`least_tau`: τ* per V by batched bracketing in log τ (:mod:`peeljax.sweeps.least_tau`).
* :func:`stick_slip_map`: per V and starting state, whether the runs carried through the folds
  of φ stick-slip once settled, at which forces, with which repeat
  (:mod:`peeljax.sweeps.stick_slip_map`).

See ``docs/sweeps.md``.
"""

from .api import PER_TRAJECTORY_KEYS, SweepResult, sweep
from .engine import MODEL_PARAMETERS, BatchSummary, run_batch, slip_velocity
from .least_tau import LeastTau, least_tau
from .stick_slip_map import StickSlipMap, stick_slip_map

__all__ = [
    "MODEL_PARAMETERS",
    "PER_TRAJECTORY_KEYS",
    "BatchSummary",
    "LeastTau",
    "StickSlipMap",
    "SweepResult",
    "least_tau",
    "run_batch",
    "slip_velocity",
    "stick_slip_map",
    "sweep",
]
