"""The paper's observables as the lattice is refined: mean |Omega| per axis, the mean orientation
angle and the velocity profile's distance from Poiseuille, by dx, with intervals, and the order
they converge at where the statistics' noise lets it show.

Levels with ``convergence_of: <level>`` run some of that level's cases at another dx (tau fixed:
dt proportional to dx^2). For each case and observable the value at each dx comes from the case's
record (``cases/<case>/stats.json``, the seeds combined where a level has several; the profile from
``profile.csv``), with its 95 % half-width. Between successive spacings h > h/2 > h/4 the changes
``d1 = f(h) - f(h/2)`` and ``d2 = f(h/2) - f(h/4)`` carry the two values' intervals combined
(``sqrt(ci_a^2 + ci_b^2)``). The observed order ``p = log2(|d1| / |d2|)`` is given only when both
changes exceed their intervals and share a sign (monotone convergence); otherwise the status says
which change the noise hides. The profile's distance has an interval from its packings' spread
(none needed for a particle-free flow, which is steady). A value without an interval (a run too
short for 20 valid batches; a particle case's profile from one packing) has unknown noise: no
order, and the status says so. The cost beside each value is the level's measured time-loop seconds
per simulated second of that case (``tables/runtime.csv``, summed over its seeds' runs).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats as _st

from ..outputs import write_json
from .cases import level_cases
from .comparison_figures import convergence_accuracy_cost
from .methods import completed_record, stats_values

ROW_COLUMNS = ["case", "observable", "level", "dx_mm", "value", "ci95", "n_seeds", "loop_s_per_sim_s", "flags"]
ORDER_COLUMNS = ["case", "observable", "dx_mm", "d1", "d1_ci95", "d2", "d2_ci95", "order", "status"]


def levels(config: dict, base: str) -> list[str]:
    """``base`` and the levels that refine or coarsen it, coarsest first."""
    fids = config["fidelities"]
    names = [base] + [n for n, f in fids.items() if f.get("convergence_of") == base]
    return sorted(names, key=lambda n: -float(fids[n]["dx_mm"]))


def profile_distance(profile_csv: Path) -> float:
    """Relative L2 distance of the averaged axial velocity from Poiseuille over the cross-section
    (``profile.csv``: each radius weighted by its node count); NaN if absent."""
    try:
        p = pd.read_csv(profile_csv)
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return float("nan")
    if not len(p):
        return float("nan")
    w = p["nodes"].astype(float)
    ref = p["uz_poiseuille_m_s"].astype(float)
    return float(np.sqrt((w * (p["uz_m_s"] - ref) ** 2).sum() / (w * ref**2).sum()))


def case_values(case_dir: Path) -> tuple[dict[str, tuple[float, float]], dict]:
    """(value, 95 % half-width) of each observable of one case's record, the profile's distance
    first, and the record itself; empty if the case is not run."""
    record = completed_record(case_dir)
    if record is None:
        return {}, {}
    stats = record[1]
    return {"profile_distance": (profile_distance(Path(case_dir) / "profile.csv"), profile_distance_ci95(case_dir, stats)),
            **stats_values(stats)}, stats


def profile_distance_ci95(case_dir: Path, stats: dict) -> float:
    """95 % half-width of a case's profile distance: 0 for a particle-free flow (steady, no
    statistical noise); from the spread of its packings' own distances (Student t, n - 1 degrees of
    freedom) where two or more completed; NaN (unknown) for a particle case from one packing."""
    if not stats:
        return 0.0
    seeds = [s["seed"] for s in stats.get("seeds") or [] if isinstance(s, dict) and s.get("status") == "completed"]
    d = np.array([profile_distance(Path(case_dir) / f"seed{k}" / "profile.csv") for k in seeds], float)
    d = d[np.isfinite(d)]
    if len(d) < 2:
        return float("nan")
    return float(_st.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d)))


def _cost(runtime: pd.DataFrame | None, case: str) -> float:
    """Time-loop seconds per simulated second of a case at a level (its ``tables/runtime.csv``),
    its seeds' runs summed."""
    if runtime is None:
        return float("nan")
    rt = runtime
    rows = rt[(rt["case"] == case) | rt["case"].astype(str).str.startswith(f"{case}/seed")]
    rows = rows[rows["status"] == "completed"]
    if not len(rows):
        return float("nan")
    # the time loop's seconds (s_per_step x steps): start-up and compilation are no cost of the lattice
    loop = rows["s_per_step"].astype(float) * rows["steps"].astype(float)
    return float(loop.sum() / rows["simulated_s"].astype(float).mean())


def _runtime(level_dir: Path) -> pd.DataFrame | None:
    try:
        return pd.read_csv(Path(level_dir) / "tables" / "runtime.csv")
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None


