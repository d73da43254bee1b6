"""Stability suite: the numerically hard cases of the reproduction, run with the run-time guard and
checked against stated invariants; the table ``results/<fid>/tables/stability.csv``.

Cases (``suite``), all in the paper's pipe (50 mm x 100 mm, periodic in z, flow-rate driving, D3Q15,
half-way bounce-back) at a lattice spacing ``dx`` with acoustic scaling: the paper's
``dt = 1 ms`` at ``dx = 1 mm`` becomes ``dt = 1e-3 s per mm of dx``, which keeps the paper's
lattice velocities and Mach numbers at any ``dx`` (paper/reading.md "Parameters"):

* the particle-free flow at Re 26 with the paper's dt (centre-line Mach 0.56), BGK and TRT, and
  with dt halved (Mach 0.28, the pipeline's setting);
* ``tau`` close to 1/2 (0.51, a high Reynolds number), BGK and TRT;
* the 50 % packings of 8 x 8 mm cylinders and 8 mm cubes (collisions on), at Re 9.4, and the
  cylinders at Re 26 with the paper's dt and with dt halved;
* the largest particles, touching the wall: 24 mm cubes at 30 % and 16 x 24 mm cylinders at 50 %;
* particles released in contact with each other and with the wall;
* density ratios 1.0 (all of the above) and below (0.8 and 0.5, gravity off);
* a long run (>= 5e4 steps) at a tiny resolution (dx = 5 mm) with a few free particles.

Invariants, measured every ``probe_every`` steps by ``run_case`` (bounds in ``BOUNDS``):

* no NaN/Inf, lattice speed and density within the guard's limits (``lbmpipe.guard``; the guard
  stops the run at the first violation and its message goes into the table);
* relative drift of the mean fluid density (particle-free: of the total fluid mass), probed right
  after the mass correction of particle runs; the mass that correction added is reported too, and
  the mass the density floor added to drained films (``effects.StreamCollide``) with the number of
  node updates it acted on;
* bounded kinetic energy: fluid + particles, relative to the Hagen-Poiseuille flow at the target
  flow rate over the whole pipe (``ke_ratio_max``);
* every particle inside: the smallest signed gap between a particle and the pipe wall
  (``min_wall_clearance_lu``, ``contact.contact_pipe``, measured after the step's drift) at least
  -0.1 lattice spacing (the collision model's bound before its next call);
* overlaps after each collision step within the collision model's bound ``overlap_tol``, and
  before it within 0.1 spacing.

Threads: on a shared, loaded machine numba's parallel regions with more threads than free cores
slow down by an order of magnitude (measured: 14 ms against 0.5 ms per step of the 20-node pipe
at load 9 on 2 cores), so the runner sets the thread count (default 1).

A case is ``stable`` when the guard never fired and every invariant holds; ``unstable`` with the
step it failed at and the guard's message; ``violated`` when it ran through but an invariant bound
was exceeded (listed in ``violations``); ``unpackable`` when its packing cannot be made.
"""

from __future__ import annotations

import copy
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from ..fluid import observables as obs
from ..outputs import write_json
from ..particles.collision_params import CollisionParams
from ..particles.contact import contact_pipe
from ..particles.placement import packed_group, write_packing
from ..scene import Scene, SceneError
from ..assemble import simulation_from_scene
from ..solver import run_loop
from ..units import derive
from .pipe import DENSITY_KG_M3, pipe_scene, time_step

#: stated bounds of the invariants
BOUNDS = {
    "mass_drift_rel": 1e-9,  # particle-free: total fluid mass (round-off over the run)
    # with particles: mean fluid density against the start. Ladd's remap loses mass systematically
    # (particles/coupling); MassCorrection restores the mean density every 25 steps to its value after the
    # first step, whose covering and uncovering shift it by up to ~2e-3 at 50 % (measured).
    "mass_drift_rel_particles": 5e-3,
    "ke_ratio_max": 3.0,  # kinetic energy / Hagen-Poiseuille's at the target Q
    # particles/collisions: overlaps are <= overlap_tol right after the collision step and within the
    # model's overlap bound (OVERLAP_BOUND_FACTOR * overlap_tol) between calls
    "overlap_before_lu": CollisionParams().overlap_bound,
    "wall_clearance_min_lu": -0.1,
}

