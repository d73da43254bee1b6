"""Particle-particle and particle-wall collisions: the instantaneous impulse model of the paper,
Eqs. (16)-(21), plus the overlap control that discrete time steps need.

Call ``resolve_collisions`` once per time step, after the velocity update (hydrodynamic forces)
and before the positions are advanced (``CollisionEffect`` does, as an effect of the solver).
Each module holds one algorithm and its physics:

- ``impulse``: the impulse of one contact, Eqs. (16)-(19) and (21) (walls), impacts and loads,
  and the Gauss-Seidel sweep over many contacts;
- ``toi``: speculative contacts: the time of impact of bodies moving freely within the step;
- ``impulse_rounds``: which contacts are active (touching, speculative, touching and turning)
  and the rounds of tests and sweeps;
- ``jam``: contacts still approaching at the sweep cap, locked into rigid clusters;
- ``projection``: the overlap projection (translations, then rotations in a jam);
- ``narrow_phase``: the Verlet list kept between calls, the candidate pairs, and the gaps,
  normals and points of pairs and walls (geometry: ``lbmpipe.particles.contact``);
- ``step``: ``resolve_collisions`` and its kernel, the stages in order, and the overlap bound
  the step keeps;
- ``bundles``: the named tuples of arrays the stages pass each other, and the stats layout;
- ``effect``: ``CollisionEffect``.

The parameters and the domain are in ``lbmpipe.particles.collision_params`` (no kernels: scene
checks import them without compiling anything). This package re-exports the public names.
"""

from ..collision_params import BOX, OVERLAP_BOUND_FACTOR, PIPE, CollisionParams, Domain, min_periodic_length
from .impulse import lab_omegas
from .narrow_phase import NeighbourList
from .step import resolve_collisions
from .effect import CollisionEffect

# the kernels benchmarks/collision_floor.py times one by one
from .impulse import _NG, _gs_sweep, _impulse_terms
from .projection import _measure_pair

__all__ = [
    "BOX", "OVERLAP_BOUND_FACTOR", "PIPE", "CollisionParams", "Domain", "min_periodic_length",
    "lab_omegas", "NeighbourList", "resolve_collisions", "CollisionEffect",
]
