"""Figures of the comparisons between levels: what the numerical method changes
(:mod:`lbmpipe.reproduction.methods`) and the paper's observables against their cost as the lattice
is refined (:mod:`lbmpipe.reproduction.convergence`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .plotting import plt, save


#: colour of a claim's cell by whether its verdict is the same under both methods
_SAME_COLOURS = {"yes": "#cde8c8", "no": "#f4b6b0", "not compared": "#eeeeee"}


def method_comparison(runs: pd.DataFrame, claims: pd.DataFrame, stem: Path, title: str = "") -> list[Path]:
    """What the method changes, as one figure: left, each paired run's relative difference of mean
    |Omega| about x, y, z (accurate / paper - 1) with its 95 % interval (filled: the difference
    exceeds the two runs' intervals combined); right, each claim's verdict under the paper's method
    and the accurate one from packing seed 1, the cell red where they differ and grey where either
    lacks inputs. ``runs`` and ``claims``: ``method/runs.csv`` and ``method/claims.csv``."""
    om = runs[runs["observable"].astype(str).str.startswith("mean_abs_omega")] if len(runs) else runs
    names = sorted(om["run"].unique()) if len(om) else []
    fig, (ax, axc) = plt.subplots(1, 2, figsize=(12, max(3.5, 0.45 * max(len(names), len(claims)) + 1.5)),
                                  gridspec_kw={"width_ratios": [1.2, 1]})
    for k, (axis, colour) in enumerate(zip("xyz", ("C0", "C1", "C2"))):
        sub = om[om["observable"] == f"mean_abs_omega_{axis}"] if len(om) else om
        for i, (_, r) in enumerate(sub.iterrows()):
            y = names.index(r["run"]) + (k - 1) * 0.22
            ci = float(r["rel_diff_ci95"]) if pd.notna(r["rel_diff_ci95"]) else 0.0
            filled = str(r["significant"]) == "True"
            ax.errorbar(100 * float(r["rel_diff"]), y, xerr=100 * ci, fmt="o", color=colour,
                        mfc=colour if filled else "white", label=f"|Omega_{axis}|" if i == 0 else None)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_yticks(range(len(names)), names)
    ax.invert_yaxis()
    ax.set_xlabel("mean |Omega|: accurate / paper method - 1 (%), 95 % interval")
    if names:
        ax.legend(loc="best", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no paired run done yet", ha="center", va="center", transform=ax.transAxes)
    axc.axis("off")
    if len(claims):
        cells = [[str(r["claim"]), str(r["verdict_paper_seed1"]), str(r["verdict_accurate_seed1"])]
                 for _, r in claims.iterrows()]
        colours = [["white"] + [_SAME_COLOURS.get(str(r["same"]), "white")] * 2 for _, r in claims.iterrows()]
        tab = axc.table(cellText=cells, cellColours=colours, colLabels=["claim", "paper method", "accurate method"],
                        loc="upper center", cellLoc="center")
        tab.auto_set_font_size(False)
        tab.set_fontsize(8)
        axc.set_title("verdicts from packing seed 1 (red: they differ; grey: not compared)", fontsize=9)
    fig.suptitle(title)
    return save(fig, stem)


#: convergence observables drawn, one panel each: (observables, y label)
_CONVERGENCE_PANELS = (
    (("profile_distance",), "profile's distance from Poiseuille"),
    (("mean_abs_omega_x", "mean_abs_omega_y", "mean_abs_omega_z"), "mean |Omega| (rad/s)"),
    (("mean_angle_deg",), "mean orientation angle (deg)"),
)


def convergence_accuracy_cost(values: pd.DataFrame, stem: Path, title: str = "") -> list[Path]:
    """The paper's observables against what they cost as the lattice is refined: per case (rows)
    the profile's distance from Poiseuille, mean |Omega| about x, y, z and the mean orientation
    angle (columns) against the measured time-loop seconds per simulated second, one point per
    dx (labelled) with its 95 % interval; a hollow marker for a flagged value (its flags in
    ``values.csv``). ``values``: ``convergence/values.csv``."""
    cases = sorted(values["case"].unique()) if len(values) else []
    fig, axes = plt.subplots(max(len(cases), 1), len(_CONVERGENCE_PANELS), squeeze=False,
                             figsize=(4.2 * len(_CONVERGENCE_PANELS), 3.0 * max(len(cases), 1)))
    for i, case in enumerate(cases):
        sub = values[values["case"] == case]
        for j, (observables, label) in enumerate(_CONVERGENCE_PANELS):
            ax = axes[i][j]
            drawn = False
            for k, obs in enumerate(observables):
                g = sub[(sub["observable"] == obs) & np.isfinite(sub["value"].astype(float))
                        & np.isfinite(sub["loop_s_per_sim_s"].astype(float))].sort_values("dx_mm")
                if not len(g):
                    continue
                colour = f"C{k}"
                x, y = g["loop_s_per_sim_s"].to_numpy(float), g["value"].to_numpy(float)
                ci = np.nan_to_num(g["ci95"].to_numpy(float))
                ax.plot(x, y, "-", color=colour, lw=0.8)
                for xi, yi, ci_i, fl, dx in zip(x, y, ci, g["flags"].fillna("").astype(str), g["dx_mm"]):
                    ax.errorbar(xi, yi, yerr=ci_i, fmt="o", color=colour, mfc="white" if fl else colour,
                                label=(obs.replace("mean_abs_omega_", "|Omega_") + "|") if len(observables) > 1
                                and dx == g["dx_mm"].iloc[0] else None)
                    ax.annotate(f"{dx:g} mm", (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=7)
                drawn = True
            if not drawn:
                ax.axis("off")
                continue
            ax.set_xscale("log")
            ax.set_xlabel("time-loop s per simulated s")
            ax.set_ylabel(label)
            ax.set_title(case, fontsize=9)
            if len(observables) > 1:
                ax.legend(fontsize=7, loc="best")
    if not cases:
        axes[0][0].text(0.5, 0.5, "no case run at a second spacing yet", ha="center", va="center",
                        transform=axes[0][0].transAxes)
        for ax in axes[0]:
            ax.axis("off")
    fig.suptitle(title + "\n(hollow: a flagged value; bars: 95 % intervals, seeds combined)", fontsize=10)
    fig.tight_layout()
    return save(fig, stem)
