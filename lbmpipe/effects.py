"""The effects model: a time step is the sequence of the effects a scene declares, and nothing else.

An effect is one piece of physics with its own cost: the fused stream-and-collide sweep (whose
generated kernel contains exactly the collision operator and forcing the scene asks for), each wall
treatment, a moving wall, the flow-rate controller, and, in later layers, particle coupling,
rigid-body motion and collisions. ``assemble`` turns a scene into the ordered list; a feature that
is absent is simply not in the list, so there is no mask and no branch for it anywhere in a step.

Each effect runs in one phase of the step:

* ``pre``: before the sweep, on the post-collision populations ``sim.f`` (wall and particle
  ghost fills, which also yield the momentum exchange);
* ``fluid``: the sweep itself, ``sim.f -> sim.f_next``;
* ``post``: after the sweep (controllers, particle dynamics, collisions).

``assemble`` decides everything about the step once: the kernel (lattice, collision operator,
forcing, flux sum, precision, density floor), the initial force density, and the effects of each
phase in order. The simulation times every effect separately; the summary reports seconds per
effect. An effect with tallies of its own (mass added by the density floor, collision totals,
mass correction) reports them through ``record()`` under its ``record_key``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fluid import boundaries as bnd
from .effect import Effect
from .fluid.kernels import KernelSpec, get_kernel


class StreamCollide(Effect):
    """Fused pull streaming + collision (Eqs. (1)-(4)) with Guo forcing when present.

    With ``rho_min`` (scenes with free particles, ``numerics.density_floor``) the kernel also
    holds every swept node at or above that density (``kernels.py``): a fluid node in a film
    thinner than one spacing, between a particle and the wall or another particle, exchanges
    mass with the rest of the fluid through one or two links only, and the moving bounce-back of
    Eq. (8) behind a receding surface drains it faster than they refill it (measured: 0.07 per
    step at a particle speed of 0.09, density negative within 100 steps, then the run diverges).
    The film is below the resolution of the method either way; the floor adds mass at zero
    momentum, and the tally (``tally``: mass added, node updates floored) goes into the
    summary. Nodes inside particles are swept too and counted alike (they hold no fluid; the
    fluid never reads them), so the tally bounds the fluid's share from above."""

    phase = "fluid"
    record_key = "density_floor"

    def __init__(self, spec: KernelSpec, rho_min: float = 0.0):
        self.spec = spec
        self.kernel = get_kernel(spec)
        self.name = spec.describe()
        self.rho_min = float(rho_min)
        self.tally = np.zeros(2)  # [mass added, node updates floored] since the start

    def __call__(self, sim) -> None:
        g = sim.grid
        fx, fy, fz = sim.force
        sim.last_flux = self.kernel(
            bnd.plane_buffer(sim.f), bnd.plane_buffer(sim.f_next), g.shape[1], g.alloc_z,
            g.cols_x, g.cols_y, g.xm, g.xp, g.ym, g.yp, g.z0, g.z1, g.nzw,
            sim.omega, sim.omega_minus, fx, fy, fz, sim.n_chunks, self.rho_min, self.tally,
        )

    def record(self) -> dict | None:
        """With the density floor: ``rho_min``, the mass added and the node updates floored."""
        if not self.spec.floor:
            return None
        return {"rho_min": self.rho_min, "mass_added": float(self.tally[0]), "node_updates": float(self.tally[1])}


class WallBounceBack(Effect):
    """Static no-slip wall by half-way bounce-back (the paper's staircase wall)."""

    name = "wall: half-way bounce-back"

    def __init__(self, links: bnd.Links):
        self.links = links

    def __call__(self, sim) -> None:
        k = self.links
        bnd.fill_bounce_back(sim.f2, k.fluid, k.solid, k.i, k.opp)


