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
import os
import tempfile
from pathlib import Path

import numpy as np

from ._atomic import replacing

__all__ = [
    "META_KEY",
    "PARAMETER_UNITS",
    "STATE_UNITS",
    "check_input_file",
    "check_output_folder",
    "check_output_path",
    "image_formats",
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


def check_input_file(option: str, path: str) -> None:
    """An input file exists and is a file: a folder, a missing file or a file under a missing
    folder, each said as such (a ValueError that opens with ``option``, the name the caller gave the path)."""
    target = Path(path)
    if target.is_file():
        return
    if target.is_dir():
        raise ValueError(f"{option}: {path!r} is a folder, expected a file")
    raise ValueError(f"{option}: file {path!r} does not exist")


def _probe_folder(option: str, folder: Path) -> None:
    """Create and remove a file in ``folder``: the one test of writability that also catches
    read-only mounts, permissions and pseudo file systems such as /proc."""
    try:
        handle, name = tempfile.mkstemp(prefix=".peeljax-probe-", dir=folder)
        os.close(handle)
        os.remove(name)
    except OSError as error:
        raise ValueError(f"{option}: cannot write in the folder {str(folder)!r} ({error.strerror or error})") from None


def _file_in_the_way(path: Path) -> Path | None:
    """The first existing ancestor of ``path`` (or ``path`` itself) if it is a file, else None."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return None if candidate.is_dir() else candidate
    return None


def check_output_path(option: str, path: str | None, suffixes: set[str] | None = None) -> None:
    """Fail now rather than after a long run: the folder of ``path`` must exist and be writable, its suffix (an
    image format) among ``suffixes`` when given; a ValueError that opens with ``option``. None: nothing to check."""
    if path is None:
        return
    target = Path(path)
    if target.is_dir():
        raise ValueError(f"{option}: {path!r} is a directory, expected a file name")
    folder = target.parent
    if not folder.is_dir():
        blocker = _file_in_the_way(folder)
        if blocker is not None:
            raise ValueError(f"{option}: {str(blocker)!r} is a file, not a folder")
        raise ValueError(f"{option}: the folder {str(folder)!r} does not exist")
    suffix = target.suffix.lstrip(".").lower()
    if suffixes is not None and suffix and suffix not in suffixes:
        raise ValueError(f"{option}: unknown image format {suffix!r}; use one of {', '.join(sorted(suffixes))}")
    _probe_folder(option, folder)


def check_output_folder(option: str, path: str) -> None:
    """An output folder: absent (its parent must exist; it is created) or a writable folder."""
    folder = Path(path)
    blocker = _file_in_the_way(folder)
    if blocker is not None:
        what = repr(path) if blocker == folder else f"{str(blocker)!r}, on the way to {path!r},"
        raise ValueError(f"{option}: {what} is a file, not a folder")
    if not folder.exists() and not folder.parent.is_dir():
        raise ValueError(f"{option}: the parent folder {str(folder.parent)!r} does not exist")
    _probe_folder(option, folder if folder.exists() else folder.parent)


def image_formats() -> set[str]:
    """The image formats matplotlib's Agg canvas writes (the suffixes: ``png``, ``pdf``, ``svg``, ...)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return set(FigureCanvasAgg(Figure()).get_supported_filetypes())
