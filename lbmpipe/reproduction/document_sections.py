"""The sections of the reproduction document read from a level's results: the method and its
decisions, the parameters, the cases, the figures with their captions, the run time, what the
method changes, the convergence in dx, the run health, the stationarity and the accuracy-cost
study. Each returns data for the template (:mod:`lbmpipe.reproduction.literate` renders it); a
section whose input is absent says ``not built at this level: <file> missing``."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd

from ..scene import Scene, SceneError
from ..units import derive
from . import figures, health
from .cases import FLOWS, case_scene, level_runs, method_numerics, numerics_text
from .convergence import levels
from .equations import EQUATION_GROUPS, EQUATIONS, N_EQUATIONS, equation_index, equation_link, relative_href
from .health import _num, read_json  # _num: a null (an error not measured) as NaN
from .methods import comparison_level
from .runcost import UNRECORDED
from .steady import steady_corrected
from .unpackable import read_summary


#: The paper's figure captions, from its text (the OCR of the paper; Fig. 7 has no caption there).
PAPER_CAPTIONS: dict[str, str] = {
    "3": "Fig. 3 Pipe flow and coordinate system",
    "4": "Fig. 4 Effect of cylindrical particle aspect ratio on angular velocity about various axes "
         "(30% in particle concentration, 26 in Reynolds number)",
    "5": "Fig. 5 Effect of cubic particle concentration on angular velocity about various axes (9.4 in "
         "Reynolds number, 8 mm×8 mm in size, LC: 30% particle concentration; HC: 50% particle concentration)",
    "6": "Fig. 6 Effect of Reynolds number on angular velocity about various axes (30% in particle "
         "concentration, 24 mm×24 mm in size of cubic particles, LF: Re=9.4; HF: Re=26)",
    "7a": "Fig. 7a (no caption in the paper's text; the text: \"The effects of particles shape and size on "
          "angular velocity about various axes are plotted in Figs. 7a and 7b\")",
    "7b": "Fig. 7b (no caption in the paper's text; see Fig. 7a)",
    "8": "Fig. 8 Numerical results (a) and experimental results (b) of orientation distribution for "
         "cylindrical particles (30% in concentration, LF: Re=9.4; HF: Re=26)",
    "9": "Fig. 9 Numerical results (a) and experimental results (b) of orientation distribution for cubic "
         "particles (30% in particle concentration, LF: Re=9.4; HF: Re=26)",
    "10": "Fig. 10 Velocity profiles with and without cylindrical particles at the outlet of pipe (30% in "
          "concentration, 26 in Reynolds number, 16 mm×16 mm in size)",
}


#: Our caption when ``lbmpipe.reproduction.figures.FIGURE_CAPTIONS`` has none (paper/reading.md, section 3).
FALLBACK_CAPTIONS: dict[str, str] = {
    "3": "Snapshot of the particles in the pipe (case in the file name).",
    "4": "Mean |angular velocity| (rad/s) about x, y, z: cylinders 16x16 and 16x24 mm, 30 %, Re 26.",
    "5": "Mean |angular velocity| (rad/s) about x, y, z: 8 mm cubes, Re 9.4, 30 % (LC) and 50 % (HC).",
    "6": "Mean |angular velocity| (rad/s) about x, y, z: 24 mm cubes, 30 %, Re 9.4 (LF) and Re 26 (HF).",
    "7a": "Shape and size: cubes 8/16/24 mm and cylinders 8x8/16x16 mm, 30 %, Re 9.4 (our choice of cases).",
    "7b": "Shape and size: cubes 8/16/24 mm and cylinders 8x8/16x16 mm, 30 %, Re 26 (our choice of cases).",
    "8": "Distribution of the angle between the cylinder axis and the pipe axis, 30 %, Re 9.4 and Re 26.",
    "9": "Distribution of the cube orientation angle folded into 0-45 degrees, 30 %, Re 9.4 and Re 26.",
    "10": "Time-averaged axial velocity against radius, against the Hagen-Poiseuille parabola (dashed).",
}


#: The paper's statement of its computing cost ("It almost takes 24 h to make the statistical average
#: ... reach a relatively steady state"), per case.
PAPER_HOURS_PER_CASE = 24.0


#: Where the paper is silent or inconsistent and the code decides (paper/reading.md); ``{...}`` fields are
#: filled from the config so that no number is typed here.
DECISIONS: list[tuple[str, str]] = [
    ("Viscosity", "The two flow rates imply different viscosities; ν is taken from the Reynolds number "
                  r"($\mathrm{Re} = U D / \nu$, $U = Q / A$), not from a fluid property (paper/reading.md, D2)."),
    ("Driving", "Periodic inlet and outlet: the flow is driven by a body force (pressure gradient) that a "
                "controller adjusts to hold the mixture flow rate Q (`lbmpipe.fluid.effects`)."),
    ("Time step at Re 26", "The paper's dt gives a centre-line Mach number near the limit of the scheme "
                           "at Re 26; every level multiplies dt there by {re26_dt_factors} (config "
                           "`re26_dt_factor`); the parameter table shows the resulting τ and Mach."),
    ("Coarser levels", "Levels coarser than the paper's lattice keep the paper's Mach number (dt ∝ dx, "
                       "acoustic scaling); τ then follows from Re (`lbmpipe.reproduction.cases`)."),
    ("Angular-velocity statistic", "Not defined by the paper: the mean of |Ω_x|, |Ω_y|, |Ω_z| in the lab "
                                   "frame over particles and samples after spin-up, with a 95 % confidence "
                                   "interval from batch means."),
    ("Cube orientation", "The experiment saw 2-D projections: the projected angle folded into 0-45 degrees "
                         "is reported, and also the 3-D angle between the pipe axis and the nearest cube "
                         "axis (0-54.7 degrees)."),
    ("Fig. 7 cases", "The text does not say which cases Figs. 7a/7b show; we take 30 %, (a) Re 9.4, "
                     "(b) Re 26, cubes 8/16/24 mm and cylinders 8x8/16x16 mm."),
    ("Quaternion convention", "Any consistent convention is allowed (Eqs. (14)-(15)); ours is "
                              r"$\frac{dq}{dt} = \frac{1}{2}\, q \otimes (0, \boldsymbol{\Omega}_{\mathrm{body}})$, "
                              "body → lab, pinned by the tests."),
    ("Restitution", "Collisions are \"instantaneous and elastic\": k = 1, kept a parameter (Eq. (17))."),
    ("Unreachable concentrations", "A packing that cannot reach its target is reported as not packable "
                                   "with the concentration it reached; a different concentration is never "
                                   "run silently."),
    ("Films thinner than one spacing", "Where a particle nearly touches the wall or another particle, the "
                                       "fluid between them is a film of single nodes with one or two fluid "
                                       "links; the moving bounce-back (Eq. (8)) behind a receding surface "
                                       "drains it faster than those links refill it, and the densest Re 26 "
                                       "cases diverged. The sweep holds such nodes at the density "
                                       "`numerics.density_floor` (0.5) by adding mass at zero momentum; each "
                                       "summary and the stability table report the mass added "
                                       "(`lbmpipe.fluid.effects.StreamCollide`)."),
    ("Experimental data", "The values of Zitoun et al. are not in our text and are never invented; a figure "
                          "shows them only from a data file whose source is stated."),
]


def read_table(path: Path):
    """The CSV file at ``path`` as a DataFrame; None if it is missing or empty."""
    try:
        return pd.read_csv(path)
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return None


def fmt(x, digits: int = 3) -> str:
    """A number for the text: ``digits`` significant digits, integers as integers, NaN as an en dash."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(v):
        return "–"
    if math.isinf(v):
        return "∞" if v > 0 else "-∞"
    if v == int(v) and abs(v) < 1e6:
        return str(int(v))
    if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e6):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}" if abs(v) >= 10 ** (digits - 1) else f"{float(f'{v:.{digits}g}'):g}"


