"""Figures of the paper, regenerated from run outputs (physical units on every axis).

Everything is drawn from the aggregated tables of :mod:`lbmpipe.reproduction.statistics`
(``results/<fid>/tables/*.csv``) and the case directories; :func:`make_figures` is the single
entry point. Cases are picked by their metadata columns (shape, size, concentration, Reynolds
number, collisions), never by parsing names. A case the figure needs but which is missing from
the table or did not complete (e.g. status ``unpackable``) is marked with a text at its place
("not packable", "not run", ...), never dropped silently.

Every figure is drawn in the style ``lbmpipe/reproduction/lbmpipe.mplstyle`` (applied on import). A case that
carries a flag (:func:`case_flags`: a ``flags`` column or ``flag_<name>`` columns of the tables, or
``flags`` in its ``stats.json``/``summary.json``; e.g. frozen, locked, unhealthy) keeps its bars,
hatched, with the flag named in the legend or the panel title. The orientation histograms (Figs. 8,
9) carry the fraction a uniformly random orientation puts in each plotted bin
(:func:`lbmpipe.reproduction.statistics.isotropic_bin_fractions`, closed form). The paper's experimental
values (Zitoun et al. 2001) are not available to us and are not drawn.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from .fractions import histogram_interval
from .statistics import isotropic_bin_fractions
from .plotting import STYLE, plt, save  # noqa: F401  (STYLE: the style every figure is drawn in)

AXES = ("x", "y", "z")
AXIS_LABELS = (r"$|\Omega_x|$", r"$|\Omega_y|$", r"$|\Omega_z|$")
OMEGA_YLABEL = "mean angular velocity |Ω| (rad/s)"
CUBE_MAX_AXIS_ANGLE_DEG = float(np.degrees(np.arccos(1.0 / np.sqrt(3.0))))

FIGURE_CAPTIONS = {
    "fig3_snapshot": (
        "Particles at the last sample of a run, drawn in their position and orientation inside the 50 mm pipe "
        "(z along the pipe axis, mm), with a 20 mm scale bar and an arrow in the flow direction (+z); colour is the "
        "angle between the pipe axis and the cylinder axis (nearest cube axis for cubes)."),
    "fig4_cylinders_re26": (
        "Mean |Ω| about the lab x, y and z axes (rad/s) of 16x16 mm and 16x24 mm cylinders at 30 % concentration, "
        "Re 26, over all particles and samples after spin-up; error bars are 95 % confidence half-widths from "
        "batch means of the particle-averaged time series. The paper's experimental values (Zitoun et al. 2001) are "
        "not available to us and are not drawn; hatched bars mark a flagged case, its flags coded above the bar (U unhealthy, S not steady, F frozen, L locked)."),
    "fig5_cubes8_concentration": (
        "Mean |Ω| about x, y, z (rad/s) of 8 mm cubes at Re 9.4, 30 % (LC) against 50 % (HC) concentration; "
        "error bars are 95 % batch-means confidence half-widths. Hatched bars mark a flagged case, its flags coded above "
        "the bar (U unhealthy, S not steady, F frozen, L locked)."),
    "fig6_cubes24_reynolds": (
        "Mean |Ω| about x, y, z (rad/s) of 24 mm cubes at 30 % concentration, Re 9.4 (LF) against Re 26 (HF); "
        "error bars are 95 % batch-means confidence half-widths. Hatched bars mark a flagged case, its flags coded above "
        "the bar (U unhealthy, S not steady, F frozen, L locked)."),
    "fig7a_shape_re9.4": (
        "Cubes (8, 16, 24 mm) against cylinders of the same size (8x8, 16x16 mm; no 24 mm cylinder in the study), "
        "30 % concentration, Re 9.4: mean |Ω| about x, y, z (rad/s) with 95 % batch-means confidence half-widths. "
        "Hatched bars mark a flagged case, its flags coded above the bar (U unhealthy, S not steady, F frozen, L locked)."),
    "fig7b_shape_re26": (
        "As Fig. 7a at Re 26: cubes (8, 16, 24 mm) against cylinders 8x8 and 16x16 mm, 30 % concentration, "
        "mean |Ω| about x, y, z (rad/s) with 95 % batch-means confidence half-widths. Hatched bars mark a flagged "
        "case, its flags coded above the bar (U unhealthy, S not steady, F frozen, L locked)."),
    "fig8_cylinder_orientation": (
        "Distribution of the angle between the cylinder axis and the pipe axis (deg; fraction of particle-samples "
        "after spin-up per 10 deg bin) for the four cylinder sizes at 30 % concentration, Re 9.4 and Re 26; "
        "error bars are 95 % Wilson score intervals of the bin fraction on the case's effective sample size (from "
        "its batch-means half-widths; lbmpipe.reproduction.fractions), inside [0, 1]. Black dashes: the "
        "fraction a uniformly random (isotropic) orientation puts in each bin, 1 - cos θ integrated over the bin. "
        "The paper's experimental distribution (its Fig. 8b, Zitoun et al. 2001) is not available to us and is not "
        "drawn; hatched bars mark a flagged case, its flags coded in the legend (U unhealthy, S not steady, F frozen, "
        "L locked)."),
    "fig9_cube_orientation": (
        "Cube orientation at 30 % concentration, one row per cube size (each row its own vertical scale, so a "
        "case locked in one bin does not flatten the others): left pair, the in-image angle of the cube "
        "projected on the x-z plane (camera along y) folded into 0-45 deg, as a camera sees it, at Re 9.4 and "
        "Re 26; right pair, the 3-D angle between the pipe axis and the nearest cube axis (0-54.7 deg); fractions "
        "per bin with 95 % Wilson score intervals on the case's effective sample size (inside [0, 1], wide in an empty "
        "bin of a case with few independent samples). Black dashes: a uniformly random (isotropic) orientation, "
        "which gives the projected angle uniformly (1/9 per 5 deg bin) and the 3-D angle its closed-form bin "
        "fractions. The paper's experimental distribution (its Fig. 9b, Zitoun et al. 2001) is not available to us "
        "and is not drawn; a flagged case has hatched bars and its flags coded in the panel title (U unhealthy, S not "
        "steady, F frozen, L locked)."),
    "fig10_profiles": (
        "Time-averaged axial fluid velocity against radius (mirrored to the full diameter) at Re 26 without "
        "particles and with 16x16 mm cylinders at 30 % concentration, against the Hagen-Poiseuille parabola of the "
        "same flow rate (dashed). A flagged case has its flag in the legend."),
}


# ----------------------------------------------------------------------------------------------
# helpers

def _table(t) -> pd.DataFrame:
    """A DataFrame from a DataFrame, a CSV path, or None/missing file (empty frame)."""
    if isinstance(t, pd.DataFrame):
        return t
    if t is None or not Path(t).exists():
        return pd.DataFrame()
    try:
        return pd.read_csv(t)
    except pd.errors.EmptyDataError:
        return pd.DataFrame()


def _is_true(col: pd.Series) -> pd.Series:
    return col.astype(str).str.strip().str.lower().isin(("true", "1", "1.0"))


def _select(table: pd.DataFrame, shape: str, size_label: str, concentration: float, reynolds: float,
            collisions: bool = True) -> pd.DataFrame:
    """Rows of ``table`` matching the case metadata (floats compared with a tolerance)."""
    need = {"shape", "size_label", "concentration", "reynolds"}
    if table.empty or not need <= set(table.columns):
        return table.iloc[0:0]
    m = (table["shape"] == shape) & (table["size_label"] == size_label)
    m &= np.isclose(table["concentration"].astype(float), concentration)
    m &= np.isclose(table["reynolds"].astype(float), reynolds)
    if "collisions" in table.columns:
        m &= _is_true(table["collisions"]) == bool(collisions)
    return table[m]


def status_text(status) -> str:
    """What a figure writes at the place of a case without data, from its run status."""
    s = str(status) if status is not None and status == status else "not run"
    return {"unpackable": "not packable", "not run": "not run", "completed": "no samples"}.get(s, s)


def _sel(shape, size_label, concentration, reynolds, collisions=True) -> dict:
    return {"shape": shape, "size_label": size_label, "concentration": concentration, "reynolds": reynolds,
            "collisions": collisions}


#: The cases each figure of the paper shows, by their metadata (Figs. 4-6 as drawn by
#: :func:`make_figures`, 7a/7b by :func:`shape_size_bars`, 8 by :func:`cylinder_orientation`, 9 by
#: :func:`cube_orientation`, 10 the particle case of :func:`make_figures`; Fig. 7 lists both panels).
FIGURE_CASES: dict[str, list[dict]] = {
    "4": [_sel("cylinder", s, 0.30, 26.0) for s in ("16x16 mm", "16x24 mm")],
    "5": [_sel("cube", "8 mm", c, 9.4) for c in (0.30, 0.50)],
    "6": [_sel("cube", "24 mm", 0.30, r) for r in (9.4, 26.0)],
    "7": [_sel(shape, s, 0.30, r) for r in (9.4, 26.0)
          for shape, s in (("cube", "8 mm"), ("cube", "16 mm"), ("cube", "24 mm"), ("cylinder", "8x8 mm"),
                           ("cylinder", "16x16 mm"))],
    "8": [_sel("cylinder", s, 0.30, r) for r in (9.4, 26.0) for s in ("8x8 mm", "8x16 mm", "16x16 mm", "16x24 mm")],
    "9": [_sel("cube", s, 0.30, r) for r in (9.4, 26.0) for s in ("8 mm", "16 mm", "24 mm")],
    "10": [_sel("cylinder", "16x16 mm", 0.30, 26.0)],
}


def figure_cases(table, key: str) -> list[str]:
    """Names of the cases of ``table`` (a table with case metadata) that Fig. ``key`` shows
    (:data:`FIGURE_CASES`), in the figure's order."""
    t = _table(table)
    names = [str(c) for crit in FIGURE_CASES.get(key, []) for c in _select(t, **crit).get("case", [])]
    return list(dict.fromkeys(names))


