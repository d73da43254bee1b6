"""Rigid-body state and motion of the particles: Newton's law, Euler's equations (13) and
quaternion kinematics (14)-(15).

State (structure of arrays, class ``Bodies``): centre of mass ``x`` and velocity ``v`` in the lab
frame; orientation as a unit quaternion ``q = (w, x, y, z)`` rotating body frame -> lab frame,
``p_lab = x + A(q) p_body`` with ``A`` the matrix of Eq. (20); angular velocity ``wb`` in the body
frame, whose axes are the principal axes, so the inertia tensor is ``diag(inertia)``.

Equations of motion (unit-agnostic):

- translation: ``m dv/dt = F``, ``dx/dt = v``;
- rotation, Euler's equations in the body frame, Eq. (13):
  ``I_x dO_x/dt = T_x + (I_y - I_z) O_y O_z`` and cyclic, i.e. ``dpi/dt = pi x O + T_body`` with
  ``pi = I O`` the body-frame angular momentum and ``T_body = A^T T_lab``;
- orientation, Eqs. (14)-(15) (Evans 1977): ``dq/dt = 1/2 q (x) (0, O_body)``, which is the same
  as ``dA/dt = A [O_body]_x``, so the lab angular velocity is ``A O_body``.

Integrator (``advance``): a Strang splitting into kicks and a torque-free drift,

    kick(dt/2) -> drift(dt) -> kick(dt/2),

- ``kick_linear``: ``v += dt F / m`` (exact for the force held fixed);
- ``kick_angular``: ``pi += dt A(q)^T T_lab`` at the current orientation (exact flow of the torque
  alone with ``q`` frozen; the second half-kick uses the new orientation);
- ``drift``: ``x += dt v`` and torque-free rotation by the symplectic splitting of the free rigid
  body of Dullweber, Leimkuhler & McLachlan (J. Chem. Phys. 107, 5840 (1997)):
  ``H = pi_1^2/2I_1 + pi_2^2/2I_2 + pi_3^2/2I_3`` is split into its three terms, each of which is
  an exact rotation about one body axis by angle ``theta = (pi_k/I_k) t``
  (``pi`` rotates by ``-theta``, ``q <- q (x) (cos theta/2, sin theta/2 e_k)``), composed
  symmetrically as ``R1(dt/2) R2(dt/2) R3(dt) R2(dt/2) R1(dt/2)``.

Properties: second order in ``dt`` (symmetric composition of exact sub-flows); time-reversible and
symplectic; the torque-free drift conserves ``|pi|`` and the lab angular momentum ``A pi`` exactly
(each sub-flow does) and the energy to ``O(dt^2)`` without secular drift; ``q`` changes only by
multiplication with unit quaternions, and is renormalised each drift so ``|q| = 1`` to round-off.
Fixed bodies (``fixed[i]``) never move and keep ``v = wb = 0``.

The kernels (``*_arrays``) are ``@njit`` loops over bodies; the Python wrappers take a ``Bodies``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit

from .shapes import principal_inertia, volume

# ----------------------------------------------------------------------------------------------
# Quaternions (w, x, y, z), Hamilton product; q rotates body -> lab.


@njit(cache=True)
def qmul(aw, ax, ay, az, bw, bx, by, bz):
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True)
def _rot(qw, qx, qy, qz, vx, vy, vz):
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (qx, qy, qz): q v q* for unit q, without a matrix.
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (
        vx + qw * tx + (qy * tz - qz * ty),
        vy + qw * ty + (qz * tx - qx * tz),
        vz + qw * tz + (qx * ty - qy * tx),
    )


@njit(cache=True)
def quat_mul(a, b):
    """Hamilton product ``a (x) b`` of two quaternions (4,) -> (4,)."""
    r = qmul(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = r
    return out


@njit(cache=True)
def quat_normalize(q):
    """``q / |q|`` as a new array (4,)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q / n


