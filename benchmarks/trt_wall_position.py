"""Where the paper's particle surface (Ladd's half-way bounce-back) sits, by collision operator:
the effective hydrodynamic radius of a fixed sphere in a simple cubic array (issue 44, the mass
put back under TRT; ``benchmarks/refill_mass.py --trt-magic``).

With half-way bounce-back the steady closure depends on the magic parameter
``Lambda = (tau_+ - 1/2)(tau_- - 1/2)`` only (BGK: ``Lambda = (tau - 1/2)^2``; Ginzburg): the
hydrodynamic surface moves with Lambda, and so does the gap between two particles. The drag of a
fixed sphere (``lbmpipe.reproduction.particle_checks.sc_array_drag``: periodic cube ``L``, solid
fraction ``c``, body force) gives ``F / (6 pi mu U) = a K`` at the nominal radius ``a``; the
effective radius ``a_eff`` is the radius whose drag in the same array is that, by the dilute
expansion of Sangani & Acrivos (1982, simple cubic; 4.289 at c = 0.125 against Zick & Homsy's
4.292):

    K(c) = 1 / (1 - 1.7601 x + x^3 - 1.5593 x^6 + 3.9799 x^8 - 3.0734 x^10),  x = c^(1/3),
    c = (4 pi / 3) a_eff^3 / L^3.

Printed per operator: Lambda, ``K / K_Zick-Homsy`` at the nominal radius, ``a_eff`` and
``a_eff - a`` (lattice spacings; > 0: the surface sits outside the nominal sphere).

Run (one thread; seconds to a minute per row):

    python benchmarks/trt_wall_position.py [--tau 1.78] [--L 20] [--c 0.125] [--magics 3/16 1/4 1/2 1 bgk]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import set_threads  # noqa: E402
from refill_mass import magic_value  # noqa: E402


def k_sangani_acrivos(c: float) -> float:
    """Dimensionless drag of a simple cubic array at solid fraction ``c`` (dilute expansion)."""
    x = c ** (1.0 / 3.0)
    return 1.0 / (1.0 - 1.7601 * x + x**3 - 1.5593 * x**6 + 3.9799 * x**8 - 3.0734 * x**10)


def effective_radius(a: float, k: float, L: int) -> float:
    """The radius whose array drag (Sangani & Acrivos) equals ``a k`` (``F / (6 pi mu U)``), by bisection."""
    target = a * k

    def g(r):
        return r * k_sangani_acrivos(4.0 * math.pi / 3.0 * r**3 / L**3) - target

    lo, hi = 0.5 * a, 1.5 * a
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def main(argv=None) -> int:
    from lbmpipe.reproduction.particle_checks import sc_array_drag

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tau", type=float, default=1.78, help="relaxation time (the credible level's at Re 9.4)")
    ap.add_argument("--L", type=int, default=20, help="edge of the periodic cube, nodes")
    ap.add_argument("--c", type=float, default=0.125, help="solid fraction (a Zick & Homsy value: 0.064, 0.125)")
    ap.add_argument("--magics", nargs="*", default=["3/16", "1/4", "1/2", "1", "bgk"],
                    help="TRT magic parameters (numbers, fractions, or bgk = (tau - 1/2)^2); BGK is always run first")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    print(f"Fixed sphere in a simple cubic array, half-way bounce-back (the paper's), L {args.L}, c {args.c:g}, "
          f"tau {args.tau:g}")
    head = f"{'operator':<12} {'Lambda':>7} {'K/K_ZH':>8} {'a':>6} {'a_eff':>7} {'a_eff-a':>8} {'steps':>6}"
    print(head)
    print("-" * len(head))
    rows = [("bgk", "bgk", (args.tau - 0.5) ** 2)] + [("trt " + m, "trt", magic_value(m, args.tau)) for m in args.magics]
    for label, op, lam in rows:
        r = sc_array_drag(args.L, args.c, tau=args.tau, collision=op, magic=lam)
        a_eff = effective_radius(r["a"], r["K"], args.L)
        print(f"{label:<12} {lam:>7.4f} {r['ratio']:>8.4f} {r['a']:>6.3f} {a_eff:>7.3f} {a_eff - r['a']:>8.3f} "
              f"{r['steps']:>6d}", flush=True)
    print("K/K_ZH: drag at the nominal radius over Zick & Homsy; a_eff: the radius with that drag in the same array "
          "(Sangani & Acrivos' expansion); a_eff - a < 0: the hydrodynamic surface inside the nominal sphere "
          "(wider gaps between particles)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
