"""Speculative contacts: the time of impact of two bodies (or a body and a wall) moving freely
within a step, and the test that activates a contact wider than the contact gap.

A contact wider than ``contact_gap`` whose two bodies, moving freely at their present velocities
and angular velocities, would overlap by the end of the step ``dt`` is speculative
(``CollisionParams.speculative``, default). The time of impact in the step is found by bisection,
halved until the bodies close by at most ``_TOI_TOL`` (1e-3 lattice spacings) over the bracket
left (at most 12 halvings); the impulse of Eqs. (16)-(21) uses the contact normal at that time
and each body's lever arm there (``_toi_lever``): the impulse acts as it would at the time of
impact, so a frictionless sphere never spins and the post-impact velocities are those of
Eq. (17) then. Momentum is conserved exactly; the angular momentum about a fixed point changes
by ``t (v_1 - v_2) x I p`` (t the time of impact): the bodies have it at time t, where the
impact happens. The bounce thus happens up to one step early instead of the bodies
overlapping; this also catches a corner turning into contact, which a test on the present gap
and normal velocity misses.

Free motion over a time t (``_advance_one``): ``x + v t`` and the rotation by ``omega t``
(Rodrigues' formula), omega constant in the lab frame. Lattice units: lengths in lattice
spacings, times in time steps.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..contact import WS_SIZE, bodies_overlap_ws, body_contact_ws, new_scratch, support3, ws_rows
from ..shapes import bounding_radius
from ..collision_params import PIPE
from .narrow_phase import _CHUNK, _wall_gap

# a gap this far above the swept distance is certainly still open at the end of the step (far
# above the gap's accuracy, ~1e-9 of the body size)
_SWEEP_SLACK = 1e-6


@njit(cache=True)
def _advance_one(i, t, x, v, wb, Rm, xo, Ro):
    """Body i after a free motion over time t: xo = x + v t, Ro = rotation by omega t applied to
    A (omega = A wb, Rodrigues' formula)."""
    for k in range(3):
        xo[k] = x[i, k] + v[i, k] * t
    w0 = Rm[i, 0, 0] * wb[i, 0] + Rm[i, 0, 1] * wb[i, 1] + Rm[i, 0, 2] * wb[i, 2]
    w1 = Rm[i, 1, 0] * wb[i, 0] + Rm[i, 1, 1] * wb[i, 1] + Rm[i, 1, 2] * wb[i, 2]
    w2 = Rm[i, 2, 0] * wb[i, 0] + Rm[i, 2, 1] * wb[i, 1] + Rm[i, 2, 2] * wb[i, 2]
    wn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    ang = wn * t
    if ang == 0.0:
        for a in range(3):
            for b in range(3):
                Ro[a, b] = Rm[i, a, b]
        return
    kx = w0 / wn
    ky = w1 / wn
    kz = w2 / wn
    sn = math.sin(ang)
    cc = 1.0 - math.cos(ang)
    r00 = 1.0 - cc * (ky * ky + kz * kz)
    r01 = -sn * kz + cc * kx * ky
    r02 = sn * ky + cc * kx * kz
    r10 = sn * kz + cc * kx * ky
    r11 = 1.0 - cc * (kx * kx + kz * kz)
    r12 = -sn * kx + cc * ky * kz
    r20 = -sn * ky + cc * kx * kz
    r21 = sn * kx + cc * ky * kz
    r22 = 1.0 - cc * (kx * kx + ky * ky)
    for b in range(3):
        a0 = Rm[i, 0, b]
        a1 = Rm[i, 1, b]
        a2 = Rm[i, 2, b]
        Ro[0, b] = r00 * a0 + r01 * a1 + r02 * a2
        Ro[1, b] = r10 * a0 + r11 * a1 + r12 * a2
        Ro[2, b] = r20 * a0 + r21 * a1 + r22 * a2



# The time-of-impact bisection stops once the bodies' relative displacement over the bracket
# left is at most this (lattice spacings): the geometry it returns is then that of bodies at most
# _TOI_TOL from touching, a tenth of the default overlap tolerance. A fixed 12 halvings (dt/4096)
# was 55 % of the collision step of 244 dense 8 mm cylinders (relative point speeds ~0.02 per
# step: 5 halvings reach the tolerance).
_TOI_TOL = 1.0e-3
_TOI_MAX_HALVINGS = 12


@njit(cache=True, inline="always")
def _toi_halvings(closing):
    """Halvings of a step over which material points close by at most ``closing`` until they
    close by at most ``_TOI_TOL`` over the bracket left (at most ``_TOI_MAX_HALVINGS``)."""
    n = 0
    while closing > _TOI_TOL and n < _TOI_MAX_HALVINGS:
        closing *= 0.5
        n += 1
    return n


@njit(cache=True)
def _toi_pair(i, j, sh, kind, h, x, v, wb, Rm, dt, sweep, manifold_tol, nrm, c, out_c, out_c2, ws, x1, x2, R1, R2):
    """Speculative contact of pair (i, j): if the bodies, moving freely, overlap at the end of the
    step, find by bisection a time t before they touch, at which they are within ``_TOI_TOL`` of
    touching (``_toi_halvings``), and return True with the contact normal ``nrm`` at t and, in
    ``out_c`` and ``out_c2``, each body's lever arm to the contact point at t placed at its
    present centre (``_toi_lever``).
    ``ws``, ``x1``, ``x2``, ``R1``, ``R2``: scratch. The trial times ask only whether the bodies
    overlap (``bodies_overlap_ws``: for two cylinders a point of one inside the other or a
    separating direction, ``cylinders_overlap_exact``; else GJK; no EPA, no contact point)."""
    _advance_one(i, dt, x, v, wb, Rm, x1, R1)
    _advance_one(j, dt, x, v, wb, Rm, x2, R2)
    for k in range(3):
        x2[k] += sh[k]
    if not bodies_overlap_ws(kind[i], h[i], x1, R1, kind[j], h[j], x2, R2, ws):
        return False
    lo_t = 0.0
    hi_t = dt
    for _it in range(_toi_halvings(_pair_closing(i, j, v, sweep) * dt)):
        mid = 0.5 * (lo_t + hi_t)
        _advance_one(i, mid, x, v, wb, Rm, x1, R1)
        _advance_one(j, mid, x, v, wb, Rm, x2, R2)
        for k in range(3):
            x2[k] += sh[k]
        if bodies_overlap_ws(kind[i], h[i], x1, R1, kind[j], h[j], x2, R2, ws):
            hi_t = mid
        else:
            lo_t = mid
    _advance_one(i, lo_t, x, v, wb, Rm, x1, R1)
    _advance_one(j, lo_t, x, v, wb, Rm, x2, R2)
    for k in range(3):
        x2[k] += sh[k]
    body_contact_ws(kind[i], h[i], x1, R1, kind[j], h[j], x2, R2, np.inf, manifold_tol, nrm, c, ws)
    _toi_lever(c, x1, i, 0.0, 0.0, 0.0, x, out_c)
    _toi_lever(c, x2, j, sh[0], sh[1], sh[2], x, out_c2)
    return True


@njit(cache=True, inline="always")
def _toi_lever(c, xt, i, s0, s1, s2, x, out):
    """``out = x_i + s + (c - xt)``: body i's lever arm at the time of impact (contact point c,
    centre xt there, periodic shift s included) placed at its present centre. The impulse then
    acts on each body as it would at the time of impact: a sphere's lever arm lies on the normal
    (a frictionless impulse passes through its centre: no spin), and the contact points' approach
    speed and the post-impact velocities are those of Eq. (17) at that time. A common point for
    both bodies (e.g. the midpoint of the two material points carried back) would conserve the
    angular momentum about a fixed point exactly but give spheres a lever arm off the normal."""
    out[0] = x[i, 0] + s0 + (c[0] - xt[0])
    out[1] = x[i, 1] + s1 + (c[1] - xt[1])
    out[2] = x[i, 2] + s2 + (c[2] - xt[2])


@njit(cache=True, inline="always")
def _pair_closing(i, j, v, sweep):
    """The fastest any two material points of bodies i and j approach each other: their relative
    velocity plus each one's rotation (``sweep - |v|``); a common translation closes nothing,
    and the flow carries touching neighbours along together."""
    s = math.sqrt((v[i, 0] - v[j, 0]) ** 2 + (v[i, 1] - v[j, 1]) ** 2 + (v[i, 2] - v[j, 2]) ** 2)
    s += sweep[i] - math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
    s += sweep[j] - math.sqrt(v[j, 0] ** 2 + v[j, 1] ** 2 + v[j, 2] ** 2)
    return s


@njit(cache=True, inline="always")
def _wall_closing(i, v, sweep, dcode, wn):
    """The fastest any point of body i approaches the wall of normal wn: only its velocity across
    the wall (radial for the pipe, whose axis is z; normal for a plane) and its rotation
    (``sweep[i] - |v_i|``) move its points towards it."""
    if dcode == PIPE:
        lin = math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2)
    else:
        lin = abs(v[i, 0] * wn[0] + v[i, 1] * wn[1] + v[i, 2] * wn[2])
    return lin + sweep[i] - math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)


