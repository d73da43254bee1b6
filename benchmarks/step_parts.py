"""The coupled step's particle effects taken apart, on 1 and 2 threads in one process (issue 45,
items 2 and 3): which parts cost, and which do not scale.

Builds the committed ``credible`` scenes as ``benchmarks/step.py`` does (paper method; the scene as
committed), steps each ``--warmup`` steps untimed, then ``--repeats`` rounds in which every case
is timed over ``--steps`` steps on each thread count in turn (the order of the thread counts
reversed every other round; two untimed steps before each repetition). Per repetition: ms per step
of every effect (``Simulation.timers``), of the whole step, and of the parts of the two big
particle effects, timed by wrapping the kernels ``ParticleSystem`` calls (module globals of
``system`` and ``remap``; the code of ``couple_free`` and ``move`` itself is the package's):

* coupling: ``external loads`` (numpy), ``couple_free`` (the link passes and the implicit update,
  Eqs. (8)-(12)), ``accumulate + clear`` (the running sums and the change marks);
* motion: ``drift`` (Eqs. (13)-(15)), ``runs`` (``compute_runs``) and ``diff`` (``diff_runs``),
  ``omega``, and the remap's phases: ``count`` (coverage counts, serial), ``settle`` (new owners,
  node by node), ``owners+links`` (owner changes, link appends and covered impulses, serial:
  their order fixes the link lists), ``refill`` (node by node), ``uncovered impulses``,
  ``wrap``. The remap's first three phases, one compiled call in a run, are three calls here
  (two more dispatches, a few microseconds).

Medians over the rounds; the speed-up is the median of the per-round ratios (1 thread / 2
threads). ``other cores``: the CPU other processes used meanwhile (/proc/stat), the most of any
repetition; on a shared 2-core machine the 2-thread figures mean little when it is not near 0.

Run: ``python benchmarks/step_parts.py [--cases ...] [--threads 1 2] [--steps 50] [--warmup 100]
[--repeats 5] [--json FILE]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import LoadMonitor, machine_info, set_threads  # noqa: E402
from step import DEFAULT_CASES, build, scenes, timed as step_timed  # noqa: E402

PARTS: dict[str, float] = {}


def _timed(name, fn):
    def wrapper(*a, **k):
        t0 = time.perf_counter()
        out = fn(*a, **k)
        PARTS[name] = PARTS.get(name, 0.0) + time.perf_counter() - t0
        return out
    return wrapper


def instrument():
    """Wrap the kernels the particle effects call (module globals) with timers into ``PARTS``."""
    import lbmpipe.particles.coupling.remap as rm
    import lbmpipe.particles.coupling.system as sm

    for mod, name, label in [(sm, "couple_free", "coupling: couple_free"),
                             (sm, "accumulate_loads", "coupling: accumulate + clear"),
                             (sm, "clear_changed", "coupling: accumulate + clear"),
                             (sm, "drift_arrays", "motion: drift"), (sm, "compute_runs", "motion: runs"),
                             (sm, "diff_runs", "motion: diff"), (sm, "omega_lab_arrays", "motion: omega"),
                             (sm, "wrap_positions", "motion: wrap"),
                             (rm, "_uncovered_and_clear", "motion: remap uncovered impulses")]:
        setattr(mod, name, _timed(label, getattr(mod, name)))
    ext = sm.ParticleSystem.external_loads
    sm.ParticleSystem.external_loads = _timed("coupling: external loads", ext)
    count = _timed("motion: remap count", rm._count_changes)
    settle = _timed("motion: remap settle", rm._settle_owners)
    change = _timed("motion: remap owners+links", rm._change_owners)

    def owners_and_covered(ids, C, all_ids, R, x, owner, f2, imp, moved, G, L, S):
        nt = count(ids, C, owner, S)
        settle(nt, all_ids, R, owner, f2, S, G)
        n_cov, n_unc = change(nt, x, owner, imp, moved, S, G, L)
        return nt, n_cov, n_unc

    rm._owners_and_covered = owners_and_covered


def link_bytes(sim) -> dict:
    """The least data the Ladd link passes move per step, from the live links: the distinct 64-byte
    lines of ``f`` they gather (``f*_i(x)``, plane i) and scatter into (the ghost slot, plane
    opp(i): read for ownership and written back), and the 16-byte link records; against the
    sweep's 240 bytes per node (15 populations read and written) over the nodes it sweeps."""
    import numpy as np

    ps = sim.particles
    plane = ps.owner.shape[0]
    ii = np.concatenate([np.full(int(ps.lcnt[k, i]), i) for k in range(ps.n) for i in range(1, ps.lcnt.shape[1])])
    pos = np.concatenate([np.arange(ps.lbase[k, i], ps.lbase[k, i] + ps.lcnt[k, i])
                          for k in range(ps.n) for i in range(1, ps.lcnt.shape[1])])
    xn = ps.LN[pos, 0].astype(np.int64)
    sn = ps.LN[pos, 1].astype(np.int64)
    gather = np.unique((ii * plane + xn) // 8).size
    scatter = np.unique((ps.opp[ii] * plane + sn) // 8).size
    links = int(pos.size)
    link_b = 64 * gather + 2 * 64 * scatter + 16 * links
    swept = int(np.count_nonzero(sim.grid.fluid))
    return {"links": links, "gather_lines": int(gather), "scatter_lines": int(scatter),
            "bytes_per_link": link_b / max(links, 1), "link_bytes": link_b, "sweep_bytes": 240 * swept,
            "ratio": link_b / (240 * swept)}


def timed(sim, steps, monitor):
    """``step.timed`` with the parts' clocks cleared after its untimed steps: ms/step per effect, per
    part and whole, and the other processes' cores."""
    rep = step_timed(sim, steps, monitor, reset=PARTS.clear)
    eff = dict(rep["effects"])
    eff.update({k: 1e3 * v / steps for k, v in PARTS.items()})
    eff["whole step"] = rep["step_ms"]
    return eff, rep["other_cores"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    instrument()
    sims = {}
    for case in args.cases:
        coupled, _ = scenes("credible", case, 1, "paper")
        sims[case], _ = build(coupled)
        ps = sims[case].particles
        ps.refill = _timed("motion: remap refill", ps.refill)
    set_threads(max(args.threads))
    for sim in sims.values():
        sim.step(args.warmup)
    monitor = LoadMonitor()
    samples = {(c, n): [] for c in sims for n in args.threads}
    loads = {c: [] for c in sims}
    t0 = time.perf_counter()
    for r in range(args.repeats):
        for case, sim in sims.items():
            order = args.threads if r % 2 == 0 else args.threads[::-1]
            for n in order:
                set_threads(n)
                eff, other = timed(sim, args.steps, monitor)
                samples[(case, n)].append(eff)
                loads[case].append(other)
    secs = time.perf_counter() - t0

    med = statistics.median
    m = machine_info()
    print(f"{m.get('cpu_model')}; committed credible scenes, paper method; median of {args.repeats} rounds x "
          f"{args.steps} steps after {args.warmup}; rounds {secs:.0f} s")
    rows = {}
    for case in sims:
        names = list(samples[(case, args.threads[0])][0])
        oc = [x for x in loads[case] if x is not None]
        lb = link_bytes(sims[case])
        print(f"\n{case} (links {lb['links']}; other processes up to {max(oc) if oc else float('nan'):.2f} cores)")
        print(f"  link passes move at least {lb['link_bytes'] / 1e6:.2f} MB a step ({lb['gather_lines']} lines "
              f"gathered, {lb['scatter_lines']} scattered, {lb['bytes_per_link']:.0f} B per link) against the "
              f"sweep's {lb['sweep_bytes'] / 1e6:.2f} MB: {lb['ratio']:.2f} of the sweep's data")
        head = "".join(f"{f'{n} thr':>9s}" for n in args.threads)
        print(f"  {'ms/step':44s}{head}   speed-up {args.threads[0]}->{args.threads[-1]}")
        rows[case] = {"link_bytes": lb}
        for name in sorted(names, key=lambda s: (s == "whole step", s)):
            vals = {n: med([x.get(name, 0.0) for x in samples[(case, n)]]) for n in args.threads}
            a, b = samples[(case, args.threads[0])], samples[(case, args.threads[-1])]
            sp = med([x.get(name, 0.0) / max(y.get(name, 0.0), 1e-12) for x, y in zip(a, b)])
            rows[case][name] = {"ms": vals, "speedup": sp}
            print(f"  {name[:44]:44s}" + "".join(f"{vals[n]:9.3f}" for n in args.threads) + f"   {sp:6.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": m, "args": vars(args), "rows": rows,
                                               "other_cores": loads,
                                               "repetitions": {f"{c}/{n}": v for (c, n), v in samples.items()}},
                                              indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