def _cell(v) -> str:
    return fmt(v).replace("|", "\\|").replace("\n", " ")


def table_of(df, columns: list[str] | None = None) -> dict:
    """A DataFrame as ``{"columns": [...], "rows": [[str, ...], ...]}`` for the template."""
    cols = [c for c in (columns or list(df.columns)) if c in df.columns]
    return {"columns": cols, "rows": [[_cell(v) for v in row] for row in df[cols].itertuples(index=False)]}


def method_section(repo_root: Path, out_dir: Path) -> tuple[list[dict], list[int]]:
    """Equation groups with each equation's statement and its source links; and the equations that
    no docstring cites (the document states them as missing)."""
    index = equation_index(Path(repo_root) / "lbmpipe")
    groups = []
    for title, numbers in EQUATION_GROUPS:
        eqs = []
        for n in numbers:
            refs = index.get(n, [])
            code = [r for r in refs if r.qualname != "<module>"] or refs
            links = [{"name": r.qualname if r.qualname != "<module>" else f"{r.module} (module)",
                      "link": equation_link(r, n, repo_root, out_dir)} for r in code]
            eqs.append({"number": n, "text": EQUATIONS[n], "links": links,
                        "refs_md": "; ".join(f"`{lk['name']}` {lk['link']}" for lk in links)})
        groups.append({"title": title, "equations": eqs})
    return groups, [n for n in range(1, N_EQUATIONS + 1) if n not in index]


