"""Chunked sweep output on disk: one ``.npz`` per finished chunk, resumable.

Layout for ``out = "sweep.npz"``:

* ``sweep.npz.chunks/meta.json``: ``{"format": "peeljax-sweep", "version": 2, "settings": …}``;
  the settings are every input that changes the results (grid, mesh, window, solver, model).
* ``sweep.npz.chunks/chunk_00000.npz``, …: each chunk's per-trajectory arrays, written (to a
  temporary name, then renamed) as soon as the chunk is done.
* ``sweep.npz``: every trajectory's arrays, plus ``meta_json``, written when all chunks are done.

A rerun with the same ``out`` and the same settings loads the finished chunks and computes
only the rest; different settings are refused. Files are read with ``allow_pickle=False``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .._npz import read_npz

__all__ = ["FORMAT", "VERSION", "ChunkStore", "load_npz", "write_npz_atomic"]

FORMAT = "peeljax-sweep"
VERSION = 2


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez to a temporary file in the same folder, then an atomic rename.

    The file gets the mode a plain ``open`` would give it (0666 less the umask, e.g. 0644),
    not the temporary file's 0600.
    """
    path = Path(path)
    handle, temporary = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez(stream, **arrays)
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def load_npz(path: Path, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """All arrays of an .npz (no pickles); a ValueError naming the file if it is unreadable
    (:func:`peeljax._npz.read_npz`: not an .npz, damaged, or missing an array)."""
    return read_npz(path, required, fix="delete it to recompute")


def _differences(old: dict, new: dict) -> list[str]:
    keys = sorted(set(old) | set(new))
    return [key for key in keys if old.get(key) != new.get(key)]


class ChunkStore:
    """The folder of finished chunks for one output file (see the module docstring)."""

    def __init__(self, out: str | Path, settings: dict, n_chunks: int, chunk_sizes: list[int], keys: tuple[str, ...]):
        self.out = Path(out)
        self.folder = Path(str(self.out) + ".chunks")
        self.settings = settings
        self.n_chunks = n_chunks
        self.chunk_sizes = chunk_sizes
        self.keys = keys
        self.meta = {"format": FORMAT, "version": VERSION, "settings": settings, "n_chunks": n_chunks}

    # ------------------------------------------------------------------ checks
    def check_meta(self, meta, source: str) -> None:
        if not isinstance(meta, dict) or meta.get("format") != FORMAT or "settings" not in meta:
            raise ValueError(f"{source} is not a peeljax sweep output (no {FORMAT!r} metadata); use another out")
        if meta.get("version") != VERSION:
            raise ValueError(
                f"{source} has format version {meta.get('version')!r}, written by another peeljax; this one reads and "
                f"writes version {VERSION}: use another out, or delete it to recompute"
            )
        if not isinstance(meta["settings"], dict):
            raise ValueError(f"{source}: malformed metadata (settings is not an object)")  # noqa: TRY004
        differ = _differences(meta["settings"], self.settings)
        if differ:
            raise ValueError(
                f"{source} was made with different settings ({', '.join(differ)} differ); refusing to resume into it: "
                f"choose another out, or delete {str(self.out)!r} and {str(self.folder)!r} to start again"
            )

    def finished_output(self) -> dict[str, np.ndarray] | None:
        """The merged output file's arrays if it exists and matches these settings (else None / error)."""
        if not self.out.exists():
            return None
        arrays = load_npz(self.out, ("meta_json", *self.keys))
        try:
            meta = json.loads(str(arrays.pop("meta_json")))
        except json.JSONDecodeError as error:
            raise ValueError(f"{str(self.out)!r}: malformed meta_json ({error})") from None
        self.check_meta(meta, repr(str(self.out)))
        return arrays

    def open(self) -> None:
        """Create the folder and meta.json, or check the existing meta.json against these settings."""
        meta_path = self.folder / "meta.json"
        if self.folder.exists():
            if not meta_path.exists():
                raise ValueError(f"{str(self.folder)!r} exists but has no meta.json; delete it or choose another out")
            try:
                meta = json.loads(meta_path.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError) as error:
                raise ValueError(
                    f"{str(meta_path)!r} is not valid JSON ({error}); delete the folder to start again"
                ) from None
            except OSError as error:  # a folder, no permission: a bad resume, not a failed write
                raise ValueError(
                    f"{str(meta_path)!r} cannot be read ({error.strerror or error}); delete the folder to start again"
                ) from None
            self.check_meta(meta, repr(str(meta_path)))
        else:
            self.folder.mkdir(parents=False)
            meta_path.write_text(json.dumps(self.meta, indent=1) + "\n")

    # ------------------------------------------------------------------ chunks
    def path(self, index: int) -> Path:
        return self.folder / f"chunk_{index:05d}.npz"

    def load(self, index: int) -> dict[str, np.ndarray] | None:
        """A finished chunk's arrays, or None if it has not been written."""
        path = self.path(index)
        if not path.exists():
            return None
        arrays = load_npz(path, self.keys)
        size = self.chunk_sizes[index]
        for key in self.keys:
            if arrays[key].shape[:1] != (size,):
                raise ValueError(
                    f"{str(path)!r} is malformed: {key} has shape {arrays[key].shape}, expected {size} trajectories; "
                    "delete it to recompute"
                )
        return arrays

    def save(self, index: int, arrays: dict[str, np.ndarray]) -> None:
        write_npz_atomic(self.path(index), arrays)

    def finish(self, arrays: dict[str, np.ndarray]) -> None:
        write_npz_atomic(self.out, {**arrays, "meta_json": np.asarray(json.dumps(self.meta), dtype=str)})
