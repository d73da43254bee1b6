"""What the numerical method changes: the paper's method (BGK, half-way bounce-back, Ladd's coupling)
against a more accurate one (``cases.METHODS``: ``accurate_fluid``, TRT with magic 1/4 and the
Bouzidi pipe wall, or ``accurate``, which adds issue 44's particle options), run by run and claim by
claim. The numerics the compared level changes are read from the config (``cases.method_numerics``)
and written into ``summary.json`` (``accurate_method``, ``accurate_numerics``).

A level with ``method: accurate`` (or ``accurate_fluid``) and ``compare_with: <level>`` runs a subset of the cases on the
same lattice, run lengths and packings as the paper-method level. Each of its runs is paired with
the paper-method run of the same case and packing seed, so the packing's large effect on the mean
spin (the seed-to-seed scatter of issue "steady results") cancels from the difference. Per pair and
observable: both values with their 95 % intervals, the difference relative to the paper method's
value, and whether it exceeds the two intervals combined (independent runs: sqrt(ci_a^2 + ci_p^2)).
Observables: mean |Omega| about x, y, z (Figs. 4-7), the mean orientation angle (Figs. 8-9), and
the flow profile's relative L2 distance from Poiseuille (Fig. 10, ``profile_error`` of the run's
``profile.csv``; for the particle-free flows this is the wall treatment's own error). Per claim: the verdicts side by side, each evaluated from packing
seed 1 of the accurate level's cases under both methods; the level's ``claims.csv`` carries them
beside its own verdict from all its packings and cases (``claims.LEVEL_CLAIM_COLUMNS``).
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

import pandas as pd

from ..outputs import write_json
from .cases import level_cases, level_runs, method_numerics
from .claims import evaluate_claims
from .comparison_figures import method_comparison
from .health import _num as _f
from .health import read_json as _read
from .health import refresh_health, thresholds
from .profile_error import read_profile_error
from .statistics import aggregate

#: the orientation angle of each shape that Figs. 8-9 show (stats.json ``orientation``)
ANGLE_KEY = {"cylinder": "cyl_axis_angle", "cube": "cube_projected_angle"}
RUN_COLUMNS = ["run", "observable", "paper", "paper_ci95", "accurate", "accurate_ci95", "rel_diff", "rel_diff_ci95",
               "significant", "paper_flags", "accurate_flags"]
CLAIM_COLUMNS = ["claim", "statement", "verdict_paper_seed1", "verdict_accurate_seed1", "same", "reason_accurate"]


def comparison_level(config: dict, level: str) -> str | None:
    """The level that runs the accurate method against ``level`` (its ``compare_with``), if any."""
    for name, fid in config["fidelities"].items():
        if fid.get("compare_with") == level:
            return name
    return None


def stats_values(stats: dict) -> dict[str, tuple[float, float]]:
    """(value, 95 % half-width) of mean |Omega| about x, y, z (Figs. 4-7) and of the mean
    orientation angle (Figs. 8-9) from a run's or a case's ``stats.json`` record; what the record
    lacks is left out."""
    out = {}
    mean, ci = stats.get("mean_abs_omega_rad_s") or {}, stats.get("ci95_rad_s") or {}
    for ax in "xyz":
        if ax in mean:
            out[f"mean_abs_omega_{ax}"] = (_f(mean[ax]), _f(ci.get(ax)))
    angle = (stats.get("orientation") or {}).get(ANGLE_KEY.get(stats.get("shape"), ""), {})
    if angle.get("mean_deg") is not None:
        out["mean_angle_deg"] = (_f(angle["mean_deg"]), _f(angle.get("ci95_deg")))
    return out


def completed_record(run_dir: Path, limits: dict | None = None) -> tuple[dict, dict] | None:
    """The ``summary.json`` and ``stats.json`` records of a completed run or case (the latter
    empty for a particle-free run); None if it is missing or did not complete. A single run's
    health and flags are judged again against ``limits`` (default: ``config.yaml``'s
    ``diagnostics.health``), as when seeds are combined (``seeds.write_combined``)."""
    summary = _read(Path(run_dir) / "summary.json")
    if summary is None or summary.get("status") != "completed":
        return None
    stats = _read(Path(run_dir) / "stats.json") or {}
    if not isinstance(stats.get("seeds"), list):
        stats = refresh_health(stats, run_dir, limits if limits is not None else thresholds()["health"])
    return summary, stats


def observables(run_dir: Path) -> tuple[dict[str, tuple[float, float]], str] | None:
    """(value, 95 % half-width) of each compared observable of one completed run, and the run's
    flags; None if the run is missing or did not complete. A particle-free run has only the
    profile's error."""
    record = completed_record(run_dir)
    if record is None:
        return None
    summary, stats = record
    # the profile's distance as every profile distance of the document (profile_error), from profile.csv
    err = read_profile_error(Path(run_dir) / "profile.csv")
    err = err if math.isfinite(err) else _f(summary.get("profile_error_rel_l2"))
    out = {"profile_error_rel_l2": (err, float("nan")), **stats_values(stats)}
    return out, ";".join(stats.get("flags") or [])