def parameter_rows(config: dict) -> tuple[list[dict], list[str]]:
    """Derived lattice values of the particle-free pipe at each fidelity level and Reynolds number
    (``lbmpipe.reproduction.cases.case_scene`` -> ``Scene`` -> ``lbmpipe.units.derive``)."""
    rows, errors = [], []
    for fid_name, fid in (config.get("fidelities") or {}).items():
        for re_ in sorted(FLOWS):
            try:
                data = case_scene(f"flow_re{re_:g}", {"reynolds": re_}, fid_name, fid)
                scene = Scene.model_validate(data)
                p = derive(scene)
            except (SceneError, ValueError) as exc:
                errors.append(f"{fid_name}, Re {fmt(re_)}: {exc}")
                continue
            rows.append({
                "fidelity": fid_name, "reynolds": fmt(re_), "flow_rate": fmt(FLOWS[re_], 4),
                "dx_mm": fmt(scene.numerics.dx_mm), "dt_ms": fmt(scene.numerics.dt_s * 1e3),
                "shape": " × ".join(str(s) for s in p.shape), "nu_m2_s": fmt(p.units.viscosity_phys(p.nu_lu))
                if hasattr(p.units, "viscosity_phys") else fmt(p.nu_lu * p.units.dx_m**2 / p.units.dt_s),
                "nu_lu": fmt(p.nu_lu), "tau": fmt(p.tau), "u_max_lu": fmt(p.u_max_lu), "mach": fmt(p.mach_max),
                "steps": fmt(p.n_steps), "spinup_steps": fmt(p.spinup_steps),
                "duration_s": fmt(scene.run.duration_s),
            })
    return rows, errors


def case_rows(config: dict, fid_dir: Path) -> list[dict]:
    """The config's case matrix with, where the results have them, the achieved concentration and
    the status (``tables/packing.csv``, ``cases/<case>/summary.json``)."""
    packing = read_table(Path(fid_dir) / "tables" / "packing.csv")
    pk = {} if packing is None else {r["case"]: r for r in packing.to_dict("records")}
    rows = []
    for name, case in (config.get("cases") or {}).items():
        p = case.get("particles") or {}
        size = (f"{fmt(p['diameter_mm'])} × {fmt(p['length_mm'])}" if p.get("shape") == "cylinder"
                else fmt(p["edge_mm"]) if p.get("shape") == "cube" else "–")
        s = read_summary(Path(fid_dir) / "cases" / name, case)  # a case declared unpackable: its record
        status = "not run"
        achieved = pk.get(name, {}).get("concentration_achieved")
        if s is not None:
            status = s.get("status", "?")
            if achieved is None:
                achieved = (s.get("particles") or {}).get("concentration_achieved")
        rows.append({"case": name, "reynolds": fmt(case["reynolds"]), "shape": p.get("shape", "none"),
                     "size_mm": size,
                     "target": fmt(100 * p["concentration"]) if "concentration" in p else "–",
                     "achieved": fmt(100 * achieved) if achieved is not None else "–",
                     "collisions": fmt(bool(case.get("collisions", True))) if p else "–",
                     "status": status})
    return rows


