"""Time integrators for the homogenized ODE, behind one contract (:mod:`.base`).

- :mod:`.alpha`: the α-method's step (Newton, its implicit-function-theorem derivatives);
- :mod:`.uniform_mesh`: the paper's uniform mesh (:class:`UniformMesh`, :func:`integrate_alpha`);
- :mod:`.log_variables`: the state carried with log v (:class:`LogTransformedODE`);
- :mod:`.adaptive`: the one error-controlled loop (:class:`ErrorControl`), with
  :mod:`.controller` (PI control), :mod:`.dense` (interpolants) and :mod:`.events` (folds, jumps);
- :mod:`.steppers`: what one step is, for any method of that loop: the α-method
  (:class:`AlphaStepper`) or a diffrax Runge–Kutta solver (:class:`RungeKutta`);
- :mod:`.switching`: Tsit5 ↔ the α-method where the homogenized ODE turns stiff
  (:class:`SwitchingStepper`, ``solver="auto"``);
- :mod:`.reference`: any diffrax solver (:class:`DiffraxIntegrator`), the reference;
- :mod:`.observers`: what an adaptive run records of each step (output, a sweep's statistics);
- :mod:`.select`: the user's options → an integrator (:func:`integrator_for`);
- :mod:`.diffrax_solver`: the α-method as a diffrax solver (:class:`AlphaSolver`).
"""

from .adaptive import ErrorControl, alpha_attempt, error_constant, integrate_adaptive, integrate_alpha_adaptive
from .alpha import (
    AlphaMethod,
    AlphaState,
    StepInfo,
    alpha_advance,
    alpha_coefficients,
    alpha_start,
    amplification_matrix,
    to_physical,
)
from .base import AbstractIntegrator, ObservedRun
from .controller import PIController
from .dense import hermite
from .diffrax_solver import AlphaSolver
from .log_variables import LogTransformedODE
from .observers import AcceptedStep, DenseOutput, EveryNthPoint, Observer, Observers, StepPoints
from .reference import DiffraxIntegrator, integrate_reference
from .select import SOLVER_NAMES, integrator_for
from .steppers import STEPPER_NAMES, AbstractStepper, AlphaStepper, RungeKutta, stepper_named
from .switching import SwitchingStepper
from .uniform_mesh import UniformMesh, integrate_alpha

__all__ = [
    "SOLVER_NAMES",
    "STEPPER_NAMES",
    "SwitchingStepper",
    "AbstractIntegrator",
    "AbstractStepper",
    "AlphaStepper",
    "RungeKutta",
    "integrate_adaptive",
    "stepper_named",
    "AcceptedStep",
    "AlphaMethod",
    "AlphaSolver",
    "AlphaState",
    "DenseOutput",
    "DiffraxIntegrator",
    "ErrorControl",
    "EveryNthPoint",
    "LogTransformedODE",
    "ObservedRun",
    "Observer",
    "Observers",
    "PIController",
    "StepInfo",
    "StepPoints",
    "UniformMesh",
    "alpha_advance",
    "alpha_attempt",
    "alpha_coefficients",
    "alpha_start",
    "amplification_matrix",
    "error_constant",
    "hermite",
    "integrate_alpha",
    "integrate_alpha_adaptive",
    "integrate_reference",
    "integrator_for",
    "to_physical",
]
