"""Which of the paper's claims survive a better method (issue 47): every verdict under the
robustness controls of a level, the systematic term of the verdict rule from their measured shifts,
the reference's convergence, the run health side by side and the controls' cost.

A level with ``control_of: <base>`` (``config.yaml``: ``credible_ma2``, ``credible_reference``,
``credible_dx0625``, ``credible_gap05``) runs some of ``base``'s cases with one change. Written to
``results/<base>/robustness/`` by :func:`write`:

- ``controls.csv``: per claim and control, the control's verdict on its own runs (the existing
  verdict machinery, :func:`lbmpipe.reproduction.claims.evaluate_claims`, on a view holding only
  the control's cases) beside ``base``'s verdict on the same cases and packings (``baseline``), and
  the ``status``: ``holds`` (the same verdict), ``changes`` (another one), ``not covered by
  <control>`` (the claim compares no pair of cases the control runs), ``not run`` (none of the
  control's runs is there) or ``partly run`` (the missing runs named: the verdict is on the runs
  present). :func:`robust_column` makes ``robust_under_controls`` of it: ``yes`` when the verdict
  holds under every control that covers it (all of them complete), ``no`` naming the controls that
  change it, ``pending`` naming the controls not (fully) run, ``not covered by any control``. A
  several-packing control still running also gets rows ``<control>, packing 1`` (:func:`control_verdicts`):
  its first packing alone against ``base``'s, a look ahead that never decides robustness.
- ``shifts.csv``: per control, case and observable, ``base``'s value and the control's (the same
  packings) and the shift: relative for mean |Omega| and the profile distance, in degrees for the
  mean angle, absolute for an orientation-bin fraction. ``systematic.json``: the largest |shift|
  per observable over every control and case (:func:`systematic_from_shifts`), with where it was
  measured; ``claims.csv``'s ``verdict_with_systematic`` and ``robust`` use it (``config.yaml``'s
  ``systematic`` values above zero override it).
- ``convergence.csv``: the reference against its refinement (``refines``): :func:`convergence_check`.
- ``health.csv``: per case the mass the particles' mass correction puts back (negative where it
  takes mass out), relative to the pipe's fluid mass and to the mass through the pipe, and the share
  of samples at the density floor: ``base`` beside the control labelled ``reference``.
- ``unstable.csv``: the runs of ``base`` that ended unstable, rerun by a level with ``unstable_of:
  base`` (the reference method): how each ended there (:func:`unstable_rows`).
- ``cost.csv`` and ``cost_robustness.png``: each control's core-hours (measured from its summaries,
  else planned with the cost model) against the verdicts it changes.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ..cost import predict
from ..outputs import write_json
from ..scene import Numerics, Scene
from ..units import derive
from .cases import case_scene, level_cases, level_runs, level_seeds, run_case, split_run, wall_model
from .claim_rules import SYSTEMATIC_KEYS
from .claims import compares_anything as _covered, evaluate_claims
from .convergence import profile_distance
from .document_sections import table_of
from .equations import relative_href
from .health import read_flow_rate, read_json, mass_corrected_signed, mass_corrected_throughflow
from .methods import SEED1_FILES, completed_record, stats_values
from .plotting import plt, save
from .statistics import aggregate

UNSTABLE_COLUMNS = ["run", "level", "method", "mach_factor", "base_status", "base_steps", "status", "steps",
                    "simulated_s", "wall_s"]
CONTROL_COLUMNS = ["claim", "control", "level", "verdict", "baseline", "status", "runs_done", "runs_planned", "missing",
                   "interim_cases"]
SHIFT_COLUMNS = ["control", "case", "observable", "key", "base", "base_ci95", "control_value", "control_ci95", "shift",
                 "sensitivity"]
CONVERGENCE_COLUMNS = ["case", "observable", "coarse", "coarse_ci95", "fine", "fine_ci95", "rel_diff", "status", "figures"]
HEALTH_COLUMNS = ["case", "level", "status", "mass_corrected_fluid", "mass_corrected_throughflow",
                  "floor_sample_share", "samples"]
#: the observable of each shift -> its key of the systematic term (claim_rules.SYSTEMATIC_KEYS)
SYSTEMATIC_OF = {"omega": "omega_rel", "angle": "angle_deg", "fraction": "fraction_abs", "profile": "profile_rel_l2"}
#: convergence check (issue 47 item 3): the two finest lattices agree within this, or within their
#: combined interval, with intervals no wider than ``CONVERGED_MAX_CI``
CONVERGED_REL, CONVERGED_MAX_CI = 0.05, 0.10
INTERIM = "interim"  # the status and header word of a first-packing look ahead (control_verdicts)


def control_levels(config: dict, base: str) -> list[str]:
    """The levels with ``control_of: base``, in the config's order."""
    return [n for n, f in config["fidelities"].items() if f.get("control_of") == base]


def unstable_levels(config: dict, base: str) -> list[str]:
    """The levels with ``unstable_of: base``: ``base``'s unstable packings rerun with another method."""
    return [n for n, f in config["fidelities"].items() if f.get("unstable_of") == base]


def control_label(config: dict, level: str) -> str:
    return str(config["fidelities"][level].get("control", level))


def reference_level(config: dict, base: str) -> str | None:
    """The control labelled ``reference`` (the accurate method the paper's is judged against)."""
    return next((c for c in control_levels(config, base) if control_label(config, c) == "reference"), None)


