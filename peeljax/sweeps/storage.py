"""Chunked sweep output on disk: one ``.npz`` per finished chunk, resumable.

Layout for ``out = "sweep.npz"``:

* ``sweep.npz.chunks/meta.json``: ``{"format": "peeljax-sweep", "version": 2, "settings": …}``;
  the settings are every input that changes the results (grid, mesh, window, solver, model).
* ``sweep.npz.chunks/chunk_00000.npz``, …: each chunk's per-trajectory arrays, written (to a
  temporary name, then renamed) as soon as the chunk is done.
* ``sweep.npz``: every trajectory's arrays, plus ``meta_json`` (the settings, and the file's
  kind, units and peeljax version: :mod:`peeljax._files`), written when all chunks are done; for
  ``out = "sweep.nc"`` a netCDF-4 file (:mod:`.labelled`) with the same settings as attributes.

A rerun with the same ``out`` and the same settings loads the finished chunks and computes
only the rest; different settings are refused. Files are read with ``allow_pickle=False`` and
written through :func:`peeljax._atomic.replacing` (a failed write keeps the previous file).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._atomic import write_npz, write_text
from .._files import META_KEY, metadata, read_netcdf, require_xarray, write_netcdf
from .._npz import read_npz

__all__ = [
    "FORMAT", "VERSION", "ChunkStore", "check_writable_format", "is_netcdf", "load_npz", "saved_chunks", "write_npz_atomic",
    "write_result",
]

FORMAT = "peeljax-sweep"
VERSION = 2

write_npz_atomic = write_npz  # the name this module gave it first


def is_netcdf(path) -> bool:
    """A ``.nc`` suffix: the merged result is written as netCDF."""
    return Path(str(path)).suffix.lower() == ".nc"


def check_writable_format(out) -> None:
    """An ``out`` ending in ``.nc`` needs xarray and h5netcdf: an ImportError now, not after the run."""
    if is_netcdf(out):
        require_xarray(f"out={str(out)!r} (netCDF)", netcdf=True)


def write_result(path, result, meta: dict) -> None:
    """The merged result: netCDF for a ``.nc`` suffix, else ``.npz``; ``meta`` (format,
    version, settings) is what a resume compares."""
    if is_netcdf(path):
        dataset = result.to_xarray()
        dataset.attrs[META_KEY] = json.dumps(meta)
        write_netcdf(dataset, path)
        return
    from .labelled import sweep_units

    described = {**meta, **metadata("sweep", sweep_units(result.params))}
    write_npz(path, {**result.arrays(), META_KEY: np.asarray(json.dumps(described), dtype=str)})


def load_npz(path: Path, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """All arrays of an .npz (no pickles); a ValueError naming the file if it is unreadable
    (:func:`peeljax._npz.read_npz`: not an .npz, damaged, or missing an array)."""
    return read_npz(path, required, fix="delete it to recompute")


def _differences(old: dict, new: dict) -> list[str]:
    keys = sorted(set(old) | set(new))
    return [key for key in keys if old.get(key) != new.get(key)]


def saved_chunks(out: str | Path) -> tuple[int, int | None]:
    """How many chunks of the sweep writing ``out`` are saved in its chunk folder, and of how many
    (None where its meta.json cannot tell): what an interrupted sweep leaves to resume from."""
    folder = Path(str(out) + ".chunks")
    saved = len(list(folder.glob("chunk_*.npz"))) if folder.is_dir() else 0
    try:
        return saved, int(json.loads((folder / "meta.json").read_text())["n_chunks"])
    except (OSError, ValueError, KeyError, TypeError, OverflowError):  # absent or damaged: no total
        return saved, None


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
        if is_netcdf(self.out):
            from .labelled import sweep_arrays

            dataset = read_netcdf(self.out)
            text = dataset.attrs.get(META_KEY)
            if not isinstance(text, str):
                raise ValueError(f"{str(self.out)!r} is not a peeljax sweep output (no {FORMAT!r} metadata); use another out")
            arrays, _ = sweep_arrays(dataset, repr(str(self.out)))
        else:
            arrays = load_npz(self.out, (META_KEY, *self.keys))
            text = str(arrays.pop(META_KEY))
        try:
            meta = json.loads(text)
        except json.JSONDecodeError as error:
            raise ValueError(f"{str(self.out)!r}: malformed meta_json ({error})") from None
        self.check_meta(meta, repr(str(self.out)))
        missing = [key for key in self.keys if key not in arrays]
        if missing:
            raise ValueError(f"{str(self.out)!r} is malformed: missing {missing}; delete it to recompute")
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
            write_text(meta_path, json.dumps(self.meta, indent=1) + "\n")

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
        write_npz(self.path(index), arrays)

    def finish(self, result) -> None:
        """Write the merged :class:`~peeljax.SweepResult` to ``out`` (:func:`write_result`)."""
        write_result(self.out, result, self.meta)
