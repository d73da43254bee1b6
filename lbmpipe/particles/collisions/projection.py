"""Overlap control: the projection that removes the overlaps the impulses leave, Gauss-Seidel
over the contacts of the step.

After the impulses, overlaps are removed by projecting positions along the
normal, split by inverse mass (``x_1 -= d p m_2/(m_1+m_2)``, ``x_2 += d p m_1/(m_1+m_2)``, which
keeps the centre of mass; against a wall the particle moves by ``d``), Gauss-Seidel over all
contacts, repeated until every overlap is at most ``overlap_tol``. If that has not happened after
``translation_iters`` sweeps (20), the configuration is jammed in a way translations cannot open,
or open only by pushing bodies back and forth for hundreds of sweeps (a cylinder wedged across the
pipe by its neighbours: pushing it off one wall pushes it into the other), and a second
projection, of at most ``max_projection_iters`` sweeps, turns the bodies as well: each correction is split over
translation and rotation by the generalized inverse masses of the contact's deepest point, the
position-level form of Eqs. (16)-(19) (``_project``); the centre of mass stays. Steps that do not
jam never reach it and are unchanged by it; ``stats["rotation_projections"]`` counts the calls
that did. Each correction of either projection also stops the contact's approach velocity at the
point it corrected (the impulse of Eq. (19) with ``k = 0``, ``_stop_approach``), as a velocity-level
constraint would: a position correction alone leaves the velocity that drives the overlap (a
spinning body jammed in its box, turned back every step, kept its spin for ever).

Units: lattice units (lengths in lattice spacings). Invariants: the centre of mass of every
pair stays (corrections split by inverse mass; a fixed body never moves), and no correction adds
kinetic energy (``_stop_approach`` is an impulse with ``k = 0``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact import body_contact_ws, new_scratch
from ..rigid import qmul, quat_to_matrix
from .bundles import _S_DISP, _S_OVA, _S_PROJ, _S_ROT
from .impulse import _NG, _impulse_terms
from .narrow_phase import _wall_gap


@njit(cache=True)
def _turn(i, lam, g, col, q, Rm):
    """Rotate body i by the body-frame rotation vector ``lam * g[col:col+3]`` (q <- q (x) dq,
    q rotating body -> lab) and refresh its matrix. Returns the angle."""
    fx = lam * g[0, col]
    fy = lam * g[0, col + 1]
    fz = lam * g[0, col + 2]
    ang = math.sqrt(fx * fx + fy * fy + fz * fz)
    if ang == 0.0:
        return 0.0
    s = math.sin(0.5 * ang) / ang
    r = qmul(q[i, 0], q[i, 1], q[i, 2], q[i, 3], math.cos(0.5 * ang), s * fx, s * fy, s * fz)
    nq = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3])
    for k in range(4):
        q[i, k] = r[k] / nq
    Rm[i] = quat_to_matrix(q[i])
    return ang


@njit(cache=True)
def _measure_pair(i, j, m, ps, kind, h, x, Rm, margin, manifold_tol, cg, cn, cc, ws, nrm, c, x2):
    """Gap, normal and point of pair row m (bodies i, j; j at x_j + ps[m]) as they are now, into
    cg, cn, cc (x2: scratch)."""
    for k in range(3):
        x2[k] = x[j, k] + ps[m, k]
    cg[m] = body_contact_ws(kind[i], h[i], x[i], Rm[i], kind[j], h[j], x2, Rm[j], margin, manifold_tol, nrm, c, ws)
    for k in range(3):
        cn[m, k] = nrm[k]
        cc[m, k] = c[k]


@njit(cache=True)
def _measure_wall(i, m, kind, h, x, Rm, dcode, Rp, cx, cy, lo, hi, manifold_tol, wg, wn, wc, nrm, c):
    """Gap, normal and point of wall row m (body i; the wall named by its stored normal) as they
    are now, into wg, wn, wc."""
    wg[m] = _wall_gap(kind[i], h[i], x[i], Rm[i], dcode, Rp, cx, cy, lo, hi, wn[m], manifold_tol, nrm, c)
    for k in range(3):
        wn[m, k] = nrm[k]
        wc[m, k] = c[k]


@njit(cache=True)
def _stop_approach(i, j, g, p, m, v, wb, Rm, imi, imj):
    """Velocity half of a projection step on contact row m (normal p[m], terms g[0] of
    ``_impulse_terms`` at the point the projection used): if the contact still approaches there,
    the impulse of Eq. (19) with k = 0 (Eq. (21) for a wall, j < 0) stops the approach, as a
    velocity-level constraint would. A position correction alone would leave the velocity that
    drives the overlap (a spinning body jammed in its box, turned back every step, would keep its
    spin for ever; a body lifted out of the body below it would keep falling into it). It never
    adds kinetic energy and keeps momentum and angular momentum as any impulse of Eqs. (16)-(18)."""
    vn = 0.0
    for b in range(2 if j >= 0 else 1):
        k = i if b == 0 else j
        o = 3 * b
        w0 = Rm[k, 0, 0] * wb[k, 0] + Rm[k, 0, 1] * wb[k, 1] + Rm[k, 0, 2] * wb[k, 2]
        w1 = Rm[k, 1, 0] * wb[k, 0] + Rm[k, 1, 1] * wb[k, 1] + Rm[k, 1, 2] * wb[k, 2]
        w2 = Rm[k, 2, 0] * wb[k, 0] + Rm[k, 2, 1] * wb[k, 1] + Rm[k, 2, 2] * wb[k, 2]
        u0 = v[k, 0] + w1 * g[0, o + 2] - w2 * g[0, o + 1]
        u1 = v[k, 1] + w2 * g[0, o] - w0 * g[0, o + 2]
        u2 = v[k, 2] + w0 * g[0, o + 1] - w1 * g[0, o]
        un = u0 * p[m, 0] + u1 * p[m, 1] + u2 * p[m, 2]
        vn += un if b == 0 else -un
    if not (vn > 0.0 and g[0, 12] > 0.0):
        return
    imp = vn / g[0, 12]
    for k in range(3):
        v[i, k] -= imp * imi * p[m, k]
        wb[i, k] -= imp * g[0, 6 + k]
    if j >= 0:
        for k in range(3):
            v[j, k] += imp * imj * p[m, k]
            wb[j, k] += imp * g[0, 9 + k]


@njit(cache=True)
def _project(rot, max_proj, overlap_tol, kind, h, x, q, Rm, im, iinv, rb, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc,
             d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi, margin, manifold_tol, ws, nrm, c, x2, v, wb):
    """Gauss-Seidel removal of the overlaps deeper than ``overlap_tol``; returns the iterations.

    ``rot = False``: each contact moves its bodies apart along the normal by the depth, split by
    inverse mass (the centre of mass stays). ``rot = True``: the same correction spread over
    translation and rotation by the generalized inverse masses of the contact point, the
    position-level form of Eqs. (16)-(19): with ``lam = depth / (1/m_1 + 1/m_2 + t_1 + t_2)``
    body 1 moves by ``-lam n / m_1`` and turns by ``-lam J_1^-1 (l_1 x n)`` (body 2: ``+``), which
    closes the gap to first order and keeps the centre of mass; walls are infinitely heavy.
    ``disp`` bounds how far each body's surface has moved (shift plus angle times bounding
    radius): a stored gap is re-measured only when that bound says it may have closed. Each
    correction also stops the contact's approach velocity (``_stop_approach``, on ``v`` and ``wb``)."""
    npair = pi.shape[0]
    nwall = wi.shape[0]
    if rot:
        # the deepest point, not the centroid of the deepest patch: a body wedged between two
        # walls has a patch at each end, and their centroid (at its middle) has no lever arm
        manifold_tol = 0.0
    g = np.empty((1, _NG))
    it_used = 0
    for it in range(max_proj):
        moved = False
        for m in range(npair):
            i = pi[m]
            j = pj[m]
            bound = cg[m] - (disp[i] - d1[m]) - (disp[j] - d2[m])
            if bound >= -overlap_tol:
                continue
            if disp[i] != d1[m] or disp[j] != d2[m]:
                _measure_pair(i, j, m, ps, kind, h, x, Rm, margin, manifold_tol, cg, cn, cc, ws, nrm, c, x2)
                d1[m] = disp[i]
                d2[m] = disp[j]
            if cg[m] >= -overlap_tol:
                continue
            wsum = im[i] + im[j]
            if wsum <= 0.0:
                continue  # two fixed bodies: nothing can move
            dep = -cg[m]
            _impulse_terms(i, j, ps[m, 0], ps[m, 1], ps[m, 2], cc, cc, cn, m, x, Rm, im, iinv, g, 0)
            _stop_approach(i, j, g, cn, m, v, wb, Rm, im[i], im[j])
            if rot:
                lam = dep / g[0, 12]
                f1 = lam * im[i]
                f2 = lam * im[j]
                disp[i] += f1 + _turn(i, -lam, g, 6, q, Rm) * rb[i]
                disp[j] += f2 + _turn(j, lam, g, 9, q, Rm) * rb[j]
            else:
                f1 = dep * im[i] / wsum
                f2 = dep * im[j] / wsum
                disp[i] += f1
                disp[j] += f2
            for k in range(3):
                x[i, k] -= f1 * cn[m, k]
                x[j, k] += f2 * cn[m, k]
            if rot:
                # closed to first order only: measure again
                _measure_pair(i, j, m, ps, kind, h, x, Rm, margin, manifold_tol, cg, cn, cc, ws, nrm, c, x2)
            else:
                # the EPA normal is the minimum translation: after it the pair just touches
                cg[m] = 0.0
            d1[m] = disp[i]
            d2[m] = disp[j]
            moved = True
        for m in range(nwall):
            i = wi[m]
            bound = wg[m] - (disp[i] - dw[m])
            if bound >= -overlap_tol:
                continue
            if disp[i] != dw[m]:
                _measure_wall(i, m, kind, h, x, Rm, dcode, Rp, cx, cy, lo, hi, manifold_tol, wg, wn, wc, nrm, c)
                dw[m] = disp[i]
            if wg[m] >= -overlap_tol or im[i] <= 0.0:
                continue
            dep = -wg[m]
            _impulse_terms(i, -1, 0.0, 0.0, 0.0, wc, wc, wn, m, x, Rm, im, iinv, g, 0)
            _stop_approach(i, -1, g, wn, m, v, wb, Rm, im[i], 0.0)
            if rot:
                lam = dep / g[0, 12]
                f1 = lam * im[i]
                disp[i] += f1 + _turn(i, -lam, g, 6, q, Rm) * rb[i]
            else:
                f1 = dep
                disp[i] += dep
            for k in range(3):
                x[i, k] -= f1 * wn[m, k]
            # the farthest point need not lie on the normal through the contact point: re-measure
            _measure_wall(i, m, kind, h, x, Rm, dcode, Rp, cx, cy, lo, hi, manifold_tol, wg, wn, wc, nrm, c)
            dw[m] = disp[i]
            moved = True
        it_used = it + 1
        if not moved:
            break
    return it_used


