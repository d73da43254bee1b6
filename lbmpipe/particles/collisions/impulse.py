"""Particle-particle and particle-wall collisions: the instantaneous impulse model of the paper,
Eqs. (16)-(21), plus the overlap control that discrete time steps need.

Impulse (Eqs. (16)-(19)). Bodies 1 and 2 touch at the point ``O`` with unit normal ``p`` pointing
from 1 to 2; ``l_i = O - x_i`` are the lever arms, ``A_i`` the body->lab rotation matrices of the
quaternions (Eq. (20)), subscript ``s`` body-frame components. With the contact-point velocities
``u_i = v_i + omega_i x l_i`` and ``v_ip = u_i . p``, the bodies approach when
``v_1p - v_2p > 0``; then

    I = m_1 (1 + k)(v_1p - v_2p) / {1 + m_1/m_2 + m_1 ([A_1 J_1^-1 (l_1s x p_1s)] x l_1) . p
                                     + m_1 ([A_2 J_2^-1 (l_2s x p_2s)] x l_2) . p}      (19)

    m_1 v_1' = m_1 v_1 - I p,            m_2 v_2' = m_2 v_2 + I p                      (16)
    J_1 w_1s' = J_1 w_1s - l_1s x (I p_s),  J_2 w_2s' = J_2 w_2s + l_2s x (I p_s)       (18)

so that ``v_1p' - v_2p' = -k (v_1p - v_2p)`` (Eq. (17)), ``k`` the restitution (paper: ``k = 1``,
elastic). The code evaluates Eq. (19) divided through by ``m_1``, i.e.
``I = (1 + k)(v_1p - v_2p) / (1/m_1 + 1/m_2 + t_1 + t_2)`` with
``t_i = ([A_i J_i^-1 (l_is x p_is)] x l_i) . p``, which also covers fixed bodies: a fixed body
has ``1/m = 0`` and ``J^-1 = 0`` (infinite mass and inertia).

Walls (Eq. (21)): the same with body 2 the wall, ``m_2 -> infinity``, ``v_2p = 0``; here ``p``
points from the particle into the wall and the particle approaches when ``v_1p > 0``,
``I = m_1 (1 + k) v_1p / {1 + m_1 ([A_1 J_1^-1 (l_1s x p_1s)] x l_1) . p}`` and
``m_1 v_1' = m_1 v_1 - I p``. (The paper writes Eq. (21) with ``p`` the wall normal into the fluid,
``-p`` here, whence its ``-v_1p``.)

Every single impulse conserves the total linear momentum and the total angular momentum about
any fixed point (both bodies receive ``-/+ I p`` at the same point ``O``; for speculative contacts
see ``toi``), and changes the kinetic energy by ``-(1 - k^2)/2 * m_eff (v_1p - v_2p)^2`` with
``1/m_eff = 1/m_1 + 1/m_2 + t_1 + t_2`` (zero for ``k = 1``).

Impacts and loads: Eq. (17) reverses the approach speed of an impact. An approach no faster
than ``CollisionParams.rest_speed`` is a load the contact carries, not an impact, and is taken up
with ``k = 0``: reflected, a body resting on another under gravity leaves with ``k g dt`` every
step and climbs through the contact gap, gaining energy. The scene sets ``rest_speed`` to twice
one step's gravity kick (``effects.collision_effect``); without gravity it is 0 and every approach
is an impact. (Telling the kicks apart by the velocities since the previous call, and reflecting
only the approach made before them, pumped energy into dense suspensions: the fluid's implicit
velocity update is a kick of the order of the velocity itself, and the 50 % packings of the
stability suite blew up within 40 steps.)

This module holds the impulse of one contact and the Gauss-Seidel sweep over many
(``impulse_rounds`` drives the sweeps). Lattice units: lengths in lattice spacings, velocities
in lattice spacings per time step, masses and inertias in the units of ``Bodies``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_NG = 13  # impulse terms of a contact: l_1 (3), l_2 (3), a_1 (3), a_2 (3), denominator of Eq. (19)


@njit(cache=True, inline="always")
def _body_terms(b, lx, ly, lz, p0, p1, p2, Rm, iinv):
    """Body b's share of Eqs. (18)-(19) for lever arm l (lab) and normal p: a_b = J_b^-1 (l_s x
    p_s) in the body frame (Eq. (18)) and t_b = ([A_b a_b] x l) . p (Eq. (19))."""
    ls0 = Rm[b, 0, 0] * lx + Rm[b, 1, 0] * ly + Rm[b, 2, 0] * lz
    ls1 = Rm[b, 0, 1] * lx + Rm[b, 1, 1] * ly + Rm[b, 2, 1] * lz
    ls2 = Rm[b, 0, 2] * lx + Rm[b, 1, 2] * ly + Rm[b, 2, 2] * lz
    ps0 = Rm[b, 0, 0] * p0 + Rm[b, 1, 0] * p1 + Rm[b, 2, 0] * p2
    ps1 = Rm[b, 0, 1] * p0 + Rm[b, 1, 1] * p1 + Rm[b, 2, 1] * p2
    ps2 = Rm[b, 0, 2] * p0 + Rm[b, 1, 2] * p1 + Rm[b, 2, 2] * p2
    a0 = iinv[b, 0] * (ls1 * ps2 - ls2 * ps1)
    a1 = iinv[b, 1] * (ls2 * ps0 - ls0 * ps2)
    a2 = iinv[b, 2] * (ls0 * ps1 - ls1 * ps0)
    b0 = Rm[b, 0, 0] * a0 + Rm[b, 0, 1] * a1 + Rm[b, 0, 2] * a2
    b1 = Rm[b, 1, 0] * a0 + Rm[b, 1, 1] * a1 + Rm[b, 1, 2] * a2
    b2 = Rm[b, 2, 0] * a0 + Rm[b, 2, 1] * a1 + Rm[b, 2, 2] * a2
    t = (b1 * lz - b2 * ly) * p0 + (b2 * lx - b0 * lz) * p1 + (b0 * ly - b1 * lx) * p2
    return a0, a1, a2, t


@njit(cache=True, inline="always")
def _lab_omega(b, wb, Rm, wl):
    """wl[b] = A_b wb[b]: body b's angular velocity in the lab frame."""
    wl[b, 0] = Rm[b, 0, 0] * wb[b, 0] + Rm[b, 0, 1] * wb[b, 1] + Rm[b, 0, 2] * wb[b, 2]
    wl[b, 1] = Rm[b, 1, 0] * wb[b, 0] + Rm[b, 1, 1] * wb[b, 1] + Rm[b, 1, 2] * wb[b, 2]
    wl[b, 2] = Rm[b, 2, 0] * wb[b, 0] + Rm[b, 2, 1] * wb[b, 1] + Rm[b, 2, 2] * wb[b, 2]


