"""Nodes of the coupled grid: the owner codes, the grid bundle ``Grid`` every kernel takes, and the
index helpers that move between a memory node and its lattice coordinates (lattice units).

Every lattice node is exactly one of: static wall (``owner = WALL``; the grid's walls and the z
padding), fluid (``owner = FLUID``) or particle ``k`` (``owner = k >= 0``); the rules for nodes
two things claim are in the package docstring. A memory node is ``node = (a ny + b) az + z`` for
lattice coordinates ``(a, b, z)``, ``az >= nz`` the allocated z length (padding is WALL).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

WALL = -2
FLUID = -1


class Grid(NamedTuple):
    """The grid as the kernels see it (a tuple, unpacked at the top of each kernel).

    ``dims`` (3,) int64 ``(nx, ny, nz)``; ``az`` the allocated z length; ``origin`` (3,) float64,
    the position of node ``(0, 0, 0)`` (lattice units); ``periodic`` (3,) bool; ``xmap``, ``ymap``,
    ``zmap`` (3 n,) int64 wrap tables: index ``c + n`` maps the coordinate ``c`` in ``[-n, 2n)`` to
    its node in ``[0, n)`` (periodic) or clamps it (not periodic); ``e`` (Q, 3) int64, the lattice
    velocities."""

    dims: np.ndarray
    az: int
    origin: np.ndarray
    periodic: np.ndarray
    xmap: np.ndarray
    ymap: np.ndarray
    zmap: np.ndarray
    e: np.ndarray


class LatticeRef(NamedTuple):
    """The lattice weights ``w`` (Q,) float64, the opposite directions ``opp`` (Q,) int64 and the
    reference density ``rho0`` (lattice units) that the link rules and the refill read."""

    w: np.ndarray
    opp: np.ndarray
    rho0: float


def wrap_table(n: int, periodic: bool) -> np.ndarray:
    """Wrap table of one axis of ``n`` nodes (``Grid.xmap``): entry ``c + n`` for ``c`` in ``[-n, 2n)``."""
    i = np.arange(-n, 2 * n)
    return (i % n if periodic else np.clip(i, 0, n - 1)).astype(np.int64)


# Compiled without reference counting (``_nrt=False``): they allocate nothing and are called per
# node, where the atomic reference counts of their array arguments would dominate.


@njit(cache=True, _nrt=False)
def decode(node, ny, az):
    """Lattice coordinates ``(a, b, z)`` of memory node ``node``."""
    return node // (ny * az), (node // az) % ny, node % az


@njit(cache=True, _nrt=False)
def shifted(a, b, zi, dx, dy, dz, G):
    """Memory node of ``(a + dx, b + dy, zi + dz)`` through the wrap tables of ``G`` (``|d| <= n``)."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    return (xmap[a + dx + dims[0]] * dims[1] + ymap[b + dy + dims[1]]) * az + zmap[zi + dz + dims[2]]


@njit(cache=True, _nrt=False)
def node_vector(node, xk, G):
    """Minimum-image vector ``(r0, r1, r2)`` from the centre ``xk`` (3,) to the centre of memory
    node ``node`` (lattice units)."""
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    a, b, zi = decode(node, dims[1], az)
    r0 = origin[0] + a - xk[0]
    r1 = origin[1] + b - xk[1]
    r2 = origin[2] + zi - xk[2]
    if periodic[0]:
        r0 -= dims[0] * math.floor(r0 / dims[0] + 0.5)
    if periodic[1]:
        r1 -= dims[1] * math.floor(r1 / dims[1] + 0.5)
    if periodic[2]:
        r2 -= dims[2] * math.floor(r2 / dims[2] + 0.5)
    return r0, r1, r2
