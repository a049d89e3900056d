"""Direct integration of the DAE (peel) with a standard stiff solver — what the paper argues fails.

Two index-1 formulations, both integrated with diffrax Kvaerno5 (adaptive, PID control):

* :func:`integrate_index1` — the DAE differentiated once: v̇ = F̃·f/(∂φ/∂v) appended to (av–str),
  i.e. the homogenized ODE at τ → 0 (``truncation=0``, J_t = −∂φ/∂v). At the maximum of φ
  (∂φ/∂v = 0, the stick → slip point) v̇ has a pole unless F̃·f vanishes too;
* :func:`integrate_state_space` — the semi-explicit form x' = f(x, v(x)) with v(x) solved from
  (sac) on the stick branch 0 < v ≤ v_top of φ (bisection in log v). v(x) ceases to exist when the
  shear force exceeds max φ: the solver is given NaN there and its step collapses.

Both report where they stop (:class:`peeljax.StopReason` ``STALLED``/``SOLVER_FAILED``) and
:func:`tolerance_sensitivity` repeats a run over tolerances: the failure point moves with them.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._arrays import float_array
from ..analysis import phi_extrema
from ..integrators.reference import solution_from_diffrax
from ..model import PeelingModel
from ..simulate import simulate_reference
from ..solution import Solution

__all__ = ["StateSpaceODE", "integrate_index1", "integrate_state_space", "tolerance_sensitivity"]


def integrate_index1(
    model: PeelingModel | None = None,
    V: float = 1.1,
    dt: float = 1 / 820,
    t_final: float = 3.0,
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 200_000,
) -> Solution:
    """diffrax Kvaerno5 on the index-1 ODE v̇ = F̃·f/(∂φ/∂v) (the DAE differentiated once), paper's start.

    The same as ``simulate_reference(..., truncation=0)``: τ plays no role there.
    """
    return simulate_reference(model, V, 1.0, dt, t_final, rtol=rtol, atol=atol, max_steps=max_steps, truncation=0)


class StateSpaceODE(eqx.Module):
    """x' = f(x, v(x)) with v(x) the stick-branch root of G(x) = φ(v, V), v ∈ (0, v_top]."""

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    v_top: Float[Array, ""] = eqx.field(converter=float_array)
    v_floor: float = 1e-14

    def velocity(self, x: Float[Array, " 3"]) -> Array:
        """v(x) by 200 bisections in log v on (v_floor, v_top]; NaN where G(x) > φ(v_top) (past the fold)."""
        G = self.model.shear_force(x)
        lo, hi = jnp.log(self.v_floor), jnp.log(self.v_top)

        def body(_, bounds):
            lo, hi = bounds
            mid = 0.5 * (lo + hi)
            above = self.model.phi(jnp.exp(mid), self.V) > G
            return jnp.where(above, lo, mid), jnp.where(above, mid, hi)

        lo, hi = jax.lax.fori_loop(0, 200, body, (lo, hi))
        v = jnp.exp(0.5 * (lo + hi))
        exists = G <= self.model.phi(self.v_top, self.V)
        return jnp.where(exists, v, jnp.nan)

    def __call__(self, x: Float[Array, " 3"]) -> Float[Array, " 3"]:
        return self.model.f(x, self.velocity(x), self.V)


@eqx.filter_jit
def _solve_state_space(system, x0, ts, rtol, atol, dtmin, max_steps):
    controller = diffrax.PIDController(rtol=rtol, atol=atol, dtmin=dtmin, force_dtmin=False)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, x, args: system(x)),
        diffrax.Kvaerno5(),
        ts[0],
        ts[-1],
        1e-6 * ts[-1],
        x0,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
        throw=False,
    )
    xs = sol.ys
    vs = jax.vmap(system.velocity)(jnp.where(jnp.isfinite(xs), xs, x0))
    return sol, vs


def integrate_state_space(
    model: PeelingModel | None = None,
    V: float = 1.1,
    dt: float = 1 / 820,
    t_final: float = 3.0,
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 200_000,
) -> Solution:
    """diffrax Kvaerno5 on x' = f(x, v(x)), v from (sac) on the stick branch (paper's initial data)."""
    model = PeelingModel() if model is None else model
    v_top, _ = phi_extrema(model, float(V))
    if not np.isfinite(v_top):
        raise ValueError(f"φ(·, V={V}) has no maximum: the stick branch is all of v > 0; use integrate_index1")
    from .._validation import check_mesh

    n = check_mesh(dt, t_final)
    ts = jnp.linspace(0.0, float(t_final), n + 1)
    y0 = model.initial_state(V)
    system = StateSpaceODE(model, V, v_top)
    sol, vs = _solve_state_space(
        system, y0[:3], ts, jnp.asarray(rtol), jnp.asarray(atol), 1e-12 * float(t_final), max_steps
    )
    ys = jnp.concatenate([sol.ys, vs[:, None]], axis=1)
    return solution_from_diffrax(sol, y0, ts, ys=ys, method="state-space", stats={"v_top": jnp.asarray(v_top)})


