"""Each claim's verdict from the second half of every run's averaging window (issue 46, item 6).

A verdict that holds on the full window but not on its later half rests on the early samples (a
spin-up the test did not catch, or a slow drift). Every run's ``stats.json`` carries a
``second_half`` record (``statistics``: the same means, intervals and orientation memory over the
later half of the window's samples); here the level is rebuilt in a scratch folder with each run's
statistics and orientation histograms taken from that record, its seeds combined and its tables
aggregated exactly as the pipeline does, and the 14 claims evaluated on it.

A run without its ``second_half`` (made before the compact series existed and not yet rerun) makes
the level's half-window verdicts unavailable, and each says how many runs lack it: never a verdict
from a partial level. Until every run has it, each claim is also evaluated on the cases whose runs
all have it, second half beside full window on those same cases (a look ahead, as the robustness
controls' "partly run"), or says that those cases compare nothing of the claim.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import pandas as pd

from . import health as H
from .angles import ORIENTATION_KINDS
from .cases import split_run
from .claims import compares_anything, evaluate_claims
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


def _half_run(src: Path, dst: Path, half_window: bool = True) -> None:
    """A run's files in ``dst`` with its statistics and histograms of the second half (``half_window``
    False: of the full window, as committed)."""
    dst.mkdir(parents=True, exist_ok=True)
    for name in COPIED:
        if (src / name).exists():
            shutil.copy2(src / name, dst / name)
    s = H.read_json(src / "stats.json") or {}
    half = s.get("second_half") if half_window else None
    if half is None:  # not completed, a flow case, or the full window: as it is
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


def half_window_level(fid_dir: Path, config: dict, dest: Path, half_window: bool = True) -> Path:
    """The level ``fid_dir`` (the cases of ``config``) rebuilt in ``dest`` from the second halves
    (``half_window`` False: from the full windows), seeds combined, tables aggregated; returns ``dest``."""
    fid_dir, dest = Path(fid_dir), Path(dest)
    cases = config["cases"]
    for case in cases:
        cdir = fid_dir / "cases" / case
        if not cdir.exists():
            continue
        seeds = sorted(int(p.name[4:]) for p in cdir.glob("seed*") if p.is_dir())
        if seeds:
            for k in seeds:
                _half_run(cdir / f"seed{k}", dest / "cases" / case / f"seed{k}", half_window)
            write_combined(case, dest / "cases" / case, seeds, config)
        else:
            _half_run(cdir, dest / "cases" / case, half_window)
    aggregate(dest, cases)
    return dest


def second_half_verdicts(fid_dir: Path, config: dict, systematic: dict | None = None) -> pd.Series:
    """Each claim's verdict on the second halves (index: claim number), or, where runs lack
    their second half, ``not available: ...`` naming how many, followed by the claim on the cases
    whose runs all have it (:func:`partial_verdicts`)."""
    fid_dir = Path(fid_dir)
    missing = missing_second_half(fid_dir, config["cases"])
    if missing:
        n = len([1 for _, r in _runs(fid_dir, config["cases"]) if (r / "stats.json").exists()])
        note = (f"not available: {len(missing)} of {n} runs lack the second-half statistics (made before the compact "
                f"series; rerun them, e.g. {missing[0]})")
        return partial_verdicts(fid_dir, config, missing, systematic).map(lambda v: f"{note}; {v}").rename(
            "verdict_second_half")
    with tempfile.TemporaryDirectory(prefix="half_window_") as tmp:
        level = half_window_level(fid_dir, config, Path(tmp) / fid_dir.name)
        claims = evaluate_claims(level, config["cases"], systematic)
    return claims.set_index("claim")["verdict"].rename("verdict_second_half")


def partial_verdicts(fid_dir: Path, config: dict, missing: list[str], systematic: dict | None = None) -> pd.Series:
    """Per claim, its verdict on the second halves of the cases none of whose runs is in ``missing``
    beside the full windows of the same cases (``on the K cases complete: <half> (full window: <full>)``),
    or ``no comparison on the K cases complete``; a look ahead while reruns are missing, never the
    level's verdict."""
    lacking = {split_run(run)[0] for run in missing}
    cases = {c: v for c, v in config["cases"].items() if c not in lacking}
    k = sum(1 for c, v in cases.items() if v.get("particles") is not None and (Path(fid_dir) / "cases" / c).exists())
    sub = {**config, "cases": cases}
    with tempfile.TemporaryDirectory(prefix="half_window_") as tmp:
        half = evaluate_claims(half_window_level(fid_dir, sub, Path(tmp) / "half"), cases, systematic)
        full = evaluate_claims(half_window_level(fid_dir, sub, Path(tmp) / "full", half_window=False), cases,
                               systematic)
    on = f"on the {k} case{'' if k == 1 else 's'} complete"
    out = {}
    for (_, h), (_, f) in zip(half.iterrows(), full.iterrows()):
        out[int(h["claim"])] = (f"{on}: {h['verdict']} (full window: {f['verdict']})" if compares_anything(h)
                                else f"no comparison {on}")
    return pd.Series(out, name="verdict_second_half")
