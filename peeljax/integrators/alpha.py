"""The α-method of the paper's section "Numerical Integration" for y' = ψ(y).

With b = β/γ, the update from (y_n, a_n) to (y_{n+1}, a_{n+1}) on a uniform mesh of step h is

    y_{n+1} = y_n + (1 − b)·h·ψ(y_n) + b·h·ψ(y_{n+1}) + (1/2 − b)·h²·a_n
    a_{n+1} = (ψ(y_{n+1}) − ψ(y_n))/(γ·h) + (1 − 1/γ)·a_n
    γ = 2/(ρ + 1) − 1/2,   β = 1/(ρ + 1)²,   ρ ∈ [0, 1),

with a_0 = dψ/dt(0) = ψ'(y_0)·ψ(y_0). This is Newmark's scheme with ψ(y) as the "velocity"
and a ≈ dψ/dt. The paper prints h·a_n and (ψ_{n+1} − ψ_n)/γ, which is the same scheme only
if a is scaled by h (a_0 = h·dψ/dt(0)); with a_0 = dψ/dt(0) as the paper states, the printed
form is dimensionally inconsistent and measurably first order (``tests/test_alpha_method.py``).
Measured here: second order for ρ = 0 and 0.5, and spectral radius ρ of the amplification
matrix as hλ → −∞.

Each step solves the implicit equation for y_{n+1} by Newton's method with the exact
autodiff Jacobian of the step residual. The Newton unknown is z = (α, ω, u, log v): the
discrete solution is the same, but v stays positive through every iterate, which carries the
run through the non-Lipschitz start v0 = 1e-10·V (φ has v^0.15). A step whose Newton
iteration fails is retried on 2, 4, … substeps (``max_subdivisions`` levels), counted in the
statistics. A step across which J_t changes sign while F̃·f does not is an impasse point:
the run stops there with that reason.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._linalg import solve_small
from ..homogenized import HomogenizedODE
from ..solution import Solution, StepDiagnostics, StopReason, mask_after_stop
from ..structure import local_index

__all__ = [
    "AlphaMethod",
    "AlphaState",
    "LogTransformedODE",
    "StepInfo",
    "alpha_advance",
    "alpha_coefficients",
    "alpha_start",
    "amplification_matrix",
    "integrate_alpha",
    "to_physical",
]


def alpha_coefficients(rho: ArrayLike) -> tuple[Array, Array]:
    """(γ, β) = (2/(ρ+1) − 1/2, 1/(ρ+1)²) of the α-method."""
    rho = jnp.asarray(rho, float)
    return 2.0 / (rho + 1.0) - 0.5, 1.0 / (rho + 1.0) ** 2


def amplification_matrix(rho: ArrayLike, z: ArrayLike) -> Float[Array, "2 2"]:
    """Amplification matrix of one step on y' = λy, z = hλ, acting on (y_n, h·a_n/λ).

    Scaling the auxiliary variable by h/λ keeps the matrix finite as z → −∞, where it tends to
    [[−(1−b)/b, −(1/2−b)/b], [−1/β, 1 − 1/(2β)]] (b = β/γ), whose spectral radius is ρ.
    """
    gamma, beta = alpha_coefficients(rho)
    b = beta / gamma
    z = jnp.asarray(z, float)
    # y_{n+1}(1 − bz) = (1 + (1−b)z)·y_n + (1/2 − b)·z·s_n, with s_n = h·a_n/λ.
    row_y = jnp.stack([(1.0 + (1.0 - b) * z) / (1.0 - b * z), (0.5 - b) * z / (1.0 - b * z)])
    # s_{n+1} = (y_{n+1} − y_n)/γ + (1 − 1/γ)·s_n.
    row_s = (row_y - jnp.array([1.0, 0.0])) / gamma + jnp.array([0.0, 1.0 - 1.0 / gamma])
    return jnp.stack([row_y, row_s])


class AlphaState(eqx.Module):
    """The α-method's state between steps (in the integrator's coordinates, see :func:`alpha_start`)."""

    y: Array
    psi: Array
    a: Array
    J: Array
    drive: Array
    status: Array


class StepInfo(eqx.Module):
    """What one macro step did (for diagnostics and statistics)."""

    newton_iterations: Array
    residual: Array
    condition: Array
    level: Array  # subdivision level used (0: the full step)


def _log_mask(n, log_components):
    return jnp.zeros(n, bool).at[jnp.asarray(log_components, int)].set(True) if log_components else jnp.zeros(n, bool)


def _from_log(z, log_components):
    mask = _log_mask(z.shape[-1], log_components)
    return jnp.where(mask, jnp.exp(jnp.where(mask, z, 0.0)), z)


def _to_log(y, log_components):
    mask = _log_mask(y.shape[-1], log_components)
    return jnp.where(mask, jnp.log(jnp.where(mask, y, 1.0)), y)


class LogTransformedODE(eqx.Module):
    """z' = ψ_z(z) for z = y with the ``log_components`` replaced by their logarithms.

    d(log v)/dt = ψ_v/v. From the paper's start v0 = 1e-10·V, ψ_v ∝ v^0.85 is not Lipschitz in
    v, but ψ_v/v ∝ e^(−0.15·log v) is smooth in log v: the α-method keeps its order there.
    """

    ode: HomogenizedODE
    log_components: tuple[int, ...] = eqx.field(static=True)

    @property
    def tau(self):
        return self.ode.tau

    def evaluate(self, z):
        y = _from_log(z, self.log_components)
        evaluation = self.ode.evaluate(y)
        mask = _log_mask(z.shape[-1], self.log_components)
        psi = jnp.where(mask, evaluation.psi / y, evaluation.psi)
        return eqx.tree_at(lambda e: e.psi, evaluation, psi)

    def __call__(self, z):
        return self.evaluate(z).psi


class AlphaMethod(eqx.Module):
    """The α-method with a Newton solve per step.

    Attributes:
        rho: spectral radius at infinity, ρ ∈ [0, 1) (traced; 0 damps the most).
        newton_rtol, newton_atol: Newton converges when every component of the update is
            below ``atol + rtol·|y_i|`` (for v: a relative change below ``rtol``).
        max_newton_iterations: iteration cap per (sub)step (static).
        max_subdivisions: a failed step is retried on 2, 4, …, 2^max_subdivisions substeps
            (static; 0 disables the safeguard, e.g. for reverse-mode differentiation).
        condition_number: also record the condition number of the iteration matrix (static).
        log_components: state components carried as their logarithm (static; default v, the
            fourth), which must stay positive; ``()`` for a general ODE.
        log_discretization: True (default): the scheme is applied to the ODE for
            (α, ω, u, log v) (:class:`LogTransformedODE`), smooth at the paper's start; False:
            the scheme is applied to y as printed in the paper and only Newton's unknown is log v.
        max_log_change: a step in which a log component (log v) changes by more than this is
            retried on substeps (v changing by more than a factor e^max_log_change is not
            resolved by the step); accepted as it is on the last subdivision level.
    """

    rho: Float[Array, ""] = eqx.field(converter=lambda a: jnp.asarray(a, dtype=float), default=0.0)
    newton_rtol: Float[Array, ""] = eqx.field(converter=lambda a: jnp.asarray(a, dtype=float), default=1e-10)
    newton_atol: Float[Array, ""] = eqx.field(converter=lambda a: jnp.asarray(a, dtype=float), default=1e-12)
    max_newton_iterations: int = eqx.field(static=True, default=25)
    max_subdivisions: int = eqx.field(static=True, default=4)
    condition_number: bool = eqx.field(static=True, default=False)
    log_components: tuple[int, ...] = eqx.field(static=True, default=(3,))
    log_discretization: bool = eqx.field(static=True, default=True)
    max_log_change: Float[Array, ""] = eqx.field(converter=lambda a: jnp.asarray(a, dtype=float), default=1.0)

    def _newton_in_log(self) -> tuple[int, ...]:
        """Components that Newton alone solves for in log form (the scheme stays in y)."""
        return () if self.log_discretization else self.log_components

    def _to_state(self, z):
        return _from_log(z, self._newton_in_log())

    def _to_unknown(self, y):
        return _to_log(y, self._newton_in_log())

    def coefficients(self) -> tuple[Array, Array, Array]:
        gamma, beta = alpha_coefficients(self.rho)
        return gamma, beta, beta / gamma

    # -------------------------------------------------------------- one step
    def _no_matrix(self, y):
        """Placeholder for the iteration matrix in loop carries (None unless it is recorded)."""
        return jnp.eye(y.shape[0]) if self.condition_number else None

    def initial_acceleration(self, ode: HomogenizedODE, y0: Array, psi0: Array) -> Array:
        """a_0 = dψ/dt at t = 0 = ψ'(y_0)·ψ(y_0)."""
        return jax.jvp(ode, (y0,), (psi0,))[1]

    def _newton(self, ode, known, hb, z_start, active):
        """Solve z: y(z) − known − hb·ψ(y(z)) = 0 by Newton.

        Returns (z, iterations, norm of the last scaled correction, converged, the last
        iteration matrix or None). An inactive solve (a stopped trajectory) does no iteration
        and returns z_start, also as a lane of a ``vmap``ped batch.
        """
        rtol, atol = self.newton_rtol, self.newton_atol

        mask = _log_mask(z_start.shape[0], self.log_components)  # log unknowns, in either mode

        def residual(z):
            y = self._to_state(z)
            r = y - known - hb * ode(y)
            return r, r

        def weights(z):
            # A log unknown's update is a relative change of the state: compare it with rtol.
            return jnp.where(mask, rtol, atol + rtol * jnp.abs(z))

        def body(carry):
            z, iteration, _, matrix = carry
            new_matrix, r = jax.jacfwd(residual, has_aux=True)(z)
            delta = solve_small(new_matrix, r)
            z_new = z - delta
            norm = jnp.max(jnp.abs(delta) / weights(z_new))
            norm = jnp.where(jnp.all(jnp.isfinite(z_new)), norm, jnp.inf)
            # The matrix is carried out of the loop only when its condition number is wanted.
            return z_new, iteration + 1, norm, (new_matrix if self.condition_number else matrix)

        def cond(carry):
            _, iteration, norm = carry[:3]
            return (norm > 1.0) & (iteration < self.max_newton_iterations) & jnp.isfinite(norm)

        # norm = 2 means "not converged yet"; a non-finite iterate sets it to inf and ends the loop.
        matrix0 = self._no_matrix(z_start)
        init = (z_start, jnp.asarray(0, jnp.int32), jnp.where(active, 2.0, 0.0), matrix0)
        z, iterations, norm, matrix = jax.lax.while_loop(cond, body, init)
        return z, iterations, norm, norm <= 1.0, matrix

    def _substep(self, ode, carry: AlphaState, h, accept_unresolved):
        """One α-method step of size h from carry; returns (new carry candidate, iterations, residual, matrix).

        Newton starts from y_n, not from an explicit predictor: near a fold of the step
        equation (J_t → 0) the predictor overshoots and Newton can land on the root beyond it,
        stepping over the singularity instead of stopping there (measured: at V = 1.1,
        τ = 1e-3, h = 1/82 the run then went on to t = 0.33 s, where diffrax stalls at 0.173 s).
        ψ, J_t and F̃·f are evaluated afresh at the accepted state for the same reason: the
        impasse test must see the state the step returns.
        """
        gamma, beta, b = self.coefficients()
        known = carry.y + (1.0 - b) * h * carry.psi + (0.5 - b) * h**2 * carry.a
        z, iterations, residual, converged, matrix = self._newton(ode, known, b * h, self._to_unknown(carry.y), carry.status == 0)
        y_new = self._to_state(z)
        evaluation = ode.evaluate(y_new)
        psi_new, J_new, drive_new = evaluation.psi, evaluation.J, evaluation.drive
        a_new = (psi_new - carry.psi) / (gamma * h) + (1.0 - 1.0 / gamma) * carry.a

        finite = jnp.all(jnp.isfinite(y_new)) & jnp.all(jnp.isfinite(psi_new)) & jnp.all(jnp.isfinite(a_new))
        crossed = (carry.J * J_new) < 0
        drive_kept_sign = (carry.drive * drive_new) > 0
        # A log component changing by more than max_log_change in one step is not resolved by
        # this step size (the paper's start: v grows by decades): subdivide, unless at the last level.
        log_change = jnp.where(_log_mask(z.shape[0], self.log_components), jnp.abs(z - self._to_unknown(carry.y)), 0.0)
        unresolved = (jnp.max(log_change) > self.max_log_change) & ~accept_unresolved
        status = jnp.where(
            ~converged | unresolved,
            StopReason.NEWTON_FAILED,
            jnp.where(~finite, StopReason.NONFINITE, jnp.where(crossed & drive_kept_sign, StopReason.IMPASSE, 0)),
        ).astype(jnp.int32)
        new = AlphaState(y=y_new, psi=psi_new, a=a_new, J=J_new, drive=drive_new, status=status)
        return new, iterations, residual, matrix

    def _subdivided(self, ode, carry: AlphaState, h, level):
        """2^level substeps of h/2^level; stops at the first failed substep."""
        n_sub = 2**level
        h_sub = h / n_sub

        def body(state):
            i, current, iterations, residual, matrix = state
            new, it, res, mat = self._substep(ode, current, h_sub, level >= self.max_subdivisions)
            ok = new.status == 0
            current = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, current)
            current = eqx.tree_at(lambda c: c.status, current, new.status)
            return i + 1, current, iterations + it, jnp.maximum(residual, res), mat

        def cond(state):
            i, current = state[0], state[1]
            return (i < n_sub) & (current.status == 0)

        init = (jnp.asarray(0, jnp.int32), carry, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), self._no_matrix(carry.y))
        _, new, iterations, residual, matrix = jax.lax.while_loop(cond, body, init)
        return new, iterations, residual, matrix

    def step(self, ode: HomogenizedODE, carry: AlphaState, h) -> tuple[AlphaState, StepInfo]:
        """One macro step of size h with the subdivision safeguard.

        Level 0 is the plain step; level k its 2^k substeps, tried only if level k − 1 failed.
        The step body is traced once (inside the loop over levels), which halves compile time.
        """
        if self.max_subdivisions == 0:
            new, iterations, residual, matrix = self._substep(ode, carry, h, jnp.asarray(True))
            level = jnp.asarray(0, jnp.int32)
        else:

            def retry_cond(state):
                level, new = state[0], state[1]
                return (new.status == StopReason.NEWTON_FAILED) & (level < self.max_subdivisions)

            def retry_body(state):
                level, _, iterations, _, _ = state
                new, it, res, mat = self._subdivided(ode, carry, h, level + 1)
                return level + 1, new, iterations + it, res, mat

            failed = eqx.tree_at(lambda c: c.status, carry, jnp.asarray(StopReason.NEWTON_FAILED, jnp.int32))
            init = (jnp.asarray(-1, jnp.int32), failed, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), self._no_matrix(carry.y))
            level, new, iterations, residual, matrix = jax.lax.while_loop(retry_cond, retry_body, init)
        if self.condition_number:
            condition = jnp.linalg.cond(matrix)
        else:
            condition = jnp.asarray(jnp.nan)
        return new, StepInfo(newton_iterations=iterations, residual=residual, condition=condition, level=level)