#: per fidelity level: lattice spacing, steps of the particle cases and of the particle-free ones,
#: steps of the long run (config ``stability: {<fid>: {...}}`` overrides any of them)
FIDELITY_DEFAULTS = {
    "smoke": {"dx_mm": 2.5, "steps": 400, "flow_steps": 2000, "long_steps": 50_000, "long_dx_mm": 5.0},
    "quick": {"dx_mm": 2.0, "steps": 800, "flow_steps": 4000, "long_steps": 50_000, "long_dx_mm": 5.0},
    "paper": {"dx_mm": 1.0, "steps": 1000, "flow_steps": 5000, "long_steps": 100_000, "long_dx_mm": 5.0},
}


@dataclass
class StabilityCase:
    """One case: ``name``, what it probes, and its scene at a given ``dx_mm`` (``scene(dx, steps)``).

    ``reynolds``, ``dt_factor`` (times the paper's dt), ``collision``, ``tau`` (if set, the
    viscosity is chosen for it), ``particles`` (the scene's ``particles`` block, or None),
    ``kind`` ("flow" | "particles" | "long") picks the step count of the fidelity level, ``expect``
    the outcome the CI test asserts ("stable", "unstable", or None: recorded only)."""
    name: str
    description: str
    reynolds: float = 9.4
    dt_factor: float = 1.0
    collision: str = "bgk"
    tau: float | None = None
    particles: dict | None = None
    kind: str = "particles"
    expect: str | None = "stable"
    fixed_dx_mm: float | None = None
    mach_limit: float = 0.6
    extra: dict = field(default_factory=dict)

    def scene(self, dx_mm: float, steps: int, sample_steps: int = 25) -> dict:
        dx = float(self.fixed_dx_mm or dx_mm)
        dt = time_step(dx, factor=self.dt_factor)
        fluid: dict = {"density_kg_m3": DENSITY_KG_M3}
        if self.tau is not None:
            fluid["viscosity_m2_s"] = (self.tau - 0.5) * (dx * 1e-3) ** 2 / (3.0 * dt)
        else:
            fluid["reynolds"] = self.reynolds
        sample = min(sample_steps, steps)
        data = pipe_scene(f"stability_{self.name}", self.reynolds,
                          {"dx_mm": dx, "dt_s": dt, "collision": self.collision, "mach_limit": self.mach_limit},
                          {"duration_s": steps * dt, "spinup_s": 0.0, "sample_interval_s": sample * dt},
                          fluid=fluid, outputs={"profile": False, "flow_rate": True})
        if self.particles is not None:
            data["particles"] = copy.deepcopy(self.particles)
        return data

    def settings(self, dx_mm: float) -> str:
        dx = float(self.fixed_dx_mm or dx_mm)
        parts = [self.collision.upper(), f"dx {dx:g} mm", f"dt {time_step(dx, factor=self.dt_factor):.4g} s",
                 f"Re {self.reynolds:g}" if self.tau is None else f"tau {self.tau:g}"]
        if self.particles:
            parts.append(_describe_particles(self.particles))
        return ", ".join(parts)


def _describe_particles(p: dict) -> str:
    out = []
    for g in p.get("packed", []):
        size = g.get("edge_mm") or f"{g.get('diameter_mm'):g}x{g.get('length_mm'):g}"
        out.append(f"{g['shape']} {size} mm at {100 * g['concentration']:g} %"
                   + (f", density ratio {g['density_ratio']:g}" if g.get("density_ratio", 1.0) != 1.0 else ""))
    if p.get("bodies"):
        out.append(f"{len(p['bodies'])} placed bodies")
    for g in p.get("random", []):
        out.append(f"{g.get('count')} random {g['shape']}")
    if not p.get("collisions", {}).get("enabled", True):
        out.append("collisions off")
    return "; ".join(out)


def _packed(shape: str, concentration: float, **kw) -> dict:
    size = {"cube": {"edge_mm": kw.pop("edge_mm", 8.0)},
            "cylinder": {"diameter_mm": kw.pop("diameter_mm", 8.0), "length_mm": kw.pop("length_mm", 8.0)}}[shape]
    return {"packed": [{"shape": shape, **size, "concentration": concentration, "seed": kw.pop("seed", 1), **kw}]}


# A cube's corner on the wall: a cube of edge a, faces along x and y, centred at y = -(sqrt(R^2 -
# (a/2)^2) - a/2) has its two lower corners exactly on the circle r = R. Placed 0.05 mm inside.
def _cube_on_wall_y(a: float, r: float = 25.0, gap: float = 0.05) -> float:
    return -(math.sqrt((r - gap) ** 2 - (a / 2) ** 2) - a / 2)


