"""The free particles' coupling with an interpolated bounce-back on their surfaces and/or the
Galilean-invariant momentum exchange (Wen, Zhang, Tu, Wang & Fang 2014), with the implicit velocity
update (``implicit``); lattice units. It runs for ``numerics.particle_boundary: bouzidi`` or
``cli``, or ``numerics.momentum_exchange: galilean``; the paper's pair (``bounce_back``, ``ladd``)
runs ``ladd.couple_free``, unchanged.

Link rule
---------
A link joins fluid node ``x`` to particle node ``s = x + e_i``; ``q`` is the fraction of it in the
fluid (``surface.link_fraction``, recomputed every step from the body's position and orientation:
one ray-shape intersection per link), ``r = x + q e_i - X`` the surface point about the centre
and ``u_w = U + Omega x r`` the wall velocity there. The pull of ``opp(i)`` at ``x`` reads slot
``(opp(i), s)``, which gets

    f[opp(i), s] = G - w_i delta - c 6 w_i rho0 (e_i . u_w)

with the ghost base ``G`` and coefficient ``c`` of the rule (``surface.link_base``): Bouzidi,
Firdaouss & Lallemand (2001) with the moving-wall term (as in Lallemand & Luo 2003),

    q <  1/2:  G = 2q f*_i(x) + (1 - 2q) f*_i(x - e_i),           c = 1
    q >= 1/2:  G = f*_i(x) / (2q) + (2q - 1)/(2q) f*_opp(i)(x),     c = 1 / (2q),

or the central linear interpolation (CLI) of Ginzburg, Verhaeghe & d'Humieres (2008),

    G = f*_i(x) + (1 - 2q)/(1 + 2q) [f*_i(x - e_i) - f*_opp(i)(x)],  c = 2 / (1 + 2q),

whose steady closure depends on the TRT rates through the magic parameter only (measured:
``benchmarks/particle_validation.py``, the drag of a sphere array is the same at tau 1 and 1.78
with TRT; Bouzidi's rule changes by 1.6 %). Where ``x - e_i`` is not fluid (the wall, another
particle, this one) the rules fall back to local ones, as the pipe wall's does
(``fluid.boundaries.fill_bouzidi``): ``q < 1/2`` to half-way bounce-back, CLI at ``q >= 1/2`` to
Bouzidi's. Every read is of a fluid node's slot and every write of a particle node's, so particles
are independent (``prange``). With ``rule == HALF_WAY`` every link is half-way (``q = 1/2``,
``G = f*_i(x)``, ``c = 1``, ``r`` the midpoint): Ladd's Eq. (8).

Mass. The interpolations do not conserve mass; as on the pipe wall, the excess over plain
bounce-back, ``sum (G - f*_i(x))`` over the particle's links, is taken back in the same step,
spread over the links in proportion to ``w_i``: ``delta = sum (G - f*_i(x)) / sum w_i``. Over the
closed link set of a particle surrounded by fluid ``sum w_i e_i = 0`` (each lattice line enters
and leaves the particle once, with equal weights), so this changes its force by nothing and its
torque by round-off. Zero for half-way links.

Momentum exchange
-----------------
``ladd``: the link force is what the fluid loses, ``F = e_i (f*_i(x) + f[opp(i), s])`` (Eq. (9)),
with the reference pressure removed as in ``ladd`` (``- 2 w_i rho0 e_i``; the fluid still loses it,
``exch``). ``galilean`` (Wen et al. 2014, Eq. (9) there): the populations are counted relative to
the wall, ``F = f*_i (e_i - u_w) - f[opp(i), s] (e_opp(i) - u_w)``, i.e. the Ladd force minus
``(f*_i(x) - f[opp(i), s]) u_w``: the momentum of the mass that crosses the link at the wall
velocity, which is not the fluid's stress on the wall. Its torque is ``r x F``. The covered and
uncovered nodes get the matching treatment in ``remap_galilean``.

Implicit update
---------------
The ghost is linear in the new velocity ``V' = (U', Omega')``: ``G - w delta - c 6 w rho0 J.V'``
with ``J = [e_i; r x e_i]``. So, as in ``implicit``, ``(F, T) = g - Z V'`` with the self-friction
``Z = sum c 6 w_i rho0 J J^T`` (each link weighted by its coefficient ``c``; symmetric, >= 0),
``g = sum [e_i; r x e_i] (f*_i + G - w_i delta - 2 w_i rho0)``, and ``(M + Z) V' = M V + g + F_ext
+ P``. The Galilean term ``(f*_i - f[opp(i), s]) u_w`` is quadratic in ``V'``; it is taken
explicitly with the velocity at the start of the step (``V``, in both factors): an error of order
``|V' - V| |u_w|`` per step, and ``Z`` stays symmetric.

Pre/postconditions as ``ladd.couple_free`` (the same inputs and outputs, the same lazy deletion of
dead links), with: fluid + particles conserve momentum to round-off with ``ladd`` (the fluid loses
``exch``, the particle gains ``force - imp`` plus the reference part); with ``galilean`` the
particle gains ``exch`` minus the reference part minus the Galilean term. One particle per
iteration, its sums in link order: the bits do not depend on the thread count.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ..rigid import quat_to_matrix
from .implicit import solve6
from .nodes import FLUID
from .prefetch import PREFETCH_AHEAD, prefetch, prefetch1
from .surface import HALF_WAY, entry_fraction, link_base


class Shapes(NamedTuple):
    """The particles' shapes (``rigid.Bodies``): ``kind`` (N,) int64 and half-extents ``h`` (N, 3)."""

    kind: np.ndarray
    h: np.ndarray


