"""Fitting the adhesion law φ(v, V) to observed peeling runs with exact gradients and optax.

The loss (:func:`trajectory_loss`) compares the α-method's trajectory at each pull velocity V_j
with observations on their own time grids:

    L(θ) = Σ_q w_q · (1/n_V) Σ_j  mean_i r_qij²,   r_qij = (q_model(t_ij; V_j, θ) − q_ij) / s_qj

for the observed quantities q ∈ {v, F, alpha} (F = the tension (k/l)·u), the model taken at
the observation times (error control: its dense output; uniform mesh: ``jnp.interp``) and s_qj
the RMS of the data q_ij. An observation time the run did not reach (t > t_stop) costs the
fixed penalty 1 (the squared residual of predicting zero), so that a trial step that stops the
run is never mistaken for a better fit. The gradient, from the reached part only, is exact
(implicit differentiation of every Newton solve, :mod:`peeljax.integrators.alpha`).

Parametrisation (positivity): every free coefficient is c = c_start·exp(θ), θ = 0 at the
start. A coefficient keeps the sign of its start value: the paper's 14 coefficients are all
positive (the powers p1, p2, p5, p7, p8, p9 must be > 0 for φ's v → 0 limit, c4 must be
non-zero), and the log parametrisation also puts coefficients of very different sizes
(0.15 … 415) on one scale for the optimizer.

Identifiability: the data fix φ only along the visited v range (:attr:`FitResult.v_range`)
and at the observed V; see ``docs/fitting.md``.
"""

from __future__ import annotations

import abc
import functools
import math
import time
from collections.abc import Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, ArrayLike, Float

from .._exported import ExportedProgram, all_arrays
from .._validation import check_positive
from ..adhesion import AdhesionLaw
from ..homogenized import HomogenizedODE
from ..integrators.alpha import AlphaMethod
from ..integrators.base import AbstractIntegrator
from ..integrators.select import integrator_for
from ..model import PeelingModel
from ..measurements.observations import Observation
from .parameters import check_free, law_from, model_and_start
from .result import FitInterrupted, FitResult

__all__ = ["FitInterrupted", "FitResult", "LossInfo", "Observation", "fit_adhesion", "fit_adhesion_steady",
    "phi_relative_error", "restart_on_ascent", "trajectory_loss"]  # fmt: skip

QUANTITIES = ("v", "F", "alpha")
UNREACHED_PENALTY = 1.0  # per observation after the run stopped, in units of (data RMS)²


class _Data(eqx.Module):
    """Observations padded to one length per quantity: times, values, scale and mask, by V."""

    V: Float[Array, " nV"]
    t: dict
    values: dict
    scale: dict
    mask: dict
    grid: Float[Array, "nV m"]  # per V: every observation time, increasing (padded with the last)


def _pack(observations: Sequence[Observation]) -> tuple[_Data, float]:
    quantities = [q for q in QUANTITIES if any(o.series(q) is not None for o in observations)]
    t, values, scale, mask = {}, {}, {}, {}
    t_max = 0.0
    for q in quantities:
        series = [o.series(q) for o in observations]
        n = max(1, max(len(s[0]) for s in series if s is not None))
        T = np.zeros((len(observations), n))
        X = np.zeros((len(observations), n))
        M = np.zeros((len(observations), n), bool)
        S = np.ones(len(observations))
        for j, s in enumerate(series):
            if s is None or len(s[0]) == 0:
                continue
            k = len(s[0])
            T[j, :k], X[j, :k], M[j, :k] = s[0], s[1], True
            rms = float(np.sqrt(np.mean(s[1] ** 2)))
            S[j] = rms if rms > 0 else 1.0
            t_max = max(t_max, float(s[0].max()))
        t[q], values[q], scale[q], mask[q] = jnp.asarray(T), jnp.asarray(X), jnp.asarray(S), jnp.asarray(M)
    V = jnp.asarray([float(o.V) for o in observations])
    times = [np.unique(np.concatenate([np.asarray(t[q])[j][np.asarray(mask[q])[j]] for q in quantities]))
             for j in range(len(observations))]  # fmt: skip
    m = max(len(row) for row in times)
    grid = np.stack([np.concatenate([row, np.full(m - len(row), row[-1])]) for row in times])
    return _Data(V=V, t=t, values=values, scale=scale, mask=mask, grid=jnp.asarray(grid)), t_max


