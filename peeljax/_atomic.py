"""Writing a file so that a failed write never destroys the previous one.

Every file peeljax writes (runs, sweeps and their chunks, maps, fits, tables, figures, JSON)
goes through :func:`replacing`: the writer fills a temporary file in the target's folder, and
only a complete file is renamed onto the target (``os.replace``, atomic within one file
system). A write that fails midway — a full disk, an error, Ctrl-C — removes the temporary
file and leaves the previous file exactly as it was.

The new file gets the mode a plain ``open`` would give it: the old file's mode when it
replaces one, else 0666 less the umask (not the temporary file's 0600). A target that exists
and is not a regular file (``/dev/null``, a named pipe) is written in place: it cannot be
replaced, and holds no previous result. A symbolic link is followed: its target is replaced.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

__all__ = ["replacing", "save_figure", "write_bytes", "write_npz", "write_text"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def replacing(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path in ``path``'s folder to write; renamed onto ``path`` when the block ends
    without an exception, removed when it raises (the exception goes on).

    ``with replacing("run.npz") as temporary: np.savez(temporary, ...)``: the name ``run.npz``
    either keeps its previous file or holds the complete new one, never a partial file.
    """
    target = Path(path)
    if target.is_symlink():
        target = Path(os.path.realpath(target))
    try:
        info = target.stat()
    except OSError:
        info = None
    if info is not None and not stat.S_ISREG(info.st_mode):
        yield target  # a device or a pipe: written in place (nothing there to keep)
        return
    mode = stat.S_IMODE(info.st_mode) if info is not None else 0o666 & ~_umask()
    handle, name = tempfile.mkstemp(prefix=f"{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        with open(temporary, "rb") as stream:  # on disk before the rename (a crash keeps the old file)
            os.fsync(stream.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """``data`` to ``path`` through :func:`replacing`."""
    with replacing(path) as temporary, open(temporary, "wb") as stream:
        stream.write(data)


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """``text`` to ``path`` through :func:`replacing`."""
    with replacing(path) as temporary, open(temporary, "w", encoding=encoding) as stream:
        stream.write(text)


def write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """``np.savez`` of ``arrays`` to ``path`` (the name kept exactly as given: ``np.savez``
    would append ``.npz`` to a bare name), through :func:`replacing`."""
    with replacing(path) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, **arrays)


def save_figure(fig, path: str | os.PathLike, **kwargs) -> None:
    """``fig.savefig(path, **kwargs)`` through :func:`replacing`: the format from the suffix as
    matplotlib reads it (a name without one gets matplotlib's default format and suffix)."""
    path = os.fspath(path)
    fmt = kwargs.pop("format", None) or os.path.splitext(path)[1][1:].lower()
    if not fmt:
        import matplotlib

        fmt = matplotlib.rcParams["savefig.format"]
        path = path.rstrip(".") + "." + fmt
    with replacing(path) as temporary, open(temporary, "wb") as stream:
        fig.savefig(stream, format=fmt, **kwargs)
