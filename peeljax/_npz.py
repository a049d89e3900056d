"""Reading an .npz that peeljax wrote (a run, a sweep's chunk or result): arrays only, never
pickles, and one clear ValueError naming the file for each way it can be unreadable."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

__all__ = ["read_npz"]

_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a zip archive's first bytes (an empty one: its end record)


def read_npz(path: str | Path, required: tuple[str, ...] = (), *, fix: str = "") -> dict[str, np.ndarray]:
    """All arrays of an .npz (``allow_pickle=False``), or a ValueError naming the file.

    Told apart: a file that cannot be opened, one that is no .npz at all (empty, or other
    bytes, which numpy would call "pickled data"), a damaged one (a truncated or corrupt zip
    archive) and one that lacks a ``required`` array. ``fix`` ends each message (what to do).
    """
    tail = f"; {fix}" if fix else ""
    name = repr(str(path))
    try:
        with open(path, "rb") as stream:
            head = stream.read(4)
    except OSError as error:
        raise ValueError(f"{name} is not a readable .npz file ({error.strerror or error}){tail}") from None
    if head not in _ZIP_MAGIC:
        what = "it is empty" if not head else "it does not start as a zip archive does"
        raise ValueError(f"{name} is not a readable .npz file: {what} (damaged, or another kind of file){tail}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (zipfile.BadZipFile, zlib.error, EOFError) as error:
        raise ValueError(
            f"{name} is not a readable .npz file: it is damaged (truncated or corrupt: {error}){tail}"
        ) from None
    except (OSError, ValueError, KeyError) as error:
        raise ValueError(f"{name} is not a readable .npz file ({error}){tail}") from None
    missing = [key for key in required if key not in arrays]
    if missing:
        raise ValueError(f"{name} is malformed: missing {missing}{tail}")
    return arrays
