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
see below), and changes the kinetic energy by ``-(1 - k^2)/2 * m_eff (v_1p - v_2p)^2`` with
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

When is a contact treated (``CollisionParams``):
- touching: the signed gap is ``<= contact_gap``. The contact takes part in the impulse sweeps
  from the start with its present point and normal, and receives an impulse whenever it
  approaches, including when it recedes at first and an impulse elsewhere in the step turns it
  around (a row of touching spheres passes a blow down the row within one step);
- speculative (``speculative=True``, default): a contact wider than ``contact_gap`` whose two
  bodies, moving freely at their present velocities and angular velocities, would overlap by the
  end of the step ``dt``. The time of impact in the step is found by bisection, halved until
  the bodies close by at most ``_TOI_TOL`` (1e-3 lattice spacings) over the bracket left (at most
  12 halvings); the impulse uses the contact normal at that time and each body's lever arm there
  (``_toi_lever``): the impulse acts as it would at the time of impact, so a frictionless sphere
  never spins and the post-impact velocities are those of Eq. (17) then. Momentum is conserved
  exactly; the angular momentum about a fixed point changes by ``t (v_1 - v_2) x I p`` (t the time
  of impact): the bodies have it at time t, where the impact happens. The bounce thus happens up
  to one step early instead of the bodies overlapping; this also catches a corner turning into contact, which a
  test on the present gap and normal velocity misses. Touching contacts that do not approach at
  the start of a step skip this test: the sweeps take their geometry from the narrow phase;
- touching and turning (with ``speculative``): a touching contact whose bodies turn by more than
  half of its gap plus half the overlap bound at their bounding radii within the step gets a twin that takes
  the speculative test above: the contact point holds only where it is, and a spinning cube's
  corner beside a face contact closes the gap elsewhere (a pair that overlaps already, by up to
  ``overlap_tol``, finds that overlap at t = 0 and gets its present contact: a jam's turning corner
  is then caught by the lock of point 3 below);
- with several contacts the impulses are applied contact by contact (Gauss-Seidel) in repeated
  sweeps until none approaches; as impulses change velocities, the speculative tests are then
  repeated (a body knocked into a third one within the step) until a round applies no impulse
  (both loops capped by ``max_sweeps``). The first half of the sweeps use the restitution ``k``,
  the rest ``k = 0``: contacts still bouncing then are a jam (a closed row at ``k = 1`` passes the
  blows back and forth without end), which inelastic sweeps settle.

Overlap control: after the impulses, overlaps are removed by projecting positions along the
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

Overlap bound (``OVERLAP_BOUND_FACTOR``; ``CollisionParams.overlap_bound``, which the run-time
guard enforces). When ``resolve_collisions`` returns, every pair and wall overlap is
``<= overlap_tol`` (default 0.01 lattice spacing) unless both projections ran out of iterations;
the value reached is ``stats["max_overlap_after"]`` either way. At any time, before a call or
after it, overlaps stay within ``overlap_bound = OVERLAP_BOUND_FACTOR * overlap_tol`` (0.1
lattice spacing). Every source of overlap, with what holds it:

1. what a call leaves: ``<= overlap_tol``, more only in a jam that exhausts
   ``max_projection_iters`` (reported as ``max_overlap_after``);
2. the drift after a call, of contacts the free-motion prediction covers: a speculative contact
   bounces within ``_TOI_TOL`` (1e-3) of touching; a touching contact is held at its present point
   and, if its bodies turn by more than half of its gap plus half the overlap bound at their
   bounding radii, its twin takes the speculative test (c), so other features turning into contact
   add at most half the overlap bound plus second order in the angle (a slack of ``overlap_tol``
   instead sent nearly every touching contact of 244 dense cylinders, turning by ~1e-3 rad a
   step, to the test, and doubled the cost per contact);
3. contacts left approaching at the sweep caps: ``stats["unresolved"]``; the last half of the
   sweeps are inelastic, which settles the jams that bounce without end at ``k = 1``, and a jam
   still approaching at the cap is locked (``_lock_jams``, ``stats["locked_bodies"]``): the bodies
   its approaching pairs join move on as one rigid body with their linear and angular momentum (a
   cluster with a body approaching a wall stops), so none of its contacts approaches in the drift,
   and inelastic sweeps then take up what the locked bodies' new velocities do to their other
   contacts (a row of cubes spinning at 0.09 rad a step jammed in a channel, and a dense box at
   ``contact_gap`` 1.0, turned 0.17-0.22 lu into each other without it; the box blew up). The
   paper's suspensions leave none unresolved at dx = 1 mm. At dx = 2 mm the dense 8 x 16 mm
   cylinders do (51-362 contacts in 4,000 steps), and there the overlap before a call reaches
   0.10-0.13 lu (0.09-0.12 without the lock): a fluid-coupled jam that the bound does not hold
   (``stats["max_overlap_before"]`` reports it; without the sweeps after the lock, 0.29 lu);
4. motion the prediction does not see: the next step's force and torque kicks (the call comes
   after the velocity update, so only the drift's own change of the rotation axis of
   non-symmetric bodies is left within a step) and the projection's pushes into contacts it has
   not listed (a pass with a fresh pair list follows any push beyond half the skin).

Each is removed again at the next call. The dry-run tests (200 spheres and cubes, 10^4 steps,
speeds ~0.1 and spins ~0.1 rad per step; a dense box of spheres, cubes and cylinders spinning at
0.05 rad per step) assert ``overlap_bound`` before each call and ``overlap_tol`` after it.

Call once per time step, after the velocity update (hydrodynamic forces) and before the positions
are advanced.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..effect import Effect
from ..errors import Unstable
from .contact import (WS_HINT, WS_WON, WS_SIZE, support3, ws_rows, bodies_overlap_ws, body_contact_ws,
                      bounding_radii, list_displacement, listed_slots, neighbour_list, new_scratch, pipe_wall_contact,
                      plane_wall_contact)
