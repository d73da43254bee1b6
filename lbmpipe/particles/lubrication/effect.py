"""``LubricationEffect``: the lubrication step as an effect of the solver's time step, and
``lubrication_effects``, the one call the assembly makes."""

from __future__ import annotations

import numpy as np

from ...effect import Effect
from ...errors import SceneError
from ..collision_params import CollisionParams, Domain, min_periodic_length
from ..collisions.bundles import BodyArrays, DomainArrays, StepParams, VerletArrays
from ..collisions.narrow_phase import NeighbourList
from ..placement import domain_geometry
from .step import lubricate

#: the pair search's margin beyond the cutoff and the Verlet list's extra margin (the collision
#: step's values: lattice spacings)
_SKIN = CollisionParams.skin
_LIST_SKIN = CollisionParams.list_skin


class LubricationEffect(Effect):
    """Lubrication (``post``, after the hydrodynamic velocity update and before the collisions and
    the drift): ``step.lubricate`` on the particle system's bodies, in lattice units (dt = 1). The
    impulses change the velocities the collisions and the drift then use; the fluid sees them in
    the next step's ghost fill, as it sees the collisions' impulses. ``force``, ``torque`` (N, 3):
    each body's lubrication force and torque of the last step (lab, about the centre).

    ``mu``: dynamic viscosity ``rho0 nu`` (lattice units); ``cutoff``, ``min_gap``, ``edge_radius``:
    ``numerics.lubrication`` (lattice spacings); ``manifold_tol``: the flatness tolerance of the
    contact features (the collision model's)."""

    name = "particles: lubrication (implicit pair impulses)"
    phase = "post"
    record_key = "lubrication"

    def __init__(self, system, domain: Domain, mu: float, cutoff: float = 0.8, min_gap: float = 0.01,
                 edge_radius: float = 1.0, manifold_tol: float = CollisionParams.manifold_tol):
        if not 0.0 < min_gap < cutoff:
            raise ValueError(f"lubrication: need 0 < min_gap < cutoff, got {min_gap}, {cutoff}")
        self.system = system
        self.domain = domain
        self.mu = float(mu)
        self.cutoff, self.min_gap, self.edge_radius = float(cutoff), float(min_gap), float(edge_radius)
        self.pairs = system.n > 1
        lo, hi, per = np.array(domain.lo), np.array(domain.hi), np.array(domain.periodic)
        if self.pairs and system.n:
            need = min_periodic_length(float(np.max(system.rb)), self.cutoff, _SKIN)
            short = [a for a in range(3) if per[a] and hi[a] - lo[a] < need]
            if short:
                a = short[0]
                raise SceneError("numerics.lubrication.cutoff_dx",
                                 f"periodic length {hi[a] - lo[a]:g} along {'xyz'[a]} holds less than two interaction "
                                 f"ranges of the lubrication pair search ({need:g} lattice spacings)",
                                 "lower cutoff_dx or lengthen the domain along that axis")
        self.params = StepParams(1.0, self.cutoff, False, CollisionParams.overlap_tol, float(manifold_tol), _SKIN,
                                 1, 1, 1, 1.0, _LIST_SKIN, 0.0, False, self.pairs)
        self.D = DomainArrays(*domain.arrays())
        self.nlist = NeighbourList()
        self.force = np.zeros((system.n, 3))
        self.torque = np.zeros((system.n, 3))
        self.counts = np.zeros(2, np.int64)
        self.totals = {"calls": 0, "pair_contacts": 0, "wall_contacts": 0, "max_force_lu": 0.0}

    def __call__(self, sim) -> None:
        b = self.system.bodies
        B = BodyArrays(b.kind, b.h, b.mass, b.inertia, b.x, b.v, b.q, b.wb, b.fixed)
        nl = self.nlist
        if nl.xref.shape[0] != b.n:
            nl.xref = np.zeros((b.n, 3))
            nl.meta[0] = 0.0
        self.counts[:] = 0
        V = lubricate(B, self.D, self.params, VerletArrays(nl.start, nl.js, nl.win, nl.xref, nl.meta), self.mu,
                      self.min_gap, self.edge_radius, self.force, self.torque, self.counts)
        nl.start, nl.js, nl.win = V.start, V.js, V.win
        t = self.totals
        t["calls"] += 1
        t["pair_contacts"] += int(self.counts[0])
        t["wall_contacts"] += int(self.counts[1])
        if b.n:
            t["max_force_lu"] = max(t["max_force_lu"], float(np.max(np.linalg.norm(self.force, axis=1))))

    def record(self) -> dict:
        """Summary entry: the parameters and the totals over the run (contacts with a force,
        summed over the steps; the largest force on a body in one step)."""
        return {"enabled": True, "cutoff_lu": self.cutoff, "min_gap_lu": self.min_gap, "edge_radius_lu": self.edge_radius,
                **self.totals}


def lubrication_effects(scene, params, system) -> list[Effect]:
    """The lubrication effect the scene asks for (``numerics.lubrication.enabled``), as a list:
    empty without free particles or with lubrication off (the paper's method)."""
    opts = scene.numerics.lubrication
    if system is None or not len(system.free_ids) or not opts.enabled:
        return []
    lo, hi, periodic, radius = domain_geometry(scene, params)
    dom = Domain.pipe(radius, hi[2] - lo[2], z0=lo[2]) if radius > 0 else Domain.box(lo, hi, periodic)
    return [LubricationEffect(system, dom, params.nu_lu * system.rho0, opts.cutoff_dx, opts.min_gap_dx,
                              opts.edge_radius_dx)]
