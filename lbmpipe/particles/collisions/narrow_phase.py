"""The pair search and the narrow phase of one collision step: the Verlet list kept between
calls, the candidate pairs taken from it, every pair's signed gap, normal and contact point, and
the wall contacts of every body near a wall (geometry from ``lbmpipe.particles.contact``).

Only a touching contact (gap ``<= contact_gap``) needs its exact geometry. Gaps beyond
``contact_gap`` may come back as lower bounds (> contact_gap), and GJK stops early on them:
nothing in the step tells them from the exact gap. A wider contact within ``reach`` is only
tested for a speculative contact (``toi``), which looks at the end of the step (the gap serves
as a bound there); the projection re-measures whatever its displacement bound says might
overlap. Lattice units: lengths in lattice spacings.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..contact import (WS_HINT, WS_WON, body_contact_ws, list_displacement, listed_slots, neighbour_list, new_scratch,
                       pipe_wall_contact, plane_wall_contact, support3)
from ..shapes import CYLINDER, SPHERE
from ..collision_params import PIPE
from .bundles import _S_CAND, _S_OVB, _S_PAIR, _S_WALL, Contacts, VerletArrays


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



# pairs (or bodies) per parallel work item, each of which allocates its scratch: 8 made ~740
# allocations a step with 244 dense cylinders; 32 runs the narrow phase in 0.94-0.95 of that time
# on 1 thread and 0.98 on 2 (same bits), and ~47 items still balance the threads
_CHUNK = 32
# contact tests (narrow phase: candidate pairs) run in parallel only in batches at least this
# large (a parallel region costs ~10 us on an idle machine, far more on a loaded one)
_PAR_MIN_PAIRS = 256


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
    """Signed gap of one body (shape code kind, half sizes h, centre x, rotation R) to the wall
    of a stored contact, the wall named by that contact's normal ``wn`` (pipe: the pipe wall;
    box: the plane whose axis wn points along, on its side); normal and point into nrm and c.
    Lattice spacings. Used to re-measure a wall contact after the body moved."""
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


@njit(cache=True)
def step_pairs(x, rb, margin, lo, hi, periodic, list_skin, pairs, V):
    """Stage 1 of the step: the candidate pairs of this call, from the Verlet list ``V``
    (``VerletArrays``), which is rebuilt first if it may miss a pair within ``margin``.

    Inputs: centres x (n, 3), bounding radii rb (n,), the interaction margin (lattice spacings:
    ``reach + skin``), the bounds lo, hi and periodic flags of the domain, the list's extra margin
    ``list_skin``, ``pairs`` (False: no pair search, walls only). Outputs: (pi, pj, ps, pk, V):
    bodies i < j (npair,), minimum-image shift ps (npair, 3) of body j, list slot pk (npair,) of
    each pair, and the list, a new one if rebuilt (its ``xref`` and ``meta`` updated in place).
    Invariant: the pairs and their order are those of a cell scan at ``margin`` (``listed_slots``),
    whether the list is fresh or kept, so keeping it changes no result. The list serves while it
    was built for ``margin + 2 * (largest displacement since)``; a rebuild carries each kept pair's
    cylinder hint over (``_carry_hints``)."""
    lstart, ljs, lwin, lxref, lmeta = V
    if pairs:
        # the Verlet list (lstart, ljs: neighbour_list), built at lxref for the margin lmeta[0]
        # (0: none yet; lmeta[1]: builds), serves while it holds every pair within margin
        if not (lmeta[0] > 0.0 and lxref.shape[0] == x.shape[0]
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
    return pi, pj, ps, pk, VerletArrays(lstart, ljs, lwin, lxref, lmeta)


@njit(cache=True)
def measure_contacts(B, T, D, P, pi, pj, ps, pk, lwin, margin, reach, stats):
    """Stage 2 of the step: the narrow phase of the pairs and the walls (``_narrow_phase``).

    Inputs: bodies B (``BodyArrays``) and their terms T (``BodyTerms``: Rm, rb), domain D
    (``DomainArrays``), parameters P (``StepParams``: contact_gap, manifold_tol), the pairs of
    ``step_pairs`` and the list's hints ``lwin`` (updated in place with this step's winners),
    ``margin`` (a wall is looked at if a body's bounding sphere comes within it) and ``reach``
    (gaps up to it are measured exactly at the pipe wall). Output: ``Contacts``, walls in body
    order (then axis, side). Gaps ``<= contact_gap`` are exact; wider ones may be lower bounds.
    Stats: adds the candidate pairs and the touching pair and wall contacts; keeps the largest
    overlap seen before the impulses (``max_overlap_before``). Every pair and body writes only its
    own rows, so the result does not depend on the thread count."""
    kind, h, x = B.kind, B.h, B.x
    Rm, rb = T.Rm, T.rb
    dcode, Rp, cx, cy, lo, hi, periodic = D
    contact_gap = P.contact_gap
    n = x.shape[0]
    npair = pi.shape[0]
    cg = np.empty(npair)
    cn = np.empty((npair, 3))
    cc = np.empty((npair, 3))
    slots = 1 if dcode == PIPE else 6
    use = np.zeros((n, slots), dtype=np.bool_)
    sg = np.empty((n, slots))
    sn = np.empty((n, slots, 3))
    sc = np.empty((n, slots, 3))
    _narrow_phase(kind, h, x, Rm, rb, pi, pj, ps, pk, lwin, contact_gap, P.manifold_tol, cg, cn, cc,
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
    return Contacts(pi, pj, ps, pk, cg, cn, cc, wi, wg, wn, wc)
