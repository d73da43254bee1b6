"""The literate reproduction: the document that puts the method, the parameters, the figures, the
claims and the costs of one fidelity level together, the paper's equations linked to the code.

Equation links are :mod:`lbmpipe.reproduction.equations`' (the index read from the docstrings,
:func:`~lbmpipe.reproduction.equations.check_links`); the sections read from the results are
:mod:`lbmpipe.reproduction.document_sections`'.

Document. :func:`build_document` renders ``paper/reproduction.md.j2`` (Jinja2) from a results
directory ``results/<fid>/``. The template receives data only: every number in the text is read
from the results (or derived from ``config.yaml`` through :func:`lbmpipe.units.derive`); a section
whose input is absent says ``not built at this level: <file> missing``. It is laid out as a paper:
an abstract with the verdict in numbers, the method (the key equations as displayed maths beside a
short excerpt of their code, ``equations.KEY_EQUATIONS``; Fig. 3 as four snapshots), one
section per figure of the paper (what the paper says, what we see, why: a physical reading of the
diagnostics of its cases, :mod:`lbmpipe.reproduction.findings`), the claims in one line each, the
limitations and the run health; the long tables follow as appendices (:func:`main_text` is
everything before them; at most :data:`MAIN_WORDS` and :data:`TOTAL_WORDS` words, a test keeps it). The web page beside it
(``.html``: maths as MathML, contents, anchors per claim and figure) is :mod:`lbmpipe.reproduction.webpage`'s.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import jinja2
import pandas as pd

from ..scene import Numerics
from . import health
from .robustness import robustness_section

from .unpackable import read_summary
from .document_sections import (DECISIONS, PAPER_CAPTIONS, case_rows, convergence_section, figure_entries, fmt,
                                health_section, method_comparison_section, method_section,
                                parameter_rows, read_table, runtime_section, stationarity_section,
                                table_of)
from .equations import check_links, equation_index, key_equations, other_equations, relative_href
from .claim_rules import find_case
from .claims import REFERENCE_DESC
from .figures import figure_cases
from .profile_error import read_profile_error
from .provenance import provenance_text
from . import findings
from .snapshots import FIG3_CAPTION, fig3_cases, snapshot_gallery
from .webpage import markdown_to_html


# --------------------------------------------------------------------------------------------------
# the paper-shaped document: key equations beside their code, one section per figure, the verdict


#: Which of the paper's claims each figure section discusses (NOTES.md: the claims and the figures they rest on).
FIGURE_CLAIMS: dict[str, list[int]] = {"4": [1, 3], "5": [4, 5], "6": [6], "7": [2, 7, 8], "8": [9, 10, 14],
                                       "9": [11, 12], "10": [13]}

#: Heading of each figure section (what the figure varies).
FIGURE_TITLES: dict[str, str] = {
    "4": "cylinder aspect ratio and rotation", "5": "cube concentration and rotation",
    "6": "Reynolds number and cube rotation", "7": "particle shape and size", "8": "cylinder orientation",
    "9": "cube orientation", "10": "velocity profile",
}


#: Word limits of the document (:func:`word_count`): the main text (:func:`main_text`) and the whole.
MAIN_WORDS, TOTAL_WORDS = 4000, 10000


def main_text(md: str) -> str:
    """The document before its first appendix heading (``## Appendix ...``)."""
    m = re.search(r"^## Appendix", md, flags=re.M)
    return md[:m.start()] if m else md


def word_count(md: str) -> int:
    """Words of Markdown text: link targets and titles, image paths and table rules left out; a
    word is a whitespace-separated token with a letter or digit."""
    text = re.sub(r"\]\([^)]*\)", "]", md)
    return sum(1 for tok in text.split() if re.search(r"[A-Za-z0-9]", tok))


def _case_dirs(fid_dir: Path, config: dict) -> dict[str, dict]:
    """Per case of the config: its summary.json and stats.json (None where absent)."""
    out = {}
    for name in config.get("cases") or {}:
        cdir = Path(fid_dir) / "cases" / name
        out[name] = {"summary": read_summary(cdir, config["cases"][name]), "stats": health.read_json(cdir / "stats.json")}
    return out


def averaging_s(summary: dict | None, stats: dict | None) -> float:
    """Simulated time averaged after spin-up of a case (s): run length minus spin-up; NaN if not run.
    A case combined over packings (``stats["seeds"]``): the mean over its packings of each one's."""
    if not summary or summary.get("status") != "completed":
        return float("nan")
    seeds = [x for x in (stats or {}).get("seeds") or [] if x.get("status") == "completed"]
    if seeds:
        spins = sum(float(x.get("spinup_s") or 0.0) for x in seeds)
        return (float(summary.get("simulated_seconds", float("nan"))) - spins) / len(seeds)
    spin = (stats or {}).get("spinup_s", summary.get("spinup_s", 0.0))
    spin = spin.get("spinup_s", 0.0) if isinstance(spin, dict) else spin
    return float(summary.get("simulated_seconds", float("nan"))) - float(spin or 0.0)


def _clauses(text: str) -> list[str]:
    """``text`` cut at its top-level ``"; "``: a clause's own parentheses (a case's flags seed by
    seed, ``(seed 1: ...; seed 2: ...)``) stay whole."""
    parts, depth, start = [], 0, 0
    for k, ch in enumerate(text):
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        elif ch == ";" and depth == 0 and text[k + 1:k + 2] == " ":
            parts.append(text[start:k])
            start = k + 2
    parts.append(text[start:])
    return parts


def _short_reason(reason: str) -> tuple[str, int, int]:
    """A claim's reason without its lists of missing and flagged cases (``claims``: ``<reason>;
    missing: <case>: <why>; ...; flagged cases: <case>: <flag> (<seeds>); ...``), and how many
    distinct cases each list names."""
    lead, named = [], {"missing": set(), "flagged": set()}
    section = None
    for part in _clauses(str(reason)):
        for key, head in (("missing", "missing: "), ("flagged", "flagged cases: ")):
            if part.startswith(head):
                section, part = key, part[len(head):]
        if section is None:
            lead.append(part)
        else:
            named[section].add(part.split(":", 1)[0].strip())
    text = "; ".join(lead)
    if len(text) > 160:  # e.g. a list of bins per case: the appendix has it all
        text = text[:160].rsplit(",", 1)[0] + " … (appendix)"
    return text, len(named["missing"]), len(named["flagged"])


def _method_cell(r: dict) -> str:
    """The verdict under the accurate method (packing seed 1) and how it stands against the paper
    method's on the same packing, or why there is none."""
    same = str(r.get("same_under_both_methods"))
    acc, paper = r.get("verdict_accurate_method_seed1"), r.get("verdict_paper_method_seed1")
    if same == "yes":
        return f"{acc} (paper method on the same packing: the same)"
    if same == "no":
        return f"{acc} (paper method on the same packing: {paper})"
    return "none: the claim's inputs are missing under one of the methods (packing 1)"


def _method_short(r: dict) -> str:
    """:func:`_method_cell` in the few words of a table cell."""
    same = str(r.get("same_under_both_methods"))
    acc, paper = r.get("verdict_accurate_method_seed1"), r.get("verdict_paper_method_seed1")
    return {"yes": f"{acc} (as the paper's)", "no": f"{acc} (paper's: {paper})"}.get(same, "–")


def _text(r: dict, key: str, default: str = "") -> str:
    v = r.get(key)
    return default if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)


