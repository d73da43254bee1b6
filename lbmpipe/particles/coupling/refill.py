"""Refill of uncovered nodes: a particle node that becomes fluid after a move gets populations
(lattice units).

The paper's rule: the equilibrium Eq. (3) at the local surface velocity ``u_b = U + Omega x r``
and the mean density of its neighbours that were fluid before the move: the two along z if either
is (their populations share the node's cache lines), else those along x and y, else ``rho0``. The
particle pays the momentum put in (``remap``).
"""

from __future__ import annotations

from numba import njit

from .nodes import FLUID, decode, node_vector, shifted


@njit(cache=True)
def fill_uncovered(n_unc, unc_list, unc_old, x, v, om, owner, touched, f2, lat, ub, G):
    """Equilibrium at the surface velocity in each uncovered node (module docstring); ``ub[u]``
    receives ``(rho u_b, r)``. Reads only untouched fluid nodes and writes only uncovered ones,
    so the nodes are independent (a tight loop whose memory accesses overlap).

    Inputs: the ``n_unc`` uncovered nodes ``unc_list`` (memory nodes, already FLUID in ``owner``)
    and their former particles ``unc_old``; ``x``, ``v``, ``om`` (N, 3) centres, velocities and lab
    angular velocities after the move; ``touched`` (nodes,) bool, the nodes whose owner the move
    may have changed (their populations are not fluid of the previous step: not averaged);
    ``f2`` (Q, nodes) post-collision populations; ``lat`` (``LatticeRef``), ``G`` (``Grid``).
    Outputs: ``f2[:, node]`` of each uncovered node; ``ub`` (>= n_unc, 6): ``(rho u_b, r)``, the
    momentum put in and the lever arm, for the particle's impulse."""
    w, opp, rho0 = lat
    dims, az, origin, periodic, xmap, ymap, zmap, e = G
    Q = e.shape[0]
    ny = dims[1]
    for u in range(n_unc):
        node = unc_list[u]
        k = unc_old[u]
        a, b, zi = decode(node, ny, az)
        # density of the neighbours along z (same cache lines as the node), else along x and y
        rho = 0.0
        nn = 0
        for axis in (2, 0, 1):
            for sgn in (-1, 1):
                nb = shifted(a, b, zi, sgn * (axis == 0), sgn * (axis == 1), sgn * (axis == 2), G)
                if owner[nb] == FLUID and not touched[nb]:
                    s = 0.0
                    for j in range(Q):
                        s += f2[j, nb]
                    rho += s
                    nn += 1
            if nn > 0:
                break
        rho = rho / nn if nn > 0 else rho0
        r = node_vector(node, x[k], G)
        ux = v[k, 0] + om[k, 1] * r[2] - om[k, 2] * r[1]
        uy = v[k, 1] + om[k, 2] * r[0] - om[k, 0] * r[2]
        uz = v[k, 2] + om[k, 0] * r[1] - om[k, 1] * r[0]
        usq = 1.5 * (ux * ux + uy * uy + uz * uz)
        for i in range(Q):
            eu = e[i, 0] * ux + e[i, 1] * uy + e[i, 2] * uz
            f2[i, node] = w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq)
        ub[u, 0] = rho * ux
        ub[u, 1] = rho * uy
        ub[u, 2] = rho * uz
        ub[u, 3] = r[0]
        ub[u, 4] = r[1]
        ub[u, 5] = r[2]
