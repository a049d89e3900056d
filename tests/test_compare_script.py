"""``benchmarks/`` keeps working; its numbers are not asserted (speed is a benchmark).

``compare.py --smoke`` runs every peer once and reports it, its JAX peers compile in ``setup`` only,
and its report is remade from its JSON alone; every result file names the command that made it;
the runner names a script for every table; the imports of ``benchmarks/`` have no circle.
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
MADE_BY = re.compile(r"^Made by `(python (benchmarks/\S+\.py)[^`]*)`")


@pytest.mark.slow
def test_compare_smoke_runs_every_peer(tmp_path):
    out = tmp_path / "latest.md"
    subprocess.run(
        [sys.executable, str(BENCH / "compare.py"), "--smoke", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    text = out.read_text()
    data = json.loads(out.with_suffix(".json").read_text())
    assert next(iter(data)) == "command" and data["command"].startswith("python benchmarks/compare.py --smoke")
    assert text.splitlines()[0] == f"Made by `{data['command']}`."
    assert (tmp_path / "work_precision_smoke.png").stat().st_size > 0
    for peer in ("peeljax α-method", "numba α-method", "diffrax Kvaerno5", "scipy Radau", "SUNDIALS CVODE", "CasADi cvodes"):
        assert f"| {peer}" in text, peer
    lines = text.splitlines()
    # Every peer of the bench extra is installed with the test extra; only PETSc (petsc4py, run by
    # another interpreter) may be missing, and then its row says so cleanly.
    petsc_rows = [line for line in lines if line.startswith("| PETSc")]
    assert len(petsc_rows) == 1, petsc_rows
    assert "unavailable" not in "\n".join(line for line in lines if not line.startswith("| PETSc"))
    unavailable = "unavailable: petsc4py not installed (" in petsc_rows[0] and "not run here" in petsc_rows[0]
    ran = "TSALPHA" in petsc_rows[0] and "| N = 300 |" in petsc_rows[0]
    assert unavailable or ran, petsc_rows[0]
    peeljax_rows = [line for line in lines if line.startswith("| peeljax α-method | N = 300 |")]
    assert peeljax_rows and "| ok |" in peeljax_rows[0]

    # (P1) the JAX peers compile in setup only: no compilation inside the checking run or the timed runs.
    (p1,) = data["p1"]
    rows = {peer["name"]: peer["rows"] for peer in p1["peers"]}
    for name in ("peeljax α-method", "peeljax adaptive α", "diffrax Kvaerno5"):
        (row,) = rows[name]
        assert row["status"] == "ok" and row["times"] and row["compiles_in_run"] == 0, (name, row)
    assert "JAX compilations inside the timed calls (the checking run and the timed runs, after `setup`): none." in text

    # (P3) the batch: every method has a row with a time and a ratio to peeljax, and the targets are stated.
    p3 = text[text.index("## (P3) a batch of 4 trajectories") : text.index("## (P4)")]
    for method in ("peeljax.sweep", "diffrax Kvaerno5 under jax.vmap", "SUNDIALS CVODE", "CasADi cvodes", "scipy Radau"):
        row = next(line for line in p3.splitlines() if line.startswith(f"| {method}"))
        assert row.rstrip().endswith("|") and row.split("|")[-2].strip().replace(".", "").isdigit(), row
    assert "Targets (issue 6): peeljax ≥ 10× faster than diffrax under vmap:" in p3

    # (P4) the gradient: peeljax, finite differences and CasADi's forward sensitivities ran and were checked.
    p4 = text[text.index("## (P4) the gradient of a trajectory loss") : text.index("## (P5)")]
    for method in ("peeljax reverse mode", "central differences of peeljax", "CasADi cvodes (log v), forward"):
        row = next(line for line in p4.splitlines() if line.startswith(f"| {method}"))
        assert "| ok |" in row, row
    assert "Targets (issue 6), at equal gradient error:" in p4

    # The report is made from the JSON alone: remade elsewhere, it is the same file, header included.
    sys.path.insert(0, str(BENCH))
    import compare_report

    again = tmp_path / "again" / "latest.md"
    again.parent.mkdir()
    compare_report.write_report(compare_report.load(out.with_suffix(".json")), again)
    assert again.read_text() == text


def _first_line_command(path: Path) -> str:
    """The command a result file names: its first line (markdown), key (JSON) or PNG description."""
    if path.suffix == ".md":
        return path.read_text(encoding="utf-8").splitlines()[0]
    if path.suffix == ".json":
        data = json.loads(path.read_text(encoding="utf-8"))
        key = next(iter(data))
        assert key == "command", path
        return f"Made by `{data[key]}`."
    if path.suffix == ".png":
        from PIL import Image

        return Image.open(path).info.get("Description", "")
    raise AssertionError(f"{path}: a result file of a kind without a header rule")


def test_every_result_file_names_the_command_that_made_it():
    files = sorted(p for folder in ("results", "studies/results") for p in (BENCH / folder).iterdir())
    assert len(files) >= 25
    for path in files:
        line = _first_line_command(path)
        found = MADE_BY.match(line)
        assert found, f"{path.relative_to(ROOT)}: {line[:100]!r}"
        script = ROOT / found.group(2)
        # a script removed since names where git keeps it, or the index of retired studies does
        retired = found.group(2) in _retired_scripts() or ("removed" in line and "git show" in line)
        assert script.is_file() or retired, (path, found.group(2))


def _retired_scripts() -> set[str]:
    """The scripts ``benchmarks/studies/README.md`` lists as retired (in its table, by path)."""
    index = (BENCH / "studies" / "README.md").read_text(encoding="utf-8")
    return set(re.findall(r"^\| `(benchmarks/\S+\.py)`", index, flags=re.M))


def test_the_retired_scripts_are_gone_and_nothing_imports_them():
    retired = _retired_scripts()
    assert len(retired) >= 20
    assert not any((ROOT / path).exists() for path in retired), retired
    names = {Path(path).stem for path in retired}
    for module in _benchmark_modules().values():
        tree = ast.parse(module.read_text(encoding="utf-8"))
        imported = {alias.name.split(".")[-1] for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        imported |= {node.module.split(".")[-1] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
        assert not imported & names, (module, imported & names)


def _benchmark_modules():
    """name -> path of every module of ``benchmarks/``, named as the scripts import them (studies: ``studies.X``)."""
    modules = {}
    for path in sorted(BENCH.rglob("*.py")):
        parts = path.relative_to(BENCH).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def test_benchmark_imports_have_no_circle():
    modules = _benchmark_modules()
    edges = {}
    for name, path in modules.items():
        edges[name] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):  # function-level imports count too
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets = [node.module]
            for target in targets:
                for candidate in (target, target.split(".")[0]):  # ``peers.x`` runs ``peers`` first
                    if candidate in modules and candidate != name:
                        edges[name].add(candidate)
    assert edges["compare_problems"] <= {"machine"}  # the floor of the suite
    assert {"compare_problems", "peers.compiled_loop"} <= edges["peers.casadi_peer"]
    for name, targets in edges.items():  # the suite never needs a study
        if not name.startswith("studies."):
            assert not any(t.startswith("studies.") for t in targets), (name, targets)
    state = {}

    def visit(name, stack):
        state[name] = "open"
        for target in sorted(edges[name]):
            assert state.get(target) != "open", f"import circle: {' -> '.join([*stack, name, target])}"
            if target not in state:
                visit(target, [*stack, name])
        state[name] = "done"

    for name in modules:
        if name not in state:
            visit(name, [])


def test_the_runner_names_a_script_for_every_table(capsys):
    sys.path.insert(0, str(BENCH))
    import run

    for table, (module, args, _) in run.TABLES.items():
        script = BENCH / f"{module}.py"
        main = next(n for n in ast.parse(script.read_text(encoding="utf-8")).body if getattr(n, "name", "") == "main")
        assert main.args.args and main.args.args[0].arg == "argv", table  # run.py calls main(argv)
        assert run.script_command(table, ["--quick"]) == [str(script), *args, "--quick"]
    assert set(run.ALL) <= set(run.TABLES)
    assert run.main([]) == 0
    listing = capsys.readouterr().out
    assert all(f"  {table} " in listing for table in run.TABLES)
    assert run.main(["p7"]) == 2 and "unknown table 'p7'" in capsys.readouterr().err
    assert run.main(["all", "--quick"]) == 2
