"""Exact contact of two separated cylinders (closed forms and one-dimensional minimisations)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


# ------------------------------------------------------------------------------------------------
# exact contact of two separated cylinders: closed forms and one-dimensional minimisations,
# each result certified by the separating-axis bound (no iteration over a simplex)

# the certificate's tolerance, relative to the body size: the same as GJK's stopping rule
_EXACT_TOL = 1e-9
# the eight sample angles that start the rim minimisations
_RIM8_COS = np.array([math.cos(0.25 * math.pi * s) for s in range(8)])
_RIM8_SIN = np.array([math.sin(0.25 * math.pi * s) for s in range(8)])


@njit(cache=True, inline="always")
def _cyl_height(x0, x1, x2, e0, e1, e2, r, hl, n0, n1, n2):
    """Support height of a cylinder (centre x, unit axis e, radius r, half length hl) along the
    unit direction n: ``max_p n . p = n . x + hl |n . e| + r |n - (n . e) e|``. The last term as
    a norm, not ``sqrt(1 - (n . e)^2)``: along the axis that would turn a rounding error of 1e-16
    into 1e-8, above the certificate's tolerance."""
    b = e0 * n0 + e1 * n1 + e2 * n2
    t0 = n0 - b * e0
    t1 = n1 - b * e1
    t2 = n2 - b * e2
    return x0 * n0 + x1 * n1 + x2 * n2 + hl * abs(b) + r * math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)


@njit(cache=True, inline="always")
def _cyl_separation(X1, E1, r1, l1, X2, E2, r2, l2, n0, n1, n2):
    """Separation of two cylinders along the unit direction n (1 -> 2), from their support
    heights: a lower bound of the gap, and > 0 only if the plane normal to n separates them."""
    return -_cyl_height(X2[0], X2[1], X2[2], E2[0], E2[1], E2[2], r2, l2, -n0, -n1, -n2) \
        - _cyl_height(X1[0], X1[1], X1[2], E1[0], E1[1], E1[2], r1, l1, n0, n1, n2)


@njit(cache=True, inline="always")
def _certified_gap(X1, E1, r1, l1, X2, E2, r2, l2, a0, a1, a2, b0, b1, b2, tol):
    """The distance |b - a| of a point a of cylinder 1 and a point b of cylinder 2 is an upper
    bound of their gap; the separation of the two along n = (b - a)/|b - a| (support heights) is
    a lower bound. If the two agree within ``tol``, |b - a| is the gap: returned, else -1."""
    d0 = b0 - a0
    d1 = b1 - a1
    d2 = b2 - a2
    g = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if g <= tol:
        return -1.0
    n0 = d0 / g
    n1 = d1 / g
    n2 = d2 / g
    lower = _cyl_separation(X1, E1, r1, l1, X2, E2, r2, l2, n0, n1, n2)
    if g - lower <= tol:
        return g
    return -1.0


@njit(cache=True, inline="always")
def _cyl_support_near(X, E, r, hl, d0, d1, d2, ref):
    """A support point of the cylinder along the unit direction d; where the support is a side
    segment or a cap disc (d normal or parallel to the axis), its point nearest ``ref``."""
    b = E[0] * d0 + E[1] * d1 + E[2] * d2
    t0 = d0 - b * E[0]
    t1 = d1 - b * E[1]
    t2 = d2 - b * E[2]
    tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    y0 = ref[0] - X[0]
    y1 = ref[1] - X[1]
    y2 = ref[2] - X[2]
    ya = y0 * E[0] + y1 * E[1] + y2 * E[2]
    if abs(b) < 1e-12:
        z = min(hl, max(-hl, ya))
    else:
        z = hl if b > 0.0 else -hl
    if tn > 1e-12:
        return (X[0] + z * E[0] + r * t0 / tn, X[1] + z * E[1] + r * t1 / tn, X[2] + z * E[2] + r * t2 / tn)
    # a cap disc: the point of the disc nearest ref's projection onto it
    p0 = y0 - ya * E[0]
    p1 = y1 - ya * E[1]
    p2 = y2 - ya * E[2]
    pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    f = 1.0 if pn <= r else r / pn
    return (X[0] + z * E[0] + f * p0, X[1] + z * E[1] + f * p1, X[2] + z * E[2] + f * p2)


