"""Where a committed run's numbers come from: the commit of its code, per level, and the reruns that
replaced first runs (issue 46, provenance).

Every run records its commit (``summary.json``: ``provenance.git_commit``, or ``git_commit`` in runs
made before the ``provenance`` record), ``-dirty`` when the tree had uncommitted changes (its code
cannot be recovered). ``reruns.csv`` (``benchmarks/rerun_identity.py --adopt``) lists each run made
again on one clean commit and whether it reproduced its first run bit for bit (last frame and force
series identical)."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pandas as pd

from .robustness import runs_done

RERUN_COLUMNS = ["run", "old_commit", "new_commit", "last_frame_identical", "force_identical"]


def run_commit(summary_path: Path) -> str:
    """The commit a run's ``summary.json`` records; an error naming the file when it records none."""
    s = json.loads(Path(summary_path).read_text())
    commit = (s.get("provenance") or {}).get("git_commit") or s.get("git_commit")
    if not commit:
        raise ValueError(f"{summary_path}: no git_commit recorded; its code cannot be named. Rerun the run "
                         "(snakemake -R simulate_particles -- <its summary.json>) from a clean commit")
    return str(commit)


def level_commits(config: dict, level: str, results: Path) -> Counter:
    """Runs per commit among the level's runs present (``robustness.runs_done``; a run not made is not counted)."""
    return Counter(run_commit(Path(results) / level / "cases" / run / "summary.json")
                   for run in runs_done(config, level, Path(results))[0])


def rerun_counts(fid_dir: Path) -> dict | None:
    """From ``reruns.csv``: reruns in all, bit-identical ones, and those replacing a first run made on a
    dirty tree that they did not reproduce; None without the file."""
    path = Path(fid_dir) / "reruns.csv"
    if not path.exists():
        return None
    df = pd.read_csv(path)
    missing = [c for c in RERUN_COLUMNS if c not in df]
    if missing:
        raise ValueError(f"{path}: columns {missing} missing; rebuild it with benchmarks/rerun_identity.py --adopt")
    same = df["last_frame_identical"].astype(bool) & df["force_identical"].astype(bool)
    dirty = df["old_commit"].astype(str).str.endswith("-dirty")
    return {"n": len(df), "identical": int(same.sum()), "dirty_differ": int((~same & dirty).sum()),
            "clean_differ": int((~same & ~dirty).sum()), "commits": set(df["new_commit"].astype(str))}


def provenance_text(config: dict, levels: list[str], fid_dir: Path) -> str:
    """One paragraph: every run of ``levels`` by commit (clean or not), and the base level's reruns."""
    fid_dir = Path(fid_dir)
    per = {lv: level_commits(config, lv, fid_dir.parent) for lv in levels}
    per = {lv: c for lv, c in per.items() if c}
    n = sum(sum(c.values()) for c in per.values())
    dirty = sum(k for c in per.values() for commit, k in c.items() if commit.endswith("-dirty"))
    spans = ", ".join(f"`{lv}` {len(c)}" for lv, c in per.items())
    text = (f"**Provenance.** Every run records the commit of its code (`summary.json`, `provenance`): "
            f"the {n} runs of the levels in this document come from " + ("clean commits" if not dirty else
                                                         f"clean commits but {dirty}, made on a tree with uncommitted "
                                                         "changes (code not recoverable)")
            + f"; commits per level: {spans}.")
    rr = rerun_counts(fid_dir)
    if rr is not None:
        base = fid_dir.name
        first = sum(k for commit, k in per.get(base, Counter()).items() if commit not in rr["commits"])
        text += (f" `{base}`'s {rr['n']} reruns on one clean commit (`reruns.csv`, `benchmarks/rerun_identity.py`): "
                 f"{rr['identical']} reproduce their first run bit for bit, {rr['dirty_differ']} replace a first run "
                 "made on a dirty tree, which they do not reproduce"
                 + (f", {rr['clean_differ']} differ from a clean first run" if rr["clean_differ"] else "")
                 + f"; {first} runs are still their first run, on an older clean commit.")
    return text