#: Hatch of the bars of a flagged case.
FLAG_HATCH = "////"
#: One letter per flag, printed above a flagged bar (short: a bar group stays legible).
FLAG_CODES = {"unhealthy": "U", "not steady": "S", "frozen": "F", "locked": "L"}


def flag_code(flags) -> str:
    """The flags as letters (:data:`FLAG_CODES`; an unknown flag keeps its name)."""
    return "".join(FLAG_CODES.get(f, f"[{f}]") for f in sorted(flags or [], key=lambda f: list(FLAG_CODES).index(f)
                                                                   if f in FLAG_CODES else 99))


def _flag_list(value) -> list[str]:
    """Flags from a cell or a JSON field: ``"frozen; locked"``, a list, or ``{name: bool}``."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return []
    if isinstance(value, dict):
        return [str(k) for k, v in value.items() if v]
    if isinstance(value, (list, tuple)):
        return [str(v).strip() for v in value if str(v).strip()]
    return [f.strip() for f in str(value).replace(",", ";").split(";") if f.strip() and f.strip().lower() != "nan"]


def case_flags(row) -> list[str]:
    """Flags of one case's table row (a Series or dict): the ``flags`` column (``;``-separated) and
    every true ``flag_<name>`` column as ``<name>``. Generic, so that a flag another stage adds to
    the tables (frozen, locked, unhealthy, ...) shows up in every figure without a change here."""
    get = row.get if hasattr(row, "get") else dict(row).get
    out = _flag_list(get("flags"))
    keys = row.index if hasattr(row, "index") and not isinstance(row, dict) else list(row)
    for k in keys:
        if str(k).startswith("flag_") and str(get(k)).strip().lower() in ("true", "1", "1.0", "yes"):
            out.append(str(k)[len("flag_"):])
    return list(dict.fromkeys(out))


def read_case_flags(fid_dir: Path) -> dict[str, list[str]]:
    """Flags per case of a results directory: ``flags``/``flag_<name>`` columns of any
    ``tables/*.csv`` with a ``case`` column, and ``flags`` in ``cases/<case>/stats.json`` or
    ``summary.json``. An absent source adds nothing."""
    fid_dir = Path(fid_dir)
    out: dict[str, list[str]] = {}
    for csv in sorted((fid_dir / "tables").glob("*.csv")):
        t = _table(csv)
        if "case" not in t.columns or not ({"flags"} | {c for c in t.columns if str(c).startswith("flag_")}) & set(
                t.columns):
            continue
        for _, r in t.iterrows():
            out.setdefault(str(r["case"]), []).extend(case_flags(r))
    for js in sorted((fid_dir / "cases").glob("*/*.json")):
        if js.name not in ("stats.json", "summary.json"):
            continue
        try:
            data = json.loads(js.read_text())
        except ValueError:
            continue
        if isinstance(data, dict) and data.get("flags"):
            out.setdefault(js.parent.name, []).extend(_flag_list(data["flags"]))
    return {k: list(dict.fromkeys(v)) for k, v in out.items() if v}


