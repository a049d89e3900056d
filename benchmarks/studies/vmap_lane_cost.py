"""The V-map's cost per lane, per core: ``peeljax.sweep`` against looped event-driven peers at equal accuracy.

The V-map of the stick-slip problem: ``--n-v`` (200) values of V in [0.2, 8] m/s, τ = 0 (the DAE,
v jumping at φ's folds), t ∈ [0, 3] s each. Each peer computes the jump times of every lane:

* ``peeljax.sweep(V=…, tau=0, grid="pairs", rtol=…, max_jumps=8192, max_steps=400_000)``, all
  lanes in one call over the JAX CPU devices (one per core; on a CPU each device runs its lanes
  one after another, ``lane_batch`` 1);
* ``peeljax.simulate(V, tau=0, rtol=…)`` called once per V (one compiled program, V traced), one
  core: the same trajectories without the sweep (``peers/vmap_peers.py``);
* scipy ``solve_ivp`` LSODA with a terminal event at the fold, restarted after each jump, looped
  over V, one core (``jump_peers.scipy_events_run``, plain-Python right-hand side);
* SUNDIALS CVODE (BDF, scikit-sundae) with rootfinding (``eventsfn``), re-initialized on the host
  after each jump, looped over V, one core (the same plain-Python right-hand side);
* CasADi cvodes with CasADi 3.8's experimental events (all jumps in one call, V a parameter), looped
  over V, one core, in a worker process (its event iteration can hang: each call has a time limit).

**Accuracy** (what the V-map is for: the jumps of each lane, from which its stick-slip statistics
come): a lane is right to the target when every jump time in [0, 3] s is within ``--target``
(1e-3 s) of the reference's, jump by jump (the same jumps; the one difference allowed is a jump
within the target of t = 3 s that one run has and the other has not yet). The reference is
``tests/jump_reference.py`` (scipy LSODA events with the arclength refinement near each fold) at
rtol 1e-12, atol 1e-14, run on the calibration V (two processes, untimed).

**Protocol.** (1) Calibration: each peer runs its ladder of rtol (half decades, atol = 1e-3·rtol)
from loose to tight on the calibration V (default 0.2, 1.1, 2, 3, 3.9, 4.6, 5, 8 m/s: stick-slip
weak to strong, then none above ≈ 5.3), hardest lane first; a rung stops at its first lane over the
target; the peer's setting is the first (loosest) rung with every lane within the target, and its
error is the max over those lanes. A second calibration leaves ``--leave-out`` V out (default 5:
there LSODA and CVODE add a small cycle where a burst ends at a grazing fold, down to rtol 3e-7 and
1e-8, which alone decides their setting); it reuses the first one's runs, and its settings are timed
too, in a second table. peeljax's rung is found with ``simulate`` (each sweep lane is
the run ``simulate`` makes). (2) Set-up apart: compilation (``simulate``: its first call minus a
warm one; the sweep: a first sweep of all lanes at V = 8, no fold, minus a second), building the
solver objects (CVODE: one per rtol, CasADi: one integrator per rtol), each in its own column.
(3) Timing: ``--repeats`` (3) rounds, round-robin over the peers: the sweep over all n lanes, the
loops over ``--subset`` (10) evenly spaced lanes of the map (extrapolated: their mean cost per lane
stands for the map's); medians. Per lane: wall s / lanes; core-seconds per lane: wall × the cores
the call used (the sweep: its JAX devices; a loop: 1), beside the process CPU time measured
(user + system, all threads). Ratio: core-s per lane / the sweep's.

    python benchmarks/studies/vmap_lane_cost.py           # ~10 min on 2 shared cores -> results/vmap_lane_cost.md (+ .json)
    python benchmarks/studies/vmap_lane_cost.py --quick   # 40 lanes, 4 calibration V -> results/vmap_lane_cost_quick.md
    python benchmarks/studies/vmap_lane_cost.py --tiny --out /tmp/x.md   # the test's run (4 lanes; XLA unoptimized)
    python benchmarks/studies/vmap_lane_cost.py --report-only benchmarks/studies/results/vmap_lane_cost.json   # the report alone
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine, compare_problems, peers
from machine import command, cpu_model, made_by
from peers.jump_peers import ATOL_RATIO, T_FINAL
from peers.vmap_peers import CvodeEvents, Isolated, PeeljaxSimulate, ScipyLoop, reference_jumps

V_RANGE = (0.2, 8.0)
CALIBRATION_V = (0.2, 1.1, 2.0, 3.0, 3.9, 4.6, 5.0, 8.0)
QUICK_CALIBRATION_V = (1.1, 3.0, 4.6, 8.0)
TINY_CALIBRATION_V = (1.1, 8.0)
REF_RTOL, REF_ATOL = 1e-12, 1e-14
MAX_JUMPS, MAX_STEPS = 8192, 400_000
LADDER = (1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7, 3e-8, 1e-8, 3e-9, 1e-9)
TINY_LADDER = (1e-5, 1e-6)
CASADI_CALL_LIMIT = 20.0  # s: a CasADi call longer than this is taken as hung (killed, the worker restarted)
PEERS = ("sweep", "simulate", "lsoda", "cvode", "casadi")
NAMES = {
    "sweep": "peeljax.sweep (all lanes, every core)",
    "simulate": "peeljax.simulate loop",
    "lsoda": "scipy LSODA events loop",
    "cvode": "SUNDIALS CVODE (BDF) + rootfinding loop",
    "casadi": "CasADi cvodes + events loop",
}
LOADS = []


def log(message):
    print(f"  [{message}]", file=sys.stderr, flush=True)


def load():
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def jump_error(jumps, reference, target):
    """max |Δt| over the jumps, matched in order; ∞ if the jumps differ by more than one near t = T."""
    jumps, reference = np.asarray(jumps, dtype=float), np.asarray(reference, dtype=float)
    n = min(jumps.size, reference.size)
    unmatched = np.concatenate([jumps[n:], reference[n:]])
    if unmatched.size > 1 or (unmatched.size and unmatched[0] < T_FINAL - target):
        return math.inf
    return float(np.max(np.abs(jumps[:n] - reference[:n]))) if n else 0.0


# --------------------------------------------------------------------------- the sweep
def run_sweep(Vs, rtol):
    import peeljax

    return peeljax.sweep(
        V=np.asarray(Vs, dtype=float), tau=0, t_final=T_FINAL, grid="pairs", rtol=rtol, atol=ATOL_RATIO * rtol,
        chunk=len(Vs), max_jumps=MAX_JUMPS, max_steps=MAX_STEPS, progress=False,
    )  # fmt: skip


def sweep_lanes(result):
    counts = result.jumps["jump_count"]
    return [np.asarray(result.jumps["jump_t"][i][: counts[i]]) for i in range(len(counts))]


# --------------------------------------------------------------------------- calibration
def run_lane(peer, V, rtol, reference, target):
    """One calibration run: {"error", "failure" (None or why it misses), "seconds"}."""
    started = time.perf_counter()
    try:
        jumps = peer.run(V, rtol)
    except Exception as error:  # noqa: BLE001 (a failing lane is reported)
        kind = "" if type(error).__name__ == "WorkerFailed" else f"{type(error).__name__}: "
        why = f"{kind}{' '.join(str(error).split())[:90]}"
        return {"error": math.inf, "failure": why, "seconds": time.perf_counter() - started}
    seconds = time.perf_counter() - started
    error = jump_error(jumps, reference, target)
    return {"error": error, "failure": None if error <= target else describe_miss(jumps, reference, target),
            "seconds": seconds}  # fmt: skip


def calibrate(key, peer, references, Vs, target, ladder, cap, cache):
    """The ladder loose → tight on ``Vs`` (hardest first); stops at the first rung meeting the target on all.

    ``cache`` holds the runs already made, by (V, rtol): a second calibration on fewer V reuses them.
    """
    entry = {"key": key, "name": NAMES[key], "rungs": [], "setting": None}
    order = sorted(Vs, key=lambda V: -references[V].size)
    for rtol in ladder:
        rung = {"rtol": rtol, "errors": {}, "seconds": 0.0, "failure": None, "reused": 0}
        for V in order:
            if (V, rtol) in cache:
                rung["reused"] += 1
            else:
                cache[(V, rtol)] = run_lane(peer, V, rtol, references[V], target)
            lane = cache[(V, rtol)]
            rung["seconds"] += lane["seconds"]
            rung["errors"][f"{V:g}"] = lane["error"]
            if lane["failure"] is not None:
                rung["failure"] = f"V = {V:g}: {lane['failure']}"
                break
        rung["ok"] = rung["failure"] is None
        rung["error"] = max(rung["errors"].values()) if rung["ok"] else math.inf
        entry["rungs"].append(rung)
        log(f"{key} rtol {rtol:g}: " + (f"ok, error {rung['error']:.2g} s" if rung["ok"] else rung["failure"]))
        if rung["ok"]:
            entry["setting"] = rung
            break
        if rung["seconds"] > cap:
            entry["capped"] = True
            break
    return entry


def describe_miss(jumps, reference, target):
    jumps = np.asarray(jumps)
    if jumps.size != reference.size:
        return f"{jumps.size} jumps, the reference {reference.size}"
    return f"error {jump_error(jumps, reference, target):.2g} s"


# --------------------------------------------------------------------------- timing
def time_round_robin(calls, repeats):
    """``calls``: {key: callable returning (wall s, CPU s)}; ({key: [(wall, cpu)]}, {key: why it failed}).

    A call that raises is reported and left out of the later rounds (and of the times).
    """
    times, failed = {key: [] for key in calls}, {}
    for round_ in range(repeats):
        for key, call in calls.items():
            if key in failed:
                continue
            try:
                times[key].append(call())
            except Exception as error:  # noqa: BLE001 (a peer failing on a timed lane is reported)
                kind = "" if type(error).__name__ == "WorkerFailed" else f"{type(error).__name__}: "
                failed[key] = f"{kind}{' '.join(str(error).split())[:120]}"
                log(f"{key} failed in round {round_ + 1}: {failed[key]}")
        LOADS.append(load())
        log(f"round {round_ + 1}/{repeats} done (load {LOADS[-1]:.1f})")
    return {key: samples for key, samples in times.items() if key not in failed}, failed


def measured(function):
    """Run ``function``; (wall s, process CPU s)."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def call_key(key, rtol):
    return f"{key}@{rtol:g}"