class LossInfo(eqx.Module):
    """What a fit's loss reports besides its value.

    Attributes:
        v_min, v_max: the v range on which the loss evaluated φ (per V for a trajectory loss):
            the data determine φ only there.
        t_stop: per V, where the model's run stopped (t_final when it completed); None for
            the steady loss, which runs no model.
    """

    v_min: Array
    v_max: Array
    t_stop: Array | None


def _run_loss(model, V, tau, integrator, t_final, t, values, scale, mask, grid, weights) -> tuple[Array, LossInfo]:
    """Loss terms of one pull velocity (see the module docstring) and what the run visited.

    An integrator with dense output (error control, diffrax) outputs at the observation
    times ``grid`` (within [0, t_final]); the uniform mesh outputs its mesh points, which are
    interpolated linearly."""
    ode = HomogenizedODE(model, V, tau)
    y0 = model.initial_state(V)
    ts = jnp.clip(grid, 0.0, t_final) if integrator.dense_output else None
    sol = integrator.integrate(ode, y0, 0.0, t_final, ts)
    ys = jnp.where(sol.valid[:, None], sol.ys, 0.0)  # the double where: no NaN reaches the gradient
    quantities = {"v": ys[:, 3], "alpha": ys[:, 0], "F": model.tension(ys[:, 2], ys[:, 0])}
    t_stop = jax.lax.stop_gradient(sol.t_stop)
    total = jnp.asarray(0.0)
    for q in values:
        # Rounding slack: an observation at the run's last mesh time counts as reached.
        reached = mask[q] & (t[q] <= t_stop + 1e-9 * t_final)
        modelled = jnp.interp(t[q], sol.ts, jnp.where(sol.valid, quantities[q], 0.0))
        r = jnp.where(reached, (modelled - values[q]) / scale[q], 0.0)
        # An observation the run did not reach costs UNREACHED_PENALTY (the loss of predicting
        # zero): without it, a trial step that stops the run early looks like a better fit.
        missed = jnp.sum(mask[q] & ~reached)
        total = total + weights[q] * (jnp.sum(r**2) + UNREACHED_PENALTY * missed) / jnp.maximum(jnp.sum(mask[q]), 1)
    v = jax.lax.stop_gradient(ys[:, 3])
    v_min = jnp.min(jnp.where(sol.valid, v, jnp.inf))
    v_max = jnp.max(jnp.where(sol.valid, v, -jnp.inf))
    return total, LossInfo(v_min=v_min, v_max=v_max, t_stop=t_stop)


def trajectory_loss(adhesion: AdhesionLaw, data: _Data, *, model: PeelingModel, tau: ArrayLike,
                    integrator: AbstractIntegrator, t_final: float, weights: dict[str, float],
                    batch: str = "map") -> tuple[Array, LossInfo]:  # fmt: skip
    """The fit's loss L (module docstring) for φ = ``adhesion``, and its :class:`LossInfo` (per V).

    ``batch="map"`` runs the pull velocities one after another (``lax.map``: a gradient costs
    the sum of the runs); ``"vmap"`` batches them (one run's wall time on many cores, but the
    replayed subdivision branch of every step is then always evaluated).
    """
    model = eqx.tree_at(lambda m: m.adhesion, model, adhesion)
    w = {q: jnp.asarray(weights.get(q, 1.0), float) for q in data.values}

    def one(args):
        V, t, values, scale, mask, grid = args
        return _run_loss(model, V, tau, integrator, t_final, t, values, scale, mask, grid, w)

    args = (data.V, data.t, data.values, data.scale, data.mask, data.grid)
    if batch == "vmap":
        terms, info = jax.vmap(one)(args)
    else:
        terms, info = jax.lax.map(one, args)
    return jnp.mean(terms), info