@njit(cache=True)
def _toi_wall(i, kind, h, x, v, wb, Rm, dt, sweep, dcode, Rp, cx, cy, lo, hi, wn, manifold_tol, nrm, c, out_c, x1,
              R1):
    """As _toi_pair for body i and the wall identified by its normal wn (x1, R1: scratch)."""
    _advance_one(i, dt, x, v, wb, Rm, x1, R1)
    if _wall_gap(kind[i], h[i], x1, R1, dcode, Rp, cx, cy, lo, hi, wn, manifold_tol, nrm, c) >= 0.0:
        return False
    lo_t = 0.0
    hi_t = dt
    for _it in range(_toi_halvings(_wall_closing(i, v, sweep, dcode, wn) * dt)):
        mid = 0.5 * (lo_t + hi_t)
        _advance_one(i, mid, x, v, wb, Rm, x1, R1)
        if _wall_gap(kind[i], h[i], x1, R1, dcode, Rp, cx, cy, lo, hi, wn, manifold_tol, nrm, c) < 0.0:
            hi_t = mid
        else:
            lo_t = mid
    _advance_one(i, lo_t, x, v, wb, Rm, x1, R1)
    _wall_gap(kind[i], h[i], x1, R1, dcode, Rp, cx, cy, lo, hi, wn, manifold_tol, nrm, c)
    _toi_lever(c, x1, i, 0.0, 0.0, 0.0, x, out_c)
    return True