def run_rows(config: dict, paper_level: str, accurate_level: str, root: Path = Path("results")) -> pd.DataFrame:
    """One row per paired run and observable, for the accurate level's runs that completed and
    whose paper-method run of the same case and seed completed too."""
    rows = []
    for run in level_runs(config, accurate_level):
        pdir, adir = Path(root) / paper_level / "cases" / run, Path(root) / accurate_level / "cases" / run
        p, a = observables(pdir), observables(adir)
        if p is None or a is None:
            continue
        (p, p_flags), (a, a_flags) = p, a
        for obs in [k for k in p if k in a]:
            (vp, cp), (va, ca) = p[obs], a[obs]
            both = math.hypot(cp, ca) if math.isfinite(cp) and math.isfinite(ca) else float("nan")
            rel = (va - vp) / vp if vp else float("nan")
            rows.append({"run": run, "observable": obs, "paper": vp, "paper_ci95": cp, "accurate": va,
                         "accurate_ci95": ca, "rel_diff": rel,
                         "rel_diff_ci95": both / abs(vp) if vp else float("nan"),
                         "significant": bool(abs(va - vp) > both) if math.isfinite(both) else None,
                         "paper_flags": p_flags, "accurate_flags": a_flags})
    return pd.DataFrame(rows, columns=RUN_COLUMNS)


def seed1_claims(config: dict, level: str, cases: list[str], root: Path, work: Path) -> pd.DataFrame:
    """The claims of ``level`` evaluated from packing seed 1 of ``cases`` alone (the other cases
    count as not run): the accurate level runs seed 1 of a subset, so its verdicts are set beside
    the paper method's on the same packings and cases, not beside the level's three packings."""
    fid = config["fidelities"][level]
    view = Path(work) / level
    for case in cases:
        seeded = config["cases"][case].get("particles") is not None and "seeds" in fid
        src = Path(root) / level / "cases" / (f"{case}/seed1" if seeded else case)
        if (_read(src / "summary.json") or {}).get("status") is None:
            continue
        dst = view / "cases" / case
        dst.mkdir(parents=True, exist_ok=True)
        for name in SEED1_FILES:
            if (src / name).exists():
                shutil.copy2(src / name, dst / name)
    aggregate(view, config["cases"])
    return evaluate_claims(view, config["cases"])


#: the files of a run the claims read (its record, orientation histograms, profile, health inputs)
SEED1_FILES = ("summary.json", "stats.json", "orientation.csv", "profile.csv", "flow_rate.csv", "particles_static.csv")


