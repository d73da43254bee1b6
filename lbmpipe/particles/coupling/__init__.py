"""Rigid particles on the lattice, coupled both ways to the fluid: Ladd's moving bounce-back,
Eqs. (8)-(12), with an implicit particle-velocity update, and the rigid-body motion of
Eqs. (13)-(15) (``lbmpipe.particles.rigid``).

Everything here is in lattice units (dx = dt = 1, reference density ``rho0 = 1``).

One algorithm a file
--------------------
- ``nodes``: owner codes (``WALL``, ``FLUID``, particle ``k >= 0``), the grid bundle ``Grid``,
  node index helpers;
- ``runs``: the nodes a particle covers, as column runs, and what a move changes;
- ``links``: the boundary links between fluid nodes and particle nodes, kept up to date with the
  owner map;
- ``ladd``: Ladd's moving bounce-back and momentum exchange on the links, Eqs. (8)-(12);
- ``implicit``: the implicit velocity update of the free particles;
- ``surface``, ``interpolated``, ``interpolated_fixed``, ``remap_galilean``, ``surface_effects``:
  the options ``numerics.particle_boundary`` (interpolated bounce-back: the link's distance to the
  surface, the rules, the free and fixed particles' kernels) and ``numerics.momentum_exchange``
  (Galilean-invariant exchange, with its remap);
- ``remap``: cover and uncover after a move, with the momentum accounting;
- ``refill``: the populations of an uncovered node (the paper's equilibrium); ``refill_extrapolated``:
  with the neighbours' non-equilibrium stress (``numerics.refill``, ``remap.REFILLS``);
- ``mass_correction``, ``flux_correction``: the mean fluid density, the mixture's flow rate;
- ``wall_guard``: interpolated pipe walls beside particle nodes;
- ``observables``: sums over the fluid nodes;
- ``system``: ``ParticleSystem``, the state and the per-step calls;
- ``effects``, ``phases``: the effects of the time step and their assembly (``particle_effects``);
- ``prefetch``: a cache hint (numba intrinsic) for the link passes.

Nodes and owners
----------------
Every lattice node is exactly one of: static wall (``owner = -2``; the grid's walls and the z
padding), fluid (``owner = -1``) or particle ``k`` (``owner = k >= 0``). A node belongs to a
particle when its centre lies in the closed shape. Rules for nodes that two things claim:

* wall beats particle: a particle reaching into the pipe wall has no nodes there. A link that
  crosses both a particle and the wall is therefore a wall link seen from the fluid node
  (``boundaries.py`` fills it); particle and wall nodes exchange nothing;
* a fixed particle keeps its nodes; a node keeps its owner while the owner still covers it; a node
  covered by several free particles (only where they overlap, which the collision model prevents)
  goes to the first one found, deterministically.

No interior fluid
-----------------
Particle nodes carry no fluid (Aidun, Lu & Ding 1998). The fluid kernel sweeps them like any node,
but the fluid never reads them: every slot a fluid node pulls from a particle node is overwritten
by the ghost fill first. Observables exclude them.

Cost
----
Per step: one pass per particle over its links (``prange`` over particles: a scattered read of
``f*_i(x)`` and a scattered write of the ghost slot per link), the 6x6 solve, the drift, the runs
(one ray per column), the run differences, and the remap, serial over the owner changes (their
order fixes the order of the link lists, so results do not depend on the thread count).
There is no Python loop over particles or links. The paper's 115 cubes of 8 mm have about 190,000
links (110,000 distinct cache lines of ``f`` read, as many written). The link passes are bound by
the latency of those scattered accesses (out of cache after the sweep; prefetched 16 links ahead),
so the coupling costs 1.3x the streaming fluid sweep on 1 thread and the remap 0.6x (measured,
2026-12); ``benchmarks/particles.py`` measures the split. The bare data movement of the two link
passes (one load, one store, one sum per link) costs 0.61-0.68 of the sweep in this layout and
0.50-0.57 fused into the sweep with the rows in cache (``benchmarks/coupling_floor.py``): a link
moves one scattered scalar, where the sweep moves rows with vector instructions, and the paper's
cubes have about 1.4 links per fluid node.
"""

from .effects import FixedParticles, ParticleCoupling, ParticleMotion
from .flux_correction import ParticleFluxCorrection
from .ladd import couple_free, fixed_fill
from .mass_correction import MassCorrection
from .nodes import FLUID, WALL
from .phases import ParticlePhases, particle_effects
from .remap import REFILLS
from .system import ParticleSystem
from .wall_guard import BouzidiParticleGuard

__all__ = [
    "FLUID", "WALL", "BouzidiParticleGuard", "FixedParticles", "MassCorrection", "ParticleCoupling",
    "ParticleFluxCorrection", "ParticleMotion", "ParticlePhases", "ParticleSystem", "REFILLS", "couple_free", "fixed_fill",
    "particle_effects",
]