class SurfaceScratch(NamedTuple):
    """Per-thread buffers (threads, max links of a particle) of the link passes: ``f`` the
    population ``f*_i(x)``, ``g`` the interpolated ghost base ``G``, ``q`` the fraction and ``c``
    the moving-wall coefficient of each link; ``m`` (threads, 6, 7) the 6x6 system."""

    f: np.ndarray
    g: np.ndarray
    q: np.ndarray
    c: np.ndarray
    m: np.ndarray


def surface_scratch(threads: int, links: int) -> SurfaceScratch:
    """Zeroed ``SurfaceScratch`` for ``threads`` threads and particles of up to ``links`` links."""
    return SurfaceScratch(*(np.zeros((threads, links)) for _ in range(4)), np.zeros((threads, 6, 7)))


@njit(parallel=True, cache=True)
def couple_free_surface(f2, owner, ids, B, D, lat, G, L, shape, S, rule, galilean):
    """One step of the coupling of the free particles ``ids`` (module docstring): pass 1 drops the
    dead links, computes each live link's ``q``, ``G`` and ``c`` and the particle's mass excess
    ``delta``, then sums ``g``, ``Z`` (and the Galilean term); the implicit update gives ``V'``;
    pass 2 writes the ghosts with ``V'``.

    Inputs as ``ladd.couple_free``, plus ``shape`` (``Shapes``), ``S`` (``SurfaceScratch``),
    ``rule`` (``surface.HALF_WAY``, ``BOUZIDI`` or ``CLI``) and ``galilean`` (bool: Wen et al.'s
    momentum exchange, else Ladd's). Outputs as ``ladd.couple_free``: ``f2[opp(i), s]`` of every live link
    of ``ids``; ``B.v``, ``B.wb``, ``D.om``, ``D.force``, ``D.torque``, ``D.exch`` of ``ids``;
    ``D.imp[ids] = 0``; dead links of ``ids`` removed from ``L``."""
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
    SCc = S.c
    SM = S.m
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
        LK = SCc[tid]
        M = SM[tid]
        A = quat_to_matrix(q[k])
        h0 = hh[k, 0]
        h1 = hh[k, 1]
        h2 = hh[k, 2]
        kk = kind[k]
        # fluid node about the centre: r_x = origin + c - e_i - X, per direction a constant plus c
        O0 = origin[0] - x[k, 0]
        O1 = origin[1] - x[k, 1]
        O2 = origin[2] - x[k, 2]
        # the velocity at the start of the step (the Galilean term's, module docstring)
        U0 = v[k, 0]
        U1 = v[k, 1]
        U2 = v[k, 2]
        W0 = om[k, 0]
        W1 = om[k, 1]
        W2 = om[k, 2]
        off0 = lbase[k, 1]
        # ---- pass 1a: compaction, fractions, ghost bases; the interpolation's mass excess
        exc = 0.0
        wsum = 0.0
        for i in range(1, Q):
            ie0 = e[i, 0]
            ie1 = e[i, 1]
            ie2 = e[i, 2]
            oi = opp[i]
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            if rule == HALF_WAY:
                # The scattered reads first, in a loop without branches: their cache misses (f is
                # out of cache after the sweep) overlap instead of waiting one by one (as in ``ladd``).
                for pos in range(b0, end):
                    if pos + PREFETCH_AHEAD < end:
                        prefetch(f2, i, LN[pos + PREFETCH_AHEAD, 0], 0)
                    LF[pos - off0] = f2[i, LN[pos, 0]]
            else:
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
                # One loop per link: the gathers f*_i(x), f*_opp(i)(x), f*_i(x - e_i) and
                # owner[x - e_i], all prefetched PREFETCH_AHEAD links ahead, then q and G, whose
                # arithmetic runs while the next links' lines are in flight (issue 45: 20-28 % off
                # the kernel against separate gather and arithmetic loops; the same operations,
                # the same bits). x - e_i from the unwrapped coordinates c - 2 e_i through the wrap
                # tables. Dead links are computed too and dropped below.
                for pos in range(b0, end):
                    if pos + PREFETCH_AHEAD < end:
                        pa = pos + PREFETCH_AHEAD
                        xa = LN[pa, 0]
                        prefetch(f2, i, xa, 0)
                        prefetch(f2, oi, xa, 0)
                        xb = ((xmap[LC[pa, 0] - 2 * ie0 + nx] * ny + ymap[LC[pa, 1] - 2 * ie1 + ny]) * az
                              + zmap[LC[pa, 2] - 2 * ie2 + nz])
                        prefetch(f2, i, xb, 0)
                        prefetch1(owner, xb)
                    p = pos - off0
                    xn = LN[pos, 0]
                    fv = f2[i, xn]
                    fo = f2[oi, xn]
                    x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                          + zmap[LC[pos, 2] - 2 * ie2 + nz])
                    fb = f2[i, x2]
                    behind = owner[x2] == FLUID
                    c0 = float(LC[pos, 0])
                    c1 = float(LC[pos, 1])
                    c2 = float(LC[pos, 2])
                    qq = entry_fraction(kk, h0, h1, h2, P0 + A[0, 0] * c0 + A[1, 0] * c1 + A[2, 0] * c2,
                                        P1 + A[0, 1] * c0 + A[1, 1] * c1 + A[2, 1] * c2,
                                        P2 + A[0, 2] * c0 + A[1, 2] * c1 + A[2, 2] * c2, d0, d1, d2, ni)
                    gv, cc = link_base(rule, qq, fv, fb, fo, behind)
                    LF[p] = fv
                    LG[p] = gv
                    LQ[p] = qq
                    LK[p] = cc
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
                        LG[pos - off0] = LG[end - off0]
                        LQ[pos - off0] = LQ[end - off0]
                        LK[pos - off0] = LK[end - off0]
                        continue
                pos += 1
            lcnt[k, i] = end - b0
            if rule == HALF_WAY:
                for pos in range(b0, end):
                    p = pos - off0
                    LG[p] = LF[p]
                    LQ[p] = 0.5
                    LK[p] = 1.0
                continue
            # the interpolation's mass excess over the live links, in link order
            for pos in range(b0, end):
                p = pos - off0
                exc += LG[p] - LF[p]
                wsum += w[i]
        delta = exc / wsum if wsum > 0.0 else 0.0
        # ---- pass 1b: sums per direction, folded into g = (F0, T0), Z and the Galilean term
        for p_ in range(6):
            for r_ in range(7):
                M[p_, r_] = 0.0
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        g3 = 0.0
        g4 = 0.0
        g5 = 0.0
        h0 = 0.0
        h1 = 0.0
        h2 = 0.0
        h3 = 0.0
        h4 = 0.0
        h5 = 0.0
        e0 = 0.0
        e1 = 0.0
        e2 = 0.0
        for i in range(1, Q):
            wr = w[i] * rho0
            c6 = 6.0 * wr
            dw = w[i] * delta
            ex = float(e[i, 0])
            ey = float(e[i, 1])
            ez = float(e[i, 2])
            a0 = O0 - ex
            a1 = O1 - ey
            a2 = O2 - ez
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            sc = 0.0
            scx = 0.0
            scy = 0.0
            scz = 0.0
            sxx = 0.0
            syy = 0.0
            szz = 0.0
            sxy = 0.0
            sxz = 0.0
            syz = 0.0
            sv = 0.0
            svx = 0.0
            svy = 0.0
            svz = 0.0
            for pos in range(b0, end):
                p = pos - off0
                qq = LQ[p]
                cc = LK[p]
                gv = LG[p] - dw
                LG[p] = gv
                fv = LF[p]
                rx = a0 + LC[pos, 0] + qq * ex
                ry = a1 + LC[pos, 1] + qq * ey
                rz = a2 + LC[pos, 2] + qq * ez
                val = fv + gv - 2.0 * wr
                sv += val
                svx += val * rx
                svy += val * ry
                svz += val * rz
                sc += cc
                scx += cc * rx
                scy += cc * ry
                scz += cc * rz
                sxx += cc * rx * rx
                syy += cc * ry * ry
                szz += cc * rz * rz
                sxy += cc * rx * ry
                sxz += cc * rx * rz
                syz += cc * ry * rz
                if galilean:
                    # -(f* - ghost) u_w, both at the start-of-step velocity
                    uwx = U0 + W1 * rz - W2 * ry
                    uwy = U1 + W2 * rx - W0 * rz
                    uwz = U2 + W0 * ry - W1 * rx
                    s_ = fv - gv + cc * c6 * (ex * uwx + ey * uwy + ez * uwz)
                    h0 -= s_ * uwx
                    h1 -= s_ * uwy
                    h2 -= s_ * uwz
                    h3 -= s_ * (ry * uwz - rz * uwy)
                    h4 -= s_ * (rz * uwx - rx * uwz)
                    h5 -= s_ * (rx * uwy - ry * uwx)
            cnt = float(end - b0)
            if cnt == 0.0:
                continue
            # the reference part the particle does not take (``ladd``) still leaves the fluid
            e0 += 2.0 * ex * wr * cnt
            e1 += 2.0 * ey * wr * cnt
            e2 += 2.0 * ez * wr * cnt
            g0 += ex * sv
            g1 += ey * sv
            g2 += ez * sv
            g3 += svy * ez - svz * ey
            g4 += svz * ex - svx * ez
            g5 += svx * ey - svy * ex
            # Z += c6 sum c [e; r x e][e; r x e]^T, from the c-weighted moments of r
            q0 = scy * ez - scz * ey
            q1 = scz * ex - scx * ez
            q2 = scx * ey - scy * ex
            M[0, 0] += c6 * sc * ex * ex
            M[0, 1] += c6 * sc * ex * ey
            M[0, 2] += c6 * sc * ex * ez
            M[1, 1] += c6 * sc * ey * ey
            M[1, 2] += c6 * sc * ey * ez
            M[2, 2] += c6 * sc * ez * ez
            M[0, 3] += c6 * ex * q0
            M[0, 4] += c6 * ex * q1
            M[0, 5] += c6 * ex * q2
            M[1, 3] += c6 * ey * q0
            M[1, 4] += c6 * ey * q1
            M[1, 5] += c6 * ey * q2
            M[2, 3] += c6 * ez * q0
            M[2, 4] += c6 * ez * q1
            M[2, 5] += c6 * ez * q2
            M[3, 3] += c6 * (syy * ez * ez - 2.0 * syz * ey * ez + szz * ey * ey)
            M[4, 4] += c6 * (szz * ex * ex - 2.0 * sxz * ex * ez + sxx * ez * ez)
            M[5, 5] += c6 * (sxx * ey * ey - 2.0 * sxy * ex * ey + syy * ex * ex)
            M[3, 4] += c6 * (syz * ex * ez - sxy * ez * ez - szz * ex * ey + sxz * ey * ez)
            M[3, 5] += c6 * (sxy * ey * ez - syy * ex * ez - sxz * ey * ey + syz * ex * ey)
            M[4, 5] += c6 * (sxz * ex * ey - syz * ex * ex - sxx * ey * ez + sxy * ex * ez)
        for p_ in range(6):
            for r_ in range(p_):
                M[p_, r_] = M[r_, p_]
        Zc = np.empty((6, 6))
        for p_ in range(6):
            for r_ in range(6):
                Zc[p_, r_] = M[p_, r_]
        # ---- implicit update (implicit.py): (M + Z) V' = M V + g + h + F_ext + P
        gs = (g0 + h0, g1 + h1, g2 + h2, g3 + h3, g4 + h4, g5 + h5)
        for p_ in range(3):
            M[p_, p_] += mass[k]
            M[p_, 6] = mass[k] * v[k, p_] + gs[p_] + fext[k, p_] + imp[k, p_]
        for p_ in range(3):
            for r_ in range(3):
                acc = 0.0
                for s_ in range(3):
                    acc += A[p_, s_] * inertia[k, s_] * A[r_, s_]
                M[3 + p_, 3 + r_] += acc
            acc = 0.0
            for s_ in range(3):
                acc += A[p_, s_] * inertia[k, s_] * wb[k, s_]
            M[3 + p_, 6] = acc + gs[3 + p_] + fext[k, 3 + p_] + imp[k, 3 + p_]
        solve6(M)
        for p_ in range(3):
            v[k, p_] = M[p_, 6]
            om[k, p_] = M[3 + p_, 6]
        for p_ in range(3):  # body frame: wb = A^T Omega
            wb[k, p_] = A[0, p_] * M[3, 6] + A[1, p_] * M[4, 6] + A[2, p_] * M[5, 6]
        for p_ in range(3):
            fz_ = 0.0
            tz_ = 0.0
            for r_ in range(6):
                fz_ += Zc[p_, r_] * M[r_, 6]
                tz_ += Zc[3 + p_, r_] * M[r_, 6]
            force[k, p_] = gs[p_] - fz_ + imp[k, p_]
            torque[k, p_] = gs[3 + p_] - tz_ + imp[k, 3 + p_]
        # what the fluid loses: the Ladd sum with the reference part, without the Galilean term
        exch[k, 0] = force[k, 0] - imp[k, 0] - h0 + e0
        exch[k, 1] = force[k, 1] - imp[k, 1] - h1 + e1
        exch[k, 2] = force[k, 2] - imp[k, 2] - h2 + e2
        for p_ in range(6):
            imp[k, p_] = 0.0
        # ---- pass 2: ghost fill with the new velocity
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
            # c6 e . u_w = c6 e . U + r . (c6 e x Omega)
            cx = c6 * (ey * oz - ez * oy)
            cy = c6 * (ez * ox - ex * oz)
            cz = c6 * (ex * oy - ey * ox)
            c6eu = c6 * (ex * ux + ey * uy + ez * uz)
            a0 = O0 - ex
            a1 = O1 - ey
            a2 = O2 - ez
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
            for pos in range(b0, end):
                if pos + PREFETCH_AHEAD < end:
                    prefetch(f2, oi, LN[pos + PREFETCH_AHEAD, 1], 1)
                p = pos - off0
                qq = LQ[p]
                rx = a0 + LC[pos, 0] + qq * ex
                ry = a1 + LC[pos, 1] + qq * ey
                rz = a2 + LC[pos, 2] + qq * ez
                f2[oi, LN[pos, 1]] = LG[p] - LK[p] * (c6eu + rx * cx + ry * cy + rz * cz)
