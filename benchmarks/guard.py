"""The speed guard: ratios that do not depend on the machine, each against a limit committed beside it.

A speed lost without noticing is a bug. Each check (``CHECKS``; the function of each says what it
times) calls two things alternately in this one process after their compilation and divides the
medians: the gradient through 210 jumps at τ = 0 ÷ the forward run (by a tangent, and with
``adjoint="checkpointed"``: ``--ci`` or ``--only`` alone), P1 with the default ``fold`` ÷ with
``fold="stop"`` (no jump happens: the room kept for jumps should cost nothing), P1 through
``simulate`` ÷ through a ``Simulator`` (one compiled program; simulate keeps a Simulator for
options it has seen), P1 at τ = 0.01 with the default (switching) stepper ÷ with Tsit5 alone,
P1 with a φ module of the user's ÷ with the paper's law (the user's program traced in the process), P6 ÷ the compiled diffrax peer
(``peers/jump_peers.py``), ``periodic_orbit(V=1.1)`` ÷ P6's 3 s run, one step of
``fit_adhesion`` ÷ the forward run it fits, and the compilation of P6's program ÷ that of
diffrax's ``diffeqsolve`` (each made new, so that neither comes from a cache).

Limits are in ``guard_limits.json`` (``measured``: what a quiet 2-core machine measured when
they were set; ``limit``: a small margin over it). Exit status 1 names every ratio over its
limit after a confirmation (measured again, alone, with three times the rounds; ``--no-confirm``
fails at once). ``--ci`` (the test suite's; ``LONGEST_SET_UP`` in its slow tier) doubles each limit's margin over the ratio
measured, so that a noisy machine never fails a run but a regression such as the 5.6× slower
gradient through jumps (3.3 → 21) does.

    python benchmarks/guard.py                 # before every stop (≤ 60 s with compiled programs cached)
    python benchmarks/guard.py --ci            # CI's limits
    python benchmarks/guard.py --only gradient_through_jumps p1_jump_rows
    python benchmarks/guard.py --record        # write this run's ratios as "measured" (limits unchanged)

The first run on a machine compiles every program (~3 min on 2 cores); later runs read them
from JAX's persistent compilation cache (the library's, in the user's cache folder).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import uuid
from pathlib import Path

HERE = Path(__file__).resolve().parent
LIMITS = HERE / "guard_limits.json"
# The peeljax beside this file is the one measured, whatever else is installed (a guard run from a
# second checkout measured the installed one's code: simulator_call 1.36 on fixed code).
sys.path.insert(0, str(HERE.parent))
V = 1.1


# ---------------------------------------------------------------------------- the calls
def gradient_through_jumps(adjoint="reverse"):
    """(gradient, forward): d/dc1 of the sum of the first 30 jump times through 210 jumps."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np

    import peeljax as pj

    def jump_times(c1, adjoint="reverse"):
        law = eqx.tree_at(lambda a: a.c1, pj.AdhesionLaw(), c1)
        sol = pj.simulate(
            pj.PeelingModel(adhesion=law), V=V, tau=0, t_final=3.0, ts=np.array([0.0, 3.0]), max_jumps=512,
            adjoint=adjoint,
        )  # fmt: skip
        return jnp.sum(sol.jumps.t[:30])

    forward, gradient = jax.jit(jump_times), jax.jit(jax.grad(lambda c1: jump_times(c1, adjoint)))
    c1 = jnp.asarray(400.0)
    return (lambda: gradient(c1)), (lambda: forward(c1))


def p1_jump_rows():
    """(default fold, fold="stop"): P1 called as a user does."""
    import numpy as np

    import peeljax as pj

    ts = np.linspace(0.0, 3.0, 301)

    def p1(**fold):
        return lambda: pj.simulate(V=V, tau=0.01, t_final=3.0, rtol=1e-5, atol=1e-7, ts=ts, **fold)

    return p1(), p1(fold="stop")


def simulator_call():
    """(simulate, the Simulator call it equals): P1, one compiled program for both. simulate,
    called again with the same options, runs through a Simulator it keeps: it costs the key of
    its options more, not its checks again."""
    import numpy as np

    import peeljax as pj

    options = {"t_final": 3.0, "rtol": 1e-5, "atol": 1e-7, "ts": np.linspace(0.0, 3.0, 301)}
    sim = pj.Simulator(**options)
    return (lambda: pj.simulate(V=V, tau=0.01, **options)), (lambda: sim(V, 0.01))