def _with_flags(table: pd.DataFrame, flags: dict[str, list[str]]) -> pd.DataFrame:
    """``table`` with the flags of ``flags`` merged into its ``flags`` column (by case)."""
    if table.empty or "case" not in table.columns or not flags:
        return table
    t = table.copy()
    t["flags"] = [";".join(dict.fromkeys(case_flags(r) + flags.get(str(r["case"]), []))) for _, r in t.iterrows()]
    return t


def _flags_of(table: pd.DataFrame, crit: dict | None) -> list[str]:
    """Flags of the case ``crit`` selects in ``table`` (none when it is absent)."""
    if crit is None:
        return []
    rows = _select(table, **crit)
    return case_flags(rows.iloc[0]) if not rows.empty else []


def _flagged(label: str, flags: list[str]) -> str:
    """A legend label with its flags coded (a bar figure explains the letters in its legend)."""
    return f"{label} [{flag_code(flags)}]" if flags else label


def _flagged_names(label: str, flags: list[str]) -> str:
    """A legend label with its flags named (a figure without the letters' key)."""
    return f"{label} [flagged: {', '.join(flags)}]" if flags else label


def _omega_of(table: pd.DataFrame, crit: dict | None):
    """``(values (3,), errors (3,), mark)`` of one case: mark is None for a completed case with
    finite values, else the text to print at its bars."""
    nan3 = np.full(3, np.nan)
    if crit is None:
        return nan3, nan3, "not in study"
    rows = _select(table, **crit)
    if rows.empty:
        return nan3, nan3, "not run"
    r = rows.iloc[0]
    v = np.array([float(r[f"omega_{a}"]) for a in AXES])
    e = np.array([float(r[f"ci_{a}"]) for a in AXES])
    if r.get("status") != "completed" or not np.all(np.isfinite(v)):
        return nan3, nan3, status_text(r.get("status"))
    return v, e, None


