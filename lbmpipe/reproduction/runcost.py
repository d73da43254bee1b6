"""The cost model's coefficients, fitted and validated in one place; :func:`lbmpipe.cost.predict`
evaluates them for a scene (its formula is in :mod:`lbmpipe.cost`).

Two fits, to two sets of runs: :func:`build` fits a level's production runs and validates them on
runs it was not fitted to (``tables/cost_model.json``, below); :func:`fit_cost_model` fits the
accuracy-cost study's runs and the case runs present (``study/cost_model.json``, non-negative
least squares on relative residuals; no share of a core, no ``s_per_step``). :func:`read_benchmark`,
:func:`run_work` and :func:`links_per_area` read a run's time and work for both.

Wall-time cost model of a level's production runs, validated on runs it was not fitted to.

Every run times each effect of its step (``summary.json`` ``effects``). The model charges each
group of effects to the work it scales with, so that every coefficient is measured on its own
and none is a free parameter traded against another:

====================  =========================================================  ==========================
group                 effects                                                    work per step
====================  =========================================================  ==========================
fluid                 stream+collide, wall, flow-rate control                    fluid nodes
particles             coupling, motion + remap, flux and mass corrections        particle boundary links
collisions            impulses + overlap removal                                 particles
rest of the loop      sampling, reporting, checkpoints                           1
set-up and output     process wall time outside the time loop                    (once per run)
====================  =========================================================  ==========================

``wall_s = (intercept_s + steps (s_per_node_update nodes + s_per_link_update links
+ s_per_particle_step particles + s_per_step) / threads) / share``: the work in seconds of a core
of one's own, over the share of a core the run gets. The host's other jobs set that share, not the
scene: each run's benchmark measures it (``cpu_share``: CPU over wall seconds), and the group
timings, wall seconds inside the process, are turned into a core's own seconds by it. Each
coefficient is the median over the fitted runs of the group's core seconds over its work (a ratio:
long and short runs count alike). The measured wall time of a run is its Snakemake benchmark's wall
seconds, or, for a run resumed from a checkpoint (the benchmark saw only its last part), the loop's
accumulated seconds plus set-up, with the median share. The production runs are single-threaded;
dividing by ``threads`` assumes ideal scaling and is not validated here (``benchmarks/fluid.py``
measures the thread scaling).

Runs are kept apart by processor (``summary.json`` ``host.cpu``, the processor the kernels were
compiled for): the vectorised fluid step costs a processor-dependent time per node that no share
of a core accounts for. A run of a recorded processor is validated against the other families'
runs of that processor where there are any, and a processor whose runs cover two families or more
keeps coefficients of its own (``hosts``). Runs that record no processor (made before the field
existed) form the group ``unrecorded``, validated against the group's other families: they come
from the machines used before the record, and a fit dominated by a recorded processor would
predict one machine from another. A group whose runs are all of one family is validated against
every other family's runs. The top-level coefficients are fitted to all runs: what a processor
without coefficients of its own is predicted from; the unrecorded group keeps none of its own.

Validation is leave-one-family-out: a family is a case with its Reynolds numbers and seeds
(``cyl8x16_c30`` holds ``cyl8x16_c30_re9.4/seed1`` ... ``cyl8x16_c30_re26/seed3``), so a run is
never predicted by a model fitted to another seed or the other Reynolds number of its own
packing. The model's error is the median absolute relative error of those predictions of the
wall time, given each run's measured share (the model of the work) and at the fitted runs' median
share (what a user who does not know the host's load can expect).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..cost import D3Q15_LINKS_PER_AREA, particle_area_volume, predict_work
from ..outputs import write_json

#: effect-name prefixes of each group of the step (``solver`` names its effects this way)
GROUPS = {"fluid": ("stream+collide", "wall", "flow-rate"), "particles": ("particles",), "collisions": ("collisions",)}
#: the work each group is charged to, and the model's coefficient for it
WORK = {"fluid": ("nodes", "s_per_node_update"), "particles": ("links", "s_per_link_update"),
        "collisions": ("particles", "s_per_particle_step")}
#: the processor group of a run that records none
UNRECORDED = "unrecorded"
COLUMNS = ["run", "family", "host", "steps", "threads", "nodes", "links", "particles", "wall_s", "loop_s", "fluid_s",
           "particles_s", "collisions_s", "rest_s", "overhead_s", "resumed", "cpu_share", "links_per_area_lu"]


def family(run: str) -> str:
    """The case family of a run: its case without the Reynolds number and seed
    (``cyl8x16_c30_re9.4_nocoll/seed2`` -> ``cyl8x16_c30_nocoll``; ``flow_re26`` -> ``flow``)."""
    case = run.split("/")[0]
    return re.sub(r"_re[0-9.]+", "", case)


def run_row(run: str, summary: dict, bench_s: float = float("nan")) -> dict | None:
    """Work and measured seconds of one completed run, by group; None if the run did not
    complete or did not time its effects."""
    if summary.get("status") != "completed" or not summary.get("steps") or not summary.get("effects"):
        return None
    eff = summary["effects"]
    groups = {g: sum(float(v) for k, v in eff.items() if k.startswith(pre)) for g, pre in GROUPS.items()}
    loop = float(summary.get("wall_seconds") or 0.0)
    setup = float(summary.get("setup_seconds") or 0.0)
    part = summary.get("particles") or {}
    resumed = not (math.isfinite(bench_s) and bench_s >= loop)
    wall = loop + setup if resumed else float(bench_s)
    rec = summary.get("host")
    cpu = rec.get("cpu") if isinstance(rec, dict) else None
    return {"run": run, "family": family(run), "host": str(cpu) if cpu else UNRECORDED, "steps": int(summary["steps"]),
            "threads": int(summary.get("threads") or 1), "nodes": int(summary.get("fluid_nodes") or 0),
            "links": int(part.get("links") or 0), "particles": int(part.get("count") or 0),
            "wall_s": wall, "loop_s": loop, **{f"{g}_s": v for g, v in groups.items()},
            "rest_s": max(loop - sum(groups.values()), 0.0), "overhead_s": max(wall - loop, 0.0),
            "resumed": bool(resumed), "cpu_share": float("nan"), "links_per_area_lu": float("nan")}


def level_rows(level_dir: Path, runs: list[str]) -> pd.DataFrame:
    """One row per completed run of ``runs`` under ``results/<level>`` (``cases/<run>/summary.json``
    and ``benchmarks/<run>.simulate.tsv``)."""
    rows = []
    for run in runs:
        path = Path(level_dir) / "cases" / run / "summary.json"
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        bench = read_benchmark(Path(level_dir) / "benchmarks" / f"{run}.simulate.tsv")
        wall, cpu = bench["s"], bench["cpu_time"]
        row = run_row(run, summary, wall)
        if row is not None:
            # boundary links per unit particle area: how lbmpipe.cost.predict estimates a new scene's links
            row["links_per_area_lu"] = (links_per_area(summary, path.parent / "particles_static.csv")
                                        if row["links"] > 0 else float("nan"))
            # the share of a core per thread the run got (other runs and jobs on the host take the
            # rest): what the wall time depends on beyond the work
            row["cpu_share"] = cpu / (wall * row["threads"]) if not row["resumed"] and wall > 0 else float("nan")
            rows.append(row)
    return pd.DataFrame(rows, columns=COLUMNS)


def _shares(rows: pd.DataFrame) -> pd.Series:
    """Each run's share of a core; the median of the others where unmeasured (a resumed run)."""
    sh = rows["cpu_share"].astype(float).clip(upper=1.0)
    med = sh.median()
    return sh.fillna(med if math.isfinite(med) else 1.0)


