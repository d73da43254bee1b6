"""The assembly of the particle phases: which particle effects a time step runs, and where."""

from __future__ import annotations

from typing import NamedTuple

from ...effect import Effect
from .effects import FixedParticles, ParticleCoupling, ParticleMotion
from .flux_correction import ParticleFluxCorrection
from .mass_correction import MassCorrection
from .system import ParticleSystem
from .wall_guard import BouzidiParticleGuard


class ParticlePhases(NamedTuple):
    """The particle effects of a time step by phase, each list in run order:

    ``pre``: before the sweep (the interpolated-wall guard, the fixed particles' bounce-back, the
    free particles' coupling and ghost fill); ``before_control``: after the sweep, before the
    flow-rate controller (the flux correction); ``after_control``: after the controller (the
    motion and remap, then the mass correction)."""

    pre: list[Effect]
    before_control: list[Effect]
    after_control: list[Effect]


def particle_effects(system: ParticleSystem, flux_control: bool = False, bouzidi_links=None,
                     wall_links=()) -> ParticlePhases:
    """The effects a particle system needs, and nothing else, by phase (``ParticlePhases``). The
    flux correction runs after the sweep and before the flow-rate controller; the motion changes
    the owner map, so it runs after the correction.

    ``flux_control``: the flow is driven at a fixed flow rate (adds the flux correction);
    ``bouzidi_links``: the interpolated wall's links, if the pipe wall is interpolated (adds the
    guard); ``wall_links``: every wall effect's links (the flux correction's wall exchange)."""
    pre: list[Effect] = []
    if bouzidi_links is not None and len(bouzidi_links) and system.n:
        pre.append(BouzidiParticleGuard(system, bouzidi_links))
    if len(system.fixed_ids):
        pre.append(FixedParticles(system))
    if len(system.free_ids):
        pre.append(ParticleCoupling(system))
    before = [ParticleFluxCorrection(system, wall_links)] if flux_control and system.n else []
    after = [ParticleMotion(system), MassCorrection(system)] if len(system.free_ids) else []
    return ParticlePhases(pre, before, after)

