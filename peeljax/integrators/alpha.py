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

Derivatives (forward and reverse mode)
--------------------------------------
Newton's iterations are never differentiated. The step residual
F(z; θ) = y(z) − known(θ) − h·b·ψ(y(z); θ) = 0 defines the solution z*(θ); by the implicit
function theorem

    dz* = −(∂F/∂z)⁻¹·(∂F/∂θ)·dθ        at z = z*,

one linear 4×4 solve with the iteration matrix per step (:func:`_implicit_root`). A whole
step, with its subdivision safeguard, is a ``custom_jvp``: the primal is the fast
``while_loop`` step (bit-identical forward results), and the tangent replays only the path
that the primal took, at the Newton solutions the primal recorded (no Newton iteration is
re-run): the plain step (level 0) or its 2^k substeps (a bounded ``lax.scan`` over
2^max_subdivisions slots, masked).
The tangent program is linear and has no ``while_loop``, so JAX transposes it for reverse
mode (``jax.grad``). A step that fails (the run stops) passes its incoming tangent through
unchanged, and singular or non-finite iteration matrices give zero tangents, never NaN.
Under ``vmap`` the replay's ``lax.cond`` runs both branches: batched gradients cost more
per step than a ``lax.map`` over the batch.
"""

from __future__ import annotations


import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
from jaxtyping import Array, ArrayLike, Float

from .._arrays import float_array
from .._linalg import solve_small
from .._validation import check_positive, check_rho
from ..homogenized import HomogenizedODE
from ..solution import StopReason
from .log_variables import LogTransformedODE, from_log, log_mask, to_log

__all__ = [
    "AlphaMethod",
    "AlphaState",
    "StepInfo",
    "alpha_advance",
    "alpha_coefficients",
    "alpha_start",
    "amplification_matrix",
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
    newton_correction: Array  # scaled max-norm of the last Newton correction
    condition: Array
    level: Array  # subdivision level used (0: the full step)


def _jvp_filtered(fn, primals, tangents):
    """``jax.jvp(fn, primals, tangents)`` where ``tangents`` has ``None`` (symbolic zero) leaves.

    Only the leaves with a tangent are differentiated; every other leaf (static fields,
    integer arrays, undifferentiated floats) is closed over.
    """
    leaves, treedef = jtu.tree_flatten(primals)
    t_leaves = treedef.flatten_up_to(tangents)
    index = [i for i, t in enumerate(t_leaves) if t is not None]

    def partial_fn(*diff):
        full = list(leaves)
        for i, d in zip(index, diff):
            full[i] = d
        return fn(*treedef.unflatten(full))

    if not index:
        out = fn(*primals)
        return out, jtu.tree_map(lambda a: None, out)
    return jax.jvp(partial_fn, tuple(leaves[i] for i in index), tuple(t_leaves[i] for i in index))


def _stop_gradient(tree):
    """``lax.stop_gradient`` on the inexact arrays of a pytree (other leaves untouched)."""
    return jtu.tree_map(lambda x: jax.lax.stop_gradient(x) if eqx.is_inexact_array(x) else x, tree)


def _step_residual(z, args):
    """F(z) = y(z) − known − h·b·ψ(y(z)), the α-method's step equation in Newton's unknown z."""
    solver, ode, known, hb = args
    y = solver._to_state(z)
    return y - known - hb * ode(y)


@eqx.filter_custom_jvp
def _implicit_root(z_star, active, residual, args):
    """z* (a root of ``residual(z, args)``, found without derivatives), made differentiable.

    The primal is z* itself; the tangent is the implicit function theorem's
    dz* = −(∂F/∂z)⁻¹·(∂F/∂args)·d(args) at z*, with F = ``residual``. An inactive solve
    (stopped trajectory) or a singular/non-finite iteration matrix gives a zero tangent:
    the matrix is replaced by 𝐈 before the solve (a "double where"), so no NaN reaches a
    reverse pass either.
    """
    return z_star


@_implicit_root.def_jvp
def _implicit_root_jvp(primals, tangents):
    z_star, active, residual, args = primals
    _, _, _, t_args = tangents
    if t_args is None or not jtu.tree_leaves(t_args):
        return z_star, None
    matrix = jax.jacfwd(lambda z: residual(z, args))(z_star)
    _, rhs = _jvp_filtered(lambda a: residual(z_star, a), (args,), (t_args,))
    n = z_star.shape[0]
    usable = active & jnp.all(jnp.isfinite(matrix)) & jnp.all(jnp.isfinite(z_star))
    safe = jnp.where(usable, matrix, jnp.eye(n))
    # A singular matrix shows as a non-finite solve (no LAPACK call: it would not fuse).
    usable = usable & jnp.all(jnp.isfinite(solve_small(safe, jnp.ones(n, safe.dtype))))
    safe = jnp.where(usable, safe, jnp.eye(n))
    dz = -solve_small(safe, rhs)
    return z_star, jnp.where(usable, dz, 0.0)


@eqx.filter_custom_jvp
def _step_with_tangent(solver, ode, carry, h):
    """:meth:`AlphaMethod._step_primal` with the replay tangent of :meth:`AlphaMethod._replay`."""
    return solver._step_primal(ode, carry, h)


@_step_with_tangent.def_jvp
def _step_with_tangent_jvp(primals, tangents):
    solver, ode, carry, h = primals
    new, info, zs = solver._step_primal(ode, carry, h, record=True)
    level = info.level
    # A failed step's tangent is the incoming one (below): replay it at the incoming state, not
    # at a diverged Newton iterate, so that its (unused) derivatives stay finite.
    zs = jnp.where(new.status != 0, solver._to_unknown(carry.y)[None, :], zs)

    def replay(solver_, ode_, carry_, h_):
        return solver_._replay(ode_, carry_, h_, level, zs)

    _, t_new = _jvp_filtered(replay, primals, tangents)
    t_carry = tangents[2]
    ok = new.status == 0

    def pick(t_n, t_c, leaf):
        if t_n is None and t_c is None:
            return None
        t_n = jnp.zeros_like(leaf) if t_n is None else t_n
        t_c = jnp.zeros_like(leaf) if t_c is None else t_c
        return jnp.where(ok, t_n, t_c)

    float_fields = ("y", "psi", "a", "J", "drive")
    t_state = AlphaState(
        **{
            name: pick(getattr(t_new, name), None if t_carry is None else getattr(t_carry, name), getattr(new, name))
            for name in float_fields
        },
        status=None,
    )
    t_info = jtu.tree_map(lambda _: None, info)
    return (new, info), (t_state, t_info)


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
        newton_kappa, chord_iterations, jacobian_max_age: error control only. Newton keeps
            its matrix across steps (:meth:`_chord_newton`) and converges when its update,
            in the error norm's weights, times min(1, its convergence rate), is ≤
            ``newton_kappa``; after ``chord_iterations`` or on divergence the step is retried
            with a fresh matrix, and only then with a smaller step. The matrix is refreshed
            at least every ``jacobian_max_age`` accepted steps (static). Error control
            uses neither ``newton_rtol``/``newton_atol`` nor the subdivision safeguard
            (``max_subdivisions``, ``max_log_change``): a failed step is retried with a
            smaller one instead.
    """

    rho: Float[Array, ""] = eqx.field(converter=float_array, default=0.0)
    newton_rtol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-10)
    newton_atol: Float[Array, ""] = eqx.field(converter=float_array, default=1e-12)
    max_newton_iterations: int = eqx.field(static=True, default=25)
    max_subdivisions: int = eqx.field(static=True, default=4)
    condition_number: bool = eqx.field(static=True, default=False)
    log_components: tuple[int, ...] = eqx.field(static=True, default=(3,))
    log_discretization: bool = eqx.field(static=True, default=True)
    max_log_change: Float[Array, ""] = eqx.field(converter=float_array, default=1.0)
    newton_kappa: Float[Array, ""] = eqx.field(converter=float_array, default=0.01)
    chord_iterations: int = eqx.field(static=True, default=4)
    jacobian_max_age: int = eqx.field(static=True, default=20)

    def __check_init__(self):
        check_rho(self.rho)
        for name in ("newton_rtol", "newton_atol", "newton_kappa", "max_log_change"):
            check_positive(name, getattr(self, name))
        for name in ("max_newton_iterations", "chord_iterations", "jacobian_max_age"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.max_subdivisions < 0:
            raise ValueError(f"max_subdivisions must be >= 0, got {self.max_subdivisions!r}")

    def settings(self) -> dict:
        """The method's settings as JSON-able host values (recorded with a sweep's results)."""
        return {
            "rho": float(self.rho),
            "newton_rtol": float(self.newton_rtol),
            "newton_atol": float(self.newton_atol),
            "max_newton_iterations": self.max_newton_iterations,
            "max_subdivisions": self.max_subdivisions,
            "log_components": list(self.log_components),
            "log_discretization": self.log_discretization,
            "max_log_change": float(self.max_log_change),
        }

    @property
    def carried_log(self) -> tuple[int, ...]:
        """Components the scheme carries as their logarithm (``log_components`` with ``log_discretization``)."""
        return self.log_components if self.log_discretization else ()

    def _newton_in_log(self) -> tuple[int, ...]:
        """Components that Newton alone solves for in log form (the scheme stays in y)."""
        return () if self.log_discretization else self.log_components

    def _to_state(self, z):
        return from_log(z, self._newton_in_log())

    def _to_unknown(self, y):
        return to_log(y, self._newton_in_log())

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

        mask = log_mask(z_start.shape[0], self.log_components)  # log unknowns, in either mode

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

    def linearize(self, ode, z: Array) -> tuple[Array, Array]:
        """(∂y/∂z, ∂ψ/∂z) at Newton's unknown z: the Newton matrix of a step of any size h is
        ∂y/∂z − h·b·∂ψ/∂z, so these pieces can be kept across steps (error control reuses them
        while Newton converges fast, as CVODE does)."""

        def parts(z):
            y = self._to_state(z)
            return y, ode(y)

        return jax.jacfwd(parts)(z)

    def _chord_newton(self, ode, known, hb, z_start, active, chord):
        """Newton with a kept matrix (a chord iteration): converged when the update's WRMS norm
        in the error weights ``scale``, times min(1, the convergence rate), is ≤ ``kappa``
        (CVODE's test); fails after ``max_iterations`` or when an update grows (divergence).

        Returns (z, iterations, the last scaled update, converged).
        """
        (Dy, Dpsi), scale, kappa, max_iterations = chord
        matrix = Dy - hb * Dpsi

        def body(carry):
            z, iteration, _, previous, rate, _ = carry
            y = self._to_state(z)
            delta = solve_small(matrix, y - known - hb * ode(y))
            z_new = z - delta
            norm = jnp.sqrt(jnp.mean((delta / scale) ** 2))
            norm = jnp.where(jnp.all(jnp.isfinite(z_new)), norm, jnp.inf)
            rate = jnp.where(iteration > 0, jnp.maximum(0.3 * rate, norm / previous), rate)
            converged = norm * jnp.minimum(1.0, rate) <= kappa
            diverged = (iteration > 0) & (norm > 2.0 * previous)
            return z_new, iteration + 1, norm, norm, rate, jnp.where(converged, 1, jnp.where(diverged, -1, 0))

        def cond(carry):
            iteration, outcome = carry[1], carry[5]
            return (outcome == 0) & (iteration < max_iterations)

        init = (z_start, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), jnp.asarray(1.0), jnp.asarray(1.0), jnp.where(active, 0, 1))
        z, iterations, norm, _, _, outcome = jax.lax.while_loop(cond, body, init)
        return z, iterations, norm, outcome == 1

    def solve_step(self, ode, carry: AlphaState, h, z_solved=None, chord=None):
        """The α-method's step of size h from ``carry``: the one step both drivers use.

        Solves y_{n+1} = y_n + (1 − b)·h·ψ_n + b·h·ψ(y_{n+1}) + (1/2 − b)·h²·a_n by Newton
        (never differentiated; the implicit function theorem gives the tangent, see
        :func:`_implicit_root`) and updates a. Returns (z, evaluation at y_{n+1}, a_{n+1},
        iterations, correction, converged, matrix). A solve that did not converge is evaluated
        at the incoming state instead (finite values and derivatives; the caller rejects it).
        ``z_solved``: the replay of an accepted step whose Newton solution is known.
        ``chord``: ((∂y/∂z, ∂ψ/∂z), scale, kappa, max_iterations) for Newton with a kept
        matrix (:meth:`_chord_newton`, error control); None: a fresh autodiff Jacobian every
        iteration and the tolerances ``newton_rtol``/``newton_atol`` (the uniform mesh).

        Newton starts from y_n, not from an explicit predictor: near a fold of the step
        equation (J_t → 0) the predictor overshoots and Newton can land on the root beyond it,
        stepping over the singularity instead of stopping there.
        ψ, J_t and F̃·f are evaluated afresh at the new state for the same reason: the
        impasse test must see the state the step returns.
        """
        gamma, beta, b = self.coefficients()
        known = carry.y + (1.0 - b) * h * carry.psi + (0.5 - b) * h**2 * carry.a
        active = carry.status == 0
        if z_solved is None:
            z_start = _stop_gradient(self._to_unknown(carry.y))
            # Newton sees no tangents: its iterations are never differentiated.
            if chord is None:
                z, iterations, correction, converged, matrix = self._newton(
                    _stop_gradient(ode), _stop_gradient(known), _stop_gradient(b * h), z_start, active
                )
            else:
                z, iterations, correction, converged = self._chord_newton(
                    _stop_gradient(ode), _stop_gradient(known), _stop_gradient(b * h), z_start, active, _stop_gradient(chord)
                )
                matrix = self._no_matrix(carry.y)
            z = jnp.where(converged, z, z_start)
        else:  # the replay of an accepted plain step: its solution is known
            z, iterations, correction, converged = z_solved, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), jnp.asarray(True)
            matrix = self._no_matrix(carry.y)
        # Identity on values; the implicit function theorem's tangent under jvp/grad.
        z = _implicit_root(jax.lax.stop_gradient(z), active & converged, _step_residual, (_stop_gradient(self), ode, known, b * h))
        evaluation = ode.evaluate(self._to_state(z))
        a_new = (evaluation.psi - carry.psi) / (gamma * h) + (1.0 - 1.0 / gamma) * carry.a
        return z, evaluation, a_new, iterations, correction, converged, matrix

    def _substep(self, ode, carry: AlphaState, h, accept_unresolved, z_solved=None):
        """One uniform-mesh step of size h with its stop tests; returns (new carry candidate,
        iterations, correction, matrix)."""
        z, evaluation, a_new, iterations, correction, converged, matrix = self.solve_step(ode, carry, h, z_solved)
        y_new = self._to_state(z)
        psi_new, J_new, drive_new = evaluation.psi, evaluation.J, evaluation.drive
        finite = jnp.all(jnp.isfinite(y_new)) & jnp.all(jnp.isfinite(psi_new)) & jnp.all(jnp.isfinite(a_new))
        crossed = (carry.J * J_new) < 0
        drive_kept_sign = (carry.drive * drive_new) > 0
        # A log component changing by more than max_log_change in one step is not resolved by
        # this step size (the paper's start: v grows by decades): subdivide, unless at the last level.
        log_change = jnp.where(log_mask(z.shape[0], self.log_components), jnp.abs(z - self._to_unknown(carry.y)), 0.0)
        unresolved = (jnp.max(log_change) > self.max_log_change) & ~accept_unresolved
        status = jnp.where(
            ~converged | unresolved,
            StopReason.NEWTON_FAILED,
            jnp.where(~finite, StopReason.NONFINITE, jnp.where(crossed & drive_kept_sign, StopReason.IMPASSE, 0)),
        ).astype(jnp.int32)
        new = AlphaState(y=y_new, psi=psi_new, a=a_new, J=J_new, drive=drive_new, status=status)
        return new, iterations, correction, matrix

    def _subdivided(self, ode, carry: AlphaState, h, level, record=False):
        """2^level substeps of h/2^level; stops at the first failed substep.

        ``record`` (static): also return the Newton solution of every substep, in slots of a
        (2^max_subdivisions, n) array (for :meth:`_replay`).
        """
        n_sub = 2**level
        h_sub = h / n_sub

        def body(state):
            i, current, iterations, correction, matrix = state[:5]
            new, it, res, mat = self._substep(ode, current, h_sub, level >= self.max_subdivisions)
            ok = new.status == 0
            current = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, current)
            current = eqx.tree_at(lambda c: c.status, current, new.status)
            out = (i + 1, current, iterations + it, jnp.maximum(correction, res), mat)
            if record:
                out = out + (state[5].at[i].set(self._to_unknown(new.y)),)
            return out

        def cond(state):
            i, current = state[0], state[1]
            return (i < n_sub) & (current.status == 0)

        init = (jnp.asarray(0, jnp.int32), carry, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), self._no_matrix(carry.y))
        if record:
            init = init + (jnp.zeros((2**self.max_subdivisions, carry.y.shape[0]), carry.y.dtype),)
        _, new, iterations, correction, matrix, *zs = jax.lax.while_loop(cond, body, init)
        return (new, iterations, correction, matrix, *zs)

    def step(self, ode: HomogenizedODE, carry: AlphaState, h) -> tuple[AlphaState, StepInfo]:
        """One macro step of size h with the subdivision safeguard.

        Level 0 is the plain step; level k its 2^k substeps, tried only if level k − 1 failed.
        The step body is traced once (inside the loop over levels), which halves compile time.
        Differentiable in forward and reverse mode with respect to ``ode``, ``carry`` and h
        (see the module docstring): values are those of the ``while_loop`` step, tangents
        come from :meth:`_replay` of the path taken.
        """
        return _step_with_tangent(self, ode, carry, h)

    def _replay(self, ode, carry: AlphaState, h, level, zs) -> AlphaState:
        """The step along the path the primal took, written without ``while_loop`` over tangents.

        ``zs`` holds the primal's Newton solutions of the accepted level's substeps, so no
        Newton iteration is re-run: level 0: the plain step at zs[0]; level k > 0: 2^k
        substeps of h/2^k at zs[i] in a ``lax.scan`` over 2^max_subdivisions slots, the slots
        beyond 2^k inactive. Only its tangent is used (its value equals the primal's).
        """

        def plain():
            new, *_ = self._substep(ode, carry, h, jnp.asarray(self.max_subdivisions == 0), z_solved=zs[0])
            return new

        if self.max_subdivisions == 0:
            return plain()

        def subdivided():
            n_sub = jnp.left_shift(jnp.asarray(1, jnp.int32), level)
            h_sub = h / n_sub
            accept = level >= self.max_subdivisions

            def body(current, slot):
                i, z_i = slot
                run = (i < n_sub) & (current.status == 0)
                trial = eqx.tree_at(lambda c: c.status, current, jnp.where(run, 0, 1).astype(jnp.int32))
                # An idle slot sits at the current state, never at an unrecorded z (zeros): ψ and
                # its derivatives stay finite there, so 0·(derivative) stays 0 in reverse mode.
                z_i = jnp.where(run, z_i, self._to_unknown(current.y))
                new, *_ = self._substep(ode, trial, h_sub, accept, z_solved=z_i)
                ok = run & (new.status == 0)
                nxt = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, current)
                nxt = eqx.tree_at(lambda c: c.status, nxt, jnp.where(run, new.status, current.status))
                return nxt, None

            final, _ = jax.lax.scan(body, carry, (jnp.arange(2**self.max_subdivisions, dtype=jnp.int32), zs))
            return final

        return jax.lax.cond(level == 0, plain, subdivided)

    def _step_primal(self, ode, carry: AlphaState, h, record=False):
        """The step's values: Newton and subdivision levels in ``while_loop``s (see :meth:`step`).

        Returns (state, info), and with ``record`` (static) also the substeps' Newton solutions
        of the accepted level (see :meth:`_subdivided`).
        """
        if self.max_subdivisions == 0:
            new, iterations, correction, matrix = self._substep(ode, carry, h, jnp.asarray(True))
            level = jnp.asarray(0, jnp.int32)
            zs = [self._to_unknown(new.y)[None]] if record else []
        else:

            def retry_cond(state):
                level, new = state[0], state[1]
                return (new.status == StopReason.NEWTON_FAILED) & (level < self.max_subdivisions)

            def retry_body(state):
                level, iterations = state[0], state[2]
                new, it, res, mat, *zs = self._subdivided(ode, carry, h, level + 1, record)
                return (level + 1, new, iterations + it, res, mat, *zs)

            failed = eqx.tree_at(lambda c: c.status, carry, jnp.asarray(StopReason.NEWTON_FAILED, jnp.int32))
            init = (jnp.asarray(-1, jnp.int32), failed, jnp.asarray(0, jnp.int32), jnp.asarray(0.0), self._no_matrix(carry.y))
            if record:
                init = init + (jnp.zeros((2**self.max_subdivisions, carry.y.shape[0]), carry.y.dtype),)
            level, new, iterations, correction, matrix, *zs = jax.lax.while_loop(retry_cond, retry_body, init)
        if self.condition_number:
            condition = jnp.linalg.cond(matrix)
        else:
            condition = jnp.asarray(jnp.nan)
        info = StepInfo(newton_iterations=iterations, newton_correction=correction, condition=condition, level=level)
        return (new, info, zs[0]) if record else (new, info)


def alpha_start(ode, solver: AlphaMethod, y0: Float[Array, " n"]) -> tuple[HomogenizedODE | LogTransformedODE, AlphaState]:
    """The ODE in the integrator's coordinates and the state at t0.

    With ``solver.log_discretization`` the ODE becomes a :class:`LogTransformedODE` and the
    state carries log v; :func:`to_physical` maps carried states back. a_0 = ψ'(y_0)·ψ(y_0).
    A start that is not finite (or not positive in the log components) has status NONFINITE.
    """
    y0 = jnp.asarray(y0, float)
    positive = jnp.all(jnp.where(log_mask(y0.shape[0], solver.log_components), y0 > 0, True))
    if solver.carried_log:
        ode = LogTransformedODE(ode, solver.log_components)
        y0 = to_log(y0, solver.log_components)
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
    return from_log(y, solver.carried_log) if solver.carried_log else y


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
