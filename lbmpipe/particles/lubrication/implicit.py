"""The lubrication force applied implicitly in each pair's relative velocity (lattice units).

A contact's film resists the relative velocity ``du = u_1(p) - u_2(p)`` of the two surfaces at its
point ``p`` (``u_b = v_b + omega_b x (p - x_b)``; a wall has ``u_2 = 0``) with

    F_1 = -Z du,   Z = zeta_n n n^T + zeta_t (I - n n^T),   F_2 = -F_1 at the same point.

The resistance grows like ``1/h`` (curved surfaces) to ``1/h^3`` (flat faces): explicitly,
``F dt`` would overshoot and reverse ``du`` once ``zeta dt`` exceeds twice the pair's effective mass
(a sphere of radius 4 at gap 0.01 spacing has ``zeta / m`` of 17-47 per step at the paper's tau
0.96-1.78). The impulse is therefore taken at the end-of-step velocity (backward Euler in ``du``):

    du' = du - dt M Z du'  =>  (I + dt M Z) du' = du,   J_1 = -dt Z du',

with ``M = M_1 + M_2`` the mobility of the pair at ``p`` (``M_b = I/m_b - [l_b]x I_b^-1 [l_b]x``,
``l_b = p - x_b``, lab inertia; zero for a fixed body or a wall). It removes kinetic energy
``dt du'.Z du' + J.M J / 2 >= 0`` for any ``zeta``, so the step is stable however thin the film;
as ``zeta dt`` grows the pair's relative velocity is simply brought to rest (the saturation gap
``min_gap_dx`` bounds ``zeta``). Contacts are taken one after the other in the narrow phase's
order, each on the velocities the ones before left (one Gauss-Seidel sweep): every contact removes
energy, so a body in several films is as stable as in one. Each impulse acts on both bodies at
the same point with opposite signs: linear and angular momentum are conserved to round-off.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _mobility(b, l0, l1, l2, Rm, im, iinv, M):
    """M += I/m_b - [l]x I^-1 [l]x of body b at lever arm l (lab; I^-1 = A diag(iinv) A^T)."""
    if im[b] == 0.0:
        return
    Iinv = np.zeros((3, 3))
    for p in range(3):
        for q in range(3):
            acc = 0.0
            for s in range(3):
                acc += Rm[b, p, s] * iinv[b, s] * Rm[b, q, s]
            Iinv[p, q] = acc
    L = np.array([[0.0, -l2, l1], [l2, 0.0, -l0], [-l1, l0, 0.0]])
    LIL = L @ Iinv @ L
    for p in range(3):
        M[p, p] += im[b]
        for q in range(3):
            M[p, q] -= LIL[p, q]


@njit(cache=True)
def _surface_velocity(b, l0, l1, l2, v, wb, Rm):
    """v_b + omega_b x l, omega_b = A_b wb_b (lab)."""
    w0 = Rm[b, 0, 0] * wb[b, 0] + Rm[b, 0, 1] * wb[b, 1] + Rm[b, 0, 2] * wb[b, 2]
    w1 = Rm[b, 1, 0] * wb[b, 0] + Rm[b, 1, 1] * wb[b, 1] + Rm[b, 1, 2] * wb[b, 2]
    w2 = Rm[b, 2, 0] * wb[b, 0] + Rm[b, 2, 1] * wb[b, 1] + Rm[b, 2, 2] * wb[b, 2]
    return v[b, 0] + w1 * l2 - w2 * l1, v[b, 1] + w2 * l0 - w0 * l2, v[b, 2] + w0 * l1 - w1 * l0


@njit(cache=True)
def _kick(b, sgn, J, l0, l1, l2, v, wb, Rm, im, iinv, dt, force, torque):
    """Impulse ``sgn J`` at lever arm l on body b: velocity, body-frame spin, and its force and
    torque over the step."""
    j0 = sgn * J[0]
    j1 = sgn * J[1]
    j2 = sgn * J[2]
    t0 = l1 * j2 - l2 * j1
    t1 = l2 * j0 - l0 * j2
    t2 = l0 * j1 - l1 * j0
    force[b, 0] += j0 / dt
    force[b, 1] += j1 / dt
    force[b, 2] += j2 / dt
    torque[b, 0] += t0 / dt
    torque[b, 1] += t1 / dt
    torque[b, 2] += t2 / dt
    if im[b] == 0.0:
        return
    v[b, 0] += im[b] * j0
    v[b, 1] += im[b] * j1
    v[b, 2] += im[b] * j2
    for s in range(3):  # body frame: dwb = J^-1 A^T (l x J)
        wb[b, s] += iinv[b, s] * (Rm[b, 0, s] * t0 + Rm[b, 1, s] * t1 + Rm[b, 2, s] * t2)


@njit(cache=True)
def _solve3(A, b0, b1, b2):
    """The solution of A y = b (3 x 3, Cramer's rule; A = I + dt M Z is never singular: M and Z are
    symmetric positive semi-definite, so M Z has no negative eigenvalue)."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    y = np.empty(3)
    y[0] = (b0 * c00 + A[0, 1] * (A[1, 2] * b2 - b1 * A[2, 2]) + A[0, 2] * (b1 * A[2, 1] - A[1, 1] * b2)) / det
    y[1] = (A[0, 0] * (b1 * A[2, 2] - A[1, 2] * b2) + b0 * c01 + A[0, 2] * (A[1, 0] * b2 - b1 * A[2, 0])) / det
    y[2] = (A[0, 0] * (A[1, 1] * b2 - b1 * A[2, 1]) + A[0, 1] * (b1 * A[2, 0] - A[1, 0] * b2) + b0 * c02) / det
    return y


