"""Issue 44, validation item 4: the Jeffery orbit of a free L/D = 2 circular cylinder tumbling in
simple shear, its period against Jeffery's with the equivalent aspect ratio of Zhang et al. (2011),
``r_e = 1.914`` (``T gamma = 15.31``), the paper's method beside the accurate one, at tau 1.0 and
1.78 (``tests/test_jeffery.py`` runs it small).

Harness: ``lbmpipe.reproduction.jeffery`` (setup, reference and measurement in its docstring):
D3Q15, plane Couette flow between walls moving at -+U (y), periodic in x (flow) and z (vorticity),
the neutrally buoyant cylinder at the centre with its axis along the flow at the start; the period
is twice the time the axis takes to turn by pi after a start-up of ``3 D^2 / nu`` steps
(``fit``: Jeffery's ``phi(t)`` fitted to the same samples, with its equivalent ratio ``r_fit``).
Contenders: ``paper`` (half-way bounce-back, Ladd's exchange, BGK) and ``accurate`` (``cli``,
``galilean``, TRT with magic 3/16).

Run (one thread)::

    python benchmarks/jeffery.py [--D 8] [--box 48 48 40] [--re-p 0.1] [--taus 1.0 1.78]
                                 [--methods paper accurate] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import machine_info, set_threads  # noqa: E402


def main(argv=None) -> int:
    from lbmpipe.reproduction import jeffery as jf

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--D", type=float, default=8.0, help="cylinder diameter (lattice spacings); length 2D")
    ap.add_argument("--box", type=int, nargs=3, default=[48, 48, 40], help="Lx (flow) H (between walls) Lz")
    ap.add_argument("--re-p", type=float, default=0.1, help="particle Reynolds number gamma D^2 / nu")
    ap.add_argument("--taus", type=float, nargs="+", default=[1.0, 1.78])
    ap.add_argument("--methods", nargs="+", default=list(jf.METHODS), choices=list(jf.METHODS))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    ref = jf.jeffery_period(jf.R_E_ZHANG)
    out: dict = {"machine": machine_info(), "command": " ".join(sys.argv), "r_e": jf.R_E_ZHANG,
                 "T_gamma_jeffery": ref, "runs": []}
    head = ["tau", "method", "D", "box (x, H, z)", "Re_p", "steps", "T gamma", "Jeffery", "error", "fit T gamma",
            "r_fit", "run (s)"]
    print(f"Jeffery period of an L/D = 2 cylinder: r_e = {jf.R_E_ZHANG:.3f} (Zhang et al. 2011), "
          f"T gamma = {ref:.3f}\n")
    print("| " + " | ".join(head) + " |")
    print("|" + " --- |" * len(head), flush=True)
    t0 = time.perf_counter()
    for tau in args.taus:
        for method in args.methods:
            run = jf.sheared_cylinder(args.D, args.box, tau=tau, re_p=args.re_p, method=method)
            g = run["gamma"]
            tg = jf.period(run) * g
            fit = jf.fit_jeffery(run)
            row = {"tau": tau, "method": method, "D": args.D, "box": list(args.box), "re_p": args.re_p,
                   "steps": run["steps"], "T_gamma": tg, "error": tg / ref - 1.0, "fit_T_gamma": fit["period"] * g,
                   "r_fit": fit["r_e"], "fit_rms_rad": fit["rms"], "seconds": run["seconds"],
                   "drift": run["drift"].tolist()}
            out["runs"].append(row)
            print(f"| {tau:g} | {method} | {args.D:g} | {' x '.join(map(str, args.box))} | {args.re_p:g} | "
                  f"{run['steps']} | {tg:.3f} | {ref:.3f} | {100 * row['error']:+.1f} % | "
                  f"{row['fit_T_gamma']:.3f} | {fit['r_e']:.3f} | {run['seconds']:.0f} |", flush=True)
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