def run_status(root: Path, level: str, run: str) -> str | None:
    return (read_json(Path(root) / level / "cases" / run / "summary.json") or {}).get("status")


def runs_done(config: dict, level: str, root: Path) -> tuple[list[str], list[str]]:
    """(runs present, runs missing) of a level: a run is present when its summary says how it ended."""
    runs = level_runs(config, level)
    done = [r for r in runs if run_status(root, level, r) is not None]
    return done, [r for r in runs if r not in done]


# ------------------------------------------------------------------------------------------------
# verdicts on a view of a level's cases


def _copy_run(src: Path, dst: Path) -> bool:
    if (read_json(src / "summary.json") or {}).get("status") is None:
        return False
    dst.mkdir(parents=True, exist_ok=True)
    for name in SEED1_FILES:
        if (src / name).exists():
            shutil.copy2(src / name, dst / name)
    return True


def view(config: dict, level: str, cases: list[str], seeds: list[int], root: Path, work: Path) -> Path:
    """A directory holding only ``cases`` of ``level`` with the packings ``seeds``: one packing ->
    its run as the case (``methods.seed1_claims``); all of the level's packings -> the combined
    records with their seeds (the pooling reads them); the tables aggregated."""
    out = Path(work) / level
    fid = config["fidelities"][level]
    mine = level_seeds(fid)
    for case in cases:
        seeded = config["cases"][case].get("particles") is not None and "seeds" in fid
        src = Path(root) / level / "cases" / case
        if not seeded:
            _copy_run(src, out / "cases" / case)
        elif len(seeds) == 1:
            _copy_run(src / f"seed{seeds[0]}", out / "cases" / case)
        elif _copy_run(src, out / "cases" / case):
            for k in [k for k in mine if k in seeds]:
                _copy_run(src / f"seed{k}", out / "cases" / case / f"seed{k}")
    aggregate(out, config["cases"])
    return out


def view_claims(config: dict, level: str, cases: list[str], seeds: list[int], root: Path, work: Path,
                systematic: dict | None = None) -> pd.DataFrame:
    """The claims of ``level`` evaluated from ``cases`` and packings ``seeds`` alone."""
    sub = {c: config["cases"][c] for c in cases}
    d = view(config, level, cases, seeds, root, work)
    return evaluate_claims(d, sub, systematic or {k: 0.0 for k in SYSTEMATIC_KEYS})


def control_rows(baseline: pd.DataFrame, control: pd.DataFrame, label: str, level: str, done: list[str],
                 missing: list[str], baseline_present: pd.DataFrame | None = None,
                 interim_cases: int = 0) -> pd.DataFrame:
    """Per claim, the control's verdict beside the baseline's on the same cases and its status
    (module docstring). ``baseline``: the claims on every case the control plans (whether it covers
    a claim); ``control`` and ``baseline_present``: on the control's cases whose runs are all
    present (``baseline_present`` defaults to ``baseline``, a complete control). A partly run
    control that compares no pair of the claim on its runs present is pending, never "changes".
    ``interim_cases`` > 0: a first-packing look ahead on that many cases (:func:`control_verdicts`),
    status ``interim (holds|changes|no comparison on packing 1 of N cases)``."""
    rows = []
    planned = len(done) + len(missing)
    present = baseline if baseline_present is None else baseline_present
    of = f"on packing 1 of {interim_cases} cases"
    for _, b in baseline.iterrows():
        k = int(b["claim"])
        c = control[control["claim"] == k].iloc[0]
        bp = present[present["claim"] == k].iloc[0]
        verdict, base_verdict = "", str(b["verdict"])
        if not _covered(b):
            status = f"not covered by {label}"
        elif not done:
            status = "not run"
        elif not (_covered(bp) and _covered(c)):
            status = (f"{INTERIM} (no comparison {of})" if interim_cases else
                      "partly run (no comparison on the runs present)")
        else:
            verdict, base_verdict = str(c["verdict"]), str(bp["verdict"])
            status = "holds" if verdict == base_verdict else "changes"
            if interim_cases:
                status = f"{INTERIM} ({status} {of})"
            elif missing:
                status = f"partly run ({status} on the runs present)"
        rows.append({"claim": k, "control": label, "level": level, "verdict": verdict, "baseline": base_verdict,
                     "status": status, "runs_done": len(done), "runs_planned": planned,
                     "missing": "; ".join(missing), "interim_cases": interim_cases})
    return pd.DataFrame(rows, columns=CONTROL_COLUMNS)


def cases_present(config: dict, level: str, done: list[str]) -> list[str]:
    """The level's cases whose every run is present."""
    runs: dict[str, list[str]] = {}
    for r in level_runs(config, level):
        runs.setdefault(split_run(r)[0], []).append(r)
    return [c for c in level_cases(config, level) if c in runs and all(r in done for r in runs[c])]