# ---------------------------------------------------------------------------- parametrisation
class _Loss(eqx.Module):
    """θ ↦ (L, :class:`LossInfo`) with φ = ``law_from(θ, start)``: the shape of every fit's loss.

    A pytree, so :func:`_update`'s compiled program is cached on its structure: a new fit
    with new data or start values but the same shapes reuses it.
    """

    start: eqx.AbstractVar[AdhesionLaw]

    @abc.abstractmethod
    def loss(self, adhesion: AdhesionLaw) -> tuple[Array, LossInfo]:
        """L and its :class:`LossInfo` for φ = ``adhesion``."""

    def __call__(self, theta):
        return self.loss(law_from(theta, self.start))


class _TrajectoryLoss(_Loss):
    """:func:`trajectory_loss` of the observed runs."""

    start: AdhesionLaw
    data: _Data
    model: PeelingModel
    tau: Float[Array, ""]
    integrator: AbstractIntegrator
    weights: dict
    t_final: float = eqx.field(static=True)
    batch: str = eqx.field(static=True)

    def loss(self, adhesion):
        return trajectory_loss(
            adhesion, self.data, model=self.model, tau=self.tau, integrator=self.integrator,
            t_final=self.t_final, weights=self.weights, batch=self.batch,
        )  # fmt: skip


class _SteadyLoss(_Loss):
    """mean_i ((φ(v_i, V_i) − force_i)/rms(force))², no model run."""

    start: AdhesionLaw
    v: Float[Array, " n"]
    force: Float[Array, " n"]
    V: Float[Array, " n"]
    scale: Float[Array, ""]

    def loss(self, adhesion):
        info = LossInfo(v_min=jnp.min(self.v), v_max=jnp.max(self.v), t_stop=None)
        return jnp.mean(((adhesion(self.v, self.V) - self.force) / self.scale) ** 2), info


OPTIMIZERS = ("adam", "lbfgs")


def restart_on_ascent(inner: optax.GradientTransformation) -> optax.GradientTransformationExtraArgs:
    """Wraps an L-BFGS-like transformation: an uphill step restarts its memory.

    optax's L-BFGS keeps curvature pairs with s·y ≤ 0 (the trajectory loss is not convex far
    from its minimum), and its direction can then point uphill. After each update the wrapper
    checks ⟨g, u⟩ < 0 (g the gradient passed in as ``updates``, u the update); where it fails,
    the update is taken again from ``inner.init(params)``: fresh memory, i.e. a line-searched
    gradient step. ``optimizer="lbfgs"`` is ``restart_on_ascent(optax.lbfgs(...))``; wrap your
    own L-BFGS the same way, e.g.
    ``fit_adhesion_steady(v, F, optimizer=restart_on_ascent(optax.lbfgs()))``.

    ``params`` is required; extra arguments (``value``, ``grad``, ``value_fn`` for a line
    search) are passed on to ``inner`` in both calls. The state is ``inner``'s.
    """
    if not isinstance(inner, optax.GradientTransformation):
        raise TypeError(f"restart_on_ascent wraps an optax.GradientTransformation, got {type(inner).__name__}")
    inner = optax.with_extra_args_support(inner)

    def update(updates, state, params=None, **extra_args):
        if params is None:
            raise ValueError("restart_on_ascent: the update needs params (its restart calls inner.init(params))")
        grad = updates
        new_updates, new_state = inner.update(grad, state, params, **extra_args)

        def restart(_):
            return inner.update(grad, inner.init(params), params, **extra_args)

        descent = optax.tree.vdot(grad, new_updates) < 0
        return jax.lax.cond(descent, lambda _: (new_updates, new_state), restart, None)

    return optax.GradientTransformationExtraArgs(inner.init, update)