class WallBouzidi(Effect):
    """Static no-slip curved wall by interpolated bounce-back (Bouzidi et al. 2001)."""

    name = "wall: interpolated bounce-back (Bouzidi)"

    def __init__(self, links: bnd.Links, weights: np.ndarray):
        self.links = links
        self.w_link = np.ascontiguousarray(weights[links.i])
        self.w_sum = float(self.w_link.sum())

    def __call__(self, sim) -> None:
        k = self.links
        bnd.fill_bouzidi(sim.f2, k.fluid, k.solid, k.i, k.opp, k.q, k.fluid2, self.w_link, self.w_sum)


class MovingWall(Effect):
    """Wall moving tangentially at constant velocity: Ladd's bounce-back, Eq. (8)."""

    name = "wall: moving (Ladd bounce-back)"

    def __init__(self, links: bnd.Links, delta: np.ndarray):
        self.links = links
        self.delta = delta

    def __call__(self, sim) -> None:
        k = self.links
        bnd.fill_moving_bounce_back(sim.f2, k.fluid, k.solid, k.i, k.opp, self.delta)


class FlowRateControl(Effect):
    """Holds the volumetric flow rate Q along the pipe by adjusting the body force.

    The paper's pipe is periodic, so a body force (a uniform pressure gradient) drives it; the
    force that yields the paper's Q is not known in advance once particles or a staircase wall
    change the resistance (a 50 % suspension needs several times the Hagen-Poiseuille gradient).
    A proportional-integral controller sets it every step from the z-momentum that the sweep sums
    anyway. The plant is an integrator: a uniform force density ``F`` on the ``N`` nodes of the
    pipe (fluid and particles: ``ParticleCoupling`` applies it to the particle volumes too)
    changes the flux ``Q = sum j_z / n_z`` at the rate ``N F / n_z`` minus the wall and particle
    drag, with no delay. So ``F = F_I + K_p (Q* - Q)`` with ``K_p = n_z / (N tau_c)`` brings a flux
    error back within ``tau_c`` steps, and ``dF_I/dt = K_p (Q* - Q) / (4 tau_c)`` (critical
    damping of the loop) finds the steady drag. ``F_I`` starts at Hagen-Poiseuille's
    ``F_ref = 8 rho nu Q* / (pi R^4)``.
    """

    name = "flow-rate control"
    phase = "post"

    #: response time of the flux, in steps: fast against the viscous time of the pipe
    #: (R^2 / nu ~ 10^3 - 10^4 steps) so Q holds while particles rearrange, slow against one step
    #: so the force does not chase the step-to-step noise of the particle remap.
    TAU_STEPS = 20.0

    def __init__(self, q_target: float, radius: float, nu: float, n_z: int, n_nodes: int | None = None,
                 tau_steps: float = TAU_STEPS):
        self.q_target = q_target
        self.n_z = n_z
        self.f_ref = 8.0 * nu * q_target / (np.pi * radius**4)
        nodes = float(n_nodes) if n_nodes is not None else np.pi * radius**2 * n_z
        self.k_p = n_z / (nodes * tau_steps)
        self.k_i = self.k_p / (4.0 * tau_steps)
        self.f_int = self.f_ref
        self.q = q_target

    def __call__(self, sim) -> None:
        # Guo's u includes F/2, so the swept z-momentum is the physical one.
        self.q = sim.last_flux / self.n_z
        err = self.q_target - self.q
        self.f_int += self.k_i * err
        sim.force[2] = self.f_int + self.k_p * err


def moving_wall_deltas(links: bnd.Links, lattice, velocities: dict[str, tuple], rho0: float = 1.0) -> np.ndarray:
    """Per-link ``2 B_i (e_i . u_w) = 6 w_i rho_0 (e_i . u_w)`` of Eq. (8) for walls that move."""
    delta = np.zeros(len(links))
    for side, u in velocities.items():
        s = bnd.SIDES.index(side)
        sel = links.side == s
        eu = lattice.e[links.i[sel]] @ np.asarray(u, dtype=np.float64)
        delta[sel] = 6.0 * lattice.w[links.i[sel]] * rho0 * eu
    return delta