def control_verdicts(config: dict, base: str, root: Path) -> pd.DataFrame:
    """:func:`control_rows` for every control of ``base`` (empty without one), one pass per control
    level: the baseline on all the control's cases (coverage) and, beside the control, on its cases
    present. A several-packing control still running (the reference) also gets rows ``<control>, packing
    1``: the claims on packing 1 alone of every case whose packing-1 run is present, beside ``base``'s on
    the same packings (as Ma/2 is judged); a look ahead, never a control (``interim_cases`` > 0)."""
    frames = []
    for lvl in control_levels(config, base):
        cases = level_cases(config, lvl)
        seeds = level_seeds(config["fidelities"][lvl])
        done, missing = runs_done(config, lvl, root)
        present = cases_present(config, lvl, done)
        label = control_label(config, lvl)
        first = [c for c in cases if f"{c}/seed{seeds[0]}" in done or c in done] if len(seeds) > 1 and missing else []
        with tempfile.TemporaryDirectory() as work:
            def claims_of(level, of_cases, of_seeds, name):
                return view_claims(config, level, of_cases, of_seeds, root, Path(work) / name)
            b = claims_of(base, cases, seeds, "base")
            bp, c = b, b  # a control with no run has no verdict to evaluate (its rows say "not run")
            if present:
                bp = b if len(present) == len(cases) else claims_of(base, present, seeds, "base_present")
                c = claims_of(lvl, present, seeds, "control")
            elif done:  # runs present, no case complete: nothing to compare yet
                bp = c = b.assign(reason="inputs missing: no case of the control complete", carried_by="no comparison")
            frames.append(control_rows(b, c, label, lvl, done, missing, baseline_present=bp))
            if first:
                frames.append(control_rows(
                    b, claims_of(lvl, first, seeds[:1], "control_first"), f"{label}, packing {seeds[0]}", lvl,
                    [r for r in done if split_run(r)[1] in (None, seeds[0])], [],
                    baseline_present=claims_of(base, first, seeds[:1], "base_first"), interim_cases=len(first)))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=CONTROL_COLUMNS)


def interim_counts(controls: pd.DataFrame) -> dict[str, int]:
    """The interim labels of a controls table and the cases each compares (``interim_cases`` > 0); a table
    without the column (an older lbmpipe's) is an error."""
    if "interim_cases" not in controls:
        raise ValueError("controls.csv has no 'interim_cases' column (written by an older lbmpipe): rebuild it with "
                         "snakemake --forcerun robustness")
    n = pd.to_numeric(controls["interim_cases"], errors="raise").astype(int)
    return {str(lbl): int(k) for lbl, k in zip(controls["control"], n) if k > 0}


def column_header(label: str, interim_cases: int = 0) -> str:
    """A control's column in the robustness table: ``under <label>`` (``... (interim, N cases)``: interim)."""
    return f"under {label}" + (f" ({INTERIM}, {interim_cases} cases)" if interim_cases else "")


def robust_column(base_verdicts: dict[int, str], controls: pd.DataFrame) -> dict[int, str]:
    """``robust_under_controls`` per claim from :func:`control_rows`' table (module docstring): a verdict
    changes only under a complete control; under one partly run it is pending; interim rows never count."""
    interim = interim_counts(controls)
    out = {}
    for k, verdict in base_verdicts.items():
        rows = controls[(controls["claim"] == k) & ~controls["control"].isin(list(interim))] if len(controls) else controls
        covering = rows[~rows["status"].astype(str).str.startswith("not covered")] if len(rows) else rows
        if not len(covering):
            out[k] = "not covered by any control"
            continue
        status = covering["status"].astype(str)
        changed = list(covering.loc[status == "changes", "control"])
        pending = list(covering.loc[(status == "not run") | status.str.startswith("partly run"), "control"])
        if changed:
            out[k] = "no: changes under " + ", ".join(changed) + (f" (pending: {', '.join(pending)})" if pending else "")
        elif pending:
            out[k] = "pending: " + ", ".join(pending)  # the controls not (fully) run
        else:
            out[k] = "yes" if verdict != "inconclusive" else "yes (inconclusive under every control)"
    return out


# ------------------------------------------------------------------------------------------------
# shifts and the systematic term


def _histogram(run_dir: Path) -> pd.DataFrame | None:
    try:
        h = pd.read_csv(Path(run_dir) / "orientation.csv")
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None
    return h if len(h) else None


def _observables(run_dir: Path) -> dict[tuple[str, str], tuple[float, float]]:
    """(value, 95 % half-width) of each shifted observable of a completed run or case."""
    rec = completed_record(run_dir)
    if rec is None:
        return {}
    out = {("profile", "profile_distance"): (profile_distance(Path(run_dir) / "profile.csv"), float("nan"))}
    for key, v in stats_values(rec[1]).items():
        out[("omega" if key.startswith("mean_abs_omega") else "angle", key)] = v
    h = _histogram(run_dir)
    if h is not None and {"kind", "fraction"} <= set(h.columns):
        for _, r in h.iterrows():
            out[("fraction", f"{r['kind']}[{r['bin_lo_deg']:g}-{r['bin_hi_deg']:g}]")] = (
                float(r["fraction"]), float(r.get("ci95", float("nan"))))
    return out


