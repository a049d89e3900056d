"""The bound simulator (:class:`peeljax.Simulator`): ``simulate``'s results, checks and gradients.

A ``Simulator`` checks ``simulate``'s options once and then runs ``simulate``'s compiled
program for each (V, τ): its solutions must be ``simulate``'s, bit for bit; its refusals
``simulate``'s, word for word, before anything compiles; and a second call with another V
and τ, or a ``simulate`` call with the same options, must compile nothing. Compilations (and
programs read back from the persistent cache) are counted by JAX's monitoring events.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import sys

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import monitoring

import peeljax as pj
from peeljax import run_program

# Error control with the default fold="jump": the DAE jumps 18 times on [0, 0.3 s].
OPTIONS = {"t_final": 0.3, "rtol": 1e-5, "atol": 1e-8, "ts": np.linspace(0.0, 0.3, 31)}
# simulate's options but V, τ and y0, at their defaults (peeljax.simulate._kept_simulator's keys)
_ALL_OPTIONS = {
    name: p.default for name, p in inspect.signature(pj.simulate).parameters.items()
    if name not in ("model", "V", "tau", "y0")
}  # fmt: skip
_COMPILES = [0]


def _count_compiles(event: str, duration: float, **kwargs) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES[0] += 1


def _count_cache_reads(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _COMPILES[0] += 1


monitoring.register_event_duration_secs_listener(_count_compiles)
monitoring.register_event_listener(_count_cache_reads)


@contextlib.contextmanager
def compilations():
    """A one-item list holding the number of programs XLA compiled, or read back from the
    persistent cache, while the block ran."""
    count, start = [0], _COMPILES[0]
    try:
        yield count
    finally:
        count[0] = _COMPILES[0] - start


def assert_same_solution(bound: pj.Solution, simulated: pj.Solution) -> None:
    """Every array of the two solutions equal, bit for bit (NaN where NaN), and the same structure."""
    bound_leaves, bound_tree = jax.tree_util.tree_flatten(bound)
    simulated_leaves, simulated_tree = jax.tree_util.tree_flatten(simulated)
    assert bound_tree == simulated_tree
    for a, b in zip(bound_leaves, simulated_leaves):
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a, b, equal_nan=True)


def refusal(call) -> tuple[type, str]:
    with pytest.raises((ValueError, TypeError)) as info:
        call()
    return type(info.value), str(info.value)


@pytest.fixture(scope="module")
def sim() -> pj.Simulator:
    return pj.Simulator(**OPTIONS)


# ---------------------------------------------------------------------------- the same solutions
@pytest.mark.slow
def test_error_control_matches_simulate_and_compiles_once(sim):
    bound = sim(1.1, 0.05)
    with compilations() as count:
        simulated = pj.simulate(V=1.1, tau=0.05, **OPTIONS)
    assert count[0] == 0  # simulate's own program: one compilation for both in a process
    assert_same_solution(bound, simulated)
    with compilations() as count:
        solutions = [sim(2.0, 0.02), sim(np.float64(4.0), np.asarray(0.1)), sim(1, 1)]
    assert count[0] == 0  # other V and τ, other kinds of numbers: no recompilation
    for solution, (V, tau) in zip(solutions, [(2.0, 0.02), (4.0, 0.1), (1.0, 1.0)]):
        assert_same_solution(solution, pj.simulate(V=V, tau=tau, **OPTIONS))
    assert int(solutions[0].status) == 0 and solutions[0].ys.shape == (31, 4)


@pytest.mark.slow
def test_dae_with_jumps_matches_simulate(sim):
    bound = sim(1.1, 0.0)
    with compilations() as count:
        simulated = pj.simulate(V=1.1, tau=0, **OPTIONS)
    assert count[0] == 0  # the jumps' rows merged on the host by both: one program
    assert_same_solution(bound, simulated)
    assert int(bound.status) == 0 and int(bound.stats["jumps"]) >= 10
    with compilations() as count:
        other = sim(1.3, 0)
    assert count[0] == 0
    assert_same_solution(other, pj.simulate(V=1.3, tau=0.0, **OPTIONS))


@pytest.mark.slow
def test_initial_state_matches_simulate(sim):
    y0 = np.array([0.0, 0.0, 0.0, 1e-3])
    assert_same_solution(sim(1.1, 0.05, y0=y0), pj.simulate(V=1.1, tau=0.05, y0=y0, **OPTIONS))
    with compilations() as count:
        other = sim(1.1, 0.05, y0=[0.0, 0.0, 0.0, 2e-3])
    assert count[0] == 0
    assert_same_solution(other, pj.simulate(V=1.1, tau=0.05, y0=[0.0, 0.0, 0.0, 2e-3], **OPTIONS))


@pytest.mark.slow
def test_uniform_mesh_matches_simulate():
    options = {"t_final": 0.3, "dt": 0.01}
    sim = pj.Simulator(**options).compile()
    with compilations() as count:
        bound = sim(1.1, 0.05)
    assert count[0] == 0  # compile() did it
    assert_same_solution(bound, pj.simulate(V=1.1, tau=0.05, **options))
    assert bound.ys.shape == (31, 4)


@pytest.mark.slow
def test_diffrax_solver_takes_simulates_route():
    options = {"t_final": 0.05, "rtol": 1e-5, "atol": 1e-8, "ts": np.linspace(0.0, 0.05, 6)}
    sim = pj.Simulator(solver=diffrax.Kvaerno5(), **options)
    assert_same_solution(sim(1.1, 0.05), pj.simulate(V=1.1, tau=0.05, solver=diffrax.Kvaerno5(), **options))


# ---------------------------------------------------------------------------- a φ of the user's
class ScaledLaw(eqx.Module):
    """A φ of the user's with a Python float field: a leaf that is not an array."""

    scale: float = 1.0

    def __call__(self, v, V):
        return self.scale * pj.AdhesionLaw()(v, V)


