"""Release mechanics: one version (pyproject.toml, read back from the installed metadata), a
licence, the PEP 561 marker, and deprecations that name the release removing them."""

import re
import tomllib
from importlib import metadata, resources
from pathlib import Path

import peeljax as pj

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in text.split("."))


def test_version_is_set_once_and_read_from_metadata():
    assert pj.__version__ == metadata.version("peeljax") == PYPROJECT["project"]["version"]
    init = (ROOT / "peeljax" / "__init__.py").read_text()
    assert PYPROJECT["project"]["version"] not in init  # not written a second time


def test_changelog_has_a_section_for_this_version():
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in changelog
    assert re.search(rf"^## \[{re.escape(pj.__version__)}\] - \d{{4}}-\d{{2}}-\d{{2}}$", changelog, re.M)


def test_license_matches_the_metadata():
    assert PYPROJECT["project"]["license"] == {"text": "MIT"}
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "the peeljax developers" in text


def test_py_typed_ships_as_package_data():
    assert resources.files("peeljax").joinpath("py.typed").is_file()
    assert "py.typed" in PYPROJECT["tool"]["setuptools"]["package-data"]["peeljax"]


def test_every_deprecation_names_the_release_that_removes_it():
    """A deprecation (a DeprecationWarning, or the CLI's note) says "removed in peeljax X.Y.Z",
    with X.Y.Z a release after this one."""
    found = 0
    for path in sorted((ROOT / "peeljax").rglob("*.py")):
        text = path.read_text()
        if "DeprecationWarning" not in text and "is deprecated" not in text:
            continue
        found += 1
        versions = re.findall(r"removed in peeljax (\d+\.\d+\.\d+)", text)
        assert versions, f"{path.relative_to(ROOT)}: a deprecation that names no release removing it"
        for v in versions:
            assert _version(v) > _version(pj.__version__), f"{path.relative_to(ROOT)}: removal in {v}, already out"
    assert found >= 3  # peeljax.fit.data, peeljax.stick_slip_plots, the CLI's old spellings
