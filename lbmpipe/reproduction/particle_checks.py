"""Validation of the particle-surface options (issue 44: ``numerics.particle_boundary``,
``numerics.momentum_exchange``) against analytic and published values, in lattice units; shared by
``tests/test_particle_boundary.py`` (small sizes) and ``benchmarks/particle_validation.py`` (full
size).

``rotating_sphere``
    A sphere turning at ``Omega`` in fluid at rest in a periodic cube of edge ``L``; Stokes'
    torque ``8 pi mu a^3 Omega``. Periodic box correction: the periodic images' rotlets add, near
    the sphere, a rigid rotation ``-T / (6 mu L^3)`` of the fluid (the Laplacian's periodic Green's
    function is ``1/(4 pi r) + r^2 / (6 L^3) + const + O(r^4)``, the ``r^2`` term from the
    neutralising background; its curl with the rotlet's strength gives the rotation), so the
    sphere turns at ``T / (8 pi mu a^3) - T / (6 mu L^3)`` relative to the fluid far away:
    ``T = 8 pi mu a^3 Omega / (1 - (4 pi / 3) (a / L)^3)``, to ``O((a/L)^8)`` (the next,
    cubic-harmonic terms of the Green's function do not rotate the fluid). The sphere is free and
    very heavy (density ``1e6``), so ``Omega`` stays constant within 1e-4 over the run; the ratio
    uses the ``Omega`` of the same step.
``sc_array_drag``
    A fixed sphere in a periodic cube (a simple cubic array at solid fraction ``c``) driven by a
    body force: ``K = F / (6 pi mu a U)`` against Zick & Homsy (1982), as in
    ``tests/test_coupling.py`` (force per sphere ``g L^3``; ``U`` the superficial velocity).
``dragged_sphere``
    A heavy sphere (density ``1e4``) moving at a constant velocity through fluid at rest: the
    force of every step, whose fluctuation (covering and uncovering of nodes) the Galilean
    exchange should remove.
"""

from __future__ import annotations

import math

import numpy as np

from ..fluid import boundaries as bnd
from ..fluid.collision import MAGIC_EXACT_WALL, trt_omega_minus
from ..fluid.lattice import get_lattice
from ..particles import coupling as cp
from ..particles import shapes
from ..particles.rigid import Bodies
from ..solver import Simulation

#: Zick & Homsy (1982), J. Fluid Mech. 115, 13-26, Table 2, simple cubic arrays: K(c)
ZICK_HOMSY_SC = {0.027: 2.008, 0.064: 2.810, 0.125: 4.292, 0.216: 7.442}


def coupled_sim(L: int, bodies: Bodies, *, tau: float, boundary: str = "bounce_back", exchange: str = "ladd",
                collision: str = "bgk", magic: float = MAGIC_EXACT_WALL, force=(0.0, 0.0, 0.0)):
    """A periodic D3Q15 cube of edge ``L`` with ``bodies`` coupled by the given surface options;
    ``(sim, system)``. ``magic`` is TRT's Lambda (ignored by BGK)."""
    grid = bnd.box_grid(get_lattice("D3Q15"), (L, L, L), (False, False, False))
    system = cp.ParticleSystem(grid, bodies)
    pre, before, after = cp.particle_effects(system, boundary=boundary, exchange=exchange)
    om_minus = trt_omega_minus(tau, magic) if collision == "trt" else None
    sim = Simulation.build(grid, collision=collision, omega=1.0 / tau, omega_minus=om_minus, force=force,
                           extra_effects=pre + before + after)
    return sim, system


def _until_steady(sim, value, chunk: int, rtol: float, max_steps: int) -> tuple[float, int]:
    """Step in chunks until ``value()`` changes by less than ``rtol`` (relative) over a chunk."""
    prev, steps = None, 0
    while steps < max_steps:
        sim.step(chunk)
        steps += chunk
        now = value()
        if prev is not None and abs(now - prev) <= rtol * abs(now):
            return now, steps
        prev = now
    return value(), steps