# --------------------------------------------------------------------------- the run
def measure(args):
    import jax

    import peeljax  # noqa: F401 (first: it sets up JAX's CPU devices, one per core)

    started_all = time.perf_counter()
    Vs = np.linspace(*V_RANGE, args.n_v)
    k = min(args.subset, args.n_v)  # the middle lane of each of k equal stretches of the map
    subset = np.unique(np.floor((np.arange(k) + 0.5) * args.n_v / k).astype(int))
    data = {
        "command": command(),
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "load_start": load()},
        "versions": versions(),
        "n_v": args.n_v,
        "subset": subset.tolist(),
        "subset_V": Vs[subset].tolist(),
        "calibration_V": list(args.calibration),
        "target": args.target,
        "repeats": args.repeats,
        "devices": len(jax.devices()),
        "ref_rtol": args.ref_rtol,
        "cap": args.cap,
    }

    # the reference on the calibration V, two processes (untimed)
    started = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with context.Pool(min(2, len(args.calibration))) as pool:
        order = sorted(args.calibration, key=lambda V: -V if V < 5.3 else 0.0)  # the costly ones (most jumps) first
        jobs = [(V, args.ref_rtol, REF_ATOL) for V in order]
        references = dict(zip(order, pool.starmap(reference_jumps, jobs, chunksize=1), strict=True))
    references = {V: references[V] for V in args.calibration}
    data["reference"] = {
        "seconds": time.perf_counter() - started,
        "jumps": {f"{V:g}": int(r.size) for V, r in references.items()},
    }
    log(f"references: {data['reference']['jumps']} jumps in {data['reference']['seconds']:.0f} s")

    # calibration: every calibration V, then (reusing those runs) without the ``--leave-out`` V
    ladder = TINY_LADDER if args.tiny else LADDER
    peers = {
        "simulate": PeeljaxSimulate(ladder, max_steps=MAX_STEPS, max_jumps=MAX_JUMPS),
        "lsoda": ScipyLoop(ladder, "LSODA"),
        "cvode": CvodeEvents(ladder, "BDF"),
        "casadi": Isolated("casadi", ladder, call_limit=CASADI_CALL_LIMIT),
    }
    peers = {key: peer for key, peer in peers.items() if key in args.peers or key == "simulate"}
    tier_V = [list(args.calibration)]
    if args.leave_out:
        tier_V.append([V for V in args.calibration if V not in args.leave_out])
    tiers = [{"V": Vs_tier, "checks": {}} for Vs_tier in tier_V]
    for key, peer in peers.items():
        started = time.perf_counter()
        peer.prepare(ladder)
        log(f"{key}: prepared in {time.perf_counter() - started:.1f} s")
        cache = {}
        for tier in tiers:
            entry = calibrate(key, peer, references, tier["V"], args.target, ladder, args.cap, cache)
            entry["setup_s"] = peer.setup_seconds(entry["setting"]["rtol"]) if entry["setting"] else None
            tier["checks"][key] = entry
    data["calibration_s"] = time.perf_counter() - started_all
    for tier in tiers:
        pj = tier["checks"]["simulate"]["setting"]
        if pj is None:
            raise SystemExit("peeljax met the target at no rung of its ladder: nothing to compare")
        tier["checks"]["sweep"] = {"key": "sweep", "name": NAMES["sweep"], "setting": pj, "rungs": []}

    # the sweep's set-up at each of its settings: a first sweep of all lanes at V = 8 (no fold) minus a second
    data["sweep_setup"] = {}
    for rtol in sorted({tier["checks"]["sweep"]["setting"]["rtol"] for tier in tiers}, reverse=True):
        first = measured(lambda rtol=rtol: run_sweep(np.full(args.n_v, 8.0), rtol))[0]
        second = measured(lambda rtol=rtol: run_sweep(np.full(args.n_v, 8.0), rtol))[0]
        data["sweep_setup"][f"{rtol:g}"] = max(first - second, 0.0)
        log(f"sweep at rtol {rtol:g} compiled in {data['sweep_setup'][f'{rtol:g}']:.1f} s")

    out = {}

    def sweep_call(rtol):
        def call():
            wall, cpu = time.perf_counter(), time.process_time()
            out[call_key("sweep", rtol)] = run_sweep(Vs, rtol)
            return time.perf_counter() - wall, time.process_time() - cpu

        return call

    def loop_call(key, rtol):
        peer = peers[key]

        def call():
            if isinstance(peer, Isolated):
                jumps, wall, cpu = peer.run_many(Vs[subset], rtol)
                out[call_key(key, rtol)] = jumps
                return wall, cpu
            wall, cpu = time.perf_counter(), time.process_time()
            jumps = []
            for V in Vs[subset]:
                try:
                    jumps.append(peer.run(V, rtol))
                except Exception as error:
                    raise RuntimeError(f"V = {V:g}: {type(error).__name__}: {error}") from error
            out[call_key(key, rtol)] = jumps
            return time.perf_counter() - wall, time.process_time() - cpu

        return call

    calls = {}  # one call per (peer, setting), whatever tiers chose it
    for tier in tiers:
        for key, entry in tier["checks"].items():
            if entry["setting"] is not None:
                rtol = entry["setting"]["rtol"]
                entry["timing_key"] = call_key(key, rtol)
                if entry["timing_key"] not in calls:
                    calls[entry["timing_key"]] = sweep_call(rtol) if key == "sweep" else loop_call(key, rtol)
    times, failed = time_round_robin(calls, args.repeats)
    data["timings"] = {}
    for name, why in failed.items():
        data["timings"][name] = {"failure": why}
    for name, samples in times.items():
        sweep = name.startswith("sweep@")
        lanes = args.n_v if sweep else subset.size
        cores = data["devices"] if sweep else 1
        walls = np.array([s[0] for s in samples]) / lanes
        cpus = np.array([s[1] for s in samples]) / lanes
        data["timings"][name] = {
            "lanes": int(lanes),
            "cores": cores,
            "wall_per_lane": float(np.median(walls)),
            "core_s_per_lane": float(np.median(walls * cores)),
            "cpu_per_lane": float(np.median(cpus)),
            "wall_total": [float(s[0]) for s in samples],
        }
    for peer in peers.values():
        peer.close()

    # each sweep: its lanes, and the timed lanes' share of its work
    data["sweeps"] = {}
    for name, result in out.items():
        if not name.startswith("sweep@"):
            continue
        steps = np.asarray(result.accepted_steps, dtype=float) + np.asarray(result.rejected_steps, dtype=float)
        counts = np.asarray(result.jumps["jump_count"], dtype=float)
        data["sweeps"][name] = {
            "completed": int(np.sum(result.completed)),
            "reasons": sorted(set(result.reasons)),
            "total_jumps": int(np.sum(counts)),
            "steps_subset_over_all": float(np.mean(steps[subset]) / np.mean(steps)),
            "jumps_subset_over_all": float(np.mean(counts[subset]) / max(np.mean(counts), 1e-300)),
        }
    # consistency on the timed lanes (first tier): each loop's jumps against the sweep's lanes
    first = tiers[0]["checks"]
    ours = sweep_lanes(out[first["sweep"]["timing_key"]])
    data["consistency"] = []
    for k, i in enumerate(subset):
        row = {"V": float(Vs[i]), "sweep": int(ours[i].size)}
        for key in PEERS[1:]:
            name = first.get(key, {}).get("timing_key")
            if name in out:
                theirs = out[name][k]
                row[key] = (int(np.size(theirs)), jump_error(theirs, ours[i], args.target))
        data["consistency"].append(row)
    data["tiers"] = tiers
    data["leave_out"] = list(args.leave_out)
    data["machine"]["load_end"] = load()
    data["machine"]["loads"] = [data["machine"]["load_start"], *LOADS, data["machine"]["load_end"]]
    data["total_s"] = time.perf_counter() - started_all
    return data


