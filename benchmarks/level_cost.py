"""What a level's production costs: every run's steps times its measured (or predicted) seconds per
step, summed for 2 cores and as the longest run for a cluster with a core per run.

    python benchmarks/level_cost.py                       # the config's default level
    python benchmarks/level_cost.py --level credible --reference paper

Seconds per step of a run come, in this order, from its own summary.json (runs done), from another
seed of the same case, or from the reference level's run of the case (same lattice) scaled by the
median ratio of this host to the reference host over the cases measured on both. Prints one line
per case and the totals; the machine's speed enters through the runs done here, so quote it with
the host (benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.reproduction.cases import case_scene, level_runs, run_case, split_run  # noqa: E402
from lbmpipe.scene import Scene  # noqa: E402
from lbmpipe.units import derive  # noqa: E402


def _per_step(summary_path: Path) -> float | None:
    try:
        s = json.loads(summary_path.read_text())
    except (OSError, ValueError):
        return None
    if s.get("status") != "completed" or not s.get("steps"):
        return None
    return float(s["wall_seconds"]) / int(s["steps"])


def _steps(config: dict, level: str, run: str) -> int:
    name, case = run_case(config, run)
    data = case_scene(name, case, level, config["fidelities"][level])
    data.pop("particles", None)
    return int(derive(Scene.model_validate(data)).n_steps)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default=None, help="fidelity level (default: config.yaml's)")
    ap.add_argument("--reference", default="paper", help="level on the same lattice measured on another host")
    ap.add_argument("--results", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    level = args.level or config["fidelity"]
    res = Path(args.results)
    runs = level_runs(config, level)

    measured = {r: _per_step(res / level / "cases" / r / "summary.json") for r in runs}
    by_case: dict[str, list[float]] = {}
    for r, v in measured.items():
        if v is not None:
            by_case.setdefault(split_run(r)[0], []).append(v)
    ref = {c: _per_step(res / args.reference / "cases" / c / "summary.json") for c in config["cases"]}
    ratios = [statistics.median(v) / ref[c] for c, v in by_case.items() if ref.get(c)]
    factor = statistics.median(ratios) if ratios else None

    def _status(level_dir: Path, run: str) -> str | None:
        try:
            return json.loads((level_dir / "cases" / run / "summary.json").read_text()).get("status")
        except (OSError, ValueError):
            return None

    rows, missing, unpackable = [], [], []
    for r in runs:
        case = split_run(r)[0]
        if "unpackable" in (_status(res / level, r), _status(res / args.reference, case)):
            unpackable.append(r)  # no run: the packer cannot reach the concentration
            continue
        if measured[r] is not None:
            per, source = measured[r], "measured"
        elif case in by_case:
            per, source = statistics.median(by_case[case]), "other seed"
        elif ref.get(case) and factor:
            per, source = ref[case] * factor, f"{args.reference} x {factor:.2f}"
        else:
            missing.append(r)
            continue
        rows.append((r, _steps(config, level, r), per, source))

    print(f"level {level}: {len(runs)} runs, {sum(v is not None for v in measured.values())} done here; "
          f"host/reference speed ratio {factor if factor is None else round(factor, 2)} "
          f"(median over {len(ratios)} cases)")
    print(f"{'run':40s} {'steps':>8s} {'s/step':>8s} {'minutes':>8s}  source")
    for r, n, per, src in rows:
        print(f"{r:40s} {n:8d} {per:8.4f} {n * per / 60:8.1f}  {src}")
    total = sum(n * per for _, n, per, _ in rows)
    todo = sum(n * per for r, n, per, _ in rows if measured[r] is None)
    longest = max(rows, key=lambda x: x[1] * x[2]) if rows else None
    print(f"\nwhole level: {total / 3600:.1f} core-hours ({total / 7200:.1f} h on 2 cores, one run per core); "
          f"still to run: {todo / 3600:.1f} core-hours ({todo / 7200:.1f} h on 2 cores)")
    if longest:
        print(f"on a cluster with a core per run: the longest run, {longest[0]}, {longest[1] * longest[2] / 60:.0f} min")
    if unpackable:
        print(f"not packable (no run): {', '.join(unpackable)}")
    if missing:
        print(f"no estimate (not measured anywhere): {', '.join(missing)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