def user_law_call():
    """(a φ module of the user's, the paper's law): P1 at τ = 0.1 through a Simulator each. The
    user's φ holds a Python float, part of the compiled program by value, and its program is
    traced in the process (a class outside peeljax is never read back from disk: its code can
    change under its name); the paper's is read back. Before 2026-12-07 such a φ took
    ``eqx.filter_jit`` on every call and came back output by output: 2.65 here."""
    import equinox as eqx
    import numpy as np

    import peeljax as pj

    class UsersLaw(eqx.Module):
        """The paper's φ times a Python float, a φ module of the user's (defined outside peeljax)."""

        scale: float = 1.0

        def __call__(self, v, V):
            return self.scale * pj.AdhesionLaw()(v, V)

    options = {"t_final": 3.0, "rtol": 5e-3, "ts": np.linspace(0.0, 3.0, 301)}
    mine, paper = pj.Simulator(pj.PeelingModel(adhesion=UsersLaw()), **options), pj.Simulator(**options)
    return (lambda: mine(V, 0.1)), (lambda: paper(V, 0.1))


def switching_overhead():
    """(the default stepper at τ > 0, Tsit5 alone): P1 at τ = 0.01 through a Simulator each, at
    rtol 5e-4, where both meet ``switching.py``'s error target with the same steps but the
    switch's (217 and 220 attempts; the default goes over to the α-method at 2.57 s). What the
    switching stepper's conditionals and counts cost a step (docs/theory.md: 1.09–1.24)."""
    import numpy as np

    import peeljax as pj

    options = {"t_final": 3.0, "rtol": 5e-4, "ts": np.linspace(0.0, 3.0, 301)}
    default, tsit5 = pj.Simulator(**options), pj.Simulator(solver="tsit5", **options)
    return (lambda: default(V, 0.01)), (lambda: tsit5(V, 0.01))


def _p6():
    import numpy as np

    import peeljax as pj

    return lambda: pj.simulate(V=V, tau=0, t_final=3.0, rtol=1e-6, ts=np.array([0.0, 3.0]))


def p6_vs_diffrax():
    """(P6, the diffrax while-loop peer) at rtol 1e-6."""
    sys.path.insert(0, str(HERE))
    from peers.jump_peers import DiffraxWhileLoop

    peer = DiffraxWhileLoop([1e-6])
    peer.prepare()
    return _p6(), (lambda: peer.run(1e-6))


def orbit_vs_run():
    """(periodic_orbit(V=1.1), the 3 s run of P6)."""
    import peeljax as pj

    return (lambda: pj.periodic_orbit(V=V).period), _p6()


def fit_step():
    """(one step of fit_adhesion, the forward run it fits)."""
    import numpy as np

    import peeljax as pj

    ts = np.linspace(0.0, 0.5, 51)
    run = pj.simulate(V=V, tau=0.01, t_final=0.5, rtol=1e-6, atol=1e-9, ts=ts)
    observation = pj.Observation(V=V, t=ts, v=np.asarray(run.v))
    start = pj.AdhesionLaw(c1=420.0)
    fit = lambda: (
        pj.fit_adhesion(  # noqa: E731
            observation, start=start, free=("c1",), steps=1, progress=False, rtol=1e-6, atol=1e-9
        ).final_loss
    )
    forward = lambda: pj.simulate(
        pj.PeelingModel(adhesion=start), V=V, tau=0.01, t_final=0.5, rtol=1e-6, atol=1e-9, ts=ts
    )  # noqa: E731
    return fit, forward