def alpha_start(ode, solver: AlphaMethod, y0: Float[Array, " n"]) -> tuple[HomogenizedODE | LogTransformedODE, AlphaState]:
    """The ODE in the integrator's coordinates and the state at t0.

    With ``solver.log_discretization`` the ODE becomes a :class:`LogTransformedODE` and the
    state carries log v; :func:`to_physical` maps carried states back. a_0 = ψ'(y_0)·ψ(y_0).
    A start that is not finite (or not positive in the log components) has status NONFINITE.
    """
    y0 = jnp.asarray(y0, float)
    positive = jnp.all(jnp.where(_log_mask(y0.shape[0], solver.log_components), y0 > 0, True))
    if solver.log_discretization and solver.log_components:
        ode = LogTransformedODE(ode, solver.log_components)
        y0 = _to_log(y0, solver.log_components)
    evaluation0 = ode.evaluate(y0)
    a0 = solver.initial_acceleration(ode, y0, evaluation0.psi)
    start_ok = jnp.all(jnp.isfinite(evaluation0.psi)) & jnp.all(jnp.isfinite(a0)) & positive
    state = AlphaState(
        y=y0,
        psi=evaluation0.psi,
        a=jnp.where(jnp.isfinite(a0), a0, 0.0),
        J=evaluation0.J,
        drive=evaluation0.drive,
        status=jnp.where(start_ok, 0, StopReason.NONFINITE).astype(jnp.int32),
    )
    return ode, state


