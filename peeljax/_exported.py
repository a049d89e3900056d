"""Traced programs kept on disk beside the compiled ones: a new process skips tracing as well.

JAX's persistent compilation cache (:mod:`peeljax._compilation_cache`) keeps XLA's compiled
programs, but a new process still traces the Python into a jaxpr and lowers it to StableHLO
before it can look one up: 8.6 of the 10.9 s of a first orbit at V = 1.1 with that cache warm
(``benchmarks/results/first_call.md``). A program called with arrays alone is therefore
exported once (``jax.export``: its StableHLO and calling convention, serialized) into the
folder ``exported-programs`` inside the compilation cache's, and the next process reads it back
in milliseconds and goes straight to the compilation cache.

The key of an entry holds everything the program depends on besides the values of its array
arguments: the arguments' structure (the classes and static fields of the model, the
integrator and the rest, as ``jax.tree_util`` sees them), every leaf's shape and dtype, the
versions of jax, jaxlib and the libraries peeljax builds on, the digest of peeljax's own source
files and the platform. Only classes of peeljax and of those libraries are trusted: a class of
the user's (a φ written as their own module) can change under the same name, and its programs
are traced in each process as before. A program that cannot be exported (a host callback) is
traced as before, and remembered so for the process; an entry that cannot be read is removed
and exported again. The folder holds at most ``MAX_BYTES`` (the oldest entries go first).
``PEELJAX_EXPORTED_PROGRAMS=off`` turns this off alone; turning the compilation cache off
(``PEELJAX_COMPILATION_CACHE=off``) turns it off too.
"""

from __future__ import annotations

import contextlib
import enum
import functools
import hashlib
import importlib
import importlib.metadata
import json
import math
import os
import struct
import weakref
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from jax import export

from ._atomic import write_bytes

__all__ = ["ExportedProgram", "HostOutputs", "OutputLayout", "all_arrays", "compiled", "forget", "programs_folder"]

VARIABLE = "PEELJAX_EXPORTED_PROGRAMS"
SUBFOLDER = "exported-programs"
MAX_BYTES = 2**30
SUFFIX = ".jaxexport"
# Classes whose structure is trusted to be what their name and static fields say.
TRUSTED_PACKAGES = ("peeljax", "equinox", "diffrax", "lineax", "optimistix", "optax", "jax", "jaxlib", "builtins", "numpy")
_LIBRARIES = ("jax", "jaxlib", "equinox", "diffrax", "lineax", "optimistix", "optax", "numpy", "flatbuffers")


class NotExportable(Exception):
    """The program or its arguments cannot be kept on disk soundly: it is traced as before."""


# ---------------------------------------------------------------------------- where and under which key
def programs_folder() -> Path | None:
    """The folder of exported programs: ``exported-programs`` inside JAX's compilation cache folder, or None (off)."""
    if os.environ.get(VARIABLE, "").strip().lower() in ("off", "0", "false", "no", "none"):
        return None
    if not jax.config.jax_enable_compilation_cache or not jax.config.jax_compilation_cache_dir:
        return None
    if not hasattr(export, "register_pytree_node_serialization"):  # jax < 0.4.32
        return None
    return Path(jax.config.jax_compilation_cache_dir) / SUBFOLDER


@functools.cache
def _code_digest() -> str:
    """peeljax's source files and the versions of what it traces with, as one digest."""
    digest = hashlib.sha256()
    for name in _LIBRARIES:
        try:
            digest.update(f"{name}={importlib.metadata.version(name)};".encode())
        except importlib.metadata.PackageNotFoundError:
            digest.update(f"{name}=-;".encode())
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    digest.update(jax.default_backend().encode())
    digest.update(str(jax.config.jax_enable_x64).encode())
    return digest.hexdigest()


def _node_classes(treedef) -> set[type]:
    """Every class of a node of ``treedef`` (containers and modules)."""
    classes, pending = set(), [treedef]
    while pending:
        node = pending.pop()
        data = node.node_data()
        if data is not None:
            classes.add(data[0])
        pending.extend(node.children())
    return classes


def _static_classes(static) -> set[type]:
    """Every class in ``static``: its values' and those of the nodes of the tree structures it
    holds (a program whose static part is the structure of its arguments, as ``simulate``'s is,
    holds the model's classes there, and its leaves that are not arrays)."""
    if isinstance(static, jax.tree_util.PyTreeDef):
        return _node_classes(static)
    if isinstance(static, (tuple, list)):
        return {type(static)}.union(*(_static_classes(item) for item in static))
    return {type(static)}


def _trusted(cls: type) -> bool:
    return cls.__module__.split(".", 1)[0] in TRUSTED_PACKAGES and "<locals>" not in cls.__qualname__


