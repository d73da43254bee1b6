"""Fig. 3-like snapshots: the particles of a case's last sample drawn in 3-D inside the pipe
outline, with a scale bar in mm and the flow direction, one PNG per particle case
(:func:`snapshots`), and the document's Fig. 3 (:func:`snapshot_gallery`): four of them side by
side, a dilute and a dense case of cylinders and of cubes (:func:`fig3_cases`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from . import statistics as st
from .steady import rotation_matrices
from .figures import CUBE_MAX_AXIS_ANGLE_DEG, status_text
from .plotting import plt
from .unpackable import declared, read_summary


def _cylinder_faces(d: float, length: float, n: int = 16) -> list[np.ndarray]:
    """Body-frame polygons of a cylinder (axis = body z): n side quads and two n-gon caps."""
    th = np.linspace(0.0, 2 * np.pi, n + 1)
    c, s = 0.5 * d * np.cos(th), 0.5 * d * np.sin(th)
    h = 0.5 * length
    quads = np.stack([np.stack([c[:-1], s[:-1], np.full(n, -h)], -1), np.stack([c[1:], s[1:], np.full(n, -h)], -1),
                      np.stack([c[1:], s[1:], np.full(n, h)], -1), np.stack([c[:-1], s[:-1], np.full(n, h)], -1)], 1)
    caps = np.stack([np.stack([c[:-1], s[:-1], np.full(n, z)], -1) for z in (-h, h)])
    return [quads, caps]  # (n, 4, 3) and (2, n, 3)


def _cube_faces(edge: float) -> list[np.ndarray]:
    a = 0.5 * edge
    faces = []
    for ax in range(3):
        for sgn in (-1.0, 1.0):
            u, v = [(1, 2), (2, 0), (0, 1)][ax]
            sq = np.zeros((4, 3))
            sq[:, ax] = sgn * a
            sq[:, u] = np.array([-a, a, a, -a])
            sq[:, v] = np.array([-a, -a, a, a])
            faces.append(sq)
    return [np.array(faces)]  # (6, 4, 3)


#: Length of the scale bar drawn beside the pipe (mm).
SCALE_BAR_MM = 20.0

#: The document's caption of Fig. 3 (``cases``: the four cases shown, by name).
FIG3_CAPTION = ("Particles at the last sample of a run, in their position and orientation inside the 50 mm pipe: "
                "{cases} (packing 1 where a case has several). The bar beside each pipe is "
                f"{SCALE_BAR_MM:g} mm; the arrow is the flow direction (+z); colour: the angle between the pipe axis and "
                "the cylinder axis (nearest cube axis for cubes).")


def _scale_and_flow(ax, R: float, L: float) -> None:
    """A scale bar of :data:`SCALE_BAR_MM` along the pipe axis (z is drawn nearly unforeshortened) on
    one side of the pipe, and an arrow in the flow direction (+z) on the other."""
    x0, z0 = -R - 6.0, 4.0
    ax.plot([x0, x0], [0.0, 0.0], [z0, z0 + SCALE_BAR_MM], color="k", lw=2.0)
    for z in (z0, z0 + SCALE_BAR_MM):
        ax.plot([x0 - 2.0, x0 + 2.0], [0.0, 0.0], [z, z], color="k", lw=1.0)
    ax.text(x0 - 3.0, 0.0, z0 + 0.5 * SCALE_BAR_MM, f"{SCALE_BAR_MM:g} mm", fontsize=7, ha="right", va="center",
            zdir=None)
    ax.quiver(R + 6.0, 0.0, 0.55 * L, 0.0, 0.0, 0.3 * L, color="C3", lw=1.6, arrow_length_ratio=0.25)
    ax.text(R + 8.0, 0.0, 0.5 * L, "flow", color="C3", fontsize=7, ha="left", va="top")


def snapshot(case_dir: Path, stem: Path, title: str = "", case: dict | None = None) -> Path:
    """Fig. 3-like view: the particles of the last sample in 3-D inside the pipe outline, each
    drawn as a polygon mesh in its position and orientation, coloured by its angle to the pipe
    axis. Writes ``stem``.png only and returns it. A case without particles to draw (not run,
    not packable, ``case`` its config entry: one declared unpackable) gets a PNG saying so."""
    stem = Path(stem)
    fig = snapshot_figure(case_dir, title, case)
    out = stem.parent / f"{stem.name}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=150, bbox_inches="tight")
    plt.close(fig)
    return out


def snapshot_figure(case_dir: Path, title: str = "", case: dict | None = None):
    """The figure of :func:`snapshot`, not saved: the 3-D axes first, the colour bar's (if any) second."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    case_dir = Path(case_dir)
    # The tall pipe fills a narrow axes; the colour bar gets its own axes right beside it (a
    # colorbar() of the 3-D axes sits beyond the axes' square box and leaves an empty band).
    fig = plt.figure(figsize=(4.0, 6.4))
    ax = fig.add_axes((0.0, 0.02, 0.78, 0.9), projection="3d")
    R, L = 25.0, 100.0
    th = np.linspace(0, 2 * np.pi, 97)
    for z in (0.0, L):
        ax.plot(R * np.cos(th), R * np.sin(th), np.full_like(th, z), color="0.5", lw=0.7)
    for a in np.linspace(0, 2 * np.pi, 9)[:-1]:
        ax.plot([R * np.cos(a)] * 2, [R * np.sin(a)] * 2, [0.0, L], color="0.75", lw=0.5)
    pq, static = case_dir / "particles.parquet", case_dir / "particles_static.csv"
    summary = read_summary(case_dir, case) or {}
    frame = case_dir / st.LAST_FRAME
    try:
        df = pd.read_csv(frame) if frame.exists() else pd.read_parquet(pq) if pq.exists() else pd.DataFrame()
    except pd.errors.EmptyDataError:
        df = pd.DataFrame()
    note = ""
    colour_bar = None
    if df.empty or not static.exists():
        note = status_text(summary.get("status", "not run")) if summary.get("status") != "completed" else "no samples"
    else:
        t_last = df["t_s"].max()
        last = df[df["t_s"] == t_last].merge(pd.read_csv(static), on="id", how="left")
        q = last[["qw", "qx", "qy", "qz"]].to_numpy()
        A = rotation_matrices(q)
        centre = last[["x_mm", "y_mm", "z_mm"]].to_numpy()
        polys, values = [], []
        is_cyl = (last["shape"] == "cylinder").to_numpy()
        angle = np.where(is_cyl, st.cylinder_axis_angle(q), st.cube_axis_angle(q))
        # one template per distinct (shape, size): particles of a case share it, so the mesh of all
        # particles is one broadcast product per template
        groups = last.reset_index(drop=True).groupby(["shape", "diameter_mm", "length_mm", "edge_mm"],
                                                      dropna=False).indices
        for idx in groups.values():
            sel = np.zeros(len(last), bool)
            sel[idx] = True
            r0 = last.iloc[idx[0]]
            faces = (_cylinder_faces(r0.diameter_mm, r0.length_mm) if r0["shape"] == "cylinder"
                     else _cube_faces(r0.edge_mm))
            for f in faces:  # f (F, k, 3) body frame -> (N, F, k, 3) lab frame
                lab = np.einsum("nij,fkj->nfki", A[sel], f) + centre[sel][:, None, None, :]
                polys += list(lab.reshape(-1, f.shape[1], 3))
                values += list(np.repeat(angle[sel], f.shape[0]))
        cmap = plt.get_cmap("viridis")
        vmax = 90.0 if is_cyl.all() else (CUBE_MAX_AXIS_ANGLE_DEG if not is_cyl.any() else 90.0)
        colors = cmap(np.asarray(values) / vmax)
        coll = Poly3DCollection(polys, facecolors=colors, edgecolors=(0, 0, 0, 0.15), linewidths=0.2)
        try:  # polygons of unequal length are padded with masked values that break autoscaling
            ax.add_collection3d(coll, autolim=False)
        except TypeError:  # matplotlib < 3.10
            ax.add_collection3d(coll)
        colour_bar = (plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax)),
                      "cylinder axis to pipe axis (deg)" if is_cyl.all() else "nearest cube axis to pipe axis (deg)")
        title = (title + "\n" if title else "") + f"t = {t_last:.2f} s, {len(last)} particles"
    _scale_and_flow(ax, R, L)
    if note:
        ax.text(0.0, 0.0, 0.5 * L, note, ha="center", fontsize=12, color="0.3", style="italic")
    ax.set_xlim(-R, R)
    ax.set_ylim(-R, R)
    ax.set_zlim(0, L)
    ax.set_box_aspect((2 * R, 2 * R, L))
    ax.set_xlabel("x (mm)", fontsize=8)
    ax.set_ylabel("y (mm)", fontsize=8)
    ax.set_zlabel("z (mm)", fontsize=8)
    # few ticks: the foreshortened x and y axes have room for three labels each without overlap
    ax.set_xticks([-20, 0, 20])
    ax.set_yticks([-20, 0, 20])
    ax.set_zticks([0, 20, 40, 60, 80, 100])
    ax.tick_params(labelsize=6, pad=0)
    ax.view_init(elev=12, azim=-70)
    if title:
        ax.set_title(title, fontsize=8)
    if colour_bar is not None:
        # right beside the z axis's label, known after a draw (the 3-D axes' own box is wider than the
        # pipe it draws)
        fig.canvas.draw()
        drawn = ax.zaxis.get_tightbbox(fig.canvas.get_renderer()).transformed(fig.transFigure.inverted())
        cb = fig.colorbar(colour_bar[0], cax=fig.add_axes((min(drawn.x1 + 0.04, 0.82), 0.3, 0.035, 0.36)))
        cb.ax.tick_params(labelsize=7)
        cb.set_label(colour_bar[1], fontsize=8)
    return fig


