"""The markdown report and the work-precision plot of ``compare.py``, made from its JSON results alone.

``compare.py`` measures and writes its numbers to ``results/latest[_quick|_smoke].json``; this
module turns such a file into ``latest[…].md`` (tables P1–P5, the ratios to peeljax, the targets of
issue 6) and ``work_precision[…].png`` (P2), without running anything:

    python benchmarks/compare_report.py benchmarks/results/latest.json   # -> latest.md, work_precision.png
    python benchmarks/compare_report.py FILE.json --out OTHER.md           # the plot beside OTHER.md
    python benchmarks/compare.py --report-only FILE.json                   # the same

The wording of the report lives here; the problems' constants (V, GRID, TARGET, …) come from
``compare_problems.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from compare_problems import (
    ADAPTIVE_ALPHA_ATOL, P4_DEN, P4_FD_STEP, P4_PERTURBATION, P4_T_FINAL, P4_TAU, P4_TIMES, REF_ATOL, REF_RTOL,
    T_FINAL, TARGET, V, cheapest_at, scaled_error
)  # fmt: skip
from machine import made_by


def render(data) -> list[str]:
    """The lines of the markdown report of one ``compare.py`` run (its JSON results, as loaded)."""
    out = []

    def emit(*lines):  # emit(): a blank line
        out.extend(lines or [""])

    emit(made_by(data["command"]), "")
    header(emit, data)
    for entry in data.get("p1") or ():
        one_trajectory_section(emit, entry)
    if data.get("p3"):
        batch_section(emit, data["p3"])
    if data.get("p4"):
        gradient_section(emit, data["p4"])
    if data.get("p5"):
        direct_dae_section(emit, data["p5"])
    if data.get("p1"):
        emit(f"Work-precision plot: `{data['plot']}`.")
    emit(f"Total benchmark time: {data['total_s']:.0f} s.")
    return out


def header(emit, data):
    machine = data["machine"]
    emit("# peeljax against its peers (issue 6: P1–P5)", "")
    emit(f"- CPU: {machine['cpu']}, {machine['cores']} logical cores; load average at start {machine['load']:.2f}")
    emit(f"- {data['versions']}")
    emit(f"- problem: V = {V}, t ∈ [0, {T_FINAL:g}] s, paper geometry and initial data; error = max over the")
    emit(f"  301 times 0, 0.01, …, 3 s of |v − v_ref|, v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g}")
    emit(f"- medians of {data['repeats']} runs after a warm-up run; adaptive peers use atol = 1e-2·rtol, "
         f"peeljax adaptive α atol = {ADAPTIVE_ALPHA_ATOL:g}·rtol", "")  # fmt: skip


# --------------------------------------------------------------------------- (P1, P2) one trajectory
def one_trajectory_section(emit, entry):
    tau, peers = entry["tau"], entry["peers"]
    rows_of = {p["name"]: p["rows"] for p in peers}
    emit(f"## τ = {tau}", "")
    emit(f"### (P1) the cheapest setting with error ≤ {TARGET:g}", "")
    base = cheapest_at(rows_of[entry["base_peer"]], TARGET)
    base_adaptive = cheapest_at(rows_of[entry["adaptive_peer"]], TARGET)
    emit("| method | setting | error | median s | set-up s | time / peeljax's | time / peeljax adaptive α's |")
    emit("|---|---:|---:|---:|---:|---:|---:|")
    for peer in peers:
        best = cheapest_at(peer["rows"], TARGET)
        if best is None:
            statuses = sorted({r["status"] for r in peer["rows"] if r.get("status") != "ok"})
            emit(f"| {peer['name']} | – | – | – | – | not reached ({'; '.join(statuses) or 'error above target'}) | – |")
            continue
        ratio = best["median_s"] / base["median_s"] if base else math.nan
        ratio_adaptive = best["median_s"] / base_adaptive["median_s"] if base_adaptive else math.nan
        emit(
            f"| {peer['name']} | {peer['setting_name']} = {best['setting']:g} | {best['error']:.1e} "
            f"| {best['median_s']:.4f} | {setup_text(best)} | {ratio:.2f} | {ratio_adaptive:.2f} |"
        )
    emit()
    emit("Both ratios are of medians measured round-robin in this run (> 1: that peeljax method is faster). "
         "Set-up s: each peer's one-time work for that setting, outside every timed call (`Peer.setup`): "
         "the JAX and numba peers' compilation (their first call: a program compiled at an earlier "
         "setting, or for the reference, is reused, and the column then holds one run), CasADi's integrator "
         "and CVODE's solver object; scipy's `solve_ivp` has no object to build.")  # fmt: skip
    compiling = [f"{peer['name']} at {r['setting']:g} ({r['compiles_in_run']})" for peer in peers
                 for r in peer["rows"] if r.get("compiles_in_run")]  # fmt: skip
    emit()
    emit("JAX compilations inside the timed calls (the checking run and the timed runs, after `setup`): "
         + ("none." if not compiling else "**" + ", ".join(compiling) + "**: their times include compilation."), "")
    emit("### (P2) work-precision: every setting", "")
    emit("| method | setting | status | error | median s | set-up s | first call s |")
    emit("|---|---:|---|---:|---:|---:|---:|")
    for peer in peers:
        for r in peer["rows"]:
            setting = "–" if r["setting"] is None else f"{peer['setting_name']} = {r['setting']:g}"
            error = f"{r['error']:.1e}" if "error" in r else "–"
            median = f"{r['median_s']:.4f}" if "median_s" in r else "–"
            first = f"{r['first_s']:.2f}" if "first_s" in r else "–"
            emit(f"| {peer['name']} | {setting} | {r['status']} | {error} | {median} | {setup_text(r)} | {first} |")
    emit()
    for peer in peers:
        kind = peer.get("info", {}).get("stats")
        described = [r for r in peer["rows"] if r.get("stats") is not None]
        if kind and described:
            info = peer["info"]
            radius = math.nan if info.get("radius") is None else info["radius"]
            what = ("accepted/rejected steps, Newton iterations" if kind == "adaptive"
                    else f"PETSc {info.get('version', '?')}, ρ∞ = {radius:g}, "
                         f"first step {info['dt0']:g} s: steps/rejected, SNES iterations")  # fmt: skip
            emit(f"- {peer['name']} ({what}): "
                 + "; ".join(f"rtol {r['setting']:g}: {describe(kind, r['stats'])}" for r in described))
    adaptive_ok = [r for r in rows_of[entry["adaptive_peer"]] if r.get("status") == "ok"]
    if len(adaptive_ok) >= 3:
        steps_taken = np.array([r["stats"]["accepted_steps"] for r in adaptive_ok], float)
        slope = np.polyfit(np.log(steps_taken), np.log([r["error"] for r in adaptive_ok]), 1)[0]
        emit(f"- {entry['adaptive_peer']}: error ∝ (accepted steps)^{slope:.2f} over rtol "
             f"{adaptive_ok[0]['setting']:g} … {adaptive_ok[-1]['setting']:g} (least squares; −2 for a second-order method)")
    emit()


def setup_text(row):
    """A row's set-up seconds (``Peer.setup``) as the tables write them; "–" where it has none (a failed row)."""
    seconds = row.get("setup_s")
    return "–" if seconds is None else f"{seconds:.4f}" if seconds < 0.1 else f"{seconds:.2f}"


