"""Reading an .npz that peeljax wrote (a run, a sweep's chunk or result): arrays only, never
pickles, and one clear ValueError naming the file for each way it can be unreadable."""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path

import numpy as np

from . import _memory

__all__ = ["check_declared_sizes", "read_npz"]

_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a zip archive's first bytes (an empty one: its end record)


def check_declared_sizes(path: str | Path, memory_limit: float | None = None) -> None:
    """Refuse (ValueError) an archive whose member's .npy header declares more bytes than the
    member holds: numpy would allocate the declared size first (a damaged or hostile header of
    a few bytes can ask for terabytes); and one whose arrays together would take more than
    ``memory_limit`` bytes (default: :func:`peeljax._memory.memory_limit`, half the RAM).
    Read: the zip directory and each header, no data."""
    limit = _memory.memory_limit() if memory_limit is None else float(memory_limit)
    total = 0
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(member)
                else:
                    shape, _, dtype = np.lib.format.read_array_header_2_0(member)
                declared = math.prod(shape) * dtype.itemsize
                held = info.file_size - member.tell()
            if declared > held and not dtype.hasobject:  # object arrays: pickles, refused when read
                raise ValueError(
                    f"damaged: its array {info.filename[:-4]!r} declares {declared} bytes (shape {shape}), "
                    f"the archive holds {held}"
                )
            total += declared
    if total > limit:
        raise ValueError(
            f"too large to read: its arrays take {total / 1e9:.3g} GB once read, more than the memory limit of "
            f"{limit / 1e9:.3g} GB"
        )


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
        check_declared_sizes(path)
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as error:
        # the last two: zipfile's "compression method not supported" and "encrypted" (damaged flag bits)
        raise ValueError(
            f"{name} is not a readable .npz file: it is damaged (truncated or corrupt: {error}){tail}"
        ) from None
    except (OSError, ValueError, KeyError) as error:
        raise ValueError(f"{name} is not a readable .npz file ({error}){tail}") from None
    missing = [key for key in required if key not in arrays]
    if missing:
        raise ValueError(f"{name} is malformed: missing {missing}{tail}")
    return arrays
