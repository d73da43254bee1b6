"""Where the accurate coupling's time goes, per link (issue 45, the accurate method's coupling).

Builds the accurate method's runs of ``benchmarks/step.py`` (committed credible scenes, seed 1,
``METHODS["accurate"]``), steps each ``--warmup`` steps, and captures the exact inputs of one call
of ``interpolated.couple_free_surface`` (CLI + Galilean, the free particles). It then times, on
those inputs restored before every call (the populations written afresh, as after the sweep):

  * ``package``: the package's kernel; ``unfused``: the kernel before issue 45's lever (its
    gathers in two loops, ``f*_i(x - e_i)`` and the owner not prefetched, the arithmetic in a loop
    of its own after them; ``couple_variant`` below, stage 7 without levers);
  * ``stage N``: a copy of it cut after its N-th part (cumulative): 1 the gather of ``f*_i(x)``
    with the compaction, 2 + the gathers of ``f*_opp(i)(x)``, ``f*_i(x - e_i)`` and
    ``owner[x - e_i]``, 3 + ``entry_fraction``, 4 + ``link_base`` (pass 1a whole), 5 + pass 1b
    (the moments and the Galilean term), 6 + the implicit update, 7 + pass 2 (the ghost write:
    the whole kernel);
  * ``lever L``: the whole kernel with a lever (``LEVERS``), checked bit for bit against
    ``package`` (populations, link lists, velocities, loads).

Medians over ``--rounds`` rounds of the median of ``--reps`` calls each, the contenders in an
order rotated every round (and the least single call, ``min``); ns per live link. Timing variants live here, not in the package.

    python benchmarks/coupling_split.py [--cases ...] [--warmup 100] [--rounds 5] [--reps 10]
        [--levers PF ONE ONE+X2 ...] [--stages] [--stage-lever ONE]
"""

from __future__ import annotations

import argparse
import math
import statistics
from typing import NamedTuple
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit, prange

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from step import DEFAULT_CASES, build, scenes  # noqa: E402

from lbmpipe.particles.coupling import surface_effects  # noqa: E402
from lbmpipe.particles.coupling.implicit import solve6  # noqa: E402
from lbmpipe.particles.coupling.interpolated import couple_free_surface  # noqa: E402
from lbmpipe.particles.coupling.nodes import FLUID  # noqa: E402
from lbmpipe.particles.coupling.prefetch import PREFETCH_AHEAD, prefetch, prefetch1  # noqa: E402
from lbmpipe.particles.coupling.runs import _EPS_DIR, _disc, _slab  # noqa: E402
from lbmpipe.particles.coupling.surface import HALF_WAY, entry_fraction, link_base  # noqa: E402
from lbmpipe.particles.rigid import quat_to_matrix  # noqa: E402
from lbmpipe.particles.shapes import CYLINDER, SPHERE  # noqa: E402

#: levers (bit flags of ``lever``): PF prefetch f*_i(x - e_i) and owner[x - e_i] ahead; ONE one
#: loop for the three gathers (all prefetched); EF entry_fraction with the per-direction
#: reciprocals and the disc's quadratic coefficient hoisted; NOB pass 1b without the branch on
#: ``galilean`` inside the link loop (two copies of the loop); X2 (with ONE) the nodes x - e_i
#: computed once per link in a loop of their own before the gathers; A8, A32 (with ONE) prefetch
#: 8 or 32 links ahead instead of 16; NOO (with ONE) no prefetch of owner[x - e_i]; FQ the
#: gathers, entry_fraction and link_base in one loop before the compaction (prefetched as ONE); CH
#: (with FQ) the change marks read in that loop, the compaction loop run only for a list with a mark
PF, ONE, EF, NOB, X2, A8, A32, NOO, FQ, CH = 1, 2, 4, 8, 16, 32, 64, 128, 256, 512
LEVERS = {"PF": PF, "ONE": ONE, "EF": EF, "NOB": NOB, "X2": X2, "A8": A8, "A32": A32, "NOO": NOO, "FQ": FQ,
          "CH": CH}


