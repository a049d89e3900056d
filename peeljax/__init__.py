"""peeljax: stick-slip peeling of an adhesive tape off a rotating spool, in JAX.

The modules follow the data flow; each imports only those above it:

    model.py, adhesion.py    the DAE: f(x, v), the constraint (sac), φ(v, V)
    structure.py             ∂f/∂x, ∂f/∂v, F̃, ∂φ/∂v by autodiff; J_t(τ); the local index
    steady.py                steady peeling and its linear stability (where it ends)
    homogenized.py           ψ(y; τ) of eq. (hv): the ODE every integrator solves (``ODE``)
    integrators/             one contract (base.py), three integrators → ``Solution``
    simulate.py              one run, its options checked before anything compiles
    run_program.py, bound.py    its compiled program and the host's assembly; a run bound to its options
    measurements/            lab files, force records, stick-slip tables and their statistics
    sweeps/, fit/, analysis.py      many runs at once; φ from data; stick-slip and index in time
    lyapunov.py, attractor_map.py   exponents through the jumps; every attractor over V
    cli/, plots/, figures.py        the command line and the pictures

Importing peeljax enables 64-bit floats in JAX (``jax_enable_x64``): the peeling problem
spans v from 1e-10 to 10 m/s and stiff Newton solves, which float32 cannot carry.

It also asks XLA:CPU to compile small while loops (the α-method's Newton and step loops) as
one function instead of one kernel launch per operation
(``xla_cpu_small_while_loop_byte_threshold``): faster per step, results bit-identical
(measured by ``benchmarks/studies/step_cost.py --default-xla-flags`` (retired: ``benchmarks/studies/README.md``); figures in the README). This only takes effect if peeljax is imported before JAX's CPU
backend starts, and is skipped when the environment variable ``PEELJAX_KEEP_XLA_FLAGS`` is
set or ``XLA_FLAGS`` already sets that option.

It turns off XLA:CPU's MLIR fusion emitters (``xla_cpu_use_fusion_emitters=false``, jaxlib ≥
0.6 where the option exists): the first call of a run compiles in 1.7 s instead of 2.5 s, per
step and per sweep lane as fast, results bit-identical (measured by
``benchmarks/first_call.py``; same two exceptions).

And it asks for one JAX CPU device per core this process may use
(``xla_force_host_platform_device_count``), so that :func:`peeljax.sweep` and
:func:`peeljax.least_tau` shard their lanes over every core (a single run uses one device, as
before). Skipped in the same two cases, or when ``XLA_FLAGS`` sets the count itself.

Finally it keeps every compiled program in JAX's persistent compilation cache, in the user's
cache folder (``~/.cache/peeljax`` on Linux), so that a program is compiled once per machine
rather than once per process; ``PEELJAX_COMPILATION_CACHE`` moves the folder or turns this off,
and a cache the user configured for JAX is left alone (:mod:`peeljax._compilation_cache`).
"""

import os as _os


def _flags_to_extend(option: str) -> str | None:
    """``XLA_FLAGS`` as they stand, or None where peeljax leaves them alone: the user asked so
    (``PEELJAX_KEEP_XLA_FLAGS``) or set ``option`` already."""
    flags = _os.environ.get("XLA_FLAGS", "")
    if _os.environ.get("PEELJAX_KEEP_XLA_FLAGS") or option in flags:
        return None
    return flags


def _small_while_loop_flag() -> None:
    flags = _flags_to_extend("xla_cpu_small_while_loop_byte_threshold")
    if flags is None:
        return
    option = "xla_cpu_small_while_loop_byte_threshold=1000000000"
    words = flags.split()
    for i, word in enumerate(words):  # merge into an existing --xla_backend_extra_options
        if word.startswith("--xla_backend_extra_options="):
            words[i] = f"{word},{option}"
            break
    else:
        words.append(f"--xla_backend_extra_options={option}")
    _os.environ["XLA_FLAGS"] = " ".join(words)


def _fusion_emitters_flag() -> None:
    flags = _flags_to_extend("xla_cpu_use_fusion_emitters")
    if flags is None:
        return
    try:  # an option older jaxlibs do not know would abort the backend's start
        from importlib.metadata import version

        major_minor = tuple(int(part) for part in version("jaxlib").split(".")[:2])
    except Exception:  # noqa: BLE001 (no jaxlib metadata, or an unusual version string)
        return
    if major_minor >= (0, 6):
        _os.environ["XLA_FLAGS"] = f"{flags} --xla_cpu_use_fusion_emitters=false".strip()


def _host_device_flag() -> None:
    flags = _flags_to_extend("xla_force_host_platform_device_count")
    if flags is None:
        return
    try:
        cores = len(_os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        cores = _os.cpu_count() or 1
    if cores > 1:
        _os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores}".strip()


def _backend_started() -> bool:
    """Whether JAX's backends started before peeljax was imported (XLA reads its flags then only)."""
    import sys

    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except Exception:  # noqa: BLE001 (a JAX without it: nothing to say)
        return False


