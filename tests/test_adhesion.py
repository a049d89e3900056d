"""The adhesion law φ(v, V): the paper's coefficients, its shape, the v ≤ 0 policy, gradients, JSON."""

from __future__ import annotations

import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import peeljax as pj
from peeljax import COEFFICIENT_NAMES, PAPER_COEFFICIENTS, AdhesionLaw, safe_pow

# The paper's φ, written out by hand (Numerical Example; after de Cicco et al.).
PAPER_NUMBERS = {
    "c1": 400.0,
    "p1": 0.35,
    "c2": 110.0,
    "p2": 0.15,
    "c3": 130.0,
    "c4": 11.0,
    "c5": 2.0,
    "p5": 1.5,
    "c6": 415.0,
    "c7": 45.0,
    "p7": 0.4,
    "c8": 0.35,
    "p8": 2.15,
    "p9": 0.5,
}


def phi_numpy(v, V):
    """400 v^0.35 + 110 v^0.15 + 130 exp(v/11) − 2 V^1.5 − (415 − 45 V^0.4 − 0.35 V^2.15) v^0.5."""
    v = np.asarray(v, float)
    return (
        400.0 * v**0.35
        + 110.0 * v**0.15
        + 130.0 * np.exp(v / 11.0)
        - 2.0 * V**1.5
        - (415.0 - 45.0 * V**0.4 - 0.35 * V**2.15) * v**0.5
    )


def dphi_dv_numpy(v, V):
    v = np.asarray(v, float)
    return (
        400.0 * 0.35 * v**-0.65
        + 110.0 * 0.15 * v**-0.85
        + 130.0 / 11.0 * np.exp(v / 11.0)
        - (415.0 - 45.0 * V**0.4 - 0.35 * V**2.15) * 0.5 * v**-0.5
    )


# Compiled once and reused (V, v and the coefficients are traced): eager op-by-op autodiff
# costs seconds on a loaded machine.
phi = jax.jit(lambda law, v, V: law(v, V))
phi_v = jax.jit(jax.grad(lambda law, v, V: law(v, V), argnums=1))
phi_vv = jax.jit(jax.grad(jax.grad(lambda law, v, V: law(v, V), argnums=1), argnums=1))
phi_coefficients = jax.jit(jax.grad(lambda law, v, V: law(v, V)))  # w.r.t. the module
pow_grads = jax.jit(jax.grad(safe_pow, argnums=(0, 1)))
pow_xx = jax.jit(jax.grad(jax.grad(safe_pow, argnums=0), argnums=0))
jacobians = eqx.filter_jit(pj.jacobians)
consistent_state = eqx.filter_jit(lambda m, V, a, w, v: m.consistent_state(V, a, w, v))


# ---------------------------------------------------------------------- coefficients
def test_defaults_are_the_papers_fourteen_numbers():
    law = AdhesionLaw()
    assert COEFFICIENT_NAMES == tuple(PAPER_NUMBERS)
    assert PAPER_COEFFICIENTS == PAPER_NUMBERS
    assert law.coefficients() == PAPER_NUMBERS
    for name, value in PAPER_NUMBERS.items():
        leaf = getattr(law, name)
        assert leaf.dtype == jnp.float64 and leaf.shape == ()
        assert float(leaf) == value


def test_constructor_overrides_one_coefficient_and_keeps_the_rest():
    law = AdhesionLaw(c1=500.0, p9=0.6)
    expected = {**PAPER_NUMBERS, "c1": 500.0, "p9": 0.6}
    assert law.coefficients() == expected


def test_unknown_coefficient_raises():
    with pytest.raises(ValueError, match="unknown"):
        AdhesionLaw(unknown=1)
    with pytest.raises(ValueError, match="c10"):
        AdhesionLaw(c1=1.0, c10=2.0)


class ScaledLaw(AdhesionLaw):
    """A user's law: the paper's φ scaled, with a field of its own (a float and an array)."""

    scale: float = 1.0
    shift: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)

    def _evaluate(self, v, V):
        return self.scale * super()._evaluate(v, V) + self.shift


