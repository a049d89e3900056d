"""Execute the notebooks once and store the executed copies for the docs site.

    python docs/execute_notebooks.py [NAME.ipynb ...] [--quick] [--timeout 1200]

Runs each ``notebooks/*.ipynb`` top to bottom (nbclient, the ``notebooks`` or ``test`` extra)
and writes it, with its outputs and figures, to ``docs/notebooks/``. The site renders those
copies (mkdocs-jupyter with ``execute: false``): ``mkdocs build`` executes nothing.
``tests/test_docs.py`` checks that every copy holds the same code as its notebook, so a notebook
edited without rerunning this script fails the tests. ``--quick`` sets
``PEELJAX_NOTEBOOK_T_FINAL=0.2`` (the short runs of the tests) instead of the notebooks' own spans.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import nbclient
import nbformat

ROOT = Path(__file__).resolve().parents[1]
SOURCE, TARGET = ROOT / "notebooks", ROOT / "docs" / "notebooks"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="notebook file names (default: all)")
    parser.add_argument("--quick", action="store_true", help="the tests' short runs (PEELJAX_NOTEBOOK_T_FINAL=0.2)")
    parser.add_argument("--timeout", type=float, default=1200, help="seconds per cell (default 1200)")
    args = parser.parse_args(argv)
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    if args.quick:
        env["PEELJAX_NOTEBOOK_T_FINAL"] = "0.2"
    TARGET.mkdir(parents=True, exist_ok=True)
    for path in sorted(SOURCE / n for n in args.names) if args.names else sorted(SOURCE.glob("*.ipynb")):
        book = nbformat.read(path, as_version=4)
        start = time.perf_counter()
        client = nbclient.NotebookClient(
            book, timeout=args.timeout, kernel_name="python3", resources={"metadata": {"path": str(SOURCE)}},
            extra_arguments=["--matplotlib=inline"],  # a cell ending in a Figure shows it as a PNG
        )
        client.execute(env=env)
        book.metadata.pop("widgets", None)
        nbformat.write(book, TARGET / path.name)
        print(f"{path.name}: {time.perf_counter() - start:.0f} s -> {(TARGET / path.name).relative_to(ROOT)}")


if __name__ == "__main__":
    main()
