"""The public entry point for one orbit: options checked, a start found, the orbit shot."""

from __future__ import annotations

import math
import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._exported import compiled
from .._validation import check_positive, check_tolerance, is_concrete
from ..cycles import cycle_statistics
from ..integrators.select import integrator_for
from ..branches import phi_folds
from ..model import PeelingModel
from ..simulate import simulate
from ..solution import Solution
from .floquet import multipliers
from .orbit import PeriodicOrbit
from .period import period_statistics
from .section import SlipSection
from .shooting import Shooting, ShootingResult, shoot

__all__ = ["DEFAULT_ORBIT_RTOL", "OrbitNotFound", "check_periodic_orbit", "orbit_shooting", "periodic_orbit"]

# The orbit's tolerances, chosen by measurement (docs/orbits.md, tests/test_orbits.py): at rtol
# 1e-8 the period and the five statistics agree with rtol 1e-11 to ~1e-7 relative.
DEFAULT_ORBIT_RTOL = 1e-8
ATOL_PER_RTOL = 1e-3
PERIODS_PER_RUN = 3.0  # one period's run is bounded by this many periods of the start
UNKNOWN_PERIOD_BOUND = 5.0  # [s]: the bound when no period is known
DEFAULT_TRANSIENT_RUN = 3.0  # [s]: the run that finds the repeat when no start is given
_MAX_STEPS_PER_SLIP = 100_000  # a bound on a runaway run only (a slip takes ~60 steps at rtol 1e-8)


class OrbitNotFound(ValueError):
    """No periodic orbit to shoot for: the run shows no repeat (steady, too short, irregular)."""


# k and Newton's iteration cap: each iteration runs k slips, so a typo must not run for hours
MAX_SLIPS = 1000
MAX_ITERATIONS = 1000


def _check_slips(slips) -> int:
    if isinstance(slips, bool) or not isinstance(slips, numbers.Integral) or not 1 <= slips <= MAX_SLIPS:
        raise ValueError(
            f"slips must be a positive integer (allowed range: [1, {MAX_SLIPS}]; the stick-to-slip events per period), got "
            f"{slips!r}"
        )
    return int(slips)


def check_iterations(max_iterations) -> int:
    """``max_iterations`` of Newton's method on the return map, checked (an integer in [1, 1000])."""
    if (
        isinstance(max_iterations, bool)
        or not isinstance(max_iterations, numbers.Integral)
        or not 1 <= max_iterations <= MAX_ITERATIONS
    ):
        raise ValueError(
            f"max_iterations must be a positive integer (allowed range: [1, {MAX_ITERATIONS}]), got {max_iterations!r}"
        )
    return int(max_iterations)


def check_periodic_orbit(
    model: PeelingModel | None,
    V: ArrayLike,
    *,
    slips: int | None,
    period: float | None,
    rtol: float,
    atol: float | None,
    max_iterations: int,
    transient: float,
) -> None:
    """The options of :func:`periodic_orbit`, checked in plain Python before anything compiles (what it
    checks first): a ValueError (TypeError for the model) naming the parameter and its allowed range."""
    if model is not None and not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    if not is_concrete(V) or np.ndim(V) != 0:
        raise ValueError(f"V must be one number (m/s, > 0), got {V!r}; for many V use peeljax.orbits.continue_orbits")
    check_positive("V", V)
    check_tolerance("rtol", rtol, upper=1.0)
    if atol is not None:
        check_tolerance("atol", atol)
    if slips is not None:
        _check_slips(slips)
    if period is not None:
        check_positive("period", period)
    check_iterations(max_iterations)
    check_positive("transient", transient)


def orbit_shooting(
    *, rtol: float = DEFAULT_ORBIT_RTOL, atol: float | None = None, max_iterations: int = 20
) -> Shooting:
    """The :class:`~peeljax.orbits.Shooting` of an orbit, its options checked (nothing compiles)."""
    check_tolerance("rtol", rtol, upper=1.0)
    atol = ATOL_PER_RTOL * rtol if atol is None else atol
    integrator = integrator_for(
        None, dae=True, t_final=1.0, rtol=rtol, atol=atol, adjoint="forward", max_jumps=1, max_steps=_MAX_STEPS_PER_SLIP,
    )  # fmt: skip
    return Shooting(integrator, max_iterations=check_iterations(max_iterations))


def as_orbit(model: PeelingModel, V, slips, result: ShootingResult) -> PeriodicOrbit:
    """The :class:`PeriodicOrbit` of a shooting result."""
    section = SlipSection.at(model, V)
    period = result.period
    return PeriodicOrbit(
        model=model, V=jnp.asarray(V, float), slips=jnp.asarray(slips, jnp.int32), section=result.z * section.scale,
        state=section.state(result.z * section.scale), period=period.time,
        force_integral=period.force_integral, approach=period.approach, crossing=period.crossing,
        monodromy=result.monodromy,
        multipliers=multipliers(result.monodromy), status=result.status, run_status=period.status,
        iterations=result.iterations, residual=result.residual, steps=period.steps,
        statistics=period_statistics(period),
    )  # fmt: skip


