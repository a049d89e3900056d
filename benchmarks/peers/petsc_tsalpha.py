"""PETSc TSALPHA (generalized-α for first-order systems, through petsc4py) on eq. ``hv``: a peer of ``compare.py``.

Run by ``compare.py`` in a subprocess with another interpreter (``PETSC_PYTHON``, default
``/usr/bin/python3``): petsc4py is not installable into the project's venv. It needs only numpy and
petsc4py: ψ is written out below in z = (α, ω, u, log v) like the other "(log v)" peers, its Newton
matrix by central differences; :func:`import_petsc4py` finds Debian's ``python3-petsc4py``.

    python3 petsc_tsalpha.py --check              # exit 0 if numpy and petsc4py import
    python3 petsc_tsalpha.py jobs.json out.json   # fixed steps: run the jobs, write the results
    python3 petsc_tsalpha.py --serve              # error control: one JSON request per line

jobs.json: {"jobs": [[V, tau], ...], "n_steps": N, "t_final": T, "every": k, "radius": ρ∞}.
out.json: {"petsc": version, "runs": [{"v": [v every k steps, NaN after a stop], "seconds": s,
"status": "ok" | "stopped near t = …" | "failed: …"}, ...]}.

--serve: first prints {"petsc": version}; then for each line {"V", "tau", "rtol", "atol",
"grid": [t_0 = 0, …, t_final], "radius", "dt0"} runs TSALPHA with ``-ts_adapt_type basic`` and prints
{"v": v at the grid times, "seconds", "status", "steps", "rejected", "snes_iterations",
"snes_failures"}. An empty line ends it.
"""

from __future__ import annotations

import glob
import json
import math
import os
import sys
import time

R, INERTIA, K = 0.1, 1e-2, 1000.0  # the paper geometry: R, I, k/l
NAMES = ("c1", "p1", "c2", "p2", "c3", "c4", "c5", "p5", "c6", "c7", "p7", "c8", "p8", "p9")
PAPER = dict(zip(NAMES, (400.0, 0.35, 110.0, 0.15, 130.0, 11.0, 2.0, 1.5, 415.0, 45.0, 0.4, 0.35, 2.15, 0.5)))


def phi_and_slope(v, V, c=PAPER):
    """φ(v, V) and ∂φ/∂v (v > 0)."""
    C6 = c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]
    e = math.exp(v / c["c4"])
    phi = c["c1"] * v ** c["p1"] + c["c2"] * v ** c["p2"] + c["c3"] * e - c["c5"] * V ** c["p5"] - C6 * v ** c["p9"]
    slope = (
        c["c1"] * c["p1"] * v ** (c["p1"] - 1)
        + c["c2"] * c["p2"] * v ** (c["p2"] - 1)
        + c["c3"] / c["c4"] * e
        - C6 * c["p9"] * v ** (c["p9"] - 1)
    )
    return phi, slope


def psi_z(z, V, tau):
    """z' = (f, ψ_v/v) with ψ_v = −F̃·f/J_t, J_t = −φ_v + τ·F̃·(𝐈 − τ·f_x)⁻¹·f_v (eq. ``hv``)."""
    import numpy as np

    al, om, u, v = z[0], z[1], z[2], math.exp(z[3])
    s, c = math.sin(al), math.cos(al)
    slip = om - v / R
    f = np.array([slip, -R * K * u * s / INERTIA, R * s * slip + V - v])
    f_x = np.array([[0.0, 1.0, 0.0], [-R * K * u * c / INERTIA, 0.0, -R * K * s / INERTIA], [R * c * slip, R * s, 0.0]])
    f_v = np.array([-1.0 / R, 0.0, -s - 1.0])
    F_tilde = np.array([K * u * c, 0.0, K * (1.0 + s)])
    _, phi_v = phi_and_slope(v, V)
    w = np.linalg.solve(np.eye(3) - tau * f_x, f_v)
    J = -phi_v + tau * F_tilde @ w
    return np.array([f[0], f[1], f[2], -(F_tilde @ f) / J / v])


def initial_z(V):
    """The paper's start: v0 = 1e-10·V, ω0 = v0/R, α0 = (π/4)·1e-8, u0 from (sac); z = (α, ω, u, log v)."""
    v0, al0 = 1e-10 * V, 0.25 * math.pi * 1e-8
    phi, _ = phi_and_slope(v0, V)
    return [al0, v0 / R, phi / (1.0 + math.sin(al0)) / K, math.log(v0)]