def compile_ratio(rounds: int = 1) -> float:
    """Seconds to compile P6's program ÷ seconds to compile diffrax's diffeqsolve, each made new
    in every round (the two alternately); the least of each side's rounds, divided. Compiling is
    the same work every time and whatever else runs only adds to it: the median of 2 rounds'
    ratios read 3.8–6.0 in four runs of the same code within 5 minutes (load ~1, 2026-12-04),
    and once broke its limit of 6.6."""
    import diffrax
    import jax
    import jax.numpy as jnp
    import numpy as np

    import peeljax as pj
    from peeljax.integrators.select import integrator_for

    integrator = integrator_for(None, t_final=3.0, rtol=1e-6, dae=True)
    ode = pj.ConstrainedDAE(pj.PeelingModel(), V)
    ts = jnp.asarray([0.0, 3.0])
    homogenized = pj.HomogenizedODE(pj.PeelingModel(), V, 0.01)
    y0 = np.asarray(pj.PeelingModel().initial_state(V))

    def peeljax_program(y0, salt):
        return integrator.integrate(ode, y0, 0.0, 3.0, ts).ys + 0.0 * (y0[0] + salt)  # salt: in the program

    def diffrax_program(y0, salt):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, y, args: homogenized(y)), diffrax.Tsit5(), 0.0, 3.0, None, y0,
            saveat=diffrax.SaveAt(ts=jnp.linspace(0.0, 3.0, 301)),
            stepsize_controller=diffrax.PIDController(rtol=1e-6, atol=1e-9), max_steps=100_000,
        )  # fmt: skip
        return sol.ys + 0.0 * (y0[0] + salt)

    def seconds(fn):
        salt = uuid.uuid4().int % 2**31  # a program made new: not from any cache
        lowered = jax.jit(lambda y0: fn(y0, salt)).lower(y0)
        began = time.perf_counter()
        lowered.compile()
        return time.perf_counter() - began

    # Programs made new are not written to the persistent cache either.
    minimum = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1e9)
    try:
        pairs = [(seconds(peeljax_program), seconds(diffrax_program)) for _ in range(rounds)]
        return min(p for p, _ in pairs) / min(d for _, d in pairs)
    finally:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", minimum)


CHECKS = {
    "gradient_through_jumps": gradient_through_jumps,
    "gradient_checkpointed": lambda: gradient_through_jumps("checkpointed"),
    "p1_jump_rows": p1_jump_rows,
    "simulator_call": simulator_call,
    "switching_overhead": switching_overhead,
    "user_law_call": user_law_call,
    "p6_vs_diffrax": p6_vs_diffrax,
    "orbit_vs_run": orbit_vs_run,
    "fit_step": fit_step,
}

# Measured with --ci and --only: tracing the checkpointed loop's gradient takes ~9 s, which the
# run before a stop (≤ 60 s with everything else) has no room for.
CI_ONLY = {"gradient_checkpointed"}
# CI's slow tier measures these, its fast tier the rest: with no compiled program kept, their
# set-up is half the guard's (fit_step 91 s, gradient_checkpointed 28 s of 210 s, load 2), and
# the fast tier has 10 minutes on 2 cores for everything.
LONGEST_SET_UP = ("fit_step", "gradient_checkpointed")


# ---------------------------------------------------------------------------- measuring
def _block(value):
    import jax

    return jax.block_until_ready(value)


# A repeat of a quick check takes this long at least, in rounds of one call per side: five single
# calls read P1's ratio anywhere in 1.08-1.27 over six runs (668812d); rounds of ~20 ms of calls
# back to back 1.11-1.22 in four runs of ed35730 (their mean carries the slow calls' tail), where
# ~340 single calls alternating read 1.09-1.12 in five (2026-12-06).
ROUND_SECONDS = 0.02


def _rounds_per_repeat(numerator, denominator) -> int:
    """Rounds of one call of each side per repeat: enough that the quicker side's calls take
    ``ROUND_SECONDS`` (one round for the checks that take longer)."""
    once = []
    for fn in (numerator, denominator):
        began = time.perf_counter()
        _block(fn())
        once.append(time.perf_counter() - began)
    return max(1, min(100, int(ROUND_SECONDS / max(min(once), 1e-6))))