def test_a_subclass_sets_its_own_fields_by_name_or_default():
    """Before: AdhesionLaw's __init__ set the 14 coefficients only, so a subclass's own field was
    refused by name and never set (flattened as equinox's `_Missing`, unreachable by tree_at)."""
    law = ScaledLaw(scale=1.1, c1=420.0)
    assert law.scale == 1.1 and law.c1 == 420.0 and float(law.shift) == 0.0
    expected = 1.1 * AdhesionLaw(c1=420.0)(0.5, 1.1)
    assert float(law(0.5, 1.1)) == pytest.approx(float(expected), rel=1e-15)
    assert ScaledLaw().scale == 1.0
    assert "_Missing" not in str(jax.tree_util.tree_structure(law))
    assert eqx.tree_at(lambda m: m.scale, law, 1.2).scale == 1.2
    # an array field of the user's is differentiated like a coefficient
    assert float(jax.grad(lambda m: m(0.5, 1.1))(ScaledLaw(shift=2.0)).shift) == 1.0
    with pytest.raises(ValueError, match=r"ScaledLaw: unknown coefficient\(s\) \['scal'\].*'c1'.*'scale', 'shift'"):
        ScaledLaw(scal=1.1)


def test_a_subclass_field_without_a_default_must_be_given():
    class Shifted(AdhesionLaw):
        shift: float

    assert Shifted(shift=3.0).shift == 3.0
    with pytest.raises(TypeError, match="Shifted: field 'shift' has no default; pass shift="):
        Shifted()


def test_a_subclass_with_a_field_runs_as_a_function_of_the_same_law():
    law = ScaledLaw(scale=1.1)
    # Tsit5 without the jump machinery (no fold within 0.2 s at τ = 0.1, where the default takes
    # Tsit5 too): the law's route into a run is the same for every stepper, and these compile faster
    options = {"V": 1.1, "tau": 0.1, "t_final": 0.2, "solver": "tsit5", "fold": "stop"}
    run = pj.simulate(pj.PeelingModel(adhesion=law), **options)
    same = pj.simulate(pj.PeelingModel(adhesion=lambda v, V: 1.1 * AdhesionLaw()(v, V)), **options)
    assert bool(run.completed)
    # the same law, another program (its coefficients constants): round-off apart, at rtol 1e-6. A run
    # that ignored the scale would be the paper's φ's, beyond rtol 1e-3 of this one (this test's third
    # run showed it until it was cut for time)
    np.testing.assert_allclose(np.asarray(run.ys), np.asarray(same.ys), rtol=1e-8, atol=1e-12)


def test_a_subclass_is_never_written_or_read_as_the_papers_family(tmp_path):
    """A subclass's _evaluate is code: to_json refuses it, and a fit's file names its class,
    which from_dict refuses (read as the family, the coefficients would be another law)."""
    from peeljax.fit.result import FitResult

    with pytest.raises(TypeError, match=r"ScaledLaw.to_json: a subclass of AdhesionLaw is code"):
        ScaledLaw(scale=1.1).to_json(tmp_path / "law.json")
    assert not (tmp_path / "law.json").exists()
    AdhesionLaw(**ScaledLaw(scale=1.1, c1=420.0).coefficients()).to_json(tmp_path / "family.json")  # on purpose
    assert float(AdhesionLaw.from_json(tmp_path / "family.json").c1) == 420.0

    def fitted(law):
        return FitResult(adhesion=law, start=law, loss_history=np.ones(1), initial_loss=1.0, final_loss=1.0,
                         gradient_norm=0.0, steps=0, stopped_early=False, v_range=(0.1, 1.0), free=("c1",), settings={})  # fmt: skip

    record = fitted(ScaledLaw(scale=1.1)).to_dict()
    assert record["law"] == "ScaledLaw" and record["c1"] == 400.0
    with pytest.raises(ValueError, match=r"coefficients of 'ScaledLaw', a subclass of AdhesionLaw"):
        AdhesionLaw.from_dict(record)
    fitted(ScaledLaw(scale=1.1)).to_json(tmp_path / "fit.json")
    with pytest.raises(ValueError, match=r"'ScaledLaw', a subclass"):
        AdhesionLaw.from_json(tmp_path / "fit.json")
    plain = fitted(AdhesionLaw(c1=420.0)).to_dict()
    assert "law" not in plain and float(AdhesionLaw.from_dict(plain).c1) == 420.0


# ---------------------------------------------------------------------- values and shape
@pytest.mark.parametrize("V", [1.1, 2.0, 4.0, 8.0])
def test_phi_equals_the_formula_written_out(V):
    v = np.array([1e-8, 1e-3, 0.1, 0.5, 1.1, 3.0, 10.0, 40.0])
    got = np.asarray(AdhesionLaw()(jnp.asarray(v), V))  # eager, vectorised
    np.testing.assert_allclose(got, phi_numpy(v, V), rtol=1e-14, atol=0)
    law = AdhesionLaw()
    for vi in (0.3, 1.1, 7.0):
        assert float(phi(law, vi, V)) == pytest.approx(phi_numpy(vi, V), rel=1e-14)
        assert float(phi_v(law, vi, V)) == pytest.approx(dphi_dv_numpy(vi, V), rel=1e-12)


