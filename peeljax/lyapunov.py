"""Lyapunov exponents of the peeling, through its jumps: Benettin's method on the run's own tangents.

The tangent map of a segment of the run, M_k = ∂x(t_k + Δ)/∂x(t_k), is the forward-mode
derivative of :func:`peeljax.simulate` with respect to its initial state. Through each jump it
carries the saltation: the jump time moves by the implicit function theorem on its fold event
and the state after the jump through the constraint (:mod:`peeljax.integrators.events`) — the
derivative the periodic orbits' monodromy is made of (:mod:`peeljax.orbits.shooting`). No
derivative is written by hand.

Benettin, Galgani, Giorgilli & Strelcyn (1980): k orthonormal tangents Q_0 are carried over each
segment and orthonormalized again, M_k Q_{k−1} = Q_k R_k (QR with diag R > 0), and

    λ_i = lim_{n→∞} 1/(nΔ) · Σ_{k=1..n} log R_k[i, i],   i = 1 … k,

the i-th Lyapunov exponent (1/s), of the DAE itself (τ = 0): the state is x = (α, ω, u), v being
algebraic (solved from the constraint (sac) at every state).

The tangents are those of the run's steps, which the error control does not look at. Where the
state stops moving (steady peeling) nothing holds the steps back: they grow to the stepper's
stability limit, and the tangent map no longer follows the flow's. At the steady state of
V = 0.2 m/s, τ = 0, over 0.5 s (13 steps), it differs from exp(A·0.5) (A = ∂ẋ/∂x there) by 14.5
in relative norm with Tsit5 in pseudo-time (the default), 10.2 with the α-method, 1.5 with
Kvaerno5, and Benettin's λ₁ read 1e-4 ± 2e-4 1/s where A's eigenvalues are −11.7 ± 28.7i and
−74.7. A steady attractor is therefore recognised (no jump and no motion over one segment) and
its exponents are the real parts of A's eigenvalues, exact by autodiff (``steady`` is True).
At τ > 0 the same happens wherever the homogenized ODE settles (the steady state of V = 1.1,
τ = 0.01: 2.6 with the α-method, 5·10³ with Tsit5, over 0.5 s), and v's fast relaxation keeps
the steps at that limit along the whole run: τ > 0 is not offered.

On a periodic orbit of period T with nontrivial Floquet multipliers μ₁, μ₂ (|μ₁| ≥ |μ₂|;
:func:`peeljax.periodic_orbit`): λ₁ = 0 (the flow's direction) and λ₂ = ln|μ₁| / T. A positive
λ₁ marks chaos; λ₁ = λ₂ = 0 a quasi-periodic (torus) attractor. Measured at V = 1.1 m/s
(``tests/test_lyapunov.py``): λ₂ = −2.68 and λ₃ = −21.33 1/s against ln|μ|/T = −2.670 and
−21.336, λ₁ = 0.014 ± 0.029, over 100 s; at 0.8 and 2 m/s the pair −2.975, −2.967 and −3.917,
−3.932 against −2.971 and −3.917.

Each segment checks its leading tangent against a run from a nearby state (10⁻⁶·|x| along it;
one more run per segment): at V = 1.1 m/s their growths agree to 0.13 % at worst over 60
segments (median 4·10⁻⁴ %); where they differ by more than 10×, the estimate stops and says so (``why``).
Jumps at tangential folds (ġ → 0 at the jump: the slip ends just as G turns) are where the run's
derivative is least accurate (:func:`peeljax.desingularized.tangential_fold`): at V = 4.9 and
5.3 m/s the check stops the estimate in its first segment (growths 16.7× and 179× apart).

:func:`lyapunov_spectra` runs many (V, start) lanes at once: each segment of every lane in one
compiled call per chunk of lanes (dealt over the devices, one lane after another on each, as
:func:`peeljax.periodic_orbits`), each lane stopping on its own (a stopped lane is not run again); :func:`lyapunov_exponents`
is its one-lane case, the same numbers lane by lane (``tests/test_lyapunov.py``).
"""

