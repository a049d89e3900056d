"""Stick-slip orbits as objects: periodic orbits of the DAE with jumps, found by shooting.

The layers of this package, each a module with one job:

    section.py    the Poincaré section at the stick → slip fold, G(x) = φ(v̂, V), and its
                  coordinates (α, ω)
    period.py     one period from the section: the return map after k stick → slip events, and
                  the period's statistics (what a stick-slip table holds), exact
    shooting.py   Newton on P^k(s) − s; derivatives by the implicit function theorem
    floquet.py    Floquet multipliers and the test functions of fold, period doubling, torus
    orbit.py      the result, :class:`PeriodicOrbit`, and :class:`SavedOrbit`, one read back by
                  :func:`peeljax.load`
    api.py        :func:`periodic_orbit`: options checked, a start found from a run
    batch.py      :func:`periodic_orbits`: many orbits in one compiled call, over every device
    continuation.py   a branch over V or a coefficient of φ: pseudo-arclength, stability, the
                  bifurcations located (fold, period doubling, torus, grazing, the end)
    diagram.py    :func:`orbit_diagram`: seeds from runs, every branch and what lies beyond
    files.py      the two file formats, an orbit's and a diagram's (arrays; it imports no
                  class: :mod:`.orbit` and :mod:`.diagram` write and read through it)
"""

from .api import DEFAULT_ORBIT_RTOL, OrbitNotFound, least_period, orbit_shooting, periodic_orbit, start_from_run
from .batch import periodic_orbits
from .continuation import Bifurcation, BifurcationKind, OrbitBranch, continue_orbit
from .diagram import OrbitDiagram, Seed, orbit_diagram
from .floquet import multipliers, test_functions
from .orbit import PeriodicOrbit, SavedOrbit
from .period import ForceIntegral, OnePeriod, one_period, period_statistics
from .section import SlipSection
from .shooting import OrbitStatus, Shooting, ShootingResult, shoot

__all__ = [
    "Bifurcation",
    "BifurcationKind",
    "DEFAULT_ORBIT_RTOL",
    "ForceIntegral",
    "OnePeriod",
    "OrbitBranch",
    "OrbitDiagram",
    "OrbitNotFound",
    "OrbitStatus",
    "PeriodicOrbit",
    "SavedOrbit",
    "Seed",
    "Shooting",
    "ShootingResult",
    "SlipSection",
    "continue_orbit",
    "least_period",
    "multipliers",
    "one_period",
    "orbit_diagram",
    "orbit_shooting",
    "period_statistics",
    "periodic_orbit",
    "periodic_orbits",
    "shoot",
    "start_from_run",
    "test_functions",
]
