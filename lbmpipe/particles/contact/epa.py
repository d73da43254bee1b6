"""EPA (expanding polytope): penetration depth, normal and witness points of two overlapping bodies."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .support import _cross_into, _dot, _support_lab

EPA_MAX_VERTS = 128
EPA_MAX_FACES = 4 * EPA_MAX_VERTS
EPA_REL_TOL = 1e-7


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
    bn = np.empty(3)
    while True:
        best = -1
        bd = 1e301
        for f in range(nf):
            if alive[f] and FD[f] < bd:
                bd = FD[f]
                best = f
        if best < 0:
            return -1.0
        # the closest face, kept aside: the answer if the expansion stops here (the table moves)
        fa = F[best, 0]
        fb = F[best, 1]
        fc = F[best, 2]
        for k in range(3):
            d[k] = FN[best, k]
            bn[k] = d[k]
        _support_lab(k1, h1, x1, R1, False, d, sa)
        for k in range(3):
            d[k] = -d[k]
        _support_lab(k2, h2, x2, R2, False, d, sb)
        sd = (sa[0] - sb[0]) * bn[0] + (sa[1] - sb[1]) * bn[1] + (sa[2] - sb[2]) * bn[2]
        if sd - bd <= tol or nv >= EPA_MAX_VERTS:
            break
        iv = nv
        for k in range(3):
            V[iv, k] = sa[k] - sb[k]
            VA[iv, k] = sa[k]
            VB[iv, k] = sb[k]
        nv += 1
        # the faces the new vertex sees die; the edges of their boundary (the horizon) get new faces
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
        # On a convex polytope the horizon is one loop of at most nv edges, but round-off on a
        # curved surface sampled this finely can make the visible faces a patchwork with many
        # more: the table is checked against ne itself, never against a count it may exceed.
        if nf + ne > EPA_MAX_FACES:
            m = 0  # drop the dead faces, keeping the order of the live ones
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
            if nf + ne > EPA_MAX_FACES:
                break  # no room: the closest face found so far stands
        for r in range(ne):
            _epa_face(V, F, FN, FD, nf, edges[r, 0], edges[r, 1], iv, scale)
            alive[nf] = True
            nf += 1
    # witness points from the barycentric coordinates of the origin's projection on the face
    depth = bd
    a = fa
    b = fb
    c = fc
    px = depth * bn[0]
    py = depth * bn[1]
    pz = depth * bn[2]
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
        nrm[k] = bn[k]
        pa[k] = la * VA[a, k] + lb * VA[b, k] + lc * VA[c, k]
        pb[k] = la * VB[a, k] + lb * VB[b, k] + lc * VB[c, k]
    return max(depth, 0.0)
