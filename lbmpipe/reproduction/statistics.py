"""Per-case statistics of the particle runs and the aggregated tables behind the paper's figures.

Angular velocity (Figs. 4-7). The paper does not define its statistic; we use (paper/reading.md) the
mean of ``|Omega_a|``, ``a`` in {x, y, z}, LAB-frame components, over all free particles and all
sampled times ``t > spinup_s``, the spin-up found by MSER-5 on the driving force, ``|Omega_a|``
and the orientation order, never shorter than two viscous times ``R^2/nu``
(:func:`lbmpipe.reproduction.steady.spinup_end`). Its 95 % confidence interval comes from batch
means of the particle-averaged time series ``m_a(t) = <|Omega_a|>_particles(t)`` with at least 20
batches of at least 5 integrated correlation times, or overlapping batch means flagged with the
duration needed (:func:`lbmpipe.reproduction.steady.mean_interval`): the samples of one run are
correlated in time, so the naive iid interval would be too narrow, and the particles of one
sample are correlated with each other through the crowded flow, so they are not counted as
independent either. Orientation statistics get intervals designed on the orientation correlation
time (:func:`lbmpipe.reproduction.steady.orientation_memory`), not the spin's.

Orientation (Figs. 8, 9), from the unit quaternion ``q`` (body -> lab, Eq. (14)-(15), Eq. (20)
for the matrix ``A``), the body axis ``k`` in the lab frame being the column ``A[:, k]``:

- ``cyl_axis_angle``: angle between the cylinder axis (body z) and the pipe axis (lab z),
  ``arccos |A[2, 2]|`` in 0-90 deg (an axis has no sign).
- ``cube_axis_angle``: 3-D angle between the pipe axis and the nearest of the three cube axes,
  ``arccos max_k |A[2, k]|`` in 0-54.74 deg (``arccos(1/sqrt 3)``, the body diagonal along z).
- ``cube_projected_angle``: what the experiment's camera sees. The camera looks along lab y at
  the vertical pipe, so the cube is projected onto the lab x-z plane. Of the three body axes we
  take the one whose projection ``(A[0, k], A[2, k])`` is longest (the edge direction lying most
  nearly in the image plane, i.e. the most clearly visible edge), and its in-plane angle to the
  pipe axis ``alpha = atan2(A[0, k], A[2, k])``, an undirected line so taken modulo 180 deg. The
  projected square is unchanged by quarter turns and by mirror images about the pipe axis, so
  the angle is folded: ``beta = alpha mod 90``, reported ``min(beta, 90 - beta)`` in 0-45 deg.
  A cube turned by ``theta`` about y gives ``theta`` folded (20 -> 20, 70 -> 20).

Histograms pool particles and samples after spin-up (fractions sum to 1 over a kind); the 95 %
CI of each bin is the :func:`lbmpipe.reproduction.steady.mean_interval` half-width of the
per-sample bin fraction. Diagnostics (frozen, locked, run health) and the flags they raise:
:mod:`lbmpipe.reproduction.health`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats as _st

from . import health as H
from . import series as SR
from . import unpackable as U
from .health import _num
from .angles import (CUBE_MAX_AXIS_ANGLE_DEG, ORIENTATION_KINDS, cube_axis_angle, cube_projected_angle,  # noqa: F401
                     cylinder_axis_angle, isotropic_bin_fractions, isotropic_cdf, orientation_angles)
from .steady import mean_interval, spinup_end, viscous_time_s

AXES = ("x", "y", "z")
ORIENTATION_COLUMNS = ["kind", "bin_lo_deg", "bin_hi_deg", "fraction", "ci95"]
META_COLUMNS = ["case", "shape", "size_label", "diameter_mm", "length_mm", "edge_mm", "concentration",
                "reynolds", "collisions"]
# n_seeds: packings the case's values combine (1 in a level without seeds); seed_sd_*: the
# seed-to-seed standard deviation of the packings' means, relative to the mean (NaN with one packing)
ANGULAR_VELOCITY_COLUMNS = META_COLUMNS + ["status", "concentration_achieved", "n_particles", "samples",
                                           "omega_x", "omega_y", "omega_z", "ci_x", "ci_y", "ci_z", "n_seeds",
                                           "seed_sd_x", "seed_sd_y", "seed_sd_z", "flags"]
ORIENTATION_TABLE_COLUMNS = ["case", "shape", "size_label", "concentration", "reynolds", "collisions", "status",
                             "kind", "bin_lo_deg", "bin_hi_deg", "fraction", "ci95"]
ORIENTATION_SUMMARY_COLUMNS = ["case", "shape", "size_label", "concentration", "reynolds", "collisions", "status",
                               "kind", "mean_deg", "ci95_deg", "median_deg", "samples", "flags"]
PACKING_COLUMNS = ["case", "shape", "size_label", "concentration_target", "concentration_achieved", "status",
                   "message"]
RUNTIME_COLUMNS = ["case", "status", "steps", "simulated_s", "wall_s", "s_per_step", "mlups", "particles",
                   "max_rss_mb"]
_NAN = float("nan")


# ----------------------------------------------------------------------------------------------
# time-series statistics

def batch_means(series: np.ndarray, n_batches: int = 10, confidence: float = 0.95) -> tuple[float, float, int]:
    """Mean of a time-correlated series and the half-width of its confidence interval.

    The series is cut into ``b`` contiguous batches of equal length ``m``; when ``m`` exceeds the
    correlation time the batch means are nearly independent, and the half-width is
    ``t_{(1+c)/2, b-1} * s_b / sqrt(b)`` (Student t, ``b - 1`` degrees of freedom, ``s_b`` the
    sample standard deviation of the batch means). ``b = min(n_batches, n // 2)`` so each batch
    holds at least two samples; the ``n - b m`` oldest samples left over are dropped from the
    batches (not from the mean, which is over the whole series).

    Returns ``(mean, half_width, b)``; ``half_width`` is NaN and ``b`` is 0 when fewer than 4
    samples (or fewer than 2 batches) are available, the mean NaN for an empty series.
    """
    x = np.asarray(series, dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return _NAN, _NAN, 0
    mean = float(x.mean())
    b = min(int(n_batches), n // 2)
    if n < 4 or b < 2:
        return mean, _NAN, 0
    m = n // b
    means = x[n - b * m:].reshape(b, m).mean(axis=1)
    hw = float(_st.t.ppf(0.5 + confidence / 2.0, b - 1) * means.std(ddof=1) / math.sqrt(b))
    return mean, hw, b


# ----------------------------------------------------------------------------------------------
# per case

def case_metadata(case: str, case_cfg: dict) -> dict:
    """Shape, sizes, concentration, Reynolds number and collisions of a case, from its config
    entry (never from its name). ``size_label``: ``"8x16 mm"`` (cylinder, diameter x length),
    ``"8 mm"`` (cube edge); shape ``"flow"`` for a particle-free case."""
    p = case_cfg.get("particles") or {}
    shape = p.get("shape", "flow")
    d = float(p["diameter_mm"]) if p.get("diameter_mm") is not None else _NAN
    ln = float(p["length_mm"]) if p.get("length_mm") is not None else _NAN
    e = float(p["edge_mm"]) if p.get("edge_mm") is not None else _NAN
    if shape == "cylinder":
        label = f"{d:g}x{ln:g} mm"
    elif shape == "cube":
        label = f"{e:g} mm"
    else:
        label = ""
    return {"case": case, "shape": shape, "size_label": label, "diameter_mm": d, "length_mm": ln, "edge_mm": e,
            "concentration": float(p["concentration"]) if p.get("concentration") is not None else _NAN,
            "reynolds": float(case_cfg["reynolds"]) if case_cfg.get("reynolds") is not None else _NAN,
            "collisions": bool(case_cfg.get("collisions", True))}


def _nan_axes() -> dict:
    return {a: _NAN for a in AXES}


#: the keys of a :func:`lbmpipe.reproduction.steady.mean_interval` dict kept in ``stats.json``
_INTERVAL_KEYS = ("method", "batch_s", "n_batches", "dof", "tau_int_s", "tau_status", "sufficient", "required_s",
                  "duration_s", "message")
PROFILE_OBSERVABLE = ("core_velocity_ratio of flow_rate.csv: the mean axial velocity within half the radius over "
                      "the mean over all the fluid, per sample (1.75 for Hagen-Poiseuille)")


def _interval(series, dt: float, tau_s: float | None = None) -> dict:
    """:func:`lbmpipe.reproduction.steady.mean_interval` of a series (batches of >= 5 tau_int, >= 20
    of them, or overlapping batch means flagged with the duration needed), JSON-sized."""
    r = mean_interval(series, dt, tau_s=tau_s)
    return {"mean": r["mean"], "ci95": r["ci95"], **{k: r[k] for k in _INTERVAL_KEYS}}


def pipe_viscous_time_s(summary: dict) -> float:
    """``R^2/nu`` (s) of a case from its ``summary.json``: the pipe diameter of its scene, ``nu`` from
    the scene's fluid (or the lattice's ``nu_lu dx^2/dt``). NaN when the summary lacks them."""
    scene = summary.get("scene") or {}
    d = (scene.get("domain") or {}).get("diameter_mm")
    nu = (scene.get("fluid") or {}).get("viscosity_m2_s")
    lat = summary.get("lattice") or {}
    units = lat.get("units") or {}
    if nu is None and lat.get("nu_lu") is not None and units.get("dx_m") and units.get("dt_s"):
        nu = float(lat["nu_lu"]) * float(units["dx_m"]) ** 2 / float(units["dt_s"])
    return viscous_time_s(float(d), float(nu)) if d and nu else _NAN


def detect_spinup(t: np.ndarray, observables: dict, summary: dict, min_viscous_times: float) -> dict:
    """Spin-up of a run: :func:`lbmpipe.reproduction.steady.spinup_end` (MSER-5 on every observable,
    the latest, halves of the kept window compared) never before ``min_viscous_times`` ``R^2/nu``
    nor before the run's own ``spinup_s``. A run that ends before that minimum keeps its own
    spin-up for the statistics, with ``steady`` False and ``required_s`` the spin-up it needed."""
    tv = pipe_viscous_time_s(summary)
    own = float(summary.get("spinup_s") or 0.0)
    floor = max(own, min_viscous_times * tv) if np.isfinite(tv) else own
    base = {"viscous_time_s": tv, "min_viscous_times": float(min_viscous_times), "required_s": floor,
            "profile_observable": PROFILE_OBSERVABLE}
    if np.count_nonzero(t > floor + 1e-9 * max(1.0, floor)) < 4:
        return {**base, "method": "run shorter than the required spin-up", "spinup_s": own, "steady": False,
                "limited_by": "run length", "observables": {},
                "message": (f"the run ends at {t[-1]:.3g} s, before the required spin-up {floor:.3g} s "
                            f"({min_viscous_times:g} R^2/nu = {min_viscous_times * tv:.3g} s): statistics after the "
                            f"run's own spin-up {own:.3g} s, not of a steady state")}
    return {**base, **spinup_end(t, observables, floor)}


def resolution(meta: dict, summary: dict) -> dict:
    """Smallest particle dimension in lattice spacings (a measured fact of the case's lattice)."""
    dx = ((summary.get("scene") or {}).get("numerics") or {}).get("dx_mm")
    dims = [meta[k] for k in ("diameter_mm", "length_mm", "edge_mm") if np.isfinite(meta[k])]
    smallest = min(dims) if dims else _NAN
    return {"dx_mm": _num(dx), "smallest_dimension_mm": smallest,
            "lattice_spacings": smallest / float(dx) if dx and dims else _NAN}


def _base_stats(case: str, meta: dict, status: str, summary: dict, spinup_s: float) -> dict:
    parts = summary.get("particles") or {}
    return {"case": case, "status": status, "shape": meta["shape"], "size_label": meta["size_label"],
            "reynolds": meta["reynolds"], "concentration": meta["concentration"], "collisions": meta["collisions"],
            "n_particles": int(parts.get("count", 0) or 0), "spinup_s": spinup_s, "samples": 0,
            "mean_abs_omega_rad_s": _nan_axes(), "ci95_rad_s": _nan_axes(), "n_batches": 0,
            "tau_int_s": _nan_axes(), "orientation": {}}


def case_statistics(case: str, case_dir: Path, case_cfg: dict, spinup_s: float | None = None,
                    config: dict | None = None) -> dict:
    """The ``stats.json`` dict of the contract for one case directory.

    A completed particle run's statistics come from its compact series (``series.csv.gz``) and
    ``trajectory.json`` (:mod:`lbmpipe.reproduction.series`); where the trajectory
    (``particles.parquet``) is present, both are first (re)written from it, so a fresh clone
    without trajectories rebuilds the same ``stats.json``. Neither present is an error.

    Spin-up (``spinup``, ``spinup_s``): :func:`detect_spinup` on the driving force density and
    the profile's core velocity ratio (``flow_rate.csv``, aligned sample by sample: a missing or
    misaligned value is an error), the particle-mean ``|Omega_a|`` per axis and the orientation
    order parameter (:func:`lbmpipe.reproduction.steady.orientation_order`), never shorter than
    ``diagnostics.min_spinup_viscous_times`` ``R^2/nu``; a given ``spinup_s`` replaces the test.
    ``mean_abs_omega_rad_s[a]``: mean of ``|Omega_a|`` (lab frame) over free particles and samples
    after spin-up; ``ci95_rad_s[a]``, ``tau_int_s[a]``, ``omega_intervals[a]``: its
    :func:`lbmpipe.reproduction.steady.mean_interval` (own ``tau_int``). ``orientation[kind]``:
    ``{mean_deg, ci95_deg, median_deg, interval}``, and ``orientation_order``, with intervals
    designed on the orientation correlation time (``orientation_memory``). ``second_half``: the
    same means and intervals over the later half of the window (the sensitivity of a verdict to
    the averaging window). Diagnostics: ``frozen``, ``locked``, ``health``
    (:func:`lbmpipe.reproduction.health.run_health`), ``resolution`` and ``flags``. NaN
    statistics when the status is not ``completed`` or no sample lies after spin-up.
    """
    case_dir = Path(case_dir)
    diag = H.thresholds(config)
    meta = case_metadata(case, case_cfg)
    summary = U.read_summary(case_dir, case_cfg)  # a case declared unpackable: its record
    status = summary.get("status", "unknown") if summary else "not run"
    s = summary or {}
    out = _base_stats(case, meta, status, s, float(spinup_s) if spinup_s is not None
                      else float(s.get("spinup_s", 0.0)) if summary else _NAN)
    out["health"] = H.run_health(summary, H.read_flow_rate(case_dir), diag["health"])
    out["resolution"] = resolution(meta, s)
    out["flags"] = H.case_flags(out)
    if status != "completed" or meta["shape"] not in ORIENTATION_KINDS:
        return out
    traj = None
    if (case_dir / SR.TRAJECTORY_FILE).exists():
        traj = SR.free_rows(pd.read_parquet(case_dir / SR.TRAJECTORY_FILE), case_dir / "particles_static.csv")
        if traj.empty:
            return out
        SR.write_series(SR.build_series(traj, meta["shape"]), case_dir)
    series = SR.read_series(case_dir, meta["shape"])
    _particle_statistics(out, series, traj, case_dir, meta, s, diag, spinup_s)
    out["flags"] = H.case_flags(out)
    return out


def _after(t: np.ndarray, start: float) -> np.ndarray:
    """Samples after ``start`` (a sample exactly at the end of spin-up belongs to spin-up)."""
    return t > start + 1e-9 * max(1.0, abs(start))


def _window_statistics(series: pd.DataFrame, keep: np.ndarray, dt: float, shape: str, window: dict) -> dict:
    """Means and intervals of ``|Omega_a|`` and of the orientation angles over the samples ``keep``
    (``window``: the orientation memory and median angles of ``trajectory.json`` for them)."""
    sub = series[keep]
    n = sub["n_bodies"].to_numpy(float)
    out = {"samples": int(keep.sum()), "mean_abs_omega_rad_s": _nan_axes(), "ci95_rad_s": _nan_axes(),
           "tau_int_s": _nan_axes(), "omega_intervals": {}, "orientation": {}}
    for a in AXES:
        m = sub[f"mean_abs_omega_{a}"].to_numpy(float)
        r = _interval(m, dt)
        out["mean_abs_omega_rad_s"][a] = float(np.sum(n * m) / np.sum(n))  # over (body, sample) pairs
        out["ci95_rad_s"][a] = r["ci95"]
        out["tau_int_s"][a] = r["tau_int_s"]
        out["omega_intervals"][a] = r
    tau_o = window["orientation_memory"]["tau_orient_s"]
    tau_o = tau_o if tau_o is not None and np.isfinite(tau_o) else None
    out["orientation_order"] = _interval(sub["orientation_order"].to_numpy(float), dt, tau_s=tau_o)
    for kind, _, _ in ORIENTATION_KINDS[shape]:
        r = _interval(sub[f"{kind}_mean_deg"].to_numpy(float), dt, tau_s=tau_o)
        out["orientation"][kind] = {"mean_deg": r["mean"], "ci95_deg": r["ci95"],
                                    "median_deg": _num(window["median_deg"].get(kind)), "interval": r}
    return out


def _particle_statistics(out: dict, series: pd.DataFrame, traj: pd.DataFrame | None, case_dir: Path, meta: dict,
                         summary: dict, diag: dict, spinup_s: float | None) -> None:
    """Fill ``out`` with the spin-up, the intervals and the diagnostics of a completed particle
    case from its series (and, where ``traj`` is given, write ``trajectory.json`` from it first)."""
    shape = meta["shape"]
    t_all = series["t_s"].to_numpy(float)
    dt = float(np.median(np.diff(t_all))) if t_all.size > 1 else 1.0
    c_start = series["orientation_start_corr"].to_numpy(float)
    tail = max(1, c_start.size // 10)
    remaining = float(c_start[-tail:].mean())
    thr = float(diag["frozen_remaining"])
    out["frozen"] = {"remaining": remaining, "threshold": thr, "frozen": bool(remaining > thr),
                     "duration_s": t_all.size * dt}
    # the initial state (t = 0) has no fluid sample: the flow is first sampled one interval later
    moving = t_all > 0.0
    t = t_all[moving]
    sub = series[moving]
    obs = {"force_density": SR.flow_series(case_dir, t, "force_density_N_m3")}
    obs.update({f"mean_abs_omega_{a}": sub[f"mean_abs_omega_{a}"].to_numpy(float) for a in AXES})
    obs["orientation_order"] = sub["orientation_order"].to_numpy(float)
    obs["core_velocity_ratio"] = SR.flow_series(case_dir, t, "core_velocity_ratio")
    if spinup_s is None:
        out["spinup"] = detect_spinup(t, obs, summary, float(diag["min_spinup_viscous_times"]))
        out["spinup_s"] = float(out["spinup"]["spinup_s"])
    else:
        out["spinup"] = {"method": "given", "spinup_s": float(spinup_s)}
    start = out["spinup_s"]
    half = SR.second_half_start(t_all, start)
    if traj is not None:
        windows = [start] + ([half] if np.isfinite(half) else [])
        doc = SR.trajectory_diagnostics(traj, shape, meta, summary, diag, windows)
        (case_dir / SR.TRAJECTORY).write_text(json.dumps(_jsonable(doc), indent=1, allow_nan=False) + "\n")
    keep = _after(t_all, start)
    out["samples"] = int(keep.sum())
    if not keep.any():
        return
    win = SR.read_window(case_dir, start)
    out["locked"] = win["locked"]
    out["n_particles"] = int(series.loc[keep, "n_bodies"].max())
    out["orientation_memory"] = win["orientation_memory"]
    full = _window_statistics(series, keep, dt, shape, win)
    for k in ("mean_abs_omega_rad_s", "ci95_rad_s", "tau_int_s", "omega_intervals", "orientation_order",
              "orientation"):
        out[k] = full[k]
    out["n_batches"] = int(min(r["n_batches"] for r in full["omega_intervals"].values()))
    if np.isfinite(half):
        # the record the half-window verdicts (``half_window``) put in place of the full window's
        hw = SR.read_window(case_dir, half)
        h = _window_statistics(series, _after(t_all, half), dt, shape, hw)
        out["second_half"] = {"spinup_s": half, **h, "n_batches": int(min(r["n_batches"] for r in
                                                                          h["omega_intervals"].values())),
                              "orientation_memory": hw["orientation_memory"]}


def orientation_histograms(case_dir: Path, shape: str, spinup_s: float, status: str = "completed",
                           tau_s: float | None = None) -> pd.DataFrame:
    """``orientation.csv`` rows (``kind, bin_lo_deg, bin_hi_deg, fraction, ci95``) of one case,
    from its series (``series.csv.gz``).

    ``fraction``: share of (particle, sample) pairs after spin-up in the bin; ``ci95``:
    :func:`lbmpipe.reproduction.steady.mean_interval` half-width of the per-sample fraction of the
    particles in the bin, its batches designed on ``tau_s`` (the orientation correlation time of
    ``stats.json``'s ``orientation_memory``) when that exceeds the bin series' own ``tau_int``.
    The bins are laid out (with NaN values) even for a case with no samples, so tables keep their shape.
    """
    case_dir = Path(case_dir)
    kinds = ORIENTATION_KINDS.get(shape, ())
    series = None
    if status == "completed" and kinds:
        if not (case_dir / SR.SERIES).exists() and (case_dir / SR.TRAJECTORY_FILE).exists():
            SR.write_series(SR.build_series(SR.free_rows(pd.read_parquet(case_dir / SR.TRAJECTORY_FILE),
                                                         case_dir / "particles_static.csv"), shape), case_dir)
        series = SR.read_series(case_dir, shape)
    keep = _after(series["t_s"].to_numpy(float), spinup_s) if series is not None else None
    rows = []
    for kind, hi, nb in kinds:
        edges = np.linspace(0.0, hi, nb + 1)
        if keep is not None and keep.any():
            sub = series[keep]
            t = sub["t_s"].to_numpy(float)
            step = float(np.median(np.diff(t))) if t.size > 1 else 1.0
            counts = sub[[f"{kind}_n{j}" for j in range(nb)]].to_numpy(float)
            n = sub["n_bodies"].to_numpy(float)
            frac = counts.sum(axis=0) / n.sum()
            per_t = counts / n[:, None]
            ci = np.array([mean_interval(per_t[:, j], step, tau_s=tau_s)["ci95"] for j in range(nb)])
        else:
            frac = np.full(nb, _NAN)
            ci = np.full(nb, _NAN)
        rows.append(pd.DataFrame({"kind": kind, "bin_lo_deg": edges[:-1], "bin_hi_deg": edges[1:],
                                  "fraction": frac, "ci95": ci}))
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=ORIENTATION_COLUMNS)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None  # strict JSON has no NaN; readers map null back to NaN
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    return obj


def write_case_outputs(case: str, case_dir: Path, case_cfg: dict, config: dict | None = None) -> None:
    """Write ``stats.json`` and ``orientation.csv`` beside the case files (NaN written as JSON
    ``null`` in ``stats.json``), and, from the trajectory where it is present, the compact series,
    ``trajectory.json`` and ``last_frame.csv``; ``config`` the pipeline config (its
    ``diagnostics`` thresholds). Without the trajectory, a completed particle run needs its
    committed series and last frame: their absence is an error (nothing is written)."""
    case_dir = Path(case_dir)
    if not (case_dir / SR.TRAJECTORY_FILE).exists():
        summary = H.read_json(case_dir / "summary.json") or {}
        if summary.get("status") == "completed" and not (case_dir / LAST_FRAME).exists():
            raise SR.SeriesError(f"{case_dir / LAST_FRAME} and {case_dir / SR.TRAJECTORY_FILE} are both missing: "
                                 f"rerun {case}")
    s = case_statistics(case, case_dir, case_cfg, config=config)
    spin = s["spinup_s"] if s["spinup_s"] is not None and np.isfinite(s["spinup_s"]) else 0.0
    tau_o = (s.get("orientation_memory") or {}).get("tau_orient_s")
    hist = orientation_histograms(case_dir, s["shape"], spin, status=s["status"], tau_s=tau_o)
    (case_dir / "stats.json").write_text(json.dumps(_jsonable(s), indent=2, allow_nan=False) + "\n")
    hist.to_csv(case_dir / "orientation.csv", index=False)
    if (case_dir / SR.TRAJECTORY_FILE).exists() or not (case_dir / LAST_FRAME).exists():
        write_last_frame(case_dir)


#: the last sample of a run's particles (positions, orientations): what the snapshot figure draws,
#: small enough to commit where the trajectory (particles.parquet) is not
LAST_FRAME = "last_frame.csv"


def write_last_frame(case_dir: Path) -> Path:
    """Write ``last_frame.csv``: the rows of ``particles.parquet``'s last sample (empty if none)."""
    case_dir = Path(case_dir)
    pq = case_dir / SR.TRAJECTORY_FILE
    df = pd.read_parquet(pq) if pq.exists() else pd.DataFrame()
    if not df.empty:
        df = df[df["t_s"] == df["t_s"].max()]
    df.to_csv(case_dir / LAST_FRAME, index=False)
    return case_dir / LAST_FRAME


# ----------------------------------------------------------------------------------------------
# aggregated tables

def _case_stats(case: str, case_dir: Path, case_cfg: dict) -> dict:
    """stats.json of a case, computed on the fly if it was not written."""
    s = H.read_json(case_dir / "stats.json")
    if s is None:
        s = case_statistics(case, case_dir, case_cfg)
    return s


def _case_orientation(case_dir: Path, shape: str, stats: dict) -> pd.DataFrame:
    path = case_dir / "orientation.csv"
    if path.exists():
        df = pd.read_csv(path)
        if not df.empty:
            return df
    spin = _num(stats.get("spinup_s"))
    tau_o = _num((stats.get("orientation_memory") or {}).get("tau_orient_s"))
    # without orientation.csv and without the series to make it (a combined record, a view of
    # another level's seeds), the histogram rows are laid out with NaN: the claims that need
    # them say so ("orientation histogram ... has NaN")
    have = (case_dir / SR.SERIES).exists() or (case_dir / SR.TRAJECTORY_FILE).exists()
    return orientation_histograms(case_dir, shape, spin if np.isfinite(spin) else 0.0,
                                  status=stats.get("status", "not run") if have else "no series",
                                  tau_s=tau_o if np.isfinite(tau_o) else None)


def aggregate(fid_dir: Path, cases: dict) -> None:
    """Write ``tables/angular_velocity.csv``, ``tables/orientation.csv``,
    ``tables/orientation_summary.csv`` and ``tables/packing.csv`` under ``fid_dir``
    (``results/<fid>``) from ``cases/<case>/{stats.json, orientation.csv, summary.json}``.

    ``cases`` is the config's case dict; every particle case gets a row, also when it is not
    packable (its status, NaN statistics, and the highest concentration the packer reached) or
    was not run at all (status ``not run``). Missing ``stats.json``/``orientation.csv`` are
    computed in memory from the case files.
    """
    fid_dir = Path(fid_dir)
    tables = fid_dir / "tables"
    tables.mkdir(parents=True, exist_ok=True)
    av, orient, osum, pack = [], [], [], []
    for case, cfg in cases.items():
        meta = case_metadata(case, cfg or {})
        if meta["shape"] not in ORIENTATION_KINDS:
            continue
        cdir = fid_dir / "cases" / case
        summary = U.read_summary(cdir, cfg) or {}
        s = _case_stats(case, cdir, cfg)
        status = summary.get("status", s.get("status", "not run")) if summary else "not run"
        parts = summary.get("particles") or {}
        packing = summary.get("packing") or {}
        achieved = parts.get("concentration_achieved")
        if achieved is None:
            achieved = packing.get("concentration_reached", packing.get("reached"))
        target = parts.get("concentration_target", packing.get("concentration_target", packing.get("target")))
        if target is None:
            target = meta["concentration"]
        om, ci = s.get("mean_abs_omega_rad_s") or {}, s.get("ci95_rad_s") or {}
        flags = ";".join(s.get("flags") or [])
        av.append({**meta, "status": status, "concentration_achieved": _num(achieved),
                   "n_particles": int(s.get("n_particles") or parts.get("count") or 0),
                   "samples": int(s.get("samples") or 0),
                   **{f"omega_{a}": _num(om.get(a)) for a in AXES}, **{f"ci_{a}": _num(ci.get(a)) for a in AXES},
                   "n_seeds": int(s.get("n_seeds", 1 if s.get("samples") else 0)),
                   **{f"seed_sd_{a}": _num((s.get("seed_spread_rel") or {}).get(a)) for a in AXES},
                   "flags": flags})
        short = {k: meta[k] for k in ("case", "shape", "size_label", "concentration", "reynolds", "collisions")}
        h = _case_orientation(cdir, meta["shape"], {**s, "status": status})
        for _, r in h.iterrows():
            orient.append({**short, "status": status, **{k: r[k] for k in ORIENTATION_COLUMNS}})
        so = s.get("orientation") or {}
        for kind, _, _ in ORIENTATION_KINDS[meta["shape"]]:
            o = so.get(kind) or {}
            osum.append({**short, "status": status, "kind": kind, "mean_deg": _num(o.get("mean_deg")),
                         "ci95_deg": _num(o.get("ci95_deg")), "median_deg": _num(o.get("median_deg")),
                         "samples": int(s.get("samples") or 0), "flags": flags})
        msg = summary.get("message") or packing.get("message") or ("" if summary else "not run: no summary.json")
        pack.append({"case": case, "shape": meta["shape"], "size_label": meta["size_label"],
                     "concentration_target": _num(target), "concentration_achieved": _num(achieved),
                     "status": status, "message": msg})
    pd.DataFrame(av, columns=ANGULAR_VELOCITY_COLUMNS).to_csv(tables / "angular_velocity.csv", index=False)
    pd.DataFrame(orient, columns=ORIENTATION_TABLE_COLUMNS).to_csv(tables / "orientation.csv", index=False)
    pd.DataFrame(osum, columns=ORIENTATION_SUMMARY_COLUMNS).to_csv(tables / "orientation_summary.csv", index=False)
    pd.DataFrame(pack, columns=PACKING_COLUMNS).to_csv(tables / "packing.csv", index=False)


def runtime_table(fid_dir: Path, cases: dict) -> Path:
    """Write ``tables/runtime.csv`` (all cases, particle-free ones included) and return its path.

    ``wall_s`` and ``max_rss_mb`` come from Snakemake's benchmark
    ``fid_dir/benchmarks/<case>.simulate.tsv`` (columns ``s``, ``max_rss`` in MB; the mean over
    repeats; NaN if the file is missing); ``wall_s`` thus includes set-up and output.
    ``s_per_step`` is the solver's time-stepping cost, ``summary.json`` ``wall_seconds / steps``
    (falling back to ``wall_s / steps``); ``steps``, ``simulated_s``, ``mlups``, ``particles``
    (count) from ``summary.json``.
    """
    fid_dir = Path(fid_dir)
    rows = []
    for case in cases:
        summary = H.read_json(fid_dir / "cases" / case / "summary.json") or {}
        bench = fid_dir / "benchmarks" / f"{case}.simulate.tsv"
        wall, rss = _NAN, _NAN
        if bench.exists():
            try:
                b = pd.read_csv(bench, sep="\t")
                wall = float(pd.to_numeric(b["s"], errors="coerce").mean()) if "s" in b else _NAN
                rss = float(pd.to_numeric(b["max_rss"], errors="coerce").mean()) if "max_rss" in b else _NAN
            except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError):
                pass
        steps = summary.get("steps")
        steps = int(steps) if steps is not None else None
        loop = _num(summary.get("wall_seconds"))
        per = (loop if np.isfinite(loop) and loop > 0 else wall) / steps if steps else _NAN
        rows.append({"case": case, "status": summary.get("status", "not run"),
                     "steps": steps if steps is not None else _NAN,
                     "simulated_s": _num(summary.get("simulated_seconds")), "wall_s": wall, "s_per_step": per,
                     "mlups": _num(summary.get("mlups")),
                     "particles": int((summary.get("particles") or {}).get("count") or 0), "max_rss_mb": rss})
    out = fid_dir / "tables" / "runtime.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows, columns=RUNTIME_COLUMNS).to_csv(out, index=False)
    return out