def rotating_sphere(L: int, a: float, *, tau: float = 1.0, omega: float = 2e-3, offset=(0.0, 0.0, 0.0),
                    rtol: float = 1e-4, max_steps: int = 20000, **options) -> dict:
    """Torque on a sphere of radius ``a`` turning about x at ``omega`` in a periodic cube ``L``
    (module docstring). Returns the measured torque over Stokes' ``8 pi mu a^3 Omega`` (``ratio``),
    over the box-corrected value (``ratio_box``), and the steps run. ``options``: ``coupled_sim``'s
    surface options and collision."""
    centre = np.full(3, L / 2.0) + np.asarray(offset, dtype=np.float64)
    bodies = Bodies.make(shapes.SPHERE, [a, a, a], 1e6, [centre], wb=[[omega, 0.0, 0.0]])
    sim, system = coupled_sim(L, bodies, tau=tau, **options)
    mu = (tau - 0.5) / 3.0

    def ratio():
        return -system.torque[0, 0] / (8.0 * math.pi * mu * a**3 * system.omega_lab()[0, 0])

    r, steps = _until_steady(sim, ratio, 200, rtol, max_steps)
    box = 1.0 - 4.0 * math.pi / 3.0 * (a / L) ** 3
    return {"ratio": r, "ratio_box": r * box, "steps": steps}


def sc_array_drag(L: int, c: float, *, tau: float = 1.0, offset=(0.0, 0.0, 0.0), g: float = 1e-6,
                  rtol: float = 1e-6, max_steps: int = 40000, **options) -> dict:
    """``K`` of a fixed sphere at solid fraction ``c`` in a periodic cube ``L`` (module docstring),
    its ratio to Zick & Homsy's (``ratio``), the momentum balance ``F / (g V_fluid)`` (1 at steady
    state) and the steps run. ``options``: ``coupled_sim``'s."""
    a = L * (3.0 * c / (4.0 * math.pi)) ** (1.0 / 3.0)
    centre = np.full(3, L / 2.0) + np.asarray(offset, dtype=np.float64)
    bodies = Bodies.make(shapes.SPHERE, [a, a, a], 1.0, [centre], fixed=[True])
    sim, system = coupled_sim(L, bodies, tau=tau, force=(g, 0.0, 0.0), **options)
    nu = (tau - 0.5) / 3.0
    fl = system.fluid_mask()

    def u_s():
        rho, ux, _, _ = sim.moments()
        return float((rho * ux)[fl].sum()) / L**3

    u, steps = _until_steady(sim, u_s, 200, rtol, max_steps)
    k = g * L**3 / (6.0 * math.pi * nu * a * u)
    return {"a": a, "K": k, "ratio": k / ZICK_HOMSY_SC[c], "balance": system.force[0, 0] / (g * fl.sum()),
            "steps": steps}


def dragged_sphere(L: int, a: float, velocity, *, tau: float = 1.0, steps: int = 1000,
                   offset=(0.0, 0.0, 0.0), **options) -> dict:
    """A heavy sphere (density 1e4) moving at ``velocity`` (3,) through fluid at rest in a periodic
    cube ``L``: the hydrodynamic force of every step (``force`` (steps, 3)), the covered and
    uncovered nodes of every move (``cover`` (steps, 2)) and the velocity at the end."""
    centre = np.full(3, L / 2.0) + np.asarray(offset, dtype=np.float64)
    bodies = Bodies.make(shapes.SPHERE, [a, a, a], 1e4, [centre], v=[velocity])
    sim, system = coupled_sim(L, bodies, tau=tau, **options)
    force = np.zeros((steps, 3))
    cover = np.zeros((steps, 2), np.int64)
    for n in range(steps):
        sim.step(1)
        force[n] = system.force[0]
        cover[n] = system.last_cover
    return {"force": force, "cover": cover, "v": bodies.v[0].copy()}