@njit(cache=True, inline="always")
def _facing_sign(X1, E1, X2):
    # +1 if the cap at X1 + l1 E1 faces the point X2 (the other cap, -1, does not)
    return 1.0 if E1[0] * (X2[0] - X1[0]) + E1[1] * (X2[1] - X1[1]) + E1[2] * (X2[2] - X1[2]) >= 0.0 else -1.0


@njit(cache=True, inline="always")
def _cap_against(X1, E1, r1, l1, X2, E2, r2, l2):
    """Cap of cylinder 1 facing cylinder 2 against cylinder 2's support point along the cap's
    normal: a circle (or side, or disc) against a plane. Returns (ok, a, b) with ``a`` on the cap
    (the foot of ``b``) and ``b`` on cylinder 2; ok if the foot lies on the cap disc."""
    s = _facing_sign(X1, E1, X2)
    m0 = s * E1[0]
    m1 = s * E1[1]
    m2 = s * E1[2]
    o = (X1[0] + l1 * m0, X1[1] + l1 * m1, X1[2] + l1 * m2)
    b = _cyl_support_near(X2, E2, r2, l2, -m0, -m1, -m2, o)
    h = (b[0] - o[0]) * m0 + (b[1] - o[1]) * m1 + (b[2] - o[2]) * m2
    a = (b[0] - h * m0, b[1] - h * m1, b[2] - h * m2)
    q0 = a[0] - o[0]
    q1 = a[1] - o[1]
    q2 = a[2] - o[2]
    return q0 * q0 + q1 * q1 + q2 * q2 <= r1 * r1, a, b


@njit(cache=True, inline="always")
def _cap_centre(X1, E1, l1, X2, flip):
    """Centre of the cap of cylinder 1 (centre X1, axis E1, half length l1) that faces the point
    X2 (``flip``: the other one)."""
    s = _facing_sign(X1, E1, X2)
    if flip:
        s = -s
    return X1[0] + s * l1 * E1[0], X1[1] + s * l1 * E1[1], X1[2] + s * l1 * E1[2]


@njit(cache=True, inline="always")
def _newton_step(d1, d2):
    """Newton's step for a minimum from the first and second derivatives d1, d2, downhill by
    0.1 where the curvature is not positive, at most 0.5 rad."""
    step = -d1 / d2 if d2 > 0.0 else (-0.1 if d1 > 0.0 else 0.1)
    return min(0.5, max(-0.5, step))


@njit(cache=True, inline="always")
def _rim_at(o0, o1, o2, U, V, r, t):
    """The point at angle t of the rim of centre o, radius r, in-plane axes U, V."""
    c = math.cos(t)
    sn = math.sin(t)
    return o0 + r * (c * U[0] + sn * V[0]), o1 + r * (c * U[1] + sn * V[1]), o2 + r * (c * U[2] + sn * V[2])


