"""Contact detection between cylinders, cubes and spheres, and between a body and the walls.

This supplies what the impulse model of Eqs. (16)-(21) needs from geometry: for two bodies the
signed gap, the unit normal ``p`` pointing from body 1 to body 2, and the contact point ``O``
(lab frame); for a body and a wall the same with the wall as body 2 (``p`` points from the body
into the wall).

Narrow phase (``body_contact``)
-------------------------------
- sphere-sphere: exact, from the centre distance;
- cylinder-cylinder, separated: exact, without GJK (``cylinder_gap_exact``). The closest points
  of two cylinders lie on one of five feature pairs: side-side (the closest points of the two
  axes: closed form), a cap against the other body (that body's support point along the cap's
  normal, projected onto the cap: closed form), rim-side and rim-rim (one angle on the rim, by
  Newton's method from the best of 8 samples: the squared distance of a rim point to the other
  axis is a trigonometric polynomial of degree 2). Candidates are tried from the cheapest, and
  each is certified: its length ``|b - a|`` bounds the gap from above, the separation of the two
  support heights along ``(b - a)/|b - a|`` bounds it from below, and the first candidate whose
  two bounds meet within ``1e-9`` of the body size (GJK's own stopping rule) is the gap. An
  uncertified pair (overlapping, touching, or a configuration the candidates miss: none of the
  1,587 random separated pairs of the paper's shapes in the tests) goes to GJK/EPA below;
- sphere-X: GJK between the sphere's centre (a point) and X, then the sphere radius is
  subtracted (exact, and GJK on a point converges fast); falls back to the general path if the
  centre is inside X;
- general: GJK (Gilbert-Johnson-Keerthi, closest point of the Minkowski difference
  ``D = A - B`` to the origin, simplex sub-problems by Voronoi regions as in Ericson,
  *Real-Time Collision Detection*, 5.1) on the support functions of ``lbmpipe.particles.shapes``; if the
  bodies overlap, EPA (expanding polytope) gives the penetration depth and normal, i.e. the
  smallest translation of body 2 that separates them.
- signed gap: ``+distance`` when separated, ``-depth`` when overlapping. Accuracy: GJK stops when
  the gap is bracketed to ``1e-9`` of the body size, EPA when its support gap is below ``1e-7``
  of the body size or at ``EPA_MAX_VERTS`` vertices (curved surfaces converge slowly in EPA).
  Against an independent separating-axis maximisation the signed gap agrees to ``1e-5`` (tests,
  bodies of size ~2-4). On curved surfaces the normal is less accurate than the gap (an error
  ``e`` in the gap allows ~``sqrt(e * curvature radius)`` in the normal: ~1e-4 rad here).

Contact point. GJK/EPA return one witness point per body. Where flat features meet (cube face on
cube face, cylinder side on cylinder side, cap on face...) the witness is an arbitrary point of the
contact patch, and an impulse there would spin the bodies spuriously. So the contact point is the
centroid of the contact patch: the support features of both bodies along the normal (vertex, edge,
face of a cube; rim point, side segment or cap disc (a 16-gon) of a cylinder), taken within
``manifold_tol`` of the extreme, are projected onto the contact plane and intersected; the centroid
of that convex polygon (or the midpoint of the overlap of two segments) is the in-plane position of
``O``; its normal coordinate is the midpoint of the witness points. ``manifold_tol`` is a length
(default in the callers: 0.1 lattice spacing): a face tilted so that its far edge is within it of the
near edge counts as flat.

Cost. The dense 8 x 8 mm cylinders at 50 % (244 bodies in the paper's pipe) give ~1,050-1,200
candidate pairs per step, ~800 of them within the collision model's contact gap of one lattice
spacing, where GJK takes ~20 iterations on the curved surfaces; the exact cylinder path takes a
fraction of GJK's time for the same pairs (figures: benchmarks/README.md). Inside these loops
nothing allocates, and arrays are made and passed sparingly: each view, and each array passed to
a function, costs a reference count, ~10-20 ns. The simplex rows go to ``_closest_triangle`` as
scalars; the scratch is one buffer (``new_scratch``), whose views are made only on the path that
needs them (a tuple of its 18 arrays cost ~0.4 us per call, more than half of a cylinder
contact); where one feature is a rim point the contact point is written out instead of making
the patch's views; beyond ``max_gap`` there is no patch.

Walls
-----
- pipe wall (``pipe_wall_contact``), a cylinder of radius ``R`` about the axis through
  ``(cx, cy)`` along z: gap = ``R - max`` distance of a body point from the axis. Exact per shape:
  sphere from its centre; cube from its 8 vertices (a convex function is maximised at a vertex);
  cylinder from its two rim circles, each sampled at 32 angles and every local maximum refined by
  Newton's method on ``rho^2(theta)``. Where several points are within ``manifold_tol`` of the
  maximum (a cube face or cylinder side lying against the wall, a cap facing the wall) the contact
  point is their mean and the normal the radial unit vector through it, so a symmetric contact
  applies no torque.
- planar walls (``plane_wall_contact``) at ``x = c`` with outward side ``+-1``: gap from the support
  point; contact point the centroid of the support feature.

Broad phase (``candidate_pairs``)
---------------------------------
Cell list on bounding spheres (cells of edge ``2 max r_b + margin``), so the cost is linear in
the number of bodies; periodic axes wrap the cells and the pair gets the minimum-image shift
``s`` (body 2 is at ``x_2 + s``). A periodic length must be at least two cells. Over time steps
the collision step keeps a Verlet list (``neighbour_list``, a wider margin) and takes each step's
pairs from it (``listed_pairs``: the cell scan's pairs in the cell scan's order) until a body has
moved by half the extra margin.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .rigid import quat_to_matrix
from .shapes import CUBE, CYLINDER, SPHERE, bounding_radius

GJK_MAX_ITER = 128
EPA_MAX_VERTS = 128
EPA_MAX_FACES = 4 * EPA_MAX_VERTS
GJK_REL_TOL = 1e-9
EPA_REL_TOL = 1e-7
DISC_SIDES = 16
RIM_SAMPLES = 32

# Status codes of _gjk
_SEPARATED = 0
_INTERSECTING = 1
_FAR = 2


# ------------------------------------------------------------------------------------------------
# small vector helpers


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _cross_into(a, b, out):
    x = a[1] * b[2] - a[2] * b[1]
    y = a[2] * b[0] - a[0] * b[2]
    z = a[0] * b[1] - a[1] * b[0]
    out[0] = x
    out[1] = y
    out[2] = z


@njit(cache=True, inline="always")
def support3(kind, h, x, R, core, d0, d1, d2):
    """Lab-frame support point of a body along the lab direction (d0, d1, d2), as a tuple.
    ``shapes.support_body`` written out on scalars (same operations, so the same bits; a test
    pins the two together): the GJK loop calls it twice per iteration and must not allocate.
    ``core``: the body is replaced by its centre (a sphere treated as point + margin)."""
    if core:
        return x[0], x[1], x[2]
    b0 = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2
    b1 = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
    b2 = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
    if kind == SPHERE:
        nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        if nb > 0.0:
            s0 = h[0] * b0 / nb
            s1 = h[0] * b1 / nb
            s2 = h[0] * b2 / nb
        else:
            s0 = h[0]
            s1 = 0.0
            s2 = 0.0
    elif kind == CYLINDER:
        r = math.sqrt(b0 * b0 + b1 * b1)
        if r > 0.0:
            s0 = h[0] * b0 / r
            s1 = h[0] * b1 / r
        else:
            s0 = h[0]
            s1 = 0.0
        s2 = h[2] * (1.0 if b2 >= 0.0 else -1.0)
    else:
        s0 = h[0] * (1.0 if b0 >= 0.0 else -1.0)
        s1 = h[1] * (1.0 if b1 >= 0.0 else -1.0)
        s2 = h[2] * (1.0 if b2 >= 0.0 else -1.0)
    return (x[0] + R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * s2,
            x[1] + R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * s2,
            x[2] + R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * s2)


@njit(cache=True)
def _support_lab(kind, h, x, R, core, d, out):
    out[0], out[1], out[2] = support3(kind, h, x, R, core, d[0], d[1], d[2])


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


# ------------------------------------------------------------------------------------------------
# EPA


@njit(cache=True)
def _epa_face(V, F, FN, FD, f, a, b, c, scale):
    F[f, 0], F[f, 1], F[f, 2] = a, b, c
    e1x = V[b, 0] - V[a, 0]
    e1y = V[b, 1] - V[a, 1]
    e1z = V[b, 2] - V[a, 2]
    e2x = V[c, 0] - V[a, 0]
    e2y = V[c, 1] - V[a, 1]
    e2z = V[c, 2] - V[a, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln <= 1e-14 * scale * scale:
        FN[f, 0], FN[f, 1], FN[f, 2] = 0.0, 0.0, 0.0
        FD[f] = 1e300  # sliver: never the closest, never visible
        return
    FN[f, 0], FN[f, 1], FN[f, 2] = nx / ln, ny / ln, nz / ln
    FD[f] = (nx * V[a, 0] + ny * V[a, 1] + nz * V[a, 2]) / ln


@njit(cache=True)
def _blow_up(k1, h1, x1, R1, k2, h2, x2, R2, scale, V, VA, VB, n):
    """Grow a GJK simplex of n < 4 vertices that touches the origin into a tetrahedron (libccd's
    approach). Returns the new vertex count (4 on success)."""
    d = np.empty(3)
    sa = np.empty(3)
    sb = np.empty(3)
    eps = 1e-9 * scale
    dirs = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    if n == 1:
        for t in range(6):
            for k in range(3):
                d[k] = dirs[t, k]
            _support_lab(k1, h1, x1, R1, False, d, sa)
            for k in range(3):
                d[k] = -dirs[t, k]
            _support_lab(k2, h2, x2, R2, False, d, sb)
            dd = 0.0
            for k in range(3):
                dd += (sa[k] - sb[k] - V[0, k]) ** 2
            if dd > eps * eps:
                for k in range(3):
                    V[1, k] = sa[k] - sb[k]
                    VA[1, k] = sa[k]
                    VB[1, k] = sb[k]
                n = 2
                break
        if n < 2:
            return n
    if n == 2:
        e = np.empty(3)
        for k in range(3):
            e[k] = V[1, k] - V[0, k]
        le = math.sqrt(_dot(e, e))
        for k in range(3):
            e[k] /= le
        # a unit vector perpendicular to e
        ax = 0
        if abs(e[1]) < abs(e[ax]):
            ax = 1
        if abs(e[2]) < abs(e[ax]):
            ax = 2
        u = np.zeros(3)
        u[ax] = 1.0
        u0 = np.empty(3)
        _cross_into(e, u, u0)
        l0 = math.sqrt(_dot(u0, u0))
        for k in range(3):
            u0[k] /= l0
        u1 = np.empty(3)
        _cross_into(e, u0, u1)
        for t in range(6):
            ang = t * math.pi / 3.0
            for k in range(3):
                d[k] = math.cos(ang) * u0[k] + math.sin(ang) * u1[k]
            _support_lab(k1, h1, x1, R1, False, d, sa)
            for k in range(3):
                d[k] = -d[k]
            _support_lab(k2, h2, x2, R2, False, d, sb)
            # distance of the new point from the line of the segment
            wx = sa[0] - sb[0] - V[0, 0]
            wy = sa[1] - sb[1] - V[0, 1]
            wz = sa[2] - sb[2] - V[0, 2]
            pr = wx * e[0] + wy * e[1] + wz * e[2]
            ox = wx - pr * e[0]
            oy = wy - pr * e[1]
            oz = wz - pr * e[2]
            if ox * ox + oy * oy + oz * oz > eps * eps:
                for k in range(3):
                    V[2, k] = sa[k] - sb[k]
                    VA[2, k] = sa[k]
                    VB[2, k] = sb[k]
                n = 3
                break
        if n < 3:
            return n
    if n == 3:
        e1 = np.empty(3)
        e2 = np.empty(3)
        nn = np.empty(3)
        for k in range(3):
            e1[k] = V[1, k] - V[0, k]
            e2[k] = V[2, k] - V[0, k]
        _cross_into(e1, e2, nn)
        ln = math.sqrt(_dot(nn, nn))
        for k in range(3):
            nn[k] /= ln
        for sgn in (1.0, -1.0):
            for k in range(3):
                d[k] = sgn * nn[k]
            _support_lab(k1, h1, x1, R1, False, d, sa)
            for k in range(3):
                d[k] = -d[k]
            _support_lab(k2, h2, x2, R2, False, d, sb)
            off = 0.0
            for k in range(3):
                off += (sa[k] - sb[k] - V[0, k]) * nn[k]
            if abs(off) > eps:
                for k in range(3):
                    V[3, k] = sa[k] - sb[k]
                    VA[3, k] = sa[k]
                    VB[3, k] = sb[k]
                n = 4
                break
    return n


@njit(cache=True)
def _epa(k1, h1, x1, R1, k2, h2, x2, R2, scale, W, WA, WB, n, nrm, pa, pb):
    """Penetration depth (>= 0) of intersecting A, B and its normal ``nrm`` (the direction in
    which B must move to separate, i.e. from A to B) with witness points. Returns -1 if the
    Minkowski difference is degenerate (flat), which the caller treats as a touching contact."""
    V = np.empty((EPA_MAX_VERTS, 3))
    VA = np.empty((EPA_MAX_VERTS, 3))
    VB = np.empty((EPA_MAX_VERTS, 3))
    for r in range(n):
        for k in range(3):
            V[r, k] = W[r, k]
            VA[r, k] = WA[r, k]
            VB[r, k] = WB[r, k]
    if n < 4:
        n = _blow_up(k1, h1, x1, R1, k2, h2, x2, R2, scale, V, VA, VB, n)
        if n < 4:
            return -1.0
    F = np.empty((EPA_MAX_FACES, 3), dtype=np.int64)
    FN = np.empty((EPA_MAX_FACES, 3))
    FD = np.empty(EPA_MAX_FACES)
    alive = np.zeros(EPA_MAX_FACES, dtype=np.bool_)
    # initial tetrahedron, faces oriented outward (away from the opposite vertex)
    e1 = np.empty(3)
    e2 = np.empty(3)
    nn = np.empty(3)
    for k in range(3):
        e1[k] = V[1, k] - V[0, k]
        e2[k] = V[2, k] - V[0, k]
    _cross_into(e1, e2, nn)
    vol = nn[0] * (V[3, 0] - V[0, 0]) + nn[1] * (V[3, 1] - V[0, 1]) + nn[2] * (V[3, 2] - V[0, 2])
    if abs(vol) <= 1e-15 * scale ** 3:
        return -1.0
    if vol > 0.0:
        # make (0,1,2) wind clockwise seen from vertex 3 -> swap vertices 1 and 2
        for k in range(3):
            t = V[1, k]
            V[1, k] = V[2, k]
            V[2, k] = t
            t = VA[1, k]
            VA[1, k] = VA[2, k]
            VA[2, k] = t
            t = VB[1, k]
            VB[1, k] = VB[2, k]
            VB[2, k] = t
    _epa_face(V, F, FN, FD, 0, 0, 1, 2, scale)
    _epa_face(V, F, FN, FD, 1, 0, 3, 1, scale)
    _epa_face(V, F, FN, FD, 2, 0, 2, 3, scale)
    _epa_face(V, F, FN, FD, 3, 1, 3, 2, scale)
    for f in range(4):
        alive[f] = True
    nf = 4
    nv = 4
    tol = EPA_REL_TOL * scale
    d = np.empty(3)
    sa = np.empty(3)
    sb = np.empty(3)
    edges = np.empty((3 * EPA_MAX_FACES, 2), dtype=np.int64)
    best = 0
    while True:
        best = -1
        bd = 1e301
        for f in range(nf):
            if alive[f] and FD[f] < bd:
                bd = FD[f]
                best = f
        if best < 0:
            return -1.0
        for k in range(3):
            d[k] = FN[best, k]
        _support_lab(k1, h1, x1, R1, False, d, sa)
        for k in range(3):
            d[k] = -d[k]
        _support_lab(k2, h2, x2, R2, False, d, sb)
        sd = (sa[0] - sb[0]) * FN[best, 0] + (sa[1] - sb[1]) * FN[best, 1] + (sa[2] - sb[2]) * FN[best, 2]
        if sd - bd <= tol or nv >= EPA_MAX_VERTS:
            break
        # compact dead faces if the face table is getting full
        if nf + nv + 1 > EPA_MAX_FACES:
            m = 0
            for f in range(nf):
                if alive[f]:
                    if m != f:
                        F[m] = F[f]
                        FN[m] = FN[f]
                        FD[m] = FD[f]
                    alive[m] = True
                    m += 1
            for f in range(m, nf):
                alive[f] = False
            nf = m
            if nf + nv + 1 > EPA_MAX_FACES:
                break
            continue
        iv = nv
        for k in range(3):
            V[iv, k] = sa[k] - sb[k]
            VA[iv, k] = sa[k]
            VB[iv, k] = sb[k]
        nv += 1
        ne = 0
        for f in range(nf):
            if not alive[f]:
                continue
            a = F[f, 0]
            vis = FN[f, 0] * (V[iv, 0] - V[a, 0]) + FN[f, 1] * (V[iv, 1] - V[a, 1]) + FN[f, 2] * (V[iv, 2] - V[a, 2])
            if vis > 1e-12 * scale:
                alive[f] = False
                for t in range(3):
                    ea = F[f, t]
                    eb = F[f, (t + 1) % 3]
                    found = -1
                    for r in range(ne):
                        if edges[r, 0] == eb and edges[r, 1] == ea:
                            found = r
                            break
                    if found >= 0:
                        edges[found, 0] = edges[ne - 1, 0]
                        edges[found, 1] = edges[ne - 1, 1]
                        ne -= 1
                    else:
                        edges[ne, 0] = ea
                        edges[ne, 1] = eb
                        ne += 1
        for r in range(ne):
            _epa_face(V, F, FN, FD, nf, edges[r, 0], edges[r, 1], iv, scale)
            alive[nf] = True
            nf += 1
    # witness points from the barycentric coordinates of the origin's projection on the face
    depth = FD[best]
    a = F[best, 0]
    b = F[best, 1]
    c = F[best, 2]
    px = depth * FN[best, 0]
    py = depth * FN[best, 1]
    pz = depth * FN[best, 2]
    v0x = V[b, 0] - V[a, 0]
    v0y = V[b, 1] - V[a, 1]
    v0z = V[b, 2] - V[a, 2]
    v1x = V[c, 0] - V[a, 0]
    v1y = V[c, 1] - V[a, 1]
    v1z = V[c, 2] - V[a, 2]
    v2x = px - V[a, 0]
    v2y = py - V[a, 1]
    v2z = pz - V[a, 2]
    d00 = v0x * v0x + v0y * v0y + v0z * v0z
    d01 = v0x * v1x + v0y * v1y + v0z * v1z
    d11 = v1x * v1x + v1y * v1y + v1z * v1z
    d20 = v2x * v0x + v2y * v0y + v2z * v0z
    d21 = v2x * v1x + v2y * v1y + v2z * v1z
    den = d00 * d11 - d01 * d01
    lb = 1.0 / 3.0
    lc = 1.0 / 3.0
    if den > 0.0:
        lb = (d11 * d20 - d01 * d21) / den
        lc = (d00 * d21 - d01 * d20) / den
        lb = min(1.0, max(0.0, lb))
        lc = min(1.0 - lb, max(0.0, lc))
    la = 1.0 - lb - lc
    for k in range(3):
        nrm[k] = FN[best, k]
        pa[k] = la * VA[a, k] + lb * VA[b, k] + lc * VA[c, k]
        pb[k] = la * VB[a, k] + lb * VB[b, k] + lc * VB[c, k]
    return max(depth, 0.0)


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


# ------------------------------------------------------------------------------------------------
# narrow phase, public kernel


_PATCH_POINTS = 2 * DISC_SIDES + 4 * DISC_SIDES * DISC_SIDES // 4 + 8  # vertices in + edge crossings


# layout of the scratch buffer (``new_scratch``): offsets of GJK's simplex W, its support points
# WA, WB (4 x 3 each), the barycentric weights (4), the witness points pa, pb, the search
# direction v, the witness midpoint (3 each), then the contact patch (``_manifold_point``): the
# two features and the body-frame points (DISC_SIDES x 3 each), the two plane polygons
# (DISC_SIDES x 2 each), -n, the plane basis t1, t2 (3 each), the patch point (2) and the patch
# points (_PATCH_POINTS x 2); last the exact cylinder path's candidate to try first and the one that
# won (``body_contact_ws``)
_WS_W = 0
_WS_WA = _WS_W + 12
_WS_WB = _WS_WA + 12
_WS_LAM = _WS_WB + 12
_WS_PA = _WS_LAM + 4
_WS_PB = _WS_PA + 3
_WS_V = _WS_PB + 3
_WS_BASE = _WS_V + 3
_WS_F1 = _WS_BASE + 3
_WS_F2 = _WS_F1 + 3 * DISC_SIDES
_WS_FB = _WS_F2 + 3 * DISC_SIDES
_WS_P1 = _WS_FB + 3 * DISC_SIDES
_WS_P2 = _WS_P1 + 2 * DISC_SIDES
_WS_MNEG = _WS_P2 + 2 * DISC_SIDES
_WS_T1 = _WS_MNEG + 3
_WS_T2 = _WS_T1 + 3
_WS_UV = _WS_T2 + 3
_WS_PTS = _WS_UV + 2
WS_HINT = _WS_PTS + 2 * _PATCH_POINTS
WS_WON = WS_HINT + 1
WS_SIZE = WS_WON + 1


@njit(cache=True)
def new_scratch(extra=0):
    """Scratch memory of ``body_contact_ws`` and ``bodies_overlap_ws`` (layout: ``_WS_*``). One
    per thread: the narrow phase runs ~10^3 times per step and must not allocate. One buffer,
    not a tuple of arrays: a function call takes a reference on every array it is passed, and
    for the 18 arrays of a tuple that cost more than most cylinder contacts (0.4 us of 1 us);
    views are made only where a path needs them. ``extra``: more room after ``WS_SIZE``, for a
    caller's own scratch in the same buffer."""
    ws = np.empty(WS_SIZE + extra)
    ws[WS_HINT] = -1.0
    return ws


