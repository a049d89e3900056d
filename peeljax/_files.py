"""What every file peeljax writes says about itself: its kind, the peeljax that wrote it, units.

An ``.npz`` carries it as one JSON string, ``meta_json`` (a sweep's also holds its resume
settings); a netCDF file as global attributes (``kind``, ``peeljax_version``) and a ``units``
attribute on each variable. :func:`peeljax.load` reads the kind to choose its reader.

Units are SI, written as UDUNITS reads them ("m/s", "kg m2"; "1" for counts and ratios). The
coefficients of φ carry units that depend on their exponents: c1 multiplies v^p1, so it is in
N (s/m)^p1, written with the exponent's name.
"""

from __future__ import annotations

from ._version import __version__

import json
import math

import numpy as np

from ._atomic import replacing

__all__ = [
    "META_KEY",
    "PARAMETER_UNITS",
    "STATE_UNITS",
    "meta_array",
    "metadata",
    "peeljax_version",
    "read_meta",
    "read_netcdf",
    "require_xarray",
    "write_netcdf",
]

META_KEY = "meta_json"

STATE_UNITS: dict[str, str] = {"alpha": "rad", "omega": "rad/s", "u": "m", "v": "m/s"}
_PHI_UNITS = {
    "c1": "N (s/m)^p1", "p1": "1", "c2": "N (s/m)^p2", "p2": "1", "c3": "N", "c4": "m/s",
    "c5": "N (s/m)^p5", "p5": "1", "c6": "N (s/m)^p9", "c7": "N (s/m)^(p7+p9)", "p7": "1",
    "c8": "N (s/m)^(p8+p9)", "p8": "1", "p9": "1",
}  # fmt: skip
# The model's parameters (PeelingModel) and the coefficients of φ (eq. of the adhesion law).
PARAMETER_UNITS: dict[str, str] = {"R": "m", "I": "kg m2", "k": "N", "l": "m", "V": "m/s", "tau": "s", **_PHI_UNITS}


def peeljax_version() -> str:
    """``peeljax.__version__``: the version of the peeljax that writes a file."""
    return __version__


def metadata(kind: str, units: dict[str, str], **extra) -> dict:
    """The JSON object a file of ``kind`` carries: kind, the writing peeljax's version, the
    units of its arrays, and ``extra``."""
    return {"kind": kind, "peeljax_version": peeljax_version(), "units": dict(units), **extra}


def meta_array(kind: str, units: dict[str, str], **extra) -> np.ndarray:
    """:func:`metadata` as the string array ``np.savez`` stores (loads without pickles)."""
    return np.asarray(json.dumps(json_safe(metadata(kind, units, **extra)), allow_nan=False), dtype=str)


def read_meta(arrays: dict, path: str) -> dict | None:
    """The ``meta_json`` object of a loaded ``.npz`` (None where the file has none: one written
    before files described themselves); a ValueError naming the file when it is malformed."""
    if META_KEY not in arrays:
        return None
    value = arrays[META_KEY]
    try:
        meta = json.loads(str(value)) if np.ndim(value) == 0 else None
    except json.JSONDecodeError as error:
        raise ValueError(f"{path!r} is malformed: {META_KEY} is not JSON ({error})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path!r} is malformed: {META_KEY} is not a JSON object")
    return meta


def require_xarray(what: str, *, netcdf: bool = False):
    """The ``xarray`` module (and with ``netcdf`` its engine h5netcdf), or an ImportError that
    says ``what`` needs them and how to install them."""
    try:
        import xarray

        if netcdf:
            import h5netcdf  # noqa: F401  (the engine xarray reads and writes netCDF-4 with)
    except ImportError as error:
        raise ImportError(
            f"{what} needs xarray and h5netcdf ({error.name} is not installed), which peeljax does not install "
            'by default: pip install "peeljax[xarray]"'
        ) from None
    return xarray


def write_netcdf(dataset, path) -> None:
    """An ``xarray.Dataset`` to a netCDF-4 file (engine h5netcdf), replaced only once complete
    (:func:`peeljax._atomic.replacing`)."""
    require_xarray("writing netCDF", netcdf=True)
    with replacing(path) as temporary:
        dataset.to_netcdf(temporary, engine="h5netcdf")


def read_netcdf(path):
    """The netCDF file's dataset, loaded into memory and the file closed; a ValueError naming
    the file when it cannot be read as netCDF."""
    xr = require_xarray("reading netCDF", netcdf=True)
    try:
        with xr.open_dataset(path, engine="h5netcdf") as dataset:
            return dataset.load()
    except (OSError, ValueError, KeyError) as error:
        raise ValueError(f"{str(path)!r} is not a readable netCDF file ({error})") from None


def json_safe(value):
    """``value`` as strict JSON takes it: NaN/inf → null, numpy scalars → Python's, keys → str."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if isinstance(value, np.generic):
        return json_safe(value.item())
    return value
