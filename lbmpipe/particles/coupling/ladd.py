"""Ladd's moving bounce-back and momentum exchange on the particle links, Eqs. (8)-(12), with the
implicit velocity update of the free particles (``implicit``); lattice units throughout.

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

Fixed particles
---------------
Never move and never remap: their links change only when a free particle covers or uncovers a
neighbouring fluid node. Each step runs only the bounce-back fill ``f[opp(i), s] = f*_i(x)`` and
the force and torque sums over their lists (``fixed_fill``).

Cost. One pass per particle over its links (``prange`` over particles: a scattered read of
``f*_i(x)`` and a scattered write of the ghost slot per link), bound by the latency of those
scattered accesses (out of cache after the sweep; prefetched ``PREFETCH_AHEAD`` links ahead).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ..rigid import quat_to_matrix
from .implicit import solve6
from .nodes import FLUID
from .prefetch import PREFETCH_AHEAD, prefetch


class BodyState(NamedTuple):
    """The rigid bodies' arrays the coupling reads and updates (``rigid.Bodies``, lattice units):
    centres ``x`` (N, 3), ``mass`` (N,), principal moments ``inertia`` (N, 3), orientations ``q``
    (N, 4) (body -> lab), velocities ``v`` (N, 3) and body-frame angular velocities ``wb`` (N, 3)."""

    x: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    q: np.ndarray
    v: np.ndarray
    wb: np.ndarray


class Loads(NamedTuple):
    """Per-particle loads (N, 6) or (N, 3), lab frame, about the centre (lattice units):
    ``fext`` the external force and torque of the step; ``imp`` the impulse of the nodes covered
    and uncovered by the last move, not yet applied; ``om`` the lab angular velocity; ``force``,
    ``torque`` the hydrodynamic force and torque of the step; ``exch`` the momentum the fluid lost
    through the particle's links in the step (the flow-rate bookkeeping)."""

    fext: np.ndarray
    imp: np.ndarray
    om: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    exch: np.ndarray


