"""Fitting φ to a stick-slip table: Levenberg–Marquardt on the cycle statistics, with uncertainties.

Each row of a :class:`~peeljax.fit.StickSlipTable` is one pull velocity V_i; the model
runs there from the paper's initial data through the folds (τ = 0 by default: the DAE with
jumps), and its statistics over the window [transient, transient + window]
(:func:`peeljax.fit.statistics.jump_statistics`: ``F_mean``, ``F_slip``, ``F_stick``,
``period``, ``slip_duration``) are compared with the table's. All rows run as one batch
(``lax.map``) in one compiled program. The residuals are

    r_is = (model_s(V_i; θ) − data_is)/σ_is,

σ_is the table's standard deviation where given, else the RMS of column s (the covariance is
then scaled by the residual variance, :mod:`peeljax.fit.uncertainty`). A statistic the table
has but the model run does not produce (no slip in the window) costs a fixed residual
``MISSING_RESIDUAL`` with zero derivative, so that a trial step that loses the stick-slip is
never mistaken for a better fit.

A force record in the stick-slip range is fitted through these statistics
(:meth:`StickSlipTable.from_force_records`), not point by point: the phase of a sawtooth drifts,
and a point-wise misfit of two sawtooths with slightly different periods is dominated by that
drift (``docs/fitting.md`` measures it).

Solver: optimistix's Levenberg–Marquardt with the Jacobian by forward-mode autodiff (one
tangent per free coefficient, through every jump by the implicit function theorem), stopped
when the relative change of the parameters and of the loss fall below ``rtol``/``atol``
(optimistix's Cauchy test) or after ``max_iterations``; ``n_starts`` perturbed starts run one
after another in one compiled program (``lax.map``: under ``vmap`` every branch of the loop runs
at every step) and the best is kept.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .._validation import check_positive
from ..adhesion import AdhesionLaw
from ..constrained import ConstrainedDAE
from ..homogenized import HomogenizedODE
from ..integrators.base import AbstractIntegrator
from ..integrators.select import integrator_for
from ..model import PeelingModel
from .statistics import jump_statistics
from .stick_slip_table import STATISTICS, StickSlipTable
from .trajectory import FitResult, _check_free, _to_law
from .uncertainty import uncertainty_from_jacobian

__all__ = ["MISSING_RESIDUAL", "TableFit", "build_table_fit", "fit_stick_slip", "table_residuals"]

MISSING_RESIDUAL = 10.0
V_REST = 1e-4  # m/s: the lower end of the reported v range where the tape comes to rest (v = 0)



class TableFit(eqx.Module):
    """θ ↦ residuals of a stick-slip table (module docstring); a pytree, so its compiled
    programs are reused by fits of the same shapes."""

    start: AdhesionLaw
    model: PeelingModel
    V: Float[Array, " n"]
    data: Float[Array, "n 5"]
    sigma: Float[Array, "n 5"]
    tau: Float[Array, ""]
    integrator: AbstractIntegrator
    names: tuple[str, ...] = eqx.field(static=True)
    measured: tuple[tuple[int, ...], tuple[int, ...]] = eqx.field(static=True)  # (rows, columns)
    transient: float = eqx.field(static=True)
    window: float = eqx.field(static=True)
    n_samples: int = eqx.field(static=True)
    dae: bool = eqx.field(static=True)

    def run(self, law: AdhesionLaw, V) -> tuple[Array, Array, Array]:
        """One row: (statistics (5,), available (5,), (v_lo, v_hi) visited in the window)."""
        model = eqx.tree_at(lambda m: m.adhesion, self.model, law)
        ode = ConstrainedDAE(model, V) if self.dae else HomogenizedODE(model, V, self.tau)
        t_end = self.transient + self.window
        ts = jnp.linspace(self.transient, t_end, self.n_samples)
        sol = self.integrator.integrate(ode, model.initial_state(V), 0.0, t_end, ts)
        ys = jnp.where(sol.valid[:, None], sol.ys, 1.0)
        F = model.tension(ys[:, 2], ys[:, 0])
        values, available = jump_statistics(sol.jumps, F, self.transient, t_end)
        v = jax.lax.stop_gradient(ys[:, 3])
        return values, available & (sol.status == 0), jnp.stack([jnp.min(v), jnp.max(v)])

    def statistics(self, theta) -> tuple[Array, Array, Array]:
        """Per row: the model's statistics, which are available, and the v range visited."""
        law = _to_law(theta, self.start)
        # One row after another (lax.map), not vmap: under vmap the jump branch of every step
        # (root search, bisection) runs for all rows at every step, measured 20x slower.
        return jax.lax.map(lambda V: self.run(law, V), self.V)

    def residuals(self, theta, args=None) -> Float[Array, " m"]:
        """r(θ): the measured entries of (model − data)/σ, row by row."""
        return self.residuals_and_range(theta)[0]

    def residuals_and_range(self, theta) -> tuple[Float[Array, " m"], Float[Array, "n 2"]]:
        """r(θ) and each row's (v_lo, v_hi) visited in its window (no derivative)."""
        values, available, v_range = self.statistics(theta)
        r = jnp.where(available, (values - self.data) / self.sigma, MISSING_RESIDUAL)
        return r[self.measured], jax.lax.stop_gradient(v_range)


