"""Cost of the collision step against the fluid sweep on the paper's pipe, from a scene.

The paper's pipe (50 mm x 100 mm, dx = 1 mm: 50 x 50 x 100 nodes, periodic in z), Re 9.4
flow-rate driving (Q = 1.577e-4 m^3/s, tau 1.78), D3Q15 BGK, half-way bounce-back, parabolic
start, with a packed suspension (``particles.packed``, packed at start-up by ``lbmpipe.particles.packing``):

  * ``cyl8x8_c50``: cylinders 8 x 8 mm at 50 % (244 particles), the issue's target case;
  * ``cube8_c30``: cubes of 8 mm at 30 % (115 particles);
  * ``cyl16x16_c50`` (only with ``--cases``): cylinders 16 x 16 mm at 50 % (31 particles), whose
    jams across the pipe go to the rotating overlap projection (``rotation_projections``).

Dense packings keep nearly every particle in contact, so every step has many pair and wall
contacts and impulses. The simulation is assembled by ``lbmpipe.assemble.simulation_from_scene``
(the same effects as a real run). After ``--warmup`` steps (particles moving and colliding),
``--repeats`` windows of ``--steps`` steps are timed with ``Simulation.timers``; the table gives
the median per step over the windows of

  * fluid sweep: the stream + collide kernel alone,
  * particles: every ``particles:`` effect (Ladd coupling with the implicit update, flux
    correction, motion and remap),
  * collisions: ``CollisionEffect`` (broad phase, narrow phase, impulses, overlap projection),
  * ratio: collisions / fluid sweep, the median of the per-window ratios (both measured in the
    same window, so load from other processes cancels to first order),
  * collisions / step: the collision step's share of the whole time step,
  * us / contact: the collision step per touching contact (pairs and walls), a figure that depends
    on the core alone and not on the memory system,
  * jams: the share of steps whose overlap projection had to turn bodies (``rotation_projections``).

The ratio to the sweep depends on the host's memory system as much as on the collision code: the
sweep is bound by the bandwidth its two population arrays are read and written at, the collision
step by the core. The first line names the CPU, its last-level cache and the size of the
population arrays: where they fit in that cache (2026-12-04: a Xeon with 480 MiB of L3 for 66 MB
of populations) the sweep runs at cache bandwidth, 2.1-2.3 ms on 1 thread against 4.9-5.8 ms on the
host of the earlier runs (an AMD EPYC), and a collision step of about the same time (1.2 ms here,
1.5-1.8 ms there) is about twice the share (0.54-0.60 against 0.30-0.33).

The issue's target: collisions at most 25 % of the fluid sweep for the 50 % cylinders.
Each thread count runs in its own process (``NUMBA_NUM_THREADS``), since the sweep fixes its
chunking when the simulation is built.

Run: ``python benchmarks/collisions.py [--threads 1 2] [--steps 100] [--repeats 5] [--warmup 100]
[--cases cyl8x8_c50 cube8_c30 cyl16x16_c50] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

CASES = {
    "cyl8x8_c50": {"shape": "cylinder", "diameter_mm": 8.0, "length_mm": 8.0, "concentration": 0.5, "seed": 0},
    "cube8_c30": {"shape": "cube", "edge_mm": 8.0, "concentration": 0.3, "seed": 0},
    # not run by default: 31 large cylinders whose jams exercise the rotating overlap projection
    "cyl16x16_c50": {"shape": "cylinder", "diameter_mm": 16.0, "length_mm": 16.0, "concentration": 0.5, "seed": 1},
}
DEFAULT_CASES = ["cyl8x8_c50", "cube8_c30"]


def scene_dict(case: str) -> dict:
    """The paper's pipe at Re 9.4 (scenes/pipe_re9.4.yaml) with the case's packed group."""
    return {
        "name": f"bench_collisions_{case}",
        "domain": {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0},
        "fluid": {"density_kg_m3": 1000.0, "reynolds": 9.4},
        "driving": {"kind": "flow_rate", "flow_rate_m3_s": 1.577e-4},
        "initial": {"velocity": "parabolic"},
        "numerics": {"dx_mm": 1.0, "dt_s": 1.0e-3, "lattice": "D3Q15", "collision": "bgk", "wall": "bounce_back"},
        "run": {"duration_s": 1.0, "spinup_s": 0.0, "sample_interval_s": 0.05},
        "particles": {"packed": [dict(CASES[case], max_seconds=300.0)]},
    }


def measure(case: str, steps: int, repeats: int, warmup: int) -> dict:
    import numba

    from lbmpipe.particles.collisions import CollisionEffect
    from lbmpipe.fluid.effects import StreamCollide
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    scene = Scene.model_validate(scene_dict(case))
    params = derive(scene)
    t0 = time.perf_counter()
    sim = simulation_from_scene(scene, params)
    setup = time.perf_counter() - t0
    coll = next(e for e in sim.effects if isinstance(e, CollisionEffect))
    sweep = next(e for e in sim.effects if isinstance(e, StreamCollide))
    sim.step(warmup)
    windows = []
    for _ in range(repeats):
        sim.timers = {k: 0.0 for k in sim.timers}
        before = dict(coll.totals)
        t0 = time.perf_counter()
        sim.step(steps)
        wall = (time.perf_counter() - t0) / steps
        per = {k: v / steps for k, v in sim.timers.items()}
        w = {
            "step": wall,
            "sweep": per[sweep.name],
            "particles": sum(v for k, v in per.items() if k.startswith("particles:")),
            "collisions": per[coll.name],
        }
        w["ratio"] = w["collisions"] / w["sweep"]
        w["share_of_step"] = w["collisions"] / wall
        for k in ("impulses", "pair_contacts", "wall_contacts", "unresolved", "rotation_projections"):
            w[k] = (coll.totals[k] - before[k]) / steps
        w["us_per_contact"] = 1e6 * w["collisions"] / max(w["pair_contacts"] + w["wall_contacts"], 1.0)
        windows.append(w)
    med = {k: statistics.median(w[k] for w in windows) for k in windows[0]}
    bodies = sim.particles.bodies
    return {
        "case": case, "threads": numba.get_num_threads(), "particles": int(bodies.n),
        "concentration": sim.packing.get("concentration_achieved"), "setup_seconds": setup,
        "population_bytes": int(sim.f.nbytes + sim.f_next.nbytes),
        "steps": steps, "repeats": repeats, "warmup": warmup, "median": med, "windows": windows,
        "max_overlap_after_lu": coll.totals["max_overlap_after_lu"],
        "max_overlap_before_lu": coll.totals["max_overlap_before_lu"],
    }


def _worker(args) -> int:
    rows = [measure(c, args.steps, args.repeats, args.warmup) for c in args.cases]
    print("JSON " + json.dumps(rows))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, choices=list(CASES))
    ap.add_argument("--json", type=str, default=None)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return _worker(args)
    rows = []
    for nt in args.threads:
        env = dict(os.environ, NUMBA_NUM_THREADS=str(nt))
        cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--steps", str(args.steps), "--repeats",
               str(args.repeats), "--warmup", str(args.warmup), "--cases", *args.cases]
        out = subprocess.run(cmd, env=env, check=True, stdout=subprocess.PIPE, text=True).stdout
        rows += json.loads(next(line for line in out.splitlines() if line.startswith("JSON "))[5:])
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from _common import machine_info

    mi = machine_info()
    llc = mi["llc_bytes"]
    pop = rows[0]["population_bytes"] if rows else 0
    fits = "unknown" if not llc else ("yes" if pop <= llc else "no")
    print(f"{mi['cpu_model']}; last-level cache {llc / 2**20 if llc else float('nan'):.0f} MiB; population arrays "
          f"{pop / 1e6:.0f} MB (fit in that cache: {fits})")
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), Re 9.4 flow-rate, D3Q15 BGK; median of {args.repeats} windows of "
          f"{args.steps} steps after {args.warmup}")
    print(f"{'case':<11} {'N':>4} {'thr':>3} {'sweep ms':>9} {'particles ms':>13} {'collisions ms':>14} {'coll/sweep':>11} "
          f"{'coll/step':>10} {'us/contact':>11} {'impulses':>9} {'pairs':>6} {'walls':>6} {'jams':>5} {'max ov':>7}")
    for r in rows:
        m = r["median"]
        print(f"{r['case']:<11} {r['particles']:>4} {r['threads']:>3} {1e3 * m['sweep']:>9.3f} {1e3 * m['particles']:>13.3f} "
              f"{1e3 * m['collisions']:>14.3f} {m['ratio']:>11.3f} {m['share_of_step']:>10.3f} {m['us_per_contact']:>11.2f} "
              f"{m['impulses']:>9.1f} {m['pair_contacts']:>6.1f} {m['wall_contacts']:>6.1f} {m['rotation_projections']:>5.2f} "
              f"{r['max_overlap_after_lu']:>7.4f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
