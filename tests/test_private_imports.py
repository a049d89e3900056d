"""No module of ``peeljax.fit``, ``peeljax.measurements`` or ``peeljax.orbits`` imports another module's private name, and
no benchmark imports one of the library's: what one module needs of another is public where it
belongs (a private name imported elsewhere is a rule kept in two places, and breaks silently when
its home changes)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "peeljax"
BENCHMARKS = PACKAGE.parent / "benchmarks"
FOLDERS = ("fit", "measurements", "orbits")


def _private_imports(path: Path, root: Path = PACKAGE.parent, only_peeljax: bool = False) -> list[str]:
    """Private names ``path`` imports from peeljax (and, unless ``only_peeljax``, relatively)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        relative = node.level > 0 and not only_peeljax if isinstance(node, ast.ImportFrom) else False
        if isinstance(node, ast.ImportFrom) and (relative or (node.module or "").startswith("peeljax")):
            found += [
                f"{path.relative_to(root)}:{node.lineno} imports {alias.name} from {'.' * node.level}{node.module or ''}"
                for alias in node.names
                if alias.name.startswith("_") and not alias.name.startswith("__")
            ]
    return found


@pytest.mark.parametrize("folder", FOLDERS)
def test_no_module_imports_a_private_name_of_another(folder):
    found = [line for path in sorted((PACKAGE / folder).glob("*.py")) for line in _private_imports(path)]
    assert not found, "\n".join(found)


def test_no_benchmark_imports_a_private_name_of_the_library():
    found = [line for path in sorted(BENCHMARKS.rglob("*.py")) for line in _private_imports(path, only_peeljax=True)]
    assert not found, "\n".join(found)


def test_the_walk_finds_a_private_import(tmp_path):
    module = tmp_path / "peeljax" / "fit" / "example.py"
    module.parent.mkdir(parents=True)
    module.write_text("from .trajectory import _to_law, Observation\n")
    assert _private_imports(module, tmp_path) == ["peeljax/fit/example.py:1 imports _to_law from .trajectory"]


def test_the_walk_finds_a_benchmark_importing_a_private_name(tmp_path):
    script = tmp_path / "benchmarks" / "example.py"
    script.parent.mkdir(parents=True)
    script.write_text("from peeljax.branches import _bounds\nfrom peers import _helper\n")
    assert _private_imports(script, tmp_path, only_peeljax=True) == ["benchmarks/example.py:1 imports _bounds from peeljax.branches"]