def claim_rows(paper_seed1: pd.DataFrame, accurate_seed1: pd.DataFrame) -> pd.DataFrame:
    """Each claim's verdict under both methods from the same packing and cases; ``same`` is
    ``yes``/``no``, or ``not compared`` where either method lacks the claim's inputs."""
    rows = []
    for _, p in paper_seed1.iterrows():
        k = int(p["claim"])
        a = accurate_seed1[accurate_seed1["claim"] == k].iloc[0]
        missing = any(str(x["reason"]).startswith("inputs missing") for x in (p, a))
        rows.append({"claim": k, "statement": p["statement"],
                     "verdict_paper_seed1": p["verdict"], "verdict_accurate_seed1": a["verdict"],
                     "same": "not compared" if missing else ("yes" if p["verdict"] == a["verdict"] else "no"),
                     "reason_accurate": str(a["reason"])})
    return pd.DataFrame(rows, columns=CLAIM_COLUMNS)


def summary(runs: pd.DataFrame, claims: pd.DataFrame) -> dict:
    """Counts for the document: paired runs, significant differences per observable group,
    the median |relative difference| of mean |Omega|, the flows' profile errors, and the claims
    whose verdict changes."""
    out = {"pairs": int(runs["run"].nunique()) if len(runs) else 0}
    om = runs[runs["observable"].str.startswith("mean_abs_omega")] if len(runs) else runs
    out["omega_compared"] = int(len(om))
    out["omega_significant"] = int((om["significant"] == True).sum()) if len(om) else 0  # noqa: E712
    out["omega_median_abs_rel_diff"] = float(om["rel_diff"].abs().median()) if len(om) else float("nan")
    ang = runs[runs["observable"] == "mean_angle_deg"] if len(runs) else runs
    out["angle_compared"] = int(ang["significant"].notna().sum()) if len(ang) else 0
    out["angle_significant"] = int((ang["significant"] == True).sum()) if len(ang) else 0  # noqa: E712
    flows = runs[(runs["observable"] == "profile_error_rel_l2") & runs["run"].str.startswith("flow")] if len(runs) else runs
    out["flows"] = [{"run": r["run"], "paper": float(r["paper"]), "accurate": float(r["accurate"])}
                    for _, r in flows.iterrows()]
    compared = claims[claims["same"] != "not compared"] if len(claims) else claims
    out["claims_compared"] = int(len(compared))
    out["claims_changed"] = [int(c) for c in compared.loc[compared["same"] == "no", "claim"]] if len(compared) else []
    return out


def write(config: dict, paper_level: str, root: Path, out_dir: Path) -> dict:
    """Write ``runs.csv``, ``claims.csv``, ``summary.json`` and the figure
    ``method_comparison.png``/``.pdf`` of the comparison of ``paper_level`` with its accurate-method
    level into ``out_dir`` (empty tables when the config has no such level or none of its runs is
    done)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    acc = comparison_level(config, paper_level)
    runs = run_rows(config, paper_level, acc, root) if acc else pd.DataFrame(columns=RUN_COLUMNS)
    if acc:
        with tempfile.TemporaryDirectory() as work:
            subset = level_cases(config, acc)
            claims = claim_rows(seed1_claims(config, paper_level, subset, root, work),
                                seed1_claims(config, acc, subset, root, work))
    else:
        claims = pd.DataFrame(columns=CLAIM_COLUMNS)
    runs.to_csv(out_dir / "runs.csv", index=False, float_format="%.6g")
    claims.to_csv(out_dir / "claims.csv", index=False)
    method_comparison(runs, claims, out_dir / "method_comparison",
                      title=f"What the method changes: level {paper_level} (paper) against {acc or 'no accurate level'}")
    s = {"paper_level": paper_level, "accurate_level": acc,
         "accurate_method": config["fidelities"][acc].get("method", "paper") if acc else None,
         "accurate_numerics": method_numerics(config, acc, against=paper_level) if acc else {},
         "accurate_runs_planned": len(level_runs(config, acc)) if acc else 0, **summary(runs, claims)}
    write_json(out_dir / "summary.json", s)  # strict JSON: NaN as null
    return s