def test_leaves_that_are_not_arrays_are_static_by_value_or_refused_where_unhashable():
    scalar, array = np.float64(1.1), jnp.ones(3)
    assert run_program.leaf_kinds([scalar, array, np.ones(2), 1.5, abs]) == (
        True, False, False, run_program.StaticLeaf(1.5), run_program.StaticLeaf(abs),
    )  # fmt: skip
    assert run_program.leaf_kinds([scalar, bytearray(b"x")]) is None  # (eqx.filter_jit's route)


def test_a_law_with_a_float_field_runs_through_the_simulators_program_as_filter_jit_ran_it():
    """Before, such a φ took ``eqx.filter_jit`` on every call (2–3 ms of its overhead); now its
    float is part of the compiled program's static part, by value, as filter_jit took it."""
    options = {"t_final": 0.02, "dt": 0.002}
    model = pj.PeelingModel(adhesion=ScaledLaw(1.05))
    sim = pj.Simulator(model, **options)
    assert sim._programs == {} and sim(1.1, 0.05).ys.shape == (11, 4)
    assert sim._programs[(False, False)].fast
    ode, y0 = run_program._prepare(model, 1.1, 0.05, None, None)
    inputs = (sim.integrators[False], ode, y0, sim.t_final, sim._run_ts)
    assert_same_solution(run_program._run(*inputs), jax.device_get(run_program._filter_jit(*inputs)))
    assert_same_solution(sim(1.1, 0.05), pj.simulate(model, V=1.1, tau=0.05, **options))
    other = pj.PeelingModel(adhesion=ScaledLaw(1.10))  # another value: another program, its own result
    assert not np.array_equal(pj.Simulator(other, **options)(1.1, 0.05).ys, sim(1.1, 0.05).ys)
    assert_same_solution(pj.Simulator(other, **options)(1.1, 0.05), pj.simulate(other, V=1.1, tau=0.05, **options))


