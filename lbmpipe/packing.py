"""Dense random packings of cylinders, cubes and spheres in a pipe (the paper's initial state:
"particle positions and orientations uniformly random", at 30 % and 50 % solid volume fraction).

The pipe has radius ``R`` about the z axis (x = y = 0) and is periodic along z with length ``L``
(positions are returned with z in ``[0, L)``). Units are whatever ``h`` and ``R`` are in (mm or
lattice units; the paper's lattice has dx = 1 mm).

Method (growth with overlap relaxation, an event-free cousin of Lubachevsky-Stillinger):

1. Random sequential addition at a reduced scale ``s0`` (every half-extent multiplied by
   ``s0 < 1``, chosen so that the reduced volume fraction is at most ``RSA_FRACTION``): centres
   uniform in the pipe, orientations uniform on SO(3) (Haar measure, ``rigid.random_quaternions``),
   a candidate is rejected if it overlaps a placed body or the wall.
2. Growth: the scale is raised by a factor ``1 + step``; the overlaps this creates are relaxed by
   Gauss-Seidel position-based projection: each overlapping pair (and body-wall contact) is pushed
   apart along its contact normal by the generalised inverse masses
   ``w_i = 1/m + (l_i x p) . J_i^-1 (l_i x p)``, i.e. by translation and by a rotation about the
   contact lever arm (so elongated bodies can turn to make room). Contacts come from
   ``lbmpipe.contact`` (GJK/EPA, the same code the collision model uses). If the relaxation
   clears all overlaps the new scale is accepted and the step grows; otherwise the configuration
   goes back to the last overlap-free one and the step is halved.
3. Done when the scale reaches 1 with every gap ``>= -tolerance`` (checked by a final pass over all
   pairs and the wall that changes nothing). If the step falls below ``MIN_STEP`` (jammed) or
   ``max_seconds`` is spent, ``PackingError`` names the shape, the target and the highest volume
   fraction reached (``fraction * s^3`` of the last overlap-free scale). A packing is never
   returned at a concentration other than the one asked for.

Orientations start uniform and are only changed by the relaxation rotations, which act where
bodies touch (mostly at high density and near the wall); the test suite checks that the
orientation statistics stay close to uniform at 30 %.

Deterministic for a given seed: the only randomness is ``numpy.random.default_rng(seed)`` and the
relaxation is sequential; ``max_seconds`` only decides when to give up.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from .contact import body_contact, candidate_pairs, pipe_wall_contact
from .rigid import quat_to_matrix, random_quaternions
from .shapes import CUBE, CYLINDER, SPHERE, bounding_radius, principal_inertia, volume

RSA_FRACTION = 0.12
RSA_ATTEMPTS = 20000
INITIAL_STEP = 0.02
MAX_STEP = 0.05
MIN_STEP = 1e-5
RELAX_SWEEPS = 60
MC_SWEEPS = 4
DEBUG = False
MC_SWEEPS_STUCK = 20
MANIFOLD_TOL = 0.1

# The paper's shapes (dimensions in mm = lattice units at dx = 1 mm) and the particle counts of
# NOTES.md for a 50 mm x 100 mm pipe.
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
    f = lambda a: f"{a:g}"  # noqa: E731
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

    This reproduces the counts of NOTES.md except cylinders 8x8 at 30 %: 146.48 rounds to 146
    (29.90 %); NOTES.md lists 147 (30.11 %), from a particle volume rounded to 402 mm^3. The
    paper's own counts are ``PAPER_COUNTS``."""
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
    # q <- exp(theta) (x) q: rotation by the lab-frame vector theta applied after q
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
def _push(i, c, nrm, sgn, lam, x, q, Rm, iinv, rotw):
    # move body i by sgn*lam along nrm at the contact point c: translation (unit mass) and
    # rotation theta = sgn*lam * J^-1 (l x n) (lab frame, J^-1 = A diag(iinv) A^T)
    lx = c[0] - x[i, 0]
    ly = c[1] - x[i, 1]
    lz = c[2] - x[i, 2]
    tx = ly * nrm[2] - lz * nrm[1]
    ty = lz * nrm[0] - lx * nrm[2]
    tz = lx * nrm[1] - ly * nrm[0]
    b0 = Rm[i, 0, 0] * tx + Rm[i, 1, 0] * ty + Rm[i, 2, 0] * tz
    b1 = Rm[i, 0, 1] * tx + Rm[i, 1, 1] * ty + Rm[i, 2, 1] * tz
    b2 = Rm[i, 0, 2] * tx + Rm[i, 1, 2] * ty + Rm[i, 2, 2] * tz
    b0 *= rotw * iinv[i, 0]
    b1 *= rotw * iinv[i, 1]
    b2 *= rotw * iinv[i, 2]
    th0 = Rm[i, 0, 0] * b0 + Rm[i, 0, 1] * b1 + Rm[i, 0, 2] * b2
    th1 = Rm[i, 1, 0] * b0 + Rm[i, 1, 1] * b1 + Rm[i, 1, 2] * b2
    th2 = Rm[i, 2, 0] * b0 + Rm[i, 2, 1] * b1 + Rm[i, 2, 2] * b2
    for k in range(3):
        x[i, k] += sgn * lam * nrm[k]
    _rotate_by(q[i], sgn * lam * th0, sgn * lam * th1, sgn * lam * th2)
    Rm[i] = quat_to_matrix(q[i])