@njit(cache=True, inline="always")
def ws_rows(ws, off, rows, cols):
    # a (rows, cols) view of the scratch buffer at offset off
    return ws[off:off + rows * cols].reshape((rows, cols))


@njit(cache=True)
def body_contact(k1, h1, x1, R1, k2, h2, x2, R2, max_gap, manifold_tol, nrm, c):
    """Signed gap between body 1 (kind k1, half-extents h1, centre x1, rotation matrix R1
    body->lab) and body 2; writes the unit normal from 1 to 2 into ``nrm`` and the contact point
    into ``c`` (both (3,)). If the gap exceeds ``max_gap`` the function may stop early and return
    a lower bound of the gap (> max_gap); ``nrm`` and ``c`` are then only approximate."""
    return body_contact_ws(k1, h1, x1, R1, k2, h2, x2, R2, max_gap, manifold_tol, nrm, c, new_scratch())


@njit(cache=True, inline="always")
def _gjk_scratch(ws):
    """GJK's and EPA's working arrays in the scratch buffer (``new_scratch``): simplex W and its
    support points WA, WB, barycentric weights, witness points, search direction."""
    return (ws_rows(ws, _WS_W, 4, 3), ws_rows(ws, _WS_WA, 4, 3), ws_rows(ws, _WS_WB, 4, 3),
            ws[_WS_LAM:_WS_LAM + 4], ws[_WS_PA:_WS_PA + 3], ws[_WS_PB:_WS_PB + 3], ws[_WS_V:_WS_V + 3])


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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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