def _figure_key(stem: str) -> str:
    m = re.match(r"fig(\d+[ab]?)", stem)
    return m.group(1) if m else stem


def our_caption(stem: str) -> tuple[str, str]:
    """Our caption for a figure file stem and where it came from."""
    key = _figure_key(stem)
    try:
        caps = getattr(figures, "FIGURE_CAPTIONS", None)
    except Exception:  # a broken figures module must not stop the document
        caps = None
    if caps:
        for k in (stem, f"fig{key}", key, key.rstrip("ab") if key[:-1].isdigit() else None):
            if k is not None and k in caps:
                return str(caps[k]), "lbmpipe.reproduction.figures.FIGURE_CAPTIONS"
    return FALLBACK_CAPTIONS.get(key, "(no caption)"), "fallback (lbmpipe.reproduction.literate)"


def _fig_sort(stem: str):
    m = re.match(r"fig(\d+)([ab]?)", stem)
    return (int(m.group(1)), m.group(2), stem) if m else (999, "", stem)


def figure_entries(fid_dir: Path, out_dir: Path) -> list[dict]:
    fig_dir = Path(fid_dir) / "figures"
    out = []
    for png in sorted(fig_dir.glob("fig*.png"), key=lambda p: _fig_sort(p.stem)):
        key = _figure_key(png.stem)
        ours, source = our_caption(png.stem)
        pdf = png.with_suffix(".pdf")
        out.append({"key": key, "stem": png.stem,
                    "image": relative_href(png, out_dir),
                    "pdf": relative_href(pdf, out_dir) if pdf.is_file() else None,
                    "ours": ours, "ours_source": source,
                    "paper": PAPER_CAPTIONS.get(key.rstrip("ab") if key not in PAPER_CAPTIONS else key,
                                                "(no such figure in the paper)")})
    return out


def _rel(path: Path, fid_dir: Path) -> str:
    return Path(path).relative_to(Path(fid_dir)).as_posix()