@njit(cache=True)
def lab_omegas(wb, Rm):
    """A wb of every body (``_lab_omega``), for ``_gs_sweep``."""
    wl = np.empty_like(wb)
    for b in range(wb.shape[0]):
        _lab_omega(b, wb, Rm, wl)
    return wl


@njit(cache=True, inline="always")
def _normal_velocity(b, lx, ly, lz, p, m, v, wl):
    """(v_b + omega_b x l) . p[m]: body b's velocity at lever arm l along the normal
    (wl: omega in the lab frame, ``_lab_omega``)."""
    wx = wl[b, 0]
    wy = wl[b, 1]
    wz = wl[b, 2]
    ux = v[b, 0] + wy * lz - wz * ly
    uy = v[b, 1] + wz * lx - wx * lz
    uz = v[b, 2] + wx * ly - wy * lx
    return ux * p[m, 0] + uy * p[m, 1] + uz * p[m, 2]


@njit(cache=True, inline="always")
def _pair_terms(i, j, sx, sy, sz, c, c2, p, r, x, Rm, imi, imj, iinv, g, m):
    """The parts of Eqs. (18)-(19) that depend only on the geometry of a contact of bodies i and
    j (j at x_j + s; point ``c[r]`` of body 1 and ``c2[r]`` of body 2, the same point ``O`` for a
    touching contact; normal ``p[r]``), into row m of g: lever arms
    l_1 = O - x_1, l_2 = O - (x_2 + s) (lab), a_i = J_i^-1 (l_is x p_is) (body frame) and the
    denominator 1/m_1 + 1/m_2 + t_1 + t_2 (Eq. (19) divided through by m_1; ``imi``, ``imj`` the
    inverse masses). Positions and orientations do not change while impulses are applied, so a
    contact's terms serve all its sweeps.

    Without a branch and with the inverse masses as numbers: numba then drops the reference
    counting of the array arguments. One function for pairs and walls, with a branch on j and
    ``im`` read inside, took 100 ns a call instead of 17-21 (a loop over 800 contacts), even
    inlined; ``_impulse_terms`` keeps that dispatch only for the rare single contacts."""
    l1x = c[r, 0] - x[i, 0]
    l1y = c[r, 1] - x[i, 1]
    l1z = c[r, 2] - x[i, 2]
    l2x = c2[r, 0] - (x[j, 0] + sx)
    l2y = c2[r, 1] - (x[j, 1] + sy)
    l2z = c2[r, 2] - (x[j, 2] + sz)
    a10, a11, a12, t1 = _body_terms(i, l1x, l1y, l1z, p[r, 0], p[r, 1], p[r, 2], Rm, iinv)
    a20, a21, a22, t2 = _body_terms(j, l2x, l2y, l2z, p[r, 0], p[r, 1], p[r, 2], Rm, iinv)
    den = imi + t1
    den += imj + t2
    g[m, 0], g[m, 1], g[m, 2] = l1x, l1y, l1z
    g[m, 3], g[m, 4], g[m, 5] = l2x, l2y, l2z
    g[m, 6], g[m, 7], g[m, 8] = a10, a11, a12
    g[m, 9], g[m, 10], g[m, 11] = a20, a21, a22
    g[m, 12] = den