def to_physical(solver: AlphaMethod, y: Float[Array, "... n"]) -> Float[Array, "... n"]:
    """Carried states (log v with ``log_discretization``) back to y = (α, ω, u, v)."""
    if solver.log_discretization and solver.log_components:
        return _from_log(y, solver.log_components)
    return y


def alpha_advance(ode, solver: AlphaMethod, state: AlphaState, h) -> tuple[AlphaState, StepInfo, Array]:
    """One macro step of size h, or nothing once the state has stopped.

    Returns (state, info, ok): a failed step keeps the previous y (with the new status); ``ok``
    is True only for an accepted step. After a stop the step does no Newton iteration and
    changes nothing; there is no ``lax.cond``, which under ``vmap`` would run both branches
    anyway, so a stopped lane of a batch costs (almost) nothing either.
    ``ode`` is the one :func:`alpha_start` returned.
    """

    active = state.status == 0
    new, info = solver.step(ode, state, h)
    ok = active & (new.status == 0)
    kept = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, state)
    kept = eqx.tree_at(lambda c: c.status, kept, jnp.where(active, new.status, state.status))
    info = jax.tree_util.tree_map(lambda a: jnp.where(active, a, jnp.zeros_like(a)), info)
    info = eqx.tree_at(lambda i: i.condition, info, jnp.where(active, info.condition, jnp.nan))
    return kept, info, ok