def runtime_section(fid_dir: Path, fidelity: str) -> dict:
    """Run cost per case (this level) and per level (every ``results/<level>/tables/runtime.csv``
    beside this one), beside the paper's hours per case."""
    fid_dir = Path(fid_dir)
    df = read_table(fid_dir / "tables" / "runtime.csv")
    sec = {"paper_hours": fmt(PAPER_HOURS_PER_CASE), "cases": None, "levels": [], "model": None}

    model = read_json(fid_dir / "tables" / "cost_model.json")
    val = read_table(fid_dir / "tables" / "cost_validation.csv")
    if model is not None and model.get("n_runs"):
        sec["model"] = {"formula": model.get("formula", ""), "n_runs": fmt(model.get("n_runs")),
                        "families": fmt(model.get("families")), "n_validated": fmt(model.get("n_validated")),
                        "median_pct": fmt(100 * _num(model.get("median_abs_rel_error"))),
                        "max_pct": fmt(100 * _num(model.get("max_abs_rel_error"))),
                        "median_share_pct": fmt(100 * _num(model.get("median_abs_rel_error_median_share"))),
                        "max_share_pct": fmt(100 * _num(model.get("max_abs_rel_error_median_share"))),
                        "share": fmt(model.get("median_cpu_share")),
                        "ns_node": fmt(1e9 * model.get("s_per_node_update", 0.0)),
                        "ns_link": fmt(1e9 * model.get("s_per_link_update", 0.0)),
                        "us_particle": fmt(1e6 * model.get("s_per_particle_step", 0.0)),
                        "ms_step": fmt(1e3 * model.get("s_per_step", 0.0)), "intercept_s": fmt(model.get("intercept_s")),
                        "hosts": [{"cpu": cpu, "n_runs": fmt(h.get("n_runs")), "families": fmt(h.get("families")),
                                   "n_validated": fmt(h.get("n_validated")),
                                   "ns_node": fmt(1e9 * h.get("s_per_node_update", 0.0)),
                                   "median_pct": fmt(100 * _num(h.get("median_abs_rel_error"))),
                                   "median_share_pct": fmt(100 * _num(h.get("median_abs_rel_error_median_share")))}
                                  for cpu, h in sorted((model.get("hosts") or {}).items())],
                        "unrecorded": fmt((model.get("runs_by_host") or {}).get(UNRECORDED, 0)),
                        "table": table_of(val, ["run", "family", "host", "steps", "particles", "links", "wall_s",
                                                "predicted_s", "rel_error", "cpu_share", "rel_error_median_share",
                                                "fitted_host"])
                        if val is not None and len(val) else None}
    if df is not None:
        d = df.copy()
        if "wall_s" in d:
            d["wall_h"] = d["wall_s"] / 3600.0
            d["fraction_of_paper"] = d["wall_h"] / PAPER_HOURS_PER_CASE
        sec["cases"] = table_of(d, ["case", "status", "steps", "simulated_s", "wall_s", "wall_h", "s_per_step",
                                    "mlups", "particles", "max_rss_mb", "fraction_of_paper"])
    for level_dir in sorted(p for p in fid_dir.parent.iterdir() if p.is_dir()) if fid_dir.parent.is_dir() else []:
        lv = read_table(level_dir / "tables" / "runtime.csv")
        if lv is None or "wall_s" not in lv or len(lv) == 0:
            continue
        ran = lv[~lv["status"].astype(str).isin(["unpackable", "not run"])] if "status" in lv else lv
        w = ran["wall_s"].astype(float)
        sec["levels"].append({"level": level_dir.name, "cases": fmt(len(ran)),
                              "total_h": fmt(w.sum() / 3600.0), "median_case_h": fmt(w.median() / 3600.0),
                              "max_case_h": fmt(w.max() / 3600.0),
                              "median_vs_paper": fmt(w.median() / 3600.0 / PAPER_HOURS_PER_CASE),
                              "this": level_dir.name == fidelity})
    return sec


def method_comparison_section(fid_dir: Path, fidelity: str, config: dict, out_dir: Path) -> dict | None:
    """What the method changes (``lbmpipe.reproduction.methods``): for a level another one
    compares with, that level, its runs done and planned, and the comparison's summary, claims
    and paired runs (``results/<level>/method/``); for an accurate-method level, the level it is
    compared with; else None."""
    fid = (config.get("fidelities") or {}).get(fidelity) or {}
    if fid.get("compare_with"):
        # the paired runs are shown in the compared level's document
        return {"is_accurate": True, "paper_level": fid["compare_with"], "runs": None,
                "method": fid.get("method", "paper"),
                "numerics": numerics_text(method_numerics(config, fidelity, against=fid["compare_with"]))}
    other = comparison_level(config, fidelity)
    if other is None:
        return None
    mdir = Path(fid_dir) / "method"
    summ = read_json(mdir / "summary.json") or {}
    runs = read_table(mdir / "runs.csv")
    claims = read_table(Path(fid_dir) / "claims.csv")  # the level's verdicts with both methods' seed-1 ones
    done, _ = _runs_done(config, other, Path(fid_dir).parent)
    flows = [{"run": f["run"], "paper_pct": fmt(100 * _num(f["paper"])), "accurate_pct": fmt(100 * _num(f["accurate"]))}
             for f in summ.get("flows", [])]
    compared = (claims["same_under_both_methods"] != "not compared"
                if claims is not None and "same_under_both_methods" in claims else None)
    png = mdir / "method_comparison.png"
    figure = relative_href(png, out_dir) if png.is_file() else None
    return {"is_accurate": False, "level": other, "planned": summ.get("accurate_runs_planned", 0), "done": done,
            "method": config["fidelities"][other].get("method", "paper"),
            "numerics": numerics_text(method_numerics(config, other, against=fidelity)),
            "figure": figure,
            "pairs": summ.get("pairs", 0), "omega_compared": summ.get("omega_compared", 0),
            "omega_significant": summ.get("omega_significant", 0),
            "omega_median_pct": fmt(100 * _num(summ.get("omega_median_abs_rel_diff"))),
            "angle_compared": summ.get("angle_compared", 0), "angle_significant": summ.get("angle_significant", 0),
            "flows": flows, "claims_compared": summ.get("claims_compared", 0),
            "claims_changed": changed_text(summ.get("claims_changed", [])),
            "claims": table_of(claims[compared], ["claim", "verdict", "verdict_paper_method_seed1",
                                                   "verdict_accurate_method_seed1", "same_under_both_methods"])
            if compared is not None and compared.any() else None,
            "runs": table_of(runs, ["run", "observable", "paper", "paper_ci95", "accurate", "accurate_ci95", "rel_diff",
                                    "significant"]) if runs is not None and len(runs) else None}