@njit(cache=True, inline="always")
def _wall_terms(i, c, p, r, x, Rm, imi, iinv, g, m):
    """``_pair_terms`` of a wall contact (Eq. (21)): body 2's terms left out."""
    l1x = c[r, 0] - x[i, 0]
    l1y = c[r, 1] - x[i, 1]
    l1z = c[r, 2] - x[i, 2]
    a10, a11, a12, t1 = _body_terms(i, l1x, l1y, l1z, p[r, 0], p[r, 1], p[r, 2], Rm, iinv)
    g[m, 0], g[m, 1], g[m, 2] = l1x, l1y, l1z
    g[m, 3] = g[m, 4] = g[m, 5] = 0.0
    g[m, 6], g[m, 7], g[m, 8] = a10, a11, a12
    g[m, 9] = g[m, 10] = g[m, 11] = 0.0
    g[m, 12] = imi + t1


@njit(cache=True)
def _impulse_terms(i, j, sx, sy, sz, c, c2, p, r, x, Rm, im, iinv, g, m):
    """``_pair_terms`` (j >= 0) or ``_wall_terms`` (j < 0: wall) of one contact."""
    if j >= 0:
        _pair_terms(i, j, sx, sy, sz, c, c2, p, r, x, Rm, im[i], im[j], iinv, g, m)
    else:
        _wall_terms(i, c, p, r, x, Rm, im[i], iinv, g, m)


