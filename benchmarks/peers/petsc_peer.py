"""PETSc TSALPHA (generalized-α for first-order systems, ρ∞ = peeljax's ρ) through ``petsc_tsalpha.py``.

petsc4py lives in another interpreter (``PETSC_PYTHON``, default ``/usr/bin/python3``): the peer
runs ``petsc_tsalpha.py`` there and talks JSON to it, so its times include ψ and a finite-difference
Jacobian in Python and one JSON round trip.

* (P1/P2) :class:`PetscAlphaPeer`: TSALPHA with its own error control (TSAdapt basic) on
  z = (α, ω, u, log v), v at ``GRID`` by TSInterpolate, in a long-lived ``--serve`` subprocess;
* (P3) :func:`petsc_tsalpha`: TSALPHA on fixed steps (the uniform mesh's N) over a few trajectories.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from compare_problems import GRID, T_FINAL, V, one_line

from peers import NotRun, Peer

HERE = Path(__file__).resolve().parent  # benchmarks/peers/, where petsc_tsalpha.py is
PETSC_DT0 = 1e-8  # TSALPHA's first step [s]; TSAdapt basic grows it by at most 10× a step


class PetscAlphaPeer(Peer):
    """PETSc TSALPHA with TSAdapt basic on z = (α, ω, u, log v), in a ``petsc_tsalpha.py --serve`` subprocess."""

    name = "petsc4py TSALPHA, TSAdapt basic (log v)"
    setting_name = "rtol"

    def prepare(self):
        import json
        import subprocess

        import peeljax

        self._json = json
        self.radius = float(peeljax.AlphaMethod().rho)
        python, script = petsc_python(), str(HERE / "petsc_tsalpha.py")
        try:
            check = subprocess.run([python, script, "--check"], check=False, capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.SubprocessError) as error:
            raise NotRun(f"{python} cannot be run ({one_line(error)})") from error
        if check.returncode != 0:
            last = (check.stderr.strip().splitlines() or ["?"])[-1]
            raise NotRun(f"petsc4py not installed ({python}: {last[:80]})")
        command = [python, script, "--serve"]
        self._proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.version = json.loads(self._proc.stdout.readline())["petsc"]
        self.stats = {}

    def run(self, rtol):
        request = {"V": V, "tau": self.tau, "rtol": rtol, "atol": 1e-2 * rtol, "grid": GRID.tolist(),
                   "radius": self.radius, "dt0": PETSC_DT0}  # fmt: skip
        self._proc.stdin.write(self._json.dumps(request) + "\n")
        self._proc.stdin.flush()
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"petsc_tsalpha.py --serve ended (exit code {self._proc.poll()})")
        result = self._json.loads(line)
        if result["v"] is None:
            raise RuntimeError(result["status"])
        self.stats[rtol] = result
        return np.array([np.nan if a is None else a for a in result["v"]], float)

    def run_stats(self, rtol):
        r = getattr(self, "stats", {}).get(rtol)
        return None if r is None else {k: r[k] for k in ("steps", "rejected", "snes_iterations", "snes_failures")}

    def info(self):
        return {"stats": "petsc", "version": getattr(self, "version", "?"), "radius": getattr(self, "radius", None)}

    def close(self):
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            proc.stdin.write("\n")
            proc.stdin.flush()
            proc.wait(timeout=60)


def petsc_python():
    return os.environ.get("PETSC_PYTHON", "/usr/bin/python3")


def petsc_tsalpha(pairs, n, radius):
    """PETSc TSALPHA in a subprocess (``petsc_tsalpha.py``); (v rows, seconds per run, statuses), or an error text."""
    import json
    import subprocess
    import tempfile

    script = HERE / "petsc_tsalpha.py"
    python = petsc_python()
    try:
        check = subprocess.run([python, str(script), "--check"], check=False, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError) as error:
        return f"unavailable: {python} cannot be run ({one_line(error)}); not run here"
    if check.returncode != 0:
        last = (check.stderr.strip().splitlines() or ["?"])[-1]
        return f"unavailable: petsc4py not installed ({python}: {last[:80]}); not run here"
    with tempfile.TemporaryDirectory() as tmp:
        jobs, out = Path(tmp) / "jobs.json", Path(tmp) / "out.json"
        every = n // (GRID.size - 1)
        jobs.write_text(json.dumps({"jobs": [list(map(float, p)) for p in pairs], "n_steps": n,
                                    "t_final": T_FINAL, "every": every, "radius": radius}))  # fmt: skip
        command = [python, str(script), str(jobs), str(out)]
        done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["?"])[-1]
            return f"failed: {last[:100]}"
        result = json.loads(out.read_text())
    runs = result["runs"]
    v = np.array([[np.nan if a is None else a for a in (r["v"] or [None] * GRID.size)] for r in runs], float)
    seconds = np.array([np.nan if r["seconds"] is None else r["seconds"] for r in runs])
    return v, seconds, [r["status"] for r in runs], result["petsc"]
