"""The particle effects of the time step that wrap the link passes and the motion: the fixed
particles' bounce-back, the free particles' coupling (Eqs. (8)-(12) with the implicit update), and
the rigid-body drift with the remap (Eqs. (13)-(15)). The flux correction, the mass correction and
the interpolated-wall guard sit with their algorithms (``flux_correction``, ``mass_correction``,
``wall_guard``); ``phases.particle_effects`` puts them in order.
"""

from __future__ import annotations

from ...effect import Effect
from ...fluid.boundaries import plane_buffer
from .remap import apply_changes
from .system import ParticleSystem


class FixedParticles(Effect):
    """Fixed particles: half-way bounce-back on their links, force and torque."""

    name = "particles: fixed obstacles (bounce-back, force)"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.fill_fixed(sim.f2)


class ParticleCoupling(Effect):
    """Free particles: link sums, implicit velocity update, Ladd's ghost fill (Eqs. (8)-(12))."""

    name = "particles: Ladd coupling + implicit velocity update"
    phase = "pre"

    def __init__(self, system: ParticleSystem):
        self.system = system

    def __call__(self, sim) -> None:
        self.system.couple_free(sim.f2, sim.force)


class ParticleMotion(Effect):
    """Rigid-body drift of the free particles (Eqs. (13)-(15)) and the remap, with the momentum of
    covered and uncovered nodes."""

    name = "particles: motion + remap (cover/uncover)"
    phase = "post"

    def __init__(self, system: ParticleSystem, remap=apply_changes):
        self.system = system
        self.remap = remap  # remap.apply_changes, or remap_galilean's (numerics.momentum_exchange)

    def __call__(self, sim) -> None:
        self.system.move(plane_buffer(sim.f_next), self.remap)