@njit(cache=True)
def _gs_sweep(act, nact, ci, cj, p, g, v, wb, wl, Rm, im, k_rest, vtol, ver, ev1, ev2, vrest=0.0):
    """One Gauss-Seidel sweep of Eqs. (16)-(19) (pairs, ``cj >= 0``) and Eq. (21) (walls,
    ``cj < 0``) over the contacts ``act[:nact]``: contact m (bodies ci[m], cj[m], normal p[m],
    terms g[m] of ``_impulse_terms``) gets its impulse if it approaches, with restitution
    ``k_rest``, or 0 if it approaches no faster than ``vrest`` (a load). ``ver`` counts the
    impulses each body has received; a contact whose bodies have the counts of its last
    evaluation (``ev1``, ``ev2``) gives what it gave then: no impulse (after one it recedes, -k
    times as fast), and is skipped. ``wl`` holds A wb of the contacts' bodies (``lab_omegas``)
    and is kept up to date with ``wb``: an evaluation reads it instead of turning wb into the lab
    frame again (twice per evaluation, ~3 evaluations per impulse). Returns the number of impulses
    applied.

    The arithmetic is written out in the loop, indexed by row: a function called per contact with
    array arguments keeps their reference counting even when numba inlines it. In a small loop
    such as ``benchmarks/collision_floor.py``'s that took 5 times as long (0.94-1.5 against
    0.19-0.33 ms for 11,000 evaluations). In the collision kernel, moving the sweep here kept the
    bits; per step it took 0.68 (0.58-1.27) of the time at steps 100-130 and 0.95 (0.73-1.13) at
    steps 300-320 (medians of 8 paired runs, 244 dense cylinders: as wide as the machine's noise)."""
    applied = 0
    for t in range(nact):
        m = act[t]
        i = ci[m]
        j = cj[m]
        if ver[i] == ev1[m] and (j < 0 or ver[j] == ev2[m]):
            continue
        # approach speed of the contact points u_i = v_i + omega_i x l_i along the normal
        vn = _normal_velocity(i, g[m, 0], g[m, 1], g[m, 2], p, m, v, wl)
        if j >= 0:
            vn -= _normal_velocity(j, g[m, 3], g[m, 4], g[m, 5], p, m, v, wl)
        if vn > vtol and g[m, 12] > 0.0:  # a zero denominator: both bodies fixed
            kk = k_rest if vn > vrest else 0.0  # a load is taken up, an impact reflected (Eq. (17))
            imp = (1.0 + kk) * vn / g[m, 12]  # Eq. (19) / Eq. (21), divided through by m_1
            f = imp * im[i]
            for k in range(3):
                v[i, k] -= f * p[m, k]  # Eq. (16)
            wb[i, 0] -= imp * g[m, 6]  # Eq. (18)
            wb[i, 1] -= imp * g[m, 7]
            wb[i, 2] -= imp * g[m, 8]
            _lab_omega(i, wb, Rm, wl)
            ver[i] += 1
            if j >= 0:
                f = imp * im[j]
                for k in range(3):
                    v[j, k] += f * p[m, k]
                wb[j, 0] += imp * g[m, 9]
                wb[j, 1] += imp * g[m, 10]
                wb[j, 2] += imp * g[m, 11]
                _lab_omega(j, wb, Rm, wl)
                ver[j] += 1
            applied += 1
        ev1[m] = ver[i]
        if j >= 0:
            ev2[m] = ver[j]
    return applied


@njit(cache=True)
def _impulse(i, j, sx, sy, sz, c, c2, p, x, v, wb, Rm, im, iinv, k_rest, vtol):
    """Apply Eqs. (16)-(19) (j >= 0) or Eq. (21) (j < 0: wall) to one contact (points c of body 1
    and c2 of body 2, normal p, body 2 at x_j + s) if it approaches: ``_impulse_terms`` then
    ``_gs_sweep``. Returns whether it did."""
    g = np.empty((1, _NG))
    pr = np.empty((1, 3))
    cr = np.empty((1, 3))
    cr2 = np.empty((1, 3))
    for k in range(3):
        pr[0, k] = p[k]
        cr[0, k] = c[k]
        cr2[0, k] = c2[k]
    _impulse_terms(i, j, sx, sy, sz, cr, cr2, pr, 0, x, Rm, im, iinv, g, 0)
    # the sweep reads the lab-frame spin of this contact's bodies only
    wl = np.empty_like(wb)
    _lab_omega(i, wb, Rm, wl)
    if j >= 0:
        _lab_omega(j, wb, Rm, wl)
    ev = np.full(1, -1, dtype=np.int64)
    return _gs_sweep(np.zeros(1, dtype=np.int64), 1, np.full(1, i), np.full(1, j), pr, g, v, wb, wl, Rm, im, k_rest,
                     vtol, np.zeros(v.shape[0], dtype=np.int64), ev, ev.copy()) > 0

