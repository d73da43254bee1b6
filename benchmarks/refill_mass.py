"""Mass put back and density-floor events on the paper's pipe, by refill of uncovered nodes
(issue 44 item 3).

The paper's pipe (50 mm x 100 mm, dx = 1 mm) at the ``credible`` level's settings, built as a run
builds it from the COMMITTED scenes ``results/<level>/cases/<case>/seed<seed>/scene.yaml`` and
the packings they name (``benchmarks/step.py`` does the same); by default ``cube8_c50_re9.4``
(192 cubes at 50 %) and ``cyl8x16_c30_re9.4`` (56 cylinders at 30 %), seed 1. Each case runs
``--steps`` steps from the committed start (particles at rest in the parabolic flow) once per
refill (``numerics.refill``): ``equilibrium`` (the paper's) and ``extrapolated`` (Grad's
reconstruction with the neighbours' non-equilibrium stress); everything else is the committed
scene (the paper's method).

Printed per run, from the simulation's own tallies (the ``summary.json`` records):
  * ``mass_correction``: the mass the particles' mass correction put back (lattice units, the
    fluid density being 1: in node volumes) and as a share of the pipe's fluid mass at the start;
  * ``density_floor``: node updates floored and the mass the floor added;
  * the largest ``|rho - 1|`` over the fluid, checked every 10 steps; the uncovered nodes per step
    (mean); ms per step of the remap effect (the refill runs inside it) and of the whole step,
    without the first step (it compiles what numba's cache lacks).

Run (one thread; about 2-4 minutes per run on one core of a 2-core EPYC host with numba's cache
warm):

    python benchmarks/refill_mass.py [--cases cube8_c50_re9.4 cyl8x16_c30_re9.4] [--seed 1]
        [--level credible] [--refills equilibrium extrapolated] [--steps 600] [--threads 1]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import set_threads  # noqa: E402

DEFAULT_CASES = ["cube8_c50_re9.4", "cyl8x16_c30_re9.4"]
REFILLS = ["equilibrium", "extrapolated"]
REMAP = "particles: motion + remap (cover/uncover)"


def scene(level: str, case: str, seed: int, refill: str):
    """The committed scene of ``case`` (its packing file resolved by ``load_scene``) with
    ``numerics.refill`` set."""
    from lbmpipe.scene import Scene, load_scene

    path = ROOT / "results" / level / "cases" / case / f"seed{seed}" / "scene.yaml"
    if not path.exists():
        raise SystemExit(f"no committed scene {path.relative_to(ROOT)}: pick a case of the {level} level "
                         f"that has particles and a seed{seed} run")
    data = load_scene(path).model_dump(mode="json", exclude_unset=True)
    data["numerics"] = {**data.get("numerics", {}), "refill": refill}
    data["name"] = f"{data['name']}_{refill}"
    return Scene.model_validate(data)


def peak_deviation(sim) -> float:
    """Largest |rho - 1| over the fluid nodes now."""
    fluid = sim.particles.fluid_mask()
    rho = np.asarray(sim.f)[..., :fluid.shape[2]].sum(axis=0)
    return float(np.abs(rho[fluid] - 1.0).max())


def run(sc, steps: int, every: int = 10) -> dict:
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    sim = simulation_from_scene(sc, derive(sc))
    ps = sim.particles
    mass0 = ps.fluid_mass(sim.f2)
    sim.step(1)  # compiles what the cache lacks: not timed (its tallies count)
    uncovered = ps.last_cover[1]
    remap0 = sim.timers.get(REMAP, 0.0)
    peak = peak_deviation(sim)
    secs = 0.0
    for s in range(1, steps):
        t0 = time.perf_counter()
        sim.step(1)
        secs += time.perf_counter() - t0
        uncovered += ps.last_cover[1]
        if (s + 1) % every == 0:
            peak = max(peak, peak_deviation(sim))
    rec = sim.records()
    mc = rec.get("mass_correction", {})
    fl = rec.get("density_floor", {})
    timed = max(steps - 1, 1)
    return {"mass0": mass0, "corrected": float(mc.get("mass_added", 0.0)), "floor_updates": float(fl.get("node_updates", 0.0)),
            "floor_mass": float(fl.get("mass_added", 0.0)), "peak_dev": peak, "uncovered": uncovered / steps,
            "remap_ms": 1e3 * (sim.timers.get(REMAP, 0.0) - remap0) / timed, "step_ms": 1e3 * secs / timed,
            "particles": int(ps.n)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="committed credible runs (with particles)")
    ap.add_argument("--seed", type=int, default=1, help="packing seed of the committed run")
    ap.add_argument("--level", default="credible", help="the level whose committed scenes are read")
    ap.add_argument("--refills", nargs="+", default=REFILLS, choices=REFILLS)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), committed {args.level} scenes, seed {args.seed}, paper's method "
          f"but the refill; {args.steps} steps from the committed start; {args.threads} thread(s)")
    head = (f"{'case':<20} {'refill':<13} {'N':>4} {'corrected':>10} {'/ M0':>9} {'floor upd':>10} {'floor mass':>11} "
            f"{'peak|rho-1|':>11} {'unc/step':>9} {'remap ms':>9} {'step ms':>8}")
    print(head)
    print("-" * len(head))
    for case in args.cases:
        for refill in args.refills:
            r = run(scene(args.level, case, args.seed, refill), args.steps)
            print(f"{case:<20} {refill:<13} {r['particles']:>4} {r['corrected']:>10.4g} {r['corrected'] / r['mass0']:>9.2e} "
                  f"{r['floor_updates']:>10.0f} {r['floor_mass']:>11.4g} {r['peak_dev']:>11.4f} {r['uncovered']:>9.1f} "
                  f"{r['remap_ms']:>9.2f} {r['step_ms']:>8.1f}", flush=True)
    print("corrected: mass the particles' mass correction put back (lattice units; / M0: share of the fluid mass at "
          "the start); floor upd / floor mass: node updates the density floor (0.5) raised and the mass it added; "
          "peak|rho-1|: over the fluid, every 10 steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