def shift_rows(config: dict, base: str, root: Path) -> pd.DataFrame:
    """Per control, case and observable: ``base``'s value and the control's on the same packings
    (one packing: seed 1 of both; all packings: the combined records; a case of a several-packing
    control with only some packings run: packing 1 of both, or nothing while packing 1 is missing)
    and the shift."""
    rows = []
    for lvl in control_levels(config, base):
        fid = config["fidelities"][lvl]
        seeds = level_seeds(fid)
        one = len(seeds) == 1
        done = set(runs_done(config, lvl, root)[0])
        for case in level_cases(config, lvl):
            seeded = config["cases"][case].get("particles") is not None
            sub = "seed1" if (one and seeded) else ""
            if seeded and not one and not all(f"{case}/seed{k}" in done for k in seeds):
                if f"{case}/seed{seeds[0]}" not in done:
                    continue  # no packing of the control to set beside the base's yet
                sub = f"seed{seeds[0]}"  # the combined record would hold fewer packings than the base's
            bdir = Path(root) / base / "cases" / case / sub
            cdir = Path(root) / lvl / "cases" / case / sub
            b, c = _observables(bdir), _observables(cdir)
            for (obs, key) in [k for k in b if k in c]:
                (vb, cb), (vc, cc) = b[(obs, key)], c[(obs, key)]
                if not (math.isfinite(vb) and math.isfinite(vc)):
                    continue
                rel = obs in ("omega", "profile")
                shift = (vc - vb) / abs(vb) if rel and vb else (vc - vb)
                rows.append({"control": control_label(config, lvl), "case": case, "observable": obs, "key": key,
                             "base": vb, "base_ci95": cb, "control_value": vc, "control_ci95": cc, "shift": shift,
                             "sensitivity": is_sensitivity(config["cases"][case])})
    return pd.DataFrame(rows, columns=SHIFT_COLUMNS)


def is_sensitivity(case: dict) -> bool:
    """A case no claim's verdict rests on: a suspension with its collisions switched off (bodies free
    to overlap, ``collisions: false``; claim 14 names it a sensitivity only)."""
    return case.get("particles") is not None and case.get("collisions", True) is False


def systematic_from_shifts(shifts: pd.DataFrame) -> dict:
    """The largest |shift| per observable (the systematic term of the verdict rule) and where it was
    measured: ``{"terms": {omega_rel, angle_deg, fraction_abs, profile_rel_l2}, "figures": {...}}``;
    an observable with no shift measured is 0 and says so. The profile's term comes from the particle
    cases only when there are any (the particle-free flows carry the wall's own error). Sensitivity
    cases (:func:`is_sensitivity`) enter no verdict, so they set no term."""
    terms, figures = {}, {}
    if len(shifts):
        shifts = shifts[~shifts["sensitivity"].astype(bool)]
    for obs, key in SYSTEMATIC_OF.items():
        sub = shifts[shifts["observable"] == obs] if len(shifts) else shifts
        if obs == "profile" and len(sub) and (~sub["case"].str.startswith("flow")).any():
            sub = sub[~sub["case"].str.startswith("flow")]
        if not len(sub):
            terms[key], figures[key] = 0.0, "no shift measured (no control run)"
            continue
        i = sub["shift"].abs().idxmax()
        r = sub.loc[i]
        terms[key] = float(abs(r["shift"]))
        figures[key] = (f"{r['control']} on {r['case']} {r['key']}: {r['base']:.4g} -> {r['control_value']:.4g} "
                        f"({r['shift']:+.4g}; over {len(sub)} shifts)")
    return {"terms": terms, "figures": figures}


def systematic_terms_for(config: dict, measured: dict | None) -> dict:
    """The systematic term the verdicts use: the measured one (:func:`systematic_from_shifts`'
    ``terms``), each observable overridden by ``config.yaml``'s ``systematic`` where that is above 0."""
    override = config.get("systematic") or {}
    got = dict((measured or {}).get("terms") or {})
    return {k: float(override[k]) if float(override.get(k, 0.0)) > 0 else float(got.get(k, 0.0))
            for k in SYSTEMATIC_KEYS}


# ------------------------------------------------------------------------------------------------
# convergence of the reference


def convergence_check(coarse: tuple[float, float], fine: tuple[float, float]) -> tuple[str, str]:
    """Issue 47 item 3 on one observable: (value, 95 % half-width) on the two finest lattices.
    ``converged`` when both intervals are at most :data:`CONVERGED_MAX_CI` of the value and the
    values differ by less than :data:`CONVERGED_REL` of the finer one or less than their combined
    interval; else ``not converged`` (or ``no interval``); with the figures."""
    (a, ca), (b, cb) = coarse, fine
    if not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return "not available", "a value is missing"
    rel = abs(a - b) / abs(b)
    both = math.hypot(ca, cb) if math.isfinite(ca) and math.isfinite(cb) else float("nan")
    wa, wb = ca / abs(a) if a else float("inf"), cb / abs(b)
    figures = (f"{a:.4g} ± {ca:.2g} vs {b:.4g} ± {cb:.2g}: differ by {100 * rel:.1f} % "
               f"(combined interval {100 * both / abs(b):.1f} %), intervals {100 * wa:.1f} % and {100 * wb:.1f} %")
    if not math.isfinite(both):
        return "no interval", figures
    if max(wa, wb) > CONVERGED_MAX_CI:
        return "not converged (interval wider than 10 %)", figures
    if rel < CONVERGED_REL or abs(a - b) < both:
        return "converged", figures
    return "not converged", figures


