"""Whether a level's "not steady" flags survive a correction for testing several observables.

    python benchmarks/steady_flags.py                 # the credible level
    python benchmarks/steady_flags.py --level paper

Each run's spin-up test (``lbmpipe.reproduction.steady.spinup_end``) compares the two halves of
the kept window of each of its observables at 95 %, and asks MSER to settle in the first half.
With k observables per run, some halves differ by chance. This reads the halves stored in every
run's ``stats.json`` and recomputes each comparison as a z-score, ``1.96 |m1 - m2| / sqrt(h1^2 +
h2^2)`` (the halves' half-widths use Student's t, so this z is if anything too small), against the
Bonferroni bound ``z_{1 - 0.025/k}``. Prints, per run, the worst z and the observables MSER did not
settle, then how many runs fail beyond the bound, fail by MSER with their halves within it, or
fail only at 95 % each (steady once the k tests are corrected for).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from statistics import NormalDist

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.reproduction.health import read_json  # noqa: E402


def classify(spinup: dict) -> tuple[str, float, str, list[str]]:
    """(verdict, worst z, its observable, observables MSER did not settle) of one run's spin-up
    record; verdict: steady, beyond the bound, only at 95 %, MSER only."""
    obs = spinup.get("observables") or {}
    k = max(len(obs), 1)
    bound = NormalDist().inv_cdf(1 - 0.025 / k)
    z = {}
    for name, o in obs.items():
        h = math.hypot(o.get("first_ci95") or math.nan, o.get("second_ci95") or math.nan)
        if math.isfinite(h) and h > 0:
            z[name] = 1.96 * abs(o["first"] - o["second"]) / h
    worst = max(z, key=z.get) if z else ""
    zw = z.get(worst, math.nan)
    unsettled = [n for n, o in obs.items() if not o.get("settled")]
    if spinup.get("steady"):
        verdict = "steady"
    elif zw > bound:
        verdict = "halves differ beyond the bound"
    elif unsettled:
        verdict = "MSER not settled (halves within the bound)"
    elif any(v > 1.96 for v in z.values()):
        verdict = "halves differ only at 95 % each (steady under the bound)"
    else:
        verdict = "halves without an interval"
    return verdict, zw, worst, unsettled


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default="credible")
    ap.add_argument("--results", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    cases = Path(args.results) / args.level / "cases"
    files = sorted(cases.glob("*/seed*/stats.json")) or sorted(cases.glob("*/stats.json"))
    counts: dict[str, int] = {}
    print(f"{'run':34s} {'k':>2s} {'bound':>5s} {'worst z':>7s}  {'observable':18s} MSER not settled")
    for f in files:
        sp = (read_json(f) or {}).get("spinup") or {}
        if not sp.get("observables"):
            continue
        verdict, zw, worst, unsettled = classify(sp)
        counts[verdict] = counts.get(verdict, 0) + 1
        k = len(sp["observables"])
        print(f"{str(f.parent.relative_to(cases)):34s} {k:2d} {NormalDist().inv_cdf(1 - 0.025 / k):5.2f} "
              f"{zw:7.2f}  {worst:18s} {', '.join(unsettled) or '-'}")
    n = sum(counts.values())
    print(f"\n{n} runs: " + "; ".join(f"{v} {k}" for k, v in sorted(counts.items(), key=lambda x: -x[1])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
