"""What accuracy costs in time: the accuracy-cost study's results, from its runs' errors and costs.

The study's settings, references and runs are :mod:`lbmpipe.reproduction.study_plan`'s; each run's
error is read by :mod:`lbmpipe.reproduction.study_errors`. This module collects them with the
cost of every run (:func:`collect`; the cost model is fitted by
:func:`lbmpipe.reproduction.runcost.fit_cost_model` and evaluated by :func:`lbmpipe.cost.predict_work`),
finds each reference's Pareto front and the cheapest setting meeting its target
(:func:`recommend`), and writes the Markdown reports and figures (:func:`report`).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import ticker

from ..cost import scene_work
from ..outputs import write_json
from ..scene import Scene
from ..units import derive
from .cases import case_scene
from .plotting import plt, save
from .runcost import case_cost_rows, fit_cost_model, links_per_area, model_predict_work
from .study_errors import averaging_rows, observable_rows, rows_for_reference, run_record
from .study_plan import REFERENCES, plan, study_settings
# ----------------------------------------------------------------------------------------------
# Pareto front and recommendation


def pareto_front(cost, error) -> np.ndarray:
    """Boolean mask of the points no other point beats: none is at most as costly and at most as
    wrong while strictly better in one of the two. Points with a non-finite value are never on
    the front."""
    c = np.asarray(cost, dtype=float)
    e = np.asarray(error, dtype=float)
    ok = np.isfinite(c) & np.isfinite(e)
    front = np.zeros(c.size, dtype=bool)
    idx = np.flatnonzero(ok)
    for i in idx:
        dominated = (c[idx] <= c[i]) & (e[idx] <= e[i]) & ((c[idx] < c[i]) | (e[idx] < e[i]))
        front[i] = not dominated.any()
    return front


def _unique_points(df: pd.DataFrame) -> pd.DataFrame:
    """One row per run of a reference (a base run is listed under several knobs)."""
    return df.drop_duplicates(subset=["reference", "run"]).reset_index(drop=True)


def cheapest_within(df: pd.DataFrame, target: float, cost: str = "wall_s") -> dict | None:
    """The cheapest row with ``error <= target`` (completed and, where measured, steady);
    ``None`` if no row qualifies."""
    ok = df[np.isfinite(df["error"].astype(float)) & (df["error"].astype(float) <= target)
            & (df.get("status", "completed") == "completed")]
    if "note" in ok:
        ok = ok[~ok["note"].fillna("").str.contains("not steady")]
    ok = ok[np.isfinite(ok[cost].astype(float))]
    if ok.empty:
        return None
    return ok.loc[ok[cost].astype(float).idxmin()].to_dict()


def _jsonable(v):
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return v


_KEEP = ("knob", "setting", "run", "dx_mm", "dt_factor", "dt_s", "collision", "wall", "precision", "tau", "mach",
         "error", "error_signed", "error_spread", "wall_s", "cpu_s", "solver_s", "steps", "nodes", "averaging_s", "simulated_s",
         "n_batches", "batch_s", "interval")


def recommend(df: pd.DataFrame, targets: dict, cost: str = "cpu_s", model: dict | None = None,
              case_scene=None, case_threads: int | None = None) -> dict:
    """The cheapest measured setting meeting each reference's target, the Pareto front of each
    reference, and a joint numerics setting (same dx, dt, collision, precision) meeting both the
    pipe and the drag targets, with its predicted wall time on ``case_scene`` (a Scene) when a
    cost ``model`` is given."""
    out: dict = {"targets": dict(targets), "cost": cost, "references": {}}
    for ref in REFERENCES:
        sub = _unique_points(df[df["reference"] == ref])
        entry: dict = {"target": targets.get(ref), "points": int(len(sub)),
                       "measured": int(np.isfinite(sub["error"].astype(float)).sum()) if len(sub) else 0}
        if len(sub):
            front = pareto_front(sub[cost], sub["error"])
            entry["pareto_front"] = [
                {k: sub.loc[i, k] for k in _KEEP if k in sub} for i in np.flatnonzero(front)]
            entry["pareto_front"].sort(key=lambda r: r[cost])
        target = targets.get(ref)
        best = cheapest_within(sub, target, cost) if (len(sub) and target is not None) else None
        if best is not None:
            entry["recommended"] = {k: best[k] for k in _KEEP if k in best}
            entry["verdict"] = "met"
        else:
            entry["verdict"] = "not met" if entry["measured"] else "not measurable"
            fin = sub[np.isfinite(sub["error"].astype(float))] if len(sub) else sub
            # an error whose interval rests on too few batches is no measurement of accuracy
            valid = fin[fin["status"].astype(str) != "insufficient"] if "status" in fin else fin
            if len(valid):
                most = valid.loc[valid["error"].astype(float).idxmin()]
                entry["most_accurate"] = {k: most[k] for k in _KEEP if k in most}
            elif len(fin):
                longest = fin.loc[fin[cost].astype(float).idxmax()]
                entry["no_valid_interval"] = {k: longest[k] for k in _KEEP if k in longest}
        out["references"][ref] = entry
    out["joint"] = _joint(df, targets, cost, model, case_scene, case_threads)
    return _jsonable(out)


def _joint(df, targets, cost, model, case_scene, case_threads=None) -> dict:
    keys = ["dx_mm", "dt_factor", "collision", "precision"]
    pipe = _unique_points(df[df["reference"] == "pipe"])
    drag = _unique_points(df[df["reference"] == "drag"])
    if pipe.empty or drag.empty:
        return {"verdict": "not measurable", "reason": "pipe or drag reference has no runs"}
    t_p, t_d = targets.get("pipe"), targets.get("drag")
    good_p = pipe[(pipe["error"].astype(float) <= t_p) & (pipe["status"] == "completed")]
    good_d = drag[(drag["error"].astype(float) <= t_d) & (drag["status"] == "completed")]
    both = good_p.merge(good_d, on=keys, suffixes=("_pipe", "_drag"))
    if both.empty:
        return {"verdict": "not met", "reason": (f"no tested setting of {', '.join(keys)} meets both the pipe "
                                                  f"({t_p:g}) and the drag ({t_d:g}) target")}
    both = both.assign(total=both[f"{cost}_pipe"] + both[f"{cost}_drag"])
    best = both.loc[both["total"].idxmin()]
    rec = {"verdict": "met", **{k: best[k] for k in keys}, "wall": best["wall_pipe"],
           "pipe_error": best["error_pipe"], "drag_error": best["error_drag"],
           "pipe_run": best["run_pipe"], "drag_run": best["run_drag"]}
    if model is not None and case_scene is not None:
        data = case_scene.model_dump(mode="json") if hasattr(case_scene, "model_dump") else copy.deepcopy(case_scene)
        dt_per_mm = float(best["dt_s_pipe"]) / float(best["dx_mm"])
        data["numerics"].update({"dx_mm": float(best["dx_mm"]), "dt_s": dt_per_mm * float(best["dx_mm"]),
                                 "collision": best["collision"], "wall": best["wall_pipe"],
                                 "precision": best["precision"], "mach_limit": 1.0})
        for g in (data.get("particles") or {}).get("packed", []):
            g.pop("file", None)
        if case_threads:
            data.setdefault("run", {})["threads"] = int(case_threads)
        try:
            sc = Scene.model_validate(data)
            steps, nodes, links, count, threads = scene_work(sc, derive(sc), model)
            # the study's model is fitted on the work summed over the steps: evaluated on those sums
            rec["predicted_case_seconds"] = float(model_predict_work(model, float(nodes) * steps, links * steps,
                                                                     count * steps, threads))
            rec["predicted_case"] = sc.name
            rec["predicted_case_threads"] = sc.run.threads
        except Exception as exc:  # a recommendation is still useful without the prediction
            rec["predicted_case_error"] = str(exc)
    return rec


# ----------------------------------------------------------------------------------------------
# Collect, report


def collect(config: dict, fidelity: str, root: Path = Path("results")) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Read every study run, the case runs and the other fidelity levels; returns
    (accuracy-cost table, per-run cost table with the model's prediction, cost model)."""
    s = study_settings(config, fidelity)
    runs = plan(config, fidelity)
    sdir = Path(root) / fidelity / "study"
    recs = []
    for rid, spec in sorted(runs.items()):
        rdir = sdir / "runs" / rid
        if not (rdir / "summary.json").exists():
            continue
        recs.append(run_record(rid, spec, rdir, sdir / "benchmarks" / f"{rid}.tsv", s))
    rec_df = pd.DataFrame(recs)
    rows: list[dict] = []
    if len(rec_df):
        for ref in ("pipe", "drag"):
            rows += rows_for_reference(rec_df[rec_df["reference"] == ref], s, ref)
    rows += observable_rows(config, fidelity, root)
    rows += averaging_rows(config, fidelity, root)
    table = pd.DataFrame(rows)
    first = ["reference", "knob", "setting", "error", "wall_s", "cpu_s", "steps", "nodes", "is_base", "run", "dx_mm",
             "dt_factor", "dt_s", "collision", "wall", "precision", "tau", "mach", "error_signed", "error_spread",
             "value", "reference_value", "error_what", "solver_s", "setup_s", "node_updates", "particles", "links",
             "link_updates", "threads", "simulated_s", "steady_rel_change", "status", "note"]
    table = table[[c for c in first if c in table] + [c for c in table if c not in first]]

    cost_rows = []
    for r in recs:
        cost_rows.append({"source": "study", "run": r["run"], **{k: r[k] for k in (
            "steps", "nodes", "node_updates", "particles", "links", "link_updates", "particle_steps", "threads",
            "solver_s", "setup_s", "simulated_s", "wall_s", "cpu_s")},
            "links_per_area_lu": links_per_area({"particles": {"links": r["links"]},
                                                 "scene": {"numerics": {"dx_mm": r["dx_mm"]}}},
                                                scene_data=runs[r["run"]]["scene"]) if r["links"] else np.nan})
    cost_rows += case_cost_rows(config, fidelity, root)
    cost_df = pd.DataFrame(cost_rows)
    model = fit_cost_model(cost_df, target=s["cost"]) if len(cost_df) else {"n_runs": 0, "note": "no runs"}
    lpa = cost_df["links_per_area_lu"].astype(float) if "links_per_area_lu" in cost_df else pd.Series(dtype=float)
    if lpa.notna().any():
        model["links_per_area_lu"] = float(lpa.median())
    model["threads"] = int(s["threads"])
    model["fidelity"] = fidelity
    model["sources"] = {k: int(v) for k, v in cost_df["source"].value_counts().items()} if len(cost_df) else {}
    if len(cost_df) and "intercept_s" in model:
        cost_df["predicted_s"] = model_predict_work(model, cost_df["node_updates"], cost_df["link_updates"],
                                                    cost_df["particle_steps"], cost_df["threads"], wall=False)
    return table, cost_df, model


