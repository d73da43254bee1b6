"""Cost of the particle coupling on the paper's pipe: seconds per step, fluid work vs particle work.

The paper's pipe (50 mm x 100 mm, dx = 1 mm: 50 x 50 x 100 nodes, periodic in z), Re 9.4 flow-rate
driving (tau = 1.78), D3Q15 BGK, half-way bounce-back wall, with
  * 115 cubes of 8 mm (30 % by volume), and
  * 18 cylinders of 16 x 16 mm (30 %),
neutrally buoyant and free, at random positions and orientations (``lbmpipe.packing.pack``: the
bounding-sphere placement of ``lbmpipe.particles`` cannot reach 30 %), starting at rest in the
parabolic flow. After ``--warmup`` steps (the particles are moving, covering and uncovering nodes)
each effect is timed over ``--steps`` steps (``Simulation.timers``).

Fluid work = stream+collide sweep + wall fill + flow-rate controller; particle work = every
``particles:`` effect (free-particle coupling with the implicit update, flow-rate flux
correction, motion and remap). The brief's target: particle work at most 50 % of the fluid step at
115 cubes. A particle-free run of the same pipe gives the reference fluid step.

Run: ``python benchmarks/particles.py [--steps 200] [--warmup 100] [--threads N] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numba
import numpy as np


def build(case: str, seed: int = 1):
    from lbmpipe import boundaries as bnd
    from lbmpipe import coupling as cp
    from lbmpipe import effects as fx
    from lbmpipe import observables as obs
    from lbmpipe.lattice import get_lattice
    from lbmpipe.rigid import Bodies
    from lbmpipe.shapes import CUBE, CYLINDER, volume
    from lbmpipe.solver import Simulation

    lat = get_lattice("D3Q15")
    grid = bnd.pipe_grid(lat, 50, 100)
    tau = 1.7816
    nu = (tau - 0.5) / 3.0
    u_mean = 0.0803
    q_lu = u_mean * math.pi * 25.0**2
    walls = fx.wall_effects(grid, "bounce_back", {})
    ctl = fx.FlowRateControl(q_lu, grid.radius, nu, 100)
    extra = list(walls)
    info = {"case": case}
    after = []
    if case != "none":
        kind, h, n = {"cubes": (CUBE, (4.0, 4.0, 4.0), 115), "cylinders": (CYLINDER, (8.0, 8.0, 8.0), 18)}[case]
        t0 = time.perf_counter()
        try:
            from lbmpipe.packing import pack

            x, q = pack(kind, h, n, 25.0, 100.0, seed=seed, max_seconds=300.0)
            info["placement"] = "lbmpipe.packing.pack"
        except ImportError:  # pragma: no cover - the dense packer belongs to another module
            raise SystemExit("lbmpipe.packing is not available: random placement of bounding spheres cannot reach 30 %")
        info["placement_seconds"] = time.perf_counter() - t0
        bodies = Bodies.make(kind, h, 1.0, x, q=q)
        system = cp.ParticleSystem(grid, bodies)
        pre, before, after = cp.particle_effects(system, flux_control=True, wall_links=[w.links for w in walls])
        extra += pre + before
        info["particles"] = n
        info["volume_fraction"] = n * volume(kind, np.asarray(h)) / (math.pi * 25.0**2 * 100.0)
        info["particle_nodes"] = int(system.covered().sum())
    extra.append(ctl)
    extra += after
    sim = Simulation(grid, collision="bgk", omega=1.0 / tau, force=(0.0, 0.0, ctl.f_ref), flux=True,
                     extra_effects=extra)
    xs, ys, _ = grid.positions()
    r = np.sqrt(xs[:, None] ** 2 + ys[None, :] ** 2)
    sim.set_equilibrium(1.0, (0.0, 0.0, obs.poiseuille_pipe(r, grid.radius, 2.0 * u_mean)[:, :, None]))
    return sim, info


def measure(case: str, steps: int, warmup: int) -> dict:
    sim, info = build(case)
    sim.step(warmup)
    sim.timers = {k: 0.0 for k in sim.timers}
    t0 = time.perf_counter()
    sim.step(steps)
    wall = (time.perf_counter() - t0) / steps
    per = {k: v / steps for k, v in sim.timers.items()}
    fluid = sum(v for k, v in per.items() if not k.startswith("particles:"))
    particles = sum(v for k, v in per.items() if k.startswith("particles:"))
    info.update(seconds_per_step=wall, fluid_seconds=fluid, particle_seconds=particles,
                particle_over_fluid=particles / fluid, effects=per)
    ps = next((e.system for e in sim.effects if hasattr(e, "system")), None)
    if ps is not None:
        info["links"] = int(ps.lcnt.sum())
        info["max_particle_speed"] = float(np.abs(ps.bodies.v).max())
        info["owner_changes_last_step"] = list(ps.last_cover)
        info["finite"] = bool(np.isfinite(ps.bodies.v).all() and np.isfinite(sim.f).all())
    return info


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--json", type=str, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        numba.set_num_threads(args.threads)
    rows = [measure(case, args.steps, args.warmup) for case in ("none", "cubes", "cylinders")]
    print(f"Paper pipe 50 x 50 x 100, D3Q15 BGK tau 1.78, flow-rate control; {numba.get_num_threads()} threads, "
          f"{args.steps} steps after {args.warmup}")
    print(f"{'case':<10} {'N':>4} {'phi':>6} {'links':>8} {'step ms':>8} {'fluid ms':>9} {'particle ms':>12} {'ratio':>6}")
    for r in rows:
        print(f"{r['case']:<10} {r.get('particles', 0):>4} {r.get('volume_fraction', 0.0):>6.3f} {r.get('links', 0):>8} "
              f"{1e3 * r['seconds_per_step']:>8.3f} {1e3 * r['fluid_seconds']:>9.3f} {1e3 * r['particle_seconds']:>12.3f} "
              f"{r['particle_over_fluid']:>6.2f}")
    for r in rows[1:]:
        print(f"  {r['case']}: " + ", ".join(f"{k.removeprefix('particles: ')} {1e3 * v:.3f} ms"
                                              for k, v in r["effects"].items() if k.startswith("particles:")))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
