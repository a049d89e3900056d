"""PeelingModel: parameters, the two geometries against the paper's equations, initial data, tracing."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from test_adhesion import phi_numpy

import peeljax as pj
from peeljax import PeelingModel
from peeljax.model import PAPER_ALPHA0, PAPER_V0_FACTOR


def traced(fn):
    """eqx.filter_jit(fn) with every float (Python or NumPy scalar) passed as a strongly typed
    float64 array: traced, so new values never recompile (ints stay static)."""
    jitted = eqx.filter_jit(fn)
    return lambda *args: jitted(
        *(jnp.asarray(a, dtype=float) if isinstance(a, (float, np.floating)) else a for a in args)
    )


# Compiled once per geometry; all arguments traced.
f_jit = traced(lambda m, x, v, V: m.f(x, v, V))
shear_jit = traced(lambda m, x: m.shear_force(x))
constraint_jit = traced(lambda m, x, v, V: m.constraint(x, v, V))
consistent_jit = traced(lambda m, V, a, w, v: m.consistent_state(V, a, w, v))
initial_jit = traced(lambda m, V: m.initial_state(V))
stretch_jit = traced(lambda m, a, F: m.stretch_for_force(a, F))


def random_states(n, seed):
    """n points (x, v, V) with α ∈ (−0.6, 0.6), ω ∈ (−5, 20), u ∈ (0.05, 0.4), v ∈ (0.05, 6), V ∈ {1.1, 2, 4}."""
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(-0.6, 0.6, n)
    omega = rng.uniform(-5.0, 20.0, n)
    u = rng.uniform(0.05, 0.4, n)
    v = rng.uniform(0.05, 6.0, n)
    V = rng.choice([1.1, 2.0, 4.0], n)
    return [(np.array([a, w, s]), vi, Vi) for a, w, s, vi, Vi in zip(alpha, omega, u, v, V)]


# ---------------------------------------------------------------------- parameters
def test_defaults():
    m = PeelingModel()
    assert (float(m.R), float(m.I), float(m.k), float(m.l)) == (0.1, 1e-2, 1000.0, 1.0)
    assert m.geometry == "paper"
    assert isinstance(m.adhesion, pj.AdhesionLaw)
    assert m.adhesion.coefficients() == pj.PAPER_COEFFICIENTS
    for name in ("R", "I", "k", "l"):
        leaf = getattr(m, name)
        assert leaf.dtype == jnp.float64 and leaf.shape == ()


def test_unknown_geometry_raises():
    with pytest.raises(ValueError, match="geometry"):
        PeelingModel(geometry="exact")
    with pytest.raises(ValueError, match="geometry"):
        PeelingModel(geometry="Paper")


# ---------------------------------------------------------------------- the paper geometry
def paper_f(x, v, V, R=0.1, I=1e-2, k_over_l=1000.0):
    """The approximated equations of the numerical example: F = (k/l)u, L ≈ l, u ≪ l, l ≫ R."""
    alpha, omega, u = x
    F = k_over_l * u
    return np.array(
        [
            omega - v / R,
            -R * np.sin(alpha) * F / I,
            R * np.sin(alpha) * (omega - v / R) + V - v,
        ]
    )


def paper_shear(x, k_over_l=1000.0):
    alpha, _, u = x
    return (1.0 + np.sin(alpha)) * k_over_l * u


def test_paper_geometry_equals_the_approximated_equations():
    m = PeelingModel()
    for x, v, V in random_states(8, seed=0):
        np.testing.assert_allclose(np.asarray(f_jit(m, jnp.asarray(x), v, V)), paper_f(x, v, V), rtol=1e-13, atol=1e-12)
        assert float(shear_jit(m, jnp.asarray(x))) == pytest.approx(paper_shear(x), rel=1e-14)
        assert float(constraint_jit(m, jnp.asarray(x), v, V)) == pytest.approx(
            paper_shear(x) - phi_numpy(v, V), rel=1e-12, abs=1e-10
        )


def test_paper_geometry_with_other_parameters_depends_on_k_over_l_only():
    x, v, V = np.array([0.3, 4.0, 0.2]), 0.7, 2.0
    m = PeelingModel(R=0.05, I=3e-3, k=600.0, l=2.0)
    np.testing.assert_allclose(
        np.asarray(f_jit(m, jnp.asarray(x), v, V)), paper_f(x, v, V, R=0.05, I=3e-3, k_over_l=300.0), rtol=1e-13
    )
    # k and l enter only through k/l
    m2 = PeelingModel(R=0.05, I=3e-3, k=6000.0, l=20.0)
    np.testing.assert_allclose(
        np.asarray(f_jit(m2, jnp.asarray(x), v, V)), np.asarray(f_jit(m, jnp.asarray(x), v, V)), rtol=1e-14
    )
    assert float(shear_jit(m2, jnp.asarray(x))) == pytest.approx(float(shear_jit(m, jnp.asarray(x))), rel=1e-14)


# ---------------------------------------------------------------------- the full geometry
def full_L(alpha, R, l):
    return np.sqrt(R**2 + l**2 - 2.0 * R * l * np.cos(alpha))  # (defL)


def full_f(x, v, V, R=0.1, I=1e-2, k=1000.0, l=1.0):
    """Eqs. (defL), (defF), (av), (tb), (str) as printed in the paper."""
    alpha, omega, u = x
    L = full_L(alpha, R, l)
    F = k * u / (L - u)  # (defF)
    return np.array(
        [
            omega - v / R,  # (av)
            -R * l * np.sin(alpha) / (I * L) * F,  # (tb)
            R * l * np.sin(alpha) / L * (1.0 + u / L) * (omega - v / R) + V - v,  # (str)
        ]
    )


def full_shear(x, R=0.1, k=1000.0, l=1.0):
    alpha, _, u = x
    L = full_L(alpha, R, l)
    return (1.0 + l * np.sin(alpha) / L) * k * u / (L - u)  # left side of (sac)


@pytest.mark.parametrize("params", [{}, {"R": 0.3, "I": 0.05, "k": 2500.0, "l": 1.7}])
def test_full_geometry_equals_the_papers_equations(params):
    m = PeelingModel(geometry="full", **params)
    for x, v, V in random_states(8, seed=1):
        got = np.asarray(f_jit(m, jnp.asarray(x), v, V))
        np.testing.assert_allclose(got, full_f(x, v, V, **params), rtol=1e-13, atol=1e-12)
        assert float(shear_jit(m, jnp.asarray(x))) == pytest.approx(
            full_shear(x, **{k: params[k] for k in ("R", "k", "l") if k in params}), rel=1e-13
        )
        assert float(m.free_length(x[0])) == pytest.approx(
            full_L(x[0], params.get("R", 0.1), params.get("l", 1.0)), rel=1e-14
        )


def test_full_geometry_tends_to_the_paper_geometry_as_l_grows():
    """l → ∞ with k/l = 1000 fixed and R, u fixed: R/l → 0 and u/l → 0.

    L(α) = l − R·cosα + O(R²/l), so l·sinα/L = sinα·(1 + O(R/l)), F = (k/l)·u·l/(L − u) =
    (k/l)·u·(1 + O((R + u)/l)) and 1 + u/L = 1 + O(u/l): every difference between the two
    geometries is O(1/l). We check that the relative difference of f and of the shear force
    falls by a factor ≈ 10 per decade of l, i.e. like 1/l, and is below 1e-4 at l = 1e4.
    """
    x, v, V = np.array([0.4, 6.0, 0.3]), 0.7, 1.1
    paper = PeelingModel()
    f_p = np.asarray(f_jit(paper, jnp.asarray(x), v, V))
    s_p = float(shear_jit(paper, jnp.asarray(x)))
    errors_f, errors_s = [], []
    for l in (10.0, 100.0, 1000.0, 10000.0):
        full = PeelingModel(k=1000.0 * l, l=l, geometry="full")
        f_full = np.asarray(f_jit(full, jnp.asarray(x), v, V))
        errors_f.append(np.linalg.norm(f_full - f_p) / np.linalg.norm(f_p))
        errors_s.append(abs(float(shear_jit(full, jnp.asarray(x))) - s_p) / s_p)
    for errors in (errors_f, errors_s):
        ratios = np.array(errors[:-1]) / np.array(errors[1:])
        assert np.all((ratios > 8.0) & (ratios < 12.0)), ratios
        assert errors[-1] < 1e-4
    # and at the paper's own l = 1 the geometries genuinely differ (the test is not vacuous)
    full1 = PeelingModel(geometry="full")
    assert np.linalg.norm(np.asarray(f_jit(full1, jnp.asarray(x), v, V)) - f_p) > 1e-2 * np.linalg.norm(f_p)


# ---------------------------------------------------------------------- initial data
@pytest.mark.parametrize("geometry", ["paper", "full"])
@pytest.mark.parametrize("V", [1.1, 2.0, 4.0])
def test_initial_state_is_the_papers(geometry, V):
    m = PeelingModel(geometry=geometry)
    y = np.asarray(initial_jit(m, V))
    v0 = 1e-10 * V
    assert PAPER_V0_FACTOR == 1e-10
    assert float(PAPER_ALPHA0) == np.pi / 4 * 1e-8
    assert y[3] == pytest.approx(v0, rel=1e-15)
    assert y[1] == pytest.approx(v0 / 0.1, rel=1e-15)
    assert y[0] == pytest.approx(np.pi / 4 * 1e-8, rel=1e-15)
    phi0 = phi_numpy(v0, V)
    assert y[2] > 0
    residual = float(constraint_jit(m, jnp.asarray(y[:3]), y[3], V))
    assert abs(residual) <= 1e-12 * abs(phi0)
    # u0 from (sac) by hand
    shear = paper_shear(y[:3]) if geometry == "paper" else full_shear(y[:3])
    assert shear == pytest.approx(phi0, rel=1e-12)


@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_consistent_state_satisfies_the_constraint(geometry):
    m = PeelingModel(geometry=geometry)
    rng = np.random.default_rng(2)
    for _ in range(6):
        alpha, omega, v = rng.uniform(-0.6, 0.6), rng.uniform(0.0, 20.0), rng.uniform(0.05, 6.0)
        V = rng.choice([1.1, 2.0, 4.0])
        y = np.asarray(consistent_jit(m, V, alpha, omega, v))
        assert (y[0], y[1], y[3]) == (alpha, omega, v)
        residual = float(constraint_jit(m, jnp.asarray(y[:3]), y[3], V))
        assert abs(residual) <= 1e-12 * abs(phi_numpy(v, V))
        shear = paper_shear(y[:3]) if geometry == "paper" else full_shear(y[:3])
        assert shear == pytest.approx(phi_numpy(v, V), rel=1e-12)


@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_stretch_for_force_inverts_the_shear_force(geometry):
    m = PeelingModel(geometry=geometry)
    for alpha in (-0.5, 0.0, 1e-8, 0.7):  # floats: traced by stretch_jit
        for force in (50.0, 286.6, 900.0):
            u = stretch_jit(m, alpha, force)
            assert float(shear_jit(m, jnp.array([alpha, 0.0, float(u)]))) == pytest.approx(force, rel=1e-13)


# ---------------------------------------------------------------------- tracing
def test_parameters_are_traced_not_static():
    traces = []

    @eqx.filter_jit
    def rhs(model, y, V):
        traces.append(1)  # a Python side effect runs only while tracing
        return model.f(y[:3], y[3], V), model.constraint(y[:3], y[3], V)

    y = jnp.array([0.1, 5.0, 0.28, 0.6])
    a = rhs(PeelingModel(), y, jnp.asarray(1.1))
    b = rhs(PeelingModel(), y, jnp.asarray(2.0))  # new V
    c = rhs(PeelingModel(R=0.2), y, jnp.asarray(1.1))  # new R
    d = rhs(PeelingModel(I=0.5, k=900.0, l=0.9), y, jnp.asarray(1.1))  # new I, k, l
    e = rhs(PeelingModel(adhesion=pj.AdhesionLaw(c1=500.0)), y, jnp.asarray(1.1))  # new coefficient
    assert len(traces) == 1
    # the values did change (so the cache hit is not hiding a stale result)
    assert float(b[0][2] - a[0][2]) == pytest.approx(0.9, rel=1e-12)
    assert float(c[0][0]) != float(a[0][0])
    assert float(d[0][1]) != float(a[0][1])
    assert float(e[1]) != float(a[1])
    # the geometry is static: switching it retraces, once
    rhs(PeelingModel(geometry="full"), y, jnp.asarray(1.1))
    rhs(PeelingModel(geometry="full", R=0.3), y, jnp.asarray(4.0))
    assert len(traces) == 2


def test_homogenized_ode_parameters_are_traced():
    traces = []

    @eqx.filter_jit
    def psi(ode, y):
        traces.append(1)
        return ode(y)

    m = PeelingModel()
    y = initial_jit(m, 1.1)
    psi(pj.HomogenizedODE(m, 1.1, 1e-3), y)
    psi(pj.HomogenizedODE(m, 2.0, 1e-2), y)
    psi(pj.HomogenizedODE(PeelingModel(R=0.2), 2.0, 1e-2), y)
    assert len(traces) == 1
    psi(pj.HomogenizedODE(m, 1.1, 1e-3, truncation=2), y)  # truncation is static
    assert len(traces) == 2
