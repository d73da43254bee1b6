"""The error of each run of the accuracy-cost study against its reference (the references and
knobs: :mod:`lbmpipe.reproduction.study_plan`): a run's work and times from its ``summary.json``
and Snakemake benchmark, the pipe's profile error and the sphere's drag error per setting, the
paper's observable across fidelity levels, and the averaging time's interval width."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from . import steady
from .runcost import read_benchmark, run_work
from .study_plan import BATCH_MEANS, KNOB_KEYS, drag_geometry, knob_settings, run_id, study_settings


def steady_change(series: np.ndarray, fraction: float = 0.2) -> float:
    """|x_end - x_(end - fraction of the run)| / |x_end|: how much a series still drifts."""
    x = np.asarray(series, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return float("nan")
    back = max(1, int(round(fraction * x.size)))
    ref = abs(x[-1]) if x[-1] != 0 else float("nan")
    return float(abs(x[-1] - x[-1 - back]) / ref)


def _lattice_info(summary: dict) -> dict:
    lat = summary.get("lattice", {}) or {}
    return {"tau": lat.get("tau", float("nan")), "mach": lat.get("mach_max", float("nan"))}


def run_record(rid: str, spec: dict, run_dir: Path, bench: Path, settings: dict) -> dict:
    """One run's measurements: work, times, status, and its raw result (pipe: profile error;
    drag: K and the force-balance check)."""
    summary = json.loads((Path(run_dir) / "summary.json").read_text())
    rec = {"run": rid, "reference": spec["reference"], **spec["setting"], "offset": spec["offset"],
           "status": summary.get("status", "missing"), "dt_s": spec["scene"]["numerics"]["dt_s"],
           **_lattice_info(summary), **run_work(summary)}
    b = read_benchmark(bench)
    rec["wall_s"], rec["cpu_s"] = b["s"], b["cpu_time"]
    proc = Path(run_dir) / "process.json"
    if proc.exists():  # exact child CPU time (run_timed) rather than the benchmark's sampled one
        rec["cpu_s"] = float(json.loads(proc.read_text())["cpu_s"])
    fr_path = Path(run_dir) / "flow_rate.csv"
    fr = pd.read_csv(fr_path) if fr_path.exists() else pd.DataFrame()
    if spec["reference"] == "pipe":
        rec["value"] = float(summary.get("profile_error_rel_l2", np.nan))
        rec["steady_rel_change"] = steady_change(fr["force_density_N_m3"]) if len(fr) else float("nan")
    else:
        geo = drag_geometry(settings)
        rec["steady_rel_change"] = steady_change(fr["q_m3_s"]) if len(fr) else float("nan")
        if len(fr) and rec["status"] == "completed":
            u_s = float(fr["q_m3_s"].iloc[-1]) / geo["L_m"] ** 2
            rec["value"] = geo["g_m_s2"] * geo["L_m"] ** 3 / (6 * math.pi * geo["nu_m2_s"] * geo["a_m"] * u_s)
        else:
            rec["value"] = float("nan")
        # at steady state the momentum exchange balances the body force on the fluid
        pq = Path(run_dir) / "particles.parquet"
        vf = float((summary.get("particles") or {}).get("volume_fraction", np.nan))
        if pq.exists() and np.isfinite(vf):
            p = pd.read_parquet(pq, columns=["t_s", "fz_N"])
            fz = float(p["fz_N"].iloc[-1]) if len(p) else float("nan")
            rec["force_balance_rel"] = fz / (1000.0 * geo["g_m_s2"] * geo["L_m"] ** 3 * (1 - vf)) - 1.0
    return rec


def rows_for_reference(recs: pd.DataFrame, settings: dict, reference: str) -> list[dict]:
    """Accuracy-cost rows of ``pipe`` or ``drag``: one per (knob, setting)."""
    tol = float(settings["steady_tol"])
    rows = []
    base_id = run_id(reference, dict(settings["base"], **({"wall": "bounce_back"} if reference == "drag" else {})))
    geo = drag_geometry(settings) if reference == "drag" else None
    for knob, label, setting in knob_settings(settings, reference):
        rid = run_id(reference, setting)
        sel = recs[recs["run"] == rid] if reference == "pipe" else recs[recs["run"].str.startswith(rid + "_o")]
        if sel.empty:
            continue
        first = sel.iloc[0]
        row = {"reference": reference, "knob": knob, "setting": label, "run": rid,
               "is_base": rid == base_id, **{k: setting[k] for k in KNOB_KEYS},
               "dt_s": first["dt_s"], "tau": first["tau"], "mach": first["mach"]}
        if reference == "drag":
            row["wall"] = "n/a (Ladd bounce-back)"
        ok = sel[sel["status"] == "completed"]
        notes = []
        if len(ok) < len(sel):
            notes.append(f"{len(sel) - len(ok)} of {len(sel)} runs {','.join(sorted(set(sel['status']) - {'completed'}))}")
        if reference == "pipe":
            row["value"] = float(ok["value"].iloc[0]) if len(ok) else float("nan")
            row["error"] = row["value"]
            row["error_signed"] = row["value"]
            row["error_spread"] = float("nan")
            row["reference_value"] = 0.0
            row["error_what"] = "relative L2 of the averaged profile vs Hagen-Poiseuille"
        else:
            k = ok["value"].to_numpy(float)
            kmean = float(np.mean(k)) if k.size else float("nan")
            row["value"] = kmean
            row["reference_value"] = geo["K_ref"]
            row["error_signed"] = kmean / geo["K_ref"] - 1.0
            row["error"] = abs(row["error_signed"])
            row["error_spread"] = float(np.std(k, ddof=1) / geo["K_ref"]) if k.size > 1 else float("nan")
            row["error_what"] = (f"|mean K / K_ref - 1| over {len(sel)} sphere position(s), K_ref = {geo['K_ref']:.4g} "
                                 f"(Zick & Homsy SC, c = {geo['concentration']:g})")
            if "force_balance_rel" in ok:
                fb = ok["force_balance_rel"].abs().max()
                row["force_balance_rel"] = float(fb)
        steady = float(sel["steady_rel_change"].max())
        row["steady_rel_change"] = steady
        if not (steady <= tol):
            notes.append(f"not steady: drift {steady:.2g} > {tol:g}")
        for c in ("wall_s", "cpu_s", "solver_s", "setup_s"):
            row[c] = float(sel[c].mean())
        for c in ("steps", "nodes", "node_updates", "particles", "links", "link_updates", "threads", "simulated_s"):
            row[c] = first[c]
        row["n_runs"] = len(sel)
        row["status"] = "completed" if len(ok) == len(sel) else ",".join(sorted(set(sel["status"])))
        row["note"] = "; ".join(notes)
        rows.append(row)
    return rows


def mean_abs_omega(parquet: Path, spinup_s: float) -> dict:
    """Mean |Omega_a| (lab frame, rad/s) over particles and samples with t > spinup."""
    df = pd.read_parquet(parquet, columns=["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s"])
    df = df[df["t_s"] > spinup_s + 1e-12]
    return {a: float(df[f"w{a}_rad_s"].abs().mean()) if len(df) else float("nan") for a in "xyz"}


def case_omega(root: Path, fidelity: str, case: str) -> dict | None:
    """Mean |Omega| of ``case`` at ``fidelity``: from ``stats.json`` when the statistics exist,
    else from ``particles.parquet``; ``None`` when the case has not run (or did not complete)."""
    cdir = Path(root) / fidelity / "cases" / case
    summ = cdir / "summary.json"
    if not summ.exists():
        return None
    summary = json.loads(summ.read_text())
    if summary.get("status") != "completed":
        return None
    stats = cdir / "stats.json"
    ci = None
    if stats.exists():
        st = json.loads(stats.read_text())
        om = st.get("mean_abs_omega_rad_s")
        ci = st.get("ci95_rad_s")
        source = "stats.json"
    else:
        if not (cdir / "particles.parquet").exists():
            return None
        om = mean_abs_omega(cdir / "particles.parquet", float(summary.get("spinup_s", 0.0)))
        source = "particles.parquet"
    if om is None:
        return None
    bench = read_benchmark(Path(root) / fidelity / "benchmarks" / f"{case}.simulate.tsv")
    scene = summary.get("scene", {}) or {}
    return {"omega": np.array([float(om[a]) for a in "xyz"]),
            "ci": np.array([float(ci[a]) for a in "xyz"]) if ci else np.full(3, np.nan),
            "source": source, "summary": summary, "wall_s": bench["s"], "cpu_s": bench["cpu_time"],
            "dx_mm": float((scene.get("numerics") or {}).get("dx_mm", np.nan)),
            "dt_s": float((scene.get("numerics") or {}).get("dt_s", np.nan)),
            "duration_s": float(summary.get("simulated_seconds", np.nan))}


def observable_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Convergence of mean |Omega| of the study's case towards the finest fidelity level that has
    results (smallest dx, then longest run)."""
    s = study_settings(config, fidelity)
    case = s["observable"]["case"]
    found = {}
    for lvl in config["fidelities"]:
        r = case_omega(root, lvl, case)
        if r is not None and np.all(np.isfinite(r["omega"])):
            found[lvl] = r
    if not found:
        return [{"reference": "omega", "knob": "fidelity", "setting": "(none)", "run": case, "error": np.nan,
                 "status": "missing", "note": f"no completed run of {case} at any fidelity level"}]
    finest = min(found, key=lambda k: (found[k]["dx_mm"], -found[k]["duration_s"]))
    ref = found[finest]["omega"]
    rows = []
    for lvl, r in sorted(found.items(), key=lambda kv: -kv[1]["dx_mm"]):
        err = float(np.linalg.norm(r["omega"] - ref) / np.linalg.norm(ref))
        note = f"mean |Omega| from {r['source']}; the levels differ in run length as well as dx"
        if lvl == finest:
            err = float("nan")
            note = (f"reference (finest level with results); 95 % CI / mean = "
                    f"{np.linalg.norm(r['ci']) / np.linalg.norm(ref):.2g}" if np.isfinite(r["ci"]).all()
                    else "reference (finest level with results)")
            if len(found) == 1:
                note = "only one fidelity level has results: no convergence measurable yet"
        w = run_work(r["summary"])
        rows.append({"reference": "omega", "knob": "fidelity", "setting": lvl, "run": f"{lvl}/{case}",
                     "is_base": lvl == fidelity, "dx_mm": r["dx_mm"], "dt_s": r["dt_s"],
                     "value": float(np.linalg.norm(r["omega"])), "reference_value": float(np.linalg.norm(ref)),
                     "error": err, "error_signed": err, "error_what": f"|Omega - Omega_{finest}| / |Omega_{finest}| (x, y, z)",
                     "wall_s": r["wall_s"], "cpu_s": r["cpu_s"], **w, "status": "completed", "note": note,
                     **_lattice_info(r["summary"])})
    return rows


