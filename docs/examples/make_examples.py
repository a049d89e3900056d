"""Writes the example data files of docs/examples/ and the README's figure (run from the
repository root; name some of ``record``, ``table``, ``figure`` to write only those):

    python docs/examples/make_examples.py [record] [table] [figure]

* ``peel_V=1.1.csv``: the force record of a peeljax stick-slip run at V = 1.1 m/s — the paper's
  φ and model, τ = 0 (the DAE itself, v jumping at the folds of φ), from the paper's initial
  data, t in [0, 1] s every 0.5 ms, the tension F = (k/l)·u that a load cell on the tape
  measures. The pull velocity is in the file name (``peeljax fit --data`` and
  ``peeljax.fit.read_force_record`` read it from there). No noise is added.
* ``stick_slip_table.csv``: a stick-slip table at 4 pull velocities (0.8 … 2 m/s) from a
  hidden φ — the paper's with c1 × 1.1 — with 1 % Gaussian noise (seed 1; one draw for the
  three forces of a row, see :func:`stick_slip_table`) and its 1 % standard deviations: the
  statistics of ``peeljax.fit.synthetic.model_statistics`` over [0.3, 0.8] s at rtol 1e-6, the
  settings ``peeljax fit --table`` is run with in docs/fitting.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import peeljax as pj

HERE = Path(__file__).resolve().parent

FORCE_RECORD = {"V": 1.1, "t_final": 1.0, "sample": 5e-4, "rtol": 1e-8, "atol": 1e-10}


def force_record(path: Path = HERE / "peel_V=1.1.csv") -> Path:
    """The stick-slip force record at V = 1.1 m/s (module docstring)."""
    V, t_final, sample = FORCE_RECORD["V"], FORCE_RECORD["t_final"], FORCE_RECORD["sample"]
    model = pj.PeelingModel()
    ts = np.round(np.arange(round(t_final / sample) + 1) * sample, 12)
    sol = pj.simulate(
        model, V=V, tau=0.0, t_final=t_final, ts=ts, fold="jump",
        rtol=FORCE_RECORD["rtol"], atol=FORCE_RECORD["atol"], max_steps=400_000,
    )  # fmt: skip
    if sol.status_name != "completed":
        raise RuntimeError(f"the run stopped at t = {float(sol.t_stop):g} s: {sol.reason}")
    ys = np.asarray(sol.ys, dtype=np.float64)
    F = np.asarray(model.tension(ys[:, 2], ys[:, 0]), dtype=np.float64)
    jumps = int(sol.jumps.count)
    up = np.asarray(sol.jumps.up)[:jumps]
    slips, first = int(np.sum(up)), float(np.asarray(sol.jumps.t)[:jumps][up][0])
    header = [
        f"# peeljax stick-slip force record at the pull velocity V = {V:g} m/s (also in the file name)",
        "# columns: t [s] time; F [N] the tape tension (k/l)*u, what a load cell on the tape measures",
        (
            f"# made by docs/examples/make_examples.py: peeljax.simulate(V={V:g}, tau=0, fold='jump', "
            f"rtol={FORCE_RECORD['rtol']:g}, atol={FORCE_RECORD['atol']:g}), the paper's phi and model,"
        ),
        (
            f"# from the paper's initial data (v0 = 1e-10*V): the tape sticks and loads until the first slip at "
            f"t = {first:.4f} s; {slips} stick -> slip jumps in [0, {t_final:g}] s; no noise"
        ),
        "t,F",
    ]
    rows = [f"{t:.4f},{f:.4f}" for t, f in zip(ts, F)]
    path.write_text("\n".join(header + rows) + "\n")
    return path


HIDDEN = {"c1": 400 * 1.1}
TABLE = {"V": (0.8, 1.2, 1.6, 2.0), "transient": 0.3, "window": 0.5, "rtol": 1e-6, "atol": 1e-9}


FORCES = ("F_stick", "F_mean", "F_slip")


def stick_slip_table(path: Path = HERE / "stick_slip_table.csv", noise: float = 0.01, seed: int = 1) -> Path:
    """The hidden-truth stick-slip table (module docstring).

    The three forces of a row come from one record, so their error is one: a load cell's
    calibration scales them together (one draw of 1 + noise·N(0, 1) per row). Independent draws
    put F_mean below F_stick at V = 2, where the sawtooth spans 4 N and 1 % is 3.3 N: a row no
    run can produce. The period and the slip duration get draws of their own."""
    from peeljax.fit.synthetic import model_statistics
    from peeljax.measurements.stick_slip_table import STATISTICS, StickSlipTable

    truth = pj.AdhesionLaw(**{**pj.AdhesionLaw().coefficients(), **HIDDEN})
    settings = {k: v for k, v in TABLE.items() if k != "V"}
    V = np.asarray(TABLE["V"], float)
    stats, _ = model_statistics(truth, V, method="window", **settings)  # the window statistics it was made with
    rng = np.random.default_rng(seed)
    force_error = 1 + noise * rng.normal(size=V.shape)
    columns = {}
    for name in STATISTICS:
        exact = np.asarray(stats[name], float)
        error = force_error if name in FORCES else 1 + noise * rng.normal(size=V.shape)
        columns[name] = exact * error
        columns[f"{name}_std"] = noise * np.abs(exact)
    ordered = (columns["F_stick"] < columns["F_mean"]) & (columns["F_mean"] < columns["F_slip"])
    if not ordered.all():
        raise RuntimeError(f"F_stick < F_mean < F_slip fails at V = {V[~ordered]}")
    StickSlipTable.from_dict(V=V, **columns).to_csv(path)
    return path


def readme_figure(path: Path = HERE.parent / "images" / "stick_slip.png") -> Path:
    """The README's figure: its example run (V = 1.1 m/s, τ = 0, 1 s) drawn by ``plot_stick_slip``."""
    from peeljax.plots import plot_stick_slip

    sol = pj.simulate(V=1.1, tau=0, t_final=1.0)
    plot_stick_slip(sol, pj.PeelingModel(), 1.1, path=path)
    return path


if __name__ == "__main__":
    import sys

    jobs = {"record": force_record, "table": stick_slip_table, "figure": readme_figure}
    for name in sys.argv[1:] or list(jobs):  # `make_examples.py table`: that file only
        print(f"wrote {jobs[name]()}")
