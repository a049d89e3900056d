"""An orbit's file (peeljax.orbits.files): PeriodicOrbit.save, read back by
peeljax.load as a SavedOrbit with every field, data only; malformed files refused naming the
file and the array.

The orbits here are built by hand (no shooting, nothing compiled but the tiny stability
check): what is tested is the file, field by field. ``tests/test_cli_orbit.py`` writes and
reads a shot orbit through ``peeljax orbit --out``.
"""

from __future__ import annotations

import dataclasses
import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.orbits import OrbitStatus, PeriodicOrbit, SavedOrbit
from peeljax.orbits.files import _FIELDS, _STATISTICS, orbit_arrays


def _orbit(model=None, status=OrbitStatus.CONVERGED) -> PeriodicOrbit:
    """An orbit with every field set to a distinct value (a complex pair of multipliers)."""
    return PeriodicOrbit(
        model=pj.PeelingModel() if model is None else model, V=jnp.asarray(1.1), slips=jnp.asarray(8, jnp.int32),
        section=jnp.asarray([0.33337, 16.0175]), state=jnp.asarray([0.33337, 16.0175, 0.2862, 0.5244]),
        period=jnp.asarray(0.2182711), force_integral=jnp.asarray(53.629), approach=jnp.asarray(-3.25),
        crossing=jnp.asarray(1520.5),
        monodromy=jnp.asarray([[-0.31, 0.002], [-20.5, -0.26]]),
        multipliers=jnp.asarray([-0.285 + 0.21j, -0.285 - 0.21j]), status=jnp.asarray(int(status), jnp.int32),
        run_status=jnp.asarray(int(pj.StopReason.MAX_JUMPS), jnp.int32), iterations=jnp.asarray(3, jnp.int32),
        residual=jnp.asarray(3.4e-11), steps=jnp.asarray(1234, jnp.int32),
        statistics={"F_mean": jnp.asarray(245.698), "F_slip": jnp.asarray(259.648), "F_stick": jnp.asarray(233.902),
                    "period": jnp.asarray(0.0272839), "slip_duration": jnp.asarray(0.0021911)},
    )  # fmt: skip


def _fields(orbit) -> dict:
    return {name: np.asarray(getattr(orbit, name)) for name in _FIELDS}


def test_the_file_holds_every_field_of_an_orbit():
    fields = {f.name for f in dataclasses.fields(PeriodicOrbit)} - {"model", "statistics"}
    assert fields == set(_FIELDS), "a field of PeriodicOrbit is not written by peeljax/orbits/files.py"
    assert set(_STATISTICS) == set(_orbit().statistics)


def test_an_orbit_comes_back_whole_with_its_model_and_settings(tmp_path):
    law = pj.AdhesionLaw(c1=0.998 * pj.AdhesionLaw().c1, p9=0.7)
    orbit = _orbit(pj.PeelingModel(R=0.12, I=2e-2, k=900.0, l=1.2, adhesion=law, geometry="full"))
    path = tmp_path / "orbit.npz"
    orbit.save(path, {"rtol": 1e-8, "transient": 3.0})
    back = pj.load(path)
    assert isinstance(back, SavedOrbit) and isinstance(back, PeriodicOrbit)
    for name, value in _fields(orbit).items():
        assert np.array_equal(np.asarray(getattr(back, name)), value), name
        assert np.asarray(getattr(back, name)).dtype.kind == value.dtype.kind, name
    assert {k: float(v) for k, v in back.statistics.items()} == {k: float(v) for k, v in orbit.statistics.items()}
    model = back.model
    assert (float(model.R), float(model.I), float(model.k), float(model.l), model.geometry) == (0.12, 2e-2, 900.0, 1.2, "full")
    assert model.adhesion.coefficients() == law.coefficients()
    assert back.settings == {"rtol": 1e-8, "transient": 3.0} and back.path == str(path)
    assert back.status_name == "converged" and back.reason == orbit.reason and bool(back.stable)
    assert back.as_dict() == orbit.as_dict()
    assert back.units["period"] == "s" and back.units["F_mean"] == "N" and back.peeljax_version == pj.__version__
    # data only: plain numpy reads it without pickles, and says what it is
    with np.load(path, allow_pickle=False) as data:
        assert json.loads(str(data["meta_json"]))["kind"] == "orbit"
        assert str(data["status_name"]) == "converged" and float(data["time_between_slips"]) == 0.0272839
    # a read orbit saves again as it was read, its settings kept
    again = tmp_path / "again.npz"
    back.save(again)
    assert pj.load(again).settings == back.settings and pj.load(again).as_dict() == orbit.as_dict()


