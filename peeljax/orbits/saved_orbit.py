"""An orbit read back from its file: :class:`SavedOrbit`, and the reader :func:`peeljax.load`
uses for files of kind ``"orbit"`` (the format: :mod:`peeljax.orbits.files`)."""

from __future__ import annotations

import os

import equinox as eqx

from ..saved import register_reader
from .files import KIND, orbit_fields, write_orbit
from .orbit import PeriodicOrbit

__all__ = ["SavedOrbit", "read_orbit"]


class SavedOrbit(PeriodicOrbit):
    """A :class:`PeriodicOrbit` read from a file (:func:`peeljax.load`), with what the file says
    about how it was found.

    Attributes (besides the orbit's):
        settings: how the orbit was found (``rtol``, ``atol``, ``transient``, … as saved; empty
            where the writer gave none).
        path: the file it was read from.
        units: the units of the file's arrays.
        peeljax_version: the version of the peeljax that wrote the file.
    """

    settings: dict = eqx.field(default_factory=dict)
    path: str = eqx.field(static=True, default="")
    units: dict = eqx.field(default_factory=dict)
    peeljax_version: str = eqx.field(static=True, default="")

    def save(self, path: str | os.PathLike, settings: dict | None = None) -> None:
        """Write the orbit to ``path`` as it was read (its settings kept unless ``settings``)."""
        write_orbit(path, self, self.settings if settings is None else settings)

    def __repr__(self) -> str:
        return (
            f"SavedOrbit({self.path!r}: V = {float(self.V):g} m/s, {int(self.slips)} slips per period, "
            f"T = {float(self.period):.7g} s, {self.status_name})"
        )


def read_orbit(arrays: dict, name: str) -> SavedOrbit:
    """The :class:`SavedOrbit` of an orbit's ``.npz`` arrays (``name``: the file, for messages);
    a ValueError naming the file where they are malformed."""
    try:
        return SavedOrbit(**orbit_fields(arrays, name), path=name)
    except (KeyError, TypeError) as error:
        raise ValueError(f"{name!r} is malformed: not an orbit's arrays ({error})") from None


# peeljax.load reads an orbit's file.
register_reader(KIND, npz=read_orbit)