CONTACT = {
    "bodies": [
        # two 8 mm cubes face to face (gap 0)
        {"shape": "cube", "edge_mm": 8.0, "position_mm": [4.0, 10.0, 50.0]},
        {"shape": "cube", "edge_mm": 8.0, "position_mm": [12.0, 10.0, 50.0]},
        # a 16 x 24 mm cylinder along the pipe axis, its side on the wall
        {"shape": "cylinder", "diameter_mm": 16.0, "length_mm": 24.0, "position_mm": [-16.95, 0.0, 50.0]},
        # an 8 mm cube with two corners on the wall
        {"shape": "cube", "edge_mm": 8.0, "position_mm": [0.0, _cube_on_wall_y(8.0), 20.0]},
        # a cube resting on a cylinder end face: 16 mm cylinder end at z = 12, cube from z = 12 to 20
        {"shape": "cylinder", "diameter_mm": 16.0, "length_mm": 16.0, "position_mm": [6.0, -4.0, 80.0 - 12.0]},
        {"shape": "cube", "edge_mm": 8.0, "position_mm": [6.0, -4.0, 80.0]},
    ],
}

LONG = {"bodies": [
    {"shape": "cube", "edge_mm": 16.0, "position_mm": [-10.0, 0.0, 25.0], "orientation": [0.9238795, 0.3826834, 0, 0]},
    {"shape": "cylinder", "diameter_mm": 16.0, "length_mm": 24.0, "position_mm": [8.0, 2.0, 75.0],
     "orientation": [0.9238795, 0.0, 0.3826834, 0.0]},
]}


def suite() -> list[StabilityCase]:
    """The cases of the suite, in table order."""
    return [
        StabilityCase("flow_re26_paper_dt_bgk", "particle-free, Re 26 at the paper's dt (Mach 0.56), BGK",
                      reynolds=26.0, kind="flow", expect=None),
        StabilityCase("flow_re26_paper_dt_trt", "particle-free, Re 26 at the paper's dt (Mach 0.56), TRT",
                      reynolds=26.0, collision="trt", kind="flow", expect=None),
        StabilityCase("flow_re26_half_dt_bgk", "particle-free, Re 26 at dt / 2 (Mach 0.28), BGK",
                      reynolds=26.0, dt_factor=0.5, kind="flow"),
        StabilityCase("tau0.51_bgk", "tau = 0.51 (high Re), particle-free, BGK", reynolds=26.0, dt_factor=0.5,
                      tau=0.51, kind="flow", expect=None),
        StabilityCase("tau0.51_trt", "tau = 0.51 (high Re), particle-free, TRT", reynolds=26.0, dt_factor=0.5,
                      tau=0.51, collision="trt", kind="flow", expect=None),
        StabilityCase("cyl8x8_c50_re9.4", "50 % packing of 8x8 mm cylinders, Re 9.4, collisions on",
                      particles=_packed("cylinder", 0.5)),
        StabilityCase("cube8_c50_re9.4", "50 % packing of 8 mm cubes, Re 9.4, collisions on",
                      particles=_packed("cube", 0.5, edge_mm=8.0)),
        StabilityCase("cyl8x8_c50_re26_paper_dt", "50 % 8x8 mm cylinders, Re 26 at the paper's dt (Mach 0.56), BGK",
                      reynolds=26.0, particles=_packed("cylinder", 0.5), expect=None),
        StabilityCase("cyl8x8_c50_re26_paper_dt_trt", "50 % 8x8 mm cylinders, Re 26 at the paper's dt, TRT",
                      reynolds=26.0, collision="trt", particles=_packed("cylinder", 0.5), expect=None),
        StabilityCase("cyl8x8_c50_re26_half_dt", "50 % 8x8 mm cylinders, Re 26 at dt / 2 (Mach 0.28), BGK",
                      reynolds=26.0, dt_factor=0.5, particles=_packed("cylinder", 0.5)),
        StabilityCase("cube24_c30_re26_wall", "largest cubes (24 mm, 30 %) touching the wall, Re 26 at dt / 2",
                      reynolds=26.0, dt_factor=0.5, particles=_packed("cube", 0.3, edge_mm=24.0)),
        StabilityCase("cyl16x24_c50_re26_wall", "largest cylinders (16x24 mm, 50 %) touching the wall, Re 26 at dt / 2",
                      reynolds=26.0, dt_factor=0.5, particles=_packed("cylinder", 0.5, diameter_mm=16.0, length_mm=24.0)),
        StabilityCase("released_in_contact", "particles released touching each other and the wall, Re 9.4",
                      particles=CONTACT),
        StabilityCase("density0.8_cyl8x8_c30", "density ratio 0.8 (gravity off), 30 % 8x8 mm cylinders, Re 9.4",
                      particles=_packed("cylinder", 0.3, density_ratio=0.8)),
        StabilityCase("density0.5_cube8_c30", "density ratio 0.5 (gravity off), 30 % 8 mm cubes, Re 9.4",
                      particles=_packed("cube", 0.3, edge_mm=8.0, density_ratio=0.5)),
        StabilityCase("long_run", "long run at a tiny resolution (dx 5 mm), two free particles, Re 9.4",
                      particles=LONG, kind="long", fixed_dx_mm=5.0),
    ]


