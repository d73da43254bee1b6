"""The assembly: a scene becomes a simulation (grid, particles, initial state, and the effects
of its time step in order). The top of the package's physics: it imports the fluid and particle
packages and the solver; nothing below imports it.

A time step is the sequence of the effects a scene declares, and nothing else. An effect
(``lbmpipe.effect.Effect``) is one piece of physics with its own cost: the fused stream-and-collide
sweep (whose generated kernel contains exactly the collision operator and forcing the scene asks
for), each wall treatment, a moving wall, the flow-rate controller (``lbmpipe.fluid.effects``), and
particle coupling, rigid-body motion and collisions (``lbmpipe.particles``). ``assemble`` turns a
scene into the ordered list; a feature that is absent is simply not in the list, so there is no
mask and no branch for it anywhere in a step.

Each effect runs in one phase of the step:

* ``pre``: before the sweep, on the post-collision populations ``sim.f`` (wall and particle
  ghost fills, which also yield the momentum exchange);
* ``fluid``: the sweep itself, ``sim.f -> sim.f_next``;
* ``post``: after the sweep (controllers, particle dynamics, collisions).

``assemble`` decides everything about the step once: the kernel (lattice, collision operator and
its rates, forcing, flux sum, precision, density floor), the initial force density, and the
effects of each phase in order. The simulation times every effect separately; the summary reports
seconds per effect. An effect with tallies of its own (mass added by the density floor, collision
totals, mass correction) reports them through ``record()`` under its ``record_key``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effect import Effect
from .fluid import boundaries as bnd
from .fluid import observables as obs
from .fluid.effects import FlowRateControl, StreamCollide, WallBouzidi, stream_collide, wall_effects
from .fluid.lattice import get_lattice
from .guard import guard_for
from .particles.collisions import CollisionEffect, CollisionParams, Domain
from .particles.coupling import REFILLS, ParticleSystem, particle_effects
from .particles.lubrication import lubrication_effects
from .particles.placement import bodies_from_scene, domain_geometry
from .solver import Simulation


@dataclass
class Step:
    """A scene's time step in its named phases, in the order they run.

    ``pre``: ``walls`` then ``particle_fills`` (ghost fills and momentum exchange); ``fluid``: the
    sweep; ``post``: ``flux_correction`` (needs the sweep's owner map), ``control`` (the flow-rate
    controller, reading the corrected flux), ``lubrication`` (implicit film impulses), ``collisions``
    (on the updated particle velocities, before the drift), ``motion`` (drift, then the mass correction: changes the owner map).
    ``force`` is the initial force density (lattice units)."""

    fluid: StreamCollide | None
    force: np.ndarray
    walls: list[Effect] = field(default_factory=list)
    particle_fills: list[Effect] = field(default_factory=list)
    flux_correction: list[Effect] = field(default_factory=list)
    control: list[Effect] = field(default_factory=list)
    lubrication: list[Effect] = field(default_factory=list)
    collisions: list[Effect] = field(default_factory=list)
    motion: list[Effect] = field(default_factory=list)

    @property
    def effects(self) -> list[Effect]:
        return (self.walls + self.particle_fills + [self.fluid] + self.flux_correction + self.control
                + self.lubrication + self.collisions + self.motion)


def collision_effect(scene, params, system):
    """The collision effect the scene asks for (``None`` without free particles or with
    ``particles.collisions.enabled: false``): the particles' domain in lattice units."""
    if system is None or not len(system.free_ids) or not scene.particles.collisions.enabled:
        return None
    lo, hi, periodic, radius = domain_geometry(scene, params)
    dom = Domain.pipe(radius, hi[2] - lo[2], z0=lo[2]) if radius > 0 else Domain.box(lo, hi, periodic)
    c = scene.particles.collisions
    # approaches no faster than twice one step's gravity kick (lattice units, dt = 1) are loads,
    # not impacts (collisions module docstring)
    rest = 2.0 * float(np.linalg.norm(system.gravity))
    return CollisionEffect(system, dom, CollisionParams(restitution=c.restitution, contact_gap=c.contact_gap_dx,
                                                        overlap_tol=c.overlap_tol_dx, rest_speed=rest), pairs=c.pairs)