def _check_options(steps, optimizer, learning_rate) -> tuple[optax.GradientTransformation, float | None]:
    """The optax transformation to run and ``learning_rate`` (a float or None), checked before anything compiles."""
    if not isinstance(steps, int) or isinstance(steps, bool) or steps < 0:
        raise ValueError(
            f"steps must be an integer >= 0 (allowed range: [0, inf); 0 evaluates the start), got {steps!r}"
        )
    if isinstance(optimizer, optax.GradientTransformation):
        if learning_rate is not None:
            raise ValueError(
                f"learning_rate={learning_rate!r} applies to optimizer='adam' or 'lbfgs' only; an optax "
                "transformation passed as optimizer carries its own learning rate: give one or the other"
            )
        if not (callable(optimizer.init) and callable(optimizer.update)):
            # ValueError like every other bad option (the CLI and callers catch ValueError).
            raise ValueError("optimizer: an optax.GradientTransformation needs callable init and update")  # noqa: TRY004
        return optimizer, None
    if not isinstance(optimizer, str) or optimizer not in OPTIMIZERS:
        hint = " (a callable, not a transformation: call it, e.g. optax.adam(1e-2))" if callable(optimizer) else ""
        raise ValueError(
            f"optimizer must be 'adam', 'lbfgs' or an optax.GradientTransformation, got {optimizer!r}{hint}"
        )
    if learning_rate is not None:
        check_positive("learning_rate", learning_rate)
        learning_rate = float(learning_rate)
    return _make_optimizer(optimizer, learning_rate), learning_rate


def _optimizer_setting(optimizer) -> str:
    """``FitResult.settings["optimizer"]``: the name, or the kind of a user's transformation (JSON-able)."""
    return optimizer if isinstance(optimizer, str) else f"optax.{type(optimizer).__name__} (user)"


# The setting each of the library's own transformations was made from, by the object's id (they
# live for the process: ``_make_optimizer`` keeps them): its update's program can be kept on disk.
_SETTING_OF: dict[int, tuple[str, float | None]] = {}


@functools.cache  # one object per setting: the jitted update is cached on it
def _make_optimizer(optimizer: str, learning_rate: float | None) -> optax.GradientTransformation:
    if optimizer == "adam":
        made = optax.adam(0.02 if learning_rate is None else learning_rate)
    elif optimizer == "lbfgs":
        # A backtracking (Armijo) line search needs only loss values: the compiled update then
        # holds one gradient program, not a second one for the zoom line search's gradients.
        linesearch = optax.scale_by_backtracking_linesearch(max_backtracking_steps=20, store_grad=False)
        made = restart_on_ascent(optax.lbfgs(learning_rate=learning_rate, linesearch=linesearch))
    else:
        raise ValueError(f"optimizer must be 'adam' or 'lbfgs', got {optimizer!r}")
    _SETTING_OF[id(made)] = (optimizer, learning_rate)
    return made


def _update(loss_fn, opt: optax.GradientTransformation, theta, state):
    """:func:`_filtered_update`, its traced program kept on disk (:mod:`peeljax._exported`)
    where the transformation is the library's own (``"adam"``, ``"lbfgs"``) and every leaf an
    array: a fit in a new process skips the tracing (~25 s for a fit at τ > 0)."""
    setting = _SETTING_OF.get(id(opt))
    args = (loss_fn, theta, state)
    if setting is None or not all_arrays(jax.tree.leaves(args)):
        return _filtered_update(loss_fn, opt, theta, state)
    new_theta, state_leaves, value, grad, aux = _kept_update(setting, *args)
    # the state comes back as its leaves (optax's state classes are not exported): same structure
    return new_theta, jax.tree.unflatten(jax.tree.structure(state), state_leaves), value, grad, aux


def _update_by_setting(setting, loss_fn, theta, state):
    new_theta, new_state, value, grad, aux = _update_body(loss_fn, _make_optimizer(*setting), theta, state)
    return new_theta, jax.tree.leaves(new_state), value, grad, aux


def _update_body(loss_fn, opt: optax.GradientTransformation, theta, state):
    """One optimizer iteration at θ: (new θ, new state, L(θ), ∇L(θ), aux(θ)).

    Compiled (``_filtered_update``) keyed on the loss module's structure and on ``opt`` (a NamedTuple of
    functions: static, compared by identity): fits with new data or new start values but the
    same shapes and the same transformation object reuse the compiled program. A
    ``GradientTransformationExtraArgs`` (optax.lbfgs, optax.chain, ...) gets ``value``,
    ``grad`` and ``value_fn`` (the loss alone, for a line search) as keyword arguments, as
    optax's own solvers expect; a plain ``GradientTransformation`` gets none.
    """

    def value_only(th):
        return loss_fn(th)[0]

    (value, aux), grad = jax.value_and_grad(loss_fn, has_aux=True)(theta)
    if isinstance(opt, optax.GradientTransformationExtraArgs):
        updates, state = opt.update(grad, state, theta, value=value, grad=grad, value_fn=value_only)
    else:
        updates, state = opt.update(grad, state, theta)
    return optax.apply_updates(theta, updates), state, value, grad, aux


