"""Step-size control of the one error-controlled loop: the error norm and a PI controller.

The controller follows diffrax's ``PIDController`` (without its derivative term): with the
scaled error norm ‖e‖ of a step of size h and the norm ‖e‖_prev of the last accepted step,

    h_next = h · clip(safety · ‖e‖^(−β₁) · ‖e‖_prev^(β₂), factormin, factormax),
    β₁ = (pcoeff + icoeff)/q,   β₂ = pcoeff/q,

with q the order of the stepper's local error estimate (err ∝ h^q: 3 for the α-method,
whose local error is O(h³); a Runge–Kutta solver's order for its embedded estimate, 5 for
Tsit5).
A step is accepted when ‖e‖ ≤ 1; a rejected step is retried with a factor ≤ ``safety``
(never grown), and a step whose Newton iteration failed with ``newton_failure_factor``.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._arrays import float_array
from .._validation import check_tolerance, is_concrete

__all__ = ["PIController", "ERROR_ORDER"]

ERROR_ORDER = 3  # local error of the α-method's step: C·h³·y'''


class PIController(eqx.Module):
    """Tolerances and the step-size update of the adaptive α-method.

    Attributes:
        rtol, atol: the weighted RMS norm of a step's error estimate e is
            ‖e‖ = sqrt(mean((e_i/s_i)²)) with s_i = atol + rtol·max(|y_n,i|, |y_n+1,i|) for
            ordinary components and s_i = rtol for components carried as a logarithm (log v):
            an error δ in log v is a relative error δ of v, weighted as such even where v is
            tiny (relaxing it by atol/v would let the take-off time of v drift; see
            ``docs/theory.md``).
        pcoeff, icoeff: proportional and integral coefficients (diffrax's naming).
            ``pcoeff = 0, icoeff = 1`` is the classical I controller.
        safety, factormin, factormax: the usual safety factor and the clip of h_next/h.
        newton_failure_factor: h_next/h after a step whose Newton iteration failed.
    """

    rtol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-6)
    atol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-9)
    pcoeff: Float[Array, ""] = eqx.field(converter=float_array, default=0.2)
    icoeff: Float[Array, ""] = eqx.field(converter=float_array, default=0.4)
    safety: Float[Array, ""] = eqx.field(converter=float_array, default=0.9)
    factormin: Float[Array, ""] = eqx.field(converter=float_array, default=0.2)
    factormax: Float[Array, ""] = eqx.field(converter=float_array, default=10.0)
    newton_failure_factor: Float[Array, ""] = eqx.field(converter=float_array, default=0.25)

    def __check_init__(self):
        if is_concrete(self.rtol):
            check_tolerance("rtol", self.rtol, upper=1.0)
        if is_concrete(self.atol):
            check_tolerance("atol", self.atol)
        for name in ("pcoeff", "icoeff"):
            value = getattr(self, name)
            if is_concrete(value) and not float(value) >= 0:
                raise ValueError(f"{name} must be >= 0, got {float(value)!r}")
        for name in ("safety", "factormin", "newton_failure_factor"):
            value = getattr(self, name)
            if is_concrete(value) and not 0.0 < float(value) <= 1.0:
                raise ValueError(f"{name} must lie in (0, 1], got {float(value)!r}")
        if is_concrete(self.factormax) and not float(self.factormax) > 1:
            raise ValueError(f"factormax must be > 1, got {float(self.factormax)!r}")

    def scale(
        self,
        y0: Float[Array, " n"],
        y1: Float[Array, " n"],
        log_mask: Bool[Array, " n"],
        increment_mask: Bool[Array, " n"] | None = None,
    ) -> Float[Array, " n"]:
        """The error weights s_i: atol + rtol·max(|y0_i|, |y1_i|), or rtol for a log component,
        or atol + rtol·|y1_i − y0_i| for an ``increment_mask`` component (the time carried by a
        run in pseudo-time: its error is a phase error, relative to the step's time increment,
        not to the time elapsed since t = 0, which would allow a drift growing with t)."""
        magnitude = jnp.maximum(jnp.abs(y0), jnp.abs(y1))
        if increment_mask is not None:
            magnitude = jnp.where(increment_mask, jnp.abs(y1 - y0), magnitude)
        return jnp.where(log_mask, self.rtol, self.atol + self.rtol * magnitude)

    def error_norm(
        self,
        error: Float[Array, " n"],
        y0: Float[Array, " n"],
        y1: Float[Array, " n"],
        log_mask: Bool[Array, " n"],
        increment_mask: Bool[Array, " n"] | None = None,
    ) -> Float[Array, ""]:
        """Weighted RMS norm of ``error`` (≤ 1: within tolerance); inf when not finite."""
        norm = jnp.sqrt(jnp.mean((error / self.scale(y0, y1, log_mask, increment_mask)) ** 2))
        return jnp.where(jnp.isfinite(norm), norm, jnp.inf)

    def factor(self, norm: Array, prev_norm: Array, accepted: Array, solved: Array, order: int = ERROR_ORDER) -> Array:
        """h_next/h after a step with error ``norm`` (the last accepted step had ``prev_norm``);
        ``order``: q of the stepper's error estimate ∝ h^q."""
        beta1 = (self.pcoeff + self.icoeff) / order
        beta2 = self.pcoeff / order
        # A zero error (a linear stretch of the solution) asks for the largest growth.
        safe_norm = jnp.where(jnp.isfinite(norm) & (norm > 0), norm, 1.0)
        raw = self.safety * safe_norm ** (-beta1) * jnp.maximum(prev_norm, 1e-10) ** beta2
        raw = jnp.where(norm > 0, raw, self.factormax)
        # As diffrax: an accepted step never shrinks the next one, a rejected one never grows it.
        upper = jnp.where(accepted, self.factormax, self.safety)
        lower = jnp.where(accepted, 1.0, self.factormin)
        factor = jnp.clip(raw, lower, upper)
        return jnp.where(solved, factor, self.newton_failure_factor)
