"""θ ↔ φ: the free coefficients of the adhesion law as the parameters a fit moves.

Every fit moves θ, one number per free coefficient, with c = c_start·exp(θ) (so a coefficient
keeps its sign and θ = 0 is the start); the others stay at their start values. A least-squares
fit takes its residuals' derivatives in θ forward (:func:`value_and_jacfwd`): few coefficients,
many residuals.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..adhesion import COEFFICIENT_NAMES, AdhesionLaw
from ..model import PeelingModel

__all__ = ["check_free", "law_from", "model_and_start", "value_and_jacfwd"]


def law_from(theta: dict[str, Array], start: AdhesionLaw) -> AdhesionLaw:
    """φ at θ: c = c_start·exp(θ) for the coefficients named in ``theta``, the others as in ``start``."""
    names = tuple(theta)
    return eqx.tree_at(
        lambda law: tuple(getattr(law, n) for n in names),
        start,
        tuple(getattr(start, n) * jnp.exp(theta[n]) for n in names),
    )


def check_free(free) -> tuple[str, ...]:
    """The free coefficients' names, checked, in φ's order without duplicates (None: all of them)."""
    if free is None:
        return COEFFICIENT_NAMES
    if isinstance(free, str):
        free = (free,)
    free = tuple(free)
    unknown = [n for n in free if n not in COEFFICIENT_NAMES]
    if unknown or not free:
        raise ValueError(f"free: unknown coefficient(s) {unknown}; allowed: {', '.join(COEFFICIENT_NAMES)}")
    return tuple(n for n in COEFFICIENT_NAMES if n in free)  # canonical order, no duplicates


def model_and_start(model: PeelingModel | None, start: AdhesionLaw | None, fit: str) -> tuple[PeelingModel, AdhesionLaw]:
    """The model (default the paper's) and the law ``fit`` starts from (default the model's φ)."""
    model = PeelingModel() if model is None else model
    start = model.adhesion if start is None else start
    if not isinstance(start, AdhesionLaw):
        raise TypeError(f"{fit} fits an AdhesionLaw; the model's adhesion is a plain callable")
    return model, start


def value_and_jacfwd(f, x):
    """f(x) and the forward-mode Jacobian of its first output (the columns last), from one
    trace: one tangent per component of x, the primal shared, not a trace for each."""

    def tangent(direction):
        out, d_out = jax.jvp(f, (x,), (direction,))
        return out, d_out[0]

    out, columns = jax.vmap(tangent, out_axes=(None, -1))(jnp.eye(x.size))
    return out, columns