# ------------------------------------------------------------------------------------------------
# walls


@njit(cache=True, inline="always")
def _rim_rho2_cs(ex, ey, ax, ay, bx, by, r, ct, st):
    # squared distance from the pipe axis of the rim point e + r (cos th a + sin th b), xy parts
    px = ex + r * (ct * ax + st * bx)
    py = ey + r * (ct * ay + st * by)
    return px * px + py * py


# cos and sin of the rim samples' angles 2 pi s / RIM_SAMPLES, as numba's math.cos and math.sin give
# them (the same bits: tests/test_contact.py checks it): the samples of pipe_wall_contact without
# their 2 x 64 trigonometric calls, which were most of its time (a pipe-wall contact is measured
# up to seven times per time-of-impact search)
_RIM_COS = np.array([math.cos(2.0 * math.pi * s / RIM_SAMPLES) for s in range(RIM_SAMPLES)])
_RIM_SIN = np.array([math.sin(2.0 * math.pi * s / RIM_SAMPLES) for s in range(RIM_SAMPLES)])


@njit(cache=True)
def pipe_wall_contact(kind, h, x, R, radius, cx, cy, manifold_tol, nrm, c):
    """Signed gap between a body and the wall of a pipe of ``radius`` about the axis through
    ``(cx, cy)`` along z: ``radius - (largest distance of a body point from the axis)``.
    ``nrm`` is the outward radial unit vector (body -> wall) through the contact point ``c``
    (the mean of the body points within ``manifold_tol`` of the farthest one)."""
    ox = x[0] - cx
    oy = x[1] - cy
    if kind == SPHERE:
        ux, uy, rho = _unit_xy(ox, oy)
        nrm[0], nrm[1], nrm[2] = ux, uy, 0.0
        c[0] = x[0] + h[0] * ux
        c[1] = x[1] + h[0] * uy
        c[2] = x[2]
        return radius - (rho + h[0])
    cand = np.empty((2 * RIM_SAMPLES + 8, 3))
    rho2 = np.empty(2 * RIM_SAMPLES + 8)
    m = 0
    if kind == CUBE:
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                for sz in (-1.0, 1.0):
                    for k in range(3):
                        cand[m, k] = x[k] + R[k, 0] * sx * h[0] + R[k, 1] * sy * h[1] + R[k, 2] * sz * h[2]
                    px = cand[m, 0] - cx
                    py = cand[m, 1] - cy
                    rho2[m] = px * px + py * py
                    m += 1
    else:
        r = h[0]
        ax, ay = R[0, 0], R[1, 0]
        bx, by = R[0, 1], R[1, 1]
        samp = np.empty(RIM_SAMPLES)
        # A rim whose farthest possible point (centre distance + r) stays short of the other
        # rim's centre distance (at most the other's largest sample: the samples' mean of rho^2
        # is exact, |e|^2 + r^2 (|a|^2 + |b|^2) / 2) by more than manifold_tol has no candidate
        # that could count: it is skipped, the same result for half the work (a tilted body)
        lm = math.sqrt((ox - h[2] * R[0, 2]) ** 2 + (oy - h[2] * R[1, 2]) ** 2)
        lp = math.sqrt((ox + h[2] * R[0, 2]) ** 2 + (oy + h[2] * R[1, 2]) ** 2)
        slack = manifold_tol + 1e-9 * (radius + r + h[2])
        for sgn in (-1.0, 1.0):
            if (lm + r < lp - slack) if sgn < 0.0 else (lp + r < lm - slack):
                continue
            ex = ox + sgn * h[2] * R[0, 2]
            ey = oy + sgn * h[2] * R[1, 2]
            ez = x[2] + sgn * h[2] * R[2, 2]
            for s in range(RIM_SAMPLES):
                samp[s] = _rim_rho2_cs(ex, ey, ax, ay, bx, by, r, _RIM_COS[s], _RIM_SIN[s])
            sbest = 0
            for s in range(RIM_SAMPLES):
                if samp[s] > samp[sbest]:
                    sbest = s
            for s in range(RIM_SAMPLES):
                prv = samp[(s - 1) % RIM_SAMPLES]
                nxt = samp[(s + 1) % RIM_SAMPLES]
                # every strict local maximum, and the best sample even on a plateau
                if s == sbest or (samp[s] >= prv and samp[s] > nxt) or (samp[s] > prv and samp[s] >= nxt):
                    # Newton on f(th) = |e + r(cos a + sin b)|^2_xy; f is a trigonometric
                    # polynomial of degree 2, so derivatives are analytic.
                    # cos and sin of th are carried along: each is computed once per th (the
                    # sample's from the table), the same bits as computing them where used
                    th = 2.0 * math.pi * s / RIM_SAMPLES
                    ct = _RIM_COS[s]
                    st = _RIM_SIN[s]
                    for _it in range(20):
                        px = ex + r * (ct * ax + st * bx)
                        py = ey + r * (ct * ay + st * by)
                        dpx = r * (-st * ax + ct * bx)
                        dpy = r * (-st * ay + ct * by)
                        ddpx = -r * (ct * ax + st * bx)
                        ddpy = -r * (ct * ay + st * by)
                        f1 = 2.0 * (px * dpx + py * dpy)
                        f2 = 2.0 * (dpx * dpx + dpy * dpy + px * ddpx + py * ddpy)
                        if f2 >= 0.0:
                            break  # not locally concave: keep the sample
                        step = -f1 / f2
                        step = min(0.2, max(-0.2, step))
                        th += step
                        ct = math.cos(th)
                        st = math.sin(th)
                        if abs(step) < 1e-13:
                            break
                    val = _rim_rho2_cs(ex, ey, ax, ay, bx, by, r, ct, st)
                    if val < samp[s]:
                        val = samp[s]
                        ct = _RIM_COS[s]
                        st = _RIM_SIN[s]
                    if m < cand.shape[0]:
                        cand[m, 0] = cx + ex + r * (ct * ax + st * bx)
                        cand[m, 1] = cy + ey + r * (ct * ay + st * by)
                        cand[m, 2] = ez + r * (ct * R[2, 0] + st * R[2, 1])
                        rho2[m] = val
                        m += 1
    best = 0.0
    for r_ in range(m):
        best = max(best, rho2[r_])
    rmax = math.sqrt(best)
    # contact point: mean of the points within manifold_tol of the farthest (distinct ones)
    sx_ = 0.0
    sy_ = 0.0
    sz_ = 0.0
    cnt = 0
    thr = rmax - manifold_tol
    for r_ in range(m):
        if math.sqrt(rho2[r_]) >= thr:
            dup = False
            for s in range(r_):
                if math.sqrt(rho2[s]) >= thr:
                    dd = (cand[s, 0] - cand[r_, 0]) ** 2 + (cand[s, 1] - cand[r_, 1]) ** 2 + (cand[s, 2] - cand[r_, 2]) ** 2
                    if dd <= 1e-18 * (1.0 + best):
                        dup = True
                        break
            if dup:
                continue
            sx_ += cand[r_, 0]
            sy_ += cand[r_, 1]
            sz_ += cand[r_, 2]
            cnt += 1
    c[0] = sx_ / cnt
    c[1] = sy_ / cnt
    c[2] = sz_ / cnt
    px = c[0] - cx
    py = c[1] - cy
    rr = math.sqrt(px * px + py * py)
    if rr > 0.0:
        nrm[0], nrm[1], nrm[2] = px / rr, py / rr, 0.0
    else:
        nrm[0], nrm[1], nrm[2] = 1.0, 0.0, 0.0
    return radius - rmax


