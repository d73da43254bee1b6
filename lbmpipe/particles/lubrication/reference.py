"""Exact and asymptotic Stokes-flow results the lubrication model is checked against (tests,
``benchmarks/lubrication.py``); plain NumPy, not used in a time step. Forces are given as the drag
factor ``lambda = F / (6 pi mu a U)`` of a sphere of radius ``a`` and speed ``U``, gaps as
``eps = h / a``.

* ``brenner_sphere_plane``: a sphere moving normal to a no-slip plane, the exact series of Brenner
  (1961, Chem. Eng. Sci. 16, 242, Eq. (2.19)) in bispherical coordinates, ``cosh(alpha) = 1 + eps``;
* ``cox_brenner_sphere_plane``: its small-gap expansion, ``1/eps + (1/5) ln(1/eps) + 0.971``
  (Cox & Brenner 1967, Chem. Eng. Sci. 22, 1753);
* ``brenner_two_spheres``: two equal spheres approaching each other with equal and opposite
  speeds ``U``; by symmetry a sphere approaching a free (slip) plane, Brenner's (1961) second series
  (also Maude 1961), ``eps`` = half the surface-to-surface gap over ``a``. Its small-gap limit is
  ``1/(4 eps) + (9/20) ln(1/eps) + O(1)`` (Jeffrey & Onishi 1984, J. Fluid Mech. 139, 261: the
  relative mode ``X11A - X12A``);
* ``stefan_disc``, ``square_plates``: the squeeze force between parallel plates in Reynolds'
  lubrication theory, ``F = 12 mu u_n / h^3 * int psi dA`` with ``lap psi = -1``, ``psi = 0`` on the
  rim: a disc of radius R (Stefan 1874, ``3 pi mu u R^4 / (2 h^3)``) and a square of side s (the
  torsion function's series, Timoshenko & Goodier, Theory of Elasticity, Sec. 109).
"""

from __future__ import annotations

import math

import numpy as np


def _bispherical(eps: float):
    alpha = math.acosh(1.0 + eps)
    n = np.arange(1, int(60.0 / alpha) + 60, dtype=np.float64)  # terms decay as exp(-(2n+1) alpha)
    return alpha, n, n * (n + 1.0) / ((2.0 * n - 1.0) * (2.0 * n + 3.0))


def brenner_sphere_plane(eps: float) -> float:
    """``F / (6 pi mu a U)`` of a sphere approaching a no-slip plane at gap ``eps * a`` (exact)."""
    alpha, n, c = _bispherical(eps)
    x = (2.0 * n + 1.0) * alpha
    # numerator and denominator of Brenner's ratio divided by exp(x), free of overflow
    num = (1.0 - np.exp(-2.0 * x)) + (2.0 * n + 1.0) * math.sinh(2.0 * alpha) * np.exp(-x)
    den = (1.0 - np.exp(-x)) ** 2 - (2.0 * n + 1.0) ** 2 * math.sinh(alpha) ** 2 * np.exp(-x)
    return float(4.0 / 3.0 * math.sinh(alpha) * np.sum(c * (num / den - 1.0)))


def cox_brenner_sphere_plane(eps: float) -> float:
    """The small-gap expansion of ``brenner_sphere_plane``."""
    return 1.0 / eps + 0.2 * math.log(1.0 / eps) + 0.971


def brenner_two_spheres(eps: float) -> float:
    """``F / (6 pi mu a U)`` on each of two equal spheres approaching each other, each at speed
    ``U``, with the surfaces ``2 eps a`` apart (exact)."""
    alpha, n, c = _bispherical(eps)
    x = (2.0 * n + 1.0) * alpha
    num = (1.0 + np.exp(-x)) ** 2 + (2.0 * n + 1.0) ** 2 * math.sinh(alpha) ** 2 * np.exp(-x)
    den = (1.0 - np.exp(-2.0 * x)) - (2.0 * n + 1.0) * math.sinh(2.0 * alpha) * np.exp(-x)
    return float(4.0 / 3.0 * math.sinh(alpha) * np.sum(c * (num / den - 1.0)))


def stefan_disc(mu: float, radius: float, h: float) -> float:
    """Squeeze resistance ``F / u_n`` of two parallel discs of ``radius`` at gap ``h``."""
    return 1.5 * math.pi * mu * radius**4 / h**3


def square_plates(mu: float, side: float, h: float) -> float:
    """Squeeze resistance ``F / u_n`` of two parallel squares of ``side`` at gap ``h`` (series to
    round-off): ``12 int psi dA = s^4 (1 - 192 / pi^5 sum_odd tanh(k pi / 2) / k^5)``."""
    k = np.arange(1, 200, 2, dtype=np.float64)
    beta = 1.0 - 192.0 / math.pi**5 * float(np.sum(np.tanh(k * math.pi / 2.0) / k**5))
    return mu * beta * side**4 / h**3
