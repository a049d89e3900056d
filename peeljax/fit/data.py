"""Deprecated: the old home of the fit's data layer, kept so that existing imports still work.

``peeljax.fit.data`` held three jobs in one file; each now has its own module, and every public
name is importable from :mod:`peeljax.fit` (where to import it from now):

* :mod:`.text_tables` — the text-file reader and :class:`DataFileError`;
* :mod:`.records` — force records and ``.npz`` observations (:func:`read_force_record`,
  :func:`read_observations`, :func:`read_npz`, :data:`FILE_NAME_V`, :data:`FORCE_COLUMNS`);
* :mod:`.stick_slip_table` — :class:`StickSlipTable`, :func:`read_stick_slip_table`,
  :data:`STATISTICS`, :data:`TABLE_UNITS`;
* :mod:`.statistics` — :func:`record_statistics` of a measured force record.

Importing this module warns (``DeprecationWarning``; the module is removed in peeljax 0.3.0); it
re-exports the names above unchanged.
"""

import warnings

from .statistics import MIN_DROP_NOISE, MIN_DROP_RANGE, record_statistics
from .records import FILE_NAME_V, FORCE_COLUMNS, read_force_record, read_npz, read_observations
from .stick_slip_table import STATISTICS, TABLE_UNITS, StickSlipTable, read_stick_slip_table
from .text_tables import DataFileError

__all__ = [
    "FILE_NAME_V",
    "FORCE_COLUMNS",
    "MIN_DROP_NOISE",
    "MIN_DROP_RANGE",
    "STATISTICS",
    "TABLE_UNITS",
    "DataFileError",
    "StickSlipTable",
    "read_force_record",
    "read_npz",
    "read_observations",
    "read_stick_slip_table",
    "record_statistics",
]

warnings.warn(
    "peeljax.fit.data is deprecated: import from peeljax.fit (read_force_record, read_observations, "
    "read_stick_slip_table, record_statistics, StickSlipTable, DataFileError) or from its modules "
    "peeljax.fit.records, .stick_slip_table, .statistics, .text_tables "
    "(peeljax.fit.data is removed in peeljax 0.3.0)",
    DeprecationWarning,
    stacklevel=2,
)
