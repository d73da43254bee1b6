"""Narrow phase: signed gap, normal and contact point of two bodies (``body_contact``)."""

from __future__ import annotations

import math

from numba import njit

from ..shapes import CYLINDER, SPHERE, bounding_radius
from .support import _dot, support3
from .gjk import _FAR, _INTERSECTING, _SEPARATED, _gjk
from .epa import _epa
from .features import _F_POINT, _F_SIDE, _cyl_feature_kind, _manifold_point, _side_side_patch
from .scratch import WS_HINT, WS_WON, _WS_BASE, _gjk_scratch, new_scratch
from .cylinders import _cylinder_gap, cylinders_overlap_exact


# ------------------------------------------------------------------------------------------------
# narrow phase, public kernel


@njit(cache=True)
def body_contact(k1, h1, x1, R1, k2, h2, x2, R2, max_gap, manifold_tol, nrm, c):
    """Signed gap between body 1 (kind k1, half-extents h1, centre x1, rotation matrix R1
    body->lab) and body 2; writes the unit normal from 1 to 2 into ``nrm`` and the contact point
    into ``c`` (both (3,)). If the gap exceeds ``max_gap`` the function may stop early and return
    a lower bound of the gap (> max_gap); ``nrm`` and ``c`` are then only approximate."""
    return body_contact_ws(k1, h1, x1, R1, k2, h2, x2, R2, max_gap, manifold_tol, nrm, c, new_scratch())


