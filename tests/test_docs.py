"""Every Python block of the README and of the docs runs, and what it shows it prints is checked.

A page's ``python`` blocks run in order in one namespace, in a scratch folder where ``docs/``
is the repository's (so ``docs/examples/…`` paths work and written files land in the scratch
folder). A block shows results in two ways, and both are checked:

* an output block right after it, fenced as ``text title="Output"``: the block's printed
  lines, compared line by line; a number printed in the docs matches to the digits it shows
  (``4.80e-03`` is 4.795e-3 … 4.805e-3), any other text exactly;
* a comment holding only a Python literal after an expression, ``sol.stats["jumps"]  # 210``:
  the expression's value, compared the same way (elementwise for lists and tuples).

A block that cannot run in one test process (it needs several processes) is preceded by
``<!-- docs-test: skip REASON -->``; the test names the ones allowed.
"""

from __future__ import annotations

import ast
import contextlib
import io
import re
import tokenize
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))]
# Pages whose blocks need more than a few seconds (each compiles its own programs).
SLOW = {"README.md", "docs/attractors.md", "docs/fitting.md", "docs/orbits.md", "docs/plotting.md", "docs/reproduction.md", "docs/sweeps.md", "docs/running.md"}
# The only blocks that do not run here, with the reason the page gives.
ALLOWED_SKIPS = {("docs/sweeps.md", "several processes")}

FENCE = re.compile(r"^```(?P<info>[^\n]*)\n(?P<body>.*?)^```[ \t]*$", re.M | re.S)
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
SKIP = re.compile(r"<!-- docs-test: skip (?P<reason>[^>]*?) -->\s*$")


def blocks(text: str) -> list[dict]:
    """The page's fenced blocks in order: python blocks with the output block that follows."""
    fences = list(FENCE.finditer(text))
    out = []
    for i, m in enumerate(fences):
        if m.group("info").strip() != "python":
            continue
        block = {"code": m.group("body"), "line": text[: m.start()].count("\n") + 1, "output": None, "skip": None}
        skip = SKIP.search(text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1] + "\n")
        if skip:
            block["skip"] = skip.group("reason")
        if i + 1 < len(fences):
            nxt = fences[i + 1]
            between = text[m.end() : nxt.start()]
            if not between.strip() and nxt.group("info").strip() == 'text title="Output"':
                block["output"] = nxt.group("body")
        out.append(block)
    return out


def _close(shown: str, value: float) -> bool:
    """``value`` rounds to the number ``shown`` to the digits shown."""
    d = Decimal(shown)
    quantum = Decimal(1).scaleb(d.as_tuple().exponent)
    return abs(Decimal(repr(float(value))) - d) <= quantum / 2 * Decimal("1.000001")


def _matches(shown, value) -> bool:
    if isinstance(shown, str):
        return isinstance(value, str) and value == shown
    if isinstance(shown, bool) or shown is None:
        return bool(value == shown)
    if isinstance(shown, (list, tuple)):
        value = np.asarray(value).tolist() if not isinstance(value, (list, tuple)) else list(value)
        return len(value) == len(shown) and all(_matches(s, v) for s, v in zip(shown, value))
    return False  # numbers are compared from their text, in _literal_matches


def _literal_matches(text: str, value) -> bool:
    node = ast.parse(text, mode="eval").body
    if isinstance(node, (ast.List, ast.Tuple)):
        items = np.asarray(value).tolist() if not isinstance(value, (list, tuple)) else list(value)
        return len(items) == len(node.elts) and all(
            _literal_matches(ast.get_source_segment(text, e), v) for e, v in zip(node.elts, items)
        )
    shown = ast.literal_eval(node)
    if isinstance(shown, (int, float)) and not isinstance(shown, bool):
        value = np.asarray(value)
        if value.shape != () or not np.issubdtype(value.dtype, np.number):
            return False
        if isinstance(shown, int) and "." not in text and "e" not in text.lower():
            return float(value) == shown
        return _close(text.strip().lstrip("+"), float(value))
    return _matches(shown, value if not isinstance(value, np.generic) else value.item())