def _mark(ax, x, text, y=None):
    """Write ``text`` vertically at a bar position (a case that has no bar)."""
    lo, hi = ax.get_ylim()
    ax.text(x, lo + 0.03 * (hi - lo) if y is None else y, text, rotation=90, ha="center", va="bottom",
            fontsize=7, color="0.3", style="italic")


def _bars(ax, groups: list[str], series: list[tuple], width=None, hatches=None):
    """Grouped bars: ``series`` = (label, values (G,), errors (G,) or (2, G) below/above, marks (G,) text or None[,
    flags (G,) list of flag names or None]). A flagged bar is hatched and its flags join the label."""
    n = len(series)
    width = width or 0.8 / max(n, 1)
    x0 = np.arange(len(groups))
    at_bar = len(groups) <= 4  # a few groups: each flagged bar's code above it; a histogram: in the legend
    pending, flag_text, seen = [], [], []
    for k, (label, vals, errs, marks, *rest) in enumerate(series):
        flags = rest[0] if rest else [None] * len(groups)
        xs = x0 + (k - (n - 1) / 2) * width
        yerr = np.where(np.isfinite(errs), errs, 0.0)  # (G,) symmetric or (2, G) below/above
        up = yerr[-1] if yerr.ndim == 2 else yerr
        bad = [m for m in marks if m and m != "not in study"]
        lab = label if not bad else f"{label} ({', '.join(sorted(set(bad)))})"
        every = list(dict.fromkeys(f for fl in flags if fl for f in fl))
        seen += every
        if not at_bar:
            lab = _flagged(lab, every)
        bars = ax.bar(xs, np.nan_to_num(vals), width * 0.92, yerr=yerr, color=f"C{k}", label=lab,
                      hatch=(hatches[k] if hatches else None), edgecolor="k", linewidth=0.4,
                      error_kw={"elinewidth": 0.8})
        for patch, fl in zip(bars.patches, flags):
            if fl:
                patch.set_hatch(FLAG_HATCH)
        pending += [(x, m) for x, m in zip(xs, marks) if m]
        if at_bar:
            flag_text += [(x, y, flag_code(fl)) for x, y, fl in zip(xs, np.nan_to_num(vals) + up, flags) if fl]
    ax.set_xticks(x0, groups)
    tops = [np.nanmax(np.where(np.isfinite(np.asarray(e)[-1] if np.ndim(e) == 2 else e),
                               v + (np.asarray(e)[-1] if np.ndim(e) == 2 else e), v))
            for _, v, e, *_ in series if np.isfinite(v).any()]
    top = max(tops) if tops else 0.0
    ax.set_ylim(0.0, 1.3 * top if top > 0 else 1.0)  # head-room for the legend
    for x, m in pending:
        _mark(ax, x, m)
    for x, y, text in flag_text:
        ax.text(x, y + 0.01 * ax.get_ylim()[1], text, ha="center", va="bottom", fontsize=6, color="0.2")
    if seen:  # one legend entry explains the hatch and the letters
        seen = list(dict.fromkeys(seen))
        ax.bar([np.nan], [np.nan], color="white", edgecolor="k", linewidth=0.4, hatch=FLAG_HATCH,
               label="flagged: " + ", ".join(f"{flag_code([f])} {f}" for f in seen))


# ----------------------------------------------------------------------------------------------
# angular velocity bars (Figs. 4-7)

def omega_bars(table, series: list[tuple[str, dict]], stem: Path, title: str = "") -> list[Path]:
    """Grouped bars of mean ``|Omega_x|, |Omega_y|, |Omega_z|`` (rad/s) with 95 % CI error bars.

    ``table``: ``angular_velocity.csv`` (path or DataFrame). ``series``: (legend label,
    selection dict with keys shape, size_label, concentration, reynolds, collisions).
    """
    t = _table(table)
    fig, ax = plt.subplots(figsize=(5.0, 3.6))
    data = []
    for label, crit in series:
        v, e, m = _omega_of(t, crit)
        rows = _select(t, **crit) if crit is not None else pd.DataFrame()
        case = f": {rows['case'].iloc[0]}" if len(rows) and "case" in rows else ""  # each case named one way
        data.append((label + case, v, e, [m] * 3, [_flags_of(t, crit) if m is None else None] * 3))
    _bars(ax, list(AXIS_LABELS), data)
    ax.set_xlabel("rotation axis (lab frame; z = pipe axis)")
    ax.set_ylabel(OMEGA_YLABEL)
    if title:
        ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, frameon=False)
    return save(fig, stem)


