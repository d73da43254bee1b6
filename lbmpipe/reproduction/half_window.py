"""Each claim's verdict from the second half of every run's averaging window (issue 46, item 6).

A verdict that holds on the full window but not on its later half rests on the early samples (a
spin-up the test did not catch, or a slow drift). Every run's ``stats.json`` carries a
``second_half`` record (``statistics``: the same means, intervals and orientation memory over the
later half of the window's samples); here the level is rebuilt in a scratch folder with each run's
statistics and orientation histograms taken from that record, its seeds combined and its tables
aggregated exactly as the pipeline does, and the 14 claims evaluated on it.

A run without its ``second_half`` (made before the compact series existed and not yet rerun) makes
the half-window verdicts unavailable, and each says how many runs lack it: never a verdict from a
partial level.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import pandas as pd

from . import health as H
from .angles import ORIENTATION_KINDS
from .claims import evaluate_claims
from .seeds import write_combined
from .statistics import _jsonable, aggregate, orientation_histograms

COPIED = ("summary.json", "profile.csv", "flow_rate.csv", "series.csv.gz", "trajectory.json")


def _runs(fid_dir: Path, cases: dict) -> list[tuple[str, Path]]:
    """(case, run folder) of every particle run of a level: its seeds, or the case folder itself."""
    out = []
    for case in cases:
        cdir = fid_dir / "cases" / case
        seeds = sorted(p for p in cdir.glob("seed*") if p.is_dir())
        out += [(case, p) for p in seeds] if seeds else [(case, cdir)]
    return out


def missing_second_half(fid_dir: Path, cases: dict) -> list[str]:
    """The completed particle runs of the level whose ``stats.json`` has no ``second_half``."""
    missing = []
    for case, run in _runs(fid_dir, cases):
        s = H.read_json(run / "stats.json") or {}
        if s.get("status") == "completed" and s.get("shape") in ORIENTATION_KINDS and s.get("samples") \
                and "second_half" not in s:
            missing.append(str(run.relative_to(fid_dir / "cases")))
    return missing


def _half_run(src: Path, dst: Path) -> None:
    """A run's files in ``dst`` with its statistics and histograms of the second half."""
    dst.mkdir(parents=True, exist_ok=True)
    for name in COPIED:
        if (src / name).exists():
            shutil.copy2(src / name, dst / name)
    s = H.read_json(src / "stats.json") or {}
    half = s.get("second_half")
    if half is None:  # not completed, or a flow case: as it is
        if (src / "stats.json").exists():
            shutil.copy2(src / "stats.json", dst / "stats.json")
        if (src / "orientation.csv").exists():
            shutil.copy2(src / "orientation.csv", dst / "orientation.csv")
        return
    s = {**{k: v for k, v in s.items() if k != "second_half"}, **half}
    (dst / "stats.json").write_text(json.dumps(_jsonable(s), indent=1, allow_nan=False) + "\n")
    tau = (half.get("orientation_memory") or {}).get("tau_orient_s")
    orientation_histograms(src, s["shape"], float(half["spinup_s"]), tau_s=tau).to_csv(dst / "orientation.csv",
                                                                                        index=False)


def half_window_level(fid_dir: Path, config: dict, dest: Path) -> Path:
    """The level ``fid_dir`` rebuilt in ``dest`` from the second halves (seeds combined, tables
    aggregated); returns ``dest``."""
    fid_dir, dest = Path(fid_dir), Path(dest)
    cases = config["cases"]
    for case in cases:
        cdir = fid_dir / "cases" / case
        if not cdir.exists():
            continue
        seeds = sorted(int(p.name[4:]) for p in cdir.glob("seed*") if p.is_dir())
        if seeds:
            for k in seeds:
                _half_run(cdir / f"seed{k}", dest / "cases" / case / f"seed{k}")
            write_combined(case, dest / "cases" / case, seeds, config)
        else:
            _half_run(cdir, dest / "cases" / case)
    aggregate(dest, cases)
    return dest


def second_half_verdicts(fid_dir: Path, config: dict, systematic: dict | None = None) -> pd.Series:
    """Each claim's verdict on the second halves (index: claim number), or, where runs lack
    their second half, ``not available: ...`` naming how many."""
    fid_dir = Path(fid_dir)
    missing = missing_second_half(fid_dir, config["cases"])
    if missing:
        n = len([1 for _, r in _runs(fid_dir, config["cases"]) if (r / "stats.json").exists()])
        note = (f"not available: {len(missing)} of {n} runs lack the second-half statistics (made before the compact "
                f"series; rerun them, e.g. {missing[0]})")
        return pd.Series({k: note for k in range(1, 15)}, name="verdict_second_half")
    with tempfile.TemporaryDirectory(prefix="half_window_") as tmp:
        level = half_window_level(fid_dir, config, Path(tmp) / fid_dir.name)
        claims = evaluate_claims(level, config["cases"], systematic)
    return claims.set_index("claim")["verdict"].rename("verdict_second_half")