from .shapes import CYLINDER, SPHERE, bounding_radius
from .rigid import Bodies, qmul, quat_to_matrix, quat_to_matrices
from .collision_params import BOX, OVERLAP_BOUND_FACTOR, PIPE, CollisionParams, Domain, min_periodic_length


class NeighbourList:
    """The Verlet list of the pair search, kept from one call of ``resolve_collisions`` to the
    next (``lbmpipe.particles.contact.neighbour_list``; the kernel rebuilds it when a body has moved too
    far). The pairs taken from it are those of the cell scan, in its order, so a fresh list
    changes no result."""

    def __init__(self):
        self.start = np.zeros(1, dtype=np.int64)
        self.js = np.zeros(0, dtype=np.int64)
        self.win = np.zeros(0, dtype=np.int8)  # per slot: the exact cylinder candidate that won last
        self.xref = np.zeros((0, 3))
        self.meta = np.zeros(2)  # margin built for (0: not built), number of builds

    @property
    def builds(self) -> int:
        return int(self.meta[1])


# stats layout
_S_CAND, _S_PAIR, _S_WALL, _S_IMP, _S_OVB, _S_OVA, _S_SWEEP, _S_PROJ, _S_UNRES, _S_DISP, _S_ROT, _S_LOCK = range(12)
_NSTATS = 12


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
_VTOL_FLOOR = 1.0e-30
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
def _xy_extent(kind, h, R):
    """Upper bound of the distance of a body point from the centre, projected on the pipe's
    cross-section (x, y): a cylinder spans h_z |a_xy| along its axis a plus at most its radius
    across; a box sum_k h_k |R_k,xy|. Never more than needed, at most the bounding radius."""
    if kind == SPHERE:
        return h[0]
    if kind == CYLINDER:
        return h[2] * math.sqrt(R[0, 2] * R[0, 2] + R[1, 2] * R[1, 2]) + h[0]
    e = 0.0
    for k in range(3):
        e += h[k] * math.sqrt(R[0, k] * R[0, k] + R[1, k] * R[1, k])
    return e


# pairs (or bodies) per parallel work item, each of which allocates its scratch: 8 made ~740
# allocations a step with 244 dense cylinders; 32 runs the narrow phase in 0.94-0.95 of that time
# on 1 thread and 0.98 on 2 (same bits), and ~47 items still balance the threads
_CHUNK = 32
# a gap this far above the swept distance is certainly still open at the end of the step (far
# above the gap's accuracy, ~1e-9 of the body size)
_SWEEP_SLACK = 1e-6
# contact tests (narrow phase: candidate pairs) run in parallel only in batches at least this
# large (a parallel region costs ~10 us on an idle machine, far more on a loaded one)
_PAR_MIN = 4096
_PAR_MIN_PAIRS = 256


@njit(cache=True)
def _wall_one(i, kind, h, x, Rm, rb, dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, manifold_tol, use, sg, sn, sc,
              nrm, c):
    """Wall contacts of body i into its slots (pipe: 1; box: 2 per axis) if its bounding sphere
    comes within ``margin`` of the wall. Pipe: the exact gap is computed only if a cheap lower
    bound (centre distance + cross-section extent) is within ``reach``; otherwise that lower
    bound (> reach) is stored, which no decision of the step can tell apart from the exact gap:
    only ``gap <= reach`` activates a contact, and the projection re-measures any entry whose
    bound (stored gap minus displacement) falls below ``-overlap_tol``."""
    if dcode == 0:
        ox = x[i, 0] - cx
        oy = x[i, 1] - cy
        rho = math.sqrt(ox * ox + oy * oy)
        if rho + rb[i] < Rp - margin:
            return
        use[i, 0] = True
        lb = Rp - (rho + min(rb[i], _xy_extent(kind[i], h[i], Rm[i])))
        if lb > reach + 1e-9 * rb[i]:
            sg[i, 0] = lb
            for k in range(3):
                sn[i, 0, k] = 0.0
                sc[i, 0, k] = x[i, k]
            return
        sg[i, 0] = pipe_wall_contact(kind[i], h[i], x[i], Rm[i], Rp, cx, cy, manifold_tol, nrm, c)
        for k in range(3):
            sn[i, 0, k] = nrm[k]
            sc[i, 0, k] = c[k]
        return
    for a in range(3):
        if periodic[a]:
            continue
        for s in range(2):
            side = -1.0 if s == 0 else 1.0
            coord = lo[a] if side < 0.0 else hi[a]
            if side * (coord - x[i, a]) - rb[i] > margin:
                continue
            t = 2 * a + s
            use[i, t] = True
            sg[i, t] = plane_wall_contact(kind[i], h[i], x[i], Rm[i], a, coord, side, manifold_tol, nrm, c)
            for k in range(3):
                sn[i, t, k] = nrm[k]
                sc[i, t, k] = c[k]


@njit(cache=True)
def _narrow_chunk(ch, ncp, kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                  dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc):
    """Work item ``ch`` of the narrow phase: pairs ``ch * _CHUNK ...`` if ``ch < ncp``, else the
    wall contacts of bodies ``(ch - ncp) * _CHUNK ...``."""
    npair = pi.shape[0]
    n = x.shape[0]
    ws = new_scratch()
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    if ch < ncp:
        for m in range(ch * _CHUNK, min(npair, ch * _CHUNK + _CHUNK)):
            i = pi[m]
            j = pj[m]
            for k in range(3):
                x2[k] = x[j, k] + ps[m, k]
            # the plane normal to the centre line often separates a pair by more than
            # max_gap already: that separation is a lower bound of the gap, and two support
            # points cost far less than GJK's iterations
            d0 = x2[0] - x[i, 0]
            d1 = x2[1] - x[i, 1]
            d2 = x2[2] - x[i, 2]
            dd = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if dd > 0.0:
                d0 /= dd
                d1 /= dd
                d2 /= dd
                p10, p11, p12 = support3(kind[i], h[i], x[i], Rm[i], False, d0, d1, d2)
                p20, p21, p22 = support3(kind[j], h[j], x2, Rm[j], False, -d0, -d1, -d2)
                sep = d0 * (p20 - p10) + d1 * (p21 - p11) + d2 * (p22 - p12)
                if sep > max_gap:
                    cg[m] = sep
                    cn[m, 0], cn[m, 1], cn[m, 2] = d0, d1, d2
                    for k in range(3):
                        cc[m, k] = 0.5 * (x[i, k] + x2[k])
                    continue
            # the pair's closest features of the step before, in its list slot, go first
            ws[WS_HINT] = lwin[pk[m]]
            cg[m] = body_contact_ws(kind[i], h[i], x[i], Rm[i], kind[j], h[j], x2, Rm[j], max_gap, manifold_tol, nrm,
                                    c, ws)
            lwin[pk[m]] = int(ws[WS_WON])
            for k in range(3):
                cn[m, k] = nrm[k]
                cc[m, k] = c[k]
    else:
        b = ch - ncp
        for i in range(b * _CHUNK, min(n, b * _CHUNK + _CHUNK)):
            _wall_one(i, kind, h, x, Rm, rb, dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, manifold_tol, use,
                      sg, sn, sc, nrm, c)


