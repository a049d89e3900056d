"""The layout of ``peeljax/``: no import circle, and no import up the layers (issue 29).

Read from the source with ``ast`` (nothing is imported): every import statement counts, also
one inside a function (a lazy import is still an edge of the graph). The last test imports
peeljax in a fresh process: importing it starts no XLA backend.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "peeljax"

# The layers, first to last (README's layer table; peeljax/__init__'s docstring): a module may
# import its own layer and those before it. Keyed by the first name under peeljax/.
LAYERS = [
    ("utilities", {"_devices", "_arrays", "_atomic", "_compilation_cache", "_exported", "_cotangents", "_files", "_linalg", "_memory", "_npz", "_panels", "_validation", "_deprecated"}),
    ("model", {"model", "adhesion"}),
    ("structure", {"structure", "branches", "steady"}),
    ("homogenized ODE and the DAE", {"homogenized", "constrained", "desingularized"}),
    ("the result type", {"solution", "run_file"}),
    ("integrators", {"integrators"}),
    ("one run", {"run_program", "simulate", "bound", "saved"}),
    ("a run's cycles, periodic orbits", {"cycles", "orbits"}),
    ("measurements", {"measurements"}),
    ("many runs, fit, analysis", {"sweeps", "fit", "analysis", "alternatives", "lyapunov", "attractor_map"}),
    ("CLI and plots", {"cli", "plots", "stick_slip_plots", "figures"}),  # stick_slip_plots: a deprecated alias
    ("the package's public names", {""}),
]
# A deprecated module path (peeljax._deprecated.moved_module) imports its new home by name, on first use: no edge.


def _modules(root: Path) -> dict[str, Path]:
    out = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


@functools.cache
def _graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module → the peeljax modules it imports. ``from .. import __version__`` (the CLI's
    ``--version``) reads a string of the package, no module: not an edge."""
    modules = _modules(root)
    edges = {}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        edges[name] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                edges[name] |= {a.name for a in node.names if a.name in modules}
            elif isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                stem = ".".join(base + ([node.module] if node.module else []))
                for alias in node.names:
                    if f"{stem}.{alias.name}" in modules:
                        edges[name].add(f"{stem}.{alias.name}")
                    elif stem in modules and alias.name != "__version__":
                        edges[name].add(stem)
        edges[name].discard(name)
    return edges


def _layer(module: str) -> int:
    head = module.split(".")[1] if "." in module else ""
    for k, (_, names) in enumerate(LAYERS):
        if head in names:
            return k
    raise AssertionError(f"peeljax/{head}: in no layer of tests/test_import_layers.py's LAYERS: add it where it belongs")


def test_no_import_circle_in_peeljax():
    edges = _graph()
    assert "peeljax.measurements.records" in edges and "peeljax.solution" in edges["peeljax.saved"]  # the graph is read
    # a circle: a module that reaches itself again
    circles = []
    for start in edges:
        seen, todo = set(), list(edges[start])
        while todo:
            m = todo.pop()
            if m == start:
                circles.append(start)
                break
            if m not in seen:
                seen.add(m)
                todo.extend(edges[m])
    assert circles == [], f"modules on an import circle: {sorted(circles)}"


def test_no_upward_import_in_peeljax():
    edges = _graph()
    upward = [
        f"{a} ({LAYERS[_layer(a)][0]}) imports {b} ({LAYERS[_layer(b)][0]})"
        for a in sorted(edges)
        for b in sorted(edges[a])
        if _layer(b) > _layer(a)
    ]
    assert upward == []


def test_the_check_sees_a_lazy_import_as_an_edge(tmp_path):
    """The circle solution.py ↔ saved.py was made by an import inside a method: such an import counts."""
    package = tmp_path / "peeljax"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "solution.py").write_text("def load(path):\n    from .saved import load\n    return load(path)\n")
    (package / "saved.py").write_text("from .solution import load as _unused\n")
    edges = _graph(package)
    assert edges["peeljax.solution"] == {"peeljax.saved"} and edges["peeljax.saved"] == {"peeljax.solution"}
    assert _layer("peeljax.solution") < _layer("peeljax.saved")  # and it went up a layer


def test_importing_peeljax_starts_no_backend():
    """No array is made at import (a module's ``jnp`` constant starts XLA's backend), so that
    ``jax.distributed.initialize`` can still run after ``import peeljax`` (multi-process sweeps)."""
    code = "import peeljax, peeljax.cli\nfrom jax._src import xla_bridge\nprint(bool(xla_bridge._backends))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