def import_petsc4py():
    """petsc4py, initialised; on Debian without ``PETSC_DIR`` or the ``/usr/lib/petsc`` alternative,
    from the first build under ``/usr/lib/petscdir`` (real numbers preferred)."""
    try:
        import petsc4py
    except ImportError:
        roots = [os.environ["PETSC_DIR"]] if os.environ.get("PETSC_DIR") else []
        roots += ["/usr/lib/petscdir/petsc-real", *sorted(glob.glob("/usr/lib/petscdir/*/*-real")),
                  *sorted(glob.glob("/usr/lib/petscdir/*"))]  # fmt: skip
        for root in roots:
            path = os.path.join(root, "lib", "python3", "dist-packages")
            if os.path.isdir(os.path.join(path, "petsc4py")):
                sys.path.append(path)
                break
        import petsc4py
    petsc4py.init([sys.argv[0]])
    from petsc4py import PETSc

    return PETSc


_PREFIXES = [0]


def make_ts(PETSc, np, V, tau, radius, adapt):
    """A TSALPHA on z' = ψ(z) (implicit form F = ż − ψ(z)), LU on the 4×4 Newton matrix.

    ``adapt``: "none" (fixed steps) or "basic" (TSAdapt basic), set through the options database
    under a prefix of its own (petsc4py 3.18 has no TS.getAdapt).
    """
    ts = PETSc.TS().create(comm=PETSc.COMM_SELF)
    ts.setType("alpha")
    _PREFIXES[0] += 1
    prefix = f"peel{_PREFIXES[0]}_"
    ts.setOptionsPrefix(prefix)
    options = PETSc.Options()
    options[f"{prefix}ts_adapt_type"] = adapt
    ts.setFromOptions()
    del options[f"{prefix}ts_adapt_type"]
    ts.setProblemType(PETSc.TS.ProblemType.NONLINEAR)
    residual = PETSc.Vec().createSeq(4, comm=PETSc.COMM_SELF)
    matrix = PETSc.Mat().createDense([4, 4], comm=PETSc.COMM_SELF)
    matrix.setUp()

    def ifunction(ts, t, x, xdot, F):
        F.setArray(xdot.getArray(readonly=True) - psi_z(x.getArray(readonly=True), V, tau))

    def ijacobian(ts, t, x, xdot, shift, A, P):
        z = np.array(x.getArray(readonly=True))
        jac = np.empty((4, 4))
        for j in range(4):
            e = 1e-7 * max(1.0, abs(z[j]))
            zp, zm = z.copy(), z.copy()
            zp[j] += e
            zm[j] -= e
            jac[:, j] = (psi_z(zp, V, tau) - psi_z(zm, V, tau)) / (2 * e)
        P.setValues(range(4), range(4), (shift * np.eye(4) - jac).ravel())
        P.assemble()
        if A != P:
            A.assemble()

    ts.setIFunction(ifunction, residual)
    ts.setIJacobian(ijacobian, matrix, matrix)
    ts.setAlphaRadius(radius)
    ts.getSNES().getKSP().setType("preonly")
    ts.getSNES().getKSP().getPC().setType("lu")
    return ts, (residual, matrix)


def run_adaptive(PETSc, np, V, tau, grid, rtol, atol, radius, dt0):
    """TSALPHA with TSAdapt basic at (rtol, atol); v at the ``grid`` times by TSInterpolate."""
    grid = np.asarray(grid, float)
    saved = np.full(grid.size, np.nan)
    z0 = initial_z(V)
    state = {"t": 0.0, "next": 0}
    work = PETSc.Vec().createSeq(4, comm=PETSc.COMM_SELF)

    def monitor(ts, step, t, x):
        k = state["next"]
        while k < grid.size and grid[k] <= t:
            if grid[k] == t or step == 0:
                saved[k] = math.exp(x.getArray(readonly=True)[3])
            else:
                ts.interpolate(grid[k], work)
                saved[k] = math.exp(work.getArray(readonly=True)[3])
            k += 1
        state["next"], state["t"] = k, t

    started = time.perf_counter()
    ts, keep = make_ts(PETSc, np, V, tau, radius, "basic")
    ts.setTolerances(rtol=rtol, atol=atol)
    ts.setTime(0.0)
    ts.setTimeStep(dt0)
    ts.setMaxSteps(10_000_000)
    ts.setMaxTime(float(grid[-1]))
    ts.setExactFinalTime(PETSc.TS.ExactFinalTime.MATCHSTEP)
    ts.setMaxStepRejections(-1)  # a rejected step is retried smaller (PETSc's default stops after 10 in one step)
    ts.setMaxSNESFailures(-1)  # a failed Newton solve too (the adaptor cuts the step by 4)
    ts.setMonitor(monitor)
    x = PETSc.Vec().createSeq(4, comm=PETSc.COMM_SELF)
    x.setArray(z0)
    try:
        ts.solve(x)
        reason = ts.getConvergedReason()
        if reason > 0 and state["next"] == grid.size - 1 and abs(ts.getTime() - grid[-1]) <= 1e-12 * grid[-1]:
            saved[-1] = math.exp(x.getArray(readonly=True)[3])  # the last step ended a rounding error short
        done = reason > 0 and np.isfinite(saved).all()
        status = "ok" if done else f"stopped near t = {state['t']:.3g} s (reason {reason})"
    except Exception as error:  # noqa: BLE001 (a PETSc error ends the run)
        status = f"stopped near t = {state['t']:.3g} s ({type(error).__name__})"
    seconds = time.perf_counter() - started
    stats = {"steps": ts.getStepNumber(), "rejected": ts.getStepRejections(),
             "snes_iterations": ts.getSNESIterations(), "snes_failures": ts.getSNESFailures()}  # fmt: skip
    for obj in (ts, *keep, x, work):
        obj.destroy()
    return {"v": [None if not math.isfinite(a) else a for a in saved], "seconds": seconds, "status": status, **stats}


