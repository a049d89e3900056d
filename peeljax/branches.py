"""φ's stable branches and the jump at a fold: v⁻ → v⁺ at fixed x (structure layer).

For the paper's φ, φ(·, V) rises to a maximum at v̂ (the fold where the tape slips), falls to
a minimum at v̌ (where it re-sticks) and rises again; between V ≈ 5 and 5.5 m/s the two merge
and vanish. The constraint G(x) = φ(v, V), G = (1 + l·sinα/L)·F, then has up to three roots
in v; the two rising ones are stable:

* the **stick branch** v ∈ [0, v̂] (index 0), on which the tape sticks;
* the **slip branch** v ∈ [v̌, v_top] (index 1), on which it slips.

When G(x) reaches the end of the current branch (φ(v̂, V) while sticking, φ(v̌, V) while
slipping), v jumps at constant x to the root of G(x) = φ(v, V) on the other branch: the
paper's "near jump in the peeling velocity with the shear force … remaining almost
unchanged" (after its theorem ``bif``), the DAE algorithm of De, Maybhate & Ananthakrishna
(2004) and the low-mass limit of the inertial model. Below φ(0⁺, V) the stick branch has no
root: the tape is fully stuck, v = 0, until G rises back to φ(0⁺, V).

Every derivative is autodiff's: a branch root v*(x, θ) is found without derivatives and
made differentiable by the implicit function theorem, dv* = (F̃·dx − ∂φ/∂θ·dθ)/(∂φ/∂v)
(the correction v* − (r − r̄)/∂φ/∂v, r = φ − G and r̄ its value held constant: zero in value,
exact in first derivatives).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .model import PeelingModel
from .structure import PHI_SEARCH_RANGE, phi_max_and_min

__all__ = [
    "SLIP",
    "STICK",
    "Folds",
    "branch_of",
    "branch_velocity",
    "fold_distance",
    "jump_velocity",
    "phi_folds",
]

STICK, SLIP = 0, 1
_LOW_V = 1e-100  # × max(V, 1) m/s: the bottom of the stick branch (v^p of φ is ~1e-15 there: φ(0⁺, V))
_ROOT_ITERATIONS = 80
_ROOT_TOLERANCE = 1e-14  # in log v
_PREDICTED_ERROR = 1e-16  # in log v: K·Δ², the error left by a Newton update Δ


class Folds(eqx.Module):
    """The folds of φ(·, V) and the ends of its two stable branches (all traced).

    Attributes:
        v_max, phi_max: φ's maximum v̂ and φ(v̂, V), the end of the stick branch (NaN: no fold).
        v_min, phi_min: φ's minimum v̌ and φ(v̌, V), the start of the slip branch (NaN: no fold).
        phi_zero: φ(0⁺, V): below it the tape is fully stuck.
        v_low, v_top: the bottom of the stick branch and the top of the slip branch searched
            for roots (1e-100 and 1e2 × max(V, 1) m/s).
    """

    v_max: Float[Array, ""]
    phi_max: Float[Array, ""]
    v_min: Float[Array, ""]
    phi_min: Float[Array, ""]
    phi_zero: Float[Array, ""]
    v_low: Float[Array, ""]
    v_top: Float[Array, ""]

    @property
    def exist(self) -> Bool[Array, ""]:
        """True where φ(·, V) has both folds (stick-slip is possible)."""
        return jnp.isfinite(self.v_max) & jnp.isfinite(self.v_min)

    @classmethod
    def not_searched(cls) -> Folds:
        """A placeholder of NaNs for folds not searched yet (:attr:`searched` False)."""
        nan = jnp.full((), jnp.nan)
        return cls(nan, nan, nan, nan, nan, nan, nan)

    @property
    def searched(self) -> Bool[Array, ""]:
        """False for :meth:`not_searched`'s placeholder (a search always gives a finite ``v_top``)."""
        return ~jnp.isnan(self.v_top)


def phi_folds(model: PeelingModel, V: ArrayLike) -> Folds:
    """φ's maximum and minimum in v (:func:`peeljax.structure.phi_max_and_min`) and its branch ends."""
    V = jnp.asarray(V, float)
    v_max, v_min = phi_max_and_min(model, V)
    v_min = jnp.where(jnp.isfinite(v_max), v_min, jnp.nan)
    scale = jnp.maximum(V, 1.0)
    v_low = _LOW_V * scale

    def phi_at(v):  # NaN where there is no fold (φ itself is evaluated at a safe point there)
        return jnp.where(jnp.isfinite(v), model.phi(jnp.where(jnp.isfinite(v), v, 1.0), V), jnp.nan)

    return Folds(
        v_max=v_max,
        phi_max=phi_at(v_max),
        v_min=v_min,
        phi_min=phi_at(v_min),
        phi_zero=model.phi(v_low, V),
        v_low=v_low,
        v_top=PHI_SEARCH_RANGE[1] * scale,
    )


