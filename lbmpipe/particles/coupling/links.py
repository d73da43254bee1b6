"""Boundary links between fluid nodes and particle nodes, kept up to date with the owner map
(lattice units).

A boundary link joins a fluid node ``x`` to a particle node ``s = x + e_i``; the set of links is a
function of the owner map alone, ``{(x, s, i): owner[s] >= 0, owner[x] = FLUID}``. Each particle
keeps its links in one list per direction, a 16-byte record per link (fluid node, particle node,
and the particle node's lattice coordinates unwrapped in the particle's frame, which give the link
midpoint ``x + e_i/2`` exactly). Owners change only in ``set_owners``, which appends the links an
owner change creates (a node joining a particle: links from its fluid neighbours; a node becoming
fluid: links into its particle neighbours) and marks the node as changed. Links an owner change
ends are deleted lazily: each step's first pass over a list (``ladd``) swap-removes the entries
with ``owner[s] != k`` or ``owner[x] != FLUID``, testing only links with a node marked since the
previous pass (no other link can have died); the marks are cleared after the passes
(``clear_changed``). So the live entries always equal the definition and nothing searches for
links; a move costs about a thousand owner changes per step for the paper's 115 cubes. Fixed and
free particles share the lists.

Layout (``LinkLists``): records of 8 + 8 bytes in two arrays. The link passes are bound by
fetching the lists after the sweep evicted them, so their size and the number of streams are their
cost (measured: int64 nodes and float64 midpoints in five arrays took 3x longer to read). The node
indices are stored, not recomputed from the coordinates: the gather of ``f*`` overlaps its cache
misses only while the loop that issues them stays a few instructions per link (measured: 3.5x
slower with the indices computed in the loop).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .nodes import FLUID, WALL


class LinkLists(NamedTuple):
    """The link lists of all particles and the change marks (a tuple the kernels unpack).

    Entry ``pos = lbase[p, i] + j`` for ``j < lcnt[p, i]`` (``lcap[p, i]`` room; (N, Q) int64 each)
    is a link of particle ``p`` in direction ``i`` from fluid node ``LN[pos, 0]`` into particle node
    ``LN[pos, 1]`` ((total, 2) int32), whose lattice coordinates, unwrapped in the particle's frame,
    are ``c = LC[pos, :3]`` ((total, 4) int16; the link midpoint is ``origin + c - e_i/2``, exact in
    floating point). An entry is live while the particle node belongs to ``p`` and the fluid node
    is FLUID. ``lerr`` (1,) counts links dropped for lack of room (never expected); ``nown`` (N,)
    the nodes each particle owns. ``chg`` (nodes,) uint8 marks the nodes whose owner changed since
    the last link passes, the first ``len(chg_list)`` of them listed in ``chg_list``, ``nchg[0]``
    in all: only a link with a marked node can be dead, so the passes read the owner map (a large
    array, scattered reads) for those links alone."""

    lbase: np.ndarray
    lcap: np.ndarray
    lcnt: np.ndarray
    LN: np.ndarray
    LC: np.ndarray
    lerr: np.ndarray
    nown: np.ndarray
    chg: np.ndarray
    chg_list: np.ndarray
    nchg: np.ndarray


@njit(cache=True, _nrt=False)
def _compact(p, i, owner, L):
    # drop the dead entries of list (p, i)
    lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg = L
    b0 = lbase[p, i]
    wpos = b0
    for pos in range(b0, b0 + lcnt[p, i]):
        if owner[LN[pos, 1]] == p and owner[LN[pos, 0]] == FLUID:
            for d in range(2):
                LN[wpos, d] = LN[pos, d]
            for d in range(3):
                LC[wpos, d] = LC[pos, d]
            wpos += 1
    lcnt[p, i] = wpos - b0


@njit(cache=True)
def set_owners(n, nodes, news, owner, x, G, L):
    """Give ``nodes[t]`` to ``news[t]`` (a particle or FLUID), ``t < n``, in order, and append
    the links each change creates, so that the live entries of the lists are exactly
    ``{(x, s, i): owner[s] >= 0, owner[x] = FLUID}``; links a change ends die with it (lazy
    deletion; the node is marked in ``chg``). One loop without calls: per node the work is a few
    table lookups, so a call passing the arrays of G and L would cost more than the work
    (measured: 2x).

    Inputs: ``nodes`` (>= n,) int64 memory nodes, ``news`` (>= n,) int64 their new owners; ``owner``
    (nodes,) int32, updated in place; ``x`` (N, 3) particle centres (lattice units; the link
    coordinates are stored as the minimum image of the midpoint about them); ``G`` (``Grid``),
    ``L`` (``LinkLists``), updated in place (``lcnt``, ``LN``, ``LC``, ``nown``, marks, ``lerr``).
    Serial and in order: the order of the changes fixes the order of the lists."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    lbase, lcap, lcnt, LN, LC, lerr, nown, chg, chg_list, nchg = L
    nx, ny, nz = dims[0], dims[1], dims[2]
    Q = e.shape[0]
    for t in range(n):
        node = nodes[t]
        new = news[t]
        old = owner[node]
        if old == new:
            continue
        if not chg[node]:
            chg[node] = 1
            if nchg[0] < chg_list.shape[0]:
                chg_list[nchg[0]] = node
            nchg[0] += 1
        a = node // (ny * az)
        b = (node // az) % ny
        zi = node % az
        owner[node] = new
        if old >= 0:
            nown[old] -= 1
        if new >= 0:
            nown[new] += 1
        for i in range(1, Q):
            # new >= 0: links of `new` from fluid neighbours x = node - e_i into the node;
            # new == FLUID: links of particle neighbours s = node + e_i from the node
            sgn = 1 if new == FLUID else -1
            na = xmap[a + sgn * e[i, 0] + nx]
            nb = ymap[b + sgn * e[i, 1] + ny]
            nzi = zmap[zi + sgn * e[i, 2] + nz]
            nbr = (na * ny + nb) * az + nzi
            o = owner[nbr]
            if new >= 0:
                if o != FLUID:
                    continue
                p, xn, sn, sa, sb, sz = new, nbr, node, a, b, zi
            else:
                if o < 0:
                    continue
                p, xn, sn, sa, sb, sz = o, node, nbr, na, nb, nzi
            if lcnt[p, i] >= lcap[p, i]:
                _compact(p, i, owner, L)
                if lcnt[p, i] >= lcap[p, i]:
                    lerr[0] += 1
                    continue
            pos = lbase[p, i] + lcnt[p, i]
            LN[pos, 0] = xn
            LN[pos, 1] = sn
            for d in range(3):
                c = sa if d == 0 else (sb if d == 1 else sz)
                if periodic[d]:
                    # the image of the node nearest the centre (minimum image of the midpoint)
                    r = origin[d] + c - 0.5 * e[i, d] - x[p, d]
                    c -= dims[d] * int(math.floor(r / dims[d] + 0.5))
                LC[pos, d] = c
            lcnt[p, i] += 1


@njit(cache=True)
def clear_changed(chg, chg_list, nchg):
    """Unmark the nodes marked since the last link passes (all of them if the list overflowed):
    ``chg`` (nodes,) uint8, ``chg_list`` and ``nchg`` (1,) as in ``LinkLists``. Call it after the
    step's last link pass, never between the passes (they test only marked links)."""
    n = nchg[0]
    if n > chg_list.shape[0]:
        chg[:] = 0
    else:
        for t in range(n):
            chg[chg_list[t]] = 0
    nchg[0] = 0


@njit(cache=True)
def mark_initial(order, R, owner, count, x, G, L):
    """Coverage count and owners of all particles, in ``order`` (fixed ones first): the first
    particle to claim a fluid node owns it. Builds the link lists on the way.

    Inputs: ``order`` (N,) int64 particle indices; ``R`` (``Runs``) of every particle; ``owner``
    (nodes,) int32 with no particle yet (WALL or FLUID); ``count`` (nodes,) int16 zeros; ``x`` (N,
    3) centres; ``G``, ``L`` as ``set_owners``. Outputs: ``count`` (shapes containing each non-wall
    node), ``owner`` and the lists. Wall nodes stay WALL (wall beats particle)."""
    run_off, rect, z1, z2 = R
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    nx, ny, nz = dims[0], dims[1], dims[2]
    one_node = np.zeros(1, np.int64)
    one_new = np.zeros(1, np.int64)
    for m in range(order.shape[0]):
        k = order[m]
        one_new[0] = k
        base = run_off[k]
        nb = rect[k, 3]
        for ca in range(rect[k, 2]):
            a = xmap[rect[k, 0] + ca + nx]
            for cb in range(nb):
                b = ymap[rect[k, 1] + cb + ny]
                c = base + ca * nb + cb
                col = (a * ny + b) * az
                for z in range(z1[c], z2[c] + 1):
                    node = col + zmap[z + nz]
                    if owner[node] == WALL:
                        continue
                    count[node] += 1
                    if owner[node] == FLUID:
                        one_node[0] = node
                        set_owners(1, one_node, one_new, owner, x, G, L)
