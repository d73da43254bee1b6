"""Where a boundary link crosses the particle surface (lattice units): the fraction ``q`` of the
link in the fluid, for the interpolated bounce-back (``interpolated``, ``interpolated_fixed``).

A link goes from fluid node ``x`` along ``e_i`` into particle node ``s = x + e_i``; ``q |e_i|`` is
the distance from ``x`` to the body surface along the link, found as the entry point of the ray
``x + t e_i/|e_i|`` into the closed shape in the body frame (``entry_fraction``: ray-sphere,
ray-slab and ray-disc as in ``runs.ray_interval``, exact up to round-off; the same test that
decides which nodes a particle covers). The surface point, where the wall velocity is taken and
the link force acts, is ``x + q e_i``.

Edge cases (round-off only: the node set and the ray test agree up to it): an entry at or beyond
``s`` (``s`` on the surface) or a ray that misses the shape gives ``q = 1``; an entry at or
before ``x`` gives ``q = 0``.
"""

from __future__ import annotations

import math

from numba import njit

from ..shapes import CYLINDER, SPHERE
from .runs import _disc, _slab


@njit(cache=True)
def entry_fraction(kind, h0, h1, h2, px, py, pz, dx, dy, dz, n):
    """``q`` of a link in the body frame, from scalars only (no array argument: no reference
    counting in the per-link loop): the fluid node at ``p``, the unit direction ``d`` of the
    link, its length ``n`` and the shape ``kind`` with half-extents ``(h0, h1, h2)``. The ray
    tests of ``runs`` (``_slab``, ``_disc``; a sphere's quadratic inline)."""
    big = 1e300
    if kind == SPHERE:
        b = px * dx + py * dy + pz * dz
        disc = b * b - (px * px + py * py + pz * pz - h0 * h0)
        if disc < 0.0:
            return 1.0
        t0 = -b - math.sqrt(disc)
    elif kind == CYLINDER:
        t0, t1 = _slab(pz, dz, h2, -big, big)
        if t0 > t1:
            return 1.0
        t0, t1 = _disc(px, py, dx, dy, h0, t0, t1)
        if t0 > t1:
            return 1.0
    else:
        t0, t1 = _slab(px, dx, h0, -big, big)
        t0, t1 = _slab(py, dy, h1, t0, t1)
        t0, t1 = _slab(pz, dz, h2, t0, t1)
        if t0 > t1:
            return 1.0
    if t0 >= n:
        return 1.0
    if t0 <= 0.0:
        return 0.0
    return t0 / n


@njit(cache=True)
def link_fraction(kind, h, A, rx, ry, rz, ex, ey, ez):
    """Fraction ``q`` in [0, 1] of the link from the fluid node at ``r = (rx, ry, rz)`` (lab frame,
    relative to the particle centre) along the lattice vector ``e = (ex, ey, ez)`` that lies in
    the fluid, for the shape ``kind`` with half-extents ``h`` (3,) and rotation ``A`` (3, 3) body
    -> lab (``rigid.quat_to_matrix``). Pure function of its arguments; allocates nothing. (The
    kernels call ``entry_fraction`` with the body-frame quantities they keep per direction.)"""
    n = math.sqrt(float(ex * ex + ey * ey + ez * ez))
    # body frame: A^T r and A^T e / |e|
    bx = A[0, 0] * rx + A[1, 0] * ry + A[2, 0] * rz
    by = A[0, 1] * rx + A[1, 1] * ry + A[2, 1] * rz
    bz = A[0, 2] * rx + A[1, 2] * ry + A[2, 2] * rz
    dx = (A[0, 0] * ex + A[1, 0] * ey + A[2, 0] * ez) / n
    dy = (A[0, 1] * ex + A[1, 1] * ey + A[2, 1] * ez) / n
    dz = (A[0, 2] * ex + A[1, 2] * ey + A[2, 2] * ez) / n
    return entry_fraction(kind, h[0], h[1], h[2], bx, by, bz, dx, dy, dz, n)


#: link rules (``numerics.particle_boundary``): half-way (Ladd's Eq. (8)), Bouzidi et al.'s linear
#: interpolation, and the central linear interpolation of Ginzburg, Verhaeghe & d'Humieres (2008)
HALF_WAY = 0
BOUZIDI = 1
CLI = 2
RULES = {"bounce_back": HALF_WAY, "bouzidi": BOUZIDI, "cli": CLI}


@njit(cache=True)
def link_base(rule, q, f, f_behind, f_opp, behind_fluid):
    """The ghost base ``G`` and the moving-wall coefficient ``c`` of one link: the slot the fluid
    node ``x`` pulls gets ``G - c 6 w_i rho0 (e_i . u_w)`` (mass correction aside). ``f =
    f*_i(x)``, ``f_behind = f*_i(x - e_i)`` (used only if ``behind_fluid``), ``f_opp =
    f*_opp(i)(x)``, all post-collision.

    * ``HALF_WAY``: ``G = f``, ``c = 1`` (any ``q``);
    * ``BOUZIDI`` (Bouzidi, Firdaouss & Lallemand 2001): ``q < 1/2``: ``G = 2q f + (1-2q)
      f_behind``, ``c = 1``; ``q >= 1/2``: ``G = (f + (2q-1) f_opp) / (2q)``, ``c = 1/(2q)``;
    * ``CLI`` (Ginzburg, Verhaeghe & d'Humieres 2008, central linear interpolation): ``G = f +
      k (f_behind - f_opp)``, ``k = (1-2q)/(1+2q)``, ``c = 2/(1+2q)``. Its coefficients of
      ``f_behind`` and ``f_opp`` are opposite, which makes the closure depend on the TRT rates
      through the magic parameter only: with TRT, steady results do not change with the viscosity
      at fixed ``Lambda`` (as for half-way bounce-back; Bouzidi's rule lacks this).

    Where ``x - e_i`` is not fluid, Bouzidi's ``q < 1/2`` branch falls back to half-way and CLI to
    Bouzidi's local rule (``q >= 1/2``) or half-way (``q < 1/2``). ``c`` follows from requiring
    the fluid moving with the wall, ``f = f^eq(rho, u_w)``, to be reproduced exactly."""
    if rule == CLI and behind_fluid:
        k = (1.0 - 2.0 * q) / (1.0 + 2.0 * q)
        return f + k * (f_behind - f_opp), 2.0 / (1.0 + 2.0 * q)
    if rule == HALF_WAY:
        return f, 1.0
    if q < 0.5:
        if behind_fluid and rule == BOUZIDI:
            return 2.0 * q * f + (1.0 - 2.0 * q) * f_behind, 1.0
        return f, 1.0
    c = 0.5 / q
    return c * (f + (2.0 * q - 1.0) * f_opp), c