@njit(parallel=True, cache=True)
def couple_free(f2, owner, ids, B, D, lat, G, L, scratch):
    """One step of the coupling of the free particles ``ids`` (module docstring), one particle per
    iteration: pass 1 swap-removes dead links (lazy deletion; only links with a node marked in
    ``chg`` are tested) and sums ``(F0, T0)`` (reference pressure removed) and the self-friction
    ``Z`` over the live ones; the implicit update ``(M + Z) V' = M V + (F0, T0) + F_ext + P`` gives the new
    velocities; pass 2 writes Ladd's ghost populations Eq. (8) with ``V'``. Outputs: ``v``,
    ``wb``, lab ``om``, and the hydrodynamic ``force`` and ``torque`` of the step (Eqs. (9)-(12)
    with ``V'``, plus the cover/uncover impulses ``imp``, which are cleared); ``exch[k]``, the
    momentum the fluid loses through k's links (the same with the reference pressure, for the
    flow-rate bookkeeping).

    Inputs: ``f2`` (Q, nodes) float64 post-collision populations of the step, ghost slots included;
    ``owner`` (nodes,) int32; ``ids`` (M,) int64 free particles; ``B`` (``BodyState``), ``D``
    (``Loads``; ``fext`` and ``imp`` read), ``lat`` (``LatticeRef``), ``G`` (``Grid``), ``L``
    (``LinkLists``); ``scratch = (SF, SM)``: per-thread buffers (threads, max links of a particle)
    and (threads, 6, 7). Outputs: ``f2[opp(i), s]`` of every live link of ``ids``; ``B.v``,
    ``B.wb``, ``D.om``, ``D.force``, ``D.torque``, ``D.exch`` of ``ids``; ``D.imp[ids] = 0``; dead
    links of ``ids`` removed from ``L`` (the marks stay: ``clear_changed`` after the last pass).
    Invariants: fluid + particles conserve momentum to round-off (the fluid loses ``exch``, the
    particle gains ``force - imp`` plus the reference part); each particle is one iteration with
    its sums in link order, so the bits do not depend on the thread count."""
    # Bundled arguments are taken apart by field access, never by tuple unpacking: in a parallel
    # kernel (numba 0.68) writes through an array unpacked from a tuple are lost.
    x = B.x
    mass = B.mass
    inertia = B.inertia
    q = B.q
    v = B.v
    wb = B.wb
    fext = D.fext
    imp = D.imp
    om = D.om
    force = D.force
    torque = D.torque
    exch = D.exch
    w = lat.w
    opp = lat.opp
    rho0 = lat.rho0
    origin = G.origin
    e = G.e
    lbase = L.lbase
    lcnt = L.lcnt
    LN = L.LN
    LC = L.LC
    chg = L.chg
    SF = scratch[0]
    SM = scratch[1]
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
        # ---- pass 1: compaction and sums per direction, folded into (F0, T0) and Z
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
                if pos + PREFETCH_AHEAD < end:
                    prefetch(f2, i, LN[pos + PREFETCH_AHEAD, 0], 0)
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
        # ---- implicit update (implicit.py): (M + Z) V' = M V + (F0, T0) + F_ext + P
        A = quat_to_matrix(q[k])
        gs = (g0, g1, g2, g3, g4, g5)
        for p in range(3):
            M[p, p] += mass[k]
            M[p, 6] = mass[k] * v[k, p] + gs[p] + fext[k, p] + imp[k, p]
        for p in range(3):
            for r in range(3):
                acc = 0.0
                for s_ in range(3):
                    acc += A[p, s_] * inertia[k, s_] * A[r, s_]
                M[3 + p, 3 + r] += acc
            acc = 0.0
            for s_ in range(3):
                acc += A[p, s_] * inertia[k, s_] * wb[k, s_]
            M[3 + p, 6] = acc + gs[3 + p] + fext[k, 3 + p] + imp[k, 3 + p]
        solve6(M)
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
            force[k, p] = gs[p] - fz_ + imp[k, p]
            torque[k, p] = gs[3 + p] - tz_ + imp[k, 3 + p]
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
                if pos + PREFETCH_AHEAD < end:
                    prefetch(f2, oi, LN[pos + PREFETCH_AHEAD, 1], 1)
                f2[oi, LN[pos, 1]] = LF[pos - off0] - c6eu - LC[pos, 0] * cx - LC[pos, 1] * cy - LC[pos, 2] * cz


@njit(parallel=True, cache=True)
def fixed_fill(f2, owner, ids, B, D, lat, G, L):
    """Fixed particles: half-way bounce-back on their live links (Eq. (8) with u_b = 0; dead links
    are dropped, as in ``couple_free``) and their force and torque, Eqs. (9)-(12) (reference
    pressure removed); ``exch`` as in ``couple_free``.

    Inputs as ``couple_free`` (``ids`` the fixed particles; only ``B.x`` read). Outputs:
    ``f2[opp(i), s] = f2[i, x]`` on every live link of ``ids``; ``D.force``, ``D.torque``,
    ``D.exch`` of ``ids``; dead links removed. Parallel over particles, sums in link order."""
    # Bundled arguments are taken apart by field access, never by tuple unpacking: in a parallel
    # kernel (numba 0.68) writes through an array unpacked from a tuple are lost.
    x = B.x
    force = D.force
    torque = D.torque
    exch = D.exch
    w = lat.w
    opp = lat.opp
    rho0 = lat.rho0
    origin = G.origin
    e = G.e
    lbase = L.lbase
    lcnt = L.lcnt
    LN = L.LN
    LC = L.LC
    chg = L.chg
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
def accumulate_loads(ids, force, torque, force_sum, torque_sum, n_sum):
    """Add the step's ``force`` and ``torque`` (N, 3) of the particles ``ids`` to the running sums
    and count the step in ``n_sum`` (N,) (the mean force over a sampling interval)."""
    for m in range(ids.shape[0]):
        k = ids[m]
        for p in range(3):
            force_sum[k, p] += force[k, p]
            torque_sum[k, p] += torque[k, p]
        n_sum[k] += 1