class SplitScratch(NamedTuple):
    """``interpolated.SurfaceScratch`` with the two buffers the unfused gathers need: ``fb``
    ``f*_i(x - e_i)`` and ``fo`` ``f*_opp(i)(x)``."""

    f: np.ndarray
    g: np.ndarray
    q: np.ndarray
    c: np.ndarray
    fb: np.ndarray
    fo: np.ndarray
    m: np.ndarray


@njit(cache=True)
def _slab_h(p, small, inv, hh, t0, t1):
    # runs._slab with the direction's reciprocal (and its smallness) computed once per direction
    if small:
        if abs(p) > hh:
            return 1.0, 0.0
        return t0, t1
    a = (-hh - p) * inv
    b = (hh - p) * inv
    if a > b:
        a, b = b, a
    return max(t0, a), min(t1, b)


@njit(cache=True)
def _disc_h(px, py, dx, dy, a, r, t0, t1):
    # runs._disc with a = dx^2 + dy^2 computed once per direction
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
def entry_fraction_h(kind, h0, h1, h2, px, py, pz, dx, dy, dz, n, s0, s1, s2, i0, i1, i2, ad):
    """``surface.entry_fraction`` with per-direction constants: ``s`` |d| < eps, ``i`` 1/d, ``ad``
    dx^2 + dy^2 (the same operations on the same operands: the same bits)."""
    big = 1e300
    if kind == SPHERE:
        b = px * dx + py * dy + pz * dz
        disc = b * b - (px * px + py * py + pz * pz - h0 * h0)
        if disc < 0.0:
            return 1.0
        t0 = -b - math.sqrt(disc)
    elif kind == CYLINDER:
        t0, t1 = _slab_h(pz, s2, i2, h2, -big, big)
        if t0 > t1:
            return 1.0
        t0, t1 = _disc_h(px, py, dx, dy, ad, h0, t0, t1)
        if t0 > t1:
            return 1.0
    else:
        t0, t1 = _slab_h(px, s0, i0, h0, -big, big)
        t0, t1 = _slab_h(py, s1, i1, h1, t0, t1)
        t0, t1 = _slab_h(pz, s2, i2, h2, t0, t1)
        if t0 > t1:
            return 1.0
    if t0 >= n:
        return 1.0
    if t0 <= 0.0:
        return 0.0
    return t0 / n