@njit(cache=True)
def plane_wall_contact(kind, h, x, R, axis, coord, side, manifold_tol, nrm, c):
    """Signed gap between a body and the planar wall ``x[axis] = coord``; ``side = +1`` for a
    wall on the high side (the body lies below it), ``-1`` on the low side. ``nrm`` is the unit
    normal from the body into the wall (``side * e_axis``); ``c`` the centroid of the body's
    support feature towards the wall."""
    for k in range(3):
        nrm[k] = 0.0
    nrm[axis] = side
    f = np.empty((DISC_SIDES, 3))
    m = _feature(kind, h, x, R, nrm, manifold_tol, f, np.empty((DISC_SIDES, 3)))
    for k in range(3):
        c[k] = 0.0
        for r in range(m):
            c[k] += f[r, k]
        c[k] /= m
    sp = np.empty(3)
    _support_lab(kind, h, x, R, False, nrm, sp)
    return side * (coord - sp[axis])


# ------------------------------------------------------------------------------------------------
# broad phase


@njit(cache=True)
def _cell_setup(x, cs, lo, hi, periodic):
    n = x.shape[0]
    nc = np.ones(3, dtype=np.int64)
    org = np.zeros(3)
    width = np.zeros(3)
    for a in range(3):
        if periodic[a]:
            L = hi[a] - lo[a]
            nc[a] = max(1, int(math.floor(L / cs)))
            org[a] = lo[a]
            width[a] = L / nc[a]
        else:
            mn = 1e300
            mx = -1e300
            for i in range(n):
                mn = min(mn, x[i, a])
                mx = max(mx, x[i, a])
            if n == 0:
                mn, mx = 0.0, 0.0
            nc[a] = max(1, min(1024, int(math.floor((mx - mn) / cs)) + 1))
            org[a] = mn
            width[a] = max(cs, (mx - mn) / nc[a] * (1.0 + 1e-12))
    return nc, org, width


