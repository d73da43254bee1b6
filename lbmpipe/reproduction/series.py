"""The compact record of a particle run from which its statistics are rebuilt without the trajectory.

A run's trajectory (``particles.parquet``: every body at every sample) is too large to commit. The
statistics (``stats.json``, ``orientation.csv``) and every claim rest on per-sample averages over the
bodies and on a few diagnostics that need the bodies one by one; both are written beside the run
the first time its statistics are computed from the trajectory, and committed:

``series.csv.gz`` (:data:`SERIES`), one row per sample, free particles only:

- ``t_s``, ``n_bodies``;
- ``mean_abs_omega_{x,y,z}``: the body average of ``|Omega_a|`` (rad/s, lab frame);
- ``orientation_order``: :func:`lbmpipe.reproduction.steady.orientation_order`;
- ``orientation_start_corr``: the body-averaged orientation correlation with the first sample
  (``c_start`` of :func:`lbmpipe.reproduction.steady.orientation_memory`, the frozen test);
- per orientation kind (``statistics.ORIENTATION_KINDS``): ``<kind>_mean_deg``, the body average
  of the angle, and ``<kind>_n<j>``, the number of bodies in bin ``j`` (exact integers).

Values are written with 9 significant digits (float32 round trip): the statistics are always
computed from the series as read back from the file, so a fresh clone rebuilds them to the bit.

``trajectory.json`` (:data:`TRAJECTORY`): what needs the bodies one by one.

- ``locked``: :func:`lbmpipe.reproduction.steady.locking_diagnostics` over the whole run;
- ``windows``: for the averaging window after spin-up (``start_s``) and for its second half, the
  orientation correlation time (``orientation_memory``) and the median angle of each kind over
  the (body, sample) pairs.

The windows depend on the spin-up, which the statistics find from the series and the fluid series
(``flow_rate.csv``). A rebuild that finds another spin-up (a changed rule) cannot recompute them
without the trajectory: that is an error naming the run, never a silent reuse.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from .angles import ORIENTATION_KINDS, orientation_angles
from .steady import locking_diagnostics, orientation_memory, orientation_order

SERIES = "series.csv.gz"
TRAJECTORY = "trajectory.json"
TRAJECTORY_FILE = "particles.parquet"
AXES = ("x", "y", "z")
_TOL = 1e-9
_NAN = float("nan")


class SeriesError(RuntimeError):
    """A run's compact series or trajectory record is missing, inconsistent, or cannot be aligned."""


def window_key(start_s: float) -> str:
    """The key of an averaging window in ``trajectory.json``: its start time, 9 digits."""
    return f"{float(start_s):.9g}"


def free_rows(df: pd.DataFrame, static_csv: Path | None) -> pd.DataFrame:
    """The rows of the free particles of a trajectory, sorted by time and id (the fixed ones of
    ``particles_static.csv`` removed)."""
    if static_csv is not None and Path(static_csv).exists():
        st = pd.read_csv(static_csv)
        if "fixed" in st.columns and len(st):
            fixed = st["fixed"].astype(str).str.lower().isin(("true", "1", "1.0"))
            df = df[~df["id"].isin(st.loc[fixed, "id"])]
    return df.sort_values(["t_s", "id"], kind="stable")


