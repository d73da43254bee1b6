"""Time-averaged velocity profiles of a box across its walls (``profile.csv`` of a box scene).

Along each walled axis, every sample after spin-up adds the plane sums of the three velocity
components over the fluid nodes of each plane (nodes count only while they are fluid: particles
are excluded); the profile is the sum over samples divided by the count of fluid node-samples.
The pipe's radial profile is ``observables.radial_profile``. The accumulators are part of a
checkpoint (``state``/``restore``), so a resumed run writes the same profile bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

AXES = "xyz"


class PlaneProfile:
    """Plane averages of (ux, uy, uz) along the walled axes of a box grid."""

    def __init__(self, grid):
        self.grid = grid
        self.axes = [a for a in range(3) if not grid.periodic[a]]
        self.samples = np.zeros(1)
        self.sums = {a: np.zeros((3, grid.shape[a])) for a in self.axes}
        self.counts = {a: np.zeros(grid.shape[a]) for a in self.axes}

    @classmethod
    def for_grid(cls, grid):
        """A profile for a box with at least one walled axis, else ``None``."""
        return cls(grid) if grid.kind == "box" and not all(grid.periodic) else None

    def add(self, u: tuple[np.ndarray, np.ndarray, np.ndarray], fluid: np.ndarray) -> None:
        """Add one sample: ``u`` the velocity components and ``fluid`` the fluid mask on the grid."""
        for a in self.axes:
            other = tuple(b for b in range(3) if b != a)
            for k in range(3):
                self.sums[a][k] += np.where(fluid, u[k], 0.0).sum(axis=other)
            self.counts[a] += fluid.sum(axis=other)
        self.samples += 1

    def state(self) -> dict[str, np.ndarray]:
        out = {"plane_samples": self.samples}
        for a in self.axes:
            out[f"plane_sum_{AXES[a]}"] = self.sums[a]
            out[f"plane_count_{AXES[a]}"] = self.counts[a]
        return out

    def restore(self, arrays: dict) -> None:
        self.samples[...] = arrays["plane_samples"]
        for a in self.axes:
            self.sums[a][...] = arrays[f"plane_sum_{AXES[a]}"]
            self.counts[a][...] = arrays[f"plane_count_{AXES[a]}"]

    def frame(self, units) -> pd.DataFrame:
        """Rows per walled axis and plane of fluid nodes: ``axis``, ``position_mm`` (node centre,
        the walls at 0 and the extent), ``ux_m_s``, ``uy_m_s``, ``uz_m_s`` and ``nodes`` (fluid
        nodes of the plane, averaged over the samples)."""
        pos = self.grid.positions()
        rows = []
        v = units.velocity_phys(1.0)
        for a in self.axes:
            cnt = self.counts[a]
            keep = cnt > 0
            mean = self.sums[a][:, keep] / cnt[keep]
            rows.append(pd.DataFrame({
                "axis": AXES[a],
                "position_mm": units.length_phys(1.0) * 1e3 * pos[a][keep],
                "ux_m_s": v * mean[0], "uy_m_s": v * mean[1], "uz_m_s": v * mean[2],
                "nodes": cnt[keep] / max(self.samples[0], 1.0),
            }))
        return pd.concat(rows, ignore_index=True)

    def write(self, out_dir: Path, units) -> str:
        """``profile.csv`` (see ``frame``)."""
        self.frame(units).to_csv(Path(out_dir) / "profile.csv", index=False)
        return "profile.csv"
