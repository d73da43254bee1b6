"""Wall-time cost model of a level's production runs, validated on runs it was not fitted to.

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

from ..outputs import write_json
from .study import D3Q15_LINKS_PER_AREA, links_per_area, read_benchmark, scene_particle_load

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
            # boundary links per unit particle area: how predict_scene estimates a new scene's links
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


def predict(model: dict, steps, nodes, links=0.0, particles=0.0, threads=1, share=1.0):
    """Wall seconds of runs (scalars or arrays) under ``model``, each getting ``share`` of a
    core per thread (1: a core of its own)."""
    t = np.maximum(np.asarray(threads, dtype=float), 1.0)
    per_step = (model["s_per_node_update"] * np.asarray(nodes, float) + model["s_per_link_update"] * np.asarray(links, float)
                + model["s_per_particle_step"] * np.asarray(particles, float) + model["s_per_step"])
    return (model["intercept_s"] + np.asarray(steps, float) * per_step / t) / np.asarray(share, float)


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
        out.loc[held, "predicted_s"] = predict(*args, share=share[held])
        out.loc[held, "predicted_median_share_s"] = predict(*args, share=m["median_cpu_share"])
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


def for_host(model: dict, host: str | None) -> tuple[dict, bool]:
    """The coefficients that predict a run on processor ``host``: its own (``model["hosts"]``)
    if the model has validated them (runs of two families or more), else the fit to all runs.
    Returns (model, own)."""
    own = (model.get("hosts") or {}).get(host) if host else None
    return ({**model, **own}, True) if own else (model, False)


def predict_scene(model: dict, scene, params, share: float = 1.0) -> float:
    """Predicted wall seconds of a validated ``Scene`` with lattice parameters ``params``, with
    ``share`` of a core per thread (``model``: a level's model, or one processor's from
    :func:`for_host`): the particles' links estimated from their surface area
    (``links_per_area_lu`` of the model), their count as the packer or random placement would
    make it."""
    count, area_mm2 = scene_particle_load(scene)
    lpa = model.get("links_per_area_lu")
    lpa = float(lpa) if lpa is not None and math.isfinite(float(lpa)) else D3Q15_LINKS_PER_AREA
    links = lpa * area_mm2 / scene.numerics.dx_mm**2
    threads = scene.run.threads or 1
    return float(predict(model, params.n_steps, params.fluid_nodes, links, count, threads, share))