dphi_grid = jax.jit(jax.vmap(phi_v, in_axes=(None, 0, None)))


def _critical_points(V):
    """Zeros of ∂φ/∂v on (1e-6, 100), located by sign changes on a grid and refined by brentq."""
    grid = np.logspace(-6, 2, 2001)
    d = np.asarray(dphi_grid(AdhesionLaw(), jnp.asarray(grid), V))
    roots = []
    for i in np.nonzero(np.sign(d[1:]) != np.sign(d[:-1]))[0]:
        roots.append(brentq(lambda v: dphi_dv_numpy(v, V), grid[i], grid[i + 1], xtol=1e-14))
    return roots, d


# (v at the maximum, v at the minimum), measured.
EXTREMA = {1.1: (0.524012, 8.49245), 2.0: (0.696663, 7.68021), 4.0: (1.294915, 5.83537)}


@pytest.mark.parametrize("V", [1.1, 2.0, 4.0])
def test_phi_has_a_maximum_then_a_minimum(V):
    roots, _ = _critical_points(V)
    assert len(roots) == 2
    v_max, v_min = roots
    assert v_max == pytest.approx(EXTREMA[V][0], rel=1e-5)
    assert v_min == pytest.approx(EXTREMA[V][1], rel=1e-5)
    law = AdhesionLaw()
    assert float(phi_vv(law, v_max, V)) < 0  # a maximum
    assert float(phi_vv(law, v_min, V)) > 0  # a minimum
    assert float(phi(law, v_max, V)) > float(phi(law, v_min, V))


def test_phi_is_monotone_for_V_8():
    roots, d = _critical_points(8.0)
    assert roots == []
    assert np.all(d > 0)
    # the smallest slope is clearly positive (measured ≈ 8.68 N·s/m), not a near-miss
    assert d.min() > 5.0


# ---------------------------------------------------------------------- v ≤ 0 policy
def test_phi_at_zero_and_negative_v_is_the_limit_from_the_right():
    law = AdhesionLaw()
    V = 1.1
    constant = 130.0 * np.exp(0.0) - 2.0 * V**1.5
    assert float(law(0.0, V)) == pytest.approx(constant, rel=1e-14)
    assert float(law(-1.0, V)) == pytest.approx(130.0 * np.exp(-1.0 / 11.0) - 2.0 * V**1.5, rel=1e-14)
    # continuity from the right at 0
    assert float(law(1e-300, V)) == pytest.approx(constant, rel=1e-12)


@pytest.mark.parametrize("v", [0.0, -1.0, -1e-300])
def test_gradients_at_nonpositive_v_are_finite(v):
    law = AdhesionLaw()
    V = 1.1
    dv = float(phi_v(law, v, V))
    assert math.isfinite(dv)
    # the powers contribute zero derivative; only the exponential term is left
    assert dv == pytest.approx(130.0 / 11.0 * np.exp(v / 11.0), rel=1e-14)
    grads = phi_coefficients(law, v, V)
    for name in COEFFICIENT_NAMES:
        g = float(getattr(grads, name))
        assert math.isfinite(g), name
    # v-powers have no influence at v ≤ 0
    for name in ("c1", "p1", "c2", "p2", "c6", "c7", "p7", "c8", "p8", "p9"):
        assert float(getattr(grads, name)) == 0.0, name
    # second derivative in v is finite too
    assert math.isfinite(float(phi_vv(law, v, V)))


@pytest.mark.parametrize("x", [0.0, -1.0, -1e-300, -5.0])
@pytest.mark.parametrize("p", [0.15, 0.5, 2.15])
def test_safe_pow_and_its_gradients_are_finite_at_nonpositive_x(x, p):
    assert float(safe_pow(x, p)) == 0.0
    gx, gp = pow_grads(x, p)
    assert float(gx) == 0.0 and float(gp) == 0.0
    hxx = pow_xx(x, p)
    assert math.isfinite(float(hxx))