@njit(parallel=True, cache=True)
def couple_variant(f2, owner, ids, B, D, lat, G, L, shape, S, rule, galilean, stage, lever, SX):
    """``interpolated.couple_free_surface`` cut after part ``stage`` (module docstring) and with the
    levers ``lever`` (bit flags)."""
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
    SB = S.fb
    SO = S.fo
    SM = S.m
    Q = e.shape[0]
    nx = dims[0]
    ny = dims[1]
    nz = dims[2]
    ahead = 8 if lever & A8 else (32 if lever & A32 else PREFETCH_AHEAD)
    for m in prange(ids.shape[0]):
        k = ids[m]
        tid = numba.get_thread_id()
        LF = SF[tid]
        LG = SG[tid]
        LQ = SQ[tid]
        LK = SCc[tid]
        LB = SB[tid]
        LO = SO[tid]
        M = SM[tid]
        LXn = SX[tid]
        A = quat_to_matrix(q[k])
        h0 = hh[k, 0]
        h1 = hh[k, 1]
        h2 = hh[k, 2]
        kk = kind[k]
        O0 = origin[0] - x[k, 0]
        O1 = origin[1] - x[k, 1]
        O2 = origin[2] - x[k, 2]
        U0 = v[k, 0]
        U1 = v[k, 1]
        U2 = v[k, 2]
        W0 = om[k, 0]
        W1 = om[k, 1]
        W2 = om[k, 2]
        off0 = lbase[k, 1]
        exc = 0.0
        wsum = 0.0
        for i in range(1, Q):
            ie0 = e[i, 0]
            ie1 = e[i, 1]
            ie2 = e[i, 2]
            oi = opp[i]
            b0 = lbase[k, i]
            end = b0 + lcnt[k, i]
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
            s0 = abs(d0) < _EPS_DIR
            s1 = abs(d1) < _EPS_DIR
            s2 = abs(d2) < _EPS_DIR
            i0 = 1.0 / d0 if not s0 else 0.0
            i1 = 1.0 / d1 if not s1 else 0.0
            i2 = 1.0 / d2 if not s2 else 0.0
            ad = d0 * d0 + d1 * d1
            if (lever & FQ) and rule != HALF_WAY:
                # the gathers, q and the ghost base in one loop (prefetched ahead); compaction
                # after, carrying q, G, c; the mass excess summed over the live links in order
                anyc = np.uint8(0)
                for pos in range(b0, end):
                    if pos + ahead < end:
                        pa = pos + ahead
                        xa = LN[pa, 0]
                        prefetch(f2, i, xa, 0)
                        prefetch(f2, oi, xa, 0)
                        x2a = ((xmap[LC[pa, 0] - 2 * ie0 + nx] * ny + ymap[LC[pa, 1] - 2 * ie1 + ny]) * az
                               + zmap[LC[pa, 2] - 2 * ie2 + nz])
                        prefetch(f2, i, x2a, 0)
                        prefetch1(owner, x2a)
                    p = pos - off0
                    xn = LN[pos, 0]
                    fv = f2[i, xn]
                    fo = f2[oi, xn]
                    x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                          + zmap[LC[pos, 2] - 2 * ie2 + nz])
                    fb = f2[i, x2]
                    bf = owner[x2] == FLUID
                    if lever & CH:
                        anyc |= chg[LN[pos, 1]] | chg[xn]
                    c0 = float(LC[pos, 0])
                    c1 = float(LC[pos, 1])
                    c2 = float(LC[pos, 2])
                    qq = entry_fraction(kk, h0, h1, h2, P0 + A[0, 0] * c0 + A[1, 0] * c1 + A[2, 0] * c2,
                                        P1 + A[0, 1] * c0 + A[1, 1] * c1 + A[2, 1] * c2,
                                        P2 + A[0, 2] * c0 + A[1, 2] * c1 + A[2, 2] * c2, d0, d1, d2, ni)
                    gv, cc = link_base(rule, qq, fv, fb, fo, bf)
                    LF[p] = fv
                    LG[p] = gv
                    LQ[p] = qq
                    LK[p] = cc
                pos = b0
                if (lever & CH) and anyc == 0:
                    pos = end
                while pos < end:
                    xn = LN[pos, 0]
                    sn = LN[pos, 1]
                    if chg[sn] | chg[xn]:
                        if owner[sn] != k or owner[xn] != FLUID:
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
                for pos in range(b0, end):
                    p = pos - off0
                    exc += LG[p] - LF[p]
                    wsum += w[i]
                continue
            if (lever & ONE) and (lever & X2):
                for pos in range(b0, end):
                    LXn[pos - off0] = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                                       + zmap[LC[pos, 2] - 2 * ie2 + nz])
                for pos in range(b0, end):
                    if pos + ahead < end:
                        pa = pos + ahead
                        xa = LN[pa, 0]
                        prefetch(f2, i, xa, 0)
                        prefetch(f2, oi, xa, 0)
                        x2a = LXn[pa - off0]
                        prefetch(f2, i, x2a, 0)
                        prefetch1(owner, x2a)
                    p = pos - off0
                    xn = LN[pos, 0]
                    LF[p] = f2[i, xn]
                    LO[p] = f2[oi, xn]
                    x2 = LXn[p]
                    LB[p] = f2[i, x2]
                    LK[p] = 1.0 if owner[x2] == FLUID else 0.0
            elif lever & ONE:
                # the three gathers and the owner in one loop, each prefetched ahead
                for pos in range(b0, end):
                    if pos + ahead < end:
                        pa = pos + ahead
                        xa = LN[pa, 0]
                        prefetch(f2, i, xa, 0)
                        prefetch(f2, oi, xa, 0)
                        x2a = ((xmap[LC[pa, 0] - 2 * ie0 + nx] * ny + ymap[LC[pa, 1] - 2 * ie1 + ny]) * az
                               + zmap[LC[pa, 2] - 2 * ie2 + nz])
                        prefetch(f2, i, x2a, 0)
                        if not (lever & NOO):
                            prefetch1(owner, x2a)
                    p = pos - off0
                    xn = LN[pos, 0]
                    LF[p] = f2[i, xn]
                    LO[p] = f2[oi, xn]
                    x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                          + zmap[LC[pos, 2] - 2 * ie2 + nz])
                    LB[p] = f2[i, x2]
                    LK[p] = 1.0 if owner[x2] == FLUID else 0.0
            else:
                for pos in range(b0, end):
                    if pos + PREFETCH_AHEAD < end:
                        prefetch(f2, i, LN[pos + PREFETCH_AHEAD, 0], 0)
                    LF[pos - off0] = f2[i, LN[pos, 0]]
                if stage >= 2 and rule != HALF_WAY:
                    if lever & PF:
                        for pos in range(b0, end):
                            if pos + PREFETCH_AHEAD < end:
                                pa = pos + PREFETCH_AHEAD
                                prefetch(f2, oi, LN[pa, 0], 0)
                                x2a = ((xmap[LC[pa, 0] - 2 * ie0 + nx] * ny + ymap[LC[pa, 1] - 2 * ie1 + ny]) * az
                                       + zmap[LC[pa, 2] - 2 * ie2 + nz])
                                prefetch(f2, i, x2a, 0)
                                prefetch1(owner, x2a)
                            p = pos - off0
                            LO[p] = f2[oi, LN[pos, 0]]
                            x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                                  + zmap[LC[pos, 2] - 2 * ie2 + nz])
                            LB[p] = f2[i, x2]
                            LK[p] = 1.0 if owner[x2] == FLUID else 0.0
                    else:
                        for pos in range(b0, end):
                            if pos + PREFETCH_AHEAD < end:
                                prefetch(f2, oi, LN[pos + PREFETCH_AHEAD, 0], 0)
                            p = pos - off0
                            LO[p] = f2[oi, LN[pos, 0]]
                            x2 = ((xmap[LC[pos, 0] - 2 * ie0 + nx] * ny + ymap[LC[pos, 1] - 2 * ie1 + ny]) * az
                                  + zmap[LC[pos, 2] - 2 * ie2 + nz])
                            LB[p] = f2[i, x2]
                            LK[p] = 1.0 if owner[x2] == FLUID else 0.0
            pos = b0
            while pos < end:
                xn = LN[pos, 0]
                sn = LN[pos, 1]
                if chg[sn] | chg[xn]:
                    if owner[sn] != k or owner[xn] != FLUID:
                        end -= 1
                        LN[pos, 0] = LN[end, 0]
                        LN[pos, 1] = LN[end, 1]
                        for d in range(3):
                            LC[pos, d] = LC[end, d]
                        LF[pos - off0] = LF[end - off0]
                        LO[pos - off0] = LO[end - off0]
                        LB[pos - off0] = LB[end - off0]
                        LK[pos - off0] = LK[end - off0]
                        continue
                pos += 1
            lcnt[k, i] = end - b0
            if rule == HALF_WAY or stage < 3:
                for pos in range(b0, end):
                    p = pos - off0
                    LG[p] = LF[p]
                    LQ[p] = 0.5
                    LK[p] = 1.0
                continue
            for pos in range(b0, end):
                p = pos - off0
                c0 = float(LC[pos, 0])
                c1 = float(LC[pos, 1])
                c2 = float(LC[pos, 2])
                if lever & EF:
                    qq = entry_fraction_h(kk, h0, h1, h2, P0 + A[0, 0] * c0 + A[1, 0] * c1 + A[2, 0] * c2,
                                          P1 + A[0, 1] * c0 + A[1, 1] * c1 + A[2, 1] * c2,
                                          P2 + A[0, 2] * c0 + A[1, 2] * c1 + A[2, 2] * c2, d0, d1, d2, ni,
                                          s0, s1, s2, i0, i1, i2, ad)
                else:
                    qq = entry_fraction(kk, h0, h1, h2, P0 + A[0, 0] * c0 + A[1, 0] * c1 + A[2, 0] * c2,
                                        P1 + A[0, 1] * c0 + A[1, 1] * c1 + A[2, 1] * c2,
                                        P2 + A[0, 2] * c0 + A[1, 2] * c1 + A[2, 2] * c2, d0, d1, d2, ni)
                fv = LF[p]
                if stage >= 4:
                    gv, cc = link_base(rule, qq, fv, LB[p], LO[p], LK[p] > 0.5)
                else:
                    gv = fv
                    cc = 1.0
                exc += gv - fv
                wsum += w[i]
                LG[p] = gv
                LQ[p] = qq
                LK[p] = cc
        if stage < 5:
            continue
        delta = exc / wsum if wsum > 0.0 else 0.0
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
            if (lever & NOB) and galilean:
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
            else:
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
            e0 += 2.0 * ex * wr * cnt
            e1 += 2.0 * ey * wr * cnt
            e2 += 2.0 * ez * wr * cnt
            g0 += ex * sv
            g1 += ey * sv
            g2 += ez * sv
            g3 += svy * ez - svz * ey
            g4 += svz * ex - svx * ez
            g5 += svx * ey - svy * ex
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
        if stage < 6:
            continue
        for p_ in range(6):
            for r_ in range(p_):
                M[p_, r_] = M[r_, p_]
        Zc = np.empty((6, 6))
        for p_ in range(6):
            for r_ in range(6):
                Zc[p_, r_] = M[p_, r_]
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
        for p_ in range(3):
            wb[k, p_] = A[0, p_] * M[3, 6] + A[1, p_] * M[4, 6] + A[2, p_] * M[5, 6]
        for p_ in range(3):
            fz_ = 0.0
            tz_ = 0.0
            for r_ in range(6):
                fz_ += Zc[p_, r_] * M[r_, 6]
                tz_ += Zc[3 + p_, r_] * M[r_, 6]
            force[k, p_] = gs[p_] - fz_ + imp[k, p_]
            torque[k, p_] = gs[3 + p_] - tz_ + imp[k, 3 + p_]
        exch[k, 0] = force[k, 0] - imp[k, 0] - h0 + e0
        exch[k, 1] = force[k, 1] - imp[k, 1] - h1 + e1
        exch[k, 2] = force[k, 2] - imp[k, 2] - h2 + e2
        for p_ in range(6):
            imp[k, p_] = 0.0
        if stage < 7:
            continue
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


