"""The benchmark suite: one command per table the README shows.

    python benchmarks/run.py                 # the list below
    python benchmarks/run.py p6 --quick      # a table; what follows its name goes to its script
    python -m benchmarks.run all             # every table, one script after the other

Each table is one call of an existing script's ``main`` in this process, under the command its result
file (``results/``) names on its first line; ``TABLES`` lists them, ``benchmarks/README.md`` what each
writes. ``--only`` (``p1`` … ``p5``) writes ``latest.md`` with those problems alone: pass ``--out
FILE.md`` to keep the full table. The studies that informed one decision each are in ``studies/``.
"""

from __future__ import annotations

import importlib
import shlex
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))  # the scripts import their neighbours (compare_problems, peers) by name

# table -> (script module, its arguments, what it measures)
TABLES = {
    "compare": ("compare", [], "P1–P5 (compare.py whole)"),
    "p1": ("compare", ["--only", "P1"], "one trajectory (P1) and work-precision (P2)"),
    "p3": ("compare", ["--only", "P3"], "the batch of 1024 (V, τ) trajectories"),
    "p4": ("compare", ["--only", "P4"], "the gradient of a trajectory loss"),
    "p5": ("compare", ["--only", "P5"], "where direct DAE solvers stop"),
    "p6": ("stick_slip", ["--skip-vmap"], "stick-slip through the folds, every jump time"),
    "vmap": ("stick_slip", [], "P6 and the V-map (200 V)"),
    "gradient": ("gradient_cost", [], "the gradient's cost, uniform mesh"),
    "jumps": ("jump_gradient_cost", [], "the gradient's cost through the jumps"),
    "switching": ("switching", [], "τ > 0: the default stepper (Tsit5 ↔ α-method) against CasADi"),
}
# ``all``: every table once (``vmap`` holds ``p6``, ``compare`` holds p1–p5)
ALL = ("compare", "vmap", "gradient", "jumps", "switching")


def script_command(table: str, extra=()) -> list[str]:
    """The argv of ``table``'s script: ``[path of the script, its arguments…, extra…]``."""
    module, args, _ = TABLES[table]
    return [str(HERE / f"{module}.py"), *args, *extra]


def run_table(table: str, extra=()) -> int:
    """Run one table by its script's ``main`` in this process, under the script's own command line."""
    argv = script_command(table, extra)
    shown = shlex.join(["python", str(Path(argv[0]).relative_to(HERE.parent)), *argv[1:]])
    print(f"== {table}: {shown}", flush=True)
    module = importlib.import_module(TABLES[table][0])
    saved = sys.argv
    sys.argv = argv  # the script's parser and its result header see its own command
    try:
        code = module.main(argv[1:])
    finally:
        sys.argv = saved
    return int(code or 0)


def listing() -> str:
    width = max(map(len, TABLES))
    rows = [f"  {name:<{width}}  {what}  ({shlex.join(['python', f'benchmarks/{m}.py', *a])})"
            for name, (m, a, what) in TABLES.items()]  # fmt: skip
    rows.append(f"  {'all':<{width}}  every table: {', '.join(ALL)}")
    return "tables:\n" + "\n".join(rows)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "--list"):
        print(__doc__.split("\n\n")[0] + "\n\nusage: python benchmarks/run.py TABLE [script options]\n\n" + listing())
        return 0
    table, extra = argv[0], argv[1:]
    if table == "all":
        if extra:
            print("run.py: error: 'all' takes no script options", file=sys.stderr)
            return 2
        return max(run_table(name) for name in ALL)
    if table not in TABLES:
        print(f"run.py: error: unknown table {table!r}; choose from {', '.join([*TABLES, 'all'])}", file=sys.stderr)
        return 2
    return run_table(table, extra)


if __name__ == "__main__":
    raise SystemExit(main())
