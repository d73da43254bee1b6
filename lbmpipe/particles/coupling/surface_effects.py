"""The particle effects of the surface options (``numerics.particle_boundary``,
``numerics.momentum_exchange``): the fixed particles' interpolated bounce-back and the free
particles' coupling with either option (``interpolated``, ``interpolated_fixed``). The paper's
pair (``bounce_back``, ``ladd``) keeps ``effects.FixedParticles`` and ``effects.ParticleCoupling``;
``phases.particle_effects`` chooses.
"""

from __future__ import annotations

import numba

from ...effect import Effect
from .interpolated import Shapes, couple_free_surface, surface_scratch
from .interpolated_fixed import fixed_fill_surface
from .ladd import accumulate_loads
from .links import clear_changed
from .surface import RULES
from .system import ParticleSystem


def _scratch(system: ParticleSystem):
    # per-thread link buffers as long as the longest particle's lists (as ``system.scratch``)
    return surface_scratch(numba.config.NUMBA_NUM_THREADS, system.scratch[0].shape[1])


class FixedParticlesInterpolated(Effect):
    """Fixed particles: interpolated bounce-back on their links (Bouzidi), force and torque."""

    name = "particles: fixed obstacles (interpolated bounce-back, force)"
    phase = "pre"

    def __init__(self, system: ParticleSystem, boundary: str = "bouzidi"):
        self.system = system
        self.rule = RULES[boundary]
        self.shape = Shapes(system.bodies.kind, system.bodies.h)
        self.scratch = _scratch(system)

    def __call__(self, sim) -> None:
        s = self.system
        ids = s.fixed_ids
        fixed_fill_surface(sim.f2, s.owner, ids, s.body_state, s.loads, s.lat, s.G, s.L, self.shape, self.scratch,
                           self.rule)
        accumulate_loads(ids, s.force, s.torque, s.force_sum, s.torque_sum, s.n_sum)
        if not len(s.free_ids):  # the last link pass of the step
            clear_changed(s.chg, s.chg_list, s.nchg)


class SurfaceCoupling(Effect):
    """Free particles: link sums, implicit velocity update and ghost fill with the interpolated
    bounce-back (``boundary == "bouzidi"``) and/or the Galilean-invariant momentum exchange
    (``exchange == "galilean"``)."""

    phase = "pre"

    def __init__(self, system: ParticleSystem, boundary: str, exchange: str):
        self.system = system
        self.rule = RULES[boundary]
        self.galilean = exchange == "galilean"
        self.name = f"particles: {boundary} + {exchange} coupling + implicit velocity update"
        self.shape = Shapes(system.bodies.kind, system.bodies.h)
        self.scratch = _scratch(system)

    def __call__(self, sim) -> None:
        s = self.system
        ids = s.free_ids
        s.external_loads(sim.force)
        couple_free_surface(sim.f2, s.owner, ids, s.body_state, s.loads, s.lat, s.G, s.L, self.shape, self.scratch,
                            self.rule, self.galilean)
        accumulate_loads(ids, s.force, s.torque, s.force_sum, s.torque_sum, s.n_sum)
        clear_changed(s.chg, s.chg_list, s.nchg)  # the last link pass of the step