def test_safe_pow_positive_values_and_gradients():
    x, p = 2.0, 0.35
    assert float(safe_pow(x, p)) == pytest.approx(x**p, rel=1e-15)
    gx, gp = pow_grads(x, p)
    assert float(gx) == pytest.approx(p * x ** (p - 1), rel=1e-14)
    assert float(gp) == pytest.approx(x**p * np.log(x), rel=1e-14)
    # elementwise on arrays with mixed signs
    xs = jnp.array([-2.0, 0.0, 0.25, 4.0])
    np.testing.assert_array_equal(np.asarray(safe_pow(xs, 0.5)), [0.0, 0.0, 0.5, 2.0])


# ---------------------------------------------------------------------- gradients w.r.t. the coefficients
@pytest.mark.parametrize("v,V", [(0.7, 1.1), (3.0, 2.0)])
def test_coefficient_gradient_matches_central_differences(v, V):
    law = AdhesionLaw()
    grads = phi_coefficients(law, v, V)  # plain jax.grad on the module: all leaves are arrays
    grads_eqx = eqx.filter_grad(lambda m: m(v, V))(law)  # eager, through equinox
    base = law.coefficients()
    scale = abs(float(phi(law, v, V)))
    for name in COEFFICIENT_NAMES:
        h = 1e-6 * abs(base[name])
        plus = phi(AdhesionLaw(**{**base, name: base[name] + h}), v, V)
        minus = phi(AdhesionLaw(**{**base, name: base[name] - h}), v, V)
        fd = float(plus - minus) / (2 * h)
        g = float(getattr(grads, name))
        assert float(getattr(grads_eqx, name)) == pytest.approx(g, rel=1e-14), name
        assert g == pytest.approx(fd, rel=1e-6, abs=1e-9 * scale), name


# ---------------------------------------------------------------------- user callables
def user_phi(v, V):
    """A smooth law with a maximum at v = 1: 300 − 50 (v − 1)² + V."""
    return 300.0 - 50.0 * (v - 1.0) ** 2 + V


@pytest.mark.parametrize("geometry", ["paper", "full"])
def test_user_callable_works_in_the_model(geometry):
    model = pj.PeelingModel(adhesion=user_phi, geometry=geometry)
    assert model.adhesion is user_phi
    V = 1.1
    assert float(model.phi(0.5, V)) == pytest.approx(user_phi(0.5, V))
    y = consistent_state(model, *map(jnp.asarray, (V, 0.2, 3.0, 0.5)))
    assert abs(float(model.constraint(y[:3], y[3], V))) <= 1e-12 * user_phi(0.5, V)
    jac = jacobians(model, y[:3], y[3], jnp.asarray(V))
    assert float(jac.phi_v) == pytest.approx(-100.0 * (0.5 - 1.0), rel=1e-14)

    @eqx.filter_jit
    def residual(m, y, V):
        return m.constraint(y[:3], y[3], V)

    assert abs(float(residual(model, y, jnp.asarray(V)))) <= 1e-12 * user_phi(0.5, V)


def test_user_callable_works_in_the_homogenized_ode():
    model = pj.PeelingModel(adhesion=user_phi)
    V, tau = 1.1, 1e-3
    y = consistent_state(model, *map(jnp.asarray, (V, 0.1, 2.0, 0.8)))
    ode = pj.HomogenizedODE(model, V, tau)
    psi = np.asarray(eqx.filter_jit(lambda o, y: o(y))(ode, y))
    jac = jacobians(model, y[:3], y[3], jnp.asarray(V))
    f = np.asarray(jac.f)
    phi_v = -100.0 * (0.8 - 1.0)
    Ft, fx, fv = np.asarray(jac.F_tilde), np.asarray(jac.f_x), np.asarray(jac.f_v)
    J = -phi_v + tau * Ft @ np.linalg.solve(np.eye(3) - tau * fx, fv)
    np.testing.assert_allclose(psi[:3], f, rtol=1e-14)
    assert psi[3] == pytest.approx(-(Ft @ f) / J, rel=1e-12)
    psi0 = np.asarray(eqx.filter_jit(lambda o, y: o(y))(pj.HomogenizedODE(model, V, tau, truncation=0), y))
    assert psi0[3] == pytest.approx((Ft @ f) / phi_v, rel=1e-12)


def test_non_callable_adhesion_is_rejected():
    with pytest.raises(TypeError):
        pj.PeelingModel(adhesion=3.0)


# ---------------------------------------------------------------------- JSON
def test_json_round_trip(tmp_path):
    law = AdhesionLaw(c1=401.25, p9=0.5 + 1e-13, c4=10.0 / 3.0)
    path = tmp_path / "phi.json"
    text = law.to_json(path, note="fitted", V=1.1)
    data = json.loads(path.read_text())
    assert json.loads(text) == data
    assert data["note"] == "fitted" and data["V"] == 1.1
    assert set(data) == set(COEFFICIENT_NAMES) | {"note", "V"}
    back = AdhesionLaw.from_json(path)
    assert back.coefficients() == law.coefficients()  # exact: repr of a float round-trips
    assert float(back(0.9, 2.0)) == float(law(0.9, 2.0))


