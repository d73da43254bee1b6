"""Refill of uncovered nodes with the non-equilibrium part carried over (``numerics.refill:
extrapolated``; lattice units).

A node that a moving particle uncovers lies within one step's travel of the body's surface. The
paper's refill (``refill``) gives it the equilibrium Eq. (3) at the surface velocity: the stress of
the fluid around it is missing, and the node's density is that of a few axis neighbours. Here the
node gets Grad's approximation (Grad 1949; as a lattice Boltzmann reconstruction: Chikatamarla,
Ansumali & Karlin 2006, Dorschner et al. 2015), built from its fluid neighbours:

    f_i = f_i^eq(rho, u_b) + w_i / (2 c_s^4) (e_i e_i - c_s^2 I) : Pi^neq,   c_s^2 = 1/3,

* ``u_b = U + Omega x r``, the body's surface velocity at the node (as the paper's);
* ``rho``, the mean density of the node's six nearest neighbours (``x +- e_x``, ``+- e_y``,
  ``+- e_z``) that were fluid before the move (not ``touched``); ``rho0`` if none is (the paper's
  rule takes the two along z if either is fluid, else those along x and y);
* ``Pi^neq``, the mean over the same neighbours of their non-equilibrium stress
  ``sum_i f_i e_i e_i - rho c_s^2 I - j j / rho`` (post-collision populations: the node's are post-
  collision too). Zero if no neighbour is fluid: the paper's equilibrium at ``rho0``.

Why this one. It is a zeroth-order extrapolation of the stress, the part of the non-equilibrium
populations that carries the Navier-Stokes physics, and it needs no surface normal: Caiazzo's
(2008) equilibrium-plus-non-equilibrium refill and Lallemand & Luo's (2003) extrapolation pick
the lattice direction closest to the normal and need one to three fluid nodes along it, which a
cube's edges and corners make ill-defined and a film between two close particles often lacks.
Grad's form drops the ghost moments a raw copy of ``f^neq`` would carry (no third-order noise
enters), and its correction has no mass and no momentum (``sum_i w_i Q_i = 0``, ``sum_i w_i Q_i
e_i = 0``), so the node holds exactly ``rho`` and ``rho u_b``, as the paper's. D3Q15 is isotropic
to fourth order, so the node's second moment is exactly ``rho c_s^2 I + rho u_b u_b + Pi^neq``.
Measured on a sphere translating through fluid at rest (``tests/test_refill.py``): the rms
density change of an uncovered node over its first step falls from 9.8e-4 to 6.2e-4 (tau 0.8) and
from 2.2e-3 to 1.6e-3 (tau 1.78); the drag fluctuation, which the changes of the link set
dominate, stays within 3 % of the paper's refill's. The mass correction does not fall with it: on
the paper's pipe it puts back as much or more (``benchmarks/refill_mass.py``), because the paper's
refill writes a density above the fluid's behind a receding surface (the node's density falls in
its first step), which offsets part of the mass the covered nodes carry away.

Neighbours: the six at distance 1. Adding the eight diagonal ones (distance sqrt 3) reads eight
more scattered nodes per uncovered node and left the density change above no smaller (6.2e-4 and
1.7e-3 with them).

Positivity: where the correction would make a population negative (a film's large stress next to
small equilibrium populations), it is scaled down until the smallest population is zero; mass and
momentum are unchanged (the correction's moments are zero whatever its scale).

Momentum bookkeeping: ``ub[u]`` receives the momentum actually written, ``sum_i f_i e_i`` of the
node (``rho u_b`` up to round-off), which the particle pays (``remap._uncovered_impulse``), so
fluid + particles conserve momentum to round-off.
"""

from __future__ import annotations

from numba import njit

from .nodes import FLUID, decode, node_vector, shifted