def build_table_fit(
    start: AdhesionLaw, model: PeelingModel, V, data, sigma, measured, *, names, tau, transient, window,
    n_samples, rtol, atol, max_jumps, max_steps,
) -> TableFit:  # fmt: skip
    """The :class:`TableFit` of (n, 5) ``data``/``sigma``/``measured`` arrays at the pull
    velocities ``V``, its rows run with the error-controlled α-method through the folds
    (forward mode: the Jacobian is a tangent per coefficient). Options as :func:`fit_stick_slip`."""
    dae = tau == 0
    integrator = integrator_for(
        None, t_final=transient + window, rtol=rtol, atol=atol, fold="jump", max_jumps=max_jumps,
        max_steps=max_steps, adjoint="forward", dae=dae,
    )  # fmt: skip
    return TableFit(
        start=start, model=model, V=jnp.asarray(V, float), data=jnp.asarray(data, float),
        sigma=jnp.asarray(sigma, float), tau=jnp.asarray(float(tau)), integrator=integrator, names=tuple(names),
        measured=tuple(tuple(int(k) for k in a) for a in np.nonzero(measured)),
        transient=float(transient), window=float(window), n_samples=int(n_samples), dae=dae,
    )  # fmt: skip


def table_residuals(fit: TableFit, theta) -> Array:
    """The residual vector r(θ) of a :class:`TableFit` (measured entries only, row-major)."""
    return fit.residuals(theta)


def _residuals_and_jacobian(fit: TableFit, theta):
    """r(θ), its Jacobian (as ``jax.jacfwd``'s pytree) and the v range visited, from one
    forward-mode trace of the runs (one tangent per coefficient, the primal shared) instead of
    a trace for each."""
    flat, unflatten = jax.flatten_util.ravel_pytree(theta)
    basis = jnp.eye(flat.size)

    def tangent(direction):
        (r, v_range), (dr, _) = jax.jvp(lambda z: fit.residuals_and_range(unflatten(z)), (flat,), (direction,))
        return r, v_range, dr

    residuals, v_range, columns = jax.vmap(tangent, out_axes=(None, None, 0))(basis)
    names = [path[0].key for path, _ in jax.tree_util.tree_flatten_with_path(theta)[0]]  # the flat order
    return residuals, {name: columns[k] for k, name in enumerate(names)}, v_range


@eqx.filter_jit
def _solve(fit: TableFit, thetas, rtol, atol, max_iterations: int):
    """Levenberg–Marquardt from each start (a batch): θ, the residuals at the start and at θ, the
    Jacobian and the v range at θ, result code, steps."""
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def one(theta0):
        start = fit.residuals(theta0)
        sol = optx.least_squares(
            fit.residuals, solver, theta0, options={"jac": "fwd"}, max_steps=max_iterations, throw=False
        )
        theta = sol.value
        residuals, jacobian, v_range = _residuals_and_jacobian(fit, theta)
        return theta, start, residuals, jacobian, v_range, sol.result._value, sol.stats["num_steps"]

    # One start after another (lax.map), not vmap: under vmap every lax.cond of the loop (the fold
    # location, the jump, the output) becomes a select that runs at every step (measured: 3
    # iterations from one start 18 s under vmap, against a fraction of a second).
    return jax.lax.map(one, thetas)


def _reason(code: int, steps: int, max_iterations: int) -> str:
    """Why the fit stopped, in words."""
    if code == 0:
        return "converged: the relative changes of the coefficients and of the loss fell below fit_rtol/fit_atol"
    if steps >= max_iterations:
        return f"max_iterations ({max_iterations}) reached before convergence"
    for item in (optx.RESULTS.nonlinear_divergence, optx.RESULTS.nonfinite, optx.RESULTS.nonlinear_max_steps_reached):
        if int(item._value) == code:
            return f"stopped by optimistix: {optx.RESULTS[item]}"
    return f"stopped by optimistix (result code {code})"


