"""Reruns of committed runs on a clean commit: are they the same run, and adopt them.

Issue 46 asks for two things of the committed ``credible`` runs: a compact series from which the
statistics can be rebuilt (it needs the trajectory, which is not committed, so every run is rerun
from its committed scene and packing) and clean provenance (32 runs were made on a tree with
uncommitted changes). A rerun on one clean commit settles both when it is the same run: this script
compares a rerun (made in another checkout, e.g. a worktree of the clean commit, with
``snakemake -c1 --config new_runs=all -R simulate_particles <summary.json>``) with the committed
files, prints per run whether the final particle state (``last_frame.csv`` against the rerun's last
trajectory sample) and the driving-force series are bit-identical and the largest relative
difference of the other flow observables, and appends the rows to ``results/<level>/reruns.csv``.

With ``--adopt`` it then copies the rerun's outputs over the committed ones (summary, flow series,
profile, static table, benchmark record, and the trajectory, which git ignores) and rebuilds the
run's statistics with today's code (``series.csv.gz``, ``trajectory.json``, ``stats.json``,
``orientation.csv``, ``last_frame.csv``).

    python benchmarks/rerun_identity.py <checkout of the reruns> --level credible [--adopt]

Bits also depend on OpenBLAS's kernel (the flux correction's dot product): the committed runs used an
AVX-512 one, so on a host whose environment forces ``OPENBLAS_CORETYPE=Haswell`` make the reruns with
it unset (``env -u OPENBLAS_CORETYPE snakemake ...``); ``summary.json``'s ``host.openblas_coretype``
says which a run had (benchmarks/README.md, "A run's bits and the BLAS kernel").
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COPY = ["summary.json", "flow_rate.csv", "profile.csv", "particles_static.csv", "particles.parquet"]
COLUMNS = ["run", "old_commit", "new_commit", "last_frame_identical", "force_identical", "max_rel_diff_flow",
           "old_wall_s", "new_wall_s"]


def committed(path: Path) -> str | None:
    """The text of ``path`` at HEAD of this repository (None if not committed)."""
    r = subprocess.run(["git", "show", f"HEAD:{path.relative_to(ROOT)}"], cwd=ROOT, capture_output=True, text=True)
    return r.stdout if r.returncode == 0 else None


def compare(run: str, level: str, rerun_root: Path) -> dict:
    """One row of the table: the rerun ``rerun_root/results/<level>/cases/<run>`` against HEAD."""
    mine = ROOT / "results" / level / "cases" / run
    new = rerun_root / "results" / level / "cases" / run
    old_summary = json.loads(committed(mine / "summary.json"))
    new_summary = json.loads((new / "summary.json").read_text())
    row = {"run": run, "old_commit": old_summary.get("git_commit"), "new_commit": new_summary.get("git_commit"),
           "old_wall_s": old_summary.get("wall_seconds"), "new_wall_s": new_summary.get("wall_seconds")}
    old_fr = pd.read_csv(io.StringIO(committed(mine / "flow_rate.csv")))
    new_fr = pd.read_csv(new / "flow_rate.csv")
    same_shape = old_fr.shape == new_fr.shape and list(old_fr.columns) == list(new_fr.columns)
    row["force_identical"] = bool(same_shape and np.array_equal(old_fr["force_density_N_m3"].to_numpy(),
                                                                new_fr["force_density_N_m3"].to_numpy()))
    if same_shape:
        rel = [np.max(np.abs(old_fr[c] - new_fr[c]) / np.maximum(np.abs(old_fr[c]), 1e-300)) for c in old_fr.columns]
        row["max_rel_diff_flow"] = float(max(rel))
    else:
        row["max_rel_diff_flow"] = float("nan")
    old_last = committed(mine / "last_frame.csv")
    pq = new / "particles.parquet"
    if old_last is not None and pq.exists():
        a = pd.read_csv(io.StringIO(old_last))
        df = pd.read_parquet(pq)
        b = df[df["t_s"] == df["t_s"].max()].reset_index(drop=True)
        cols = [c for c in a.columns if c in b.columns]
        row["last_frame_identical"] = bool(len(a) == len(b) and all(np.array_equal(a[c].to_numpy(), b[c].to_numpy())
                                                                    for c in cols))
    else:
        row["last_frame_identical"] = False
    return row


def adopt(run: str, level: str, rerun_root: Path, config: dict) -> None:
    """Copy the rerun's outputs over the committed run and rebuild its statistics."""
    from lbmpipe.reproduction.cases import run_case
    from lbmpipe.reproduction.statistics import write_case_outputs

    mine = ROOT / "results" / level / "cases" / run
    new = rerun_root / "results" / level / "cases" / run
    for name in COPY:
        if (new / name).exists():
            shutil.copy2(new / name, mine / name)
    bench = Path("results") / level / "benchmarks" / f"{run}.simulate.tsv"
    if (rerun_root / bench).exists():
        shutil.copy2(rerun_root / bench, ROOT / bench)
    write_case_outputs(run, mine, run_case(config, run)[1], config)


def main(argv=None) -> int:
    import yaml

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rerun_root", type=Path, help="checkout holding the reruns (its results/<level>/cases/...)")
    ap.add_argument("--level", default="credible")
    ap.add_argument("--adopt", action="store_true", help="copy the reruns in and rebuild their statistics")
    a = ap.parse_args(argv)
    table = ROOT / "results" / a.level / "reruns.csv"
    done = pd.read_csv(table) if table.exists() else pd.DataFrame(columns=COLUMNS)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    rows = []
    for marker in sorted((a.rerun_root / "results" / a.level / "cases").glob("*/seed*/.rerun_done")):
        run = f"{marker.parent.parent.name}/{marker.parent.name}"
        if run in set(done["run"]):
            continue
        row = compare(run, a.level, a.rerun_root)
        rows.append(row)
        print(f"{run:34s} last frame {'identical' if row['last_frame_identical'] else 'DIFFERS':9s} "
              f"force {'identical' if row['force_identical'] else 'DIFFERS':9s} "
              f"flow observables max rel diff {row['max_rel_diff_flow']:.1e}  ({row['old_commit']} -> {row['new_commit']})")
        if a.adopt:
            adopt(run, a.level, a.rerun_root, config)
    if rows and a.adopt:
        out = pd.concat([done, pd.DataFrame(rows, columns=COLUMNS)], ignore_index=True).sort_values("run")
        out.to_csv(table, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
