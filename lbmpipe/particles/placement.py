"""Particles of a scene: construction of the rigid bodies (explicit and random placement) and the
particle outputs (``particles.parquet``, ``particles_static.csv``).

Units: the scene is physical (mm, m/s, rad/s, density ratio); ``Bodies`` are in lattice units
(positions in the lab frame of ``boundaries.Grid.positions``: pipe axis at x = y = 0, z from 0;
box from 0), with the fluid density 1, so a particle's lattice density is its density ratio.

Random placement (``RandomParticles``) is random sequential addition of non-overlapping
*bounding spheres*: centres uniform in the region where the bounding sphere stays inside the walls
(pipe: ``r <= R - r_b``; walled box axes: ``r_b`` from each wall; periodic axes: anywhere, with
minimum-image distances), orientations uniform on SO(3) (``rigid.random_quaternions``), each
candidate rejected if its bounding sphere overlaps one already placed (explicit bodies included).
Bounding spheres make this a dilute-suspension tool: an 8 mm cube's bounding sphere has 2.7 times
its volume, so random addition of bounding spheres jams near 10 % for cubes. Dense packings (the
paper's 30 % and 50 %) belong to ``lbmpipe.particles.packing``. When the requested number does not fit in
``MAX_ATTEMPTS`` candidates, placement fails with a ``SceneError`` naming the number reached; it
never returns fewer particles.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pandas as pd
from numba import njit

from ..outputs import replace_atomically
from . import packing
from .rigid import Bodies, random_quaternions, rotate_inv
from ..scene import SHAPE_SIZES, SceneError
from .shapes import bounding_radius, make_shape, volume

MAX_ATTEMPTS = 200_000

PARQUET_COLUMNS = ("t_s", "id", "x_mm", "y_mm", "z_mm", "vx_m_s", "vy_m_s", "vz_m_s", "qw", "qx", "qy", "qz",
                   "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_N", "fy_N", "fz_N", "tx_N_m", "ty_N_m", "tz_N_m")
STATIC_COLUMNS = ("id", "shape", "diameter_mm", "length_mm", "edge_mm", "density_kg_m3", "fixed")


def _shape_spec(p, dx_mm: float) -> dict:
    """``shapes.make_shape`` spec in lattice units from a scene particle entry."""
    spec = {"shape": p.shape}
    for key in SHAPE_SIZES[p.shape]:
        spec[key.removesuffix("_mm")] = getattr(p, key) / dx_mm
    return spec


def domain_geometry(scene, params):
    """``(lo, hi, periodic, radius)`` of the fluid domain in lattice coordinates (radius 0 for a
    box)."""
    nx, ny, nz = params.shape
    if scene.domain.kind == "pipe":
        r = nx / 2.0
        return np.array([-r, -r, 0.0]), np.array([r, r, float(nz)]), np.array([False, False, True]), r
    walls = scene.domain.walls
    periodic = np.array([getattr(walls, a) == "periodic" for a in "xyz"])
    return np.zeros(3), np.array([nx, ny, nz], dtype=np.float64), periodic, 0.0


@njit(cache=True)
def _rsa(n_new, rb_new, x_old, rb_old, lo, hi, periodic, radius, u, max_attempts):
    """Random sequential addition of ``n_new`` spheres of radius ``rb_new`` among fixed spheres
    ``x_old`` (radii ``rb_old``); ``u`` (max_attempts, 3) uniform numbers. Returns (centres,
    number placed)."""
    n_old = x_old.shape[0]
    out = np.zeros((n_new, 3))
    placed = 0
    span = hi - lo
    for t in range(max_attempts):
        if placed == n_new:
            break
        c = np.empty(3)
        if radius > 0.0:
            # uniform in the disc r <= radius - rb, z uniform
            rr = (radius - rb_new) * math.sqrt(u[t, 0])
            ph = 2.0 * math.pi * u[t, 1]
            c[0] = rr * math.cos(ph)
            c[1] = rr * math.sin(ph)
            c[2] = lo[2] + span[2] * u[t, 2]
        else:
            for d in range(3):
                if periodic[d]:
                    c[d] = lo[d] + span[d] * u[t, d]
                else:
                    c[d] = lo[d] + rb_new + (span[d] - 2.0 * rb_new) * u[t, d]
        ok = True
        for j in range(n_old + placed):
            if j < n_old:
                xj = x_old[j]
                rj = rb_old[j]
            else:
                xj = out[j - n_old]
                rj = rb_new
            d2 = 0.0
            for d in range(3):
                dd = c[d] - xj[d]
                if periodic[d]:
                    dd -= span[d] * math.floor(dd / span[d] + 0.5)
                d2 += dd * dd
            if d2 < (rj + rb_new) ** 2:
                ok = False
                break
        if ok:
            out[placed] = c
            placed += 1
    return out, placed


def bodies_from_scene(scene, params, info: dict | None = None) -> tuple[Bodies, list[dict]]:
    """The scene's particles as ``Bodies`` (lattice units) and one static record per body
    (``id, shape, diameter_mm, length_mm, edge_mm, density_kg_m3, fixed``). Raises SceneError when
    a random group cannot be placed or a packed group cannot be packed. ``info``, if given, receives
    how a packed group was made (``packed_group``)."""
    units = params.units
    dx_mm = scene.numerics.dx_mm
    rho_f = scene.fluid.density_kg_m3
    parts: list[Bodies] = []
    static: list[dict] = []
    centres: list[np.ndarray] = []
    radii: list[np.ndarray] = []
    lo, hi, periodic, radius = domain_geometry(scene, params)
    pspec = scene.particles

    def record(p, n, fixed):
        for _ in range(n):
            static.append({"id": len(static), "shape": p.shape,
                           "diameter_mm": p.diameter_mm if p.diameter_mm is not None else float("nan"),
                           "length_mm": p.length_mm if p.length_mm is not None else float("nan"),
                           "edge_mm": p.edge_mm if p.edge_mm is not None else float("nan"),
                           "density_kg_m3": p.density_ratio * rho_f, "fixed": bool(fixed)})

    for p in pspec.bodies:
        kind, h = make_shape(_shape_spec(p, dx_mm))
        q = np.asarray(p.orientation, dtype=np.float64)
        q = q / np.linalg.norm(q)
        x = np.asarray(p.position_mm, dtype=np.float64) / dx_mm
        v = np.array([units.velocity(c) for c in p.velocity_m_s])
        om = np.array([units.angular_velocity(c) for c in p.angular_velocity_rad_s])
        wb = rotate_inv(q, om)
        parts.append(Bodies.make(kind, h, p.density_ratio, x[None], q=q[None], v=v[None], wb=wb[None],
                                 fixed=np.array([p.fixed])))
        centres.append(x[None])
        radii.append(np.array([bounding_radius(kind, h)]))
        record(p, 1, p.fixed)

    for gi, g in enumerate(pspec.random):
        kind, h = make_shape(_shape_spec(g, dx_mm))
        vp = volume(kind, h)
        if g.count is not None:
            n = int(g.count)
            field = f"particles.random[{gi}].count"
        else:
            v_dom = math.pi * radius**2 * (hi[2] - lo[2]) if radius > 0 else float(np.prod(hi - lo))
            n = max(1, int(round(g.concentration * v_dom / vp)))
            field = f"particles.random[{gi}].concentration"
        rb = bounding_radius(kind, h)
        rng = np.random.default_rng(g.seed)
        u = rng.random((MAX_ATTEMPTS, 3))
        x_old = np.concatenate(centres) if centres else np.zeros((0, 3))
        rb_old = np.concatenate(radii) if radii else np.zeros(0)
        fits = (radius - rb > 0) if radius > 0 else all(periodic[d] or hi[d] - lo[d] > 2 * rb for d in range(3))
        x, placed = _rsa(n, rb, x_old, rb_old, lo, hi, periodic, radius, u, MAX_ATTEMPTS) if fits else (None, 0)
        if placed < n:
            v_dom = math.pi * radius**2 * (hi[2] - lo[2]) if radius > 0 else float(np.prod(hi - lo))
            raise SceneError(
                field,
                f"random placement of non-overlapping bounding spheres fitted only {placed} of {n} {g.shape}s "
                f"(volume fraction {placed * vp / v_dom:.3g}) in {MAX_ATTEMPTS} attempts",
                "lower the count or concentration; dense packings need lbmpipe.particles.packing (bounding spheres of a "
                "random placement waste most of the volume)")
        q = random_quaternions(n, rng)
        parts.append(Bodies.make(kind, h, g.density_ratio, x, q=q, fixed=np.full(n, g.fixed)))
        centres.append(x)
        radii.append(np.full(n, rb))
        record(g, n, g.fixed)

    for g in pspec.packed:
        x_mm, q, made = packed_group(g, scene)
        if info is not None:
            info.update(made)
        kind, h = make_shape(_shape_spec(g, dx_mm))
        n = x_mm.shape[0]
        parts.append(Bodies.make(kind, h, g.density_ratio, x_mm / dx_mm, q=q, fixed=np.zeros(n, dtype=bool)))
        record(g, n, False)
    return Bodies.concatenate(parts), static


PACKING_COLUMNS = ("id", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz")


def packed_group(g, scene) -> tuple[np.ndarray, np.ndarray, dict]:
    """Centres (mm, pipe axis at x = y = 0) and quaternions of a ``PackedParticles`` group, read
    from ``g.file`` when given, else packed now (``lbmpipe.particles.packing.pack``, in mm, so the packing
    does not depend on dx). Returns ``(x_mm (N, 3), q (N, 4), info)``; info holds the target and
    achieved concentrations, the count and the packing time. Raises ``SceneError`` (naming the
    highest concentration reached) when the target cannot be packed or the file does not match."""
    kind, h = make_shape(_shape_spec(g, 1.0))  # mm
    radius, length = scene.domain.diameter_mm / 2.0, scene.domain.length_mm
    n = packing.count_for_concentration(kind, h, radius, length, g.concentration)
    info = {"concentration_target": float(g.concentration), "count": n,
            "concentration_achieved": packing.achieved_concentration(kind, h, n, radius, length), "seed": int(g.seed)}
    if g.file is not None:
        try:
            df = pd.read_csv(g.file)
        except (OSError, ValueError) as exc:
            raise SceneError("particles.packed[0].file", f"cannot read the packing file {g.file} ({exc})",
                             "run `lbmpipe pack SCENE --out FILE` first, or remove `file` to pack at start-up") from None
        if list(df.columns) != list(PACKING_COLUMNS) or len(df) != n:
            raise SceneError("particles.packed[0].file",
                             f"{g.file} holds {len(df)} rows with columns {list(df.columns)}; this group needs {n} rows "
                             f"with columns {list(PACKING_COLUMNS)}",
                             "regenerate it with `lbmpipe pack` for this scene")
        x = df[["x_mm", "y_mm", "z_mm"]].to_numpy(np.float64)
        q = df[["qw", "qx", "qy", "qz"]].to_numpy(np.float64)
        info["source"] = str(g.file)
        info["max_overlap_mm"] = packing.max_overlap(kind, h, x, q, radius, length)
        return x, q / np.linalg.norm(q, axis=1)[:, None], info
    t0 = time.perf_counter()
    try:
        x, q = packing.pack(kind, h, n, radius, length, g.seed, max_seconds=g.max_seconds)
    except packing.PackingError as exc:
        err = SceneError("particles.packed[0].concentration", str(exc),
                         f"lower the concentration to at most {exc.reached:.3f}, or use smaller particles")
        err.reached = exc.reached
        raise err from None
    info["seconds"] = time.perf_counter() - t0
    info["source"] = "packed at start-up"
    info["max_overlap_mm"] = packing.max_overlap(kind, h, x, q, radius, length)
    return x, q, info


def write_packing(path: Path, x_mm: np.ndarray, q: np.ndarray) -> None:
    """The packing CSV ``packed_group`` reads (columns ``PACKING_COLUMNS``), full precision."""
    df = pd.DataFrame({"id": np.arange(len(x_mm)), "x_mm": x_mm[:, 0], "y_mm": x_mm[:, 1], "z_mm": x_mm[:, 2],
                       "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]})
    df.to_csv(path, index=False, float_format="%.17g")


# ----------------------------------------------------------------------------------------------
# Outputs


def write_static(out_dir: Path, static: list[dict]) -> str:
    """``particles_static.csv``: one row per particle, its shape and size (NaN where the shape has
    no such size), density and whether it is fixed."""
    df = pd.DataFrame(static, columns=list(STATIC_COLUMNS))
    replace_atomically(Path(out_dir) / "particles_static.csv", lambda tmp: df.to_csv(tmp, index=False))
    return "particles_static.csv"


class ParticleRecorder:
    """Samples of the particle state for ``particles.parquet`` (physical units).

    Per sample and particle: time, id, centre (mm, wrapped into the periodic domain), velocity
    (m/s), orientation quaternion (body -> lab), lab-frame angular velocity (rad/s), and the
    hydrodynamic force (N) and torque about the centre (N m) averaged over the steps since the
    previous sample (momentum exchange of the links plus the momentum of covered/uncovered nodes;
    external forces such as the driving pressure gradient and gravity are not included)."""

    def __init__(self, system, units):
        self.system = system
        self.units = units
        self.rows: list[np.ndarray] = []

    def sample(self, step: int) -> None:
        s, u = self.system, self.units
        b = s.bodies
        n = b.n
        if n == 0:
            return
        f, t = s.take_mean_force()
        om = s.omega_lab()
        lscale = u.dx_m * 1e3
        block = np.empty((n, len(PARQUET_COLUMNS)))
        block[:, 0] = u.time_phys(step)
        block[:, 1] = np.arange(n)
        block[:, 2:5] = b.x * lscale
        block[:, 5:8] = u.velocity_phys(1.0) * b.v
        block[:, 8:12] = b.q
        block[:, 12:15] = u.angular_velocity_phys(1.0) * om
        block[:, 15:18] = u.force_phys(1.0) * f
        block[:, 18:21] = u.torque_phys(1.0) * t
        self.rows.append(block)

    def frame(self) -> pd.DataFrame:
        data = np.concatenate(self.rows) if self.rows else np.zeros((0, len(PARQUET_COLUMNS)))
        df = pd.DataFrame(data, columns=list(PARQUET_COLUMNS))
        df["id"] = df["id"].astype(np.int64)
        return df

    def write(self, out_dir: Path) -> str:
        df = self.frame()
        replace_atomically(Path(out_dir) / "particles.parquet", lambda tmp: df.to_parquet(tmp, index=False))
        return "particles.parquet"