def versions():
    import casadi
    import jax
    import scipy
    import sksundae

    import peeljax

    return (
        f"peeljax {getattr(peeljax, '__version__', '?')}, jax {jax.__version__}, scipy {scipy.__version__}, "
        f"scikit-sundae {sksundae.__version__}, casadi {casadi.__version__}, numpy {np.__version__}, "
        f"Python {sys.version.split()[0]}"
    )


# --------------------------------------------------------------------------- the report
def fmt(x, digits=3):
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.{digits}g}" if x < 1000 else f"{x:.0f}"


def V_list(values):
    return ", ".join(f"{float(V):g}" for V in values)


def tier_title(data, index):
    tier = data["tiers"][index]
    if index == 0:
        return f"Setting calibrated on every calibration V ({V_list(tier['V'])} m/s)"
    return f"Setting calibrated without V = {V_list(data['leave_out'])} ({V_list(tier['V'])} m/s)"


def table(data, index) -> list[str]:
    checks = data["tiers"][index]["checks"]
    timings = data["timings"]
    sweep = timings[checks["sweep"]["timing_key"]]
    sim_key = checks["simulate"].get("timing_key")
    simulate = timings.get(sim_key) if sim_key else None
    simulate = simulate if simulate and "failure" not in simulate else None
    lines = [
        ("| method | rtol | error (s) | lanes timed | s per lane | cores | core-s per lane | CPU s per lane | "
         "/ sweep, per core | / sweep, CPU s | / simulate loop, same lanes | set-up (s) |"),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]  # fmt: skip
    # the sweep's set-up: its compilation, paid by whichever rtol ran first (rtol is traced: one program)
    checks["sweep"]["setup_s"] = max(data["sweep_setup"].values())
    for key in PEERS:
        entry = checks.get(key)
        if entry is None:
            continue
        setting = entry["setting"]
        if setting is None:
            last = entry["rungs"][-1] if entry["rungs"] else None
            why = f"not reached: at rtol {last['rtol']:g} {last['failure']}" if last else "not run"
            if entry.get("capped"):
                why += f" (the ladder stopped: a rung took over {data['cap']:g} s)"
            lines.append(f"| {entry['name']} | – | {why} | | | | | | | | | {fmt(entry.get('setup_s'))} |")
            continue
        t = timings.get(entry.get("timing_key"), {"failure": "not timed"})
        if "failure" in t:
            lines.append(
                f"| {entry['name']} | {setting['rtol']:g} | {setting['error']:.2g} | failed on the timed lanes: "
                f"{t['failure']} | | | | | | | | {fmt(entry.get('setup_s'))} |"
            )
            continue
        lanes = f"{t['lanes']} of {data['n_v']}" + ("" if key == "sweep" else " (extrapolated)")
        vs_sweep = t["core_s_per_lane"] / sweep["core_s_per_lane"]
        vs_sweep_cpu = t["cpu_per_lane"] / sweep["cpu_per_lane"]
        vs_sim = t["core_s_per_lane"] / simulate["core_s_per_lane"] if simulate and key != "sweep" else None
        lines.append(
            f"| {entry['name']} | {setting['rtol']:g} | {setting['error']:.2g} | {lanes} | {fmt(t['wall_per_lane'])} | "
            f"{t['cores']} | {fmt(t['core_s_per_lane'])} | {fmt(t['cpu_per_lane'])} | {vs_sweep:.2g}× | "
            f"{vs_sweep_cpu:.2g}× | {'–' if vs_sim is None else f'{vs_sim:.2g}×'} | {fmt(entry.get('setup_s'))} |"
        )
    sw = data["sweeps"][checks["sweep"]["timing_key"]]
    lines += [
        "",
        (f"The sweep at rtol {checks['sweep']['setting']['rtol']:g}: {sw['completed']} of {data['n_v']} lanes "
         f"completed ({', '.join(sw['reasons'])}), {sw['total_jumps']} jumps in all; its error is that of `simulate` "
         f"at the same rtol (each lane is the run `simulate` makes). The timed lanes take "
         f"{sw['steps_subset_over_all']:.2f}× the map's mean step attempts per lane (peeljax's, from this sweep) and "
         f"have {sw['jumps_subset_over_all']:.2f}× its mean jump count: the extrapolation's bias, as far as peeljax's "
         "work tells."),
        "",
        mix_line(data, index),
    ]  # fmt: skip
    return lines


