"""The lubrication resistances in closed form (Reynolds' equation of a thin film): ``F = zeta u``
for the relative velocity ``u`` of the two surfaces, in any consistent units (the solver: lattice
units, ``mu = rho0 nu``). The package docstring says which pair of features uses which.

Curved contacts (``curved_squeeze``). Near the closest point the gap is the quadratic
``h(x, y) = H + (k_x x^2 + k_y y^2) / 2`` (``k_x >= k_y`` the principal curvatures of the gap, the
sums of both surfaces' curvatures). Reynolds' equation ``div(h^3 grad p) = 12 mu u_n`` is solved
exactly by ``p = 6 mu u_n / ((k_x + k_y) h^2)``, whence (Cox 1974, Int. J. Multiphase Flow 1, 343)

    zeta = 12 pi mu (R_x R_y)^(3/2) / ((R_x + R_y) H),      R = 1/k,

which is Nguyen & Ladd's (2002) ``6 pi mu (a1 a2 / (a1 + a2))^2 / H`` for two spheres and
``6 pi mu a^2 / H`` for a sphere and a plane. Where the features end within the film (a cylinder's
side is straight along its axis, ``k_y = 0``, and ends at its rims), the film is summed in strips
across the soft direction ``y`` (each a two-dimensional squeeze, ``3 sqrt(2) pi mu R_x^(3/2) h^-3/2``
per unit length) between the ends ``s_a, s_b`` of the features' overlap:

    zeta = chi 3 sqrt(2) pi mu k_x^(-3/2) int_{s_a}^{s_b} (H + k_y s^2 / 2)^(-3/2) ds,
    chi = k_x / (k_x + max(k_y, 0)),

exact for infinite ends (the factor chi carries the strip sum to Cox's result for any ``k_y >= 0``)
and for a straight line contact of length ``L`` (``L`` times the two-dimensional squeeze); a
negative ``k_y`` (a straight feature inside the concave pipe wall) has its film thinnest at the
ends. The integral is ``[s / (H sqrt(H + k_y s^2 / 2))]`` between the ends.

Flat contacts (``plate_squeeze``, ``plate_shear``). Between parallel flat faces overlapping in a
patch of area ``A`` the film is ``h`` thick everywhere; Reynolds' equation with ``p = 0`` on the rim
is the torsion problem, ``zeta = 12 mu int psi dA / h^3`` with ``lap psi = -1``, and Saint-Venant's
approximation of the torsion integral, ``int psi dA = A^4 / (16 pi^2 I_p)`` (``I_p`` the polar moment
of the patch about its centroid), gives

    zeta = beta mu A^2 / h^3,    beta = 3 A^2 / (4 pi^2 I_p):

exact for discs (Stefan's ``3 pi mu R^4 / (2 h^3)``, beta = 3/(2 pi)) and ellipses, 8 % high for a
square (beta 0.456 against 0.422), 2 % for a 4:1 rectangle. The same plates sliding past each other
carry the plane Couette stress ``mu u_t / h``: ``zeta_t = mu A / h``.
"""

from __future__ import annotations

import math

from numba import njit

SQRT2 = math.sqrt(2.0)


@njit(cache=True)
def strip_integral(H, k, sa, sb):
    """``int_{sa}^{sb} (H + k s^2 / 2)^(-3/2) ds`` for ``H > 0`` and ``H + k s^2 / 2 > 0`` on the
    interval; ``sa``/``sb`` may be -inf/+inf when ``k > 0``."""
    return _strip_end(H, k, sb) - _strip_end(H, k, sa)


@njit(cache=True, inline="always")
def _strip_end(H, k, s):
    if math.isinf(s):
        return math.copysign(1.0, s) / (H * math.sqrt(0.5 * k))
    return s / (H * math.sqrt(H + 0.5 * k * s * s))


@njit(cache=True)
def curved_squeeze(mu, kx, ky, H, sa, sb):
    """Normal resistance of a curved contact: principal gap curvatures ``kx >= ky`` (``kx > 0``),
    gap ``H`` at the contact point, the features' overlap ``[sa, sb]`` along the ``ky`` direction
    measured from the contact point (module docstring)."""
    chi = kx / (kx + max(ky, 0.0))
    return chi * 3.0 * SQRT2 * math.pi * mu * kx ** -1.5 * strip_integral(H, ky, sa, sb)


@njit(cache=True)
def plate_squeeze(mu, area, ip, h):
    """Normal resistance of parallel flat faces overlapping in a patch of ``area`` and polar moment
    ``ip`` about its centroid, at gap ``h`` (Saint-Venant's torsion integral; module docstring)."""
    return 3.0 * mu * area**4 / (4.0 * math.pi**2 * ip * h**3)


@njit(cache=True)
def plate_shear(mu, area, h):
    """Tangential (Couette) resistance of parallel flat faces sliding past each other."""
    return mu * area / h
