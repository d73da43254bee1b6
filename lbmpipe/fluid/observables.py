"""Macroscopic fields and the quantities the outputs report (lattice units in, lattice units out).

Velocities follow the forcing scheme: with a body force ``F`` the physical velocity is
``u = (sum_i f_i e_i + F/2) / rho`` over the *streamed* populations (Guo et al. 2002), Eq. (4)
shifted by half the force. The solver stores *post-collision* populations, whose momentum is
larger by a whole ``F`` (Guo's source adds ``(1 - omega/2) F`` and the relaxation the rest), so
from them ``u = (sum_i f*_i e_i - F/2) / rho``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def ordered_sum(a):
    """Sum of the 1-D array ``a`` in index order. Inside a ``parallel=True`` function numba turns
    ``a.sum()`` into a parallel reduction whose order, and so whose last bits, follow the thread
    count; the per-chunk partials of the parallel functions are added with this instead."""
    total = 0.0
    for k in range(a.shape[0]):
        total += a[k]
    return total


@njit(parallel=True, cache=True, fastmath=True)
def _moments(f, ex, ey, ez, fx, fy, fz, rho, ux, uy, uz):
    q, nx, ny, nz = f.shape[0], rho.shape[0], rho.shape[1], rho.shape[2]
    for a in prange(nx):
        for b in range(ny):
            for c in range(nz):
                r = 0.0
                jx = 0.0
                jy = 0.0
                jz = 0.0
                for i in range(q):
                    v = f[i, a, b, c]
                    r += v
                    jx += ex[i] * v
                    jy += ey[i] * v
                    jz += ez[i] * v
                rho[a, b, c] = r
                ux[a, b, c] = (jx - 0.5 * fx) / r
                uy[a, b, c] = (jy - 0.5 * fy) / r
                uz[a, b, c] = (jz - 0.5 * fz) / r


def moments(f: np.ndarray, lattice, shape, force=(0.0, 0.0, 0.0)):
    """Density and velocity (Eq. (4), force-shifted) from post-collision ``f`` on ``shape`` (drops padding).

    Values at solid nodes are meaningless; mask them with the grid's ``fluid``.
    """
    rho = np.empty(shape)
    ux, uy, uz = np.empty(shape), np.empty(shape), np.empty(shape)
    e = lattice.e.astype(np.float64)
    _moments(f, e[:, 0], e[:, 1], e[:, 2], float(force[0]), float(force[1]), float(force[2]), rho, ux, uy, uz)
    return rho, ux, uy, uz


@njit(parallel=True, cache=True)
def _masked_sum(f, fluid):
    q, nx = f.shape[0], fluid.shape[0]
    ny, nz = fluid.shape[1], fluid.shape[2]
    partial = np.zeros(nx)
    for a in prange(nx):
        for b in range(ny):
            for c in range(nz):
                if fluid[a, b, c]:
                    for i in range(q):
                        partial[a] += f[i, a, b, c]
    return ordered_sum(partial)


def total_mass(f: np.ndarray, fluid: np.ndarray) -> float:
    """Sum of all populations over fluid nodes (ghost slots of solid nodes excluded)."""
    return float(_masked_sum(f, fluid))


def radial_profile(uz_mean: np.ndarray, fluid: np.ndarray, x: np.ndarray, y: np.ndarray, radius: float,
                   bin_width: float = 0.5):
    """Axial velocity against radius, averaged over z and azimuth, in bins of ``bin_width``.

    Returns ``(r, uz, count)`` per non-empty bin, ``r`` the mean node radius in the bin.
    """
    X, Y = np.meshgrid(x, y, indexing="ij")
    r2d = np.sqrt(X**2 + Y**2)
    mask2d = fluid.any(axis=2)
    col_mean = np.where(mask2d, uz_mean.sum(axis=2) / np.maximum(fluid.sum(axis=2), 1), 0.0)
    r = r2d[mask2d]
    u = col_mean[mask2d]
    edges = np.arange(0.0, radius + bin_width, bin_width)
    idx = np.clip(np.digitize(r, edges) - 1, 0, len(edges) - 2)
    count = np.bincount(idx, minlength=len(edges) - 1)
    rs = np.bincount(idx, weights=r, minlength=len(edges) - 1)
    us = np.bincount(idx, weights=u, minlength=len(edges) - 1)
    keep = count > 0
    return rs[keep] / count[keep], us[keep] / count[keep], count[keep]


#: fraction of the pipe radius inside which :func:`core_velocity_ratio` averages
CORE_FRACTION = 0.5
#: its Hagen-Poiseuille value: the mean of 2 U (1 - r^2/R^2) over r < c R is 2 U (1 - c^2/2)
CORE_RATIO_POISEUILLE = 2.0 * (1.0 - CORE_FRACTION**2 / 2.0)


def core_mask(x: np.ndarray, y: np.ndarray, radius: float, nz: int) -> np.ndarray:
    """Nodes of a pipe lattice (node coordinates ``x``, ``y`` about the axis) within
    ``CORE_FRACTION`` of the radius, shape ``(len(x), len(y), nz)``."""
    X, Y = np.meshgrid(x, y, indexing="ij")
    return np.repeat((X**2 + Y**2 < (CORE_FRACTION * radius) ** 2)[:, :, None], nz, axis=2)


def core_velocity_ratio(uz: np.ndarray, fluid: np.ndarray, core: np.ndarray) -> float:
    """One number for the shape of the flow profile at an instant: the mean axial velocity of the
    fluid nodes in the core (``core_mask``) over that of all fluid nodes; ``CORE_RATIO_POISEUILLE``
    (1.75) for Hagen-Poiseuille, lower for a blunted profile, NaN without fluid in the core.
    The spin-up test follows it sample by sample (``profile.csv`` is a time average)."""
    inner = fluid & core
    n_all, n_in = int(fluid.sum()), int(inner.sum())
    if n_all == 0 or n_in == 0:
        return float("nan")
    u_all = float(uz[fluid].sum()) / n_all
    return float(uz[inner].sum()) / n_in / u_all if u_all != 0.0 else float("nan")


def poiseuille_pipe(r: np.ndarray, radius: float, u_max: float) -> np.ndarray:
    """Hagen-Poiseuille profile ``u_max (1 - r^2/R^2)`` (zero outside the pipe)."""
    return np.where(r < radius, u_max * (1.0 - (r / radius) ** 2), 0.0)


def relative_l2(u: np.ndarray, u_ref: np.ndarray) -> float:
    return float(np.sqrt(np.sum((u - u_ref) ** 2) / np.sum(u_ref**2)))


def couette_box(coord: np.ndarray, height: float, u_lo, u_hi) -> list[np.ndarray]:
    """Steady plane Couette profile between walls at ``0`` and ``height`` (half-way bounce-back:
    half a link outside the outermost nodes) moving with ``u_lo`` and ``u_hi`` (3-vectors):
    ``u(s) = u_lo + (u_hi - u_lo) s / height`` at node coordinates ``coord`` (lattice units)."""
    s = np.asarray(coord, dtype=np.float64) / height
    return [u_lo[k] + (u_hi[k] - u_lo[k]) * s for k in range(3)]
