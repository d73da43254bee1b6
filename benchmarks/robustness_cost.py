"""Planned core-hours of the robustness controls of a level (issue 47), per control level and in total.

    python benchmarks/robustness_cost.py                 # the controls of config.yaml's default level
    python benchmarks/robustness_cost.py --particle-factor 1.8 2.5

Per control: its runs, those done, the core-hours measured (the runs' summaries) and planned
(``lbmpipe.reproduction.robustness.level_core_hours``: the wall-time model of the committed runs at a core
per run, times the accurate method's measured cost over the paper's on ``credible_accurate``), and the
longest run at one core. ``--particle-factor LO HI``: the new particle side's whole step over the paper's
(interpolated surfaces, Galilean exchange, lubrication), which the committed accurate runs do not contain,
applied to the levels with ``method: accurate`` as a range; the default 1.8 2.5 is issue 44's step
benchmarks (cli + galilean 1.83-2.07 times the paper's step, lubrication 1.02-1.20 on top;
benchmarks/README.md). Prints a table and the total.
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
    ap.add_argument("--particle-factor", nargs=2, type=float, default=(1.8, 2.5), metavar=("LO", "HI"))
    args = ap.parse_args(argv)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    base = args.level or config["fidelity"]
    results = ROOT / "results"
    model = wall_model(base, ROOT)
    lo, hi = args.particle_factor
    print(f"accurate method's measured cost over the paper's (credible_accurate): {R.accurate_factor(config, results):.2f}")
    print(f"{'control':24s} {'level':20s} {'runs':>5s} {'done':>5s} {'measured h':>10s} {'planned h':>10s} "
          f"{'with particle side':>18s} {'longest run (1 core)':>28s}")
    tot = [0.0, 0.0, 0.0]
    for lvl in R.control_levels(config, base):
        measured, planned, _ = R.level_core_hours(config, lvl, results)
        done, missing = R.runs_done(config, lvl, results)
        acc = config["fidelities"][lvl].get("method") == "accurate"
        f_lo, f_hi = (lo, hi) if acc else (1.0, 1.0)
        run, minutes = longest_minutes(config, lvl, model) if model else ("", float("nan"))
        rng = f"{planned * f_lo:.1f}-{planned * f_hi:.1f}" if acc else f"{planned:.1f}"
        mins = f"{minutes * f_lo:.0f}-{minutes * f_hi:.0f}" if acc else f"{minutes:.0f}"
        print(f"{R.control_label(config, lvl):24s} {lvl:20s} {len(done) + len(missing):5d} {len(done):5d} "
              f"{measured:10.1f} {planned:10.1f} {rng:>18s} {run + ' ' + mins + ' min':>28s}")
        tot[0] += planned
        tot[1] += planned * f_lo
        tot[2] += planned * f_hi
    print(f"total planned: {tot[0]:.1f} core-hours at the committed runs' cost; {tot[1]:.1f}-{tot[2]:.1f} with the "
          f"new particle side (factor {lo:g}-{hi:g} on the accurate levels)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
