"""The least the Ladd coupling's link passes can cost, against the fluid sweep: a floor, not physics.

Per step the coupling (``lbmpipe.particles.coupling``, Eqs. (8)-(12)) reads the post-collision population
``f*_i(x)`` at every link (for the force, torque and self-friction sums) and writes one ghost
population ``f[opp(i), s]`` per link (Eq. (8)). This script measures the bare data movement of those
two passes and nothing else (no lever arms, no surface velocity, no implicit update, no remap):

* ``ghost``: ``f[o2] = f[o1] - c`` per link, from precomputed flat offsets;
* ``capture``: ``sum_k += f[o1]`` per link, one sum per particle;

in two placements, on the state of ``benchmarks/particles.py`` (the paper's pipe at dx = 1 mm with
115 cubes of 8 mm, 30 %, after ``--warmup`` coupled steps):

* ``separate``: the passes over all links in the coupling's own order (particle, direction), after
  the whole sweep: the layout ``lbmpipe.particles.coupling`` uses;
* ``fused``: the sweep run chunk by chunk (its own column chunks), each chunk's links filled just
  before its columns are swept and captured just after, while those rows are in cache: the best
  placement a particle-aware sweep could have.

Each is timed against the same chunked sweep without link work, interleaved over ``--repeats``
rounds; reported are medians of the per-round extra time and its ratio to the sweep. Issue 3's
target for *all* particle work is 0.5 of the sweep.

One core: the chunks run one after another (each kernel call sweeps one chunk), so the figures
are per core; the sweep and the link passes scale alike over cores.

Run: ``python benchmarks/coupling_floor.py [--repeats 30] [--warmup 60]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import SweepOnly, machine_info, set_threads  # noqa: E402
from particles import build  # noqa: E402


@njit(cache=True, boundscheck=False)
def _ghost(fl, lo, hi, src_off, dst_off, c):
    for p in range(lo, hi):
        fl[dst_off[p]] = fl[src_off[p]] - c[p]


@njit(cache=True, boundscheck=False)
def _capture(fl, lo, hi, src_off, owner_k, acc):
    for p in range(lo, hi):
        acc[owner_k[p]] += fl[src_off[p]]


def _links(ps, plane, grid):
    """Live links as flat offsets into the (q, plane) buffer, sorted by the sweep's column order."""
    ny, az = grid.shape[1], grid.alloc_z
    per = [ps.links(k)[:3] for k in range(ps.n)]  # (fluid node, particle node, direction), live only
    xs, ss, ii = (np.concatenate([p[a] for p in per]) for a in range(3))
    kk = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(per)])
    colmap = np.full(grid.shape[0] * ny, -1, np.int64)
    colmap[grid.cols_x * ny + grid.cols_y] = np.arange(len(grid.cols_x))
    col = colmap[xs // az]
    order = np.lexsort((xs % az, col))  # column, then z: the order the sweep meets them
    src = ii * plane + xs
    dst = ps.opp[ii] * plane + ss
    return {"particle_order": (src, dst, kk), "column_order": (src[order], dst[order], kk[order]),
            "col": col[order]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=60)
    args = ap.parse_args(argv)

    set_threads(1)
    sim, info = build("cubes")
    sim.step(args.warmup)
    ps, g = sim.particles, sim.grid
    sweep = SweepOnly(sim)
    plane = sweep.src.shape[1]
    L = _links(ps, plane, g)
    n_links = len(L["col"])
    fs, fd = sweep.src.reshape(-1), sweep.dst.reshape(-1)
    c = 1e-3 * np.ones(n_links)
    acc = np.zeros(ps.n)
    nch = sim.n_chunks
    ncol = len(g.cols_x)
    bounds = sweep.bounds
    lbound = np.searchsorted(L["col"], [b[0] for b in bounds] + [ncol])
    sweep_cols = sweep.sweep_cols
    plain = sweep.run

    def separate():
        plain()
        so, do, kk = L["particle_order"]
        _capture(fd, 0, n_links, so, kk, acc)
        _ghost(fd, 0, n_links, so, do, c)

    def fused():
        so, do, kk = L["column_order"]
        for m, (a, b) in enumerate(bounds):
            _ghost(fs, lbound[m], lbound[m + 1], so, do, c)
            sweep_cols(a, b)
            _capture(fd, lbound[m], lbound[m + 1], so, kk, acc)

    for fn in (plain, separate, fused):
        fn()
    runs = {"plain": plain, "separate": separate, "fused": fused}
    t = {k: [] for k in runs}
    names = list(runs)
    for r in range(args.repeats):
        for name in names[r % 3:] + names[:r % 3]:
            t0 = time.perf_counter()
            runs[name]()
            t[name].append(time.perf_counter() - t0)
    med = statistics.median
    sw = med(t["plain"])
    m = machine_info()
    print(f"{m['cpu_model']}; one core; {n_links} live links, {ps.n} cubes, "
          f"{int((ps.owner == -1).sum())} fluid nodes; median of {args.repeats} interleaved rounds")
    print(f"  sweep (in {nch} column chunks)          {1e3 * sw:7.3f} ms")
    for name in ("separate", "fused"):
        extra = [a - b for a, b in zip(t[name], t["plain"])]
        me = med(extra)
        print(f"  {name:9s} link passes, extra    {1e3 * me:7.3f} ms = {me / sw:.2f} of the sweep "
              f"({1e9 * me / n_links:.1f} ns per link)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
