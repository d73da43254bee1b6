"""Dense random packings of cylinders, cubes and spheres in a pipe (the paper's initial state:
"particle positions and orientations uniformly random", at 30 % and 50 % solid volume fraction).

The pipe has radius ``R`` about the z axis (x = y = 0) and is periodic along z with length ``L``;
positions are returned with z in ``[0, L)``. Units are whatever ``h`` and ``R`` are in (mm or
lattice units; the paper's lattice has dx = 1 mm).

Method: random start, then overlap removal (a force-biased / position-based relaxation).

1. Orientations uniform on SO(3) (Haar measure, ``rigid.random_quaternions``); centres uniform
   in z and uniform over the disc of the cross-section where the body, in its orientation, fits
   inside the pipe (radius ``R`` minus its largest lateral extent from the centre); full size: the
   bodies overlap each other, not the wall. (Drawing centres over the whole disc instead and
   letting the wall push them in piles them up against the wall: at 30 % of 16 mm cylinders only
   6 % of the centres ended in the inner half of the reachable area.)
2. Relaxation sweeps (Gauss-Seidel, in a numba kernel): every overlapping pair (and body-wall
   contact) from ``lbmpipe.particles.contact`` (GJK/EPA, exact for separated cylinder pairs: the code the
   collision model uses) is pushed apart
   along its contact normal to the gap ``+push`` (a small fraction of the size), split by the
   generalised inverse masses ``w_i = 1/m + (l_i x p) . J_i^-1 (l_i x p)`` (unit mass, shape
   inertia, rotational part scaled by ``rotation_weight``): by translation and by a rotation about
   the contact lever arm, so that elongated bodies can turn to make room.
   As in the force-biased algorithm, the bodies are first inflated (scale ``INFLATE_FIRST``) and
   deflated linearly to their true size over ``DEFLATE_SWEEPS`` sweeps, then held; pushing
   inflated bodies apart opens room faster than relaxing at the true size (measured: at 50 %
   16x16 cylinders this doubles the fraction of random starts that clear within a few thousand
   sweeps). A start still overlapping after ``HOLD_SWEEPS`` is re-inflated (``INFLATE_AGAIN``).
3. Every ``BATCH_SWEEPS`` sweeps the configuration is checked at the true size by an independent
   pass that changes nothing: if every pair and wall gap is ``>= -tolerance`` it is returned.
4. Dense targets sometimes get stuck in a frustrated cluster (the time to clear overlaps is heavy
   tailed), so after ``CYCLES_PER_START`` deflation cycles a fresh random start is drawn. The
   sub-seeds are ``(seed, attempt)`` and budgets count sweeps, not seconds, so the result depends
   on the seed only.
5. ``max_seconds`` caps the whole call: ``PackingError`` then names the shape, the target and the
   highest volume fraction reached over all attempts (for each attempt, ``fraction * s^3`` with
   ``s`` the largest scale factor of all bodies, about their centres, at which that configuration is
   overlap-free, by bisection). A packing is never returned at another concentration.

Orientations start uniform and are changed only by the relaxation rotations, which act where
bodies overlap; the tests check that the orientation statistics of 30 % packings stay close to
uniform.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from .contact import body_contact_ws, candidate_pairs, new_scratch, pipe_wall_contact
from .rigid import quat_to_matrix, random_quaternions
from .shapes import CUBE, CYLINDER, SPHERE, bounding_radius, principal_inertia, volume

BATCH_SWEEPS = 100
INFLATE_FIRST = 1.08  # scale of the bodies at the start of the first deflation
INFLATE_AGAIN = 1.03  # ... and of the later ones
DEFLATE_SWEEPS = 1000  # sweeps over which the scale falls linearly to 1
HOLD_SWEEPS = 1000  # sweeps at scale 1 before re-inflating
CYCLES_PER_START = 3  # deflation cycles before a fresh random start
PUSH_FRACTION = 3e-4  # push target gap, relative to the bounding radius
ROTATION_WEIGHT = 0.5
MANIFOLD_TOL = 0.1

# The paper's shapes (dimensions in mm = lattice units at dx = 1 mm) and the particle counts of
# paper/reading.md for its 50 mm x 100 mm pipe.
PAPER_SHAPES = {
    "cylinder 8x8": (CYLINDER, (4.0, 4.0, 4.0)),
    "cylinder 8x16": (CYLINDER, (4.0, 4.0, 8.0)),
    "cylinder 16x16": (CYLINDER, (8.0, 8.0, 8.0)),
    "cylinder 16x24": (CYLINDER, (8.0, 8.0, 12.0)),
    "cube 8": (CUBE, (4.0, 4.0, 4.0)),
    "cube 16": (CUBE, (8.0, 8.0, 8.0)),
    "cube 24": (CUBE, (12.0, 12.0, 12.0)),
}
PAPER_COUNTS = {
    ("cylinder 8x8", 0.3): 147, ("cylinder 8x8", 0.5): 244,
    ("cylinder 8x16", 0.3): 73, ("cylinder 8x16", 0.5): 122,
    ("cylinder 16x16", 0.3): 18, ("cylinder 16x16", 0.5): 31,
    ("cylinder 16x24", 0.3): 12, ("cylinder 16x24", 0.5): 20,
    ("cube 8", 0.3): 115, ("cube 8", 0.5): 192,
    ("cube 16", 0.3): 14, ("cube 16", 0.5): 24,
    ("cube 24", 0.3): 4, ("cube 24", 0.5): 7,
}
PAPER_PIPE_RADIUS = 25.0
PAPER_PIPE_LENGTH = 100.0


class PackingError(RuntimeError):
    """A packing could not reach its target. Attributes: ``shape`` (label), ``target`` and
    ``reached`` (volume fractions), ``n_particles``."""

    def __init__(self, shape: str, target: float, reached: float, n_particles: int, reason: str):
        self.shape = shape
        self.target = float(target)
        self.reached = float(reached)
        self.n_particles = int(n_particles)
        super().__init__(
            f"cannot pack {n_particles} x {shape} at volume fraction {target:.4f} ({100 * target:.1f} %): "
            f"{reason}; highest concentration reached without overlap: {reached:.4f} ({100 * reached:.1f} %)"
        )


def shape_label(kind: int, h) -> str:
    """Readable name, e.g. ``cylinder 8x16`` (diameter x length), ``cube 8``, ``sphere 10``."""
    h = np.asarray(h, dtype=np.float64)

    def f(a):
        return f"{a:g}"

    if kind == CYLINDER:
        return f"cylinder {f(2 * h[0])}x{f(2 * h[2])}"
    if kind == CUBE:
        if np.allclose(h, h[0]):
            return f"cube {f(2 * h[0])}"
        return f"box {f(2 * h[0])}x{f(2 * h[1])}x{f(2 * h[2])}"
    if kind == SPHERE:
        return f"sphere {f(2 * h[0])}"
    return f"kind {kind}"


def pipe_volume(radius: float, length: float) -> float:
    return math.pi * radius * radius * length


def count_for_concentration(kind: int, h, radius: float, length: float, fraction: float) -> int:
    """Number of particles closest to the solid volume ``fraction`` of the pipe:
    ``round(fraction * pi R^2 L / V_particle)``.

    This reproduces the counts of the paper's reading (paper/reading.md, ``PAPER_COUNTS``) except
    cylinders 8x8 at 30 %: 146.48 rounds to 146 (29.90 %); ``PAPER_COUNTS`` has 147 (30.11 %), which
    follows from a particle volume rounded to 402 mm^3."""
    if not (0.0 < fraction < 1.0):
        raise ValueError(f"fraction must be in (0, 1), got {fraction}")
    return int(round(fraction * pipe_volume(radius, length) / volume(kind, h)))


def achieved_concentration(kind: int, h, n_particles: int, radius: float, length: float) -> float:
    """Solid volume fraction of ``n_particles`` bodies in the pipe."""
    return n_particles * volume(kind, h) / pipe_volume(radius, length)


# ------------------------------------------------------------------------------------------------
# kernels


@njit(cache=True)
def _rotate_by(q, th0, th1, th2):
    # q <- exp(theta) (x) q: the rotation by the lab-frame vector theta applied after q
    ang = math.sqrt(th0 * th0 + th1 * th1 + th2 * th2)
    if ang == 0.0:
        return
    s = math.sin(0.5 * ang) / ang
    aw = math.cos(0.5 * ang)
    ax = s * th0
    ay = s * th1
    az = s * th2
    w = aw * q[0] - ax * q[1] - ay * q[2] - az * q[3]
    x = aw * q[1] + ax * q[0] + ay * q[3] - az * q[2]
    y = aw * q[2] - ax * q[3] + ay * q[0] + az * q[1]
    z = aw * q[3] + ax * q[2] - ay * q[1] + az * q[0]
    nn = math.sqrt(w * w + x * x + y * y + z * z)
    q[0] = w / nn
    q[1] = x / nn
    q[2] = y / nn
    q[3] = z / nn


@njit(cache=True)
def _lever_body(i, c, nrm, x, Rm, out):
    # body-frame components of l x n, l = c - x_i
    lx = c[0] - x[i, 0]
    ly = c[1] - x[i, 1]
    lz = c[2] - x[i, 2]
    tx = ly * nrm[2] - lz * nrm[1]
    ty = lz * nrm[0] - lx * nrm[2]
    tz = lx * nrm[1] - ly * nrm[0]
    out[0] = Rm[i, 0, 0] * tx + Rm[i, 1, 0] * ty + Rm[i, 2, 0] * tz
    out[1] = Rm[i, 0, 1] * tx + Rm[i, 1, 1] * ty + Rm[i, 2, 1] * tz
    out[2] = Rm[i, 0, 2] * tx + Rm[i, 1, 2] * ty + Rm[i, 2, 2] * tz


@njit(cache=True)
def _winv(i, c, nrm, x, Rm, iinv, rotw, tb):
    # generalised inverse mass 1/m + (l x n) . J^-1 (l x n), m = 1
    _lever_body(i, c, nrm, x, Rm, tb)
    return 1.0 + rotw * (iinv[0] * tb[0] * tb[0] + iinv[1] * tb[1] * tb[1] + iinv[2] * tb[2] * tb[2])


@njit(cache=True)
def _push(i, c, nrm, sgn, lam, x, q, Rm, iinv, rotw, tb):
    # displacement sgn*lam along nrm at the contact point: translation lam/m and rotation
    # theta = sgn*lam J^-1 (l x n) (lab frame, J^-1 = A diag(iinv) A^T)
    _lever_body(i, c, nrm, x, Rm, tb)
    b0 = rotw * iinv[0] * tb[0]
    b1 = rotw * iinv[1] * tb[1]
    b2 = rotw * iinv[2] * tb[2]
    th0 = Rm[i, 0, 0] * b0 + Rm[i, 0, 1] * b1 + Rm[i, 0, 2] * b2
    th1 = Rm[i, 1, 0] * b0 + Rm[i, 1, 1] * b1 + Rm[i, 1, 2] * b2
    th2 = Rm[i, 2, 0] * b0 + Rm[i, 2, 1] * b1 + Rm[i, 2, 2] * b2
    for k in range(3):
        x[i, k] += sgn * lam * nrm[k]
    _rotate_by(q[i], sgn * lam * th0, sgn * lam * th1, sgn * lam * th2)
    Rm[i] = quat_to_matrix(q[i])


@njit(cache=True)
def _relax_sweeps(kind, h, x, q, iinv, radius, lo, hi, periodic, push, nsweeps, rotw):
    """``nsweeps`` Gauss-Seidel sweeps pushing every overlapping pair and body-wall contact to the
    gap ``+push``. Returns the largest overlap met in the last sweep."""
    n = x.shape[0]
    Rm = np.empty((n, 3, 3))
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
    rb = bounding_radius(kind, h)
    rbv = np.full(n, rb)
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    tb = np.empty(3)
    ws = new_scratch()  # once, not per pair: a scratch is 18 small arrays
    worst = 0.0
    for _sw in range(nsweeps):
        worst = 0.0
        pi, pj, ps = candidate_pairs(x, rbv, 0.0, lo, hi, periodic)
        for m in range(pi.shape[0]):
            i = pi[m]
            j = pj[m]
            for k in range(3):
                x2[k] = x[j, k] + ps[m, k]
            g = body_contact_ws(kind, h, x[i], Rm[i], kind, h, x2, Rm[j], 0.0, MANIFOLD_TOL, nrm, c, ws)
            if g >= 0.0:
                continue
            worst = max(worst, -g)
            w1 = _winv(i, c, nrm, x, Rm, iinv, rotw, tb)
            for k in range(3):
                x2[k] = c[k] - ps[m, k]  # the contact point seen from body j's own image
            w2 = _winv(j, x2, nrm, x, Rm, iinv, rotw, tb)
            lam = (push - g) / (w1 + w2)
            _push(i, c, nrm, -1.0, lam, x, q, Rm, iinv, rotw, tb)
            _push(j, x2, nrm, 1.0, lam, x, q, Rm, iinv, rotw, tb)
        for i in range(n):
            if math.sqrt(x[i, 0] ** 2 + x[i, 1] ** 2) + rb < radius:
                continue
            g = pipe_wall_contact(kind, h, x[i], Rm[i], radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c)
            if g >= 0.0:
                continue
            worst = max(worst, -g)
            w1 = _winv(i, c, nrm, x, Rm, iinv, rotw, tb)
            _push(i, c, nrm, -1.0, (push - g) / w1, x, q, Rm, iinv, rotw, tb)
    return worst


@njit(cache=True)
def _max_overlap(kind, h, x, q, radius, lo, hi, periodic):
    """Largest overlap (max of -gap, 0 if none) over all pairs and the pipe wall, for bodies of
    half-extents ``h``; changes nothing."""
    n = x.shape[0]
    Rm = np.empty((n, 3, 3))
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
    rb = bounding_radius(kind, h)
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    ws = new_scratch()
    worst = 0.0
    pi, pj, ps = candidate_pairs(x, np.full(n, rb), 0.0, lo, hi, periodic)
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
        g = body_contact_ws(kind, h, x[i], Rm[i], kind, h, x2, Rm[j], 0.0, MANIFOLD_TOL, nrm, c, ws)
        worst = max(worst, -g)
    for i in range(n):
        if math.sqrt(x[i, 0] ** 2 + x[i, 1] ** 2) + rb < radius:
            continue
        g = pipe_wall_contact(kind, h, x[i], Rm[i], radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c)
        worst = max(worst, -g)
    return worst


@njit(cache=True)
def _lateral_extents(kind, h, q):
    """For each orientation, the largest distance from the centre of a body point projected on
    the cross-section (x, y): the body fits in the pipe iff its centre is within R minus this."""
    n = q.shape[0]
    out = np.empty(n)
    nrm = np.empty(3)
    c = np.empty(3)
    origin = np.zeros(3)
    for i in range(n):
        out[i] = -pipe_wall_contact(kind, h, origin, quat_to_matrix(q[i]), 0.0, 0.0, 0.0, MANIFOLD_TOL, nrm, c)
    return out


# ------------------------------------------------------------------------------------------------
# driver


def _overlap_free_scale(kind, h, x, q, radius, lo, hi, periodic, tolerance) -> float:
    """Largest s in [0, 1] (to 1e-4) at which bodies scaled by s about their centres have no
    overlap beyond ``tolerance``."""
    a, b = 0.0, 1.0
    if _max_overlap(kind, h, x, q, radius, lo, hi, periodic) <= tolerance:
        return 1.0
    while b - a > 1e-4:
        m = 0.5 * (a + b)
        if _max_overlap(kind, h * m, x, q, radius, lo, hi, periodic) <= tolerance:
            a = m
        else:
            b = m
    return a


def _compile_kernels() -> None:
    """Compile (or load from numba's cache) the packing's kernels on two tiny bodies, so that
    ``max_seconds`` times the search and not a cold first compile, which takes most of a minute
    and would otherwise turn a packable target into a ``PackingError`` on a fresh machine."""
    h = np.full(3, 0.5)
    x = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.5]])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    lo = np.array([-3.0, -3.0, 0.0])
    hi = np.array([3.0, 3.0, 6.0])
    periodic = np.array([False, False, True])
    _relax_sweeps(CUBE, h, x, q, np.ones(3), 3.0, lo, hi, periodic, 1e-3, 1, ROTATION_WEIGHT)
    _max_overlap(CUBE, h, x, q, 3.0, lo, hi, periodic)


def pack(
    kind: int,
    h,
    n_particles: int,
    radius: float,
    length: float,
    seed: int,
    max_seconds: float = 60.0,
    tolerance: float = 1e-3,
    rotation_weight: float = ROTATION_WEIGHT,
) -> tuple[np.ndarray, np.ndarray]:
    """``n_particles`` bodies of one shape (``kind``, half-extents ``h``) at uniformly random
    positions and orientations, without overlap (every pair and body-wall gap ``>= -tolerance``,
    in the length unit of ``h``), inside a pipe of ``radius`` about the z axis, periodic along z
    with ``length``.

    Returns ``(x (N, 3), q (N, 4))``: centres (z in ``[0, length)``) and unit quaternions
    (body -> lab). Deterministic for ``seed``. Raises ``PackingError`` (with the highest volume
    fraction reached) if the target is not reached within ``max_seconds``; ``ValueError`` for
    invalid input. Method: module docstring.
    """
    _compile_kernels()
    t0 = time.perf_counter()
    kind = int(kind)
    h = np.ascontiguousarray(h, dtype=np.float64).reshape(3)
    n = int(n_particles)
    if n < 1:
        raise ValueError(f"n_particles must be >= 1, got {n_particles}")
    if not (radius > 0 and length > 0 and np.all(h > 0)):
        raise ValueError(f"radius, length and h must be > 0 (radius={radius}, length={length}, h={h})")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    label = shape_label(kind, h)
    target = achieved_concentration(kind, h, n, radius, length)
    rb = bounding_radius(kind, h)
    if length < 4.0 * rb:
        raise ValueError(f"pipe length {length} is shorter than two bounding diameters ({4 * rb:.3g}) of {label}")
    if target >= 1.0:
        raise PackingError(label, target, 0.0, n, "the particles' volume exceeds the pipe's")

    inertia = principal_inertia(kind, h, 1.0 / volume(kind, h))  # per unit mass; only ratios matter
    iinv = 1.0 / inertia
    lo = np.array([-radius, -radius, 0.0])
    hi = np.array([radius, radius, float(length)])
    periodic = np.array([False, False, True])
    push = max(0.5 * tolerance, PUSH_FRACTION * rb)
    best = 0.0
    attempt = 0
    cycle_len = DEFLATE_SWEEPS + HOLD_SWEEPS
    while True:
        rng = np.random.default_rng([int(seed), attempt])
        q = random_quaternions(n, rng)
        # centre uniform over the cross-section the body can reach in its orientation
        reach = np.maximum(radius - _lateral_extents(kind, h, q), 0.0)
        r = reach * np.sqrt(rng.random(n))
        phi = 2.0 * np.pi * rng.random(n)
        x = np.column_stack([r * np.cos(phi), r * np.sin(phi), length * rng.random(n)])
        for done in range(0, CYCLES_PER_START * cycle_len, BATCH_SWEEPS):
            cycle, t_in = divmod(done, cycle_len)
            s_top = INFLATE_FIRST if cycle == 0 else INFLATE_AGAIN
            s = 1.0 + (s_top - 1.0) * max(0.0, 1.0 - t_in / DEFLATE_SWEEPS)
            _relax_sweeps(kind, h * s, x, q, iinv, float(radius), lo, hi, periodic, push * s, BATCH_SWEEPS,
                          float(rotation_weight))
            # done as soon as the bodies at their true size are clear (even while still inflated)
            if _max_overlap(kind, h, x, q, float(radius), lo, hi, periodic) <= tolerance:
                x[:, 2] = np.mod(x[:, 2], length)
                x[x[:, 2] >= length, 2] -= length  # np.mod(-1e-17, L) == L
                return x, q
            if time.perf_counter() - t0 > max_seconds:
                s = _overlap_free_scale(kind, h, x, q, float(radius), lo, hi, periodic, tolerance)
                best = max(best, target * s**3)
                raise PackingError(label, target, best, n,
                                   f"no overlap-free packing found within {max_seconds:g} s ({attempt + 1} random starts)")
        s = _overlap_free_scale(kind, h, x, q, float(radius), lo, hi, periodic, tolerance)
        best = max(best, target * s**3)
        attempt += 1


def max_overlap(kind: int, h, x, q, radius: float, length: float) -> float:
    """Largest overlap (``max(-gap)``, 0 if none) of a packing over all pairs (periodic along z)
    and the pipe wall."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    q = np.ascontiguousarray(q, dtype=np.float64)
    h = np.ascontiguousarray(h, dtype=np.float64).reshape(3)
    lo = np.array([-radius, -radius, 0.0])
    hi = np.array([radius, radius, float(length)])
    return float(_max_overlap(int(kind), h, x, q, float(radius), lo, hi, np.array([False, False, True])))