from __future__ import annotations

import math
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._validation import check_positive, check_y0
from .constrained import ConstrainedDAE
from ._devices import batch_mesh, deal, over_devices, put_lanes, to_host
from .model import PeelingModel
from .simulate import DEFAULT_MAX_JUMPS, simulate
from .solution import StopReason

__all__ = ["LyapunovExponents", "lyapunov_exponents", "lyapunov_spectra"]

_BATCHES = 10  # batch means for the standard error
_CHECK_STEP = 1e-6  # the nearby run's distance, relative to |x| (V = 1.1: the growths agree to 0.13 % at worst)
_CHECK_FACTOR = 10.0  # the leading tangent's growth and the nearby run's may differ by this factor
_CHUNK = 16  # lanes per compiled call of lyapunov_spectra (the last chunk padded)


class LyapunovExponents(eqx.Module):
    """The result of :func:`lyapunov_exponents`.

    Attributes:
        exponents: λ₁ ≥ λ₂ ≥ … (1/s), the mean growth rates over the segments run (on a
            steady attractor: the real parts of the linearization's eigenvalues).
        standard_error: each exponent's standard error, from the means of 10 batches of
            consecutive segments (NaN with fewer than 10 segments).
        history: (n, k) the estimates after each segment (their convergence).
        t: (n,) the time after the transient at each segment's end (s).
        V, segment, t_transient: what was run.
        status: :class:`~peeljax.StopReason` of the run (``COMPLETED``, or why a segment stopped).
        stopped_at: the time after the transient where the run stopped (NaN if it completed;
            negative: within the transient); the exponents are those of the segments before it.
        steady: the attractor is steady peeling (module docstring): no segment was run, the
            standard errors are 0 and the history is the one exact row.
        why: why the estimate stopped where no run did (``status`` ``COMPLETED``): the leading
            tangent left the growth of a run from a nearby state (module docstring).
    """

    exponents: Float[Array, " k"]
    standard_error: Float[Array, " k"]
    history: Float[Array, "n k"]
    t: Float[Array, " n"]
    V: float
    segment: float
    t_transient: float
    status: int
    stopped_at: float
    steady: bool = False
    why: str = ""

    @property
    def message(self) -> str:
        reason = StopReason(self.status)
        if self.steady:
            return "steady peeling: the real parts of the linearization's eigenvalues at the steady state"
        if reason == StopReason.COMPLETED and not self.why:
            return (
                f"completed: {self.t.size} segments of {self.segment:g} s after a transient of {self.t_transient:g} s"
            )
        if self.stopped_at < 0:
            return f"the transient stopped at t = {self.t_transient + self.stopped_at:g} s: {reason.message}"
        return f"stopped at t = {self.stopped_at:g} s after the transient: {self.why or reason.message}"

    def __str__(self) -> str:
        rows = ", ".join(
            f"λ{i + 1} = {lam:.4g} ± {se:.2g} 1/s"
            for i, (lam, se) in enumerate(zip(self.exponents, self.standard_error))
        )
        return f"Lyapunov exponents at V = {self.V:g} m/s (τ = 0): {rows} ({self.message})"


