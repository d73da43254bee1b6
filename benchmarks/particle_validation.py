"""Issue 44, items 1-2: the particle-surface options against analytic and published values, the
paper's method beside them (full size; ``tests/test_particle_boundary.py`` runs them small).

Harnesses: ``lbmpipe.reproduction.particle_checks`` (D3Q15, periodic cube, lattice units).

1. Torque on a sphere of radius ``a`` turning in fluid at rest, over ``8 pi mu a^3 Omega`` with the
   periodic-box correction ``1 / (1 - (4 pi/3)(a/L)^3)`` (derived in ``particle_checks``), box
   ``L = 4a``, mean over ``--offsets`` sub-lattice positions of the centre.
2. Drag ``K`` of a fixed sphere in a simple cubic array over Zick & Homsy (1982), c = 0.064
   (L = 26, a = 6.45) and 0.125 (L = 20, a = 6.20), mean over ``--offsets`` positions.
3. A heavy sphere (a = 6, L = 32) dragged at U = (0.02, 0.006, 0) through fluid at rest, tau 1:
   the step-to-step force fluctuation (residual about a 51-step running mean, steps 500-1500)
   over the Stokes drag ``6 pi mu a |U|``.

Each at tau 1.0 and 1.78 where it applies. Contenders ("set"): ``paper`` (half-way bounce-back,
BGK); ``bouzidi`` and ``cli`` with BGK; ``bouzidi+trt`` and ``cli+trt`` with TRT (magic 3/16).

Run (one thread; 8 minutes on the 2-core EPYC host, shared, with numba's cache warm):

    python benchmarks/particle_validation.py [--offsets 4] [--threads 1] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import machine_info, set_threads  # noqa: E402

#: contender -> (particle_boundary, collision)
SETS = {"paper": ("bounce_back", "bgk"), "bouzidi": ("bouzidi", "bgk"), "bouzidi+trt": ("bouzidi", "trt"),
        "cli": ("cli", "bgk"), "cli+trt": ("cli", "trt")}
TAUS = (1.0, 1.78)
#: simple cubic arrays: solid fraction -> box edge (radius >= 6)
SC_BOXES = {0.064: 26, 0.125: 20}
RADII = (6.0, 8.0)


def _table(title, head, rows):
    print(f"\n{title}\n")
    print("| " + " | ".join(head) + " |")
    print("|" + " --- |" * len(head))
    for r in rows:
        print("| " + " | ".join(r) + " |")


def _cell(vals):
    v = np.asarray(vals)
    return f"{v.mean():.4f} ({v.min():.3f}-{v.max():.3f})" if len(v) > 1 else f"{v[0]:.4f}"


def main(argv=None) -> int:
    from lbmpipe.reproduction.particle_checks import dragged_sphere, rotating_sphere, sc_array_drag

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--offsets", type=int, default=4, help="sub-lattice positions of the sphere (mean)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    offsets = np.random.default_rng(0).random((args.offsets, 3))
    out: dict = {"machine": machine_info(), "command": " ".join(sys.argv), "offsets": offsets.tolist()}
    t0 = time.perf_counter()

    rot = {}
    for a in RADII:
        for tau in TAUS:
            for name, (boundary, coll) in SETS.items():
                rot[(a, tau, name)] = [rotating_sphere(int(4 * a), a, tau=tau, offset=o, boundary=boundary,
                                                       collision=coll)["ratio_box"] for o in offsets]
    out["rotating_sphere"] = {f"a{a:g}_tau{t:g}_{n}": v for (a, t, n), v in rot.items()}
    _table("Torque on a rotating sphere / (8 pi mu a^3 Omega) with the box correction (L = 4a; mean (min-max) "
           f"over {args.offsets} positions)", ["a", "tau", *SETS],
           [[f"{a:g}", f"{t:g}", *[_cell(rot[(a, t, n)]) for n in SETS]] for a in RADII for t in TAUS])
    print(f"({time.perf_counter() - t0:.0f} s so far)", flush=True)

    drag = {}
    for c, L in SC_BOXES.items():
        for tau in TAUS:
            for name, (boundary, coll) in SETS.items():
                drag[(c, tau, name)] = [sc_array_drag(L, c, tau=tau, offset=o, boundary=boundary,
                                                      collision=coll)["ratio"] for o in offsets]
    out["sc_array_drag"] = {f"c{c:g}_tau{t:g}_{n}": v for (c, t, n), v in drag.items()}
    _table("Drag of a sphere in a simple cubic array, K / K_Zick-Homsy (mean (min-max) over "
           f"{args.offsets} positions)", ["c", "L", "a", "tau", *SETS],
           [[f"{c:g}", str(L), f"{L * (3 * c / (4 * math.pi)) ** (1 / 3):.2f}", f"{t:g}",
             *[_cell(drag[(c, t, n)]) for n in SETS]] for c, L in SC_BOXES.items() for t in TAUS])
    print(f"({time.perf_counter() - t0:.0f} s so far)", flush=True)

    jit = {}
    a, L, U = 6.0, 32, np.array([0.02, 0.006, 0.0])
    stokes = 6.0 * math.pi * (0.5 / 3.0) * a * float(np.linalg.norm(U))
    for boundary in ("bounce_back", "bouzidi", "cli"):
        for ex in ("ladd", "galilean"):
            r = dragged_sphere(L, a, U, tau=1.0, steps=1500, offset=offsets[0], boundary=boundary, exchange=ex)
            f = r["force"][500:] @ (U / np.linalg.norm(U))
            res = f[25:-25] - np.convolve(f, np.ones(51) / 51, mode="valid")
            jit[(boundary, ex)] = {"jitter": float(res.std() / stokes),
                                   "cover_per_step": float(r["cover"][500:].sum(axis=1).mean())}
    out["dragged_sphere"] = {f"{b}_{e}": v for (b, e), v in jit.items()}
    _table("Sphere dragged through fluid at rest (a = 6, L = 32, |U| = 0.0209, tau 1, BGK): force along U, "
           "steps 500-1500: its fluctuation about a 51-step running mean over the Stokes drag",
           ["boundary", "exchange", "fluctuation", "nodes covered + uncovered per step"],
           [[b, e, f"{v['jitter']:.4f}", f"{v['cover_per_step']:.2f}"] for (b, e), v in jit.items()])
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
