"""Inertial regularization (de2005missing; the paper's discussion after Theorem 2, `expv`).

The constraint (sac) is replaced by an equation of motion for the peeling velocity with a small
mass m [kg]:

    α̇ = ω − v/R,  ω̇ = −R·l·sinα/(I·L)·F,  u̇ = (av–str) as in the DAE,
    m·v̇ = (1 + l·sinα/L)·F(u, α) − φ(v, V).                                 (inertial)

The paper writes the left side as m·ü, "which involves m·v̇"; with u̇ = … + V − v, ü = −v̇ + …,
and taking the printed sign literally (−m·v̇ = G − φ) makes every rising branch of φ unstable
(∂/∂v of the right side is +∂φ/∂v > 0). peeljax uses the stable sign above, which keeps
G − φ → 0 as m → 0 wherever ∂φ/∂v > 0 (the index-1 slow scale) — this is the sense in which the
formulation "satisfies (sac) in the limit m → 0" there. On the falling branch (∂φ/∂v < 0, slip)
no nearby equilibrium of the fast equation exists: v jumps across it in a time O(m), and the
constraint residual G − φ stays O(1) during the jump however small m is. That is the paper's
remark, and what :func:`constraint_report` measures.

v can overshoot towards 0 in a jump; φ is defined for v > 0 only, so the state carries
s = log v (ṡ = v̇/v), which keeps v > 0 exactly.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._arrays import float_array
from ..integrators.reference import solution_from_diffrax
from ..model import PeelingModel
from ..solution import Solution

__all__ = ["InertialModel", "constraint_report", "integrate_inertial"]


class InertialModel(eqx.Module):
    """The peeling ODE with tape inertia m (eq. ``inertial`` of the module doc), state (α, ω, u, log v)."""

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    m: Float[Array, ""] = eqx.field(converter=float_array)

    def rhs(self, z: Float[Array, " 4"]) -> Float[Array, " 4"]:
        """d/dt (α, ω, u, log v)."""
        x, v = z[:3], jnp.exp(z[3])
        vdot = self.model.constraint(x, v, self.V) / self.m
        return jnp.concatenate([self.model.f(x, v, self.V), (vdot / v)[None]])

    def constraint_residual(self, y: Float[Array, "... 4"]) -> Array:
        """(1 + l·sinα/L)·F − φ(v, V) at states y = (α, ω, u, v) (eq. ``sac``; m·v̇ along the flow)."""
        y = jnp.asarray(y)
        return jnp.vectorize(lambda y: self.model.constraint(y[:3], y[3], self.V), signature="(4)->()")(y)


@eqx.filter_jit
def _solve(system, z0, ts, rtol, atol, dtmin, max_steps, save_steps=False):
    controller = diffrax.PIDController(rtol=rtol, atol=atol, dtmin=dtmin, force_dtmin=False)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, z, args: system.rhs(z)),
        diffrax.Kvaerno5(),
        ts[0],
        ts[-1],
        1e-9,
        z0,
        saveat=diffrax.SaveAt(steps=True) if save_steps else diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
        throw=False,
    )
    return sol


def integrate_inertial(
    model: PeelingModel | None = None,
    V: ArrayLike = 1.1,
    m: ArrayLike = 1e-3,
    dt: float = 1 / 820,
    t_final: float = 3.0,
    y0: ArrayLike | None = None,
    *,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 200_000,
    save_steps: bool = False,
) -> Solution:
    """Integrate the inertially regularized model with diffrax Kvaerno5 (adaptive), output every ``dt``.

    Args:
        model, V: as for :func:`peeljax.simulate`; the paper's initial data by default (consistent,
            so v̇(0) = 0).
        m: the tape mass [kg], > 0.
        dt: output spacing [s]; steps are adaptive.
        save_steps: save every accepted step instead of the grid (``ts`` then has ``max_steps``
            entries, unused ones masked invalid): a jump of duration O(m) falls between grid
            points, so residuals in the slip need this.

    Returns:
        A :class:`Solution` with ``method="inertial"`` and states (α, ω, u, v); no diagnostics.
    """
    from .._validation import check_mesh, check_positive, check_y0

    model = PeelingModel() if model is None else model
    check_positive("V", V)
    check_positive("m", m)
    check_y0(y0)
    n = check_mesh(dt, t_final)
    y0 = model.initial_state(V) if y0 is None else jnp.asarray(y0, float)
    z0 = y0.at[3].set(jnp.log(y0[3]))
    ts = jnp.linspace(0.0, float(t_final), n + 1)
    system = InertialModel(model, V, m)
    sol = _solve(system, z0, ts, jnp.asarray(rtol), jnp.asarray(atol), 1e-14 * float(t_final), max_steps, save_steps)
    ys = sol.ys.at[:, 3].set(jnp.exp(sol.ys[:, 3]))
    return solution_from_diffrax(sol, y0, None if save_steps else ts, ys=ys, method="inertial")


def constraint_report(solution: Solution, model: PeelingModel | None = None, V: float = 1.1) -> dict[str, float]:
    """How well a run keeps (sac): the residual G − φ on each branch of φ, and where the slip starts.

    Branches (:mod:`peeljax.analysis`): 0 below the maximum of φ (stick), 1 between maximum and
    minimum (slip, ∂φ/∂v < 0), 2 above the minimum (fast rising branch). Fractions are
    time-weighted (the saved times may be the solver's adaptive steps).

    Returns:
        ``max_abs_residual`` [N] overall and ``max_abs_residual_branch{0,1,2}``,
        ``max_relative_residual`` (max |G − φ|/φ), ``fraction_above_1pct`` (time share with
        |G − φ| > 1 % of φ), ``slip_fraction`` (time share on branch 1),
        ``t_first_slip`` (first time v passes the maximum of φ), ``t_stop``, ``completed``.
    """
    import jax

    from ..analysis import phi_extrema

    model = PeelingModel() if model is None else model
    valid = np.asarray(solution.valid)
    ts = np.asarray(solution.ts)[valid]
    ys = jnp.asarray(np.asarray(solution.ys)[valid])
    residual = np.asarray(jax.vmap(lambda y: model.constraint(y[:3], y[3], V))(ys))
    phi = np.asarray(jax.vmap(lambda v: model.phi(v, V))(ys[:, 3]))
    v = np.asarray(ys[:, 3])
    v_top, v_bottom = phi_extrema(model, V)
    branch = np.where(v < v_top, 0, np.where(np.isnan(v_bottom) | (v < v_bottom), 1, 2))
    rel = np.abs(residual) / np.abs(phi)
    weights = np.diff(ts, append=ts[-1]) if ts.size else ts
    total = weights.sum()

    def _max(mask):
        return float(np.max(np.abs(residual[mask]))) if mask.any() else float("nan")

    def _share(mask):
        return float(weights[mask].sum() / total) if total > 0 else float("nan")

    above = np.flatnonzero(v >= v_top)
    return {
        "max_abs_residual": _max(np.ones_like(rel, bool)),
        "max_abs_residual_branch0": _max(branch == 0),
        "max_abs_residual_branch1": _max(branch == 1),
        "max_abs_residual_branch2": _max(branch == 2),
        "max_relative_residual": float(rel.max()) if rel.size else float("nan"),
        "fraction_above_1pct": _share(rel > 0.01),
        "slip_fraction": _share(branch == 1),
        "t_first_slip": float(ts[above[0]]) if above.size else float("nan"),
        "t_stop": float(solution.t_stop),
        "completed": bool(solution.completed),
    }