def _key(name: str, static: object, treedef, classes: set[type], leaves: list) -> str:
    classes = sorted(_class_name(cls) for cls in classes)
    text = f"{static!r}|{treedef}|{classes}"
    if " at 0x" in text or "..." in text:  # a function, a summarized array: what it is cannot be told
        raise NotExportable(f"{name}: an argument without a stable description")
    shapes = [(tuple(np.shape(leaf)), str(_dtype(leaf))) for leaf in leaves]
    return hashlib.sha256(f"{_code_digest()}|{name}|{text}|{shapes}".encode()).hexdigest()[:40]


@functools.cache
def _device():
    return jax.devices()[0]


def _dtype(leaf) -> np.dtype:
    return leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf)


# ---------------------------------------------------------------------------- the structure of the outputs
def _encode(value):
    """A module's static fields as JSON (``TypeError`` where one is not plain data)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)) and type(value) in (int, float):
        return {"float": repr(value)} if isinstance(value, float) else value
    if isinstance(value, tuple):
        return {"tuple": [_encode(v) for v in value]}
    if isinstance(value, list):
        return {"list": [_encode(v) for v in value]}
    if value is _MISSING:
        return {"missing": True}
    if isinstance(value, enum.Enum) and _trusted(type(value)):
        return {"enum": f"{type(value).__module__}:{type(value).__qualname__}", "value": _encode(value.value)}
    raise TypeError(f"a static field of type {type(value).__name__} is not plain data")


def _decode(value):
    if not isinstance(value, dict):
        return value
    if "float" in value:
        return float(value["float"])
    if "tuple" in value:
        return tuple(_decode(v) for v in value["tuple"])
    if "list" in value:
        return [_decode(v) for v in value["list"]]
    if "missing" in value:
        return _MISSING
    if "enum" in value:
        return _class(value["enum"])(_decode(value["value"]))
    raise ValueError(f"an unknown static field {value!r}")


def _missing():
    """equinox's marker of a field without a value (a private name: where it moves, no static
    field matches it and modules holding one are traced in each process, as before)."""
    try:
        from equinox._module import _flatten

        return _flatten.MISSING
    except (ImportError, AttributeError):
        return object()


_MISSING = _missing()


def _class_name(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _class(name: str) -> type:
    """A trusted class by its name (the only import an entry can ask for)."""
    module, _, qualname = name.partition(":")
    if module.split(".", 1)[0] not in TRUSTED_PACKAGES:
        raise ValueError(f"an entry names the class {name}, outside the trusted packages")
    cls = importlib.import_module(module)
    for part in qualname.split("."):
        cls = getattr(cls, part)
    if not isinstance(cls, type):
        raise ValueError(f"{name} is not a class")
    return cls


_registered: set[type] = set()


def _register(cls: type) -> None:
    """Let ``jax.export`` write and read nodes of the module ``cls`` (its static fields as JSON)."""
    if cls in _registered:
        return
    if not (isinstance(cls, type) and issubclass(cls, eqx.Module) and _trusted(cls)):
        raise NotExportable(f"the output holds a {cls.__name__}, not a module of peeljax or its libraries")
    try:
        export.register_pytree_node_serialization(
            cls,
            serialized_name=_class_name(cls),
            serialize_auxdata=lambda aux: json.dumps(_encode(aux)).encode(),
            deserialize_auxdata=lambda data: _decode(json.loads(data.decode())),
        )
    except ValueError:  # registered before (by another program, or the library itself)
        pass
    _registered.add(cls)


_CONTAINERS = (tuple, list, dict, type(None))


# ---------------------------------------------------------------------------- entries: header (JSON) and the export
def _write(path: Path, serialized: bytes, classes: list[str]) -> None:
    header = json.dumps({"classes": classes}).encode()
    write_bytes(path, struct.pack("<I", len(header)) + header + serialized)
    _evict(path.parent)


def _read(path: Path) -> export.Exported:
    data = path.read_bytes()
    (length,) = struct.unpack("<I", data[:4])
    header = json.loads(data[4 : 4 + length].decode())
    for name in header["classes"]:
        _register(_class(name))
    return export.deserialize(bytearray(data[4 + length :]))


def _evict(folder: Path) -> None:
    """The oldest entries removed while the folder holds more than ``MAX_BYTES``."""
    try:
        entries = [(p.stat().st_mtime, p.stat().st_size, p) for p in folder.glob(f"*{SUFFIX}")]
    except OSError:
        return
    total = sum(size for _, size, _ in entries)
    for _, size, path in sorted(entries):
        if total <= MAX_BYTES:
            break
        path.unlink(missing_ok=True)
        total -= size


# ---------------------------------------------------------------------------- the program
_PROGRAMS: weakref.WeakSet = weakref.WeakSet()


def forget() -> None:
    """Every program's memory of what it read or exported in this process (the folder changed)."""
    for program in list(_PROGRAMS):
        program._programs.clear()


