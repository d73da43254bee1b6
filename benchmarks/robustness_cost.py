"""Planned core-hours of the robustness controls of a level (issue 47), per control level and in total.

    python benchmarks/robustness_cost.py                 # the controls of config.yaml's default level

Per control: its runs, those done, the core-hours measured (the runs' summaries) and planned
(``lbmpipe.reproduction.robustness.level_core_hours``: the wall-time model of the committed runs at a core
per run, times ``plan_factor``: what the level's runs, else other levels' runs of its method, took against
the model; printed with its basis), and the longest run at one core times that factor. Prints a table and
the total.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.cost import predict  # noqa: E402
from lbmpipe.reproduction import robustness as R  # noqa: E402
from lbmpipe.reproduction.cases import case_scene, level_runs, run_case, wall_model  # noqa: E402
from lbmpipe.scene import Scene  # noqa: E402
from lbmpipe.units import derive  # noqa: E402


def longest_minutes(config: dict, level: str, model: dict) -> tuple[str, float]:
    best = ("", 0.0)
    for run in level_runs(config, level):
        name, case = run_case(config, run)
        sc = Scene.model_validate(case_scene(name, case, level, config["fidelities"][level]))
        m = predict(sc, derive(sc), model, 1.0) / 60.0
        best = max(best, (run, m), key=lambda x: x[1])
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default=None, help="the level the controls belong to (default: config.yaml's)")
    args = ap.parse_args(argv)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    base = args.level or config["fidelity"]
    results = ROOT / "results"
    model = wall_model(base, ROOT)
    print(f"accurate method's measured cost over the paper's (credible_accurate): {R.accurate_factor(config, results):.2f}")
    print(f"{'control':24s} {'level':20s} {'runs':>5s} {'done':>5s} {'measured h':>10s} {'planned h':>10s} "
          f"{'model x':>8s} {'from':>22s} {'longest run (1 core)':>28s}")
    total = 0.0
    for lvl in R.control_levels(config, base):
        measured, planned, _ = R.level_core_hours(config, lvl, results)
        done, missing = R.runs_done(config, lvl, results)
        factor, basis = R.plan_factor(config, lvl, results, model) if model else (float("nan"), "no model")
        run, minutes = longest_minutes(config, lvl, model) if model else ("", float("nan"))
        print(f"{R.control_label(config, lvl):24s} {lvl:20s} {len(done) + len(missing):5d} {len(done):5d} "
              f"{measured:10.1f} {planned:10.1f} {factor:8.2f} {basis:>22s} {run + f' {minutes * factor:.0f} min':>28s}")
        total += planned
    print(f"total planned: {total:.1f} core-hours")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