def orbit_of(shooting: Shooting, model: PeelingModel, V, s0, slips, t_max, avoid=None) -> PeriodicOrbit:
    """The orbit with ``slips`` slips per period shot from the section point ``s0`` (each
    period's run bounded by ``t_max``; ``avoid``: a section point Newton is kept away from, NaN
    or None: none): traceable, for ``jit``, ``vmap`` and ``lax.map``."""
    scale = SlipSection.at(model, V).scale
    avoid = None if avoid is None else jax.lax.stop_gradient(avoid / scale)
    result = shoot(shooting, model, V, jax.lax.stop_gradient(s0 / scale), slips, t_max, avoid)
    return as_orbit(model, V, slips, result)


compiled_orbit = compiled(orbit_of, "orbit")  # orbit_of, traced and compiled once per machine

# φ(·, V) has a maximum and a minimum
phi_has_folds = compiled(lambda model, V: phi_folds(model, V).exist, "phi_has_folds")


# Newton's iterations to tell a fixed point of P^j at the orbit's point (one step, then the test)
_SUB_PERIOD_ITERATIONS = 2


def _divisors(k: int) -> list[int]:
    return [j for j in range(1, k) if k % j == 0]


def least_period(shooting: Shooting, orbit: PeriodicOrbit) -> PeriodicOrbit:
    """``orbit`` with its least number of slips per period: a fixed point of P^k that is one of
    P^j for a divisor j of k (the orbit run k/j times, as a repeat seen before it settled can
    suggest) is shot again with j. Unchanged where it is not (or did not converge)."""
    k = int(orbit.slips)
    if int(orbit.status) != 0 or k == 1:
        return orbit
    # From a fixed point of P^j Newton stops at once; a point that is none would lead it, in 7–10
    # iterations, to another orbit with j slips (measured at V = 1.1 and 2), discarded anyway.
    check = eqx.tree_at(lambda s: s.max_iterations, shooting, jnp.asarray(_SUB_PERIOD_ITERATIONS, jnp.int32))
    for j in _divisors(k):
        ratio = jnp.asarray(j / k)
        shorter = compiled_orbit(check, orbit.model, orbit.V, orbit.section, jnp.asarray(j, jnp.int32),
                                 PERIODS_PER_RUN * ratio * orbit.period)  # fmt: skip
        # (a Python bool: under jax.grad without jit the fields are tracers whose values can be tested)
        if bool(_is_the_orbit(shorter, orbit, ratio)):
            return shorter
    return orbit


def _the_orbit_again(shorter: PeriodicOrbit, orbit: PeriodicOrbit, ratio) -> Array:
    """``shorter`` (j slips) converged to ``orbit``'s point with its period times j/k = ``ratio``."""
    scale = SlipSection.at(orbit.model, orbit.V).scale
    same_point = jnp.max(jnp.abs(shorter.section - orbit.section) / scale) < 1e-6
    same_period = jnp.abs(shorter.period - ratio * orbit.period) < 1e-6 * ratio * orbit.period
    return (shorter.status == 0) & same_point & same_period


_is_the_orbit = compiled(_the_orbit_again, "the_orbit_again")  # one program, not a dozen eager operations


def start_from_run(sol: Solution, slips: int | None = None) -> tuple[np.ndarray, int, float]:
    """(s0 = (α, ω) at the run's last stick → slip event, k, T) from a run's repeat.

    The repeat is looked for in the run's second half (:func:`peeljax.cycle_statistics`); where
    none is confirmed but a near repeat is forming (too few repeats yet to tell), that one is
    taken — Newton's method then says whether the orbit is there. α and ω, continuous across
    the jumps, are interpolated from the run's rows at the slip's time. Raises
    :class:`OrbitNotFound` where the run shows no repeat at all, saying why.
    """
    if not isinstance(sol, Solution):
        raise TypeError(f"start must be a Solution, a state (alpha, omega[, u, v]) or None, got {type(sol).__name__}")
    if sol.jumps is None or np.ndim(sol.t_stop) != 0:
        raise ValueError(
            "start: a single run of the DAE with jumps is needed (tau=0, fold='jump'), not a batch or a run without a jump record"
        )
    t_stop = float(sol.t_stop)
    if not t_stop > 0:
        raise OrbitNotFound("start: the run ended at t = 0; there is nothing to find a repeat in")
    stats = cycle_statistics(sol, t_stop, transient=0.5 * t_stop)
    repeat = stats.repeat
    if (
        repeat is None
        and stats.too_few is not None
        and stats.too_few.events > 0
        and math.isfinite(stats.too_few.period)
    ):
        repeat = stats.too_few  # a near repeat: k and T to shoot from
    if repeat is None:
        if stats.slips == 0:
            why = "no stick → slip event in the run's second half (steady peeling, a stuck tape, or a run too short)"
        elif stats.too_few is not None:
            why = f"too few stick → slip events in the run's second half to look for a repeat ({stats.too_few}): run longer"
        else:
            why = (
                "no repeat in the run's second half (irregular): give start=(alpha, omega) and slips= to shoot near it"
            )
        raise OrbitNotFound(f"start: {why}")
    k = repeat.events if slips is None else slips
    period = repeat.period * k / repeat.events
    jumps = sol.jumps.as_numpy()
    slip_times = jumps["jump_t"][jumps["jump_up"]]
    t_slip = float(slip_times[-1])
    valid = np.asarray(sol.valid)
    ts = np.asarray(sol.ts)[valid]
    ys = np.asarray(sol.ys)[valid]
    s0 = np.array([np.interp(t_slip, ts, ys[:, 0]), np.interp(t_slip, ts, ys[:, 1])])
    return s0, k, period