def fidelity_settings(config: dict | None, fidelity: str) -> dict:
    """Lattice spacing and step counts of the suite at a fidelity level (``FIDELITY_DEFAULTS``,
    overridden by ``config["stability"][fidelity]``)."""
    base = dict(FIDELITY_DEFAULTS.get(fidelity, FIDELITY_DEFAULTS["smoke"]))
    base.update(((config or {}).get("stability") or {}).get(fidelity) or {})
    return base


def steps_for(case: StabilityCase, settings: dict) -> int:
    return int({"flow": settings["flow_steps"], "long": settings["long_steps"]}.get(case.kind, settings["steps"]))


# ----------------------------------------------------------------------------------------------
# running one case


def _pack_files(data: dict, work_dir: Path) -> dict:
    """Replace a ``packed`` group without a file by a packing file made once per (shape, size,
    concentration, seed) in ``work_dir`` (cases share packings; the density ratio is not part of
    the packing)."""
    groups = (data.get("particles") or {}).get("packed") or []
    if not groups or groups[0].get("file"):
        return data
    g = groups[0]
    key = "_".join(f"{k}{g[k]}" for k in ("shape", "edge_mm", "diameter_mm", "length_mm", "concentration", "seed")
                   if k in g)
    path = Path(work_dir) / f"packing_{key}.csv"
    if not path.exists():
        scene = Scene.model_validate(data)
        x, q, _ = packed_group(scene.particles.packed[0], scene)
        write_packing(path, x, q)
    out = copy.deepcopy(data)
    out["particles"]["packed"][0]["file"] = str(path)
    return out


def _ke_reference(sim, params) -> float:

    g = sim.grid
    x, y, _ = g.positions()
    r = np.sqrt(x[:, None] ** 2 + y[None, :] ** 2)
    u = obs.poiseuille_pipe(r, g.radius, 2.0 * params.u_mean_lu)
    col = np.where(g.fluid.all(axis=2), u, 0.0)
    return float(0.5 * (col**2).sum() * g.shape[2])


def _kinetic_energy(sim) -> float:
    rho, ux, uy, uz = sim.moments()
    fl = sim.fluid_mask()
    ke = 0.5 * float((rho * (ux**2 + uy**2 + uz**2))[fl].sum())
    ps = sim.particles
    if ps is not None and ps.n:
        b = ps.bodies
        free = ~b.fixed
        ke += 0.5 * float((b.mass[free] * (b.v[free] ** 2).sum(axis=1)).sum())
        ke += 0.5 * float((b.inertia[free] * b.wb[free] ** 2).sum())
    return ke


def _min_wall_clearance(sim) -> float:
    """Smallest signed gap (lattice units) between a particle and the pipe wall (negative: the
    particle reaches into the wall)."""
    ps = sim.particles
    if ps is None or ps.n == 0 or sim.grid.kind != "pipe":
        return float("nan")
    b = ps.bodies
    r = np.hypot(b.x[:, 0], b.x[:, 1]) + ps.rb
    near = np.flatnonzero(r > sim.grid.radius - 2.0)  # only these can be within 2 spacings of the wall
    if len(near) == 0:
        return float(sim.grid.radius - r.max())
    return min(contact_pipe(b.kind[k], b.h[k], b.x[k], b.q[k], sim.grid.radius)[0] for k in near)


