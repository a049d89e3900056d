"""peeljax against the solvers people would use instead, on this very problem (issue 6).

Problems (paper geometry and initial data; the constants are in ``compare_problems.py``, the
full description in ``benchmarks/README.md``): (P1) one trajectory at V = 1.1, τ = 0.01 and 0.1:
each method's cheapest setting with error in v ≤ ``TARGET``, timed against peeljax's; (P2) the
work-precision of every setting (``results/work_precision.png``); (P3) a batch of 1024 (V, τ)
trajectories, ``peeljax.sweep`` against diffrax under ``jax.vmap`` and looped peers; (P4) the
gradient of a trajectory loss with respect to φ's 14 coefficients; (P5) where direct DAE solvers stop.

Peers: one module each in ``peers/`` on ``peers.Peer``. Each answer is checked against the
reference before it is timed; a wrong answer is reported, not timed. Peers marked "(log v)"
integrate (α, ω, u, log v), the others (α, ω, u, v).

    python benchmarks/compare.py                  # full: ~6 min on 2 shared cores; P3 on 1024 trajectories
    python benchmarks/compare.py --quick          # ~2.5 min: τ = 0.01 only, P3 on 16 trajectories, fewer settings
    python benchmarks/compare.py --smoke          # the test: one setting per peer, its times mean nothing
    python benchmarks/compare.py --only P3 P4     # some problems only (P1 includes P2)
    python benchmarks/compare.py --report-only benchmarks/results/latest.json   # the report alone, from the JSON

Writes the numbers to ``results/latest.json`` (``latest_quick.json``, ``latest_smoke.json``; with
``--out X.md``: ``X.json``), then ``compare_report.py``'s report from that JSON: ``latest[…].md``
and the plot beside it. Times are medians of round-robin runs after a warm-up run; set-up times
are listed apart, and the JAX compilations inside each P1 peer's timed calls are counted
(``compiles_in_run``, 0 when its ``setup`` built everything; ``tests/test_compare_script.py`` asserts it).
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from compare_problems import (
    GRID, P3_ADAPTIVE_RTOLS, P3_RTOL_LADDER, P3_SAVE_DT, P3_TAU_RANGE, P3_TUNED_ATOL, P3_TUNED_RHO, P3_VELOCITIES,
    P4_T_FINAL, REF_ATOL, REF_RTOL, T_FINAL, calibrate, central_differences, one_line, p3_grid, p3_subsample,
    p4_coefficients, reference, relative_errors, scaled_error
)  # fmt: skip
from machine import command, cpu_model, load_average, round_robin, timed, versions, write_json
from peers import NotRun, Peer
from peers.casadi_peer import CasadiBatch, CasadiLoss, CasadiPeer, dae_casadi_idas, p4_data
from peers.diffrax_peer import DiffraxPeer, dae_diffrax_index1, diffrax_loss_of, diffrax_vmap
from peers.numba_peer import NumbaAlpha
from peers.peeljax_peer import (
    PeeljaxAdaptive, PeeljaxAlpha, adaptive_alpha_loss, alpha_loss_of, peeljax_batch, peeljax_batch_adaptive
)  # fmt: skip
from peers.petsc_peer import PETSC_DT0, PetscAlphaPeer, petsc_tsalpha
from peers.scipy_peer import ScipyPeer, dae_index1_ode, radau_y
from peers.sundials_peer import CvodeBatch, CvodePeer, dae_ida


_COMPILES = [0]  # JAX backend compilations in this process so far (``count_compilations``)


def count_compilations():
    """Count JAX's backend compilations from now on in ``_COMPILES`` (JAX's own monitoring events)."""
    import jax

    def listener(name, duration, **kwargs):
        if name == "/jax/core/compile/backend_compile_duration":
            _COMPILES[0] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)


# --------------------------------------------------------------------------- (P1, P2) one trajectory
def check(peer: Peer, v_ref: np.ndarray):
    """Prepare the peer and run each setting once (warm-up, compilation), checking its answer."""
    rows = []
    try:
        peer.prepare()
    except NotRun as error:  # an optional peer whose dependency is missing here
        return [{"setting": None, "status": f"not run here: {error}"}]
    except Exception as error:  # noqa: BLE001 (a missing optional peer is reported, not fatal)
        return [{"setting": None, "status": f"unavailable: {one_line(error)}"}]
    scale = np.max(np.abs(v_ref))
    for setting in peer.settings:
        try:
            _, setup = timed(peer.setup, setting)  # the solver object, integrator or compiled program, not the run
            compiled = _COMPILES[0]
            v, first = timed(peer.run, setting)
            compiled = _COMPILES[0] - compiled  # after setup, a run compiles nothing
        except Exception as error:  # noqa: BLE001 (a failing setting is reported)
            rows.append({"setting": setting, "status": f"failed: {one_line(error)}"})
            continue
        finite = np.isfinite(v)
        if not finite.all():
            stop = GRID[np.argmin(finite)] if not finite[0] else GRID[np.argmax(~finite) - 1]
            rows.append({"setting": setting, "status": f"stopped near t = {stop:.3g} s", "setup_s": setup,
                         "first_s": first, "compiles_in_run": compiled})  # fmt: skip
            continue
        error = float(np.max(np.abs(v - v_ref)))
        # Wrong: off by 10 % of max|v|, or (adaptive peers) far above what the tolerance asks.
        limit = 0.1 if peer.setting_name != "rtol" else min(0.1, max(1e3 * setting, 1e-4))
        status = "ok" if error <= limit * scale else f"wrong answer (max/Δv/ = {error:.2g})"
        rows.append({"setting": setting, "status": status, "error": error, "setup_s": setup, "first_s": first,
                     "times": [], "compiles_in_run": compiled})  # fmt: skip
    return rows


def time_round_robin(peers, rows_of, repeats):
    """``repeats`` rounds, each running every checked (peer, setting) once: load hits all alike."""
    for _ in range(repeats):
        for peer in peers:
            for row in rows_of[peer.name]:
                if row.get("status") == "ok":
                    compiled = _COMPILES[0]
                    row["times"].append(timed(peer.run, row["setting"])[1])
                    row["compiles_in_run"] += _COMPILES[0] - compiled
    for rows in rows_of.values():
        for row in rows:
            if row.get("times"):
                row["median_s"] = float(np.median(row["times"]))


def measure_one_trajectory(tau, steps, rtols, adaptive_rtols, petsc_rtols, repeats, diffrax_solvers):
    """(P1, P2) at τ: every peer checked against the reference at each setting, then timed round-robin."""
    v_ref = reference(tau)
    peers = [
        PeeljaxAlpha(tau, steps),
        PeeljaxAdaptive(tau, adaptive_rtols),
        NumbaAlpha(tau, steps),
        *(DiffraxPeer(tau, rtols, solver) for solver in diffrax_solvers),
        ScipyPeer(tau, rtols, "Radau"),
        ScipyPeer(tau, rtols, "BDF"),
        ScipyPeer(tau, rtols, "BDF", log_v=True),
        CvodePeer(tau, rtols),
        CvodePeer(tau, rtols, log_v=True),
        CasadiPeer(tau, rtols),
        CasadiPeer(tau, rtols, log_v=True),
        PetscAlphaPeer(tau, petsc_rtols),
    ]
    rows_of = {}
    for peer in peers:
        rows_of[peer.name] = check(peer, v_ref)
        print(f"  [τ = {tau}: {peer.name} checked]", file=sys.stderr, flush=True)
    time_round_robin(peers, rows_of, repeats)
    entry = {"tau": tau, "base_peer": PeeljaxAlpha.name, "adaptive_peer": PeeljaxAdaptive.name, "peers": []}
    for peer in peers:
        peer.close()
        rows = rows_of[peer.name]
        for row in rows:
            stats = None if row["setting"] is None else peer.run_stats(row["setting"])
            if stats is not None:
                row["stats"] = stats
        info = peer.info()
        if info.get("stats") == "petsc":
            info["dt0"] = PETSC_DT0
        entry["peers"].append({"name": peer.name, "setting_name": peer.setting_name, "info": info, "rows": rows})
    return entry


# --------------------------------------------------------------------------- (P3) a batch of trajectories
def _loop(fn, Vs, taus, setting):
    return np.stack([fn(float(Vp), float(tau), setting) for Vp, tau in zip(Vs, taus)])


def measure_batch(n_tau, per_v, settings, repeats, radau_count):
    """(P3): the batch of 4·n_tau trajectories; errors checked on a subsample of 4·per_v."""
    import jax

    import peeljax
    from peeljax.integrators.dense import output_times

    Vs, taus = p3_grid(n_tau)
    B = Vs.size
    sub = p3_subsample(n_tau, per_v)
    radau_sub = sub[np.linspace(0, sub.size - 1, radau_count).round().astype(int)]
    save_ts = output_times(P3_SAVE_DT, T_FINAL)
    if save_ts.shape != GRID.shape or np.max(np.abs(save_ts - GRID)) > 1e-12 * T_FINAL:
        raise RuntimeError(f"output_times({P3_SAVE_DT}, {T_FINAL}) is not GRID: the error-controlled sweep would "
                           "save v at other times than the peers'")  # fmt: skip
    devices = jax.devices()
    started = time.perf_counter()
    run_diffrax = diffrax_vmap()
    v_ref, ref_status = run_diffrax(Vs[sub], taus[sub], REF_RTOL, REF_ATOL)
    if np.any(ref_status != 0):
        raise RuntimeError(f"the P3 reference stopped at (V, τ) = {list(zip(Vs[sub][ref_status != 0], taus[sub]))}")
    print(f"  [P3 reference on {sub.size} trajectories: {time.perf_counter() - started:.0f} s]", file=sys.stderr)
    casadi, cvode = CasadiBatch(), CvodeBatch()  # their solvers are built by setup(rtol), outside every timing
    calibration = {}
    radau_pos = np.searchsorted(sub, radau_sub)
    tuned = lambda V_, tau_, r: peeljax_batch_adaptive(V_, tau_, r, rho=P3_TUNED_RHO, atol_factor=P3_TUNED_ATOL)
    looped = lambda batch: lambda V_, tau_, r: _loop(batch, V_, tau_, r)
    # key: (its calibration's name, the settings tried, run(Vs, taus, setting) -> v or a tuple led by v)
    runs = {
        "adaptive": ("peeljax error control (rtol)", settings["rtols_adaptive"], peeljax_batch_adaptive),
        "tuned": (f"peeljax error control, ρ = {P3_TUNED_RHO:g}, atol = {P3_TUNED_ATOL:g}·rtol (rtol)",
                  settings["rtols_adaptive"], tuned),
        "uniform": ("peeljax uniform mesh (N)", settings["steps"], peeljax_batch),
        "diffrax": ("diffrax", settings["rtols_diffrax"], run_diffrax),
        "cvode": ("cvode", settings["rtols_loop"], looped(cvode)),
        "casadi": ("casadi", settings["rtols_loop"], looped(casadi)),
        "radau": ("radau", settings["rtols_radau"], looped(radau_y)),
    }  # fmt: skip
    lanes = {key: radau_sub if key == "radau" else slice(None) for key in runs}  # what the timed run covers
    chosen = {}  # key: (setting, whether it met TARGET)
    for key, (name, tried, run) in runs.items():
        checked, ref = (radau_sub, v_ref[radau_pos]) if key == "radau" else (sub, v_ref)

        def on_checked(setting, key=key, run=run, checked=checked):
            if key in ("cvode", "casadi"):
                {"cvode": cvode, "casadi": casadi}[key].setup(setting)
            v = run(Vs[checked], taus[checked], setting)
            return v[0] if isinstance(v, tuple) else v

        (setting, _, _), met = calibrate(name, tried, on_checked, ref, calibration)
        chosen[key] = (setting, met)
    n_alpha = chosen["uniform"][0]
    radius = float(peeljax.AlphaMethod().rho)
    petsc = petsc_tsalpha(list(zip(Vs[radau_sub], taus[radau_sub])), n_alpha, radius)
    calls = {key: functools.partial(run, Vs[lanes[key]], taus[lanes[key]], chosen[key][0])
             for key, (_, _, run) in runs.items()}  # fmt: skip
    # First (compiling) calls on the whole batch, then `repeats` round-robin rounds.
    first, outputs = {}, {}
    for key in ("adaptive", "tuned", "uniform", "diffrax"):
        outputs[key], first[key] = timed(calls[key])
    v_adaptive, status_adaptive, accepted, rejected = outputs["adaptive"]
    v_tuned, status_tuned, accepted_tuned, _ = outputs["tuned"]
    v_alpha, status_alpha = outputs["uniform"]
    v_dfx, status_dfx = outputs["diffrax"]
    casadi.setup(chosen["casadi"][0])
    cvode.setup(chosen["cvode"][0])

    def progress(times):
        print(f"  [P3 round: { {k: round(t[-1], 2) for k, t in times.items()} }]", file=sys.stderr, flush=True)

    times = round_robin(calls, repeats, progress, outputs)
    completed = {
        "adaptive": np.asarray(status_adaptive) == 0,
        "tuned": np.asarray(status_tuned) == 0,
        "uniform": np.asarray(status_alpha) == 0,
        "diffrax": np.asarray(status_dfx) == 0,
        "cvode": np.all(np.isfinite(outputs["cvode"]), axis=1),
        "casadi": np.all(np.isfinite(outputs["casadi"]), axis=1),
    }
    # The errors of the timed runs themselves, on the checked subsample.
    errors_adaptive = relative_errors(v_adaptive[sub], v_ref)
    errors_alpha = relative_errors(v_alpha[sub], v_ref)
    check_error = {
        "adaptive": float(np.max(errors_adaptive)),
        "uniform": float(np.max(errors_alpha)),
        "tuned": float(np.max(relative_errors(v_tuned[sub], v_ref))),
        "diffrax": float(np.max(relative_errors(v_dfx[sub], v_ref))),
        "cvode": float(np.max(relative_errors(outputs["cvode"][sub], v_ref))),
        "casadi": float(np.max(relative_errors(outputs["casadi"][sub], v_ref))),
        "radau": float(np.max(relative_errors(outputs["radau"], v_ref[radau_pos]))),
    }
    methods = {
        key: {"setting": setting, "met": met, "median_s": float(np.median(times[key])), "times": times[key],
              "first_s": first.get(key), "timed_n": radau_sub.size if key == "radau" else B,
              "setup_s": {"casadi": casadi, "cvode": cvode}[key].setup_seconds[setting] if key in ("casadi", "cvode")
              else None,
              "check_error": check_error[key]}
        for key, (setting, met) in chosen.items()
    }  # fmt: skip
    if not isinstance(petsc, str):
        v_p, seconds, statuses, version = petsc
        petsc = {"version": version, "radius": radius, "n": n_alpha, "statuses": statuses,
                 "seconds": [None if np.isnan(s) else float(s) for s in seconds],
                 "error": float(np.max(relative_errors(v_p, v_ref[radau_pos])))}  # fmt: skip
    device = devices[0]
    return {
        "B": B, "n_tau": n_tau, "per_v": per_v, "sub_size": int(sub.size), "radau_size": int(radau_sub.size),
        "velocities": list(P3_VELOCITIES), "tau_range": list(P3_TAU_RANGE), "save_dt": P3_SAVE_DT,
        "repeats": repeats,
        "devices": {"count": len(devices), "platform": device.platform, "device_kind": device.device_kind},
        "methods": methods, "completed": completed, "petsc": petsc, "calibration": calibration,
        "Vs": Vs, "taus": taus, "sub_Vs": Vs[sub],
        "errors_checked": {"adaptive": errors_adaptive, "uniform": errors_alpha},
        "accepted": np.asarray(accepted), "rejected": np.asarray(rejected),
        "accepted_tuned": np.asarray(accepted_tuned), "tuned": {"rho": P3_TUNED_RHO, "atol_factor": P3_TUNED_ATOL},
        "elapsed_s": time.perf_counter() - started,
    }  # fmt: skip


# --------------------------------------------------------------------------- (P4) the gradient of a trajectory loss
def measure_gradient(settings, repeats):
    """(P4): dL/dc for the 14 coefficients of φ, every method against the exact gradient."""
    import jax
    import jax.numpy as jnp

    started = time.perf_counter()
    c = p4_coefficients()
    v_data = p4_data()
    reference_loss = CasadiLoss(1e-11, v_data)
    L_ref, g_ref = reference_loss.value_and_grad(c)
    alpha_loss, diffrax_loss = alpha_loss_of(v_data), diffrax_loss_of(v_data)
    adaptive_loss = adaptive_alpha_loss(v_data)
    n_base = settings["steps"][0]
    methods = []  # (name, setting text, prepare() -> (setup s, call), family)

    def jit_compiled(fn, *args):
        return timed(lambda: jax.jit(fn).lower(*args).compile())

    c_jax = jnp.asarray(c)

    def reverse_mode(loss):
        """(setup seconds, call) for jax.grad of ``loss(c) -> (L, status)``, compiled once."""
        exe, setup = jit_compiled(jax.value_and_grad(loss, has_aux=True), c_jax)

        def call():
            (L, status), g = jax.block_until_ready(exe(c_jax))
            return float(L), np.asarray(g), int(status)

        return setup, call

    for n in settings["steps"]:
        prepare = functools.partial(reverse_mode, lambda c, n=n: alpha_loss(c, n))
        methods.append(("peeljax reverse mode (jax.grad)", f"N = {n} (dt = 1/{n / P4_T_FINAL:g})", prepare, "peeljax"))
    for rtol in settings.get("rtols_adaptive", ()):
        prepare = functools.partial(reverse_mode, lambda c, rtol=rtol: adaptive_loss(c, rtol))
        methods.append(("peeljax adaptive α, reverse mode (jax.grad)", f"rtol = {rtol:g}", prepare, "adaptive"))
    def prepare_fd(n=n_base):
        exe, setup = jit_compiled(lambda c: alpha_loss(c, n)[0], c_jax)
        value = lambda x: float(exe(jnp.asarray(x)))
        L = value(c)
        return setup, lambda: (L, central_differences(value, c), 0)

    methods.append(("central differences of peeljax", f"N = {n_base}", prepare_fd, "fd"))
    def prepare_casadi(rtol, differences):
        loss, setup = timed(CasadiLoss, rtol, v_data)
        if differences:
            L = loss.value(c)
            return setup, lambda: (L, central_differences(loss.value, c), 0)
        return setup, lambda: (*loss.value_and_grad(c), 0)

    for rtol in settings["rtols_casadi"]:
        methods.append(("CasADi cvodes (log v), forward sensitivities", f"rtol = {rtol:g}",
                        functools.partial(prepare_casadi, rtol, False), "casadi"))  # fmt: skip
    for rtol in settings["rtols_casadi_fd"]:
        methods.append(("central differences of CasADi cvodes (log v)", f"rtol = {rtol:g}",
                        functools.partial(prepare_casadi, rtol, True), "fd"))  # fmt: skip
    diffrax_exe = {}
    for rtol in settings["rtols_diffrax"]:
        def prepare_diffrax(rtol=rtol):
            if "exe" not in diffrax_exe:  # rtol is traced: one compilation serves every rtol
                diffrax_exe["exe"], diffrax_exe["setup"] = jit_compiled(jax.value_and_grad(diffrax_loss), c_jax, 1e-8)
            setup, exe = diffrax_exe["setup"], diffrax_exe["exe"]

            def call():
                L, g = jax.block_until_ready(exe(c_jax, rtol))
                return float(L), np.asarray(g), 0

            return setup, call

        methods.append(("diffrax Kvaerno5, RecursiveCheckpointAdjoint (y)", f"rtol = {rtol:g}", prepare_diffrax,
                        "diffrax"))  # fmt: skip

    rows, calls = [], []
    for name, setting, prepare, family in methods:
        row, call = {"name": name, "setting": setting, "family": family, "times": []}, None
        try:
            row["setup"], call = prepare()
            (L, g, status), row["first"] = timed(call)  # warm-up; its answer is the one checked
            if status != 0 or not (np.isfinite(L) and np.all(np.isfinite(g))):
                row["status"] = f"stopped (status {status})" if status else "non-finite loss or gradient"
            else:
                row["status"], row["L"], row["g"], row["error"] = "ok", L, g, scaled_error(g, g_ref, c)
        except Exception as error:  # noqa: BLE001 (a failing method is reported)
            inner = re.search(r"EquinoxRuntimeError: ([^\n.]*)", str(error))  # equinox's runtime checks
            row["status"] = f"failed: {inner.group(1).strip()}" if inner else f"failed: {one_line(error)}"
        rows.append(row)
        calls.append(call)
        print(f"  [P4 {name} {setting}: {row['status']} {row.get('error', '')}]", file=sys.stderr, flush=True)
    times = round_robin({i: call for i, call in enumerate(calls) if rows[i]["status"] == "ok"}, repeats)
    for i, samples in times.items():
        rows[i]["times"], rows[i]["median"] = samples, float(np.median(samples))
    return {"c": c, "L_ref": L_ref, "repeats": repeats, "diffrax_run": bool(settings["rtols_diffrax"]), "rows": rows,
            "elapsed_s": time.perf_counter() - started}  # fmt: skip


# --------------------------------------------------------------------------- (P5) the direct DAE
def measure_direct_dae(velocities, rtols):
    """(P5): t_stop and v there of each direct-DAE solver per V and tolerance (or the error it raised)."""
    solvers = [
        ("SUNDIALS IDA (scikit-sundae)", dae_ida),
        ("CasADi idas", dae_casadi_idas),
        ("scipy Radau, index-1 ODE", dae_index1_ode),
        ("diffrax Kvaerno5, index-1 ODE", dae_diffrax_index1),
    ]
    rows = []
    for name, run in solvers:
        for Vp in velocities:
            cells = []
            for rtol in rtols:
                try:
                    t_stop, v_stop, message = run(Vp, rtol)
                    cells.append({"t_stop": t_stop, "v_stop": v_stop, "message": message})
                except Exception as error:  # noqa: BLE001 (a solver's failure is the result)
                    cells.append({"error": one_line(error)[:40]})
            rows.append({"name": name, "V": Vp, "cells": cells})
    return {"velocities": list(velocities), "rtols": list(rtols), "rows": rows}


# --------------------------------------------------------------------------- the run
def mode_settings(quick, smoke):
    """The settings of each problem in full, ``--quick`` or ``--smoke`` mode."""
    adaptive_rtols = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)  # ~1-15 ms a run: the whole ladder in every mode
    if smoke:
        steps, rtols = (300,), (1e-4,)
        adaptive_rtols, petsc_rtols = (1e-5,), (1e-3,)
        p3 = {"n_tau": 1, "per_v": 1, "radau_count": 1, "repeats": 1, "settings": {
            "rtols_adaptive": (1e-4,), "steps": (300,), "rtols_diffrax": (1e-3,), "rtols_loop": (1e-4,),
            "rtols_radau": (1e-5,)}}
        p4 = {"repeats": 1, "settings": {
            "steps": (82,), "rtols_casadi": (1e-6,), "rtols_casadi_fd": (1e-8,), "rtols_diffrax": (),
            "rtols_adaptive": ()}}
        p5 = {"velocities": (1.1,), "rtols": (1e-6,)}
    elif quick:
        steps, rtols = (300, 1200, 4800, 9600), (1e-3, 1e-5, 1e-7)
        petsc_rtols = (1e-2, 1e-3, 1e-4, 1e-5)
        p3 = {"n_tau": 4, "per_v": 4, "radau_count": 4, "repeats": 2, "settings": {
            "rtols_adaptive": P3_ADAPTIVE_RTOLS, "steps": (9600,), "rtols_diffrax": (1e-3, 1e-4, 1e-5),
            "rtols_loop": (1e-4, 1e-5, 1e-6),
            "rtols_radau": (1e-5, 1e-7)}}
        p4 = {"repeats": 3, "settings": {
            "steps": (82,), "rtols_casadi": (1e-4, 1e-6, 1e-8), "rtols_casadi_fd": (1e-8,), "rtols_diffrax": (),
            "rtols_adaptive": (1e-4, 1e-6, 1e-8)}}
        p5 = {"velocities": (1.1, 2.0, 4.0), "rtols": (1e-4, 1e-6, 1e-8)}
    else:
        steps, rtols = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400), (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
        petsc_rtols = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)  # 1e-7 takes ~10 s a run (ψ and its Jacobian in Python)
        p3 = {"n_tau": 256, "per_v": 8, "radau_count": 8, "repeats": 3, "settings": {
            "rtols_adaptive": P3_ADAPTIVE_RTOLS, "steps": (4800, 9600, 19200),
            "rtols_diffrax": tuple(r for r in P3_RTOL_LADDER if r >= 1e-6),
            "rtols_loop": tuple(r for r in P3_RTOL_LADDER if r <= 1e-3), "rtols_radau": (1e-5, 1e-6, 1e-7)}}
        p4 = {"repeats": 5, "settings": {
            "steps": (82, 820, 8200), "rtols_casadi": (1e-4, 1e-6, 1e-8), "rtols_casadi_fd": (1e-6, 1e-8),
            "rtols_diffrax": (1e-6, 1e-8, 1e-10), "rtols_adaptive": (1e-4, 1e-6, 1e-8)}}
        p5 = {"velocities": (1.1, 2.0, 4.0), "rtols": (1e-4, 1e-6, 1e-8)}
    p1 = {"taus": (0.01,) if (quick or smoke) else (0.01, 0.1), "steps": steps, "rtols": rtols,
          "adaptive_rtols": adaptive_rtols, "petsc_rtols": petsc_rtols,
          "diffrax": ("Kvaerno5",) if smoke else ("Kvaerno5", "Kvaerno3")}  # fmt: skip
    return p1, p3, p4, p5


def measure(args):
    """Run the problems of ``args.only`` in the mode of ``args``; the JSON-able results."""
    p1, p3, p4, p5 = mode_settings(args.quick, args.smoke)
    count_compilations()
    repeats = args.repeats or (1 if args.smoke else 3 if args.quick else 5)
    suffix = "_quick" if args.quick else "_smoke" if args.smoke else ""
    started = time.perf_counter()
    load = load_average()
    data = {
        "command": command(),  # first: the JSON's header, and the report's
        "mode": "quick" if args.quick else "smoke" if args.smoke else "full",
        "only": list(args.only),
        "plot": f"work_precision{suffix}.png",
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "load": load},
        "versions": versions("jax", "jaxlib", "diffrax", "equinox", "numpy", "scipy", "numba", "sksundae", "casadi"),
        "repeats": repeats,
        "p1": [],
        "p3": None,
        "p4": None,
        "p5": None,
    }
    for tau in p1["taus"] if "P1" in args.only else ():
        data["p1"].append(measure_one_trajectory(
            tau, p1["steps"], p1["rtols"], p1["adaptive_rtols"], p1["petsc_rtols"], repeats, p1["diffrax"]))  # fmt: skip
    if "P3" in args.only:
        data["p3"] = measure_batch(p3["n_tau"], p3["per_v"], p3["settings"], args.repeats or p3["repeats"],
                                   p3["radau_count"])  # fmt: skip
    if "P4" in args.only:
        data["p4"] = measure_gradient(p4["settings"], args.repeats or p4["repeats"])
    if "P5" in args.only:
        data["p5"] = measure_direct_dae(p5["velocities"], p5["rtols"])
    data["total_s"] = time.perf_counter() - started
    return data


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer τ, settings, repeats; P3 on 16 trajectories")
    parser.add_argument("--repeats", type=int, default=None, help="timed runs per setting (default 5, quick 3)")
    parser.add_argument("--smoke", action="store_true", help="one setting per peer, one repeat: checks the script runs")
    parser.add_argument("--only", nargs="+", choices=("P1", "P3", "P4", "P5"), default=("P1", "P3", "P4", "P5"),
                        help="run only these problems (P1 includes P2)")  # fmt: skip
    parser.add_argument("--out", default=None, help="markdown output (default results/latest[_quick|_smoke].md); "
                        "the JSON goes beside it, with .json")  # fmt: skip
    parser.add_argument("--report-only", metavar="FILE.json", default=None,
                        help="measure nothing: write the report (markdown and plot) from this JSON")  # fmt: skip
    args = parser.parse_args(argv)
    if args.smoke and not args.report_only:  # before JAX's backend starts; the smoke's times are not read
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
    import compare_report

    if args.report_only:
        compare_report.write_report(compare_report.load(args.report_only),
                                    args.out or Path(args.report_only).with_suffix(".md"))  # fmt: skip
        return 0
    suffix = "_quick" if args.quick else "_smoke" if args.smoke else ""
    md_path = Path(args.out) if args.out else HERE / "results" / f"latest{suffix}.md"
    md_path.parent.mkdir(parents=True, exist_ok=True)
    json_path = md_path.with_suffix(".json")
    data = measure(args)
    write_json(json_path, data)
    print(f"(numbers written to {json_path})")
    compare_report.write_report(compare_report.load(json_path), md_path, echo=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
