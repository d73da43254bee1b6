"""The film between two close surfaces, from the collision narrow phase's contact (gap, normal,
point): which features face each other, the curvature of the gap, the features' overlap, and
from them the normal and tangential resistances (``formulas``). The package docstring gives the
model for each pair of features; this module implements it. Lattice units.

Inputs of ``contact_resistance``: body 1 (shape code, half sizes, centre, rotation matrix) and body 2
(the same, or a wall: ``wall`` 1 a plane, 2 the pipe of radius ``Rp``), the contact's unit normal
``n`` (from 1 to 2, or into the wall), point ``c`` and signed gap ``h0``; the viscosity ``mu``, the
cutoff ``hc``, the saturation gap ``hmin``, the edge radius ``re`` and the flatness tolerance
``tol`` (the narrow phase's ``manifold_tol``); scratch ``S`` (``new_scratch``). Output:
``(zeta_n, zeta_t, p)``: the resistances to the normal and the tangential relative velocity at the
point ``p`` (lab), both 0 for ``h0 >= hc``, both continuous in ``h0`` (zero at ``hc``), constant below
``hmin``. Only reads its inputs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.features import _feature, _plane_axes
from ..contact.support import DISC_SIDES
from ..shapes import CUBE, CYLINDER, SPHERE
from .formulas import curved_squeeze, plate_shear, plate_squeeze

_NCLIP = 2 * DISC_SIDES + 8  # vertices of the overlap of two convex features, with room
#: a cap is a regular DISC_SIDES-gon in the contact features; scaled by this it has the disc's area
_DISC_AREA_FIX = math.sqrt(math.pi / (0.5 * DISC_SIDES * math.sin(2.0 * math.pi / DISC_SIDES)))

WALL_NONE = 0
WALL_PLANE = 1
WALL_PIPE = 2


@njit(cache=True)
def new_scratch():
    """Scratch of ``contact_resistance``: feature points (lab), plane coordinates and the clip's
    ping-pong buffers. One per thread, made outside the loop over contacts."""
    return (np.empty((DISC_SIDES, 3)), np.empty((DISC_SIDES, 3)), np.empty((DISC_SIDES, 3)),
            np.empty((_NCLIP, 2)), np.empty((_NCLIP, 2)), np.empty((_NCLIP, 2)), np.empty((_NCLIP, 2)))


@njit(cache=True, inline="always")
def _add_dir(K, u0, u1, k):
    # K += k u u^T, K = (kxx, kxy, kyy) in the contact plane's axes
    K[0] += k * u0 * u0
    K[1] += k * u0 * u1
    K[2] += k * u1 * u1


@njit(cache=True)
def _in_plane(a0, a1, a2, t1, t2):
    """Unit in-plane direction of the lab vector a (its projection normalised), as (u0, u1)."""
    u0 = a0 * t1[0] + a1 * t1[1] + a2 * t1[2]
    u1 = a0 * t2[0] + a1 * t2[1] + a2 * t2[2]
    ln = math.sqrt(u0 * u0 + u1 * u1)
    if ln == 0.0:
        return 1.0, 0.0
    return u0 / ln, u1 / ln


@njit(cache=True)
def _add_feature_curvature(kind, h, x, R, m, F, n, t1, t2, re, K):
    """Add the curvature (towards the gap) of a body's feature F (m lab points, ``_feature``) to
    K: a sphere ``1/a`` both ways; a cube vertex ``1/re`` both ways, an edge ``1/re`` across it; a
    cylinder's side ``1/b`` across its axis, a rim point ``1/re`` across the rim and the rim circle's
    normal curvature along it; faces and caps are flat."""
    if m >= 3:
        return
    k = 0.0
    if m == 2:
        d0, d1 = _in_plane(F[1, 0] - F[0, 0], F[1, 1] - F[0, 1], F[1, 2] - F[0, 2], t1, t2)
        _add_dir(K, -d1, d0, 1.0 / (h[0] if kind == CYLINDER else re))
        return
    if kind == SPHERE:
        k = 1.0 / h[0]
    elif kind == CUBE:
        k = 1.0 / re
    else:  # a cylinder's rim point: the torus of tube radius re about the rim circle
        s = 0.0
        for d in range(3):
            s += (F[0, d] - x[d]) * R[d, 2]
        sg = 1.0 if s >= 0.0 else -1.0
        r = np.empty(3)
        for d in range(3):
            r[d] = F[0, d] - x[d] - sg * h[2] * R[d, 2]  # from the cap centre to the rim point
        lr = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        if lr > 0.0:
            for d in range(3):
                r[d] /= lr
        ta0 = R[1, 2] * r[2] - R[2, 2] * r[1]  # rim tangent: axis x radial
        ta1 = R[2, 2] * r[0] - R[0, 2] * r[2]
        ta2 = R[0, 2] * r[1] - R[1, 2] * r[0]
        u0, u1 = _in_plane(ta0, ta1, ta2, t1, t2)
        along = max(0.0, r[0] * n[0] + r[1] * n[1] + r[2] * n[2]) / h[0]
        _add_dir(K, u0, u1, along)
        _add_dir(K, -u1, u0, 1.0 / re)
        return
    K[0] += k
    K[2] += k


@njit(cache=True)
def _project(F, m, c, t1, t2, P, scale):
    """Plane coordinates of the m points F about c; polygons counter-clockwise, scaled by
    ``scale`` about their mean (the cap's area fix)."""
    mx = 0.0
    my = 0.0
    for r in range(m):
        dx = F[r, 0] - c[0]
        dy = F[r, 1] - c[1]
        dz = F[r, 2] - c[2]
        P[r, 0] = dx * t1[0] + dy * t1[1] + dz * t1[2]
        P[r, 1] = dx * t2[0] + dy * t2[1] + dz * t2[2]
        mx += P[r, 0]
        my += P[r, 1]
    if m < 3:
        return
    mx /= m
    my /= m
    area = 0.0
    for r in range(m):
        P[r, 0] = mx + scale * (P[r, 0] - mx)
        P[r, 1] = my + scale * (P[r, 1] - my)
    for r in range(m):
        s = (r + 1) % m
        area += P[r, 0] * P[s, 1] - P[s, 0] * P[r, 1]
    if area < 0.0:
        for r in range(m // 2):
            s = m - 1 - r
            a0 = P[r, 0]
            a1 = P[r, 1]
            P[r, 0] = P[s, 0]
            P[r, 1] = P[s, 1]
            P[s, 0] = a0
            P[s, 1] = a1


@njit(cache=True)
def _clip(S, ns, C, nc, out, tmp):
    """Sutherland-Hodgman: the convex polygon S (ns points) clipped by the convex polygon C (nc
    points), both counter-clockwise; result in ``out``, returns its number of points."""
    cnt = ns
    for r in range(ns):
        out[r, 0] = S[r, 0]
        out[r, 1] = S[r, 1]
    for e in range(nc):
        if cnt == 0:
            return 0
        ax = C[e, 0]
        ay = C[e, 1]
        ex = C[(e + 1) % nc, 0] - ax
        ey = C[(e + 1) % nc, 1] - ay
        for r in range(cnt):
            tmp[r, 0] = out[r, 0]
            tmp[r, 1] = out[r, 1]
        k = 0
        for r in range(cnt):
            px = tmp[r, 0]
            py = tmp[r, 1]
            qx = tmp[(r + 1) % cnt, 0]
            qy = tmp[(r + 1) % cnt, 1]
            sp = ex * (py - ay) - ey * (px - ax)
            sq = ex * (qy - ay) - ey * (qx - ax)
            if sp >= 0.0 and k < out.shape[0]:
                out[k, 0] = px
                out[k, 1] = py
                k += 1
            if (sp >= 0.0) != (sq >= 0.0) and k < out.shape[0]:
                t = sp / (sp - sq)
                out[k, 0] = px + t * (qx - px)
                out[k, 1] = py + t * (qy - py)
                k += 1
        cnt = k
    return cnt


@njit(cache=True)
def _polygon_moments(P, m):
    """Area, centroid (gx, gy) and the second moments int x^2, int x y, int y^2 (about the origin)
    of the counter-clockwise polygon P (m points)."""
    a = 0.0
    gx = 0.0
    gy = 0.0
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for r in range(m):
        s = (r + 1) % m
        x0 = P[r, 0]
        y0 = P[r, 1]
        x1 = P[s, 0]
        y1 = P[s, 1]
        cr = x0 * y1 - x1 * y0
        a += cr
        gx += (x0 + x1) * cr
        gy += (y0 + y1) * cr
        sxx += (x0 * x0 + x0 * x1 + x1 * x1) * cr
        syy += (y0 * y0 + y0 * y1 + y1 * y1) * cr
        sxy += (x0 * y1 + 2.0 * x0 * y0 + 2.0 * x1 * y1 + x1 * y0) * cr
    a *= 0.5
    if a <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return a, gx / (6.0 * a), gy / (6.0 * a), sxx / 12.0, sxy / 24.0, syy / 12.0


@njit(cache=True)
def _interval(P, m, u0, u1, lo, hi):
    """[lo, hi] narrowed to where the line ``s (u0, u1)`` through the contact point (the origin)
    stays on the feature P (m plane points): a point feature (curved both ways) does not narrow
    it; a segment (curved across, straight along) ends at the planes normal to it through its
    ends; a polygon (a flat face) at its rim (the chord through the origin)."""
    if m < 2:
        return lo, hi
    if m == 2:
        d0 = P[1, 0] - P[0, 0]
        d1 = P[1, 1] - P[0, 1]
        ln = math.sqrt(d0 * d0 + d1 * d1)
        if ln == 0.0:
            return lo, hi
        d0 /= ln
        d1 /= ln
        cs = u0 * d0 + u1 * d1
        if abs(cs) < 1e-9:
            return lo, hi
        a = (P[0, 0] * d0 + P[0, 1] * d1) / cs
        b = (P[1, 0] * d0 + P[1, 1] * d1) / cs
        return max(lo, min(a, b)), min(hi, max(a, b))
    for r in range(m):
        s = (r + 1) % m
        g0 = P[s, 0] - P[r, 0]
        g1 = P[s, 1] - P[r, 1]
        ge = g0 * u1 - g1 * u0  # cross(g, u): the edge's inside is cross(g, p - P_r) >= 0
        ga = g0 * P[r, 1] - g1 * P[r, 0]
        if ge > 1e-12 * (abs(g0) + abs(g1)):
            lo = max(lo, ga / ge)
        elif ge < -1e-12 * (abs(g0) + abs(g1)):
            hi = min(hi, ga / ge)
    return lo, hi


@njit(cache=True)
def contact_resistance(k1, h1, x1, R1, k2, h2, x2, R2, wall, Rp, n, c, h0, mu, hc, hmin, re, tol, S):
    """``(zeta_n, zeta_t, p0, p1, p2)`` of one contact (module docstring)."""
    if h0 >= hc:
        return 0.0, 0.0, c[0], c[1], c[2]
    F1, F2, pb, P1, P2, Q, T = S
    (a0, a1, a2), (b0, b1, b2) = _plane_axes(n[0], n[1], n[2])
    t1 = np.array([a0, a1, a2])
    t2 = np.array([b0, b1, b2])
    m1 = _feature(k1, h1, x1, R1, n, tol, F1, pb)
    K = np.zeros(3)
    _add_feature_curvature(k1, h1, x1, R1, m1, F1, n, t1, t2, re, K)
    _project(F1, m1, c, t1, t2, P1, _DISC_AREA_FIX if (k1 == CYLINDER and m1 >= 3) else 1.0)
    m2 = 0
    if wall == WALL_NONE:
        mn = -n
        m2 = _feature(k2, h2, x2, R2, mn, tol, F2, pb)
        _add_feature_curvature(k2, h2, x2, R2, m2, F2, mn, t1, t2, re, K)
        _project(F2, m2, c, t1, t2, P2, _DISC_AREA_FIX if (k2 == CYLINDER and m2 >= 3) else 1.0)
    elif wall == WALL_PIPE:
        # the concave wall: curvature -1/Rp along the azimuth z x n (n is radial)
        u0, u1 = _in_plane(-n[1], n[0], 0.0, t1, t2)
        _add_dir(K, u0, u1, -1.0 / Rp)
    he = max(h0, hmin)
    if m1 >= 3 and (m2 >= 3 or wall != WALL_NONE):
        # flat against flat: the patch where the faces overlap (a wall: the whole face)
        if wall == WALL_NONE:
            np_ = _clip(P1, m1, P2, m2, Q, T)
        else:
            np_ = m1
            for r in range(m1):
                Q[r, 0] = P1[r, 0]
                Q[r, 1] = P1[r, 1]
        area, gx, gy, sxx, sxy, syy = _polygon_moments(Q, np_)
        if area <= 1e-12:
            return 0.0, 0.0, c[0], c[1], c[2]
        ip = sxx + syy - area * (gx * gx + gy * gy)
        # gap H + xi K xi / 2 over the patch (K from the pipe wall only): smallest h0 at a vertex
        qmin = 0.0
        for r in range(np_):
            qmin = min(qmin, 0.5 * (K[0] * Q[r, 0] ** 2 + 2.0 * K[1] * Q[r, 0] * Q[r, 1] + K[2] * Q[r, 1] ** 2))
        hm = -qmin + 0.5 * (K[0] * sxx + 2.0 * K[1] * sxy + K[2] * syy) / area  # mean gap minus h0
        zn = plate_squeeze(mu, area, ip, hm + he) - plate_squeeze(mu, area, ip, hm + hc)
        zt = plate_shear(mu, area, hm + he) - plate_shear(mu, area, hm + hc)
        return max(zn, 0.0), max(zt, 0.0), c[0] + gx * t1[0] + gy * t2[0], c[1] + gx * t1[1] + gy * t2[1], \
            c[2] + gx * t1[2] + gy * t2[2]
    # curved: principal curvatures kx >= ky of the gap and the soft direction (e0, e1)
    tr = 0.5 * (K[0] + K[2])
    dd = math.sqrt(0.25 * (K[0] - K[2]) ** 2 + K[1] * K[1])
    kx = tr + dd
    ky = tr - dd
    if kx <= 1e-12:
        return 0.0, 0.0, c[0], c[1], c[2]
    if abs(K[1]) > 1e-14 * kx:
        e0 = K[1]
        e1 = ky - K[0]
        le = math.sqrt(e0 * e0 + e1 * e1)
        e0 /= le
        e1 /= le
    elif K[0] <= K[2]:
        e0, e1 = 1.0, 0.0
    else:
        e0, e1 = 0.0, 1.0
    sa = -math.inf
    sb = math.inf
    sa, sb = _interval(P1, m1, e0, e1, sa, sb)
    if wall == WALL_NONE:
        sa, sb = _interval(P2, m2, e0, e1, sa, sb)
    if sb <= sa:
        return 0.0, 0.0, c[0], c[1], c[2]
    if ky <= 1e-9 * kx and (math.isinf(sa) or math.isinf(sb)):
        # a film open along y needs finite ends there (only a rim against the pipe wall): the
        # width over which a gap of curvature kx rises by the cutoff
        w = 2.0 * math.sqrt(2.0 * hc / kx)
        sa = max(sa, -w)
        sb = min(sb, w)
    H = h0
    if ky < 0.0:  # the film is thinnest at the far end of the overlap
        H = h0 - 0.5 * ky * max(sa * sa, sb * sb)
    zn = curved_squeeze(mu, kx, ky, H - h0 + he, sa, sb) - curved_squeeze(mu, kx, ky, H - h0 + hc, sa, sb)
    return max(zn, 0.0), 0.0, c[0], c[1], c[2]