def run_case(case: StabilityCase, dx_mm: float, steps: int, work_dir: Path | None = None, probe_every: int = 25,
             threads: int | None = 1) -> dict:
    """Run one case for ``steps`` steps at ``dx_mm`` with the guard, probing the invariants every
    ``probe_every`` steps; returns the table row (module docstring)."""


    if threads:
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    row: dict = {"case": case.name, "description": case.description, "settings": case.settings(dx_mm),
                 "dx_mm": float(case.fixed_dx_mm or dx_mm), "steps_requested": int(steps)}
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory()
        work_dir = Path(tmp.name)
    Path(work_dir).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        data = case.scene(dx_mm, steps, sample_steps=probe_every)
        try:
            data = _pack_files(data, Path(work_dir))
        except SceneError as exc:
            row.update(status="unpackable", failed_step=None, message=exc.message, wall_seconds=0.0)
            return _finish(row)
        scene = Scene.model_validate(data)
        params = derive(scene)
        sim = simulation_from_scene(scene, params)
        row.update(dt_s=params.units.dt_s, tau=params.tau, mach=params.mach_max, reynolds=params.reynolds,
                   particles=sim.particles.n if sim.particles is not None else 0)
        probe = _Probe(sim, params)
        out = run_loop(sim, steps, probe_every, [probe], interruptible=False)
        if out.status == "unstable":
            status, message, failed = "unstable", out.message, out.error.step if out.error is not None else None
        else:
            status, message, failed = "stable", "", None
        stats, mass0 = probe.stats, probe.mass0
        records = sim.records()
        floor = records.get("density_floor", {"mass_added": 0.0, "node_updates": 0.0})
        ce = records.get("collisions")
        row.update(status=status, failed_step=failed, message=message, steps_done=int(sim.step_count),
                   max_u_over_cs=stats["u_max"] * math.sqrt(3.0), rho_min=stats["rho_min"], rho_max=stats["rho_max"],
                   mass_drift_rel=stats["drift"],
                   mass_corrected_rel=(records["mass_correction"]["mass_added"] / mass0
                                       if "mass_correction" in records else 0.0),
                   floor_mass_rel=floor["mass_added"] / mass0, floor_node_updates=int(floor["node_updates"]),
                   ke_ratio_max=stats["ke"],
                   max_overlap_before_lu=ce["max_overlap_before_lu"] if ce is not None else float("nan"),
                   max_overlap_after_lu=ce["max_overlap_after_lu"] if ce is not None else float("nan"),
                   overlap_tol_lu=ce["overlap_tol_lu"] if ce is not None else float("nan"),
                   impulses=ce["impulses"] if ce is not None else 0,
                   min_wall_clearance_lu=stats["clear"],
                   wall_seconds=time.perf_counter() - t0)
        return _finish(row)
    finally:
        if tmp is not None:
            tmp.cleanup()


class _Probe:
    """The suite's reporter (``solver.Reporter``): at every sample a guard check, and the extremes
    of the invariants (fluid speed and density, mass drift, kinetic energy against
    Hagen-Poiseuille's, wall clearance)."""
    def __init__(self, sim, params):
        self.mass0 = sim.mass()
        self.rho0 = self.mass0 / max(int(sim.fluid_mask().sum()), 1)
        self.ke_ref = _ke_reference(sim, params)
        self.stats = {"u_max": 0.0, "rho_min": np.inf, "rho_max": -np.inf, "drift": 0.0, "ke": 0.0,
                      "clear": _min_wall_clearance(sim)}

    def advanced(self, sim, steps) -> None:
        pass

    def sample(self, sim, sample) -> None:
        stats = self.stats
        res = sim.guard.check(sim)
        stats["u_max"] = max(stats["u_max"], res["u_max"])
        stats["rho_min"] = min(stats["rho_min"], res["rho_min"])
        stats["rho_max"] = max(stats["rho_max"], res["rho_max"])
        m = sim.mass()
        if sim.particles is None:
            drift = abs(m - self.mass0) / self.mass0
        else:
            drift = abs(m / max(int(sim.particles.n_fluid), 1) - self.rho0) / self.rho0
        stats["drift"] = max(stats["drift"], drift)
        stats["ke"] = max(stats["ke"], _kinetic_energy(sim) / self.ke_ref)
        stats["clear"] = min(stats["clear"], _min_wall_clearance(sim))

    def between(self, sim) -> None:
        pass

    def finish(self, sim, status) -> None:
        pass