# --------------------------------------------------------------------------------------------
# capture and replay


class Capture:
    """The arguments of one call of ``couple_free_surface`` (copies), and work arrays to replay it."""

    def __init__(self, args):
        f2, owner, ids, B, D, lat, G, L, shape, S, rule, galilean = args
        self.fixed = (owner, ids.copy(), lat, G, shape, rule, galilean)
        self.snap = {"f2": f2.copy(), "B": [a.copy() for a in B], "D": [a.copy() for a in D],
                     "L": [a.copy() if isinstance(a, np.ndarray) else a for a in L]}
        self.f2 = f2.copy()
        self.B = type(B)(*[a.copy() for a in B])
        self.D = type(D)(*[a.copy() for a in D])
        self.L = type(L)(*[a.copy() if isinstance(a, np.ndarray) else a for a in L])
        self.S = type(S)(*[a.copy() for a in S])
        self.SV = SplitScratch(S.f.copy(), S.g.copy(), S.q.copy(), S.c.copy(), np.zeros(S.f.shape),
                               np.zeros(S.f.shape), S.m.copy())
        self.SX = np.zeros(S.f.shape, np.int64)

    def restore(self):
        np.copyto(self.f2, self.snap["f2"])
        for dst, src in zip(self.B, self.snap["B"]):
            np.copyto(dst, src)
        for dst, src in zip(self.D, self.snap["D"]):
            np.copyto(dst, src)
        for dst, src in zip(self.L, self.snap["L"]):
            if isinstance(dst, np.ndarray):
                np.copyto(dst, src)

    def call(self, stage=None, lever=0):
        owner, ids, lat, G, shape, rule, galilean = self.fixed
        self.restore()
        t0 = time.perf_counter()
        if stage is None:
            couple_free_surface(self.f2, owner, ids, self.B, self.D, lat, G, self.L, shape, self.S, rule, galilean)
        else:
            couple_variant(self.f2, owner, ids, self.B, self.D, lat, G, self.L, shape, self.SV, rule, galilean,
                           stage, lever, self.SX)
        return time.perf_counter() - t0

    def outputs(self):
        return [self.f2, *self.B, *self.D, self.L.lcnt, self.L.LN, self.L.LC]

    def links(self) -> int:
        ids = self.fixed[1]
        return int(self.L.lcnt[ids].sum())