@njit(cache=True)
def _apart_after(i, j, sh, axis, kind, h, x, v, wb, Rm, dt, x1, x2, R1, R2):
    """True if, after a free step of dt, the plane normal to ``axis`` (the present contact normal,
    1 -> 2) still separates the pair by more than 1e-9 of the body size: then the overlap test
    (the exact one for two cylinders, which needs a point inside the other body by more than
    1e-9 of the size; GJK, which reports an overlap only within 1e-10 of the body size of
    touching) finds none, and ``_toi_pair`` returns False; this test costs two support points
    instead of that test."""
    _advance_one(i, dt, x, v, wb, Rm, x1, R1)
    _advance_one(j, dt, x, v, wb, Rm, x2, R2)
    a0 = axis[0]
    a1 = axis[1]
    a2 = axis[2]
    p10, p11, p12 = support3(kind[i], h[i], x1, R1, False, a0, a1, a2)
    p20, p21, p22 = support3(kind[j], h[j], x2, R2, False, -a0, -a1, -a2)
    sep = a0 * (p20 + sh[0] - p10) + a1 * (p21 + sh[1] - p11) + a2 * (p22 + sh[2] - p12)
    return sep > 1e-9 * (bounding_radius(kind[i], h[i]) + bounding_radius(kind[j], h[j]))



@njit(cache=True)
def _test_scratch():
    """Scratch of ``_activate_one``: the contact scratch (``new_scratch``), then its own arrays
    (normal, point, the two bodies' trial centres and rotations), in one buffer: each array passed
    to a function costs a reference count."""
    return new_scratch(30)


@njit(cache=True, inline="always")
def _test_arrays(scr):
    # the arrays of _activate_one in the buffer of _test_scratch
    o = WS_SIZE
    return (scr[o:o + 3], scr[o + 3:o + 6], scr[o + 6:o + 9], scr[o + 9:o + 12], ws_rows(scr, o + 12, 3, 3),
            ws_rows(scr, o + 21, 3, 3))


@njit(cache=True)
def _activate_one(m, pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep, dt, manifold_tol, dcode,
                  Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c, scr):
    """Speculative test (b) of contact m (m < npair: pair; else wall m - npair), wider than the
    contact gap: active if its bodies overlap after a free step (``_toi_pair`` / ``_toi_wall``),
    with the geometry at the time of impact. A contact's free motion cannot close more than the
    sum of its bodies' point speeds |v| + |omega| r_b times dt, so a gap wider than that skips the
    test (it would find no overlap), as does a present normal that still separates the pair at
    the end of the step. Writes only contact m's entries; never switches a contact off."""
    if m < npair:
        i = pi[m]
        j = pj[m]
        if cg[m] - (sweep[i] + sweep[j]) * dt > _SWEEP_SLACK:
            return
        pnrm, pc, x1, x2, R1, R2 = _test_arrays(scr)
        if _apart_after(i, j, ps[m], cn[m], kind, h, x, v, wb, Rm, dt, x1, x2, R1, R2):
            return
        if _toi_pair(i, j, ps[m], kind, h, x, v, wb, Rm, dt, sweep, manifold_tol, pnrm, pc, gp_c[m], gp_c2[m], scr, x1,
                     x2, R1, R2):
            on_p[m] = True
            for k in range(3):
                gp_n[m, k] = pnrm[k]
    else:
        m -= npair
        i = wi[m]
        if wg[m] - _wall_closing(i, v, sweep, dcode, wn[m]) * dt > _SWEEP_SLACK:
            return
        pnrm, pc, x1, x2, R1, R2 = _test_arrays(scr)
        if _toi_wall(i, kind, h, x, v, wb, Rm, dt, sweep, dcode, Rp, cx, cy, lo, hi, wn[m], manifold_tol, pnrm, pc, gw_c[m],
                     x1, R1):
            on_w[m] = True
            for k in range(3):
                gw_n[m, k] = pnrm[k]


@njit(cache=True, parallel=True)
def _activate_par(todo, ntodo, pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep, dt,
                  manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c):
    """``_activate_one`` for the contacts ``todo[:ntodo]``, in parallel (thread-count independent:
    each writes only its own entries and reads velocities no one writes meanwhile)."""
    nch = (ntodo + _CHUNK - 1) // _CHUNK
    for ch in prange(nch):
        scr = _test_scratch()
        for t in range(ch * _CHUNK, min(ntodo, ch * _CHUNK + _CHUNK)):
            _activate_one(todo[t], pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep, dt,
                          manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c, scr)

