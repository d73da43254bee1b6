"""Cover and uncover with the Galilean-invariant momentum exchange (``numerics.momentum_exchange:
galilean``); lattice units. The remap of ``remap.apply_changes`` (same phases, same owner rules,
same refill), with the momentum a covered or uncovered node gives its particle counted relative to
the surface, as the link force of ``interpolated`` counts the populations relative to the wall
(Wen, Zhang, Tu, Wang & Fang 2014):

* a fluid node covered by particle ``k`` gives ``k`` the impulse ``j - rho u_b`` (``j``, ``rho``:
  its momentum and density; ``u_b = U + Omega x r`` the surface velocity at the node), not ``j``;
* a node of ``k`` that becomes fluid costs ``k`` the momentum written into it relative to the
  surface, ``j' - rho' u_b`` (zero for the equilibrium refill at ``u_b``), not ``j'``.

Why: the node's mass ``rho`` leaves (or enters) the fluid without joining (or leaving) the rigid
particle, whose mass is fixed; Ladd's accounting moves its momentum ``rho u_b`` to the particle
anyway, once per node, so a particle moving through fluid at rest is kicked forward at each cover
and back at each uncover (force spikes of order ``rho |u_b|`` per node and step). Counted relative
to the surface, the kicks are only what the fluid's motion relative to the surface carries.

Conservation: fluid + particles then conserve momentum up to ``sum rho u_b`` over the covered
nodes minus the same over the uncovered ones (the momentum of the mass the remap removes and adds
at the surface velocity; zero on average for a particle in steady motion) and the Galilean link
term. ``moved`` still receives the momentum that left the fluid (``j`` and ``j'``), which the
flux correction needs.
"""

from __future__ import annotations

from numba import njit

from .nodes import FLUID, node_vector
from .refill import fill_uncovered
from .remap import _change_owners, _count_changes, _settle_owners, _uncovered_impulse


@njit(cache=True)
def _relative_cover(nt, x, v, om, owner, f2, moved, S, G):
    # covered nodes (fluid now, a particle next): jb -= rho u_b; the fluid still loses j (moved)
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    Q = f2.shape[0]
    for t in range(nt):
        node = touch_list[t]
        k = new_own[t]
        if owner[node] != FLUID or k < 0:
            continue
        rho = 0.0
        for i in range(Q):
            rho += f2[i, node]
        r0, r1, r2 = node_vector(node, x[k], G)
        u0 = v[k, 0] + om[k, 1] * r2 - om[k, 2] * r1
        u1 = v[k, 1] + om[k, 2] * r0 - om[k, 0] * r2
        u2 = v[k, 2] + om[k, 0] * r1 - om[k, 1] * r0
        jb[t, 0] -= rho * u0
        jb[t, 1] -= rho * u1
        jb[t, 2] -= rho * u2
        moved[0] += rho * u0
        moved[1] += rho * u1
        moved[2] += rho * u2


@njit(cache=True)
def _relative_uncover(n_unc, unc_list, unc_old, x, v, om, f2, ub, moved, G):
    # uncovered nodes, after the refill: ub = (j' - rho' u_b, r) from what was written
    e = G.e
    Q = f2.shape[0]
    for u in range(n_unc):
        node = unc_list[u]
        k = unc_old[u]
        rho = 0.0
        j0 = 0.0
        j1 = 0.0
        j2 = 0.0
        for i in range(Q):
            fv = f2[i, node]
            rho += fv
            j0 += e[i, 0] * fv
            j1 += e[i, 1] * fv
            j2 += e[i, 2] * fv
        r0, r1, r2 = node_vector(node, x[k], G)
        u0 = v[k, 0] + om[k, 1] * r2 - om[k, 2] * r1
        u1 = v[k, 1] + om[k, 2] * r0 - om[k, 0] * r2
        u2 = v[k, 2] + om[k, 0] * r1 - om[k, 1] * r0
        ub[u, 0] = j0 - rho * u0
        ub[u, 1] = j1 - rho * u1
        ub[u, 2] = j2 - rho * u2
        ub[u, 3] = r0
        ub[u, 4] = r1
        ub[u, 5] = r2
        moved[0] -= rho * u0
        moved[1] -= rho * u1
        moved[2] -= rho * u2


@njit(cache=True)
def _galilean_owners_and_covered(ids, C, all_ids, R, x, v, om, owner, f2, imp, moved, G, L, S):
    # the phases before the refill, the covered nodes' momentum relative to the surface velocity
    nt = _count_changes(ids, C, owner, S)
    _settle_owners(nt, all_ids, R, owner, f2, S, G)
    _relative_cover(nt, x, v, om, owner, f2, moved, S, G)
    n_cov, n_unc = _change_owners(nt, x, owner, imp, moved, S, G, L)
    return nt, n_cov, n_unc


@njit(cache=True)
def _galilean_uncovered_and_clear(nt, n_unc, x, v, om, f2, imp, moved, G, S):
    # the phases after the refill: the uncovered nodes' momentum relative to the surface velocity
    count, touched, acq, touch_list, unc_list, unc_old, new_own, jb, ub = S
    _relative_uncover(n_unc, unc_list, unc_old, x, v, om, f2, ub, moved, G)
    _uncovered_impulse(n_unc, unc_old, ub, imp, moved)
    for t in range(nt):
        touched[touch_list[t]] = False


def apply_changes_galilean(ids, C, all_ids, R, x, v, om, owner, f2, lat, imp, moved, G, L, S, refill=fill_uncovered):
    """``remap.apply_changes`` with the impulses of covered and uncovered nodes relative to the
    surface velocity (module docstring). Inputs, outputs, postconditions, the serial order and the
    ``refill`` kernel (``remap.REFILLS``, called between two compiled halves) as
    ``remap.apply_changes``; ``imp`` receives the relative impulses, ``moved`` the momentum that
    left the fluid. Returns ``(n_covered, n_uncovered)``."""
    nt, n_cov, n_unc = _galilean_owners_and_covered(ids, C, all_ids, R, x, v, om, owner, f2, imp, moved, G, L, S)
    refill(n_unc, S.unc_list, S.unc_old, x, v, om, owner, S.touched, f2, lat, S.ub, G)
    _galilean_uncovered_and_clear(nt, n_unc, x, v, om, f2, imp, moved, G, S)
    return n_cov, n_unc
