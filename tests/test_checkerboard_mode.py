"""D3Q15's checkerboard momentum mode, which the diagnosis of the unstable `cube24_c30_re26` run
rests on (`benchmarks/unstable_cause.py`, benchmarks/README.md "Issue 47: the two unstable runs").

Every D3Q15 velocity changes x + y + z by an odd number, so a momentum field
(-1)^(x+y+z+t) A is carried onto itself by streaming, and the collision conserves momentum at
every node: its staggered momentum P = sum (-1)^(x+y+z+t) j never decays, whatever the collision
rates. On D3Q19 the diagonal links keep the parity, and the same field decays.
"""

from __future__ import annotations

import numpy as np
import pytest

from lbmpipe.fluid import boundaries as bnd
from lbmpipe.fluid.lattice import get_lattice
from lbmpipe.solver import Simulation

N = 8  # periodic box, even: the parity pattern is periodic too
OMEGA = 1.038  # the unstable runs' rate (tau 0.963, Re 26)
MAGIC = 3.0 / 16.0


def _staggered(sim, parity) -> float:
    """P_z = sum (-1)^(x+y+z+t) rho u_z over the box (no force: u is j / rho)."""
    rho, _, _, uz = sim.moments()
    sign = 1.0 if sim.step_count % 2 == 0 else -1.0
    return float((sign * parity * rho * uz).sum())


def _box(lattice: str, collision: str):
    grid = bnd.box_grid(get_lattice(lattice), (N, N, N), (False, False, False))
    omega_minus = 1.0 / (MAGIC / (1.0 / OMEGA - 0.5) + 0.5) if collision == "trt" else None
    sim = Simulation.build(grid, collision=collision, omega=OMEGA, omega_minus=omega_minus)
    parity = (np.indices((N, N, N)).sum(axis=0) % 2 * 2 - 1).astype(np.float64)
    # a mean flow of 0.1 with a checkerboard of amplitude 0.02 on u_z
    sim.set_equilibrium(1.0, (0.0, 0.0, 0.1 + 0.02 * parity))
    return sim, parity


@pytest.mark.parametrize("collision", ["bgk", "trt"])
def test_checkerboard_momentum_is_never_damped_on_d3q15_but_decays_on_d3q19(collision):
    sim, parity = _box("D3Q15", collision)
    p0 = _staggered(sim, parity)
    assert p0 > 1.0  # 0.02 on each of 512 nodes
    sim.step(300)
    assert abs(_staggered(sim, parity) / p0 - 1.0) < 1e-9

    sim19, parity = _box("D3Q19", collision)
    q0 = _staggered(sim19, parity)
    sim19.step(300)
    assert abs(_staggered(sim19, parity) / q0) < 0.5
