"""The non-stiff test set of Hull, Enright, Fellen and Sedgwick (1972), problems A1–E5.

T. E. Hull, W. H. Enright, B. M. Fellen, A. E. Sedgwick, "Comparing numerical methods for
ordinary differential equations", SIAM J. Numer. Anal. 9(4) (1972) 603–637; every problem on
t ∈ [0, 20]. The statements follow the paper (as PETSc's ``ex31`` and diffrax's ``test_detest.py``
restate them); C3 and C4 keep the paper's last row y'_n = y_{n−1} − 2·y_n (diffrax's restatement
drops its −2). C5, the five outer planets, is written as one 30-vector (15 positions, then 15
velocities) rather than a pair of 3 × 5 arrays.

``PROBLEMS[name]()`` returns (f(t, y, args), y0) with y0 a float64 array (shape (1,) for class A),
for ``diffrax.ODETerm``. The functions are written in ``jax.numpy`` (jit them for scipy).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

__all__ = ["PROBLEMS", "T_FINAL"]

T_FINAL = 20.0


def _scalar(rate, y0):
    return (lambda t, y, args: rate(t, y)), jnp.array([y0])


# Class A: single equations
def a1():
    return _scalar(lambda t, y: -y, 1.0)


def a2():
    return _scalar(lambda t, y: -0.5 * y**3, 1.0)


def a3():
    return _scalar(lambda t, y: y * jnp.cos(t), 1.0)


def a4():
    return _scalar(lambda t, y: 0.25 * y * (1 - 0.05 * y), 1.0)


def a5():
    return _scalar(lambda t, y: (y - t) / (y + t), 4.0)


# Class B: small systems
def b1():  # growth of two conflicting populations
    def f(t, y, args):
        return jnp.stack([2 * (y[0] - y[0] * y[1]), -y[1] + y[0] * y[1]])

    return f, jnp.array([1.0, 3.0])


def b2():  # linear chemical reaction
    def f(t, y, args):
        return jnp.stack([-y[0] + y[1], y[0] - 2 * y[1] + y[2], y[1] - y[2]])

    return f, jnp.array([2.0, 0.0, 1.0])


def b3():  # nonlinear chemical reaction
    def f(t, y, args):
        return jnp.stack([-y[0], y[0] - y[1] ** 2, y[1] ** 2])

    return f, jnp.array([1.0, 0.0, 0.0])


def b4():  # integral surface of a torus
    def f(t, y, args):
        r = jnp.sqrt(y[0] ** 2 + y[1] ** 2)
        return jnp.stack([-y[1] - y[0] * y[2] / r, y[0] - y[1] * y[2] / r, y[0] / r])

    return f, jnp.array([3.0, 0.0, 0.0])


def b5():  # Euler's equations of a rigid body without external forces
    def f(t, y, args):
        return jnp.stack([y[1] * y[2], -y[0] * y[2], -0.51 * y[0] * y[1]])

    return f, jnp.array([0.0, 1.0, 1.0])


# Class C: moderate systems (linear chains, then the five outer planets)
def _linear(A):
    A = jnp.asarray(A)
    return (lambda t, y, args: A @ y), jnp.zeros(A.shape[0]).at[0].set(1.0)


def c1():  # radioactive decay chain
    A = np.diag(-np.ones(10)) + np.diag(np.ones(9), -1)
    A[9, 9] = 0.0
    return _linear(A)


def c2():  # decay chain with rates 1 … 9
    k = np.arange(1.0, 10.0)
    A = np.diag(np.append(-k, 0.0)) + np.diag(k, -1)
    return _linear(A)


def _tridiagonal(n):
    return np.diag(-2 * np.ones(n)) + np.diag(np.ones(n - 1), -1) + np.diag(np.ones(n - 1), 1)


def c3():
    return _linear(_tridiagonal(10))


def c4():
    return _linear(_tridiagonal(51))


_K2, _M0 = 2.95912208286, 1.00000597682
_MASSES = (0.000954786104043, 0.000285583733151, 0.0000437273164546, 0.0000517759138449, 0.00000277777777778)
_Q0 = (
    (3.42947415189, 6.64145542550, 11.2630437207, -30.1552268759, -21.1238353380),
    (3.35386959711, 5.97156957878, 14.6952576794, 1.65699966404, 28.4465098142),
    (1.35494901715, 2.18231499728, 6.27960525067, 1.43785752721, 15.3882659679),
)
_P0 = (
    (-0.557160570446, -0.415570776342, -0.325325669158, -0.024047625417, -0.176860753121),
    (0.505696783289, 0.365682722812, 0.189706021964, -0.287659532608, -0.216393453025),
    (0.230578543901, 0.169143213293, 0.087726532278, -0.117219543175, -0.014864789309),
)


def c5():  # the five outer planets about the sun (Jupiter … Pluto), y = (positions, velocities)
    m = jnp.array(_MASSES)
    off = ~jnp.eye(5, dtype=bool)

    def f(t, y, args):
        q, p = y[:15].reshape(3, 5), y[15:].reshape(3, 5)
        r3 = jnp.sum(q**2, axis=0) ** 1.5
        d = q[:, None, :] - q[:, :, None]  # d[:, j, k] = q_k − q_j
        d3 = jnp.where(off, jnp.sum(d**2, axis=0), 1.0) ** 1.5  # (no self-interaction: the diagonal is masked)
        pull = jnp.where(off, m * (d / d3 - (q / r3)[:, None, :]), 0.0)
        return jnp.concatenate([p.ravel(), (_K2 * (-(_M0 + m) * q / r3 + jnp.sum(pull, axis=-1))).ravel()])

    return f, jnp.concatenate([jnp.array(_Q0).ravel(), jnp.array(_P0).ravel()])


# Class D: orbit equations, eccentricity ε
def _orbit(eps):
    def f(t, y, args):
        r3 = (y[0] ** 2 + y[1] ** 2) ** 1.5
        return jnp.stack([y[2], y[3], -y[0] / r3, -y[1] / r3])

    return f, jnp.array([1 - eps, 0.0, 0.0, math.sqrt((1 + eps) / (1 - eps))])


def d1():
    return _orbit(0.1)


def d2():
    return _orbit(0.3)


def d3():
    return _orbit(0.5)


def d4():
    return _orbit(0.7)


def d5():
    return _orbit(0.9)


# Class E: higher-order equations as first-order systems
def e1():  # Bessel's equation, order 1/2
    def f(t, y, args):
        return jnp.stack([y[1], -(y[1] / (t + 1) + y[0] * (1 - 0.25 / (t + 1) ** 2))])

    return f, jnp.array([0.6713967071418030, 0.09540051444747446])


def e2():  # Van der Pol, μ = 1
    def f(t, y, args):
        return jnp.stack([y[1], (1 - y[0] ** 2) * y[1] - y[0]])

    return f, jnp.array([2.0, 0.0])


def e3():  # Duffing
    def f(t, y, args):
        return jnp.stack([y[1], y[0] ** 3 / 6 - y[0] + 2 * jnp.sin(2.78535 * t)])

    return f, jnp.array([0.0, 0.0])


def e4():
    def f(t, y, args):
        return jnp.stack([y[1], 0.032 - 0.4 * y[1] ** 2])

    return f, jnp.array([30.0, 0.0])


def e5():
    def f(t, y, args):
        return jnp.stack([y[1], jnp.sqrt(1 + y[1] ** 2) / (25 - t)])

    return f, jnp.array([0.0, 0.0])


PROBLEMS = {fn.__name__: fn for fn in (a1, a2, a3, a4, a5, b1, b2, b3, b4, b5, c1, c2, c3, c4, c5,
                                       d1, d2, d3, d4, d5, e1, e2, e3, e4, e5)}  # fmt: skip