def _warn_flags_too_late(flags_before: str) -> None:
    """A CPU backend that started before peeljax set its flags runs without them: say so."""
    if _os.environ.get("XLA_FLAGS", "") == flags_before or _jax.default_backend() != "cpu":
        return
    import warnings

    warnings.warn(
        "peeljax was imported after JAX's CPU backend had started, so its XLA flags do not apply in this "
        f"process ({len(_jax.devices())} CPU device(s); small while loops not compiled as one call): runs take "
        "several times longer (P1: 4.5-4.7 ms against 0.9-1.0 ms, measured) and sweeps use fewer cores. "
        "Import peeljax before anything that starts JAX (jax.devices(), a first jax.numpy operation), or "
        "restart the process; PEELJAX_KEEP_XLA_FLAGS=1 silences this.",
        RuntimeWarning,
        stacklevel=3,
    )


_started_before, _flags_before = _backend_started(), _os.environ.get("XLA_FLAGS", "")
_small_while_loop_flag()
_fusion_emitters_flag()
_host_device_flag()

import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)
if _started_before:
    _warn_flags_too_late(_flags_before)

from . import _compilation_cache  # noqa: E402

_compilation_cache.enable()

from .adhesion import COEFFICIENT_NAMES, PAPER_COEFFICIENTS, AdhesionLaw, safe_pow  # noqa: E402
from .analysis import StickSlipAnalysis, analyze, bifurcation_diagram, phi_extrema, trajectory_structure  # noqa: E402
from .bound import Simulator  # noqa: E402
from .branches import Folds, phi_folds  # noqa: E402
from .constrained import ConstrainedDAE  # noqa: E402
from .desingularized import DesingularizedDAE  # noqa: E402
from .cycles import CycleStatistics, RepeatPattern, cycle_statistics  # noqa: E402
from .fit import (  # noqa: E402
    FitResult,
    Observation,
    StickSlipTable,
    fit_adhesion,
    fit_adhesion_steady,
    fit_stick_slip,
    phi_relative_error,
    read_force_record,
    read_stick_slip_table,
)
from .homogenized import ODE, HomogenizedODE  # noqa: E402
from .integrators import (  # noqa: E402
    AlphaMethod,
    AlphaSolver,
    LogTransformedODE,
    PIController,
    alpha_coefficients,
    amplification_matrix,
    integrate_alpha,
    integrate_alpha_adaptive,
    integrate_reference,
)
from .lyapunov import LyapunovExponents, lyapunov_exponents, lyapunov_spectra  # noqa: E402
from .model import PeelingModel  # noqa: E402
from .orbits import (  # noqa: E402
    OrbitDiagram,
    OrbitNotFound,
    OrbitStatus,
    PeriodicOrbit,
    continue_orbit,
    orbit_diagram,
    periodic_orbit,
    periodic_orbits,
)
from .saved import SavedRun, load  # noqa: E402
from .simulate import simulate, simulate_reference  # noqa: E402
from .solution import JumpRecord, Solution, StepDiagnostics, StopReason  # noqa: E402
from .structure import (  # noqa: E402
    Jacobians,
    is_fast_scale,
    jacobians,
    local_index,
    neumann_radius,
    neumann_terms,
    schur_complement,
    truncated_schur_complement,
)
from .steady import steady_eigenvalues, steady_jacobian, steady_peeling_ends, steady_state  # noqa: E402
from .sweeps import LeastTau, StickSlipMap, SweepResult, least_tau, stick_slip_map, sweep  # noqa: E402
from .attractor_map import AttractorMap, attractor_map  # noqa: E402

from ._version import __version__ as __version__  # noqa: E402

__all__ = [
    "COEFFICIENT_NAMES",
    "ODE",
    "PAPER_COEFFICIENTS",
    "AdhesionLaw",
    "AlphaMethod",
    "AlphaSolver",
    "ConstrainedDAE",
    "DesingularizedDAE",
    "CycleStatistics",
    "FitResult",
    "Folds",
    "HomogenizedODE",
    "Jacobians",
    "JumpRecord",
    "LeastTau",
    "LyapunovExponents",
    "LogTransformedODE",
    "Observation",
    "OrbitDiagram",
    "OrbitNotFound",
    "OrbitStatus",
    "PIController",
    "PeelingModel",
    "PeriodicOrbit",
    "RepeatPattern",
    "SavedRun",
    "Simulator",
    "Solution",
    "StepDiagnostics",
    "StickSlipAnalysis",
    "StickSlipMap",
    "AttractorMap",
    "StickSlipTable",
    "StopReason",
    "SweepResult",
    "alpha_coefficients",
    "amplification_matrix",
    "analyze",
    "bifurcation_diagram",
    "continue_orbit",
    "cycle_statistics",
    "fit_adhesion",
    "fit_adhesion_steady",
    "fit_stick_slip",
    "integrate_alpha",
    "integrate_alpha_adaptive",
    "integrate_reference",
    "is_fast_scale",
    "jacobians",
    "least_tau",
    "load",
    "orbit_diagram",
    "periodic_orbit",
    "periodic_orbits",
    "lyapunov_exponents",
    "lyapunov_spectra",
    "attractor_map",
    "local_index",
    "neumann_radius",
    "neumann_terms",
    "phi_extrema",
    "phi_folds",
    "phi_relative_error",
    "read_force_record",
    "read_stick_slip_table",
    "safe_pow",
    "schur_complement",
    "simulate",
    "simulate_reference",
    "steady_eigenvalues",
    "steady_jacobian",
    "steady_peeling_ends",
    "steady_state",
    "stick_slip_map",
    "sweep",
    "trajectory_structure",
    "truncated_schur_complement",
]