def fit(rows: pd.DataFrame) -> dict:
    """The model's coefficients from ``rows`` (:func:`level_rows`): per group, the median of
    core seconds (wall x share) x threads / (work x steps) over the runs that have that work."""
    model = {"formula": "wall_s = (intercept_s + steps * (s_per_node_update * fluid_nodes + s_per_link_update * links"
                        " + s_per_particle_step * particles + s_per_step) / threads) / cpu_share",
             "n_runs": int(len(rows)), "intercept_s": 0.0, "s_per_step": 0.0,
             **{coef: 0.0 for _, coef in WORK.values()}}
    if not len(rows):
        return model
    share = _shares(rows)
    thr = rows["threads"].clip(lower=1).astype(float)
    steps = rows["steps"].astype(float)
    for g, (work, coef) in WORK.items():
        has = rows[work] > 0
        if has.any():
            core_s = rows.loc[has, f"{g}_s"] * share[has] * thr[has]
            model[coef] = float(np.median(core_s / (rows.loc[has, work] * steps[has])))
    model["s_per_step"] = float(np.median(rows["rest_s"] * share * thr / steps))
    fresh = ~rows["resumed"].astype(bool)
    model["intercept_s"] = float(np.median((rows["overhead_s"] * share)[fresh])) if fresh.any() else 0.0
    model["median_cpu_share"] = float(share.median())
    return model


