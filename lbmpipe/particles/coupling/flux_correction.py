"""Flow-rate control with particles (lattice units).

The fluid kernel's flux sum runs over particle nodes too. ``ParticleFluxCorrection`` replaces it by
the volumetric flow rate of the mixture, fluid momentum (kept by exact bookkeeping of what crosses
wall and particle links and what covering moves) plus the particles' volume flux
``sum_k n_k U_z,k`` (``n_k`` nodes), which the controller then holds.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ...effect import Effect
from ...fluid.boundaries import plane_buffer
from ...fluid.observables import ordered_sum
from .nodes import FLUID
from .system import ParticleSystem


@njit(parallel=True, cache=True)
def wall_exchange(f2, owner, fluid, solid, i, opp, ez):
    """z-momentum the fluid loses through the wall links ``(fluid, solid, i)`` this step:
    ``sum e_iz (f_i(x) + f_opp(i)(s))``: the population that leaves ``x`` and the one the wall
    sends back (any wall rule), on links whose fluid node is not covered by a particle.

    Inputs: ``f2`` (Q, nodes) populations after the wall fill; ``owner`` (nodes,) int32; the wall
    links as (n,) arrays ``fluid``, ``solid``, ``i``, ``opp`` (int64) and ``ez`` (float64, ``e_iz``).
    Output: the sum (lattice momentum units), in 32 fixed chunks combined by ``ordered_sum``: the
    same bits on any thread count."""
    n = fluid.shape[0]
    nchunk = 32
    part = np.zeros(nchunk)
    for c in prange(nchunk):
        acc = 0.0
        for k in range(c * n // nchunk, (c + 1) * n // nchunk):
            if owner[fluid[k]] == FLUID:
                acc += ez[k] * (f2[i[k], fluid[k]] + f2[opp[k], solid[k]])
        part[c] = acc
    return ordered_sum(part)


class ParticleFluxCorrection(Effect):
    """Flow-rate control with particles: replaces the kernel's flux sum (which runs over particle
    nodes too) by the mixture's, ``sum_fluid (j_z - F_z/2) + sum_k n_k U_z,k``.

    The fluid's z-momentum ``P`` (post-collision, fluid nodes) is kept by exact bookkeeping rather
    than summed over the nodes: per step ``P += F_z n_fluid - (exchange through wall links) -
    (exchange through particle links)``, and each move subtracts the momentum of covered nodes and
    adds that of uncovered ones. The wall exchange is summed from each wall link's two slots
    (``wall_exchange``), so it holds for any wall rule. ``P`` is recomputed from the populations
    every ``resync_every`` steps against round-off. Runs after the sweep, before the controller."""

    name = "particles: flow-rate flux correction"
    phase = "post"

    def __init__(self, system: ParticleSystem, wall_links=(), resync_every: int = 1000):
        self.system = system
        parts = [k for k in wall_links if len(k)]
        ez = system.e[:, 2]
        if parts:
            cat = {a: np.concatenate([getattr(k, a) for k in parts]) for a in ("fluid", "solid", "i", "opp")}
        else:
            cat = {a: np.zeros(0, np.int64) for a in ("fluid", "solid", "i", "opp")}
        sel = ez[cat["i"]] != 0
        self.fluid, self.solid = cat["fluid"][sel], cat["solid"][sel]
        self.i, self.opp = cat["i"][sel], cat["opp"][sel]
        self.ez = ez[self.i].astype(np.float64)
        self.resync_every = int(resync_every)
        self.p_fluid = None
        self.steps = 0

    def __call__(self, sim) -> None:
        s = self.system
        f2 = sim.f2  # populations the sweep read, ghost slots included
        if self.p_fluid is None:
            self.p_fluid = float(s.fluid_momentum(f2)[3])
            s.moved[:] = 0.0
        self.p_fluid -= s.moved[2]  # the previous move's covered and uncovered nodes
        s.moved[:] = 0.0
        fz = float(sim.force[2])
        e_wall = wall_exchange(f2, s.owner, self.fluid, self.solid, self.i, self.opp, self.ez)
        self.p_fluid += fz * s.n_fluid - e_wall - float(s.exch[:, 2].sum())
        self.steps += 1
        if self.steps % self.resync_every == 0:
            self.p_fluid = float(s.fluid_momentum(plane_buffer(sim.f_next))[3])
        # per fluid node the kernel sums the streamed j_z + F_z/2 = post-collision j_z - F_z/2
        sim.last_flux = self.p_fluid - 0.5 * fz * s.n_fluid + float(np.dot(s.nown, s.bodies.v[:, 2]))
