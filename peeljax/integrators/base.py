"""The integrator contract: what :func:`peeljax.simulate`, :func:`peeljax.sweep`,
:func:`peeljax.least_tau` and :func:`peeljax.fit_adhesion` ask of a time integrator.

An integrator is a method together with its step control, an ``eqx.Module`` whose numbers
are traced and whose shapes (step budgets, mesh sizes) are static. It integrates y' = ψ(y)
for any :class:`peeljax.ODE` (``evaluate(y)`` → ψ, J_t and F̃·f; ``tau``) and reports an
honest stop (``status``, ``t_stop``; NaN after the stop). It has two ways to run:

* :meth:`AbstractIntegrator.integrate`: one trajectory as a :class:`~peeljax.Solution`, at
  given times (dense output) or at the integrator's own points;
* :meth:`AbstractIntegrator.observe`: every step shown to an observer
  (:mod:`peeljax.integrators.observers`), with the cubic Hermite data of its ends, and an
  :class:`ObservedRun` back. That is all a sweep lane needs (:mod:`peeljax.sweeps.engine`):
  statistics over a window, event counts, saved states and the work done, in memory
  independent of the number of steps.

and :meth:`AbstractIntegrator.settings` (JSON metadata, compared when a sweep resumes).

=================================================  ==================================  =========================
integrator                                         built by ``integrator_for`` from    steps
=================================================  ==================================  =========================
:class:`~peeljax.integrators.UniformMesh`          ``solver=AlphaMethod``, ``dt``      the paper's uniform mesh
:class:`~peeljax.integrators.ErrorControl`         ``solver=AlphaMethod``, no ``dt``   the α-method's PI control
:class:`~peeljax.integrators.DiffraxIntegrator`    any ``diffrax.AbstractSolver``      diffrax's PID control
=================================================  ==================================  =========================
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, ArrayLike, Float, Int

from ..homogenized import ODE
from ..solution import JumpRecord, Solution
from .observers import Observer

__all__ = ["AbstractIntegrator", "ObservedRun"]


class ObservedRun(eqx.Module):
    """The outcome of :meth:`AbstractIntegrator.observe`.

    Attributes:
        record: the observer's final record.
        status: a :class:`~peeljax.StopReason` code; t_stop: the time of the last accepted state.
        y_final: the last accepted state (physical coordinates; NaN if the start failed).
        accepted_steps, rejected_steps: step counts; newton_iterations: their sum over all
            attempts (0 where the integrator does not report them).
        subdivided_steps, max_subdivision_level: the uniform mesh's safeguard (0 elsewhere).
        jumps: the :class:`~peeljax.JumpRecord` where folds are located (error control), else None.
    """

    record: object
    status: Int[Array, ""]
    t_stop: Float[Array, ""]
    y_final: Float[Array, " n"]
    accepted_steps: Int[Array, ""]
    rejected_steps: Int[Array, ""]
    newton_iterations: Int[Array, ""]
    subdivided_steps: Int[Array, ""]
    max_subdivision_level: Int[Array, ""]
    jumps: JumpRecord | None = None


class AbstractIntegrator(eqx.Module):
    """A time integrator of y' = ψ(y) with its step control (an abstract base).

    Attributes:
        dense_output: whether :meth:`integrate` can output at arbitrary times ``ts``; False:
            only at its own points (``ts`` must be None), and a sweep's statistics are taken
            over those points rather than as time integrals.
        carried_log: components of the state the integrator carries as their logarithm (an
            observer sees log v there); ``()`` when it carries y itself.
    """

    dense_output: ClassVar[bool]

    @property
    @abc.abstractmethod
    def carried_log(self) -> tuple[int, ...]:
        """Components carried as logarithms (observers see these in log form)."""

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
    def observe(
        self, ode: ODE, y0: Float[Array, " n"], t0: ArrayLike, t_final: ArrayLike, observer: Observer
    ) -> ObservedRun:
        """Integrate from ``t0`` to ``t_final``, showing each step attempt to ``observer``
        (in carried coordinates: see :attr:`carried_log`)."""

    @abc.abstractmethod
    def settings(self) -> dict:
        """The settings that determine the results, JSON-able (host values)."""
