"""A stepper that switches between Tsit5 and the α-method where the homogenized ODE turns stiff.

The homogenized ODE (τ > 0, eq. ``hv``) is non-stiff while v moves (a slip, a take-off) and
stiff where it has settled: v then relaxes with a time scale ~τ, and an explicit stepper's
steps stay ~τ however long the run (measured: a 10⁹ s run at V = 1.1 m/s used up 10⁷ Tsit5
attempts). :class:`SwitchingStepper` takes Tsit5 steps (a seventh of the α-method's attempts
on the 3-s problems) while the problem is non-stiff and the paper's α-method (L-stable) where
it is stiff, as DifferentialEquations.jl's ``AutoTsit5(Rosenbrock23())`` does:

* **stiffness on a Tsit5 step**, from stages the step already has (Hairer & Wanner II, IV.2):
  ϱ·h = ‖k₇ − k₆‖ / ‖g₇ − g₆‖, with k the stage increments h·f(g) of its two last stages
  (both at t + h: g₇ = y₁, g₆ its sixth stage's argument). Stiff where ϱ·h exceeds
  ``stiff_fraction`` of Tsit5's stability bound on the negative real axis (3.507, measured in
  ``tests/test_switching.py``) on ``to_stiff`` accepted steps, ``calm_steps`` calm ones in a row
  resetting the count (Hairer's rule in DOPRI5): the step size is then held by stability, not
  by accuracy.
* **non-stiffness on an α-method step**: the spectral radius of the Newton matrix's Jacobian
  ∂ψ/∂y (kept across steps, so free), bounded from above by Gelfand's formula
  ‖M^(2^k)‖^(1/2^k) in the error weights' scaling; back to Tsit5 where ϱ·h is below the same
  fraction of the bound, halved, on ``to_nonstiff`` accepted steps in a row: Tsit5 would be
  stable at twice the α-method's present step.

A switch happens at the end of an accepted step: the new stepper restarts there as after a
jump (:meth:`AbstractStepper.restart`), and the step-size controller goes on with the new
stepper's error order. Jumps at folds keep the stepper that reached them. ``stats`` count the
accepted steps of each stepper, the switches and the times of the first and the last.
"""

from __future__ import annotations

from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._linalg import solve_small
from .alpha import AlphaMethod
from .dense import HermiteInterpolant
from .steppers import AbstractStepper, AlphaStepper, Attempt, RungeKutta, StepperState

__all__ = ["SwitchingStepper", "TSIT5_STABILITY_BOUND", "spectral_radius_bound", "tsit5_stiffness"]

# |R(z)| = 1 on the negative real axis at z = −3.507 for Tsit5's stability function (measured).
TSIT5_STABILITY_BOUND = 3.507
_GELFAND_SQUARINGS = 6  # ‖M^64‖^(1/64): an upper bound within a factor cond^(1/64) of ϱ
# Back to Tsit5 only where its stable step is at least twice the α-method's: where the α-method's step is
# held by accuracy just below Tsit5's stability bound, a switch back would be undone 15 steps later
# (measured at V = 4, τ = 0.1, rtol 1e-9: 9 switches in 10 s with a margin of 1).
_BACK_MARGIN = 2.0


def tsit5_stiffness(interpolation, scale: Float[Array, " n"]) -> Float[Array, ""]:
    """ϱ·h of a Tsit5 step (Hairer's estimate) from its dense output's stage increments k = h·f.

    ϱ·h = ‖k₇ − k₆‖ / ‖g₇ − g₆‖, g₇ − g₆ = Σⱼ (a₇ⱼ − a₆ⱼ) kⱼ (stages 6 and 7 are both at
    t + h), in the error weights ``scale``. A value only: stiffness decides which stepper
    runs, it is not differentiated.
    """
    k = jax.lax.stop_gradient(interpolation.k) / scale
    a = diffrax.Tsit5.tableau.a_lower
    weights = jnp.zeros(k.shape[0]).at[: a[5].shape[0]].add(a[5]).at[: a[4].shape[0]].add(-a[4])
    dg = weights @ k
    dk = k[6] - k[5]
    norm_dg = jnp.linalg.norm(dg)
    return jnp.where(norm_dg > 0, jnp.linalg.norm(dk) / jnp.where(norm_dg > 0, norm_dg, 1.0), 0.0)