def describe(kind, stats):
    """A run's counts as the report writes them (``run_stats`` of the adaptive α-method or of PETSc)."""
    if kind == "adaptive":
        return f"{stats['accepted_steps']}/{stats['rejected_steps']}, {stats['newton_iterations']}"
    return f"{stats['steps']}/{stats['rejected']}, {stats['snes_iterations']} ({stats['snes_failures']} failed)"


def work_precision_plot(p1, path, cmd):
    """Wall time against error of every ok (peer, setting), one panel per τ."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    entries = sorted(p1, key=lambda e: e["tau"])
    fig = Figure(figsize=(5.5 * len(entries), 4.5), layout="constrained")
    axes = fig.subplots(1, len(entries), squeeze=False)[0]
    palette = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
               "tab:olive", "tab:cyan", "black", "gold")  # fmt: skip
    for ax, entry in zip(axes, entries):
        for i, peer in enumerate(entry["peers"]):
            pts = sorted((r["error"], r["median_s"]) for r in peer["rows"] if r.get("status") == "ok")
            if pts:
                errors, times = zip(*pts)
                marker = "o-" if i < 10 else "s--"  # more peers than tab10 has colours
                ax.loglog(errors, times, marker, color=palette[i % len(palette)], label=peer["name"], lw=1.2, ms=4)
        ax.axvline(TARGET, color="0.6", ls=":", lw=1)
        ax.set_xlabel("max |v − v_ref| over 301 times [m/s]")
        ax.set_ylabel("wall time per run [s]")
        ax.set_title(f"V = {V} m/s, τ = {entry['tau']} s, t ∈ [0, {T_FINAL:g}] s")
        ax.grid(True, which="both", alpha=0.3)
    # one legend beside the panels: inside one it covered the cheapest settings' points
    handles, labels = max((ax.get_legend_handles_labels() for ax in axes), key=lambda hl: len(hl[1]))
    fig.legend(handles, labels, loc="outside right upper", fontsize=8)
    FigureCanvasAgg(fig).print_figure(path, dpi=120, metadata={"Description": made_by(cmd)})  # the PNG's header


# --------------------------------------------------------------------------- (P3) a batch of trajectories
def _stopped_note(label, setting, completed, stopped_ok, Vs, taus, B, velocities):
    """One sentence: where ``label`` stopped (by V, up to which τ) and how the others did there."""
    stopped = ~completed
    if not stopped.any():
        return f"{label} completed all {B} trajectories at {setting}"
    return (f"{label} stopped on {int(stopped.sum())} of {B} (V, τ) at {setting}: "
            + ", ".join(f"V = {Vp:g}: τ ≤ {taus[stopped & (Vs == Vp)].max():.3g} ({int(np.sum(stopped & (Vs == Vp)))})"
                        for Vp in velocities if np.any(stopped & (Vs == Vp)))
            + "; on those, " + ", ".join(f"{k} completed {int(np.sum(ok[stopped]))}" for k, ok in stopped_ok.items()))  # fmt: skip


def batch_section(emit, d):
    B, velocities, tau_range = d["B"], d["velocities"], d["tau_range"]
    sub_size, radau_size, per_v = d["sub_size"], d["radau_size"], d["per_v"]
    m = d["methods"]
    Vs, taus = np.asarray(d["Vs"], float), np.asarray(d["taus"], float)
    completed = {k: np.asarray(v, bool) for k, v in d["completed"].items()}
    device = d["devices"]
    emit(f"## (P3) a batch of {B} trajectories", "")
    emit(f"V ∈ {{{', '.join(f'{v:g}' for v in velocities)}}} × {d['n_tau']} τ log-spaced in "
         f"[{tau_range[0]:g}, {tau_range[1]:g}] s, t ∈ [0, {T_FINAL:g}] s, paper initial data, v kept at the 301 times "
         f"of P1. Error of a trajectory: max over those times of |v − v_ref| / max|v_ref| (relative to the largest v of "
         f"the reference), v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g} under vmap; checked on "
         f"{sub_size} trajectories spread over the grid ({per_v} τ per V, both ends included). Each method's setting is "
         f"the cheapest of those tried whose max error on them is ≤ {TARGET:g}.", "")  # fmt: skip
    platform = device["platform"]
    kind = platform + ("" if device["device_kind"] == platform else f", {device['device_kind']}")
    emit(f"peeljax.sweep ran on {device['count']} JAX device(s) ({kind}; "
         f"jax.devices() of this process), its lanes dealt over them; with error control each device runs its lanes "
         f"{'one at a time (lane_batch = 1, the CPU default)' if platform == 'cpu' else 'together (vmap)'} "
         f"and v is saved at the 301 times by save_dt = {d['save_dt']:g} (dense output). diffrax under vmap runs on "
         "one device; the looped peers run one trajectory after another in this process (one core).", "")  # fmt: skip
    median = {k: m[k]["median_s"] for k in m}
    base = median["adaptive"]
    r_adaptive, n_alpha = m["adaptive"]["setting"], m["uniform"]["setting"]

    def compiled(key):  # the first call on the whole batch compiles, unless the check ran the same batch size
        return "in the check" if B == sub_size else f"{m[key]['first_s'] - median[key]:.1f}"

    def setup(key):  # the solver object or integrator, built once outside the timing
        return f"{m[key]['setup_s']:.4f}"

    rows = [
        ("peeljax.sweep, error control (α-method, a step size per trajectory)",
         f"rtol = {r_adaptive:g}, atol = {ADAPTIVE_ALPHA_ATOL:g}·rtol", "adaptive", compiled("adaptive"), ""),
        (f"peeljax.sweep, error control, ρ = {d['tuned']['rho']:g} (tuned)",
         f"rtol = {m['tuned']['setting']:g}, atol = {d['tuned']['atol_factor']:g}·rtol", "tuned", compiled("tuned"), ""),
        ("peeljax.sweep, uniform mesh", f"N = {n_alpha} (dt = 1/{n_alpha / T_FINAL:g})", "uniform",
         compiled("uniform"), ""),
        ("diffrax Kvaerno5 under jax.vmap", f"rtol = {m['diffrax']['setting']:g}", "diffrax", compiled("diffrax"), ""),
        ("SUNDIALS CVODE (BDF) (log v), looped", f"rtol = {m['cvode']['setting']:g}", "cvode", setup("cvode"), ""),
        ("CasADi cvodes (log v), looped", f"rtol = {m['casadi']['setting']:g}", "casadi", setup("casadi"), ""),
        ("scipy Radau, looped", f"rtol = {m['radau']['setting']:g}", "radau", "–",
         f" (timed on {radau_size}, × {B / radau_size:g})"),
    ]  # fmt: skip
    emit("| method | setting | completed | max error (checked) | s per batch | ms per trajectory | set-up / compile s "
         "| time / peeljax's |")  # fmt: skip
    emit("|---|---|---:|---:|---:|---:|---:|---:|")
    per_batch = {}
    for name, setting, key, compile_s, note in rows:
        per_batch[key] = median[key] * B / m[key]["timed_n"]
        done = f"{int(np.sum(completed[key]))}/{B}" if key in completed else "–"
        checked = sub_size if key != "radau" else radau_size
        flag = "" if m[key]["met"] else " (target not reached)"
        emit(f"| {name} | {setting}{flag} | {done} | {m[key]['check_error']:.1e} ({checked}) | {per_batch[key]:.2f}{note} "
             f"| {1e3 * per_batch[key] / B:.2f} | {compile_s} | {per_batch[key] / base:.2f} |")  # fmt: skip
    petsc = d["petsc"]
    if isinstance(petsc, str):
        emit(f"| PETSc TSALPHA (petsc4py), looped | – | – | – | – | – | – | {petsc} |")
    else:
        ok = np.array([s == "ok" for s in petsc["statuses"]])
        seconds = np.array([math.nan if s is None else s for s in petsc["seconds"]], float)
        per = float(np.nanmean(seconds)) * B
        emit(f"| PETSc {petsc['version']} TSALPHA (ρ∞ = {petsc['radius']:g}, log v), looped | N = {petsc['n']} "
             f"| {int(ok.sum())}/{ok.size} of the timed | {petsc['error']:.1e} ({ok.size}) | {per:.2f} (timed on "
             f"{ok.size}, × {B / ok.size:g}) | {1e3 * per / B:.2f} | – | {per / base:.2f} |")  # fmt: skip
    emit()
    emit(f"Times: median of {d['repeats']} timed round-robin round(s) after a first (compiling) call on the whole batch; loops "
         "call one trajectory after another (CasADi: one integrator with (V, τ) as parameters, built outside the "
         "timing; CVODE: one solver object per rtol, built outside the timing, its (V, τ) set per call). Set-up / "
         "compile s: JAX's compilation (first call − median), CasADi's integrator and CVODE's solver object (their "
         "construction time). "
         "time / peeljax's: divided by peeljax.sweep with error control (the first row; > 1: it is faster). "
         "Settings tried on the checked trajectories (setting: max error, completed):", "")  # fmt: skip
    for name, tried in d["calibration"].items():
        emit(f"- {name}: " + "; ".join(f"{s:g}: {e:.1e} ({c})" for s, e, c in tried))
    sub_Vs = np.asarray(d["sub_Vs"], float)
    errors_adaptive = np.asarray(d["errors_checked"]["adaptive"], float)
    errors_alpha = np.asarray(d["errors_checked"]["uniform"], float)
    emit()
    emit(f"peeljax's max error by V (checked trajectories): error control at rtol = {r_adaptive:g}: "
         + ", ".join(f"{Vp:g}: {np.max(errors_adaptive[sub_Vs == Vp]):.1e}" for Vp in velocities)
         + f"; uniform mesh at N = {n_alpha}: "
         + ", ".join(f"{Vp:g}: {np.max(errors_alpha[sub_Vs == Vp]):.1e}" for Vp in velocities)
         + " (one dt serves the whole batch, so the hardest (V, τ) sets it; with error control each trajectory "
           "takes the steps its own error needs).", "")  # fmt: skip
    accepted, rejected = np.asarray(d["accepted"]), np.asarray(d["rejected"])
    emit(f"Steps of the error-controlled sweep per trajectory (whole batch): accepted mean {np.mean(accepted):.0f} "
         f"(min {int(np.min(accepted))}, max {int(np.max(accepted))}; by V: "
         + ", ".join(f"{Vp:g}: {np.mean(accepted[Vs == Vp]):.0f}" for Vp in velocities)
         + f"), rejected mean {np.mean(rejected):.1f}; the uniform mesh takes N = {n_alpha} on every trajectory.", "")  # fmt: skip
    others = {"diffrax": completed["diffrax"], "CVODE": completed["cvode"], "CasADi": completed["casadi"]}
    note = lambda label, setting, key: _stopped_note(label, setting, completed[key], others, Vs, taus, B, velocities)
    emit(note("peeljax with error control", f"rtol = {r_adaptive:g}", "adaptive")
         + "; " + note("on the uniform mesh", f"N = {n_alpha}", "uniform")
         + f"; diffrax completed {int(completed['diffrax'].sum())}, CVODE {int(completed['cvode'].sum())}, "
         f"CasADi {int(completed['casadi'].sum())}.", "")  # fmt: skip
    n_cores = device["count"] if platform == "cpu" else 1
    casadi_shared = per_batch["casadi"] / n_cores  # the loop split perfectly over the cores peeljax used
    ratio_dfx = per_batch["diffrax"] / base
    ratio_casadi = casadi_shared / base
    looped = {k: per_batch[k] for k in ("cvode", "casadi", "radau")}
    best = min(looped, key=looped.get)
    emit(f"Targets (issue 6): peeljax ≥ 10× faster than diffrax under vmap: "
         f"{'met' if ratio_dfx >= 10 else 'missed'} ({ratio_dfx:.2f}×); faster than looping CasADi cvodes (log v) on the "
         f"same cores: {'met' if ratio_casadi > 1 else 'missed'} ({ratio_casadi:.2f}×: CasADi's "
         f"{per_batch['casadi']:.2f} s per batch on one core / {n_cores} core(s), as if its loop were split perfectly "
         f"over the {n_cores} the sweep used; {per_batch['casadi'] / base:.2f}× as looped here). peeljax here is "
         f"peeljax.sweep with error control at equal error ({base:.2f} s per batch on {device['count']} device(s)); on the "
         f"uniform mesh (before): {per_batch['diffrax'] / per_batch['uniform']:.2f}× diffrax, "
         f"{casadi_shared / per_batch['uniform']:.2f}× CasADi on the same cores. Best looped peer: {best} "
         f"({looped[best]:.2f} s per batch). P3 time: {d['elapsed_s']:.0f} s.", "")  # fmt: skip
    tuned = per_batch["tuned"]
    accepted_tuned = np.asarray(d["accepted_tuned"])
    emit(f"Tuned (ρ = {d['tuned']['rho']:g}, atol = {d['tuned']['atol_factor']:g}·rtol, the peers' atol rule; "
         f"`benchmarks/studies/results/lane_levers.md` measured each lever): {tuned:.2f} s per batch at rtol = "
         f"{m['tuned']['setting']:g}, {np.mean(accepted_tuned):.0f} accepted steps per trajectory (default: "
         f"{np.mean(accepted):.0f}); {base / tuned:.2f}× the default sweep's speed, {per_batch['diffrax'] / tuned:.2f}× "
         f"diffrax's, against CasADi's loop split over the same cores {casadi_shared / tuned:.2f}× "
         f"({'met' if casadi_shared / tuned > 1 else 'missed'}).", "")  # fmt: skip


# --------------------------------------------------------------------------- (P4) the gradient of a trajectory loss
def gradient_section(emit, d):
    rows, c, repeats = d["rows"], np.asarray(d["c"], float), d["repeats"]
    emit("## (P4) the gradient of a trajectory loss with respect to φ's 14 coefficients", "")
    emit(f"L(c) = mean over the {P4_TIMES.size} times t_i = i/{P4_DEN} s, t ∈ [0, {P4_T_FINAL:g}] s, of (v(t_i) − "
         f"v_data(t_i))², V = {V}, τ = {P4_TAU}; v_data: the paper's φ (CasADi cvodes, rtol 1e-11); the gradient is "
         f"taken at the paper's φ with {P4_PERTURBATION[0]} × {P4_PERTURBATION[1]:g} (L = {d['L_ref']:.4e}). Reference "
         "gradient: CasADi cvodes forward sensitivities at rtol 1e-11 (atol 1e-13). Gradient error: "
         "max_i |c_i·(g − g_ref)_i| / max_i |c_i·g_ref,i| (sensitivities to relative changes of the coefficients); "
         "it includes each method's discretization error of the trajectory (different discretizations have "
         f"different gradients). Central differences: relative step {P4_FD_STEP:g}, 28 forward runs.", "")  # fmt: skip
    base_row = rows[0]
    base = base_row.get("median", math.nan)
    emit("| method | setting | status | L | gradient error | median s | first-call overhead s | time / peeljax's |")
    emit("|---|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        L = f"{r['L']:.4e}" if "L" in r else "–"
        error = f"{r['error']:.1e}" if "error" in r else "–"
        median = f"{r['median']:.4f}" if "median" in r else "–"
        if "median" in r:
            overhead = f"{r['setup'] + r['first'] - r['median']:.1f}"
        else:
            overhead = f"{r['setup']:.1f}" if "setup" in r else "–"
        ratio = f"{r['median'] / base:.2f}" if "median" in r else "–"
        emit(f"| {r['name']} | {r['setting']} | {r['status']} | {L} | {error} | {median} | {overhead} | {ratio} |")
    if not d["diffrax_run"]:
        emit("| diffrax Kvaerno5, RecursiveCheckpointAdjoint (y) | – | not run in this mode (full mode only: its "
             "compilation alone takes ~1 min) | – | – | – | – | – |")  # fmt: skip
    emit()
    emit(f"Medians of {repeats} round-robin runs after a warm-up call. First-call overhead: compile (JAX's lower + "
         "compile) or construction (CasADi's integrator and derivative functions, built lazily) plus the first call, "
         "minus the median (diffrax: rtol is traced, so its one compilation is listed on each of its rows; failed "
         "rows: the compile or construction time alone).")  # fmt: skip
    fd_row = next((r for r in rows if r["family"] == "fd" and r["name"].endswith("peeljax") and "g" in r), None)
    if "g" in base_row and fd_row is not None:
        emit(f"peeljax's reverse-mode gradient and its own central differences (same N) differ by "
             f"{scaled_error(base_row['g'], fd_row['g'], c):.1e} (the same measure): the reverse mode is the exact "
             "gradient of the discrete loss; its error against g_ref is the discretization error of the α-method.")
    emit()
    # Equal accuracy: for each peeljax setting, the cheapest setting of each other family whose error is ≤ its own.
    families = (("casadi", "CasADi forward sensitivities"), ("fd", "finite differences (any)"),
                ("diffrax", "diffrax adjoint"), ("peeljax", "peeljax uniform mesh"),
                ("adaptive", "peeljax adaptive α"))  # fmt: skip
    emit("Time of the cheapest setting of each peer with a gradient error ≤ peeljax's (within 5 %), divided by "
         "peeljax's time (> 1: peeljax faster), for each setting of peeljax on the uniform mesh and of the adaptive "
         "α-method:", "")  # fmt: skip
    emit("| peeljax setting | gradient error | median s | " + " | ".join(label for _, label in families) + " |")
    emit("|---|---:|---:|" + "---|" * len(families))
    verdicts = []
    for p_row in (r for r in rows if r["family"] in ("peeljax", "adaptive") and "median" in r):
        cells = []
        for family, label in families:
            if family == p_row["family"]:
                cells.append("–")
                continue
            timed = [r for r in rows if r["family"] == family and "median" in r]
            if not timed:
                cells.append("not run")
                continue
            equal = [r for r in timed if r["error"] <= 1.05 * p_row["error"]]
            if not equal:
                cells.append("none as accurate")
                verdicts.append((p_row, label, None))
                continue
            best = min(equal, key=lambda r: r["median"])
            ratio = best["median"] / p_row["median"]
            cells.append(f"{ratio:.2f} ({best['setting']}{', ' + best['name'].split(' of ')[-1] if family == 'fd' else ''})")
            verdicts.append((p_row, label, ratio))
        label = p_row["setting"] if p_row["family"] == "peeljax" else f"adaptive α, {p_row['setting']}"
        emit(f"| {label} | {p_row['error']:.1e} | {p_row['median']:.4f} | " + " | ".join(cells) + " |")
    emit()
    lines = []
    for p_row in (r for r in rows if r["family"] == "peeljax" and "median" in r):
        for label in ("CasADi forward sensitivities", "finite differences (any)"):
            found = [v[2] for v in verdicts if v[0] is p_row and v[1] == label]
            if not found:
                state = "not run"
            elif found[0] is None:
                state = "no peer setting tried is as accurate"
            else:
                state = f"{'met' if found[0] > 1 else 'missed'} ({found[0]:.2f}×)"
            lines.append(f"{p_row['setting'].split(' (')[0]}: faster than {label.split(' (')[0]}: {state}")
    emit("Targets (issue 6), at equal gradient error: " + "; ".join(lines)
         + f". P4 time: {d['elapsed_s']:.0f} s.", "")  # fmt: skip


# --------------------------------------------------------------------------- (P5) the direct DAE
def direct_dae_section(emit, d):
    rtols = d["rtols"]
    emit("## (P5) the direct DAE: where each solver stops", "")
    emit("t_stop [s] (v there [m/s]) per tolerance; t_final = 3 s means it completed. The paper")
    emit("claims that direct DAE solvers fail at the stick-slip points (J_t → 0 at the maximum of φ).")
    emit("IDA and scipy report their last internal step; CasADi idas runs output interval by output interval")
    emit("(every 0.05 s) and reports the last one reached; diffrax reports its last output time (every 1 ms).")
    emit("φ at V = 1.1 has its maximum at v = 0.524 and its minimum at v = 8.49.", "")
    emit("| solver | V | " + " | ".join(f"rtol {r:g}" for r in rtols) + " |")
    emit("|---|---:|" + "---:|" * len(rtols))
    for row in d["rows"]:
        cells = [f"error: {cell['error']}" if "error" in cell else f"{cell['t_stop']:.4g} ({cell['v_stop']:.3g})"
                 for cell in row["cells"]]  # fmt: skip
        emit(f"| {row['name']} | {row['V']:g} | " + " | ".join(cells) + " |")
    emit()


# --------------------------------------------------------------------------- files
def load(path):
    return json.loads(Path(path).read_text(encoding="utf-8"))


def write_report(data, md_path, echo=False):
    """``md_path`` and, when P1 ran, the work-precision plot beside it (its name is in ``data["plot"]``)."""
    md_path = Path(md_path)
    if data.get("p1"):
        work_precision_plot(data["p1"], md_path.parent / data["plot"], data["command"])
    lines = render(data)
    if echo:
        print("\n".join(lines), flush=True)
    md_path.write_text("\n".join(lines) + "\n")
    print(f"(written to {md_path})")
    return md_path


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", help="JSON written by compare.py (results/latest[_quick|_smoke].json)")
    parser.add_argument("--out", default=None, help="markdown output (default: the JSON's name with .md)")
    args = parser.parse_args(argv)
    write_report(load(args.results), args.out or Path(args.results).with_suffix(".md"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
