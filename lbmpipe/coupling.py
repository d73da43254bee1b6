"""Rigid particles on the lattice, coupled both ways to the fluid: Ladd's moving bounce-back,
Eqs. (8)-(12), with an implicit particle-velocity update, and the rigid-body motion of
Eqs. (13)-(15) (``lbmpipe.rigid``).

Everything here is in lattice units (dx = dt = 1, reference density ``rho0 = 1``).

Nodes and owners
----------------
Every lattice node is exactly one of: static wall (``owner = -2``; the grid's walls and the z
padding), fluid (``owner = -1``) or particle ``k`` (``owner = k >= 0``). A node belongs to a
particle when its centre lies in the closed shape (``shapes.inside_body``). The rules for nodes
that two things claim:

* wall beats particle: a particle that reaches into the pipe wall simply has no nodes there, so a
  link crossing both a particle and the wall is a wall link (``boundaries.py``) from the fluid side
  and does not exist from the particle side (particle-wall pairs of nodes exchange nothing);
* a fixed particle keeps all its nodes; a node keeps its owner while the owner still covers it;
  a node covered by several free particles (only where they overlap, which the collision model
  prevents) goes to the first one found, deterministically.

A per-node coverage count (how many particle shapes contain the node) makes these updates local:
only nodes whose count changes are looked at.

Each particle's nodes are stored as column runs: over the (x, y) columns of the particle's
axis-aligned bounding box, the z-interval of node centres inside the shape, found analytically
(ray-box slabs for a cube, ray-cylinder for a cylinder, ray-sphere) in the body frame. A convex
shape meets each column in one interval. Runs use unwrapped indices around the particle's centre
(so relative vectors are the minimum image without any rounding) and are wrapped into memory by
small lookup tables; particle centres are kept inside the periodic box (wrapped after each move,
the runs shifted with them). A particle's bounding diameter must be at least two nodes shorter than every periodic length.

Links and the coupling, Eqs. (8)-(12)
-------------------------------------
A boundary link joins a fluid node ``x`` to a node ``s = x + e_i`` of particle ``k``. Links are
found from the runs: for direction ``i`` and a column of the particle, the candidates are the run
nodes whose ``x`` is not in the particle's run of the neighbouring column (at most two
sub-intervals), each kept if ``owner[s] == k`` and ``owner[x] == -1``. So there is no Python
loop and no per-node search; each particle is one iteration of a ``prange`` loop.

Per link (as for walls, ``boundaries.py``: the pull of direction ``opp(i)`` at ``x`` reads the
slot ``(opp(i), s)`` of ``f``), Ladd's rule Eq. (8) with ``B_i = 3 rho0 w_i``:

    f[opp(i), s] = f*_i(x) - 6 w_i rho0 (e_i . u_b),   u_b = U + Omega x r,  r = x + e_i/2 - X,

the force on the particle Eq. (9), ``F = 2 e_i [f*_i(x) - 3 w_i rho0 (e_i . u_b)]``, its torque
Eq. (10) ``r x F``, summed over the links, Eqs. (11)-(12). ``X`` is the centre of mass; relative
vectors are minimum images on periodic axes.

Implicit velocity update (stability at density ratio 1)
-------------------------------------------------------
The link force is linear in the particle's own velocity. Summed over the links,

    (F, T) = (F0, T0) - Z (U, Omega),      F0 = sum 2 e_i f*_i(x),   T0 = sum r x 2 e_i f*_i(x),
    Z = sum_links 6 w_i rho0 [e_i; r x e_i] [e_i; r x e_i]^T     (6 x 6, symmetric, >= 0),

and an explicit update ``M dU = F`` is unstable once ``Z`` exceeds the particle's mass (light or
small particles; neutrally buoyant particles without interior fluid are at the limit). The
velocities are therefore advanced implicitly in the self-friction (Lowe, Frenkel & Masters 1995;
Nguyen & Ladd 2002):

    (M + Z dt) V' = M V + (F0 + F_ext + P, T0 + L_P) dt,     V = (U, Omega_lab),

with ``M = diag(m, m, m, I_lab)``, ``I_lab = A diag(I) A^T``, ``F_ext`` the external force and
``(P, L_P)`` the impulse of the nodes covered and uncovered in the previous move (below). The
ghost fill then uses the *new* velocity ``V'``, so the force the fluid feels is exactly minus
the force the particle receives, ``(F0, T0) - Z V'``: fluid + particles conserve momentum to
round-off. Sums are taken per link direction over each column's run in closed form (count, sum of
z, sum of z^2, sum of f and of f z), so ``Z`` costs a few operations per link.

Time step (``dt = 1``): ``pre``: links at ``X(t)`` -> ``F0, T0, Z`` -> ``V(t+1)`` -> ghost fill;
fluid sweep; ``post``: free rigid-body motion ``rigid.drift_arrays`` over one step with ``V(t+1)``
(``x += v``, the torque-free rotation of Eqs. (13)-(15) that carries the gyroscopic term and keeps
``|q| = 1``), remap. The kick is the implicit angular-momentum update ``L' = L + T dt`` in the lab
frame at the current orientation, then the drift: first order in time, like the link coupling
itself.

No interior fluid
-----------------
Particle nodes carry no fluid (Aidun, Lu & Ding 1998): their populations are swept by the fluid
kernel like any node but are never read by the fluid, because each slot a fluid node pulls from a
particle node is overwritten by the ghost fill first. They are excluded from every observable.

Covering and uncovering (momentum accounting)
---------------------------------------------
After the move, for each node whose coverage changed:

* a fluid node now covered by particle ``k`` is removed from the fluid; its momentum
  ``j = sum_i f_i e_i`` (post-collision, the fluid's) is given to ``k``: ``P_k += j``,
  ``L_P += r x j``;
* a node of particle ``k`` no longer covered becomes fluid, filled with the equilibrium Eq. (3) at
  the local surface velocity ``u_b = U + Omega x r`` and the mean density of its fluid neighbours
  that were fluid before the move (``rho0`` if there are none); the particle pays the momentum:
  ``P_k -= rho u_b``, ``L_P -= r x rho u_b``;
* a node passed from one particle to another holds no fluid: nothing is exchanged.

``(P, L_P)`` enters the next implicit update, so fluid + particles conserve total momentum exactly
(``ParticleSystem.total_momentum``). Mass is not conserved exactly by a moving particle (covered
nodes take their mass with them and uncovered ones get the neighbours' density), a known property
of Ladd's scheme; the change averages out as a particle moves on.

External forces on particles
----------------------------
* The flow's driving body force stands for a pressure gradient, which pushes on the particle
  volume too: a particle gets ``f_drive V_p`` (force density times its volume).
* Optional gravity ``g`` acts on the particle's excess mass, ``(rho_p - rho_f) V_p g``; the fluid
  carries no gravity (its hydrostatic pressure would only add the buoyancy already subtracted).
``V_p`` is the geometric volume (``shapes.volume``), as is the mass ``rho_p V_p``.

Flow-rate control with particles
--------------------------------
The fluid kernel's flux sum runs over particle nodes too. ``ParticleFluxCorrection`` replaces
their contribution by the particles' own volume flux, ``sum_k n_k U_z,k`` (``n_k`` nodes), so the
flow-rate controller holds the volumetric flow rate of the mixture.

Fixed particles
---------------
Mapped once: their links are precomputed (flat indices, direction, lever arm) and each step only
the bounce-back fill ``f[opp(i), s] = f*_i(x)`` and the force/torque sums run, skipping links
whose fluid node a free particle currently covers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from . import effects as fx
from .rigid import Bodies, _rot, drift_arrays, quat_to_matrix
from .shapes import CUBE, CYLINDER, SPHERE, bounding_radius, volume

WALL = -2
FLUID = -1
#: directions with |e_x + e_y| = 0 contribute to the column itself
_EPS_DIR = 1e-12


# ----------------------------------------------------------------------------------------------
# Geometry: column runs


@njit(cache=True)
def _slab(p, d, hh, t0, t1):
    # Interval of t with |p + t d| <= hh, intersected with [t0, t1]; empty -> t0 > t1.
    if abs(d) < _EPS_DIR:
        if abs(p) > hh:
            return 1.0, 0.0
        return t0, t1
    inv = 1.0 / d
    a = (-hh - p) * inv
    b = (hh - p) * inv
    if a > b:
        a, b = b, a
    return max(t0, a), min(t1, b)


@njit(cache=True)
def _disc(px, py, dx, dy, r, t0, t1):
    # Interval of t with (px + t dx)^2 + (py + t dy)^2 <= r^2, intersected with [t0, t1].
    a = dx * dx + dy * dy
    c = px * px + py * py - r * r
    if a < _EPS_DIR:
        if c > 0.0:
            return 1.0, 0.0
        return t0, t1
    b = px * dx + py * dy
    disc = b * b - a * c
    if disc < 0.0:
        return 1.0, 0.0
    sq = math.sqrt(disc)
    return max(t0, (-b - sq) / a), min(t1, (-b + sq) / a)


@njit(cache=True)
def ray_interval(kind, h, px, py, pz, dx, dy, dz):
    """Interval ``[t0, t1]`` of ``t`` with the body-frame point ``p + t d`` inside the closed
    shape (``t0 > t1``: the line misses it)."""
    big = 1e300
    if kind == SPHERE:
        # |p + t d|^2 <= r^2 with |d| = 1
        b = px * dx + py * dy + pz * dz
        c = px * px + py * py + pz * pz - h[0] * h[0]
        disc = b * b - c
        if disc < 0.0:
            return 1.0, 0.0
        sq = math.sqrt(disc)
        return -b - sq, -b + sq
    if kind == CYLINDER:
        t0, t1 = _slab(pz, dz, h[2], -big, big)
        if t0 > t1:
            return t0, t1
        return _disc(px, py, dx, dy, h[0], t0, t1)
    t0, t1 = _slab(px, dx, h[0], -big, big)
    t0, t1 = _slab(py, dy, h[1], t0, t1)
    return _slab(pz, dz, h[2], t0, t1)


@njit(cache=True)
def _half_extents_xy(kind, h, a):
    # Half-extents along lab x and y of the rotated shape (its tight axis-aligned box).
    out = np.empty(2)
    for r in range(2):
        if kind == SPHERE:
            out[r] = h[0]
        elif kind == CYLINDER:
            c = abs(a[r, 2])
            out[r] = c * h[2] + h[0] * math.sqrt(max(0.0, 1.0 - c * c))
        else:
            out[r] = abs(a[r, 0]) * h[0] + abs(a[r, 1]) * h[1] + abs(a[r, 2]) * h[2]
    return out


@njit(parallel=True, cache=True)
def compute_runs(ids, kind, h, x, q, origin, dims, periodic, run_off, rect, z1, z2):
    """Column runs of the particles ``ids`` at centres ``x`` (unwrapped) and orientations ``q``:
    ``rect[k] = (a0, b0, na, nb)`` (first column, unwrapped, and extents) and, for column
    ``(a0 + ca, b0 + cb)``, the node interval ``[z1, z2]`` at ``run_off[k] + ca nb + cb``
    (``z1 > z2`` if empty)."""
    for m in prange(ids.shape[0]):
        k = ids[m]
        A = quat_to_matrix(q[k])
        ext = _half_extents_xy(kind[k], h[k], A)
        lo = np.empty(2, np.int64)
        n = np.empty(2, np.int64)
        for r in range(2):
            c_lo = int(math.ceil(x[k, r] - ext[r] - origin[r]))
            c_hi = int(math.floor(x[k, r] + ext[r] - origin[r]))
            if not periodic[r]:
                c_lo = max(c_lo, 0)
                c_hi = min(c_hi, dims[r] - 1)
            lo[r] = c_lo
            n[r] = max(0, c_hi - c_lo + 1)
        cap = run_off[k + 1] - run_off[k]
        if n[0] * n[1] > cap:  # cannot happen: capacity is from the bounding radius
            n[0] = 0
            n[1] = 0
        rect[k, 0] = lo[0]
        rect[k, 1] = lo[1]
        rect[k, 2] = n[0]
        rect[k, 3] = n[1]
        # body-frame direction of the lab z axis: A^T e_z
        dx, dy, dz = A[2, 0], A[2, 1], A[2, 2]
        base = run_off[k]
        nz = dims[2]
        for ca in range(n[0]):
            px = origin[0] + lo[0] + ca - x[k, 0]
            for cb in range(n[1]):
                py = origin[1] + lo[1] + cb - x[k, 1]
                bx = A[0, 0] * px + A[1, 0] * py
                by = A[0, 1] * px + A[1, 1] * py
                bz = A[0, 2] * px + A[1, 2] * py
                t0, t1 = ray_interval(kind[k], h[k], bx, by, bz, dx, dy, dz)
                c = base + ca * n[1] + cb
                if t0 > t1:
                    z1[c] = 1
                    z2[c] = 0
                    continue
                za = int(math.ceil(x[k, 2] + t0 - origin[2]))
                zb = int(math.floor(x[k, 2] + t1 - origin[2]))
                if not periodic[2]:
                    za = max(za, 0)
                    zb = min(zb, nz - 1)
                z1[c] = za
                z2[c] = zb


@njit(cache=True)
def _covers(k, node, rect, run_off, z1, z2, dims, az, periodic):
    """Does particle ``k``'s run set contain memory node ``node``?"""
    ny = dims[1]
    a = node // (ny * az)
    b = (node // az) % ny
    zi = node % az
    ca = a - rect[k, 0]
    cb = b - rect[k, 1]
    if periodic[0]:
        ca %= dims[0]
    if periodic[1]:
        cb %= dims[1]
    if ca < 0 or ca >= rect[k, 2] or cb < 0 or cb >= rect[k, 3]:
        return False
    c = run_off[k] + ca * rect[k, 3] + cb
    lo = z1[c]
    hi = z2[c]
    if lo > hi:
        return False
    if periodic[2]:
        return (zi - lo) % dims[2] <= hi - lo
    return lo <= zi <= hi


@njit(cache=True)
def mark_initial(order, rect, run_off, z1, z2, xmap, ymap, zmap, dims, az, owner, count):
    """Set the coverage count and the owners of all particles, in ``order`` (fixed ones first):
    the first particle to claim a free node owns it."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    for m in range(order.shape[0]):
        k = order[m]
        base = run_off[k]
        nb = rect[k, 3]
        for ca in range(rect[k, 2]):
            a = xmap[rect[k, 0] + ca + nx]
            for cb in range(nb):
                b = ymap[rect[k, 1] + cb + ny]
                c = base + ca * nb + cb
                col = (a * ny + b) * az
                for z in range(z1[c], z2[c] + 1):
                    node = col + zmap[z + nz]
                    if owner[node] == WALL:
                        continue
                    count[node] += 1
                    if owner[node] == FLUID:
                        owner[node] = k


# ----------------------------------------------------------------------------------------------
# Per-step link work for free particles


@njit(cache=True, inline="always")
def _candidates(s1, s2, w1, w2):
    # [s1, s2] minus [w1, w2] as (lo1, hi1, lo2, hi2); empty parts have lo > hi.
    if w1 > w2 or w2 < s1 or w1 > s2:
        return s1, s2, 1, 0
    return s1, min(s2, w1 - 1), max(s1, w2 + 1), s2


@njit(parallel=True, cache=True, fastmath=True)
def free_accumulate(f2, owner, ids, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, origin, x,
                    e, w, rho0, g0, zmat):
    """Pass 1 over the links of the free particles ``ids``: ``g0[k] = (F0, T0)`` (the velocity-free
    parts of Eqs. (9)-(12)) and the 6x6 self-friction ``zmat[k]`` (module docstring)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for m in prange(ids.shape[0]):
        k = ids[m]
        a0 = rect[k, 0]
        b0 = rect[k, 1]
        na = rect[k, 2]
        nb = rect[k, 3]
        base = run_off[k]
        G = np.zeros(6)
        Z = np.zeros((6, 6))
        S = np.zeros((3, 3))
        E = np.zeros((3, 3))
        for i in range(1, Q):
            exi = e[i, 0]
            eyi = e[i, 1]
            ezi = e[i, 2]
            cnt = 0.0
            rx_s = 0.0
            ry_s = 0.0
            rz_s = 0.0
            sxx = 0.0
            syy = 0.0
            szz = 0.0
            sxy = 0.0
            sxz = 0.0
            syz = 0.0
            sf = 0.0
            sfx = 0.0
            sfy = 0.0
            sfz = 0.0
            c0 = origin[2] - 0.5 * ezi - x[k, 2]
            for ca in range(na):
                na_ = ca - exi
                a = a0 + ca
                sa = xmap[a + nx]
                xa = xmap[a - exi + nx]
                rx = origin[0] + a - 0.5 * exi - x[k, 0]
                for cb in range(nb):
                    c = base + ca * nb + cb
                    s1 = z1[c]
                    s2 = z2[c]
                    if s1 > s2:
                        continue
                    nb_ = cb - eyi
                    if na_ >= 0 and na_ < na and nb_ >= 0 and nb_ < nb:
                        cn = base + na_ * nb + nb_
                        w1 = z1[cn] + ezi
                        w2 = z2[cn] + ezi
                    else:
                        w1 = 1
                        w2 = 0
                    lo1, hi1, lo2, hi2 = _candidates(s1, s2, w1, w2)
                    if lo1 > hi1 and lo2 > hi2:
                        continue
                    b = b0 + cb
                    sbase = (sa * ny + ymap[b + ny]) * az
                    xbase = (xa * ny + ymap[b - eyi + ny]) * az
                    ry = origin[1] + b - 0.5 * eyi - x[k, 1]
                    n = 0.0
                    sz = 0.0
                    sz2 = 0.0
                    sff = 0.0
                    sfzz = 0.0
                    for part in range(2):
                        lo = lo1 if part == 0 else lo2
                        hi = hi1 if part == 0 else hi2
                        for z in range(lo, hi + 1):
                            if owner[sbase + zmap[z + nz]] != k:
                                continue
                            xn = xbase + zmap[z - ezi + nz]
                            if owner[xn] != FLUID:
                                continue
                            fv = f2[i, xn]
                            zf = float(z)
                            n += 1.0
                            sz += zf
                            sz2 += zf * zf
                            sff += fv
                            sfzz += fv * zf
                    if n == 0.0:
                        continue
                    rzn = c0 * n + sz
                    cnt += n
                    rx_s += rx * n
                    ry_s += ry * n
                    rz_s += rzn
                    sxx += rx * rx * n
                    syy += ry * ry * n
                    sxy += rx * ry * n
                    sxz += rx * rzn
                    syz += ry * rzn
                    szz += c0 * c0 * n + 2.0 * c0 * sz + sz2
                    sf += sff
                    sfx += rx * sff
                    sfy += ry * sff
                    sfz += c0 * sff + sfzz
            if cnt == 0.0:
                continue
            fe = float(exi)
            fey = float(eyi)
            fez = float(ezi)
            # F0 = sum 2 e f;  T0 = sum r x 2 e f = 2 (sum f r) x e
            G[0] += 2.0 * fe * sf
            G[1] += 2.0 * fey * sf
            G[2] += 2.0 * fez * sf
            G[3] += 2.0 * (sfy * fez - sfz * fey)
            G[4] += 2.0 * (sfz * fe - sfx * fez)
            G[5] += 2.0 * (sfx * fey - sfy * fe)
            c6 = 6.0 * w[i] * rho0
            ev = (fe, fey, fez)
            # R x e (sum over links of r x e)
            rxe0 = ry_s * fez - rz_s * fey
            rxe1 = rz_s * fe - rx_s * fez
            rxe2 = rx_s * fey - ry_s * fe
            rxe = (rxe0, rxe1, rxe2)
            for p in range(3):
                for r in range(3):
                    Z[p, r] += c6 * cnt * ev[p] * ev[r]
                    Z[p, 3 + r] += c6 * ev[p] * rxe[r]
            # sum (r x e)(r x e)^T = E S E^T with E = [e]_x
            S[0, 0] = sxx
            S[1, 1] = syy
            S[2, 2] = szz
            S[0, 1] = sxy
            S[1, 0] = sxy
            S[0, 2] = sxz
            S[2, 0] = sxz
            S[1, 2] = syz
            S[2, 1] = syz
            E[0, 1] = -fez
            E[0, 2] = fey
            E[1, 0] = fez
            E[1, 2] = -fe
            E[2, 0] = -fey
            E[2, 1] = fe
            # r x e = -E r, so (r x e)(r x e)^T = E r r^T E^T
            for p in range(3):
                for r in range(3):
                    acc = 0.0
                    for s in range(3):
                        for t in range(3):
                            acc += E[p, s] * S[s, t] * E[r, t]
                    Z[3 + p, 3 + r] += c6 * acc
        for p in range(3):
            for r in range(3):
                Z[3 + r, p] = Z[p, 3 + r]
        for p in range(6):
            g0[k, p] = G[p]
            for r in range(6):
                zmat[k, p, r] = Z[p, r]


@njit(parallel=True, cache=True, fastmath=True)
def free_fill(f2, owner, ids, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, origin, x, v, om,
              e, w, opp, rho0):
    """Pass 2: Ladd's ghost fill Eq. (8) on every link of the free particles ``ids``, with the
    (new) velocity ``v`` and lab angular velocity ``om``."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for m in prange(ids.shape[0]):
        k = ids[m]
        a0 = rect[k, 0]
        b0 = rect[k, 1]
        na = rect[k, 2]
        nb = rect[k, 3]
        base = run_off[k]
        ox, oy, oz = om[k, 0], om[k, 1], om[k, 2]
        for i in range(1, Q):
            exi = e[i, 0]
            eyi = e[i, 1]
            ezi = e[i, 2]
            fe = float(exi)
            fey = float(eyi)
            fez = float(ezi)
            oi = opp[i]
            c6 = 6.0 * w[i] * rho0
            eu = fe * v[k, 0] + fey * v[k, 1] + fez * v[k, 2]
            c0 = origin[2] - 0.5 * ezi - x[k, 2]
            for ca in range(na):
                na_ = ca - exi
                a = a0 + ca
                sa = xmap[a + nx]
                xa = xmap[a - exi + nx]
                rx = origin[0] + a - 0.5 * exi - x[k, 0]
                for cb in range(nb):
                    c = base + ca * nb + cb
                    s1 = z1[c]
                    s2 = z2[c]
                    if s1 > s2:
                        continue
                    nb_ = cb - eyi
                    if na_ >= 0 and na_ < na and nb_ >= 0 and nb_ < nb:
                        cn = base + na_ * nb + nb_
                        w1 = z1[cn] + ezi
                        w2 = z2[cn] + ezi
                    else:
                        w1 = 1
                        w2 = 0
                    lo1, hi1, lo2, hi2 = _candidates(s1, s2, w1, w2)
                    if lo1 > hi1 and lo2 > hi2:
                        continue
                    b = b0 + cb
                    sbase = (sa * ny + ymap[b + ny]) * az
                    xbase = (xa * ny + ymap[b - eyi + ny]) * az
                    ry = origin[1] + b - 0.5 * eyi - x[k, 1]
                    # e . u_b = e.U + Omega . (r x e), linear in z: alpha + beta z
                    alpha = eu + ox * (ry * fez - c0 * fey) + oy * (c0 * fe - rx * fez) + oz * (rx * fey - ry * fe)
                    beta = -ox * fey + oy * fe
                    for part in range(2):
                        lo = lo1 if part == 0 else lo2
                        hi = hi1 if part == 0 else hi2
                        for z in range(lo, hi + 1):
                            sn = sbase + zmap[z + nz]
                            if owner[sn] != k:
                                continue
                            xn = xbase + zmap[z - ezi + nz]
                            if owner[xn] != FLUID:
                                continue
                            f2[oi, sn] = f2[i, xn] - c6 * (alpha + beta * z)


@njit(cache=True)
def _solve6(K, rhs):
    # Gaussian elimination with partial pivoting of a 6x6 system (K is SPD here).
    n = 6
    M = np.empty((n, n + 1))
    for p in range(n):
        for r in range(n):
            M[p, r] = K[p, r]
        M[p, n] = rhs[p]
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if piv != col:
            for c in range(n + 1):
                t = M[col, c]
                M[col, c] = M[piv, c]
                M[piv, c] = t
        d = M[col, col]
        for r in range(col + 1, n):
            fct = M[r, col] / d
            if fct != 0.0:
                for c in range(col, n + 1):
                    M[r, c] -= fct * M[col, c]
    out = np.empty(n)
    for r in range(n - 1, -1, -1):
        acc = M[r, n]
        for c in range(r + 1, n):
            acc -= M[r, c] * out[c]
        out[r] = acc / M[r, r]
    return out


@njit(parallel=True, cache=True)
def implicit_update(ids, mass, inertia, q, v, wb, g0, zmat, fext, imp, om_out, force, torque):
    """Implicit velocity update ``(M + Z) V' = M V + G`` (module docstring) of the free particles
    ``ids``; writes ``v``, ``wb``, the lab angular velocity ``om_out`` and the hydrodynamic force
    and torque of the step, ``(F0, T0) - Z V' + impulses``; clears the impulses ``imp``."""
    for m in prange(ids.shape[0]):
        k = ids[m]
        A = quat_to_matrix(q[k])
        K = np.zeros((6, 6))
        rhs = np.empty(6)
        for p in range(3):
            K[p, p] = mass[k]
            rhs[p] = mass[k] * v[k, p] + g0[k, p] + fext[k, p] + imp[k, p]
        # lab inertia A diag(I) A^T and lab angular momentum A (I wb)
        for p in range(3):
            for r in range(3):
                acc = 0.0
                for s in range(3):
                    acc += A[p, s] * inertia[k, s] * A[r, s]
                K[3 + p, 3 + r] = acc
        for p in range(3):
            acc = 0.0
            for s in range(3):
                acc += A[p, s] * inertia[k, s] * wb[k, s]
            rhs[3 + p] = acc + g0[k, 3 + p] + fext[k, 3 + p] + imp[k, 3 + p]
        for p in range(6):
            for r in range(6):
                K[p, r] += zmat[k, p, r]
        V = _solve6(K, rhs)
        for p in range(3):
            v[k, p] = V[p]
            om_out[k, p] = V[3 + p]
        for p in range(3):  # wb = A^T Omega
            wb[k, p] = A[0, p] * V[3] + A[1, p] * V[4] + A[2, p] * V[5]
        for p in range(3):
            fz = 0.0
            tz = 0.0
            for r in range(6):
                fz += zmat[k, p, r] * V[r]
                tz += zmat[k, 3 + p, r] * V[r]
            force[k, p] = g0[k, p] - fz + imp[k, p]
            torque[k, p] = g0[k, 3 + p] - tz + imp[k, 3 + p]
        for p in range(6):
            imp[k, p] = 0.0


@njit(cache=True)
def _accumulate(ids, force, torque, force_sum, torque_sum, n_sum):
    for m in range(ids.shape[0]):
        k = ids[m]
        for p in range(3):
            force_sum[k, p] += force[k, p]
            torque_sum[k, p] += torque[k, p]
        n_sum[k] += 1


# ----------------------------------------------------------------------------------------------
# Fixed particles: links mapped once


@njit(cache=True)
def _fixed_links_pass(ids, is_fixed, owner, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, e, origin, x,
                      off, lx, ls, li, lr, store):
    # Links from nodes outside a fixed particle's runs into nodes it owns. Wall nodes and nodes of
    # other fixed particles never hold fluid; nodes of free particles may later (checked per step).
    nx, ny, nz = dims[0], dims[1], dims[2]
    counts = np.zeros(ids.shape[0], np.int64)
    for m in range(ids.shape[0]):
        k = ids[m]
        a0, b0, na, nb = rect[k, 0], rect[k, 1], rect[k, 2], rect[k, 3]
        base = run_off[k]
        cnt = off[m] if store else 0
        for i in range(1, e.shape[0]):
            exi, eyi, ezi = e[i, 0], e[i, 1], e[i, 2]
            for ca in range(na):
                for cb in range(nb):
                    c = base + ca * nb + cb
                    s1, s2 = z1[c], z2[c]
                    if s1 > s2:
                        continue
                    na_, nb_ = ca - exi, cb - eyi
                    if 0 <= na_ < na and 0 <= nb_ < nb:
                        cn = base + na_ * nb + nb_
                        w1, w2 = z1[cn] + ezi, z2[cn] + ezi
                    else:
                        w1, w2 = 1, 0
                    lo1, hi1, lo2, hi2 = _candidates(s1, s2, w1, w2)
                    a, b = a0 + ca, b0 + cb
                    sbase = (xmap[a + nx] * ny + ymap[b + ny]) * az
                    xbase = (xmap[a - exi + nx] * ny + ymap[b - eyi + ny]) * az
                    for part in range(2):
                        lo = lo1 if part == 0 else lo2
                        hi = hi1 if part == 0 else hi2
                        for z in range(lo, hi + 1):
                            sn = sbase + zmap[z + nz]
                            if owner[sn] != k:
                                continue
                            xn = xbase + zmap[z - ezi + nz]
                            ox = owner[xn]
                            if ox == WALL or (ox >= 0 and is_fixed[ox]):
                                continue
                            if store:
                                lx[cnt] = xn
                                ls[cnt] = sn
                                li[cnt] = i
                                lr[cnt, 0] = origin[0] + a - 0.5 * exi - x[k, 0]
                                lr[cnt, 1] = origin[1] + b - 0.5 * eyi - x[k, 1]
                                lr[cnt, 2] = origin[2] + z - 0.5 * ezi - x[k, 2]
                            cnt += 1
        counts[m] = cnt - (off[m] if store else 0)
    return counts


def map_fixed_links(ids, is_fixed, owner, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, e, origin, x):
    """Links of the fixed particles ``ids`` as CSR arrays ``(off, x, s, i, r)`` (flat fluid node,
    flat particle node, direction, lever arm ``x + e_i/2 - X``)."""
    args = (ids, is_fixed, owner, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, e, origin, x)
    empty = (np.zeros(len(ids) + 1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
             np.zeros(0, np.int64), np.zeros((0, 3)))
    counts = _fixed_links_pass(*args, *empty, False)
    off = np.zeros(len(ids) + 1, np.int64)
    off[1:] = np.cumsum(counts)
    tot = int(off[-1])
    lx, ls, li, lr = np.zeros(tot, np.int64), np.zeros(tot, np.int64), np.zeros(tot, np.int64), np.zeros((tot, 3))
    _fixed_links_pass(*args, off, lx, ls, li, lr, True)
    return off, lx, ls, li, lr


@njit(parallel=True, cache=True, fastmath=True)
def fixed_fill(f2, owner, off, lx, ls, li, lr, e, opp, force, torque, ids):
    """Half-way bounce-back on the precomputed links of fixed particles (Eq. (8) with u_b = 0)
    and their force and torque, Eqs. (9)-(12)."""
    for m in prange(ids.shape[0]):
        k = ids[m]
        fx_ = 0.0
        fy_ = 0.0
        fz_ = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        for l in range(off[m], off[m + 1]):
            xn = lx[l]
            if owner[xn] != FLUID:
                continue
            i = li[l]
            fv = f2[i, xn]
            f2[opp[i], ls[l]] = fv
            gx = 2.0 * e[i, 0] * fv
            gy = 2.0 * e[i, 1] * fv
            gz = 2.0 * e[i, 2] * fv
            fx_ += gx
            fy_ += gy
            fz_ += gz
            tx += lr[l, 1] * gz - lr[l, 2] * gy
            ty += lr[l, 2] * gx - lr[l, 0] * gz
            tz += lr[l, 0] * gy - lr[l, 1] * gx
        force[k, 0] = fx_
        force[k, 1] = fy_
        force[k, 2] = fz_
        torque[k, 0] = tx
        torque[k, 1] = ty
        torque[k, 2] = tz


# ----------------------------------------------------------------------------------------------
# Remap after a move: coverage changes, owners, covered/uncovered momentum


@njit(parallel=True, cache=True)
def diff_runs(ids, run_off, rect_o, z1o, z2o, rect_n, z1n, z2n, xmap, ymap, zmap, dims, az, chg_off,
              chg_node, chg_d, chg_n):
    """Nodes each moved particle leaves (-1) and enters (+1): per column of the union of its old
    and new boxes, old run minus new run and vice versa (both unwrapped in the same frame)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    for m in prange(ids.shape[0]):
        k = ids[m]
        base = run_off[k]
        ao, bo, nao, nbo = rect_o[k, 0], rect_o[k, 1], rect_o[k, 2], rect_o[k, 3]
        an, bn, nan, nbn = rect_n[k, 0], rect_n[k, 1], rect_n[k, 2], rect_n[k, 3]
        a_lo = min(ao, an) if nao > 0 and nan > 0 else (ao if nao > 0 else an)
        a_hi = max(ao + nao, an + nan) if nao > 0 and nan > 0 else (ao + nao if nao > 0 else an + nan)
        b_lo = min(bo, bn) if nbo > 0 and nbn > 0 else (bo if nbo > 0 else bn)
        b_hi = max(bo + nbo, bn + nbn) if nbo > 0 and nbn > 0 else (bo + nbo if nbo > 0 else bn + nbn)
        cnt = chg_off[m]
        for a in range(a_lo, a_hi):
            for b in range(b_lo, b_hi):
                o1 = 1
                o2 = 0
                if ao <= a < ao + nao and bo <= b < bo + nbo:
                    c = base + (a - ao) * nbo + (b - bo)
                    o1 = z1o[c]
                    o2 = z2o[c]
                n1 = 1
                n2 = 0
                if an <= a < an + nan and bn <= b < bn + nbn:
                    c = base + (a - an) * nbn + (b - bn)
                    n1 = z1n[c]
                    n2 = z2n[c]
                if o1 > o2 and n1 > n2:
                    continue
                if o1 == n1 and o2 == n2:
                    continue
                col = (xmap[a + nx] * ny + ymap[b + ny]) * az
                # left: old \ new
                if o1 <= o2:
                    l1, h1, l2, h2 = _candidates(o1, o2, n1, n2)
                    for z in range(l1, h1 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = -1
                        cnt += 1
                    for z in range(l2, h2 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = -1
                        cnt += 1
                if n1 <= n2:
                    l1, h1, l2, h2 = _candidates(n1, n2, o1, o2)
                    for z in range(l1, h1 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = 1
                        cnt += 1
                    for z in range(l2, h2 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = 1
                        cnt += 1
        chg_n[m] = cnt - chg_off[m]


@njit(cache=True)
def _node_vector(node, xk, origin, dims, az, periodic):
    # Minimum-image vector from the centre xk to the node's centre.
    ny = dims[1]
    a = node // (ny * az)
    b = (node // az) % ny
    zi = node % az
    r = np.empty(3)
    r[0] = origin[0] + a - xk[0]
    r[1] = origin[1] + b - xk[1]
    r[2] = origin[2] + zi - xk[2]
    for d in range(3):
        if periodic[d]:
            L = float(dims[d])
            r[d] -= L * math.floor(r[d] / L + 0.5)
    return r


@njit(cache=True)
def apply_changes(ids, chg_off, chg_node, chg_d, chg_n, all_ids, rect, run_off, z1, z2, dims, az, periodic,
                  origin, x, v, om, owner, count, touched, acq, touch_list, unc_list, unc_old, f2, e, w, opp,
                  xmap, ymap, zmap, rho0, imp):
    """Apply the coverage changes and settle owners (module docstring): momentum of covered
    nodes to the particle, uncovered nodes refilled at the surface velocity. Returns
    ``(n_covered, n_uncovered)``. Serial: the changes are few (surface nodes that moved)."""
    nt = 0
    for m in range(ids.shape[0]):
        k = ids[m]
        for c in range(chg_off[m], chg_off[m] + chg_n[m]):
            node = chg_node[c]
            if owner[node] == WALL:
                continue
            d = chg_d[c]
            count[node] += d
            if d > 0:
                acq[node] = k
            if not touched[node]:
                touched[node] = True
                touch_list[nt] = node
                nt += 1
    Q = e.shape[0]
    n_cov = 0
    n_unc = 0
    for t in range(nt):
        node = touch_list[t]
        old = owner[node]
        new = FLUID
        if count[node] > 0:
            if old >= 0 and _covers(old, node, rect, run_off, z1, z2, dims, az, periodic):
                new = old
            else:
                cand = acq[node]
                if cand >= 0 and _covers(cand, node, rect, run_off, z1, z2, dims, az, periodic):
                    new = cand
                else:
                    for j in range(all_ids.shape[0]):
                        kk = all_ids[j]
                        if _covers(kk, node, rect, run_off, z1, z2, dims, az, periodic):
                            new = kk
                            break
                    if new == FLUID:  # inconsistent count (cannot happen): trust the geometry
                        count[node] = 0
        acq[node] = -1
        if new == old:
            continue
        if old == FLUID:
            # fluid node swallowed: its momentum goes to the particle
            r = _node_vector(node, x[new], origin, dims, az, periodic)
            jx = 0.0
            jy = 0.0
            jz = 0.0
            for i in range(Q):
                fv = f2[i, node]
                jx += e[i, 0] * fv
                jy += e[i, 1] * fv
                jz += e[i, 2] * fv
            imp[new, 0] += jx
            imp[new, 1] += jy
            imp[new, 2] += jz
            imp[new, 3] += r[1] * jz - r[2] * jy
            imp[new, 4] += r[2] * jx - r[0] * jz
            imp[new, 5] += r[0] * jy - r[1] * jx
            n_cov += 1
        elif new == FLUID:
            unc_list[n_unc] = node
            unc_old[n_unc] = old
            n_unc += 1
        owner[node] = new
    nx, ny, nz = dims[0], dims[1], dims[2]
    for u in range(n_unc):
        node = unc_list[u]
        k = unc_old[u]
        a = node // (ny * az)
        b = (node // az) % ny
        zi = node % az
        rho = 0.0
        nn = 0
        for i in range(1, Q):
            nb = (xmap[a + e[i, 0] + nx] * ny + ymap[b + e[i, 1] + ny]) * az + zmap[zi + e[i, 2] + nz]
            if owner[nb] == FLUID and not touched[nb]:
                s = 0.0
                for j in range(Q):
                    s += f2[j, nb]
                rho += s
                nn += 1
        rho = rho / nn if nn > 0 else rho0
        r = _node_vector(node, x[k], origin, dims, az, periodic)
        ux = v[k, 0] + om[k, 1] * r[2] - om[k, 2] * r[1]
        uy = v[k, 1] + om[k, 2] * r[0] - om[k, 0] * r[2]
        uz = v[k, 2] + om[k, 0] * r[1] - om[k, 1] * r[0]
        usq = 1.5 * (ux * ux + uy * uy + uz * uz)
        for i in range(Q):
            eu = e[i, 0] * ux + e[i, 1] * uy + e[i, 2] * uz
            f2[i, node] = w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq)
        px = rho * ux
        py = rho * uy
        pz = rho * uz
        imp[k, 0] -= px
        imp[k, 1] -= py
        imp[k, 2] -= pz
        imp[k, 3] -= r[1] * pz - r[2] * py
        imp[k, 4] -= r[2] * px - r[0] * pz
        imp[k, 5] -= r[0] * py - r[1] * px
    for t in range(nt):
        touched[touch_list[t]] = False
    return n_cov, n_unc


@njit(cache=True)
def wrap_positions(ids, x, lo, dims, periodic, rect, run_off, z1, z2):
    """Bring centres back into the periodic box and shift their runs by the same whole number of
    periods."""
    for m in range(ids.shape[0]):
        k = ids[m]
        for d in range(3):
            if not periodic[d]:
                continue
            L = float(dims[d])
            s = math.floor((x[k, d] - lo[d]) / L)
            if s == 0:
                continue
            x[k, d] -= s * L
            shift = int(s) * dims[d]
            if d < 2:
                rect[k, d] -= shift
            else:
                for c in range(run_off[k], run_off[k] + rect[k, 2] * rect[k, 3]):
                    z1[c] -= shift
                    z2[c] -= shift


# ----------------------------------------------------------------------------------------------
# Flux correction and observables


@njit(parallel=True, cache=True)
def particle_node_flux(f2, owner, ids, run_off, rect, z1, z2, xmap, ymap, zmap, dims, az, ez, out_j, out_n):
    """Per particle: the z-momentum ``sum_i e_iz f_i`` held by its nodes (``out_j``) and their
    number (``out_n``)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = ez.shape[0]
    for m in prange(ids.shape[0]):
        k = ids[m]
        base = run_off[k]
        nb = rect[k, 3]
        j = 0.0
        cnt = 0
        for ca in range(rect[k, 2]):
            a = xmap[rect[k, 0] + ca + nx]
            for cb in range(nb):
                c = base + ca * nb + cb
                col = (a * ny + ymap[rect[k, 1] + cb + ny]) * az
                for z in range(z1[c], z2[c] + 1):
                    node = col + zmap[z + nz]
                    if owner[node] != k:
                        continue
                    cnt += 1
                    for i in range(Q):
                        if ez[i] != 0:
                            j += ez[i] * f2[i, node]
        out_j[k] = j
        out_n[k] = cnt


@njit(parallel=True, cache=True)
def _fluid_momentum(f2, owner, e):
    n = owner.shape[0]
    Q = e.shape[0]
    nchunk = 64
    part = np.zeros((nchunk, 4))
    for c in prange(nchunk):
        lo = c * n // nchunk
        hi = (c + 1) * n // nchunk
        for node in range(lo, hi):
            if owner[node] != FLUID:
                continue
            for i in range(Q):
                fv = f2[i, node]
                part[c, 0] += fv
                part[c, 1] += e[i, 0] * fv
                part[c, 2] += e[i, 1] * fv
                part[c, 3] += e[i, 2] * fv
    return part.sum(axis=0)


# ----------------------------------------------------------------------------------------------
# The particle system and its effects


def _wrap_table(n: int, periodic: bool) -> np.ndarray:
    i = np.arange(-n, 2 * n)
    return (i % n if periodic else np.clip(i, 0, n - 1)).astype(np.int64)


class ParticleSystem:
    """Rigid bodies on a grid: owner map, runs, links, forces (lattice units).

    ``bodies`` (``rigid.Bodies``) is updated in place. ``gravity`` (3,) acts on each particle's
    excess mass ``(rho_p - rho0) V_p``; the flow's body force density acts on ``V_p``.
    """

    def __init__(self, grid, bodies: Bodies, gravity=(0.0, 0.0, 0.0), rho0: float = 1.0):
        self.grid = grid
        self.bodies = bodies
        self.rho0 = float(rho0)
        lat = grid.lattice
        self.e = np.ascontiguousarray(lat.e.astype(np.int64))
        self.w = np.ascontiguousarray(lat.w.astype(np.float64))
        self.opp = np.ascontiguousarray(lat.opp.astype(np.int64))
        nx, ny, nz = grid.shape
        self.dims = np.array([nx, ny, nz], dtype=np.int64)
        self.az = int(grid.alloc_z)
        self.periodic = np.array(grid.periodic, dtype=np.bool_)
        pos = grid.positions()
        self.origin = np.array([p[0] for p in pos], dtype=np.float64)
        self.lo = self.origin - 0.5
        self.xmap = _wrap_table(nx, grid.periodic[0])
        self.ymap = _wrap_table(ny, grid.periodic[1])
        self.zmap = _wrap_table(nz, grid.periodic[2])
        n = bodies.n
        self.n = n
        self.vol = np.array([volume(bodies.kind[k], bodies.h[k]) for k in range(n)], dtype=np.float64)
        self.gravity = np.asarray(gravity, dtype=np.float64).reshape(3)
        rb = np.array([bounding_radius(bodies.kind[k], bodies.h[k]) for k in range(n)], dtype=np.float64)
        self.rb = rb
        span = (2.0 * rb).astype(np.int64) + 2
        for d in range(3):
            # a node must not belong to a particle's runs twice (through the periodic image)
            if grid.periodic[d] and n and span.max() > self.dims[d]:
                raise ValueError(f"a particle's bounding diameter ({2 * rb.max():.3g} nodes) must be below the "
                                 f"periodic length along {'xyz'[d]} ({self.dims[d]} nodes) minus 2")
        self.run_off = np.zeros(n + 1, dtype=np.int64)
        self.run_off[1:] = np.cumsum(span * span)
        ncol = int(self.run_off[-1])
        self.rect = np.zeros((n, 4), np.int64)
        self.z1 = np.ones(ncol, np.int64)
        self.z2 = np.zeros(ncol, np.int64)
        self.rect_n = np.zeros((n, 4), np.int64)
        self.z1_n = np.ones(ncol, np.int64)
        self.z2_n = np.zeros(ncol, np.int64)
        self.fixed_ids = np.flatnonzero(bodies.fixed).astype(np.int64)
        self.free_ids = np.flatnonzero(~bodies.fixed).astype(np.int64)
        self.all_ids = np.concatenate([self.fixed_ids, self.free_ids])
        # change buffers of moving particles: a column changes by at most its old + new run
        cap = 2 * (span * span * span)[self.free_ids]
        self.chg_off = np.zeros(len(self.free_ids) + 1, np.int64)
        self.chg_off[1:] = np.cumsum(cap)
        tot = int(self.chg_off[-1])
        self.chg_node = np.zeros(tot, np.int64)
        self.chg_d = np.zeros(tot, np.int8)
        self.chg_n = np.zeros(len(self.free_ids), np.int64)
        self.touch_list = np.zeros(max(tot, 1), np.int64)
        self.unc_list = np.zeros(max(tot, 1), np.int64)
        self.unc_old = np.zeros(max(tot, 1), np.int64)
        # node state
        size = nx * ny * self.az
        owner = np.full((nx, ny, self.az), WALL, dtype=np.int32)
        owner[:, :, :nz][grid.fluid] = FLUID
        self.owner = owner.reshape(-1)
        self.count = np.zeros(size, np.int16)
        self.touched = np.zeros(size, np.bool_)
        self.acq = np.full(size, -1, np.int64)
        # dynamics
        self.g0 = np.zeros((n, 6))
        self.zmat = np.zeros((n, 6, 6))
        self.fext = np.zeros((n, 6))
        self.imp = np.zeros((n, 6))
        self.om = np.zeros((n, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.force_sum = np.zeros((n, 3))
        self.torque_sum = np.zeros((n, 3))
        self.n_sum = np.zeros(n, np.int64)
        self.node_j = np.zeros(n)
        self.node_n = np.zeros(n, np.int64)
        self.last_cover = (0, 0)
        self._map_all()
        self._map_fixed_links()
        self._update_omega()

    # -- set-up --------------------------------------------------------------------------------
    def _runs(self, ids, rect, z1, z2):
        b = self.bodies
        compute_runs(ids, b.kind, b.h, b.x, b.q, self.origin, self.dims, self.periodic, self.run_off, rect, z1, z2)

    def _map_all(self):
        b = self.bodies
        # centres into the periodic box first
        for d in range(3):
            if self.periodic[d]:
                b.x[:, d] = self.lo[d] + np.mod(b.x[:, d] - self.lo[d], self.dims[d])
        self._runs(self.all_ids, self.rect, self.z1, self.z2)
        self.rect_n[:] = self.rect
        self.z1_n[:] = self.z1
        self.z2_n[:] = self.z2
        mark_initial(self.all_ids, self.rect, self.run_off, self.z1, self.z2, self.xmap, self.ymap, self.zmap,
                     self.dims, self.az, self.owner, self.count)

    def _map_fixed_links(self):
        b = self.bodies
        self.fix_off, self.fix_x, self.fix_s, self.fix_i, self.fix_r = map_fixed_links(
            self.fixed_ids, b.fixed, self.owner, self.run_off, self.rect, self.z1, self.z2, self.xmap, self.ymap,
            self.zmap, self.dims, self.az, self.e, self.origin, b.x)

    def _update_omega(self):
        from .rigid import omega_lab_arrays

        self.om[:] = omega_lab_arrays(self.bodies.q, self.bodies.wb)

    # -- per step ------------------------------------------------------------------------------
    def fill_fixed(self, f2):
        if len(self.fixed_ids):
            fixed_fill(f2, self.owner, self.fix_off, self.fix_x, self.fix_s, self.fix_i, self.fix_r, self.e,
                       self.opp, self.force, self.torque, self.fixed_ids)
            _accumulate(self.fixed_ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)

    def couple_free(self, f2, body_force):
        """Links -> implicit velocity update -> ghost fill (the ``pre`` work of free particles)."""
        ids = self.free_ids
        if not len(ids):
            return
        b = self.bodies
        free_accumulate(f2, self.owner, ids, self.run_off, self.rect, self.z1, self.z2, self.xmap, self.ymap,
                        self.zmap, self.dims, self.az, self.origin, b.x, self.e, self.w, self.rho0, self.g0, self.zmat)
        fb = np.asarray(body_force, dtype=np.float64)
        self.fext[:, :3] = self.vol[:, None] * (fb[None, :] + (b.mass / self.vol - self.rho0)[:, None] * self.gravity)
        implicit_update(ids, b.mass, b.inertia, b.q, b.v, b.wb, self.g0, self.zmat, self.fext, self.imp, self.om,
                        self.force, self.torque)
        free_fill(f2, self.owner, ids, self.run_off, self.rect, self.z1, self.z2, self.xmap, self.ymap, self.zmap,
                  self.dims, self.az, self.origin, b.x, b.v, self.om, self.e, self.w, self.opp, self.rho0)
        _accumulate(ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)

    def take_mean_force(self):
        """Mean hydrodynamic force and torque (lab) on each particle over the steps since the last
        call, (N, 3) each (the last step's values if no step ran)."""
        n = self.n_sum[:, None]
        f = np.where(n > 0, self.force_sum / np.maximum(n, 1), self.force)
        t = np.where(n > 0, self.torque_sum / np.maximum(n, 1), self.torque)
        self.force_sum[:] = 0.0
        self.torque_sum[:] = 0.0
        self.n_sum[:] = 0
        return f, t

    def node_flux(self, f2):
        """Per particle: z-momentum held by its nodes in ``f2`` and their count."""
        particle_node_flux(f2, self.owner, self.all_ids, self.run_off, self.rect, self.z1, self.z2, self.xmap,
                           self.ymap, self.zmap, self.dims, self.az, np.ascontiguousarray(self.e[:, 2]),
                           self.node_j, self.node_n)
        return self.node_j, self.node_n

    def move(self, f2):
        """Free motion over one step with the new velocities, then remap (``post`` work)."""
        ids = self.free_ids
        if not len(ids):
            return
        b = self.bodies
        drift_arrays(b.x, b.v, b.q, b.wb, b.inertia, b.fixed, 1.0)
        self._runs(ids, self.rect_n, self.z1_n, self.z2_n)
        diff_runs(ids, self.run_off, self.rect, self.z1, self.z2, self.rect_n, self.z1_n, self.z2_n, self.xmap,
                  self.ymap, self.zmap, self.dims, self.az, self.chg_off, self.chg_node, self.chg_d, self.chg_n)
        # the new orientation's lab angular velocity (the drift turned wb with the body)
        self._update_omega()
        self.last_cover = apply_changes(
            ids, self.chg_off, self.chg_node, self.chg_d, self.chg_n, self.all_ids, self.rect_n, self.run_off,
            self.z1_n, self.z2_n, self.dims, self.az, self.periodic, self.origin, b.x, b.v, self.om, self.owner,
            self.count, self.touched, self.acq, self.touch_list, self.unc_list, self.unc_old, f2, self.e, self.w,
            self.opp, self.xmap, self.ymap, self.zmap, self.rho0, self.imp)
        wrap_positions(ids, b.x, self.lo, self.dims, self.periodic, self.rect_n, self.run_off, self.z1_n, self.z2_n)
        self.rect, self.rect_n = self.rect_n, self.rect
        self.z1, self.z1_n = self.z1_n, self.z1
        self.z2, self.z2_n = self.z2_n, self.z2

    # -- observables ---------------------------------------------------------------------------
    def covered(self) -> np.ndarray:
        """(nx, ny, nz) bool: nodes that belong to a particle."""
        nx, ny, nz = self.dims
        return (self.owner.reshape(nx, ny, self.az)[:, :, :nz] >= 0).copy()

    def fluid_mask(self) -> np.ndarray:
        """(nx, ny, nz) bool: fluid nodes (neither wall nor particle)."""
        nx, ny, nz = self.dims
        return self.owner.reshape(nx, ny, self.az)[:, :, :nz] == FLUID

    def fluid_momentum(self, f2) -> np.ndarray:
        """(mass, px, py, pz) of the fluid nodes in ``f2`` (post-collision populations)."""
        return _fluid_momentum(f2, self.owner, self.e)

    def total_momentum(self, f2) -> np.ndarray:
        """Fluid + particle momentum (3,), counting the impulses not yet applied to particles."""
        b = self.bodies
        p = self.fluid_momentum(f2)[1:].copy()
        free = ~b.fixed
        p += (b.mass[free, None] * b.v[free]).sum(axis=0)
        p += self.imp[free, :3].sum(axis=0)
        return p

    def omega_lab(self) -> np.ndarray:
        from .rigid import omega_lab_arrays

        return omega_lab_arrays(self.bodies.q, self.bodies.wb)


# ----------------------------------------------------------------------------------------------
# Effects


class FixedParticles(fx.Effect):
    """Fixed particles: half-way bounce-back on their precomputed links, force and torque."""

    name = "particles: fixed obstacles (bounce-back, force)"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.fill_fixed(sim.f2)


class ParticleCoupling(fx.Effect):
    """Free particles: link sums, implicit velocity update, Ladd's ghost fill (Eqs. (8)-(12))."""

    name = "particles: Ladd coupling + implicit velocity update"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.couple_free(sim.f2, sim.force)


class ParticleFluxCorrection(fx.Effect):
    """Flow-rate control with particles: the kernel's flux sum minus the particle nodes' share,
    plus the particles' volume flux (the mixture's flow rate). Runs before the controller."""

    name = "particles: flow-rate flux correction"
    phase = "post"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        s = self.system
        j, n = s.node_flux(sim.f_next.reshape(sim.lattice.q, -1))
        # kernel summed (streamed j_z + F_z/2) = (post-collision j_z - F_z/2) per node
        fz = float(sim.force[2])
        sim.last_flux += -(j.sum() - 0.5 * fz * n.sum()) + float(np.dot(n, s.bodies.v[:, 2]))


class ParticleMotion(fx.Effect):
    """Rigid-body drift (Eqs. (13)-(15)) of the free particles and the remap with the momentum of
    covered and uncovered nodes."""

    name = "particles: motion + remap (cover/uncover)"
    phase = "post"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.move(sim.f_next.reshape(sim.lattice.q, -1))


class BouzidiParticleGuard(fx.Effect):
    """With interpolated walls: a wall link whose second fluid node (x - e_i) is covered by a
    particle falls back to plain bounce-back (its populations are not fluid)."""

    name = "particles: interpolated-wall guard"
    phase = "pre"

    def __init__(self, system: ParticleSystem, links):
        sel = (links.q < 0.5) & (links.fluid2 >= 0)
        self.system = system
        self.fluid = links.fluid[sel]
        self.fluid2 = links.fluid2[sel]
        self.solid = links.solid[sel]
        self.i = links.i[sel]
        self.opp = links.opp[sel]

    def __call__(self, sim) -> None:
        _bouzidi_guard(sim.f2, self.system.owner, self.fluid, self.fluid2, self.solid, self.i, self.opp)


@njit(parallel=True, cache=True)
def _bouzidi_guard(f2, owner, fluid, fluid2, solid, i, opp):
    for k in prange(len(i)):
        if owner[fluid2[k]] >= 0 and owner[fluid[k]] == FLUID:
            f2[opp[k], solid[k]] = f2[i[k], fluid[k]]


def particle_effects(system: ParticleSystem, flux_control: bool = False, bouzidi_links=None):
    """The effects a particle system needs, and nothing else: ``(pre, post_before_control,
    post_after_control)``. The flux correction must run after the sweep and before the flow-rate
    controller; the motion changes the owner map, so it comes after the correction."""
    pre: list[fx.Effect] = []
    if bouzidi_links is not None and len(bouzidi_links) and system.n:
        pre.append(BouzidiParticleGuard(system, bouzidi_links))
    if len(system.fixed_ids):
        pre.append(FixedParticles(system))
    if len(system.free_ids):
        pre.append(ParticleCoupling(system))
    before = [ParticleFluxCorrection(system)] if flux_control and system.n else []
    after = [ParticleMotion(system)] if len(system.free_ids) else []
    return pre, before, after
