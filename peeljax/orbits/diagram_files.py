"""A bifurcation diagram's file: what :meth:`OrbitDiagram.save` writes and :func:`peeljax.load`
reads back (an :class:`~peeljax.orbits.OrbitDiagram`; this module knows the arrays, not the
diagram class: :mod:`.diagram` writes and reads through it).

An ``.npz`` of plain arrays (``np.load(path, allow_pickle=False)`` reads it; text is stored as
fixed-width unicode arrays), ``meta_json`` saying its kind (``"orbit_diagram"``), the units
and the peeljax that wrote it (:mod:`peeljax._files`):

* every branch point, the branches one after another: ``point_branch`` (its branch's index),
  ``point_parameter`` (the continued parameter's value), ``V`` [m/s], ``slips``, ``period`` [s],
  the five statistics ``F_mean``, ``F_slip``, ``F_stick`` [N], ``time_between_slips``,
  ``slip_duration`` [s], ``multipliers`` (n × 2 complex), ``stable``, ``approach`` [N],
  ``crossing`` [N/s], ``section`` (n × 2: α [rad], ω [rad/s]), the test functions
  ``fold``, ``period_doubling``, ``torus``;
* ``branch_parameter`` (the parameter's name per branch) and ``branch_ends`` (why each ended,
  its lines joined by newlines);
* every bifurcation: ``bif_branch``, ``bif_kind``, ``bif_parameter``, ``bif_V``, ``bif_slips``,
  ``bif_note``;
* every seed run: ``seed_V``, ``seed_start``, ``seed_slips``, ``seed_period``, ``seed_F_slip``,
  ``seed_F_stick``, ``seed_interval``, ``seed_orbit``, ``seed_branch``;
* ``V_range``, ``wall_time``, ``seed_time`` [s]; ``complete`` (False: the diagram was
  interrupted, and holds the seeds and branches finished before; files without it are complete).
"""

from __future__ import annotations

import os

import numpy as np

from .._atomic import write_npz
from .._files import meta_array
from .continuation import STATISTICS, Bifurcation, BifurcationKind, OrbitBranch

__all__ = ["DIAGRAM_KIND", "diagram_parts", "write_diagram"]

DIAGRAM_KIND = "orbit_diagram"
_STAT_FILE_NAMES = {"period": "time_between_slips"}
_UNITS = {
    "V": "m/s", "period": "s", "F_mean": "N", "F_slip": "N", "F_stick": "N", "time_between_slips": "s",
    "slip_duration": "s", "approach": "N", "crossing": "N/s", "bif_V": "m/s", "seed_V": "m/s", "seed_period": "s",
    "seed_F_slip": "N", "seed_F_stick": "N", "seed_interval": "s", "V_range": "m/s", "wall_time": "s",
}  # fmt: skip
_TESTS = ("fold", "period_doubling", "torus")


def write_diagram(path: str | os.PathLike, diagram) -> None:
    """Write ``diagram`` to ``path`` (module docstring), atomically."""
    branches = diagram.branches
    cat = lambda get, empty=(0,): np.concatenate([get(b) for b in branches]) if branches else np.zeros(empty)  # noqa: E731
    arrays = {
        "point_branch": np.concatenate([np.full(len(b), i) for i, b in enumerate(branches)] or [np.zeros(0)]).astype(np.int64),
        "point_parameter": cat(lambda b: b.values), "V": cat(lambda b: b.V),
        "slips": cat(lambda b: b.slips).astype(np.int64), "period": cat(lambda b: b.period),
        "multipliers": cat(lambda b: b.multipliers, (0, 2)).astype(complex), "stable": cat(lambda b: b.stable).astype(bool),
        "approach": cat(lambda b: b.approach), "crossing": cat(lambda b: b.crossing),
        "section": cat(lambda b: b.section, (0, 2)),
        **{_STAT_FILE_NAMES.get(k, k): cat(lambda b, k=k: b.statistics[k]) for k in STATISTICS},
        **{k: cat(lambda b, k=k: b.test_functions[k]) for k in _TESTS},
        "branch_parameter": np.array([b.parameter for b in branches], dtype=str),
        "branch_ends": np.array(["\n".join(b.ends) for b in branches], dtype=str),
        "branch_wall_time": np.array([b.wall_time for b in branches], float),
        "V_range": np.asarray(diagram.V_range, float),
        "wall_time": np.asarray(diagram.wall_time, float), "seed_time": np.asarray(diagram.seed_time, float),
        "complete": np.asarray(bool(getattr(diagram, "complete", True))),
    }  # fmt: skip
    found = diagram.bifurcations
    arrays.update({
        "bif_branch": np.array([i for i, _ in found], np.int64), "bif_kind": np.array([b.kind.name for _, b in found], dtype=str),
        "bif_parameter": np.array([b.parameter for _, b in found], float), "bif_V": np.array([b.V for _, b in found], float),
        "bif_slips": np.array([b.slips for _, b in found], np.int64), "bif_note": np.array([b.note for _, b in found], dtype=str),
    })  # fmt: skip
    seeds = diagram.seeds
    arrays.update({
        "seed_V": np.array([s.V for s in seeds], float), "seed_start": np.array([s.start for s in seeds], dtype=str),
        "seed_slips": np.array([s.slips for s in seeds], np.int64), "seed_period": np.array([s.period for s in seeds], float),
        "seed_F_slip": np.array([s.F_slip for s in seeds], float), "seed_F_stick": np.array([s.F_stick for s in seeds], float),
        "seed_interval": np.array([s.interval for s in seeds], float), "seed_orbit": np.array([s.orbit for s in seeds], dtype=str),
        "seed_branch": np.array([s.branch for s in seeds], np.int64),
    })  # fmt: skip
    arrays["meta_json"] = meta_array(DIAGRAM_KIND, _UNITS)
    write_npz(path, arrays)