def _finish(row: dict) -> dict:
    """Check the invariants' bounds; a case that ran through but broke one is ``violated``."""
    bad = []
    if row.get("status") in ("stable", "unstable"):
        with_p = row.get("particles", 0) > 0
        bound = BOUNDS["mass_drift_rel_particles" if with_p else "mass_drift_rel"]
        if row.get("mass_drift_rel", 0.0) > bound:
            bad.append(f"mass drift {row['mass_drift_rel']:.3g} > {bound:g}")
        if row.get("ke_ratio_max", 0.0) > BOUNDS["ke_ratio_max"]:
            bad.append(f"kinetic energy ratio {row['ke_ratio_max']:.3g} > {BOUNDS['ke_ratio_max']:g}")
        ova, tol = row.get("max_overlap_after_lu", float("nan")), row.get("overlap_tol_lu", float("nan"))
        if math.isfinite(ova) and ova > tol * (1 + 1e-9):
            bad.append(f"overlap after the collision step {ova:.3g} > overlap_tol {tol:g}")
        ovb = row.get("max_overlap_before_lu", float("nan"))
        if math.isfinite(ovb) and ovb > BOUNDS["overlap_before_lu"]:
            bad.append(f"overlap before the collision step {ovb:.3g} > {BOUNDS['overlap_before_lu']:g}")
        clear = row.get("min_wall_clearance_lu", float("nan"))
        if math.isfinite(clear) and clear < BOUNDS["wall_clearance_min_lu"]:
            bad.append(f"wall clearance {clear:.3g} < {BOUNDS['wall_clearance_min_lu']:g}")
    row["violations"] = "; ".join(bad)
    if bad and row["status"] == "stable":
        row["status"] = "violated"
    return row


# ----------------------------------------------------------------------------------------------
# the table

COLUMNS = ["case", "description", "settings", "status", "failed_step", "steps_done", "steps_requested", "dx_mm", "dt_s",
           "tau", "mach", "reynolds", "particles", "max_u_over_cs", "rho_min", "rho_max", "mass_drift_rel",
           "mass_corrected_rel", "floor_mass_rel", "floor_node_updates", "ke_ratio_max", "max_overlap_before_lu",
           "max_overlap_after_lu", "overlap_tol_lu", "impulses", "min_wall_clearance_lu", "violations", "message", "wall_seconds"]


def run_suite(settings: dict, out_csv: Path | None = None, cases: list[StabilityCase] | None = None,
              work_dir: Path | None = None, threads: int | None = 1, log=print):
    """Run ``cases`` (default: the whole ``suite()``) at ``settings`` (``fidelity_settings``) and
    write the table to ``out_csv``; returns it as a DataFrame, with a ``cheapest stable`` note for
    the Re 26 settings in ``DataFrame.attrs["recommendation"]``."""
    import pandas as pd

    rows = []
    for case in cases or suite():
        dx = case.fixed_dx_mm or settings["long_dx_mm"] if case.kind == "long" else settings["dx_mm"]
        row = run_case(case, dx, steps_for(case, settings), work_dir=work_dir, threads=threads)
        rows.append(row)
        if log:
            log(f"{row['case']:32s} {row['status']:10s} steps {row.get('steps_done', 0)}/{row['steps_requested']}"
                f"  {row.get('wall_seconds', 0):.1f} s  {row.get('violations') or ''}{row.get('message', '')[:160]}")
    df = pd.DataFrame(rows).reindex(columns=COLUMNS)
    df.attrs["recommendation"] = cheapest_stable(rows)
    if out_csv is not None:
        Path(out_csv).parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(out_csv, index=False)
        write_json(Path(out_csv).with_suffix(".json"),
                   {"settings": settings, "bounds": BOUNDS, "recommendation": df.attrs["recommendation"]})
    return df


def cheapest_stable(rows: list[dict]) -> str:
    """Which Re 26 setting with particles is the cheapest stable one (largest dt; BGK before TRT
    at equal dt, since BGK is the paper's operator and cheaper)."""
    cand = [r for r in rows if r["case"].startswith("cyl8x8_c50_re26")]
    ok = [r for r in cand if r["status"] == "stable"]
    if not ok:
        return "no Re 26 particle setting of the suite was stable" if cand else ""
    best = max(ok, key=lambda r: (r.get("dt_s", 0.0), "trt" not in r["case"]))
    return f"cheapest stable Re 26 setting with particles: {best['case']} ({best['settings']})"
