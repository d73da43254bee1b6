"""What a level's production costs: every run's steps times its measured (or predicted) seconds per
step, summed for 2 cores and as the longest run for a cluster with a core per run.

    python benchmarks/level_cost.py                       # the config's default level
    python benchmarks/level_cost.py --level credible

A run's wall time comes from its own benchmark (runs done) or from the cost model
(``lbmpipe.cost.predict``) with the coefficients ``lbmpipe.reproduction.runcost`` fits to the runs
done here and validates with each case family held out; its median error is printed. Prints one line per run and the totals; the machine's speed
enters through the runs done here, so quote it with the host (benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.cost import for_host, predict  # noqa: E402
from lbmpipe.outputs import host  # noqa: E402
from lbmpipe.reproduction import runcost  # noqa: E402
from lbmpipe.reproduction.health import read_json  # noqa: E402
from lbmpipe.reproduction.cases import case_scene, level_runs, run_case, split_run  # noqa: E402
from lbmpipe.scene import Scene  # noqa: E402
from lbmpipe.units import derive  # noqa: E402


def _scene(config: dict, level: str, run: str) -> Scene:
    name, case = run_case(config, run)
    return Scene.model_validate(case_scene(name, case, level, config["fidelities"][level]))


def _status(level_dir: Path, run: str) -> str | None:
    return (read_json(level_dir / "cases" / run / "summary.json") or {}).get("status")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default=None, help="fidelity level (default: config.yaml's)")
    ap.add_argument("--results", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    level = args.level or config["fidelity"]
    level_dir = Path(args.results) / level
    runs = level_runs(config, level)
    model, val = runcost.build(level_dir, runs, level)
    done = dict(zip(val["run"], val["wall_s"]))
    if model.get("families", 0) < 3:  # too few runs of its own to identify the model: the default level's (same host)
        base = config["fidelity"]
        model, _ = runcost.build(Path(args.results) / base, level_runs(config, base), base)
        print(f"(level {level} has {len(done)} runs: predicting with level {base}'s cost model)")

    cpu = host()["cpu"]
    used, own = for_host(model, cpu)  # this processor's coefficients if the model has runs of it
    rows, unpackable, own_core = [], [], {}
    for r in runs:
        if _status(level_dir, r) == "unpackable" or _status(Path(args.results) / "paper", split_run(r)[0]) == "unpackable":
            unpackable.append(r)  # no run: the packer cannot reach the concentration
            continue
        sc = _scene(config, level, r)
        params = derive(sc)
        own_core[r] = predict(sc, params, used, 1.0)
        if r in done:
            rows.append((r, params.n_steps, float(done[r]), "measured"))
        elif (status := _status(level_dir, r)) not in (None, "completed"):  # ran and ended early: a full rerun's cost
            rows.append((r, params.n_steps, own_core[r], f"ended {status}"))
        else:
            share = used.get("median_cpu_share", 1.0)  # under the conditions of the runs measured here
            rows.append((r, params.n_steps, predict(sc, params, used, share), "cost model"))

    print(f"level {level}: {len(runs)} runs, {len(done)} done here; cost model fitted to {model['n_runs']} runs, "
          f"median error {100 * model['median_abs_rel_error_median_share']:.1f} % at the median share of a core "
          f"{model['median_cpu_share']:.2f} ({100 * model['median_abs_rel_error']:.1f} % given each run's share) "
          f"over {model['n_validated']} runs predicted with their family held out")
    print(f"predictions for this processor ({cpu}): " + (
        f"its own coefficients, {used['n_runs']} runs, median error {100 * used['median_abs_rel_error']:.1f} % given "
        f"each run's share over {used['n_validated']} runs" if own else
        f"{(model.get('runs_by_host') or {}).get(cpu, 0)} runs of it here, too few families to validate its own "
        "coefficients: the fit to all runs"))
    print(f"{'run':40s} {'steps':>8s} {'s/step':>8s} {'minutes':>8s}  source")
    for r, n, wall, src in rows:
        print(f"{r:40s} {n:8d} {wall / n:8.4f} {wall / 60:8.1f}  {src}")
    total = sum(w for _, _, w, _ in rows)
    todo = sum(w for _, _, w, src in rows if src == "cost model")
    longest = max(own_core.items(), key=lambda x: x[1]) if own_core else None
    print(f"\nwhole level: {total / 3600:.1f} core-hours ({total / 7200:.1f} h on 2 cores, one run per core); "
          f"still to run: {todo / 3600:.1f} core-hours ({todo / 7200:.1f} h on 2 cores)")
    if longest:
        print(f"on a cluster with a core of its own per run (the model at share 1): the longest run, {longest[0]}, "
              f"{longest[1] / 60:.0f} min")
    ended = [r for r, _, _, src in rows if src.startswith("ended")]
    if ended:
        print(f"ran and ended early (not averaged; counted above at a full run's predicted cost): {', '.join(ended)}")
    if unpackable:
        print(f"not packable (no run): {', '.join(unpackable)}")
    _five_percent(level_dir, runs, own_core)
    return 0


def _within_run_se(level_dir: Path, case: str, seeds: list[int], axis: str) -> float | None:
    """Root mean square over the seeds of each run's own standard error of mean |Omega| on one axis
    (its 95 % half-width over Student's t at its batches' degrees of freedom): the part of the
    seed-to-seed scatter that longer runs would lower."""
    from scipy import stats as sps

    se2 = []
    for k in seeds:
        iv = ((read_json(level_dir / "cases" / case / f"seed{k}" / "stats.json") or {}).get("omega_intervals") or {}).get(axis) or {}
        if iv.get("ci95") is not None and (iv.get("dof") or 0) >= 1:
            se2.append((float(iv["ci95"]) / sps.t.ppf(0.975, float(iv["dof"]))) ** 2)
    return (sum(se2) / len(se2)) ** 0.5 if se2 else None


def _five_percent(level_dir: Path, runs: list[str], own_core: dict) -> None:
    """What the 5 % target on mean |Omega| (seeds included) would cost: per case, the packings its
    seed-to-seed spread needs (``stats.json`` ``seeds_for_5pct``, worst axis) against those it has,
    the extra runs at this processor's one-core prediction; beside it the seeds' scatter and the
    runs' own standard error on that axis, which says whether the scatter is the packings' (more
    packings the only way down) or averaging noise (longer runs would lower it too)."""
    rows = []
    for case in sorted({split_run(r)[0] for r in runs if split_run(r)[1] is not None}):
        st = read_json(level_dir / "cases" / case / "stats.json") or {}
        need = {a: n for a, n in (st.get("seeds_for_5pct") or {}).items() if n is not None}
        seed_runs = [r for r in runs if split_run(r)[0] == case and r in own_core]
        if st.get("status") != "completed" or not need or not seed_runs:
            continue
        axis = max(need, key=need.get)
        mean = (st.get("mean_abs_omega_rad_s") or {}).get(axis)
        seeds = [int(s["seed"]) for s in st.get("seeds") or [] if s.get("mean_abs_omega_rad_s")]
        se = _within_run_se(level_dir, case, seeds, axis)
        have, n = int(st.get("n_seeds") or 0), need[axis]
        per_run = sum(own_core[r] for r in seed_runs) / len(seed_runs)
        rows.append((case, have, n, axis, (st.get("seed_spread_rel") or {}).get(axis),
                     se / abs(mean) if se is not None and mean else None, max(0, n - have) * per_run))
    if not rows:
        return
    pct = lambda v: "    -" if v is None else f"{100 * v:4.1f}%"
    print("\nthe 5 % half-width on every axis of mean |Omega| (seeds' spread; worst axis; sd and a run's own")
    print("standard error relative to the mean):")
    print(f"{'case':32s} {'packings':>8s} {'needed':>7s} {'axis':>4s} {'seed sd':>7s} {'run se':>7s} {'extra core-h':>12s}")
    for case, have, n, axis, sd, se, extra in rows:
        print(f"{case:32s} {have:8d} {n:7d} {axis:>4s} {pct(sd):>7s} {pct(se):>7s} {extra / 3600:12.1f}")
    extra = sum(r[6] for r in rows)
    packing_bound = [r[0] for r in rows if r[4] is not None and r[5] is not None and r[4] > 2 * r[5]]
    print(f"extra for the 5 % target on every completed case: {extra / 3600:.1f} core-hours "
          f"({extra / 7200:.1f} h on 2 cores); cases already within it: {sum(1 for r in rows if r[2] <= r[1])} "
          f"of {len(rows)}; cases whose seeds scatter more than twice a run's own standard error (the packings, "
          f"not the averaging, set their floor): {len(packing_bound)} of {len(rows)}")

if __name__ == "__main__":
    raise SystemExit(main())
