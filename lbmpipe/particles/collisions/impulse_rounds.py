"""The impulse stage of a collision step: which contacts take part, and the rounds of
speculative tests and Gauss-Seidel sweeps of Eqs. (16)-(21) that resolve them.

When is a contact treated (``CollisionParams``):
- touching: the signed gap is ``<= contact_gap``. The contact takes part in the impulse sweeps
  from the start with its present point and normal, and receives an impulse whenever it
  approaches, including when it recedes at first and an impulse elsewhere in the step turns it
  around (a row of touching spheres passes a blow down the row within one step);
- speculative (``speculative=True``, default): a contact wider than ``contact_gap`` whose two
  bodies, moving freely at their present velocities and angular velocities, would overlap by the
  end of the step ``dt``; the impulse acts at the time of impact (``toi``). Touching contacts
  that do not approach at the start of a step skip this test: the sweeps take their geometry
  from the narrow phase;
- touching and turning (with ``speculative``): a touching contact whose bodies turn by more than
  half of its gap plus half the overlap bound at their bounding radii within the step gets a twin
  that takes the speculative test above: the contact point holds only where it is, and a spinning
  cube's corner beside a face contact closes the gap elsewhere (a pair that overlaps already, by up
  to ``overlap_tol``, finds that overlap at t = 0 and gets its present contact: a jam's turning
  corner is then caught by the lock of ``jam``, point 3 of the overlap bound in ``step``);
- with several contacts the impulses are applied contact by contact (Gauss-Seidel) in repeated
  sweeps until none approaches; as impulses change velocities, the speculative tests are then
  repeated (a body knocked into a third one within the step) until a round applies no impulse
  (both loops capped by ``max_sweeps``). The first half of the sweeps use the restitution ``k``,
  the rest ``k = 0``: contacts still bouncing then are a jam (a closed row at ``k = 1`` passes the
  blows back and forth without end), which inelastic sweeps settle.

Contacts still approaching when the sweeps reach their cap are a jam (``jam``). Lattice units:
lengths in lattice spacings, velocities in lattice spacings per step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..collision_params import OVERLAP_BOUND_FACTOR
from .bundles import _S_IMP, _S_SWEEP, _S_UNRES, ImpulseRows
from .impulse import _NG, _gs_sweep, _pair_terms, _wall_terms, lab_omegas
from .jam import settle_unresolved
from .toi import _SWEEP_SLACK, _activate_one, _activate_par, _test_scratch, _wall_closing

# approach speeds below 1e-12 of the fastest are round-off; this floor keeps bodies at rest
_VTOL_FLOOR = 1.0e-30
# speculative tests run in parallel only in batches at least this large (a parallel region
# costs ~10 us on an idle machine, far more on a loaded one)
_PAR_MIN = 4096


@njit(cache=True)
def impulse_rows(B, T, C, P):
    """The impulse rows of the step's contacts (``ImpulseRows``), with the touching contacts (a)
    switched on and their terms computed.

    Inputs: bodies B (``BodyArrays``: x), terms T (``BodyTerms``: Rm, im, iinv), contacts C
    (``Contacts``), parameters P (``StepParams``: contact_gap). Output: rows for the nc = npair +
    nwall contacts and their nc twins: normals and bodies copied from C, points from C (the
    speculative tests overwrite those of the contacts they switch on), twins off. Invariant: a
    row's terms are set whenever it is on (positions and orientations do not change while
    impulses are applied, so a contact's terms serve all its sweeps)."""
    x = B.x
    Rm, im, iinv = T.Rm, T.im, T.iinv
    pi, pj, ps, cg, cn, cc, wi, wg, wn, wc = C.pi, C.pj, C.ps, C.cg, C.cn, C.cc, C.wi, C.wg, C.wn, C.wc
    npair = pi.shape[0]
    nwall = wi.shape[0]
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
    on_p = cg <= P.contact_gap
    on_w = wg <= P.contact_gap
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
    return ImpulseRows(gn, gt, ci, cj, gp_n, gw_n, tp_n, tw_n, gt_p, gt_w, tt_p, tt_w, gp_c, gp_c2, gw_c, tp_c, tp_c2,
                       tw_c, on_p, on_w, on_tp, on_tw)