def serve(PETSc, np):
    """Answer one JSON request per stdin line (see the module's docstring) until an empty line."""
    version = ".".join(str(n) for n in PETSc.Sys.getVersion())
    print(json.dumps({"petsc": version}), flush=True)
    for line in sys.stdin:
        if not line.strip():
            break
        job = json.loads(line)
        try:
            result = run_adaptive(PETSc, np, job["V"], job["tau"], job["grid"], job["rtol"], job["atol"],
                                  job.get("radius", 0.0), job.get("dt0", 1e-8))  # fmt: skip
        except Exception as error:  # noqa: BLE001 (reported per request)
            result = {"v": None, "seconds": None, "status": f"failed: {type(error).__name__}: {error}"[:120]}
        print(json.dumps(result), flush=True)
    return 0


def run_one(PETSc, np, V, tau, n_steps, t_final, every, radius):
    dt = t_final / n_steps
    saved = np.full(n_steps // every + 1, np.nan)
    z0 = initial_z(V)
    saved[0] = math.exp(z0[3])
    last = {"t": 0.0}

    def monitor(ts, step, t, x):
        last["t"] = t
        if step % every == 0 and step // every < saved.size:
            saved[step // every] = math.exp(x.getArray(readonly=True)[3])

    ts, keep = make_ts(PETSc, np, V, tau, radius, "none")
    ts.setTime(0.0)
    ts.setTimeStep(dt)
    ts.setMaxSteps(n_steps)
    ts.setMaxTime(t_final)
    ts.setExactFinalTime(PETSc.TS.ExactFinalTime.MATCHSTEP)
    ts.setMonitor(monitor)
    x = PETSc.Vec().createSeq(4, comm=PETSc.COMM_SELF)
    x.setArray(z0)
    started = time.perf_counter()
    try:
        ts.solve(x)
        reason = ts.getConvergedReason()
        status = "ok" if reason > 0 and np.isfinite(saved).all() else f"stopped near t = {last['t']:.3g} s"
    except Exception as error:  # noqa: BLE001 (a diverged nonlinear solve ends the run)
        status = f"stopped near t = {last['t']:.3g} s ({type(error).__name__})"
    seconds = time.perf_counter() - started
    for obj in (ts, *keep, x):
        obj.destroy()
    return {"v": [None if not math.isfinite(a) else a for a in saved], "seconds": seconds, "status": status}


def main(argv):
    import numpy as np

    PETSc = import_petsc4py()
    if argv[:1] == ["--check"]:
        return 0
    if argv[:1] == ["--serve"]:
        return serve(PETSc, np)
    with open(argv[0]) as file:
        jobs = json.load(file)

    runs = []
    for V, tau in jobs["jobs"]:
        try:
            runs.append(run_one(PETSc, np, V, tau, jobs["n_steps"], jobs["t_final"], jobs["every"], jobs["radius"]))
        except Exception as error:  # noqa: BLE001 (reported per run)
            runs.append({"v": None, "seconds": None, "status": f"failed: {type(error).__name__}: {error}"[:120]})
    version = ".".join(str(n) for n in PETSc.Sys.getVersion())
    with open(argv[1], "w") as out:
        json.dump({"petsc": version, "runs": runs}, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
