"""Cost of the run-time guard (``lbmpipe.guard``) against the time step, on the paper's pipe.

The paper's particle-free pipe (``scenes/pipe_re9.4.yaml``: 50 mm x 100 mm, dx = 1 mm, i.e.
50 x 50 x 100 nodes, D3Q15 BGK, half-way bounce-back, flow-rate driving), built by
``simulation_from_scene`` as a run builds it; optionally (``--particles``) with the 115 cubes of
8 mm at 30 % (collisions on), where the guard reads the particle owner map and checks the bodies.

Two figures, each the median over ``--repeats`` interleaved repetitions (one repetition of each
contender per round, so a drifting load on the shared machine hits both alike):

* direct: ms per step of ``--steps`` steps with the guard off and with the guard on at its default
  interval (``guard.DEFAULT_EVERY``), and their ratio (with - without) / without; on a shared
  2-core machine this difference is within the noise;
* derived: ms of one guard check (``Guard.check``) over ms of one step, i.e. the overhead per
  step at interval 1, and divided by the interval, the overhead at the default interval.

Run: ``python benchmarks/guard.py [--steps 200] [--repeats 7] [--threads 2] [--particles]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import set_threads  # noqa: E402


def build(particles: bool):
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    data = yaml.safe_load((ROOT / "scenes" / "pipe_re9.4.yaml").read_text())
    data["name"] = "bench_guard"
    if particles:
        data["particles"] = {"packed": [{"shape": "cube", "edge_mm": 8.0, "concentration": 0.3, "seed": 1}]}
    scene = Scene.model_validate(data)
    return simulation_from_scene(scene, derive(scene))


def main(argv=None) -> int:
    from lbmpipe.guard import DEFAULT_EVERY

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--particles", action="store_true")
    args = ap.parse_args(argv)
    set_threads(args.threads)
    sim = build(args.particles)
    guard = sim.guard
    sim.guard = None
    sim.step(20)  # compile, page in
    guard.check(sim)
    off, on, chk = [], [], []
    perf = time.perf_counter
    for r in range(args.repeats):
        order = ("off", "on") if r % 2 == 0 else ("on", "off")
        for which in order:
            sim.guard = guard if which == "on" else None
            t0 = perf()
            sim.step(args.steps)
            (on if which == "on" else off).append((perf() - t0) / args.steps * 1e3)
        sim.guard = None
        t0 = perf()
        for _ in range(10):
            guard.check(sim)
        chk.append((perf() - t0) / 10 * 1e3)
    m_off, m_on, m_chk = statistics.median(off), statistics.median(on), statistics.median(chk)
    n = guard.every
    print(f"pipe 50x50x100{' + 115 cubes 8 mm (30 %)' if args.particles else ''}, {args.threads} thread(s), "
          f"{args.steps} steps x {args.repeats} repeats (median)")
    print(f"  step without guard      {m_off:8.3f} ms")
    print(f"  step with guard (every {n:3d}) {m_on:8.3f} ms   ratio with/without {m_on / m_off:.4f}")
    print(f"  one guard check         {m_chk:8.3f} ms   = {m_chk / m_off:.3f} of a step")
    print(f"  derived overhead at every {n}: {100 * m_chk / m_off / n:.2f} % of the step "
          f"(default interval {DEFAULT_EVERY}; 2 % would allow every {max(1, int(m_chk / m_off / 0.02) + 1)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
