"""Contact features and the contact-patch centroid (the contact point where flat features meet)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..shapes import CUBE, SPHERE
from .support import DISC_SIDES
from .scratch import (_PATCH_POINTS, _WS_F1, _WS_F2, _WS_FB, _WS_MNEG, _WS_P1, _WS_P2, _WS_PTS, _WS_T1, _WS_T2, _WS_UV,
                      ws_rows)


# ------------------------------------------------------------------------------------------------
# contact features (for the contact-patch centroid)


# vertices of the 16-gon that stands for a cap disc in a contact patch (a table: trigonometry per
# vertex cost more than the rest of the patch)
_DISC_COS = np.array([math.cos(2.0 * math.pi * r / DISC_SIDES) for r in range(DISC_SIDES)])
_DISC_SIN = np.array([math.sin(2.0 * math.pi * r / DISC_SIDES) for r in range(DISC_SIDES)])


@njit(cache=True, inline="always")
def _unit_xy(a, b):
    """(a, b) / |(a, b)| and |(a, b)|; (1, 0) for the zero vector."""
    rho = math.sqrt(a * a + b * b)
    ux = 1.0
    uy = 0.0
    if rho > 0.0:
        ux = a / rho
        uy = b / rho
    return ux, uy, rho


@njit(cache=True)
def _feature(kind, h, x, R, n, tol, out, pb):
    """Lab points (rows of ``out``) of the face/edge/vertex of the body that is extreme along the
    unit lab direction ``n``, within ``tol`` of the extreme. Polygons are returned in cyclic
    order. Returns the number of points. ``pb``: scratch, (DISC_SIDES, 3)."""
    d0 = R[0, 0] * n[0] + R[1, 0] * n[1] + R[2, 0] * n[2]
    d1 = R[0, 1] * n[0] + R[1, 1] * n[1] + R[2, 1] * n[2]
    d2 = R[0, 2] * n[0] + R[1, 2] * n[1] + R[2, 2] * n[2]
    m = 0
    if kind == SPHERE:
        pb[0, 0], pb[0, 1], pb[0, 2] = h[0] * d0, h[0] * d1, h[0] * d2
        m = 1
    elif kind == CUBE:
        # tuples and a bit mask, not small arrays: this runs for every touching pair and step,
        # and three allocations cost more than the arithmetic
        dd = (d0, d1, d2)
        s = (h[0] if d0 >= 0.0 else -h[0], h[1] if d1 >= 0.0 else -h[1], h[2] if d2 >= 0.0 else -h[2])
        free = 0
        nfree = 0
        for k in range(3):
            if 2.0 * h[k] * abs(dd[k]) <= tol:
                free |= 1 << k
                nfree += 1
        if nfree == 3:
            # only for a body smaller than tol: keep the dominant axis fixed
            kk = 0
            for k in range(3):
                if abs(dd[k]) > abs(dd[kk]):
                    kk = k
            free &= ~(1 << kk)
            nfree = 2
        if nfree == 0:
            pb[0, 0], pb[0, 1], pb[0, 2] = s[0], s[1], s[2]
            m = 1
        elif nfree == 1:
            for k in range(3):
                pb[0, k] = s[k]
                pb[1, k] = s[k]
                if free & (1 << k):
                    pb[0, k] = -h[k]
                    pb[1, k] = h[k]
            m = 2
        else:
            a = -1
            b = -1
            for k in range(3):
                if free & (1 << k):
                    if a < 0:
                        a = k
                    else:
                        b = k
            sa_ = (-1.0, 1.0, 1.0, -1.0)
            sb_ = (-1.0, -1.0, 1.0, 1.0)
            for r in range(4):
                for k in range(3):
                    pb[r, k] = s[k]
                pb[r, a] = sa_[r] * h[a]
                pb[r, b] = sb_[r] * h[b]
            m = 4
    else:  # CYLINDER, axis = body z
        side, cap, _dr = _cyl_side_cap(h, d0, d1, d2, tol)
        if side and not cap:
            e0, e1 = _side_ends(h, x, R, n[0], n[1], n[2])
            out[0, 0], out[0, 1], out[0, 2] = e0
            out[1, 0], out[1, 1], out[1, 2] = e1
            return 2
        zs = h[2] if d2 >= 0.0 else -h[2]
        if cap:
            for r in range(DISC_SIDES):
                pb[r, 0] = h[0] * _DISC_COS[r]
                pb[r, 1] = h[0] * _DISC_SIN[r]
                pb[r, 2] = zs
            m = DISC_SIDES
        else:
            cx, cy, _dr = _unit_xy(d0, d1)
            pb[0, 0], pb[0, 1], pb[0, 2] = h[0] * cx, h[0] * cy, zs
            m = 1
    for r in range(m):
        for k in range(3):
            out[r, k] = x[k] + R[k, 0] * pb[r, 0] + R[k, 1] * pb[r, 1] + R[k, 2] * pb[r, 2]
    return m


@njit(cache=True, inline="always")
def _cyl_side_cap(h, d0, d1, d2, tol):
    """Is the feature of a cylinder extreme along the body-frame unit direction d its side (d
    within tol of normal to the axis), a cap (within tol of the axis), both (a body smaller than
    tol) or neither (a rim point)? Returns (side, cap, |d_xy|)."""
    dr = math.sqrt(d0 * d0 + d1 * d1)
    return 2.0 * h[2] * abs(d2) <= tol, 2.0 * h[0] * dr <= tol, dr


_F_POINT = 0
_F_SIDE = 1
_F_CAP = 2


@njit(cache=True, inline="always")
def _cyl_feature_kind(h, R, n0, n1, n2, tol):
    """Which feature of a cylinder is extreme along the lab direction n (``_feature``): a single
    rim point (_F_POINT), its side segment (_F_SIDE) or a cap (_F_CAP, also for a body smaller
    than tol, whose side and cap both are)."""
    d0 = R[0, 0] * n0 + R[1, 0] * n1 + R[2, 0] * n2
    d1 = R[0, 1] * n0 + R[1, 1] * n1 + R[2, 1] * n2
    d2 = R[0, 2] * n0 + R[1, 2] * n1 + R[2, 2] * n2
    side, cap, _dr = _cyl_side_cap(h, d0, d1, d2, tol)
    return _F_CAP if cap else (_F_SIDE if side else _F_POINT)


@njit(cache=True, inline="always")
def _side_ends(h, x, R, n0, n1, n2):
    """The two ends of the side segment of a cylinder extreme along the lab direction n (the
    feature ``_feature`` returns for a side)."""
    d0 = R[0, 0] * n0 + R[1, 0] * n1 + R[2, 0] * n2
    d1 = R[0, 1] * n0 + R[1, 1] * n1 + R[2, 1] * n2
    cx, cy, _dr = _unit_xy(d0, d1)
    s0 = h[0] * cx
    s1 = h[0] * cy
    lo = -h[2]
    hi = h[2]
    return ((x[0] + R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * lo,
             x[1] + R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * lo,
             x[2] + R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * lo),
            (x[0] + R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * hi,
             x[1] + R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * hi,
             x[2] + R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * hi))


@njit(cache=True, inline="always")
def _in_segment(px, py, a0, a1, b0, b1, tol):
    # is (px, py) within tol of the segment a-b (``_in_poly`` of a polygon of 2 points)
    dx = b0 - a0
    dy = b1 - a1
    ll = dx * dx + dy * dy
    t = 0.0
    if ll > 0.0:
        t = ((px - a0) * dx + (py - a1) * dy) / ll
        t = min(1.0, max(0.0, t))
    ex = a0 + t * dx - px
    ey = a1 + t * dy - py
    return ex * ex + ey * ey <= tol * tol


@njit(cache=True)
def _side_side_patch(h1, x1, R1, h2, x2, R2, n0, n1, n2, b0, b1, b2, tol):
    """``_manifold_point`` for two cylinder sides (both features segments), on scalars: the
    middle of the two points farthest apart among the segments' ends that lie on the other
    segment (within tol) and their crossing, in the plane normal to n through the witness
    midpoint b. The same operations in the same order as the general path, so the same bits
    (a test pins the two together); b itself where the segments do not meet."""
    e10, e11 = _side_ends(h1, x1, R1, n0, n1, n2)
    e20, e21 = _side_ends(h2, x2, R2, -n0, -n1, -n2)
    (t10, t11, t12), (t20, t21, t22) = _plane_axes(n0, n1, n2)
    # _to_plane: the four ends in the plane
    pts = ((e10[0] - b0, e10[1] - b1, e10[2] - b2), (e11[0] - b0, e11[1] - b1, e11[2] - b2),
           (e20[0] - b0, e20[1] - b1, e20[2] - b2), (e21[0] - b0, e21[1] - b1, e21[2] - b2))
    P = ((pts[0][0] * t10 + pts[0][1] * t11 + pts[0][2] * t12, pts[0][0] * t20 + pts[0][1] * t21 + pts[0][2] * t22),
         (pts[1][0] * t10 + pts[1][1] * t11 + pts[1][2] * t12, pts[1][0] * t20 + pts[1][1] * t21 + pts[1][2] * t22),
         (pts[2][0] * t10 + pts[2][1] * t11 + pts[2][2] * t12, pts[2][0] * t20 + pts[2][1] * t21 + pts[2][2] * t22),
         (pts[3][0] * t10 + pts[3][1] * t11 + pts[3][2] * t12, pts[3][0] * t20 + pts[3][1] * t21 + pts[3][2] * t22))
    # _patch_centroid of two segments: ends on the other segment, in order, then the crossing
    use = (_in_segment(P[0][0], P[0][1], P[2][0], P[2][1], P[3][0], P[3][1], tol),
           _in_segment(P[1][0], P[1][1], P[2][0], P[2][1], P[3][0], P[3][1], tol),
           _in_segment(P[2][0], P[2][1], P[0][0], P[0][1], P[1][0], P[1][1], tol),
           _in_segment(P[3][0], P[3][1], P[0][0], P[0][1], P[1][0], P[1][1], tol))
    ax_ = P[0][0]
    ay_ = P[0][1]
    bx = P[1][0] - ax_
    by = P[1][1] - ay_
    cx = P[2][0]
    cy = P[2][1]
    dx = P[3][0] - cx
    dy = P[3][1] - cy
    den = bx * dy - by * dx
    cross = False
    qx = 0.0
    qy = 0.0
    if not abs(den) <= 1e-12 * (abs(bx) + abs(by)) * (abs(dx) + abs(dy)):
        t = ((cx - ax_) * dy - (cy - ay_) * dx) / den
        u = ((cx - ax_) * by - (cy - ay_) * bx) / den
        if -1e-9 <= t <= 1.0 + 1e-9 and -1e-9 <= u <= 1.0 + 1e-9:
            cross = True
            qx = ax_ + t * bx
            qy = ay_ + t * by
    # _extreme_midpoint over the collected points, in the same order (first strict maximum)
    X = (P[0][0], P[1][0], P[2][0], P[3][0], qx)
    Y = (P[0][1], P[1][1], P[2][1], P[3][1], qy)
    on = (use[0], use[1], use[2], use[3], cross)
    bi = -1
    bj = -1
    bd = -1.0
    for r in range(5):
        if not on[r]:
            continue
        if bi < 0:
            bi = r
            bj = r
        for s in range(r + 1, 5):
            if not on[s]:
                continue
            dd = (X[r] - X[s]) ** 2 + (Y[r] - Y[s]) ** 2
            if dd > bd:
                bd = dd
                bi = r
                bj = s
    if bi < 0:
        return b0, b1, b2
    u = 0.5 * (X[bi] + X[bj])
    v = 0.5 * (Y[bi] + Y[bj])
    return b0 + u * t10 + v * t20, b1 + u * t11 + v * t21, b2 + u * t12 + v * t22


@njit(cache=True)
def _in_poly(px, py, P, m, tol):
    # P: 2-D convex polygon (counter-clockwise if m >= 3); closed test with tolerance
    if m == 1:
        return (px - P[0, 0]) ** 2 + (py - P[0, 1]) ** 2 <= tol * tol
    if m == 2:
        return _in_segment(px, py, P[0, 0], P[0, 1], P[1, 0], P[1, 1], tol)
    for r in range(m):
        s = (r + 1) % m
        dx = P[s, 0] - P[r, 0]
        dy = P[s, 1] - P[r, 1]
        cr = dx * (py - P[r, 1]) - dy * (px - P[r, 0])
        # the edge's length only matters outside its line (cr < 0): no square root per edge
        # for the points inside, most of those tested against a cap's 16-gon
        if cr < 0.0 and cr < -tol * math.sqrt(dx * dx + dy * dy):
            return False
    return True


@njit(cache=True)
def _patch_centroid(P1, m1, P2, m2, tol, out, pts):
    """In-plane centroid of the intersection of two convex 2-D features (points, segments or
    polygons). Returns False if they do not meet (within tol). ``pts``: scratch,
    (_PATCH_POINTS, 2)."""
    cap = pts.shape[0]
    k = 0
    for r in range(m1):
        if k < cap and _in_poly(P1[r, 0], P1[r, 1], P2, m2, tol):
            pts[k, 0], pts[k, 1] = P1[r, 0], P1[r, 1]
            k += 1
    for r in range(m2):
        if k < cap and _in_poly(P2[r, 0], P2[r, 1], P1, m1, tol):
            pts[k, 0], pts[k, 1] = P2[r, 0], P2[r, 1]
            k += 1
    ne1 = 0 if m1 == 1 else (1 if m1 == 2 else m1)
    ne2 = 0 if m2 == 1 else (1 if m2 == 2 else m2)
    for r in range(ne1):
        ax = P1[r, 0]
        ay = P1[r, 1]
        bx = P1[(r + 1) % m1, 0] - ax
        by = P1[(r + 1) % m1, 1] - ay
        for s in range(ne2):
            cx = P2[s, 0]
            cy = P2[s, 1]
            dx = P2[(s + 1) % m2, 0] - cx
            dy = P2[(s + 1) % m2, 1] - cy
            den = bx * dy - by * dx
            if abs(den) <= 1e-12 * (abs(bx) + abs(by)) * (abs(dx) + abs(dy)):
                continue
            t = ((cx - ax) * dy - (cy - ay) * dx) / den
            u = ((cx - ax) * by - (cy - ay) * bx) / den
            if -1e-9 <= t <= 1.0 + 1e-9 and -1e-9 <= u <= 1.0 + 1e-9 and k < cap:
                pts[k, 0] = ax + t * bx
                pts[k, 1] = ay + t * by
                k += 1
    if k == 0:
        return False
    if m1 <= 2 and m2 <= 2:
        # points and segments meet in a point or a segment: skip the hull (and its allocations)
        return _extreme_midpoint(pts, k, out)
    # centroid of the convex hull of the collected points: sort by angle about their mean
    mx = 0.0
    my = 0.0
    for r in range(k):
        mx += pts[r, 0]
        my += pts[r, 1]
    mx /= k
    my /= k
    ang = np.empty(k)
    for r in range(k):
        ang[r] = math.atan2(pts[r, 1] - my, pts[r, 0] - mx)
    order = np.argsort(ang)
    area = 0.0
    gx = 0.0
    gy = 0.0
    for r in range(k):
        i = order[r]
        j = order[(r + 1) % k]
        x0 = pts[i, 0] - mx
        y0 = pts[i, 1] - my
        x1 = pts[j, 0] - mx
        y1 = pts[j, 1] - my
        cr = x0 * y1 - x1 * y0
        area += cr
        gx += (x0 + x1) * cr
        gy += (y0 + y1) * cr
    # the spread of the points sets what counts as a flat (degenerate) patch
    spread = 0.0
    for r in range(k):
        spread = max(spread, abs(pts[r, 0] - mx) + abs(pts[r, 1] - my))
    if abs(area) > 1e-9 * spread * spread and abs(area) > 0.0:
        out[0] = mx + gx / (3.0 * area)
        out[1] = my + gy / (3.0 * area)
        return True
    # points (nearly) on a line
    return _extreme_midpoint(pts, k, out)


@njit(cache=True, inline="always")
def _extreme_midpoint(pts, k, out):
    """Midpoint of the two points farthest apart among the first k rows of pts."""
    bi = 0
    bj = 0
    bd = -1.0
    for r in range(k):
        for s in range(r + 1, k):
            dd = (pts[r, 0] - pts[s, 0]) ** 2 + (pts[r, 1] - pts[s, 1]) ** 2
            if dd > bd:
                bd = dd
                bi = r
                bj = s
    out[0] = 0.5 * (pts[bi, 0] + pts[bj, 0])
    out[1] = 0.5 * (pts[bi, 1] + pts[bj, 1])
    return True


@njit(cache=True, inline="always")
def _plane_axes(n0, n1, n2):
    """Unit axes t1 = n x e / |n x e| (e the lab axis least aligned with n) and t2 = n x t1 of
    the plane normal to the unit vector n, as tuples."""
    ax = 0
    if abs(n1) < abs(n0):
        ax = 1
    if abs(n2) < abs((n0, n1)[ax]):
        ax = 2
    u0 = 1.0 if ax == 0 else 0.0
    u1 = 1.0 if ax == 1 else 0.0
    u2 = 1.0 if ax == 2 else 0.0
    t10 = n1 * u2 - n2 * u1
    t11 = n2 * u0 - n0 * u2
    t12 = n0 * u1 - n1 * u0
    l1 = math.sqrt(t10 * t10 + t11 * t11 + t12 * t12)
    t10 /= l1
    t11 /= l1
    t12 /= l1
    return (t10, t11, t12), (n1 * t12 - n2 * t11, n2 * t10 - n0 * t12, n0 * t11 - n1 * t10)


@njit(cache=True)
def _plane_basis(n, t1, t2):
    a, b = _plane_axes(n[0], n[1], n[2])
    t1[0], t1[1], t1[2] = a
    t2[0], t2[1], t2[2] = b


@njit(cache=True)
def _to_plane(pts3, m, base, t1, t2, P):
    for r in range(m):
        dx = pts3[r, 0] - base[0]
        dy = pts3[r, 1] - base[1]
        dz = pts3[r, 2] - base[2]
        P[r, 0] = dx * t1[0] + dy * t1[1] + dz * t1[2]
        P[r, 1] = dx * t2[0] + dy * t2[1] + dz * t2[2]
    if m >= 3:
        area = 0.0
        for r in range(m):
            s = (r + 1) % m
            area += P[r, 0] * P[s, 1] - P[s, 0] * P[r, 1]
        if area < 0.0:
            for r in range(m // 2):
                s = m - 1 - r
                a0, a1 = P[r, 0], P[r, 1]
                P[r, 0], P[r, 1] = P[s, 0], P[s, 1]
                P[s, 0], P[s, 1] = a0, a1


@njit(cache=True)
def _manifold_point(k1, h1, x1, R1, k2, h2, x2, R2, nrm, base, tol, out_c, ws):
    """Centroid of the contact patch (module docstring); ``base`` is the witness midpoint and
    fixes the coordinate along the normal. Leaves out_c = base if the features do not meet.
    ``ws``: the scratch of ``new_scratch`` (it runs for every touching pair and step: no
    allocations)."""
    f1 = ws_rows(ws, _WS_F1, DISC_SIDES, 3)
    f2 = ws_rows(ws, _WS_F2, DISC_SIDES, 3)
    pb = ws_rows(ws, _WS_FB, DISC_SIDES, 3)
    P1 = ws_rows(ws, _WS_P1, DISC_SIDES, 2)
    P2 = ws_rows(ws, _WS_P2, DISC_SIDES, 2)
    mneg = ws[_WS_MNEG:_WS_MNEG + 3]
    t1 = ws[_WS_T1:_WS_T1 + 3]
    t2 = ws[_WS_T2:_WS_T2 + 3]
    uv = ws[_WS_UV:_WS_UV + 2]
    pts = ws_rows(ws, _WS_PTS, _PATCH_POINTS, 2)
    m1 = _feature(k1, h1, x1, R1, nrm, tol, f1, pb)
    for k in range(3):
        mneg[k] = -nrm[k]
    m2 = _feature(k2, h2, x2, R2, mneg, tol, f2, pb)
    for k in range(3):
        out_c[k] = base[k]
    if m1 == 1 and m2 == 1:
        return
    _plane_basis(nrm, t1, t2)
    _to_plane(f1, m1, base, t1, t2, P1)
    _to_plane(f2, m2, base, t1, t2, P2)
    if m1 == 1:
        uv[0], uv[1] = P1[0, 0], P1[0, 1]
    elif m2 == 1:
        uv[0], uv[1] = P2[0, 0], P2[0, 1]
    else:
        if not _patch_centroid(P1, m1, P2, m2, tol, uv, pts):
            return
    for k in range(3):
        out_c[k] = base[k] + uv[0] * t1[k] + uv[1] * t2[k]
