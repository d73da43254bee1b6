"""The assembly of the particle phases: which particle effects a time step runs, and where."""

from __future__ import annotations

from typing import NamedTuple

from ...effect import Effect
from .effects import FixedParticles, ParticleCoupling, ParticleMotion
from .flux_correction import ParticleFluxCorrection
from .mass_correction import MassCorrection
from .remap import apply_changes
from .remap_galilean import apply_changes_galilean
from .surface_effects import FixedParticlesInterpolated, SurfaceCoupling
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
                     wall_links=(), boundary: str = "bounce_back", exchange: str = "ladd") -> ParticlePhases:
    """The effects a particle system needs, and nothing else, by phase (``ParticlePhases``). The
    flux correction runs after the sweep and before the flow-rate controller; the motion changes
    the owner map, so it runs after the correction.

    ``flux_control``: the flow is driven at a fixed flow rate (adds the flux correction);
    ``bouzidi_links``: the interpolated wall's links, if the pipe wall is interpolated (adds the
    guard); ``wall_links``: every wall effect's links (the flux correction's wall exchange);
    ``boundary``, ``exchange``: ``numerics.particle_boundary`` and ``numerics.momentum_exchange``
    (the paper's ``bounce_back`` and ``ladd`` keep Ladd's kernels; a fixed particle has no wall
    velocity, so only ``boundary`` changes it)."""
    if boundary not in ("bounce_back", "bouzidi", "cli") or exchange not in ("ladd", "galilean"):
        raise ValueError(f"numerics.particle_boundary {boundary!r} / momentum_exchange {exchange!r}: choose "
                         "bounce_back, bouzidi or cli, and ladd or galilean")
    paper = (boundary, exchange) == ("bounce_back", "ladd")
    pre: list[Effect] = []
    if bouzidi_links is not None and len(bouzidi_links) and system.n:
        pre.append(BouzidiParticleGuard(system, bouzidi_links))
    if len(system.fixed_ids):
        fixed = FixedParticles(system) if boundary == "bounce_back" else FixedParticlesInterpolated(system, boundary)
        pre.append(fixed)
    if len(system.free_ids):
        pre.append(ParticleCoupling(system) if paper else SurfaceCoupling(system, boundary, exchange))
    before = [ParticleFluxCorrection(system, wall_links)] if flux_control and system.n else []
    remap = apply_changes_galilean if exchange == "galilean" else apply_changes
    after = [ParticleMotion(system, remap), MassCorrection(system)] if len(system.free_ids) else []
    return ParticlePhases(pre, before, after)