@njit(cache=True)
def _speculative_tests(near, nnear, seen1, seen2, ver, todo, scr, ev1, B, T, C, D, P, R):
    """Test (b) of one round: the wider contacts ``near[:nnear]`` (pairs, then walls as npair + m)
    with a body that received an impulse since their last test (``ver`` against ``seen1``,
    ``seen2``: the test depends only on the two bodies' velocities) are tested for a speculative
    contact (``toi._activate_one``; in parallel for large batches), and the terms of those it
    switches on are computed, their last evaluation (``ev1``) reset. ``todo``: scratch (the
    contacts tested, -1 for those skipped early). Never switches a contact off."""
    kind, h, x, v, wb = B.kind, B.h, B.x, B.v, B.wb
    Rm, im, iinv, sweep = T.Rm, T.im, T.iinv, T.sweep
    pi, pj, ps, cg, cn, wi, wg, wn = C.pi, C.pj, C.ps, C.cg, C.cn, C.wi, C.wg, C.wn
    dcode, Rp, cx, cy, lo, hi = D.dcode, D.Rp, D.cx, D.cy, D.lo, D.hi
    dt, manifold_tol = P.dt, P.manifold_tol
    on_p, gp_n, gp_c, gp_c2, gt_p = R.on_p, R.gp_n, R.gp_c, R.gp_c2, R.gt_p
    on_w, gw_n, gw_c, gt_w = R.on_w, R.gw_n, R.gw_c, R.gt_w
    npair = pi.shape[0]
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
        _activate_par(todo, ntodo, pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep,
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
            _activate_one(m, pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep, dt,
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


@njit(cache=True)
def _turning_tests(touch, ntouch, tseen1, tseen2, ver, todo, scr, ev1, B, T, C, D, P, R):
    """Test (c) of one round. A touching contact is held at its present point, where the sweeps
    leave it not approaching; another feature of a turning body can still close the gap within
    the step (a spinning cube's corner beside a face contact at the face centre). If the bodies
    of a touching contact ``touch[:ntouch]`` turn by more than half of the gap plus half the
    overlap bound at their bounding radii (a point other than the contact point approaches by at
    most its distance from it, 2 r_b, times the angle), its twin (row nc + m) takes the
    speculative test (b) with the velocities of this round; if it switches on, its terms are
    computed and its last evaluation reset. Only contacts with a body that received an impulse
    since their last test (``tseen1``, ``tseen2``) are looked at. The paper's suspensions turn
    by ~1e-3 rad a step: the test is skipped. ``todo``: scratch."""
    kind, h, x, v, wb = B.kind, B.h, B.x, B.v, B.wb
    Rm, im, iinv, sweep = T.Rm, T.im, T.iinv, T.sweep
    pi, pj, ps, cg, cn, wi, wg, wn = C.pi, C.pj, C.ps, C.cg, C.cn, C.wi, C.wg, C.wn
    dcode, Rp, cx, cy, lo, hi = D.dcode, D.Rp, D.cx, D.cy, D.lo, D.hi
    dt, manifold_tol, overlap_tol = P.dt, P.manifold_tol, P.overlap_tol
    on_tp, tp_n, tp_c, tp_c2, tt_p = R.on_tp, R.tp_n, R.tp_c, R.tp_c2, R.tt_p
    on_tw, tw_n, tw_c, tt_w = R.on_tw, R.tw_n, R.tw_c, R.tt_w
    npair = pi.shape[0]
    nc = npair + wi.shape[0]
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
        _activate_one(m, pi, pj, ps, cg, cn, wi, wg, wn, npair, kind, h, x, v, wb, Rm, sweep, dt,
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


@njit(cache=True)
def _active_rows(R, nc, act):
    """The rows switched on, into ``act``: contacts 0 .. nc - 1 (pairs, then walls), then the
    twins nc + m. Returns their number."""
    on_p, on_w, on_tp, on_tw = R.on_p, R.on_w, R.on_tp, R.on_tw
    npair = on_p.shape[0]
    nact = 0
    for m in range(nc):
        if (on_p[m] if m < npair else on_w[m - npair]):
            act[nact] = m
            nact += 1
    for m in range(nc):
        if (on_tp[m] if m < npair else on_tw[m - npair]):
            act[nact] = nc + m
            nact += 1
    return nact


@njit(cache=True)
def impulse_rounds(B, T, C, D, P, vmax, reach, stats):
    """Stage 3 of the step: the impulses of Eqs. (16)-(21), Gauss-Seidel over the active contacts.

    A contact is active (a) if it touches now (gap <= contact_gap): with its present point and
    normal, from the start; the sweeps give it an impulse whenever it approaches, so a touching
    contact that recedes now joins in as soon as an impulse elsewhere turns it around; or, with
    ``spec``, (b) if it is wider (up to ``reach``) but the two bodies, moving freely at the present
    velocities, would overlap by the end of the step: the impulse uses the contact normal at the
    time of impact and each body's lever arm there (``toi``). This catches corners turning into
    contact as well as approaching faces; (c) the twin of a touching contact whose bodies turn
    fast (``_turning_tests``). Impulses change velocities, so the predictions (b), (c) are redone
    until a round applies none. The test of a contact depends only on its two bodies'
    velocities, so a round re-tests only the contacts with a body that received an impulse since
    their last test (the others would give the same answer again).

    Inputs: bodies B (``BodyArrays``: v, wb changed in place), terms T (``BodyTerms``), contacts
    C, domain D, parameters P (``StepParams``), ``vmax`` (the fastest point speed of a movable
    body, lattice spacings per step), ``reach`` (the widest gap that can close within the step).
    Positions and orientations are not changed. Postcondition: no active contact approaches
    faster than round-off (``vtol``), unless the sweeps reached ``max_sweeps`` over all rounds;
    then the contacts left approaching are locked (``jam.settle_unresolved``). Stats: impulses,
    the largest number of sweeps, contacts left unresolved, bodies locked. Momentum is conserved
    by every impulse (walls and fixed bodies aside)."""
    v, wb = B.v, B.wb
    Rm, im = T.Rm, T.im
    cg, wg = C.cg, C.wg
    contact_gap, spec, max_sweeps, k_rest, vrest = P.contact_gap, P.spec, P.max_sweeps, P.k_rest, P.vrest
    n = v.shape[0]
    npair = cg.shape[0]
    nwall = wg.shape[0]
    nc = npair + nwall
    R = impulse_rows(B, T, C, P)
    on_p, on_w, gn, gt, ci, cj = R.on_p, R.on_w, R.gn, R.gt, R.ci, R.cj
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
    for _round in range(max_sweeps):
        _speculative_tests(near, nnear, seen1, seen2, ver, todo, scr, ev1, B, T, C, D, P, R)
        _turning_tests(touch, ntouch, tseen1, tseen2, ver, todo, scr, ev1, B, T, C, D, P, R)
        nact = _active_rows(R, nc, act)
        applied_round = 0
        for _sweep in range(max_sweeps):
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
        unres, nlock = settle_unresolved(act, nact, ver, ev1, ev2, vtol, B, T, C, P, R, stats)
        nimp += nlock
    stats[_S_IMP] += nimp
    stats[_S_SWEEP] = max(stats[_S_SWEEP], sweeps)
    stats[_S_UNRES] += unres