def shape_size_bars(table, reynolds: float, stem: Path, title: str = "", concentration: float = 0.30) -> list[Path]:
    """Figs. 7a/7b: cubes (8, 16, 24 mm) against cylinders of the same size (8x8, 16x16 mm), one
    panel per rotation axis, bars grouped by size. The 24 mm cylinder is not in the study and is
    marked so."""
    t = _table(table)
    sizes = [("8 mm", "8 mm", "8x8 mm"), ("16 mm", "16 mm", "16x16 mm"), ("24 mm", "24 mm", None)]
    cube_sel = [_sel("cube", c, concentration, reynolds) for _, c, _ in sizes]
    cyl_sel = [_sel("cylinder", y, concentration, reynolds) if y else None for _, _, y in sizes]
    cube = [(*_omega_of(t, c), _flags_of(t, c)) for c in cube_sel]
    cyl = [(*_omega_of(t, c), _flags_of(t, c)) for c in cyl_sel]
    fig, axs = plt.subplots(1, 3, figsize=(9.0, 3.4))
    tops = []
    for j, ax in enumerate(axs):
        series = []
        for label, res in (("cube (edge)", cube), ("cylinder (D x L = size)", cyl)):
            series.append((label, np.array([r[0][j] for r in res]), np.array([r[1][j] for r in res]),
                           [r[2] for r in res], [r[3] if r[2] is None else None for r in res]))
        _bars(ax, [s[0] for s in sizes], series)
        tops.append(ax.get_ylim()[1])
        ax.set_title(f"about {AXES[j]}", fontsize=9)
        ax.set_xlabel("particle size")
    for ax in axs:  # one scale for the three axes; the "not ..." marks are re-placed at the bottom
        ax.set_ylim(0, max(tops))
    axs[0].set_ylabel(OMEGA_YLABEL)
    # one legend below the panels: its labels carry statuses and flags, too long for a panel
    handles, labels = axs[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=7, frameon=False, bbox_to_anchor=(0.5, 0.0))
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0.0, 0.07, 1.0, 1.0))
    return save(fig, stem)


# ----------------------------------------------------------------------------------------------
# orientation histograms (Figs. 8, 9)

#: The legend entry of the isotropic reference (one per figure).
ISOTROPIC_LABEL = "isotropic (random orientation)"
#: The legend entry of a histogram's bars and their intervals (Figs. 8-9).
INTERVAL_LABEL = "95 % Wilson interval on the effective sample size"


def _fraction_errors(frac: np.ndarray, ci: np.ndarray) -> np.ndarray:
    """(2, G) error bars below and above each bin fraction: its Wilson interval on the case's
    effective sample size (:mod:`lbmpipe.reproduction.fractions`), inside [0, 1]; none (0) without one."""
    lo, hi, _ = histogram_interval(frac, ci)
    f = np.nan_to_num(frac)
    return np.nan_to_num(np.vstack([f - lo, hi - f]), nan=0.0).clip(min=0.0)


def _reference(ax, kind: str, edges: np.ndarray, x: np.ndarray, half: float) -> float:
    """Draw, as black dashes over each bin at positions ``x``, the fraction a uniformly random
    orientation puts in the bins ``edges`` of ``kind``; return the largest."""
    ref = isotropic_bin_fractions(kind, edges)
    # one legend entry whatever the kind (uniform for the projected cube angle, the closed form otherwise)
    ax.hlines(ref, x - half, x + half, colors="k", linestyles=(0, (3, 1.5)), linewidth=1.2,
              label=ISOTROPIC_LABEL, zorder=3)
    return float(np.max(ref))


def _hist_rows(table: pd.DataFrame, kind: str, crit: dict):
    """``(rows sorted by bin, status, ok)`` of one case and histogram kind."""
    rows = _select(table, **crit)
    rows = rows[rows["kind"] == kind] if not rows.empty else rows
    if not rows.empty:
        rows = rows.sort_values("bin_lo_deg")
    status = rows["status"].iloc[0] if not rows.empty and "status" in rows else None
    ok = (not rows.empty and (status is None or status == "completed")
          and np.isfinite(rows["fraction"].astype(float)).any())
    return rows, status, ok


def _nominal_edges(lo: float, hi: float, nb: int = 9) -> np.ndarray:
    return np.linspace(lo, hi, nb + 1)


def _bin_labels(edges) -> list[str]:
    return [f"{a:.0f}-{b:.0f}" for a, b in zip(edges[:-1], edges[1:])]