def averaging_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Relative 95 % half-width of mean |Omega_c| (c = ``averaging.component``) against the
    averaging window: the particle-averaged series after spin-up, truncated to its first
    T / 2^k (k = 0, 1, ...) while at least ``min_samples`` remain. Cost: the case's wall time
    pro-rated to spin-up plus window."""
    s = study_settings(config, fidelity)
    a = s["averaging"]
    case, comp = a["case"], a["component"]
    cdir = Path(root) / fidelity / "cases" / case
    base = {"reference": "averaging", "knob": "averaging time"}
    if not (cdir / "summary.json").exists() or not (cdir / "particles.parquet").exists():
        return [{**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": "missing",
                 "note": f"{case} has no results at {fidelity}"}]
    summary = json.loads((cdir / "summary.json").read_text())
    if summary.get("status") != "completed":
        return [{**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": summary.get("status"),
                 "note": f"{case} did not complete at {fidelity}"}]
    spin = float(summary.get("spinup_s", 0.0))
    df = pd.read_parquet(cdir / "particles.parquet", columns=["t_s", f"w{comp}_rad_s"])
    df = df[df["t_s"] > spin + 1e-12]
    series = df.assign(w=df[f"w{comp}_rad_s"].abs()).groupby("t_s")["w"].mean().sort_index()
    t = series.index.to_numpy(float)
    x = series.to_numpy(float)
    dt_sample = float(np.median(np.diff(t))) if t.size > 1 else float("nan")
    bench = read_benchmark(Path(root) / fidelity / "benchmarks" / f"{case}.simulate.tsv")
    wall, cpu = bench["s"], bench["cpu_time"]
    total = float(summary.get("simulated_seconds", np.nan))
    work = run_work(summary)
    rows = []
    n = x.size
    k = 0
    while n // 2**k >= int(a["min_samples"]):
        m = n // 2**k
        # the interval of steady.mean_interval: >= 20 batches of >= 5 correlation times, else
        # overlapping batch means marked insufficient; only a sufficient window is recommended
        iv = steady.mean_interval(x[:m], dt_sample)
        mean, hw = iv["mean"], iv["ci95"]
        window = m * dt_sample
        frac = (spin + window) / total if total > 0 else float("nan")
        rows.append({**base, "run": f"{fidelity}/{case}/window_{window:.4g}s", "setting": f"{window:.3g} s", "is_base": k == 0, "value": mean, "reference_value": mean,
                     "error": hw / mean if mean > 0 else float("nan"), "error_signed": hw / mean if mean > 0 else float("nan"),
                     "error_what": f"95 % half-width / mean of |Omega_{comp}| ({BATCH_MEANS})",
                     "averaging_s": window, "simulated_s": spin + window, "samples": m,
                     "wall_s": wall * frac, "cpu_s": cpu * frac, "solver_s": work["solver_s"] * frac,
                     "steps": int(round(work["steps"] * frac)), "nodes": work["nodes"],
                     "node_updates": work["node_updates"] * frac, "particles": work["particles"],
                     "links": work["links"], "link_updates": work["link_updates"] * frac, "threads": work["threads"],
                     "dx_mm": float(summary["scene"]["numerics"]["dx_mm"]), "dt_s": float(summary["scene"]["numerics"]["dt_s"]),
                     "n_batches": iv["n_batches"], "batch_s": iv["batch_s"], "interval": iv["method"],
                     "status": "completed" if iv["sufficient"] else "insufficient",
                     "note": "cost pro-rated from the case's wall time to spin-up + window"
                             + ("" if iv["sufficient"] else f"; not recommendable: {iv['message']}")})
        k += 1
    if not rows:
        rows.append({**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": "completed",
                     "note": f"only {n} samples after spin-up: fewer than min_samples = {a['min_samples']}"})
    return rows
