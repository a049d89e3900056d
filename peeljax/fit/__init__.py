"""Fitting the adhesion law φ(v, V) to what a peel test measures.

* :mod:`.text_tables` — the reader of a lab's text files (header with units, cells, the
  :class:`DataFileError` naming file, line and column);
* :mod:`.records` — measured runs from files: force records (CSV/whitespace text) and ``.npz``;
* :mod:`.stick_slip_table` — :class:`StickSlipTable`, statistics against V, and its file;
* :mod:`.measured_statistics` — the stick-slip statistics of a measured sawtooth F(t);
* :mod:`.statistics` — the same statistics of a simulated run, differentiable through its jumps;
* :mod:`.table` — Levenberg–Marquardt on a stick-slip table (:func:`fit_stick_slip`);
* :mod:`.table_rows` — each table row on its attractor: steady peeling, a periodic orbit, a window;
* :mod:`.attractors` — each row's periodic orbit found, followed from step to step, checked;
* :mod:`.profile` — profile-likelihood intervals, honest across bifurcations;
* :mod:`.instrument` — the model's statistics as a record's sampling and noise show them;
* :mod:`.points` — records fitted point by point by Levenberg–Marquardt, with uncertainties;
* :mod:`.records_fit` — records of every kind in one fit (:func:`fit_records`);
* :mod:`.uncertainty` — covariance, standard errors, correlations, undetermined coefficients,
  the band on φ;
* :mod:`.parameters` — θ ↔ φ: the free coefficients as the parameters every fit moves
  (c = c_start·exp(θ));
* :mod:`.trajectory` — point-wise fits of smooth runs v(t), F(t), α(t) (optax), and of
  steady peeling (φ's own branch).

The plots of a fit (data against fit, residuals, φ with its band and folds) are
:mod:`peeljax.plots.fit`. Deprecated, removed in peeljax 0.3.0, each re-exporting its names:
``peeljax.fit.data`` (held the first four in one file) and ``peeljax.fit.plots`` (the plots' old home).
"""

from .measured_statistics import record_statistics
from .records import read_force_record, read_observations
from .statistics import jump_statistics
from .stick_slip_table import StickSlipTable, read_stick_slip_table
from .instrument import Instrument
from .records_fit import fit_records
from .table import fit_stick_slip
from .text_tables import DataFileError
from .trajectory import (
    QUANTITIES,
    FitInterrupted,
    FitResult,
    LossInfo,
    Observation,
    fit_adhesion,
    fit_adhesion_steady,
    phi_relative_error,
    restart_on_ascent,
    trajectory_loss,
)
from .uncertainty import Uncertainty

__all__ = [
    "QUANTITIES",
    "DataFileError",
    "FitInterrupted",
    "FitResult",
    "Instrument",
    "LossInfo",
    "Observation",
    "StickSlipTable",
    "Uncertainty",
    "fit_adhesion",
    "fit_adhesion_steady",
    "fit_records",
    "fit_stick_slip",
    "jump_statistics",
    "phi_relative_error",
    "read_force_record",
    "read_observations",
    "read_stick_slip_table",
    "record_statistics",
    "restart_on_ascent",
    "trajectory_loss",
]