def value_rows(config: dict, base: str, root: Path = Path("results")) -> pd.DataFrame:
    """One row per case, observable and level of the convergence levels of ``base`` (the cases
    every refining level runs), where the case's record exists."""
    lvls = levels(config, base)
    shared = sorted(set.intersection(*[set(level_cases(config, lv)) for lv in lvls])) if len(lvls) > 1 else []
    runtime = {lv: _runtime(Path(root) / lv) for lv in lvls}
    rows = []
    for case in shared:
        for lv in lvls:
            values, stats = case_values(Path(root) / lv / "cases" / case)
            cost = _cost(runtime[lv], case)
            for obs, (v, c) in values.items():
                rows.append({"case": case, "observable": obs, "level": lv,
                             "dx_mm": float(config["fidelities"][lv]["dx_mm"]), "value": v, "ci95": c,
                             "n_seeds": int(stats.get("n_seeds", 1)) if stats else 1,
                             "loop_s_per_sim_s": cost,
                             "flags": ";".join(stats.get("flags") or [])})
    return pd.DataFrame(rows, columns=ROW_COLUMNS)


def order_rows(values: pd.DataFrame) -> pd.DataFrame:
    """Per case and observable with three spacings halving in turn: the two changes with their
    intervals and the observed order, or the reason it is not given."""
    rows = []
    for (case, obs), g in values.groupby(["case", "observable"], sort=True):
        g = g.sort_values("dx_mm", ascending=False)
        dx = g["dx_mm"].to_numpy(float)
        c_all = g["ci95"].to_numpy(float)
        # a value without an interval (a run too short for one; a particle case's profile from one
        # packing) has unknown noise
        unknown = [f"{x:g}" for x, ci in zip(dx[:3], c_all[:3]) if not np.isfinite(ci)]
        no_noise = f"no valid interval at dx {', '.join(unknown)} mm: the noise cannot be judged"
        if len(g) < 3:
            row = {"case": case, "observable": obs, "dx_mm": " ".join(f"{x:g}" for x in dx),
                   "status": f"{len(g)} of 3 spacings run"}
            if len(g) == 2:  # the one change there is, and whether it stands out of the noise
                f, c = g["value"].to_numpy(float), c_all
                row.update(d1=f[0] - f[1], d1_ci95=math.hypot(c[0], c[1]))
                row["status"] += (f"; {no_noise}" if unknown else "; the change exceeds its interval"
                                  if abs(row["d1"]) > row["d1_ci95"] else "; the change is within its interval")
            rows.append(row)
            continue
        f, c = g["value"].to_numpy(float)[:3], c_all[:3]  # an unknown interval stays NaN in d*_ci95
        d1, d2 = f[0] - f[1], f[1] - f[2]
        e1, e2 = math.hypot(c[0], c[1]), math.hypot(c[1], c[2])
        row = {"case": case, "observable": obs, "dx_mm": " ".join(f"{x:g}" for x in dx[:3]),
               "d1": d1, "d1_ci95": e1, "d2": d2, "d2_ci95": e2, "order": float("nan")}
        if not np.allclose([dx[0] / dx[1], dx[1] / dx[2]], 2.0):
            row["status"] = "spacings do not halve"
        elif unknown:
            row["status"] = no_noise
        elif abs(d2) <= e2:
            row["status"] = f"noise hides the order: the finer change {abs(d2):.3g} is within its interval {e2:.3g}"
        elif abs(d1) <= e1:
            row["status"] = f"noise hides the order: the coarser change {abs(d1):.3g} is within its interval {e1:.3g}"
        elif np.sign(d1) != np.sign(d2):
            row["status"] = "not monotone: the two changes differ in sign"
        else:
            row["order"] = math.log2(abs(d1) / abs(d2))
            row["status"] = "observed"
        rows.append(row)
    return pd.DataFrame(rows, columns=ORDER_COLUMNS)


def write(config: dict, base: str, root: Path, out_dir: Path) -> dict:
    """Write ``values.csv``, ``order.csv``, ``summary.json`` and the figure ``accuracy_cost.png``/
    ``.pdf`` (each observable against its cost, by dx) of ``base``'s convergence levels."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    vals = value_rows(config, base, root)
    order = order_rows(vals) if len(vals) else pd.DataFrame(columns=ORDER_COLUMNS)
    vals.to_csv(out_dir / "values.csv", index=False, float_format="%.6g")
    order.to_csv(out_dir / "order.csv", index=False, float_format="%.4g")
    convergence_accuracy_cost(vals, out_dir / "accuracy_cost",
                              title=f"The paper's observables against their cost as dx is refined (level {base})")
    lvls = levels(config, base)
    s = {"base": base, "levels": {lv: float(config["fidelities"][lv]["dx_mm"]) for lv in lvls},
         "cases": sorted(vals["case"].unique().tolist()) if len(vals) else [],
         "observed": int((order["status"] == "observed").sum()) if len(order) else 0,
         "compared": int(len(order))}
    write_json(out_dir / "summary.json", s)
    return s
