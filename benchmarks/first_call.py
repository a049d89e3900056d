"""What a user waits for before the first result: a fresh process, with an empty and with a warm compilation cache.

Each case runs in a new Python process whose JAX persistent compilation cache
(``PEELJAX_COMPILATION_CACHE``) is an empty folder ("empty cache") or the folder a first run of
the same case filled ("cache warm": the compiled programs, and the traced ones peeljax keeps
beside them, ``peeljax._exported``). JAX's own monitoring events split the first call into
tracing (Python into a jaxpr), lowering (jaxpr into MLIR) and XLA's compilation (or the
cache's read); ``wall`` is the whole first call, import of peeljax excluded:

* ``forward``: ``simulate(V=1.1, tau=0, t_final=1)`` (the README's first command);
* ``gradient through jumps``: ``jax.grad`` of the sum of the first 30 jump times w.r.t. c1
  (τ = 0, 3 s, 210 jumps; the guard's);
* ``first orbit``: ``periodic_orbit(V=1.1)``;
* and the command lines ``peeljax simulate --V 1.1 --tau 0 --t-final 1`` and ``peeljax orbit
  --V 1.1`` as a user types them (wall time of the process, import included).

    python benchmarks/first_call.py          # ~3 min on 2 cores; writes results/first_call.md
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_model, write_result  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

_CASE = """
import json, sys, time
from jax import monitoring
phases = {"trace": 0.0, "lower": 0.0, "compile": 0.0}
names = {"jaxpr_trace_duration": "trace", "jaxpr_to_mlir_module_duration": "lower", "backend_compile_duration": "compile"}
def listen(event, seconds, **kwargs):
    name = names.get(event.rsplit("/", 1)[-1])
    if name:
        phases[name] += seconds
monitoring.register_event_duration_secs_listener(listen)
import jax, jax.numpy as jnp, numpy as np, equinox as eqx
import peeljax as pj
case = sys.argv[1]
if case == "forward":
    call = lambda: pj.simulate(V=1.1, tau=0, t_final=1.0).ys
elif case == "gradient through jumps":
    def jump_times(c1):
        law = eqx.tree_at(lambda a: a.c1, pj.AdhesionLaw(), c1)
        sol = pj.simulate(pj.PeelingModel(adhesion=law), V=1.1, tau=0, t_final=3.0, ts=np.array([0.0, 3.0]), max_jumps=512)
        return jnp.sum(sol.jumps.t[:30])
    call = lambda: jax.jit(jax.grad(jump_times))(400.0)
else:
    call = lambda: pj.periodic_orbit(V=1.1).period
began = time.perf_counter()
jax.block_until_ready(call())
print(json.dumps({"wall": time.perf_counter() - began, **phases}))
"""

CASES = ("forward", "gradient through jumps", "first orbit")
COMMANDS = {
    "peeljax simulate --V 1.1 --tau 0 --t-final 1": ["simulate", "--V", "1.1", "--tau", "0", "--t-final", "1"],
    "peeljax orbit --V 1.1": ["orbit", "--V", "1.1"],
}


def _environment(folder: str) -> dict:
    env = {key: value for key, value in os.environ.items() if not key.startswith("JAX_COMPILATION_CACHE")}
    env["PEELJAX_COMPILATION_CACHE"] = folder
    return env


def _case(case: str, folder: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", _CASE, case], env=_environment(folder), capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.splitlines()[-1])


def _command(argv: list[str], folder: str) -> float:
    began = time.perf_counter()
    script = "import sys; from peeljax.cli import main; sys.exit(main(sys.argv[1:]))"
    subprocess.run(
        [sys.executable, "-c", script, *argv],
        env=_environment(folder),
        capture_output=True,
        check=True,
        cwd=tempfile.gettempdir(),
    )
    return time.perf_counter() - began


def main() -> None:
    rows = []
    load = [os.getloadavg()[0]]
    for case in CASES:
        with tempfile.TemporaryDirectory() as folder:
            empty, warm = _case(case, folder), _case(case, folder)
        rows.append(
            f"| {case} | {empty['trace']:.1f} / {empty['lower']:.1f} / {empty['compile']:.1f} | {empty['wall']:.1f} "
            f"| {warm['trace']:.1f} / {warm['lower']:.1f} / {warm['compile']:.1f} | {warm['wall']:.1f} |"
        )
        print(rows[-1], flush=True)
    commands = []
    for name, argv in COMMANDS.items():
        with tempfile.TemporaryDirectory() as folder:
            empty, warm = _command(argv, folder), _command(argv, folder)
        commands.append(f"| `{name}` | {empty:.1f} | {warm:.1f} |")
        print(commands[-1], flush=True)
    load.append(os.getloadavg()[0])
    text = "\n".join(
        [
            "# The first call: fresh processes, empty and warm compilation cache",
            "",
            f"{cpu_model()}, {os.cpu_count()} cores; load average {min(load):.2f}–{max(load):.2f}. "
            "Seconds; trace / lower / compile are JAX's monitoring events summed over the call "
            "(compile: XLA's compilation or the cache's read).",
            "",
            "| first call | empty cache: trace / lower / compile | wall | cache warm: trace / lower / compile | wall |",
            "|---|---|---|---|---|",
            *rows,
            "",
            "| command (a new process, import included) | empty cache | cache warm |",
            "|---|---|---|",
            *commands,
            "",
        ]
    )
    print(write_result(RESULTS / "first_call.md", text))


if __name__ == "__main__":
    main()