@njit(cache=True, parallel=True)
def _narrow_par(ncp, nch, kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc):
    for ch in prange(nch):
        _narrow_chunk(ch, ncp, kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                      dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc)


@njit(cache=True)
def _narrow_phase(kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                  dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc):
    """All pair gaps (``cg``, normals ``cn``, points ``cc``) and the wall gaps per body and slot
    (``_wall_one``), in one parallel region if there are enough pairs (its start-up costs more
    than a small problem's work, and far more on a loaded machine). Every pair and body writes
    only its own rows, so the result does not depend on the thread count. Pair gaps above
    ``max_gap`` may come back as lower bounds (> max_gap). ``lwin[pk[m]]``: pair m's exact
    cylinder candidate of the step before, to try first (``contact._cylinder_gap``), replaced by
    this step's; each pair has its own slot."""
    ncp = (pi.shape[0] + _CHUNK - 1) // _CHUNK
    nch = ncp + (x.shape[0] + _CHUNK - 1) // _CHUNK
    if pi.shape[0] >= _PAR_MIN_PAIRS:
        _narrow_par(ncp, nch, kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                    dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc)
    else:
        for ch in range(nch):
            _narrow_chunk(ch, ncp, kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, max_gap, manifold_tol, cg, cn, cc,
                          dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc)


@njit(cache=True)
def _gather_walls(use, sg, sn, sc):
    """The wall contacts in body order (then axis, side): (body, gap, normal, point)."""
    n, slots = use.shape
    cnt = 0
    for i in range(n):
        for t in range(slots):
            if use[i, t]:
                cnt += 1
    wi = np.empty(cnt, dtype=np.int64)
    wg = np.empty(cnt)
    wn = np.empty((cnt, 3))
    wc = np.empty((cnt, 3))
    m = 0
    for i in range(n):
        for t in range(slots):
            if use[i, t]:
                wi[m] = i
                wg[m] = sg[i, t]
                for k in range(3):
                    wn[m, k] = sn[i, t, k]
                    wc[m, k] = sc[i, t, k]
                m += 1
    return wi, wg, wn, wc


