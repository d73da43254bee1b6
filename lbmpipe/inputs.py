"""Checks on what a user hands to lbmpipe beyond the scene's own fields: the geometry of placed
bodies, the memory a run needs, the output folder and the command-line arguments.

Each check fails with one line naming the field (scene), argument or file and the fix: a scene
problem as :class:`lbmpipe.errors.SceneError`, an argument or folder problem as
:class:`InputError` (``"<kind> error in <where>: <message>. Fix: <fix>"``). Everything here runs
before the first allocation of the lattice, so ``lbmpipe check`` and ``lbmpipe run`` apply the
same rules and a refused run has written nothing.
"""

from __future__ import annotations

import json
import math
import os
import resource
from pathlib import Path

import numpy as np

from lbmpipe.checkpoint import scene_fingerprint
from lbmpipe.errors import SceneError
from lbmpipe.particles.collision_params import CollisionParams, min_periodic_length
from lbmpipe.particles.shapes import scene_shape, volume

#: bytes per node beside the two population arrays: moments at a sample (4 float64), the profile
#: sums (2 float64), masks and owner maps, and the temporaries of the initial equilibrium
EXTRA_BYTES_PER_NODE = 64
#: bytes per particle: rigid-body state, link lists of a small body, recorder rows
BYTES_PER_BODY = 4096
#: fixed cost of a run (interpreter, numba, compiled kernels)
BASE_BYTES = 300 * 2**20
#: nodes per axis beyond which no run is meaningful (and integer arithmetic stays exact)
MAX_NODES_PER_AXIS = 10**7


class InputError(ValueError):
    """A bad argument, file or folder: ``"<kind> error in <where>: <message>. Fix: <fix>"``."""

    def __init__(self, where: str, message: str, fix: str, kind: str = "argument"):
        self.where, self.message, self.fix, self.kind = where, message.rstrip("."), fix.rstrip("."), kind
        super().__init__(self.line())

    def line(self) -> str:
        return f"{self.kind} error in {self.where}: {self.message}. Fix: {self.fix}"


def _fmt(x: float) -> str:
    return f"{x:.4g}"


# ---------------------------------------------------------------------------------------------
# Memory


def lattice_q(name: str) -> int:
    return int(name.removeprefix("D3Q"))


def grid_shape(scene) -> tuple[int, int, int]:
    """Nodes along x, y, z (as ``units.derive`` counts them; the scene has been validated)."""
    d, dx = scene.domain, scene.numerics.dx_mm
    if d.kind == "pipe":
        n = int(round(d.diameter_mm / dx))
        return n, n, int(round(d.length_mm / dx))
    return tuple(int(round(s / dx)) for s in d.size_mm)


def body_count(scene) -> int:
    """Number of particles the run will hold (random groups by concentration rounded as
    ``particles.bodies_from_scene`` does; packed groups by ``round(c V / v_p)``)."""
    p = scene.particles
    if p is None:
        return 0
    n = len(p.bodies)
    v_dom = domain_volume_mm3(scene)
    for g in list(p.random) + list(p.packed):
        if getattr(g, "count", None) is not None:
            n += int(g.count)
        elif g.concentration is not None and all(getattr(g, k) is not None for k in _sizes(g.shape)):
            n += max(1, int(round(g.concentration * v_dom / body_volume_mm3(g))))
    return n


def memory_estimate(scene) -> dict:
    """Bytes a run of ``scene`` needs at its peak: two population arrays of the whole block
    (``nx ny (nz + 2)`` nodes, ``q`` values of ``numerics.precision``), the per-node extras
    (``EXTRA_BYTES_PER_NODE``), the particles and a fixed base."""
    nx, ny, nz = grid_shape(scene)
    nodes = nx * ny * (nz + 2)
    item = 8 if scene.numerics.precision == "float64" else 4
    q = lattice_q(scene.numerics.lattice)
    pops = 2 * q * item * nodes
    bodies = body_count(scene) * BYTES_PER_BODY
    total = BASE_BYTES + pops + EXTRA_BYTES_PER_NODE * nodes + bodies
    return {"bytes": total, "nodes": nx * ny * nz, "populations_bytes": pops, "bodies": body_count(scene)}


