"""Makes ``docs/fields_example.png``: the particle demonstration scene (``scenes/pipe_cylinders_demo.yaml``,
the paper's 50 x 50 x 100 pipe at dx = 1 mm with 21 free cylinders and cubes) run with
``outputs.fields``, its last sample read back from the VTK files with ``vtk`` and drawn headless
with matplotlib: the axial velocity in the plane x = 0 and in the cross-section through the
middle, solid nodes (wall, particles) in grey, centres of the particles near the plane (+) and the
axes of the cylinders among them (arrows).

    python docs/fields_example.py [--out DIR] [--png PATH] [--duration S]

Needs the ``fields`` extra (vtk): ``pip install -e '.[fields]'``.

Also prints the size of one sample's files (lattice, particles).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def render(out_dir: Path, png: Path) -> Path:
    """Draw the last sample of ``out_dir/fields.pvd`` into ``png`` from the read-back arrays."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lbmpipe.fields import read_lattice, read_particles, read_series

    entries = read_series(out_dir / "fields.pvd")
    t_last = max(t for t, _, _ in entries)
    files = {part: out_dir / f for t, part, f in entries if t == t_last}
    lat = read_lattice(files[0])
    parts = read_particles(files[1]) if 1 in files else None
    nx, ny, nz = lat["shape"]
    o, h = lat["origin"], lat["spacing"]
    edges = [o[a] + h[a] * np.arange(lat["shape"][a] + 1) for a in range(3)]
    uz = lat["velocity_m_s"][..., 2] * 1e3  # mm/s
    solid = lat["solid"] > 0
    vmax = float(np.abs(uz[~solid]).max())

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.2), gridspec_kw={"width_ratios": [2.2, 1]},
                                   constrained_layout=True)
    ix = nx // 2
    sl = np.ma.masked_where(solid[ix], uz[ix])
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.6")
    m = ax1.pcolormesh(edges[2], edges[1], sl, cmap=cmap, vmin=0, vmax=vmax, shading="flat")
    if parts is not None:
        p = parts["points"]
        near = np.abs(p[:, 0] - 0.5 * (edges[0][ix] + edges[0][ix + 1])) < parts["bounding_radius_mm"]
        ax1.plot(p[near, 2], p[near, 1], "w+", ms=6)
        cyl = near & (parts["shape_id"] == 1)  # a cylinder's axis is its body z axis
        axis = parts["axis_z"]
        ax1.quiver(p[cyl, 2], p[cyl, 1], axis[cyl, 2], axis[cyl, 1], color="w", angles="xy", scale=12, width=0.004)
    ax1.set_xlabel("z (mm)")
    ax1.set_ylabel("y (mm)")
    ax1.set_aspect("equal")
    ax1.set_title(f"axial velocity at x = 0, t = {t_last:g} s")
    iz = nz // 2
    cs = np.ma.masked_where(solid[:, :, iz], uz[:, :, iz])
    ax2.pcolormesh(edges[0], edges[1], cs.T, cmap=cmap, vmin=0, vmax=vmax, shading="flat")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("y (mm)")
    ax2.set_aspect("equal")
    ax2.set_title(f"cross-section z = {0.5 * (edges[2][iz] + edges[2][iz + 1]):g} mm")
    fig.colorbar(m, ax=[ax1, ax2], label="u_z (mm/s); grey: wall and particles", shrink=0.9)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results/fields_example", help="run directory (default results/fields_example)")
    ap.add_argument("--png", default=str(ROOT / "docs" / "fields_example.png"))
    ap.add_argument("--duration", type=float, default=1.0, help="simulated seconds (default 1.0)")
    args = ap.parse_args(argv)

    import yaml

    from lbmpipe.scene import Scene
    from lbmpipe.run import run_scene
    from lbmpipe.units import derive

    data = yaml.safe_load((ROOT / "scenes" / "pipe_cylinders_demo.yaml").read_text())
    data["run"].update({"duration_s": args.duration, "spinup_s": args.duration / 2})
    data["outputs"] = {"fields": {"interval_s": args.duration / 4}}
    scene = Scene.model_validate(data)
    params = derive(scene)
    out = Path(args.out)
    summary = run_scene(scene, params, out, progress=False)
    if summary["status"] != "completed":
        print(summary["message"], file=sys.stderr)
        return 1
    for kind in ("lattice", "particles"):
        name = sorted((out / "fields").glob(f"{kind}_*"))[-1]
        print(f"{name}: {name.stat().st_size:,} bytes")
    print(render(out, Path(args.png)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
