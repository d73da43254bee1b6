"""Several packings per case: the runs of one case from independent packings (seeds), combined.

A level with ``seeds: N`` runs every particle case once per packing seed, in
``cases/<case>/seed<k>/`` (each with its own ``stats.json``: spin-up, intervals, diagnostics). This
module writes the case's combined record in ``cases/<case>/``, the files the tables, figures,
claims and the document read:

- ``stats.json``: per axis, the mean |Omega| over the seeds and a 95 % interval that holds both
  the noise within each run and the spread between packings (``combine_means``); the orientation
  means the same way; every diagnostic as its worst seed (frozen, locked, unhealthy, not steady:
  a case is flagged when any of its seeds is, and says which); the per-seed values under
  ``seeds`` and the seed-to-seed spread under ``seed_spread_rel``.
- ``orientation.csv``: the orientation histograms averaged over the seeds, with the seed-to-seed
  standard error as the bin's interval where the runs give none.
- ``profile.csv``: the mean axial velocity profile over the seeds.
- ``summary.json``: the status (``completed`` when every seed completed), the seeds' statuses,
  steps and seconds summed, the packing of each seed, and the combined profile's distance from its
  parabola (``profile_error_rel_l2``, :func:`lbmpipe.reproduction.profile_error.profile_error`).

The combined interval is :func:`lbmpipe.reproduction.steady.combine_seeds` (independent
replications: the larger of the seeds' scatter and the runs' own noise).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from . import health as H
from . import steady
from .profile_error import profile_error
from .statistics import _jsonable

AXES = ("x", "y", "z")
_NAN = float("nan")


def combine_means(means, ci95s, dofs=None) -> dict:
    """:func:`lbmpipe.reproduction.steady.combine_seeds` on per-seed values that may be missing
    (``None``): a seed without a mean is left out; one without an interval or its degrees of
    freedom leaves only the between-seed interval."""
    dofs = list(dofs) if dofs is not None else [None] * len(means)
    num = [[_NAN if not H.finite(v) else float(v) for v in col] for col in (means, ci95s, dofs)]
    return steady.combine_seeds(*num)


def seeds_needed(spread_rel: float | None, target_rel: float, confidence: float = 0.95, most: int = 10000) -> int | None:
    """Packings a case needs for a relative half-width ``target_rel`` of its mean when the seeds'
    means scatter by ``spread_rel`` (relative standard deviation): the least ``n >= 2`` with
    ``t_{n-1} spread_rel / sqrt(n) <= target_rel`` (the between-seed interval alone, the floor
    that longer runs cannot lower); None without a measured spread."""
    if spread_rel is None or not H.finite(spread_rel):
        return None
    from scipy import stats as sps

    for n in range(2, most + 1):
        if sps.t.ppf(0.5 + confidence / 2, n - 1) * spread_rel / math.sqrt(n) <= target_rel:
            return n
    return most


def _seed_dirs(case_dir: Path, seeds) -> list[tuple[int, Path]]:
    return [(int(k), Path(case_dir) / f"seed{int(k)}") for k in seeds]


def combine_stats(case: str, per_seed: list[tuple[int, dict]]) -> dict:
    """The case's combined ``stats.json`` from the seeds' (``[(seed, stats), ...]``)."""
    done = [(k, s) for k, s in per_seed if s and s.get("status") == "completed" and s.get("samples")]
    first = next((s for _, s in per_seed if s), {})
    out = {k: first.get(k) for k in ("shape", "size_label", "reynolds", "concentration", "collisions")}
    out["case"] = case
    statuses = {k: (s or {}).get("status", "not run") for k, s in per_seed}
    out["status"] = ("completed" if done else
                     next((st for st in statuses.values() if st != "not run"), "not run"))
    out["seed_status"] = {str(k): st for k, st in statuses.items()}
    out["n_seeds"] = len(done)
    out["n_particles"] = int(np.mean([s.get("n_particles") or 0 for _, s in done])) if done else int(
        first.get("n_particles") or 0)
    out["samples"] = int(sum(int(s.get("samples") or 0) for _, s in done))
    spins = [float(s["spinup_s"]) for _, s in done if H.finite(s.get("spinup_s"))]
    out["spinup_s"] = max(spins) if spins else None

    omega, ci, intervals, spread = {}, {}, {}, {}
    for a in AXES:
        iv = [((s.get("omega_intervals") or {}).get(a) or {}) for _, s in done]
        means = [(s.get("mean_abs_omega_rad_s") or {}).get(a) for _, s in done]
        c = combine_means(means, [(s.get("ci95_rad_s") or {}).get(a) for _, s in done], [r.get("dof") for r in iv])
        omega[a], ci[a] = c["mean"], c["ci95"]
        vals = [float(v) for v in means if H.finite(v)]
        spread[a] = (float(np.std(vals, ddof=1) / abs(np.mean(vals))) if len(vals) >= 2 and np.mean(vals) else None)
        insufficient = [k for (k, _), r in zip(done, iv) if not r.get("sufficient")]
        # two or more independent packings give a valid interval whatever the correlation within
        # each run (independent replications); one packing needs its own batches to suffice
        valid = len(vals) >= 2 or (len(vals) == 1 and not insufficient)
        intervals[a] = {**c, "method": "seeds combined", "sufficient": valid,
                        "required_s": max((float(r.get("required_s") or 0.0) for r in iv), default=None),
                        "duration_s": min((float(r.get("duration_s") or 0.0) for r in iv), default=None),
                        "message": (f"seeds {', '.join(map(str, insufficient))} averaged less than 20 batches of "
                                    "5 correlation times" + ("" if valid else ": a single packing's interval is "
                                                             "not valid") if insufficient else "")}
    out["mean_abs_omega_rad_s"], out["ci95_rad_s"] = omega, ci
    out["omega_intervals"], out["seed_spread_rel"] = intervals, spread
    out["seeds_for_5pct"] = {a: seeds_needed(spread[a], 0.05) for a in AXES}
    out["tau_int_s"] = {a: max((float((s.get("tau_int_s") or {}).get(a)) for _, s in done
                                if H.finite((s.get("tau_int_s") or {}).get(a))), default=None) for a in AXES}

    kinds = sorted({kind for _, s in done for kind in (s.get("orientation") or {})})
    orient = {}
    for kind in kinds:
        rows = [((s.get("orientation") or {}).get(kind) or {}) for _, s in done]
        c = combine_means([r.get("mean_deg") for r in rows], [r.get("ci95_deg") for r in rows],
                          [(r.get("interval") or {}).get("dof") for r in rows])
        med = [float(r["median_deg"]) for r in rows if H.finite(r.get("median_deg"))]
        orient[kind] = {"mean_deg": c["mean"], "ci95_deg": c["ci95"], "median_deg": float(np.mean(med)) if med else None,
                        "interval": c}
    out["orientation"] = orient
    taus = [float((s.get("orientation_memory") or {}).get("tau_orient_s")) for _, s in done
            if H.finite((s.get("orientation_memory") or {}).get("tau_orient_s"))]
    out["orientation_memory"] = {"tau_orient_s": max(taus) if taus else None}
    order = [(s.get("orientation_order") or {}) for _, s in done]
    out["orientation_order"] = combine_means([o.get("mean") for o in order], [o.get("ci95") for o in order],
                                             [o.get("dof") for o in order])

    out.update(_worst_diagnostics(done))
    # a packing that ran but did not finish (unstable, failed) is not in the mean, and the case
    # says so: its issues join the case's health
    ended = [(k, s) for k, s in per_seed if s and s.get("status") not in ("completed", "not run", None)]
    for k, s in ended:
        own = list((s.get("health") or {}).get("issues") or []) or [f"status {s.get('status')}"]
        out["health"]["issues"] += [f"seed {k}: {i}" for i in own]
    out["health"]["healthy"] = not out["health"]["issues"]
    out["resolution"] = first.get("resolution")
    out["flags"] = H.case_flags(out)
    out["seeds"] = [{"seed": k, "status": statuses[k], "spinup_s": (s or {}).get("spinup_s"),
                     "mean_abs_omega_rad_s": (s or {}).get("mean_abs_omega_rad_s"),
                     "ci95_rad_s": (s or {}).get("ci95_rad_s"), "flags": (s or {}).get("flags") or []}
                    for k, s in per_seed]
    return out


def _worst_diagnostics(done: list[tuple[int, dict]]) -> dict:
    """Frozen, locked, health and spin-up of a case as its worst seed's, naming the seeds."""
    fr = [(k, s.get("frozen") or {}) for k, s in done]
    frozen_seeds = [k for k, f in fr if f.get("frozen")]
    rem = [float(f["remaining"]) for _, f in fr if H.finite(f.get("remaining"))]
    frozen = {"frozen": bool(frozen_seeds), "seeds": frozen_seeds, "remaining": max(rem) if rem else None,
              "threshold": next((f.get("threshold") for _, f in fr if f.get("threshold") is not None), None)}
    lk = [(k, s.get("locked") or {}) for k, s in done]
    locked_seeds = [k for k, d in lk if d.get("locked")]
    kept = [float(d["neighbours_retained"]) for _, d in lk if H.finite(d.get("neighbours_retained"))]
    locked = {"locked": bool(locked_seeds), "seeds": locked_seeds, "column": any(d.get("column") for _, d in lk),
              "neighbours_retained": max(kept) if kept else None}
    issues, numbers = [], {}
    for k, s in done:
        h = s.get("health") or {}
        issues += [f"seed {k}: {i}" for i in h.get("issues") or []]
        for key, v in h.items():
            if H.finite(v):
                numbers[key] = max(numbers.get(key, float(v)), float(v))  # magnitudes: the worst seed's
    health = {**numbers, "issues": issues, "healthy": not issues}
    sp = [(k, s.get("spinup") or {}) for k, s in done]
    unsteady = [k for k, d in sp if d and not d.get("steady", True)]
    spinup = {"steady": not unsteady, "seeds_not_steady": unsteady,
              "spinup_s": max((float(d["spinup_s"]) for _, d in sp if H.finite(d.get("spinup_s"))), default=None),
              "required_s": max((float(d["required_s"]) for _, d in sp if H.finite(d.get("required_s"))), default=None),
              "message": "; ".join(f"seed {k}: {d.get('message')}" for k, d in sp if k in unsteady and d.get("message"))}
    return {"frozen": frozen, "locked": locked, "health": health, "spinup": spinup}


