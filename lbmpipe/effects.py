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

The simulation times every effect separately; the summary reports seconds per effect.
"""

from __future__ import annotations

import numpy as np

from . import boundaries as bnd
from .kernels import KernelSpec, get_kernel


class Effect:
    """One piece of physics in the time step. Subclasses set ``name``, ``phase`` and ``__call__``."""

    name = "effect"
    phase = "pre"

    def __call__(self, sim) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<{self.phase}: {self.name}>"


class StreamCollide(Effect):
    """Fused pull streaming + collision (Eqs. (1)-(4)) with Guo forcing when present."""

    phase = "fluid"

    def __init__(self, spec: KernelSpec):
        self.spec = spec
        self.kernel = get_kernel(spec)
        self.name = spec.describe()

    def __call__(self, sim) -> None:
        g = sim.grid
        fx, fy, fz = sim.force
        sim.last_flux = self.kernel(
            sim.f, sim.f_next, g.cols_x, g.cols_y, g.xm, g.xp, g.ym, g.yp, g.z0, g.z1, g.nzw,
            sim.omega, sim.omega_minus, fx, fy, fz, sim.n_chunks,
        )


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
    change the resistance. An integral controller adjusts it every step from the z-momentum that
    the sweep sums anyway. Its gain is set for critical damping of the slowest viscous mode of a
    pipe, time constant ``tau_p = R^2 / (nu j_0^2)`` (``j_0 = 2.405``, the first zero of J_0):
    ``dF/dt = F_ref (Q* - Q) / (4 tau_p Q*)``, ``F_ref = 8 rho nu Q* / (pi R^4)`` (Hagen-Poiseuille).
    """

    name = "flow-rate control"
    phase = "post"

    def __init__(self, q_target: float, radius: float, nu: float, n_z: int):
        self.q_target = q_target
        self.n_z = n_z
        self.f_ref = 8.0 * nu * q_target / (np.pi * radius**4)
        tau_p = radius**2 / (nu * 2.404825557695773**2)
        self.gain = self.f_ref / (4.0 * tau_p * q_target)
        self.q = q_target

    def __call__(self, sim) -> None:
        # Guo's u includes F/2, so the swept z-momentum is the physical one.
        self.q = sim.last_flux / self.n_z
        sim.force[2] += self.gain * (self.q_target - self.q)


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