def claims_summary(claims) -> list[dict]:
    """One row per claim: number, statement, verdict, how many comparisons carry it, the verdicts
    without the flagged cases and with the systematic term, the deciding number (``claims.csv``'s
    ``deciding``: the pooled difference, or the deciding comparison or bin) and the reason, shortened."""
    rows = []
    for r in claims.to_dict("records"):
        reason, n_missing, n_flagged = _short_reason(r.get("reason", ""))
        counts = [f"{n} case{'s' if n > 1 else ''} {what}" for n, what in ((n_missing, "missing"),
                                                                             (n_flagged, "flagged")) if n]
        if counts:
            reason += f" ({'; '.join(counts)})"
        number = _text(r, "deciding") or str(r.get("values", "")).split("; ")[0].split(" over ")[0]
        rows.append({"claim": fmt(r["claim"]), "statement": str(r.get("statement", "")),
                     "verdict": str(r.get("verdict", "")), "carried": _text(r, "carried_by", "–"),
                     "without": (f"{_text(r, 'verdict_without_frozen_locked', '–')} / "
                                 f"{_text(r, 'verdict_without_flagged', '–')}"),
                     # with the systematic term; then under the robustness controls (issue 47), where there are any
                     "robust": _text(r, "robust", "–") + (f"; under the controls: {_text(r, 'robust_under_controls')}"
                                                          if _text(r, "robust_under_controls") else ""),
                     "systematic": _text(r, "verdict_with_systematic", "–"),
                     "controls": _text(r, "robust_under_controls", "–"),
                     "number": number, "reason": reason,
                     # the verdict under the accurate method (seed 1), where a level compares with this one
                     "method": _method_cell(r) if "same_under_both_methods" in r else None,
                     "method_short": _method_short(r) if "same_under_both_methods" in r else None})
    return rows