def convergence_rows(config: dict, base: str, root: Path) -> pd.DataFrame:
    """The check on |Omega| per axis and the mean angle of every case a refining control
    (``refines: <reference>``) shares with the reference: the reference (coarser) and the refinement
    on packing seed 1 (the refinement runs one packing)."""
    rows = []
    for fine in control_levels(config, base):
        coarse = config["fidelities"][fine].get("refines")
        if coarse is None or coarse not in config["fidelities"]:
            continue
        for case in [c for c in level_cases(config, fine) if c in level_cases(config, coarse)]:
            sub = "seed1" if config["cases"][case].get("particles") is not None else ""
            a = completed_record(Path(root) / coarse / "cases" / case / sub)
            b = completed_record(Path(root) / fine / "cases" / case / sub)
            va, vb = (stats_values(a[1]) if a else {}), (stats_values(b[1]) if b else {})
            for key in sorted(set(va) | set(vb)):
                if key not in va or key not in vb:
                    missing = coarse if key not in va else fine
                    rows.append({"case": case, "observable": key, "status": "not run", "figures": f"{missing} missing"})
                    continue
                status, figures = convergence_check(va[key], vb[key])
                rows.append({"case": case, "observable": key, "coarse": va[key][0], "coarse_ci95": va[key][1],
                             "fine": vb[key][0], "fine_ci95": vb[key][1],
                             "rel_diff": (va[key][0] - vb[key][0]) / vb[key][0] if vb[key][0] else float("nan"),
                             "status": status, "figures": figures})
            if not va and not vb:
                rows.append({"case": case, "observable": "all", "status": "not run",
                             "figures": f"{coarse} and {fine} missing"})
    return pd.DataFrame(rows, columns=CONVERGENCE_COLUMNS)


# ------------------------------------------------------------------------------------------------
# health side by side


def density_floor(run_dir: Path) -> float | None:
    """The run's density floor (``numerics.density_floor`` of its ``scene.yaml``, the model's default
    where the scene leaves it out; None: no floor). A run without its scene is an error."""
    path = Path(run_dir) / "scene.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the run's density floor is read from its scene; "
                                "restore it from git or rerun the case")
    numerics = (yaml.safe_load(path.read_text()) or {}).get("numerics") or {}
    return numerics.get("density_floor", Numerics.model_fields["density_floor"].default)


def run_health_figures(run_dir: Path) -> dict:
    """Net mass put back by the mass correction, negative where it took mass out (of the fluid mass;
    of the mass through the pipe) and the share of samples with a node at the run's density floor
    (:func:`density_floor`; 0 without a floor), of one run (NaN where not recorded)."""
    s = read_json(Path(run_dir) / "summary.json")
    if s is None:
        return {"status": "not run"}
    fr = read_flow_rate(run_dir)
    share, n = float("nan"), 0
    if fr is not None and "max_density_deviation" in fr and len(fr):
        dev = fr["max_density_deviation"].astype(float)
        n = int(len(dev))
        floor = density_floor(run_dir)
        share = 0.0 if floor is None else float((dev >= (1.0 - floor) - 1e-9).mean())
    signed = mass_corrected_signed(s)
    return {"status": s.get("status"), "mass_corrected_fluid": signed,
            "mass_corrected_throughflow": math.copysign(mass_corrected_throughflow(s), signed),
            "floor_sample_share": share, "samples": n}


def health_rows(config: dict, base: str, root: Path) -> pd.DataFrame:
    """Per case of the reference and run: the paper's method (``base``) beside the reference, mean
    over the packings the reference runs; "not run" where the reference's runs are missing."""
    ref = reference_level(config, base)
    if ref is None:
        return pd.DataFrame(columns=HEALTH_COLUMNS)
    rows = []
    for case in level_cases(config, ref):
        runs = [r for r in level_runs(config, ref) if split_run(r)[0] == case]
        for lvl in (base, ref):
            got = [run_health_figures(Path(root) / lvl / "cases" / r) for r in runs]
            ran = [g for g in got if g.get("status") != "not run"]
            if not ran:
                rows.append({"case": case, "level": lvl, "status": "not run"})
                continue
            statuses = sorted({str(g["status"]) for g in ran})
            row = {"case": case, "level": lvl,
                   "status": ";".join(statuses) + (f" ({len(ran)} of {len(runs)} runs)" if len(ran) < len(runs) else "")}
            for k in ("mass_corrected_fluid", "mass_corrected_throughflow", "floor_sample_share"):
                v = np.array([g.get(k, float("nan")) for g in ran], float)
                row[k] = float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
            row["samples"] = int(sum(g.get("samples", 0) for g in ran))
            rows.append(row)
    return pd.DataFrame(rows, columns=HEALTH_COLUMNS)


# ------------------------------------------------------------------------------------------------
# cost


def _wall_against_model(config: dict, level: str, root: Path, model) -> tuple[float, float, float, int]:
    """(wall seconds of the level's runs present, the model's prediction for those runs, its prediction
    for the runs missing, how many are missing); predictions 0 without a model."""
    fid = config["fidelities"][level]
    wall, done_pred, missing_pred, missing = 0.0, 0.0, 0.0, 0
    for run in level_runs(config, level):
        s = read_json(Path(root) / level / "cases" / run / "summary.json")
        name, case = run_case(config, run)
        pred = 0.0
        if model is not None:
            sc = Scene.model_validate(case_scene(name, case, level, fid))
            pred = predict(sc, derive(sc), model, 1.0)
        if s is not None and s.get("wall_seconds"):
            wall += float(s["wall_seconds"])
            done_pred += pred
        elif model is not None:
            missing_pred += pred
            missing += 1
    return wall, done_pred, missing_pred, missing