def _table_arrays(table: StickSlipTable, wanted) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(data, σ, measured, σ from the table) as (n, 5) arrays over :data:`STATISTICS`."""
    data = np.zeros((len(table), len(STATISTICS)))
    sigma = np.ones_like(data)
    measured = np.zeros_like(data, bool)
    has_std = all(s in table.std and not np.any(np.isnan(table.std[s][~np.isnan(table.values[s])])) for s in wanted)
    for j, s in enumerate(STATISTICS):
        if s not in wanted:
            continue
        column = table.values[s]
        measured[:, j] = ~np.isnan(column)
        data[:, j] = np.nan_to_num(column)
        sigma[:, j] = np.nan_to_num(table.std[s], nan=1.0) if has_std else float(np.sqrt(np.nanmean(column**2)))
    return data, sigma, measured, has_std


def _check_options(table, transient, window, n_samples, tau, n_starts, max_iterations, fit_rtol, fit_atol):
    if not isinstance(table, StickSlipTable):
        raise TypeError(f"table must be a StickSlipTable (read_stick_slip_table), got {type(table).__name__}")
    check_positive("window", window)
    if not (isinstance(transient, (int, float)) and math.isfinite(transient) and transient >= 0):
        raise ValueError(f"transient must be a number >= 0, got {transient!r}")
    if not (isinstance(tau, (int, float)) and math.isfinite(tau) and tau >= 0):
        raise ValueError(f"tau must be a number >= 0, got {tau!r}")
    for name, value, least in (("n_samples", n_samples, 2), ("n_starts", n_starts, 1), ("max_iterations", max_iterations, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
    check_positive("fit_rtol", fit_rtol)
    check_positive("fit_atol", fit_atol)


def table_tolerances(tau: float, rtol: float | None = None, atol: float | None = None) -> tuple[float, float]:
    """The integrator's tolerances of a table fit: given ones, else by τ.

    τ = 0 runs Tsit5, whose forward-mode Jacobian of the statistics through ~30 jumps is
    right to 1e-3 at rtol 1e-9 and 1e-8 but not at 1e-7, where one near-tangential slip's
    time derivative is 3× off (measured: ``tests/test_steppers.py``); a fifth-order
    stepper's tighter tolerance costs little. τ > 0 keeps the α-method's 1e-7.
    """
    loose = float(tau) > 0
    return (
        (1e-7 if loose else 1e-9) if rtol is None else rtol,
        (1e-10 if loose else 1e-12) if atol is None else atol,
    )


def fit_stick_slip(
    table: StickSlipTable,
    model: PeelingModel | None = None,
    *,
    free: Sequence[str] | None = ("c1", "c3", "c6"),
    start: AdhesionLaw | None = None,
    statistics: Sequence[str] | None = None,
    tau: float = 0.0,
    transient: float = 0.5,
    window: float = 1.0,
    n_samples: int = 401,
    rtol: float | None = None,
    atol: float | None = None,
    fit_rtol: float = 1e-6,
    fit_atol: float = 1e-8,
    max_iterations: int = 30,
    n_starts: int = 1,
    start_spread: float = 0.05,
    seed: int = 0,
    max_jumps: int = 4096,
    max_steps: int = 400_000,
) -> FitResult:
    """Fit φ's free coefficients to a stick-slip table by Levenberg–Marquardt (module docstring).

    Args:
        table: the measured statistics against V (:func:`peeljax.fit.read_stick_slip_table`,
            :meth:`StickSlipTable.from_force_records`).
        model: spool and tape (default the paper's); its φ is the start unless ``start`` is given.
        free: the coefficients to fit (default c1, c3, c6); None: all 14. Coefficients the
            table cannot determine are named in ``result.uncertainty.undetermined``.
        statistics: the table's statistics to fit (default all it has).
        tau: 0 (default: the DAE with jumps) or τ > 0 (the homogenized ODE with jumps).
        transient, window: the statistics are taken over [transient, transient + window] [s].
        n_samples: dense-output times in the window (``F_mean`` is their mean).
        rtol, atol: the integrator's tolerances; None: :func:`table_tolerances` (τ = 0: rtol
            1e-9, atol 1e-12 for the default Tsit5 stepper; τ > 0: 1e-7, 1e-10).
        fit_rtol, fit_atol: Levenberg–Marquardt's convergence tolerances (optimistix's Cauchy
            test on the coefficients and the loss); ``max_iterations``: its budget.
        n_starts: starts run one after another in one program: the first at ``start``, the others with each free
            coefficient scaled by exp(N(0, start_spread²)) (``seed``); the best is kept,
            ``result.start_losses`` holds every start's final loss.
        max_jumps, max_steps: each run's jump record and step budget.

    Returns:
        A :class:`~peeljax.fit.FitResult`: ``adhesion`` (the fitted law), ``uncertainty``
        (:class:`~peeljax.fit.uncertainty.Uncertainty`), ``stop_reason``, ``residuals`` (the
        measured entries of (model − data)/σ, row by row), ``v_range`` (the v visited in the
        windows, from at least ``V_REST`` = 1e-4 m/s where the tape comes to rest: φ is fixed
        by the data only there) and ``settings``.
    """
    began = time.perf_counter()
    rtol, atol = table_tolerances(tau, rtol, atol)
    _check_options(table, transient, window, n_samples, tau, n_starts, max_iterations, fit_rtol, fit_atol)
    names = _check_free(free)
    model = PeelingModel() if model is None else model
    start = model.adhesion if start is None else start
    if not isinstance(start, AdhesionLaw):
        raise TypeError("fit_stick_slip fits an AdhesionLaw; the model's adhesion is a plain callable")
    wanted = table.statistics if statistics is None else tuple(statistics)
    unknown = [s for s in wanted if s not in table.statistics]
    if unknown or not wanted:
        raise ValueError(f"statistics: {unknown or 'none'} not in the table, which has {list(table.statistics)}")
    data, sigma, measured, has_std = _table_arrays(table, wanted)
    if int(measured.sum()) <= len(names):
        raise ValueError(
            f"free: {int(measured.sum())} measured values cannot determine {len(names)} coefficients "
            "with an error estimate; fit fewer"
        )
    fit = build_table_fit(
        start, model, table.V, data, sigma, measured, names=names, tau=tau, transient=transient, window=window,
        n_samples=n_samples, rtol=rtol, atol=atol, max_jumps=max_jumps, max_steps=max_steps,
    )  # fmt: skip
    offsets = np.zeros((n_starts, len(names)))
    offsets[1:] = np.random.default_rng(seed).normal(0.0, start_spread, size=(n_starts - 1, len(names)))
    thetas, starts, rs, Js, v_ranges, codes, steps = _solve(
        fit, {n: jnp.asarray(offsets[:, k]) for k, n in enumerate(names)}, fit_rtol, fit_atol, max_iterations
    )
    rs, codes, steps = np.asarray(rs), np.asarray(codes), np.asarray(steps)
    losses = np.sum(rs**2, axis=1)
    best = int(np.argmin(np.where(np.isfinite(losses), losses, np.inf)))
    theta = {n: thetas[n][best] for n in names}
    J = np.stack([np.asarray(Js[n][best]) for n in names], axis=1)
    law = _to_law(theta, start)
    values = np.asarray([float(getattr(law, n)) for n in names])
    initial = np.asarray(starts[0])  # the first start is at ``start`` itself
    v_range = np.asarray(v_ranges[best])
    settings = {
        "kind": "stick-slip table", "V": [float(v) for v in table.V], "statistics": list(wanted), "tau": float(tau),
        "transient": float(transient), "window": float(window), "n_samples": n_samples, "rtol": rtol, "atol": atol,
        "fit_rtol": fit_rtol, "fit_atol": fit_atol, "max_iterations": max_iterations, "n_starts": n_starts,
        "start_spread": start_spread, "seed": seed, "method": "levenberg-marquardt (optimistix)",
        "weights": "the table's standard deviations" if has_std else "column RMS; covariance scaled by s^2",
        "parametrisation": "c = c_start*exp(theta)",
    }  # fmt: skip
    return FitResult(
        adhesion=law,
        start=start,
        loss_history=np.asarray([float(initial @ initial), float(losses[best])]),
        initial_loss=float(initial @ initial),
        final_loss=float(losses[best]),
        gradient_norm=float(np.linalg.norm(2 * J.T @ rs[best])),
        steps=int(steps[best]),
        stopped_early=bool(codes[best] == 0),
        v_range=(float(max(np.min(v_range[:, 0]), V_REST)), float(np.max(v_range[:, 1]))),
        free=names,
        settings=settings,
        wall_time_s=time.perf_counter() - began,
        uncertainty=uncertainty_from_jacobian(J, rs[best], values, names, scaled=not has_std),
        stop_reason=_reason(int(codes[best]), int(steps[best]), max_iterations),
        residuals=rs[best],
        start_losses=losses,
    )