@njit(cache=True, inline="always")
def _image_offset(d0, d1, d2, L0, L1, L2, p0, p1, p2):
    # minimum-image shift (s0, s1, s2) of the separation d on the periodic axes, and the squared
    # distance after it (scalars only: no array reference counting in the pair loops)
    s0 = -L0 * math.floor(d0 / L0 + 0.5) if p0 else 0.0
    s1 = -L1 * math.floor(d1 / L1 + 0.5) if p1 else 0.0
    s2 = -L2 * math.floor(d2 / L2 + 0.5) if p2 else 0.0
    d0 += s0
    d1 += s1
    d2 += s2
    return s0, s1, s2, d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, inline="always")
def _cell_index(x, i, nc, org, width, periodic):
    # flat cell of body i (periodic axes wrapped, others clamped)
    idx = 0
    for a in range(3):
        t = (x[i, a] - org[a]) / width[a]
        ia = int(math.floor(t))
        if periodic[a]:
            ia %= nc[a]
        else:
            ia = min(nc[a] - 1, max(0, ia))
        idx = idx * nc[a] + ia
    return idx


@njit(cache=True)
def _stencil(nc, periodic):
    """The cell offsets the pair scan visits per axis, in its order (``offs[a, :noff[a]]``):
    -1, 0, 1; on a periodic axis of two cells 0, 1 (-1 is +1 there), of one cell 0."""
    noff = np.empty(3, dtype=np.int64)
    offs = np.empty((3, 3), dtype=np.int64)
    for a in range(3):
        if periodic[a] and nc[a] == 2:
            noff[a] = 2
            offs[a, 0], offs[a, 1] = 0, 1
        elif periodic[a] and nc[a] == 1:
            noff[a] = 1
            offs[a, 0] = 0
        else:
            noff[a] = 3
            offs[a, 0], offs[a, 1], offs[a, 2] = -1, 0, 1
    return noff, offs