@njit(cache=True)
def lubrication_impulses(ci, cj, shift, nrm, pt, zn, zt, x, v, wb, Rm, im, iinv, dt, force, torque):
    """Apply the implicit lubrication impulse of every contact (module docstring), in order.

    Inputs: contacts ``m``: bodies ``ci[m]``, ``cj[m]`` (-1: a wall), body 2's periodic shift
    ``shift[m]`` (it sits at ``x[cj] + shift``), unit normal ``nrm[m]`` (1 -> 2), point ``pt[m]``,
    resistances ``zn[m]``, ``zt[m]`` (a contact with both 0 is skipped); bodies: centres ``x``,
    velocities ``v``, body-frame spins ``wb``, rotation matrices ``Rm``, inverse masses ``im`` and
    principal inverse inertias ``iinv`` (0 for a fixed body), time step ``dt``. Outputs: ``v``,
    ``wb`` updated in place; ``force``, ``torque`` (N, 3) accumulate each body's lubrication force
    and torque (about its centre) over the step. Returns the number of contacts applied."""
    applied = 0
    A = np.empty((3, 3))
    Z = np.empty((3, 3))
    J = np.empty(3)
    for m in range(ci.shape[0]):
        i = ci[m]
        j = cj[m]
        if zn[m] <= 0.0 and zt[m] <= 0.0:
            continue
        if im[i] == 0.0 and (j < 0 or im[j] == 0.0):
            continue
        l10 = pt[m, 0] - x[i, 0]
        l11 = pt[m, 1] - x[i, 1]
        l12 = pt[m, 2] - x[i, 2]
        u0, u1, u2 = _surface_velocity(i, l10, l11, l12, v, wb, Rm)
        M = np.zeros((3, 3))
        _mobility(i, l10, l11, l12, Rm, im, iinv, M)
        l20 = 0.0
        l21 = 0.0
        l22 = 0.0
        if j >= 0:
            l20 = pt[m, 0] - (x[j, 0] + shift[m, 0])
            l21 = pt[m, 1] - (x[j, 1] + shift[m, 1])
            l22 = pt[m, 2] - (x[j, 2] + shift[m, 2])
            w0, w1, w2 = _surface_velocity(j, l20, l21, l22, v, wb, Rm)
            u0 -= w0
            u1 -= w1
            u2 -= w2
            _mobility(j, l20, l21, l22, Rm, im, iinv, M)
        for p in range(3):
            for q in range(3):
                Z[p, q] = (zn[m] - zt[m]) * nrm[m, p] * nrm[m, q]
            Z[p, p] += zt[m]
        # (I + dt M Z) du' = du
        MZ = M @ Z
        for p in range(3):
            for q in range(3):
                A[p, q] = dt * MZ[p, q]
            A[p, p] += 1.0
        du = _solve3(A, u0, u1, u2)
        for p in range(3):
            J[p] = -dt * (Z[p, 0] * du[0] + Z[p, 1] * du[1] + Z[p, 2] * du[2])
        _kick(i, 1.0, J, l10, l11, l12, v, wb, Rm, im, iinv, dt, force, torque)
        if j >= 0:
            _kick(j, -1.0, J, l20, l21, l22, v, wb, Rm, im, iinv, dt, force, torque)
        applied += 1
    return applied
