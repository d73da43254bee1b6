"""What the accurate method costs per step against the paper's, on the production scenes.

Builds each case's scene at the paper-method level (``credible``: BGK, half-way bounce-back) and at
the accurate one (``credible_accurate``: its method ``accurate_fluid``, TRT with magic 1/4 and the
Bouzidi pipe wall; see ``lbmpipe.reproduction.cases.METHODS``) from the same committed packing (seed 1), exactly as a run
builds it (``lbmpipe.assemble.simulation_from_scene``). After ``--warmup`` steps each repetition
times ``--steps`` steps of every contender in turn, the order rotating each round, so a drift of
the shared machine's load falls on all alike. Prints the median ms/step of each method, the
ratio accurate / paper per case (median over repetitions of the per-round ratio), and the
step's time per effect group.

    python benchmarks/method_cost.py [--cases flow_re9.4 cyl8x16_c30_re9.4 cube16_c30_re9.4]
        [--steps 100] [--warmup 50] [--repeats 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import machine_info, set_threads  # noqa: E402

from lbmpipe.reproduction.cases import case_scene, packing_id, run_case  # noqa: E402

LEVELS = {"paper": "credible", "accurate": "credible_accurate"}


def build(config: dict, level: str, case: str):
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    name, c = run_case(config, case if config["cases"][case].get("particles") is None else f"{case}/seed1")
    pid = packing_id(c)
    packing = ROOT / "results" / "packings" / f"{pid}.csv" if pid else None
    scene = Scene.model_validate(case_scene(name, c, level, config["fidelities"][level], packing))
    params = derive(scene)
    return simulation_from_scene(scene, params)


def groups(timers: dict) -> dict:
    out = {"fluid": 0.0, "particles": 0.0, "collisions": 0.0}
    for k, v in timers.items():
        g = "particles" if k.startswith("particles") else "collisions" if k.startswith("collisions") else "fluid"
        out[g] += v
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["flow_re9.4", "cyl8x16_c30_re9.4", "cube16_c30_re9.4"])
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    sims = {(case, m): build(config, lvl, case) for case in args.cases for m, lvl in LEVELS.items()}
    for sim in sims.values():
        sim.step(args.warmup)
    times = {k: [] for k in sims}
    effect_s = {k: {} for k in sims}
    order = list(sims)
    for rep in range(args.repeats):
        for k in order[rep % len(order):] + order[:rep % len(order)]:
            sim = sims[k]
            before = dict(sim.timers)
            t0 = time.perf_counter()
            sim.step(args.steps)
            times[k].append((time.perf_counter() - t0) / args.steps)
            for name, v in sim.timers.items():
                effect_s[k].setdefault(name, []).append((v - before.get(name, 0.0)) / args.steps)
    rows = []
    print(f"{args.steps} steps x {args.repeats} repetitions after {args.warmup}; {args.threads} thread(s)")
    print(f"{'case':24s} {'paper ms':>9s} {'accurate ms':>12s} {'ratio':>6s}   accurate per group (ms): fluid / particles / collisions")
    for case in args.cases:
        p, a = times[(case, "paper")], times[(case, "accurate")]
        ratio = statistics.median(x / y for x, y in zip(a, p))
        g = groups({n: statistics.median(v) for n, v in effect_s[(case, "accurate")].items()})
        gp = groups({n: statistics.median(v) for n, v in effect_s[(case, "paper")].items()})
        rows.append({"case": case, "paper_ms": 1e3 * statistics.median(p), "accurate_ms": 1e3 * statistics.median(a),
                     "ratio": ratio, "paper_groups_ms": {k: 1e3 * v for k, v in gp.items()},
                     "accurate_groups_ms": {k: 1e3 * v for k, v in g.items()}})
        print(f"{case:24s} {rows[-1]['paper_ms']:9.2f} {rows[-1]['accurate_ms']:12.2f} {ratio:6.2f}   "
              f"{1e3 * g['fluid']:.2f} / {1e3 * g['particles']:.2f} / {1e3 * g['collisions']:.2f}"
              f"  (paper {1e3 * gp['fluid']:.2f} / {1e3 * gp['particles']:.2f} / {1e3 * gp['collisions']:.2f})")
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": machine_info(), "args": vars(args), "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
