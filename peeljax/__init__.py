"""peeljax: stick-slip peeling of an adhesive tape off a rotating spool, in JAX.

Importing peeljax enables 64-bit floats in JAX (``jax_enable_x64``): the peeling problem
spans v from 1e-10 to 10 m/s and stiff Newton solves, which float32 cannot carry.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from .adhesion import COEFFICIENT_NAMES, PAPER_COEFFICIENTS, AdhesionLaw, safe_pow  # noqa: E402
from .homogenized import HomogenizedODE  # noqa: E402
from .integrators import (  # noqa: E402
    AlphaMethod,
    alpha_coefficients,
    amplification_matrix,
    integrate_alpha,
    integrate_reference,
)
from .model import PeelingModel  # noqa: E402
from .simulate import simulate, simulate_reference  # noqa: E402
from .solution import Solution, StepDiagnostics, StopReason  # noqa: E402
from .structure import (  # noqa: E402
    Jacobians,
    is_fast_scale,
    jacobians,
    local_index,
    neumann_radius,
    neumann_terms,
    schur_complement,
    truncated_schur_complement,
)

__version__ = "0.1.0"

__all__ = [
    "AdhesionLaw",
    "AlphaMethod",
    "COEFFICIENT_NAMES",
    "HomogenizedODE",
    "Jacobians",
    "PAPER_COEFFICIENTS",
    "PeelingModel",
    "Solution",
    "StepDiagnostics",
    "StopReason",
    "alpha_coefficients",
    "amplification_matrix",
    "integrate_alpha",
    "integrate_reference",
    "is_fast_scale",
    "jacobians",
    "local_index",
    "neumann_radius",
    "neumann_terms",
    "safe_pow",
    "schur_complement",
    "simulate",
    "simulate_reference",
    "truncated_schur_complement",
]