@njit(cache=True)
def quat_to_matrix(q):
    """Rotation matrix ``A`` (3, 3) of the unit quaternion ``q``, body -> lab (Eq. (20)):
    ``p_lab = A p_body``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    a = np.empty((3, 3))
    a[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    a[0, 1] = 2.0 * (x * y - w * z)
    a[0, 2] = 2.0 * (x * z + w * y)
    a[1, 0] = 2.0 * (x * y + w * z)
    a[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    a[1, 2] = 2.0 * (y * z - w * x)
    a[2, 0] = 2.0 * (x * z - w * y)
    a[2, 1] = 2.0 * (y * z + w * x)
    a[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return a


@njit(cache=True)
def quat_to_matrices(q):
    """``quat_to_matrix`` for each row of ``q`` (N, 4) -> (N, 3, 3)."""
    n = q.shape[0]
    out = np.empty((n, 3, 3))
    for i in range(n):
        out[i] = quat_to_matrix(q[i])
    return out


@njit(cache=True)
def rotate(q, v):
    """Body -> lab: ``A(q) v`` for a unit quaternion ``q`` (4,) and vector ``v`` (3,)."""
    r = _rot(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    out = np.empty(3)
    out[0], out[1], out[2] = r
    return out


@njit(cache=True)
def rotate_inv(q, v):
    """Lab -> body: ``A(q)^T v`` (rotation by the conjugate quaternion)."""
    r = _rot(q[0], -q[1], -q[2], -q[3], v[0], v[1], v[2])
    out = np.empty(3)
    out[0], out[1], out[2] = r
    return out


@njit(cache=True)
def quat_from_axis_angle(axis, angle):
    """Unit quaternion of a right-handed rotation by ``angle`` (rad) about ``axis`` (3,, any
    length). A zero axis gives the identity."""
    n = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    out = np.zeros(4)
    if n == 0.0:
        out[0] = 1.0
        return out
    s = math.sin(0.5 * angle) / n
    out[0] = math.cos(0.5 * angle)
    out[1] = s * axis[0]
    out[2] = s * axis[1]
    out[3] = s * axis[2]
    return out


def random_quaternions(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` unit quaternions (n, 4) uniformly distributed on SO(3) (Haar measure).

    A 4-D isotropic Gaussian vector normalised is uniform on the 3-sphere, and the double cover
    S^3 -> SO(3) maps that to the Haar measure. The sign is fixed to ``w >= 0`` (``q`` and ``-q``
    are the same rotation)."""
    q = rng.standard_normal((int(n), 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[q[:, 0] < 0.0] *= -1.0
    return q


# ----------------------------------------------------------------------------------------------
# State


def _as(a, dtype, shape, name):
    # Always an owned, writable, C-contiguous copy: the kernels update these arrays in place.
    arr = np.array(a, dtype=dtype, copy=True, order="C")
    if arr.shape != shape:
        raise ValueError(f"Bodies.{name}: expected shape {shape}, got {arr.shape}")
    return arr


@dataclass
class Bodies:
    """N rigid bodies, structure of arrays (see the module docstring for frames and units).

    ``kind (N,) int64``, ``h (N,3)`` half-extents, ``mass (N,)``, ``inertia (N,3)`` principal
    moments (body frame), ``x (N,3)`` centre of mass (lab), ``v (N,3)`` velocity (lab),
    ``q (N,4)`` unit quaternion body -> lab, ``wb (N,3)`` angular velocity (body frame),
    ``fixed (N,) bool``.
    """

    kind: np.ndarray
    h: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    x: np.ndarray
    v: np.ndarray
    q: np.ndarray
    wb: np.ndarray
    fixed: np.ndarray

    def __post_init__(self):
        n = np.asarray(self.kind).reshape(-1).shape[0]
        self.kind = _as(np.asarray(self.kind).reshape(-1), np.int64, (n,), "kind")
        self.h = _as(self.h, np.float64, (n, 3), "h")
        self.mass = _as(self.mass, np.float64, (n,), "mass")
        self.inertia = _as(self.inertia, np.float64, (n, 3), "inertia")
        self.x = _as(self.x, np.float64, (n, 3), "x")
        self.v = _as(self.v, np.float64, (n, 3), "v")
        self.q = _as(self.q, np.float64, (n, 4), "q")
        self.wb = _as(self.wb, np.float64, (n, 3), "wb")
        self.fixed = _as(self.fixed, np.bool_, (n,), "fixed")
        moving = ~self.fixed
        if np.any(self.mass[moving] <= 0.0) or np.any(self.inertia[moving] <= 0.0):
            raise ValueError("Bodies: moving bodies need mass > 0 and principal moments > 0")
        norms = np.linalg.norm(self.q, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-6):
            raise ValueError("Bodies.q: quaternions must be unit (|q| = 1 within 1e-6)")
        self.q /= norms[:, None]
        self.v[self.fixed] = 0.0
        self.wb[self.fixed] = 0.0

    @property
    def n(self) -> int:
        return self.kind.shape[0]

    def __len__(self) -> int:
        return self.n

    @classmethod
    def from_arrays(cls, kind, h, mass, inertia, x, v=None, q=None, wb=None, fixed=None) -> "Bodies":
        """Bodies from arrays; ``v``, ``wb`` default to 0, ``q`` to the identity, ``fixed`` to
        False."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        n = x.shape[0]
        if q is None:
            q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        return cls(
            kind=np.broadcast_to(np.asarray(kind, dtype=np.int64), (n,)),
            h=np.broadcast_to(np.asarray(h, dtype=np.float64), (n, 3)),
            mass=np.broadcast_to(np.asarray(mass, dtype=np.float64), (n,)),
            inertia=np.broadcast_to(np.asarray(inertia, dtype=np.float64), (n, 3)),
            x=x,
            v=np.zeros((n, 3)) if v is None else v,
            q=q,
            wb=np.zeros((n, 3)) if wb is None else wb,
            fixed=np.zeros(n, dtype=bool) if fixed is None else np.broadcast_to(fixed, (n,)),
        )

    @classmethod
    def empty(cls) -> "Bodies":
        """No bodies (N = 0)."""
        return cls.from_arrays(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))

    @classmethod
    def make(cls, kind, h, density, x, q=None, v=None, wb=None, fixed=None) -> "Bodies":
        """Bodies of uniform ``density`` at centres ``x`` (N, 3); mass and principal moments follow
        from the shape (``kind`` scalar or (N,), ``h`` (3,) or (N, 3), ``density`` scalar or (N,))."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        n = x.shape[0]
        kind_a = np.broadcast_to(np.asarray(kind, dtype=np.int64), (n,))
        h_a = np.broadcast_to(np.asarray(h, dtype=np.float64), (n, 3))
        rho = np.broadcast_to(np.asarray(density, dtype=np.float64), (n,))
        # Setup only (not inside a time step): one shape formula per body.
        mass = np.array([rho[i] * volume(kind_a[i], h_a[i]) for i in range(n)], dtype=np.float64)
        inertia = np.array([principal_inertia(kind_a[i], h_a[i], rho[i]) for i in range(n)], dtype=np.float64)
        return cls.from_arrays(kind_a, h_a, mass, inertia.reshape(n, 3), x, v=v, q=q, wb=wb, fixed=fixed)

    def copy(self) -> "Bodies":
        return Bodies(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    @classmethod
    def concatenate(cls, parts: list["Bodies"]) -> "Bodies":
        """All bodies of ``parts`` in order, as one ``Bodies``."""
        if not parts:
            return cls.empty()
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})


# ----------------------------------------------------------------------------------------------
# Kernels (arrays in, modified in place)


@njit(cache=True)
def kick_linear_arrays(v, mass, fixed, force, dt):
    """``v += dt F / m`` for non-fixed bodies (Newton's law over an impulse ``F dt``)."""
    for i in range(v.shape[0]):
        if fixed[i]:
            continue
        c = dt / mass[i]
        v[i, 0] += c * force[i, 0]
        v[i, 1] += c * force[i, 1]
        v[i, 2] += c * force[i, 2]


@njit(cache=True)
def kick_angular_arrays(wb, inertia, q, fixed, torque, dt):
    """Body-frame angular momentum ``I wb += dt A(q)^T T_lab`` for non-fixed bodies: the torque
    term of Eq. (13) integrated with the orientation held at ``q``."""
    for i in range(wb.shape[0]):
        if fixed[i]:
            continue
        tb = _rot(q[i, 0], -q[i, 1], -q[i, 2], -q[i, 3], torque[i, 0], torque[i, 1], torque[i, 2])
        wb[i, 0] += dt * tb[0] / inertia[i, 0]
        wb[i, 1] += dt * tb[1] / inertia[i, 1]
        wb[i, 2] += dt * tb[2] / inertia[i, 2]


@njit(cache=True)
def _free_rotate(q, pi, inertia, k, t):
    # Exact flow over time t of H_k = pi_k^2 / (2 I_k): pi_k is constant, so the body spins about
    # body axis k at the fixed rate pi_k / I_k; pi (body frame) turns the opposite way so that
    # the lab angular momentum A pi is unchanged. Eq. (13) restricted to H_k, and Eq. (15).
    theta = pi[k] / inertia[k] * t
    j = (k + 1) % 3
    m = (k + 2) % 3
    c = math.cos(theta)
    s = math.sin(theta)
    pj = pi[j]
    pm = pi[m]
    pi[j] = c * pj + s * pm
    pi[m] = -s * pj + c * pm
    ch = math.cos(0.5 * theta)
    sh = math.sin(0.5 * theta)
    b1 = sh if k == 0 else 0.0
    b2 = sh if k == 1 else 0.0
    b3 = sh if k == 2 else 0.0
    r = qmul(q[0], q[1], q[2], q[3], ch, b1, b2, b3)
    q[0], q[1], q[2], q[3] = r


@njit(cache=True)
def _drift_one(x, v, q, wb, inertia, dt):
    x[0] += dt * v[0]
    x[1] += dt * v[1]
    x[2] += dt * v[2]
    pi = np.empty(3)
    for k in range(3):
        pi[k] = inertia[k] * wb[k]
    # Symmetric (Strang) composition -> second order; Dullweber, Leimkuhler & McLachlan 1997.
    _free_rotate(q, pi, inertia, 0, 0.5 * dt)
    _free_rotate(q, pi, inertia, 1, 0.5 * dt)
    _free_rotate(q, pi, inertia, 2, dt)
    _free_rotate(q, pi, inertia, 1, 0.5 * dt)
    _free_rotate(q, pi, inertia, 0, 0.5 * dt)
    for k in range(3):
        wb[k] = pi[k] / inertia[k]
    # Products of unit quaternions stay unit up to round-off; renormalising stops its random walk.
    nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for k in range(4):
        q[k] /= nq


@njit(cache=True)
def drift_arrays(x, v, q, wb, inertia, fixed, dt):
    """Torque- and force-free motion over ``dt`` for non-fixed bodies: ``x += dt v`` and the
    second-order symplectic free rotation of ``(q, wb)`` (module docstring)."""
    for i in range(x.shape[0]):
        if fixed[i]:
            continue
        _drift_one(x[i], v[i], q[i], wb[i], inertia[i], dt)


@njit(cache=True)
def advance_arrays(x, v, q, wb, mass, inertia, fixed, force, torque, dt):
    """One step ``kick(dt/2) drift(dt) kick(dt/2)`` of all non-fixed bodies under the lab-frame
    ``force`` (N, 3) and ``torque`` (N, 3), held constant over the step. Fixed bodies get
    ``v = wb = 0``."""
    h = 0.5 * dt
    for i in range(x.shape[0]):
        if fixed[i]:
            for k in range(3):
                v[i, k] = 0.0
                wb[i, k] = 0.0
            continue
        for k in range(3):
            v[i, k] += h * force[i, k] / mass[i]
        tb = _rot(q[i, 0], -q[i, 1], -q[i, 2], -q[i, 3], torque[i, 0], torque[i, 1], torque[i, 2])
        for k in range(3):
            wb[i, k] += h * tb[k] / inertia[i, k]
        _drift_one(x[i], v[i], q[i], wb[i], inertia[i], dt)
        for k in range(3):
            v[i, k] += h * force[i, k] / mass[i]
        # second half-kick: same lab torque, seen from the new orientation
        tb = _rot(q[i, 0], -q[i, 1], -q[i, 2], -q[i, 3], torque[i, 0], torque[i, 1], torque[i, 2])
        for k in range(3):
            wb[i, k] += h * tb[k] / inertia[i, k]


@njit(cache=True)
def kinetic_energy_arrays(v, wb, mass, inertia):
    n = v.shape[0]
    out = np.empty(n)
    for i in range(n):
        e = 0.0
        for k in range(3):
            e += mass[i] * v[i, k] * v[i, k] + inertia[i, k] * wb[i, k] * wb[i, k]
        out[i] = 0.5 * e
    return out


@njit(cache=True)
def spin_angular_momentum_arrays(q, wb, inertia):
    n = q.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        r = _rot(
            q[i, 0], q[i, 1], q[i, 2], q[i, 3],
            inertia[i, 0] * wb[i, 0], inertia[i, 1] * wb[i, 1], inertia[i, 2] * wb[i, 2],
        )
        out[i, 0], out[i, 1], out[i, 2] = r
    return out


@njit(cache=True)
def omega_lab_arrays(q, wb):
    n = q.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        r = _rot(q[i, 0], q[i, 1], q[i, 2], q[i, 3], wb[i, 0], wb[i, 1], wb[i, 2])
        out[i, 0], out[i, 1], out[i, 2] = r
    return out


# ----------------------------------------------------------------------------------------------
# Python wrappers (one kernel call each; no loop over bodies here)


def _vec3(a, n, name):
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.shape != (n, 3):
        raise ValueError(f"{name}: expected shape ({n}, 3), got {arr.shape}")
    return arr


def kick_linear(bodies: Bodies, force, dt: float) -> None:
    """Apply the lab-frame impulse ``force * dt`` (force (N, 3)) to the velocities, in place."""
    kick_linear_arrays(bodies.v, bodies.mass, bodies.fixed, _vec3(force, bodies.n, "force"), float(dt))


def kick_angular(bodies: Bodies, torque, dt: float) -> None:
    """Apply the lab-frame torque impulse ``torque * dt`` (torque (N, 3)) to the body-frame angular
    momentum ``I wb`` at the current orientation, in place."""
    kick_angular_arrays(bodies.wb, bodies.inertia, bodies.q, bodies.fixed, _vec3(torque, bodies.n, "torque"), float(dt))


def drift(bodies: Bodies, dt: float) -> None:
    """Free motion over ``dt``, in place: ``x += v dt`` and the torque-free rotation of ``q, wb``
    (Eqs. (13)-(15) with ``T = 0``; second order, exact conservation of ``|I wb|`` and of the lab
    angular momentum)."""
    drift_arrays(bodies.x, bodies.v, bodies.q, bodies.wb, bodies.inertia, bodies.fixed, float(dt))


def advance(bodies: Bodies, force, torque, dt: float) -> None:
    """Advance all non-fixed bodies by ``dt`` under the lab-frame ``force`` and ``torque`` (N, 3),
    in place: ``kick(dt/2) drift(dt) kick(dt/2)`` (module docstring; second order, |q| = 1)."""
    n = bodies.n
    advance_arrays(
        bodies.x, bodies.v, bodies.q, bodies.wb, bodies.mass, bodies.inertia, bodies.fixed,
        _vec3(force, n, "force"), _vec3(torque, n, "torque"), float(dt),
    )


def kinetic_energy(bodies: Bodies) -> np.ndarray:
    """Translational plus rotational kinetic energy (N,): ``m v^2/2 + sum_k I_k wb_k^2/2``."""
    return kinetic_energy_arrays(bodies.v, bodies.wb, bodies.mass, bodies.inertia)


def angular_momentum_lab(bodies: Bodies, origin=None) -> np.ndarray:
    """Lab-frame angular momentum (N, 3): the spin ``A(q) (I wb)`` about each centre of mass, plus,
    if an ``origin`` (3,) is given, the orbital part ``(x - origin) x m v``."""
    ell = spin_angular_momentum_arrays(bodies.q, bodies.wb, bodies.inertia)
    if origin is not None:
        r = bodies.x - np.asarray(origin, dtype=np.float64)
        ell += np.cross(r, bodies.mass[:, None] * bodies.v)
    return ell


def omega_lab(bodies: Bodies) -> np.ndarray:
    """Lab-frame angular velocity (N, 3): ``A(q) wb``."""
    return omega_lab_arrays(bodies.q, bodies.wb)