def snapshots(fid_dir: Path, cases: dict, fidelity: str | None = None, run: str = "") -> list[Path]:
    """``fid_dir/figures/fig3_<case>.png`` for every particle case of the config dict ``cases``,
    drawn from ``cases/<case>/<run>`` (``run``: ``seed1`` in a level with several packings)."""

    fid_dir = Path(fid_dir)
    fidelity = fidelity or fid_dir.name
    out = []
    for case, cfg in cases.items():
        if not (cfg or {}).get("particles"):
            continue
        label = f"{case}{', ' + run.replace('seed', 'seed ') if run else ''}, fidelity {fidelity}"
        case_dir, png = fid_dir / "cases" / case / run, fid_dir / "figures" / f"fig3_{case}.png"
        if png.exists() and not declared(cfg) and not any((case_dir / f).exists()
                                                          for f in (st.LAST_FRAME, "particles.parquet")):
            out.append(png)  # drawn from a trajectory no longer here (not committed): kept, not blanked
            continue
        out.append(snapshot(case_dir, png.with_suffix(""), title=label, case=cfg))
    return out


def fig3_cases(config: dict, fid_dir: Path | None = None) -> list[str]:
    """The four cases of the document's Fig. 3: for cylinders, then cubes, the smallest size that was
    run at a dilute and a dense concentration (the lowest and the highest of that size, lowest Reynolds
    number, collisions on), those two. A case counts as run when its summary says ``completed`` (any
    case of the config when ``fid_dir`` is None)."""
    cases = config.get("cases") or {}

    def ran(name):
        if fid_dir is None:
            return True
        return (read_summary(Path(fid_dir) / "cases" / name, cases[name]) or {}).get("status") == "completed"

    out = []
    for shape in ("cylinder", "cube"):
        rows = [(n, c) for n, c in cases.items() if ((c or {}).get("particles") or {}).get("shape") == shape
                and (c or {}).get("collisions") is not False and ran(n)]
        if not rows:
            continue
        re_min = min(float(c["reynolds"]) for _, c in rows)
        rows = [(n, c) for n, c in rows if float(c["reynolds"]) == re_min]
        by_size: dict[tuple, list] = {}
        for n, c in rows:
            p = c["particles"]
            size = (p.get("edge_mm") or 0.0, p.get("diameter_mm") or 0.0, p.get("length_mm") or 0.0)
            by_size.setdefault(size, []).append((float(p.get("concentration", 0.0)), n))
        sizes = [k for k in sorted(by_size) if len({c for c, _ in by_size[k]}) > 1] or sorted(by_size)
        pick = sorted(by_size[sizes[0]])
        out += list(dict.fromkeys([pick[0][1], pick[-1][1]]))
    return out