def checked_comments(code: str) -> dict[int, str]:
    """Line (1-based) → the literal in its trailing comment, for comments that are one literal."""
    found = {}
    for tok in tokenize.generate_tokens(io.StringIO(code).readline):
        if tok.type != tokenize.COMMENT:
            continue
        text = tok.string[1:].strip()
        try:
            ast.literal_eval(text)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
        found[tok.start[0]] = text
    return found


def run_block(code: str, namespace: dict, where: str = "<docs>", first_line: int = 1) -> tuple[str, list[str]]:
    """Run ``code``; return what it printed and the failed ``# literal`` checks. Tracebacks
    name ``where`` and the page's own line numbers (the block's first line is ``first_line``)."""
    tree = ast.parse(code)
    comments = checked_comments(code)
    failures = []
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        for stmt in tree.body:
            literal = comments.get(stmt.end_lineno)
            if isinstance(stmt, ast.Expr) and literal is not None:
                expr = ast.increment_lineno(ast.Expression(stmt.value), first_line - 1)
                value = eval(compile(expr, where, "eval"), namespace)
                if not _literal_matches(literal, value):
                    failures.append(f"line {stmt.end_lineno + first_line - 1}: {ast.unparse(stmt.value)} is {value!r}, the page shows {literal}")
            else:
                module = ast.increment_lineno(ast.Module([stmt], type_ignores=[]), first_line - 1)
                exec(compile(module, where, "exec"), namespace)
    return buffer.getvalue(), failures


def compare_output(shown: str, printed: str) -> list[str]:
    failures = []
    shown_lines, printed_lines = shown.rstrip("\n").split("\n"), printed.rstrip("\n").split("\n")
    if len(shown_lines) != len(printed_lines):
        return [f"printed {len(printed_lines)} lines, the page shows {len(shown_lines)}:\n{printed}"]
    for s, p in zip(shown_lines, printed_lines):
        s_nums, p_nums = NUMBER.findall(s), NUMBER.findall(p)
        same_text = NUMBER.sub("#", s).split() == NUMBER.sub("#", p).split()
        if not same_text or len(s_nums) != len(p_nums) or not all(_close(a, float(b)) for a, b in zip(s_nums, p_nums)):
            failures.append(f"printed  {p!r}\n  page shows {s!r}")
    return failures


def test_the_harness_checks_what_it_claims():
    assert _close("4.80e-03", 4.8049e-3) and not _close("4.80e-03", 4.806e-3)
    assert _literal_matches("210", 210) and not _literal_matches("210", 211)
    assert _literal_matches("[0.36788, 0.73576]", np.array([0.367879, 0.735759]))
    assert _literal_matches("'completed'", "completed") and not _literal_matches("'completed'", "stopped")
    assert compare_output("tau* 4.80e-03 s\n", "tau* 4.801e-03 s\n") == []
    assert compare_output("tau* 4.80e-03 s\n", "tau* 4.67e-03 s\n")
    assert checked_comments("x  # 210\ny  # (n,) arrays\n") == {1: "210"}
    found = blocks('```python\nprint(1)\n```\n\n```text title="Output"\n1\n```\n')
    assert found[0]["output"] == "1\n"


def test_every_page_is_listed_and_the_skips_are_the_allowed_ones():
    skipped = {
        (page, b["skip"]) for page in PAGES for b in blocks((ROOT / page).read_text()) if b["skip"] is not None
    }
    assert skipped <= ALLOWED_SKIPS, skipped - ALLOWED_SKIPS
    assert sum(len([b for b in blocks((ROOT / p).read_text()) if b["skip"] is None]) for p in PAGES) >= 10