def plan_factor(config: dict, level: str, root: Path, model, own: tuple | None = None) -> tuple[float, str]:
    """What the cost model's prediction is multiplied by for the level's missing runs, and from what:
    the level's own runs (summed wall over summed prediction), else the other levels' runs of its
    ``method``, else the accurate method's measured cost over the paper's (``accurate_factor``) for
    ``method: accurate``, else 1. ``own``: the level's ``_wall_against_model`` when the caller has it."""
    method = config["fidelities"][level].get("method")
    wall, pred, _, _ = own if own is not None else _wall_against_model(config, level, root, model)
    if pred > 0:
        return wall / pred, "its own runs"
    if method is not None:
        same = [_wall_against_model(config, other, root, model) for other, f in config["fidelities"].items()
                if other != level and f.get("method") == method]
        wall, pred = sum(x[0] for x in same), sum(x[1] for x in same)
        if pred > 0:
            return wall / pred, f"runs of method {method}"
    if method == "accurate":
        return accurate_factor(config, root), "credible_accurate"
    return 1.0, "the model"


def level_core_hours(config: dict, level: str, root: Path) -> tuple[float, float, str]:
    """(measured core-hours of the runs present, planned core-hours of the whole level, source).
    Measured: each run's ``wall_seconds`` (one thread a run). Planned: the measured runs plus the
    others predicted by the wall-time model of the committed runs (``cases.wall_model``, at a core
    each) times ``plan_factor`` (what runs of the same method took against the model)."""
    model = wall_model("credible", Path(root).parent)
    own = _wall_against_model(config, level, root, model)
    measured, _, missing_pred, missing = own
    factor = plan_factor(config, level, root, model, own)[0] if missing else 1.0
    src = "measured" if not missing else ("cost model" if not measured else "measured + cost model")
    return measured / 3600, (measured + factor * missing_pred) / 3600, src


def accurate_factor(config: dict, root: Path) -> float:
    """The accurate method's wall time over the paper method's on the same runs (``compare_with``
    level's seed-1 runs against the compared level's); 1 when none is there."""
    for name, fid in config["fidelities"].items():
        other = fid.get("compare_with")
        if other is None:
            continue
        a = b = 0.0
        for run in level_runs(config, name):
            sa = read_json(Path(root) / name / "cases" / run / "summary.json") or {}
            sb = read_json(Path(root) / other / "cases" / run / "summary.json") or {}
            if sa.get("wall_seconds") and sb.get("wall_seconds"):
                a += float(sa["wall_seconds"])
                b += float(sb["wall_seconds"])
        if b > 0:
            return a / b
    return 1.0