def branch_of(v: ArrayLike, folds: Folds) -> Int[Array, ""]:
    """The branch v lies on: ``SLIP`` above the geometric mean of v̂ and v̌, else ``STICK``
    (always ``STICK`` where φ has no fold)."""
    split = jnp.sqrt(folds.v_max * folds.v_min)
    return jnp.where(folds.exist & (v > split), SLIP, STICK).astype(jnp.int32)


def _bounds(folds: Folds, branch):
    """(v_lo, v_hi) of a branch; the whole search range where φ has no fold."""
    stick_hi = jnp.where(folds.exist, folds.v_max, folds.v_top)
    slip_lo = jnp.where(folds.exist, folds.v_min, folds.v_low)
    slip = branch == SLIP
    return jnp.where(slip, slip_lo, folds.v_low), jnp.where(slip, folds.v_top, stick_hi)


def _stop_gradient(tree):
    """``lax.stop_gradient`` on a pytree's inexact arrays (callables and static leaves untouched)."""
    return jax.tree_util.tree_map(lambda a: jax.lax.stop_gradient(a) if eqx.is_inexact_array(a) else a, tree)


@jax.custom_jvp
def _tangent_only(r):
    """0 in value, ``r``'s tangent in derivative: ``r − stop_gradient(r)`` without computing r
    when no derivative is taken (r's primal is then dead code that XLA drops)."""
    return jnp.zeros_like(r)


@_tangent_only.defjvp
def _tangent_only_jvp(primals, tangents):
    return jnp.zeros_like(primals[0]), tangents[0]


def _root_on(model: PeelingModel, V, target, lo, hi, guess, clamped=False, *, count: bool = False):
    """log v* with φ(v*, V) = target on [lo, hi] where φ increases, clamped to the ends.

    Safeguarded Newton in log v (a bisection step wherever Newton leaves the bracket or the
    slope is not positive), from ``guess``; no derivatives flow (see :func:`branch_velocity`).
    φ and ∂φ/∂(log v) come from one forward-mode pass (``jax.jvp`` of w ↦ φ(eʷ, V)).

    It stops (i) once a Newton update is below ``_ROOT_TOLERANCE`` (that update is taken: it
    no longer moves w beyond round-off, and a zero residual is a root), (ii) once the update
    predicted next, K·Δ² with K ≈ |Δ|/Δ_prev² from the last two Newton updates, is below
    ``_PREDICTED_ERROR`` (quadratic convergence: the update Δ just taken leaves an error below
    round-off, so the confirming iteration is skipped), (iii) once an update (bisection
    included) moves w by at most ``_ROOT_TOLERANCE``, or (iv) after ``_ROOT_ITERATIONS``.
    ``clamped`` (G outside [φ(lo), φ(hi)]: the caller returns the branch's end) skips the
    iteration altogether. ``count=True`` also returns the number of φ evaluations.
    """
    log_lo, log_hi = jnp.log(lo), jnp.log(hi)

    def residual(w):
        return model.phi(jnp.exp(w), V) - target

    def body(carry):
        w, a, b, i, _, step_prev = carry
        r, slope = jax.jvp(residual, (w,), (jnp.ones_like(w),))
        a = jnp.where(r < 0, w, a)  # φ increases on the branch: r < 0 ⇒ the root is above w
        b = jnp.where(r < 0, b, w)
        positive = slope > 0
        step = -r / jnp.where(positive, slope, 1.0)
        newton = w + step
        converged = positive & (jnp.abs(step) <= _ROOT_TOLERANCE)  # round-off: take it, clipped
        inside = positive & (newton > a) & (newton < b)
        w_new = jnp.where(converged, jnp.clip(newton, a, b), jnp.where(inside, newton, 0.5 * (a + b)))
        size = jnp.abs(step)
        predicted = size * size * size <= _PREDICTED_ERROR * step_prev * step_prev  # K·Δ² small
        done = converged | (inside & predicted) | (jnp.abs(w_new - w) <= _ROOT_TOLERANCE)
        # a bisection step leaves no Newton update to extrapolate from (0: no prediction)
        return w_new, a, b, i + 1, done, jnp.where(inside, size, 0.0)

    def more(carry):
        return (carry[3] < _ROOT_ITERATIONS) & ~carry[4]

    w0 = jnp.clip(jnp.log(jnp.clip(guess, lo, hi)), log_lo, log_hi)
    init = (w0, log_lo, log_hi, jnp.asarray(0), jnp.asarray(clamped), jnp.zeros_like(w0))
    w, _, _, i, *_ = jax.lax.while_loop(more, body, init)
    return (w, i) if count else w


