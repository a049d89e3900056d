"""The adhesion law φ(v, V) of the shear-adhesion constraint (eq. ``sac``).

The paper's family (its numerical example, after de Cicco et al.) is

    φ(v, V) = c1·v^p1 + c2·v^p2 + c3·exp(v/c4) − c5·V^p5 − (c6 − c7·V^p7 − c8·V^p8)·v^p9,

with a maximum and a minimum in v between which the tape sticks and slips.

Policy at v ≤ 0
---------------
φ has fractional powers of v and is defined for v > 0 only. peeljax extends every
power to v ≤ 0 by its limit from the right, ``v^p := 0`` (p > 0), with zero derivative,
through a "double where" so that neither the value nor any derivative is ever NaN.
The integrators never rely on this extension: the α-method solves for log v, so v stays
positive, and initial states with v ≤ 0 are rejected before compilation.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import re
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, ArrayLike, Float

from ._arrays import float_array
from ._atomic import write_text

__all__ = ["AdhesionLaw", "COEFFICIENT_NAMES", "PAPER_COEFFICIENTS", "as_adhesion", "paper_defaults", "read_json", "safe_pow"]

COEFFICIENT_NAMES: tuple[str, ...] = (
    "c1", "p1", "c2", "p2", "c3", "c4", "c5", "p5", "c6", "c7", "p7", "c8", "p8", "p9",
)
PAPER_COEFFICIENTS: dict[str, float] = dict(
    zip(COEFFICIENT_NAMES, (400.0, 0.35, 110.0, 0.15, 130.0, 11.0, 2.0, 1.5, 415.0, 45.0, 0.4, 0.35, 2.15, 0.5))
)


# The family's domain, (lower bound, bound included): every coefficient carries its sign in
# the formula, so they are non-negative; c4 divides v, the powers of v must vanish at v = 0.
COEFFICIENT_DOMAIN: dict[str, tuple[float, bool]] = {
    "c1": (0.0, False), "p1": (0.0, False), "c2": (0.0, False), "p2": (0.0, False), "c3": (0.0, True),
    "c4": (0.0, False), "c5": (0.0, True), "p5": (0.0, True), "c6": (0.0, True), "c7": (0.0, True),
    "p7": (0.0, True), "c8": (0.0, True), "p8": (0.0, True), "p9": (0.0, False),
}  # fmt: skip


@jax.custom_jvp
def safe_pow(x: ArrayLike, p: ArrayLike) -> Array:
    """``x**p`` for x > 0, and 0 (its limit from the right, p > 0) for x ≤ 0.

    The inner ``where`` keeps the untaken branch finite, so gradients with respect to
    x and p are finite everywhere (zero where x ≤ 0). The derivative rule
    ∂(x^p) = (p·x^p/x)·dx + (x^p·log x)·dp reuses the primal power, so derivatives of every
    order (the α-method's Newton matrix is a second derivative of φ) cost no further
    powers, and a zero tangent costs nothing.
    """
    x = jnp.asarray(x)
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, x_safe**p, 0.0)


@functools.partial(safe_pow.defjvp, symbolic_zeros=True)
def _safe_pow_jvp(primals, tangents):
    x, p = primals
    dx, dp = tangents
    x = jnp.asarray(x)
    y = safe_pow(x, p)
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    dy = jnp.zeros(jnp.broadcast_shapes(jnp.shape(x), jnp.shape(p)), y.dtype)
    if not isinstance(dx, SymbolicZero):
        dy = dy + jnp.where(positive, p * y / x_safe, 0.0) * dx
    if not isinstance(dp, SymbolicZero):
        dy = dy + jnp.where(positive, y * jnp.log(x_safe), 0.0) * dp
    return y, dy


def _coefficient():
    return eqx.field(converter=float_array)


class AdhesionLaw(eqx.Module):
    """φ(v, V) of the paper's family with its 14 coefficients as array leaves.

    All coefficients are traced values: ``jax.grad`` with respect to an ``AdhesionLaw``
    differentiates through them, and changing them never recompiles.
    """

    c1: Float[Array, ""] = _coefficient()
    p1: Float[Array, ""] = _coefficient()
    c2: Float[Array, ""] = _coefficient()
    p2: Float[Array, ""] = _coefficient()
    c3: Float[Array, ""] = _coefficient()
    c4: Float[Array, ""] = _coefficient()
    c5: Float[Array, ""] = _coefficient()
    p5: Float[Array, ""] = _coefficient()
    c6: Float[Array, ""] = _coefficient()
    c7: Float[Array, ""] = _coefficient()
    p7: Float[Array, ""] = _coefficient()
    c8: Float[Array, ""] = _coefficient()
    p8: Float[Array, ""] = _coefficient()
    p9: Float[Array, ""] = _coefficient()

    def __init__(self, **coefficients: ArrayLike):
        """The 14 coefficients by name (the paper's values where not given). A subclass's own
        fields are set here too: by name, else their default (``scale: float = 1.0`` in a
        subclass that scales ``_evaluate``)."""
        # a subclass of a module with its own __init__ gets no dataclass __init__ (equinox):
        # without this, its fields were never set, a flattened leaf read as equinox's `_Missing`
        own = _own_fields(type(self))
        unknown = set(coefficients) - set(COEFFICIENT_NAMES) - set(own)
        if unknown:
            names = [*COEFFICIENT_NAMES, *own]
            raise ValueError(f"{type(self).__name__}: unknown coefficient(s) {sorted(unknown)}; the names are {names}")
        for name in COEFFICIENT_NAMES:
            setattr(self, name, coefficients.get(name, PAPER_COEFFICIENTS[name]))
        for name, field in own.items():  # none in AdhesionLaw itself
            if name in coefficients:
                value = coefficients[name]
            elif field.default is not dataclasses.MISSING:
                value = field.default
            elif field.default_factory is not dataclasses.MISSING:
                value = field.default_factory()
            else:
                raise TypeError(f"{type(self).__name__}: field {name!r} has no default; pass {name}=...")
            setattr(self, name, value)

    def __call__(self, v: ArrayLike, V: ArrayLike) -> Array:
        """φ(v, V) (eq. ``sac``); v^p is 0 for v ≤ 0 (see the module docstring)."""
        return _adhesion(self, v, V)

    def _evaluate(self, v: ArrayLike, V: ArrayLike) -> Array:
        v = jnp.asarray(v)
        return (
            self.c1 * safe_pow(v, self.p1)
            + self.c2 * safe_pow(v, self.p2)
            + self.c3 * jnp.exp(v / self.c4)
            - self.c5 * safe_pow(V, self.p5)
            - (self.c6 - self.c7 * safe_pow(V, self.p7) - self.c8 * safe_pow(V, self.p8)) * safe_pow(v, self.p9)
        )

    # ------------------------------------------------------------------ coefficients
    def coefficients(self) -> dict[str, float]:
        """The 14 coefficients as plain floats, keyed by name (host values)."""
        return {name: float(getattr(self, name)) for name in COEFFICIENT_NAMES}

    def to_json(self, path: str | Path | None = None, **extra) -> str:
        """The coefficients as a JSON object (keys ``c1, p1, …, p9``), plus ``extra`` keys.

        Raises ``TypeError`` for a subclass: its ``_evaluate`` is code, which a file of
        coefficients cannot hold (read back, it would be the paper's family, another law)."""
        if not in_a_file(self):
            raise TypeError(
                f"{type(self).__qualname__}.to_json: a subclass of AdhesionLaw is code (its _evaluate), which a JSON "
                "file of coefficients cannot hold: read back, the file would be the paper's family with these "
                "coefficients, another law. Keep the subclass in your own code; "
                "AdhesionLaw(**law.coefficients()).to_json(path) writes the paper's family on purpose"
            )
        text = json.dumps({**self.coefficients(), **extra}, indent=2)
        if path is not None:
            write_text(path, text + "\n")
        return text

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "coefficients") -> "AdhesionLaw":
        """Coefficients from a mapping.

        Missing names keep the paper's values (:func:`paper_defaults` lists them); every present
        value must be a finite number in the family's domain (``COEFFICIENT_DOMAIN``: c1, c2, c4
        and the powers of v p1, p2, p9 are > 0, the others ≥ 0). A key that looks like a
        coefficient but is none of the 14 names (``"C3"``, ``"c9"``, ``"p_1"``, ``"c1 "``) is
        refused, naming it and the valid names: taken silently, a misspelling would leave the
        paper's value in place. Other keys are notes and are ignored (``to_json(**extra)``
        writes them, and a fit's result file carries its history next to the coefficients).
        """
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a JSON object of coefficients, got {type(data).__name__}")
        law = data.get(LAW_KEY, AdhesionLaw.__qualname__)
        if law != AdhesionLaw.__qualname__:
            raise ValueError(
                f"{source}: the coefficients of {str(law)[:60]!r}, a subclass of AdhesionLaw (code, not in the file): "
                "read as the paper's family they would be another law; build that class from them in Python"
            )
        unknown = [key for key in data if key not in COEFFICIENT_NAMES and _looks_like_coefficient(key)]
        if unknown:
            raise ValueError(
                f"{source}: unknown coefficient name{'s' if len(unknown) > 1 else ''} {unknown} (names are "
                f"case-sensitive); the coefficients are {', '.join(COEFFICIENT_NAMES)}"
            )
        values = {}
        for name in COEFFICIENT_NAMES:
            if name not in data:
                continue
            value = data[name]
            try:
                number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None
            except OverflowError:  # a huge JSON integer
                number = None
            if number is None or not math.isfinite(number):
                raise ValueError(f"{source}: coefficient {name!r} must be a finite number, got {str(value)[:40]!r}")
            values[name] = number
        if not values:
            raise ValueError(f"{source}: none of the coefficient names {list(COEFFICIENT_NAMES)} is present")
        for name, number in values.items():
            low, closed = COEFFICIENT_DOMAIN[name]
            if number < low or (number == low and not closed):
                allowed = f"[{low:g}, inf)" if closed else f"({low:g}, inf)"
                raise ValueError(
                    f"{source}: coefficient {name!r} must lie in {allowed} (the family's domain: the signs are in "
                    f"the formula, and the powers of v must vanish at v = 0), got {number:g}; "
                    "for another law pass a callable phi(v, V) in Python"
                )
        return cls(**values)

    @classmethod
    def from_json(cls, path: str | Path) -> "AdhesionLaw":
        """Coefficients from a JSON file written by :meth:`to_json` (data, never code), read by
        :meth:`from_dict`; :func:`read_json` also says which coefficients kept the paper's values."""
        return read_json(path)[0]


def read_json(path: str | Path) -> tuple[AdhesionLaw, tuple[str, ...]]:
    """The law in a JSON file (:meth:`AdhesionLaw.from_dict`) and the coefficients the file left
    out, which keep the paper's values (:func:`paper_defaults`)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"--phi: file {str(path)!r} does not exist") from None
    except json.JSONDecodeError as error:
        raise ValueError(f"--phi: {str(path)!r} is not valid JSON ({error})") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"--phi: {str(path)!r} is not a text (JSON) file ({error.reason})") from None
    try:
        return AdhesionLaw.from_dict(data, source=str(path)), paper_defaults(data)
    except ValueError as error:  # a value said as the file spells it, not as Python does
        raise ValueError(_in_json_terms(str(error), data)) from None


_GOT = re.compile(r"coefficient '(\w+)' (.*), got '[^']*'$")


def _in_json_terms(message: str, data: dict) -> str:
    """A coefficient that is no number said as JSON spells it (``got null``, ``got true``, ``got
    the string "abc"``), not as Python does (``'None'``, ``'True'``)."""
    found = _GOT.search(message)
    if found is None:
        return message
    value = data[found.group(1)]
    if value is None or isinstance(value, bool):
        shown = json.dumps(value)
    elif isinstance(value, str):
        shown = f"the string {json.dumps(value)}"
    elif isinstance(value, list):
        shown = f"the array {json.dumps(value)[:40]}"
    elif isinstance(value, dict):
        shown = "an object"
    else:
        shown = json.dumps(value)  # NaN, Infinity: JSON extensions Python reads
    return f"{message[: found.start()]}coefficient '{found.group(1)}' {found.group(2)}, got {shown} (JSON)"


def paper_defaults(data: dict) -> tuple[str, ...]:
    """The coefficients a mapping leaves out, which :meth:`AdhesionLaw.from_dict` takes from the paper."""
    return tuple(name for name in COEFFICIENT_NAMES if not isinstance(data, dict) or name not in data)


def _looks_like_coefficient(key) -> bool:
    """A key that is probably a misspelled coefficient name: a letter and digits in any case or
    with a separator (C3, c9, p_1, "c1 "), or close to one of the names."""
    if not isinstance(key, str):
        return True
    squeezed = re.sub(r"[\s_\-.]", "", key).lower()
    if re.fullmatch(r"[a-z]\d+", squeezed):
        return True
    return bool(difflib.get_close_matches(key.lower(), COEFFICIENT_NAMES, n=1, cutoff=0.75))


LAW_KEY = "law"  # a file of coefficients that belong to a subclass names it here (never read as the family)


def in_a_file(phi) -> bool:
    """Whether a file of data holds φ: an :class:`AdhesionLaw` itself, its 14 coefficients. A
    subclass's ``_evaluate`` and a callable are code, which files never hold (read back as the
    paper's family, a subclass would be another law under the same coefficients)."""
    return type(phi) is AdhesionLaw


def law_settings(phi) -> dict | str:
    """φ as JSON-able settings (a sweep compares them when it resumes): the 14 coefficients; a
    subclass adds its class and its own fields; a callable is named by its class."""
    if not isinstance(phi, AdhesionLaw):
        return f"callable {type(phi).__qualname__}"
    settings = phi.coefficients()
    if type(phi) is not AdhesionLaw:
        settings |= {"class": type(phi).__qualname__}
        settings |= {name: _json_value(getattr(phi, name)) for name in _own_fields(type(phi))}
    return settings


@functools.cache
def _own_fields(cls: type) -> dict[str, dataclasses.Field]:
    """A subclass's fields beside the 14 coefficients, by name; once per class (read at every
    construction: ``dataclasses.fields`` doubled the cost of ``AdhesionLaw()``)."""
    return {field.name: field for field in dataclasses.fields(cls) if field.name not in COEFFICIENT_NAMES}


def _json_value(value):
    """A field's value as JSON: numbers and arrays as lists, anything else by its repr (a
    function's holds its address: a sweep resumed in another process refuses it, the safe side)."""
    try:
        return np.asarray(value, dtype=float).tolist()
    except (TypeError, ValueError):
        return repr(value)


def as_adhesion(phi: AdhesionLaw | Callable | None) -> AdhesionLaw | Callable:
    """The paper's law for ``None``; any callable φ(v, V) is used as it is."""
    if phi is None:
        return AdhesionLaw()
    if not callable(phi):
        raise TypeError(f"adhesion: expected an AdhesionLaw or a callable phi(v, V), got {type(phi).__name__}")
    return phi


# φ as one compiled function: a run's program calls φ (and its derivatives) dozens of times,
# and a gradient through the loop traces the loop's body again and again; jit traces φ once
# per argument shape and reuses it (and its derivatives) everywhere. XLA inlines it.
_adhesion = jax.jit(lambda law, v, V: law._evaluate(v, V))  # (a subclass's _evaluate is its own)