@njit(cache=True)
def _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, fill, pi, pj, ps):
    n = x.shape[0]
    L = np.empty(3)
    for a in range(3):
        L[a] = hi[a] - lo[a]
    noff, offs = _stencil(nc, periodic)
    cnt = 0
    ci = np.empty(3, dtype=np.int64)
    for i in range(n):
        c = cell_of[i]
        ci[2] = c % nc[2]
        ci[1] = (c // nc[2]) % nc[1]
        ci[0] = c // (nc[1] * nc[2])
        for o0 in range(noff[0]):
            a0 = ci[0] + offs[0, o0]
            if periodic[0]:
                a0 %= nc[0]
            elif a0 < 0 or a0 >= nc[0]:
                continue
            for o1 in range(noff[1]):
                a1 = ci[1] + offs[1, o1]
                if periodic[1]:
                    a1 %= nc[1]
                elif a1 < 0 or a1 >= nc[1]:
                    continue
                for o2 in range(noff[2]):
                    a2 = ci[2] + offs[2, o2]
                    if periodic[2]:
                        a2 %= nc[2]
                    elif a2 < 0 or a2 >= nc[2]:
                        continue
                    cc = (a0 * nc[1] + a1) * nc[2] + a2
                    for t in range(start[cc], start[cc + 1]):
                        j = members[t]
                        if j <= i:
                            continue
                        s0, s1, s2, dd = _image_offset(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                                                       L[0], L[1], L[2], periodic[0], periodic[1], periodic[2])
                        cut = rb[i] + rb[j] + margin
                        if dd <= cut * cut:
                            if fill:
                                pi[cnt] = i
                                pj[cnt] = j
                                ps[cnt, 0], ps[cnt, 1], ps[cnt, 2] = s0, s1, s2
                            cnt += 1
    return cnt


@njit(cache=True)
def candidate_pairs(x, rb, margin, lo, hi, periodic):
    """Pairs (i < j) whose bounding spheres (radii ``rb``) come within ``margin`` of each other,
    by a cell list; ``periodic[a]`` wraps axis a over ``[lo[a], hi[a])`` and returns the
    minimum-image shift of body j (``x[j] + shift``). Returns (pi, pj, shift)."""
    n = x.shape[0]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, rb[i])
    cs = 2.0 * rmax + margin
    nc, org, width = _cell_setup(x, cs, lo, hi, periodic)
    ncell = nc[0] * nc[1] * nc[2]
    cell_of = np.empty(n, dtype=np.int64)
    for i in range(n):
        cell_of[i] = _cell_index(x, i, nc, org, width, periodic)
    start = np.zeros(ncell + 1, dtype=np.int64)
    for i in range(n):
        start[cell_of[i] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    members = np.empty(n, dtype=np.int64)
    pos = start[:-1].copy()
    for i in range(n):
        members[pos[cell_of[i]]] = i
        pos[cell_of[i]] += 1
    dummy_i = np.empty(0, dtype=np.int64)
    dummy_s = np.empty((0, 3))
    cnt = _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, False, dummy_i, dummy_i, dummy_s)
    pi = np.empty(cnt, dtype=np.int64)
    pj = np.empty(cnt, dtype=np.int64)
    ps = np.empty((cnt, 3))
    _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, True, pi, pj, ps)
    return pi, pj, ps


