"""Cover and uncover: the remap after a move, with its momentum accounting (lattice units).

After a move, for each node whose owner changed:

* a fluid node now covered by particle ``k`` leaves the fluid; its momentum ``j = sum_i f_i e_i``
  (post-collision) goes to ``k``: ``P_k += j``, ``L_P += r x j``;
* a node of particle ``k`` that becomes fluid is refilled (``refill``: the equilibrium Eq. (3) at
  the local surface velocity and its neighbours' density; or ``refill_extrapolated``, with the
  neighbours' non-equilibrium stress: ``REFILLS``, the scene's ``numerics.refill``); the particle
  pays the momentum written, ``j = rho u_b``: ``P_k -= j``, ``L_P -= r x j``;
* a node passed from one particle to another holds no fluid: nothing is exchanged.

``(P, L_P)`` enters the next implicit update (``implicit``), so fluid + particles conserve total
momentum exactly (``ParticleSystem.total_momentum`` counts the impulse not yet applied). Mass is
not conserved (``mass_correction``).

Rules for a node several shapes cover: a fixed particle keeps its nodes; a node keeps its owner
while the owner still covers it; else the particle that entered it in this move if it covers it,
else the first covering particle in ``all_ids`` order (deterministic). Wall beats particle.

The remap is serial over the owner changes: their order fixes the order of the link lists and of
the impulse sums, so results do not depend on the thread count.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .links import set_owners
from .nodes import FLUID, WALL, decode
from .refill import fill_uncovered
from .refill_extrapolated import fill_extrapolated


class RemapState(NamedTuple):
    """Node state and buffers of the remap.

    ``count`` (nodes,) int16: particle shapes containing each node; ``touched`` (nodes,) bool,
    False between moves; ``acq`` (nodes,) int32: the particle that entered the node in this move
    (-1 between moves); ``touch_list``, ``unc_list``, ``unc_old`` (cap,) int64: the touched nodes,
    the uncovered nodes and their former owners; scratch per touched node: ``new_own`` (cap,) int64,
    ``jb`` (cap, 3) the covered momentum, ``ub`` (cap, 6) ``(rho u_b, r)`` of an uncovered node.
    ``cap`` bounds the nodes one move can touch (twice the moved particles' box volumes)."""

    count: np.ndarray
    touched: np.ndarray
    acq: np.ndarray
    touch_list: np.ndarray
    unc_list: np.ndarray
    unc_old: np.ndarray
    new_own: np.ndarray
    jb: np.ndarray
    ub: np.ndarray


@njit(cache=True, _nrt=False)
def _covers(k, node, rect, run_off, z1, z2, dims, az, periodic):
    """Does particle ``k``'s run set contain memory node ``node``?"""
    ny = dims[1]
    a, b, zi = decode(node, ny, az)
    ca = a - rect[k, 0]
    cb = b - rect[k, 1]
    if periodic[0]:
        ca %= dims[0]
    if periodic[1]:
        cb %= dims[1]
    if ca < 0 or ca >= rect[k, 2] or cb < 0 or cb >= rect[k, 3]:
        return False
    c = run_off[k] + ca * rect[k, 3] + cb
    lo = z1[c]
    hi = z2[c]
    if lo > hi:
        return False
    if periodic[2]:
        return (zi - lo) % dims[2] <= hi - lo
    return lo <= zi <= hi


@njit(cache=True)
def _settle_owners(nt, all_ids, R, owner, f2, S, G):
    """New owner of each touched node (module docstring rules) and, for a fluid node a particle
    covers, its momentum ``j = sum_i f_i e_i`` into ``jb``. The owner map is not changed here, so
    the nodes are independent: a loop with no other work between the scattered reads of the
    populations, which then overlap."""
    run_off, rect, z1, z2 = R
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    Q = e.shape[0]
    for t in range(nt):
        node = touch_list[t]
        old = owner[node]
        new = FLUID
        if count[node] > 0:
            if old >= 0 and _covers(old, node, rect, run_off, z1, z2, dims, az, periodic):
                new = old
            else:
                cand = acq[node]
                if cand >= 0 and _covers(cand, node, rect, run_off, z1, z2, dims, az, periodic):
                    new = cand
                else:
                    for j in range(all_ids.shape[0]):
                        kk = all_ids[j]
                        if _covers(kk, node, rect, run_off, z1, z2, dims, az, periodic):
                            new = kk
                            break
                    if new == FLUID:  # a count without a covering shape cannot happen; trust the shapes
                        count[node] = 0
        acq[node] = -1
        new_own[t] = new
        if old == FLUID and new >= 0:
            jx = 0.0
            jy = 0.0
            jz = 0.0
            for i in range(Q):
                fv = f2[i, node]
                jx += e[i, 0] * fv
                jy += e[i, 1] * fv
                jz += e[i, 2] * fv
            jb[t, 0] = jx
            jb[t, 1] = jy
            jb[t, 2] = jz


@njit(cache=True)
def _count_changes(ids, C, owner, S):
    # coverage counts of the changed nodes; each touched node listed once, in change order
    chg_off, chg_node, chg_d, chg_n = C
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    nt = 0
    for m in range(ids.shape[0]):
        k = ids[m]
        for c in range(chg_off[m], chg_off[m] + chg_n[m]):
            node = chg_node[c]
            if owner[node] == WALL:
                continue
            d = chg_d[c]
            count[node] += d
            if d > 0:
                acq[node] = k
            if not touched[node]:
                touched[node] = True
                touch_list[nt] = node
                nt += 1
    return nt


@njit(cache=True)
def _change_owners(nt, x, owner, imp, moved, S, G, L):
    # Serial, in the order of the touched list: the owner changes append links, and the impulse
    # sums keep one order (results independent of the thread count). The impulses depend on the
    # old owners only, so they come first, then the owner changes in the same order.
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    n_cov = 0
    n_unc = 0
    for t in range(nt):
        node = touch_list[t]
        old = owner[node]
        new = new_own[t]
        if new == old:
            continue
        if old == FLUID:
            # a fluid node swallowed: its momentum goes to the particle, r its minimum-image
            # vector from the centre
            r0 = origin[0] + node // (ny * az) - x[new, 0]
            r1 = origin[1] + (node // az) % ny - x[new, 1]
            r2 = origin[2] + node % az - x[new, 2]
            if periodic[0]:
                r0 -= nx * math.floor(r0 / nx + 0.5)
            if periodic[1]:
                r1 -= ny * math.floor(r1 / ny + 0.5)
            if periodic[2]:
                r2 -= nz * math.floor(r2 / nz + 0.5)
            jx = jb[t, 0]
            jy = jb[t, 1]
            jz = jb[t, 2]
            imp[new, 0] += jx
            imp[new, 1] += jy
            imp[new, 2] += jz
            moved[0] += jx
            moved[1] += jy
            moved[2] += jz
            imp[new, 3] += r1 * jz - r2 * jy
            imp[new, 4] += r2 * jx - r0 * jz
            imp[new, 5] += r0 * jy - r1 * jx
            n_cov += 1
        elif new == FLUID:
            unc_list[n_unc] = node
            unc_old[n_unc] = old
            n_unc += 1
    set_owners(nt, touch_list, new_own, owner, x, G, L)
    return n_cov, n_unc


@njit(cache=True)
def _uncovered_impulse(n_unc, unc_old, ub, imp, moved):
    # the particle pays the momentum put into its uncovered nodes, in list order
    for u in range(n_unc):
        k = unc_old[u]
        px = ub[u, 0]
        py = ub[u, 1]
        pz = ub[u, 2]
        imp[k, 0] -= px
        imp[k, 1] -= py
        imp[k, 2] -= pz
        moved[0] -= px
        moved[1] -= py
        moved[2] -= pz
        imp[k, 3] -= ub[u, 4] * pz - ub[u, 5] * py
        imp[k, 4] -= ub[u, 5] * px - ub[u, 3] * pz
        imp[k, 5] -= ub[u, 3] * py - ub[u, 4] * px


@njit(cache=True)
def _owners_and_covered(ids, C, all_ids, R, x, owner, f2, imp, moved, G, L, S):
    # the phases before the refill: coverage counts, new owners, owner changes with their links
    # and the covered impulses; returns (n_touched, n_covered, n_uncovered)
    nt = _count_changes(ids, C, owner, S)
    _settle_owners(nt, all_ids, R, owner, f2, S, G)
    n_cov, n_unc = _change_owners(nt, x, owner, imp, moved, S, G, L)
    return nt, n_cov, n_unc


@njit(cache=True)
def _uncovered_and_clear(nt, n_unc, imp, moved, S):
    # the phases after the refill: the uncovered impulses, then the touched marks cleared
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    _uncovered_impulse(n_unc, unc_old, ub, imp, moved)
    for t in range(nt):
        touched[touch_list[t]] = False


def apply_changes(ids, C, all_ids, R, x, v, om, owner, f2, lat, imp, moved, G, L, S, refill=fill_uncovered):
    """Apply the coverage changes of a move and settle the owners (module docstring): momentum of
    covered nodes to the particle, uncovered nodes refilled by ``refill``, links updated with each
    owner. ``moved`` (3,) receives the momentum that left the fluid. Returns
    ``(n_covered, n_uncovered)``.

    Serial, in phases that keep the scattered accesses to ``f`` in tight loops of independent
    nodes (their cache misses overlap): coverage counts; new owners and the covered nodes'
    momentum; owner changes with their links and the covered impulses (in touch order); refill of
    the uncovered nodes; their impulses (in list order). Running the node phases in parallel
    gained nothing measurable and cost much on a loaded machine (each parallel region waits for
    its slowest thread).

    ``refill`` is the refill kernel the scene chose (``REFILLS``), called between two compiled
    halves (a compiled function taking another as an argument is not cached by numba).

    Inputs: ``ids`` (M,) the moved particles and ``C`` (``RunChanges``) their changes; ``all_ids``
    (N,) every particle, fixed ones first (the tie-break order); ``R`` (``Runs``) the runs after
    the move; ``x``, ``v``, ``om`` (N, 3) centres (unwrapped, as the runs), velocities, lab angular
    velocities; ``owner`` (nodes,) int32; ``f2`` (Q, nodes) post-collision populations of the new
    time; ``lat`` (``LatticeRef``); ``imp`` (N, 6) impulses, added to; ``moved`` (3,) added to;
    ``G`` (``Grid``), ``L`` (``LinkLists``); ``S`` (``RemapState``). Outputs: ``S.count``,
    ``owner``, the link lists and their marks, ``f2`` of the uncovered nodes, ``imp``, ``moved``.
    Postconditions: every node's owner follows the rules above from the runs ``R``; ``S.touched``
    all False and ``S.acq`` all -1 again; the impulse of an uncovered node is the momentum the
    refill wrote (``ub``)."""
    nt, n_cov, n_unc = _owners_and_covered(ids, C, all_ids, R, x, owner, f2, imp, moved, G, L, S)
    refill(n_unc, S.unc_list, S.unc_old, x, v, om, owner, S.touched, f2, lat, S.ub, G)
    _uncovered_and_clear(nt, n_unc, imp, moved, S)
    return n_cov, n_unc


#: the refill kernels by their scene name (``numerics.refill``), one signature (``refill``)
REFILLS = {"equilibrium": fill_uncovered, "extrapolated": fill_extrapolated}


@njit(cache=True)
def wrap_positions(ids, x, lo, G, R, L):
    """Bring centres back into the periodic box; shift their runs and link coordinates by the same
    whole number of periods.

    Inputs: ``ids`` (M,) the moved particles; ``x`` (N, 3) their centres, in place; ``lo`` (3,) the
    lower edge of the periodic box (``origin - 1/2``); ``G`` (``Grid``); ``R`` (``Runs``) and
    ``L`` (``LinkLists``) shifted in place. Postcondition: ``lo <= x < lo + dims`` along every
    periodic axis, and runs and link coordinates describe the same nodes about the new centre."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    run_off, rect, z1, z2 = R
    lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg = L
    for m in range(ids.shape[0]):
        k = ids[m]
        for d in range(3):
            if not periodic[d]:
                continue
            per = float(dims[d])
            s = math.floor((x[k, d] - lo[d]) / per)
            if s == 0:
                continue
            x[k, d] -= s * per
            shift = int(s) * dims[d]
            if d < 2:
                rect[k, d] -= shift
            else:
                for c in range(run_off[k], run_off[k] + rect[k, 2] * rect[k, 3]):
                    z1[c] -= shift
                    z2[c] -= shift
            for i in range(1, lbase.shape[1]):
                for pos in range(lbase[k, i], lbase[k, i] + lcnt[k, i]):
                    LC[pos, d] -= shift
