"""The whole coupled time step against the particle-free sweep, on the production runs (issue 45).

The paper's pipe (50 mm x 100 mm, dx = 1 mm: 50 x 50 x 100 nodes, periodic in z) at the
``credible`` level's settings, built exactly as a run builds it (``lbmpipe.scene.load_scene``,
``lbmpipe.units.derive``, ``lbmpipe.assemble.simulation_from_scene``, with its run-time guard) from
the COMMITTED scenes ``results/<level>/cases/<case>/seed<seed>/scene.yaml`` and the packings they
name (``results/packings/*.csv``). By default the three runs of issue 45's table, seed 1:
``cyl8x8_c30_re26`` (146 cylinders), ``cube8_c50_re26`` (192 cubes), ``cube16_c30_re26`` (14 cubes);
flow-rate driving at Re 26 (tau 0.963), collisions on, starting at rest in the parabolic flow.

Each case is built with both methods:
  * ``paper``: the scene as committed (D3Q15 BGK, half-way bounce-back wall);
  * ``accurate``: the same scene with the numerics of ``lbmpipe.reproduction.cases.METHODS
    ["accurate"]`` (TRT with magic 3/16, Bouzidi pipe wall, CLI particle surfaces, Galilean momentum
    exchange, lubrication on); ``accurate_fluid``: ``METHODS["accurate_fluid"]`` (TRT with magic 1/4,
    Bouzidi pipe wall, the Ladd coupling), exactly what the ``credible_accurate`` level writes into
    its scenes.
The yardstick is the **particle-free pipe** of each method: the same scene with ``particles``
removed (the committed ``flow_re26`` run's numerics), built in the same process.

All contenders (cases x methods, and the particle-free pipes) are first stepped ``--warmup``
steps untimed (numba compiles, pages fault in, and the particles start moving: they begin at
rest). Then each of ``--repeats`` rounds times ``--steps`` steps of every contender, one after
another, in an order rotated and reversed from round to round, so a drift of the shared machine's
load falls on all alike; two untimed steps before each timed repetition bring the contender's
data back into the caches the others evicted. Per repetition: ms per step of each effect
(``Simulation.timers``, the names the run summaries record), the whole step (wall time of
``Simulation.step`` over the repetition / steps: the effects, the guard's check every 50 steps
and the Python loop between effects), and the CPU other processes used meanwhile (``other
cores``, from /proc/stat; 0 = the machine was ours alone).

Reported (medians over the rounds):
  * per case and method: ms/step of every effect, of the groups (sweep = ``stream+collide``,
    wall, particles = every ``particles:`` effect, collisions), and of the whole step;
  * ``step/sweep``: the whole coupled step over the **particle-free pipe's stream+collide effect**
    of the same method (median over rounds of the per-round ratio), issue 45's target ratio;
    also ``step/free step``: over the particle-free pipe's whole step (sweep + wall + flow-rate
    control + guard);
  * ``acc/paper``: the accurate method's whole step over the paper method's on the same packing
    (median of the per-round ratios).
Issue 45's targets (one core, float64) are printed beside: step/sweep at most 2.0 for
``cyl8x8_c30``, 2.5 for ``cube8_c50``, 1.6 for ``cube16_c30``; acc/paper at most 1.3.

Run (with the defaults: 10 s of warm-up and 46 s of rounds on one core of the 2-core AMD EPYC host
with numba's cache warm; a cold compile adds about 2.5 minutes to the warm-up):

    python benchmarks/step.py [--cases cyl8x8_c30_re26 cube8_c50_re26 cube16_c30_re26] [--seed 1]
        [--level credible] [--methods paper accurate] [--steps 100] [--warmup 100] [--repeats 5]
        [--threads 1] [--json FILE]
(``--methods`` also takes issue 44's particle options on the paper's method: ``bouzidi``, ``cli``,
``galilean``, ``cli_galilean``, ``extrapolated`` (refill), ``lubrication``.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import LoadMonitor, machine_info, set_threads  # noqa: E402

#: issue 45's table: the Re 26 runs of the credible level (seed 1)
DEFAULT_CASES = ["cyl8x8_c30_re26", "cube8_c50_re26", "cube16_c30_re26"]
#: issue 45's targets for whole step / particle-free sweep, by packing (the case name before _re)
TARGET_STEP_OVER_SWEEP = {"cyl8x8_c30": 2.0, "cube8_c50": 2.5, "cube16_c30": 1.6}
#: issue 45's target for the accurate method's whole step over the paper method's
TARGET_ACCURATE_OVER_PAPER = 1.3
#: how the effects are grouped in the table (by the prefix of their names; the rest is "other")
GROUPS = [("sweep", "stream+collide"), ("wall", "wall"), ("flow-rate control", "flow-rate control"),
          ("particles", "particles:"), ("collisions", "collisions")]
FREE = "particle-free"
#: issue 44's particle-surface options, each on top of the paper's method (``--methods``); their
#: particle-free pipe is the paper's, and ``/ paper`` is their whole step over the paper method's
OPTION_METHODS = {"bouzidi": {"particle_boundary": "bouzidi"}, "cli": {"particle_boundary": "cli"},
                  "galilean": {"momentum_exchange": "galilean"},
                  "cli_galilean": {"particle_boundary": "cli", "momentum_exchange": "galilean"},
                  "extrapolated": {"refill": "extrapolated"}, "lubrication": {"lubrication": {"enabled": True}}}


def scenes(level: str, case: str, seed: int, method: str):
    """(coupled scene, particle-free scene) of ``case`` at ``method``: the committed scene (its
    packing file resolved by ``load_scene``), with the accurate method's numerics when asked, and
    the same scene without particles."""
    from lbmpipe.reproduction.cases import METHODS
    from lbmpipe.scene import Scene, load_scene

    path = ROOT / "results" / level / "cases" / case / f"seed{seed}" / "scene.yaml"
    if not path.exists():
        raise SystemExit(f"no committed scene {path.relative_to(ROOT)}: pick a case of the {level} level "
                         f"that has particles and a seed{seed} run")
    base = load_scene(path)
    data = base.model_dump(mode="json", exclude_unset=True)
    extra = METHODS[method] if method in METHODS else OPTION_METHODS[method]
    data["numerics"] = {**data.get("numerics", {}), **extra}
    data["name"] = f"{base.name}_{method}"
    coupled = Scene.model_validate(data)
    free = {k: v for k, v in data.items() if k != "particles"}
    free["name"] = f"{base.name}_{method}_{FREE}"
    return coupled, Scene.model_validate(free)


def build(scene):
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    t0 = time.perf_counter()
    sim = simulation_from_scene(scene, derive(scene))  # with the guard, as a run has it
    return sim, time.perf_counter() - t0


def flow_key(scene) -> str:
    """What decides the particle-free pipe: everything of the scene but its name, run and particles."""
    d = scene.model_dump(mode="json")
    return json.dumps({k: d[k] for k in ("domain", "fluid", "driving", "initial", "numerics")}, sort_keys=True)


def group_of(name: str) -> str:
    return next((g for g, prefix in GROUPS if name.startswith(prefix)), "other")


def timed(sim, steps: int, monitor: LoadMonitor, reset=None) -> dict:
    """One repetition: ``steps`` steps after two untimed ones; ms/step per effect and whole.
    ``reset`` (optional) is called after the untimed steps, just before the timed ones."""
    sim.step(2)  # caches back after the other contenders
    before = dict(sim.timers)
    if reset is not None:
        reset()
    monitor.start()
    t0 = time.perf_counter()
    sim.step(steps)
    wall = time.perf_counter() - t0
    load = monitor.read()
    eff = {k: 1e3 * (v - before[k]) / steps for k, v in sim.timers.items()}
    grp: dict[str, float] = {}
    for k, v in eff.items():
        grp[group_of(k)] = grp.get(group_of(k), 0.0) + v
    return {"effects": eff, "groups": grp, "step_ms": 1e3 * wall / steps,
            "between_ms": 1e3 * wall / steps - sum(eff.values()),  # guard + Python loop
            "other_cores": load.get("foreign_cores")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="committed credible runs (with particles)")
    ap.add_argument("--seed", type=int, default=1, help="packing seed of the committed run")
    ap.add_argument("--level", default="credible", help="the level whose committed scenes are read")
    ap.add_argument("--methods", nargs="+", default=["paper", "accurate"],
                    choices=["paper", "accurate", "accurate_fluid", *OPTION_METHODS])
    ap.add_argument("--steps", type=int, default=100, help="timed steps per repetition")
    ap.add_argument("--warmup", type=int, default=100, help="untimed steps first (compile; particles moving)")
    ap.add_argument("--repeats", type=int, default=5, help="rounds (medians over them)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None, help="write every figure and repetition here")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.steps < 1:
        ap.error("--repeats and --steps must be at least 1")
    set_threads(args.threads)

    # Contenders: (case, method) coupled runs, and one particle-free pipe per distinct flow and
    # method ((FREE, method, key); all default cases share one per method).
    sims: dict[tuple, object] = {}
    info: dict[tuple, dict] = {}
    free_of: dict[tuple, tuple] = {}
    keys_free: dict[str, tuple] = {}
    for case in args.cases:
        for m in args.methods:
            coupled, free = scenes(args.level, case, args.seed, m)
            sims[(case, m)], secs = build(coupled)
            ps = sims[(case, m)].particles
            if ps is None:
                raise SystemExit(f"{case}: the committed scene has no particles")
            fk = flow_key(free)
            if fk not in keys_free:
                keys_free[fk] = (FREE, m, f"re{coupled.fluid.reynolds:g}")
                sims[keys_free[fk]], _ = build(free)
                info[keys_free[fk]] = {"scene": free.name}
            free_of[(case, m)] = keys_free[fk]
            info[(case, m)] = {"scene": coupled.name, "build_seconds": secs, "particles": int(ps.n),
                               "packing": str(Path(coupled.particles.packed[0].file).relative_to(ROOT))}
    t0 = time.perf_counter()
    for k, sim in sims.items():  # compile, fault in, set the particles moving
        sim.step(args.warmup)
    warm_s = time.perf_counter() - t0
    for k, sim in sims.items():
        if sim.particles is not None:
            ps = sim.particles
            info[k]["links_after_warmup"] = int(ps.lcnt.sum())
            info[k]["max_speed_lu_after_warmup"] = float(np.sqrt((ps.bodies.v ** 2).sum(axis=1)).max())

    monitor = LoadMonitor()
    order0 = list(sims)
    samples: dict[tuple, list[dict]] = {k: [] for k in sims}
    t0 = time.perf_counter()
    for r in range(args.repeats):
        order = order0[r % len(order0):] + order0[:r % len(order0)]
        if r % 2:  # reverse every other round: no contender always follows the same neighbour
            order.reverse()
        for k in order:
            samples[k].append(timed(sims[k], args.steps, monitor))
    timed_s = time.perf_counter() - t0

    med = statistics.median
    rows = []
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), committed {args.level} scenes, packing seed {args.seed}; "
          f"{args.threads} thread(s); median of {args.repeats} rounds x {args.steps} steps after {args.warmup} "
          f"(warm-up {warm_s:.0f} s, rounds {timed_s:.0f} s)")
    print("step/sweep: whole coupled step / the particle-free pipe's stream+collide effect (same method, same "
          "round); step/free step: / the particle-free pipe's whole step")
    free_med = {}
    for k in sims:
        if k[0] == FREE:
            s = samples[k]
            free_med[k] = {"sweep_ms": med([x["groups"].get("sweep", 0.0) for x in s]),
                           "step_ms": med([x["step_ms"] for x in s]),
                           "effects_ms": {e: med([x["effects"][e] for x in s]) for e in s[0]["effects"]}}
            print(f"\n{FREE} pipe, {k[1]} method ({info[k]['scene']}): whole step {free_med[k]['step_ms']:.3f} ms")
            for e, v in free_med[k]["effects_ms"].items():
                print(f"    {v:8.3f} ms  {e}")
    for case in args.cases:
        for m in args.methods:
            k = (case, m)
            s, f = samples[k], samples[free_of[k]]
            eff = {e: med([x["effects"][e] for x in s]) for e in s[0]["effects"]}
            grp = {g: med([x["groups"].get(g, 0.0) for x in s]) for g, _ in GROUPS}
            row = dict(info[k], case=case, method=m, effects_ms=eff, groups_ms=grp,
                       step_ms=med([x["step_ms"] for x in s]), between_ms=med([x["between_ms"] for x in s]),
                       free_sweep_ms=free_med[free_of[k]]["sweep_ms"], free_step_ms=free_med[free_of[k]]["step_ms"],
                       step_over_sweep=med([x["step_ms"] / y["groups"]["sweep"] for x, y in zip(s, f)]),
                       step_over_sweep_all=[x["step_ms"] / y["groups"]["sweep"] for x, y in zip(s, f)],
                       step_over_free_step=med([x["step_ms"] / y["step_ms"] for x, y in zip(s, f)]),
                       target_step_over_sweep=TARGET_STEP_OVER_SWEEP.get(case.split("_re")[0]),
                       other_cores=[x["other_cores"] for x in s],
                       finite=bool(np.isfinite(sims[k].particles.bodies.v).all() and np.isfinite(sims[k].f).all()))
            if m in ("accurate", "accurate_fluid") and (case, "paper") in samples:
                row["accurate_over_paper"] = med([a["step_ms"] / p["step_ms"]
                                                  for a, p in zip(s, samples[(case, "paper")])])
                row["target_accurate_over_paper"] = TARGET_ACCURATE_OVER_PAPER
            elif m in OPTION_METHODS and (case, "paper") in samples:
                row["option_over_paper"] = med([a["step_ms"] / p["step_ms"]
                                                for a, p in zip(s, samples[(case, "paper")])])
            rows.append(row)
            tgt = row["target_step_over_sweep"]
            oc = [x for x in row["other_cores"] if x is not None]
            print(f"\n{case}, {m} method ({row['particles']} bodies, {row['links_after_warmup']} links, fastest "
                  f"{row['max_speed_lu_after_warmup']:.3g} lu after warm-up): whole step {row['step_ms']:.3f} ms; "
                  f"step/sweep {row['step_over_sweep']:.2f}" + (f" (target <= {tgt})" if tgt else "")
                  + f" (rounds {', '.join(f'{x:.2f}' for x in row['step_over_sweep_all'])}); step/free step "
                  f"{row['step_over_free_step']:.2f}"
                  + (f"; acc/paper {row['accurate_over_paper']:.2f} (target <= {TARGET_ACCURATE_OVER_PAPER})"
                     if "accurate_over_paper" in row else "")
                  + (f"; /paper {row['option_over_paper']:.2f}" if "option_over_paper" in row else "")
                  + (f"; other processes {max(oc):.2f} cores at most" if oc else ""))
            for e, v in eff.items():
                print(f"    {v:8.3f} ms  {e}")
            print(f"    {row['between_ms']:8.3f} ms  (between effects: guard every 50 steps, Python loop)")

    # the summary table (the one benchmarks/README.md carries)
    print("\n| run | method | sweep | wall | particles | collisions | whole step | particle-free sweep | "
          "step / sweep (target) | step / free step | accurate / paper (target) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in rows:
        g = row["groups_ms"]
        ap_ = (f"{row['accurate_over_paper']:.2f} (<= {TARGET_ACCURATE_OVER_PAPER})" if "accurate_over_paper" in row
               else f"{row['option_over_paper']:.2f}" if "option_over_paper" in row else "")
        tgt = row["target_step_over_sweep"]
        print(f"| `{row['case']}` | {row['method']} | {g['sweep']:.2f} | {g['wall']:.2f} | {g['particles']:.2f} | "
              f"{g['collisions']:.2f} | {row['step_ms']:.2f} | {row['free_sweep_ms']:.2f} | "
              f"{row['step_over_sweep']:.2f}" + (f" (<= {tgt})" if tgt else "")
              + f" | {row['step_over_free_step']:.2f} | {ap_} |")
    if not all(r["finite"] for r in rows):
        print("\nWARNING: a run went non-finite; its figures mean nothing")
    if args.json:
        out = {"machine": machine_info(), "args": vars(args), "command": " ".join(sys.argv),
               "warmup_seconds": warm_s, "rounds_seconds": timed_s, "rows": rows,
               "particle_free": {f"{k[1]}_{k[2]}": dict(info[k], **v) for k, v in free_med.items()},
               "repetitions": {"/".join(k): v for k, v in samples.items()}}
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
