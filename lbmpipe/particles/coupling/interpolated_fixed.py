"""Fixed particles with an interpolated bounce-back (``numerics.particle_boundary: bouzidi`` or
``cli``); lattice units. The link rule of ``interpolated`` (``surface.link_base``) with ``u_w =
0``: ghost ``G - w_i delta`` with ``G`` the interpolation of ``f*`` at the link's fraction ``q``
and ``delta`` the particle's mass excess. With ``u_w = 0`` both momentum exchanges agree, so a
fixed particle's force is ``sum e_i (f*_i(x) + f[opp(i), s] - 2 w_i rho0)`` (reference pressure
removed as in ``ladd``), acting at the surface point ``r = x + q e_i - X``. The paper's half-way
rule stays in ``ladd.fixed_fill``.
"""

from __future__ import annotations

import math

import numba
from numba import njit, prange

from ..rigid import quat_to_matrix
from .nodes import FLUID
from .surface import entry_fraction, link_base


@njit(parallel=True, cache=True)
def fixed_fill_surface(f2, owner, ids, B, D, lat, G, L, shape, S, rule):
    """Interpolated bounce-back on the live links of the fixed particles ``ids`` (dead links are
    dropped, as in ``ladd.fixed_fill``), their force and torque, and ``exch``.

    Inputs as ``ladd.fixed_fill`` (``B.x`` and ``B.q`` read), plus ``shape``
    (``interpolated.Shapes``) and ``S`` (``interpolated.SurfaceScratch``; ``f``, ``g``, ``q``
    used), ``rule`` (``surface.BOUZIDI`` or ``CLI``). Outputs: ``f2[opp(i), s]`` on every live
    link of ``ids``; ``D.force``, ``D.torque``, ``D.exch`` of ``ids``; dead links removed. Reads
    fluid slots only and writes particle slots only: parallel over particles, sums in link order
    (bits independent of the thread count)."""
    # Bundled arguments are taken apart by field access, never by tuple unpacking: in a parallel
    # kernel (numba 0.68) writes through an array unpacked from a tuple are lost.
    x = B.x
    q = B.q
    force = D.force
    torque = D.torque
    exch = D.exch
    w = lat.w
    opp = lat.opp
    rho0 = lat.rho0
    dims = G.dims
    az = G.az
    origin = G.origin
    xmap = G.xmap
    ymap = G.ymap
    zmap = G.zmap
    e = G.e
    lbase = L.lbase
    lcnt = L.lcnt
    LN = L.LN
    LC = L.LC
    chg = L.chg
    kind = shape.kind
    hh = shape.h
    SF = S.f
    SG = S.g
    SQ = S.q
    Q = e.shape[0]
    nx = dims[0]
    ny = dims[1]
    nz = dims[2]
    for m in prange(ids.shape[0]):
        k = ids[m]
        tid = numba.get_thread_id()
        LF = SF[tid]
        LG = SG[tid]
        LQ = SQ[tid]
        A = quat_to_matrix(q[k])
        h0 = hh[k, 0]
        h1 = hh[k, 1]
        h2 = hh[k, 2]
        kk = kind[k]
        O0 = origin[0] - x[k, 0]
        O1 = origin[1] - x[k, 1]
        O2 = origin[2] - x[k, 2]
        off0 = lbase[k, 1]
        exc = 0.0
        wsum = 0.0
        # pass 1: compaction, fractions, interpolated ghost bases, the mass excess
        for i in range(1, Q):
            ie0 = e[i, 0]
            ie1 = e[i, 1]
            ie2 = e[i, 2]
            oi = opp[i]
            # body frame: the link's unit direction, and the fluid node at c = 0 (A^T (O - e_i))
            ex = float(ie0)
            ey = float(ie1)
            ez = float(ie2)
            ni = math.sqrt(ex * ex + ey * ey + ez * ez)
            d0 = (A[0, 0] * ex + A[1, 0] * ey + A[2, 0] * ez) / ni
            d1 = (A[0, 1] * ex + A[1, 1] * ey + A[2, 1] * ez) / ni
            d2 = (A[0, 2] * ex + A[1, 2] * ey + A[2, 2] * ez) / ni
            P0 = A[0, 0] * (O0 - ex) + A[1, 0] * (O1 - ey) + A[2, 0] * (O2 - ez)
            P1 = A[0, 1] * (O0 - ex) + A[1, 1] * (O1 - ey) + A[2, 1] * (O2 - ez)
            P2 = A[0, 2] * (O0 - ex) + A[1, 2] * (O1 - ey) + A[2, 2] * (O2 - ez)
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
                c0 = float(LC[pos, 0])
                c1 = float(LC[pos, 1])
                c2 = float(LC[pos, 2])
                qq = entry_fraction(kk, h0, h1, h2, P0 + A[0, 0] * c0 + A[1, 0] * c1 + A[2, 0] * c2,
                                    P1 + A[0, 1] * c0 + A[1, 1] * c1 + A[2, 1] * c2,
                                    P2 + A[0, 2] * c0 + A[1, 2] * c1 + A[2, 2] * c2, d0, d1, d2, ni)
                # x - e_i from the unwrapped coordinates c - 2 e_i through the wrap tables
                x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                      + zmap[LC[pos, 2] - 2 * ie2 + nz])
                fv = f2[i, xn]
                gv, cc = link_base(rule, qq, fv, f2[i, x2], f2[oi, xn], owner[x2] == FLUID)
                exc += gv - fv
                wsum += w[i]
                p = pos - off0
                LF[p] = fv
                LG[p] = gv
                LQ[p] = qq
                pos += 1
            lcnt[k, i] = end - b0
        delta = exc / wsum if wsum > 0.0 else 0.0
        # pass 2: ghosts with the mass excess taken back; force and torque at the surface points
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
            dw = w[i] * delta
            ex = float(e[i, 0])
            ey = float(e[i, 1])
            ez = float(e[i, 2])
            a0 = O0 - ex
            a1 = O1 - ey
            a2 = O2 - ez
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            sv = 0.0
            svx = 0.0
            svy = 0.0
            svz = 0.0
            for pos in range(b0, end):
                p = pos - off0
                gv = LG[p] - dw
                f2[oi, LN[pos, 1]] = gv
                qq = LQ[p]
                val = LF[p] + gv - 2.0 * wr
                sv += val
                svx += val * (a0 + LC[pos, 0] + qq * ex)
                svy += val * (a1 + LC[pos, 1] + qq * ey)
                svz += val * (a2 + LC[pos, 2] + qq * ez)
            cnt = float(end - b0)
            e0 += 2.0 * ex * wr * cnt
            e1 += 2.0 * ey * wr * cnt
            e2 += 2.0 * ez * wr * cnt
            fx_ += ex * sv
            fy_ += ey * sv
            fz_ += ez * sv
            tx += svy * ez - svz * ey
            ty += svz * ex - svx * ez
            tz += svx * ey - svy * ex
        force[k, 0] = fx_
        force[k, 1] = fy_
        force[k, 2] = fz_
        torque[k, 0] = tx
        torque[k, 1] = ty
        torque[k, 2] = tz
        exch[k, 0] = fx_ + e0
        exch[k, 1] = fy_ + e1
        exch[k, 2] = fz_ + e2
