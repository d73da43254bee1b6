"""Particle nodes as column runs: which nodes a particle's shape covers, and which change when it
moves (lattice units).

Over the (x, y) columns of a particle's axis-aligned bounding box, the z-interval of node centres
inside the shape is found analytically in the body frame (ray-slab for a cube, ray-cylinder,
ray-sphere); a convex shape meets a column in one interval. Runs use unwrapped indices around the
particle's centre, so relative vectors are minimum images without rounding; the wrap tables of
``Grid`` map them into memory. Centres are kept in the periodic box (wrapped after each move, runs
and lever arms shifted by whole periods: ``remap.wrap_positions``). A particle's bounding diameter
must be at least two nodes shorter than every periodic length. A per-node coverage count (how many
particle shapes contain the node) makes a move local: only nodes whose count changes are visited
(the old and new runs of a column differ in a few nodes at the ends; ``diff_runs``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..rigid import quat_to_matrix
from ..shapes import CYLINDER, SPHERE

_EPS_DIR = 1e-12  # below this a direction component counts as zero (line parallel to a face)


class Runs(NamedTuple):
    """Column runs of all particles (one set: current or next).

    ``run_off`` (N + 1,) int64: particle ``k``'s columns are ``run_off[k] .. run_off[k + 1]``
    (capacity from its bounding radius); ``rect`` (N, 4) int64: ``(a0, b0, na, nb)``, the first
    column (unwrapped lattice coordinates) and the extents of its box; ``z1``, ``z2`` (ncol,) int64:
    the node interval ``[z1, z2]`` (unwrapped) of column ``(a0 + ca, b0 + cb)`` at
    ``run_off[k] + ca nb + cb``, empty when ``z1 > z2``."""

    run_off: np.ndarray
    rect: np.ndarray
    z1: np.ndarray
    z2: np.ndarray


class RunChanges(NamedTuple):
    """Nodes the moved particles leave and enter (``diff_runs``). For the ``m``-th moved particle
    the entries ``off[m] .. off[m] + n[m]`` of ``node`` (int64 memory nodes) and ``d`` (int8: -1
    left, +1 entered); ``off`` (M + 1,) is the capacity (twice the box volume)."""

    off: np.ndarray
    node: np.ndarray
    d: np.ndarray
    n: np.ndarray


@njit(cache=True)
def _slab(p, d, hh, t0, t1):
    # Interval of t with |p + t d| <= hh, intersected with [t0, t1]; empty -> t0 > t1.
    if abs(d) < _EPS_DIR:
        if abs(p) > hh:
            return 1.0, 0.0
        return t0, t1
    inv = 1.0 / d
    a = (-hh - p) * inv
    b = (hh - p) * inv
    if a > b:
        a, b = b, a
    return max(t0, a), min(t1, b)


@njit(cache=True)
def _disc(px, py, dx, dy, r, t0, t1):
    # Interval of t with (px + t dx)^2 + (py + t dy)^2 <= r^2, intersected with [t0, t1].
    a = dx * dx + dy * dy
    c = px * px + py * py - r * r
    if a < _EPS_DIR:
        if c > 0.0:
            return 1.0, 0.0
        return t0, t1
    b = px * dx + py * dy
    disc = b * b - a * c
    if disc < 0.0:
        return 1.0, 0.0
    sq = math.sqrt(disc)
    return max(t0, (-b - sq) / a), min(t1, (-b + sq) / a)


@njit(cache=True)
def ray_interval(kind, h, px, py, pz, dx, dy, dz):
    """Interval ``[t0, t1]`` of ``t`` with the body-frame point ``p + t d`` inside the closed
    shape (``t0 > t1``: the line misses it).

    Inputs: ``kind`` (``shapes.SPHERE``, ``CYLINDER`` or a cube), ``h`` (3,) half-extents (sphere:
    ``h[0]`` the radius; cylinder: radius ``h[0]``, half-length ``h[2]``), ``p`` a body-frame
    point and ``d`` a unit body-frame direction, lattice units. Exact up to round-off (ray-slab,
    ray-disc, ray-sphere)."""
    big = 1e300
    if kind == SPHERE:
        # |p + t d|^2 <= r^2 with |d| = 1
        b = px * dx + py * dy + pz * dz
        c = px * px + py * py + pz * pz - h[0] * h[0]
        disc = b * b - c
        if disc < 0.0:
            return 1.0, 0.0
        sq = math.sqrt(disc)
        return -b - sq, -b + sq
    if kind == CYLINDER:
        t0, t1 = _slab(pz, dz, h[2], -big, big)
        if t0 > t1:
            return t0, t1
        return _disc(px, py, dx, dy, h[0], t0, t1)
    t0, t1 = _slab(px, dx, h[0], -big, big)
    t0, t1 = _slab(py, dy, h[1], t0, t1)
    return _slab(pz, dz, h[2], t0, t1)


@njit(cache=True)
def _half_extents_xy(kind, h, a):
    # Half-extents along lab x and y of the rotated shape (its tight axis-aligned box).
    out = np.empty(2)
    for r in range(2):
        if kind == SPHERE:
            out[r] = h[0]
        elif kind == CYLINDER:
            c = abs(a[r, 2])
            out[r] = c * h[2] + h[0] * math.sqrt(max(0.0, 1.0 - c * c))
        else:
            out[r] = abs(a[r, 0]) * h[0] + abs(a[r, 1]) * h[1] + abs(a[r, 2]) * h[2]
    return out



@njit(parallel=True, cache=True)
def compute_runs(ids, kind, h, x, q, G, R):
    """Column runs of the particles ``ids`` at centres ``x`` (unwrapped) and orientations ``q``.

    Inputs: ``ids`` (M,) int64 particle indices; ``kind`` (N,), ``h`` (N, 3) half-extents (lattice
    units), ``x`` (N, 3) centres, ``q`` (N, 4) unit quaternions; ``G`` the grid (``Grid``).
    Output: ``R`` (``Runs``) for the particles ``ids``: ``rect[k]`` and the intervals of their
    columns (other particles' entries untouched). Postcondition: node ``(a, b, z)`` (unwrapped)
    lies in particle ``k``'s closed shape iff its column is in ``rect[k]`` and ``z1 <= z <= z2``
    (clamped to the grid along non-periodic axes). Parallel over particles, each writing its own
    entries: the same result on any thread count."""
    # Bundled arguments are taken apart by field access, never by tuple unpacking: in a parallel
    # kernel (numba 0.68) writes through an array unpacked from a tuple are lost.
    dims = G.dims
    origin = G.origin
    periodic = G.periodic
    run_off = R.run_off
    rect = R.rect
    z1 = R.z1
    z2 = R.z2
    for m in prange(ids.shape[0]):
        k = ids[m]
        A = quat_to_matrix(q[k])
        ext = _half_extents_xy(kind[k], h[k], A)
        lo = np.empty(2, np.int64)
        n = np.empty(2, np.int64)
        for r in range(2):
            c_lo = int(math.ceil(x[k, r] - ext[r] - origin[r]))
            c_hi = int(math.floor(x[k, r] + ext[r] - origin[r]))
            if not periodic[r]:
                c_lo = max(c_lo, 0)
                c_hi = min(c_hi, dims[r] - 1)
            lo[r] = c_lo
            n[r] = max(0, c_hi - c_lo + 1)
        cap = run_off[k + 1] - run_off[k]
        if n[0] * n[1] > cap:  # cannot happen: capacity is from the bounding radius
            n[0] = 0
            n[1] = 0
        rect[k, 0] = lo[0]
        rect[k, 1] = lo[1]
        rect[k, 2] = n[0]
        rect[k, 3] = n[1]
        # body-frame direction of the lab z axis: A^T e_z
        dx, dy, dz = A[2, 0], A[2, 1], A[2, 2]
        base = run_off[k]
        nz = dims[2]
        for ca in range(n[0]):
            px = origin[0] + lo[0] + ca - x[k, 0]
            for cb in range(n[1]):
                py = origin[1] + lo[1] + cb - x[k, 1]
                bx = A[0, 0] * px + A[1, 0] * py
                by = A[0, 1] * px + A[1, 1] * py
                bz = A[0, 2] * px + A[1, 2] * py
                t0, t1 = ray_interval(kind[k], h[k], bx, by, bz, dx, dy, dz)
                c = base + ca * n[1] + cb
                if t0 > t1:
                    z1[c] = 1
                    z2[c] = 0
                    continue
                za = int(math.ceil(x[k, 2] + t0 - origin[2]))
                zb = int(math.floor(x[k, 2] + t1 - origin[2]))
                if not periodic[2]:
                    za = max(za, 0)
                    zb = min(zb, nz - 1)
                z1[c] = za
                z2[c] = zb


@njit(cache=True, inline="always")
def _candidates(s1, s2, w1, w2):
    # [s1, s2] minus [w1, w2] as (lo1, hi1, lo2, hi2); empty parts have lo > hi.
    if w1 > w2 or w2 < s1 or w1 > s2:
        return s1, s2, 1, 0
    return s1, min(s2, w1 - 1), max(s1, w2 + 1), s2



@njit(parallel=True, cache=True)
def diff_runs(ids, old, new, G, C):
    """Nodes each moved particle leaves (-1) and enters (+1): per column of the union of its old
    and new boxes, old run minus new run and vice versa (both unwrapped in the same frame).

    Inputs: ``ids`` (M,) the moved particles; ``old``, ``new`` (``Runs``) their runs before and
    after the move; ``G`` the grid. Output: ``C`` (``RunChanges``): for the ``m``-th particle,
    ``C.n[m]`` entries from ``C.off[m]`` (memory node, direction of change), in column order.
    A node is listed at most once per particle. Parallel over particles (disjoint output ranges)."""
    # Bundled arguments are taken apart by field access, never by tuple unpacking: in a parallel
    # kernel (numba 0.68) writes through an array unpacked from a tuple are lost.
    run_off = old.run_off
    rect_o = old.rect
    z1o = old.z1
    z2o = old.z2
    rect_n = new.rect
    z1n = new.z1
    z2n = new.z2
    dims = G.dims
    az = G.az
    xmap = G.xmap
    ymap = G.ymap
    zmap = G.zmap
    chg_off = C.off
    chg_node = C.node
    chg_d = C.d
    chg_n = C.n
    nx, ny, nz = dims[0], dims[1], dims[2]
    for m in prange(ids.shape[0]):
        k = ids[m]
        base = run_off[k]
        ao, bo, nao, nbo = rect_o[k, 0], rect_o[k, 1], rect_o[k, 2], rect_o[k, 3]
        an, bn, nan, nbn = rect_n[k, 0], rect_n[k, 1], rect_n[k, 2], rect_n[k, 3]
        a_lo = min(ao, an) if nao > 0 and nan > 0 else (ao if nao > 0 else an)
        a_hi = max(ao + nao, an + nan) if nao > 0 and nan > 0 else (ao + nao if nao > 0 else an + nan)
        b_lo = min(bo, bn) if nbo > 0 and nbn > 0 else (bo if nbo > 0 else bn)
        b_hi = max(bo + nbo, bn + nbn) if nbo > 0 and nbn > 0 else (bo + nbo if nbo > 0 else bn + nbn)
        cnt = chg_off[m]
        for a in range(a_lo, a_hi):
            for b in range(b_lo, b_hi):
                o1 = 1
                o2 = 0
                if ao <= a < ao + nao and bo <= b < bo + nbo:
                    c = base + (a - ao) * nbo + (b - bo)
                    o1 = z1o[c]
                    o2 = z2o[c]
                n1 = 1
                n2 = 0
                if an <= a < an + nan and bn <= b < bn + nbn:
                    c = base + (a - an) * nbn + (b - bn)
                    n1 = z1n[c]
                    n2 = z2n[c]
                if o1 > o2 and n1 > n2:
                    continue
                if o1 == n1 and o2 == n2:
                    continue
                col = (xmap[a + nx] * ny + ymap[b + ny]) * az
                # left: old \ new
                if o1 <= o2:
                    l1, h1, l2, h2 = _candidates(o1, o2, n1, n2)
                    for z in range(l1, h1 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = -1
                        cnt += 1
                    for z in range(l2, h2 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = -1
                        cnt += 1
                if n1 <= n2:
                    l1, h1, l2, h2 = _candidates(n1, n2, o1, o2)
                    for z in range(l1, h1 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = 1
                        cnt += 1
                    for z in range(l2, h2 + 1):
                        chg_node[cnt] = col + zmap[z + nz]
                        chg_d[cnt] = 1
                        cnt += 1
        chg_n[m] = cnt - chg_off[m]

