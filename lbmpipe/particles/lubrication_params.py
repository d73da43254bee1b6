"""The scene's lubrication option (``numerics.lubrication``): a small pydantic model that the scene
imports without compiling any kernel (``lbmpipe.particles.lubrication`` holds the model and its
kernels). Lengths in lattice spacings: they are properties of the discrete fluid, not of the
particles."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from lbmpipe.errors import SceneError


class Lubrication(BaseModel):
    """Sub-grid lubrication between close surfaces (`lbmpipe/particles/lubrication/`): below `cutoff_dx` the
    fluid has no node left in the gap, so the squeeze (and, between flat faces, the shear) force of the
    film is added from lubrication theory with the part the lattice resolves subtracted (Nguyen & Ladd
    2002), for particle pairs and particles against the walls. Off by default (the paper's method)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    enabled: bool = Field(False, description="Add the lubrication correction. `false`: none (the paper's method).")
    cutoff_dx: float = Field(
        0.8, gt=0, le=4,
        description="Gap (lattice spacings) below which the correction acts; it is zero above and continuous at it. About "
        "one spacing, where the gap has no fluid node left; 0.8 fits Brenner's force on a sphere approaching a wall "
        "best with Ladd's bounce-back (BGK) and with CLI (TRT, magic 3/16) at tau 1, one value for both boundaries "
        "(benchmarks/README.md, issue 44: lubrication).")
    min_gap_dx: float = Field(
        0.01, gt=0,
        description="Gap (lattice spacings) below which the force stops growing (saturates): surfaces this close count as "
        "touching (roughness), and the collision model takes over.")
    edge_radius_dx: float = Field(
        1.0, gt=0,
        description="Radius of curvature (lattice spacings) given to cube edges and vertices and cylinder rims: the lattice "
        "does not resolve a sharper feature.")

    @model_validator(mode="after")
    def _gaps_ordered(self) -> "Lubrication":
        if self.min_gap_dx >= self.cutoff_dx:
            raise SceneError("numerics.lubrication.min_gap_dx",
                             f"the saturation gap {self.min_gap_dx:g} is not below the cutoff {self.cutoff_dx:g}",
                             "give min_gap_dx < cutoff_dx (e.g. 0.01 and 0.8 lattice spacings)")
        return self