def tolerance_sensitivity(
    V: float = 1.1,
    rtols=(1e-4, 1e-6, 1e-8, 1e-10),
    *,
    form: str = "index1",
    model: PeelingModel | None = None,
    dt: float = 1 / 8200,
    t_final: float = 0.4,
    atol_ratio: float = 1e-2,
) -> list[dict]:
    """Stop time of a direct DAE integration against its tolerance (atol = atol_ratio·rtol).

    ``dt`` is the output spacing, so it bounds how finely the stop time is located.
    Returns one dict per rtol: rtol, atol, status, t_stop, v at the stop, steps.
    """
    run = {"index1": integrate_index1, "state_space": integrate_state_space}[form]
    rows = []
    for rtol in rtols:
        sol = run(model, V, dt, t_final, rtol=rtol, atol=atol_ratio * rtol)
        v = np.asarray(sol.v)[np.asarray(sol.valid)]
        row = _row(form, V, rtol, float(atol_ratio * rtol), bool(sol.completed), float(sol.t_stop),
                   float(v[-1]) if v.size else float("nan"))  # fmt: skip
        rows.append(row | {"steps": int(np.asarray(sol.stats["steps"]))})
    return rows


def _row(form, V, rtol, atol, completed, t_stop, v_at_stop) -> dict:
    """Where a direct integration stopped, as a row of :func:`tolerance_sensitivity` or :func:`integrate_ida`."""
    return {"form": form, "V": float(V), "rtol": float(rtol), "atol": atol, "completed": completed,
            "t_stop": t_stop, "v_at_stop": v_at_stop}  # fmt: skip


def integrate_ida(
    model: PeelingModel | None = None,
    V: float = 1.1,
    dt: float = 1 / 8200,
    t_final: float = 0.5,
    *,
    rtol: float = 1e-8,
    atol: float | tuple[float, float, float, float] = 1e-10,
    max_num_steps: int = 100_000,
    positive_v: bool = False,
) -> dict:
    """SUNDIALS IDA (BDF, via the optional ``scikit-sundae`` binding) on the index-1 DAE itself.

    Residuals F(t, y, ẏ) = (ẋ − f(x, v), G(x) − φ(v, V)) with v algebraic (``algebraic_idx``) and,
    with ``positive_v``, v > 0 imposed (``constraints_type`` 2); y0 the paper's consistent data,
    ẏ0 = (f(x0, v0), 0). A failure inside the binding is reported in ``message`` with ``t_stop``
    NaN: with ``positive_v`` scikit-sundae 1.2.0 sporadically rejects the same constraint vector
    in setup ("Illegal values in constraints vector"), so it is off by default (the runs measured
    in ``docs/reproduction.md`` reach the same stops with and without it).

    Returns:
        dict: ``completed``, ``t_stop`` (last output time reached), ``v_at_stop``, ``message``
        (IDA's), ``ts``, ``ys`` (reached part), ``rtol``, ``atol``.

    Raises:
        ImportError: when scikit-sundae is not installed (``pip install peeljax[sundials]``).
    """
    try:
        from sksundae.ida import IDA
    except ImportError as error:  # pragma: no cover - optional dependency
        raise ImportError("integrate_ida needs scikit-sundae: pip install 'peeljax[sundials]'") from error
    from .._validation import check_mesh, check_positive

    model = PeelingModel() if model is None else model
    check_positive("V", V)
    check_positive("rtol", rtol)
    check_positive("atol", atol)
    n = check_mesh(dt, t_final)

    @jax.jit
    def residual_jax(y, yp):
        x, v = y[:3], y[3]
        return jnp.concatenate([yp[:3] - model.f(x, v, V), model.constraint(x, v, V)[None]])

    def resfn(t, y, yp, res):
        res[:] = np.asarray(residual_jax(jnp.asarray(y), jnp.asarray(yp)))

    y0 = np.asarray(model.initial_state(V), float)
    yp0 = np.concatenate([np.asarray(model.f(jnp.asarray(y0[:3]), y0[3], V)), [0.0]])
    options = {"constraints_idx": [3], "constraints_type": [2]} if positive_v else {}
    solver = IDA(
        resfn,
        algebraic_idx=[3],
        rtol=rtol,
        atol=np.asarray(atol, float) if np.ndim(atol) else float(atol),
        max_num_steps=max_num_steps,
        **options,
    )
    ts = np.linspace(0.0, float(t_final), n + 1)
    atol_out = atol if np.ndim(atol) == 0 else list(np.asarray(atol, float))
    try:
        result = solver.solve(ts, y0, yp0)
    except RuntimeError as error:
        failed = {"message": f"IDA setup failed: {error}", "ts": np.zeros(0), "ys": np.zeros((0, 4))}
        return _row("ida", V, rtol, atol_out, False, float("nan"), float("nan")) | failed
    t_out, y_out = np.asarray(result.t), np.asarray(result.y)
    completed = bool(result.success) and t_out.size == ts.size
    v_stop = float(y_out[-1, 3]) if t_out.size else float("nan")
    row = _row("ida", V, rtol, atol_out, completed, float(t_out[-1]) if t_out.size else 0.0, v_stop)
    return row | {"message": str(result.message), "ts": t_out, "ys": y_out}