def cost_rows(config: dict, base: str, root: Path, controls: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for lvl in control_levels(config, base):
        label = control_label(config, lvl)
        sub = controls[controls["control"] == label] if len(controls) else controls
        measured, planned, src = level_core_hours(config, lvl, root)
        done, missing = runs_done(config, lvl, root)
        rows.append({"control": label, "level": lvl, "core_hours_measured": measured, "core_hours_planned": planned,
                     "source": src, "runs_done": len(done), "runs_planned": len(done) + len(missing),
                     "claims_covered": int((~sub["status"].str.startswith("not covered")).sum()) if len(sub) else 0,
                     # a complete control's verdicts only (a partly run one's are pending)
                     "claims_changed": ",".join(str(int(k)) for k in sub.loc[sub["status"] == "changes", "claim"])
                     if len(sub) else "",
                     "claims_held": int((sub["status"] == "holds").sum()) if len(sub) else 0})
    return pd.DataFrame(rows)


def cost_figure(cost: pd.DataFrame, stem: Path) -> list[Path]:
    """Verdicts robust against cost: per control, its core-hours (measured, else planned: hollow)
    against the claims it covers (square), whose verdict holds (o) and changes (x) under it; a
    control not (fully) run is labelled so."""
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for i, r in cost.reset_index(drop=True).iterrows():
        x = max(float(r["core_hours_measured"]) if r["runs_done"] else float(r["core_hours_planned"]), 1e-3)
        changed = len([c for c in str(r["claims_changed"]).split(",") if c])
        filled = r["runs_done"] == r["runs_planned"] and r["runs_planned"] > 0
        face = f"C{i}" if filled else "white"
        ax.plot([x], [r["claims_covered"]], "s", color=f"C{i}", mfc=face, ms=8)
        ax.plot([x], [r["claims_held"]], "o", color=f"C{i}", mfc=face, ms=9,
                label=f"{r['control']}: covers {r['claims_covered']}, held {r['claims_held']}, changed {changed}")
        ax.plot([x], [changed], "x", color=f"C{i}", ms=9)
        note = ("not run (planned)" if r["runs_done"] == 0 else
                "measured" if filled else f"partly run {r['runs_done']}/{r['runs_planned']}")
        ax.annotate(f"{r['control']}: {note}", (x, r["claims_covered"]), textcoords="offset points",
                    xytext=(6, 6 + 11 * (i % 3)), fontsize=7, color=f"C{i}")
    ax.set_xscale("log")
    ax.set_ylim(-0.7, 15.5)
    ax.set_xlabel("core-hours (filled: measured, every run done; hollow: planned by the cost model, or partly run)")
    ax.set_ylabel("claims: covered (square), verdict holds (o), changes (x)")
    ax.set_title("What accuracy costs: verdicts under each control against its core-hours")
    if len(cost):
        ax.legend(fontsize=7, loc="center right")
    return save(fig, stem)


# ------------------------------------------------------------------------------------------------
# the outputs


def write(config: dict, base: str, root: Path, out_dir: Path) -> dict:
    """Write the files of the module docstring under ``out_dir`` (``results/<base>/robustness/``) and
    return the summary (also ``summary.json``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    controls = control_verdicts(config, base, root)
    shifts = shift_rows(config, base, root)
    measured = systematic_from_shifts(shifts)
    conv = convergence_rows(config, base, root)
    health = health_rows(config, base, root)
    cost = cost_rows(config, base, root, controls)
    unstable_rows(config, base, root).to_csv(out_dir / "unstable.csv", index=False, float_format="%.6g")
    controls.to_csv(out_dir / "controls.csv", index=False)
    shifts.to_csv(out_dir / "shifts.csv", index=False, float_format="%.6g")
    conv.to_csv(out_dir / "convergence.csv", index=False, float_format="%.6g")
    health.to_csv(out_dir / "health.csv", index=False, float_format="%.6g")
    cost.to_csv(out_dir / "cost.csv", index=False, float_format="%.4g")
    cost_figure(cost, out_dir / "cost_robustness")
    write_json(out_dir / "systematic.json", {**measured, "used": systematic_terms_for(config, measured)})
    summary = {"base": base, "controls": [{"level": lvl, "control": control_label(config, lvl),
                                           "runs_done": len(runs_done(config, lvl, root)[0]),
                                           "runs_planned": len(level_runs(config, lvl))}
                                          for lvl in control_levels(config, base)],
               "systematic": measured, "reference": reference_level(config, base)}
    write_json(out_dir / "summary.json", summary)
    return summary


def robustness_table(claims: pd.DataFrame, controls: pd.DataFrame, short: bool = False) -> pd.DataFrame:
    """One row per claim: the level's verdict, per control (:func:`column_header`) its verdict with its
    status and the baseline's (or its status alone: not covered / not run), ``robust_under_controls``.
    ``short`` (the document; legend in ``paper/reproduction.md.j2``): a verdict that holds drops the
    baseline, "so far" (partly run), "no pair (yet)" (no comparison), "–" (not covered)."""
    out = claims[["claim", "verdict", "verdict_with_systematic"]].copy()
    interim = interim_counts(controls)
    for label in (list(dict.fromkeys(controls["control"])) if len(controls) else []):
        sub = controls[controls["control"] == label].set_index("claim")

        def cell(k, sub=sub, interim=label in interim):
            r = sub.loc[k]
            s, same = str(r["status"]), r["verdict"] == r["baseline"]
            if s.startswith(("not covered", "not run")) or not r["verdict"]:
                return s if not short else "–" if s.startswith("not covered") else s if s == "not run" else \
                    "no pair" + ("" if interim else " yet")  # the interim look has no other packings to wait for
            word = ("holds" if same else "changes") + (" so far" if short and s.startswith("partly run") else "")
            s = word if short or interim else s  # interim: judged on the rows' verdicts, the status is for the reader
            return f"{r['verdict']} ({s})" if short and same else f"{r['verdict']} ({s}; baseline {r['baseline']})"
        out[column_header(label, interim.get(label, 0))] = out["claim"].map(cell)
    out["robust_under_controls"] = out["claim"].map(robust_column(dict(zip(claims["claim"], claims["verdict"])),
                                                                  controls))
    return out


def read_controls(controls_csv: Path, required: bool = False) -> pd.DataFrame:
    """``controls.csv`` (:func:`write`): empty where the level has none; an error if ``required`` and missing."""
    if required and not Path(controls_csv).is_file():
        raise FileNotFoundError(f"{controls_csv} is missing though tables/robustness.csv names controls: rebuild "
                                "both with snakemake --forcerun robustness")
    try:
        return pd.read_csv(controls_csv, dtype={"verdict": str, "baseline": str, "missing": str}, keep_default_na=False)
    except (OSError, pd.errors.EmptyDataError):
        return pd.DataFrame(columns=CONTROL_COLUMNS)


def add_to_claims(claims_csv: Path, controls_csv: Path, table_csv: Path) -> pd.DataFrame:
    """Add the robustness columns to a level's ``claims.csv`` (``verdict_under_<control>``, the
    ``status_under_<control>`` and ``robust_under_controls``) and write the table
    (:func:`robustness_table`) to ``table_csv``."""
    claims = pd.read_csv(claims_csv)
    controls = read_controls(controls_csv)
    for label in (list(dict.fromkeys(controls["control"])) if len(controls) else []):
        sub = controls[controls["control"] == label].set_index("claim")
        claims[f"verdict_under_{label}"] = claims["claim"].map(sub["verdict"])
        claims[f"status_under_{label}"] = claims["claim"].map(sub["status"])
    claims["robust_under_controls"] = claims["claim"].map(
        robust_column(dict(zip(claims["claim"], claims["verdict"])), controls))
    claims.to_csv(claims_csv, index=False)
    table = robustness_table(claims, controls)
    Path(table_csv).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(table_csv, index=False)
    return table


# ------------------------------------------------------------------------------------------------
# the document


def unstable_rows(config: dict, base: str, root: Path) -> pd.DataFrame:
    """Per run of each ``unstable_of: base`` level: how ``base``'s run of the same packing ended
    (status, steps) beside how this one did (``not run`` where its summary is missing)."""
    rows = []
    for lvl in unstable_levels(config, base):
        fid = config["fidelities"][lvl]
        for run in level_runs(config, lvl):
            b = read_json(Path(root) / base / "cases" / run / "summary.json") or {}
            s = read_json(Path(root) / lvl / "cases" / run / "summary.json") or {}
            rows.append({"run": run, "level": lvl, "method": fid.get("method", "paper"),
                         "mach_factor": fid.get("mach_factor", 1.0), "base_status": b.get("status", "not run"),
                         "base_steps": b.get("steps"), "status": s.get("status", "not run"), "steps": s.get("steps"),
                         "simulated_s": s.get("simulated_seconds"), "wall_s": s.get("wall_seconds")})
    return pd.DataFrame(rows, columns=UNSTABLE_COLUMNS)


def _variants_said(evidence: dict) -> str:
    """The variant runs of an unstable run's evidence (``benchmarks/unstable_cause.py``), a clause each."""
    return "; ".join(f"{v.get('variant')} ({v.get('mode')}): {v.get('status')}" for v in evidence.get("variants") or [])