@njit(cache=True, inline="always")
def _rim_side(X1, E1, U1, V1, r1, l1, X2, E2, r2, l2, flip):
    """The rim of cylinder 1 on its cap facing cylinder 2 (``flip``: the other cap) against the
    side of cylinder 2: the rim angle minimising the squared distance to 2's axis,
    D(t) = |a_p + r1 (u_p cos t + v_p sin t)|^2 with ``_p`` the components normal to 2's axis (a
    trigonometric polynomial of degree 2), from the best of 8 samples by Newton's method. Returns
    (ok, rim point, side point); ok if the foot on 2's axis is within its length."""
    o0, o1, o2 = _cap_centre(X1, E1, l1, X2, flip)
    a0 = o0 - X2[0]
    a1 = o1 - X2[1]
    a2 = o2 - X2[2]
    ae = a0 * E2[0] + a1 * E2[1] + a2 * E2[2]
    a0 -= ae * E2[0]
    a1 -= ae * E2[1]
    a2 -= ae * E2[2]
    ue = U1[0] * E2[0] + U1[1] * E2[1] + U1[2] * E2[2]
    ve = V1[0] * E2[0] + V1[1] * E2[1] + V1[2] * E2[2]
    P0 = r1 * (U1[0] - ue * E2[0])
    P1 = r1 * (U1[1] - ue * E2[1])
    P2 = r1 * (U1[2] - ue * E2[2])
    Q0 = r1 * (V1[0] - ve * E2[0])
    Q1 = r1 * (V1[1] - ve * E2[1])
    Q2 = r1 * (V1[2] - ve * E2[2])
    k0 = a0 * a0 + a1 * a1 + a2 * a2
    k1 = a0 * P0 + a1 * P1 + a2 * P2
    k2 = a0 * Q0 + a1 * Q1 + a2 * Q2
    pp = P0 * P0 + P1 * P1 + P2 * P2
    qq = Q0 * Q0 + Q1 * Q1 + Q2 * Q2
    k4 = P0 * Q0 + P1 * Q1 + P2 * Q2
    best = 1e300
    c = 1.0
    sn = 0.0
    for r in range(8):
        cr = _RIM8_COS[r]
        sr = _RIM8_SIN[r]
        D = k0 + 2.0 * (k1 * cr + k2 * sr) + pp * cr * cr + 2.0 * k4 * cr * sr + qq * sr * sr
        if D < best:
            best = D
            c = cr
            sn = sr
    t = math.atan2(sn, c)
    k3 = qq - pp
    for it in range(30):
        c = math.cos(t)
        sn = math.sin(t)
        c2 = c * c - sn * sn
        s2 = 2.0 * sn * c
        d1 = -2.0 * k1 * sn + 2.0 * k2 * c + k3 * s2 + 2.0 * k4 * c2
        d2 = -2.0 * k1 * c - 2.0 * k2 * sn + 2.0 * k3 * c2 - 4.0 * k4 * s2
        step = _newton_step(d1, d2)
        t += step
        if abs(step) < 1e-12:
            break
    p = _rim_at(o0, o1, o2, U1, V1, r1, t)
    tf = (p[0] - X2[0]) * E2[0] + (p[1] - X2[1]) * E2[1] + (p[2] - X2[2]) * E2[2]
    w0 = p[0] - X2[0] - tf * E2[0]
    w1 = p[1] - X2[1] - tf * E2[1]
    w2 = p[2] - X2[2] - tf * E2[2]
    rho = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    ok = abs(tf) <= l2 and rho > 0.0  # rho <= r2: an overlap, which the certificate rejects
    f = r2 / rho if rho > 0.0 else 0.0
    q = (X2[0] + tf * E2[0] + f * w0, X2[1] + tf * E2[1] + f * w1, X2[2] + tf * E2[2] + f * w2)
    return ok, p, q


@njit(cache=True, inline="always")
def _rim_rim(X1, E1, U1, V1, r1, l1, X2, E2, r2, l2, flip1, flip2):
    """The rims of the two caps facing each other (``flip1``, ``flip2``: the other cap of that
    body): the angle t on rim 1 minimising the squared
    distance to rim 2, F(t) = |y|^2 - 2 r2 rho + r2^2 (y from rim 2's centre to the point of rim 1,
    rho its distance from 2's axis), from the best of 8 samples by Newton's method. Returns
    (ok, point of rim 1, point of rim 2)."""
    o0, o1, o2 = _cap_centre(X1, E1, l1, X2, flip1)
    c0, c1, c2 = _cap_centre(X2, E2, l2, X1, flip2)
    a0 = o0 - c0
    a1 = o1 - c1
    a2 = o2 - c2
    au = a0 * U1[0] + a1 * U1[1] + a2 * U1[2]
    av = a0 * V1[0] + a1 * V1[1] + a2 * V1[2]
    aa = a0 * a0 + a1 * a1 + a2 * a2 + r1 * r1
    ae = a0 * E2[0] + a1 * E2[1] + a2 * E2[2]
    ue = r1 * (U1[0] * E2[0] + U1[1] * E2[1] + U1[2] * E2[2])
    ve = r1 * (V1[0] * E2[0] + V1[1] * E2[1] + V1[2] * E2[2])
    best = 1e300
    c = 1.0
    sn = 0.0
    for r in range(8):
        cr = _RIM8_COS[r]
        sr = _RIM8_SIN[r]
        A = aa + 2.0 * r1 * (au * cr + av * sr)
        hh = ae + ue * cr + ve * sr
        F = A - 2.0 * r2 * math.sqrt(max(0.0, A - hh * hh))
        if F < best:
            best = F
            c = cr
            sn = sr
    t = math.atan2(sn, c)
    for it in range(30):
        c = math.cos(t)
        sn = math.sin(t)
        A = aa + 2.0 * r1 * (au * c + av * sn)
        A1 = 2.0 * r1 * (-au * sn + av * c)
        A2 = -2.0 * r1 * (au * c + av * sn)
        hh = ae + ue * c + ve * sn
        h1 = -ue * sn + ve * c
        h2 = -ue * c - ve * sn
        rr = A - hh * hh
        if rr <= 0.0:
            break
        rho = math.sqrt(rr)
        rr1 = A1 - 2.0 * hh * h1
        rr2 = A2 - 2.0 * (h1 * h1 + hh * h2)
        rho1 = rr1 / (2.0 * rho)
        rho2 = (rr2 - 2.0 * rho1 * rho1) / (2.0 * rho)
        step = _newton_step(A1 - 2.0 * r2 * rho1, A2 - 2.0 * r2 * rho2)
        t += step
        if abs(step) < 1e-12:
            break
    p = _rim_at(o0, o1, o2, U1, V1, r1, t)
    y0 = p[0] - c0
    y1 = p[1] - c1
    y2 = p[2] - c2
    ye = y0 * E2[0] + y1 * E2[1] + y2 * E2[2]
    w0 = y0 - ye * E2[0]
    w1 = y1 - ye * E2[1]
    w2 = y2 - ye * E2[2]
    rho = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if rho <= 0.0:
        return False, p, p
    f = r2 / rho
    return True, p, (c0 + f * w0, c1 + f * w1, c2 + f * w2)