def mix_line(data, index) -> str:
    """The loops against the sweep with the sweep's cost scaled to the timed lanes' mix of work."""
    checks = data["tiers"][index]["checks"]
    timings = data["timings"]
    factor = data["sweeps"][checks["sweep"]["timing_key"]]["steps_subset_over_all"]
    sweep = timings[checks["sweep"]["timing_key"]]
    sweep_cpu, sweep_core = sweep["cpu_per_lane"] * factor, sweep["core_s_per_lane"] * factor
    cells = []
    for key in PEERS[1:]:
        t = timings.get(checks.get(key, {}).get("timing_key"))
        if t and "failure" not in t:
            cells.append(
                f"{checks[key]['name']} {t['cpu_per_lane'] / sweep_cpu:.2g}× "
                f"({t['core_s_per_lane'] / sweep_core:.2g}× in core-s)"
            )
    return (
        f"Scaled to the timed lanes' mix (the sweep's figures × {factor:.2f}, its step ratio), the sweep costs "
        f"{fmt(sweep_cpu)} CPU s ({fmt(sweep_core)} core-s) a lane; each loop's CPU s per lane over that: "
        + "; ".join(cells)
        + "."
    )


def report(data) -> str:
    n_sub = len(data["subset"])
    lines = [
        made_by(data["command"]),
        "",
        "# The V-map's cost per lane, per core (τ = 0, jumps at φ's folds)",
        "",
        (f"{data['machine']['cpu']}, {data['machine']['cores']} cores shared with other jobs "
         f"(load average {data['machine']['load_start']:.1f} at the start, {data['machine']['load_end']:.1f} at the end; "
         f"after each timed round: {', '.join(f'{x:.1f}' for x in data['machine']['loads'][1:-1])}); {data['versions']}. "
         f"The whole run took {data['total_s'] / 60:.1f} min (calibration {data['calibration_s'] / 60:.1f} min)."),
        "",
        (f"The map: {data['n_v']} V in [{V_RANGE[0]:g}, {V_RANGE[1]:g}] m/s, τ = 0, t ∈ [0, {T_FINAL:g}] s. "
         f"**Accuracy**: every jump time in [0, {T_FINAL:g}] s within {data['target']:g} s of the reference's "
         f"(`tests/jump_reference.py` at rtol {data['ref_rtol']:g}; the same jumps, except one within the target of "
         f"t = {T_FINAL:g} s), on each calibration V ({V_list(data['calibration_V'])} m/s; the reference has "
         f"{', '.join(map(str, data['reference']['jumps'].values()))} jumps there, computed in "
         f"{data['reference']['seconds']:.0f} s on two processes). Setting: the loosest rtol of the ladder "
         f"(half decades, atol = {ATOL_RATIO:g}·rtol) meeting it on every calibration V; error: the max over them."
         + (f" A second calibration leaves V = {V_list(data['leave_out'])} out (reusing the runs of the first): "
            "there the event-located peers add a small stick-slip cycle where a burst ends at a grazing fold "
            "(see the rungs), and that one lane decides their setting." if data["leave_out"] else "")),
        "",
        (f"Timing: medians of {data['repeats']} round-robin rounds over every (peer, setting) of the tables. The sweep "
         f"runs all {data['n_v']} lanes on {data['devices']} JAX CPU devices; each loop runs {n_sub} lanes of the map, "
         f"the middle one of each of {n_sub} equal stretches (V = {', '.join(f'{V:.2f}' for V in data['subset_V'])}), "
         "on one core, **extrapolated**: their mean cost per lane stands for the map's. Core-s per lane: wall per lane "
         "× the cores the call used; CPU: the process's user + system time per lane (all threads). Set-up "
         "(compilation, solver objects) is apart; peeljax's rtol is traced, so one compiled program (one for `simulate`, "
         "one for the sweep) serves every setting, and the column shows that one compilation."),
    ]  # fmt: skip
    for index, tier in enumerate(data["tiers"]):
        lines += ["", f"## {tier_title(data, index)}", ""]
        same = index > 0 and all(
            (entry["setting"] or {}).get("rtol") == (data["tiers"][0]["checks"][key]["setting"] or {}).get("rtol")
            for key, entry in tier["checks"].items()
        )
        lines += ["Every peer's setting is the one above: the same table."] if same else table(data, index)
    lines += ["", "## Calibration: every rung tried (error in s; a rung stops at its first lane over the target)"]
    for index, tier in enumerate(data["tiers"]):
        lines += ["", f"{tier_title(data, index)}:", ""]
        for key in PEERS:
            entry = tier["checks"].get(key)
            if entry is None or not entry["rungs"]:
                continue
            cells = []
            for rung in entry["rungs"]:
                if rung["ok"]:
                    per_v = ", ".join(
                        f"{V}: {e:.2g}" for V, e in sorted(rung["errors"].items(), key=lambda i: float(i[0]))
                    )
                    cells.append(f"{rung['rtol']:g}: **ok**, max {rung['error']:.2g} ({per_v})")
                else:
                    cells.append(f"{rung['rtol']:g}: {rung['failure']}")
            ran = sum(r["seconds"] for r in entry["rungs"])
            reused = sum(r.get("reused", 0) for r in entry["rungs"])
            tail = f" ({fmt(ran, 2)} s of runs" + (
                f", {reused} of them reused from the first calibration)" if reused else ")"
            )
            lines.append(f"* {entry['name']}: " + "; ".join(cells) + tail)
    lines += [
        "",
        "## The timed lanes at the first settings: jump counts, and each loop's max |Δt| from the sweep's lanes (s)",
        "",
        "| V | sweep | " + " | ".join(NAMES[k] for k in PEERS[1:] if k in data["consistency"][0]) + " |",
        "|---:|---:|" + "---:|" * sum(k in data["consistency"][0] for k in PEERS[1:]),
    ]
    for row in data["consistency"]:
        cells = [f"{row[k][0]}, {fmt(row[k][1], 2)}" for k in PEERS[1:] if k in row]
        lines.append(f"| {row['V']:.2f} | {row['sweep']} | " + " | ".join(cells) + " |")
    lines += ["", *limits(data)]
    return "\n".join(lines) + "\n"


