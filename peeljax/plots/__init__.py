"""The pictures, one module per kind (matplotlib only; nothing is computed beyond what is drawn):

- :mod:`.runs`: runs in the style of the paper's Figs. 2–3, a run carried through the folds of
  φ (:func:`plot_stick_slip`), a sweep's map (:func:`plot_sweep_map`) and a trajectory fit
  (:func:`plot_fit`);
- :mod:`.stick_slip_map`: the stick-slip map over V (:func:`plot_stick_slip_map`);
- :mod:`.orbits`: a periodic stick-slip orbit over one period (:func:`plot_orbit`).
- :mod:`.orbit_diagram`: the orbits' bifurcation diagram over V (:func:`plot_orbit_diagram`).
- :mod:`.attractor_map`: every attractor over V, its basin share and the boundaries (:func:`plot_attractor_map`).
- :mod:`.fit`: a fit of φ, data against the fitted model with residuals and φ's band
  (``plot_table_fit``, ``plot_records_fit``; imported from :mod:`peeljax.plots.fit`, not here: it
  imports the fit).
"""

from .attractor_map import plot_attractor_map
from .orbit_diagram import plot_orbit_diagram
from .orbits import plot_orbit
from .runs import SWEEP_MAP_MAX_LINES, plot_fit, plot_run, plot_runs, plot_stick_slip, plot_sweep_map, short_reason
from .stick_slip_map import plot_stick_slip_map

__all__ = [
    "SWEEP_MAP_MAX_LINES",
    "plot_attractor_map",
    "plot_fit",
    "plot_orbit",
    "plot_orbit_diagram",
    "plot_run",
    "plot_runs",
    "plot_stick_slip",
    "plot_stick_slip_map",
    "plot_sweep_map",
    "short_reason",
]
