"""The alternatives the paper argues against: inertial regularization and direct DAE integration."""

from .direct import StateSpaceODE, integrate_ida, integrate_index1, integrate_state_space, tolerance_sensitivity
from .inertial import InertialModel, constraint_report, integrate_inertial

__all__ = [
    "InertialModel",
    "StateSpaceODE",
    "constraint_report",
    "integrate_ida",
    "integrate_index1",
    "integrate_inertial",
    "integrate_state_space",
    "tolerance_sensitivity",
]