@njit(cache=True)
def _winv(i, c, nrm, x, Rm, iinv, rotw):
    # generalised inverse mass 1/m + (l x n) . J^-1 (l x n) with m = 1
    lx = c[0] - x[i, 0]
    ly = c[1] - x[i, 1]
    lz = c[2] - x[i, 2]
    tx = ly * nrm[2] - lz * nrm[1]
    ty = lz * nrm[0] - lx * nrm[2]
    tz = lx * nrm[1] - ly * nrm[0]
    b0 = Rm[i, 0, 0] * tx + Rm[i, 1, 0] * ty + Rm[i, 2, 0] * tz
    b1 = Rm[i, 0, 1] * tx + Rm[i, 1, 1] * ty + Rm[i, 2, 1] * tz
    b2 = Rm[i, 0, 2] * tx + Rm[i, 1, 2] * ty + Rm[i, 2, 2] * tz
    return 1.0 + rotw * (iinv[i, 0] * b0 * b0 + iinv[i, 1] * b1 * b1 + iinv[i, 2] * b2 * b2)


@njit(cache=True)
def _relax(kind, hs, x, q, iinv, radius, lo, hi, periodic, push, tol, max_sweeps, rotw):
    """Gauss-Seidel projection sweeps until a sweep sees no overlap beyond ``tol``; overlapping
    contacts are pushed to the gap ``+push``. Returns (largest overlap seen in the last sweep,
    sweeps used)."""
    n = x.shape[0]
    Rm = np.empty((n, 3, 3))
    rb = np.empty(n)
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
        rb[i] = bounding_radius(kind, hs[i])
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    worst = 0.0
    sweeps = 0
    margin = 2.0 * push + tol
    for sweep in range(max_sweeps):
        worst = 0.0
        pi, pj, ps = candidate_pairs(x, rb, margin, lo, hi, periodic)
        for m in range(pi.shape[0]):
            i = pi[m]
            j = pj[m]
            for k in range(3):
                x2[k] = x[j, k] + ps[m, k]
            g = body_contact(kind, hs[i], x[i], Rm[i], kind, hs[j], x2, Rm[j], push, MANIFOLD_TOL, nrm, c)
            if g >= push:
                continue
            if g >= 0.0:
                continue
            worst = max(worst, -g)
            w1 = _winv(i, c, nrm, x, Rm, iinv, rotw)
            for k in range(3):
                x2[k] = c[k] - ps[m, k]
            w2 = _winv(j, x2, nrm, x, Rm, iinv, rotw)
            lam = (push - g) / (w1 + w2)
            _push(i, c, nrm, -1.0, lam, x, q, Rm, iinv, rotw)
            _push(j, x2, nrm, 1.0, lam, x, q, Rm, iinv, rotw)
        for i in range(n):
            if math.sqrt(x[i, 0] ** 2 + x[i, 1] ** 2) + rb[i] < radius - push:
                continue
            g = pipe_wall_contact(kind, hs[i], x[i], Rm[i], radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c)
            if g >= push:
                continue
            if g >= 0.0:
                continue
            worst = max(worst, -g)
            w1 = _winv(i, c, nrm, x, Rm, iinv, rotw)
            _push(i, c, nrm, -1.0, (push - g) / w1, x, q, Rm, iinv, rotw)
        sweeps = sweep + 1
        if worst <= tol:
            break
    return worst, sweeps


