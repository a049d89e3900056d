"""Lemmas 1–3: Jacobians by autodiff, the Schur complement J_t, its Neumann series, the local index."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import peeljax as pj
from peeljax import PeelingModel
from peeljax.model import PAPER_ALPHA0
from peeljax.structure import MAX_INDEX


def traced(fn):
    """eqx.filter_jit(fn) with every float (Python or NumPy scalar) passed as a strongly typed
    float64 array: traced, so new values never recompile (ints stay static)."""
    jitted = eqx.filter_jit(fn)
    return lambda *args: jitted(
        *(jnp.asarray(a, dtype=float) if isinstance(a, (float, np.floating)) else a for a in args)
    )


# Compiled once per model structure (geometry, truncation); states, V and τ are traced.
jacobians = traced(pj.jacobians)
schur = traced(pj.schur_complement)
truncated = pj.truncated_schur_complement  # eager: a jit would compile once per m (static)
consistent = traced(lambda m, V, a, w, v: m.consistent_state(V, a, w, v))
local_index = jax.jit(pj.local_index)
is_fast_scale = jax.jit(pj.is_fast_scale)


@traced
def pieces(m, x, v, V):
    """f, the shear force and φ in one compiled call (for the finite differences)."""
    return m.f(x, v, V), m.shear_force(x), m.phi(v, V)


@traced
def psi_variants(m, V, tau, y):
    """ψ for truncation None, 0 and 2, compiled together."""
    return (
        pj.HomogenizedODE(m, V, tau).evaluate(y),
        pj.HomogenizedODE(m, V, tau, truncation=0)(y),
        pj.HomogenizedODE(m, V, tau, truncation=2)(y),
    )


V_PAPER = 1.1
# Near the paper's steady state for V = 1.1 (α = 0, ω = v/R, v = V): ∂f/∂x has eigenvalues
# 0, ±i·√(R·F/I) = ±56.3i there, so ρ = 56.3 and 1/ρ = 0.01776.
Y_STEADY = np.array([0.0, 11.0, 0.317, 1.1])


def as_np(jac):
    return {name: np.asarray(getattr(jac, name)) for name in ("f", "f_x", "f_v", "F_tilde", "phi_v")}


def states(geometry):
    """Consistent states and a few arbitrary (inconsistent) ones."""
    m = PeelingModel(geometry=geometry)
    rng = np.random.default_rng(7)
    out = []
    for _ in range(3):
        a, w, v, V = rng.uniform(-0.6, 0.6), rng.uniform(0.0, 20.0), rng.uniform(0.1, 6.0), rng.choice([1.1, 2.0, 4.0])
        y = np.asarray(consistent(m, V, a, w, v))
        out.append((y[:3], y[3], V))
    out.append((Y_STEADY[:3], Y_STEADY[3], V_PAPER))
    out.append((np.array([-0.3, 2.0, 0.15]), 2.5, 4.0))
    return m, out


# ---------------------------------------------------------------------- Jacobians vs finite differences
def fd_x(m, x, v, V, out):
    """Central differences of pieces(…)[out] with respect to x (steps 1e-6·max(|x_j|, 1e-2))."""
    h = 1e-6 * np.maximum(np.abs(x), 1e-2)
    cols = []
    for j in range(3):
        e = np.zeros(3)
        e[j] = h[j]
        plus, minus = pieces(m, jnp.asarray(x + e), v, V)[out], pieces(m, jnp.asarray(x - e), v, V)[out]
        cols.append((np.asarray(plus) - np.asarray(minus)) / (2 * h[j]))
    return np.stack(cols, axis=-1)


def fd_v(m, x, v, V, out):
    """Central difference of pieces(…)[out] with respect to v (step 1e-6·v)."""
    h = 1e-6 * v
    plus, minus = pieces(m, jnp.asarray(x), v + h, V)[out], pieces(m, jnp.asarray(x), v - h, V)[out]
    return (np.asarray(plus) - np.asarray(minus)) / (2 * h)


def assert_close_rowwise(ad, fd, rtol):
    """|ad − fd| ≤ rtol·‖row of ad‖ entrywise (rows mix terms of very different size);
    a row that autodiff finds exactly zero is compared against the norm of the whole matrix."""
    ad, fd = np.atleast_2d(ad), np.atleast_2d(fd)
    scale = np.linalg.norm(ad, axis=-1, keepdims=True)
    scale = np.where(scale > 0, scale, max(np.linalg.norm(ad), 1.0))
    err = np.abs(ad - fd) / scale
    assert np.all(err <= rtol), err.max()
    return err.max()


@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_jacobians_match_central_differences(geometry):
    m, pts = states(geometry)
    worst = 0.0
    for x, v, V in pts:
        jac = as_np(jacobians(m, jnp.asarray(x), v, V))
        np.testing.assert_allclose(jac["f"], np.asarray(pieces(m, jnp.asarray(x), v, V)[0]), rtol=1e-15)
        fx_fd, Ft_fd = fd_x(m, x, v, V, 0), fd_x(m, x, v, V, 1)
        fv_fd, phiv_fd = fd_v(m, x, v, V, 0), fd_v(m, x, v, V, 2)
        worst = max(
            worst,
            assert_close_rowwise(jac["f_x"], fx_fd, 1e-6),
            assert_close_rowwise(jac["f_v"][:, None], fv_fd[:, None], 1e-6),
            assert_close_rowwise(jac["F_tilde"], Ft_fd, 1e-6),
            assert_close_rowwise(jac["phi_v"], phiv_fd, 1e-6),
        )
    assert worst < 1e-6


# ---------------------------------------------------------------------- Schur complement (Lemma 1)
def schur_numpy(jac, tau):
    w = np.linalg.solve(np.eye(3) - tau * jac["f_x"], jac["f_v"])
    return -jac["phi_v"] + tau * jac["F_tilde"] @ w


@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_schur_complement_equals_numpy_solve(geometry):
    m, pts = states(geometry)
    for x, v, V in pts:
        jac = jacobians(m, jnp.asarray(x), v, V)
        for tau in (1e-6, 1e-4, 1e-3, 1e-2, 0.1, 1.0):
            assert float(schur(jac, tau)) == pytest.approx(schur_numpy(as_np(jac), tau), rel=1e-12)
        # τ → 0: J_t → −φ_v, linearly in τ with slope F̃·f_v
        j = as_np(jac)
        tau = 1e-9
        assert (float(schur(jac, tau)) + j["phi_v"]) / tau == pytest.approx(j["F_tilde"] @ j["f_v"], rel=1e-5)


# ---------------------------------------------------------------------- Neumann series (Lemma 2, eq. hvex)
def steady_jacobians():
    m = PeelingModel()
    return jacobians(m, jnp.asarray(Y_STEADY[:3]), jnp.asarray(Y_STEADY[3]), V_PAPER)


def test_neumann_radius_at_the_steady_state():
    jac = steady_jacobians()
    rho = np.max(np.abs(np.linalg.eigvals(np.asarray(jac.f_x))))
    assert rho == pytest.approx(np.sqrt(0.1 * 1000.0 * 0.317 / 1e-2), rel=1e-12)  # √(R·(k/l)·u/I) = 56.30
    assert float(pj.neumann_radius(jac)) == pytest.approx(1.0 / rho, rel=1e-12)
    assert float(pj.neumann_radius(jac)) == pytest.approx(0.017761, rel=1e-4)


def test_neumann_terms_are_the_series_terms():
    jac = steady_jacobians()
    j = as_np(jac)
    tau = 1e-3
    terms = np.asarray(pj.neumann_terms(jac, tau, 6))
    expected = [tau**p * j["F_tilde"] @ np.linalg.matrix_power(j["f_x"], p - 1) @ j["f_v"] for p in range(1, 7)]
    np.testing.assert_allclose(terms, expected, rtol=1e-13, atol=1e-30)
    # here (α = 0, ω = v/R) the even terms vanish: F̃·∂f/∂x·∂f/∂v = 0
    assert terms[1] == 0.0 and terms[3] == 0.0
    assert terms[0] == pytest.approx(-tau * (0.317 * 1000.0 / 0.1 + 1000.0), rel=1e-12)  # −τ·4170


def test_truncated_series_converges_geometrically_below_the_radius():
    """τ = 1e-3, τ·ρ = 0.0563 < 1: the error |J̃_m − J_t| falls by (τρ)² = 3.17e-3 every two terms.

    (At this state the even terms are zero, so the error is flat over odd→even steps; the
    per-term rate is (τρ²)^{1/2} = τρ.)
    """
    jac = steady_jacobians()
    tau = 1e-3
    rho = 1.0 / float(pj.neumann_radius(jac))
    J = float(schur(jac, tau))
    errors = np.array([abs(float(truncated(jac, tau, m)) - J) for m in range(10)])
    assert np.all(np.diff(errors) <= 0)
    ratios = errors[3:9] / errors[1:7]  # m → m + 2 for m = 1…6, all above round-off
    np.testing.assert_allclose(ratios, (tau * rho) ** 2, rtol=1e-3)
    assert errors[9] < 1e-11 * abs(J)
    per_term = (errors[8] / errors[2]) ** (1 / 6)
    assert per_term == pytest.approx(tau * rho, rel=1e-3)


def test_truncated_series_diverges_above_the_radius():
    """τ = 0.1 > 1/ρ = 0.0178 (τρ = 5.63): the error grows by (τρ)² = 31.7 every two terms."""
    jac = steady_jacobians()
    tau = 0.1
    assert tau > float(pj.neumann_radius(jac))
    rho = 1.0 / float(pj.neumann_radius(jac))
    J = float(schur(jac, tau))
    assert np.isfinite(J) and J == pytest.approx(schur_numpy(as_np(jac), tau), rel=1e-12)
    errors = np.array([abs(float(truncated(jac, tau, m)) - J) for m in range(1, 16)])
    ratios = errors[2:] / errors[:-2]
    np.testing.assert_allclose(ratios, (tau * rho) ** 2, rtol=1e-9)
    assert errors[-1] > 1e9 * abs(J)


def test_truncation_zero_is_minus_phi_v():
    m, pts = states("full")
    for x, v, V in pts[:2]:
        jac = jacobians(m, jnp.asarray(x), v, V)
        assert float(truncated(jac, 1e-3, 0)) == -float(jac.phi_v)
        assert float(truncated(jac, 1e-3, 1)) == pytest.approx(
            -float(jac.phi_v) + 1e-3 * float(jnp.dot(jac.F_tilde, jac.f_v)), rel=1e-14
        )


# ---------------------------------------------------------------------- the homogenized ODE (eq. hv)
@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_homogenized_psi(geometry):
    m, pts = states(geometry)
    tau = 1e-3
    for x, v, V in pts[:2]:
        y = jnp.asarray(np.append(x, v))
        j = as_np(jacobians(m, jnp.asarray(x), v, V))
        drive = j["F_tilde"] @ j["f"]
        ev, psi0, psi2 = psi_variants(m, V, tau, y)
        np.testing.assert_allclose(np.asarray(ev.psi[:3]), j["f"], rtol=1e-14)
        J = schur_numpy(j, tau)
        assert float(ev.J) == pytest.approx(J, rel=1e-12)
        assert float(ev.drive) == pytest.approx(drive, rel=1e-12)
        assert float(ev.psi[3]) == pytest.approx(-drive / J, rel=1e-12)
        # truncation = 0: the index-1 ODE v̇ = F̃·f/φ_v
        assert float(psi0[3]) == pytest.approx(drive / j["phi_v"], rel=1e-12)
        # truncation = m: −F̃f/J̃_m
        J2 = -j["phi_v"] + tau * j["F_tilde"] @ j["f_v"] + tau**2 * j["F_tilde"] @ j["f_x"] @ j["f_v"]
        assert float(psi2[3]) == pytest.approx(-drive / J2, rel=1e-12)


# ---------------------------------------------------------------------- local index (Lemma 2)
@pytest.mark.parametrize(
    "J,tau,expected",
    [
        (1e-3**2.5, 1e-3, 4),  # ⌈2.5⌉ + 1
        (-(1e-2**2.5), 1e-2, 4),  # |J|
        (1e-3**0.5, 1e-3, 2),  # ⌈0.5⌉ + 1
        (1e-4**1.2, 1e-4, 3),
        (0.9, 1e-3, 2),  # |J| < 1, τ < 1: at least 2
        (0.999999, 0.5, 2),
        (1e-7, 0.5, 25),  # log_0.5(1e-7) = 23.25
        (1.0, 1e-3, 1),  # |J| ≥ 1: index 1
        (-1.0, 1e-3, 1),
        (250.0, 1e-3, 1),
        (0.5, 1.0, 1),  # τ ≥ 1: index 1
        (0.5, 3.0, 1),
        (0.0, 3.0, 1),
        (0.0, 1e-3, MAX_INDEX),  # J = 0: the cap
        (1e-300, 0.9, MAX_INDEX),  # log_0.9(1e-300) = 6556: capped
    ],
)
def test_local_index_hand_computed(J, tau, expected):
    assert int(local_index(J, tau)) == expected
    assert bool(is_fast_scale(J, tau)) == (expected > 1)


def test_local_index_regimes_on_a_grid():
    J = np.concatenate([-np.logspace(-20, 3, 47), [0.0], np.logspace(-20, 3, 47)])
    taus = np.array([1e-8, 1e-5, 1e-3, 0.1, 0.5, 0.99, 1.0, 1.5, 10.0])
    index = np.asarray(local_index(J[:, None], taus[None, :]))
    fast = np.asarray(is_fast_scale(J[:, None], taus[None, :]))
    assert index.shape == (J.size, taus.size) and index.dtype == np.int32
    A, T = np.abs(J)[:, None], taus[None, :]
    regular = (A > 0) & (A < 1) & (T < 1)
    assert np.all(index[(A >= 1) | (T >= 1)] == 1)
    assert np.all(index[(A < 1) & (T < 1)] >= 2)
    assert np.all(index[(A == 0) & (T < 1)] == MAX_INDEX)
    assert np.all((index >= 1) & (index <= MAX_INDEX))
    np.testing.assert_array_equal(fast, index > 1)
    np.testing.assert_array_equal(fast, (A < 1) & (T < 1))
    # the formula on the regular set, away from exact integers of log_τ|J|
    with np.errstate(divide="ignore", invalid="ignore"):  # off the regular set the logs are not used
        logs = np.log(np.broadcast_to(A, index.shape)) / np.log(np.broadcast_to(T, index.shape))
        ok = regular & (np.abs(logs - np.round(logs)) > 1e-9)
    np.testing.assert_array_equal(index[ok], np.minimum(np.ceil(logs[ok]) + 1, MAX_INDEX))
    # the index never decreases as |J| falls at fixed τ < 1
    for k in range(taus.size):
        pos = index[J.size // 2 :, k]  # |J| increasing from 0
        assert np.all(np.diff(pos) <= 0)


# ---------------------------------------------------------------------- Lemma 3 at and near the maximum of φ
@functools.cache
def v_star(V=V_PAPER):
    m = PeelingModel()
    return brentq(lambda v: float(jacobians(m, jnp.zeros(3), v, V).phi_v), 0.3, 0.8, xtol=1e-15)


def state_at(v, V=V_PAPER):
    """Consistent state with α = α0, ω = v/R (no slip) at peeling velocity v."""
    m = PeelingModel()
    return m, consistent(m, V, PAPER_ALPHA0, v / 0.1, v)


V_STAR = 0.5240117  # measured: ∂φ/∂v(v*, 1.1) = 0
TAU_STAR = 2.5864e-4  # measured: 1/|F̃·∂f/∂v| at (α0, v*/R, u, v*), |F̃·∂f/∂v| = 3866.4


def test_maximum_of_phi_and_the_lemma3_threshold():
    vs = v_star()
    assert vs == pytest.approx(V_STAR, rel=1e-6)
    m, y = state_at(vs)
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    assert abs(float(jac.phi_v)) < 1e-10
    Ff_v = float(jnp.dot(jac.F_tilde, jac.f_v))
    # F̃·f_v ≈ −(k/l)·u/R − (k/l) = −(φ(v*)·10 + 1000) for α ≈ 0
    assert Ff_v == pytest.approx(-(float(m.phi(vs, V_PAPER)) / 0.1 + 1000.0), rel=1e-6)
    assert 1.0 / abs(Ff_v) == pytest.approx(TAU_STAR, rel=1e-4)


@pytest.mark.parametrize("geometry,threshold", [("paper", 2.5864e-4), ("full", 1.9903e-4)])
def test_lemma3_threshold_brackets_the_switch_from_index_one_to_two(geometry, threshold):
    """At the maximum of φ the index estimate switches from 1 to 2 at τ ≈ 1/|F̃·∂f/∂v|
    (paper geometry 2.59e-4; full geometry with l = 1: |F̃·∂f/∂v| = 5024, 1.99e-4)."""
    m = PeelingModel(geometry=geometry)
    vs = v_star()
    y = consistent(m, V_PAPER, PAPER_ALPHA0, vs / 0.1, vs)
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    tau_star = 1.0 / abs(float(jnp.dot(jac.F_tilde, jac.f_v)))
    assert tau_star == pytest.approx(threshold, rel=1e-4)
    below, above = 0.95 * tau_star, 1.05 * tau_star
    assert int(local_index(schur(jac, below), below)) == 2
    assert int(local_index(schur(jac, above), above)) == 1


@pytest.mark.parametrize("tau", [1e-4, 1e-5, 1e-6])
def test_lemma3_index_two_at_the_maximum_for_small_tau(tau):
    """At ∂φ/∂v = 0: |J_t| = τ·|F̃ f_v|·(1 + O((τρ)²)) < 1, so the index is 2 for τ < TAU_STAR."""
    m, y = state_at(v_star())
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    Ff_v = float(jnp.dot(jac.F_tilde, jac.f_v))
    rho = 1.0 / float(pj.neumann_radius(jac))
    J = float(schur(jac, tau))
    assert abs(J / (tau * Ff_v) - 1.0) <= (tau * rho) ** 2  # leading order (measured 2.1e-5 at τ = 1e-4)
    assert abs(J) < 1
    assert int(local_index(J, tau)) == 2
    assert bool(is_fast_scale(J, tau))


@pytest.mark.parametrize("tau", [1e-3, 1e-2])
def test_lemma3_fails_at_the_maximum_for_moderate_tau(tau):
    """Measured disagreement with Lemma 3 (which holds only as τ → 0): for τ > TAU_STAR ≈ 2.6e-4,
    |J_t| ≥ 1 at the maximum of φ (3.86 at τ = 1e-3, 32.3 at τ = 1e-2), so the index estimate is 1."""
    m, y = state_at(v_star())
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    J = float(schur(jac, tau))
    assert tau > TAU_STAR
    assert abs(J) >= 1
    assert abs(J) == pytest.approx({1e-3: 3.858, 1e-2: 32.28}[tau], rel=1e-3)
    assert int(local_index(J, tau)) == 1
    assert not bool(is_fast_scale(J, tau))


@traced
def truncation_at(v, tau, m_terms):
    model = PeelingModel()
    y = model.consistent_state(V_PAPER, PAPER_ALPHA0, v / 0.1, v)
    return pj.truncated_schur_complement(pj.jacobians(model, y[:3], y[3], V_PAPER), tau, m_terms)


PHI_VV = jax.jit(jax.grad(jax.grad(pj.AdhesionLaw(), argnums=0), argnums=0))


def _root_of_truncation(tau, m_terms):
    """v > v* where −φ_v + Σ_{p≤m} τ^p F̃(∂f/∂x)^{p−1}f_v = 0 on consistent states (α0, v/R, u(v), v)."""

    def g(v):
        return float(truncation_at(v, tau, m_terms))

    vs = v_star()
    return brentq(g, vs, vs + 0.1, xtol=1e-16, rtol=1e-15)


@pytest.mark.parametrize("tau,expected", [(1e-4, 3), (1e-5, 3), (1e-6, 3)])
def test_lemma3_index_above_two_near_the_maximum(tau, expected):
    """Where −φ_v cancels the first Neumann term τF̃f_v (just past the maximum, φ_v < 0), J_t is the
    remainder: the τ² term vanishes on ω = v/R, so |J_t| ≈ τ³·F̃(∂f/∂x)²f_v ≈ 8.2e6·τ³ and the
    index is 3 (log_τ(8.2e6·τ³) = 3 − 6.91/|log10 τ| ∈ (1, 2) for 1e-6.91 < τ < 1e-3.46, so ⌈·⌉ + 1 = 3).

    The tolerance on J_t ≈ τ³-term is looser at τ = 1e-6, where |J_t| = 8e-12 and brentq's
    last-ulp error in v (|φ_vv|·δv ≈ 4e-14) is no longer negligible."""
    v_root = _root_of_truncation(tau, 1)
    vs = v_star()
    # just past the maximum, by ≈ τ·|F̃f_v|/|φ_vv(v*)| (φ_vv(v*) = −67.0): 5.8e-3, 5.8e-4, 5.8e-5
    phi_vv = float(PHI_VV(vs, V_PAPER))
    assert phi_vv == pytest.approx(-67.0, rel=1e-2)
    assert v_root - vs == pytest.approx(tau * 3866.4 / abs(phi_vv), rel=2e-2)
    m, y = state_at(v_root)
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    J = float(schur(jac, tau))
    third = float(pj.neumann_terms(jac, tau, 3)[2])
    assert J == pytest.approx(third, rel=1e-3 if tau >= 1e-5 else 2e-2)
    assert third == pytest.approx(8.216e6 * tau**3, rel=1e-3)
    assert int(local_index(J, tau)) == expected


def test_lemma3_index_four_when_three_terms_cancel():
    """Cancelling three Neumann terms (τ = 1e-4): |J_t| ≈ 2.4e-10 = τ^2.4, index ⌈2.4⌉ + 1 = 4."""
    tau = 1e-4
    v_root = _root_of_truncation(tau, 3)
    m, y = state_at(v_root)
    jac = jacobians(m, y[:3], y[3], V_PAPER)
    J = float(schur(jac, tau))
    assert 1e-11 < abs(J) < tau**2
    assert int(local_index(J, tau)) == 4