def periodic_orbit(
    model: PeelingModel | None = None,
    V: ArrayLike = 1.1,
    start: Solution | ArrayLike | None = None,
    *,
    slips: int | None = None,
    period: float | None = None,
    rtol: float = DEFAULT_ORBIT_RTOL,
    atol: float | None = None,
    max_iterations: int = 20,
    transient: float = DEFAULT_TRANSIENT_RUN,
) -> PeriodicOrbit:
    """The periodic stick-slip orbit of the DAE (τ = 0) at V, by shooting through its jumps.

    The orbit is the fixed point of the return map after k stick → slip events on the
    section at φ's maximum (:mod:`peeljax.orbits`), found by Newton's method; its Floquet
    multipliers are the eigenvalues of the return map's Jacobian; its statistics are exact
    over one period. Every float of the result is differentiable (``jax.grad``, ``jax.jvp``)
    with respect to ``V`` and the model (φ's coefficients) by the implicit function theorem.

    Args:
        model: spool, tape and adhesion law (default: the paper's).
        V: pull velocity [m/s], > 0.
        start: where Newton starts:

            * None (default): a run of ``transient`` seconds from the paper's start; its
              repeat (:func:`peeljax.cycle_statistics` over its second half) gives k, T and
              the state at its last slip;
            * a :class:`~peeljax.Solution` of a τ = 0 run with jumps: the same from it;
            * (α, ω) on the section, or a state (α, ω, u, v) whose α and ω are taken: ``slips``
              is then needed.
        slips: k, the stick → slip events per period (default: the run's repeat). Twice the
            repeat's k shoots for the period-doubled orbit.
        period: a guess of T [s] (bounds each period's run at 3T; default: the repeat's, or
            5 s for a given state).
        rtol, atol: the tolerances of each period's run (default 1e-8 and 1e-3·rtol).
        max_iterations: Newton's iteration cap.
        transient: the length of the run that finds the repeat when ``start`` is None [s].

    Returns:
        A :class:`PeriodicOrbit`: ``status`` 0 (converged) or why not — Newton did not converge
        or diverged, or the run from the section did not come back through k slips (the
        number of events changed). Never NaN.

    Raises:
        OrbitNotFound: the run (given or made) shows no repeat: steady peeling, too short to
            tell, or irregular — said in the message.
        ValueError: a bad option, named with its allowed range (before anything compiles).
    """
    check_periodic_orbit(
        model, V, slips=slips, period=period, rtol=rtol, atol=atol, max_iterations=max_iterations, transient=transient
    )
    model = PeelingModel() if model is None else model
    slips = None if slips is None else int(slips)
    if not bool(phi_has_folds(model, jnp.asarray(V, float))):
        raise OrbitNotFound(
            f"phi has no fold at V = {float(V):g} m/s: the peeling is steady, there is no stick-slip orbit"
        )

    if start is None or isinstance(start, Solution):
        if start is None:
            start = simulate(model, V=V, tau=0, t_final=transient)
        s0, k, T = start_from_run(start, slips)
    else:
        state = np.asarray(start, float)
        if state.shape not in ((2,), (4,)) or not np.all(np.isfinite(state)):
            raise ValueError(f"start must be (alpha, omega) or (alpha, omega, u, v), finite, got {start!r}")
        if slips is None:
            raise ValueError("slips is needed with a start state: the number of stick → slip events per period (>= 1)")
        s0, k, T = state[:2], slips, period
    t_max = PERIODS_PER_RUN * (period if period is not None else T) if (period or T) else UNKNOWN_PERIOD_BOUND
    shooting = orbit_shooting(rtol=rtol, atol=atol, max_iterations=max_iterations)
    orbit = compiled_orbit(
        shooting,
        model,
        jnp.asarray(V, float),
        jnp.asarray(s0, float),
        jnp.asarray(k, jnp.int32),
        jnp.asarray(t_max, float),
    )
    # k from a repeat may be a multiple of the orbit's own (a repeat seen before it settled).
    return orbit if slips is not None else least_period(shooting, orbit)