@njit(cache=True)
def fill_extrapolated(n_unc, unc_list, unc_old, x, v, om, owner, touched, f2, lat, ub, G):
    """Grad's reconstruction at the surface velocity in each uncovered node (module docstring);
    ``ub[u]`` receives ``(j, r)``: the momentum written and the lever arm. Reads only untouched
    fluid nodes and writes only uncovered ones, so the nodes are independent.

    Inputs (as ``refill.fill_uncovered``): the ``n_unc`` uncovered nodes ``unc_list`` (memory
    nodes, already FLUID in ``owner``) and their former particles ``unc_old``; ``x``, ``v``, ``om``
    (N, 3) centres, velocities and lab angular velocities after the move; ``touched`` (nodes,)
    bool, the nodes whose owner the move may have changed (not read as neighbours); ``f2`` (Q,
    nodes) post-collision populations; ``lat`` (``LatticeRef``), ``G`` (``Grid``).
    Outputs: ``f2[:, node]`` of each uncovered node, every population >= 0 where the equilibrium
    is; ``ub`` (>= n_unc, 6): ``(sum_i f_i e_i, r)``.
    Postconditions: density ``rho`` and momentum ``rho u_b`` at each node to round-off."""
    w, opp, rho0 = lat
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    Q = e.shape[0]
    ny = dims[1]
    cs2 = 1.0 / 3.0
    for u in range(n_unc):
        node = unc_list[u]
        k = unc_old[u]
        a, b, zi = decode(node, ny, az)
        # mean density and non-equilibrium stress of the neighbours that were fluid
        rho = 0.0
        pxx = 0.0
        pyy = 0.0
        pzz = 0.0
        pxy = 0.0
        pxz = 0.0
        pyz = 0.0
        nn = 0
        for m in range(6):  # the six nearest neighbours, +-x, +-y, +-z
            axis = m // 2
            sgn = 2 * (m % 2) - 1
            nb = shifted(a, b, zi, sgn * (axis == 0), sgn * (axis == 1), sgn * (axis == 2), G)
            if owner[nb] != FLUID or touched[nb]:
                continue
            rn = 0.0
            jx = 0.0
            jy = 0.0
            jz = 0.0
            sxx = 0.0
            syy = 0.0
            szz = 0.0
            sxy = 0.0
            sxz = 0.0
            syz = 0.0
            for j in range(Q):
                fv = f2[j, nb]
                cx = e[j, 0] * fv
                cy = e[j, 1] * fv
                rn += fv
                jx += cx
                jy += cy
                jz += e[j, 2] * fv
                sxx += e[j, 0] * cx
                syy += e[j, 1] * cy
                szz += e[j, 2] * e[j, 2] * fv
                sxy += e[j, 1] * cx
                sxz += e[j, 2] * cx
                syz += e[j, 2] * cy
            rho += rn
            pxx += sxx - rn * cs2 - jx * jx / rn
            pyy += syy - rn * cs2 - jy * jy / rn
            pzz += szz - rn * cs2 - jz * jz / rn
            pxy += sxy - jx * jy / rn
            pxz += sxz - jx * jz / rn
            pyz += syz - jy * jz / rn
            nn += 1
        if nn > 0:
            rho /= nn
            pxx /= nn
            pyy /= nn
            pzz /= nn
            pxy /= nn
            pxz /= nn
            pyz /= nn
        else:
            rho = rho0
        tr = (pxx + pyy + pzz) * cs2
        r = node_vector(node, x[k], G)
        ux = v[k, 0] + om[k, 1] * r[2] - om[k, 2] * r[1]
        uy = v[k, 1] + om[k, 2] * r[0] - om[k, 0] * r[2]
        uz = v[k, 2] + om[k, 0] * r[1] - om[k, 1] * r[0]
        usq = 1.5 * (ux * ux + uy * uy + uz * uz)
        # scale of the correction that keeps every population >= 0 (1 unless a film's stress is large)
        scale = 1.0
        for i in range(Q):
            ex = e[i, 0]
            ey = e[i, 1]
            ez = e[i, 2]
            eu = ex * ux + ey * uy + ez * uz
            feq = w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq)
            g = 4.5 * w[i] * (ex * ex * pxx + ey * ey * pyy + ez * ez * pzz
                              + 2.0 * (ex * ey * pxy + ex * ez * pxz + ey * ez * pyz) - tr)
            if feq + scale * g < 0.0 <= feq:
                scale = feq / -g
        jx = 0.0
        jy = 0.0
        jz = 0.0
        for i in range(Q):
            ex = e[i, 0]
            ey = e[i, 1]
            ez = e[i, 2]
            eu = ex * ux + ey * uy + ez * uz
            g = 4.5 * w[i] * (ex * ex * pxx + ey * ey * pyy + ez * ez * pzz
                              + 2.0 * (ex * ey * pxy + ex * ez * pxz + ey * ez * pyz) - tr)
            fv = w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq) + scale * g
            f2[i, node] = fv
            jx += ex * fv
            jy += ey * fv
            jz += ez * fv
        ub[u, 0] = jx
        ub[u, 1] = jy
        ub[u, 2] = jz
        ub[u, 3] = r[0]
        ub[u, 4] = r[1]
        ub[u, 5] = r[2]
