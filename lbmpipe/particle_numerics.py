"""The particle-surface options of ``numerics`` (issue 44): how the fluid sees a particle's surface,
how the momentum it exchanges there is counted, how an uncovered node is refilled, and the
sub-grid lubrication between close surfaces. A small model of its own so that ``scene.py``
stays short; ``scene.Numerics`` inherits its fields (so they are listed first in its table).
The defaults are the paper's method: Ladd's half-way bounce-back, Eq. (8), and momentum exchange,
Eqs. (9)-(12)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from lbmpipe.particles.lubrication_params import Lubrication


class ParticleSurfaceNumerics(BaseModel):
    """Particle-surface fields of ``numerics`` (``lbmpipe.particles.coupling.phases`` reads them)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    particle_boundary: Literal["bounce_back", "bouzidi", "cli"] = Field(
        "bounce_back",
        description="Particle surfaces: `bounce_back` (Ladd's half-way moving bounce-back, Eq. (8), the paper's), "
        "`bouzidi` (linear interpolated bounce-back of Bouzidi, Firdaouss & Lallemand 2001) or `cli` (central linear "
        "interpolation of Ginzburg, Verhaeghe & d'Humieres 2008: with `collision: trt` its steady results do not "
        "depend on tau at fixed `trt_magic`), both with the moving-wall term, on the exact distance along each link to "
        "the sphere, cylinder or cube surface; fixed particles too.",
    )
    momentum_exchange: Literal["ladd", "galilean"] = Field(
        "ladd",
        description="Force on free particles: `ladd` (Eqs. (9)-(12), the paper's; fluid + particles conserve "
        "momentum exactly) or `galilean` (Wen et al. 2014: each link counts its populations relative to the wall "
        "velocity, and a covered or uncovered node gives the particle only its momentum relative to the surface, "
        "which removes the force spikes of covering and uncovering).",
    )
    refill: Literal["equilibrium", "extrapolated"] = Field(
        "equilibrium",
        description="Moving particles: populations of a node a particle uncovers. `equilibrium` (the paper's: Eq. (3) "
        "at the surface velocity and the neighbours' mean density) or `extrapolated` (plus the neighbours' "
        "non-equilibrium stress, Grad's approximation: `lbmpipe/particles/coupling/refill_extrapolated.py`).",
    )
    lubrication: Lubrication = Field(default_factory=Lubrication,
                                     description="Sub-grid lubrication between close particle surfaces (off: the paper's method).")
