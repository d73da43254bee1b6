"""Per-case statistics of the particle runs and the aggregated tables behind the paper's figures.

Angular velocity (Figs. 4-7). The paper does not define its statistic; we use (paper/reading.md) the
mean of ``|Omega_a|``, ``a`` in {x, y, z}, LAB-frame components, over all free particles and all
sampled times ``t > spinup_s``. Its 95 % confidence interval comes from batch means of the
particle-averaged time series ``m_a(t) = <|Omega_a|>_particles(t)``: the samples of one run are
correlated in time, so the naive iid interval would be too narrow, and the particles of one
sample are correlated with each other through the crowded flow, so they are not counted as
independent either.

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
CI of each bin is the batch-means half-width of the per-sample bin fraction.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats as _st

AXES = ("x", "y", "z")
CUBE_MAX_AXIS_ANGLE_DEG = math.degrees(math.acos(1.0 / math.sqrt(3.0)))  # 54.7356
# (kind, upper edge of the range in degrees, number of bins)
ORIENTATION_KINDS = {
    "cylinder": (("cyl_axis_angle", 90.0, 9),),
    "cube": (("cube_projected_angle", 45.0, 9), ("cube_axis_angle", CUBE_MAX_AXIS_ANGLE_DEG, 9)),
}
ORIENTATION_COLUMNS = ["kind", "bin_lo_deg", "bin_hi_deg", "fraction", "ci95"]
META_COLUMNS = ["case", "shape", "size_label", "diameter_mm", "length_mm", "edge_mm", "concentration",
                "reynolds", "collisions"]
ANGULAR_VELOCITY_COLUMNS = META_COLUMNS + ["status", "concentration_achieved", "n_particles", "samples",
                                           "omega_x", "omega_y", "omega_z", "ci_x", "ci_y", "ci_z"]
ORIENTATION_TABLE_COLUMNS = ["case", "shape", "size_label", "concentration", "reynolds", "collisions", "status",
                             "kind", "bin_lo_deg", "bin_hi_deg", "fraction", "ci95"]
ORIENTATION_SUMMARY_COLUMNS = ["case", "shape", "size_label", "concentration", "reynolds", "collisions", "status",
                               "kind", "mean_deg", "ci95_deg", "median_deg", "samples"]
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


def integrated_autocorrelation_time(series: np.ndarray, dt: float = 1.0, c: float = 5.0) -> float:
    """Integrated autocorrelation time ``tau_int = dt (1/2 + sum_{k>=1} rho_k)`` of a series
    sampled every ``dt``, the discrete form of ``int_0^inf rho(t) dt`` (an exponential
    ``rho = exp(-t/T)`` gives ``T``; white noise gives ``dt/2``). Then the variance of the mean
    of ``n`` samples is ``2 tau_int / (n dt)`` times the variance of one sample.

    The sum is cut at Sokal's self-consistent window: the smallest ``M`` with
    ``M >= c * tau_int(M) / dt``, which keeps the noise of the long-lag tail out. NaN for fewer
    than 4 samples or a constant series.
    """
    x = np.asarray(series, dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = x.size
    if n < 4:
        return _NAN
    y = x - x.mean()
    var = float(np.dot(y, y)) / n
    if var <= 0.0:
        return _NAN
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(y, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[:n] / (n * var)  # biased estimator, rho_0 = 1
    tau = 0.5 + np.cumsum(acf[1:])  # tau(M) in samples for M = 1 .. n-1
    ok = np.nonzero(np.arange(1, n) >= c * tau)[0]
    t = tau[ok[0]] if ok.size else tau[-1]
    return float(max(t, 0.5) * dt)


# ----------------------------------------------------------------------------------------------
# orientation

def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``A`` (N, 3, 3), body -> lab (Eq. (20)), of unit quaternions
    ``q = (w, x, y, z)`` (N, 4); same convention as ``lbmpipe.particles.rigid.quat_to_matrix``."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    a = np.empty((q.shape[0], 3, 3))
    a[:, 0, 0] = 1 - 2 * (y * y + z * z)
    a[:, 0, 1] = 2 * (x * y - w * z)
    a[:, 0, 2] = 2 * (x * z + w * y)
    a[:, 1, 0] = 2 * (x * y + w * z)
    a[:, 1, 1] = 1 - 2 * (x * x + z * z)
    a[:, 1, 2] = 2 * (y * z - w * x)
    a[:, 2, 0] = 2 * (x * z - w * y)
    a[:, 2, 1] = 2 * (y * z + w * x)
    a[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return a


def cylinder_axis_angle(q: np.ndarray) -> np.ndarray:
    """Angle (deg, 0-90) between the cylinder axis (body z) and the pipe axis (lab z)."""
    a = rotation_matrices(q)
    return np.degrees(np.arccos(np.clip(np.abs(a[:, 2, 2]), 0.0, 1.0)))


def cube_axis_angle(q: np.ndarray) -> np.ndarray:
    """3-D angle (deg, 0-54.74) between the pipe axis and the nearest cube axis."""
    a = rotation_matrices(q)
    return np.degrees(np.arccos(np.clip(np.abs(a[:, 2, :]).max(axis=1), 0.0, 1.0)))


def cube_projected_angle(q: np.ndarray) -> np.ndarray:
    """In-image angle (deg, 0-45) of a cube seen by a camera looking along lab y: the body axis
    with the longest projection on the x-z plane, its angle to the pipe axis folded by the
    square's symmetry (module docstring gives the exact definition)."""
    a = rotation_matrices(q)
    px, pz = a[:, 0, :], a[:, 2, :]  # (N, 3): projections of the three body axes
    k = np.argmax(px * px + pz * pz, axis=1)
    i = np.arange(a.shape[0])
    alpha = np.degrees(np.arctan2(px[i, k], pz[i, k]))
    beta = np.mod(alpha, 90.0)
    return np.minimum(beta, 90.0 - beta)