def limits(data) -> list[str]:
    checks = data["tiers"][0]["checks"]
    sweep = data["timings"][checks["sweep"]["timing_key"]]
    casadi = checks.get("casadi")
    out = [
        "## What limits each figure",
        "",
        (f"* **Extrapolation.** The loops ran {len(data['subset'])} of {data['n_v']} lanes; the cost of a lane varies "
         "with V by more than 10× (no fold above ≈ 5.3 m/s: a few hundred steps; near it thousands of jumps), so the "
         "loops' per-lane figures are means over the timed lanes, the sweep's over the whole map (see the step ratio "
         "and the scaled ratios under each table). The column '/ simulate loop, same lanes' compares like with like."),
        (f"* **Shared cores.** The machine's {data['machine']['cores']} cores ran other jobs (the load averages above); "
         f"the sweep's {data['devices']} devices want every core, so load hits it more than a one-core loop: its "
         f"CPU time per lane ({fmt(sweep['cpu_per_lane'])} s) against its core-seconds ({fmt(sweep['core_s_per_lane'])} s) "
         "shows how much of its cores it got. The core-s ratio charges the sweep for cores other jobs held; the CPU-s "
         "ratio charges each peer for what it ran. Round-robin rounds spread the load over all peers alike."),
        ("* **Calibration on a subset.** One setting per peer, calibrated on the calibration V only; other lanes of the "
         "map may miss the target at it. Near the end of the folds (V ≈ 4.5–5.3 m/s) stick-slip comes in bursts that "
         "end where G grazes a fold: whether a burst has one more small cycle is decided by a tiny state difference, "
         "so there the jump lists differ at most affordable rtol (measured at V = 5.2, in development: peeljax at rtol "
         "1e-7 and LSODA at 1e-8 both have 2 jumps more than the reference; LSODA at 1e-9 matches, at ~20 s a lane; "
         "V = 5.2 is not a calibration V). On such lanes even the sweep and the simulate loop, the same run in two "
         "compiled programs, can part: rounding-level differences grow into a cycle more or less (the table of timed "
         "lanes, V ≈ 5.3)."),
        ("* **The errors are not monotone in rtol** (the folds are reached almost tangentially: a jump time moves like "
         "the square root of a state error, and one jump more or less shifts the rest), so the loosest passing rung "
         "can be a lucky one; a setting between two rungs might meet the target for less."),
        ("* **Peers' right-hand sides.** scipy and CVODE call a plain-Python right-hand side (v from the constraint by "
         "a warm-started safeguarded Newton in log v, `jump_peers._Branch`) and Python event functions: much of their "
         "cost is Python's, a compiled right-hand side (numba) would cut it (not tried here); CasADi's is its own SX "
         "(56 bisections and two Newton steps per evaluation, no Python). CVODE's solver object is built once per rtol "
         "and re-initialized per segment; scikit-sundae 1.2 keeps every event found on the events function and copies "
         "the whole list at each `step`, so the peer empties that record before each segment (without it the cost "
         "grows as jumps², 9.7 s a lane measured instead of 0.7). peeljax's step is the compiled α-method (second "
         "order: more steps than these higher-order codes at tight targets)."),
        ("* **The sweep on a CPU** runs each device's lanes one after another (`lane_batch` 1): its gain over the "
         "simulate loop is the cores, not vectorization; the sweep's per-lane CPU s against the simulate loop's "
         "(same program per lane) show what the sweep's machinery costs or saves."),
    ]  # fmt: skip
    if casadi is not None and casadi["setting"] is None:
        failures = [r for r in casadi["rungs"] if not r["ok"]]
        out.append(
            "* **CasADi** (3.8, experimental events): no rung of the ladder got through every calibration V: "
            + "; ".join(f"rtol {r['rtol']:g}: {r['failure']}" for r in failures[:3])
            + (f"; and so on at the {len(failures) - 3} other rungs" if len(failures) > 3 else "")
            + ". CVODES stops with 'tout too far back in direction of integration' right after an event; some "
            f"calls never return (killed after {CASADI_CALL_LIMIT:g} s); so it has no row timed."
        )
    return out


