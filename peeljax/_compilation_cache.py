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
* an entry that cannot be read (truncated, corrupt) is compiled again: JAX warns and goes on.
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
    return folder