def markdown_table(table: pd.DataFrame) -> str:
    """The accuracy-cost table as Markdown, one section per reference."""
    lines = []
    titles = {"pipe": "Pipe Poiseuille (analytic), Re 9.4", "drag": "Sphere drag in a simple cubic array (Zick & Homsy)",
              "omega": "Mean |Omega| of a particle case towards the finest level",
              "averaging": "Averaging time: 95 % half-width of mean |Omega_x|"}

    def f(v, spec):
        try:
            return "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)
        except (TypeError, ValueError):
            return str(v)

    for ref in REFERENCES:
        sub = table[table["reference"] == ref]
        if sub.empty:
            continue
        lines += [f"### {titles[ref]}", ""]
        what = sub["error_what"].dropna().unique() if "error_what" in sub else []
        if len(what):
            lines += [f"error: {what[0]}", ""]
        lines += ["| knob | setting | error | wall s | CPU s | solver s | steps | nodes | tau | Mach | note |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for _, r in sub.iterrows():
            base = " (base)" if r.get("is_base") is True and ref in ("pipe", "drag") else ""
            lines.append(f"| {r['knob']} | {r['setting']}{base} | {f(r.get('error'), '.3g')} | {f(r.get('wall_s'), '.3g')} | "
                         f"{f(r.get('cpu_s'), '.3g')} | {f(r.get('solver_s'), '.3g')} | {f(r.get('steps'), '.0f')} | {f(r.get('nodes'), '.0f')} | "
                         f"{f(r.get('tau'), '.3f')} | {f(r.get('mach'), '.3f')} | {r.get('note') if isinstance(r.get('note'), str) else ''} |")
        lines.append("")
    return "\n".join(lines)


def recommendation_markdown(rec: dict, model: dict | None = None) -> str:
    """``recommendation.md``: the targets, the cheapest setting meeting each, the joint setting."""
    out = ["# Accuracy against cost: recommendation", "",
           f"Computed by `lbmpipe.reproduction.study.recommend` from `accuracy_cost.csv`; cost = `{rec['cost']}` "
           + ("(CPU seconds of each run's process, start-up included; for the case runs the benchmark's sampled "
              "CPU time)" if rec["cost"] == "cpu_s" else "(wall seconds of the Snakemake benchmark, start-up included)")
           + ".", ""]
    names = {"pipe": "pipe profile error", "drag": "sphere drag error", "omega": "mean |Omega| vs finest level",
             "averaging": "relative 95 % half-width of mean |Omega_x|"}
    for ref, e in rec["references"].items():
        t = e.get("target")
        head = f"- **{names[ref]}** (target {t:g}): " if t is not None else f"- **{names[ref]}**: "
        if e.get("verdict") == "met":
            r = e["recommended"]
            desc = _describe(ref, r)
            rests = (f" (the interval rests on {r['n_batches']} batches of {r['batch_s']:.3g} s, {r['interval']})"
                     if r.get("n_batches") else "")
            out.append(head + f"cheapest meeting it: {desc}, error {r['error']:.3g}, "
                              f"{r.get(rec['cost'], float('nan')):.3g} s{rests}.")
        elif e.get("verdict") == "not met" and "no_valid_interval" in e:
            r = e["no_valid_interval"]
            out.append(head + "not met: no tested setting has an interval that rests on 20 batches of 5 correlation "
                              f"times; the longest, {_describe(ref, r)}, has {r.get('n_batches', 0):g} batch(es) of "
                              f"{r.get('batch_s', float('nan')):.3g} s ({r.get('interval', '')}).")
        elif e.get("verdict") == "not met":
            r = e.get("most_accurate", {})
            out.append(head + f"not met by any tested setting; the most accurate was {_describe(ref, r)} "
                              f"(error {r.get('error', float('nan')):.3g}, {r.get(rec['cost'], float('nan')):.3g} s).")
        else:
            out.append(head + "not measurable with the results present.")
    j = rec.get("joint", {})
    out.append("")
    if j.get("verdict") == "met":
        line = (f"**Joint setting** meeting the pipe and drag targets at the least cost: dx = {j['dx_mm']:g} mm, "
                f"dt = {j['dt_factor']:g} x the paper's dt per mm, {j['collision']}, wall {j['wall']}, {j['precision']} "
                f"(pipe error {j['pipe_error']:.3g}, drag error {j['drag_error']:.3g}).")
        if j.get("predicted_case_seconds") is not None:
            what = "CPU time" if (model or {}).get("target") == "cpu_s" else "wall time"
            line += (f" Predicted {what} of case `{j['predicted_case']}` with it on {j.get('predicted_case_threads')} "
                     f"thread(s): {j['predicted_case_seconds']:.3g} s (the study's cost model below; a production "
                     f"run's wall time: the level's `tables/cost_model.json`).")
        out.append(line)
    else:
        out.append(f"**Joint setting**: {j.get('verdict')}: {j.get('reason', '')}")
    if model:
        out += ["", f"Cost model ({model.get('n_runs')} runs, relative rms error {model.get('rel_rms_error', float('nan')):.2g}): "
                    f"{model.get('formula')}, intercept {model.get('intercept_s', 0):.3g} s, "
                    f"{model.get('s_per_node_update', 0):.3g} s/node update, {model.get('s_per_link_update', 0):.3g} s/link update, "
                    f"{model.get('s_per_particle_step', 0):.3g} s/particle step."]
    return "\n".join(out) + "\n"


def _describe(ref: str, r: dict) -> str:
    if not r:
        return "(none)"
    if ref in ("pipe", "drag"):
        wall = f", wall {r.get('wall')}" if ref == "pipe" else ""
        return (f"dx = {r.get('dx_mm', float('nan')):g} mm, dt = {r.get('dt_factor', float('nan')):g} x paper "
                f"({r.get('dt_s', float('nan')):.3g} s), {r.get('collision')}{wall}, {r.get('precision')} [{r.get('knob')}]")
    if ref == "averaging":
        return f"averaging {r.get('averaging_s', float('nan')):.3g} s after spin-up"
    return f"level {r.get('setting')} (dx = {r.get('dx_mm', float('nan')):g} mm)"


def _log_axes(ax) -> None:
    """Log axes labelled at 1, 2, 5 x 10^k in plain numbers: the study's ranges are often
    narrower than a decade, where matplotlib would print overlapping minor labels."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        axis.set_minor_formatter(ticker.NullFormatter())


_KNOB_STYLE = {"dx": ("C0", "o"), "dt": ("C1", "s"), "wall": ("C2", "^"), "collision": ("C3", "D"),
               "precision": ("C4", "v"), "fidelity": ("C5", "o"), "averaging time": ("C6", "o")}


def plot_accuracy_cost(table: pd.DataFrame, rec: dict, stem: Path, title: str = "") -> list[Path]:
    """Log-log error against wall time, one panel per reference; knobs by colour, the base
    setting as a black star, the Pareto front as a line, the target dashed, the recommendation
    circled."""
    cost = rec.get("cost", "wall_s")
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    titles = {"pipe": "pipe Poiseuille profile (L2)", "drag": "sphere-array drag K",
              "omega": "mean |Omega| vs finest level", "averaging": "95 % half-width of mean |Omega_x|"}
    for ax, ref in zip(axes.ravel(), REFERENCES):
        sub = table[table["reference"] == ref]
        ax.set_title(titles[ref], fontsize=9)
        what = {"wall_s": "wall time (s, benchmark)", "cpu_s": "CPU time (s)"}.get(cost, cost)
        ax.set_xlabel(what if ref != "averaging" else f"{what}, pro-rated from the case run")
        ax.set_ylabel("relative error")
        pts = sub[np.isfinite(sub["error"].astype(float)) & (sub["error"].astype(float) > 0)] if len(sub) else sub
        pts = pts[np.isfinite(pts[cost].astype(float))] if len(pts) else pts
        if pts.empty:
            note = "; ".join(str(n) for n in sub.get("note", pd.Series(dtype=str)).dropna().unique()) if len(sub) else ""
            ax.text(0.5, 0.5, "no measurable points\n" + note, ha="center", va="center", fontsize=8,
                    transform=ax.transAxes, wrap=True)
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        seen = set()
        k = 0
        for _, r in pts.iterrows():
            knob = r["knob"]
            if knob not in _KNOB_STYLE:
                _KNOB_STYLE[knob] = (f"C{7 + k % 3}", "P")
                k += 1
            color, marker = _KNOB_STYLE[knob]
            if r.get("is_base") is True and ref in ("pipe", "drag"):
                color, marker, label = "k", "*", "base"
            else:
                label = knob
            ax.plot(r[cost], r["error"], marker=marker, color=color, ls="none", ms=7 if marker == "*" else 5,
                    label=None if label in seen else label)
            seen.add(label)
            if ref in ("pipe", "drag") and not r.get("is_base"):
                ax.annotate(str(r["setting"]).replace(" x paper", ""), (r[cost], r["error"]), fontsize=5,
                            xytext=(3, 2), textcoords="offset points")
            elif ref in ("omega", "averaging"):
                ax.annotate(str(r["setting"]), (r[cost], r["error"]), fontsize=6, xytext=(3, 2), textcoords="offset points")
        u = _unique_points(pts)
        front = pareto_front(u[cost], u["error"])
        fr = u[front].sort_values(cost)
        ax.step(fr[cost], fr["error"], where="post", color="0.4", lw=1.0, zorder=0, label="Pareto front")
        ent = rec["references"].get(ref, {})
        if ent.get("target") is not None:
            ax.axhline(ent["target"], color="0.5", ls="--", lw=0.8, label=f"target {ent['target']:g}")
        if ent.get("verdict") == "met":
            rr = ent["recommended"]
            ax.plot(rr[cost], rr["error"], "o", mfc="none", mec="r", ms=13, mew=1.5, label="recommended")
        _log_axes(ax)
        ax.legend(fontsize=6, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, stem)


def plot_cost_model(cost_df: pd.DataFrame, model: dict, stem: Path, title: str = "") -> list[Path]:
    """Predicted against measured time (the quantity the model was fitted on) of every run the
    cost model was fitted on."""
    target = model.get("target", "wall_s")
    what = {"wall_s": "wall time", "cpu_s": "CPU time"}.get(target, target)
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    d = cost_df[np.isfinite(cost_df[target].astype(float))] if (len(cost_df) and target in cost_df) else cost_df.iloc[0:0]
    if len(d) and "predicted_s" in d:
        for src, marker in (("study", "o"), ("case", "s")):
            s = d[d["source"] == src]
            if len(s):
                ax.plot(s[target], s["predicted_s"], marker, ls="none", ms=4, label=f"{src} runs ({len(s)})")
        lo = float(np.nanmin([d[target].min(), d["predicted_s"].min()])) * 0.8
        hi = float(np.nanmax([d[target].max(), d["predicted_s"].max()])) * 1.25
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="predicted = measured")
        _log_axes(ax)
        ax.legend(fontsize=7, frameon=False)
    ax.set_xlabel(f"measured {what} (s, Snakemake benchmark)")
    ax.set_ylabel(f"predicted {what} (s)")
    ax.set_title((title + "\n" if title else "") + f"relative rms error {model.get('rel_rms_error', float('nan')):.2g}",
                 fontsize=8)
    fig.tight_layout()
    return save(fig, stem)


def report(config: dict, fidelity: str, table: pd.DataFrame, cost_df: pd.DataFrame, model: dict,
           out_dir: Path) -> dict:
    """Write the figures, ``accuracy_cost.md``, ``recommendation.json`` and ``.md`` into
    ``out_dir``; returns the recommendation."""
    s = study_settings(config, fidelity)
    out_dir = Path(out_dir)
    table = table.copy()
    if "is_base" in table:  # a CSV round trip turns the column into strings or objects
        table["is_base"] = table["is_base"].map(lambda v: str(v) == "True")
    case = s["observable"]["case"]
    scene = None
    if case in config.get("cases", {}):
        fid = config["fidelities"][fidelity]
        scene = case_scene(case, config["cases"][case], fidelity, fid)
    rec = recommend(table, s["targets"], cost=s["cost"], model=model, case_scene=scene,
                    case_threads=int(config["fidelities"][fidelity].get("threads", 1)))
    rec["fidelity"] = fidelity
    write_json(out_dir / "recommendation.json", rec)
    (out_dir / "recommendation.md").write_text(recommendation_markdown(rec, model))
    (out_dir / "accuracy_cost.md").write_text(f"# Accuracy against cost ({fidelity})\n\n" + markdown_table(table))
    plot_accuracy_cost(table, rec, out_dir / "accuracy_cost", title=f"accuracy against cost, fidelity {fidelity}")
    plot_cost_model(cost_df, model, out_dir / "cost_model", title=f"cost model, fidelity {fidelity}")
    return rec