def unstable_causes(fid_dir: Path) -> list[dict]:
    """The measured cause of each unstable run (``unstable/<case>.json`` of
    ``benchmarks/unstable_cause.py``): the guard's message says "likely cause"; this is the
    mechanism the evidence shows, and the variants' outcomes."""
    out = []
    try:
        reruns = pd.read_csv(Path(fid_dir) / "robustness" / "unstable.csv", keep_default_na=False)
    except (OSError, pd.errors.EmptyDataError):
        reruns = pd.DataFrame(columns=UNSTABLE_COLUMNS)
    for path in sorted((Path(fid_dir) / "unstable").glob("*.json")):
        d = read_json(path) or {}
        variants = _variants_said(d)
        case = d.get("case", path.stem)
        mine = [r for r in reruns.itertuples() if str(r.run).split("/seed")[0] == case]
        ends = [f"{r.status}" + (f" after {int(float(r.steps))} steps" if str(r.steps) not in ("", "nan", "None") else "")
                for r in mine]
        again = [f"{r.method} at Mach x {r.mach_factor} ({r.level}): {e}" for r, e in zip(mine, ends)]
        # the rerun's own diagnosis, where it ended unstable too (<level>/unstable/<case>.json)
        there = {r.level: read_json(Path(fid_dir).parent / str(r.level) / "unstable" / f"{case}.json") or {} for r in mine}
        measured = "; ".join(f"{lvl}: " + "; ".join(e["mechanism"])
                             + (f". One change at a time: {_variants_said(e)}" if e.get("variants") else "")
                             for lvl, e in there.items() if e.get("mechanism"))
        out.append({"case": case, "scene": d.get("scene", ""), "rerun": "; ".join(again) or "not rerun",
                    "outcome": "; ".join(ends) or "not rerun",
                    "rerun_mechanism": measured,
                    "rerun_cause": "; ".join(e["mechanism"][0].split(":")[0] for e in there.values() if e.get("mechanism")),
                    "step": (d.get("committed") or {}).get("steps"),
                    "mechanism": " ".join(d.get("mechanism") or []) or "not measured",
                    "variants": variants or "none run", "complete": bool(d.get("complete")),
                    "file": path.name})
    return out


def robustness_section(fid_dir: Path, out_dir: Path) -> dict | None:
    """The document's robustness section (``paper/reproduction.md.j2``) from
    ``tables/robustness.csv`` and ``robustness/``; None where the level has no controls."""
    fid_dir = Path(fid_dir)
    rob = fid_dir / "robustness"
    try:
        table = pd.read_csv(fid_dir / "tables" / "robustness.csv", keep_default_na=False)
        cost = pd.read_csv(rob / "cost.csv", keep_default_na=False)
    except (OSError, pd.errors.EmptyDataError):
        return None
    if not len(cost):
        return None
    robust = table["robust_under_controls"].astype(str)
    counts = {"robust": int((robust.str.startswith("yes")).sum()), "changed": int(robust.str.startswith("no:").sum()),
              "pending": int(robust.str.startswith("pending").sum()),
              "not covered": int(robust.str.startswith("not covered").sum())}
    cost_show = cost[["control", "level", "runs_done", "runs_planned", "core_hours_measured", "core_hours_planned",
                      "source", "claims_changed"]].copy()
    cost_show["status"] = [("not run" if r.runs_done == 0 else "complete" if r.runs_done == r.runs_planned else
                            f"partly run ({r.runs_done} of {r.runs_planned})") for r in cost.itertuples()]

    def read(name):
        try:
            return pd.read_csv(rob / name, keep_default_na=False)
        except (OSError, pd.errors.EmptyDataError):
            return pd.DataFrame()
    sysj = read_json(rob / "systematic.json") or {}
    fig = rob / "cost_robustness.png"
    # shown: a cell that holds drops its baseline (the same verdict); the verdicts with the systematic
    # term are in the claims summary (``tables/robustness.csv`` keeps every column)
    controls = read_controls(rob / "controls.csv", required=any(c.startswith("under ") for c in table.columns))
    shown = robustness_table(table, controls, short=True).drop(columns=["verdict_with_systematic"])
    health = read("health.csv")
    conv = read("convergence.csv")
    return {"table": table_of(shown), "counts": counts, "cost": table_of(cost_show),
            "not_run": [r.control for r in cost.itertuples() if r.runs_done == 0],
            "planned_total": float(cost["core_hours_planned"].sum()),
            "systematic": [{"key": k, "value": v, "figures": (sysj.get("figures") or {}).get(k, "")}
                           for k, v in (sysj.get("used") or {}).items()],
            "figure": relative_href(fig, Path(out_dir)) if fig.exists() else None,
            "health": table_of(health) if len(health) else None,
            "convergence": table_of(conv) if len(conv) else None,
            "unstable": unstable_causes(fid_dir)}