def changed_text(claims: list) -> str:
    """The claims whose verdict the method changes, as a count with their numbers: ``none``,
    ``1 claim (claim 12)``, ``2 claims (claims 3, 12)``."""
    claims = [int(c) for c in claims]
    if not claims:
        return "none"
    nums = ", ".join(map(str, claims))
    return f"1 claim (claim {nums})" if len(claims) == 1 else f"{len(claims)} claims (claims {nums})"


def convergence_section(fid_dir: Path, fidelity: str, config: dict, out_dir: Path) -> dict | None:
    """The paper's observables by dx (``lbmpipe.reproduction.convergence``): the levels with their
    runs done and planned, the values, the observed orders and the figure of accuracy against cost
    (``results/<level>/convergence/``); None for a level nothing refines."""
    lvls = levels(config, fidelity)
    if len(lvls) < 2:
        return None
    cdir = Path(fid_dir) / "convergence"
    summ = read_json(cdir / "summary.json") or {}
    vals, order = read_table(cdir / "values.csv"), read_table(cdir / "order.csv")
    info = []
    for lv in lvls:
        done, planned = _runs_done(config, lv, Path(fid_dir).parent)
        info.append({"level": lv, "dx": fmt(config["fidelities"][lv]["dx_mm"]), "done": done, "planned": planned})
    png = cdir / "accuracy_cost.png"
    figure = relative_href(png, out_dir) if png.is_file() else None
    return {"levels": info, "observed": summ.get("observed", 0), "compared": summ.get("compared", 0), "figure": figure,
            "order_table": table_of(order, list(order.columns)) if order is not None and len(order) else None,
            "value_table": table_of(vals, ["case", "observable", "dx_mm", "value", "ci95", "n_seeds", "loop_s_per_sim_s", "flags"])
            if vals is not None and len(vals) else None}


def _runs_done(config: dict, level: str, results_dir: Path) -> tuple[int, int]:
    """(completed, planned) runs of a level under ``results_dir``."""
    runs = level_runs(config, level)
    done = sum(1 for r in runs if (read_json(Path(results_dir) / level / "cases" / r / "summary.json") or {}).get("status")
               == "completed")
    return done, len(runs)


