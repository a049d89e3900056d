"""Fitting the adhesion law φ(v, V) to what a peel test measures, in one flow:
files → observations → rows → solver → intervals → result.

* **files → observations**: :mod:`.text_tables` reads a lab's text files (header with units,
  cells; :class:`DataFileError` names file, line and column); :mod:`.records` gives force
  records (text, ``.npz``) as :class:`Observation` s (:mod:`.observations`);
  :mod:`.stick_slip_table` gives a :class:`StickSlipTable`, statistics against V, from its file
  or from force records;
* **statistics**: :mod:`.statistics` holds :data:`~peeljax.fit.statistics.STATISTICS` and
  computes them from both sides, a measured sawtooth F(t) (:func:`record_statistics`) and a
  simulated run, differentiable through its jumps (:func:`jump_statistics`);
* **rows** (what the model predicts for each datum at θ, its residuals and Jacobian):
  :mod:`.table_rows` puts each table row on its attractor — steady peeling, a periodic orbit
  (:mod:`.attractors` finds and follows it), or the statistics over a window of a run
  (:mod:`.window_rows`); :mod:`.instrument` shows a row's statistics as a record's sampling and
  noise would; :mod:`.points` fits records point by point;
* **θ ↔ φ**: :mod:`.parameters`, the free coefficients as the parameters every fit moves
  (c = c_start·exp(θ));
* **solver**: :mod:`.levenberg_marquardt` for every least-squares fit, driven by :mod:`.table`
  (:func:`fit_stick_slip`) and :mod:`.records_fit` (:func:`fit_records`: records of every kind
  in one fit); optax for the smooth runs v(t), F(t), α(t) and steady peeling in
  :mod:`.trajectory` (:func:`fit_adhesion`, :func:`fit_adhesion_steady`);
* **intervals**: :mod:`.uncertainty` (linearized: covariance, standard errors, correlations,
  undetermined coefficients, the band on φ) and :mod:`.profile` (profile likelihood, honest
  across bifurcations);
* **result**: :mod:`.result`, every fit's :class:`FitResult`; a least-squares fit's
  :class:`~peeljax.fit.result.TableFitResult` is built in one place,
  :func:`~peeljax.fit.result.least_squares_result`.

:mod:`.synthetic` gives the model's statistics as a fit predicts them and tables made of them;
the plots of a fit (data against fit, residuals, φ with its band and folds) are
:mod:`peeljax.plots.fit`. Deprecated, removed in peeljax 0.3.0, each re-exporting its names:
``peeljax.fit.data`` (the first three and the measured statistics in one file),
``peeljax.fit.measured_statistics`` (now in :mod:`.statistics`) and ``peeljax.fit.plots`` (the
plots' old home).
"""

from .records import read_force_record, read_observations
from .statistics import jump_statistics, record_statistics
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
