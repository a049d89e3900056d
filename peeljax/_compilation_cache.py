"""JAX's persistent compilation cache in the user's cache folder: each program compiled once per machine.

XLA's compilation is most of what a user of peeljax waits for (an orbit computed in 16 ms took
35 s to compile, again in every new process). Importing peeljax points JAX's persistent
compilation cache at one folder per user, so a program compiled by one process (a notebook, the
command line, a sweep's workers) is read back by the next in milliseconds:

* the folder is the platform's user cache folder (``platformdirs``: ``~/.cache/peeljax`` on
  Linux, ``~/Library/Caches/peeljax`` on macOS, ``%LOCALAPPDATA%\\peeljax\\Cache`` on Windows),
  subfolder ``jax-compilation-cache``;
* ``PEELJAX_COMPILATION_CACHE`` moves it (a folder) or turns it off (``off``, ``0``, ``false``,
  ``none``); a cache the user set up for JAX (``JAX_COMPILATION_CACHE_DIR``, or
  ``jax.config.update("jax_compilation_cache_dir", …)`` before importing peeljax) is left as it
  is, and so is ``JAX_ENABLE_COMPILATION_CACHE=false``;
* it holds at most ``MAX_BYTES`` (least recently used entries go first;
  ``JAX_COMPILATION_CACHE_MAX_SIZE`` overrides). A size limit also makes JAX lock the folder
  around each read and write (``filelock``), so processes sharing it never read an entry being
  written;
* an entry that cannot be read (truncated, corrupt) is compiled again: JAX warns and goes on;
* an entry without its record of last use (``KEY-atime`` beside ``KEY-cache``: a process killed
  between JAX's two writes, or a folder filled with no size limit) would make every later write
  fail — JAX's eviction reads every entry's last use — so that nothing is cached again: importing
  peeljax gives each such entry its file's time (:func:`restore_last_use`).
"""

from __future__ import annotations

import os
from pathlib import Path

VARIABLE = "PEELJAX_COMPILATION_CACHE"
OFF = ("off", "0", "false", "no", "none")
SUBFOLDER = "jax-compilation-cache"
MAX_BYTES = 4 * 2**30
# Programs that compile faster than this are not written: about the time an entry takes to key,
# write and read (JAX's own default, 1 s, left out most of an orbit's small programs).
MIN_COMPILE_SECONDS = 0.1
# JAX's names of an entry and of its last use (jax/_src/lru_cache.py)
_ENTRY, _LAST_USE = "-cache", "-atime"


def default_folder() -> Path:
    """The platform's user cache folder for peeljax's compiled programs."""
    import platformdirs

    return Path(platformdirs.user_cache_dir("peeljax", appauthor=False)) / SUBFOLDER


def cache_folder() -> Path | None:
    """The folder peeljax gives JAX's persistent compilation cache, or None where it leaves JAX as it is."""
    import jax

    wanted = os.environ.get(VARIABLE, "").strip()
    if wanted.lower() in OFF:
        return None
    if not jax.config.jax_enable_compilation_cache or jax.config.jax_compilation_cache_dir:
        return None  # the user's own setting
    return Path(wanted).expanduser() if wanted else default_folder()


def enable() -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_folder`; returns the folder (None: untouched).

    A folder that cannot be created (a read-only home) leaves the cache off rather than failing
    the import.
    """
    import jax

    folder = cache_folder()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ:
        jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    restore_last_use(folder)
    return folder


def restore_last_use(folder: Path) -> int:
    """Give each entry of JAX's cache in ``folder`` that lacks it a record of last use (``KEY-atime``:
    the entry's modification time, 8 bytes of nanoseconds, little-endian, as JAX writes it);
    returns how many. Without it JAX's size-limited cache cannot evict, and every write fails
    (``FileNotFoundError … -atime``, a warning per compiled program)."""
    try:
        names = set(os.listdir(folder))
    except OSError:
        return 0
    restored = 0
    for name in names:
        key = name.removesuffix(_ENTRY)
        if key == name or key + _LAST_USE in names:
            continue
        try:  # (a process writing the entry now overwrites this with its own time: harmless)
            used = (folder / name).stat().st_mtime_ns
            (folder / (key + _LAST_USE)).write_bytes(int(used).to_bytes(8, "little"))
        except OSError:
            continue
        restored += 1
    return restored
