"""Pack all 14 particle configurations of the paper (7 shapes x 30 % / 50 %) in its 50 mm x 100 mm
pipe (dx = 1 mm, so lengths in mm are lattice units) and print a table: shape, target, count,
achieved concentration, largest overlap, seconds, or the failure with the highest concentration
reached.

    python benchmarks/packing.py [--seed 1] [--max-seconds 60] [--shapes "cube 8" ...]
"""

from __future__ import annotations

import argparse
import time

from lbmpipe.particles.packing import (
    PAPER_COUNTS,
    PAPER_PIPE_LENGTH,
    PAPER_PIPE_RADIUS,
    PAPER_SHAPES,
    PackingError,
    achieved_concentration,
    max_overlap,
    pack,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-seconds", type=float, default=60.0)
    ap.add_argument("--shapes", nargs="*", default=list(PAPER_SHAPES))
    args = ap.parse_args()
    R, L = PAPER_PIPE_RADIUS, PAPER_PIPE_LENGTH
    # compile the kernels once, outside the timings
    kind, h = PAPER_SHAPES["cube 16"]
    pack(kind, h, 2, R, L, seed=0)
    print(f"pipe R = {R:g} mm, L = {L:g} mm, seed {args.seed}, limit {args.max_seconds:g} s")
    print(f"{'shape':<16} {'target':>6} {'count':>5} {'achieved':>8} {'overlap':>8} {'seconds':>7}  result")
    for name in args.shapes:
        kind, h = PAPER_SHAPES[name]
        for frac in (0.3, 0.5):
            n = PAPER_COUNTS[(name, frac)]
            phi = achieved_concentration(kind, h, n, R, L)
            t0 = time.perf_counter()
            try:
                x, q = pack(kind, h, n, R, L, seed=args.seed, max_seconds=args.max_seconds)
                dt = time.perf_counter() - t0
                ov = max_overlap(kind, h, x, q, R, L)
                print(f"{name:<16} {frac:>6.0%} {n:>5d} {phi:>8.2%} {ov:>8.1e} {dt:>7.1f}  ok")
            except PackingError as e:
                dt = time.perf_counter() - t0
                print(f"{name:<16} {frac:>6.0%} {n:>5d} {phi:>8.2%} {'-':>8} {dt:>7.1f}  FAILED: highest reached "
                      f"{e.reached:.2%} ({e})")


if __name__ == "__main__":
    main()