def _segment(model, V, y, Q, *, duration: float, rtol: float, atol: float, max_steps: int):
    """One lane's segment: the state after ``duration``, the tangents Q carried and orthonormalized
    again (Q_k), the run's status, log diag R_k and the check's |log(growth ratio)|."""
    d = Q.shape[0]

    def run(x):
        y0 = jnp.concatenate([x, y[d:]])  # at τ = 0 y's v starts the root search on its branch
        solution = simulate(
            model, V=V, tau=0, t_final=duration, y0=y0, ts=np.array([0.0, duration]), rtol=rtol, atol=atol,
            max_steps=max_steps, adjoint="forward",
        )  # fmt: skip
        return solution.ys[-1, :d], (solution.ys[-1], solution.status)

    x = y[:d]
    # k tangents along one run (its values unbatched: computed once)
    x_end, pushed, (y_end, status) = jax.vmap(
        lambda q: jax.jvp(run, (x,), (q,), has_aux=True), in_axes=1, out_axes=(None, 1, None)
    )(Q)
    # The leading tangent against a run from a nearby state (module docstring: a tangential fold)
    step = _CHECK_STEP * jnp.maximum(jnp.linalg.norm(x), 1.0)
    separated = jnp.linalg.norm(run(x + step * Q[:, 0])[0] - x_end) / step
    disagreement = jnp.abs(jnp.log(separated / jnp.linalg.norm(pushed[:, 0])))
    Q_new, R = jnp.linalg.qr(pushed)
    signs = jnp.where(jnp.diagonal(R) < 0, -1.0, 1.0)
    return y_end, Q_new * signs, status, jnp.log(jnp.abs(jnp.diagonal(R))), disagreement


def _plain_run(model, V, y, Q, *, duration: float, rtol: float, atol: float, max_steps: int, max_jumps: int):
    """One lane's run without tangents (``Q`` unused): its last state, status, stop time and jumps."""
    del Q
    run = simulate(
        model, V=V, tau=0, t_final=duration, y0=y, ts=np.array([0.0, duration]), rtol=rtol, atol=atol,
        max_steps=max_steps, max_jumps=max_jumps,
    )  # fmt: skip
    return run.ys[-1], run.status, run.t_stop, run.stats["jumps"]


@eqx.filter_jit
def _on_lanes(lane, model, V, y, Q, mesh, **settings):
    """``lane`` on every lane (V, y, Q): one after another on each device, the lanes dealt over
    the devices (as :func:`peeljax.periodic_orbits`: a vmapped loop would run every lane until
    the slowest is done)."""

    def lanes(model, V, y, Q):
        return jax.lax.map(lambda one: lane(model, *one, **settings), (V, y, Q))

    return over_devices(lanes, mesh, (model,), (V, y, Q))