def branch_velocity(
    model: PeelingModel,
    x: Float[Array, "3"],
    V: ArrayLike,
    branch: ArrayLike,
    folds: Folds,
    guess: ArrayLike = 1.0,
    skip: ArrayLike = False,
) -> Float[Array, ""]:
    """v(x) on a branch: the root of G(x) = φ(v, V) there, clamped at the branch's ends.

    ``skip``: where True the root search is skipped (the caller discards v: under ``vmap``,
    where both sides of a ``lax.cond`` run, a rare branch would otherwise search every step).

    Past the branch's fold (G above φ(v̂, V) on the stick branch, below φ(v̌, V) on the slip
    branch) v stays at the fold velocity, a continuous extension that lets a step cross the
    fold before the fold event is located inside it (:mod:`peeljax.integrators.events`). Below
    φ(0⁺, V) on the stick branch v = 0 (fully stuck).

    Differentiable in x, V and the model: the root is found without derivatives and the
    correction v* − (r − r̄)/∂φ/∂v (r = φ(v*, V) − G(x), r̄ and ∂φ/∂v held constant) carries the
    implicit function theorem's first derivatives; past the clamped ends the derivative is zero.
    """
    lo, hi = _bounds(folds, branch)
    target = model.shear_force(x)
    sg = _stop_gradient
    # A root exists iff φ(lo) < G < φ(hi) (φ rises on the branch); else v is clamped at an end
    # and the root search is skipped.
    past_end = sg(target >= model.phi(hi, V))
    below_start = sg(target <= model.phi(lo, V))
    w = _root_on(sg(model), sg(V), sg(target), sg(lo), sg(hi), sg(guess), past_end | below_start | skip)
    v_star = jnp.exp(w)
    slope = jax.lax.stop_gradient(jax.grad(lambda v: model.phi(v, V))(v_star))
    interior = ~past_end & ~below_start & (slope > 0)
    # Zero in value (round-off in the residual, divided by a slope that vanishes at a fold, must
    # not move v), −dr/(∂φ/∂v) in derivative: the implicit function theorem. ``_tangent_only``
    # is r − r̄ without evaluating r when no derivative is taken.
    residual = model.phi(v_star, V) - target
    correction = jnp.where(interior, _tangent_only(residual) / jnp.where(interior, slope, 1.0), 0.0)
    v = jnp.where(past_end, hi, jnp.where(below_start, lo, v_star - correction))
    stuck = (branch == STICK) & (target < folds.phi_zero)
    return jnp.where(stuck, 0.0, v)


def jump_velocity(
    model: PeelingModel, x: Float[Array, "3"], V: ArrayLike, branch: ArrayLike, folds: Folds
) -> Float[Array, ""]:
    """v⁺: the root of G(x) = φ(v, V) on the branch other than ``branch`` (the jump at a fold).

    From the stick branch the tape slips (v⁺ on [v̌, v_top]); from the slip branch it re-sticks
    (v⁺ on [0, v̂], and v⁺ = 0 when G(x) < φ(0⁺, V): it lands fully stuck).
    """
    other = 1 - branch
    lo, hi = _bounds(folds, other)
    return branch_velocity(model, x, V, other, folds, guess=jnp.sqrt(lo * hi))


def fold_distance(model: PeelingModel, x: Float[Array, "3"], V: ArrayLike, branch: ArrayLike, folds: Folds) -> Array:
    """How far past the current branch's fold G(x) is, in N: G − φ(v̂, V) on the stick branch,
    φ(v̌, V) − G on the slip branch; negative before the fold, zero at it (the fold event),
    −inf where φ has no fold. Smooth in x (G is), unlike ∂φ/∂v along the solution, whose
    zero is approached like an inverse square root."""
    G = model.shear_force(x)
    distance = jnp.where(branch == SLIP, folds.phi_min - G, G - folds.phi_max)
    return jnp.where(folds.exist, distance, -jnp.inf)