def _training(rows: pd.DataFrame, fam: str, host: str) -> tuple[pd.DataFrame, str]:
    """The runs that predict family ``fam``'s runs on processor ``host``: the other families' runs
    of that processor (or of the unrecorded group) if there are any, else every other family's
    runs ("all")."""
    other = rows["family"] != fam
    same = other & (rows["host"] == host)
    if same.any():
        return rows[same], host
    return rows[other], "all"


def validate(rows: pd.DataFrame) -> pd.DataFrame:
    """Leave-one-family-out predictions: each run predicted by the model fitted to the other
    families' runs (of its own processor where it records one that has others, ``fitted_host``),
    at the run's measured share (``predicted_s``, ``rel_error`` = predicted / measured - 1) and at
    those runs' median share (``predicted_median_share_s``, ``rel_error_median_share``);
    ``fitted_on``: runs in that fit. NaN where no other family exists."""
    out = rows.copy()
    share = _shares(rows)
    for c in ("predicted_s", "rel_error", "predicted_median_share_s", "rel_error_median_share"):
        out[c] = np.nan
    out["fitted_on"] = 0
    out["fitted_host"] = ""
    for (fam, host), held_rows in rows.groupby(["family", "host"], sort=False):
        held = rows.index.isin(held_rows.index)
        train, fitted_host = _training(rows, fam, host)
        if not len(train):
            continue
        m = fit(train)
        args = (m, rows.loc[held, "steps"], rows.loc[held, "nodes"], rows.loc[held, "links"], rows.loc[held, "particles"],
                rows.loc[held, "threads"])
        out.loc[held, "predicted_s"] = predict_work(*args, share=share[held])
        out.loc[held, "predicted_median_share_s"] = predict_work(*args, share=m["median_cpu_share"])
        out.loc[held, "fitted_on"] = len(train)
        out.loc[held, "fitted_host"] = fitted_host
    out["rel_error"] = out["predicted_s"] / rows["wall_s"] - 1.0
    out["rel_error_median_share"] = out["predicted_median_share_s"] / rows["wall_s"] - 1.0
    return out


def _errors(val: pd.DataFrame) -> dict:
    err = val["rel_error"].abs().dropna()
    err_med = val["rel_error_median_share"].abs().dropna()
    return {"n_validated": int(len(err)),
            "median_abs_rel_error": float(err.median()) if len(err) else float("nan"),
            "max_abs_rel_error": float(err.max()) if len(err) else float("nan"),
            "median_abs_rel_error_median_share": float(err_med.median()) if len(err_med) else float("nan"),
            "max_abs_rel_error_median_share": float(err_med.max()) if len(err_med) else float("nan")}


def build(level_dir: Path, runs: list[str], level: str) -> tuple[dict, pd.DataFrame]:
    """The level's model (fitted to all its completed runs) with its leave-one-family-out
    validation, and the per-run validation table."""
    rows = level_rows(level_dir, runs)
    model = fit(rows)
    val = validate(rows)
    model.update({
        "level": level, "target": "wall_s (Snakemake benchmark; loop + set-up for a resumed run)",
        "validation": "leave one case family out (both Reynolds numbers and every seed of a case held out together),"
                      " against the other families' runs of the same processor where the run records one",
        "families": int(rows["family"].nunique()) if len(rows) else 0,
        **_errors(val),
        "threads_measured": sorted(int(t) for t in rows["threads"].unique()) if len(rows) else [],
        # the median measured boundary links per particle surface area over the runs with particles
        "links_per_area_lu": float(rows["links_per_area_lu"].median()) if rows["links_per_area_lu"].notna().any()
        else float("nan"),
    })
    # each recorded processor's own coefficients, and the validation of its runs
    hosts = {}
    for host, hrows in rows.groupby("host", sort=True):
        if host == UNRECORDED or hrows["family"].nunique() < 2:
            continue  # a processor's own coefficients only where its runs validate them (two families)
        hm = fit(hrows)
        hm.pop("formula", None)
        hosts[host] = {**hm, "families": int(hrows["family"].nunique()), **_errors(val[val["host"] == host])}
    model["hosts"] = hosts
    model["runs_by_host"] = {str(h): int(n) for h, n in rows["host"].value_counts().sort_index().items()}
    return model, val