def spectral_radius_bound(matrix: Float[Array, "n n"], scale: Float[Array, " n"]) -> Float[Array, ""]:
    """An upper bound of the spectral radius of ``matrix``: ‖M^(2^k)‖^(1/2^k) (Gelfand) with
    M = D⁻¹·matrix·D, D = diag(scale) (a similarity, which leaves the eigenvalues and makes the
    norm of a badly scaled Jacobian meaningful); every square normalized (no overflow)."""
    m = jax.lax.stop_gradient(matrix * scale[None, :] / scale[:, None])
    log_rho = jnp.zeros(())
    weight = 1.0
    for _ in range(_GELFAND_SQUARINGS):
        norm = jnp.max(jnp.sum(jnp.abs(m), axis=1))
        norm = jnp.where(norm > 0, norm, 1.0)
        log_rho = log_rho + weight * jnp.log(norm)
        m = m / norm
        m = m @ m
        weight = weight / 2
    last = jnp.max(jnp.sum(jnp.abs(m), axis=1))
    return jnp.where(last > 0, jnp.exp(log_rho + weight * jnp.log(jnp.where(last > 0, last, 1.0))), 0.0)


class _SwitchingInner(eqx.Module):
    stiff: Array  # the α-method's turn
    explicit: object  # Tsit5's state (its first stage, FSAL)
    implicit: object  # the α-method's (a, the kept Newton matrix)
    count: Array  # accepted steps on which the other stepper's test held (see attempt)
    calm: Array  # Tsit5's accepted steps in a row that did not look stiff
    steps: Array  # accepted steps (Tsit5, α-method)
    switches: Array
    first_switch_at: Array
    last_switch_at: Array