def integrate_alpha(
    ode: HomogenizedODE,
    solver: AlphaMethod,
    y0: Float[Array, "4"],
    t0: ArrayLike,
    t_final: ArrayLike,
    n_steps: int,
) -> Solution:
    """Integrate y' = ψ(y) with the α-method on a uniform mesh of ``n_steps`` steps (static).

    One ``lax.scan`` of :func:`alpha_advance` over the steps; after a stop the remaining steps
    are skipped and their states masked. Pure and traceable: ``jit``/``vmap`` over ode,
    solver, y0 and the times. Validation is the caller's job (see :func:`peeljax.simulate`).
    """
    t0 = jnp.asarray(t0, float)
    h = (jnp.asarray(t_final, float) - t0) / n_steps
    y0 = jnp.asarray(y0, float)
    ode, state0 = alpha_start(ode, solver, y0)
    start_ok = state0.status == 0

    def body(state, _):
        state, info, ok = alpha_advance(ode, solver, state, h)
        return state, (state.y, state.J, ok, info)

    final, (ys, Js, oks, infos) = jax.lax.scan(body, state0, None, length=n_steps)

    ts = t0 + h * jnp.arange(n_steps + 1)
    valid = jnp.concatenate([start_ok[None], oks])
    ys = to_physical(solver, jnp.concatenate([state0.y[None], ys]))
    Js = jnp.concatenate([state0.J[None], Js])
    n_valid = jnp.sum(valid)
    t_stop = jnp.where(start_ok, ts[jnp.maximum(n_valid - 1, 0)], t0)
    diagnostics = StepDiagnostics(
        newton_iterations=jnp.concatenate([jnp.zeros(1, jnp.int32), infos.newton_iterations]),
        residual=jnp.concatenate([jnp.zeros(1), infos.residual]),
        schur=jnp.where(valid, Js, jnp.nan),
        local_index=jnp.where(valid, local_index(Js, ode.tau), 0),
        condition=jnp.concatenate([jnp.full(1, jnp.nan), infos.condition]),
    )
    stats = {
        "steps": n_valid - 1,
        "step_size": h,
        "newton_iterations": jnp.sum(infos.newton_iterations),
        "max_newton_iterations": jnp.max(infos.newton_iterations),
        "subdivided_steps": jnp.sum(infos.level > 0),
        "max_subdivision_level": jnp.max(infos.level),
    }
    return Solution(
        ts=ts,
        ys=mask_after_stop(ys, valid),
        valid=valid,
        status=final.status,
        t_stop=t_stop,
        stats=stats,
        diagnostics=diagnostics,
        method="alpha",
    )
