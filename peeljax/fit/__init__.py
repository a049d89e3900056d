"""Fitting the adhesion law φ(v, V) to what a peel test measures, in one flow:
files → observations → rows → solver → intervals → result.

* **files → observations, statistics**: :mod:`peeljax.measurements` (a lab's text files, force
  records as :class:`Observation` s, a :class:`StickSlipTable`; :data:`STATISTICS
  <peeljax.measurements.STATISTICS>` computed alike from a record and from a run);
* **rows** (what the model predicts for each datum at θ, its residuals and Jacobian):
  :mod:`.table_rows` puts each table row on its attractor — steady peeling, a periodic orbit
  (:mod:`.attractors` finds and follows it), or the statistics over a window of a run
  (:mod:`.window_rows`); :mod:`.points` fits records point by point;
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
the plots of a fit are :mod:`peeljax.plots.fit`. The old module paths ``peeljax.fit.records``,
``.statistics``, ``.stick_slip_table``, ``.text_tables``, ``.observations``, ``.instrument``,
``.data``, ``.measured_statistics`` and ``.plots`` warn on use (``DeprecationWarning``) and are
removed in peeljax 0.3.0.
"""

from ..measurements import (DataFileError, Instrument, StickSlipTable, jump_statistics, read_force_record,
                           read_observations, read_stick_slip_table, record_statistics)  # fmt: skip
from .records_fit import fit_records
from .table import fit_stick_slip
from .trajectory import (QUANTITIES, FitInterrupted, FitResult, LossInfo, Observation, fit_adhesion,
                         fit_adhesion_steady, phi_relative_error, restart_on_ascent, trajectory_loss)  # fmt: skip
from .uncertainty import Uncertainty

__all__ = ["QUANTITIES", "DataFileError", "FitInterrupted", "FitResult", "Instrument", "LossInfo", "Observation",
    "StickSlipTable", "Uncertainty", "fit_adhesion", "fit_adhesion_steady", "fit_records", "fit_stick_slip",
    "jump_statistics", "phi_relative_error", "read_force_record", "read_observations", "read_stick_slip_table",
    "record_statistics", "restart_on_ascent", "trajectory_loss"]  # fmt: skip