@njit(cache=True)
def _max_overlap(kind, hs, x, q, radius, lo, hi, periodic):
    """Largest overlap (max of -gap, 0 if none) over all pairs and the pipe wall; changes
    nothing."""
    n = x.shape[0]
    Rm = np.empty((n, 3, 3))
    rb = np.empty(n)
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
        rb[i] = bounding_radius(kind, hs[i])
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    worst = 0.0
    pi, pj, ps = candidate_pairs(x, rb, 0.0, lo, hi, periodic)
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
        g = body_contact(kind, hs[i], x[i], Rm[i], kind, hs[j], x2, Rm[j], 0.0, MANIFOLD_TOL, nrm, c)
        worst = max(worst, -g)
    for i in range(n):
        g = pipe_wall_contact(kind, hs[i], x[i], Rm[i], radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c)
        worst = max(worst, -g)
    return worst


@njit(cache=True)
def _neighbour_csr(x, rb, skin, lo, hi, periodic):
    n = x.shape[0]
    pi, pj, ps = candidate_pairs(x, rb, skin, lo, hi, periodic)
    m = pi.shape[0]
    start = np.zeros(n + 1, dtype=np.int64)
    for t in range(m):
        start[pi[t] + 1] += 1
        start[pj[t] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    nb = np.empty(2 * m, dtype=np.int64)
    sh = np.empty((2 * m, 3))
    for t in range(m):
        i = pi[t]
        j = pj[t]
        nb[fill[i]] = j
        for k in range(3):
            sh[fill[i], k] = ps[t, k]
        fill[i] += 1
        nb[fill[j]] = i
        for k in range(3):
            sh[fill[j], k] = -ps[t, k]
        fill[j] += 1
    return start, nb, sh


@njit(cache=True)
def _mc(kind, hs, x, q, radius, lo, hi, periodic, rnd, dmax, amax, skin, gmin):
    """Hard-particle Monte Carlo sweeps (random translation in a cube of half-width ``dmax`` and
    rotation by a random vector of components up to ``amax``; a move is accepted if all its gaps
    to the neighbours and the wall stay ``>= gmin``). ``rnd`` (sweeps, N, 6) holds the uniform random
    numbers. Returns the number of accepted moves."""
    n = x.shape[0]
    Rm = np.empty((n, 3, 3))
    rb = np.empty(n)
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
        rb[i] = bounding_radius(kind, hs[i])
    start, nb, sh = _neighbour_csr(x, rb, skin, lo, hi, periodic)
    moved = np.zeros(n)
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    xt = np.empty(3)
    qt = np.empty(4)
    acc = 0
    for sw in range(rnd.shape[0]):
        for i in range(n):
            for k in range(3):
                xt[k] = x[i, k] + dmax * (2.0 * rnd[sw, i, k] - 1.0)
            step = math.sqrt((xt[0] - x[i, 0]) ** 2 + (xt[1] - x[i, 1]) ** 2 + (xt[2] - x[i, 2]) ** 2)
            if moved[i] + step > 0.5 * skin:
                start, nb, sh = _neighbour_csr(x, rb, skin, lo, hi, periodic)
                for k in range(n):
                    moved[k] = 0.0
            for k in range(4):
                qt[k] = q[i, k]
            _rotate_by(qt, amax * (2.0 * rnd[sw, i, 3] - 1.0), amax * (2.0 * rnd[sw, i, 4] - 1.0),
                       amax * (2.0 * rnd[sw, i, 5] - 1.0))
            Rt = quat_to_matrix(qt)
            if math.sqrt(xt[0] ** 2 + xt[1] ** 2) + rb[i] > radius:
                if pipe_wall_contact(kind, hs[i], xt, Rt, radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c) < gmin:
                    continue
            ok = True
            for t in range(start[i], start[i + 1]):
                j = nb[t]
                for k in range(3):
                    x2[k] = x[j, k] + sh[t, k]
                dd = (x2[0] - xt[0]) ** 2 + (x2[1] - xt[1]) ** 2 + (x2[2] - xt[2]) ** 2
                if dd > (rb[i] + rb[j]) ** 2:
                    continue
                if body_contact(kind, hs[i], xt, Rt, kind, hs[j], x2, Rm[j], 0.0, MANIFOLD_TOL, nrm, c) < gmin:
                    ok = False
                    break
            if ok:
                for k in range(3):
                    x[i, k] = xt[k]
                for k in range(4):
                    q[i, k] = qt[k]
                Rm[i] = Rt
                moved[i] += step
                acc += 1
    return acc


@njit(cache=True)
def _rsa(kind, hs, q, radius, length, u, push):
    """Random sequential addition: candidate centres from the uniform numbers ``u`` (A, 3),
    accepted if clear of the wall and of all placed bodies by ``push``. Returns (x, number
    placed)."""
    n = q.shape[0]
    x = np.zeros((n, 3))
    Rm = np.empty((n, 3, 3))
    for i in range(n):
        Rm[i] = quat_to_matrix(q[i])
    rb = bounding_radius(kind, hs[0])
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    placed = 0
    t = 0
    while placed < n and t < u.shape[0]:
        r = radius * math.sqrt(u[t, 0])
        phi = 2.0 * math.pi * u[t, 1]
        cand = np.array([r * math.cos(phi), r * math.sin(phi), length * u[t, 2]])
        t += 1
        if r + rb > radius - push:
            if pipe_wall_contact(kind, hs[placed], cand, Rm[placed], radius, 0.0, 0.0, MANIFOLD_TOL, nrm, c) < push:
                continue
        ok = True
        for j in range(placed):
            dz = x[j, 2] - cand[2]
            dz -= length * math.floor(dz / length + 0.5)
            dx = x[j, 0] - cand[0]
            dy = x[j, 1] - cand[1]
            if dx * dx + dy * dy + dz * dz > (2.0 * rb + push) ** 2:
                continue
            x2[0] = x[j, 0]
            x2[1] = x[j, 1]
            x2[2] = cand[2] + dz
            if body_contact(kind, hs[placed], cand, Rm[placed], kind, hs[j], x2, Rm[j], push, MANIFOLD_TOL, nrm, c) < push:
                ok = False
                break
        if ok:
            for k in range(3):
                x[placed, k] = cand[k]
            placed += 1
    return x, placed


# ------------------------------------------------------------------------------------------------
# driver


def pack(
    kind: int,
    h,
    n_particles: int,
    radius: float,
    length: float,
    seed: int,
    max_seconds: float = 60.0,
    tolerance: float = 1e-3,
    rotation_weight: float = 1.0,
    axial_share: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``n_particles`` bodies of one shape (``kind``, half-extents ``h``) at uniformly random
    positions and orientations, without overlap (every pair and body-wall gap ``>= -tolerance``),
    inside a pipe of ``radius`` about the z axis, periodic along z with ``length``.

    Returns ``(x (N, 3), q (N, 4))``: centres (z in ``[0, length)``) and unit quaternions
    (body -> lab). Deterministic for ``seed``. Raises ``PackingError`` (with the highest volume
    fraction reached) if the target cannot be reached (jammed) within ``max_seconds``; raises
    ``ValueError`` for invalid input. Method: module docstring.
    """
    t0 = time.perf_counter()
    kind = int(kind)
    h = np.asarray(h, dtype=np.float64).reshape(3)
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
    if 2.0 * (2.0 * rb + 3.0 * tolerance) > length:
        raise ValueError(f"pipe length {length} is shorter than two particle diameters ({4 * rb:.3g}) of {label}")
    if target >= 1.0:
        raise PackingError(label, target, 0.0, n, "the particles' volume exceeds the pipe's")

    rng = np.random.default_rng(seed)
    q = random_quaternions(n, rng)
    # mass 1; principal moments per unit mass of the full-size shape (only ratios matter)
    inertia = principal_inertia(kind, h, 1.0 / volume(kind, h))
    iinv = np.tile(1.0 / inertia, (n, 1))
    periodic = np.array([False, False, True])
    push = 0.5 * tolerance
    a = float(axial_share)
    if not (0.0 <= a <= 1.0):
        raise ValueError(f"axial_share must be in [0, 1], got {axial_share}")

    # compression variable c in (0, 1]: volume fraction target * c^3, reached by scaling the
    # bodies by s(c) = c^(1-a) and the pipe length by L(c) = length * c^(-3a)
    def scale(c):
        return c ** (1.0 - a)

    def plen(c):
        return length * c ** (-3.0 * a)

    def bounds(c):
        return np.array([-radius, -radius, 0.0]), np.array([radius, radius, plen(c)])

    # 1. random sequential addition at a low compression
    c = min(1.0, (RSA_FRACTION / target) ** (1.0 / 3.0))
    if a < 1.0:
        # a body must fit in the pipe at the start scale
        c = min(c, (0.9 * radius / rb) ** (1.0 / (1.0 - a)))
    x = None
    for _attempt in range(8):
        hs = np.tile(h * scale(c), (n, 1))
        u = rng.random((RSA_ATTEMPTS + 200 * n, 3))
        x, placed = _rsa(kind, hs, q, radius, plen(c), u, push)
        if placed == n:
            break
        c *= 0.8
    else:
        raise PackingError(label, target, 0.0, n, "random sequential addition failed even at a low density")

    def timed_out():
        return time.perf_counter() - t0 > max_seconds

    # 2. compression with relaxation, and Monte Carlo shaking at the last overlap-free state
    c_valid = c
    x_valid = x.copy()
    q_valid = q.copy()
    step = INITIAL_STEP
    dmax = 0.05 * rb * scale(c)
    amax = 0.05
    failures = 0
    while c_valid < 1.0:
        if timed_out():
            raise PackingError(label, target, target * c_valid**3, n, f"time limit of {max_seconds:g} s reached")
        sv = scale(c_valid)
        hs = np.tile(h * sv, (n, 1))
        lo, hi = bounds(c_valid)
        sweeps = MC_SWEEPS if failures == 0 else MC_SWEEPS_STUCK
        rnd = rng.random((sweeps, n, 6))
        skin = max(4.0 * dmax, 0.1 * rb * sv)
        acc = _mc(kind, hs, x_valid, q_valid, radius, lo, hi, periodic, rnd, dmax, amax, skin, -push)
        ratio = acc / (sweeps * n)
        if DEBUG:
            print(f"c={c_valid:.4f} phi={target * c_valid**3:.4f} step={step:.2e} acc={ratio:.2f} "
                  f"dmax={dmax:.3g} amax={amax:.3g} t={time.perf_counter() - t0:.1f}")
        # keep the acceptance near 1/3: larger moves decorrelate faster until they mostly fail
        fac = min(2.0, max(0.5, ratio / 0.33))
        dmax = min(0.5 * rb * sv, max(1e-6 * rb, dmax * fac))
        amax = min(0.5, max(1e-6, amax * fac))
        c_try = min(1.0, c_valid * (1.0 + step))
        x = x_valid.copy()
        q = q_valid.copy()
        x[:, 2] *= plen(c_try) / plen(c_valid)  # affine compression along z
        hs = np.tile(h * scale(c_try), (n, 1))
        lo, hi = bounds(c_try)
        worst, _ = _relax(kind, hs, x, q, iinv, radius, lo, hi, periodic, push, 0.5 * tolerance, RELAX_SWEEPS,
                          float(rotation_weight))
        if worst <= 0.5 * tolerance and _max_overlap(kind, hs, x, q, radius, lo, hi, periodic) <= tolerance:
            c_valid = c_try
            x_valid = x
            q_valid = q
            step = min(MAX_STEP, 1.5 * step)
            failures = 0
        else:
            step *= 0.5
            failures += 1
            if step < MIN_STEP:
                raise PackingError(label, target, target * c_valid**3, n, "the packing jammed")

    x = x_valid
    q = q_valid
    x[:, 2] = np.mod(x[:, 2], length)
    # 3. independent final check
    lo, hi = bounds(1.0)
    hs = np.tile(h, (n, 1))
    worst = _max_overlap(kind, hs, x, q, radius, lo, hi, periodic)
    if worst > tolerance:  # pragma: no cover - guarded by the acceptance test above
        raise PackingError(label, target, 0.0, n, f"final check found an overlap of {worst:.3g}")
    return x, q


def max_overlap(kind: int, h, x, q, radius: float, length: float) -> float:
    """Largest overlap (``max(-gap)``, 0 if none) of a packing over all pairs (periodic along z)
    and the pipe wall."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    q = np.ascontiguousarray(q, dtype=np.float64)
    hs = np.tile(np.asarray(h, dtype=np.float64).reshape(3), (x.shape[0], 1))
    lo = np.array([-radius, -radius, 0.0])
    hi = np.array([radius, radius, length])
    return float(_max_overlap(int(kind), hs, x, q, float(radius), lo, hi, np.array([False, False, True])))