# ---------------------------------------------------------------------------- gradients, batches
@pytest.mark.slow
def test_grad_and_vmap_match_simulate():
    # fold="stop": the same route as "jump", whose reverse-mode program takes ~80 s to compile here.
    options = {"t_final": 0.05, "ts": np.linspace(0.0, 0.05, 6), "fold": "stop"}
    sim = pj.Simulator(**options)
    bound = jax.grad(lambda V: sim(V, 0.1).ys[-1, 3])(1.1)
    simulated = jax.grad(lambda V: pj.simulate(V=V, tau=0.1, **options).ys[-1, 3])(1.1)
    assert np.isfinite(bound) and bound != 0.0
    assert bound == simulated
    Vs = jnp.array([1.1, 2.0, 4.0])
    batch = jax.vmap(lambda V: sim(V, 0.1).ys)(Vs)
    assert batch.shape == (3, 6, 4)
    np.testing.assert_array_equal(batch, jax.vmap(lambda V: pj.simulate(V=V, tau=0.1, **options).ys)(Vs))
    # a batched program may round differently from the single run: equal to a few ulps
    np.testing.assert_allclose(batch[1], sim(2.0, 0.1).ys, rtol=1e-13, atol=0)


# ---------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(
    "options",
    [
        {"rtol": 2.0},
        {"atol": 0.0},
        {"t_final": -1.0},
        {"ts": [0.0, 4.0]},
        {"ts": [0.5, 0.2]},
        {"t_final": 1.0, "ts": [-0.1, 0.5]},
        {"dt": 0.01, "rtol": 1e-6},
        {"dt": 0.01, "ts": [0.0, 1.0]},
        {"dt": 5.0},
        {"fold": "bounce"},
        {"max_steps": 0},
        {"max_jumps": -1},
        {"adjoint": "sideways"},
        {"rho": 1.0},
        {"dtmin": 5.0},
        {"truncation": -1},
        {"checkpoint_every": 10},
        {"solver": "Radau"},
        {"model": "paper"},
        {"model": pj.PeelingModel(R=-0.1)},
        {"memory_limit": 1.0},
    ],
)
def test_bad_options_are_refused_at_construction_with_simulates_message(options):
    with compilations() as count:
        bound = refusal(lambda: pj.Simulator(**options))
        simulated = refusal(lambda: pj.simulate(V=1.1, tau=0.01, **options))
    assert bound == simulated
    assert count[0] == 0


def test_construction_compiles_nothing():
    with compilations() as count:
        pj.Simulator(**OPTIONS)
        pj.Simulator(t_final=1.0, dt=0.01)
    assert count[0] == 0


@pytest.mark.parametrize(
    ("V", "tau"),
    [
        (0.0, 0.1),
        (-1.0, 0.1),
        (-1, 0.1),
        (math.nan, 0.1),
        (math.inf, 0.1),
        (np.float64(-2.0), 0.1),
        (np.asarray(-2.0), 0.1),
        (jnp.asarray(-2.0), 0.1),
        ("fast", 0.1),
        (1.1, -0.1),
        (1.1, math.nan),
        (1.1, -math.inf),
        (1.1, 2e6),
        (1.1, np.asarray(-0.1)),
        (-1.0, -1.0),  # τ is checked first, as in simulate
    ],
)
def test_bad_V_or_tau_is_refused_per_call_with_simulates_message(sim, V, tau):
    with compilations() as count:
        bound = refusal(lambda: sim(V, tau))
        simulated = refusal(lambda: pj.simulate(V=V, tau=tau, **OPTIONS))
    assert bound == simulated
    assert count[0] == 0


def test_bad_y0_and_arrays_of_V_are_refused_per_call(sim):
    y0 = [0.0, 0.0, 0.0, -1.0]
    assert refusal(lambda: sim(1.1, 0.1, y0=y0)) == refusal(lambda: pj.simulate(V=1.1, tau=0.1, y0=y0, **OPTIONS))
    with pytest.raises(ValueError, match=r"V must be a scalar for a Simulator call, got shape \(2,\)"):
        sim([1.1, 2.0], 0.1)
    with pytest.raises(ValueError, match=r"tau must be a scalar"):
        sim(1.1, np.array([0.1, 0.2]))


@pytest.mark.parametrize(
    "options",
    [{"dt": 0.01}, {"truncation": 1}, {"fold": "follow"}, {"solver": diffrax.ImplicitEuler()}],
)
def test_options_of_tau_positive_only_are_refused_on_a_dae_call(options):
    with compilations() as count:
        sim = pj.Simulator(t_final=1.0, **options)  # valid for τ > 0
        bound = refusal(lambda: sim(1.1, 0.0))
        simulated = refusal(lambda: pj.simulate(V=1.1, tau=0.0, t_final=1.0, **options))
    assert bound == simulated
    assert count[0] == 0


