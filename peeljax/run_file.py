"""A run's file: the ``.npz`` that ``peeljax simulate --out`` and :meth:`Solution.save` write.

One writer of the format, :func:`run_arrays` (what the file holds) and :func:`write_run`
(atomically, :mod:`peeljax._atomic`); :func:`peeljax.load` reads it back as a
:class:`~peeljax.saved.SavedRun`.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from ._atomic import write_npz, write_text
from ._files import META_KEY, STATE_UNITS, json_safe, meta_array
from .adhesion import in_a_file
from .model import PeelingModel

__all__ = ["RUN_UNITS", "TEXT_COLUMNS", "run_arrays", "write_run", "write_run_text"]

RUN_UNITS: dict[str, str] = {
    "t": "s", **STATE_UNITS, "F": "N", "t_stop": "s", "V": "m/s", "tau": "s", "dt": "s", "t_final": "s",
    "rho": "1", "rtol": "1", "jump_t": "s", "jump_v_before": "m/s", "jump_v_after": "m/s", "jump_G": "N",
    "jump_F": "N", "transient": "s",
}  # fmt: skip


def _nan(value) -> np.float64:
    return np.float64(math.nan if value is None else value)


def run_arrays(
    solution,
    *,
    model: PeelingModel | None = None,
    V: float,
    tau: float,
    t_final: float | None = None,
    dt: float | None = None,
    rho: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    method_option: str | None = None,
    fold: str | None = None,
    max_jumps: int | None = None,
    transient: float = 0.0,
) -> dict[str, np.ndarray]:
    """The arrays of a run's ``.npz``, the format ``peeljax simulate --out`` writes and
    :func:`load` reads (plain arrays and scalars: ``np.load(path, allow_pickle=False)``).

    Arrays t, alpha, omega, u, v, F (tension) and valid share one length, NaN after a stop; the
    rows keep both sides of every jump (two rows at the jump's time, the second marked True in
    ``after_jump``, where the solution has it). Scalars: status, status_code (the
    :class:`~peeljax.StopReason`), reason, t_stop, V, tau (0: the DAE itself), dt (the uniform
    step; NaN with error control), t_final, rho, rtol and atol (NaN where they do not apply),
    geometry, method (the stepper that ran), method_option, phi_json (the 14 coefficients; ""
    for a callable φ or a subclass of AdhesionLaw, code, which the file does not hold),
    stats_json (strict JSON: NaN is null) and meta_json (kind "run", the units, the peeljax
    version). A run with a jump record also has jump_t [s], jump_up,
    jump_v_before, jump_v_after [m/s], jump_G [N] (and jump_F [N]), one entry per jump, and the
    scalars fold, max_jumps and transient [s].
    """
    model = PeelingModel() if model is None else model
    ys = np.asarray(solution.ys, dtype=float)
    valid = np.asarray(solution.valid, dtype=bool)
    tension = np.asarray(model.tension(ys[:, 2], ys[:, 0]), dtype=float)
    adhesion = model.adhesion
    phi_json = json.dumps(adhesion.coefficients()) if in_a_file(adhesion) else ""
    stats = {key: np.asarray(value).tolist() for key, value in solution.stats.items()}
    ts = np.asarray(solution.ts, dtype=float)
    after_jump = getattr(solution, "after_jump", None)
    arrays = {
        "t": ts,
        "alpha": ys[:, 0],
        "omega": ys[:, 1],
        "u": ys[:, 2],
        "v": ys[:, 3],
        "F": np.where(valid, tension, np.nan),
        "valid": valid,
        **({} if after_jump is None else {"after_jump": np.asarray(after_jump, dtype=bool)}),
        "status": np.asarray(solution.status_name, dtype=str),
        "status_code": np.int64(solution.status),
        "reason": np.asarray(solution.reason, dtype=str),
        "t_stop": np.float64(solution.t_stop),
        "V": np.float64(V),
        "tau": np.float64(tau),
        "dt": _nan(dt),
        "t_final": np.float64(ts[-1] if t_final is None else t_final),
        "rho": _nan(rho),
        "rtol": _nan(rtol),
        "atol": _nan(atol),
        "geometry": np.asarray(model.geometry, dtype=str),
        "method": np.asarray(solution.method, dtype=str),  # the stepper that ran
        "method_option": np.asarray(solution.method if method_option is None else method_option, dtype=str),
        "phi_json": np.asarray(phi_json, dtype=str),
        "stats_json": np.asarray(json.dumps(json_safe(stats), allow_nan=False), dtype=str),  # strict: NaN -> null
    }
    if solution.jumps is not None:
        jumps = solution.jumps.as_numpy()
        arrays.update({key: np.asarray(value, dtype=bool if key == "jump_up" else float) for key, value in jumps.items()})
        if fold is not None:
            arrays["fold"] = np.asarray(fold, dtype=str)
        arrays["max_jumps"] = np.int64(solution.jumps.max_jumps if max_jumps is None else max_jumps)
        arrays["transient"] = np.float64(transient)
    arrays[META_KEY] = meta_array("run", {key: unit for key, unit in RUN_UNITS.items() if key in arrays})
    return arrays


def write_run(path: str | os.PathLike, solution, **run) -> None:
    """Write ``solution`` to ``path`` in the format of ``peeljax simulate --out``
    (:func:`run_arrays`; ``run``: its keyword arguments, ``V`` and ``tau`` required). The name
    is kept exactly as given, and the file is replaced only once it is complete: a failed write
    leaves the previous file as it was."""
    for key in ("V", "tau"):
        if key not in run:
            raise TypeError(f"save needs the run's {key} (save(path, V=..., tau=...)): the Solution does not hold it")
    write_npz(path, run_arrays(solution, **run))


# The columns of a run written as text: the rows' arrays, the constant V, units in the header.
TEXT_COLUMNS = ("t", "alpha", "omega", "u", "v", "F", "G", "V", "after_jump")


def write_run_text(path: str | os.PathLike, solution, **run) -> None:
    """``solution`` as comma-separated text: ``#`` lines with the run's settings, a header
    ``t [s],alpha [rad],omega [rad/s],u [m],v [m/s],F [N],G [N],V [m/s],after_jump`` (G = (1 +
    l·sinα/L)·F, the constraint's left side: what φ(v, V) balances) and one row per
    output time up to a stop (both sides of a jump: two rows at its time, ``after_jump`` 1 on the
    second; the rows after a stop, NaN in the .npz, are left out). ``peeljax fit --data`` reads it as a record (:func:`peeljax.fit.read_force_record`:
    the rows not after a jump). ``run``: as :func:`write_run`."""
    arrays = run_arrays(solution, **run)
    n = arrays["t"].shape[0]
    model = PeelingModel() if run.get("model") is None else run["model"]
    G = np.asarray(model.shear_force(np.stack([arrays["alpha"], arrays["omega"], arrays["u"]])), dtype=float)
    rows = {"G": G, "V": np.full(n, float(arrays["V"])), "after_jump": arrays.get("after_jump", np.zeros(n, bool))}
    valid = np.asarray(arrays["valid"], bool)
    columns = [np.asarray(rows[name] if name in rows else arrays[name], dtype=float)[valid] for name in TEXT_COLUMNS]
    header = ",".join(name if name == "after_jump" else f"{name} [{RUN_UNITS.get(name, 'N')}]" for name in TEXT_COLUMNS)
    settings = (
        f"# peeljax run: V = {_cell(arrays['V'])} m/s, tau = {_cell(arrays['tau'])} s, {arrays['status']} "
        f"({arrays['reason']}), t_stop = {_cell(arrays['t_stop'])} s, method {arrays['method']}"
    )
    phi = str(arrays["phi_json"]) or "not in this file: a Python function or a subclass of AdhesionLaw"
    cells = [[_cell(x) for x in column] for column in columns[:-1]] + [["1" if x else "0" for x in columns[-1]]]
    lines = [settings, f"# phi: {phi}", header, *(",".join(row) for row in zip(*cells))]
    write_text(path, "\n".join(lines) + "\n")


def _cell(x) -> str:
    """The shortest text that reads back as the same float64."""
    return repr(float(x))