def wall_effects(grid: bnd.Grid, scheme: str, wall_velocities: dict[str, tuple]) -> list[Effect]:
    """The wall effects a grid needs: none for a fully periodic box."""
    links = bnd.wall_links(grid)
    if len(links) == 0:
        return []
    moving = {s: u for s, u in wall_velocities.items() if any(abs(c) > 0 for c in u)}
    effects: list[Effect] = []
    if moving:
        delta = moving_wall_deltas(links, grid.lattice, moving)
        on_moving = delta != 0.0
        if on_moving.any():
            effects.append(MovingWall(_subset(links, on_moving), delta[on_moving]))
            links = _subset(links, ~on_moving)
    if len(links):
        effects.append(WallBouzidi(links, grid.lattice.w) if scheme == "bouzidi" else WallBounceBack(links))
    return effects


def _subset(links: bnd.Links, sel: np.ndarray) -> bnd.Links:
    return bnd.Links(**{k: getattr(links, k)[sel] for k in links.__dataclass_fields__})


def fluid_spec(lattice: str, collision: str, precision: str, force, flux: bool, density_floor: float | None) -> KernelSpec:
    """The sweep's kernel: Guo forcing when there is a force or a controlled flux, the flux sum for
    the controller, the density floor when one is asked for."""
    forcing = bool(np.any(np.asarray(force) != 0.0)) or flux
    return KernelSpec(lattice, collision, forcing, flux, precision, bool(density_floor))


@dataclass
class Step:
    """A scene's time step in its named phases, in the order they run.

    ``pre``: ``walls`` then ``particle_fills`` (ghost fills and momentum exchange); ``fluid``: the
    sweep; ``post``: ``flux_correction`` (needs the sweep's owner map), ``control`` (the flow-rate
    controller, reading the corrected flux), ``collisions`` (on the updated particle velocities,
    before the drift), ``motion`` (drift, then the mass correction: changes the owner map).
    ``force`` is the initial force density (lattice units)."""

    fluid: StreamCollide
    force: np.ndarray
    walls: list[Effect] = field(default_factory=list)
    particle_fills: list[Effect] = field(default_factory=list)
    flux_correction: list[Effect] = field(default_factory=list)
    control: list[Effect] = field(default_factory=list)
    collisions: list[Effect] = field(default_factory=list)
    motion: list[Effect] = field(default_factory=list)

    @property
    def effects(self) -> list[Effect]:
        return (self.walls + self.particle_fills + [self.fluid] + self.flux_correction + self.control
                + self.collisions + self.motion)


def collision_effect(scene, params, system):
    """The collision effect the scene asks for (``None`` without free particles or with
    ``particles.collisions.enabled: false``): the particles' domain in lattice units."""
    if system is None or not len(system.free_ids) or not scene.particles.collisions.enabled:
        return None
    from .particles.collisions import CollisionEffect, CollisionParams, Domain
    from .particles.placement import domain_geometry

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
        from .particles.coupling import particle_effects

        bouzidi = [e.links for e in walls if isinstance(e, WallBouzidi)]
        phases = particle_effects(system, flux_control=flux, bouzidi_links=bouzidi[0] if bouzidi else None,
                                  wall_links=[e.links for e in walls])
        step.particle_fills, step.flux_correction, step.motion = phases.pre, phases.before_control, phases.after_control
    if flux:
        ctl = FlowRateControl(params.flow_rate_lu, grid.radius, params.nu_lu, grid.shape[2], grid.n_fluid)
        step.control = [ctl]
        step.force = np.array([0.0, 0.0, ctl.f_ref])
    collide = collision_effect(scene, params, system)
    step.collisions = [collide] if collide is not None else []
    # the density floor only where free particles can squeeze films
    floor = num.density_floor if system is not None and len(system.free_ids) else None
    spec = fluid_spec(grid.lattice.name, num.collision, num.precision, step.force, flux, floor)
    step.fluid = StreamCollide(spec, floor if spec.floor else 0.0)
    return step