def health_section(fid_dir: Path, config: dict) -> dict:
    """Run health and diagnostics, one row per case (:func:`lbmpipe.reproduction.health.health_row`:
    from ``summary.json``, ``flow_rate.csv`` and ``stats.json``), thresholds from ``config.yaml``'s
    ``diagnostics`` block; the diagnostics of a ``stats.json`` written before they existed read
    "not computed"."""


    diag = health.thresholds(config)
    rows, stale = [], []
    for name in config.get("cases") or {}:
        cdir = Path(fid_dir) / "cases" / name
        r = health.health_row(name, cdir, diag["health"], config["cases"][name])
        stats = health.read_json(cdir / "stats.json")
        if stats is not None and not health.health_is_computed(stats):
            stale.append(name)
            r.update(frozen="not computed", locked="not computed", steady="not computed")
        r["rotation_projection_share"] = r.pop("rotation_projection_share")
        r["flags"] = r["flags"].replace(";", ", ") or "none"
        rows.append(r)
    cols = ["case", "status", "mass_floor_rel", "mass_drift_rel", "mass_corrected_rel", "mass_corrected_throughflow",
            "density_deviation_median",
            "density_deviation_max", "rotation_projection_share", "max_overlap_lu", "max_overlap_between_lu",
            "flow_rate_error_rel", "frozen",
            "locked", "steady", "flags", "issues"]
    limits = ", ".join(f"`{k}` = {fmt(v)}" for k, v in diag["health"].items())
    intro = (f"Thresholds (`config.yaml`, `diagnostics`): {limits}; frozen beyond "
             f"{fmt(diag['frozen_remaining'])} of the orientation correlation with the packing left at the end, "
             f"locked when no pair passed and {fmt(diag['locked_neighbours_retained'])} of the nearest neighbours "
             f"are kept (or the bodies cannot sit side by side), spin-up at least "
             f"{fmt(diag['min_spinup_viscous_times'])} R²/ν. A case beyond a threshold is flagged in every table, "
             "figure and claim that uses it. `mass_corrected_rel` is – where `summary.json` does not record the "
             "mass correction.")
    note = (f"Frozen, locked and steady: {health.NOT_COMPUTED} ({', '.join(f'`{c}`' for c in stale)})."
            if stale else "")
    return {"table": table_of(pd.DataFrame(rows, columns=cols)), "intro": intro, "note": note, "rows": rows}


def stationarity_section(fid_dir: Path) -> dict | None:
    """How the runs' spin-up tests read at a family-wise 95 % (``steady.steady_corrected``): every
    run whose ``stats.json`` keeps the halves of its observables (``cases/*/seed*/`` or, one
    packing per case, ``cases/*/``); None when no run does."""
    cases = Path(fid_dir) / "cases"
    files = sorted(cases.glob("*/seed*/stats.json")) + sorted(cases.glob("*/stats.json"))
    runs = []
    for f in files:
        sp = (read_json(f) or {}).get("spinup") or {}
        if sp.get("observables"):
            runs.append({"run": str(f.parent.relative_to(cases)), **steady_corrected(sp)})
    if not runs:
        return None
    counts = {v: sum(r["verdict"] == v for r in runs) for v in ("steady", "drift", "mser", "chance", "no interval")}
    drift = [r["worst_z"] for r in runs if r["verdict"] == "drift"]
    ks = sorted({r["k"] for r in runs})
    return {"runs": runs, "n": len(runs), "counts": counts, "not_steady": len(runs) - counts["steady"],
            "k": "/".join(map(str, ks)), "bound": fmt(max(r["bound"] for r in runs)),
            "z_max": fmt(max(drift)) if drift else None,
            "mostly_drift": counts["drift"] + counts["mser"] > 2 * counts["chance"]}


def study_section(fid_dir: Path, out_dir: Path) -> dict:
    """The accuracy-cost study: its Markdown reports (``study/*.md``, generated from its CSVs), any
    CSV without a report as a table, and its figures."""
    sdir = Path(fid_dir) / "study"
    sec = {"present": sdir.is_dir(), "reports": [], "tables": [], "figures": []}
    if not sdir.is_dir():
        return sec
    mds = sorted(sdir.glob("*.md"))
    for md in mds:
        text = md.read_text(encoding="utf-8")
        # Demote the report's headings below the document's section level.
        text = re.sub(r"^(#+)", lambda m: "###" + m.group(1), text, flags=re.M)
        sec["reports"].append({"file": _rel(md, fid_dir), "text": text.strip()})
    covered = {md.stem for md in mds}
    for csv in sorted(sdir.glob("*.csv")):
        if csv.stem in covered:
            continue
        df = read_table(csv)
        if df is not None:
            sec["tables"].append({"file": _rel(csv, fid_dir), "table": table_of(df.head(60)),
                                  "truncated": len(df) > 60, "rows": fmt(len(df))})
    for png in sorted(sdir.glob("*.png")):
        sec["figures"].append({"file": _rel(png, fid_dir),
                               "image": relative_href(png, out_dir)})
    return sec
