"""The wall-time model of a level's runs, per processor, as Markdown (the section "Run cost per
processor" of benchmarks/README.md; the reproduction document links to it).

    python benchmarks/run_cost_model.py                 # the credible level
    python benchmarks/run_cost_model.py --level paper

Reads ``results/<level>/tables/cost_model.json`` and ``cost_validation.csv`` (written by the
pipeline through ``lbmpipe.reproduction.runcost``) and prints the fitted coefficients, the errors
of the family-held-out validation and one row per processor. Nothing is run or fitted here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lbmpipe.reproduction.document_sections import runtime_section  # noqa: E402


def markdown(level_dir: Path, level: str) -> str:
    m = runtime_section(level_dir, level)["model"]
    if m is None:
        return f"{level_dir}/tables/cost_model.json: missing or without runs.\n"
    out = [f"Level `{level}`: `lbmpipe.reproduction.runcost` charges each group of the step's effects, timed in "
           f"every run's `summary.json`, to the work it scales with. Per step, with a core of one's own: "
           f"{m['ns_node']} ns per fluid node, {m['ns_link']} ns per particle boundary link, {m['us_particle']} µs "
           f"per particle (collisions) and {m['ms_step']} ms for the rest of the loop; per run, {m['intercept_s']} s "
           f"of set-up and output. The wall time is that over the share of a core the run gets beside the host's "
           f"other jobs (`cpu_share`, median {m['share']}). Fitted to {m['n_runs']} runs ({m['families']} case "
           f"families); each run predicted by the model fitted with its whole family held out: given the run's "
           f"share, median error {m['median_pct']} % (largest {m['max_pct']} %); at the median share "
           f"{m['median_share_pct']} % (largest {m['max_share_pct']} %), over {m['n_validated']} runs "
           f"(`tables/cost_validation.csv`). `lbmpipe check` prints both predictions for any scene.", "",
           "The vectorised fluid step's time per node depends on the processor the kernels were compiled for: a "
           "processor with runs of two case families or more gets its own coefficients, validated against the "
           f"other families' runs of that processor alone. Runs made before the processor was recorded: "
           f"{m['unrecorded']}.", ""]
    if m["hosts"]:
        out += ["| processor | runs | families | validated | ns per fluid node | median error, given share (%) "
                "| at median share (%) |", "|---|---|---|---|---|---|---|"]
        out += [f"| {h['cpu']} | {h['n_runs']} | {h['families']} | {h['n_validated']} | {h['ns_node']} | "
                f"{h['median_pct']} | {h['median_share_pct']} |" for h in m["hosts"]]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", default="credible")
    ap.add_argument("--results", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    print(markdown(Path(args.results) / args.level, args.level), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