class ExportedProgram:
    """``fn(static, *args)`` compiled once per machine and traced once per machine.

    ``static`` is hashable and closed over (part of the key, by its ``repr``); ``args`` are
    pytrees of arrays. Called with concrete arrays, the program is read from (or exported to)
    :func:`programs_folder` and run through ``jax.jit``. With tracers (under ``jax.grad``,
    ``vmap``, an outer ``jit``), where the folder is off, or where the program cannot be
    exported (a host callback; a class outside peeljax and its libraries, in the arguments or
    in a tree structure held by ``static``), ``fallback(static, *args)`` runs instead (``fn``
    compiled as before); with ``host_outputs``, concrete calls run ``fn`` traced in this
    process instead, its outputs packed as an exported program's (:class:`HostOutputs`).
    """

    def __init__(self, name: str, fn: Callable, fallback: Callable, *, host_outputs: bool = False):
        self.name = name
        self.fn = fn
        self.fallback = fallback
        self.host_outputs = host_outputs
        self._programs: dict = {}  # signature → the program under jit, or None: the fallback runs
        _PROGRAMS.add(self)

    def __call__(self, static, *args):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return self.fallback(static, *args)
        program = self.program(static, treedef, leaves)
        if program is None:
            return self.fallback(static, *args)
        return program(*leaves)

    def program(self, static, treedef, leaves: list):
        """The exported program under ``jax.jit``, called with the flat ``leaves`` of concrete
        arguments (``jax.tree_util.tree_flatten(args)``): with ``host_outputs``, ``fn`` traced
        here where it is not exported; else None where ``fallback`` runs instead. One
        ``jax.jit`` per signature: a caller compiling it ahead of time
        (``.lower(*leaves).compile()``) shares the compilation with ``__call__``."""
        signature = (static, treedef, tuple((np.shape(leaf), _dtype(leaf)) for leaf in leaves))
        program = self._programs.get(signature, False)
        if program is False:
            program = self._load_or_export(static, treedef, leaves)
            if program is None and self.host_outputs:  # traced in this process, its outputs packed all the same
                program = HostOutputs(
                    self.name,
                    lambda *leaves: self.fn(static, *jax.tree_util.tree_unflatten(treedef, leaves)),
                    jax.sharding.SingleDeviceSharding(_device()),
                )
            self._programs[signature] = program
        return program

    def _load_or_export(self, static, treedef, leaves):
        folder = programs_folder()
        if folder is None:
            return None
        try:
            # the static part's classes too: a user's class is keyed by its name alone, and
            # its code can change under that name (a program read back would be stale)
            classes = _node_classes(treedef) | _static_classes(static)
            if not all(_trusted(cls) for cls in classes):
                raise NotExportable(f"{self.name}: a class outside peeljax and its libraries")
            path = folder / f"{_key(self.name, static, treedef, classes, leaves)}{SUFFIX}"
        except NotExportable:
            return None
        refused = path.with_suffix(".refused")
        if refused.is_file():  # tried before: not exportable
            return None
        exported = None
        if path.is_file():
            try:
                exported = _read(path)
                os.utime(path)  # recently used: evicted last
            except Exception:  # noqa: BLE001 — a truncated, corrupt or foreign entry: exported again
                path.unlink(missing_ok=True)
        if exported is None:
            exported = self._export(static, treedef, leaves, path)
            if exported is None:
                with contextlib.suppress(OSError):  # not tried again in the next process
                    refused.parent.mkdir(parents=True, exist_ok=True)
                    refused.touch()
                return None
        # Every argument placed on one device: an exported program's outputs are committed
        # arrays, and one handed back in (an orbit's model) would otherwise compile it again.
        sharding = jax.sharding.SingleDeviceSharding(_device())
        if self.host_outputs:
            return HostOutputs(self.name, exported.call, sharding, exported.out_tree, exported.out_avals)
        return jax.jit(exported.call, in_shardings=sharding)

    def _export(self, static, treedef, leaves, path: Path):
        def flat(*leaves):  # the arguments' structure is in the key: the export sees arrays only
            return self.fn(static, *jax.tree_util.tree_unflatten(treedef, leaves))

        try:
            exported = export.export(jax.jit(flat))(*leaves)
            classes = [cls for cls in _node_classes(exported.out_tree) if cls not in _CONTAINERS]
            for cls in classes:
                _register(cls)
            serialized = bytes(exported.serialize())
        except Exception:  # noqa: BLE001 — not exportable (a callback, a field that is not data): traced as before
            return None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            _write(path, serialized, sorted(_class_name(cls) for cls in classes))
        except OSError:
            pass  # a read-only cache: the program still runs, exported in this process
        # what the next process reads back: a program compiled around a fresh export has
        # another compilation-cache key than one around the same export read back
        return export.deserialize(bytearray(serialized))