def test_from_dict_ignores_notes_and_keeps_defaults():
    law = AdhesionLaw.from_dict({"c1": 500, "comment": "x", "nested": {"a": 1}, "V": 1.1})
    assert law.coefficients() == {**PAPER_NUMBERS, "c1": 500.0}


@pytest.mark.parametrize("key", ["C1", "c9", "p_1", "c1 ", "P9", "c10"])
def test_from_dict_refuses_a_misspelled_coefficient(key):
    """Taken silently, a misspelling would leave the paper's value in place (issue 21)."""
    with pytest.raises(ValueError, match=rf"unknown coefficient name \['{key}'\].*c1, p1, c2"):
        AdhesionLaw.from_dict({"c1": 500, key: 3.0})


@pytest.mark.parametrize(
    "bad",
    [float("nan"), float("inf"), -float("inf"), "400", True, False, None, [400.0], {"v": 1}],
    ids=repr,
)
@pytest.mark.parametrize("key", ["c1", "p9", "c4"])
def test_from_dict_rejects_bad_values_naming_the_key(key, bad):
    with pytest.raises(ValueError, match=repr(key)):
        AdhesionLaw.from_dict({"c2": 110.0, key: bad})


@pytest.mark.parametrize("data", [[1.0, 2.0], "c1", 3.0, None])
def test_from_dict_rejects_a_non_object(data):
    with pytest.raises(ValueError, match="JSON object"):
        AdhesionLaw.from_dict(data)


@pytest.mark.parametrize("data", [{}, {"unknown": 1.0}])
def test_from_dict_rejects_an_object_without_coefficients(data):
    # the message names the expected keys
    with pytest.raises(ValueError, match="'c1'.*'p9'"):
        AdhesionLaw.from_dict(data)


def test_from_dict_rejects_zero_c4():
    with pytest.raises(ValueError, match="'c4'"):
        AdhesionLaw.from_dict({"c4": 0.0})


@pytest.mark.parametrize("text", ['{"c1": NaN}', '{"c1": Infinity}', '{"p5": "1.5"}', '{"c3": true}'])
def test_from_json_rejects_non_finite_and_non_numbers(tmp_path, text):
    path = tmp_path / "phi.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=str(path)):
        AdhesionLaw.from_json(path)


def test_from_json_reports_missing_file_and_bad_json(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        AdhesionLaw.from_json(tmp_path / "missing.json")
    path = tmp_path / "bad.json"
    path.write_text("{c1: 400")
    with pytest.raises(ValueError, match="not valid JSON"):
        AdhesionLaw.from_json(path)


def test_from_dict_rejects_a_huge_integer_with_value_error():
    with pytest.raises(ValueError, match="'c1'"):
        AdhesionLaw.from_dict({"c1": 10**400})


def test_safe_pow_higher_derivatives_match_central_differences():
    # safe_pow has a custom JVP that reuses x**p; its second and mixed derivatives (the
    # α-method's Newton matrix differentiates φ_v once more) must still be exact.
    x, p, eps = 0.7, 0.35, 1e-5
    d_x = jax.grad(safe_pow, argnums=0)
    d_xx = jax.grad(d_x, argnums=0)
    d_xp = jax.grad(d_x, argnums=1)
    assert float(d_xx(x, p)) == pytest.approx(p * (p - 1) * x ** (p - 2), rel=1e-13)
    assert float(d_xp(x, p)) == pytest.approx(x ** (p - 1) * (1 + p * np.log(x)), rel=1e-13)
    fd = (float(d_x(x + eps, p)) - float(d_x(x - eps, p))) / (2 * eps)
    assert float(d_xx(x, p)) == pytest.approx(fd, rel=1e-7)
    # forward over reverse and forward over forward agree, and stay finite at x ≤ 0
    hess = jax.jacfwd(jax.jacfwd(safe_pow, argnums=(0, 1)), argnums=(0, 1))
    for x0 in (0.7, 0.0, -1.0):
        h = np.asarray(jax.tree_util.tree_leaves(hess(x0, p)))
        assert np.all(np.isfinite(h))
    assert np.all(np.asarray(jax.tree_util.tree_leaves(hess(-1.0, p))) == 0.0)