@pytest.mark.parametrize(
    "page", [pytest.param(p, marks=pytest.mark.slow) if p in SLOW else p for p in PAGES]
)
def test_python_blocks_run_and_print_what_the_page_shows(page, tmp_path, monkeypatch):
    found = [b for b in blocks((ROOT / page).read_text()) if b["skip"] is None]
    if not found:
        return  # a page without Python (still listed: a block added later is run)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    (tmp_path / "docs").symlink_to(ROOT / "docs")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    failures = []
    for block in found:
        printed, wrong = run_block(block["code"], namespace, str(ROOT / page), block["line"] + 1)
        wrong += compare_output(block["output"], printed) if block["output"] is not None else []
        failures += [f"{page}:{block['line']}: {w}" for w in wrong]
    import matplotlib.pyplot as plt

    plt.close("all")
    assert not failures, "\n".join(failures)


def test_output_blocks_follow_python_blocks():
    """An output block that follows no Python block would never be checked."""
    for page in PAGES:
        text = (ROOT / page).read_text()
        fences = list(FENCE.finditer(text))
        for prev, m in zip([None, *fences], fences):
            if m.group("info").strip() == 'text title="Output"':
                ok = prev is not None and prev.group("info").strip() == "python" and not text[prev.end() : m.start()].strip()
                assert ok, f"{page}:{text[: m.start()].count(chr(10)) + 1}: an output block after no Python block"



def test_the_site_shows_every_notebook_with_the_code_it_has_now():
    """``docs/notebooks/`` holds the executed copies the site renders
    (``python docs/execute_notebooks.py``): one per notebook, with its code as it is now and the
    outputs of a run of that code."""
    import json

    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        copy = ROOT / "docs" / "notebooks" / path.name
        assert copy.exists(), f"{copy.relative_to(ROOT)} missing: run python docs/execute_notebooks.py {path.name}"
        code = [
            [("".join(c["source"]) if c["cell_type"] == "code" else None) for c in json.loads(p.read_text())["cells"]]
            for p in (path, copy)
        ]
        assert code[0] == code[1], f"{path.name} changed since docs/notebooks/ was made: run python docs/execute_notebooks.py {path.name}"
        cells = [c for c in json.loads(copy.read_text())["cells"] if c["cell_type"] == "code"]
        assert all(c.get("outputs") is not None and c.get("execution_count") for c in cells), f"{copy.name}: not executed"
        assert not any(o.get("output_type") == "error" for c in cells for o in c["outputs"]), f"{copy.name}: a cell failed"


def test_the_example_stick_slip_table_is_one_a_run_can_produce():
    """F_stick < F_mean < F_slip in every row (the forces at re-stick, on average, at slip)."""
    from peeljax.fit import read_stick_slip_table

    table = read_stick_slip_table(ROOT / "docs" / "examples" / "stick_slip_table.csv")
    F = table.values
    assert np.all(F["F_stick"] < F["F_mean"]) and np.all(F["F_mean"] < F["F_slip"])


def test_the_api_reference_documents_every_exported_name():
    """Each name of ``peeljax.__all__`` has its ``::: peeljax.NAME`` entry in ``docs/api/``
    (mkdocstrings renders it from the docstring), and the reference names nothing else but the
    public names of subpackages (``peeljax.orbits.OrbitBranch``: a result's type)."""
    import peeljax

    import importlib

    paths = re.findall(r"^::: (peeljax(?:\.\w+)+)$", "\n".join(p.read_text() for p in (ROOT / "docs" / "api").glob("*.md")), re.M)
    entries = [path.rsplit(".", 1)[1] for path in paths]
    missing = sorted(set(peeljax.__all__) - set(entries))
    assert not missing, f"add to a page of docs/api/ (and its nav entry in mkdocs.yml): {missing}"
    assert len(entries) == len(set(entries))
    for path, name in zip(paths, entries):  # a longer path where a submodule has the name (peeljax.simulate)
        module, _, attr = path.rpartition(".")
        if name in peeljax.__all__:
            assert getattr(importlib.import_module(module), attr) is getattr(peeljax, name), path
        else:
            assert attr in importlib.import_module(module).__all__, f"{path}: not a public name of {module}"
