"""Python conveniences over the contact kernels (tests, set-up; not for the time loop)."""

from __future__ import annotations

import numpy as np

from ..rigid import quat_to_matrix
from .narrow import body_contact
from .walls import pipe_wall_contact, plane_wall_contact


# ------------------------------------------------------------------------------------------------
# Python conveniences (tests, set-up; not for the time loop)


def _matrix(q) -> np.ndarray:
    # no renormalisation: the kernels use the stored unit quaternions as they are, and the same
    # input must give the same contact bit for bit
    q = np.asarray(q, dtype=np.float64)
    if abs(float(q @ q) - 1.0) > 1e-9:
        raise ValueError(f"quaternion {q} is not a unit quaternion")
    return quat_to_matrix(q)


def contact_pair(kind1, h1, x1, q1, kind2, h2, x2, q2, manifold_tol: float = 0.1, max_gap: float = np.inf):
    """Signed gap, unit normal (1 -> 2) and contact point of two bodies given by unit quaternions."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = body_contact(
        int(kind1), np.asarray(h1, np.float64), np.asarray(x1, np.float64), _matrix(q1),
        int(kind2), np.asarray(h2, np.float64), np.asarray(x2, np.float64), _matrix(q2),
        float(max_gap), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c


def contact_pipe(kind, h, x, q, radius: float, center=(0.0, 0.0), manifold_tol: float = 0.1):
    """Signed gap to the pipe wall, outward radial normal and contact point of one body."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = pipe_wall_contact(
        int(kind), np.asarray(h, np.float64), np.asarray(x, np.float64), _matrix(q),
        float(radius), float(center[0]), float(center[1]), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c


def contact_plane(kind, h, x, q, axis: int, coord: float, side: int, manifold_tol: float = 0.1):
    """Signed gap to the planar wall ``x[axis] = coord`` (``side`` +1: wall above the body)."""
    nrm = np.empty(3)
    c = np.empty(3)
    g = plane_wall_contact(
        int(kind), np.asarray(h, np.float64), np.asarray(x, np.float64), _matrix(q),
        int(axis), float(coord), float(side), float(manifold_tol), nrm, c,
    )
    return float(g), nrm, c
