"""Fitting φ (issue 4 §2): the trajectory acceptance fit, the steady-peeling fit of all 14
coefficients, and input errors.

The acceptance fit's setup is ``benchmarks/fit_acceptance.py`` (the same fit, printed).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import optax
import pytest

import peeljax as pj
from peeljax.fit.trajectory import _filtered_update, _kept_update, restart_on_ascent

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import fit_acceptance


def perturbed(rng, names):
    true = pj.PAPER_COEFFICIENTS
    return pj.AdhesionLaw(**{n: true[n] * (1 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.2)) for n in names})


def test_steady_fit_of_all_coefficients():
    """(v, peel force) pairs of steady peeling (v = V), 1 % noise, all 14 coefficients from a 10–20 % start."""
    rng = np.random.default_rng(0)
    true = pj.AdhesionLaw()
    v = np.geomspace(0.3, 5.0, 40)
    force = np.asarray(true(v, v)) * (1 + 0.01 * rng.standard_normal(v.size))
    start = perturbed(rng, pj.COEFFICIENT_NAMES)
    result = pj.fit_adhesion_steady(v, force, start=start, steps=500, progress=False)
    fitted, expected = np.asarray(result.adhesion(v, v)), np.asarray(true(v, v))
    assert np.max(np.abs(fitted - expected) / np.abs(expected)) < 0.02
    assert result.loss_reduction >= 100
    assert result.v_range == pytest.approx((0.3, 5.0))
    record = result.to_dict()
    assert pj.AdhesionLaw.from_dict(record).coefficients() == result.adhesion.coefficients()


@pytest.mark.slow
def test_trajectory_fit_acceptance():
    """Issue 4's acceptance on a shorter record: v, F and α at V = 1.1, 2, 4 (τ = 0.01 s, here
    t ≤ 0.5 s, every 1/82 s) with 1 % noise; all 14 coefficients from a ±(10–20) % start; 300
    L-BFGS iterations; the model on the error-controlled α-method (the default, rtol 1e-6).
    Measured here: loss ÷ 1700, final loss 0.95 × the noise floor, φ within 1.1 %. The issue's
    own setting (t ≤ 1 s, 500 iterations): ``python benchmarks/fit_acceptance.py``
    (docs/fitting.md). The coefficients themselves are not all recovered: docs/fitting.md,
    identifiability.
    """
    out = fit_acceptance.run(t_final=0.5, steps=300, progress=False)
    result = out["result"]
    assert result.settings["rtol"] == 1e-6 and result.settings["dt"] is None  # error control, the default
    assert result.loss_reduction >= 100
    assert result.final_loss <= 1.05 * out["noise_floor"]  # at the noise floor: nothing left to fit
    assert result.v_range[0] < 1e-9 and result.v_range[1] > 4.0  # from v0 = 1e-10·V past V = 4
    assert out["phi_error_start"] > 0.1
    assert out["phi_error"] < 0.02


def test_fit_input_errors():
    obs = pj.Observation(V=1.1, t=np.linspace(0, 1, 5), v=np.ones(5))
    with pytest.raises(ValueError, match="free"):
        pj.fit_adhesion(obs, free=["c1", "nope"])
    with pytest.raises(ValueError, match="optimizer"):
        pj.fit_adhesion(obs, optimizer="sgd")
    with pytest.raises(ValueError, match="V"):
        pj.fit_adhesion(pj.Observation(V=-1.0, t=np.linspace(0, 1, 5), v=np.ones(5)))
    with pytest.raises(ValueError, match="no observations"):
        pj.fit_adhesion([])
    with pytest.raises(ValueError, match="steps"):
        pj.fit_adhesion(obs, steps=-1)
    with pytest.raises(ValueError, match="learning_rate"):
        pj.fit_adhesion(obs, learning_rate=0.0)


def test_fit_tolerances_are_checked():
    obs = pj.Observation(V=1.1, t=np.linspace(0, 0.2, 5), v=np.ones(5))
    with pytest.raises(ValueError, match="rtol"):
        pj.fit_adhesion(obs, rtol=2.0, progress=False)
    with pytest.raises(ValueError, match="cannot be combined with dt"):
        pj.fit_adhesion(obs, dt=0.01, rtol=1e-6, progress=False)


def steady_data(seed=0):
    """(v, force, start) of the steady fit above: 1 % noise, all 14 coefficients 10–20 % off."""
    rng = np.random.default_rng(seed)
    v = np.geomspace(0.3, 5.0, 40)
    force = np.asarray(pj.AdhesionLaw()(v, v)) * (1 + 0.01 * rng.standard_normal(v.size))
    return v, force, perturbed(rng, pj.COEFFICIENT_NAMES)


def test_optax_transformation_as_optimizer():
    """optimizer=optax.adam(0.05) is optimizer="adam", learning_rate=0.05; the settings name it."""
    v, force, start = steady_data()
    named = pj.fit_adhesion_steady(v, force, start=start, steps=15, optimizer="adam", learning_rate=0.05,
                                   progress=False)  # fmt: skip
    given = pj.fit_adhesion_steady(v, force, start=start, steps=15, optimizer=optax.adam(0.05), progress=False)
    assert named.settings["optimizer"] == "adam"
    np.testing.assert_allclose(given.loss_history, named.loss_history, rtol=0, atol=1e-12)
    assert given.settings["optimizer"] == "optax.GradientTransformationExtraArgs (user)"
    assert given.settings["learning_rate"] is None
    assert '"optax.GradientTransformationExtraArgs (user)"' in given.to_json()


def test_chained_transformation_lowers_the_loss_and_compiles_once():
    """optax.chain(clip, sgd) fits; a second fit with the same object and new data values reuses
    the compiled update. A user L-BFGS (zoom line search: needs value, grad, value_fn) wrapped
    in restart_on_ascent fits too."""
    v, force, start = steady_data()
    opt = optax.chain(optax.clip_by_global_norm(1.0), optax.sgd(0.01))
    result = pj.fit_adhesion_steady(v, force, start=start, steps=5, optimizer=opt, progress=False)
    assert result.steps == 5 and result.final_loss < result.initial_loss
    size = _filtered_update._cached._cache_size()  # a user's transformation: traced in the process
    again = pj.fit_adhesion_steady(v, 1.01 * force, start=start, steps=5, optimizer=opt, progress=False)
    assert again.final_loss < again.initial_loss
    assert _filtered_update._cached._cache_size() == size  # same shapes, free set and transformation
    lbfgs = pj.fit_adhesion_steady(
        v, force, start=start, steps=10, optimizer=restart_on_ascent(optax.lbfgs()), progress=False
    )
    assert lbfgs.final_loss < 0.1 * lbfgs.initial_loss


def test_bad_optimizers_are_rejected_before_compiling():
    obs = pj.Observation(V=1.1, t=np.linspace(0, 0.2, 5), v=np.ones(5))
    v, force, _ = steady_data()
    sizes = (_filtered_update._cached._cache_size(), len(_kept_update._programs))
    for bad in ("sgd", optax.adam, (optax.adam(0.1).init, optax.adam(0.1).update), 0.1, None):
        with pytest.raises(ValueError, match="optimizer must be"):
            pj.fit_adhesion(obs, optimizer=bad, progress=False)
        with pytest.raises(ValueError, match="optimizer must be"):
            pj.fit_adhesion_steady(v, force, optimizer=bad, progress=False)
    with pytest.raises(ValueError, match="call it"):
        pj.fit_adhesion_steady(v, force, optimizer=optax.sgd, progress=False)
    with pytest.raises(ValueError, match="learning_rate.*optimizer"):
        pj.fit_adhesion(obs, optimizer=optax.adam(0.1), learning_rate=0.1, progress=False)
    with pytest.raises(ValueError, match="learning_rate.*optimizer"):
        pj.fit_adhesion_steady(v, force, optimizer=optax.sgd(0.1), learning_rate=0.1, progress=False)
    assert (_filtered_update._cached._cache_size(), len(_kept_update._programs)) == sizes