_ANGLE_FUNCS = {"cyl_axis_angle": cylinder_axis_angle, "cube_axis_angle": cube_axis_angle,
                "cube_projected_angle": cube_projected_angle}


def orientation_angles(kind: str, q: np.ndarray) -> np.ndarray:
    """Angles (deg) of ``kind`` (``cyl_axis_angle``, ``cube_axis_angle``,
    ``cube_projected_angle``) for quaternions ``q`` (N, 4)."""
    return _ANGLE_FUNCS[kind](q)


def isotropic_cdf(kind: str, angle_deg) -> np.ndarray:
    """Share of uniformly random orientations (Haar measure on rotations) whose angle ``kind``
    is at most ``angle_deg`` -- the reference an isotropic suspension gives, in closed form:

    - ``cyl_axis_angle``: the axis is uniform on the sphere and its angle to the pipe axis has
      density ``sin theta`` on 0-90 deg, so ``F = 1 - cos theta``.
    - ``cube_axis_angle``: the pipe axis seen from the body is uniform on the sphere; the nearest
      cube axis is the one whose cell (``|u_k| = max``, 1/6 of the sphere) holds it. In the cell of
      body z, polar angle ``t``, azimuth ``p`` in 0-45 deg (1/8 of the cell), the cell ends at
      ``tan t = 1 / cos p``. Up to 45 deg no cell boundary is reached: ``F = 3 (1 - cos theta)``;
      beyond, with ``cos p* = cot theta``, ``F = (12/pi) [p* - asin(sin p* / sqrt 2)
      + (pi/4 - p*)(1 - cos theta)]`` (the boundary term integrates in closed form with
      ``s = sin p``), which reaches 1 at ``theta = arccos(1/sqrt 3)``.
    - ``cube_projected_angle``: uniform on 0-45 deg, ``F = theta / 45``. A rotation about the
      camera axis (lab y) leaves the Haar measure unchanged, turns every projected edge by the
      same angle and keeps which one is longest, so the in-image angle is uniform on the circle
      and its fold into 0-45 deg is uniform too.
    """
    th = np.radians(np.clip(np.asarray(angle_deg, dtype=float), 0.0, None))
    if kind == "cyl_axis_angle":
        return 1.0 - np.cos(np.minimum(th, np.pi / 2))
    if kind == "cube_projected_angle":
        return np.clip(np.degrees(th) / 45.0, 0.0, 1.0)
    if kind == "cube_axis_angle":
        th = np.minimum(th, math.radians(CUBE_MAX_AXIS_ANGLE_DEG))
        low = 3.0 * (1.0 - np.cos(th))
        with np.errstate(divide="ignore", invalid="ignore"):
            p = np.arccos(np.clip(1.0 / np.tan(np.maximum(th, np.pi / 4)), 0.0, 1.0))
        high = (12.0 / np.pi) * (p - np.arcsin(np.sin(p) / math.sqrt(2.0)) + (np.pi / 4 - p) * (1.0 - np.cos(th)))
        return np.where(th <= np.pi / 4, low, np.minimum(high, 1.0))
    raise KeyError(f"unknown orientation kind {kind!r}; one of {sorted(_ANGLE_FUNCS)}")