@njit(cache=True)
def neighbour_list(x, rb, margin, lo, hi, periodic):
    """Verlet list for ``listed_pairs``: the ``candidate_pairs`` of ``margin`` as CSR, the
    partners ``j > i`` of body i in ``js[start[i]:start[i + 1]]``."""
    pi, pj, _ = candidate_pairs(x, rb, margin, lo, hi, periodic)
    n = x.shape[0]
    start = np.zeros(n + 1, dtype=np.int64)
    for m in range(pi.shape[0]):
        start[pi[m] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    return start, pj


@njit(cache=True)
def listed_pairs(x, rb, margin, lo, hi, periodic, start, js):
    """``candidate_pairs(x, rb, margin, lo, hi, periodic)``, the same pairs, shifts and order,
    taken from a neighbour list (``neighbour_list``) that holds every pair of them: one built for
    a margin ``M`` at positions that every body has since left by at most ``d``, with
    ``margin + 2 d <= M``. A pair's bounding spheres then came within ``M`` of each other when
    the list was built. The test of each listed pair is the cell scan's, and the pairs of a body
    are put in the scan's order (its stencil of cells in turn, a cell's bodies by index), so the
    contacts, and the Gauss-Seidel order of the impulses, are those of ``candidate_pairs``: a
    list kept over time steps looks at ~6 listed partners a body instead of the ~55 bodies the
    scan visits (244 dense 8 mm cylinders) and changes no result."""
    pi, pj, ps, _slot = listed_slots(x, rb, margin, lo, hi, periodic, start, js)
    return pi, pj, ps


@njit(cache=True)
def listed_slots(x, rb, margin, lo, hi, periodic, start, js):
    """``listed_pairs`` and, for each pair, its slot t in the list (``js[t]`` is its j): where the
    collision step keeps what it learns of a pair from one step to the next."""
    n = x.shape[0]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, rb[i])
    nc, org, width = _cell_setup(x, 2.0 * rmax + margin, lo, hi, periodic)
    cell = np.empty((n, 3), dtype=np.int64)
    for i in range(n):
        c = _cell_index(x, i, nc, org, width, periodic)
        cell[i, 2] = c % nc[2]
        cell[i, 1] = (c // nc[2]) % nc[1]
        cell[i, 0] = c // (nc[1] * nc[2])
    noff, offs = _stencil(nc, periodic)
    # the stencil position of a cell difference d on each axis, looked up (-1: not visited): the
    # collision step took 1.01-1.02 times as long with a search by modulo per listed pair
    nmax = max(nc[0], max(nc[1], nc[2]))
    pos = np.full((3, 2 * nmax - 1), -1, dtype=np.int64)
    for a in range(3):
        for d in range(1 - nc[a], nc[a]):
            for u in range(noff[a]):
                if (d - offs[a, u]) % nc[a] == 0 if periodic[a] else d == offs[a, u]:
                    pos[a, d + nmax - 1] = u
                    break
    L = np.empty(3)
    for a in range(3):
        L[a] = hi[a] - lo[a]
    cap = js.shape[0]
    pi = np.empty(cap, dtype=np.int64)
    pj = np.empty(cap, dtype=np.int64)
    ps = np.empty((cap, 3))
    key = np.empty(cap, dtype=np.int64)
    slot = np.empty(cap, dtype=np.int64)
    cnt = 0
    for i in range(n):
        first = cnt
        for t in range(start[i], start[i + 1]):
            j = js[t]
            # the cell scan's stencil position of j's cell (_stencil), or none: the scan does
            # not look there
            st = 0
            for a in range(3):
                o = pos[a, cell[j, a] - cell[i, a] + nmax - 1]
                if o < 0:
                    st = -1
                    break
                st = st * 3 + o
            if st < 0:
                continue
            s0, s1, s2, dd = _image_offset(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                                           L[0], L[1], L[2], periodic[0], periodic[1], periodic[2])
            cut = rb[i] + rb[j] + margin
            if dd <= cut * cut:
                # insertion by (stencil position, j): a handful of pairs per body
                k = st * n + j
                u = cnt
                while u > first and key[u - 1] > k:
                    key[u] = key[u - 1]
                    pi[u] = i
                    pj[u] = pj[u - 1]
                    ps[u, 0], ps[u, 1], ps[u, 2] = ps[u - 1, 0], ps[u - 1, 1], ps[u - 1, 2]
                    slot[u] = slot[u - 1]
                    u -= 1
                key[u] = k
                pi[u] = i
                pj[u] = j
                ps[u, 0], ps[u, 1], ps[u, 2] = s0, s1, s2
                slot[u] = t
                cnt += 1
    return pi[:cnt], pj[:cnt], ps[:cnt], slot[:cnt]


@njit(cache=True)
def list_displacement(x, xref, lo, hi, periodic):
    """How far the bodies have moved relative to each other since ``xref``: the largest distance
    of a body's displacement (minimum image on periodic axes: the drift wraps positions into the
    period) from a shift c common to all, or from none if that is less. A pair's distance changes
    by at most |d_i - d_j| <= |d_i - c| + |d_j - c|, so a list built for a margin M holds every
    pair within ``margin`` while ``margin + 2 * list_displacement <= M``. The common shift is the
    middle of the displacements' range on each axis: in the pipe the suspension is carried along z
    at about 0.1 lattice units a step, and measured from their positions at the build the bodies
    left a list of 1 unit's skin every ~6 steps (244 dense 8 mm cylinders)."""
    L0, L1, L2 = hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]
    n = x.shape[0]
    d = np.empty((n, 3))
    dmax = 0.0
    for i in range(n):
        s0, s1, s2, dd = _image_offset(x[i, 0] - xref[i, 0], x[i, 1] - xref[i, 1], x[i, 2] - xref[i, 2],
                                       L0, L1, L2, periodic[0], periodic[1], periodic[2])
        d[i, 0] = x[i, 0] - xref[i, 0] + s0
        d[i, 1] = x[i, 1] - xref[i, 1] + s1
        d[i, 2] = x[i, 2] - xref[i, 2] + s2
        dmax = max(dmax, dd)
    if n == 0:
        return 0.0
    c = np.empty(3)
    for a in range(3):
        c[a] = 0.5 * (d[:, a].min() + d[:, a].max())
    cmax = 0.0
    for i in range(n):
        cmax = max(cmax, (d[i, 0] - c[0]) ** 2 + (d[i, 1] - c[1]) ** 2 + (d[i, 2] - c[2]) ** 2)
    return math.sqrt(min(dmax, cmax))


