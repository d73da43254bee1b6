"""Rigid particles on the lattice, coupled both ways to the fluid: Ladd's moving bounce-back,
Eqs. (8)-(12), with an implicit particle-velocity update, and the rigid-body motion of
Eqs. (13)-(15) (``lbmpipe.particles.rigid``).

Everything here is in lattice units (dx = dt = 1, reference density ``rho0 = 1``).

Nodes and owners
----------------
Every lattice node is exactly one of: static wall (``owner = -2``; the grid's walls and the z
padding), fluid (``owner = -1``) or particle ``k`` (``owner = k >= 0``). A node belongs to a
particle when its centre lies in the closed shape. Rules for nodes that two things claim:

* wall beats particle: a particle reaching into the pipe wall has no nodes there. A link that
  crosses both a particle and the wall is therefore a wall link seen from the fluid node
  (``boundaries.py`` fills it); particle and wall nodes exchange nothing;
* a fixed particle keeps its nodes; a node keeps its owner while the owner still covers it; a node
  covered by several free particles (only where they overlap, which the collision model prevents)
  goes to the first one found, deterministically.

Particle nodes as column runs. Over the (x, y) columns of a particle's axis-aligned bounding box,
the z-interval of node centres inside the shape is found analytically in the body frame (ray-slab
for a cube, ray-cylinder, ray-sphere); a convex shape meets a column in one interval. Runs use
unwrapped indices around the particle's centre, so relative vectors are minimum images without
rounding; lookup tables wrap them into memory. Centres are kept in the periodic box (wrapped
after each move, runs and lever arms shifted by whole periods). A particle's bounding diameter
must be at least two nodes shorter than every periodic length. A per-node coverage count (how many
particle shapes contain the node) makes a move local: only nodes whose count changes are visited
(the old and new runs of a column differ in a few nodes at the ends).

Links, kept up to date
----------------------
A boundary link joins a fluid node ``x`` to a particle node ``s = x + e_i``; the set of links is a
function of the owner map alone, ``{(x, s, i): owner[s] >= 0, owner[x] = -1}``. Each particle keeps
its links in one list per direction, a 16-byte record per link (fluid node, particle node, and the
particle node's lattice coordinates unwrapped in the particle's frame, which give the link midpoint
``x + e_i/2`` exactly). Owners change only in ``_set_owners``, which appends the links an owner
change creates (a node joining a particle: links from its fluid neighbours; a node becoming fluid:
links into its particle neighbours) and marks the node as changed. Links an owner change ends are
deleted lazily: each step's first pass over a list swap-removes the entries with ``owner[s] != k``
or ``owner[x] != -1``, testing only links with a node marked since the previous pass (no other
link can have died); the marks are cleared after the passes. So the live entries always equal the
definition and nothing searches for links; a move costs about a thousand owner changes per step
for the paper's 115 cubes. Fixed and free particles share the lists.

Coupling, Eqs. (8)-(12)
-----------------------
As for walls (``boundaries.py``), the pull of direction ``opp(i)`` at ``x`` reads slot
``(opp(i), s)`` of ``f``; Ladd's rule Eq. (8) with ``B_i = 3 rho0 w_i`` writes there

    f[opp(i), s] = f*_i(x) - 6 w_i rho0 (e_i . u_b),   u_b = U + Omega x r,  r = x + e_i/2 - X,

and the link force Eq. (9) is ``F = 2 e_i [f*_i(x) - 3 w_i rho0 (e_i . u_b)]``, its torque
Eq. (10) ``r x F``, summed over the links, Eqs. (11)-(12).

Reference pressure (contacts). The force sums use ``f*_i(x) - w_i rho0`` in place of ``f*_i(x)``.
The constant ``2 e_i w_i rho0`` (the uniform pressure ``rho0 c_s^2``) sums to zero force and torque
over a closed set of links (a lattice line through a convex particle enters it once and leaves it
once), so nothing changes for a particle surrounded by fluid. Where links are missing because the
neighbour node is another particle or the wall, Eq. (9) taken literally leaves the uniform pressure
acting on the exposed surface only: two 8-node cubes face to face attract with ``64/3`` lattice
force units and accelerate by 0.04 per step. Without the reference part the missing links carry
the reference pressure, balanced by the contact (or the wall). Between two particles the removed
parts are equal and opposite (both see the same missing link), so fluid + particles still conserve
momentum exactly; against a wall the wall takes it, as it takes any wall force. The ghost fill
Eq. (8) itself is unchanged.

Implicit velocity update (stability at density ratio 1)
-------------------------------------------------------
The link force is linear in the particle's own velocity. Summed over the links,

    (F, T) = (F0, T0) - Z (U, Omega),   F0 = sum 2 e_i (f*_i(x) - w_i rho0),  T0 = sum r x (same),
    Z = sum_links 6 w_i rho0 [e_i; r x e_i] [e_i; r x e_i]^T     (6 x 6, symmetric, >= 0),

and an explicit update ``M dU = F`` is unstable once ``Z`` is comparable to the particle's mass
(light or small particles; neutrally buoyant particles without interior fluid). Velocities are
therefore advanced implicitly in this self-friction (Lowe, Frenkel & Masters 1995; Nguyen & Ladd
2002):

    (M + Z dt) V' = M V + (F0 + F_ext + P, T0 + L_P) dt,     V = (U, Omega_lab),

with ``M = diag(m, m, m, I_lab)``, ``I_lab = A diag(I) A^T``, ``F_ext`` the external force and
``(P, L_P)`` the impulse of the nodes covered and uncovered by the previous move (below). The ghost
fill then uses the *new* velocity ``V'``, so the momentum the fluid loses through the links is
exactly what the particle gains, ``(F0, T0) - Z V'`` (plus the reference-pressure part, which
cancels between touching particles): fluid + particles conserve momentum to round-off. ``Z`` is
summed per direction from the link count, the sum of lever arms and the sum of their outer
products.

Time step (``dt = 1``): ``pre``: ``F0, T0, Z`` from ``f*(t)`` on the links at ``X(t)`` -> implicit
update to ``V(t+1)`` -> ghost fill with ``V(t+1)``; fluid sweep; ``post``: the torque-free motion
``rigid.drift_arrays`` over one step (``x += v``, the exact free rotation of Eqs. (13)-(15) that
carries the gyroscopic term and keeps ``|q| = 1``), then the remap. The kick is the implicit
angular-momentum update ``L' = L + T dt`` in the lab frame at the current orientation (Eq. (13)'s
torque term), the drift the rest: first order in time, like the link coupling itself.

No interior fluid
-----------------
Particle nodes carry no fluid (Aidun, Lu & Ding 1998). The fluid kernel sweeps them like any node,
but the fluid never reads them: every slot a fluid node pulls from a particle node is overwritten
by the ghost fill first. Observables exclude them.

Covering and uncovering (momentum accounting)
---------------------------------------------
After a move, for each node whose owner changed:

* a fluid node now covered by particle ``k`` leaves the fluid; its momentum ``j = sum_i f_i e_i``
  (post-collision) goes to ``k``: ``P_k += j``, ``L_P += r x j``;
* a node of particle ``k`` that becomes fluid is filled with the equilibrium Eq. (3) at the local
  surface velocity ``u_b = U + Omega x r`` and the mean density of its neighbours that were fluid
  before the move: the two along z if either is (their populations share the node's cache lines),
  else those along x and y, else ``rho0``; the particle pays: ``P_k -= rho u_b``,
  ``L_P -= r x rho u_b``;
* a node passed from one particle to another holds no fluid: nothing is exchanged.

``(P, L_P)`` enters the next implicit update, so fluid + particles conserve total momentum exactly
(``ParticleSystem.total_momentum`` counts the impulse not yet applied). Mass is not conserved
by a moving particle (a covered node takes its mass along, an uncovered one gets its neighbours'
density; the moving-wall term of Eq. (8) transfers mass across each link), a known property of
Ladd's scheme, and the loss is systematic: a covered node, on the front of a moving particle, is
denser than the nodes uncovered in its wake. Measured: the mean fluid density falls 0.6 % per
100 steps with 115 cubes at 30 % in the Re 9.4 pipe (dx 2.5 mm), growing with the particle
speed. ``MassCorrection`` therefore restores the mean fluid density every few steps by adding
``w_i d_rho`` to every fluid node (no momentum: ``sum_i w_i e_i = 0``), and the summary reports the
total mass it added.

External forces on particles
----------------------------
* The flow's driving body force stands for a pressure gradient, which pushes on the particle
  volume too: a particle gets ``f_drive V_p`` (force density times its volume).
* Optional gravity ``g`` acts on the particle's excess mass, ``(rho_p - rho0) V_p g``; the fluid
  carries no gravity (its hydrostatic pressure would only produce the buoyancy subtracted here).
``V_p`` is the geometric volume (``shapes.volume``), as is the mass ``rho_p V_p``.

Flow-rate control with particles
--------------------------------
The fluid kernel's flux sum runs over particle nodes too. ``ParticleFluxCorrection`` replaces it by
the volumetric flow rate of the mixture, fluid momentum (kept by exact bookkeeping of what crosses
wall and particle links and what covering moves) plus the particles' volume flux
``sum_k n_k U_z,k`` (``n_k`` nodes), which the controller then holds.

Fixed particles
---------------
Never move and never remap: their links change only when a free particle covers or uncovers a
neighbouring fluid node. Each step runs only the bounce-back fill ``f[opp(i), s] = f*_i(x)`` and
the force and torque sums over their lists.

Cost
----
Per step: one pass per particle over its links (``prange`` over particles: a scattered read of
``f*_i(x)`` and a scattered write of the ghost slot per link), the 6x6 solve, the drift, the runs
(one ray per column), the run differences, and the remap, serial over the owner changes (their
order fixes the order of the link lists, so results do not depend on the thread count).
There is no Python loop over particles or links. The paper's 115 cubes of 8 mm have about 190,000
links (110,000 distinct cache lines of ``f`` read, as many written). The link passes are bound by
the latency of those scattered accesses (out of cache after the sweep; prefetched 16 links ahead),
so the coupling costs 1.3x the streaming fluid sweep on 1 thread and the remap 0.6x (measured,
2026-12); ``benchmarks/particles.py`` measures the split. The bare data movement of the two link
passes (one load, one store, one sum per link) costs 0.61-0.68 of the sweep in this layout and
0.50-0.57 fused into the sweep with the rows in cache (``benchmarks/coupling_floor.py``): a link
moves one scattered scalar, where the sweep moves rows with vector instructions, and the paper's
cubes have about 1.4 links per fluid node.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..effect import Effect
from ..fluid.boundaries import plane_buffer
from ..fluid.observables import ordered_sum
from .rigid import Bodies, drift_arrays, omega_lab_arrays, quat_to_matrix
from .shapes import CYLINDER, SPHERE, bounding_radius, volume

WALL = -2
FLUID = -1
_EPS_DIR = 1e-12  # below this a direction component counts as zero (line parallel to a face)
#: links ahead whose population the link passes prefetch (measured: the gather of f* 25-35 %
#: faster at 16; 8 and 64 gain less)
_PREFETCH = 16


@intrinsic
def _prefetch(typingctx, arr, i, j, write):
    """Hint the cache to fetch ``arr[i, j]`` (for writing if the literal ``write`` is 1); no effect
    on results. The link passes are bound by the latency of scattered accesses to ``f``, and a
    hint issued a few links ahead keeps more of them in flight than the out-of-order window."""
    rw = int(getattr(write, "literal_value", 0))
    sig = types.void(arr, i, j, write)

    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        idx = [context.cast(builder, args[q], signature.args[q], types.intp) for q in (1, 2)]
        ptr = cgutils.get_item_pointer(context, builder, aty, ary, idx, wraparound=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, rw), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


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


@njit(cache=True, inline="always")
def _candidates(s1, s2, w1, w2):
    # [s1, s2] minus [w1, w2] as (lo1, hi1, lo2, hi2); empty parts have lo > hi.
    if w1 > w2 or w2 < s1 or w1 > s2:
        return s1, s2, 1, 0
    return s1, min(s2, w1 - 1), max(s1, w2 + 1), s2



# ----------------------------------------------------------------------------------------------
# Link lists: per particle and direction, appended on owner changes, compacted by the passes
#
# G = (dims, az, origin, periodic, xmap, ymap, zmap, e): the grid
# L = (lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg): the lists; entry
#     ``pos = lbase[p, i] + j`` for ``j < lcnt[p, i]`` is a link of particle p in direction i from
#     fluid node ``LN[pos, 0]`` into particle node ``LN[pos, 1]`` (int32), whose lattice
#     coordinates, unwrapped in the particle's frame, are ``c = LC[pos, :3]`` (int16; the link
#     midpoint is ``origin + c - e_i/2``, exact in floating point). An entry is live while the
#     particle node belongs to p and the fluid node is FLUID. Records of 8 + 8 bytes in two
#     arrays: the link passes are bound by fetching the lists after the sweep evicted them, so
#     their size and the number of streams are their cost (measured: int64 nodes and float64
#     midpoints in five arrays took 3x longer to read). The node indices are stored, not
#     recomputed from the coordinates: the gather of ``f*`` overlaps its cache misses only while
#     the loop that issues them stays a few instructions per link (measured: 3.5x slower with the
#     indices computed in the loop).
#     ``lerr[0]`` counts links dropped for lack of room (never expected); ``nown[p]`` is the number
#     of nodes particle p owns. ``chg[node]`` marks the nodes whose owner changed since the last
#     link passes (the first ``len(chg_list)`` of them listed in ``chg_list``, ``nchg[0]`` in
#     all): only a link with a marked node can be dead, so the passes read the owner map (a large
#     array, scattered reads) for those links alone.
# The helpers are compiled without reference counting (``_nrt=False``): they allocate nothing and
# are called per node, where the atomic reference counts of their array arguments would dominate.


@njit(cache=True, _nrt=False)
def _decode(node, ny, az):
    return node // (ny * az), (node // az) % ny, node % az


@njit(cache=True, _nrt=False)
def _shifted(a, b, zi, dx, dy, dz, G):
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    return (xmap[a + dx + dims[0]] * dims[1] + ymap[b + dy + dims[1]]) * az + zmap[zi + dz + dims[2]]


@njit(cache=True, _nrt=False)
def _compact(p, i, owner, L):
    # drop the dead entries of list (p, i)
    lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg = L
    b0 = lbase[p, i]
    wpos = b0
    for pos in range(b0, b0 + lcnt[p, i]):
        if owner[LN[pos, 1]] == p and owner[LN[pos, 0]] == FLUID:
            for d in range(2):
                LN[wpos, d] = LN[pos, d]
            for d in range(3):
                LC[wpos, d] = LC[pos, d]
            wpos += 1
    lcnt[p, i] = wpos - b0


@njit(cache=True)
def _set_owners(n, nodes, news, owner, x, G, L):
    """Give ``nodes[t]`` to ``news[t]`` (a particle or FLUID), ``t < n``, in order, and append
    the links each change creates, so that the live entries of the lists are exactly
    ``{(x, s, i): owner[s] >= 0, owner[x] = FLUID}``; links a change ends die with it (lazy
    deletion; the node is marked in ``chg``). One loop without calls: per node the work is a few
    table lookups, so a call passing the arrays of G and L would cost more than the work
    (measured: 2x)."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg = L
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for t in range(n):
        node = nodes[t]
        new = news[t]
        old = owner[node]
        if old == new:
            continue
        if not chg[node]:
            chg[node] = 1
            if nchg[0] < chg_list.shape[0]:
                chg_list[nchg[0]] = node
            nchg[0] += 1
        a = node // (ny * az)
        b = (node // az) % ny
        zi = node % az
        owner[node] = new
        if old >= 0:
            nown[old] -= 1
        if new >= 0:
            nown[new] += 1
        for i in range(1, Q):
            # new >= 0: links of `new` from fluid neighbours x = node - e_i into the node;
            # new == FLUID: links of particle neighbours s = node + e_i from the node
            sgn = 1 if new == FLUID else -1
            na = xmap[a + sgn * e[i, 0] + nx]
            nb = ymap[b + sgn * e[i, 1] + ny]
            nzi = zmap[zi + sgn * e[i, 2] + nz]
            nbr = (na * ny + nb) * az + nzi
            o = owner[nbr]
            if new >= 0:
                if o != FLUID:
                    continue
                p, xn, sn, sa, sb, sz = new, nbr, node, a, b, zi
            else:
                if o < 0:
                    continue
                p, xn, sn, sa, sb, sz = o, node, nbr, na, nb, nzi
            if lcnt[p, i] >= lcap[p, i]:
                _compact(p, i, owner, L)
                if lcnt[p, i] >= lcap[p, i]:
                    lerr[0] += 1
                    continue
            pos = lbase[p, i] + lcnt[p, i]
            LN[pos, 0] = xn
            LN[pos, 1] = sn
            for d in range(3):
                c = sa if d == 0 else (sb if d == 1 else sz)
                if periodic[d]:
                    # the image of the node nearest the centre (minimum image of the midpoint)
                    r = origin[d] + c - 0.5 * e[i, d] - x[p, d]
                    c -= dims[d] * int(math.floor(r / dims[d] + 0.5))
                LC[pos, d] = c
            lcnt[p, i] += 1


@njit(cache=True)
def clear_changed(chg, chg_list, nchg):
    """Unmark the nodes marked since the last link passes (all of them if the list overflowed)."""
    n = nchg[0]
    if n > chg_list.shape[0]:
        chg[:] = 0
    else:
        for t in range(n):
            chg[chg_list[t]] = 0
    nchg[0] = 0


@njit(cache=True)
def mark_initial(order, rect, run_off, z1, z2, owner, count, x, G, L):
    """Coverage count and owners of all particles, in ``order`` (fixed ones first): the first
    particle to claim a fluid node owns it. Builds the link lists on the way."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    one_node = np.zeros(1, np.int64)
    one_new = np.zeros(1, np.int64)
    for m in range(order.shape[0]):
        k = order[m]
        one_new[0] = k
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
                        one_node[0] = node
                        _set_owners(1, one_node, one_new, owner, x, G, L)


# ----------------------------------------------------------------------------------------------
# Per-step coupling over the link lists


@njit(parallel=True, cache=True)
def couple_free(f2, owner, chg, ids, x, mass, inertia, q, v, wb, fext, imp, om, force, torque, exch, w, opp, rho0,
                G, lbase, lcnt, LN, LC, SF, SM):
    """One step of the coupling of the free particles ``ids`` (module docstring), one particle per
    iteration: pass 1 swap-removes dead links (lazy deletion; only links with a node marked in
    ``chg`` are tested) and sums ``(F0, T0)`` (reference pressure removed) and the self-friction
    ``Z`` over the live ones; the implicit update ``(M + Z) V' = M V + G`` gives the new
    velocities; pass 2 writes Ladd's ghost populations Eq. (8) with ``V'``. Outputs: ``v``,
    ``wb``, lab ``om``, and the hydrodynamic ``force`` and ``torque`` of the step (Eqs. (9)-(12)
    with ``V'``, plus the cover/uncover impulses ``imp``, which are cleared); ``exch[k]``, the
    momentum the fluid loses through k's links (the same with the reference pressure, for the
    flow-rate bookkeeping). ``SF``, ``SM``: per-thread scratch."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for m in prange(ids.shape[0]):
        k = ids[m]
        tid = numba.get_thread_id()
        LF = SF[tid]
        M = SM[tid]
        X0 = x[k, 0]
        X1 = x[k, 1]
        X2 = x[k, 2]
        # lever arm r = origin + c - e_i/2 - X: per direction a constant plus the coordinates
        O0 = origin[0] - X0
        O1 = origin[1] - X1
        O2 = origin[2] - X2
        off0 = lbase[k, 1]
        for p in range(6):
            for r in range(7):
                M[p, r] = 0.0
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        g3 = 0.0
        g4 = 0.0
        g5 = 0.0
        e0 = 0.0
        e1 = 0.0
        e2 = 0.0
        # ---- pass 1: compaction and sums per direction, folded into G and Z
        for i in range(1, Q):
            wr = w[i] * rho0
            ei0 = e[i, 0]
            ei1 = e[i, 1]
            ei2 = e[i, 2]
            a0 = O0 - 0.5 * ei0
            a1 = O1 - 0.5 * ei1
            a2 = O2 - 0.5 * ei2
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            # The scattered reads of f* first, in a loop without branches: their cache misses
            # (f is out of cache after the sweep) overlap instead of waiting one by one.
            for pos in range(b0, end):
                if pos + _PREFETCH < end:
                    _prefetch(f2, i, LN[pos + _PREFETCH, 0], 0)
                LF[pos - off0] = f2[i, LN[pos, 0]]
            rxs = 0.0
            rys = 0.0
            rzs = 0.0
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
            pos = b0
            while pos < end:
                xn = LN[pos, 0]
                sn = LN[pos, 1]
                if chg[sn] | chg[xn]:
                    if owner[sn] != k or owner[xn] != FLUID:
                        # dead link: the last entry takes its place (swap-remove)
                        end -= 1
                        LN[pos, 0] = LN[end, 0]
                        LN[pos, 1] = LN[end, 1]
                        for d in range(3):
                            LC[pos, d] = LC[end, d]
                        LF[pos - off0] = LF[end - off0]
                        continue
                rx = a0 + LC[pos, 0]
                ry = a1 + LC[pos, 1]
                rz = a2 + LC[pos, 2]
                fv = LF[pos - off0] - wr
                pos += 1
                rxs += rx
                rys += ry
                rzs += rz
                sxx += rx * rx
                syy += ry * ry
                szz += rz * rz
                sxy += rx * ry
                sxz += rx * rz
                syz += ry * rz
                sf += fv
                sfx += fv * rx
                sfy += fv * ry
                sfz += fv * rz
            lcnt[k, i] = end - b0
            cnt = float(end - b0)
            if cnt == 0.0:
                continue
            ex = float(e[i, 0])
            ey = float(e[i, 1])
            ez = float(e[i, 2])
            # the reference part the particle does not take (module docstring) still leaves the fluid
            e0 += 2.0 * ex * wr * cnt
            e1 += 2.0 * ey * wr * cnt
            e2 += 2.0 * ez * wr * cnt
            # F0 = sum 2 e (f - w rho0);  T0 = 2 (sum (f - w rho0) r) x e
            g0 += 2.0 * ex * sf
            g1 += 2.0 * ey * sf
            g2 += 2.0 * ez * sf
            g3 += 2.0 * (sfy * ez - sfz * ey)
            g4 += 2.0 * (sfz * ex - sfx * ez)
            g5 += 2.0 * (sfx * ey - sfy * ex)
            c6 = 6.0 * wr
            # Z_UU += c6 n e e^T;  Z_UO += c6 e (R x e)^T with R = sum r
            q0 = rys * ez - rzs * ey
            q1 = rzs * ex - rxs * ez
            q2 = rxs * ey - rys * ex
            M[0, 0] += c6 * cnt * ex * ex
            M[0, 1] += c6 * cnt * ex * ey
            M[0, 2] += c6 * cnt * ex * ez
            M[1, 1] += c6 * cnt * ey * ey
            M[1, 2] += c6 * cnt * ey * ez
            M[2, 2] += c6 * cnt * ez * ez
            M[0, 3] += c6 * ex * q0
            M[0, 4] += c6 * ex * q1
            M[0, 5] += c6 * ex * q2
            M[1, 3] += c6 * ey * q0
            M[1, 4] += c6 * ey * q1
            M[1, 5] += c6 * ey * q2
            M[2, 3] += c6 * ez * q0
            M[2, 4] += c6 * ez * q1
            M[2, 5] += c6 * ez * q2
            # Z_OO += c6 sum (r x e)(r x e)^T; r x e = (ry ez - rz ey, rz ex - rx ez, rx ey - ry ex)
            M[3, 3] += c6 * (syy * ez * ez - 2.0 * syz * ey * ez + szz * ey * ey)
            M[4, 4] += c6 * (szz * ex * ex - 2.0 * sxz * ex * ez + sxx * ez * ez)
            M[5, 5] += c6 * (sxx * ey * ey - 2.0 * sxy * ex * ey + syy * ex * ex)
            M[3, 4] += c6 * (syz * ex * ez - sxy * ez * ez - szz * ex * ey + sxz * ey * ez)
            M[3, 5] += c6 * (sxy * ey * ez - syy * ex * ez - sxz * ey * ey + syz * ex * ey)
            M[4, 5] += c6 * (sxz * ex * ey - syz * ex * ex - sxx * ey * ez + sxy * ex * ez)
        for p in range(6):
            for r in range(p):
                M[p, r] = M[r, p]
        Zc = np.empty((6, 6))
        for p in range(6):
            for r in range(6):
                Zc[p, r] = M[p, r]
        # ---- implicit update: (M + Z) V' = M V + G
        A = quat_to_matrix(q[k])
        G = (g0, g1, g2, g3, g4, g5)
        for p in range(3):
            M[p, p] += mass[k]
            M[p, 6] = mass[k] * v[k, p] + G[p] + fext[k, p] + imp[k, p]
        for p in range(3):
            for r in range(3):
                acc = 0.0
                for s_ in range(3):
                    acc += A[p, s_] * inertia[k, s_] * A[r, s_]
                M[3 + p, 3 + r] += acc
            acc = 0.0
            for s_ in range(3):
                acc += A[p, s_] * inertia[k, s_] * wb[k, s_]
            M[3 + p, 6] = acc + G[3 + p] + fext[k, 3 + p] + imp[k, 3 + p]
        _solve6(M)
        for p in range(3):
            v[k, p] = M[p, 6]
            om[k, p] = M[3 + p, 6]
        for p in range(3):  # body frame: wb = A^T Omega
            wb[k, p] = A[0, p] * M[3, 6] + A[1, p] * M[4, 6] + A[2, p] * M[5, 6]
        for p in range(3):
            fz_ = 0.0
            tz_ = 0.0
            for r in range(6):
                fz_ += Zc[p, r] * M[r, 6]
                tz_ += Zc[3 + p, r] * M[r, 6]
            force[k, p] = G[p] - fz_ + imp[k, p]
            torque[k, p] = G[3 + p] - tz_ + imp[k, 3 + p]
        exch[k, 0] = force[k, 0] - imp[k, 0] + e0
        exch[k, 1] = force[k, 1] - imp[k, 1] + e1
        exch[k, 2] = force[k, 2] - imp[k, 2] + e2
        for p in range(6):
            imp[k, p] = 0.0
        # ---- pass 2: ghost fill, Eq. (8), with the new velocity
        ux = v[k, 0]
        uy = v[k, 1]
        uz = v[k, 2]
        ox = om[k, 0]
        oy = om[k, 1]
        oz = om[k, 2]
        for i in range(1, Q):
            ex = float(e[i, 0])
            ey = float(e[i, 1])
            ez = float(e[i, 2])
            oi = opp[i]
            c6 = 6.0 * w[i] * rho0
            # e . u_b = e . U + Omega . (r x e) = e . U + r . (e x Omega), r = a + LC
            cx = c6 * (ey * oz - ez * oy)
            cy = c6 * (ez * ox - ex * oz)
            cz = c6 * (ex * oy - ey * ox)
            c6eu = c6 * (ex * ux + ey * uy + ez * uz) + (O0 - 0.5 * ex) * cx + (O1 - 0.5 * ey) * cy + (O2 - 0.5 * ez) * cz
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            for pos in range(b0, end):
                if pos + _PREFETCH < end:
                    _prefetch(f2, oi, LN[pos + _PREFETCH, 1], 1)
                f2[oi, LN[pos, 1]] = LF[pos - off0] - c6eu - LC[pos, 0] * cx - LC[pos, 1] * cy - LC[pos, 2] * cz


@njit(parallel=True, cache=True)
def fixed_fill(f2, owner, chg, ids, x, force, torque, exch, w, opp, rho0, G, lbase, lcnt, LN, LC):
    """Fixed particles: half-way bounce-back on their live links (Eq. (8) with u_b = 0; dead links
    are dropped, as in ``couple_free``) and their force and torque, Eqs. (9)-(12) (reference
    pressure removed); ``exch`` as in ``couple_free``."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for m in prange(ids.shape[0]):
        k = ids[m]
        fx_ = 0.0
        fy_ = 0.0
        fz_ = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        e0 = 0.0
        e1 = 0.0
        e2 = 0.0
        for i in range(1, Q):
            oi = opp[i]
            wr = w[i] * rho0
            sf = 0.0
            sfx = 0.0
            sfy = 0.0
            sfz = 0.0
            ei0 = e[i, 0]
            ei1 = e[i, 1]
            ei2 = e[i, 2]
            a0 = origin[0] - 0.5 * ei0 - x[k, 0]
            a1 = origin[1] - 0.5 * ei1 - x[k, 1]
            a2 = origin[2] - 0.5 * ei2 - x[k, 2]
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            pos = b0
            while pos < end:
                xn = LN[pos, 0]
                sn = LN[pos, 1]
                if (chg[sn] and owner[sn] != k) or (chg[xn] and owner[xn] != FLUID):
                    end -= 1
                    LN[pos, 0] = LN[end, 0]
                    LN[pos, 1] = LN[end, 1]
                    for d in range(3):
                        LC[pos, d] = LC[end, d]
                    continue
                fv = f2[i, xn]
                f2[oi, sn] = fv
                fv -= wr
                sf += fv
                sfx += fv * (a0 + LC[pos, 0])
                sfy += fv * (a1 + LC[pos, 1])
                sfz += fv * (a2 + LC[pos, 2])
                pos += 1
            lcnt[k, i] = end - b0
            ex = float(ei0)
            ey = float(ei1)
            ez = float(ei2)
            e0 += 2.0 * ex * wr * (end - b0)
            e1 += 2.0 * ey * wr * (end - b0)
            e2 += 2.0 * ez * wr * (end - b0)
            fx_ += 2.0 * ex * sf
            fy_ += 2.0 * ey * sf
            fz_ += 2.0 * ez * sf
            tx += 2.0 * (sfy * ez - sfz * ey)
            ty += 2.0 * (sfz * ex - sfx * ez)
            tz += 2.0 * (sfx * ey - sfy * ex)
        force[k, 0] = fx_
        force[k, 1] = fy_
        force[k, 2] = fz_
        torque[k, 0] = tx
        torque[k, 1] = ty
        torque[k, 2] = tz
        exch[k, 0] = fx_ + e0
        exch[k, 1] = fy_ + e1
        exch[k, 2] = fz_ + e2


@njit(cache=True)
def _accumulate(ids, force, torque, force_sum, torque_sum, n_sum):
    for m in range(ids.shape[0]):
        k = ids[m]
        for p in range(3):
            force_sum[k, p] += force[k, p]
            torque_sum[k, p] += torque[k, p]
        n_sum[k] += 1


@njit(cache=True)
def _solve6(M):
    """Solve the 6x6 system held in ``M`` (6, 7) (matrix | right-hand side) in place by Gaussian
    elimination with partial pivoting; the solution ends in ``M[:, 6]``."""
    n = 6
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
            for c in range(col, n + 1):
                M[r, c] -= fct * M[col, c]
    for r in range(n - 1, -1, -1):
        acc = M[r, n]
        for c in range(r + 1, n):
            acc -= M[r, c] * M[c, n]
        M[r, n] = acc / M[r, r]



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


# ----------------------------------------------------------------------------------------------
# Remap after a move: coverage changes, owners (and links), covered/uncovered momentum


@njit(cache=True, _nrt=False)
def _covers(k, node, rect, run_off, z1, z2, dims, az, periodic):
    """Does particle ``k``'s run set contain memory node ``node``?"""
    ny = dims[1]
    a, b, zi = _decode(node, ny, az)
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


@njit(cache=True, _nrt=False)
def _node_vector(node, xk, G):
    # minimum-image vector from the centre xk to the node's centre
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    a, b, zi = _decode(node, dims[1], az)
    r0 = origin[0] + a - xk[0]
    r1 = origin[1] + b - xk[1]
    r2 = origin[2] + zi - xk[2]
    if periodic[0]:
        r0 -= dims[0] * math.floor(r0 / dims[0] + 0.5)
    if periodic[1]:
        r1 -= dims[1] * math.floor(r1 / dims[1] + 0.5)
    if periodic[2]:
        r2 -= dims[2] * math.floor(r2 / dims[2] + 0.5)
    return r0, r1, r2


@njit(cache=True)
def _settle_owners(nt, touch_list, new_own, all_ids, rect, run_off, z1, z2, owner, count, acq, f2, jb, G):
    """New owner of each touched node (module docstring rules) and, for a fluid node a particle
    covers, its momentum ``j = sum_i f_i e_i`` into ``jb``. The owner map is not changed here, so
    the nodes are independent: a loop with no other work between the scattered reads of the
    populations, which then overlap."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    Q = e.shape[0]
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
                    if new == FLUID:  # a count without a covering shape cannot happen; trust the shapes
                        count[node] = 0
        acq[node] = -1
        new_own[t] = new
        if old == FLUID and new >= 0:
            jx = 0.0
            jy = 0.0
            jz = 0.0
            for i in range(Q):
                fv = f2[i, node]
                jx += e[i, 0] * fv
                jy += e[i, 1] * fv
                jz += e[i, 2] * fv
            jb[t, 0] = jx
            jb[t, 1] = jy
            jb[t, 2] = jz


@njit(cache=True)
def _fill_uncovered(n_unc, unc_list, unc_old, x, v, om, owner, touched, f2, w, rho0, ub, G):
    """Equilibrium at the surface velocity in each uncovered node (module docstring); ``ub[u]``
    receives ``(rho u_b, r)``. Reads only untouched fluid nodes and writes only uncovered ones,
    so the nodes are independent (a tight loop whose memory accesses overlap)."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    Q = e.shape[0]
    ny = dims[1]
    for u in range(n_unc):
        node = unc_list[u]
        k = unc_old[u]
        a, b, zi = _decode(node, ny, az)
        # density of the neighbours along z (same cache lines as the node), else along x and y
        rho = 0.0
        nn = 0
        for axis in (2, 0, 1):
            for sgn in (-1, 1):
                nb = _shifted(a, b, zi, sgn * (axis == 0), sgn * (axis == 1), sgn * (axis == 2), G)
                if owner[nb] == FLUID and not touched[nb]:
                    s = 0.0
                    for j in range(Q):
                        s += f2[j, nb]
                    rho += s
                    nn += 1
            if nn > 0:
                break
        rho = rho / nn if nn > 0 else rho0
        r = _node_vector(node, x[k], G)
        ux = v[k, 0] + om[k, 1] * r[2] - om[k, 2] * r[1]
        uy = v[k, 1] + om[k, 2] * r[0] - om[k, 0] * r[2]
        uz = v[k, 2] + om[k, 0] * r[1] - om[k, 1] * r[0]
        usq = 1.5 * (ux * ux + uy * uy + uz * uz)
        for i in range(Q):
            eu = e[i, 0] * ux + e[i, 1] * uy + e[i, 2] * uz
            f2[i, node] = w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq)
        ub[u, 0] = rho * ux
        ub[u, 1] = rho * uy
        ub[u, 2] = rho * uz
        ub[u, 3] = r[0]
        ub[u, 4] = r[1]
        ub[u, 5] = r[2]


