"""Contact of a body with the pipe wall and with planar walls."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..shapes import CUBE, SPHERE
from .support import DISC_SIDES, RIM_SAMPLES, _support_lab
from .features import _feature, _unit_xy


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
