"""Ctrl-C: exit status 130 and one line on stderr, in every phase of every command.

A plain ``KeyboardInterrupt`` went wrong two ways in a JAX program (measured on ``peeljax simulate
--tau 0 --t-final 2000`` interrupted 0 to 10 s after it announced the run): the interpreter's exit
ran JAX's ``atexit`` clean-up while a compilation still ran, and crashed (exit 139); or a callback
(JAX's garbage-collection callback) swallowed the exception and the command ran on, exit 0.

So while a command runs, :func:`guard` notes each SIGINT twice: Python's handler raises the
``KeyboardInterrupt`` that lets the command remove what it half wrote and say what was saved
(:func:`interrupted`); the C-level wake-up fd (``signal.set_wakeup_fd``) wakes a watcher thread,
which raises a swallowed one again (:func:`_unraisable`) and, if the main thread has not ended the
process :data:`GRACE_S` seconds later, prints the line itself. Either way the process ends with
``os._exit(130)`` after flushing stdout and stderr, skipping the ``atexit`` clean-up that would
crash. A ``KeyboardInterrupt`` raised without a signal (a test's stand-in) returns 130.
"""

from __future__ import annotations

import _thread
import contextlib
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator

PROG = "peeljax"
EXIT_STATUS = 130  # the shell's status for a process ended by SIGINT (128 + 2)

# Seconds the main thread has, after SIGINT, to end the process itself (its finally blocks
# remove half-written files) before the watcher does: long enough for Python code to reach
# its next bytecode under load, short enough that a Ctrl-C it cannot take is still prompt.
GRACE_S = 1.0

_STOP = b"\0"  # written by guard() on leaving: no signal has the number 0


class _State:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.said = False  # the one line is printed
        self.signalled = threading.Event()  # a real SIGINT came while guarded
        self.note: Callable[[], str | None] | None = None
        self.swallowed = threading.Event()  # a callback swallowed the KeyboardInterrupt (_unraisable)
        self.reraise = False  # the watcher raises it again: the handler's next call raises
        self.previous_hook = sys.unraisablehook


_state = _State()


def _say(detail: str | None) -> bool:
    """Print the one line, once per process; False if it was printed already."""
    with _state.lock:
        if _state.said:
            return False
        _state.said = True
    with contextlib.suppress(OSError, ValueError):  # stderr closed or gone: the status still says it
        print(f"{PROG}: interrupted" + (f": {detail}" if detail else ""), file=sys.stderr, flush=True)
    return True


def _flush_and_exit() -> None:
    """End the process now with status 130: stdout and stderr flushed (in a helper thread, so
    a blocked pipe cannot hold the exit), no atexit handlers, no interpreter teardown."""

    def flush() -> None:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()

    helper = threading.Thread(target=flush, daemon=True)
    helper.start()
    helper.join(0.5)
    os._exit(EXIT_STATUS)


def interrupted(detail: str | None = None) -> int:
    """After a ``KeyboardInterrupt``: print ``peeljax: interrupted[: detail]`` (once) and, if a real SIGINT came, end
    the process with status 130; else (no signal: an interrupt raised by code) return 130."""
    _say(detail)
    if _state.signalled.is_set():
        _flush_and_exit()
    return EXIT_STATUS


@contextlib.contextmanager
def note(describe: Callable[[], str | None]) -> Iterator[None]:
    """While inside, an interruption's line ends with ``describe()`` (e.g. how many chunks of
    a sweep are saved), whichever thread prints it."""
    previous, _state.note = _state.note, describe
    try:
        yield
        if _state.signalled.is_set():  # the work ended although Ctrl-C came (its exception swallowed)
            interrupted(_detail())
    finally:
        _state.note = previous


def _detail() -> str | None:
    describe = _state.note
    with contextlib.suppress(Exception):  # a damaged chunk folder must not hide the interruption itself
        return None if describe is None else describe()
    return None


def _watch(reader: socket.socket) -> None:
    """The watcher thread: on SIGINT, give the main thread GRACE_S to end the process, then end it."""
    while True:
        try:
            data = reader.recv(64)
        except OSError:
            return
        if not data or _STOP in data:
            return
        if bytes([signal.SIGINT]) in data:
            break
    deadline = time.monotonic() + GRACE_S
    while (left := deadline - time.monotonic()) > 0:
        if _state.swallowed.wait(min(left, 0.02)):  # a callback swallowed it: raise it again
            _state.swallowed.clear()
            _state.reraise = True
            _thread.interrupt_main(signal.SIGINT)
    # Still alive GRACE_S later: the main thread is inside XLA, its KeyboardInterrupt was
    # swallowed again and again, or its clean-up is slow; either way the process ends here.
    _say(_detail())
    _flush_and_exit()


def _on_sigint(signum, frame) -> None:
    """Python's handler (main thread): the first SIGINT raises KeyboardInterrupt; a second one, while the first is
    being handled, is left to the watcher (no exception out of the clean-up), unless the first one was swallowed
    (:func:`_unraisable`): then it is raised again."""
    if _state.signalled.is_set() and not _state.reraise:
        return
    _state.reraise = False
    _state.signalled.set()
    raise KeyboardInterrupt


def _unraisable(hook_args) -> None:
    """``sys.unraisablehook`` while guarded: a KeyboardInterrupt that a callback swallowed (JAX's garbage-collection
    callback) prints no "Exception ignored" traceback; it is raised again in the main thread by the watcher (a
    raise from here would be swallowed too)."""
    if isinstance(hook_args.exc_value, KeyboardInterrupt) and _state.signalled.is_set():
        _state.swallowed.set()  # the watcher raises it again, once the callback has returned
        return
    _state.previous_hook(hook_args)


@contextlib.contextmanager
def guard() -> Iterator[None]:
    """While inside (the main thread of a command), SIGINT ends the process with status 130 and one line, whatever
    the main thread is doing (see the module's docstring). Elsewhere (another thread, a platform without a
    wake-up fd) a no-op."""
    _state.said = False
    _state.signalled.clear()
    _state.swallowed.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    try:
        reader, writer = socket.socketpair()
    except OSError:
        yield
        return
    writer.setblocking(False)
    try:
        previous_fd = signal.set_wakeup_fd(writer.fileno(), warn_on_full_buffer=False)
        previous_handler = signal.signal(signal.SIGINT, _on_sigint)
    except (ValueError, OSError):
        reader.close()
        writer.close()
        yield
        return
    watcher = threading.Thread(target=_watch, args=(reader,), name="peeljax-sigint", daemon=True)
    watcher.start()
    _state.reraise, _state.previous_hook, sys.unraisablehook = False, sys.unraisablehook, _unraisable
    try:
        yield
        if _state.signalled.is_set():  # the command ended although Ctrl-C came (its exception swallowed)
            interrupted(_detail())
    finally:
        sys.unraisablehook = _state.previous_hook
        signal.signal(signal.SIGINT, previous_handler)
        signal.set_wakeup_fd(previous_fd)
        with contextlib.suppress(OSError):
            writer.send(_STOP)
        watcher.join(0.1)
        reader.close()
        writer.close()