_filtered_update = eqx.filter_jit(_update_body)
_kept_update = ExportedProgram("fit_adhesion_update", _update_by_setting, eqx.filter_jit(_update_by_setting))


def _strong(x):
    # optax's init leaves weakly typed scalars (L-BFGS' line-search counter) that come back
    # strongly typed from the first update: make them strong now, or step 2 compiles again.
    return jnp.array(x, dtype=jnp.result_type(x)) if eqx.is_array_like(x) else x


def _fit(loss_fn: _Loss, names, settings, *, opt, steps, patience, tolerance, progress, description):
    """Minimise loss_fn(θ) → (L, :class:`LossInfo`) with the optax transformation ``opt``
    from θ = 0 and report it as a :class:`FitResult`.

    The best of θ_0 … θ_steps is returned (the last update is evaluated too).
    """
    began = time.perf_counter()
    theta = {n: jnp.zeros((), float) for n in names}  # strongly typed: no recompile after step 1
    state = jax.tree.map(_strong, opt.init(theta))
    history, best, since_best, early, bar = [], (math.inf, theta, math.nan, None), 0, False, None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=steps, desc=description, leave=False)

    def result(stop_reason: str = "") -> FitResult:
        value, theta_best, gnorm, aux = best
        return FitResult(
            adhesion=law_from(theta_best, loss_fn.start), start=loss_fn.start, loss_history=np.asarray(history),
            initial_loss=float(history[0]), final_loss=float(value), gradient_norm=float(gnorm),
            steps=len(history) - 1, stopped_early=early, v_range=(float(np.min(aux.v_min)), float(np.max(aux.v_max))),
            free=names, settings=settings,
            t_stop=[] if aux.t_stop is None else [float(x) for x in np.atleast_1d(aux.t_stop)],
            wall_time_s=time.perf_counter() - began, stop_reason=stop_reason,
        )  # fmt: skip

    try:
        for k in range(steps + 1):
            new_theta, state, value, grad, aux = _update(loss_fn, opt, theta, state)
            value = float(value)
            if not math.isfinite(value):
                break
            history.append(value)
            since_best = 0 if value < best[0] * (1.0 - tolerance) else since_best + 1
            if value < best[0]:
                best = (value, theta, float(optax.tree.norm(grad)), aux)
            if k == steps:  # θ_steps evaluated; its update is not taken
                break
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{value:.3e}")
            theta = new_theta
            if since_best >= patience:
                early = True
                break
    except KeyboardInterrupt:
        if best[3] is None:
            raise
        raise FitInterrupted(result(f"interrupted after {len(history) - 1} iterations")) from None
    finally:
        if bar is not None:
            bar.close()
    if best[3] is None:
        raise FloatingPointError(f"{description}: the loss is not finite at the start; check the data and the start")
    return result()


