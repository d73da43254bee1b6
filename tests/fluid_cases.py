"""Small analytic flows shared by the fluid tests and the accuracy/cost study."""

from __future__ import annotations

import numpy as np

from lbmpipe.fluid import boundaries as bnd
from lbmpipe.fluid import effects as fx
from lbmpipe.fluid import observables as obs
from lbmpipe.fluid.lattice import get_lattice
from lbmpipe.solver import Simulation
from lbmpipe.units import MAGIC_EXACT_WALL as MAGIC  # noqa: F401
from lbmpipe.units import trt_omega_minus as omega_minus


def run_to_steady(sim: Simulation, chunk: int = 200, tol: float = 1e-12, max_steps: int = 200_000):
    """Step until the velocity field changes by less than ``tol`` (relative, max norm) per chunk."""
    _, ux_old, _, uz_old = sim.moments()
    fluid = sim.grid.fluid
    while sim.step_count < max_steps:
        sim.step(chunk)
        _, ux, _, uz = sim.moments()
        scale = max(np.abs(uz[fluid]).max(), np.abs(ux[fluid]).max(), 1e-300)
        change = max(np.abs(uz - uz_old)[fluid].max(), np.abs(ux - ux_old)[fluid].max()) / scale
        assert np.isfinite(change), "velocity field became non-finite"
        if change < tol:
            return sim
        uz_old, ux_old = uz, ux
    raise AssertionError(f"no steady state after {max_steps} steps (last relative change {change:.2e})")


def pipe_poiseuille(diameter: int, scheme: str, collision: str = "trt", tau: float = 0.8, nz: int = 2,
                    lattice: str = "D3Q15", precision: str = "float64", tol: float = 1e-10):
    """Body-force-driven pipe flow; returns (L2 relative error vs Hagen-Poiseuille, simulation)."""
    grid = bnd.pipe_grid(get_lattice(lattice), diameter, nz)
    nu = (tau - 0.5) / 3.0
    R = grid.radius
    u_max = 0.02  # keeps Mach ~ 0.03: compressibility error far below the discretisation error
    g = 4.0 * nu * u_max / R**2
    sim = Simulation.build(grid, collision=collision, omega=1 / tau, omega_minus=omega_minus(tau), precision=precision,
                     force=(0.0, 0.0, g), extra_effects=fx.wall_effects(grid, scheme, {}))
    x, y, _ = grid.positions()
    r = np.sqrt(x[:, None, None] ** 2 + y[None, :, None] ** 2) * np.ones(grid.shape)
    sim.set_equilibrium(1.0, (0.0, 0.0, obs.poiseuille_pipe(r, R, u_max)))
    run_to_steady(sim, chunk=100, tol=tol)
    _, _, _, uz = sim.moments()
    fluid = grid.fluid
    return obs.relative_l2(uz[fluid], obs.poiseuille_pipe(r[fluid], R, u_max)), sim


def observed_order(sizes, errors) -> float:
    """Slope of log(error) against log(1/size): the order of convergence."""
    return float(-np.polyfit(np.log(sizes), np.log(errors), 1)[0])
