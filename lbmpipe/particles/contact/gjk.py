"""GJK (Gilbert-Johnson-Keerthi): closest points of two convex bodies, or that they overlap."""

from __future__ import annotations

import math

from numba import njit

from .support import _dot, support3

GJK_MAX_ITER = 128
GJK_REL_TOL = 1e-9

# Status codes of _gjk
_SEPARATED = 0
_INTERSECTING = 1
_FAR = 2


# ------------------------------------------------------------------------------------------------
# GJK: closest point of a simplex to the origin (Ericson 5.1), reducing the simplex in place.
# Nothing here allocates: these run ~20 times per pair and per narrow-phase call, and they are
# inlined (numba IR) into GJK, since a call with array arguments costs more than their arithmetic.


@njit(cache=True, inline="always")
def _keep(W, WA, WB, lam, mask):
    """Compact the rows whose bit is set in ``mask`` to the front, in ascending order (so no row
    is overwritten before it is moved). Returns their number."""
    r = 0
    for s in range(4):
        if mask & (1 << s):
            if s != r:
                for k in range(3):
                    W[r, k] = W[s, k]
                    WA[r, k] = WA[s, k]
                    WB[r, k] = WB[s, k]
                lam[r] = lam[s]
            r += 1
    return r


@njit(cache=True, inline="always")
def _closest_triangle(a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """Barycentric weights (tuple of 3) of the point of triangle abc closest to the origin. The
    vertices come as scalars: rows of the simplex passed as array views cost a reference count
    each, more than the arithmetic here (GJK calls this up to four times per iteration)."""
    ab0 = b0 - a0
    ab1 = b1 - a1
    ab2 = b2 - a2
    ac0 = c0 - a0
    ac1 = c1 - a1
    ac2 = c2 - a2
    d1 = -(ab0 * a0 + ab1 * a1 + ab2 * a2)
    d2 = -(ac0 * a0 + ac1 * a1 + ac2 * a2)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    d3 = -(ab0 * b0 + ab1 * b1 + ab2 * b2)
    d4 = -(ac0 * b0 + ac1 * b1 + ac2 * b2)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0
    d5 = -(ab0 * c0 + ab1 * c1 + ab2 * c2)
    d6 = -(ac0 * c0 + ac1 * c1 + ac2 * c2)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t
    den = va + vb + vc
    if not den > 0.0:
        # degenerate (collinear) triangle: best of the three edges
        best = 1e300
        r0 = 1.0
        r1 = 0.0
        r2 = 0.0
        for e in range(3):
            if e == 0:
                p0, p1, p2, q0, q1, q2 = a0, a1, a2, b0, b1, b2
            elif e == 1:
                p0, p1, p2, q0, q1, q2 = b0, b1, b2, c0, c1, c2
            else:
                p0, p1, p2, q0, q1, q2 = c0, c1, c2, a0, a1, a2
            dx = q0 - p0
            dy = q1 - p1
            dz = q2 - p2
            ll = dx * dx + dy * dy + dz * dz
            t = 0.0
            if ll > 0.0:
                t = -(p0 * dx + p1 * dy + p2 * dz) / ll
                t = min(1.0, max(0.0, t))
            px = p0 + t * dx
            py = p1 + t * dy
            pz = p2 + t * dz
            dd = px * px + py * py + pz * pz
            if dd < best:
                best = dd
                if e == 0:
                    r0, r1, r2 = 1.0 - t, t, 0.0
                elif e == 1:
                    r0, r1, r2 = 0.0, 1.0 - t, t
                else:
                    r0, r1, r2 = t, 0.0, 1.0 - t
        return r0, r1, r2
    inv = 1.0 / den
    v = vb * inv
    w = vc * inv
    return 1.0 - v - w, v, w


@njit(cache=True, inline="always")
def _simplex_closest(W, WA, WB, n, lam, v):
    """Closest point ``v`` of the simplex W[0..n-1] to the origin; reduces the simplex to the
    vertices with non-zero weight (stored first, weights in ``lam``). Returns the new size, or 4
    if the origin is inside the tetrahedron."""
    if n == 1:
        lam[0] = 1.0
        v[0], v[1], v[2] = W[0, 0], W[0, 1], W[0, 2]
        return 1
    if n == 2:
        dx = W[1, 0] - W[0, 0]
        dy = W[1, 1] - W[0, 1]
        dz = W[1, 2] - W[0, 2]
        ll = dx * dx + dy * dy + dz * dz
        t = 0.0
        if ll > 0.0:
            t = -(W[0, 0] * dx + W[0, 1] * dy + W[0, 2] * dz) / ll
        if t <= 0.0:
            lam[0] = 1.0
            v[0], v[1], v[2] = W[0, 0], W[0, 1], W[0, 2]
            return 1
        if t >= 1.0:
            lam[1] = 1.0
            _keep(W, WA, WB, lam, 2)
            v[0], v[1], v[2] = W[0, 0], W[0, 1], W[0, 2]
            return 1
        lam[0] = 1.0 - t
        lam[1] = t
        for k in range(3):
            v[k] = W[0, k] + t * (W[1, k] - W[0, k])
        return 2
    if n == 3:
        r0, r1, r2 = _closest_triangle(W[0, 0], W[0, 1], W[0, 2], W[1, 0], W[1, 1], W[1, 2], W[2, 0], W[2, 1], W[2, 2])
        mask = 0
        if r0 > 0.0:
            lam[0] = r0
            mask |= 1
        if r1 > 0.0:
            lam[1] = r1
            mask |= 2
        if r2 > 0.0:
            lam[2] = r2
            mask |= 4
        m = _keep(W, WA, WB, lam, mask)
        for k in range(3):
            v[k] = 0.0
            for r in range(m):
                v[k] += lam[r] * W[r, k]
        return m
    # tetrahedron: test the origin against each face (opposite vertex o)
    best = 1e300
    bestf = -1
    b0 = 0.0
    b1 = 0.0
    b2 = 0.0
    for f in range(4):
        i0 = (f + 1) % 4
        i1 = (f + 2) % 4
        i2 = (f + 3) % 4
        e10 = W[i1, 0] - W[i0, 0]
        e11 = W[i1, 1] - W[i0, 1]
        e12 = W[i1, 2] - W[i0, 2]
        e20 = W[i2, 0] - W[i0, 0]
        e21 = W[i2, 1] - W[i0, 1]
        e22 = W[i2, 2] - W[i0, 2]
        n0 = e11 * e22 - e12 * e21
        n1 = e12 * e20 - e10 * e22
        n2 = e10 * e21 - e11 * e20
        sp = -(n0 * W[i0, 0] + n1 * W[i0, 1] + n2 * W[i0, 2])
        sd = n0 * (W[f, 0] - W[i0, 0]) + n1 * (W[f, 1] - W[i0, 1]) + n2 * (W[f, 2] - W[i0, 2])
        ee1 = e10 * e10 + e11 * e11 + e12 * e12
        ee2 = e20 * e20 + e21 * e21 + e22 * e22
        outside = sp * sd < 0.0 or sd * sd <= 1e-24 * (ee1 * ee2 + 1e-300)
        if not outside:
            continue
        r0, r1, r2 = _closest_triangle(W[i0, 0], W[i0, 1], W[i0, 2], W[i1, 0], W[i1, 1], W[i1, 2], W[i2, 0], W[i2, 1],
                                        W[i2, 2])
        px = r0 * W[i0, 0] + r1 * W[i1, 0] + r2 * W[i2, 0]
        py = r0 * W[i0, 1] + r1 * W[i1, 1] + r2 * W[i2, 1]
        pz = r0 * W[i0, 2] + r1 * W[i1, 2] + r2 * W[i2, 2]
        dd = px * px + py * py + pz * pz
        if dd < best:
            best = dd
            bestf = f
            b0, b1, b2 = r0, r1, r2
    if bestf < 0:
        return 4
    # weights by row; the face's opposite row gets none
    mask = 0
    for r in range(4):
        wr = 0.0
        if r == (bestf + 1) % 4:
            wr = b0
        elif r == (bestf + 2) % 4:
            wr = b1
        elif r == (bestf + 3) % 4:
            wr = b2
        if wr > 0.0:
            lam[r] = wr
            mask |= 1 << r
    m = _keep(W, WA, WB, lam, mask)
    for k in range(3):
        v[k] = 0.0
        for r in range(m):
            v[k] += lam[r] * W[r, k]
    return m


@njit(cache=True)
def _gjk(k1, h1, x1, R1, c1, k2, h2, x2, R2, c2, scale, max_gap, W, WA, WB, lam, pa, pb, v):
    """GJK on D = A - B. Returns (status, dist, n): separated (dist, witnesses pa/pb, v = pa - pb),
    intersecting (simplex W[0..n-1] holds the origin, for EPA) or far (dist is a lower bound
    greater than max_gap)."""
    for k in range(3):
        v[k] = x1[k] - x2[k]
    if _dot(v, v) <= (1e-12 * scale) ** 2:
        v[0], v[1], v[2] = scale, 0.0, 0.0
    return _gjk_from(k1, h1, x1, R1, c1, k2, h2, x2, R2, c2, scale, max_gap, GJK_REL_TOL, W, WA, WB, lam, pa, pb, v)


@njit(cache=True)
def _gjk_from(k1, h1, x1, R1, c1, k2, h2, x2, R2, c2, scale, max_gap, rel_tol, W, WA, WB, lam, pa, pb, v):
    """``_gjk`` from the search direction in ``v`` (nonzero), stopping when the gap is bracketed
    to ``rel_tol * scale``. ``benchmarks/collision_floor.py`` starts it from the converged normal
    to time the fewest iterations GJK can take on a contact."""
    n = 0
    tol = rel_tol * scale
    for _it in range(GJK_MAX_ITER):
        sa0, sa1, sa2 = support3(k1, h1, x1, R1, c1, -v[0], -v[1], -v[2])
        sb0, sb1, sb2 = support3(k2, h2, x2, R2, c2, v[0], v[1], v[2])
        w0 = sa0 - sb0
        w1 = sa1 - sb1
        w2 = sa2 - sb2
        vw = v[0] * w0 + v[1] * w1 + v[2] * w2
        vv = _dot(v, v)
        if n > 0:
            if vw > 0.0 and vw * vw > max_gap * max_gap * vv:
                return _FAR, vw / math.sqrt(vv), n
            if vv - vw <= tol * math.sqrt(vv):
                break
            dup = False
            for r in range(n):
                dx = W[r, 0] - w0
                dy = W[r, 1] - w1
                dz = W[r, 2] - w2
                if dx * dx + dy * dy + dz * dz <= (1e-14 * scale) ** 2:
                    dup = True
            if dup:
                break
        W[n, 0], W[n, 1], W[n, 2] = w0, w1, w2
        WA[n, 0], WA[n, 1], WA[n, 2] = sa0, sa1, sa2
        WB[n, 0], WB[n, 1], WB[n, 2] = sb0, sb1, sb2
        n += 1
        n = _simplex_closest(W, WA, WB, n, lam, v)
        if n == 4 or _dot(v, v) <= (1e-10 * scale) ** 2:
            return _INTERSECTING, 0.0, n
    for k in range(3):
        pa[k] = 0.0
        pb[k] = 0.0
        for r in range(n):
            pa[k] += lam[r] * WA[r, k]
            pb[k] += lam[r] * WB[r, k]
    return _SEPARATED, math.sqrt(_dot(v, v)), n