def fit_adhesion(observations: Observation | Sequence[Observation], model: PeelingModel | None = None, *,
                 tau: float = 0.01, dt: float | None = None, t_final: float | None = None,
                 free: Sequence[str] | None = None, start: AdhesionLaw | None = None,
                 optimizer: str | optax.GradientTransformation = "adam", steps: int = 500,
                 learning_rate: float | None = None, weights: dict[str, float] | None = None,
                 patience: int = 50, tolerance: float = 1e-4, progress: bool = True,
                 solver: AlphaMethod | diffrax.AbstractSolver | None = None, checkpoint_every=None,
                 batch: str = "map", rtol: float | None = None, atol: float | None = None,
                 max_steps: int | None = None) -> FitResult:  # fmt: skip
    """Fit φ's coefficients to observed runs (v(t), optionally F(t) and α(t)) at one or more V.

    Minimises :func:`trajectory_loss` (module docstring) over θ, c = c_start·exp(θ), with
    optax; the model runs from the paper's consistent initial data at each V on [0, t_final]
    (default: the last observation time). ``solver``: any ``diffrax.AbstractSolver`` in place
    of the α-method (error control; gradients through diffrax's ``RecursiveCheckpointAdjoint``).

    Args:
        observations: one :class:`Observation` per pull velocity.
        model: spool and tape (default the paper's); its adhesion law is the start unless
            ``start`` is given.
        free: names of the coefficients to fit (default all 14); the rest stay at the start.
        optimizer: ``"adam"`` (default; ``optax.adam(learning_rate)``), ``"lbfgs"``
            (:func:`restart_on_ascent` of ``optax.lbfgs`` with a backtracking Armijo line
            search; ``learning_rate`` caps its step), or an ``optax.GradientTransformation``
            acting on θ, e.g. ``optax.chain(optax.clip_by_global_norm(1.0), optax.sgd(1e-2))``
            or ``restart_on_ascent(optax.lbfgs())``. A ``GradientTransformationExtraArgs``
            (``optax.lbfgs``, anything from ``optax.chain``) is updated with the keyword
            arguments ``value``, ``grad`` and ``value_fn`` (θ ↦ L, for a line search); a plain
            ``GradientTransformation`` without. Reuse one object across fits: the compiled
            update is cached on it.
        steps: optimizer iterations (0: only evaluate the loss and its gradient at the start).
        learning_rate: Adam's step (default 0.02) or L-BFGS' cap on its step (default none);
            only with ``optimizer="adam"``/``"lbfgs"`` (a transformation carries its own).
        weights: per observed quantity ``{"v": 1, "F": 1, "alpha": 1}``.
        patience, tolerance: stop when the loss has not fallen by a relative ``tolerance``
            for ``patience`` iterations.
        progress: a tqdm progress bar (on stderr).
        checkpoint_every: passed to :func:`integrate_alpha` (``"sqrt"`` for long runs).
        batch: ``"map"`` (default) or ``"vmap"`` over the pull velocities.
        dt: None (default): the error-controlled α-method, its dense output at the observation
            times; a number: the uniform mesh of that step, interpolated linearly.
        rtol, atol: error control's tolerances (default 1e-6, 1e-9; not with ``dt``); gradients
            exact in reverse mode through its checkpointed loop (step sizes held constant).
        max_steps: error control's budget of step attempts per run (None: the library's,
            ``peeljax.integrators.select.DEFAULT_MAX_STEPS``); a run that uses it up stops there.

    Returns:
        A :class:`FitResult`: the best iterate, the loss history, the gradient norm, the v visited.
    """
    if isinstance(observations, Observation):
        observations = [observations]
    observations = list(observations)
    if not observations:
        raise ValueError("fit_adhesion: no observations")
    for o in observations:
        check_positive("V", o.V)
        if o.series("v") is None or len(o.series("v")[0]) == 0:
            raise ValueError(f"observation at V = {o.V:g}: no finite v data")
    check_positive("tau", tau)
    if batch not in ("map", "vmap"):
        raise ValueError(f"batch must be 'map' or 'vmap', got {batch!r}")
    names = check_free(free)
    model, start = model_and_start(model, start, "fit_adhesion")
    weights = {q: 1.0 for q in QUANTITIES} | dict(weights or {})
    data, t_obs_max = _pack(observations)
    t_final = float(t_obs_max if t_final is None else t_final)
    opt, learning_rate = _check_options(steps, optimizer, learning_rate)
    # fold="stop": gradients do not yet follow the jump times (a separate piece of work), so the
    # fit integrates up to the first fold, as before runs were carried through the folds.
    budget = {} if max_steps is None else {"max_steps": max_steps}  # None: integrator_for's default
    integrator = integrator_for(
        solver, dt=dt, t_final=t_final, rtol=rtol, atol=atol, checkpoint_every=checkpoint_every, fold="stop", **budget
    )
    loss_fn = _TrajectoryLoss(start=start, data=data, model=model, tau=jnp.asarray(tau, float), integrator=integrator,
                              weights={q: jnp.asarray(weights[q], float) for q in data.values}, t_final=t_final,
                              batch=batch)  # fmt: skip
    uniform = dt is not None
    error_control = integrator.settings()
    settings = {
        "V": [float(o.V) for o in observations], "tau": float(tau),
        "dt": float(t_final / integrator.n_steps) if uniform else None, "t_final": t_final,
        "n_steps": integrator.n_steps if uniform else None, "optimizer": _optimizer_setting(optimizer),
        "learning_rate": learning_rate, "steps": steps, "patience": patience, "tolerance": tolerance,
        "weights": {q: weights[q] for q in data.values}, "batch": batch, "checkpoint_every": checkpoint_every,
        "rtol": None if uniform else error_control["rtol"], "atol": None if uniform else error_control["atol"],
        "method": "alpha" if uniform else error_control["method"], "parametrisation": "c = c_start*exp(theta)",
    }  # fmt: skip
    return _fit(loss_fn, names, settings, opt=opt, steps=steps, patience=patience, tolerance=tolerance,
                progress=progress, description="fit_adhesion")  # fmt: skip


