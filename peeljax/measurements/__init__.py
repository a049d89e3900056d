"""What a user hands in and what is measured from it, below :mod:`peeljax.fit`:

* :mod:`.text_tables` reads a lab's text files (header with units, cells;
  :class:`DataFileError` names file, line and column);
* :mod:`.records` gives force records (text, ``.npz``) as :class:`Observation` s
  (:mod:`.observations`);
* :mod:`.stick_slip_table` gives a :class:`StickSlipTable`, statistics against V, from its file
  or from force records;
* :mod:`.statistics` holds :data:`STATISTICS` and computes them from both sides, a measured
  sawtooth F(t) (:func:`record_statistics`) and a simulated run, differentiable through its jumps
  (:func:`jump_statistics`);
* :mod:`.instrument` shows a run's statistics as a record's sampling and noise would.
"""

from .instrument import Instrument
from .observations import Observation
from .records import FILE_NAME_V, FORCE_COLUMNS, read_force_record, read_npz, read_observations
from .statistics import MIN_DROP_NOISE, MIN_DROP_RANGE, STATISTICS, jump_statistics, record_statistics
from .stick_slip_table import TABLE_UNITS, StickSlipTable, read_stick_slip_table
from .text_tables import DataFileError

__all__ = [
    "FILE_NAME_V",
    "FORCE_COLUMNS",
    "MIN_DROP_NOISE",
    "MIN_DROP_RANGE",
    "STATISTICS",
    "TABLE_UNITS",
    "DataFileError",
    "Instrument",
    "Observation",
    "StickSlipTable",
    "jump_statistics",
    "read_force_record",
    "read_npz",
    "read_observations",
    "read_stick_slip_table",
    "record_statistics",
]
