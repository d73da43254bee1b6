"""Jams: contacts still approaching when the impulse sweeps reach their cap, and the perfectly
inelastic lock that ends them.

The last half of the sweeps are inelastic, which settles the jams that bounce without end at
``k = 1``; a jam still approaching at the cap is locked (``_lock_jams``,
``stats["locked_bodies"]``): the bodies its approaching pairs join move on as one rigid body with
their linear and angular momentum (a cluster with a body approaching a wall stops), so none of
its contacts approaches in the drift, and inelastic sweeps then take up what the locked bodies'
new velocities do to their other contacts (a row of cubes spinning at 0.09 rad a step jammed in
a channel, and a dense box at ``contact_gap`` 1.0, turned 0.17-0.22 lu into each other without
it; the box blew up). Lattice units.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .bundles import _S_LOCK
from .impulse import _gs_sweep, _impulse, lab_omegas


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
def settle_unresolved(act, nact, ver, ev1, ev2, vtol, B, T, C, P, R, stats):
    """End of the impulse stage when the sweeps reached their cap: find the contacts still
    approaching (faster than ``vtol``) on copies of the velocities, lock the jams they form
    (``_lock_jams``) and sweep the active rows ``act[:nact]`` again, inelastically, until none
    approaches or ``max_sweeps``.

    Inputs: the sweep state of ``impulse_rounds`` (``act``, ``nact``, the impulse counts ``ver``
    and last evaluations ``ev1``, ``ev2``, all updated in place), bodies B (``BodyArrays``: v, wb
    changed in place by the lock and the sweeps; mass, inertia, fixed read), terms T, contacts C,
    parameters P (``StepParams``: k_rest, vrest, max_sweeps), impulse rows R (``ImpulseRows``).
    Output: (contacts left approaching, impulses of the sweeps after the lock). Stats: bodies
    locked. The lock keeps each cluster's linear and angular momentum and makes no energy."""
    x, v, wb, mass, inertia, fixed = B.x, B.v, B.wb, B.mass, B.inertia, B.fixed
    Rm, im, iinv = T.Rm, T.im, T.iinv
    pi, pj, ps, wi = C.pi, C.pj, C.ps, C.wi
    k_rest, vrest, max_sweeps = P.k_rest, P.vrest, P.max_sweeps
    gn, gt, ci, cj = R.gn, R.gt, R.ci, R.cj
    on_p, gp_n, gp_c, gp_c2 = R.on_p, R.gp_n, R.gp_c, R.gp_c2
    on_tp, tp_n, tp_c, tp_c2 = R.on_tp, R.tp_n, R.tp_c, R.tp_c2
    on_w, gw_n, gw_c, on_tw, tw_n, tw_c = R.on_w, R.gw_n, R.gw_c, R.on_tw, R.tw_n, R.tw_c
    n = x.shape[0]
    npair = pi.shape[0]
    nwall = wi.shape[0]
    nc = npair + nwall
    unres = 0
    nimp = 0
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
        for _sweep in range(max_sweeps):
            applied = _gs_sweep(act, nact, ci, cj, gn, gt, v, wb, wl, Rm, im, 0.0, vtol, ver, ev1, ev2, vrest)
            nimp += applied
            if applied == 0:
                break
    return unres, nimp
