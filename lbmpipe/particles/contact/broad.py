"""Broad phase: cell scan of candidate pairs, Verlet (neighbour) list, bounding radii."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..shapes import bounding_radius


# ------------------------------------------------------------------------------------------------
# broad phase


@njit(cache=True)
def _cell_setup(x, cs, lo, hi, periodic):
    n = x.shape[0]
    nc = np.ones(3, dtype=np.int64)
    org = np.zeros(3)
    width = np.zeros(3)
    for a in range(3):
        if periodic[a]:
            L = hi[a] - lo[a]
            nc[a] = max(1, int(math.floor(L / cs)))
            org[a] = lo[a]
            width[a] = L / nc[a]
        else:
            mn = 1e300
            mx = -1e300
            for i in range(n):
                mn = min(mn, x[i, a])
                mx = max(mx, x[i, a])
            if n == 0:
                mn, mx = 0.0, 0.0
            nc[a] = max(1, min(1024, int(math.floor((mx - mn) / cs)) + 1))
            org[a] = mn
            width[a] = max(cs, (mx - mn) / nc[a] * (1.0 + 1e-12))
    return nc, org, width


@njit(cache=True, inline="always")
def _image_offset(d0, d1, d2, L0, L1, L2, p0, p1, p2):
    # minimum-image shift (s0, s1, s2) of the separation d on the periodic axes, and the squared
    # distance after it (scalars only: no array reference counting in the pair loops)
    s0 = -L0 * math.floor(d0 / L0 + 0.5) if p0 else 0.0
    s1 = -L1 * math.floor(d1 / L1 + 0.5) if p1 else 0.0
    s2 = -L2 * math.floor(d2 / L2 + 0.5) if p2 else 0.0
    d0 += s0
    d1 += s1
    d2 += s2
    return s0, s1, s2, d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, inline="always")
def _cell_index(x, i, nc, org, width, periodic):
    # flat cell of body i (periodic axes wrapped, others clamped)
    idx = 0
    for a in range(3):
        t = (x[i, a] - org[a]) / width[a]
        ia = int(math.floor(t))
        if periodic[a]:
            ia %= nc[a]
        else:
            ia = min(nc[a] - 1, max(0, ia))
        idx = idx * nc[a] + ia
    return idx


@njit(cache=True)
def _stencil(nc, periodic):
    """The cell offsets the pair scan visits per axis, in its order (``offs[a, :noff[a]]``):
    -1, 0, 1; on a periodic axis of two cells 0, 1 (-1 is +1 there), of one cell 0."""
    noff = np.empty(3, dtype=np.int64)
    offs = np.empty((3, 3), dtype=np.int64)
    for a in range(3):
        if periodic[a] and nc[a] == 2:
            noff[a] = 2
            offs[a, 0], offs[a, 1] = 0, 1
        elif periodic[a] and nc[a] == 1:
            noff[a] = 1
            offs[a, 0] = 0
        else:
            noff[a] = 3
            offs[a, 0], offs[a, 1], offs[a, 2] = -1, 0, 1
    return noff, offs


@njit(cache=True)
def _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, fill, pi, pj, ps):
    n = x.shape[0]
    L = np.empty(3)
    for a in range(3):
        L[a] = hi[a] - lo[a]
    noff, offs = _stencil(nc, periodic)
    cnt = 0
    ci = np.empty(3, dtype=np.int64)
    for i in range(n):
        c = cell_of[i]
        ci[2] = c % nc[2]
        ci[1] = (c // nc[2]) % nc[1]
        ci[0] = c // (nc[1] * nc[2])
        for o0 in range(noff[0]):
            a0 = ci[0] + offs[0, o0]
            if periodic[0]:
                a0 %= nc[0]
            elif a0 < 0 or a0 >= nc[0]:
                continue
            for o1 in range(noff[1]):
                a1 = ci[1] + offs[1, o1]
                if periodic[1]:
                    a1 %= nc[1]
                elif a1 < 0 or a1 >= nc[1]:
                    continue
                for o2 in range(noff[2]):
                    a2 = ci[2] + offs[2, o2]
                    if periodic[2]:
                        a2 %= nc[2]
                    elif a2 < 0 or a2 >= nc[2]:
                        continue
                    cc = (a0 * nc[1] + a1) * nc[2] + a2
                    for t in range(start[cc], start[cc + 1]):
                        j = members[t]
                        if j <= i:
                            continue
                        s0, s1, s2, dd = _image_offset(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                                                       L[0], L[1], L[2], periodic[0], periodic[1], periodic[2])
                        cut = rb[i] + rb[j] + margin
                        if dd <= cut * cut:
                            if fill:
                                pi[cnt] = i
                                pj[cnt] = j
                                ps[cnt, 0], ps[cnt, 1], ps[cnt, 2] = s0, s1, s2
                            cnt += 1
    return cnt


@njit(cache=True)
def candidate_pairs(x, rb, margin, lo, hi, periodic):
    """Pairs (i < j) whose bounding spheres (radii ``rb``) come within ``margin`` of each other,
    by a cell list; ``periodic[a]`` wraps axis a over ``[lo[a], hi[a])`` and returns the
    minimum-image shift of body j (``x[j] + shift``). Returns (pi, pj, shift)."""
    n = x.shape[0]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, rb[i])
    cs = 2.0 * rmax + margin
    nc, org, width = _cell_setup(x, cs, lo, hi, periodic)
    ncell = nc[0] * nc[1] * nc[2]
    cell_of = np.empty(n, dtype=np.int64)
    for i in range(n):
        cell_of[i] = _cell_index(x, i, nc, org, width, periodic)
    start = np.zeros(ncell + 1, dtype=np.int64)
    for i in range(n):
        start[cell_of[i] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    members = np.empty(n, dtype=np.int64)
    pos = start[:-1].copy()
    for i in range(n):
        members[pos[cell_of[i]]] = i
        pos[cell_of[i]] += 1
    dummy_i = np.empty(0, dtype=np.int64)
    dummy_s = np.empty((0, 3))
    cnt = _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, False, dummy_i, dummy_i, dummy_s)
    pi = np.empty(cnt, dtype=np.int64)
    pj = np.empty(cnt, dtype=np.int64)
    ps = np.empty((cnt, 3))
    _pair_scan(x, rb, margin, lo, hi, periodic, nc, org, width, cell_of, start, members, True, pi, pj, ps)
    return pi, pj, ps


@njit(cache=True)
def neighbour_list(x, rb, margin, lo, hi, periodic):
    """Verlet list for ``listed_pairs``: the ``candidate_pairs`` of ``margin`` as CSR, the
    partners ``j > i`` of body i in ``js[start[i]:start[i + 1]]``."""
    pi, pj, _ = candidate_pairs(x, rb, margin, lo, hi, periodic)
    n = x.shape[0]
    start = np.zeros(n + 1, dtype=np.int64)
    for m in range(pi.shape[0]):
        start[pi[m] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    return start, pj


@njit(cache=True)
def listed_pairs(x, rb, margin, lo, hi, periodic, start, js):
    """``candidate_pairs(x, rb, margin, lo, hi, periodic)``, the same pairs, shifts and order,
    taken from a neighbour list (``neighbour_list``) that holds every pair of them: one built for
    a margin ``M`` at positions that every body has since left by at most ``d``, with
    ``margin + 2 d <= M``. A pair's bounding spheres then came within ``M`` of each other when
    the list was built. The test of each listed pair is the cell scan's, and the pairs of a body
    are put in the scan's order (its stencil of cells in turn, a cell's bodies by index), so the
    contacts, and the Gauss-Seidel order of the impulses, are those of ``candidate_pairs``: a
    list kept over time steps looks at ~6 listed partners a body instead of the ~55 bodies the
    scan visits (244 dense 8 mm cylinders) and changes no result."""
    pi, pj, ps, _slot = listed_slots(x, rb, margin, lo, hi, periodic, start, js)
    return pi, pj, ps


@njit(cache=True)
def listed_slots(x, rb, margin, lo, hi, periodic, start, js):
    """``listed_pairs`` and, for each pair, its slot t in the list (``js[t]`` is its j): where the
    collision step keeps what it learns of a pair from one step to the next."""
    n = x.shape[0]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, rb[i])
    nc, org, width = _cell_setup(x, 2.0 * rmax + margin, lo, hi, periodic)
    cell = np.empty((n, 3), dtype=np.int64)
    for i in range(n):
        c = _cell_index(x, i, nc, org, width, periodic)
        cell[i, 2] = c % nc[2]
        cell[i, 1] = (c // nc[2]) % nc[1]
        cell[i, 0] = c // (nc[1] * nc[2])
    noff, offs = _stencil(nc, periodic)
    # the stencil position of a cell difference d on each axis, looked up (-1: not visited): the
    # collision step took 1.01-1.02 times as long with a search by modulo per listed pair
    nmax = max(nc[0], max(nc[1], nc[2]))
    pos = np.full((3, 2 * nmax - 1), -1, dtype=np.int64)
    for a in range(3):
        for d in range(1 - nc[a], nc[a]):
            for u in range(noff[a]):
                if (d - offs[a, u]) % nc[a] == 0 if periodic[a] else d == offs[a, u]:
                    pos[a, d + nmax - 1] = u
                    break
    L = np.empty(3)
    for a in range(3):
        L[a] = hi[a] - lo[a]
    cap = js.shape[0]
    pi = np.empty(cap, dtype=np.int64)
    pj = np.empty(cap, dtype=np.int64)
    ps = np.empty((cap, 3))
    key = np.empty(cap, dtype=np.int64)
    slot = np.empty(cap, dtype=np.int64)
    cnt = 0
    for i in range(n):
        first = cnt
        for t in range(start[i], start[i + 1]):
            j = js[t]
            # the cell scan's stencil position of j's cell (_stencil), or none: the scan does
            # not look there
            st = 0
            for a in range(3):
                o = pos[a, cell[j, a] - cell[i, a] + nmax - 1]
                if o < 0:
                    st = -1
                    break
                st = st * 3 + o
            if st < 0:
                continue
            s0, s1, s2, dd = _image_offset(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                                           L[0], L[1], L[2], periodic[0], periodic[1], periodic[2])
            cut = rb[i] + rb[j] + margin
            if dd <= cut * cut:
                # insertion by (stencil position, j): a handful of pairs per body
                k = st * n + j
                u = cnt
                while u > first and key[u - 1] > k:
                    key[u] = key[u - 1]
                    pi[u] = i
                    pj[u] = pj[u - 1]
                    ps[u, 0], ps[u, 1], ps[u, 2] = ps[u - 1, 0], ps[u - 1, 1], ps[u - 1, 2]
                    slot[u] = slot[u - 1]
                    u -= 1
                key[u] = k
                pi[u] = i
                pj[u] = j
                ps[u, 0], ps[u, 1], ps[u, 2] = s0, s1, s2
                slot[u] = t
                cnt += 1
    return pi[:cnt], pj[:cnt], ps[:cnt], slot[:cnt]


@njit(cache=True)
def list_displacement(x, xref, lo, hi, periodic):
    """How far the bodies have moved relative to each other since ``xref``: the largest distance
    of a body's displacement (minimum image on periodic axes: the drift wraps positions into the
    period) from a shift c common to all, or from none if that is less. A pair's distance changes
    by at most |d_i - d_j| <= |d_i - c| + |d_j - c|, so a list built for a margin M holds every
    pair within ``margin`` while ``margin + 2 * list_displacement <= M``. The common shift is the
    middle of the displacements' range on each axis: in the pipe the suspension is carried along z
    at about 0.1 lattice units a step, and measured from their positions at the build the bodies
    left a list of 1 unit's skin every ~6 steps (244 dense 8 mm cylinders)."""
    L0, L1, L2 = hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]
    n = x.shape[0]
    d = np.empty((n, 3))
    dmax = 0.0
    for i in range(n):
        s0, s1, s2, dd = _image_offset(x[i, 0] - xref[i, 0], x[i, 1] - xref[i, 1], x[i, 2] - xref[i, 2],
                                       L0, L1, L2, periodic[0], periodic[1], periodic[2])
        d[i, 0] = x[i, 0] - xref[i, 0] + s0
        d[i, 1] = x[i, 1] - xref[i, 1] + s1
        d[i, 2] = x[i, 2] - xref[i, 2] + s2
        dmax = max(dmax, dd)
    if n == 0:
        return 0.0
    c = np.empty(3)
    for a in range(3):
        c[a] = 0.5 * (d[:, a].min() + d[:, a].max())
    cmax = 0.0
    for i in range(n):
        cmax = max(cmax, (d[i, 0] - c[0]) ** 2 + (d[i, 1] - c[1]) ** 2 + (d[i, 2] - c[2]) ** 2)
    return math.sqrt(min(dmax, cmax))


@njit(cache=True)
def bounding_radii(kind, h):
    """``bounding_radius`` of each body (N,)."""
    n = kind.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = bounding_radius(kind[i], h[i])
    return out