@njit(cache=True)
def _count_changes(ids, chg_off, chg_node, chg_d, chg_n, owner, count, touched, acq, touch_list):
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
    return nt


@njit(cache=True)
def _change_owners(nt, touch_list, new_own, jb, x, owner, unc_list, unc_old, imp, moved, G, L):
    # Serial, in the order of the touched list: the owner changes append links, and the impulse
    # sums keep one order (results independent of the thread count). The impulses depend on the
    # old owners only, so they come first, then the owner changes in the same order.
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    n_cov = 0
    n_unc = 0
    for t in range(nt):
        node = touch_list[t]
        old = owner[node]
        new = new_own[t]
        if new == old:
            continue
        if old == FLUID:
            # a fluid node swallowed: its momentum goes to the particle, r its minimum-image
            # vector from the centre
            r0 = origin[0] + node // (ny * az) - x[new, 0]
            r1 = origin[1] + (node // az) % ny - x[new, 1]
            r2 = origin[2] + node % az - x[new, 2]
            if periodic[0]:
                r0 -= nx * math.floor(r0 / nx + 0.5)
            if periodic[1]:
                r1 -= ny * math.floor(r1 / ny + 0.5)
            if periodic[2]:
                r2 -= nz * math.floor(r2 / nz + 0.5)
            jx = jb[t, 0]
            jy = jb[t, 1]
            jz = jb[t, 2]
            imp[new, 0] += jx
            imp[new, 1] += jy
            imp[new, 2] += jz
            moved[0] += jx
            moved[1] += jy
            moved[2] += jz
            imp[new, 3] += r1 * jz - r2 * jy
            imp[new, 4] += r2 * jx - r0 * jz
            imp[new, 5] += r0 * jy - r1 * jx
            n_cov += 1
        elif new == FLUID:
            unc_list[n_unc] = node
            unc_old[n_unc] = old
            n_unc += 1
    _set_owners(nt, touch_list, new_own, owner, x, G, L)
    return n_cov, n_unc


@njit(cache=True)
def _uncovered_impulse(n_unc, unc_old, ub, imp, moved):
    # the particle pays the momentum put into its uncovered nodes, in list order
    for u in range(n_unc):
        k = unc_old[u]
        px = ub[u, 0]
        py = ub[u, 1]
        pz = ub[u, 2]
        imp[k, 0] -= px
        imp[k, 1] -= py
        imp[k, 2] -= pz
        moved[0] -= px
        moved[1] -= py
        moved[2] -= pz
        imp[k, 3] -= ub[u, 4] * pz - ub[u, 5] * py
        imp[k, 4] -= ub[u, 5] * px - ub[u, 3] * pz
        imp[k, 5] -= ub[u, 3] * py - ub[u, 4] * px


@njit(cache=True)
def apply_changes(ids, chg_off, chg_node, chg_d, chg_n, all_ids, rect, run_off, z1, z2, x, v, om, owner, count,
                  touched, acq, touch_list, unc_list, unc_old, f2, w, rho0, imp, moved, G, L, new_own, jb, ub):
    """Apply the coverage changes of a move and settle the owners (module docstring): momentum of
    covered nodes to the particle, uncovered nodes refilled at the surface velocity, links updated
    with each owner. ``moved`` (3,) receives the momentum that left the fluid. Returns
    ``(n_covered, n_uncovered)``.

    Serial, in phases that keep the scattered accesses to ``f`` in tight loops of independent
    nodes (their cache misses overlap): coverage counts; new owners and the covered nodes'
    momentum; owner changes with their links and the covered impulses (in touch order); refill of
    the uncovered nodes; their impulses (in list order). Running the node phases in parallel
    gained nothing measurable and cost much on a loaded machine (each parallel region waits for
    its slowest thread)."""
    nt = _count_changes(ids, chg_off, chg_node, chg_d, chg_n, owner, count, touched, acq, touch_list)
    _settle_owners(nt, touch_list, new_own, all_ids, rect, run_off, z1, z2, owner, count, acq, f2, jb, G)
    n_cov, n_unc = _change_owners(nt, touch_list, new_own, jb, x, owner, unc_list, unc_old, imp, moved, G, L)
    _fill_uncovered(n_unc, unc_list, unc_old, x, v, om, owner, touched, f2, w, rho0, ub, G)
    _uncovered_impulse(n_unc, unc_old, ub, imp, moved)
    for t in range(nt):
        touched[touch_list[t]] = False
    return n_cov, n_unc


@njit(cache=True)
def wrap_positions(ids, x, lo, dims, periodic, rect, run_off, z1, z2, lbase, lcnt, LC):
    """Bring centres back into the periodic box; shift their runs and link coordinates by the same
    whole number of periods."""
    for m in range(ids.shape[0]):
        k = ids[m]
        for d in range(3):
            if not periodic[d]:
                continue
            per = float(dims[d])
            s = math.floor((x[k, d] - lo[d]) / per)
            if s == 0:
                continue
            x[k, d] -= s * per
            shift = int(s) * dims[d]
            if d < 2:
                rect[k, d] -= shift
            else:
                for c in range(run_off[k], run_off[k] + rect[k, 2] * rect[k, 3]):
                    z1[c] -= shift
                    z2[c] -= shift
            for i in range(1, lbase.shape[1]):
                for pos in range(lbase[k, i], lbase[k, i] + lcnt[k, i]):
                    LC[pos, d] -= shift


# ----------------------------------------------------------------------------------------------
# Flux correction and observables


@njit(parallel=True, cache=True)
def wall_exchange(f2, owner, fluid, solid, i, opp, ez):
    """z-momentum the fluid loses through the wall links ``(fluid, solid, i)`` this step:
    ``sum e_iz (f_i(x) + f_opp(i)(s))``: the population that leaves ``x`` and the one the wall
    sends back (any wall rule), on links whose fluid node is not covered by a particle."""
    n = fluid.shape[0]
    nchunk = 32
    part = np.zeros(nchunk)
    for c in prange(nchunk):
        acc = 0.0
        for k in range(c * n // nchunk, (c + 1) * n // nchunk):
            if owner[fluid[k]] == FLUID:
                acc += ez[k] * (f2[i[k], fluid[k]] + f2[opp[k], solid[k]])
        part[c] = acc
    return ordered_sum(part)


@njit(parallel=True, cache=True)
def _fluid_sums(f2, owner, e, nsum):
    """The first ``nsum`` of (mass, px, py, pz) over the fluid nodes, in fixed chunks (the same bits
    on any thread count; the mass has the same bits for either ``nsum``). The mass correction asks
    for the mass alone: one stream of additions instead of four, half the time."""
    n = owner.shape[0]
    Q = e.shape[0]
    nchunk = 64
    part = np.zeros((nchunk, 4))
    for c in prange(nchunk):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for node in range(c * n // nchunk, (c + 1) * n // nchunk):
            if owner[node] != FLUID:
                continue
            if nsum == 1:
                for i in range(Q):
                    a0 += f2[i, node]
            else:
                for i in range(Q):
                    fv = f2[i, node]
                    a0 += fv
                    a1 += e[i, 0] * fv
                    a2 += e[i, 1] * fv
                    a3 += e[i, 2] * fv
        part[c, 0] = a0
        part[c, 1] = a1
        part[c, 2] = a2
        part[c, 3] = a3
    total = np.empty(nsum)
    for a in range(nsum):
        total[a] = ordered_sum(part[:, a])
    return total


# ----------------------------------------------------------------------------------------------
# The particle system and its effects


def _wrap_table(n: int, periodic: bool) -> np.ndarray:
    i = np.arange(-n, 2 * n)
    return (i % n if periodic else np.clip(i, 0, n - 1)).astype(np.int64)


class ParticleSystem:
    """Rigid bodies on a grid: owner map, runs, link lists, forces (lattice units).

    ``bodies`` (``rigid.Bodies``) is updated in place: centres are wrapped into the periodic box.
    ``gravity`` (3,) acts on each particle's excess mass ``(rho_p - rho0) V_p``; the flow's body
    force density acts on ``V_p`` (module docstring). ``force``/``torque`` (N, 3) hold the
    hydrodynamic force and torque (lab frame, about the centre) of the last step.
    """

    def __init__(self, grid, bodies: Bodies, gravity=(0.0, 0.0, 0.0), rho0: float = 1.0):
        self.grid = grid
        self.bodies = bodies
        self.rho0 = float(rho0)
        lat = grid.lattice
        self.e = np.ascontiguousarray(lat.e.astype(np.int64))
        self.w = np.ascontiguousarray(lat.w.astype(np.float64))
        self.opp = np.ascontiguousarray(lat.opp.astype(np.int64))
        Q = lat.q
        nx, ny, nz = grid.shape
        self.dims = np.array([nx, ny, nz], dtype=np.int64)
        self.az = int(grid.alloc_z)
        self.periodic = np.array(grid.periodic, dtype=np.bool_)
        self.origin = np.array([p[0] for p in grid.positions()], dtype=np.float64)
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
        self.fixed_ids = np.flatnonzero(bodies.fixed).astype(np.int64)
        self.free_ids = np.flatnonzero(~bodies.fixed).astype(np.int64)
        self.all_ids = np.concatenate([self.fixed_ids, self.free_ids])
        # runs (current and next)
        self.run_off = np.zeros(n + 1, dtype=np.int64)
        self.run_off[1:] = np.cumsum(span * span)
        ncol = int(self.run_off[-1])
        self.rect = np.zeros((n, 4), np.int64)
        self.z1 = np.ones(ncol, np.int64)
        self.z2 = np.zeros(ncol, np.int64)
        self.rect_n = np.zeros((n, 4), np.int64)
        self.z1_n = np.ones(ncol, np.int64)
        self.z2_n = np.zeros(ncol, np.int64)
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
        # per touched node: new owner, covered momentum, uncovered (rho u_b, r); a tuple, so that
        # checkpoints skip it (scratch)
        self.remap_scratch = (np.zeros(max(tot, 1), np.int64), np.zeros((max(tot, 1), 3)), np.zeros((max(tot, 1), 6)))
        # node state
        size = nx * ny * self.az
        owner = np.full((nx, ny, self.az), WALL, dtype=np.int32)
        owner[:, :, :nz][grid.fluid] = FLUID
        self.owner = owner.reshape(-1)
        self.count = np.zeros(size, np.int16)
        self.touched = np.zeros(size, np.bool_)
        self.acq = np.full(size, -1, np.int32)
        # link lists: a lattice line through a convex particle enters it once, so direction i has
        # at most pi (r_b + 1)^2 |e_i| links (lines per unit area across e_i: |e_i|); padded
        norms = np.linalg.norm(self.e, axis=1)
        lcap = np.zeros((n, Q), np.int64)
        lcap[:, 1:] = (math.pi * (rb[:, None] + 2.0) ** 2 * norms[None, 1:]).astype(np.int64) + 16
        self.lcap = lcap
        self.lbase = np.zeros((n, Q), np.int64)
        flat = np.concatenate([[0], np.cumsum(lcap.reshape(-1))])
        self.lbase[:] = flat[:-1].reshape(n, Q)
        total = int(flat[-1])
        self.lcnt = np.zeros((n, Q), np.int64)
        if size >= 2**31 or self.dims.max() >= 10000:
            raise ValueError(f"grid {tuple(self.dims)} too large for particles: link lists hold node indices as "
                             "int32 and unwrapped coordinates as int16 (below 10000 nodes per axis)")
        self.LN = np.zeros((total, 2), np.int32)
        self.LC = np.zeros((total, 4), np.int16)
        self.lerr = np.zeros(1, np.int64)
        self.nown = np.zeros(n, np.int64)
        # nodes whose owner changed since the last link passes (a node changes at most once per
        # move, so a move's touched-node capacity bounds the list; mark_initial overflows it)
        self.chg = np.zeros(size, np.uint8)
        self.chg_list = np.zeros(max(tot, 1), np.int64)
        self.nchg = np.zeros(1, np.int64)
        nt = numba.config.NUMBA_NUM_THREADS
        per_particle = int(lcap.sum(axis=1).max()) if n else 1
        self.scratch = (np.zeros((nt, per_particle)), np.zeros((nt, 6, 7)))
        # dynamics and outputs
        self.fext = np.zeros((n, 6))
        self.imp = np.zeros((n, 6))
        self.om = np.zeros((n, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.force_sum = np.zeros((n, 3))
        self.torque_sum = np.zeros((n, 3))
        self.n_sum = np.zeros(n, np.int64)
        self.exch = np.zeros((n, 3))
        self.moved = np.zeros(3)
        self.last_cover = (0, 0)
        self._map_all()
        self.om[:] = omega_lab_arrays(bodies.q, bodies.wb)
        self.n_fluid = int(np.count_nonzero(self.owner == FLUID))

    # -- packed arguments of the kernels
    @property
    def G(self):
        return (self.dims, self.az, self.origin, self.periodic, self.xmap, self.ymap, self.zmap, self.e)

    @property
    def L(self):
        return (self.lbase, self.lcap, self.lcnt, self.LN, self.LC, self.lerr, self.nown, self.chg,
                self.chg_list, self.nchg)

    def _check_links(self):
        if self.lerr[0]:
            raise RuntimeError(f"particle link list overflow ({int(self.lerr[0])} links dropped); please report")

    def _runs(self, ids, rect, z1, z2):
        b = self.bodies
        compute_runs(ids, b.kind, b.h, b.x, b.q, self.origin, self.dims, self.periodic, self.run_off, rect, z1, z2)

    def _map_all(self):
        b = self.bodies
        for d in range(3):
            if self.periodic[d]:
                b.x[:, d] = self.lo[d] + np.mod(b.x[:, d] - self.lo[d], self.dims[d])
        self._runs(self.all_ids, self.rect, self.z1, self.z2)
        self.rect_n[:] = self.rect
        self.z1_n[:] = self.z1
        self.z2_n[:] = self.z2
        mark_initial(self.all_ids, self.rect, self.run_off, self.z1, self.z2, self.owner, self.count, b.x, self.G,
                     self.L)
        self._check_links()

    # -- per step ------------------------------------------------------------------------------
    def fill_fixed(self, f2):
        """Bounce-back and force of the fixed particles (``pre``)."""
        ids = self.fixed_ids
        if len(ids):
            fixed_fill(f2, self.owner, self.chg, ids, self.bodies.x, self.force, self.torque, self.exch, self.w,
                       self.opp, self.rho0, self.G, self.lbase, self.lcnt, self.LN, self.LC)
            _accumulate(ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)
            if not len(self.free_ids):  # the last link pass of the step
                clear_changed(self.chg, self.chg_list, self.nchg)

    def couple_free(self, f2, body_force):
        """Link sums -> implicit velocity update -> ghost fill of the free particles (``pre``)."""
        ids = self.free_ids
        if not len(ids):
            return
        b = self.bodies
        fb = np.asarray(body_force, dtype=np.float64)
        self.fext[:, :3] = self.vol[:, None] * (fb[None, :] + (b.mass / self.vol - self.rho0)[:, None] * self.gravity)
        couple_free(f2, self.owner, self.chg, ids, b.x, b.mass, b.inertia, b.q, b.v, b.wb, self.fext, self.imp,
                    self.om, self.force, self.torque, self.exch, self.w, self.opp, self.rho0, self.G, self.lbase,
                    self.lcnt, self.LN, self.LC, *self.scratch)
        _accumulate(ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)
        clear_changed(self.chg, self.chg_list, self.nchg)  # the last link pass of the step

    def move(self, f2):
        """Drift of the free particles over one step with their new velocities, then the remap
        (``post``; ``f2`` holds the post-collision populations of the new time)."""
        ids = self.free_ids
        if not len(ids):
            return
        b = self.bodies
        drift_arrays(b.x, b.v, b.q, b.wb, b.inertia, b.fixed, 1.0)
        self._runs(ids, self.rect_n, self.z1_n, self.z2_n)
        diff_runs(ids, self.run_off, self.rect, self.z1, self.z2, self.rect_n, self.z1_n, self.z2_n, self.xmap,
                  self.ymap, self.zmap, self.dims, self.az, self.chg_off, self.chg_node, self.chg_d, self.chg_n)
        # the drift turned wb with the body: the lab angular velocity for the surface velocities
        self.om[:] = omega_lab_arrays(b.q, b.wb)
        self.last_cover = apply_changes(
            ids, self.chg_off, self.chg_node, self.chg_d, self.chg_n, self.all_ids, self.rect_n, self.run_off,
            self.z1_n, self.z2_n, b.x, b.v, self.om, self.owner, self.count, self.touched, self.acq,
            self.touch_list, self.unc_list, self.unc_old, f2, self.w, self.rho0, self.imp, self.moved, self.G,
            self.L, *self.remap_scratch)
        self.n_fluid -= self.last_cover[0] - self.last_cover[1]
        self._check_links()
        wrap_positions(ids, b.x, self.lo, self.dims, self.periodic, self.rect_n, self.run_off, self.z1_n, self.z2_n,
                       self.lbase, self.lcnt, self.LC)
        self.rect, self.rect_n = self.rect_n, self.rect
        self.z1, self.z1_n = self.z1_n, self.z1
        self.z2, self.z2_n = self.z2_n, self.z2

    def take_mean_force(self):
        """Mean hydrodynamic force and torque (lab) on each particle over the steps since the last
        call, (N, 3) each (the last step's values where no step ran)."""
        n = self.n_sum[:, None]
        f = np.where(n > 0, self.force_sum / np.maximum(n, 1), self.force)
        t = np.where(n > 0, self.torque_sum / np.maximum(n, 1), self.torque)
        self.force_sum[:] = 0.0
        self.torque_sum[:] = 0.0
        self.n_sum[:] = 0
        return f, t

    # -- observables and checks ----------------------------------------------------------------
    def owner_grid(self) -> np.ndarray:
        """(nx, ny, nz) int32 owner of each node: -2 wall, -1 fluid, k particle (a view)."""
        nx, ny, nz = self.dims
        return self.owner.reshape(nx, ny, self.az)[:, :, :nz]

    def covered(self) -> np.ndarray:
        """(nx, ny, nz) bool: nodes that belong to a particle."""
        return self.owner_grid() >= 0

    def fluid_mask(self) -> np.ndarray:
        """(nx, ny, nz) bool: fluid nodes (neither wall nor particle)."""
        return self.owner_grid() == FLUID

    def fluid_momentum(self, f2) -> np.ndarray:
        """(mass, px, py, pz) of the fluid nodes of ``f2`` (post-collision populations)."""
        return _fluid_sums(f2, self.owner, self.e, 4)

    def fluid_mass(self, f2) -> float:
        """Mass of the fluid nodes of ``f2``: ``fluid_momentum(f2)[0]``, bit for bit."""
        return float(_fluid_sums(f2, self.owner, self.e, 1)[0])

    def total_momentum(self, f2) -> np.ndarray:
        """Fluid + particle momentum (3,), with the impulses not yet applied to the particles."""
        b = self.bodies
        free = ~b.fixed
        p = self.fluid_momentum(f2)[1:].copy()
        p += (b.mass[free, None] * b.v[free]).sum(axis=0)
        p += self.imp[free, :3].sum(axis=0)
        return p

    def omega_lab(self) -> np.ndarray:
        """Lab-frame angular velocities (N, 3)."""
        return omega_lab_arrays(self.bodies.q, self.bodies.wb)

    def links(self, k: int):
        """Live links of particle ``k`` as arrays ``(fluid node, particle node, direction, lever
        arm)`` (a copy, for checks and diagnostics)."""
        xs, ss, ii, rr = [], [], [], []
        for i in range(1, len(self.w)):
            sl = slice(self.lbase[k, i], self.lbase[k, i] + self.lcnt[k, i])
            c = self.LC[sl, :3].astype(np.int64)
            xn, sn = self.LN[sl, 0].astype(np.int64), self.LN[sl, 1].astype(np.int64)
            live = (self.owner[sn] == k) & (self.owner[xn] == FLUID)
            xs.append(xn[live])
            ss.append(sn[live])
            ii.append(np.full(int(live.sum()), i))
            mid = self.origin + c[live] - 0.5 * self.e[i]
            rr.append(mid - self.bodies.x[k])
        return np.concatenate(xs), np.concatenate(ss), np.concatenate(ii), np.concatenate(rr)


class FixedParticles(Effect):
    """Fixed particles: half-way bounce-back on their links, force and torque."""

    name = "particles: fixed obstacles (bounce-back, force)"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.fill_fixed(sim.f2)


class ParticleCoupling(Effect):
    """Free particles: link sums, implicit velocity update, Ladd's ghost fill (Eqs. (8)-(12))."""

    name = "particles: Ladd coupling + implicit velocity update"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.couple_free(sim.f2, sim.force)


class ParticleFluxCorrection(Effect):
    """Flow-rate control with particles: replaces the kernel's flux sum (which runs over particle
    nodes too) by the mixture's, ``sum_fluid (j_z - F_z/2) + sum_k n_k U_z,k``.

    The fluid's z-momentum ``P`` (post-collision, fluid nodes) is kept by exact bookkeeping rather
    than summed over the nodes: per step ``P += F_z n_fluid - (exchange through wall links) -
    (exchange through particle links)``, and each move subtracts the momentum of covered nodes and
    adds that of uncovered ones. The wall exchange is summed from each wall link's two slots
    (``wall_exchange``), so it holds for any wall rule. ``P`` is recomputed from the populations
    every ``resync_every`` steps against round-off. Runs after the sweep, before the controller."""

    name = "particles: flow-rate flux correction"
    phase = "post"

    def __init__(self, system: ParticleSystem, wall_links=(), resync_every: int = 1000):
        self.system = system
        parts = [k for k in wall_links if len(k)]
        ez = system.e[:, 2]
        if parts:
            cat = {a: np.concatenate([getattr(k, a) for k in parts]) for a in ("fluid", "solid", "i", "opp")}
        else:
            cat = {a: np.zeros(0, np.int64) for a in ("fluid", "solid", "i", "opp")}
        sel = ez[cat["i"]] != 0
        self.fluid, self.solid = cat["fluid"][sel], cat["solid"][sel]
        self.i, self.opp = cat["i"][sel], cat["opp"][sel]
        self.ez = ez[self.i].astype(np.float64)
        self.resync_every = int(resync_every)
        self.p_fluid = None
        self.steps = 0

    def __call__(self, sim) -> None:
        s = self.system
        f2 = sim.f2  # populations the sweep read, ghost slots included
        if self.p_fluid is None:
            self.p_fluid = float(s.fluid_momentum(f2)[3])
            s.moved[:] = 0.0
        self.p_fluid -= s.moved[2]  # the previous move's covered and uncovered nodes
        s.moved[:] = 0.0
        fz = float(sim.force[2])
        e_wall = wall_exchange(f2, s.owner, self.fluid, self.solid, self.i, self.opp, self.ez)
        self.p_fluid += fz * s.n_fluid - e_wall - float(s.exch[:, 2].sum())
        self.steps += 1
        if self.steps % self.resync_every == 0:
            self.p_fluid = float(s.fluid_momentum(plane_buffer(sim.f_next))[3])
        # per fluid node the kernel sums the streamed j_z + F_z/2 = post-collision j_z - F_z/2
        sim.last_flux = self.p_fluid - 0.5 * fz * s.n_fluid + float(np.dot(s.nown, s.bodies.v[:, 2]))


class ParticleMotion(Effect):
    """Rigid-body drift of the free particles (Eqs. (13)-(15)) and the remap, with the momentum of
    covered and uncovered nodes."""

    name = "particles: motion + remap (cover/uncover)"
    phase = "post"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.move(plane_buffer(sim.f_next))


class BouzidiParticleGuard(Effect):
    """With interpolated walls: a wall link whose second fluid node (``x - e_i``) belongs to a
    particle falls back to plain bounce-back (that node holds no fluid)."""

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


class MassCorrection(Effect):
    """Restores the mean fluid density lost by the moving particles' remap (module docstring):
    every ``every`` steps, after the motion, ``f_i += w_i d_rho`` on every fluid node with
    ``d_rho = rho_target - M / n_fluid``, where ``rho_target`` is the mean density at the first
    call. Adds no momentum. ``added`` is the total mass added (lattice units)."""

    name = "particles: mass correction"
    phase = "post"
    record_key = "mass_correction"

    def __init__(self, system: ParticleSystem, every: int = 25):
        self.system = system
        self.every = int(every)
        self.rho_target = None
        self.added = 0.0
        self.calls = 0

    def __call__(self, sim) -> None:
        s = self.system
        self.calls += 1
        f2 = plane_buffer(sim.f_next)
        if self.rho_target is None:
            self.rho_target = s.fluid_mass(f2) / max(s.n_fluid, 1)
        if self.calls % self.every:
            return
        mass = s.fluid_mass(f2)
        n = int(s.n_fluid)
        d_rho = self.rho_target - mass / max(n, 1)
        _add_density(f2, s.owner, s.w, d_rho)
        self.added += d_rho * n

    def record(self) -> dict:
        return {"mass_added": self.added, "calls": self.calls}


@njit(parallel=True, cache=True)
def _add_density(f2, owner, w, d_rho):
    n = owner.shape[0]
    for node in prange(n):
        if owner[node] == FLUID:
            for i in range(w.shape[0]):
                f2[i, node] += w[i] * d_rho


def particle_effects(system: ParticleSystem, flux_control: bool = False, bouzidi_links=None, wall_links=()):
    """The effects a particle system needs, and nothing else: ``(pre, post_before_control,
    post_after_control)``. The flux correction runs after the sweep and before the flow-rate
    controller; the motion changes the owner map, so it runs after the correction."""
    pre: list[fx.Effect] = []
    if bouzidi_links is not None and len(bouzidi_links) and system.n:
        pre.append(BouzidiParticleGuard(system, bouzidi_links))
    if len(system.fixed_ids):
        pre.append(FixedParticles(system))
    if len(system.free_ids):
        pre.append(ParticleCoupling(system))
    before = [ParticleFluxCorrection(system, wall_links)] if flux_control and system.n else []
    after = [ParticleMotion(system), MassCorrection(system)] if len(system.free_ids) else []
    return pre, before, after

