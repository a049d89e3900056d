"""Cost of exact gradients through the α-method (issue 4 §4).

For N steps on t ∈ [0, 3] s (dt = 3/N; V = 1.1 m/s, τ = 0.1 s, a run that completes), the loss
L = mean over the valid points of v² + α, differentiated with respect to φ's 14 coefficients:

* forward time (one run, compiled), ``value_and_grad`` time and their ratio;
* peak temporary memory of the compiled gradient (XLA's ``memory_analysis().temp_size_in_bytes``)
  without and with checkpointing (``checkpoint_every="sqrt"``: chunks of ≈ √N steps), and the
  gradient time with checkpointing;
* the same gradient by finite differences: the time of 15 forward runs (one per coefficient
  plus the centre, forward differences);
* diffrax (Kvaerno5, rtol 1e-8, atol 1e-10) with ``RecursiveCheckpointAdjoint`` on the same loss,
  saving at the same N + 1 times (forward and gradient times).

Timings are medians of repeated calls after compilation; compile times are listed apart.
Run: ``python benchmarks/gradient_cost.py [--quick]`` (quick: N = 10³, 10⁴); writes
``benchmarks/results/gradient_cost[_quick].md``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

import peeljax as pj
from peeljax.integrators.uniform_mesh import integrate_alpha

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import round_robin, timed, write_result  # noqa: E402

V, TAU, T_FINAL = 1.1, 0.1, 3.0
RESULTS = Path(__file__).parent / "results"


def alpha_loss(law, n_steps, checkpoint_every=None):
    model = pj.PeelingModel(adhesion=law)
    ode = pj.HomogenizedODE(model, V, TAU)
    sol = integrate_alpha(
        ode, pj.AlphaMethod(), model.initial_state(V), 0.0, T_FINAL, n_steps, checkpoint_every=checkpoint_every
    )
    ys = jnp.where(sol.valid[:, None], sol.ys, 0.0)
    return jnp.sum(ys[:, 3] ** 2 + ys[:, 0]) / jnp.sum(sol.valid)


def diffrax_loss(law, n_steps):
    model = pj.PeelingModel(adhesion=law)
    ode = pj.HomogenizedODE(model, V, TAU)
    ts = jnp.linspace(0.0, T_FINAL, n_steps + 1)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, y, args: ode(y)), diffrax.Kvaerno5(), 0.0, T_FINAL, 1e-6 * T_FINAL,
        model.initial_state(V), saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10), max_steps=16384,
        adjoint=diffrax.RecursiveCheckpointAdjoint(), throw=False,
    )  # fmt: skip
    ys = jnp.where(jnp.isfinite(sol.ys), sol.ys, 0.0)
    return jnp.mean(ys[:, 3] ** 2 + ys[:, 0])


def median_s(fn, *args, repeats=3):
    """The median of ``repeats`` calls after a first."""
    call = lambda: jax.block_until_ready(fn(*args))
    call()
    return statistics.median(round_robin({0: call}, repeats)[0])


def compiled(fn, *args):
    return timed(lambda: jax.jit(fn).lower(*args).compile())


def temp_mib(exe) -> float:
    analysis = exe.memory_analysis()
    return float("nan") if analysis is None else analysis.temp_size_in_bytes / 2**20


def measure(n_steps: int, with_diffrax: bool, repeats: int) -> dict:
    law = pj.AdhesionLaw()
    row = {"N": n_steps}
    fwd, row["compile_fwd_s"] = compiled(lambda p: alpha_loss(p, n_steps), law)
    row["forward_s"] = median_s(fwd, law, repeats=repeats)
    grad, row["compile_grad_s"] = compiled(jax.value_and_grad(lambda p: alpha_loss(p, n_steps)), law)
    row["grad_s"] = median_s(grad, law, repeats=repeats)
    row["mem_grad_mib"] = temp_mib(grad)
    row["mem_fwd_mib"] = temp_mib(fwd)
    grad_ck, row["compile_grad_ckpt_s"] = compiled(jax.value_and_grad(lambda p: alpha_loss(p, n_steps, "sqrt")), law)
    row["grad_ckpt_s"] = median_s(grad_ck, law, repeats=repeats)
    row["mem_grad_ckpt_mib"] = temp_mib(grad_ck)
    g_plain, g_ck = grad(law)[1], grad_ck(law)[1]
    row["ckpt_grad_max_rel_diff"] = max(
        float(jnp.abs(a - b) / jnp.maximum(jnp.abs(a), 1e-300))
        for a, b in zip(jax.tree_util.tree_leaves(g_plain), jax.tree_util.tree_leaves(g_ck))
    )
    # Finite differences: 15 forward runs (centre + one per coefficient), timed as such.
    bumped = [
        eqx.tree_at(lambda p, n=n: getattr(p, n), law, getattr(law, n) * (1 + 1e-6)) for n in pj.COEFFICIENT_NAMES
    ]
    row["fd15_s"] = timed(lambda: jax.block_until_ready([fwd(law)] + [fwd(b) for b in bumped]))[1]
    if with_diffrax:
        dfwd, row["compile_diffrax_fwd_s"] = compiled(lambda p: diffrax_loss(p, n_steps), law)
        row["diffrax_forward_s"] = median_s(dfwd, law, repeats=repeats)
        dgrad, row["compile_diffrax_grad_s"] = compiled(jax.value_and_grad(lambda p: diffrax_loss(p, n_steps)), law)
        row["diffrax_grad_s"] = median_s(dgrad, law, repeats=repeats)
        row["mem_diffrax_grad_mib"] = temp_mib(dgrad)
    print(row, flush=True)
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| N | forward [s] | value_and_grad [s] | ratio | grad, √N checkpoints [s] | ratio | peak temp memory, grad [MiB] | with √N checkpoints [MiB] | FD, 15 forward runs [s] | diffrax fwd [s] | diffrax RecursiveCheckpointAdjoint grad [s] | diffrax grad memory [MiB] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['N']} | {r['forward_s']:.3g} | {r['grad_s']:.3g} | {r['grad_s'] / r['forward_s']:.2f} | {r['grad_ckpt_s']:.3g} | "
            f"{r['grad_ckpt_s'] / r['forward_s']:.2f} | {r['mem_grad_mib']:.3g} | {r['mem_grad_ckpt_mib']:.3g} | {r['fd15_s']:.3g} | "
            f"{r.get('diffrax_forward_s', float('nan')):.3g} | {r.get('diffrax_grad_s', float('nan')):.3g} | {r.get('mem_diffrax_grad_mib', float('nan')):.3g} |"
        )
    lines += ["", "Compile times [s] (forward / grad / grad with checkpoints / diffrax forward / diffrax grad):", ""]
    for r in rows:
        lines.append(
            f"- N = {r['N']}: {r['compile_fwd_s']:.1f} / {r['compile_grad_s']:.1f} / {r['compile_grad_ckpt_s']:.1f} / "
            f"{r.get('compile_diffrax_fwd_s', float('nan')):.1f} / {r.get('compile_diffrax_grad_s', float('nan')):.1f}; "
            f"checkpointed vs plain gradient: max relative difference {r['ckpt_grad_max_rel_diff']:.1e}"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 10^3 and 10^4 only")
    parser.add_argument("--no-diffrax", action="store_true")
    args = parser.parse_args(argv)
    sizes = (1_000, 10_000) if args.quick else (1_000, 10_000, 100_000)
    rows = [measure(n, not args.no_diffrax, repeats=1 if n >= 100_000 else 3) for n in sizes]
    text = (
        f"# Gradient cost (issue 4 §4)\n\nV = {V} m/s, τ = {TAU} s, t ∈ [0, {T_FINAL}] s, dt = {T_FINAL}/N; "
        f"loss = mean(v² + α) over valid points; gradient w.r.t. φ's 14 coefficients. "
        f"CPU: {jax.devices()[0].device_kind}, jax {jax.__version__}, shared machine (timings are indicative).\n\n"
        + table(rows)
        + "\n"
    )
    out = write_result(RESULTS / ("gradient_cost_quick.md" if args.quick else "gradient_cost.md"), text)
    print(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