def _hist_panel(ax, table: pd.DataFrame, kind: str, series: list[tuple[str, dict]], lo: float, hi: float):
    """Grouped bars of bin fractions with 95 % CI for each case of ``series``, and the isotropic
    reference of each bin; missing or not-completed cases are marked in the panel and in the
    legend, flagged cases hatched with their flags in the legend."""
    marks = []
    data = []
    edges = None
    for label, crit in series:
        rows, status, ok = _hist_rows(table, kind, crit)
        if not rows.empty and edges is None:
            edges = np.append(rows.bin_lo_deg.to_numpy(float), rows.bin_hi_deg.to_numpy(float)[-1])
        if ok:
            frac = rows["fraction"].to_numpy(float)
            data.append((label, frac, _fraction_errors(frac, rows["ci95"].to_numpy(float)), case_flags(rows.iloc[0])))
        else:
            why = "not run" if rows.empty else status_text(status)
            data.append((label, None, why, []))
            marks.append(f"{label}: {why}")
    if edges is None:  # nothing at all: lay out nominal bins so the panel still reads
        edges = _nominal_edges(lo, hi)
    groups = _bin_labels(edges)
    g = len(groups)
    series_bars = []
    for label, frac, ci, flags in data:
        if frac is None:
            series_bars.append((label, np.full(g, np.nan), np.full(g, np.nan), [None] * g))
        else:
            series_bars.append((label, frac[:g], ci[:, :g], [None] * g, [flags or None] * g))
    _bars(ax, groups, series_bars)
    ref_top = _reference(ax, kind, edges, np.arange(g), 0.45)
    # legend labels of marked cases carry their status
    handles, labels = ax.get_legend_handles_labels()
    status_of = {d[0]: d[2] for d in data if d[1] is None}
    labels = [f"{lab} ({status_of[lab]})" if lab in status_of else lab for lab in labels]
    ax.legend(handles, labels, fontsize=6.5)
    if marks:
        ax.text(0.02, 0.97, "\n".join(marks), transform=ax.transAxes, va="top", ha="left", fontsize=7,
                color="0.3", style="italic")
    ax.tick_params(axis="x", labelsize=6.5, rotation=45)
    ax.set_ylabel("fraction of particle-samples")
    return max(ax.get_ylim()[1], 1.3 * ref_top)


def cylinder_orientation(table, stem: Path, title: str = "", concentration: float = 0.30,
                         reynolds: tuple[float, float] = (9.4, 26.0)) -> list[Path]:
    """Fig. 8: histograms of the cylinder-axis / pipe-axis angle (deg, 0-90) for the four
    cylinder sizes, one panel per Reynolds number. ``table``: ``tables/orientation.csv``."""
    t = _table(table)
    sizes = ["8x8 mm", "8x16 mm", "16x16 mm", "16x24 mm"]
    fig, axs = plt.subplots(1, len(reynolds), figsize=(10.0, 3.8))
    axs = np.atleast_1d(axs)
    tops = []
    for ax, re in zip(axs, reynolds):
        tops.append(_hist_panel(ax, t, "cyl_axis_angle",
                                [(s, _sel("cylinder", s, concentration, re)) for s in sizes], 0.0, 90.0))
        ax.set_xlabel("angle between cylinder axis and pipe axis (deg)")
        ax.set_title(f"Re {re:g}, {concentration:.0%} concentration", fontsize=9)
    for ax in axs:  # one scale for both Reynolds numbers
        ax.set_ylim(0.0, max(tops))
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save(fig, stem)


def _case_hist(ax, table: pd.DataFrame, kind: str, crit: dict, hi: float, color: str) -> tuple[float, str]:
    """One case's histogram of ``kind`` as bars with 95 % CI, the isotropic reference over it,
    and its status written in the panel when it has no data; returns (top of the data, flags)."""
    rows, status, ok = _hist_rows(table, kind, crit)
    edges = (np.append(rows.bin_lo_deg.to_numpy(float), rows.bin_hi_deg.to_numpy(float)[-1]) if not rows.empty
             else _nominal_edges(0.0, hi))
    x = np.arange(len(edges) - 1)
    top, flags = 0.0, []
    if ok:
        frac = rows["fraction"].to_numpy(float)
        err = _fraction_errors(frac, rows["ci95"].to_numpy(float))
        flags = case_flags(rows.iloc[0])
        ax.bar(x, np.nan_to_num(frac), 0.85, yerr=err, color=color,
               edgecolor="k", linewidth=0.4, error_kw={"elinewidth": 0.8}, hatch=FLAG_HATCH if flags else None,
               label=f"this case ({INTERVAL_LABEL})")
        top = float(np.nanmax(np.nan_to_num(frac) + err[1]))
    else:
        ax.text(0.5, 0.6, "not run" if rows.empty else status_text(status), transform=ax.transAxes,
                ha="center", va="center", fontsize=9, color="0.3", style="italic")
    top = max(top, _reference(ax, kind, edges, x, 0.45))
    ax.set_xticks(x, _bin_labels(edges))
    ax.tick_params(axis="x", labelsize=6.5, rotation=45)
    return top, flag_code(flags)