class SwitchingStepper(AbstractStepper):
    """Tsit5 while the homogenized ODE is non-stiff, the α-method where it is stiff (module docstring).

    Attributes:
        explicit: the explicit stepper (Tsit5, carrying log v).
        implicit: the α-method's stepper.
        stiff_fraction: the fraction of Tsit5's stability bound at which ϱ·h counts as stiff
            (and below which, on the α-method's steps, as non-stiff).
        to_stiff: Tsit5's accepted steps that look stiff before the switch to the α-method;
            ``calm_steps`` of its accepted steps in a row that do not look stiff reset the
            count (Hairer's rule in DOPRI5: the estimate of a complex pair of eigenvalues
            swings from step to step, measured 0.2–13× the bound at V = 4 m/s, τ = 0.1 s).
        to_nonstiff: the α-method's accepted steps in a row at which Tsit5 would be stable
            before the switch back.
    """

    cuts_at_folds: ClassVar[bool] = False
    explicit: RungeKutta = RungeKutta(diffrax.Tsit5(), (3,))
    implicit: AlphaStepper = AlphaStepper(AlphaMethod())
    stiff_fraction: float = eqx.field(static=True, default=0.9)
    to_stiff: int = eqx.field(static=True, default=15)
    calm_steps: int = eqx.field(static=True, default=6)
    to_nonstiff: int = eqx.field(static=True, default=3)

    def __check_init__(self):
        if not isinstance(self.explicit.solver, diffrax.Tsit5):
            raise TypeError(f"explicit must be a Tsit5 stepper (its stiffness estimate is Tsit5's), got {self.explicit.name}")
        if self.explicit.carried_log != self.implicit.carried_log:
            raise ValueError(
                f"both steppers must carry the same log components, got {self.explicit.carried_log} and "
                f"{self.implicit.carried_log}"
            )
        if not 0 < self.stiff_fraction <= 1:
            raise ValueError(f"stiff_fraction must lie in (0, 1], got {self.stiff_fraction!r}")
        for name in ("to_stiff", "calm_steps", "to_nonstiff"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")

    @property
    def order(self) -> int:
        return self.explicit.order  # the initial step's rule (after a start or a jump): Tsit5's

    def step_factor(self, controller, state, norm, prev_norm, accept, solved):
        # each with its order a constant: the same factor, to the last bit, as the stepper alone
        # (a traced order changed the steps at round-off, and with them a sweep's lanes under vmap)
        implicit = controller.factor(norm, prev_norm, accept, solved, self.implicit.order)
        explicit = controller.factor(norm, prev_norm, accept, solved, self.explicit.order)
        return jnp.where(state.inner.stiff, implicit, explicit)

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.explicit.carried_log

    @property
    def name(self) -> str:
        return "switching-tsit5-alpha"

    def for_loop(self, controller, kind: str) -> "SwitchingStepper":
        return eqx.tree_at(lambda s: s.explicit, self, self.explicit.for_loop(controller, kind))

    # -- the two steppers' states inside the switching one
    def _explicit_state(self, state: StepperState) -> StepperState:
        return eqx.tree_at(lambda s: s.inner, state, state.inner.explicit)

    def _implicit_state(self, state: StepperState) -> StepperState:
        return eqx.tree_at(lambda s: s.inner, state, state.inner.implicit)

    def _merged(self, sub: StepperState, inner: _SwitchingInner, which: str) -> StepperState:
        inner = eqx.tree_at(lambda i: getattr(i, which), inner, sub.inner)
        return eqx.tree_at(lambda s: s.inner, sub, inner)

    def start(self, ode, t0, y0):
        ode, state = self.explicit.start(ode, t0, y0)
        implicit = self.implicit._inner(state.y.shape[0], jnp.zeros_like(state.y))
        zero = jnp.asarray(0, jnp.int32)
        nan = jnp.full((), jnp.nan)
        inner = _SwitchingInner(
            stiff=jnp.asarray(False), explicit=state.inner, implicit=implicit, count=zero, calm=zero,
            steps=jnp.zeros(2, jnp.int32), switches=zero, first_switch_at=nan, last_switch_at=nan,
        )  # fmt: skip
        return ode, eqx.tree_at(lambda s: s.inner, state, inner)

    def _switched(self, ode, t, state: StepperState, to_stiff: bool) -> StepperState:
        """The state restarted in the other stepper at (t, state.y), counted as a switch."""
        inner = state.inner
        new = self._restarted_in(ode, t, state.y, state, to_stiff)
        return eqx.tree_at(
            lambda s: (s.inner.stiff, s.inner.count, s.inner.calm, s.inner.switches, s.inner.first_switch_at, s.inner.last_switch_at),
            new,
            (
                jnp.asarray(to_stiff), jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), inner.switches + 1,
                jnp.where(inner.switches == 0, t, inner.first_switch_at), jnp.asarray(t, float),
            ),
        )  # fmt: skip

    def attempt(self, ode, t, h, state, weights):
        inner = state.inner
        dummy_hermite, dummy_solver = self._dummy_interpolants(ode, t, h, state)

        def explicit():
            sub = self.explicit.attempt(ode, t, h, self._explicit_state(state), weights)
            ratio = tsit5_stiffness(sub.interpolant.interpolation, weights) / TSIT5_STABILITY_BOUND
            return sub, ratio, dummy_hermite, sub.interpolant, "explicit"

        def implicit():
            sub = self.implicit.attempt(ode, t, h, self._implicit_state(state), weights)
            dy, dpsi = jax.lax.stop_gradient(sub.candidate.inner.parts)
            # ∂ψ/∂y = ∂ψ/∂z·(∂y/∂z)⁻¹ (∂y/∂z = I where Newton's unknown is the state itself); the
            # unrolled solve: a LAPACK call in this branch cost 7 µs a step of the other (measured)
            jacobian = dpsi if not self.implicit.method._newton_in_log() else jax.vmap(lambda row: solve_small(dy.T, row))(dpsi)
            ratio = h * spectral_radius_bound(jacobian, weights) / TSIT5_STABILITY_BOUND
            return sub, ratio, sub.interpolant, dummy_solver, "implicit"

        def branch(run):
            sub, ratio, hermite, solver, which = run()
            ratio = jax.lax.stop_gradient(ratio)
            if which == "explicit":  # stiff-looking steps counted, reset after calm_steps calm ones in a row
                held = ratio > self.stiff_fraction
                calm = jnp.where(held, 0, inner.calm + 1).astype(jnp.int32)
                count = jnp.where(held, inner.count + 1, jnp.where(calm >= self.calm_steps, 0, inner.count))
            else:  # non-stiff-looking steps in a row
                held = ratio <= self.stiff_fraction / _BACK_MARGIN
                calm = inner.calm
                count = jnp.where(held, inner.count + 1, 0)
            count = count.astype(jnp.int32)
            steps = inner.steps.at[0 if which == "explicit" else 1].add(1)
            counted = eqx.tree_at(lambda i: (i.count, i.calm, i.steps), inner, (count, calm, steps))
            candidate = self._merged(sub.candidate, counted, which)
            retained = self._merged(sub.retained, inner, which)
            needed = self.to_stiff if which == "explicit" else self.to_nonstiff
            interpolant = _SwitchedInterpolant(jnp.asarray(which == "implicit"), hermite, solver)
            attempt = Attempt(candidate, retained, sub.error, sub.solved, sub.retry, sub.iterations, interpolant)
            return attempt, sub.solved & (count >= needed)

        attempt, switch = jax.lax.cond(inner.stiff, lambda: branch(implicit), lambda: branch(explicit))
        # The switch outside the stepper's branches, one conditional of three ways: nested in
        # them it cost 5 µs a Tsit5 step (measured, P1 at rtol 1e-9: 3.6 against 1.4 ms).
        candidate = attempt.candidate
        which = jnp.where(switch, jnp.where(inner.stiff, 2, 1), 0)
        candidate = jax.lax.switch(
            which,
            (
                lambda: candidate,
                lambda: self._switched(ode, t + h, candidate, True),
                lambda: self._switched(ode, t + h, candidate, False),
            ),
        )
        return eqx.tree_at(lambda a: a.candidate, attempt, candidate)

    def _dummy_interpolants(self, ode, t, h, state):
        """Interpolants of the right structure for the branch that did not run (never selected)."""
        y = state.y
        hermite = _hermite_placeholder(t, h, y)
        shapes = jax.eval_shape(
            lambda: self.explicit.attempt(ode, t, h, self._explicit_state(state), jnp.ones_like(y)).interpolant
        )
        solver = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return hermite, solver

    def _restarted_in(self, ode, t, y, state: StepperState, implicit: bool) -> StepperState:
        """The state restarted at (t, y) by the α-method (``implicit``) or by Tsit5."""
        if implicit:
            return self._merged(self.implicit.restart(ode, t, y, self._implicit_state(state)), state.inner, "implicit")
        return self._merged(self.explicit.restart(ode, t, y, self._explicit_state(state)), state.inner, "explicit")

    def restart(self, ode, t, y, state):
        return jax.lax.cond(
            state.inner.stiff,
            lambda: self._restarted_in(ode, t, y, state, True),
            lambda: self._restarted_in(ode, t, y, state, False),
        )

    def statistics(self, state):
        inner = state.inner
        return {
            "tsit5_steps": inner.steps[0],
            "alpha_steps": inner.steps[1],
            "stepper_switches": inner.switches,
            "first_switch_at": inner.first_switch_at,
            "last_switch_at": inner.last_switch_at,
            "jacobian_evaluations": inner.implicit.jacobian_evaluations,
        }

    def settings(self) -> dict:
        return {
            "name": "switching",
            "explicit": self.explicit.settings(),
            "implicit": self.implicit.settings(),
            "stiff_fraction": self.stiff_fraction,
            "to_stiff": self.to_stiff,
            "calm_steps": self.calm_steps,
            "to_nonstiff": self.to_nonstiff,
        }


def _hermite_placeholder(t, h, y):
    zeros = jnp.zeros_like(y)
    return HermiteInterpolant(jnp.asarray(t, float), jnp.asarray(h, float), y, zeros, y, zeros)


class _SwitchedInterpolant(eqx.Module):
    """The dense output of the stepper that took the step: the α-method's cubic Hermite one or Tsit5's."""

    implicit: Array
    hermite: eqx.Module
    solver: eqx.Module

    def evaluate(self, t: Float[Array, " m"]) -> Float[Array, "m n"]:
        return jnp.where(self.implicit, self.hermite.evaluate(t), self.solver.evaluate(t))