@njit(cache=True)
def _final_overlap(kind, h, x, Rm, pi, pj, ps, cg, wi, wg, wn, d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi, margin,
                   manifold_tol, ws, nrm, c, x2):
    """Largest overlap left: every stored gap whose displacement bound says it may overlap is
    re-measured, unless neither body has moved since it was measured. A negative stored gap is
    always a measurement (bounds are only stored above the contact gap; a pair the projection
    closes is stored as 0), and measuring the same bodies again gives the same bits: the ~30
    wall contacts of 244 dense cylinders left overlapping within ``overlap_tol`` were measured
    twice every step for nothing."""
    ova = 0.0
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        bound = cg[m] - (disp[i] - d1[m]) - (disp[j] - d2[m])
        if bound < 0.0 and (disp[i] != d1[m] or disp[j] != d2[m]):
            for k in range(3):
                x2[k] = x[j, k] + ps[m, k]
            bound = body_contact_ws(kind[i], h[i], x[i], Rm[i], kind[j], h[j], x2, Rm[j], margin, manifold_tol, nrm, c,
                                    ws)
        ova = max(ova, -bound)
    for m in range(wi.shape[0]):
        i = wi[m]
        bound = wg[m] - (disp[i] - dw[m])
        if bound < 0.0 and disp[i] != dw[m]:
            bound = _wall_gap(kind[i], h[i], x[i], Rm[i], dcode, Rp, cx, cy, lo, hi, wn[m], manifold_tol, nrm, c)
        ova = max(ova, -bound)
    return ova



