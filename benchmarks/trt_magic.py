"""Issue 44, item 6: which TRT magic parameter the accurate method takes, 3/16 (the exact closure of
half-way bounce-back and CLI) or 1/4 (what the Bouzidi pipe wall of the first accurate method used).
The accurate method has both surfaces at once: the Bouzidi pipe wall and the CLI particle surface.

1. The pipe wall: body-force Poiseuille flow in the paper's pipe cross-section (``--diameter``
   nodes, D3Q15, Bouzidi wall, TRT) at the two taus of the credible level (1.78 at Re 9.4, 0.963 at
   Re 26): relative L2 distance of the steady profile from Hagen-Poiseuille.
2. The particle surface: drag of a fixed sphere in a simple cubic array over Zick & Homsy (c 0.125,
   L 20, a 6.2; CLI, TRT; ``lbmpipe.reproduction.particle_checks.sc_array_drag``), mean over
   ``--offsets`` sub-lattice positions.

Run: ``PYTHONPATH=. python benchmarks/trt_magic.py [--diameter 50] [--offsets 2]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

MAGICS = (3.0 / 16.0, 0.25)
TAUS = (1.78, 0.963)


def pipe_error(diameter: int, tau: float, magic: float, tol: float = 1e-9) -> float:
    """Relative L2 distance of the steady Bouzidi-wall pipe flow from Hagen-Poiseuille (TRT, Lambda ``magic``)."""
    from fluid_cases import run_to_steady

    from lbmpipe.fluid import boundaries as bnd
    from lbmpipe.fluid import effects as fx
    from lbmpipe.fluid import observables as obs
    from lbmpipe.fluid.lattice import get_lattice
    from lbmpipe.solver import Simulation
    from lbmpipe.units import trt_omega_minus

    grid = bnd.pipe_grid(get_lattice("D3Q15"), diameter, 2)
    nu, R, u_max = (tau - 0.5) / 3.0, grid.radius, 0.02
    sim = Simulation.build(grid, collision="trt", omega=1 / tau, omega_minus=trt_omega_minus(tau, magic),
                           force=(0.0, 0.0, 4.0 * nu * u_max / R**2), extra_effects=fx.wall_effects(grid, "bouzidi", {}))
    x, y, _ = grid.positions()
    r = np.sqrt(x[:, None, None] ** 2 + y[None, :, None] ** 2) * np.ones(grid.shape)
    sim.set_equilibrium(1.0, (0.0, 0.0, obs.poiseuille_pipe(r, R, u_max)))
    run_to_steady(sim, chunk=200, tol=tol)
    _, _, _, uz = sim.moments()
    return float(obs.relative_l2(uz[grid.fluid], obs.poiseuille_pipe(r[grid.fluid], R, u_max)))


def main() -> None:
    from lbmpipe.reproduction.particle_checks import sc_array_drag

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--diameter", type=int, default=50, help="pipe diameter, nodes (the credible level's: 50)")
    ap.add_argument("--offsets", type=int, default=2, help="sub-lattice positions of the sphere (mean)")
    args = ap.parse_args()
    offsets = np.random.default_rng(0).random((args.offsets, 3))
    t0 = time.perf_counter()
    print(f"| tau | magic | pipe D {args.diameter}, Bouzidi wall: L2 distance from Poiseuille | "
          f"sphere array c 0.125, CLI: K / Zick-Homsy (mean of {args.offsets}) |")
    print("| --- | --- | ---: | ---: |")
    for tau in TAUS:
        for magic in MAGICS:
            err = pipe_error(args.diameter, tau, magic)
            k = np.mean([sc_array_drag(20, 0.125, tau=tau, offset=o, boundary="cli", collision="trt",
                                       magic=magic)["ratio"] for o in offsets])
            print(f"| {tau:g} | {magic:g} | {100 * err:.3f} % | {k:.4f} | ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