def cube_orientation(table, stem: Path, title: str = "", concentration: float = 0.30,
                     reynolds: tuple[float, float] = (9.4, 26.0)) -> list[Path]:
    """Fig. 9: cube orientation histograms as small multiples, one row per cube size and one
    column per (angle, Reynolds number): the projected (camera) angle folded into 0-45 deg and
    the 3-D angle of the nearest cube axis to the pipe axis (0-54.7 deg), each against the
    isotropic reference. Each row has its own vertical scale (one case locked in a single bin
    must not flatten the others). ``table``: ``tables/orientation.csv``."""
    t = _table(table)
    sizes = ["8 mm", "16 mm", "24 mm"]
    kinds = (("cube_projected_angle", 45.0, "projected angle, camera along y (deg)"),
             ("cube_axis_angle", CUBE_MAX_AXIS_ANGLE_DEG, "3-D angle, nearest cube axis (deg)"))
    cols = [(kind, hi, xlabel, re) for kind, hi, xlabel in kinds for re in reynolds]
    fig, axs = plt.subplots(len(sizes), len(cols), figsize=(2.7 * len(cols), 2.3 * len(sizes) + 0.6),
                            squeeze=False)
    coded = set()
    for i, size in enumerate(sizes):
        tops = []
        for j, (kind, hi, xlabel, re) in enumerate(cols):
            ax = axs[i, j]
            top, flags = _case_hist(ax, t, kind, _sel("cube", size, concentration, re), hi, "C0")
            coded.update(flags)
            tops.append(top)
            ax.set_title(f"cube {size}, Re {re:g}" + (f" [{flags}]" if flags else ""), fontsize=8,
                         color="C3" if flags else "k")
            if i == len(sizes) - 1:
                ax.set_xlabel(xlabel, fontsize=8)
        for ax in axs[i]:  # one scale per row (cube size)
            ax.set_ylim(0.0, 1.15 * max(tops))
        axs[i, 0].set_ylabel("fraction of\nparticle-samples", fontsize=8)
    handles, labels = [], []
    for ax in axs.flat:  # one legend: the case's bars and the isotropic references
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if coded:  # the letters of the panel titles, once
        handles.append(plt.Rectangle((0, 0), 1, 1, facecolor="white", edgecolor="k", hatch=FLAG_HATCH))
        labels.append("flagged: " + ", ".join(f"{c} {f}" for f, c in FLAG_CODES.items() if c in coded))
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=7.5, bbox_to_anchor=(0.5, 0.0))
    if title:
        fig.suptitle(f"{title}; {concentration:.0%} concentration", fontsize=9)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return save(fig, stem)


# ----------------------------------------------------------------------------------------------
# velocity profiles (Fig. 10)

def _profile_state(path) -> tuple[pd.DataFrame | None, str]:
    """Profile table of a case, or None and the reason it has none."""
    if path is None or not Path(path).exists():
        return None, "not run"
    df = pd.read_csv(path)
    if df.empty:
        summ = Path(path).parent / "summary.json"
        status = None
        if summ.exists():
            try:
                status = json.loads(summ.read_text()).get("status")
            except ValueError:
                pass
        return None, status_text(status) if status else "no data"
    return df, ""


def velocity_profiles(profiles: dict[str, Path], stem: Path, title: str = "", parabola: str = "each") -> list[Path]:
    """Fig. 10: axial velocity against radius at the outlet, each run against its parabola.

    ``profiles`` maps a legend label to a ``profile.csv`` (columns ``r_mm``, ``uz_m_s``,
    ``uz_poiseuille_m_s``). The profile is mirrored to the full diameter as in the paper.
    ``parabola``: ``"each"`` draws every run's Hagen-Poiseuille reference, ``"first"`` only the
    first available one (runs at the same flow rate share it). A profile that is missing or
    empty (case not run, not packable) is listed in the panel with its reason.
    """
    fig, ax = plt.subplots(figsize=(5.0, 3.6))
    marks = []
    drawn_ref = False
    for k, (label, path) in enumerate(profiles.items()):
        df, why = _profile_state(path)
        if df is None:
            marks.append(f"{label}: {why}")
            continue
        r = np.concatenate([-df.r_mm[::-1], df.r_mm])
        u = np.concatenate([df.uz_m_s[::-1], df.uz_m_s])
        ax.plot(r, u, "-", color=f"C{k}", label=label)
        if parabola == "each" or (parabola == "first" and not drawn_ref):
            ref = np.concatenate([df.uz_poiseuille_m_s[::-1], df.uz_poiseuille_m_s])
            ref_label = f"{label}: Hagen-Poiseuille" if parabola == "each" else "Hagen-Poiseuille (same Q)"
            ax.plot(r, ref, "--", color=f"C{k}" if parabola == "each" else "k", lw=0.9, label=ref_label)
            drawn_ref = True
    if marks:
        ax.text(0.02, 0.03, "\n".join(marks), transform=ax.transAxes, fontsize=7, color="0.3", style="italic")
    ax.set_xlabel("r (mm)")
    ax.set_ylabel("axial velocity $u_z$ (m/s)")
    if title:
        ax.set_title(title, fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, frameon=False)
    return save(fig, stem)