# ---------------------------------------------------------------------------- simulate keeps Simulators
def test_simulate_called_again_with_its_options_runs_through_a_kept_simulator():
    """The second call with the same options (the model by its values) makes a Simulator and
    keeps it; the third runs through it: the same bits as simulate's own route and as a
    Simulator's call. Other options, another model, a traced V: simulate's own route."""
    simulate_module = sys.modules["peeljax.simulate"]
    kept = simulate_module._KEPT_SIMULATORS
    own = pj.simulate(V=1.1, tau=0.05, **OPTIONS)
    assert not kept  # options seen once: simulate's own route
    second = pj.simulate(V=1.1, tau=0.05, **OPTIONS)
    assert len(kept) == 1
    with compilations() as count:
        pj.simulate(model=pj.PeelingModel(), V=2.0, tau=0.02, **OPTIONS)  # the paper's model given: another key than None
        third = pj.simulate(model=pj.PeelingModel(), V=2.0, tau=0.02, **OPTIONS)  # its second call: a Simulator
        fourth = pj.simulate(V=2.0, tau=0.02, **OPTIONS)
    assert count[0] == 0 and len(kept) == 2  # one program for every Simulator of this structure
    assert_same_solution(second, own)
    assert_same_solution(third, fourth)
    assert_same_solution(fourth, pj.Simulator(**OPTIONS)(2.0, 0.02))
    other_law = pj.PeelingModel(adhesion=pj.AdhesionLaw(c1=420.0))
    for _ in range(2):
        changed = pj.simulate(model=other_law, V=2.0, tau=0.02, **OPTIONS)
    assert len(kept) == 3 and not np.array_equal(np.asarray(changed.ys), np.asarray(fourth.ys))
    for _ in range(2):
        jax.eval_shape(lambda V: pj.simulate(V=V, tau=0.05, **OPTIONS).ys, 1.1)
    assert len(kept) == 3  # traced: simulate's own route
    with pytest.raises(ValueError, match="V must be > 0"):
        pj.simulate(V=-1.0, tau=0.05, **OPTIONS)  # refused by the kept Simulator with simulate's words
    assert refusal(lambda: pj.simulate(V=1.1, tau=0.05, **{**OPTIONS, "rtol": -1.0})) == refusal(
        lambda: pj.simulate(V=1.1, tau=0.05, **{**OPTIONS, "rtol": -1.0})
    )


def test_simulate_keeps_the_simulators_of_its_most_recent_options(monkeypatch):
    """At most KEPT_SIMULATORS Simulators, the least recently used let go first; 0 keeps none."""
    simulate_module = sys.modules["peeljax.simulate"]
    monkeypatch.setattr(simulate_module, "KEPT_SIMULATORS", 2)
    key = lambda t_final: simulate_module._options_key(None, {**_ALL_OPTIONS, **OPTIONS, "t_final": t_final})  # noqa: E731
    for t_final in (0.3, 0.4, 0.3, 0.5):
        for _ in range(2):
            simulate_module._kept_simulator(None, 1.1, 0.05, None, {**_ALL_OPTIONS, **OPTIONS, "t_final": t_final})
    assert list(simulate_module._KEPT_SIMULATORS) == [key(0.3), key(0.5)]
    assert simulate_module._options_key(None, {**_ALL_OPTIONS, "ts": jnp.linspace(0.0, 0.3, 31)}) is None  # a JAX array
    solver = lambda rho: simulate_module._options_key(None, {**_ALL_OPTIONS, "solver": pj.AlphaMethod(rho=rho)})  # noqa: E731
    assert solver(0.5) == solver(0.5) != solver(0.3)  # a solver given as a module: by its values
    assert simulate_module._options_key(None, {**_ALL_OPTIONS, "solver": pj.AlphaMethod(rho=jnp.asarray(0.5))}) is None
    monkeypatch.setattr(simulate_module, "KEPT_SIMULATORS", 0)
    assert simulate_module._kept_simulator(None, 1.1, 0.05, None, {**_ALL_OPTIONS, **OPTIONS, "t_final": 0.3}) is None
