"""One lubrication step (``lubricate``): the collision narrow phase's contacts within the cutoff,
each contact's resistances (``geometry``), then the implicit impulses (``implicit``). Lattice units;
called once per time step by ``LubricationEffect``."""

from __future__ import annotations

import numpy as np
from numba import njit

from ..collision_params import PIPE
from ..collisions.bundles import _NSTATS
from ..collisions.narrow_phase import measure_contacts, step_pairs
from ..collisions.step import _step_bodies
from .geometry import WALL_NONE, WALL_PIPE, WALL_PLANE, contact_resistance, new_scratch
from .implicit import lubrication_impulses


@njit(cache=True)
def lubricate(B, D, P, V, mu, hmin, re, force, torque, counts):
    """Lubrication impulses of one step of ``P.dt`` on the bodies ``B`` (``BodyArrays``) in the
    domain ``D`` (``DomainArrays``).

    The pairs and walls come from the collision step's stages, unchanged: ``step_pairs`` (the
    Verlet list ``V``, kept between calls) and ``measure_contacts`` with ``P.contact_gap`` the
    cutoff, so every gap below the cutoff is exact and wider ones may be lower bounds (which give
    no force). Inputs: ``P`` (``StepParams``: contact_gap = cutoff, manifold_tol, list_skin, pairs,
    dt, skin), viscosity ``mu``, saturation gap ``hmin``, edge radius ``re``. Outputs: ``B.v``,
    ``B.wb`` (impulses), ``force``, ``torque`` (N, 3): each body's lubrication force and torque of the
    step; ``counts`` += (pair contacts, wall contacts) with a force. Returns the Verlet list (a new
    one if rebuilt). The result does not depend on the thread count."""
    T, _vmax = _step_bodies(B)
    hc = P.contact_gap
    margin = hc + P.skin
    pi, pj, ps, pk, V = step_pairs(B.x, T.rb, margin, D.lo, D.hi, D.periodic, P.list_skin, P.pairs, V)
    stats = np.zeros(_NSTATS)
    C = measure_contacts(B, T, D, P, pi, pj, ps, pk, V.win, margin, hc, stats)
    npair = pi.shape[0]
    nwall = C.wi.shape[0]
    nc = npair + nwall
    ci = np.empty(nc, np.int64)
    cj = np.empty(nc, np.int64)
    shift = np.zeros((nc, 3))
    nrm = np.empty((nc, 3))
    pt = np.empty((nc, 3))
    zn = np.zeros(nc)
    zt = np.zeros(nc)
    S = new_scratch()
    x2 = np.empty(3)
    kind, h, x = B.kind, B.h, B.x
    Rm = T.Rm
    for m in range(npair):
        i = pi[m]
        j = pj[m]
        ci[m] = i
        cj[m] = j
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
            shift[m, k] = ps[m, k]
            nrm[m, k] = C.cn[m, k]
        r = contact_resistance(kind[i], h[i], x[i], Rm[i], kind[j], h[j], x2, Rm[j], WALL_NONE, 0.0, C.cn[m],
                               C.cc[m], C.cg[m], mu, hc, hmin, re, P.manifold_tol, S)
        zn[m], zt[m], pt[m, 0], pt[m, 1], pt[m, 2] = r
        if r[0] > 0.0 or r[1] > 0.0:
            counts[0] += 1
    wall = WALL_PIPE if D.dcode == PIPE else WALL_PLANE
    for w in range(nwall):
        m = npair + w
        i = C.wi[w]
        ci[m] = i
        cj[m] = -1
        for k in range(3):
            nrm[m, k] = C.wn[w, k]
        r = contact_resistance(kind[i], h[i], x[i], Rm[i], kind[i], h[i], x[i], Rm[i], wall, D.Rp, C.wn[w], C.wc[w],
                               C.wg[w], mu, hc, hmin, re, P.manifold_tol, S)
        zn[m], zt[m], pt[m, 0], pt[m, 1], pt[m, 2] = r
        if r[0] > 0.0 or r[1] > 0.0:
            counts[1] += 1
    force[:] = 0.0
    torque[:] = 0.0
    lubrication_impulses(ci, cj, shift, nrm, pt, zn, zt, x, B.v, B.wb, Rm, T.im, T.iinv, P.dt, force, torque)
    return V