class _Lanes:
    """The lanes' placement: padded to whole chunks of ``chunk`` lanes (one program for any number
    of lanes), each chunk dealt over the devices."""

    def __init__(self, n: int, devices, chunk: int = _CHUNK):
        self.n, self.devices = n, list(devices)
        self.chunk = -(-max(chunk, len(self.devices)) // len(self.devices)) * len(self.devices)
        self.padded = -(-n // self.chunk) * self.chunk
        self.mesh = batch_mesh(self.devices)

    def __call__(self, lane, model, V, y, Q, **settings):
        """``lane`` over the n lanes (host arrays in, host arrays out, lane order kept)."""
        fill = np.concatenate([np.arange(self.n), np.full(self.padded - self.n, self.n - 1)])
        blocks = []
        for first in range(0, self.padded, self.chunk):
            dealt = deal(np.arange(self.chunk), len(self.devices))  # position in the chunk, device-major
            order = fill[first : first + self.chunk][dealt]
            arrays = [V[order], y[order], Q[order]]
            arrays = put_lanes(arrays, self.devices) if self.mesh is not None else [jnp.asarray(a) for a in arrays]
            out = _on_lanes(lane, model, *arrays, mesh=self.mesh, **settings)
            back = np.empty(self.chunk, int)
            back[dealt] = np.arange(self.chunk)
            blocks.append((out, back))
        outs = [jax.tree_util.tree_map(lambda a, back=back: a[back], to_host(out)) for out, back in blocks]
        return jax.tree_util.tree_map(lambda *a: np.concatenate(a)[: self.n], *outs)


def _is_moving(y, y_end, rtol: float, atol: float) -> np.ndarray:
    """Per lane: x moved beyond the error control's tolerance over the run from y to y_end."""
    x0, x1 = y[:, :3], y_end[:, :3]
    return np.any(np.abs(x1 - x0) > 100 * (rtol * np.abs(x0) + atol), axis=1)


def _linearized_exponents(model, V, y) -> np.ndarray:
    """The real parts of the eigenvalues of A = ∂ẋ/∂x at y, v solved from the constraint
    (autodiff through the root: :class:`~peeljax.ConstrainedDAE`), largest first."""
    dae = ConstrainedDAE(model, V).with_folds()
    v = jnp.asarray(y)[3:]
    A = jax.jacfwd(lambda x: dae(jnp.concatenate([x, v]))[:3])(jnp.asarray(y)[:3])
    return np.sort(np.linalg.eigvals(np.asarray(A)).real)[::-1]


def lyapunov_exponents(
    model: PeelingModel | None = None,
    V: float = 1.1,
    *,
    n: int = 2,
    t_total: float = 100.0,
    segment: float = 0.5,
    t_transient: float = 10.0,
    y0: ArrayLike | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    seed: int = 0,
    progress: bool = False,
) -> LyapunovExponents:
    """The ``n`` largest Lyapunov exponents of the DAE (τ = 0) on the attractor reached from
    ``y0`` (module docstring); τ > 0 is not offered (module docstring: its tangents).

    Args:
        model: the peeling model (default: the paper's).
        V: the pull velocity (m/s).
        n: how many exponents, 1 … 3 (x = (α, ω, u)).
        t_total: time over which the growth rates are averaged, after the transient (s); the
            exponents converge like 1/t_total on a periodic orbit.
        segment: the time between two orthonormalizations (s); ``t_total`` is run as
            round(t_total / segment) segments of one compiled program.
        t_transient: time run first, from ``y0``, to reach the attractor (s); then a tenth of
            the segments (at least one) is run to turn the tangents towards the leading directions,
            their growth not counted (it holds the start's orientation, a bias ∝ 1/t_total).
        y0: the initial state (α, ω, u, v) (default: the paper's initial data); a run's last
            state (``run.ys[-1]``) continues that run.
        rtol, atol, max_steps: each segment's error control (:func:`peeljax.simulate`; the
            transient gets ``max_steps`` per segment's duration, and room for as many jumps per
            segment's duration as a segment has).
        seed: the random orthonormal tangents the method starts from.
        progress: a line on stderr every tenth of the segments.

    Returns:
        A :class:`LyapunovExponents`; a segment whose run stopped ends the estimate there
        (``status``, ``stopped_at``; the exponents are those of the segments before it, NaN
        where none was counted, the message says where and why).
    """
    if np.ndim(V) != 0:
        raise ValueError(f"V must be one pull velocity (a number in (0, inf)), got an array of shape {np.shape(V)}")
    check_positive("V", V)
    check_y0(y0)
    return lyapunov_spectra(
        model, [float(V)], None if y0 is None else np.asarray(y0, float)[None], n=n, t_total=t_total, segment=segment,
        t_transient=t_transient, rtol=rtol, atol=atol, max_steps=max_steps, seed=seed, progress=progress,
        devices=jax.devices()[:1], chunk=1,
    )[0]  # fmt: skip


def lyapunov_spectra(
    model: PeelingModel | None = None,
    V: ArrayLike = (1.1,),
    y0: ArrayLike | None = None,
    *,
    n: int = 2,
    t_total: float = 100.0,
    segment: float = 0.5,
    t_transient: float = 10.0,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    seed: int = 0,
    progress: bool = False,
    devices=None,
    chunk: int = _CHUNK,
) -> list[LyapunovExponents]:
    """:func:`lyapunov_exponents` at many (V, y0) at once: every segment of every lane in one
    compiled call per ``chunk`` lanes, the lanes dealt over ``devices`` (default: every device
    JAX sees; on a CPU one per core), each lane stopping on its own (the same tangents, checks
    and results as :func:`lyapunov_exponents` lane by lane).

    Args:
        V: the lanes' pull velocities [m/s], shape (m,).
        y0: (m, 4) initial states (default: the paper's initial data at each V).
        chunk: lanes per compiled call (the last chunk padded; one program for any m).
        n, t_total, segment, t_transient, rtol, atol, max_steps, seed, progress: as
            :func:`lyapunov_exponents`, the same for every lane.

    Returns:
        One :class:`LyapunovExponents` per lane, in lane order.
    """
    model = PeelingModel() if model is None else model
    V = np.atleast_1d(np.asarray(V, float))
    if V.ndim != 1 or V.size == 0:
        raise ValueError(f"V must be a 1-d array of pull velocities, got shape {V.shape}")
    check_positive("V", V)
    if y0 is not None:
        y0 = np.asarray(y0, float)
        check_y0(y0)
        if y0.shape != (V.size, 4):
            raise ValueError(f"y0 must be one state (alpha, omega, u, v) per V, shape ({V.size}, 4), got {y0.shape}")
    dimension = 3
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= dimension:
        raise ValueError(f"n must be an integer in [1, {dimension}] (x = (alpha, omega, u)), got {n!r}")
    for name, value in (("t_total", t_total), ("segment", segment), ("rtol", rtol), ("atol", atol)):
        check_positive(name, value)
    if not (isinstance(t_transient, (int, float)) and math.isfinite(t_transient) and t_transient >= 0):
        raise ValueError(f"t_transient must be a number in [0, inf), got {t_transient!r}")
    if segment > t_total:
        raise ValueError(f"segment must lie in (0, t_total] = (0, {t_total:g}], got {segment:g}")
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be an integer >= 1, got {chunk!r}")
    m, count = V.size, round(t_total / segment)
    devices = jax.devices() if devices is None else devices

    def lanes(which, lane, model, V, y, Q, **settings):  # the lanes ``which`` only (stopped ones are not run)
        return _Lanes(which.size, devices, chunk)(lane, model, V[which], y[which], Q[which], **settings)

    y = np.stack([np.asarray(model.initial_state(v)) for v in V]) if y0 is None else y0.copy()
    Q0, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(dimension, n)))
    Q = np.repeat(Q0[None], m, axis=0)
    settings = {"rtol": float(rtol), "atol": float(atol)}
    common = {"V": V, "segment": float(segment), "t_transient": float(t_transient)}

    def stopped(i: int, status: int, at: float) -> LyapunovExponents:  # the transient stopped
        nan = jnp.full(n, jnp.nan)
        return LyapunovExponents(
            exponents=nan, standard_error=nan, history=jnp.zeros((0, n)), t=jnp.zeros(0), V=float(V[i]),
            segment=float(segment), t_transient=float(t_transient), status=status, stopped_at=at,
        )  # fmt: skip

    results: list[LyapunovExponents | None] = [None] * m
    if t_transient > 0:  # every lane
        per = math.ceil(t_transient / segment)
        y_end, status, t_stop, _ = lanes(
            np.arange(m), _plain_run, model, V, y, Q, duration=float(t_transient), max_steps=int(max_steps) * per,
            max_jumps=DEFAULT_MAX_JUMPS * per, **settings,
        )  # fmt: skip
        for i in np.flatnonzero(status != StopReason.COMPLETED):
            results[i] = stopped(i, int(status[i]), float(t_stop[i]) - t_transient)
        y = np.where((status == StopReason.COMPLETED)[:, None], y_end, y)
    started = np.asarray([r is None for r in results])
    steady = np.zeros(m, bool)
    if started.any():
        y_end, status, _, jumps = lanes(
            np.flatnonzero(started), _plain_run, model, V, y, Q, duration=float(segment), max_steps=int(max_steps),
            max_jumps=DEFAULT_MAX_JUMPS, **settings,
        )  # fmt: skip
        steady[started] = (status == StopReason.COMPLETED) & (jumps == 0) & ~_is_moving(y[started], y_end, rtol, atol)
    for i in np.flatnonzero(steady):
        exponents = _linearized_exponents(model, V[i], y[i])[:n]
        results[i] = LyapunovExponents(
            exponents=jnp.asarray(exponents), standard_error=jnp.zeros(n), history=jnp.asarray(exponents)[None],
            t=jnp.zeros(1), V=float(V[i]), segment=float(segment), t_transient=float(t_transient),
            status=int(StopReason.COMPLETED), stopped_at=math.nan, steady=True,
        )  # fmt: skip
    running = np.asarray([r is None for r in results])
    align = max(count // 10, 1)  # segments that turn the tangents towards the leading directions, not counted
    growth = np.zeros((m, count, n))
    done, status_of, why = np.full(m, count), np.full(m, int(StopReason.COMPLETED)), [""] * m
    for k in range(-align, count):
        which = np.flatnonzero(running)
        if not which.size:
            break
        y_next, Q_next, run_status, log_r, disagreement = lanes(
            which, _segment, model, V, y, Q, duration=float(segment), max_steps=int(max_steps), **settings
        )  # fmt: skip
        counted = np.ones(which.size, bool)
        for lane, i in enumerate(which):
            if (problem := _trouble(run_status[lane], log_r[lane], disagreement[lane])) is not None:
                (status_of[i], why[i]), done[i] = problem, max(k, 0)
                running[i], counted[lane] = False, False
        y[which[counted]], Q[which[counted]] = y_next[counted], Q_next[counted]
        if k >= 0:
            growth[which[counted], k] = log_r[counted] / segment
        if progress and k >= 0 and (k + 1) % align == 0:
            print(
                f"lyapunov_exponents: {k + 1}/{count} segments, {running.sum()} of {m} lanes running", file=sys.stderr
            )
    for i in range(m):
        if results[i] is None:
            results[i] = _estimate(growth[i, : done[i]], count, n, status_of[i], why[i], **common | {"V": V[i]})
    return results


def _trouble(run_status, log_r, disagreement) -> tuple[int, str] | None:
    """(status, why) where a segment cannot be counted, else None."""
    if int(run_status) != StopReason.COMPLETED:
        return int(run_status), ""
    if not np.all(np.isfinite(np.asarray(log_r))):
        return int(StopReason.NONFINITE), "the tangents overflowed"
    if not float(disagreement) <= math.log(_CHECK_FACTOR):
        return int(StopReason.COMPLETED), (
            f"the leading tangent's growth over the segment and that of a run from a nearby state differ by a "
            f"factor {math.exp(min(float(disagreement), 700.0)):.3g} (> {_CHECK_FACTOR:g}): the run's derivative is "
            f"not the flow's there (a tangential fold or a grazing: peeljax.lyapunov's docstring)"
        )
    return None


def _estimate(growth, count, n, status, why, *, V, segment, t_transient) -> LyapunovExponents:
    """The exponents, their batch-means standard errors and history from the segments' growths."""
    done = growth.shape[0]
    steps = np.arange(1, done + 1)[:, None]
    history = np.cumsum(growth, axis=0) / steps if done else np.zeros((0, n))
    exponents = history[-1] if done else np.full(n, np.nan)
    if done >= _BATCHES:
        batches = np.array([b.mean(axis=0) for b in np.array_split(growth, _BATCHES)])
        standard_error = batches.std(axis=0, ddof=1) / math.sqrt(_BATCHES)
    else:
        standard_error = np.full(n, np.nan)
    return LyapunovExponents(
        exponents=jnp.asarray(exponents), standard_error=jnp.asarray(standard_error), history=jnp.asarray(history),
        t=jnp.asarray(segment * np.arange(1, done + 1)), V=float(V), segment=float(segment),
        t_transient=float(t_transient), status=int(status), stopped_at=math.nan if done == count else segment * done,
        why=why,
    )  # fmt: skip
