"""Whether a level's "not steady" flags survive a correction for testing several observables.

    python benchmarks/steady_flags.py                 # the credible level
    python benchmarks/steady_flags.py --level credible_accurate

Each run's spin-up test (``lbmpipe.reproduction.steady.spinup_end``) compares the two halves of
the kept window of each of its k observables at 95 %, and asks MSER to settle in the first half;
with k tests some halves differ by chance. ``steady.steady_corrected`` reads every run's stored
halves again at a family-wise 95 % (Bonferroni). Prints, per run, the worst z, the bound and the
observables MSER did not settle, then the count of each verdict: drift (halves beyond the bound),
mser (not settled), chance (steady once corrected).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.reproduction.document_sections import stationarity_section  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default="credible")
    ap.add_argument("--results", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    sec = stationarity_section(Path(args.results) / args.level)
    if sec is None:
        print(f"level {args.level}: no run records the halves of its spin-up test")
        return 0
    print(f"{'run':34s} {'k':>2s} {'bound':>5s} {'worst z':>7s}  {'observable':18s} {'verdict':8s} MSER not settled")
    for r in sec["runs"]:
        print(f"{r['run']:34s} {r['k']:2d} {r['bound']:5.2f} {r['worst_z']:7.2f}  {r['worst'] or '-':18s} "
              f"{r['verdict']:8s} {', '.join(r['unsettled']) or '-'}")
    print(f"\n{sec['n']} runs: " + "; ".join(f"{v} {k}" for k, v in sec["counts"].items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