@njit(cache=True)
def _wall_gap(kind, h, x, R, dcode, Rp, cx, cy, lo, hi, wn, manifold_tol, nrm, c):
    # re-measure one wall contact whose wall is identified by its stored normal
    if dcode == 0:
        return pipe_wall_contact(kind, h, x, R, Rp, cx, cy, manifold_tol, nrm, c)
    a = 0
    for k in range(3):
        if abs(wn[k]) > 0.5:
            a = k
    side = 1.0 if wn[a] > 0.0 else -1.0
    coord = hi[a] if side > 0.0 else lo[a]
    return plane_wall_contact(kind, h, x, R, a, coord, side, manifold_tol, nrm, c)


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
def _activate_one(m, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep, dt, manifold_tol, dcode,
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
def _activate_par(todo, ntodo, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep, dt,
                  manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c):
    """``_activate_one`` for the contacts ``todo[:ntodo]``, in parallel (thread-count independent:
    each writes only its own entries and reads velocities no one writes meanwhile)."""
    nch = (ntodo + _CHUNK - 1) // _CHUNK
    for ch in prange(nch):
        scr = _test_scratch()
        for t in range(ch * _CHUNK, min(ntodo, ch * _CHUNK + _CHUNK)):
            _activate_one(todo[t], pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep, dt,
                          manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c, scr)


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
def _carry_hints(ostart, ojs, owin, nstart, njs):
    """The exact cylinder candidates of the pairs of a rebuilt Verlet list, taken from the old
    list where it held the pair (-1 elsewhere): a rebuild would otherwise make every pair search
    its candidates from the start for a step."""
    win = np.full(njs.shape[0], -1, dtype=np.int8)
    if ostart.shape[0] != nstart.shape[0]:  # the first list, or a new number of bodies
        return win
    for i in range(nstart.shape[0] - 1):
        for t in range(nstart[i], nstart[i + 1]):
            j = njs[t]
            for u in range(ostart[i], ostart[i + 1]):
                if ojs[u] == j:
                    win[t] = owin[u]
                    break
    return win


_min_periodic_length = njit(cache=True, inline="always")(min_periodic_length)


@njit(cache=True)
def _lock_jams(jam, grounded, pi, pj, ps, x, v, wb, Rm, mass, inertia, fixed):
    """Perfectly inelastic end of a jam the sweeps could not resolve (contacts still approaching
    at the cap): the bodies joined by the pairs ``jam`` left approaching move on as one rigid
    cluster, each cluster with the velocity and spin that keep its linear and angular momentum
    (the rigid motion of least kinetic energy with them, so no energy is made); a cluster with a
    body left approaching a wall (``grounded``) or a fixed body stops. No contact within a cluster
    then approaches, and the drift after the call cannot turn a corner into another body (a row of
    cubes spinning at 0.09 rad a step, jammed end to end in a channel: 0.17 lu after the drift).
    The caller sweeps the contacts again (k = 0) for what the new velocities do to the others.
    Returns the number of bodies locked."""
    n = x.shape[0]
    npair = jam.shape[0]
    # adjacency of the jammed pairs (each stored both ways, with the periodic shift of the partner)
    deg = np.zeros(n + 1, dtype=np.int64)
    for m in range(npair):
        if jam[m]:
            deg[pi[m] + 1] += 1
            deg[pj[m] + 1] += 1
    for i in range(n):
        deg[i + 1] += deg[i]
    fill = deg[:n].copy()
    nb = np.empty(deg[n], dtype=np.int64)
    nsh = np.empty((deg[n], 3))
    for m in range(npair):
        if jam[m]:
            i, j = pi[m], pj[m]
            nb[fill[i]] = j
            nsh[fill[i]] = ps[m]
            fill[i] += 1
            nb[fill[j]] = i
            nsh[fill[j]] = -ps[m]
            fill[j] += 1
    seen = np.zeros(n, dtype=np.bool_)
    xu = np.empty((n, 3))  # positions unwrapped across the periodic boundary within a cluster
    members = np.empty(n, dtype=np.int64)
    locked = 0
    for r in range(n):
        if seen[r] or not (grounded[r] or deg[r + 1] > deg[r]):
            continue
        seen[r] = True
        xu[r] = x[r]
        members[0] = r
        nm = 1
        head = 0
        stop = False
        while head < nm:
            a = members[head]
            head += 1
            stop = stop or grounded[a] or fixed[a]
            for e in range(deg[a], deg[a + 1]):
                b = nb[e]
                if not seen[b]:
                    seen[b] = True
                    # b's centre as seen from a (periodic shift of the pair), carried to a's unwrapped place
                    for k in range(3):
                        xu[b, k] = xu[a, k] + (x[b, k] + nsh[e, k] - x[a, k])
                    members[nm] = b
                    nm += 1
        locked += nm
        if stop:
            for t in range(nm):
                b = members[t]
                if fixed[b]:
                    continue  # its motion is prescribed
                for k in range(3):
                    v[b, k] = 0.0
                    wb[b, k] = 0.0
            continue
        mt = 0.0
        com = np.zeros(3)
        mom = np.zeros(3)
        for t in range(nm):
            b = members[t]
            mt += mass[b]
            for k in range(3):
                com[k] += mass[b] * xu[b, k]
                mom[k] += mass[b] * v[b, k]
        com /= mt
        vel = mom / mt
        ang = np.zeros(3)  # angular momentum about the centre of mass, lab frame
        itot = np.zeros((3, 3))  # the cluster's inertia tensor about it
        for t in range(nm):
            b = members[t]
            rr = xu[b] - com
            ang += mass[b] * np.cross(rr, v[b])
            r2 = rr[0] ** 2 + rr[1] ** 2 + rr[2] ** 2
            for a in range(3):
                for c in range(3):
                    # spin: A J wb and A J A^T; orbit: m (|r|^2 1 - r r^T)
                    ang[a] += Rm[b, a, c] * inertia[b, c] * wb[b, c]
                    s_ac = 0.0
                    for k in range(3):
                        s_ac += Rm[b, a, k] * inertia[b, k] * Rm[b, c, k]
                    itot[a, c] += s_ac + mass[b] * ((r2 if a == c else 0.0) - rr[a] * rr[c])
        om = np.linalg.solve(itot, ang)
        for t in range(nm):
            b = members[t]
            rr = xu[b] - com
            cr = np.cross(om, rr)
            for k in range(3):
                v[b, k] = vel[k] + cr[k]
                wb[b, k] = Rm[b, 0, k] * om[0] + Rm[b, 1, k] * om[1] + Rm[b, 2, k] * om[2]
    return locked


@njit(cache=True)
def _resolve_kernel(
    kind, h, mass, inertia, x, v, q, wb, fixed,
    dcode, Rp, cx, cy, lo, hi, periodic,
    k_rest, contact_gap, spec, overlap_tol, manifold_tol, skin, max_sweeps, max_proj, max_trans, dt,
    do_impulses, stats, pairs, list_skin, lstart, ljs, lwin, lxref, lmeta, vrest,
):
    n = x.shape[0]
    Rm = quat_to_matrices(q)
    rb = bounding_radii(kind, h)
    im = np.zeros(n)
    iinv = np.zeros((n, 3))
    for i in range(n):
        if not fixed[i]:
            im[i] = 1.0 / mass[i]
            for k in range(3):
                iinv[i, k] = 1.0 / inertia[i, k]
    sweep = np.empty(n)  # fastest point speed |v| + |omega| r_b of each body
    vmax = 0.0
    for i in range(n):
        sp = math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
        sp += math.sqrt(wb[i, 0] ** 2 + wb[i, 1] ** 2 + wb[i, 2] ** 2) * rb[i]
        sweep[i] = sp
        if not fixed[i]:
            vmax = max(vmax, sp)
    # gap below which a contact can become active within this step
    reach = contact_gap + (2.0 * vmax * dt if spec else 0.0)
    margin = reach + skin
    if do_impulses and pairs:
        # A periodic axis shorter than two interaction ranges 2 r_b,max + margin would let a pair
        # meet two images: refused before anything moves (status 1 + axis; 4 + axis if only the
        # speculative reach is too long), for resolve_collisions to raise. Checked here rather than
        # with NumPy before the call: run cold after the fluid sweep, those calls took 0.15 ms a step.
        # Without a pair search (one body, or pairs off) a body meets only the walls: no rule.
        rbmax = 0.0
        for i in range(n):
            rbmax = max(rbmax, rb[i])
        for a in range(3):
            if periodic[a] and (hi[a] - lo[a]) < _min_periodic_length(rbmax, contact_gap, skin):
                return 0.0, lstart, ljs, lwin, 1 + a
        for a in range(3):
            if periodic[a] and (hi[a] - lo[a]) < _min_periodic_length(rbmax, reach, skin):
                return 0.0, lstart, ljs, lwin, 4 + a
    if pairs:
        # the Verlet list (lstart, ljs: neighbour_list), built at lxref for the margin lmeta[0]
        # (0: none yet; lmeta[1]: builds), serves while it holds every pair within margin
        if not (lmeta[0] > 0.0 and lxref.shape[0] == n
                and margin + 2.0 * list_displacement(x, lxref, lo, hi, periodic) <= lmeta[0]):
            lmeta[0] = margin + list_skin
            ostart, ojs, owin = lstart, ljs, lwin
            lstart, ljs = neighbour_list(x, rb, lmeta[0], lo, hi, periodic)
            lwin = _carry_hints(ostart, ojs, owin, lstart, ljs)
            lxref[:] = x
            lmeta[1] += 1.0
        pi, pj, ps, pk = listed_slots(x, rb, margin, lo, hi, periodic, lstart, ljs)
    else:  # one particle, or a scene that asks for wall contacts only
        pi = np.empty(0, dtype=np.int64)
        pj = np.empty(0, dtype=np.int64)
        ps = np.empty((0, 3))
        pk = np.empty(0, dtype=np.int64)
    npair = pi.shape[0]
    cg = np.empty(npair)
    cn = np.empty((npair, 3))
    cc = np.empty((npair, 3))
    # Gaps beyond ``contact_gap`` may come back as lower bounds (> contact_gap), and GJK stops
    # early on them: nothing in this step tells them from the exact gap. Only a touching contact
    # (gap <= contact_gap) uses its present geometry; a wider one within ``reach`` is only
    # tested for a speculative contact, which looks at the end of the step (the gap serves as a
    # bound there); the projection re-measures whatever its displacement bound says might overlap.
    slots = 1 if dcode == PIPE else 6
    use = np.zeros((n, slots), dtype=np.bool_)
    sg = np.empty((n, slots))
    sn = np.empty((n, slots, 3))
    sc = np.empty((n, slots, 3))
    _narrow_phase(kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, contact_gap, manifold_tol, cg, cn, cc,
                  dcode, Rp, cx, cy, lo, hi, periodic, margin, reach, use, sg, sn, sc)
    wi, wg, wn, wc = _gather_walls(use, sg, sn, sc)
    nwall = wi.shape[0]
    ov = 0.0
    npc = 0
    nwc = 0
    for m in range(npair):
        ov = max(ov, -cg[m])
        if cg[m] <= contact_gap:
            npc += 1
    for m in range(nwall):
        ov = max(ov, -wg[m])
        if wg[m] <= contact_gap:
            nwc += 1
    stats[_S_CAND] += npair
    stats[_S_PAIR] += npc
    stats[_S_WALL] += nwc
    stats[_S_OVB] = max(stats[_S_OVB], ov)

    # ---- impulses, Eqs. (16)-(21), Gauss-Seidel over the active contacts. A contact is active
    # (a) if it touches now (gap <= contact_gap): with its present point and normal, from the
    #     start; the sweeps give it an impulse whenever it approaches, so a touching contact that
    #     recedes now joins in as soon as an impulse elsewhere turns it around; or, with ``spec``,
    # (b) if it is wider but the two bodies, moving freely at the present velocities, would
    #     overlap by the end of the step: the time of impact is found by bisection, and the
    #     impulse uses the contact normal there and the contact's material points carried back to
    #     the present (their midpoint, so that both bodies get -/+ I p at one point). This catches
    #     corners turning into contact as well as approaching faces.
    # Impulses change velocities, so the prediction (b) is redone until a round applies none. The
    # test of a contact depends only on its two bodies' velocities, so a round re-tests only the
    # contacts with a body that received an impulse since their last test (the others would
    # give the same answer again).
    if do_impulses:
        # impulse normals, and the bodies, of the contacts: pairs, then walls as npair + m; rows
        # nc + m: the twins (c) of the touching contacts (a), kept apart from their present geometry
        nc = npair + nwall
        gn = np.empty((2 * nc, 3))
        ci = np.empty(2 * nc, dtype=np.int64)
        cj = np.empty(2 * nc, dtype=np.int64)
        for m in range(npair):
            for k in range(3):  # element by element: a row assignment makes two views per row
                gn[m, k] = cn[m, k]
            ci[m] = ci[nc + m] = pi[m]
            cj[m] = cj[nc + m] = pj[m]
        for m in range(nwall):
            for k in range(3):
                gn[npair + m, k] = wn[m, k]
            ci[npair + m] = ci[nc + npair + m] = wi[m]
            cj[npair + m] = cj[nc + npair + m] = -1
        gp_n = gn[:npair]
        gw_n = gn[npair:nc]
        tp_n = gn[nc:nc + npair]
        tw_n = gn[nc + npair:]
        gp_c = cc.copy()  # impulse points: body 1's, body 2's (gp_c2; differ for speculative contacts)
        gp_c2 = cc.copy()
        gw_c = wc.copy()
        tp_c = np.empty((npair, 3))  # the twins'
        tp_c2 = np.empty((npair, 3))
        tw_c = np.empty((nwall, 3))
        gt = np.empty((2 * nc, _NG))  # impulse terms (_impulse_terms) of the active contacts
        gt_p = gt[:npair]
        gt_w = gt[npair:nc]
        tt_p = gt[nc:nc + npair]
        tt_w = gt[nc + npair:]
        # (a): the touching contacts, with the geometry the narrow phase measured
        on_p = cg <= contact_gap
        on_w = wg <= contact_gap
        on_tp = np.zeros(npair, dtype=np.bool_)
        on_tw = np.zeros(nwall, dtype=np.bool_)
        for m in range(npair):
            if on_p[m]:
                i = pi[m]
                j = pj[m]
                _pair_terms(i, j, ps[m, 0], ps[m, 1], ps[m, 2], gp_c, gp_c2, gp_n, m, x, Rm, im[i], im[j], iinv, gt_p,
                            m)
        for m in range(nwall):
            if on_w[m]:
                i = wi[m]
                _wall_terms(i, gw_c, gw_n, m, x, Rm, im[i], iinv, gt_w, m)
        # approaches slower than this are round-off; the floor keeps bodies at rest (a jam locked by
        # _lock_jams, left with ~1e-24 lattice units a step) from sweeping to the cap every step
        vtol = max(1e-12 * vmax, _VTOL_FLOOR)
        nimp = 0
        sweeps = 0
        # (b): the wider contacts within reach (pairs, then walls as npair + m)
        near = np.empty(nc, dtype=np.int64)
        nnear = 0
        # (c): the touching contacts, whose other features may turn into contact within the step
        touch = np.empty(nc, dtype=np.int64)
        ntouch = 0
        if spec:
            for m in range(npair):
                if contact_gap < cg[m] <= reach:
                    near[nnear] = m
                    nnear += 1
                elif on_p[m]:
                    touch[ntouch] = m
                    ntouch += 1
            for m in range(nwall):
                if contact_gap < wg[m] <= reach:
                    near[nnear] = npair + m
                    nnear += 1
                elif on_w[m]:
                    touch[ntouch] = npair + m
                    ntouch += 1
        ver = np.zeros(n, dtype=np.int64)  # impulses received by each body so far
        seen1 = np.full(nc, -1, dtype=np.int64)  # ver of the bodies at a contact's last test
        seen2 = np.full(nc, -1, dtype=np.int64)
        tseen1 = np.full(nc, -1, dtype=np.int64)  # ... at a touching contact's last test (c)
        tseen2 = np.full(nc, -1, dtype=np.int64)
        todo = np.empty(nnear + ntouch, dtype=np.int64)
        scr = _test_scratch()
        act = np.empty(2 * nc, dtype=np.int64)
        ev1 = np.full(2 * nc, -1, dtype=np.int64)  # ver of the bodies at a contact's last impulse evaluation
        ev2 = np.full(2 * nc, -1, dtype=np.int64)
        wl = lab_omegas(wb, Rm)
        for rnd in range(max_sweeps):
            ntodo = 0
            for t in range(nnear):
                m = near[t]
                i = pi[m] if m < npair else wi[m - npair]
                j = pj[m] if m < npair else i
                if ver[i] != seen1[m] or ver[j] != seen2[m]:
                    seen1[m] = ver[i]
                    seen2[m] = ver[j]
                    todo[ntodo] = m
                    ntodo += 1
            if ntodo >= _PAR_MIN:
                _activate_par(todo, ntodo, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep,
                              dt, manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c)
            else:
                for t in range(ntodo):
                    m = todo[t]
                    # _activate_one's common outcome, inline: a contact too far to close within the step
                    # (the call takes a reference on each of its ~20 arrays: calling it for every
                    # contact instead took 1.09 of the kernel's time, 244 dense cylinders)
                    if m < npair:
                        if cg[m] - (sweep[pi[m]] + sweep[pj[m]]) * dt > _SWEEP_SLACK:
                            todo[t] = -1
                            continue
                    elif wg[m - npair] - _wall_closing(wi[m - npair], v, sweep, dcode, wn[m - npair]) * dt > _SWEEP_SLACK:
                        todo[t] = -1
                        continue
                    _activate_one(m, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep, dt,
                                  manifold_tol, dcode, Rp, cx, cy, lo, hi, on_p, gp_n, gp_c, gp_c2, on_w, gw_n, gw_c, scr)
            # impulse terms of the contacts whose geometry this round may have set
            for t in range(ntodo):
                m = todo[t]
                if m < 0:
                    continue
                if m < npair:
                    if on_p[m]:
                        i = pi[m]
                        j = pj[m]
                        _pair_terms(i, j, ps[m, 0], ps[m, 1], ps[m, 2], gp_c, gp_c2, gp_n, m, x, Rm, im[i], im[j],
                                    iinv, gt_p, m)
                        ev1[m] = -1
                elif on_w[m - npair]:
                    mw = m - npair
                    i = wi[mw]
                    _wall_terms(i, gw_c, gw_n, mw, x, Rm, im[i], iinv, gt_w, mw)
                    ev1[m] = -1
            # (c): a touching contact is held at its present point, where the sweeps leave it not
            # approaching; another feature of a turning body can still close the gap within the step
            # (a spinning cube's corner beside a face contact at the face centre). If the bodies
            # turn by more than half of the gap plus half the overlap bound at their bounding radii (a
            # point other than the contact point approaches by at most its distance from it, 2 r_b,
            # times the angle), its twin (row nc + m) takes the speculative test (b) with the
            # velocities of this round. The paper's suspensions turn by ~1e-3 rad a step: the test is
            # skipped.
            ntodo = 0
            for t in range(ntouch):
                m = touch[t]
                if m < npair:
                    i = pi[m]
                    j = pj[m]
                    gap = cg[m]
                else:
                    i = wi[m - npair]
                    j = i
                    gap = wg[m - npair]
                if ver[i] == tseen1[m] and ver[j] == tseen2[m]:
                    continue
                tseen1[m] = ver[i]
                tseen2[m] = ver[j]
                turn = sweep[i] - math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
                if j != i:
                    turn += sweep[j] - math.sqrt(v[j, 0] ** 2 + v[j, 1] ** 2 + v[j, 2] ** 2)
                if 2.0 * turn * dt <= gap + 0.5 * OVERLAP_BOUND_FACTOR * overlap_tol:
                    continue
                todo[ntodo] = m
                ntodo += 1
            for t in range(ntodo):
                m = todo[t]
                _activate_one(m, pi, pj, ps, cg, cn, cc, wi, wg, wn, wc, npair, kind, h, x, v, wb, Rm, sweep, dt,
                              manifold_tol, dcode, Rp, cx, cy, lo, hi, on_tp, tp_n, tp_c, tp_c2, on_tw, tw_n, tw_c, scr)
                if m < npair:
                    if on_tp[m]:
                        i = pi[m]
                        j = pj[m]
                        _pair_terms(i, j, ps[m, 0], ps[m, 1], ps[m, 2], tp_c, tp_c2, tp_n, m, x, Rm, im[i], im[j],
                                    iinv, tt_p, m)
                        ev1[nc + m] = -1
                elif on_tw[m - npair]:
                    mw = m - npair
                    i = wi[mw]
                    _wall_terms(i, tw_c, tw_n, mw, x, Rm, im[i], iinv, tt_w, mw)
                    ev1[nc + m] = -1
            nact = 0
            for m in range(nc):
                if (on_p[m] if m < npair else on_w[m - npair]):
                    act[nact] = m
                    nact += 1
            for m in range(nc):
                if (on_tp[m] if m < npair else on_tw[m - npair]):
                    act[nact] = nc + m
                    nact += 1
            applied_round = 0
            for sweep_ in range(max_sweeps):
                # restitution k in the first half of the sweeps; a set of contacts still bouncing
                # after them is a jam (a closed row with k = 1 passes blows back and forth without
                # end): the remaining sweeps are inelastic (k = 0), which settles it
                k_now = k_rest if sweeps < max_sweeps // 2 else 0.0
                applied = _gs_sweep(act, nact, ci, cj, gn, gt, v, wb, wl, Rm, im, k_now, vtol, ver, ev1, ev2, vrest)
                sweeps += 1
                applied_round += applied
                if applied == 0:
                    break
            nimp += applied_round
            if sweeps >= max_sweeps:
                # the cap holds for all rounds together: twins (c) re-tested round after round in a
                # jam kept every round at its own cap (10^4 sweeps a call in a squeezed row)
                break
            if applied_round == 0 or nnear + ntouch == 0:
                break
        # contacts still approaching after the last sweep (only if a sweep cap was hit)
        unres = 0
        if sweeps >= max_sweeps:
            vsave = v.copy()
            wsave = wb.copy()
            jam = np.zeros(npair, dtype=np.bool_)  # pairs left approaching
            grounded = np.zeros(n, dtype=np.bool_)  # bodies left approaching a wall
            for m in range(npair):
                if on_p[m] and _impulse(pi[m], pj[m], ps[m, 0], ps[m, 1], ps[m, 2], gp_c[m], gp_c2[m], gp_n[m], x,
                                        vsave, wsave, Rm, im, iinv, k_rest, vtol):
                    unres += 1
                    jam[m] = True
                if on_tp[m] and _impulse(pi[m], pj[m], ps[m, 0], ps[m, 1], ps[m, 2], tp_c[m], tp_c2[m], tp_n[m], x,
                                         vsave, wsave, Rm, im, iinv, k_rest, vtol):
                    unres += 1
                    jam[m] = True
            for m in range(nwall):
                if on_w[m] and _impulse(wi[m], -1, 0.0, 0.0, 0.0, gw_c[m], gw_c[m], gw_n[m], x, vsave, wsave, Rm, im,
                                        iinv, k_rest, vtol):
                    unres += 1
                    grounded[wi[m]] = True
                if on_tw[m] and _impulse(wi[m], -1, 0.0, 0.0, 0.0, tw_c[m], tw_c[m], tw_n[m], x, vsave, wsave, Rm, im,
                                         iinv, k_rest, vtol):
                    unres += 1
                    grounded[wi[m]] = True
            if unres > 0:
                stats[_S_LOCK] += _lock_jams(jam, grounded, pi, pj, ps, x, v, wb, Rm, mass, inertia, fixed)
                # the locked bodies' new velocities against their other contacts: inelastic sweeps
                # (every contact evaluated afresh: the lock changed velocities behind ver's back)
                wl = lab_omegas(wb, Rm)
                for t in range(2 * nc):
                    ev1[t] = -1
                for sweep_ in range(max_sweeps):
                    applied = _gs_sweep(act, nact, ci, cj, gn, gt, v, wb, wl, Rm, im, 0.0, vtol, ver, ev1, ev2, vrest)
                    nimp += applied
                    if applied == 0:
                        break
        stats[_S_IMP] += nimp
        stats[_S_SWEEP] = max(stats[_S_SWEEP], sweeps)
        stats[_S_UNRES] += unres

    # ---- overlap projection: positions, split by inverse mass; orientations too in a jam
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
    return maxdisp, lstart, ljs, lwin, 0


def resolve_collisions(bodies: Bodies, domain: Domain, params: CollisionParams, dt: float, pairs: bool = True,
                       step: int = -1, nlist: NeighbourList | None = None) -> dict:
    """Detect all particle-particle and particle-wall contacts, apply the impulses of
    Eqs. (16)-(21) (in place on ``bodies.v`` and ``bodies.wb``) and project overlaps away (in place
    on ``bodies.x``). See the module docstring for the model and the overlap bound.

    Returns stats: ``candidates`` (broad-phase pairs), ``pair_contacts`` and ``wall_contacts``
    (gap <= contact_gap), ``impulses`` (applied), ``max_overlap_before`` (largest overlap seen
    before the projection), ``max_overlap_after`` (after it; <= overlap_tol unless the projection
    was exhausted), ``sweeps``, ``projection_iters``, ``unresolved`` (contacts still approaching
    after max_sweeps), ``max_displacement`` (largest projection shift of a body), ``passes``.
    ``pairs=False`` skips the broad phase and all particle-particle contacts (walls only).
    Raises ``errors.Unstable`` (naming ``step``) when a body moves so fast that its reach per step
    spans the periodic length: the sign of a run that has blown up between guard checks.
    ``nlist``: the pair search's Verlet list, to keep between calls (time steps); None: a fresh one
    (the same result, at the cost of a new list).
    """
    n = bodies.n
    stats = np.zeros(_NSTATS)
    if n == 0:
        return _stats_dict(stats, 0)
    dcode, Rp, cx, cy, lo, hi, periodic = domain.arrays()
    if nlist is None:
        nlist = NeighbourList()
    if nlist.xref.shape[0] != n:
        nlist.xref = np.zeros((n, 3))
        nlist.meta[0] = 0.0
    passes = 0
    for p in range(4):
        maxdisp, nlist.start, nlist.js, nlist.win, status = _resolve_kernel(
            bodies.kind, bodies.h, bodies.mass, bodies.inertia, bodies.x, bodies.v, bodies.q, bodies.wb, bodies.fixed,
            dcode, Rp, cx, cy, lo, hi, periodic,
            float(params.restitution), float(params.contact_gap), bool(params.speculative), float(params.overlap_tol),
            float(params.manifold_tol), float(params.skin), int(params.max_sweeps), int(params.max_projection_iters),
            int(params.translation_iters), float(dt), p == 0, stats, bool(pairs), float(params.list_skin),
            nlist.start, nlist.js, nlist.win, nlist.xref, nlist.meta, float(params.rest_speed),
        )
        if status:
            _refuse(status, bodies, params, lo, hi, step)
        passes += 1
        # bodies pushed further than half the skin may meet pairs outside the list: rebuild it
        if maxdisp <= 0.5 * params.skin:
            break
    return _stats_dict(stats, passes)


def _refuse(status: int, bodies: Bodies, params: CollisionParams, lo, hi, step: int):
    """Raise the error of a kernel status (``_resolve_kernel`` has left the bodies untouched)."""
    a = (status - 1) % 3
    rb = bounding_radii(bodies.kind, bodies.h)
    if status <= 3:
        from ..errors import SceneError  # a ValueError; lbmpipe check applies the same rule first

        need = min_periodic_length(float(np.max(rb)), params.contact_gap, params.skin)
        raise SceneError(
            "domain", f"periodic length {hi[a] - lo[a]:g} along axis {'xyz'[a]} is shorter than two interaction "
            f"ranges in lattice spacings (2 x {need / 2:g}): a pair would interact with two images",
            f"make the domain at least {need:g} lattice spacings long along that axis, or set "
            "particles.collisions.pairs: false")
    # The geometry fits; only the speculative reach of a body moving many lattice spacings per
    # step does not. No physical suspension does that: it is a blown-up run, so report it as one
    # (the guard's status 'unstable') rather than as a bad domain.
    speed = np.linalg.norm(bodies.v, axis=1) + np.linalg.norm(bodies.wb, axis=1) * rb
    k = int(np.argmax(np.where(~bodies.fixed, speed, -1.0)))
    raise Unstable(f"particle speed {speed[k]:.3g} lattice units per step (translation plus rotation at the "
                   f"bounding radius) reaches past the periodic images", f"particle {k}", step,
                   "the fluid-particle coupling went unstable (high Mach number or a thin fluid film)",
                   "reduce numerics.dt_s, use numerics.collision: trt, or lower the concentration")


def _stats_dict(stats: np.ndarray, passes: int) -> dict:
    return {
        "candidates": int(stats[_S_CAND]),
        "pair_contacts": int(stats[_S_PAIR]),
        "wall_contacts": int(stats[_S_WALL]),
        "impulses": int(stats[_S_IMP]),
        "max_overlap_before": float(stats[_S_OVB]),
        "max_overlap_after": float(stats[_S_OVA]),
        "sweeps": int(stats[_S_SWEEP]),
        "projection_iters": int(stats[_S_PROJ]),
        "unresolved": int(stats[_S_UNRES]),
        "max_displacement": float(stats[_S_DISP]),
        "rotation_projections": int(stats[_S_ROT]),
        "locked_bodies": int(stats[_S_LOCK]),
        "passes": int(passes),
    }


class CollisionEffect(Effect):
    """Collisions as a step of the solver (``post``, after the hydrodynamic velocity update and
    before the drift): ``resolve_collisions`` on the particle system's bodies, in lattice units
    (dt = 1). With a single movable particle the pair search is skipped (walls only). Keeps the
    run's totals and the largest overlaps for the summary (``record``)."""

    phase = "post"
    record_key = "collisions"

    def __init__(self, system, domain: Domain, params: CollisionParams, pairs: bool = True):
        self.system = system
        self.domain = domain
        self.params = params
        self.pairs = system.n > 1 and pairs
        self.name = ("collisions: impulses + overlap removal" if self.pairs else
                     "collisions: walls only (pairs switched off)" if system.n > 1 else
                     "collisions: walls only (one particle)")
        self.totals = {"calls": 0, "impulses": 0, "pair_contacts": 0, "wall_contacts": 0, "unresolved": 0,
                       "rotation_projections": 0, "locked_bodies": 0,
                       "max_overlap_before_lu": 0.0, "max_overlap_after_lu": 0.0}
        self.last: dict = {}
        self.nlist = NeighbourList()

    def __call__(self, sim) -> None:
        st = resolve_collisions(self.system.bodies, self.domain, self.params, 1.0, pairs=self.pairs,
                                step=sim.step_count, nlist=self.nlist)
        t = self.totals
        t["calls"] += 1
        for k in ("impulses", "pair_contacts", "wall_contacts", "unresolved"):
            t[k] += st[k]
        # .get: a checkpoint from before the rotating projection has no such total
        t["rotation_projections"] = t.get("rotation_projections", 0) + st["rotation_projections"]
        t["locked_bodies"] = t.get("locked_bodies", 0) + st["locked_bodies"]
        t["max_overlap_before_lu"] = max(t["max_overlap_before_lu"], st["max_overlap_before"])
        t["max_overlap_after_lu"] = max(t["max_overlap_after_lu"], st["max_overlap_after"])
        self.last = st

    def record(self) -> dict:
        """Summary entry: parameters, pair search on/off, totals over the run."""
        p = self.params
        return {"enabled": True, "pairs": self.pairs, "restitution": p.restitution, "contact_gap_lu": p.contact_gap,
                "overlap_tol_lu": p.overlap_tol, "overlap_bound_lu": p.overlap_bound, **self.totals}