def combine_orientation(frames: list[pd.DataFrame]) -> pd.DataFrame:
    """Orientation histograms averaged over the seeds: per (kind, bin) the mean fraction; the
    bin's interval the larger of the seeds' standard error and the runs' own intervals combined."""
    frames = [f for f in frames if f is not None and not f.empty]
    if not frames:
        return pd.DataFrame()
    keys = [c for c in frames[0].columns if c not in ("fraction", "ci95")]
    rows = []
    for key, g in pd.concat(frames, ignore_index=True).groupby(keys, sort=False, dropna=False):
        c = combine_means(list(g["fraction"]), list(g["ci95"]) if "ci95" in g else [None] * len(g))
        rows.append({**dict(zip(keys, key if isinstance(key, tuple) else (key,))),
                     "fraction": c["mean"], "ci95": c["ci95"] if c["ci95"] is not None else float("nan")})
    return pd.DataFrame(rows, columns=list(frames[0].columns))


def combine_profiles(frames: list[pd.DataFrame]) -> pd.DataFrame:
    """Mean axial velocity profile over the seeds (same radial bins: same lattice and pipe)."""
    frames = [f for f in frames if f is not None and not f.empty]
    if not frames:
        return pd.DataFrame(columns=["r_mm", "uz_m_s", "uz_poiseuille_m_s", "nodes"])
    out = frames[0].copy()
    out["uz_m_s"] = np.mean([f["uz_m_s"].to_numpy() for f in frames], axis=0)
    return out