def fit_adhesion_steady(v: ArrayLike, force: ArrayLike, V: ArrayLike | None = None, *,
                        start: AdhesionLaw | None = None, free: Sequence[str] | None = None,
                        optimizer: str | optax.GradientTransformation = "adam", steps: int = 2000,
                        learning_rate: float | None = None, patience: int = 200, tolerance: float = 1e-6,
                        progress: bool = True) -> FitResult:  # fmt: skip
    """Fit φ to steady peeling: measured (v, peel force) pairs, φ(v_i, V_i) = force_i.

    In steady peeling the constraint (sac) holds with α, u constant, so the shear force
    (1 + l·sinα/L)·F equals φ(v, V) with v = V (default ``V = v``). The loss is
    mean_i ((φ(v_i, V_i) − force_i)/rms(force))², with the same parametrisation and
    optimizers as :func:`fit_adhesion` (``optimizer``: ``"adam"``, ``"lbfgs"`` or an
    ``optax.GradientTransformation``; ``learning_rate`` only with the names). φ is determined
    only on the measured v range.
    """
    v = jnp.asarray(v, float)
    force = jnp.asarray(force, float)
    V = v if V is None else jnp.broadcast_to(jnp.asarray(V, float), v.shape)
    if v.ndim != 1 or v.shape != force.shape or v.size < 1:
        raise ValueError("v and force must be 1-D arrays of one length")
    if not bool(jnp.all(v > 0)) or not bool(jnp.all(jnp.isfinite(force))):
        raise ValueError("v must be > 0 and force finite")
    names = check_free(free)
    opt, learning_rate = _check_options(steps, optimizer, learning_rate)
    start = AdhesionLaw() if start is None else start
    loss_fn = _SteadyLoss(start=start, v=v, force=force, V=V, scale=jnp.sqrt(jnp.mean(force**2)))
    settings = {"kind": "steady", "optimizer": _optimizer_setting(optimizer), "learning_rate": learning_rate,
                "steps": steps, "patience": patience, "tolerance": tolerance}  # fmt: skip
    return _fit(loss_fn, names, settings, opt=opt, steps=steps, patience=patience, tolerance=tolerance,
                progress=progress, description="fit_adhesion_steady")  # fmt: skip


def phi_relative_error(
    fitted: AdhesionLaw, true: AdhesionLaw, V: ArrayLike, v_range: tuple[float, float], n: int = 400
) -> float:
    """max |φ_fit(v, V) − φ_true(v, V)| / |φ_true(v, V)| over log-spaced v in ``v_range`` and the V given."""
    lo, hi = v_range
    v = jnp.geomspace(lo, hi, n)
    Vs = jnp.atleast_1d(jnp.asarray(V, float))
    err = jax.vmap(lambda V_: jnp.max(jnp.abs(fitted(v, V_) - true(v, V_)) / jnp.abs(true(v, V_))))(Vs)
    return float(jnp.max(err))