@njit(cache=True)
def project_overlaps(B, T, C, D, P, margin, stats):
    """Stage 4 of the step: remove the overlaps deeper than ``overlap_tol`` by translations
    (``_project``, at most ``min(max_trans, max_proj)`` sweeps), and, if some are left, by the
    rotating projection (at most ``max_proj`` more sweeps; a jam).

    Inputs: bodies B (``BodyArrays``: x, q, v, wb changed in place), their terms T (``BodyTerms``:
    ``Rm`` kept in step with q), the contacts C (``Contacts``: gaps, normals and points
    re-measured in place where a body moved), domain D, parameters P (``StepParams``), ``margin``
    (gaps are measured exactly up to it). Output: the largest displacement bound of a body (shift
    plus angle times bounding radius, lattice spacings), which tells the caller whether a pass
    with a fresh pair list is needed. Stats: ``max_overlap_after`` (the largest overlap left,
    ``<= overlap_tol`` unless both projections ran out), projection iterations, rotating
    projections, largest displacement. Postcondition: every listed overlap ``<= overlap_tol`` or
    the iterations exhausted. Steps that do not jam never reach the rotating projection and are
    exactly what the translations compute."""
    kind, h, x, v, q, wb = B.kind, B.h, B.x, B.v, B.q, B.wb
    Rm, rb, im, iinv = T.Rm, T.rb, T.im, T.iinv
    pi, pj, ps, cg, cn, cc, wi, wg, wn, wc = C.pi, C.pj, C.ps, C.cg, C.cn, C.cc, C.wi, C.wg, C.wn, C.wc
    dcode, Rp, cx, cy, lo, hi = D.dcode, D.Rp, D.cx, D.cy, D.lo, D.hi
    overlap_tol, manifold_tol, max_proj, max_trans = P.overlap_tol, P.manifold_tol, P.max_proj, P.max_trans
    n = x.shape[0]
    npair = pi.shape[0]
    nwall = wi.shape[0]
    # positions, split by inverse mass; orientations too in a jam
    ws = new_scratch()
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    disp = np.zeros(n)
    d1 = np.zeros(npair)
    d2 = np.zeros(npair)
    dw = np.zeros(nwall)
    it_used = _project(False, min(max_trans, max_proj), overlap_tol, kind, h, x, q, Rm, im, iinv, rb, pi, pj, ps, cg,
                       cn, cc, wi, wg, wn, wc, d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi, margin, manifold_tol, ws,
                       nrm, c, x2, v, wb)
    ova = _final_overlap(kind, h, x, Rm, pi, pj, ps, cg, wi, wg, wn, d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi,
                         margin, manifold_tol, ws, nrm, c, x2)
    if ova > overlap_tol:
        # Translations alone cannot open a jam such as a body wedged across the pipe by a
        # neighbour: only turning it can. Leaving this to a fallback keeps every step that does
        # not jam exactly as the translation-only projection computes it; a step that still
        # overlaps after ``max_trans`` sweeps counts as jammed (CollisionParams.translation_iters).
        it_used += _project(True, max_proj, overlap_tol, kind, h, x, q, Rm, im, iinv, rb, pi, pj, ps, cg, cn, cc, wi,
                            wg, wn, wc, d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi, margin, manifold_tol, ws, nrm, c,
                            x2, v, wb)
        ova = _final_overlap(kind, h, x, Rm, pi, pj, ps, cg, wi, wg, wn, d1, d2, dw, disp, dcode, Rp, cx, cy, lo, hi,
                             margin, manifold_tol, ws, nrm, c, x2)
        stats[_S_ROT] += 1
    maxdisp = 0.0
    for i in range(n):
        maxdisp = max(maxdisp, disp[i])
    stats[_S_OVA] = ova
    stats[_S_PROJ] += it_used
    stats[_S_DISP] = max(stats[_S_DISP], maxdisp)
    return maxdisp