def write(level_dir: Path, runs: list[str], level: str, model_path: Path, table_path: Path) -> dict:
    """:func:`build` and write ``cost_model.json`` and ``cost_validation.csv``."""
    model, val = build(level_dir, runs, level)
    Path(model_path).parent.mkdir(parents=True, exist_ok=True)
    write_json(model_path, model)  # strict JSON: an error not measured is null
    val.to_csv(table_path, index=False, float_format="%.6g")
    return model


def read_benchmark(path: Path) -> dict:
    """Wall seconds ``s``, ``cpu_time`` and ``max_rss`` (MB) of a Snakemake benchmark file (the
    mean over its repeats); NaN when the file is missing."""
    try:
        df = pd.read_csv(path, sep="\t")
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return {"s": float("nan"), "cpu_time": float("nan"), "max_rss": float("nan")}
    out = {}
    for k in ("s", "cpu_time", "max_rss"):
        # snakemake writes "-" where it could not measure
        out[k] = float(pd.to_numeric(df[k], errors="coerce").mean()) if k in df else float("nan")
    return out


COST_FEATURES = ("node_updates", "link_updates", "particle_steps")


def fit_cost_model(df: pd.DataFrame, target: str = "cpu_s") -> dict:
    """Fit ``seconds = c0 + (a node_updates + b link_updates + c particle_steps) / threads`` with
    non-negative coefficients, minimising the relative (not absolute) residuals, so that short
    and long runs count alike. On ``target = "cpu_s"`` (CPU seconds summed over threads) the work
    terms are not divided by the threads; the model then predicts wall time as the CPU time
    spread ideally over the threads. A feature that is zero in every row is left out
    (coefficient 0, listed under ``not_identified``). Returns the model dict
    :func:`lbmpipe.cost.predict` evaluates."""
    from scipy.optimize import nnls

    d = df[np.isfinite(df[target].astype(float)) & (df[target].astype(float) > 0)].copy()
    for c in COST_FEATURES:
        d[c] = d[c].astype(float).fillna(0.0) if c in d else 0.0
    per_thread = target != "cpu_s"
    thr = d["threads"].astype(float).clip(lower=1) if ("threads" in d and per_thread) else pd.Series(1.0, index=d.index)
    y = d[target].to_numpy(float)
    used = [c for c in COST_FEATURES if (d[c] > 0).any()]
    cols = [np.ones(len(d))] + [(d[c] / thr).to_numpy(float) for c in used]
    X = np.stack(cols, axis=1)
    # the formula names what was fitted: CPU seconds of the study's runs are not a wall time (the
    # production runs' wall-time model is lbmpipe.reproduction.runcost)
    model = {"formula": f"{target} = intercept_s + (s_per_node_update * node_updates + s_per_link_update * link_updates"
                        " + s_per_particle_step * particle_steps)" + (" / threads" if per_thread else ""),
             "target": target, "work_per_thread_in_fit": per_thread, "n_runs": int(len(d)),
             "intercept_s": 0.0, "s_per_node_update": 0.0, "s_per_link_update": 0.0, "s_per_particle_step": 0.0,
             "links_per_area_lu": D3Q15_LINKS_PER_AREA,
             "not_identified": [c for c in COST_FEATURES if c not in used]}
    if len(d) < X.shape[1]:
        model["note"] = f"{len(d)} runs for {X.shape[1]} coefficients: not fitted"
        return model
    w = 1.0 / y
    scale = np.abs(X).max(axis=0)
    scale[scale == 0] = 1.0
    coef, _ = nnls((X / scale) * w[:, None], y * w)
    coef = coef / scale
    names = {"node_updates": "s_per_node_update", "link_updates": "s_per_link_update",
             "particle_steps": "s_per_particle_step"}
    model["intercept_s"] = float(coef[0])
    for c, v in zip(used, coef[1:]):
        model[names[c]] = float(v)
    pred = X @ coef
    rel = pred / y - 1.0
    model["rel_rms_error"] = float(np.sqrt(np.mean(rel**2)))
    model["max_rel_error"] = float(np.max(np.abs(rel)))
    if model["s_per_node_update"] > 0:
        model["mlups_equivalent"] = 1e-6 / model["s_per_node_update"]
    return model