def available_memory() -> tuple[int | None, str]:
    """Bytes this process may still allocate and where the figure comes from: the smallest of
    the kernel's MemAvailable, a cgroup limit and the address-space limit (``ulimit -v``)."""
    cands: list[tuple[int, str]] = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                cands.append((int(line.split()[1]) * 1024, "available memory (/proc/meminfo)"))
    except (OSError, ValueError, IndexError):
        pass
    try:
        lim = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        if lim != "max":
            cands.append((int(lim) - used, "the cgroup memory limit"))
    except (OSError, ValueError):
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        cands.append((int(soft), "the address-space limit (ulimit -v)"))
    if not cands:
        return None, "unknown"
    return min(cands)


def format_bytes(n: float) -> str:
    for unit, scale in (("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.0f} B"


def check_memory(scene) -> dict:
    """The memory estimate; raises SceneError (field ``numerics.dx_mm``) when it exceeds what the
    machine has available. Needs no allocation, so a grid of billions of nodes is refused at once."""
    est = memory_estimate(scene)
    avail, source = available_memory()
    est["available_bytes"], est["available_source"] = avail, source
    if avail is not None and est["bytes"] > avail:
        nx, ny, nz = grid_shape(scene)
        # nodes scale as dx^-3: the spacing that fits the populations into what is available
        room = max(avail - BASE_BYTES - est["bodies"] * BYTES_PER_BODY, 1)
        factor = (est["bytes"] - BASE_BYTES - est["bodies"] * BYTES_PER_BODY) / room
        dx_ok = scene.numerics.dx_mm * max(factor, 1.0) ** (1 / 3) * 1.01
        field = "numerics.dx_mm"
        fix = (f"raise numerics.dx_mm to at least {_fmt(dx_ok)} mm (every extent a multiple of it), or shrink "
               "the domain")
        if est["bodies"] * BYTES_PER_BODY > avail / 2:
            field, fix = "particles", "lower the particle count"
        raise SceneError(field, f"the run needs about {format_bytes(est['bytes'])} ({nx} x {ny} x {nz} = "
                         f"{est['nodes']:,} nodes, {est['bodies']:,} particles), more than the "
                         f"{format_bytes(avail)} of {source}", fix)
    return est


# ---------------------------------------------------------------------------------------------
# Geometry of the particles a scene places


def _sizes(shape: str) -> tuple[str, ...]:
    return {"sphere": ("diameter_mm",), "cylinder": ("diameter_mm", "length_mm"), "cube": ("edge_mm",)}[shape]


def half_extents(p) -> np.ndarray:
    if p.shape == "sphere":
        return np.full(3, p.diameter_mm / 2)
    if p.shape == "cylinder":
        return np.array([p.diameter_mm / 2, p.diameter_mm / 2, p.length_mm / 2])
    return np.full(3, p.edge_mm / 2)


def bounding_radius_mm(p) -> float:
    h = half_extents(p)
    if p.shape == "sphere":
        return float(h[0])
    if p.shape == "cylinder":
        return float(math.hypot(h[0], h[2]))
    return float(math.sqrt(3.0) * h[0])


def body_volume_mm3(p) -> float:
    return volume(*scene_shape(p.shape, p.diameter_mm, p.length_mm, p.edge_mm))


def domain_volume_mm3(scene) -> float:
    d = scene.domain
    if d.kind == "pipe":
        return math.pi * (d.diameter_mm / 2) ** 2 * d.length_mm
    return float(np.prod(d.size_mm))


def rotation(q) -> np.ndarray:
    """Rotation matrix body -> lab of the quaternion ``q`` [w, x, y, z] (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _boundary_points(p, R: np.ndarray, n_rim: int = 4096) -> np.ndarray:
    """Lab-frame points (relative to the centre) whose convex hull is the body (cube: corners;
    cylinder: the two rims, sampled; sphere: not used)."""
    h = half_extents(p)
    if p.shape == "cube":
        s = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)
        return (s * h) @ R.T
    t = np.linspace(0.0, 2 * math.pi, n_rim, endpoint=False)
    ring = np.stack([h[0] * np.cos(t), h[0] * np.sin(t), np.zeros_like(t)], axis=1)
    pts = np.concatenate([ring + [0, 0, h[2]], ring - [0, 0, h[2]]])
    return pts @ R.T


def wall_overlap_mm(scene, p) -> tuple[float, str]:
    """How far (mm) an explicit body reaches into the pipe wall or a wall of the box (<= 0: it
    does not), and which wall."""
    d = scene.domain
    c = np.asarray(p.position_mm, dtype=np.float64)
    R = rotation(p.orientation)
    h = half_extents(p)
    if d.kind == "pipe":
        rad = d.diameter_mm / 2
        if p.shape == "sphere":
            reach = math.hypot(c[0], c[1]) + h[0]
        else:
            pts = _boundary_points(p, R) + c
            reach = float(np.hypot(pts[:, 0], pts[:, 1]).max())
        return reach - rad, "the pipe wall"
    worst, where = -math.inf, ""
    for a, axis in enumerate("xyz"):
        if getattr(d.walls, axis) != "wall":
            continue
        if p.shape == "sphere":
            ext = h[0]
        elif p.shape == "cube":
            ext = float(np.abs(R[a]) @ h)
        else:
            ext = abs(R[a, 2]) * h[2] + h[0] * math.sqrt(max(0.0, 1.0 - R[a, 2] ** 2))
        for side, ov in ((f"{axis}-", ext - c[a]), (f"{axis}+", c[a] + ext - d.size_mm[a])):
            if ov > worst:
                worst, where = ov, f"the wall {side}"
    return worst, where


def _min_image(d: np.ndarray, scene) -> np.ndarray:
    dom = scene.domain
    if dom.kind == "pipe":
        L = np.array([math.inf, math.inf, dom.length_mm])
    else:
        L = np.array([s if getattr(dom.walls, a) == "periodic" else math.inf for a, s in zip("xyz", dom.size_mm)])
    per = np.isfinite(L)
    d = d.copy()
    d[per] -= L[per] * np.round(d[per] / L[per])
    return d


def _support(p, R: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Support function of the body (centre at 0, rotation ``R``) along unit directions ``n`` (m, 3)."""
    h = half_extents(p)
    if p.shape == "sphere":
        return np.full(len(n), h[0])
    nb = n @ R  # body-frame components
    if p.shape == "cube":
        return np.abs(nb) @ h
    c = np.clip(np.abs(nb[:, 2]), 0.0, 1.0)
    return h[2] * c + h[0] * np.sqrt(1.0 - c * c)


def _directions(count: int = 4000) -> np.ndarray:
    """Quasi-uniform unit vectors (Fibonacci sphere)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def pair_gap_mm(scene, p1, p2) -> float:
    """Signed gap (mm; negative: overlap depth) between two explicit bodies at the nearest
    periodic image. Separating-axis form for convex bodies: the overlap depth is the minimum over
    unit ``n`` of ``s1(n) + s2(n) - n . d`` (supports about the centres, ``d`` the centre
    offset), minimised over sampled directions, the bodies' own axes and their cross products,
    then refined locally; a sampled minimum never underestimates the depth. NumPy only: no
    compiled kernel, so ``check`` stays fast."""
    d = _min_image(np.asarray(p2.position_mm, float) - np.asarray(p1.position_mm, float), scene)
    dist = float(np.linalg.norm(d))
    r1, r2 = bounding_radius_mm(p1), bounding_radius_mm(p2)
    if dist >= r1 + r2:
        return dist - r1 - r2
    if p1.shape == "sphere" and p2.shape == "sphere":
        return dist - p1.diameter_mm / 2 - p2.diameter_mm / 2
    R1, R2 = rotation(p1.orientation), rotation(p2.orientation)
    axes = [R1[:, k] for k in range(3)] + [R2[:, k] for k in range(3)]
    axes += [np.cross(a, b) for a in axes[:3] for b in axes[3:]]
    if dist > 0:
        axes.append(d / dist)
    special = np.array([a / np.linalg.norm(a) for a in axes if np.linalg.norm(a) > 1e-12])
    n = np.concatenate([_directions(), special, -special])

    def depth(n):
        return _support(p1, R1, n) + _support(p2, R2, n) - n @ d

    f = depth(n)
    best = n[np.argsort(f)[:8]]
    rng = np.random.default_rng(0)
    step = 0.05
    for _ in range(40):  # local refinement around the best directions, shrinking the step
        trial = (best[:, None, :] + step * rng.standard_normal((len(best), 32, 3))).reshape(-1, 3)
        trial /= np.linalg.norm(trial, axis=1)[:, None]
        cand = np.concatenate([best, trial])
        fc = depth(cand)
        best = cand[np.argsort(fc)[:8]]
        step *= 0.85
    return -float(min(f.min(), depth(best).min()))


def placement_errors(scene) -> list:
    """Explicit bodies (``particles.bodies``) that reach into a wall, or into each other, by more
    than round-off: SceneErrors with the overlap in mm. Fixed bodies may touch the wall and each
    other (a static obstacle may be built from several bodies, or meet the wall)."""
    errs = []
    bodies = scene.particles.bodies if scene.particles is not None else []
    # the collision model's own bound on overlaps: smaller ones are resolved within its tolerance
    tol = scene.particles.collisions.overlap_tol_dx * scene.numerics.dx_mm if bodies else 0.0
    ok = [all(getattr(b, k) is not None for k in _sizes(b.shape)) and any(b.orientation) for b in bodies]
    for i, b in enumerate(bodies):
        if not ok[i] or b.fixed:
            continue
        ov, where = wall_overlap_mm(scene, b)
        if ov > tol:
            errs.append(SceneError(f"particles.bodies[{i}].position_mm",
                                   f"the {b.shape} reaches {_fmt(ov)} mm into {where} (centre "
                                   f"{', '.join(_fmt(c) for c in b.position_mm)} mm)",
                                   f"move it at least {_fmt(ov)} mm away from that wall, or make it smaller"))
    for i in range(len(bodies)):
        for j in range(i + 1, len(bodies)):
            a, b = bodies[i], bodies[j]
            if not (ok[i] and ok[j]) or (a.fixed and b.fixed):
                continue
            gap = pair_gap_mm(scene, a, b)
            if gap < -tol:
                errs.append(SceneError(f"particles.bodies[{j}].position_mm",
                                       f"the {b.shape} overlaps particles.bodies[{i}] (a {a.shape}) by {_fmt(-gap)} mm",
                                       f"move the two centres at least {_fmt(-gap)} mm further apart"))
    return errs


def pair_rule_errors(scene) -> list:
    """The collision model's periodic rule, as the run applies it (``collisions.min_periodic_length``):
    a pair search needs every periodic length to hold two interaction ranges. It applies only when
    there are pairs to search: collisions and ``pairs`` on, more than one body, a free one."""
    p = scene.particles
    if p is None or not p.collisions.enabled or not p.collisions.pairs:
        return []
    groups = list(p.bodies) + list(p.random) + list(p.packed)
    if not groups or any(not all(getattr(g, k) is not None for k in _sizes(g.shape)) for g in groups):
        return []
    free = any(not getattr(g, "fixed", False) for g in groups)
    if not free or body_count(scene) < 2:
        return []
    dx = scene.numerics.dx_mm
    rb_lu = max(bounding_radius_mm(g) for g in groups) / dx
    need_mm = min_periodic_length(rb_lu, p.collisions.contact_gap_dx, CollisionParams.skin) * dx
    d = scene.domain
    lengths = ([("z", "domain.length_mm", d.length_mm)] if d.kind == "pipe" else
               [(a, f"domain.size_mm[{i}]", d.size_mm[i]) for i, a in enumerate("xyz")
                if getattr(d.walls, a) == "periodic"])
    errs = []
    for axis, field, length in lengths:
        if length is not None and length < need_mm * (1 - 1e-12):
            n_ok = math.ceil(need_mm / dx - 1e-9)
            errs.append(SceneError(field, f"the periodic length along {axis} ({_fmt(length)} mm) is shorter than "
                                   f"the collision model's pair search needs: two interaction ranges, 2 x (2 x the "
                                   f"largest bounding radius {_fmt(rb_lu * dx)} mm + contact gap and skin "
                                   f"{_fmt((p.collisions.contact_gap_dx + CollisionParams.skin) * dx)} mm) = "
                                   f"{_fmt(need_mm)} mm, so a pair would meet twice across the period",
                                   f"make it at least {_fmt(n_ok * dx)} mm, or set particles.collisions.pairs: false "
                                   "(walls only), or use smaller particles"))
    return errs


def random_volume_errors(scene) -> list:
    """A random group whose particles hold more volume than the domain can never be placed:
    refused before anything is allocated for them."""
    errs = []
    p = scene.particles
    if p is None:
        return errs
    v_dom = domain_volume_mm3(scene)
    for i, g in enumerate(p.random):
        if g.count is None or not all(getattr(g, k) is not None for k in _sizes(g.shape)):
            continue
        frac = g.count * body_volume_mm3(g) / v_dom
        if frac >= 1.0:
            n_max = int(v_dom / body_volume_mm3(g))
            errs.append(SceneError(f"particles.random[{i}].count",
                                   f"{g.count:,} {g.shape}s hold {frac:.3g} times the domain's volume",
                                   f"give a count well below {n_max:,} (random placement reaches about a third "
                                   "of the volume), or use particles.packed for dense suspensions"))
    return errs


# ---------------------------------------------------------------------------------------------
# Output folder and checkpoint path


def _first_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_writable_dir(path: Path, arg: str) -> None:
    """``path`` is, or can be made, a folder we can write in: creates it and a scratch file in it
    (removed). Raises InputError naming ``arg``."""
    if path.exists() and not path.is_dir():
        raise InputError(arg, f"{path} is an existing file, not a folder", "give the path of a folder (it is created "
                         "if missing), or move the file away")
    anc = _first_existing(path)
    if not anc.is_dir():
        raise InputError(arg, f"{path} lies under {anc}, which is a file, not a folder",
                         "choose a path whose parents are folders")
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".lbmpipe-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise InputError(arg, f"cannot write in {path} ({exc.strerror or exc})",
                         "choose a folder you can write to, or fix its permissions") from None


def check_checkpoint_path(path: Path) -> None:
    """``--checkpoint`` names a file (existing or not) in a folder we can write in."""
    if path.is_dir():
        raise InputError("--checkpoint", f"{path} is a folder", "give a file path, e.g. run.ckpt.npz")
    anc = _first_existing(path.parent)
    if not anc.is_dir():
        raise InputError("--checkpoint", f"{path} lies under {anc}, which is a file, not a folder",
                         "choose a path whose parents are folders")
    if path.exists() and not os.access(path, os.R_OK):
        raise InputError("--checkpoint", f"cannot read {path}", "fix its permissions, or delete it to start afresh")


def out_dir_owner(out: Path) -> dict | None:
    """``{"name", "fingerprint", "status"}`` of the run whose ``summary.json`` lies in ``out``
    (fingerprint None if unreadable), or None when there is none."""
    path = out / "summary.json"
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        scene = doc.get("scene")
        return {"name": (scene or {}).get("name", "?"), "status": doc.get("status"),
                "fingerprint": scene_fingerprint(scene) if isinstance(scene, dict) else None}
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        return {"name": "?", "status": None, "fingerprint": None}