@njit(cache=True)
def bounding_radii(kind, h):
    """``bounding_radius`` of each body (N,)."""
    n = kind.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = bounding_radius(kind[i], h[i])
    return out


# ------------------------------------------------------------------------------------------------
# Python conveniences (tests, set-up; not for the time loop)


def _matrix(q) -> np.ndarray:
    # no renormalisation: the kernels use the stored unit quaternions as they are, and the same
    # input must give the same contact bit for bit
    q = np.asarray(q, dtype=np.float64)
    if abs(float(q @ q) - 1.0) > 1e-9:
        raise ValueError(f"quaternion {q} is not a unit quaternion")
    return quat_to_matrix(q)


def contact_pair(kind1, h1, x1, q1, kind2, h2, x2, q2, manifold_tol: float = 0.1, max_gap: float = np.inf):
    """Signed gap, unit normal (1 -> 2) and contact point of two bodies given by unit quaternions."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = body_contact(
        int(kind1), np.asarray(h1, np.float64), np.asarray(x1, np.float64), _matrix(q1),
        int(kind2), np.asarray(h2, np.float64), np.asarray(x2, np.float64), _matrix(q2),
        float(max_gap), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c


def contact_pipe(kind, h, x, q, radius: float, center=(0.0, 0.0), manifold_tol: float = 0.1):
    """Signed gap to the pipe wall, outward radial normal and contact point of one body."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = pipe_wall_contact(
        int(kind), np.asarray(h, np.float64), np.asarray(x, np.float64), _matrix(q),
        float(radius), float(center[0]), float(center[1]), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c


def contact_plane(kind, h, x, q, axis: int, coord: float, side: int, manifold_tol: float = 0.1):
    """Signed gap to the planar wall ``x[axis] = coord`` (``side`` +1: wall above the body)."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = plane_wall_contact(
        int(kind), np.asarray(h, np.float64), np.asarray(x, np.float64), _matrix(q),
        int(axis), float(coord), float(side), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c
