"""``CollisionEffect``: the collision step as an effect of the solver's time step."""

from __future__ import annotations

from ...effect import Effect
from ..collision_params import CollisionParams, Domain
from .narrow_phase import NeighbourList
from .step import resolve_collisions


class CollisionEffect(Effect):
    """Collisions as a step of the solver (``post``, after the hydrodynamic velocity update and
    before the drift): ``resolve_collisions`` on the particle system's bodies, in lattice units
    (dt = 1). With a single movable particle the pair search is skipped (walls only). Keeps the
    run's totals and the largest overlaps for the summary (``record``)."""

    phase = "post"
    record_key = "collisions"

    def __init__(self, system, domain: Domain, params: CollisionParams, pairs: bool = True):
        self.system = system
        self.domain = domain
        self.params = params
        self.pairs = system.n > 1 and pairs
        self.name = ("collisions: impulses + overlap removal" if self.pairs else
                     "collisions: walls only (pairs switched off)" if system.n > 1 else
                     "collisions: walls only (one particle)")
        self.totals = {"calls": 0, "impulses": 0, "pair_contacts": 0, "wall_contacts": 0, "unresolved": 0,
                       "rotation_projections": 0, "locked_bodies": 0,
                       "max_overlap_before_lu": 0.0, "max_overlap_after_lu": 0.0}
        self.last: dict = {}
        self.nlist = NeighbourList()

    def __call__(self, sim) -> None:
        st = resolve_collisions(self.system.bodies, self.domain, self.params, 1.0, pairs=self.pairs,
                                step=sim.step_count, nlist=self.nlist)
        t = self.totals
        t["calls"] += 1
        for k in ("impulses", "pair_contacts", "wall_contacts", "unresolved"):
            t[k] += st[k]
        # .get: a checkpoint from before the rotating projection has no such total
        t["rotation_projections"] = t.get("rotation_projections", 0) + st["rotation_projections"]
        t["locked_bodies"] = t.get("locked_bodies", 0) + st["locked_bodies"]
        t["max_overlap_before_lu"] = max(t["max_overlap_before_lu"], st["max_overlap_before"])
        t["max_overlap_after_lu"] = max(t["max_overlap_after_lu"], st["max_overlap_after"])
        self.last = st

    def record(self) -> dict:
        """Summary entry: parameters, pair search on/off, totals over the run."""
        p = self.params
        return {"enabled": True, "pairs": self.pairs, "restitution": p.restitution, "contact_gap_lu": p.contact_gap,
                "overlap_tol_lu": p.overlap_tol, "overlap_bound_lu": p.overlap_bound, **self.totals}
