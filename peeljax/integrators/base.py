"""The integrator contract: what :func:`peeljax.simulate`, :func:`peeljax.sweep`,
:func:`peeljax.least_tau` and :func:`peeljax.fit_adhesion` ask of a time integrator.

An integrator is a method together with its step control, an ``eqx.Module`` whose numbers
are traced and whose shapes (step budgets, mesh sizes) are static. It integrates y' = ψ(y)
for any :class:`peeljax.ODE` (``evaluate(y)`` → ψ, J_t and F̃·f; ``tau``) and reports an
honest stop in a :class:`~peeljax.Solution` (``status``, ``t_stop``; NaN after the stop):

==========================================  ==============================  =====================
integrator                                  built by ``integrator_for`` from  per-lane summaries
==========================================  ==============================  =====================
:class:`~peeljax.integrators.UniformMesh`   ``solver=AlphaMethod``, ``dt``   the mesh points
:class:`~peeljax.integrators.ErrorControl`  ``solver=AlphaMethod``, no dt    an :class:`Observer`
:class:`~peeljax.integrators.DiffraxIntegrator`  any ``diffrax.AbstractSolver``  an :class:`Observer`
==========================================  ==============================  =====================

Every integrator implements :meth:`AbstractIntegrator.integrate` (one trajectory, output at
given times or at its own points) and :meth:`AbstractIntegrator.settings` (JSON metadata, compared when
a sweep resumes). An integrator that chooses its own steps also implements
:meth:`AbstractAdaptiveIntegrator.observe`: it hands every step to an observer
(:mod:`peeljax.integrators.observers`) and returns an :class:`ObservedRun`. That is all a sweep
lane needs (:mod:`peeljax.sweeps.engine`): time integrals over a window on the dense output,
event counts, saved states, and the work done, in memory independent of the number of steps.
The uniform mesh's sweep lane is its own scan (:func:`peeljax.sweeps.engine.run_batch`), whose
statistics are over the mesh points, as in the paper.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, ArrayLike, Float, Int

from ..homogenized import ODE
from ..solution import Solution
from .observers import Observer

__all__ = ["AbstractAdaptiveIntegrator", "AbstractIntegrator", "ObservedRun"]


class AbstractIntegrator(eqx.Module):
    """A time integrator of y' = ψ(y) with its step control (an abstract base).

    Attributes:
        dense_output: whether :meth:`integrate` can output at arbitrary times ``ts`` (by the
            integrator's dense output); False: only at its own points (``ts`` must be None).
    """

    dense_output: ClassVar[bool]

    @abc.abstractmethod
    def integrate(
        self,
        ode: ODE,
        y0: Float[Array, " n"],
        t0: ArrayLike,
        t_final: ArrayLike,
        ts: Float[Array, " m"] | None = None,
    ) -> Solution:
        """Integrate from ``t0`` to ``t_final``; output at ``ts`` (increasing, in [t0, t_final])
        or, with None, at the integrator's own points. Traceable: no Python control flow on values."""

    @abc.abstractmethod
    def settings(self) -> dict:
        """The settings that determine the results, JSON-able (host values)."""


class ObservedRun(eqx.Module):
    """The outcome of :meth:`AbstractAdaptiveIntegrator.observe`.

    Attributes:
        record: the observer's final record.
        status: a :class:`~peeljax.StopReason` code; t_stop: the time reached.
        y_final: the last accepted state (physical coordinates; y0 if no step was accepted).
        accepted_steps, rejected_steps: step counts; newton_iterations: their sum over all
            attempts (0 where the integrator does not report them).
    """

    record: object
    status: Int[Array, ""]
    t_stop: Float[Array, ""]
    y_final: Float[Array, " n"]
    accepted_steps: Int[Array, ""]
    rejected_steps: Int[Array, ""]
    newton_iterations: Int[Array, ""]


class AbstractAdaptiveIntegrator(AbstractIntegrator):
    """An integrator that chooses its own steps and shows each to an observer.

    Attributes:
        carried_log: components of the state the integrator carries as their logarithm (the
            observer sees log v there); ``()`` when it carries y itself.
    """

    dense_output: ClassVar[bool] = True

    @property
    @abc.abstractmethod
    def carried_log(self) -> tuple[int, ...]:
        """Components carried as logarithms (observers see these in log form)."""

    @abc.abstractmethod
    def observe(
        self, ode: ODE, y0: Float[Array, " n"], t0: ArrayLike, t_final: ArrayLike, observer: Observer
    ) -> ObservedRun:
        """Integrate from ``t0`` to ``t_final``, handing each step attempt to ``observer``
        (in carried coordinates: see :attr:`carried_log`)."""