def assemble(scene, params, grid: bnd.Grid, system=None) -> Step:
    """The time step ``scene`` declares on ``grid`` with the particle system ``system``
    (``coupling.ParticleSystem`` or None): exactly its effects, each decided here once."""
    num = scene.numerics
    walls = wall_effects(grid, num.wall, dict(params.wall_velocities_lu))
    flux = scene.driving.kind == "flow_rate"
    step = Step(fluid=None, force=np.array(params.accel_lu, dtype=np.float64), walls=walls)  # force density = rho_0 g
    if system is not None:
        system.refill = REFILLS[num.refill]  # populations of the nodes a moving particle uncovers
        bouzidi = [e.links for e in walls if isinstance(e, WallBouzidi)]
        phases = particle_effects(system, flux_control=flux, bouzidi_links=bouzidi[0] if bouzidi else None,
                                  wall_links=[e.links for e in walls], boundary=num.particle_boundary,
                                  exchange=num.momentum_exchange)
        step.particle_fills, step.flux_correction, step.motion = phases.pre, phases.before_control, phases.after_control
    if flux:
        ctl = FlowRateControl(params.flow_rate_lu, grid.radius, params.nu_lu, grid.shape[2], grid.n_fluid)
        step.control = [ctl]
        step.force = np.array([0.0, 0.0, ctl.f_ref])
    step.lubrication = lubrication_effects(scene, params, system)  # numerics.lubrication: before the collisions
    collide = collision_effect(scene, params, system)
    step.collisions = [collide] if collide is not None else []
    # the density floor only where free particles can squeeze films
    floor = num.density_floor if system is not None and len(system.free_ids) else None
    step.fluid = stream_collide(grid.lattice.name, params.relaxation, num.precision, step.force, flux, floor)
    return step


def grid_from_scene(scene, params) -> bnd.Grid:
    """The scene's lattice and geometry: a pipe, or a box with its walled axes."""
    lat = get_lattice(scene.numerics.lattice)
    nx, ny, nz = params.shape
    if scene.domain.kind == "pipe":
        return bnd.pipe_grid(lat, nx, nz)
    w = scene.domain.walls
    return bnd.box_grid(lat, (nx, ny, nz), (w.x == "wall", w.y == "wall", w.z == "wall"))


def particle_system_from_scene(scene, params, grid):
    """The scene's particles on ``grid`` as a ``coupling.ParticleSystem`` and their static records,
    or ``(None, [])`` when the scene has none."""
    pspec = scene.particles
    if pspec is None or not (pspec.bodies or pspec.random or pspec.packed):
        return None, []
    info: dict = {}
    bodies, static = bodies_from_scene(scene, params, info)
    gravity = [params.units.acceleration(g) for g in pspec.gravity_m_s2]
    system = ParticleSystem(grid, bodies, gravity=gravity)
    system.packing_info = info
    return system, static


def simulation_from_scene(scene, params, guard: bool = True) -> Simulation:
    """Assemble the simulation a scene declares: exactly its effects (``assemble``), and its
    initial state, with the run-time guard (``lbmpipe.guard``) unless ``guard=False``."""
    grid = grid_from_scene(scene, params)
    system, static = particle_system_from_scene(scene, params, grid)
    step = assemble(scene, params, grid, system)
    sim = Simulation(grid, step.effects, force=step.force)
    sim.particles = system
    sim.particle_static = static
    sim.packing = getattr(system, "packing_info", {}) if system is not None else {}
    if scene.initial.velocity == "parabolic" and grid.kind == "pipe":
        x, y, _ = grid.positions()
        r = np.sqrt(x[:, None] ** 2 + y[None, :] ** 2)
        uz = obs.poiseuille_pipe(r, grid.radius, 2.0 * params.u_mean_lu)[:, :, None]
        sim.set_equilibrium(1.0, (0.0, 0.0, uz))
    if scene.initial.velocity == "linear" and grid.kind == "box":
        a = next(b for b in range(3) if not grid.periodic[b])  # the walled axis (the scene checks it is one)
        w = params.wall_velocities_lu
        lo, hi = w.get(f"{'xyz'[a]}-", (0.0, 0.0, 0.0)), w.get(f"{'xyz'[a]}+", (0.0, 0.0, 0.0))
        u = obs.couette_box(grid.positions()[a], float(params.shape[a]), lo, hi)
        sim.set_equilibrium(1.0, [np.expand_dims(c, tuple(b for b in range(3) if b != a)) for c in u])
    if guard:
        sim.guard = guard_for(sim, scene, params)
    return sim