@njit(cache=True, inline="always")
def _side_side(X1, E1, r1, l1, X2, E2, r2, l2):
    """The closest points of the two axis lines, if inside both segments, moved out to the sides
    along the line joining them. Returns (ok, a, b)."""
    w0 = X1[0] - X2[0]
    w1 = X1[1] - X2[1]
    w2 = X1[2] - X2[2]
    cb = E1[0] * E2[0] + E1[1] * E2[1] + E1[2] * E2[2]
    dd = E1[0] * w0 + E1[1] * w1 + E1[2] * w2
    ee = E2[0] * w0 + E2[1] * w1 + E2[2] * w2
    den = 1.0 - cb * cb
    if den > 1e-12:
        s = (cb * ee - dd) / den
    else:  # parallel axes: the middle of the overlap of the two segments along axis 1
        s = 0.5 * (max(-l1, -dd - l2) + min(l1, -dd + l2))
    t = ee + s * cb
    q1 = (X1[0] + s * E1[0], X1[1] + s * E1[1], X1[2] + s * E1[2])
    d0 = X2[0] + t * E2[0] - q1[0]
    d1 = X2[1] + t * E2[1] - q1[1]
    d2 = X2[2] + t * E2[2] - q1[2]
    dl = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if not (abs(s) < l1 and abs(t) < l2 and dl > 0.0):
        return False, q1, q1
    a = (q1[0] + r1 * d0 / dl, q1[1] + r1 * d1 / dl, q1[2] + r1 * d2 / dl)
    b = (q1[0] + (dl - r2) * d0 / dl, q1[1] + (dl - r2) * d1 / dl, q1[2] + (dl - r2) * d2 / dl)
    return True, a, b


_N_CANDIDATES = 11


# _cyl_candidate and _cylinder_gap are called, not inlined: inlined at their call sites they had the rim
# solvers typed and optimised a dozen times (a slower cold compile, more memory: benchmarks/README.md)
@njit(cache=True)
def _cyl_candidate(k, X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2):
    """Candidate k of ``cylinder_gap_exact``, cheapest first: (ok, a on body 1, b on body 2).
    0 side-side; 1, 2 the cap of body 1 / 2; then for the caps facing the other body, and after
    them the other caps: rim of 1 - side of 2, rim of 2 - side of 1, rim-rim."""
    if k == 0:
        return _side_side(X1, E1, r1, l1, X2, E2, r2, l2)
    if k == 1:
        return _cap_against(X1, E1, r1, l1, X2, E2, r2, l2)
    if k == 2:
        ok, b, a = _cap_against(X2, E2, r2, l2, X1, E1, r1, l1)
        return ok, a, b
    # 3-5: facing caps; 6-8: the other caps (rim-rim with body 1's); 9, 10: rim-rim, the others
    kk = k - 3
    if kk < 6:
        flip = kk >= 3
        f = kk % 3
        if f == 0:
            return _rim_side(X1, E1, U1, V1, r1, l1, X2, E2, r2, l2, flip)
        if f == 1:
            ok, b, a = _rim_side(X2, E2, U2, V2, r2, l2, X1, E1, r1, l1, flip)
            return ok, a, b
        return _rim_rim(X1, E1, U1, V1, r1, l1, X2, E2, r2, l2, flip, False)
    return _rim_rim(X1, E1, U1, V1, r1, l1, X2, E2, r2, l2, kk == 7, True)


