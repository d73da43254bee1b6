"""The distance of a time-averaged velocity profile from another (Fig. 10, claim 13), defined once.

Every number of the reproduction that says how far a profile is from the Hagen-Poiseuille parabola
or from the particle-free flow (the abstract's particle-free baseline, Fig. 10's section, claim 13,
a case's combined ``summary.json``) is :func:`profile_error` of its ``profile.csv``: the relative
L2 distance over the pipe's cross-section, each radial bin weighted by its number of lattice nodes
(area weighting; the bins are 0.5 lattice spacings wide, so an unweighted sum would count the few
nodes near the axis as much as the many near the wall, where the bounce-back wall errs most).
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def rel_l2(r: np.ndarray, u: np.ndarray, u_ref: np.ndarray, weights: np.ndarray) -> float:
    """Relative L2 distance sqrt(sum w (u - u_ref)^2 / sum w u_ref^2) (w = nodes per radial bin: area weighting)."""
    return float(np.sqrt(np.sum(weights * (u - u_ref) ** 2) / np.sum(weights * u_ref**2)))


def _weights(p: pd.DataFrame) -> np.ndarray:
    return p["nodes"].to_numpy(float) if "nodes" in p else np.ones(len(p))


def profile_error(profile: pd.DataFrame, reference: pd.DataFrame | None = None) -> float:
    """Relative L2 distance (node-weighted) of a ``profile.csv`` table (``r_mm``, ``uz_m_s``,
    ``uz_poiseuille_m_s``, ``nodes``) from its Hagen-Poiseuille parabola, or from ``reference``'s
    profile interpolated in r when given; NaN for an empty profile."""
    p = profile.dropna(subset=["r_mm", "uz_m_s"])
    if not len(p):
        return float("nan")
    if reference is None:
        u_ref = p["uz_poiseuille_m_s"].to_numpy(float)
    else:
        f = reference.dropna(subset=["r_mm", "uz_m_s"])
        if not len(f):
            return float("nan")
        u_ref = np.interp(p["r_mm"].to_numpy(float), f["r_mm"].to_numpy(float), f["uz_m_s"].to_numpy(float))
    return rel_l2(p["r_mm"].to_numpy(float), p["uz_m_s"].to_numpy(float), u_ref, _weights(p))


def read_profile_error(path) -> float:
    """:func:`profile_error` of the ``profile.csv`` at ``path``; NaN when it is missing or empty."""
    try:
        return profile_error(pd.read_csv(path))
    except (FileNotFoundError, pd.errors.EmptyDataError, KeyError):
        return float("nan")