def isotropic_bin_fractions(kind: str, edges_deg) -> np.ndarray:
    """Fraction of uniformly random orientations in each bin ``[edges[i], edges[i+1])`` of the
    angle ``kind`` (:func:`isotropic_cdf` differenced): the reference line of Figs. 8 and 9."""
    return np.diff(isotropic_cdf(kind, np.asarray(edges_deg, dtype=float)))


# ----------------------------------------------------------------------------------------------
# per case

def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


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


def _load_samples(case_dir: Path, spinup_s: float) -> tuple[pd.DataFrame, int]:
    """Rows of the free particles at sampled times ``t > spinup_s``; number of such times."""
    case_dir = Path(case_dir)
    pq = case_dir / "particles.parquet"
    if not pq.exists():
        return pd.DataFrame(), 0
    df = pd.read_parquet(pq)
    if df.empty:
        return df, 0
    static = case_dir / "particles_static.csv"
    if static.exists():
        st = pd.read_csv(static)
        if "fixed" in st.columns and len(st):
            fixed = st["fixed"].astype(str).str.lower().isin(("true", "1", "1.0"))
            df = df[~df["id"].isin(st.loc[fixed, "id"])]
    # a sample written exactly at the end of spin-up belongs to spin-up; allow for round-off in t
    tol = 1e-9 * max(1.0, abs(spinup_s))
    df = df[df["t_s"] > spinup_s + tol].sort_values(["t_s", "id"], kind="stable")
    return df, int(df["t_s"].nunique())


def _per_sample(df: pd.DataFrame, values: np.ndarray) -> np.ndarray:
    """Average of ``values`` (one per row of ``df``) over the particles of each sampled time."""
    return pd.Series(values, index=df.index).groupby(df["t_s"].to_numpy()).mean().to_numpy()


def _sample_interval(df: pd.DataFrame) -> float:
    t = np.unique(df["t_s"].to_numpy())
    return float(np.median(np.diff(t))) if t.size > 1 else _NAN


def _nan_axes() -> dict:
    return {a: _NAN for a in AXES}


def case_statistics(case: str, case_dir: Path, case_cfg: dict, spinup_s: float | None = None,
                    n_batches: int = 10) -> dict:
    """The ``stats.json`` dict of the contract for one case directory.

    ``mean_abs_omega_rad_s[a]``: mean of ``|Omega_a|`` (lab frame) over free particles and
    samples with ``t > spinup_s``; ``ci95_rad_s[a]``: batch-means 95 % half-width (Student t) of
    the particle-averaged series; ``tau_int_s[a]``: its integrated autocorrelation time.
    ``spinup_s`` defaults to ``summary.json``'s. NaN statistics when the status is not
    ``completed`` or no sample lies after spin-up. An extra key ``orientation`` holds, per
    orientation kind, ``{mean_deg, ci95_deg, median_deg}`` (used by :func:`aggregate`).
    """
    case_dir = Path(case_dir)
    meta = case_metadata(case, case_cfg)
    summary = _read_json(case_dir / "summary.json")
    status = summary.get("status", "unknown") if summary else "not run"
    if spinup_s is None:
        spinup_s = float(summary.get("spinup_s", 0.0)) if summary else _NAN
    parts = (summary or {}).get("particles") or {}
    out = {"case": case, "status": status, "shape": meta["shape"], "size_label": meta["size_label"],
           "reynolds": meta["reynolds"], "concentration": meta["concentration"], "collisions": meta["collisions"],
           "n_particles": int(parts.get("count", 0) or 0), "spinup_s": spinup_s, "samples": 0,
           "mean_abs_omega_rad_s": _nan_axes(), "ci95_rad_s": _nan_axes(), "n_batches": 0,
           "tau_int_s": _nan_axes(), "orientation": {}}
    if status != "completed" or meta["shape"] not in ORIENTATION_KINDS:
        return out
    df, n_samples = _load_samples(case_dir, float(spinup_s))
    out["samples"] = n_samples
    if n_samples == 0:
        return out
    out["n_particles"] = int(df["id"].nunique())
    dt = _sample_interval(df)
    for a in AXES:
        series = _per_sample(df, np.abs(df[f"w{a}_rad_s"].to_numpy()))
        mean, hw, b = batch_means(series, n_batches)
        out["mean_abs_omega_rad_s"][a] = mean
        out["ci95_rad_s"][a] = hw
        out["n_batches"] = b
        out["tau_int_s"][a] = integrated_autocorrelation_time(series, dt if np.isfinite(dt) else 1.0)
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    for kind, _, _ in ORIENTATION_KINDS[meta["shape"]]:
        ang = orientation_angles(kind, q)
        mean, hw, _ = batch_means(_per_sample(df, ang), n_batches)
        out["orientation"][kind] = {"mean_deg": mean, "ci95_deg": hw, "median_deg": float(np.median(ang))}
    return out