class OutputLayout:
    """Where each output of a program lies when its outputs travel as one flat buffer per
    dtype: a few copies to the host instead of dozens (a copy per output cost ~50 µs, where a
    short run's whole call takes ~1 ms). :meth:`pack` inside the program, :meth:`unpack` on the
    host: each output a read-only view of its buffer, reshaped, in the output structure."""

    def __init__(self, out_tree, out_avals):
        self.tree = out_tree
        self.dtypes = list(dict.fromkeys(np.dtype(aval.dtype) for aval in out_avals))
        offsets = dict.fromkeys(self.dtypes, 0)
        self.views = []  # (buffer, start, stop, shape) per output
        for aval in out_avals:
            buffer, size = self.dtypes.index(np.dtype(aval.dtype)), math.prod(aval.shape)
            start = offsets[self.dtypes[buffer]]
            offsets[self.dtypes[buffer]] = start + size
            self.views.append((buffer, start, start + size, tuple(aval.shape)))

    @classmethod
    def packed(cls, outputs) -> tuple[tuple, OutputLayout]:
        """(the buffers, their layout) of a program's outputs, inside the program."""
        leaves, tree = jax.tree_util.tree_flatten(outputs)
        layout = cls(tree, leaves)
        return layout.pack(leaves), layout

    def pack(self, leaves) -> tuple:
        return tuple(
            jax.numpy.concatenate([jax.numpy.ravel(o) for o in leaves if np.dtype(o.dtype) == dtype])
            for dtype in self.dtypes
        )

    def unpack(self, buffers):
        host = [np.asarray(buffer) for buffer in buffers]
        leaves = [host[b][start:stop].reshape(shape) for b, start, stop, shape in self.views]
        return jax.tree_util.tree_unflatten(self.tree, leaves)


class HostOutputs:
    """A program whose outputs come back to the host as NumPy arrays, packed by
    :class:`OutputLayout`.

    ``name`` names the compiled program (``jit(name)``). ``call`` is an exported program's
    call, with its ``out_tree`` and ``out_avals``, or a function traced in this process (both
    None): its layout is then read off its outputs when it is traced (one HostOutputs per signature: the layout is the same at every trace).
    ``lower(*leaves).compile()`` compiles ahead of time; :meth:`unpack` turns what the compiled
    program returns into the outputs, as a call does."""

    def __init__(self, name: str, call: Callable, sharding, out_tree=None, out_avals=None):
        self._layout = None if out_tree is None else OutputLayout(out_tree, out_avals)

        def by_dtype(*leaves):
            buffers, layout = OutputLayout.packed(call(*leaves))
            self._layout = self._layout or layout
            return buffers

        # named after the program (``jit(simulate)``): profiles and compile events tell it apart
        by_dtype.__name__ = by_dtype.__qualname__ = name
        self._jitted = jax.jit(by_dtype, in_shardings=sharding)

    def lower(self, *leaves):
        return self._jitted.lower(*leaves)

    def unpack(self, buffers):
        return self._layout.unpack(buffers)

    def __call__(self, *leaves):
        return self.unpack(self._jitted(*leaves))


def all_arrays(leaves) -> bool:
    """Whether every leaf is an array (``jax.jit``'s C++ dispatch and a kept program take them;
    a plain Python function or number among them takes ``eqx.filter_jit``)."""
    return all(isinstance(leaf, (jax.Array, np.ndarray, np.generic)) for leaf in leaves)


def compiled(fn: Callable, name: str) -> Callable:
    """``fn`` compiled: called through ``jax.jit``'s C++ dispatch where every leaf of the
    arguments is an array (~1 ms of overhead per orbit call against ~10 for
    ``eqx.filter_jit``, measured at V = 1.1), else through ``eqx.filter_jit`` (a φ given as a
    Python function). Called with concrete arrays, its traced program is kept on disk under
    ``name``: a new process skips the tracing too."""
    plain, filtered = jax.jit(fn), eqx.filter_jit(fn)
    kept = ExportedProgram(name, lambda _, *args: fn(*args), lambda _, *args: plain(*args))

    def call(*args):
        if all_arrays(jax.tree_util.tree_leaves(args)):
            return kept(None, *args)
        return filtered(*args)

    return call