@njit(cache=True, inline="always")
def _leans_more(X1, E1, X2, E2):
    """Does cylinder 1's axis lean towards the centre line at least as much as cylinder 2's?"""
    d0 = X2[0] - X1[0]
    d1 = X2[1] - X1[1]
    d2 = X2[2] - X1[2]
    return abs(E1[0] * d0 + E1[1] * d1 + E1[2] * d2) >= abs(E2[0] * d0 + E2[1] * d1 + E2[2] * d2)


@njit(cache=True, inline="always")
def _try_order(s, lean1):
    """The candidate (``_cyl_candidate``) to try s-th. A rim faces the other body only if its axis
    leans towards the centre line more than the other's: of 5,924 pairs of dense 8 mm cylinders,
    rim 1 - side 2 never won with |E1 . d| < |E2 . d|, nor rim 2 - side 1 with
    |E1 . d| >= |E2 . d|. So after the closed forms the more leaning body's rim-side search goes
    first, then rim-rim, and the other rim-side after them: 0.66 of the Newton searches of the
    order of ``_cyl_candidate``. The candidates are independent and a certified one is the gap
    within ``_EXACT_TOL`` (never were two certified in those pairs), so the order sets the time,
    not the result."""
    if s == 3:
        return 3 if lean1 else 4
    if s == 4:
        return 5
    if s == 5:
        return 4 if lean1 else 3
    return s


@njit(cache=True, inline="always")
def _cyl_frames(h1, x1, R1, h2, x2, R2):
    return ((x1[0], x1[1], x1[2]), (R1[0, 2], R1[1, 2], R1[2, 2]), (R1[0, 0], R1[1, 0], R1[2, 0]),
            (R1[0, 1], R1[1, 1], R1[2, 1]), h1[0], h1[2],
            (x2[0], x2[1], x2[2]), (R2[0, 2], R2[1, 2], R2[2, 2]), (R2[0, 0], R2[1, 0], R2[2, 0]),
            (R2[0, 1], R2[1, 1], R2[2, 1]), h2[0], h2[2])


@njit(cache=True)
def _cylinder_gap(h1, x1, R1, h2, x2, R2, first):
    """``cylinder_gap_exact`` on tuples: (gap or -1, witness point on 1, witness point on 2, the
    candidate that was certified or -1). The contact of the narrow phase takes its result without
    the three arrays, whose views cost as much as a rim-side contact's arithmetic.

    ``first`` (>= 0) is a candidate to try before the order of ``_try_order``: the one that won
    for the same pair in the step before. Touching pairs keep their closest features for many
    steps, so it is nearly always right, and then none of the candidates before it in the order is
    evaluated. Like that order it sets the time, not the result: a certified candidate is the
    gap, and no pair has been seen with two (``_try_order``)."""
    X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2 = _cyl_frames(h1, x1, R1, h2, x2, R2)
    tol = _EXACT_TOL * (math.sqrt(r1 * r1 + l1 * l1) + math.sqrt(r2 * r2 + l2 * l2))
    none = (-1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), -1)
    # ``first`` on its own, not as a step -1 of the loop: that one loop took 1.09 times as long
    # (replayed collision step, same bits)
    if first >= 0:
        ok, a, b = _cyl_candidate(first, X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2)
        if ok:
            g = _certified_gap(X1, E1, r1, l1, X2, E2, r2, l2, a[0], a[1], a[2], b[0], b[1], b[2], tol)
            if g >= 0.0:
                return g, a, b, first
            if _inside_cyl(a, X2, E2, r2, l2, tol) or _inside_cyl(b, X1, E1, r1, l1, tol):
                return none
    lean1 = _leans_more(X1, E1, X2, E2)
    for s in range(_N_CANDIDATES):
        k = _try_order(s, lean1)
        if k == first:
            continue
        ok, a, b = _cyl_candidate(k, X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2)
        if not ok:
            continue
        g = _certified_gap(X1, E1, r1, l1, X2, E2, r2, l2, a[0], a[1], a[2], b[0], b[1], b[2], tol)
        if g >= 0.0:
            return g, a, b, k
        # a point of one body inside the other by more than tol: the two overlap, so no candidate
        # can be certified (its separation would be negative). The ~6-21 pairs a step of 244 dense
        # cylinders that overlap within the projection's bound stop here, not after all eleven
        if _inside_cyl(a, X2, E2, r2, l2, tol) or _inside_cyl(b, X1, E1, r1, l1, tol):
            return none
    return none