def measure(names, repeats: int = 5) -> dict[str, float]:
    """Each named check's ratio: the calls compiled (first call), then rounds of one call each,
    numerator and denominator alternately, each check's in turn: ``repeats`` rounds, times as
    many as fill :data:`ROUND_SECONDS` for a quick check; median ÷ median of the single calls.

    A check's rounds run together, not interleaved with the other checks': interleaved, each
    call followed another check's and found the memory it needs freshly returned to the system,
    and P1's ratio with the default ``fold`` read 1.96–3.28 in the guard where the same two
    calls alone read 1.30 (the code of 85496b0 measured the same, 2026-11-29)."""
    pairs, setup = {}, {}
    for name in names:
        if name == "compile":
            continue
        began = time.perf_counter()
        numerator, denominator = CHECKS[name]()
        _block(numerator())
        _block(denominator())
        pairs[name] = (numerator, denominator, [], [])
        setup[name] = time.perf_counter() - began
    for numerator, denominator, top, bottom in pairs.values():
        for _ in range(repeats * _rounds_per_repeat(numerator, denominator)):
            for fn, times in ((numerator, top), (denominator, bottom)):
                began = time.perf_counter()
                _block(fn())
                times.append(time.perf_counter() - began)
    ratios = {name: statistics.median(top) / statistics.median(bottom) for name, (_, _, top, bottom) in pairs.items()}
    print("set-up (compilation or cache reads) [s]:", {name: round(seconds, 1) for name, seconds in setup.items()})
    if "compile" in names:
        # ~8 s a round
        ratios["compile"] = compile_ratio(rounds=min(5, max(3, repeats // 2)))
    return ratios


def limits_of(table: dict, ci: bool) -> dict[str, float]:
    """The limit of each ratio (``--ci``: its margin over the ratio measured doubled)."""
    return {name: (2.0 * row["limit"] - row["measured"]) if ci else row["limit"] for name, row in table.items()}


def broken(ratios: dict[str, float], limits: dict[str, float]) -> list[str]:
    """The ratios over their limits, in words."""
    return [
        f"{name} = {ratio:.2f} is over its limit {limits[name]:.2f}"
        for name, ratio in ratios.items()
        if ratio > limits[name]
    ]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ci", action="store_true", help="each limit's margin over 1 doubled (CI's fast tier)")
    parser.add_argument("--only", nargs="+", choices=[*CHECKS, "compile"], help="these checks only")
    parser.add_argument("--repeats", type=int, default=5, help="rounds of timed calls (default 5)")
    parser.add_argument(
        "--record", action="store_true", help="write the ratios measured as guard_limits.json's 'measured'"
    )
    parser.add_argument("--json", type=Path, help="also write the ratios and limits to this file")
    parser.add_argument(
        "--no-confirm", action="store_true", help="fail at once, without measuring a ratio over its limit again"
    )
    args = parser.parse_args(argv)
    table = json.loads(LIMITS.read_text())
    names = args.only or [*(name for name in CHECKS if args.ci or name not in CI_ONLY), "compile"]
    began = time.perf_counter()
    ratios = measure(names, args.repeats)
    limits = limits_of(table, args.ci)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    import peeljax

    print(f"peeljax {peeljax.__version__} from {Path(peeljax.__file__).parent}")
    print(f"{'ratio':<24} {'measured':>9} {'limit':>7}   (load {load:.2f}, {time.perf_counter() - began:.0f} s)")
    for name, ratio in ratios.items():
        print(f"{name:<24} {ratio:>9.2f} {limits[name]:>7.2f}   {table[name]['what']}")
    failures = broken(ratios, limits)
    if failures and not args.no_confirm:
        # A ratio over its limit is measured again, alone and with three times the rounds: a busy
        # machine (CI's fast tier runs beside another test worker) rarely slows the same check
        # twice, while a real slowdown is over its limit both times.
        again = [name for name in ratios if ratios[name] > limits[name]]
        print(f"confirming {', '.join(again)} with {3 * args.repeats} rounds")
        confirmed = {k: v for name in again for k, v in measure([name], 3 * args.repeats).items()}
        for name in again:
            print(f"{name:<24} {confirmed[name]:>9.2f} {limits[name]:>7.2f}   (confirmation)")
        ratios.update(confirmed)
        failures = broken(ratios, limits)
    if args.record:
        for name, ratio in ratios.items():
            table[name]["measured"] = round(ratio, 2)
        LIMITS.write_text(json.dumps(table, indent=2, ensure_ascii=False) + "\n")
    if args.json:
        args.json.write_text(json.dumps({"ratios": ratios, "limits": limits, "load": load}, indent=2))
    for failure in failures:
        print(f"guard: {failure}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