def orientation_histograms(case_dir: Path, shape: str, spinup_s: float, n_batches: int = 10,
                           status: str = "completed") -> pd.DataFrame:
    """``orientation.csv`` rows (``kind, bin_lo_deg, bin_hi_deg, fraction, ci95``) of one case.

    ``fraction``: share of (particle, sample) pairs after spin-up in the bin; ``ci95``: batch-
    means 95 % half-width of the per-sample fraction of the particles in the bin. The bins are
    laid out (with NaN values) even for a case with no samples, so tables keep their shape.
    """
    kinds = ORIENTATION_KINDS.get(shape, ())
    df, n = _load_samples(case_dir, spinup_s) if status == "completed" else (pd.DataFrame(), 0)
    rows = []
    for kind, hi, nb in kinds:
        edges = np.linspace(0.0, hi, nb + 1)
        if n:
            ang = orientation_angles(kind, df[["qw", "qx", "qy", "qz"]].to_numpy())
            idx = np.clip(np.searchsorted(edges, ang, side="right") - 1, 0, nb - 1)
            onehot = np.zeros((ang.size, nb))
            onehot[np.arange(ang.size), idx] = 1.0
            per_t = pd.DataFrame(onehot, index=df.index).groupby(df["t_s"].to_numpy()).mean().to_numpy()
            frac = onehot.mean(axis=0)
            ci = np.array([batch_means(per_t[:, j], n_batches)[1] for j in range(nb)])
        else:
            frac = np.full(nb, _NAN)
            ci = np.full(nb, _NAN)
        rows.append(pd.DataFrame({"kind": kind, "bin_lo_deg": edges[:-1], "bin_hi_deg": edges[1:],
                                  "fraction": frac, "ci95": ci}))
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=ORIENTATION_COLUMNS)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, float) and not math.isfinite(obj):
        return None  # strict JSON has no NaN; readers map null back to NaN
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    return obj


def write_case_outputs(case: str, case_dir: Path, case_cfg: dict) -> None:
    """Write ``stats.json`` and ``orientation.csv`` beside the case files (NaN written as JSON
    ``null`` in ``stats.json``)."""
    case_dir = Path(case_dir)
    s = case_statistics(case, case_dir, case_cfg)
    (case_dir / "stats.json").write_text(json.dumps(_jsonable(s), indent=2) + "\n")
    spin = s["spinup_s"] if s["spinup_s"] is not None and np.isfinite(s["spinup_s"]) else 0.0
    orientation_histograms(case_dir, s["shape"], spin, status=s["status"]).to_csv(
        case_dir / "orientation.csv", index=False)


# ----------------------------------------------------------------------------------------------
# aggregated tables

def _num(v) -> float:
    return _NAN if v is None else float(v)


def _case_stats(case: str, case_dir: Path, case_cfg: dict) -> dict:
    """stats.json of a case, computed on the fly if it was not written."""
    s = _read_json(case_dir / "stats.json")
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
    return orientation_histograms(case_dir, shape, spin if np.isfinite(spin) else 0.0,
                                  status=stats.get("status", "not run"))


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
        summary = _read_json(cdir / "summary.json") or {}
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
        av.append({**meta, "status": status, "concentration_achieved": _num(achieved),
                   "n_particles": int(s.get("n_particles") or parts.get("count") or 0),
                   "samples": int(s.get("samples") or 0),
                   **{f"omega_{a}": _num(om.get(a)) for a in AXES}, **{f"ci_{a}": _num(ci.get(a)) for a in AXES}})
        short = {k: meta[k] for k in ("case", "shape", "size_label", "concentration", "reynolds", "collisions")}
        h = _case_orientation(cdir, meta["shape"], {**s, "status": status})
        for _, r in h.iterrows():
            orient.append({**short, "status": status, **{k: r[k] for k in ORIENTATION_COLUMNS}})
        so = s.get("orientation") or {}
        for kind, _, _ in ORIENTATION_KINDS[meta["shape"]]:
            o = so.get(kind) or {}
            osum.append({**short, "status": status, "kind": kind, "mean_deg": _num(o.get("mean_deg")),
                         "ci95_deg": _num(o.get("ci95_deg")), "median_deg": _num(o.get("median_deg")),
                         "samples": int(s.get("samples") or 0)})
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
        summary = _read_json(fid_dir / "cases" / case / "summary.json") or {}
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
