"""Traced programs kept on disk (peeljax/_exported.py): read back without tracing, the same bits,
never a crash, never a program of a class that could have changed under its name."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax import _exported
from peeljax._exported import ExportedProgram, HostOutputs


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """An empty folder of exported programs for the test (what was read from another forgotten)."""
    monkeypatch.setattr(_exported, "programs_folder", lambda: tmp_path)
    _exported.forget()
    yield tmp_path
    _exported.forget()


def _law(c1):
    return eqx.tree_at(lambda law: law.c1, pj.AdhesionLaw(), jnp.asarray(c1))


def _double(scale, law, v):
    return {"phi": scale * law(v, 1.1), "law": law}


def _program(name="double"):
    return ExportedProgram(name, _double, jax.jit(_double, static_argnums=0))


def test_a_program_is_exported_once_and_read_back_without_tracing(folder, monkeypatch):
    program = _program()
    v = jnp.linspace(0.01, 2.0, 7)
    first = program(2.0, _law(400.0), v)
    entries = list(folder.glob("*.jaxexport"))
    assert len(entries) == 1
    # a new process (a fresh program object): read from the folder, nothing traced or exported
    again = _program()
    with monkeypatch.context() as patch:
        patch.setattr(_exported.export, "export", lambda *a, **k: pytest.fail("exported again"))
        second = again(2.0, _law(400.0), v)
        np.testing.assert_array_equal(np.asarray(second["phi"]), np.asarray(first["phi"]))
        assert isinstance(second["law"], pj.AdhesionLaw) and float(second["law"].c1) == 400.0
        # other values, the same program
        other = again(2.0, _law(410.0), v)["phi"]
        np.testing.assert_array_equal(np.asarray(other), np.asarray(_double(2.0, _law(410.0), v)["phi"]))
    # another static value or another shape: another entry
    again(3.0, _law(400.0), v)
    again(2.0, _law(400.0), v[:3])
    assert len(list(folder.glob("*.jaxexport"))) == 3


def test_a_run_gives_the_same_bits_read_back(folder):
    """simulate through its kept program equals the same call traced anew."""
    simulate_module = sys.modules["peeljax.run_program"]
    sol = pj.simulate(V=1.1, tau=0, t_final=0.3)
    assert list(folder.glob("*.jaxexport"))  # the run's program was kept
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(_exported, "programs_folder", lambda: None)  # off: traced and compiled as before
        patch.setattr(simulate_module._kept_run, "_programs", {})
        patch.setattr(sys.modules["peeljax.simulate"], "KEPT_SIMULATORS", 0)  # (the same options again)
        plain = pj.simulate(V=1.1, tau=0, t_final=0.3)
        (traced_here,) = simulate_module._kept_run._programs.values()
        assert isinstance(traced_here, HostOutputs)  # its outputs still one buffer per dtype
        assert isinstance(plain.ys, np.ndarray)
    np.testing.assert_array_equal(np.asarray(sol.ys), np.asarray(plain.ys))
    np.testing.assert_array_equal(np.asarray(sol.jumps.t), np.asarray(plain.jumps.t))


@pytest.mark.slow
def test_an_orbit_gives_the_same_bits_read_back(folder):
    """The orbit through its kept program equals jax.jit of the same function (two compilations
    of the orbit: 40 s)."""
    from peeljax.orbits import api

    shooting = api.orbit_shooting()
    args = (
        pj.PeelingModel(),
        jnp.asarray(1.1),
        jnp.asarray([0.3334, 16.02]),
        jnp.asarray(8, jnp.int32),
        jnp.asarray(0.7),
    )
    kept = api.compiled_orbit(shooting, *args)
    assert list(folder.glob("*.jaxexport"))
    direct = jax.jit(api.orbit_of)(shooting, *args)
    assert int(kept.status) == 0
    for a, b in zip(jax.tree_util.tree_leaves(kept), jax.tree_util.tree_leaves(direct)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("optimizer", ["adam", "lbfgs"])
def test_a_fit_step_gives_the_same_bits_read_back(folder, optimizer):
    """A fit's update (value, gradient, optax's step) through its kept program equals the same
    fit traced anew; a user's own optax transformation is traced as before (never kept: its
    functions cannot be told apart by name)."""
    import optax

    v = np.geomspace(0.01, 3.0, 12)
    force = np.asarray(pj.AdhesionLaw(c1=430.0)(v, v))
    options = {"start": pj.AdhesionLaw(), "free": ("c1", "c3"), "steps": 4, "progress": False, "optimizer": optimizer}
    kept = pj.fit_adhesion_steady(v, force, **options)
    assert len(list(folder.glob("*.jaxexport"))) == 1
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(_exported, "programs_folder", lambda: None)  # off: traced and compiled as before
        _exported.forget()
        plain = pj.fit_adhesion_steady(v, force, **options)
    np.testing.assert_array_equal(kept.loss_history, plain.loss_history)
    assert float(kept.adhesion.c1) == float(plain.adhesion.c1) != 400.0
    _exported.forget()
    pj.fit_adhesion_steady(v, force, **(options | {"optimizer": optax.sgd(1e-3)}))
    assert len(list(folder.glob("*.jaxexport"))) == 1


def test_a_corrupt_entry_is_exported_again(folder):
    program = _program()
    v = jnp.linspace(0.01, 2.0, 5)
    expected = np.asarray(program(2.0, _law(400.0), v)["phi"])
    (entry,) = folder.glob("*.jaxexport")
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    again = _program()
    np.testing.assert_array_equal(np.asarray(again(2.0, _law(400.0), v)["phi"]), expected)
    assert entry.stat().st_size > 100  # written anew


def test_tracers_and_classes_of_the_user_run_as_before(folder):
    """Under jax.grad the program is traced as before (its derivative is the jit's); a class
    defined outside peeljax and its libraries could change under its name: never kept."""
    program = _program()
    v = jnp.linspace(0.01, 2.0, 5)
    gradient = jax.grad(lambda c1: jnp.sum(program(2.0, _law(c1), v)["phi"]))(400.0)
    assert float(gradient) == pytest.approx(float(2.0 * jnp.sum(v**0.35)), rel=1e-12)
    assert not list(folder.glob("*"))

    class MyLaw(pj.AdhesionLaw):
        pass

    mine = eqx.tree_at(lambda law: law.c1, MyLaw(), jnp.asarray(400.0))
    np.testing.assert_array_equal(np.asarray(program(2.0, mine, v)["phi"]), np.asarray(_double(2.0, mine, v)["phi"]))
    assert not list(folder.glob("*"))


class UserScale(eqx.Module):
    """A class of the user's: this module is outside peeljax and its libraries."""

    k: jax.Array


def _unflattened_times_three(structure, k):
    """A program whose static part is its argument's tree structure (as simulate's is)."""
    return {"value": 3.0 * jax.tree_util.tree_unflatten(structure, [k]).k}


def test_a_class_of_the_user_held_in_the_static_part_is_never_kept(folder):
    """simulate's program holds the model's structure, with a user's φ class, in its static
    part: keyed by the class's name alone, a program read back after the user edited the class
    would be stale. It is traced in each process, its outputs packed all the same."""
    k = jnp.asarray(2.0)
    program = ExportedProgram(
        "static-structure", _unflattened_times_three, jax.jit(_unflattened_times_three, static_argnums=0),
        host_outputs=True,
    )  # fmt: skip
    mine = jax.tree_util.tree_structure(UserScale(k))
    out = program(mine, k)
    assert isinstance(out["value"], np.ndarray) and float(out["value"]) == 6.0
    assert not list(folder.glob("*"))
    (traced_here,) = program._programs.values()
    assert isinstance(traced_here, HostOutputs)
    # the same program with a structure of peeljax's classes is kept
    theirs = jax.tree_util.tree_structure(eqx.tree_at(lambda law: law.c1, pj.AdhesionLaw(), k))
    kept = ExportedProgram("static-structure", lambda s, x: {"value": 3.0 * x}, jax.jit(lambda s, x: 3.0 * x, static_argnums=0))
    assert float(kept(theirs, k)["value"]) == 6.0
    assert len(list(folder.glob("*.jaxexport"))) == 1


def _paper_phi(v, V):
    return pj.AdhesionLaw()(v, V)


def test_a_law_given_as_a_function_runs_compiled_and_is_never_kept(folder):
    """A φ given as a function is a leaf that is not an array: part of the program's static
    part, by value, so that the run takes jit's dispatch; what it computes could change under
    its name, so its program is never kept on disk."""
    paper = pj.simulate(V=1.1, tau=0.05, t_final=0.02, dt=0.002)
    kept = list(folder.glob("*"))
    assert len(kept) == 1  # the paper's law: its program kept
    sol = pj.simulate(pj.PeelingModel(adhesion=_paper_phi), V=1.1, tau=0.05, t_final=0.02, dt=0.002)
    np.testing.assert_allclose(sol.ys, paper.ys, rtol=1e-12, atol=0)
    assert list(folder.glob("*")) == kept


_EDITED_LAW = """
import sys
import peeljax as pj

FACTOR = float(sys.argv[1])


class EditedLaw(pj.AdhesionLaw):
    def _evaluate(self, v, V):
        return FACTOR * super()._evaluate(v, V)


# the uniform mesh: keyed as error control's program is, which is larger and compiles in each of the three processes
sol = pj.simulate(pj.PeelingModel(adhesion=EditedLaw()), V=1.1, tau=0.1, t_final=0.2, dt=0.002)
print(repr(float(sol.ys[-1, 3])))
"""


@pytest.mark.slow
def test_a_run_follows_the_users_edit_of_its_law_class(tmp_path):
    """The user edits their φ class (same module, same name) between two processes sharing a
    cache: the second run is the edited law's, not the first program read back."""
    script = tmp_path / "edited_law.py"
    script.write_text(_EDITED_LAW)
    shared, fresh = tmp_path / "shared-cache", tmp_path / "fresh-cache"

    def v_final(factor, cache):
        env = dict(os.environ, PEELJAX_COMPILATION_CACHE=str(cache), PYTHONPATH=str(Path(pj.__file__).parents[1]))
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        done = subprocess.run([sys.executable, str(script), str(factor)], env=env, capture_output=True, text=True, check=True)
        return float(done.stdout.strip().splitlines()[-1])

    before, edited = v_final(1.0, shared), v_final(1.1, shared)
    assert edited == v_final(1.1, fresh) != before


def test_a_program_that_cannot_be_exported_is_remembered_and_runs(folder):
    def with_callback(scale, x):
        jax.debug.callback(lambda value: None, x)
        return scale * x

    program = ExportedProgram("callback", with_callback, jax.jit(with_callback, static_argnums=0))
    assert float(program(2.0, jnp.asarray(3.0))) == 6.0
    assert len(list(folder.glob("*.refused"))) == 1 and not list(folder.glob("*.jaxexport"))
    assert (
        float(
            ExportedProgram("callback", with_callback, jax.jit(with_callback, static_argnums=0))(2.0, jnp.asarray(4.0))
        )
        == 8.0
    )


def test_the_folder_follows_the_compilation_cache(monkeypatch):
    folder = jax.config.jax_compilation_cache_dir
    monkeypatch.delenv(_exported.VARIABLE, raising=False)
    assert folder and _exported.programs_folder() == Path(folder) / _exported.SUBFOLDER  # the suite's cache
    monkeypatch.setenv(_exported.VARIABLE, "off")
    assert _exported.programs_folder() is None