@njit(cache=True)
def body_contact_ws(k1, h1, x1, R1, k2, h2, x2, R2, max_gap, manifold_tol, nrm, c, ws):
    """``body_contact`` with caller-provided scratch ``ws`` (``new_scratch()``). Callers that need
    only whether two bodies overlap ask ``bodies_overlap_ws``, which skips EPA and the contact
    point. ``ws[WS_HINT]`` is the exact cylinder path's candidate to try first (``_cylinder_gap``'s
    ``first``; -1: none; used once), and ``ws[WS_WON]`` the certified one after the call (-1:
    none, or not two cylinders): the narrow phase keeps it per pair from one step to the next.
    A wrong hint costs one candidate and changes no result."""
    first = int(ws[WS_HINT])
    ws[WS_HINT] = -1.0
    ws[WS_WON] = -1.0
    if k1 == CYLINDER and k2 == CYLINDER:
        gap, pa, pb, won = _cylinder_gap(h1, x1, R1, h2, x2, R2, first)
        ws[WS_WON] = won
        if gap >= 0.0:
            for k in range(3):
                nrm[k] = (pb[k] - pa[k]) / gap
        if gap >= 0.0 and gap > max_gap:
            # beyond max_gap the contact point need only be approximate: no patch (a gap of -1,
            # uncertified, goes to GJK/EPA whatever max_gap is)
            for k in range(3):
                c[k] = 0.5 * (pa[k] + pb[k])
            return gap
        if gap >= 0.0:
            # Where a feature is a single rim point, the patch is that point, and where both are
            # side segments, the middle of their overlap: what _manifold_point returns, written
            # out here on scalars, since making its ten scratch views costs more than the contact
            # itself (these are 0.9 of the touching pairs of 244 dense cylinders)
            f1 = _cyl_feature_kind(h1, R1, nrm[0], nrm[1], nrm[2], manifold_tol)
            f2 = _cyl_feature_kind(h2, R2, -nrm[0], -nrm[1], -nrm[2], manifold_tol)
            b0 = 0.5 * (pa[0] + pb[0])
            b1 = 0.5 * (pa[1] + pb[1])
            b2 = 0.5 * (pa[2] + pb[2])
            if f1 == _F_SIDE and f2 == _F_SIDE:
                c[0], c[1], c[2] = _side_side_patch(h1, x1, R1, h2, x2, R2, nrm[0], nrm[1], nrm[2], b0, b1, b2,
                                                    manifold_tol)
                return gap
            p1 = f1 == _F_POINT
            p2 = f2 == _F_POINT
            if p1 or p2:
                if p1 and p2:
                    c[0], c[1], c[2] = b0, b1, b2
                    return gap
                if p1:
                    q0, q1, q2 = support3(k1, h1, x1, R1, False, nrm[0], nrm[1], nrm[2])
                else:
                    q0, q1, q2 = support3(k2, h2, x2, R2, False, -nrm[0], -nrm[1], -nrm[2])
                q0 -= b0
                q1 -= b1
                q2 -= b2
                qn = q0 * nrm[0] + q1 * nrm[1] + q2 * nrm[2]
                c[0] = b0 + q0 - qn * nrm[0]
                c[1] = b1 + q1 - qn * nrm[1]
                c[2] = b2 + q2 - qn * nrm[2]
                return gap
            base = ws[_WS_BASE:_WS_BASE + 3]
            base[0], base[1], base[2] = b0, b1, b2
            _manifold_point(k1, h1, x1, R1, k2, h2, x2, R2, nrm, base, manifold_tol, c, ws)
            return gap
    rb1 = bounding_radius(k1, h1)
    rb2 = bounding_radius(k2, h2)
    scale = rb1 + rb2
    if k1 == SPHERE and k2 == SPHERE:
        dx = x2[0] - x1[0]
        dy = x2[1] - x1[1]
        dz = x2[2] - x1[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > 0.0:
            nrm[0], nrm[1], nrm[2] = dx / dist, dy / dist, dz / dist
        else:
            nrm[0], nrm[1], nrm[2] = 1.0, 0.0, 0.0
        gap = dist - h1[0] - h2[0]
        for k in range(3):
            c[k] = x1[k] + nrm[k] * (h1[0] + 0.5 * gap)
        return gap
    W, WA, WB, lam, pa, pb, v = _gjk_scratch(ws)
    base = ws[_WS_BASE:_WS_BASE + 3]
    # a sphere enters GJK as its centre; its radius is a margin subtracted afterwards
    c1 = k1 == SPHERE
    c2 = k2 == SPHERE
    margin = (h1[0] if c1 else 0.0) + (h2[0] if c2 else 0.0)
    if c1 or c2:
        st, dist, n = _gjk(k1, h1, x1, R1, c1, k2, h2, x2, R2, c2, scale, max_gap + margin, W, WA, WB, lam, pa, pb, v)
        if st == _FAR:
            lv = math.sqrt(_dot(v, v))
            for k in range(3):
                nrm[k] = -v[k] / lv
                c[k] = 0.5 * (x1[k] + x2[k])
            return dist - margin
        if st == _SEPARATED and dist > 1e-9 * scale:
            for k in range(3):
                nrm[k] = -v[k] / dist
            if c1:
                for k in range(3):
                    pa[k] += h1[0] * nrm[k]
            if c2:
                for k in range(3):
                    pb[k] -= h2[0] * nrm[k]
            for k in range(3):
                c[k] = 0.5 * (pa[k] + pb[k])
            return dist - margin
        # the centre is inside the other body: fall through to the full shapes
    st, dist, n = _gjk(k1, h1, x1, R1, False, k2, h2, x2, R2, False, scale, max_gap, W, WA, WB, lam, pa, pb, v)
    if st == _FAR:
        lv = math.sqrt(_dot(v, v))
        for k in range(3):
            nrm[k] = -v[k] / lv
            c[k] = 0.5 * (x1[k] + x2[k])
        return dist
    gap = 0.0
    if st == _SEPARATED:
        for k in range(3):
            nrm[k] = -v[k] / dist
        gap = dist
    else:
        depth = _epa(k1, h1, x1, R1, k2, h2, x2, R2, scale, W, WA, WB, n, nrm, pa, pb)
        if depth < 0.0:
            # degenerate (touching with zero volume): centre line as normal, zero gap
            dx = x2[0] - x1[0]
            dy = x2[1] - x1[1]
            dz = x2[2] - x1[2]
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            if ln == 0.0:
                dx, ln = 1.0, 1.0
            nrm[0], nrm[1], nrm[2] = dx / ln, dy / ln, dz / ln
            for k in range(3):
                pa[k] = 0.5 * (x1[k] + x2[k])
                pb[k] = pa[k]
            depth = 0.0
        gap = -depth
    for k in range(3):
        base[k] = 0.5 * (pa[k] + pb[k])
    if c1 or c2:
        for k in range(3):
            c[k] = base[k]
    else:
        _manifold_point(k1, h1, x1, R1, k2, h2, x2, R2, nrm, base, manifold_tol, c, ws)
    return gap


@njit(cache=True)
def bodies_overlap_ws(k1, h1, x1, R1, k2, h2, x2, R2, ws):
    """Do the two bodies overlap (``body_contact_ws`` would give a negative gap)? GJK alone,
    stopped at the first separating direction, and no EPA: the time-of-impact bisection asks only
    this. It differs from the sign of ``body_contact_ws`` only for bodies touching with zero
    overlap volume (EPA's degenerate case, gap 0 there, an overlap here)."""
    if k1 == SPHERE and k2 == SPHERE:
        dx = x2[0] - x1[0]
        dy = x2[1] - x1[1]
        dz = x2[2] - x1[2]
        return math.sqrt(dx * dx + dy * dy + dz * dz) - h1[0] - h2[0] < 0.0
    scale = bounding_radius(k1, h1) + bounding_radius(k2, h2)
    if k1 == CYLINDER and k2 == CYLINDER:
        ov = cylinders_overlap_exact(h1, x1, R1, h2, x2, R2)
        if ov >= 0:
            return ov == 1
    W, WA, WB, lam, pa, pb, v = _gjk_scratch(ws)
    c1 = k1 == SPHERE
    c2 = k2 == SPHERE
    if c1 or c2:
        margin = (h1[0] if c1 else 0.0) + (h2[0] if c2 else 0.0)
        st, dist, n = _gjk(k1, h1, x1, R1, c1, k2, h2, x2, R2, c2, scale, margin, W, WA, WB, lam, pa, pb, v)
        if st == _FAR:
            return False
        if st == _SEPARATED and dist > 1e-9 * scale:
            return dist - margin < 0.0
    st, dist, n = _gjk(k1, h1, x1, R1, False, k2, h2, x2, R2, False, scale, 0.0, W, WA, WB, lam, pa, pb, v)
    return st == _INTERSECTING