def snapshot_gallery(fid_dir: Path, cases, out_png: Path | None = None, ncols: int = 4) -> Path | None:
    """The document's Fig. 3: the snapshots ``fid_dir/figures/fig3_<case>.png`` of ``cases`` (names,
    in order, :func:`fig3_cases`; those without a PNG are left out) side by side, ``ncols`` to a row,
    each titled with its case name, into ``out_png`` (default ``fid_dir/figures/fig3_gallery.png``, the
    name the pipeline's ``paper`` rule expects). Returns the path, or None when no snapshot exists
    (nothing is written)."""
    fig_dir = Path(fid_dir) / "figures"
    found = [(c, fig_dir / f"fig3_{c}.png") for c in cases]
    found = [(c, p) for c, p in found if p.is_file()]
    if not found:
        return None
    out_png = Path(out_png) if out_png is not None else fig_dir / "fig3_gallery.png"
    ncols = max(1, min(ncols, len(found)))
    nrows = -(-len(found) // ncols)
    images = [plt.imread(p) for _, p in found]
    aspect = max(im.shape[0] / im.shape[1] for im in images)
    fig, axs = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, 3.2 * aspect * nrows + 0.3), squeeze=False)
    for ax in axs.flat:
        ax.axis("off")
    for ax, (case, _), im in zip(axs.flat, found, images):
        ax.imshow(im)
        ax.set_title(case, fontsize=10)
    fig.tight_layout(pad=0.3)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png
