"""Cost of the particle work on the paper's pipe, per effect, against the fluid sweep.

The paper's pipe (50 mm x 100 mm, dx = 1 mm: 50 x 50 x 100 nodes, periodic in z), Re 9.4
flow-rate driving (tau = 1.78), D3Q15 BGK, half-way bounce-back wall (``scenes/pipe_re9.4.yaml``),
built through ``lbmpipe.assemble.simulation_from_scene`` exactly as a run builds it, with
  * 115 cubes of 8 mm (``particles.packed``: 30 % by volume), and
  * 18 cylinders of 16 x 16 mm (30 %),
neutrally buoyant and free, at packed random positions and orientations (``lbmpipe.particles.packing``),
starting at rest in the parabolic flow. Collisions are off by default (``--collisions`` turns them
on; they are then reported on their own line, outside the particle share).

After ``--warmup`` steps (the particles are moving, covering and uncovering nodes) each of
``--repeats`` repetitions times ``--steps`` steps per effect (``Simulation.timers``); the cases and
thread counts are interleaved, repetition by repetition, so a drift of the shared machine's load
spreads over all of them alike. Reported: the median over the repetitions of ms/step per effect,
of the fluid sweep (``stream-collide``), of the particle work (every ``particles:`` effect:
coupling with the implicit update, flux correction, motion and remap, mass correction) and of the
ratio particle work / fluid sweep (the target: at most 0.5 with the 115 cubes).

Run: ``python benchmarks/particles.py [--steps 100] [--warmup 100] [--repeats 5] [--threads 1 2]
[--collisions] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import machine_info, set_threads  # noqa: E402

CASES = {
    "cubes": {"shape": "cube", "edge_mm": 8.0, "concentration": 0.3, "seed": 1},
    "cylinders": {"shape": "cylinder", "diameter_mm": 16.0, "length_mm": 16.0, "concentration": 0.3, "seed": 1},
}


def build(case: str, collisions: bool = False):
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    data = yaml.safe_load((ROOT / "scenes" / "pipe_re9.4.yaml").read_text())
    data["name"] = f"bench_{case}"
    data["particles"] = {"packed": [dict(CASES[case], max_seconds=300.0)],
                         "collisions": {"enabled": bool(collisions)}}
    scene = Scene.model_validate(data)
    params = derive(scene)
    t0 = time.perf_counter()
    sim = simulation_from_scene(scene, params)
    ps = sim.particles
    info = {"case": case, "particles": ps.n, "build_seconds": time.perf_counter() - t0,
            "particle_nodes": int(ps.covered().sum()), "collisions": bool(collisions)}
    return sim, info


def _split(timers: dict, steps: int) -> dict:
    per = {k: 1e3 * v / steps for k, v in timers.items()}
    sweep = sum(v for k, v in per.items() if k.startswith("stream+collide"))
    part = sum(v for k, v in per.items() if k.startswith("particles:"))
    coll = sum(v for k, v in per.items() if k.startswith("collisions"))
    return {"effects": per, "sweep_ms": sweep, "particle_ms": part, "collision_ms": coll,
            "step_ms": sum(per.values()), "ratio": part / sweep if sweep > 0 else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--collisions", action="store_true")
    ap.add_argument("--json", type=str, default=None)
    args = ap.parse_args(argv)

    sims = {}
    for case in args.cases:
        sim, info = build(case, args.collisions)
        set_threads(max(args.threads))
        sim.step(args.warmup)
        sims[case] = (sim, info)
    samples = {(c, t): [] for c in args.cases for t in args.threads}
    keys = list(samples)
    for r in range(args.repeats):
        order = keys[r % len(keys):] + keys[:r % len(keys)]
        for case, nt in order:
            sim = sims[case][0]
            set_threads(nt)
            sim.step(2)  # caches back after the other contenders
            sim.timers = {k: 0.0 for k in sim.timers}
            sim.step(args.steps)
            samples[(case, nt)].append(_split(sim.timers, args.steps))

    med = statistics.median
    rows = []
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), D3Q15 BGK tau 1.78, flow-rate control; collisions "
          f"{'on' if args.collisions else 'off'}; median of {args.repeats} x {args.steps} steps after {args.warmup}")
    for (case, nt), s in samples.items():
        sim, info = sims[case]
        ps = sim.particles
        eff = {k: med([x["effects"][k] for x in s]) for k in s[0]["effects"]}
        row = dict(info, threads=nt, links=int(ps.lcnt.sum()), effects_ms=eff,
                   sweep_ms=med([x["sweep_ms"] for x in s]), particle_ms=med([x["particle_ms"] for x in s]),
                   collision_ms=med([x["collision_ms"] for x in s]), step_ms=med([x["step_ms"] for x in s]),
                   ratio=med([x["ratio"] for x in s]), ratio_all=[x["ratio"] for x in s],
                   finite=bool(np.isfinite(ps.bodies.v).all() and np.isfinite(sim.f).all()))
        rows.append(row)
        print(f"\n{case} (N = {info['particles']}, {row['links']} links), {nt} thread(s): step {row['step_ms']:.3f} ms, "
              f"sweep {row['sweep_ms']:.3f} ms, particle work {row['particle_ms']:.3f} ms, "
              f"ratio {row['ratio']:.3f} (repeats {', '.join(f'{x:.3f}' for x in row['ratio_all'])})"
              + (f", collisions {row['collision_ms']:.3f} ms" if args.collisions else ""))
        for k, v in eff.items():
            print(f"    {v:8.3f} ms  {k}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"machine": machine_info(), "args": vars(args), "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