# ----------------------------------------------------------------------------------------------
# entry point

def make_figures(fid_dir: Path, fidelity: str, cases: dict | None = None) -> list[Path]:
    """Figs. 4-10 of ``fid_dir`` (``results/<fid>``) from ``tables/angular_velocity.csv``,
    ``tables/orientation.csv`` and the cases' ``profile.csv``, into ``fid_dir/figures/``:
    ``fig4_cylinders_re26``, ``fig5_cubes8_concentration``, ``fig6_cubes24_reynolds``,
    ``fig7a_shape_re9.4``, ``fig7b_shape_re26``, ``fig8_cylinder_orientation``,
    ``fig9_cube_orientation``, ``fig10_profiles`` (each ``.pdf`` and ``.png``). Returns the paths.

    Flags of the cases (:func:`read_case_flags`) are merged into the tables first, so every figure
    marks a flagged case. ``cases`` (the config's case dict, optional) locates Fig. 10's particle-free Re 26 case by its
    metadata; without it the contract's name ``flow_re26`` is used."""
    fid_dir = Path(fid_dir)
    tables, figs = fid_dir / "tables", fid_dir / "figures"
    flags = read_case_flags(fid_dir)  # flagged cases are marked in every figure that shows them
    av = _with_flags(_table(tables / "angular_velocity.csv"), flags)
    orient = _with_flags(_table(tables / "orientation.csv"), flags)
    lvl = f"fidelity: {fidelity}"
    out = []
    out += omega_bars(av, [("cylinder 16x16 mm", _sel("cylinder", "16x16 mm", 0.30, 26.0)),
                           ("cylinder 16x24 mm", _sel("cylinder", "16x24 mm", 0.30, 26.0))],
                      figs / "fig4_cylinders_re26", title=f"Fig. 4: cylinders, 30 %, Re 26 ({lvl})")
    out += omega_bars(av, [("LC (30 %)", _sel("cube", "8 mm", 0.30, 9.4)),
                           ("HC (50 %)", _sel("cube", "8 mm", 0.50, 9.4))],
                      figs / "fig5_cubes8_concentration", title=f"Fig. 5: 8 mm cubes, Re 9.4 ({lvl})")
    out += omega_bars(av, [("LF (Re 9.4)", _sel("cube", "24 mm", 0.30, 9.4)),
                           ("HF (Re 26)", _sel("cube", "24 mm", 0.30, 26.0))],
                      figs / "fig6_cubes24_reynolds", title=f"Fig. 6: 24 mm cubes, 30 % ({lvl})")
    out += shape_size_bars(av, 9.4, figs / "fig7a_shape_re9.4",
                           title=f"Fig. 7a: cubes vs cylinders, 30 %, Re 9.4 ({lvl})")
    out += shape_size_bars(av, 26.0, figs / "fig7b_shape_re26",
                           title=f"Fig. 7b: cubes vs cylinders, 30 %, Re 26 ({lvl})")
    out += cylinder_orientation(orient, figs / "fig8_cylinder_orientation",
                                title=f"Fig. 8: cylinder orientation ({lvl})")
    out += cube_orientation(orient, figs / "fig9_cube_orientation", title=f"Fig. 9: cube orientation ({lvl})")
    # Fig. 10: the particle case is found by metadata in the table when it is there
    cyl = _select(av, **_sel("cylinder", "16x16 mm", 0.30, 26.0))
    cyl_case = cyl["case"].iloc[0] if not cyl.empty else None
    flow_case = "flow_re26"
    for name, cfg in (cases or {}).items():
        cfg = cfg or {}
        if not cfg.get("particles") and np.isclose(float(cfg.get("reynolds", np.nan)), 26.0):
            flow_case = name
            break
    profiles = {_flagged_names("no particles, Re 26", flags.get(flow_case, [])):
                    fid_dir / "cases" / flow_case / "profile.csv",
                _flagged_names("cylinders 16x16 mm, 30 %, Re 26", flags.get(cyl_case, [])):
                    (fid_dir / "cases" / cyl_case / "profile.csv") if cyl_case else None}
    out += velocity_profiles(profiles, figs / "fig10_profiles", title=f"Fig. 10: axial velocity profiles ({lvl})",
                             parabola="first")
    return out