def capture(case: str, warmup: int) -> Capture:
    coupled, _ = scenes("credible", case, 1, "accurate")
    sim, _ = build(coupled)
    sim.step(warmup)
    got = []
    real = surface_effects.couple_free_surface

    def recorder(*args):
        if not got:
            got.append(Capture(args))
        return real(*args)

    surface_effects.couple_free_surface = recorder
    try:
        sim.step(1)
    finally:
        surface_effects.couple_free_surface = real
    return got[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--stages", action="store_true", help="time the cumulative stages 1-7 too")
    ap.add_argument("--stage-lever", default="", help="the lever set the stages run with (default none)")
    ap.add_argument("--levers", nargs="*", default=[], help="lever sets, e.g. PF ONE PF+EF")
    args = ap.parse_args(argv)
    numba.set_num_threads(1)
    for case in args.cases:
        cap = capture(case, args.warmup)
        cont = [("package", None, 0), ("unfused", 7, 0)]
        if args.stages:
            sbits = 0
            for part in (args.stage_lever.split("+") if args.stage_lever else []):
                sbits |= LEVERS[part]
            cont += [(f"stage {s}", s, sbits) for s in range(1, 8)]
        for name in args.levers:
            bits = 0
            for part in name.split("+"):
                bits |= LEVERS[part]
            cont.append((f"lever {name}", 7, bits))
        # reference outputs, and the bits of every whole-kernel variant against them
        cap.call()
        ref = [a.copy() for a in cap.outputs()]
        links = cap.links()
        same = {}
        for name, stage, bits in cont:
            cap.call(stage, bits)
            if stage in (None, 7):
                same[name] = all(np.array_equal(a, b) for a, b in zip(cap.outputs(), ref))
        times = {name: [] for name, _, _ in cont}
        best = {}
        for r in range(args.rounds):
            order = cont[r % len(cont):] + cont[:r % len(cont)]
            if r % 2:
                order = order[::-1]
            for name, stage, bits in order:
                reps = [cap.call(stage, bits) for _ in range(args.reps)]
                times[name].append(statistics.median(reps))
                best[name] = min(best.get(name, 1e9), min(reps))
        print(f"\n{case}: {links} live links, {len(cap.fixed[1])} free particles (accurate method, 1 thread)")
        base = statistics.median(times["package"])
        prev = 0.0
        print(f"{'contender':16s} {'ms/call':>8s} {'ns/link':>8s} {'part ns/link':>12s} {'/ package':>9s} "
              f"{'min ns/link':>11s} same bits")
        for name, stage, bits in cont:
            t = statistics.median(times[name])
            part = ""
            if name.startswith("stage"):
                part = f"{1e9 * (t - prev) / links:12.1f}"
                prev = t
            print(f"{name:16s} {1e3 * t:8.3f} {1e9 * t / links:8.1f} {part:>12s} {t / base:9.3f} "
                  f"{1e9 * best[name] / links:11.1f} {same.get(name, '')}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