def body_arrays(df: pd.DataFrame, cols: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (n_t,) and ``cols`` per body (n_t, n_b, len(cols)) of the bodies present in
    every sample."""
    times = np.unique(df["t_s"].to_numpy())
    counts = df.groupby("id")["t_s"].nunique()
    ids = counts.index[counts.to_numpy() == times.size]
    d = df[df["id"].isin(ids)].sort_values(["t_s", "id"], kind="stable")
    return times, d[cols].to_numpy(float).reshape(times.size, ids.size, len(cols))


def _bins(ang: np.ndarray, hi: float, nb: int) -> np.ndarray:
    edges = np.linspace(0.0, hi, nb + 1)
    return np.clip(np.searchsorted(edges, ang, side="right") - 1, 0, nb - 1)


def build_series(df: pd.DataFrame, shape: str) -> pd.DataFrame:
    """The per-sample series (module docstring) of the free-particle rows ``df`` of a trajectory."""
    t_row = df["t_s"].to_numpy(float)
    times, inv = np.unique(t_row, return_inverse=True)
    n = np.bincount(inv, minlength=times.size)
    out = {"t_s": times, "n_bodies": n}
    for a in AXES:
        out[f"mean_abs_omega_{a}"] = np.bincount(inv, np.abs(df[f"w{a}_rad_s"].to_numpy(float)), times.size) / n
    tb, q = body_arrays(df, ["qw", "qx", "qy", "qz"])
    if tb.size != times.size:
        raise SeriesError("no body is present in every sample of the trajectory: the orientation series are undefined")
    out["orientation_order"] = orientation_order(q, shape)
    out["orientation_start_corr"] = orientation_memory(q, 1.0, shape)["c_start"]
    qs = df[["qw", "qx", "qy", "qz"]].to_numpy(float)
    for kind, hi, nb in ORIENTATION_KINDS[shape]:
        ang = orientation_angles(kind, qs)
        out[f"{kind}_mean_deg"] = np.bincount(inv, ang, times.size) / n
        counts = np.bincount(inv * nb + _bins(ang, hi, nb), minlength=times.size * nb).reshape(times.size, nb)
        for j in range(nb):
            out[f"{kind}_n{j}"] = counts[:, j]
    return pd.DataFrame(out)


def write_series(series: pd.DataFrame, case_dir: Path) -> Path:
    """Write ``series.csv.gz`` (9 significant digits, gzip without a time stamp: the same series
    gives the same bytes)."""
    path = Path(case_dir) / SERIES
    series.to_csv(path, index=False, float_format="%.9g", compression={"method": "gzip", "mtime": 0})
    return path


def read_series(case_dir: Path, shape: str) -> pd.DataFrame:
    """``series.csv.gz`` of a run, checked: every column of the shape present, times increasing,
    bin counts adding up to ``n_bodies``. A missing or malformed file is a :class:`SeriesError`."""
    path = Path(case_dir) / SERIES
    if not path.exists():
        raise SeriesError(f"{path} is missing: the run's statistics need it or its trajectory "
                          f"({Path(case_dir) / TRAJECTORY_FILE}); rerun the case")
    s = pd.read_csv(path)
    need = ["t_s", "n_bodies", "orientation_order", "orientation_start_corr"] + [f"mean_abs_omega_{a}" for a in AXES]
    for kind, _, nb in ORIENTATION_KINDS[shape]:
        need += [f"{kind}_mean_deg"] + [f"{kind}_n{j}" for j in range(nb)]
    missing = [c for c in need if c not in s.columns]
    if missing:
        raise SeriesError(f"{path} lacks the columns {missing} of a {shape} run: rebuild it from the trajectory")
    if len(s) == 0 or not np.all(np.diff(s["t_s"].to_numpy(float)) > 0):
        raise SeriesError(f"{path}: no samples, or sample times not increasing")
    for kind, _, nb in ORIENTATION_KINDS[shape]:
        tot = s[[f"{kind}_n{j}" for j in range(nb)]].sum(axis=1).to_numpy()
        if not np.array_equal(tot, s["n_bodies"].to_numpy()):
            raise SeriesError(f"{path}: the bin counts of {kind} do not add up to n_bodies")
    return s


def flow_series(case_dir: Path, t: np.ndarray, column: str) -> np.ndarray:
    """A column of ``flow_rate.csv`` at the sample times ``t`` (all > 0: the flow is first sampled
    one interval after the start). Missing file or column, a time without a row, or a value that is
    not finite is a :class:`SeriesError` naming the file: never a quiet omission."""
    path = Path(case_dir) / "flow_rate.csv"
    if not path.exists():
        raise SeriesError(f"{path} is missing: the stationarity test needs its {column!r} series")
    fr = pd.read_csv(path)
    if column not in fr.columns:
        raise SeriesError(f"{path} has no column {column!r} (columns: {list(fr.columns)}): rerun the case")
    key = pd.Series(pd.to_numeric(fr[column], errors="coerce").to_numpy(float),
                    index=np.round(fr["t_s"].to_numpy(float), 9))
    key = key[~key.index.duplicated()]
    out = key.reindex(np.round(np.asarray(t, float), 9)).to_numpy()
    bad = ~np.isfinite(out)
    if bad.any():
        first = float(np.asarray(t)[bad][0])
        raise SeriesError(f"{path}: {column!r} has no finite value at {int(bad.sum())} of the {len(t)} particle sample "
                          f"times (first t = {first:.6g} s): the particle and fluid series do not align")
    return out


def locked(x: np.ndarray, q: np.ndarray, meta: dict, summary: dict, diag: dict) -> dict:
    """:func:`lbmpipe.reproduction.steady.locking_diagnostics` over the whole run (column, no
    passing, cannot sit side by side); not computed without the scene's pipe in the summary."""
    dom = (summary.get("scene") or {}).get("domain") or {}
    if not dom.get("diameter_mm") or not dom.get("length_mm") or x.shape[1] < 2:
        return {"locked": False, "message": "not computed: no pipe in summary.json or fewer than 2 bodies"}
    size = ({"edge_mm": meta["edge_mm"]} if meta["shape"] == "cube"
            else {"diameter_mm": meta["diameter_mm"], "length_mm": meta["length_mm"]})
    return locking_diagnostics(x, q, meta["shape"], float(dom["diameter_mm"]), float(dom["length_mm"]),
                               k_neighbours=int(diag["k_neighbours"]),
                               retained_locked=float(diag["locked_neighbours_retained"]), **size)


def trajectory_diagnostics(df: pd.DataFrame, shape: str, meta: dict, summary: dict, diag: dict,
                           windows: list[float]) -> dict:
    """``trajectory.json`` of a run (module docstring) from its free-particle rows, for the
    averaging windows starting at ``windows`` (s)."""
    t, arr = body_arrays(df, ["x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"])
    x, q = arr[..., :3], arr[..., 3:7]
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    out = {"locked": locked(x, q, meta, summary, diag), "sample_interval_s": dt, "windows": {}}
    for start in windows:
        keep = t > start + _TOL * max(1.0, abs(start))
        w = {"start_s": float(start), "samples": int(keep.sum())}
        if keep.sum() >= 4:
            mem = orientation_memory(q[keep], dt, shape)
            w["orientation_memory"] = {k: mem[k] for k in ("tau_orient_s", "tau_status", "e_fold_s")}
        else:
            w["orientation_memory"] = {"tau_orient_s": _NAN, "tau_status": "undefined", "e_fold_s": _NAN}
        rows = df[df["t_s"].to_numpy(float) > start + _TOL * max(1.0, abs(start))]
        qs = rows[["qw", "qx", "qy", "qz"]].to_numpy(float)
        w["median_deg"] = {kind: float(np.median(orientation_angles(kind, qs))) if len(qs) else _NAN
                           for kind, _, _ in ORIENTATION_KINDS[shape]}
        out["windows"][window_key(start)] = w
    return out


def read_window(case_dir: Path, start_s: float) -> dict:
    """The window of ``trajectory.json`` starting at ``start_s``; a :class:`SeriesError` if the
    file is missing or holds no such window (the spin-up moved: the trajectory is needed)."""
    path = Path(case_dir) / TRAJECTORY
    if not path.exists():
        raise SeriesError(f"{path} is missing: the run's orientation memory, median angles and locking need it "
                          "or the trajectory; rerun the case")
    doc = json.loads(path.read_text())
    w = (doc.get("windows") or {}).get(window_key(start_s))
    if w is None:
        raise SeriesError(f"{path} holds the windows {sorted(doc.get('windows') or {})} but the statistics ask for one "
                          f"starting at {start_s:.9g} s (the spin-up rule or the run changed): rerun the case to "
                          "recompute it from the trajectory")
    return {**w, "locked": doc.get("locked") or {}, "sample_interval_s": doc.get("sample_interval_s")}


def second_half_start(t: np.ndarray, start_s: float) -> float:
    """Start of the second half of the averaging window ``(start_s, t[-1]]``, on a sample time:
    the samples after it are the later half of the window's samples."""
    keep = np.asarray(t, float)[np.asarray(t, float) > start_s + _TOL * max(1.0, abs(start_s))]
    if keep.size < 2:
        return math.inf
    return float(keep[keep.size // 2 - 1])
