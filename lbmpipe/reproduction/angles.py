"""Orientation angles of a body against the pipe axis (the definitions of ``statistics``'s module
docstring), the histogram kinds, and their distributions for isotropic orientations."""

from __future__ import annotations

import math

import numpy as np

from .steady import rotation_matrices

CUBE_MAX_AXIS_ANGLE_DEG = math.degrees(math.acos(1.0 / math.sqrt(3.0)))  # 54.7356
# (kind, upper edge of the range in degrees, number of bins)
ORIENTATION_KINDS = {
    "cylinder": (("cyl_axis_angle", 90.0, 9),),
    "cube": (("cube_projected_angle", 45.0, 9), ("cube_axis_angle", CUBE_MAX_AXIS_ANGLE_DEG, 9)),
}


def cylinder_axis_angle(q: np.ndarray) -> np.ndarray:
    """Angle (deg, 0-90) between the cylinder axis (body z) and the pipe axis (lab z)."""
    a = rotation_matrices(np.reshape(q, (-1, 4)))
    return np.degrees(np.arccos(np.clip(np.abs(a[:, 2, 2]), 0.0, 1.0)))


def cube_axis_angle(q: np.ndarray) -> np.ndarray:
    """3-D angle (deg, 0-54.74) between the pipe axis and the nearest cube axis."""
    a = rotation_matrices(np.reshape(q, (-1, 4)))
    return np.degrees(np.arccos(np.clip(np.abs(a[:, 2, :]).max(axis=1), 0.0, 1.0)))


def cube_projected_angle(q: np.ndarray) -> np.ndarray:
    """In-image angle (deg, 0-45) of a cube seen by a camera looking along lab y: the body axis
    with the longest projection on the x-z plane, its angle to the pipe axis folded by the
    square's symmetry (module docstring gives the exact definition)."""
    a = rotation_matrices(np.reshape(q, (-1, 4)))
    px, pz = a[:, 0, :], a[:, 2, :]  # (N, 3): projections of the three body axes
    k = np.argmax(px * px + pz * pz, axis=1)
    i = np.arange(a.shape[0])
    alpha = np.degrees(np.arctan2(px[i, k], pz[i, k]))
    beta = np.mod(alpha, 90.0)
    return np.minimum(beta, 90.0 - beta)


_ANGLE_FUNCS = {"cyl_axis_angle": cylinder_axis_angle, "cube_axis_angle": cube_axis_angle,
                "cube_projected_angle": cube_projected_angle}


def orientation_angles(kind: str, q: np.ndarray) -> np.ndarray:
    """Angles (deg) of ``kind`` (``cyl_axis_angle``, ``cube_axis_angle``,
    ``cube_projected_angle``) for quaternions ``q`` (N, 4)."""
    return _ANGLE_FUNCS[kind](q)


def isotropic_cdf(kind: str, angle_deg) -> np.ndarray:
    """Share of uniformly random orientations (Haar measure on rotations) whose angle ``kind``
    is at most ``angle_deg`` -- the reference an isotropic suspension gives, in closed form:

    - ``cyl_axis_angle``: the axis is uniform on the sphere and its angle to the pipe axis has
      density ``sin theta`` on 0-90 deg, so ``F = 1 - cos theta``.
    - ``cube_axis_angle``: the pipe axis seen from the body is uniform on the sphere; the nearest
      cube axis is the one whose cell (``|u_k| = max``, 1/6 of the sphere) holds it. In the cell of
      body z, polar angle ``t``, azimuth ``p`` in 0-45 deg (1/8 of the cell), the cell ends at
      ``tan t = 1 / cos p``. Up to 45 deg no cell boundary is reached: ``F = 3 (1 - cos theta)``;
      beyond, with ``cos p* = cot theta``, ``F = (12/pi) [p* - asin(sin p* / sqrt 2)
      + (pi/4 - p*)(1 - cos theta)]`` (the boundary term integrates in closed form with
      ``s = sin p``), which reaches 1 at ``theta = arccos(1/sqrt 3)``.
    - ``cube_projected_angle``: uniform on 0-45 deg, ``F = theta / 45``. A rotation about the
      camera axis (lab y) leaves the Haar measure unchanged, turns every projected edge by the
      same angle and keeps which one is longest, so the in-image angle is uniform on the circle
      and its fold into 0-45 deg is uniform too.
    """
    th = np.radians(np.clip(np.asarray(angle_deg, dtype=float), 0.0, None))
    if kind == "cyl_axis_angle":
        return 1.0 - np.cos(np.minimum(th, np.pi / 2))
    if kind == "cube_projected_angle":
        return np.clip(np.degrees(th) / 45.0, 0.0, 1.0)
    if kind == "cube_axis_angle":
        th = np.minimum(th, math.radians(CUBE_MAX_AXIS_ANGLE_DEG))
        low = 3.0 * (1.0 - np.cos(th))
        with np.errstate(divide="ignore", invalid="ignore"):
            p = np.arccos(np.clip(1.0 / np.tan(np.maximum(th, np.pi / 4)), 0.0, 1.0))
        high = (12.0 / np.pi) * (p - np.arcsin(np.sin(p) / math.sqrt(2.0)) + (np.pi / 4 - p) * (1.0 - np.cos(th)))
        return np.where(th <= np.pi / 4, low, np.minimum(high, 1.0))
    raise KeyError(f"unknown orientation kind {kind!r}; one of {sorted(_ANGLE_FUNCS)}")


def isotropic_bin_fractions(kind: str, edges_deg) -> np.ndarray:
    """Fraction of uniformly random orientations in each bin ``[edges[i], edges[i+1])`` of the
    angle ``kind`` (:func:`isotropic_cdf` differenced): the reference line of Figs. 8 and 9."""
    return np.diff(isotropic_cdf(kind, np.asarray(edges_deg, dtype=float)))
