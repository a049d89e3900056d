"""The README: its test command is the one CI runs, it stays short, and names no issue numbers."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    command = next(line for line in ci.splitlines() if "pytest" in line).strip()
    # set -e does not stop at a failure inside a && list: CI must, or a lint error skips the fast tier
    assert command.endswith(" || exit 1"), command
    command = command.removesuffix(" || exit 1")
    assert command.startswith("python3 -m venv .venv") and "mkdocs build --strict" in command and "ruff check" in command
    assert command in README
    assert README.index(command) < README.index("## Example")  # among the opening commands


def test_readme_is_at_most_150_lines():
    assert len(README.splitlines()) <= 150


def test_user_facing_text_names_no_issue_numbers():
    pages = {"README.md": README, "CHANGELOG.md": (ROOT / "CHANGELOG.md").read_text()}
    pages |= {str(p.relative_to(ROOT)): p.read_text() for p in (ROOT / "docs").rglob("*.md")}
    for name, text in pages.items():
        hits = re.findall(r"\b(?:[Ii]ssues?|#) ?\d+(?:\s*[–-]\s*\d+)?\b(?![\d.])", text)
        hits = [h for h in hits if not h.startswith("#")]  # "#1" in a Markdown heading or a shell comment
        assert not hits, f"{name}: {hits}"


def test_links_in_the_readme_point_to_files_that_exist():
    for target in re.findall(r"\]\(([^)#]+)\)", README):
        if "://" not in target:
            assert (ROOT / target).exists(), target
