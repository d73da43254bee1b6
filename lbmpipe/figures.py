"""Figures of the paper, regenerated from run outputs (physical units on every axis)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402


def save(fig, stem: Path) -> list[Path]:
    """Write ``stem``.pdf and ``stem``.png."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    out = []
    for ext in ("pdf", "png"):
        path = stem.with_suffix(f".{ext}")
        fig.savefig(path, dpi=150, bbox_inches="tight")
        out.append(path)
    plt.close(fig)
    return out


def velocity_profiles(profiles: dict[str, Path], stem: Path, title: str = "") -> list[Path]:
    """Fig. 10: axial velocity against radius at the outlet, each run against its parabola.

    ``profiles`` maps a legend label to a ``profile.csv`` (columns ``r_mm``, ``uz_m_s``,
    ``uz_poiseuille_m_s``). The profile is mirrored to the full diameter as in the paper.
    """
    fig, ax = plt.subplots(figsize=(5.0, 3.6))
    for k, (label, path) in enumerate(profiles.items()):
        df = pd.read_csv(path)
        r = np.concatenate([-df.r_mm[::-1], df.r_mm])
        u = np.concatenate([df.uz_m_s[::-1], df.uz_m_s])
        ax.plot(r, u, "-", color=f"C{k}", label=label)
        ref = np.concatenate([df.uz_poiseuille_m_s[::-1], df.uz_poiseuille_m_s])
        ax.plot(r, ref, "--", color=f"C{k}", lw=0.9, label=f"{label}: Hagen-Poiseuille")
    ax.set_xlabel("r (mm)")
    ax.set_ylabel("axial velocity $u_z$ (m/s)")
    if title:
        ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, frameon=False)
    return save(fig, stem)
