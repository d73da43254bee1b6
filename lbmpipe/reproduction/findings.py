"""What the reproduction found, in sentences for the document's abstract, its "Why" paragraphs, its
limitations and its claim appendix; every number read from a level's committed tables at build time.

- :func:`claim_findings`: which claims hold (``claims.csv``'s ``verdict``) and how each stands under
  the robustness controls (``tables/robustness.csv``, rendered as the table's strings: a control with
  too few runs reads whatever status the table holds, e.g. ``pending``);
- :func:`physical_results`: the physical results a reader needs (cylinder alignment against random
  orientation, cubes against cylinders of the same size, 50 % against 30 %, the largest cubes);
- :func:`correction_sizes`: how much mass the particles' mass correction and the density floor put
  back, per concentration (``tables/run_health.csv`` and each run's ``flow_rate.csv``);
- :func:`why`: a physical reading of the flags of a figure's cases (counts and worst values);
- :func:`claim_lines`: one line per claim for Appendix A.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from .document_sections import fmt, read_table
from .robustness import column_header, interim_counts, read_controls
from .robustness import run_health_figures  # one run's mass correction and floor samples, as the controls read them

#: Mean angle between a randomly (isotropically) oriented axis and the pipe axis, folded into
#: 0-90 deg: the integral of theta sin(theta) over 0..pi/2 is 1 rad.
ISOTROPIC_MEAN_DEG = math.degrees(1.0)

#: What each flag means for a mean rotation rate or orientation (health.py and steady.py define them).
FLAG_MEANING = {
    "unhealthy": ("films thinner than a spacing between near-touching surfaces are refilled by the mass correction "
                  "and the density floor, so the lubrication between those particles is not resolved"),
    "not steady": "the halves of the averaging window differ, a drift the interval does not include",
    "frozen": "the orientations still remember the packing",
    "locked": "the particles never pass one another, a jammed plug",
}

#: What an unresolved film does to the result a figure shows (``why``'s ``kind``).
UNHEALTHY_EFFECT = {
    "rotation": "the torque passed between near-touching particles, and with it their rotation rate, carries an "
                "error the interval does not include",
    "orientation": "the contacts that turn the particles, and so the orientations they settle in, are not resolved",
    "profile": "the mass put back is a source inside the flow the profile averages",
}


def flag_meanings() -> str:
    """The flags and what each means for a result, once for the document."""
    return "; ".join(f"*{f}*: {m}" for f, m in FLAG_MEANING.items())


def _verdict_lists(claims: pd.DataFrame) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for r in claims.itertuples():
        out.setdefault(str(r.verdict), []).append(fmt(r.claim))
    return out


def _links(nums: list[str]) -> str:
    """Claim numbers as links, three or more consecutive ones as a range (``[1](#claim-1)–[4](#claim-4)``)."""
    def link(n):
        return f"[{n}](#claim-{n})"
    bad = [n for n in nums if not str(n).isdigit()]
    if bad:  # claims.csv numbers its claims 1-14; anything else is a broken table, not a label to print
        raise ValueError(f"claim labels {bad} are not claim numbers: rebuild claims.csv (snakemake --forcerun claims)")
    runs: list[list[int]] = []
    for n in sorted(int(n) for n in nums):
        if runs and n == runs[-1][-1] + 1:
            runs[-1].append(n)
        else:
            runs.append([n])
    return ", ".join(f"{link(r[0])}–{link(r[-1])}" if len(r) >= 3 else ", ".join(link(n) for n in r) for r in runs)


def claim_findings(fid_dir: Path) -> dict | None:
    """The verdicts by claim and the robustness by claim, as text (None without ``claims.csv``)."""
    fid_dir = Path(fid_dir)
    claims = read_table(fid_dir / "claims.csv")
    if claims is None or "verdict" not in claims:
        return None
    lists = _verdict_lists(claims)
    order = sorted(lists, key=lambda v: -len(lists[v]))
    verdicts = "; ".join(f"{v}: claims {_links(lists[v])}" for v in order)
    statements = {fmt(r.claim): str(r.statement).rstrip(".") for r in claims.itertuples()}
    contradicted = [f"claim {n} (\"{statements[n]}\")" for n in lists.get("contradicted", [])]
    out = {"verdicts": verdicts, "contradicted": "; ".join(contradicted), "robustness": None}
    rob = pd.read_csv(fid_dir / "tables" / "robustness.csv", keep_default_na=False) \
        if (fid_dir / "tables" / "robustness.csv").is_file() else None
    if rob is None or "robust_under_controls" not in rob:
        return out
    # the leading word of each claim's robustness cell, as the table writes it (yes / no / pending / not covered)
    lead: dict[str, list[str]] = {}
    for r in rob.itertuples():
        cell = str(r.robust_under_controls)
        key = "not covered" if cell.startswith("not covered") else cell.split(":")[0].split(" (")[0].strip()
        lead.setdefault(key, []).append(fmt(r.claim))
    controls = [c for c in rob.columns if c.startswith("under ")]
    if not controls:  # a level without robustness controls has nothing to say about them
        return out
    # a several-packing control on its first packing alone while the others run (robustness.INTERIM)
    rows = read_controls(fid_dir / "robustness" / "controls.csv", required=True)
    interim = {column_header(label, n): (label, n) for label, n in interim_counts(rows).items()}
    per_control = []
    for c in controls:
        cells = rob[c].astype(str)

        def having(mark, cells=cells):
            return [fmt(n) for n, v in zip(rob["claim"], cells) if mark in v]
        holds, changes = having("(holds;"), having("(changes;")
        # a partly run control: the verdicts on its runs present, pending until it is complete
        agree, differ = having("(partly run (holds"), having("(partly run (changes")
        i_agree, i_differ = (holds, changes) if c in interim else ([], [])
        if c in interim:
            holds = changes = []
        status = sorted({v for v in cells if not v.startswith("not covered") and "(" not in v})
        name = c[len("under "):]
        if holds or changes:
            per_control.append(f"under {name} claims {_links(holds) or 'none'} hold"
                               + (f" and {_links(changes)} change" if changes else ""))
        elif agree or differ:
            per_control.append(f"{name} partly run: on its runs present claims {_links(agree) or 'none'} agree"
                               + (f" and {_links(differ)} differ" if differ else "") + " (pending)")
        elif i_agree or i_differ:
            name, case_n = interim[c]
            per_control.append(f"{name.replace(', packing', ' on packing')} alone ({case_n} cases, interim): "
                               f"claims {_links(i_agree) or 'none'} agree"
                               + (f" and {_links(i_differ)} differ" if i_differ else ""))
        elif status:
            per_control.append(f"{name}: {', '.join(status)}")
    words = {"yes": "robust (holds under every control)", "no": "changed by a control",
             "pending": "pending (a control not fully run)", "not covered": "not covered by any control"}
    out["robustness"] = {"by_status": "; ".join(f"{words.get(k, k)}: {_links(v)}" for k, v in lead.items()),
                         "per_control": "; ".join(per_control)}
    return out


def _completed(t: pd.DataFrame) -> pd.DataFrame:
    return t[t["status"].astype(str) == "completed"] if "status" in t else t


def _colliding(t: pd.DataFrame) -> pd.DataFrame:
    return t[t["collisions"].astype(str).str.lower().isin(("true", "1", "1.0"))] if "collisions" in t else t


def _range(values, unit: str = "", digits: int = 3) -> str:
    v = [x for x in values if np.isfinite(x)]
    if not v:
        return "–"
    lo, hi = fmt(min(v), digits), fmt(max(v), digits)
    if lo == hi:
        return f"{lo}{unit}"
    # both ends to the same significant digits, trailing zeros kept ("1.30–5.18", not "1.3–5.18")
    if any("." not in t or "e" in t for t in (lo, hi)):
        return f"{lo}–{hi}{unit}"
    lo, hi = (f"{x:#.{digits}g}" for x in (min(v), max(v)))
    return f"{lo}–{hi}{unit}"


def physical_results(fid_dir: Path) -> list[str]:
    """The physical results of a level, each a sentence with the numbers of its tables (those whose
    tables are absent are left out)."""
    fid_dir = Path(fid_dir)
    out = []
    ori = read_table(fid_dir / "tables" / "orientation_summary.csv")
    av = read_table(fid_dir / "tables" / "angular_velocity.csv")
    if ori is not None and not {"kind", "mean_deg", "ci95_deg", "case"} <= set(ori.columns):
        ori = None
    if av is not None and not {"case", "shape", "edge_mm", "diameter_mm", "length_mm", "concentration", "reynolds",
                               "omega_x", "omega_y", "omega_z", "n_particles"} <= set(av.columns):
        av = None  # a table of another layout (older level, synthetic test): no sentence rather than a wrong one
    if ori is not None:
        cyl = _colliding(_completed(ori[ori["kind"] == "cyl_axis_angle"])).dropna(subset=["mean_deg"])
        if len(cyl):
            lo, hi = cyl["mean_deg"] - cyl["ci95_deg"], cyl["mean_deg"] + cyl["ci95_deg"]
            inside = int(((lo <= ISOTROPIC_MEAN_DEG) & (ISOTROPIC_MEAN_DEG <= hi)).sum())
            below = int((hi < ISOTROPIC_MEAN_DEG).sum())
            lead = ("Cylinders do not align with the flow" if below < len(cyl) / 2 else
                    "Cylinders lean towards the flow direction")
            out.append(f"{lead}: their mean angle to the pipe axis is {_range(cyl['mean_deg'])} deg over "
                       f"{len(cyl)} cases, against {fmt(ISOTROPIC_MEAN_DEG)} deg for random orientation, which lies inside the "
                       f"95 % interval of {inside} of them and above that of {below}.")
    if av is not None:
        t = _colliding(_completed(av)).copy()
        t["omega"] = t[["omega_x", "omega_y", "omega_z"]].mean(axis=1)
        cubes, cyls = t[t["shape"] == "cube"], t[t["shape"] == "cylinder"]
        ratios = []
        for r in cubes.itertuples():
            m = cyls[(cyls["diameter_mm"] == r.edge_mm) & (cyls["length_mm"] == r.edge_mm)
                     & (cyls["concentration"] == r.concentration) & (cyls["reynolds"] == r.reynolds)]
            if len(m) and r.omega > 0:
                ratios.append(float(m["omega"].iloc[0]) / r.omega)
        if ratios:
            pairs = f"(mean |Ω| over x, y, z; {len(ratios)} pairs at the same concentration and Reynolds number)"
            if min(ratios) > 1:
                out.append(f"Cubes spin {_range(ratios)} times slower than cylinders of the same size {pairs}.")
            elif max(ratios) < 1:
                out.append(f"Cubes spin {_range([1 / x for x in ratios])} times faster than cylinders of the same "
                           f"size {pairs}.")
            else:
                out.append(f"Cylinders of a cube's size spin {_range(ratios)} times as fast as the cube {pairs}.")
        # the densest case of each shape, size and Reynolds number against the next lower concentration
        dense, concs = [], set()
        key = ["shape", "edge_mm", "diameter_mm", "length_mm", "reynolds"]
        for _, g in t.fillna({"edge_mm": 0, "diameter_mm": 0, "length_mm": 0}).groupby(key):
            g = g.sort_values("concentration")
            if len(g) > 1 and g["omega"].iloc[-1] > 0:
                dense.append(float(g["omega"].iloc[-2] / g["omega"].iloc[-1]))
                concs.add((fmt(100 * g["concentration"].iloc[-2]), fmt(100 * g["concentration"].iloc[-1])))
        if dense and len(concs) == 1:
            lo, hi = concs.pop()
            out.append((f"At {hi} % every particle turns slower than at {lo} %, by a factor {_range(dense)}"
                        if min(dense) > 1 else f"From {lo} % to {hi} % the rotation rate changes by a factor "
                        f"{_range([1 / x for x in dense])}") + f" ({len(dense)} pairs of cases).")
        big = av[(av["shape"] == "cube")]
        if len(big) and big["edge_mm"].notna().any():
            edge = big["edge_mm"].max()
            big = big[(big["edge_mm"] == edge) & big["omega_x"].notna()]
            small = cubes[cubes["edge_mm"] == cubes["edge_mm"].min()]
            locked = [str(r.case) for r in big.itertuples() if "locked" in str(getattr(r, "flags", ""))]
            if len(big):
                om = big[["omega_x", "omega_y", "omega_z"]].to_numpy(float).ravel()
                angle = ""
                if ori is not None:
                    a = ori[(ori["case"].isin(big["case"])) & (ori["kind"] == "cube_axis_angle")]["mean_deg"]
                    angle = f", a cube axis within {_range(a)} deg of the pipe axis on average"
                n = fmt(big["n_particles"].max())
                head = (f"lock: {len(locked)} of {len(big)} cases run are flagged locked" if locked else
                        "are not flagged locked but barely turn")
                out.append(f"The {fmt(edge)} mm cubes ({n} per pipe) {head}{angle}; they turn at {_range(om)} rad/s against "
                           f"{_range(small[['omega_x', 'omega_y', 'omega_z']].to_numpy(float).ravel())} rad/s for the "
                           f"{fmt(small['edge_mm'].min())} mm cubes.")
    sens = method_sensitivity(fid_dir)
    if sens:
        out.append(sens)
    return out


def method_sensitivity(fid_dir: Path) -> str | None:
    """How far each robustness control moves the mean |Omega| of the same packings
    (``robustness/shifts.csv``, relative shifts over the three axes): median and range per control,
    with the cases measured (None without shifts)."""
    sh = read_table(Path(fid_dir) / "robustness" / "shifts.csv")
    if sh is None or not {"control", "case", "observable", "shift"} <= set(sh.columns):
        return None
    if "sensitivity" not in sh:
        raise ValueError(f"{Path(fid_dir) / 'robustness' / 'shifts.csv'}: no 'sensitivity' column; rebuild it "
                         "(snakemake --forcerun robustness)")
    # the cases no verdict rests on (robustness.is_sensitivity) are not the method's effect on the claims
    om = sh[(sh["observable"] == "omega") & ~sh["sensitivity"].astype(bool)].dropna(subset=["shift"])
    parts = []
    for control, g in om.groupby("control", sort=False):
        pct, n = 100 * g["shift"].astype(float), g["case"].nunique()
        parts.append(f"{control} {pct.median():+.0f} % ({pct.min():+.0f} to {pct.max():+.0f} %, "
                     f"{n} case{'' if n == 1 else 's'})")
    if not parts:
        return None
    return ("The method moves the rotation rates: mean |Ω| of the same packings against the paper's method, median "
            "(range) per control: " + "; ".join(parts) + ".")


def _runs(fid_dir: Path, config: dict) -> pd.DataFrame:
    """``tables/run_health.csv`` with each run's concentration and collisions from the config."""
    rh = read_table(Path(fid_dir) / "tables" / "run_health.csv")
    if rh is None or not len(rh) or not {"case", "status"} <= set(rh.columns):
        return pd.DataFrame(columns=["case", "status", "concentration"])
    cases = config.get("cases") or {}
    conc, coll = [], []
    for c in rh["case"].astype(str):
        p = (cases.get(c.split("/")[0]) or {}).get("particles") or {}
        conc.append(float(p.get("concentration", float("nan"))))
        coll.append((cases.get(c.split("/")[0]) or {}).get("collisions", True) is not False)
    rh = rh.assign(concentration=conc, colliding=coll)
    return rh[rh["colliding"] & rh["concentration"].notna() & rh["status"].isin(["completed", "unstable"])]


def correction_sizes(fid_dir: Path, config: dict) -> list[dict]:
    """Per concentration, over the runs with collisions: the mass the mass correction put back
    (fraction of the pipe's fluid mass over the run, in size; of the mass through the pipe; the runs
    where it took mass out instead), the mass the
    density floor added, and the share of samples with a node at the floor (the runs'
    ``flow_rate.csv``, as :func:`lbmpipe.reproduction.robustness.run_health_figures` counts them)."""
    rh = _runs(fid_dir, config)
    out = []
    if not len(rh) or "mass_corrected_rel" not in rh:
        return out
    for c, g in rh.groupby("concentration"):
        share = [run_health_figures(Path(fid_dir) / "cases" / r).get("floor_sample_share", float("nan"))
                 for r in g["case"]]
        share = np.array([s for s in share if s is not None], float)
        mc = g["mass_corrected_rel"].astype(float)
        out.append({"concentration": fmt(100 * c), "runs": len(g),
                    "fluid_median": fmt(mc.median()), "fluid_max": fmt(mc.max()),
                    "through_max": fmt(g["mass_corrected_throughflow"].astype(float).max()),
                    # runs where the correction took mass out instead (its sign; a table without it: error)
                    "taken_out": int((g["mass_corrected_signed"].astype(float) < 0).sum()),
                    "floor_mass_max": fmt(g["mass_floor_rel"].astype(float).max()),
                    "floor_share_median": fmt(float(np.nanmedian(share)) if np.isfinite(share).any() else float("nan")),
                    "floor_share_max": fmt(float(np.nanmax(share)) if np.isfinite(share).any() else float("nan")),
                    "floor_runs": int((share > 0).sum())})
    return out


def why(names: list[str], health_rows: list[dict], fid_dir: Path, config: dict, kind: str = "rotation") -> str:
    """A physical reading of the flags of the cases ``names``: how many carry each flag and what it
    means for the result the figure shows (``kind``: a key of :data:`UNHEALTHY_EFFECT`), the worst
    run-health values and where they occur; the cases that did not complete, by status."""
    rows = [h for h in health_rows if h["case"] in names]
    if not rows:
        return ""
    counts = {f: sum(f in str(h["flags"]) for h in rows) for f in FLAG_MEANING}
    flagged = sum(str(h["flags"]) not in ("none", "") for h in rows)
    unstable = [h for h in rows if str(h["status"]) != "completed"]
    if not flagged and not unstable:
        return f"None of the {len(rows)} cases is flagged by the run-health diagnostics."
    text = [f"{flagged} of {len(rows)} cases are flagged ("
            + ", ".join(f"{n} {f}" for f, n in counts.items() if n) + ")."]
    rh = _runs(fid_dir, config)
    if len(rh):
        rh = rh[rh["case"].astype(str).str.split("/").str[0].isin(names)]
    if counts["unhealthy"]:
        worst = []
        for col, what in (("mass_corrected_throughflow", "the worst run puts back {v} of the mass through the pipe"),
                          ("density_deviation_max", "the largest density deviation is {v}")):
            v = rh[col].astype(float) if len(rh) and col in rh else pd.Series(dtype=float)
            if v.notna().any():
                k = v.idxmax()
                worst.append(what.format(v=fmt(v[k])) + f" (`{rh.loc[k, 'case']}`)")
        text.append(f"Unhealthy, here: {UNHEALTHY_EFFECT.get(kind, UNHEALTHY_EFFECT['rotation'])}"
                    + ("; " + " and ".join(worst) if worst else "") + ".")
    locked = [f for f in ("frozen", "locked") if counts[f]]
    if locked:  # the flags' meaning in general: the document's method section (FLAG_MEANING)
        text.append(f"{' and '.join(locked).capitalize()}: these means describe the packing more than the suspension.")
    by_status: dict[str, list[str]] = {}
    for h in unstable:  # "unstable (seed 3: unstable)" -> unstable
        by_status.setdefault(str(h["status"]).split(" (")[0], []).append(f"`{h['case']}`")
    if by_status:
        text.append("; ".join(f"{k.capitalize()}: {', '.join(v)}" for k, v in by_status.items())
                    + " (left out of the figure's bars and of the claims).")
    return " ".join(text)


def claim_lines(fid_dir: Path, claims_href: str) -> list[str]:
    """Appendix A: one line per claim, its statistic's deciding number and what carries it; the
    full statistics are ``claims.csv`` (linked)."""
    claims = read_table(Path(fid_dir) / "claims.csv")
    if claims is None:
        return []
    out = []
    for r in claims.to_dict("records"):
        deciding = str(r.get("deciding") or "").strip()
        if deciding in ("", "nan"):
            deciding = str(r.get("values", "")).split("; ")[0].split(" (")[0]
        carried = str(r.get("carried_by") or "")
        out.append(f"Claim {fmt(r['claim'])}, **{r['verdict']}**: {deciding}"
                   + (f"; {carried}" if carried not in ("", "nan") else "")
                   + f" ([claims.csv]({claims_href}), row {fmt(r['claim'])}).")
    return out
