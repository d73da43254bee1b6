"""Interpolated pipe walls beside particles: Bouzidi's rule for ``q < 1/2`` reads ``f*_i(x - e_i)``,
and a particle node there holds no fluid; such a link falls back to plain bounce-back."""

from __future__ import annotations

from numba import njit, prange

from ...effect import Effect
from .nodes import FLUID
from .system import ParticleSystem


class BouzidiParticleGuard(Effect):
    """With interpolated walls: a wall link whose second fluid node (``x - e_i``) belongs to a
    particle falls back to plain bounce-back (that node holds no fluid)."""

    name = "particles: interpolated-wall guard"
    phase = "pre"

    def __init__(self, system: ParticleSystem, links):
        sel = (links.q < 0.5) & (links.fluid2 >= 0)
        self.system = system
        self.fluid = links.fluid[sel]
        self.fluid2 = links.fluid2[sel]
        self.solid = links.solid[sel]
        self.i = links.i[sel]
        self.opp = links.opp[sel]

    def __call__(self, sim) -> None:
        _bouzidi_guard(sim.f2, self.system.owner, self.fluid, self.fluid2, self.solid, self.i, self.opp)


@njit(parallel=True, cache=True)
def _bouzidi_guard(f2, owner, fluid, fluid2, solid, i, opp):
    """Plain bounce-back ``f2[opp, solid] = f2[i, fluid]`` on the wall links (n,) whose second
    fluid node ``fluid2`` belongs to a particle while ``fluid`` is still fluid; other links are
    left as the wall rule wrote them. Runs after the wall fill; links independent (any thread count)."""
    for k in prange(len(i)):
        if owner[fluid2[k]] >= 0 and owner[fluid[k]] == FLUID:
            f2[opp[k], solid[k]] = f2[i[k], fluid[k]]