def diagram_parts(arrays: dict, name: str) -> tuple:
    """(V_range, branches, seeds' fields, wall_time, seed_time, complete) of a diagram file's arrays
    (``name``: the file, for messages); a ValueError naming the file where they are malformed."""
    try:
        point_branch = np.asarray(arrays["point_branch"])
        n_branches = len(arrays["branch_parameter"])
        if point_branch.size and not (0 <= point_branch.min() and point_branch.max() < n_branches):
            raise ValueError("point_branch names a branch that is not in the file")
        bif_branch = np.asarray(arrays["bif_branch"])
        branches = []
        for i in range(n_branches):
            at = point_branch == i
            stats = {k: np.asarray(arrays[_STAT_FILE_NAMES.get(k, k)], float)[at] for k in STATISTICS}
            mine = np.flatnonzero(bif_branch == i)
            bifurcations = [
                Bifurcation(BifurcationKind[str(arrays["bif_kind"][j])], float(arrays["bif_parameter"][j]),
                            float(arrays["bif_V"][j]), int(arrays["bif_slips"][j]), -1, str(arrays["bif_note"][j]))
                for j in mine
            ]  # fmt: skip
            branches.append(OrbitBranch(
                parameter=str(arrays["branch_parameter"][i]), values=np.asarray(arrays["point_parameter"], float)[at],
                V=np.asarray(arrays["V"], float)[at], slips=np.asarray(arrays["slips"])[at],
                period=np.asarray(arrays["period"], float)[at], statistics=stats,
                multipliers=np.asarray(arrays["multipliers"])[at], stable=np.asarray(arrays["stable"], bool)[at],
                test_functions={k: np.asarray(arrays[k], float)[at] for k in _TESTS},
                approach=np.asarray(arrays["approach"], float)[at], crossing=np.asarray(arrays["crossing"], float)[at],
                section=np.asarray(arrays["section"], float)[at], bifurcations=bifurcations,
                ends=[e for e in str(arrays["branch_ends"][i]).split("\n") if e],
                wall_time=float(arrays["branch_wall_time"][i]),
            ))  # fmt: skip
        seeds = [
            (float(arrays["seed_V"][j]), str(arrays["seed_start"][j]), int(arrays["seed_slips"][j]),
                 float(arrays["seed_period"][j]), float(arrays["seed_F_slip"][j]), float(arrays["seed_F_stick"][j]),
                 float(arrays["seed_interval"][j]), str(arrays["seed_orbit"][j]), int(arrays["seed_branch"][j]))
            for j in range(len(arrays["seed_V"]))
        ]  # fmt: skip
        V_range = tuple(float(v) for v in np.asarray(arrays["V_range"], float))
        if len(V_range) != 2:
            raise ValueError("V_range must hold two numbers")
        complete = bool(np.asarray(arrays.get("complete", True)))  # (files before it: complete)
        return V_range, branches, seeds, float(arrays["wall_time"]), float(arrays["seed_time"]), complete
    except (KeyError, IndexError, TypeError, ValueError) as error:
        raise ValueError(f"{name!r} is malformed: not an orbit diagram's arrays ({error})") from None
