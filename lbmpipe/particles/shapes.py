"""Particle shapes of the paper: cylinders (diameter x length), cubes (edge) and spheres.

A shape is an integer ``kind`` (``SPHERE``, ``CYLINDER``, ``CUBE``) plus half-extents ``h`` (3,)
in the body frame, whose axes are the principal axes through the centroid:

- sphere of diameter ``d``: ``h = (d/2, d/2, d/2)``
- cylinder of diameter ``d`` and length ``L``, axis along body z: ``h = (d/2, d/2, L/2)``
- cube of edge ``a``: ``h = (a/2, a/2, a/2)`` (the code treats ``CUBE`` as a box with half-edges
  ``h``, so a cuboid works too)

Everything is unit-agnostic; the solver passes lattice units. The geometric kernels
(``inside_body``, ``support_body``, ``bounding_radius``) are ``@njit`` so the particle-mapping and
collision code can call them from its own compiled loops. The principal moments of inertia feed
Euler's equations, Eq. (13), and the collision impulse, Eqs. (18)-(19), through ``J``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SPHERE = 0
CYLINDER = 1
CUBE = 2

SHAPE_NAMES = {SPHERE: "sphere", CYLINDER: "cylinder", CUBE: "cube"}


@njit(cache=True)
def inside_body(kind, h, px, py, pz):
    """Is the body-frame point ``(px, py, pz)`` inside the shape? The shape is a closed set:
    points exactly on the surface count as inside."""
    if kind == SPHERE:
        return px * px + py * py + pz * pz <= h[0] * h[0]
    if kind == CYLINDER:
        return px * px + py * py <= h[0] * h[0] and abs(pz) <= h[2]
    if kind == CUBE:
        return abs(px) <= h[0] and abs(py) <= h[1] and abs(pz) <= h[2]
    return False


@njit(cache=True)
def inside_points(kind, h, p):
    """``inside_body`` for each row of ``p`` (M, 3) of body-frame points -> bool (M,)."""
    m = p.shape[0]
    out = np.empty(m, dtype=np.bool_)
    for k in range(m):
        out[k] = inside_body(kind, h, p[k, 0], p[k, 1], p[k, 2])
    return out


@njit(cache=True)
def _sign(a):
    # sign(0) = +1 so that ties (d exactly along a face normal) resolve to the same point always.
    return 1.0 if a >= 0.0 else -1.0


@njit(cache=True)
def support_body(kind, h, d, out):
    """Write into ``out`` (3,) the body-frame point of the shape farthest along the body-frame
    direction ``d`` (3,), i.e. a maximiser of ``p . d`` over the shape (the support function).
    ``d`` need not be normalised.

    Ties are broken consistently: ``sign(0) = +1`` per component (a cube then returns its
    ``(+, +, +)``-most corner of the face or edge), and where the lateral direction of a cylinder
    (or the whole direction of a sphere) is zero, the point on the +x side is returned.
    """
    if kind == SPHERE:
        n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if n > 0.0:
            out[0] = h[0] * d[0] / n
            out[1] = h[0] * d[1] / n
            out[2] = h[0] * d[2] / n
        else:
            out[0] = h[0]
            out[1] = 0.0
            out[2] = 0.0
    elif kind == CYLINDER:
        r = math.sqrt(d[0] * d[0] + d[1] * d[1])
        if r > 0.0:
            out[0] = h[0] * d[0] / r
            out[1] = h[0] * d[1] / r
        else:
            out[0] = h[0]
            out[1] = 0.0
        out[2] = h[2] * _sign(d[2])
    else:
        out[0] = h[0] * _sign(d[0])
        out[1] = h[1] * _sign(d[1])
        out[2] = h[2] * _sign(d[2])


@njit(cache=True)
def bounding_radius(kind, h):
    """Radius of the sphere about the centroid that circumscribes the shape."""
    if kind == SPHERE:
        return h[0]
    if kind == CYLINDER:
        return math.sqrt(h[0] * h[0] + h[2] * h[2])
    return math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])


def _check_kind(kind: int) -> int:
    kind = int(kind)
    if kind not in SHAPE_NAMES:
        raise ValueError(f"unknown shape kind {kind}: expected one of {sorted(SHAPE_NAMES)} {SHAPE_NAMES}")
    return kind


def volume(kind: int, h) -> float:
    """Volume of the shape with half-extents ``h``."""
    kind = _check_kind(kind)
    h = np.asarray(h, dtype=np.float64)
    if kind == SPHERE:
        return 4.0 / 3.0 * math.pi * h[0] ** 3
    if kind == CYLINDER:
        return math.pi * h[0] ** 2 * 2.0 * h[2]
    return 8.0 * h[0] * h[1] * h[2]


def surface_area(kind: int, h) -> float:
    """Surface area of the shape with half-extents ``h`` (the unit of ``h`` squared)."""
    kind = _check_kind(kind)
    h = np.asarray(h, dtype=np.float64)
    if kind == SPHERE:
        r = h[0]
        return 4 * math.pi * r * r
    if kind == CYLINDER:
        r, length = h[0], 2.0 * h[2]
        return 2 * math.pi * r * r + 2 * math.pi * r * length
    if h[0] == h[1] == h[2]:
        return 6 * (2.0 * h[0]) ** 2
    return 8.0 * (h[0] * h[1] + h[1] * h[2] + h[0] * h[2])


def scene_shape(shape: str, diameter_mm=None, length_mm=None, edge_mm=None) -> tuple[int, np.ndarray]:
    """``(kind, h)`` in mm of a particle as a scene gives it (``shape`` and its full sizes in mm;
    the sizes a shape does not use may be None)."""
    return make_shape({"shape": shape, "diameter": diameter_mm, "length": length_mm, "edge": edge_mm})


def principal_inertia(kind: int, h, density: float) -> np.ndarray:
    """Principal moments of inertia (3,) about the body axes through the centroid, for a
    uniform ``density``: sphere ``2/5 m r^2``; cylinder ``I_zz = m r^2/2``,
    ``I_xx = I_yy = m (3 r^2 + L^2)/12``; box ``I_xx = m (b^2 + c^2)/12`` with full edges
    (``m a^2/6`` for a cube)."""
    kind = _check_kind(kind)
    h = np.asarray(h, dtype=np.float64)
    m = float(density) * volume(kind, h)
    if kind == SPHERE:
        i = 0.4 * m * h[0] ** 2
        return np.array([i, i, i])
    if kind == CYLINDER:
        r, length = h[0], 2.0 * h[2]
        ixx = m * (3.0 * r * r + length * length) / 12.0
        return np.array([ixx, ixx, 0.5 * m * r * r])
    return m / 3.0 * np.array([h[1] ** 2 + h[2] ** 2, h[0] ** 2 + h[2] ** 2, h[0] ** 2 + h[1] ** 2])


def _positive(spec: dict, key: str) -> float:
    if key not in spec:
        raise ValueError(f"shape spec {spec!r} for a {spec.get('shape')!r} needs the key {key!r}")
    try:
        value = float(spec[key])
    except (TypeError, ValueError):
        raise ValueError(f"shape spec {spec!r}: {key!r} must be a number, got {spec[key]!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"shape spec {spec!r}: {key!r} must be finite and > 0, got {value}")
    return value


def make_shape(spec: dict) -> tuple[int, np.ndarray]:
    """``(kind, h)`` from a spec such as ``{"shape": "cylinder", "diameter": 8, "length": 16}``,
    ``{"shape": "cube", "edge": 8}`` or ``{"shape": "sphere", "diameter": 10}``.

    Keys other than the ones a shape needs are ignored (a scene may carry e.g. a density next to
    them); a missing, non-numeric or non-positive size, or an unknown shape, is a ValueError.
    """
    if not isinstance(spec, dict) or "shape" not in spec:
        raise ValueError(f"shape spec must be a dict with a 'shape' key, got {spec!r}")
    name = str(spec["shape"]).strip().lower()
    if name == "sphere":
        r = 0.5 * _positive(spec, "diameter")
        return SPHERE, np.array([r, r, r])
    if name == "cylinder":
        r = 0.5 * _positive(spec, "diameter")
        return CYLINDER, np.array([r, r, 0.5 * _positive(spec, "length")])
    if name == "cube":
        a = 0.5 * _positive(spec, "edge")
        return CUBE, np.array([a, a, a])
    raise ValueError(f"unknown shape {spec['shape']!r}: choose one of 'sphere', 'cylinder', 'cube'")


def sample_surface(kind: int, h, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` body-frame points (n, 3) uniformly distributed (by area) on the shape's surface."""
    kind = _check_kind(kind)
    h = np.asarray(h, dtype=np.float64)
    if kind == SPHERE:
        p = rng.standard_normal((n, 3))
        return h[0] * p / np.linalg.norm(p, axis=1)[:, None]
    if kind == CYLINDER:
        r, hz = h[0], h[2]
        side, cap = 2.0 * math.pi * r * 2.0 * hz, math.pi * r * r
        which = rng.choice(3, size=n, p=np.array([side, cap, cap]) / (side + 2.0 * cap))
        phi = rng.uniform(0.0, 2.0 * math.pi, n)
        # area-uniform on a disc: radius ~ sqrt(U)
        rho = np.where(which == 0, r, r * np.sqrt(rng.uniform(0.0, 1.0, n)))
        z = np.where(which == 0, rng.uniform(-hz, hz, n), np.where(which == 1, hz, -hz))
        return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
    areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    p = rng.uniform(-1.0, 1.0, (n, 3)) * h
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    p[np.arange(n), axis] = side * h[axis]
    return p
