"""Bit-level digests of a few short deterministic runs, to show that a change of code that should
not change the physics ("same bits") does not.

Each run builds a scene through the public API (``Scene``, ``derive``, ``simulation_from_scene``),
steps it and prints the sha256 of the final populations and of the particle state (position,
velocity, orientation, angular velocity). One run is the accurate method's (issue 45's accurate
coupling): the committed credible scene ``cyl8x16_c30_re9.4`` seed 1 (50 x 50 x 100 nodes, its
committed packing) with ``METHODS["accurate"]`` applied as ``benchmarks/step.py`` does. Run it with the code before and after the change, on one
thread, and compare the lines::

    NUMBA_NUM_THREADS=1 python benchmarks/digests.py [--steps 200]
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import os
import sys
from pathlib import Path

import numpy as np
import yaml

from lbmpipe.scene import Scene
from lbmpipe.assemble import simulation_from_scene
from lbmpipe.units import derive

try:
    from lbmpipe.reproduction.cases import case_scene
except ImportError:  # the flat layout before the subpackages
    from lbmpipe.cases import case_scene

ROOT = Path(__file__).resolve().parents[1]
SMOKE = {"dx_mm": 2.5, "dt_per_mm_s": 1.0e-3, "re26_dt_factor": 0.5, "mach_limit": 0.6,
         "run": {"duration_s": 0.3, "spinup_s": 0.1, "sample_interval_s": 0.025}}


def cases() -> dict[str, dict]:
    """Scene dicts by name: the paper's pipe with crowded cylinders (coupling and collisions), with
    cubes, particle-free, and the box scenes of ``scenes/`` (TRT Couette flow, Poiseuille). The
    packings get an unbounded time budget, so that the machine's load cannot change them."""
    cyl = {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 16,
                                          "concentration": 0.30}}
    cube = {"reynolds": 26, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.30}}
    out = {
        "cyl8x16_c30_re9.4": case_scene("cyl8x16_c30_re9.4", cyl, "smoke", SMOKE),
        "cube8_c30_re26": case_scene("cube8_c30_re26", cube, "smoke", SMOKE),
        "flow_re26": case_scene("flow_re26", {"reynolds": 26}, "smoke", SMOKE),
    }
    for data in out.values():  # the packing's wall-time budget must not decide the particles
        for group in (data.get("particles") or {}).get("packed", []):
            group["max_seconds"] = 1.0e6
    trt = copy.deepcopy(out["cyl8x16_c30_re9.4"])
    trt["name"] = "cyl8x16_c30_trt_bouzidi"
    trt["numerics"].update({"collision": "trt", "wall": "bouzidi"})
    out[trt["name"]] = trt
    # the accurate method (CLI + Galilean coupling, TRT, Bouzidi wall) on a committed credible scene
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from step import scenes

    acc, _ = scenes("credible", "cyl8x16_c30_re9.4", 1, "accurate")
    out["cyl8x16_c30_re9.4_accurate"] = acc.model_dump(mode="json", exclude_unset=True)
    for name in ("box_couette", "box_poiseuille"):
        out[name] = yaml.safe_load((ROOT / "scenes" / f"{name}.yaml").read_text())
    # cheapest first (fewest kernels to compile): the fluid-only runs, then the particle runs
    return dict(sorted(out.items(), key=lambda kv: "particles" in kv[1]))


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--only", nargs="*", default=None, help="names of the runs to do (default: all)")
    args = ap.parse_args(argv)
    print(f"threads={os.environ.get('NUMBA_NUM_THREADS', 'default')} steps={args.steps}")
    for name, data in cases().items():
        if args.only and name not in args.only:
            continue
        scene = Scene.model_validate(data)
        sim = simulation_from_scene(scene, derive(scene))
        sim.step(args.steps)
        line = f"{name:28s} f={digest(sim.f)}"
        ps = sim.particles
        if ps is not None:
            b = ps.bodies
            line += f" particles={digest(b.x, b.v, b.q, b.wb)} n={ps.n}"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