def abstract_section(fid_dir: Path, fidelity: str, config: dict, claims, params: list[dict],
                     cases: dict[str, dict], health_rows: list[dict]) -> dict:
    """The verdict in numbers: claim counts, the particle-free flow against Hagen-Poiseuille, the
    lattice, the averaging time and the packings the results rest on."""
    counts = claims["verdict"].value_counts().to_dict() if claims is not None and "verdict" in claims else {}
    particle = [n for n, c in (config.get("cases") or {}).items() if (c or {}).get("particles")]
    flow = [n for n, c in (config.get("cases") or {}).items() if not (c or {}).get("particles")]
    # the particle-free baseline, as claim 13 and Fig. 10 compute it (one function, profile_error)
    errors = {n: read_profile_error(Path(fid_dir) / "cases" / n / "profile.csv") for n in flow}
    poiseuille = [f"{fmt(e)} at Re {fmt((config['cases'][n] or {}).get('reynolds'))}" for n, e in errors.items()
                  if math.isfinite(e)]
    avg = [averaging_s(cases[n]["summary"], cases[n]["stats"]) for n in particle if n in cases]
    avg = [a for a in avg if math.isfinite(a)]
    seeds = [int(s["n_seeds"]) for n in particle for s in [cases.get(n, {}).get("stats") or {}] if "n_seeds" in s]
    status = {}
    for n in particle:
        st = (cases.get(n, {}).get("summary") or {}).get("status", "not run")
        status[st] = status.get(st, 0) + 1
    lattice = [p for p in params if p["fidelity"] == fidelity]
    flagged = sum(1 for r in health_rows if r["flags"] not in ("none", ""))
    # resolution: lattice spacings across the smallest particle dimension of the level
    dx = ((config.get("fidelities") or {}).get(fidelity) or {}).get("dx_mm")
    dims = [float(v) for n in particle for k, v in ((config["cases"][n] or {}).get("particles") or {}).items()
            if k in ("diameter_mm", "length_mm", "edge_mm")]
    return {
        "n_claims": fmt(sum(counts.values())),
        "counts": ", ".join(f"{fmt(int(v))} {k}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])),
        "poiseuille": " and ".join(poiseuille),
        "lattice": "; ".join(f"Re {p['reynolds']}: dx {p['dx_mm']} mm, dt {p['dt_ms']} ms, τ {p['tau']}, "
                             f"Mach {p['mach']}" for p in lattice),
        "n_particle_cases": fmt(len(particle)),
        "status": ", ".join(f"{fmt(v)} {k}" for k, v in sorted(status.items(), key=lambda kv: -kv[1])),
        "avg_min": fmt(min(avg)) if avg else "–", "avg_max": fmt(max(avg)) if avg else "–",
        "avg_median": fmt(float(sorted(avg)[len(avg) // 2])) if avg else "–",
        "seeds": (f"{fmt(min(seeds))}–{fmt(max(seeds))}" if seeds and min(seeds) != max(seeds)
                  else fmt(seeds[0]) if seeds else None),
        "n_flagged": fmt(flagged), "n_health": fmt(len(health_rows)),
        "min_spacings": fmt(min(dims) / float(dx)) if dims and dx else None, "dx": fmt(dx),
    }


def _figure_case_names(key: str, av, config: dict) -> list[str]:
    """Cases a figure shows, by their metadata in ``angular_velocity.csv`` (the selections of
    :data:`lbmpipe.reproduction.figures.FIGURE_CASES`); Fig. 10 adds the particle-free flow, the figure
    of claim 14 its dilute reference and the cases with collisions off."""
    names = figure_cases(av, key) if av is not None else []
    if key == "10":
        names += [n for n, c in (config.get("cases") or {}).items()
                  if not (c or {}).get("particles") and float((c or {}).get("reynolds", 0)) == 26.0]
    if 14 in FIGURE_CLAIMS.get(key, []):  # claim 14: its dilute reference, and the collisions-off sensitivity
        ref = find_case(config.get("cases") or {}, *REFERENCE_DESC)
        names += ([ref] if ref else []) + [n for n, c in (config.get("cases") or {}).items()
                                           if (c or {}).get("particles") and (c or {}).get("collisions") is False]
    return list(dict.fromkeys(names))


def _not_completed_line(row: dict, health_by_case: dict) -> str:
    status = (health_by_case.get(row["case"]) or {}).get("status", row.get("status"))
    return f"`{row['case']}`: {status}; no bars, and left out of the claims"


def _omega_line(row: dict) -> str | None:
    """A completed case's bars in numbers; None for a case that did not complete (the figure draws no bar)."""
    if str(row.get("status")) != "completed":
        return None
    return (f"`{row['case']}` |Ω| x, y, z = {fmt(row['omega_x'])} ± {fmt(row['ci_x'])}, "
            f"{fmt(row['omega_y'])} ± {fmt(row['ci_y'])}, {fmt(row['omega_z'])} ± {fmt(row['ci_z'])} rad/s")


def first_sentence(text: str) -> str:
    """The first sentence of a caption (the rest stays in the figure files' captions)."""
    return re.split(r"(?<=\.)\s+(?=[A-Z])", text.strip(), maxsplit=1)[0]


def figure_sections(fid_dir: Path, out_dir: Path, config: dict, claims_rows: list[dict],
                    cases: dict[str, dict], health_rows: list[dict]) -> list[dict]:
    """One section per paper figure (Figs. 4-10): the paper's caption and claims, our figures with the
    numbers that decide (the bars of Figs. 4-6, the profile errors of Fig. 10, the deciding number
    of each claim), and why, from the measured diagnostics of the cases the figure shows."""
    fid_dir = Path(fid_dir)
    av = read_table(fid_dir / "tables" / "angular_velocity.csv")
    entries = figure_entries(fid_dir, out_dir)
    by_claim = {r["claim"]: r for r in claims_rows}
    health_by_case = {r["case"]: r for r in health_rows}
    out = []
    for key, title in FIGURE_TITLES.items():
        figs = [e for e in entries if e["key"] in (key, key + "a", key + "b")]
        names = _figure_case_names(key, av, config)
        numbers = []
        if key in ("4", "5", "6") and av is not None:
            numbers = [_omega_line(r) for r in av[av["case"].isin(names)].to_dict("records")]
            # a case that did not complete is named as the figure and the claims treat it: no bar, left out
            numbers = [n if n is not None else _not_completed_line(r, health_by_case)
                       for n, r in zip(numbers, av[av["case"].isin(names)].to_dict("records"))]
        elif key == "10":
            numbers = [f"`{n}`: relative L2 difference from the Hagen-Poiseuille parabola "
                       f"{fmt(read_profile_error(fid_dir / 'cases' / n / 'profile.csv'))}"
                       for n in names if cases.get(n, {}).get("summary")]
        claims_here = [by_claim[fmt(c)] for c in FIGURE_CLAIMS.get(key, []) if fmt(c) in by_claim]
        # why: the flags and run-health issues measured for the cases of this figure
        why, not_computed = [], []
        for n in names:
            h = health_by_case.get(n)
            if h is None:
                continue
            if h["status"] not in ("completed",):
                why.append(f"`{n}` {h['status']}" + (f", {h['flags']}" if h["flags"] not in ("none", "") else ""))
            elif h["flags"] not in ("none", ""):
                why.append(f"`{n}` {h['flags']}" + (f" ({h['issues']})" if h["issues"] else ""))
            if h.get("frozen") == "not computed":
                not_computed.append(n)
        avg = [averaging_s(cases[n]["summary"], cases[n]["stats"]) for n in names if n in cases]
        avg = [a for a in avg if math.isfinite(a)]
        out.append({
            "key": key, "title": title, "figures": figs,
            "why": findings.why(names, health_rows, fid_dir, config,
                                "orientation" if key in ("8", "9") else "profile" if key == "10" else "rotation"),
            "paper_caption": PAPER_CAPTIONS.get(key, PAPER_CAPTIONS.get(key + "a", "")),
            "claims": claims_here, "numbers": numbers, "cases": names,
            "flagged": why, "n_clean": fmt(sum(1 for n in names if n in health_by_case) - len(why)),
            "not_computed": fmt(len(not_computed)) if not_computed else None,
            "avg": (f"{fmt(min(avg))}–{fmt(max(avg))}" if min(avg) != max(avg) else fmt(avg[0])) if avg else None,
            "diagnosed": [c for c in claims_here if "likely:" in c["reason"]],
        })
    return out


def health_summary_table(fid_dir: Path, config: dict, health_rows: list[dict], cases: dict[str, dict]) -> dict:
    """The run-health table of the main text: one row per case, short columns."""
    pk = read_table(Path(fid_dir) / "tables" / "packing.csv")
    achieved = {} if pk is None else dict(zip(pk["case"], pk.get("concentration_achieved", [])))
    rows = []
    for r in health_rows:
        c = cases.get(r["case"], {})
        summ = c.get("summary") or {}
        ach = achieved.get(r["case"], (summ.get("particles") or {}).get("concentration_achieved"))
        rows.append({"case": r["case"], "status": r["status"],
                     "achieved (%)": 100 * ach if ach is not None else None,
                     "averaged (s)": averaging_s(summ, c.get("stats")),
                     "max abs(ρ-1)": r["density_deviation_max"], "flags": r["flags"]})
    return table_of(pd.DataFrame(rows))


def build_context(repo_root: Path, fid_dir: Path, fidelity: str, config: dict, out_md: Path) -> dict:
    """Everything the template shows, read from the results and the config (no literal numbers)."""
    repo_root, fid_dir, out_dir = Path(repo_root), Path(fid_dir), Path(out_md).parent
    groups, uncited = method_section(repo_root, out_dir)
    params, param_errors = parameter_rows(config)
    fids = config.get("fidelities") or {}
    decisions = []
    factors = sorted({fmt(f.get("re26_dt_factor", 1.0)) for f in fids.values()}) or ["1"]
    for title, text in DECISIONS:
        decisions.append({"title": title, "text": text.replace("{re26_dt_factors}", " / ".join(factors))})

    claims = read_table(fid_dir / "claims.csv")
    claims_ctx = None
    if claims is not None:
        counts = claims["verdict"].value_counts().to_dict() if "verdict" in claims else {}
        claims_ctx = {"table": table_of(claims, ["claim", "statement", "statistic", "values", "verdict", "reason"]),
                      "counts": [{"verdict": k, "n": fmt(int(v))} for k, v in sorted(counts.items())]}
        claims_ctx["counts_md"] = ", ".join(f"{c['n']} {c['verdict']}" for c in claims_ctx["counts"])
    fid_cfg = fids.get(fidelity, {})
    # A level on another level's lattice shows that level's stability suite and study (study_level).
    study_dir = fid_dir.parent / study_level(config, fidelity)
    stability = read_table(study_dir / "tables" / "stability.csv")
    health_ctx = health_section(fid_dir, config)
    case_data = _case_dirs(fid_dir, config)
    claim_rows = claims_summary(claims) if claims is not None else []
    particle_cases = [n for n, c in (config.get("cases") or {}).items() if (c or {}).get("particles")]

    shown = fig3_cases(config, fid_dir)
    gallery = snapshot_gallery(fid_dir, shown)  # Fig. 3: four snapshots, dilute and dense, cylinders and cubes
    health_rows = health_ctx["rows"]
    n_flagged = sum(1 for r in health_rows if r["flags"] not in ("none", ""))
    flag_counts = {f: sum(f in str(r["flags"]) for r in health_rows) for f in findings.FLAG_MEANING}
    return {
        "findings": findings.claim_findings(fid_dir),
        "n_unhealthy": fmt(flag_counts["unhealthy"]),
        "flag_meanings": findings.flag_meanings(),
        "physics": findings.physical_results(fid_dir),
        "corrections": findings.correction_sizes(fid_dir, config),
        "density_floor": fmt(Numerics.model_fields["density_floor"].default),  # the scenes' default
        "unpackable": [f"`{c['case']}` ({c['achieved']} % reached)" for c in case_rows(config, fid_dir)
                       if c["status"] == "unpackable"],
        "health_counts": (f"{n_flagged} of {len(health_rows)} cases carry a flag: "
                          + ", ".join(f"{n} {f}" for f, n in flag_counts.items() if n) + "; "
                          + ", ".join(f"{n} {s}" for s, n in sorted(
                              pd.Series([str(r['status']).split(' (')[0] for r in health_rows]).value_counts().items()))
                          + "."),
        "claim_lines": findings.claim_lines(fid_dir, relative_href(fid_dir / "claims.csv", out_dir)),
        "claims_href": relative_href(fid_dir / "claims.csv", out_dir),
        "benchmarks_href": relative_href(repo_root.resolve() / "benchmarks" / "README.md", out_dir)
                           + "#run-cost-per-processor",
        "mass_href": relative_href(repo_root.resolve() / "benchmarks" / "README.md", out_dir) + "#mass-validation-item-5",
        "abstract": abstract_section(fid_dir, fidelity, config, claims, params, case_data, health_ctx["rows"]),
        "key_equations": key_equations(repo_root, out_dir, equation_index(repo_root / "lbmpipe")),
        "other_equations": other_equations(groups),
        "figure_sections": figure_sections(fid_dir, out_dir, config, claim_rows, case_data, health_ctx["rows"]),
        "claims_summary": claim_rows,
        "health_summary": health_summary_table(fid_dir, config, health_ctx["rows"], case_data),
        "provenance": provenance_text(config, _document_levels(config, fidelity), fid_dir),
        "gallery": relative_href(gallery, out_dir) if gallery else None,
        "gallery_caption": FIG3_CAPTION.format(cases=", ".join(f"`{c}`" for c in shown)),
        "level_parameters": [p for p in params if p["fidelity"] == fidelity],
        "fidelity": fidelity,
        "fid_dir": _rel_to(fid_dir, repo_root),
        # the paper's reading, relative to the document wherever it is built
        "reading_link": relative_href(repo_root.resolve() / "paper" / "reading.md", out_dir),
        "level_md": ", ".join(f"`{k}` = {fmt(v)}" for k, v in fid_cfg.items() if not isinstance(v, dict))
                    or "(not in config.yaml)",
        "level_run_md": ", ".join(f"`{k}` = {fmt(v)}" for k, v in (fid_cfg.get("run") or {}).items()) or "–",
        "equation_groups": groups,
        "uncited_equations": uncited,
        "parameters": [p for p in params if p["fidelity"] in _related_levels(config, fidelity)],
        "parameter_errors": param_errors,
        "cases": case_rows(config, fid_dir),
        "figures": figure_entries(fid_dir, out_dir),
        "decisions": decisions,
        "claims": claims_ctx,
        "stability": table_of(stability, STABILITY_COLUMNS) if stability is not None else None,
        "study_level": study_level(config, fidelity),
        "health": health_ctx,
        "runtime": _current_levels(runtime_section(fid_dir, fidelity), config, fidelity, fid_dir),
        "method": method_comparison_section(fid_dir, fidelity, config, out_dir),
        "convergence": convergence_section(fid_dir, fidelity, config, out_dir),
        "robustness": robustness_section(fid_dir, out_dir),
        "stationarity": stationarity_section(fid_dir),
        "missing": lambda rel: f"not built at this level: `{_rel_to(fid_dir, repo_root)}/{rel}` missing",
    }


#: The columns of the stability suite the document shows (the file has them all).
STABILITY_COLUMNS = ["case", "description", "status", "failed_step", "max_u_over_cs", "rho_min", "rho_max",
                     "mass_corrected_rel", "floor_mass_rel"]


def _related_levels(config: dict, fidelity: str) -> set[str]:
    """This level and the levels built on it: its controls, its convergence levels, the level
    comparing its method with it."""
    fids = config.get("fidelities") or {}
    return {fidelity} | {k for k, v in fids.items() if fidelity in
                         ((v or {}).get("control_of"), (v or {}).get("convergence_of"), (v or {}).get("compare_with"))}


def _document_levels(config: dict, fidelity: str) -> list[str]:
    """The levels whose runs the document draws on: :func:`_related_levels` and the reruns of its unstable runs."""
    fids = config.get("fidelities") or {}
    levels = _related_levels(config, fidelity) | {k for k, v in fids.items() if (v or {}).get("unstable_of") == fidelity}
    return [fidelity] + sorted(levels - {fidelity})


def _current_levels(runtime: dict, config: dict, fidelity: str, fid_dir: Path) -> dict:
    """``runtime`` with its per-level rows cut to :func:`_related_levels` (and the results folder's own)."""
    mine = _related_levels(config, fidelity) | {Path(fid_dir).name}
    return {**runtime, "levels": [lv for lv in runtime["levels"] if lv["level"] in mine]}


def study_level(config: dict, fidelity: str) -> str:
    """The level whose stability suite and accuracy-cost study a level's document shows: the
    level's ``study_level`` (a level on the same lattice), else the level itself."""
    return str(((config.get("fidelities") or {}).get(fidelity) or {}).get("study_level", fidelity))


def _rel_to(path: Path, root: Path) -> str:
    try:
        return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return Path(path).as_posix()


def build_document(repo_root: Path, fid_dir: Path, fidelity: str, config: dict, out_md: Path) -> Path:
    """Render ``paper/reproduction.md.j2`` for the results in ``fid_dir`` (``results/<fidelity>``)
    into ``out_md``, and its HTML beside it (``.html``). Links are relative to ``out_md``'s folder.
    Returns ``out_md``."""
    repo_root, out_md = Path(repo_root), Path(out_md)
    out_md.parent.mkdir(parents=True, exist_ok=True)
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(repo_root / "paper")),
                             undefined=jinja2.StrictUndefined, keep_trailing_newline=True,
                             trim_blocks=True, lstrip_blocks=True, autoescape=False)
    env.filters["fmt"] = fmt
    env.filters["first_sentence"] = first_sentence
    text = env.get_template("reproduction.md.j2").render(**build_context(repo_root, fid_dir, fidelity, config, out_md))
    text = re.sub(r"\n{3,}", "\n\n", text)
    out_md.write_text(text, encoding="utf-8")

    out_md.with_suffix(".html").write_text(markdown_to_html(text, title=f"lbmpipe reproduction ({fidelity})"),
                                           encoding="utf-8")
    return out_md


def build_checked_document(repo_root: Path, fidelity: str, config: dict,
                           out_md: Path | None = None) -> tuple[Path, list[str]]:
    """``build_document`` for ``results/<fidelity>`` under ``repo_root`` into ``out_md`` (default
    ``paper/reproduction_<fidelity>.md``), then ``check_links`` on it: the document and its stale
    links (empty when all are fresh). The pipeline's ``paper`` rule and ``lbmpipe document``."""
    repo_root = Path(repo_root)
    out_md = Path(out_md) if out_md is not None else repo_root / "paper" / f"reproduction_{fidelity}.md"
    out = build_document(repo_root, repo_root / "results" / fidelity, fidelity, config, out_md)
    return out, check_links(out, repo_root)