def test_a_failed_orbit_is_saved_with_its_status(tmp_path):
    orbit = _orbit(status=OrbitStatus.EVENTS_CHANGED)
    orbit.save(tmp_path / "failed.npz")
    back = pj.load(tmp_path / "failed.npz")
    assert back.status_name == "events_changed" and not bool(back.converged)
    assert "did not come back through k stick → slip events" in back.reason


def test_what_a_file_cannot_hold_is_refused():
    callable_phi = pj.PeelingModel(adhesion=lambda v, V: pj.AdhesionLaw()(v, V))
    with pytest.raises(ValueError, match="callable, which a file cannot hold"):
        orbit_arrays(_orbit(callable_phi))

    class ScaledLaw(pj.AdhesionLaw):
        def _evaluate(self, v, V):
            return 1.1 * super()._evaluate(v, V)

    with pytest.raises(ValueError, match="a subclass of AdhesionLaw, which a file cannot hold"):
        orbit_arrays(_orbit(pj.PeelingModel(adhesion=ScaledLaw())))
    batch = jax_stack([_orbit(), _orbit()])
    with pytest.raises(ValueError, match="one orbit per file"):
        orbit_arrays(batch)


def jax_stack(orbits):
    import jax

    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *orbits)


def _spoiled(arrays: dict, key: str, value) -> dict:
    out = dict(arrays)
    if value is None:
        del out[key]
    else:
        out[key] = value
    return out


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("period", None, "has no 'period'"),
        ("section", np.zeros(3), "section must be numbers of shape (2,)"),
        ("slips", np.float64(8.0), "slips must be integers"),
        ("slips", np.int64(0), "slips must be a positive integer"),
        ("status", np.int64(17), "status 17 is no orbit status"),
        ("run_status", np.int64(-5), "run_status -5 is no StopReason"),
        ("period", np.float64(np.nan), "period must be finite"),
        ("approach", np.float64(np.nan), "approach must be a number"),
        ("V", np.float64(-1.0), "V must be finite and > 0"),
        ("R", np.float64(0.0), "R must be finite and > 0"),
        ("F_slip", np.float64(np.inf), "F_slip must be finite"),
        ("multipliers", np.array(["a", "b"]), "multipliers must be numbers"),
        ("geometry", np.asarray("round"), "geometry 'round' is none of"),
        ("phi_json", np.asarray("{c1: 1"), "phi_json is not JSON"),
        ("phi_json", np.asarray('{"c1": -3}'), "coefficient 'c1' must lie in"),
        ("settings_json", np.asarray("[1, 2]"), "settings_json is not a JSON object"),
    ],
)
def test_a_malformed_orbit_file_is_refused_naming_it(tmp_path, key, value, words):
    path = tmp_path / "bad.npz"
    np.savez(path, **_spoiled(orbit_arrays(_orbit()), key, value))
    with pytest.raises(ValueError) as refused:
        pj.load(path)
    message = str(refused.value)
    assert str(path) in message and words in message, message


def test_an_infinite_approach_is_kept(tmp_path):
    # -inf: no stick or slip phase turned back towards a fold (no grazing near)
    orbit = eqx.tree_at(lambda o: o.approach, _orbit(), jnp.asarray(-jnp.inf))
    orbit.save(tmp_path / "o.npz")
    assert float(pj.load(tmp_path / "o.npz").approach) == -np.inf