def model_predict_work(model: dict, node_updates, link_updates=0.0, particle_steps=0.0, threads=1,
                       wall: bool = True):
    """The cost model on work counts (arrays or scalars): wall seconds, or with ``wall=False``
    the quantity the model was fitted on (CPU seconds for a ``cpu_s`` model)."""
    per_thread = wall or model.get("work_per_thread_in_fit", True)
    # the work is already summed over the steps: one step of it, through the one formula
    return predict_work(model, 1.0, node_updates, link_updates, particle_steps, threads if per_thread else 1.0)


def links_per_area(summary: dict, static_csv: Path | None = None, scene_data: dict | None = None) -> float:
    """Measured links per unit particle area (lattice units) of one run: ``particles.links`` of
    the summary over the particles' area from ``particles_static.csv`` (or the scene's bodies)."""
    links = float((summary.get("particles") or {}).get("links", 0) or 0)
    dx = float(((summary.get("scene") or {}).get("numerics") or {}).get("dx_mm", np.nan))
    area = 0.0
    if static_csv is not None and Path(static_csv).exists():
        st = pd.read_csv(static_csv)
        for _, r in st.iterrows():
            kw = {k: (None if pd.isna(r.get(k)) else float(r[k])) for k in ("diameter_mm", "length_mm", "edge_mm")}
            area += particle_area_volume(r["shape"], **kw)[0]
    elif scene_data is not None:
        for b in (scene_data.get("particles") or {}).get("bodies", []):
            area += particle_area_volume(b["shape"], b.get("diameter_mm"), b.get("length_mm"), b.get("edge_mm"))[0]
    if not (links > 0 and area > 0 and np.isfinite(dx)):
        return float("nan")
    return links / (area / dx**2)


def case_cost_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Work and wall time of the pipeline's case runs at ``fidelity`` that have a benchmark file
    and a completed summary (the cases are not inputs of the study: whatever exists is used)."""
    rows = []
    bdir = Path(root) / fidelity / "benchmarks"
    for bench in sorted(bdir.glob("*.simulate.tsv")) if bdir.exists() else []:
        case = bench.name.removesuffix(".simulate.tsv")
        summ = Path(root) / fidelity / "cases" / case / "summary.json"
        if not summ.exists():
            continue
        summary = json.loads(summ.read_text())
        if summary.get("status") != "completed":
            continue
        b = read_benchmark(bench)
        row = {"source": "case", "run": case, **run_work(summary), "wall_s": b["s"], "cpu_s": b["cpu_time"],
               "links_per_area_lu": links_per_area(summary, Path(root) / fidelity / "cases" / case / "particles_static.csv")}
        rows.append(row)
    return rows


def run_work(summary: dict) -> dict:
    steps = int(summary.get("steps", 0) or 0)
    nodes = int(summary.get("fluid_nodes", 0) or 0)
    part = summary.get("particles", {}) or {}
    links = int(part.get("links", 0) or 0)
    count = int(part.get("count", 0) or 0)
    return {"steps": steps, "nodes": nodes, "node_updates": float(nodes) * steps, "particles": count,
            "links": links, "link_updates": float(links) * steps, "particle_steps": float(count) * steps,
            "threads": int(summary.get("threads", 1) or 1), "solver_s": float(summary.get("wall_seconds", np.nan)),
            "setup_s": float(summary.get("setup_seconds", np.nan)),
            "simulated_s": float(summary.get("simulated_seconds", np.nan))}
