"""No module of ``peeljax.fit`` or ``peeljax.orbits`` imports another module's private name: what
one module needs of another is public where it belongs (a private name imported elsewhere is a
rule kept in two places, and breaks silently when its home changes)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "peeljax"
FOLDERS = ("fit", "orbits")


def _private_imports(path: Path, root: Path = PACKAGE.parent) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.level > 0 or (node.module or "").startswith("peeljax")):
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


def test_the_walk_finds_a_private_import(tmp_path):
    module = tmp_path / "peeljax" / "fit" / "example.py"
    module.parent.mkdir(parents=True)
    module.write_text("from .trajectory import _to_law, Observation\n")
    assert _private_imports(module, tmp_path) == ["peeljax/fit/example.py:1 imports _to_law from .trajectory"]