# --------------------------------------------------------------------------- main
def parse(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="40 lanes, 6 timed, 4 calibration V")
    parser.add_argument("--tiny", action="store_true", help="the test's run: 4 lanes, 2 timed, V = 1.1 and 8, 1 round")
    parser.add_argument("--n-v", type=int, default=None, help="lanes of the map (default 200)")
    parser.add_argument("--subset", type=int, default=None, help="lanes the loops run (default 10)")
    parser.add_argument("--repeats", type=int, default=None, help="timed rounds (default 3)")
    parser.add_argument("--target", type=float, default=1e-3, help="jump-time target [s] (default 1e-3)")
    parser.add_argument(
        "--cap", type=float, default=90.0, help="a peer's ladder stops after a failing rung over this [s]"
    )
    parser.add_argument("--peers", default=",".join(PEERS[2:]), help="loops besides peeljax's: lsoda,cvode,casadi")
    parser.add_argument(
        "--out", type=Path, default=None, help="the markdown report (default results/vmap_lane_cost.md)"
    )
    parser.add_argument("--report-only", type=Path, default=None, help="remake the report from a run's .json")
    parser.add_argument(
        "--leave-out",
        default=None,
        help="V (comma-separated) a second calibration leaves out (default 5 full, 4.6 quick)",
    )
    args = parser.parse_args(argv)
    mode = "tiny" if args.tiny else ("quick" if args.quick else "full")
    defaults = {"full": (200, 10, 3, CALIBRATION_V, (5.0,)), "quick": (40, 6, 3, QUICK_CALIBRATION_V, (4.6,)),
                "tiny": (4, 2, 1, TINY_CALIBRATION_V, (8.0,))}[mode]  # fmt: skip
    args.n_v = args.n_v or defaults[0]
    args.subset = args.subset or defaults[1]
    args.repeats = args.repeats or defaults[2]
    args.calibration = defaults[3]
    leave_out = defaults[4] if args.leave_out is None else [float(V) for V in args.leave_out.split(",") if V.strip()]
    args.leave_out = tuple(V for V in leave_out if V in args.calibration)
    args.ref_rtol = 1e-10 if args.tiny else REF_RTOL
    args.peers = tuple(p.strip() for p in args.peers.split(",") if p.strip())
    unknown = set(args.peers) - set(PEERS[2:])
    if unknown:
        parser.error(f"unknown peers: {', '.join(sorted(unknown))}")
    if args.out is None:
        args.out = HERE / "results" / ("vmap_lane_cost.md" if mode == "full" else f"vmap_lane_cost_{mode}.md")
    return args


def main(argv=None):
    args = parse(argv)
    if args.tiny and not args.report_only:  # before JAX starts; the test's run reads no time
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
    if args.report_only:
        data = json.loads(args.report_only.read_text())
    else:
        data = measure(args)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".json").write_text(json.dumps(data, indent=1))
    text = report(data)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
