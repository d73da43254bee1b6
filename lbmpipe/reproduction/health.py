"""Diagnostics of one case beyond its statistics: run health (did the solver stay physical) and the
flags every table, figure and claim shows for it.

The thresholds are stated once, in the ``diagnostics:`` block of ``config.yaml`` (validated by
``workflow/schemas/config.schema.yaml`` and ``lbmpipe check-config``); :func:`thresholds` reads them.

Run health of a case (:func:`run_health`), from its ``summary.json`` and ``flow_rate.csv``:

- ``status``: the run's status (anything but ``completed`` is unhealthy); a case combined over
  packings shows its ``summary.json``'s, naming the packings that did not complete
  (:func:`combined_status`);
- ``mass_floor_rel``: mass added by the density floor, relative to the initial mass;
- ``mass_drift_rel``: the run's relative drift of the mean fluid density (mass per fluid node,
  ``summary.json``'s ``density_drift_rel``; without particles, or in a summary that predates it,
  the drift of the total mass): with particles the total mass follows the fluid's volume, which
  bodies free to overlap (collisions off) change by several per cent without any leak;
- ``mass_corrected_rel``: mass renormalised in total by the particles' mass correction, relative
  (NaN when the summary does not record it); it grows with the run's length at a steady loss;
- ``mass_corrected_throughflow``: the same mass relative to the mass the pipe carried through a
  cross-section during the run (``mass_corrected_rel * fluid nodes / (Q_lu * steps)``): the
  spurious source the correction is, against the flow it sits in, independent of the run's length
  (judged: ``max_mass_corrected_throughflow``);
- ``mass_corrected_signed``: ``mass_corrected_rel`` with its sign (negative where the correction took
  mass out over the run);
- ``density_deviation_median``, ``density_deviation_max``: median and maximum over the samples of
  ``flow_rate.csv``'s ``max_density_deviation`` (largest ``|rho - 1|`` of the lattice);
- ``rotation_projections``, ``rotation_projection_share``: rotating projections of the collision
  step, total and per step (an upper bound on the share of steps with one);
- ``max_overlap_lu``: largest overlap left after the collisions (lattice spacings; the model
  leaves at most ``overlap_tol``, :mod:`lbmpipe.particles.collisions`);
- ``max_overlap_between_lu``: largest overlap found at the start of a collision call, i.e. what the
  fluid and the drift made of the bodies between two calls (the model's overlap bound,
  ``OVERLAP_BOUND_FACTOR * overlap_tol``, is the threshold);
- ``flow_rate_error_rel``: ``|Q_mean / Q_target - 1|``.

Flags (:func:`case_flags`): ``frozen`` (the orientations keep the packing,
:func:`lbmpipe.reproduction.steady.orientation_memory`), ``locked``
(:func:`lbmpipe.reproduction.steady.locking_diagnostics`), ``unhealthy`` (a health quantity beyond its
threshold) and ``not steady`` (the run ends before the required spin-up, or its halves disagree).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from .unpackable import read_json, read_summary

_NAN = float("nan")
CONFIG_PATH = Path(__file__).resolve().parents[2] / "config.yaml"
HEALTH_COLUMNS = ["case", "status", "mass_floor_rel", "mass_drift_rel", "mass_corrected_rel",
                  "mass_corrected_throughflow", "mass_corrected_signed", "density_deviation_median", "density_deviation_max", "rotation_projections",
                  "rotation_projection_share", "max_overlap_lu", "max_overlap_between_lu", "flow_rate_error_rel", "frozen", "locked",
                  "steady", "issues", "flags"]
#: health quantity -> (threshold key in diagnostics.health, label of an issue)
_LIMITS = {
    "mass_floor_rel": ("max_mass_floor_rel", "mass added by the density floor"),
    "mass_drift_rel": ("max_mass_drift_rel", "mass drift"),
    "mass_corrected_throughflow": ("max_mass_corrected_throughflow", "mass renormalised / mass through the pipe"),
    "density_deviation_max": ("max_density_deviation", "largest density deviation"),
    "rotation_projection_share": ("max_rotation_projection_share", "rotating projections per step"),
    "max_overlap_lu": ("max_overlap_lu", "largest overlap (lattice spacings)"),
    "max_overlap_between_lu": ("max_overlap_between_lu", "largest overlap between collision calls (lattice spacings)"),
    "flow_rate_error_rel": ("max_flow_rate_error_rel", "flow-rate error"),
}
NOT_COMPUTED = "not computed by this version of the statistics; rerun the case's statistics"


def thresholds(config: dict | None = None) -> dict:
    """The ``diagnostics`` block of a pipeline config (default: the repository's ``config.yaml``)."""
    if config is None or "diagnostics" not in config:
        config = yaml.safe_load(CONFIG_PATH.read_text())
    return config["diagnostics"]


def _num(v) -> float:
    try:
        return _NAN if v is None else float(v)
    except (TypeError, ValueError):
        return _NAN


def read_flow_rate(case_dir: Path) -> pd.DataFrame | None:
    """``flow_rate.csv`` of a case (``t_s, q_m3_s, force_density_N_m3, max_density_deviation``) or None."""
    try:
        return pd.read_csv(Path(case_dir) / "flow_rate.csv")
    except (FileNotFoundError, pd.errors.EmptyDataError, pd.errors.ParserError):
        return None


def density_deviation(flow_rate: pd.DataFrame | None) -> tuple[float, float]:
    """Median and maximum over the samples of the largest density deviation ``|rho - 1|``."""
    if flow_rate is None or "max_density_deviation" not in flow_rate:
        return _NAN, _NAN
    d = pd.to_numeric(flow_rate["max_density_deviation"], errors="coerce").to_numpy(float)
    d = d[np.isfinite(d)]
    return (float(np.median(d)), float(d.max())) if d.size else (_NAN, _NAN)


def rotation_projection_share(summary: dict) -> tuple[float, float]:
    """Rotating projections of the collision step (total) and their number per time step."""
    coll = summary.get("collisions") or {}
    n = _num(coll.get("rotation_projections"))
    steps = _num(summary.get("steps"))
    return n, (n / steps if np.isfinite(n) and steps > 0 else _NAN)


def mass_corrected_signed(summary: dict) -> float:
    """Net mass the particles' mass correction added over the run, relative to the initial mass,
    with its sign (negative: it took mass out): ``summary.json`` ``mass_correction.mass_added_rel``
    (or ``mass_added`` over ``mass0``); NaN if the summary does not record it."""
    rec = summary.get("mass_correction") or {}
    if "mass_added_rel" in rec:
        return _num(rec["mass_added_rel"])
    if "mass_added" in rec and _num(rec.get("mass0")) > 0:
        return _num(rec["mass_added"]) / _num(rec["mass0"])
    return _NAN


def mass_corrected_rel(summary: dict) -> float:
    """Mass renormalised in total by the particles' mass correction, relative to the initial mass: the
    size of :func:`mass_corrected_signed` (what the health limit judges)."""
    return abs(mass_corrected_signed(summary))


def mass_corrected_throughflow(summary: dict) -> float:
    """Mass renormalised by the particles' mass correction over the run, relative to the mass that
    flowed through the pipe meanwhile (``lattice.fluid_nodes`` times ``mass_corrected_rel`` over
    ``lattice.flow_rate_lu`` times ``steps``); NaN without a flow-rate-driven lattice record."""
    lat = summary.get("lattice") or {}
    nodes, q, steps = _num(lat.get("fluid_nodes")), _num(lat.get("flow_rate_lu")), _num(summary.get("steps"))
    m = mass_corrected_rel(summary)
    return m * nodes / (q * steps) if q > 0 and steps > 0 and np.isfinite(m) and np.isfinite(nodes) else _NAN


def flow_rate_error_rel(summary: dict) -> float:
    """``|Q_mean / Q_target - 1|`` of a flow-rate-driven run (NaN without a target)."""
    target = _num(((summary.get("scene") or {}).get("driving") or {}).get("flow_rate_m3_s"))
    q = _num(summary.get("flow_rate_m3_s"))
    return abs(q / target - 1.0) if target > 0 and np.isfinite(q) else _NAN


def refresh_health(stats: dict, run_dir: Path, limits: dict) -> dict:
    """``stats`` (a run's ``stats.json``) with its ``health`` judged again from the run's
    ``summary.json`` and ``flow_rate.csv`` against ``limits`` (today's thresholds, not those of the
    day the statistics were computed) and its ``unhealthy`` flag set accordingly (the other flags
    as the statistics found them); unchanged without a summary."""
    summary = read_json(Path(run_dir) / "summary.json")
    if not stats or summary is None:
        return stats
    health = run_health(summary, read_flow_rate(run_dir), limits)
    flags = [f for f in (stats.get("flags") or []) if f != "unhealthy"]
    if health["issues"]:  # where case_flags puts it: before "not steady"
        flags.insert(flags.index("not steady") if "not steady" in flags else len(flags), "unhealthy")
    return dict(stats, health=health, flags=flags)


def run_health(summary: dict | None, flow_rate: pd.DataFrame | None, limits: dict) -> dict:
    """Run-health quantities of a case (module docstring), the ``issues`` beyond ``limits``
    (``diagnostics.health`` of the config) and ``healthy``."""
    s = summary or {}
    med, mx = density_deviation(flow_rate)
    n_rot, share = rotation_projection_share(s)
    coll = s.get("collisions") or {}
    out = {"status": s.get("status", "not run") if summary else "not run",
           "mass_floor_rel": abs(_num((s.get("density_floor") or {}).get("mass_added_rel"))),
           "mass_drift_rel": abs(_num(s.get("density_drift_rel", s.get("mass_drift_rel")))),
           "mass_corrected_rel": mass_corrected_rel(s),
           "mass_corrected_throughflow": mass_corrected_throughflow(s),
           "mass_corrected_note": "" if "mass_correction" in s else "not recorded in summary.json",
           "density_deviation_median": med, "density_deviation_max": mx,
           "rotation_projections": n_rot, "rotation_projection_share": share,
           "max_overlap_lu": _num(coll.get("max_overlap_after_lu")),
           "max_overlap_between_lu": _num(coll.get("max_overlap_before_lu")),
           "flow_rate_error_rel": flow_rate_error_rel(s)}
    issues = [] if out["status"] in ("completed", "unpackable", "not run") else [f"status {out['status']}"]
    for key, (lim, label) in _LIMITS.items():
        v, t = out[key], _num(limits.get(lim))
        if np.isfinite(v) and np.isfinite(t) and v > t:
            issues.append(f"{label} {v:.3g} > {t:.3g}")
    out["issues"] = issues
    out["healthy"] = not issues
    return out


def case_flags(stats: dict) -> list[str]:
    """Flags of a case from its ``stats.json``: frozen, locked, unhealthy, not steady (module docstring)."""
    flags = []
    if (stats.get("frozen") or {}).get("frozen"):
        flags.append("frozen")
    if (stats.get("locked") or {}).get("locked"):
        flags.append("locked")
    h = stats.get("health")
    if isinstance(h, dict) and h.get("issues"):
        flags.append("unhealthy")
    spin = stats.get("spinup")
    if isinstance(spin, dict) and stats.get("samples") and not spin.get("steady", True):
        flags.append("not steady")
    return flags


def combined_status(stats: dict, summary: dict | None) -> str:
    """The status of a case combined over packings: its ``summary.json``'s (``completed`` only when
    every packing completed; an unstable packing makes the case ``unstable``), with the packings
    that did not complete named (``unstable (seed 3: unstable)``). The statistics' own status says
    ``completed`` as soon as one packing did, which hides the packing that failed."""
    status = str((summary or {}).get("status") or stats.get("status", "not run"))
    bad = [f"seed {k}: {v}" for k, v in (stats.get("seed_status") or {}).items() if v != "completed"]
    return f"{status} ({'; '.join(bad)})" if status != "completed" and bad else status


def _fmt_bool(d, key: str):
    return "" if not isinstance(d, dict) or key not in d else bool(d[key])


def health_row(case: str, case_dir: Path, limits: dict, case_cfg: dict | None = None) -> dict:
    """One row of ``tables/run_health.csv``: the run health of the case, its diagnostics from
    ``stats.json`` when written (empty when not computed) and its flags (``case_cfg``: its config
    entry, which may declare it unpackable)."""
    case_dir = Path(case_dir)
    stats = read_json(case_dir / "stats.json") or {}
    if isinstance(stats.get("seeds"), list) and isinstance(stats.get("health"), dict):
        # a case combined over packings (lbmpipe.reproduction.seeds): its seeds' worst health
        h = {k: _num(stats["health"].get(k)) for k in HEALTH_COLUMNS[2:HEALTH_COLUMNS.index("frozen")]}
        h.update(status=combined_status(stats, read_json(case_dir / "summary.json")),
                 issues=list(stats["health"].get("issues") or []))
    else:
        summary = read_summary(case_dir, case_cfg)
        h = run_health(summary, read_flow_rate(case_dir), limits)
        h["mass_corrected_signed"] = mass_corrected_signed(summary or {})  # the table's alone, not stats.json's
    flags = [f for f in case_flags(stats) if f != "unhealthy"] + (["unhealthy"] if h["issues"] else [])
    spin = stats.get("spinup") if isinstance(stats.get("spinup"), dict) else {}
    return {"case": case, **{k: h[k] for k in HEALTH_COLUMNS[1:HEALTH_COLUMNS.index("frozen")]},
            "frozen": _fmt_bool(stats.get("frozen"), "frozen"), "locked": _fmt_bool(stats.get("locked"), "locked"),
            "steady": _fmt_bool(spin, "steady"), "issues": "; ".join(h["issues"]), "flags": ";".join(flags)}


def run_health_table(fid_dir: Path, cases: dict, config: dict | None = None) -> Path:
    """Write ``tables/run_health.csv`` (one row per case of ``cases``, particle-free ones included)."""
    fid_dir = Path(fid_dir)
    limits = thresholds(config)["health"]
    rows = [health_row(case, fid_dir / "cases" / case, limits) for case in cases]
    out = fid_dir / "tables" / "run_health.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows, columns=HEALTH_COLUMNS).to_csv(out, index=False)
    return out


def health_is_computed(stats: dict | None) -> bool:
    """Whether a ``stats.json`` holds the diagnostics of this version (older ones lack them)."""
    return isinstance(stats, dict) and isinstance(stats.get("health"), dict) and "frozen" in stats


def finite(v) -> bool:
    """A measured number (not a flag) that is finite."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