def combine_summaries(case: str, per_seed: list[tuple[int, dict | None]]) -> dict:
    """The case's ``summary.json``: status, the seeds' statuses, summed steps and seconds."""
    ok = [s for _, s in per_seed if s]
    statuses = {str(k): (s or {}).get("status", "not run") for k, s in per_seed}
    status = ("completed" if ok and all(st == "completed" for st in statuses.values()) else
              "unpackable" if ok and all(st == "unpackable" for st in statuses.values()) else
              next((st for st in statuses.values() if st not in ("completed", "not run")), "not run"))
    first = next((s for s in ok if s.get("status") == "completed"), ok[0] if ok else {})
    msg = "; ".join(f"seed {k}: {st}" for k, st in statuses.items() if st != "completed")
    return {"case": case, "status": status, "message": msg or first.get("message", ""),
            "seeds": [{"seed": k, "status": statuses[str(k)], "message": (s or {}).get("message", ""),
                       "packing": (s or {}).get("packing"), "steps": (s or {}).get("steps"),
                       "wall_seconds": (s or {}).get("wall_seconds")} for k, s in per_seed],
            "steps": int(sum(int(s.get("steps") or 0) for s in ok)),
            "simulated_seconds": float(sum(float(s.get("simulated_seconds") or 0.0) for s in ok)),
            "wall_seconds": float(sum(float(s.get("wall_seconds") or 0.0) for s in ok)),
            "spinup_s": first.get("spinup_s"), "particles": first.get("particles"),
            "packing": first.get("packing")}


def write_combined(case: str, case_dir: Path, seeds, config: dict | None = None) -> dict:
    """Write the combined ``stats.json``, ``orientation.csv``, ``profile.csv`` and ``summary.json``
    of ``case`` in ``case_dir`` from its ``seed<k>/`` runs; returns the combined stats. Each seed's
    run health is judged again against ``config``'s thresholds (default: the repository's
    ``config.yaml``) from its summary and flow-rate series, so a threshold changed after a run's
    statistics were computed applies without its trajectory."""
    case_dir = Path(case_dir)
    dirs = _seed_dirs(case_dir, seeds)
    limits = H.thresholds(config)["health"]
    stats = combine_stats(case, [(k, H.refresh_health(H.read_json(d / "stats.json"), d, limits)) for k, d in dirs])
    (case_dir / "stats.json").write_text(json.dumps(_jsonable(stats), indent=2, allow_nan=False) + "\n")

    def _csv(p: Path):
        try:
            return pd.read_csv(p) if p.exists() else None
        except pd.errors.EmptyDataError:
            return None

    combine_orientation([_csv(d / "orientation.csv") for _, d in dirs]).to_csv(case_dir / "orientation.csv", index=False)
    profile = combine_profiles([_csv(d / "profile.csv") for _, d in dirs])
    profile.to_csv(case_dir / "profile.csv", index=False)
    summary = combine_summaries(case, [(k, H.read_json(d / "summary.json")) for k, d in dirs])
    # the combined profile's distance from its parabola (Fig. 10), as every profile distance is defined
    err = profile_error(profile) if len(profile) else float("nan")
    if np.isfinite(err):
        summary["profile_error_rel_l2"] = err
    (case_dir / "summary.json").write_text(json.dumps(_jsonable(summary), indent=2, allow_nan=False) + "\n")
    return stats