@njit(cache=True)
def cylinder_gap_exact(h1, x1, R1, h2, x2, R2, nrm, pa, pb):
    """Gap of two separated cylinders (half-extents h = (radius, -, half length), centres x,
    rotation matrices R body->lab, axis = body z) without GJK. The closest points lie on one of
    five feature pairs (``_cyl_candidate``, tried in the order of ``_try_order``): side-side
    (closest points of the two axes, closed form), a cap against the other body (its support point
    projected on the cap's plane, closed form; each body's cap in turn), a rim against a side (each
    way) and rim-rim (one angle each, by Newton's method). The first candidate whose distance meets the
    separating-axis lower bound along its own direction within ``_EXACT_TOL`` of the size is the
    gap, as exact as GJK's. Writes the unit normal from 1 to 2 into ``nrm`` and the witness points
    into ``pa``, ``pb``; returns -1 if no candidate is certified (overlapping or touching bodies,
    or a case the candidates miss), for the caller to use GJK/EPA."""
    g, a, b, _won = _cylinder_gap(h1, x1, R1, h2, x2, R2, -1)
    if g >= 0.0:
        for kk in range(3):
            pa[kk] = a[kk]
            pb[kk] = b[kk]
            nrm[kk] = (b[kk] - a[kk]) / g
    return g


@njit(cache=True, inline="always")
def _inside_cyl(p, X, E, r, hl, tol):
    """Is the point p inside the cylinder by more than tol?"""
    y0 = p[0] - X[0]
    y1 = p[1] - X[1]
    y2 = p[2] - X[2]
    t = y0 * E[0] + y1 * E[1] + y2 * E[2]
    if abs(t) > hl - tol:
        return False
    y0 -= t * E[0]
    y1 -= t * E[1]
    y2 -= t * E[2]
    rr = r - tol
    return rr > 0.0 and y0 * y0 + y1 * y1 + y2 * y2 < rr * rr


@njit(cache=True)
def cylinders_overlap_exact(h1, x1, R1, h2, x2, R2):
    """Do two cylinders overlap? 1 if a candidate point of ``cylinder_gap_exact`` lies inside the
    other body (by more than ``_EXACT_TOL`` of the size), 0 if a candidate's direction separates
    them (support heights apart by more than that), -1 if neither settles it (GJK decides). The
    time-of-impact bisection asks only this."""
    X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2 = _cyl_frames(h1, x1, R1, h2, x2, R2)
    tol = _EXACT_TOL * (math.sqrt(r1 * r1 + l1 * l1) + math.sqrt(r2 * r2 + l2 * l2))
    lean1 = _leans_more(X1, E1, X2, E2)
    for s in range(_N_CANDIDATES):
        ok, a, b = _cyl_candidate(_try_order(s, lean1), X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2)
        if not ok:
            continue
        if _inside_cyl(a, X2, E2, r2, l2, tol) or _inside_cyl(b, X1, E1, r1, l1, tol):
            return 1
        d0 = b[0] - a[0]
        d1 = b[1] - a[1]
        d2 = b[2] - a[2]
        g = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if g > 0.0:
            n0 = d0 / g
            n1 = d1 / g
            n2 = d2 / g
            if _cyl_separation(X1, E1, r1, l1, X2, E2, r2, l2, n0, n1, n2) > tol:
                return 0
    return -1
