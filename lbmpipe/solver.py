"""The simulation: state, the time step assembled from effects, and a scene's run with its outputs.

State lives in lattice units. ``f`` holds the post-collision populations of the current time
(Eq. (2) applied), ``f_next`` receives the next ones; the two swap every step. The step is

1. ``pre`` effects fill the ghost slots of solid nodes (walls, later particles) in ``f``;
2. the ``fluid`` effect streams and collides ``f -> f_next`` (one generated kernel);
3. ``post`` effects (flow-rate control, later rigid-body motion and collisions);
4. swap;
5. every ``guard.every`` steps, the run-time guard (``lbmpipe.guard``): NaN/Inf, lattice speed,
   density range, particles inside and overlaps within the collision bound; a failure raises
   ``guard.Unstable``, which ``run_scene`` reports as status ``unstable``.

``run_scene`` can write checkpoints (``lbmpipe.checkpoint``) every few minutes of wall time and at
an interrupt, and resumes from one: the resumed run is bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import math
import signal
import time
from pathlib import Path

import numba
import numpy as np

from . import boundaries as bnd
from . import effects as fx
from . import observables as obs
from .kernels import KernelSpec, dtype_of
from .lattice import get_lattice

#: column chunks of the fluid sweep: 4 per thread up to 16 threads
SWEEP_CHUNKS = 64


class Simulation:
    """A lattice Boltzmann run on a grid with an ordered list of effects."""

    def __init__(self, grid: bnd.Grid, *, collision: str = "bgk", omega: float, omega_minus: float | None = None,
                 precision: str = "float64", force=(0.0, 0.0, 0.0), flux: bool = False,
                 extra_effects: list[fx.Effect] | None = None, density_floor: float | None = None):
        self.grid = grid
        self.lattice = grid.lattice
        self.omega = float(omega)
        self.omega_minus = float(omega if omega_minus is None else omega_minus)
        self.force = np.array(force, dtype=np.float64)
        self.dtype = dtype_of(precision)
        q = self.lattice.q
        nx, ny, nz = grid.shape
        self.f = bnd.alloc_populations(q, grid, self.dtype)
        self.f_next = bnd.alloc_populations(q, grid, self.dtype)
        self.last_flux = 0.0
        self.step_count = 0
        forcing = bool(np.any(self.force != 0.0)) or flux
        floor = bool(density_floor)
        spec = KernelSpec(self.lattice.name, collision, forcing, flux, precision, floor)
        self.effects: list[fx.Effect] = []
        self.effects += [e for e in (extra_effects or []) if e.phase == "pre"]
        self.effects.append(fx.StreamCollide(spec, density_floor if floor else 0.0))
        self.effects += [e for e in (extra_effects or []) if e.phase == "post"]
        self.timers = {e.name: 0.0 for e in self.effects}
        # Chunks of columns balance the cores without per-column overhead. Their number must not
        # depend on the thread count: the flux is summed per chunk, and a run on 1 thread must
        # give the bits of a run on 2 (or a resumed run on another machine).
        self.n_chunks = max(1, min(len(grid.cols_x), SWEEP_CHUNKS))
        self.set_equilibrium(1.0, (0.0, 0.0, 0.0))
        self.guard = None  # guard.Guard: checks the state every guard.every steps
        self.particles = None  # coupling.ParticleSystem when the scene has particles
        self.particle_static: list[dict] = []
        self.packing: dict = {}  # how a packed group was made (target/achieved concentration, ...)

    @property
    def f2(self) -> np.ndarray:
        """``f`` as (q, nodes) for flat-index access by boundary fills (``plane_buffer``)."""
        return bnd.plane_buffer(self.f)

    def set_equilibrium(self, rho, u) -> None:
        """Set ``f`` to the equilibrium Eq. (3) of density ``rho`` and velocity ``u`` (scalars or
        fields of the grid's shape); solid nodes get the rest state."""
        nx, ny, nz = self.grid.shape
        rho = np.broadcast_to(np.asarray(rho, dtype=np.float64), (nx, ny, nz))
        u = [np.broadcast_to(np.asarray(c, dtype=np.float64), (nx, ny, nz)) for c in u]
        usq = 1.5 * (u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
        for i in range(self.lattice.q):
            ex, ey, ez = self.lattice.e[i]
            eu = ex * u[0] + ey * u[1] + ez * u[2]
            self.f[i, :, :, :nz] = self.lattice.w[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq)
        self.f_next[...] = self.f

    def step(self, n: int = 1) -> None:
        perf = time.perf_counter
        timers = self.timers
        guard = self.guard
        for _ in range(n):
            for e in self.effects:
                t0 = perf()
                e(self)
                timers[e.name] += perf() - t0
            self.f, self.f_next = self.f_next, self.f
            self.step_count += 1
            if guard is not None and self.step_count % guard.every == 0:
                t0 = perf()
                try:
                    guard.check(self)
                finally:
                    guard.seconds += perf() - t0

    def moments(self):
        """(rho, ux, uy, uz) on the grid (lattice units); meaningless at solid nodes."""
        return obs.moments(self.f, self.lattice, self.grid.shape, self.force)

    def fluid_mask(self) -> np.ndarray:
        """(nx, ny, nz) bool: fluid nodes now (neither wall nor particle)."""
        return self.grid.fluid if self.particles is None else self.particles.fluid_mask()

    def mass(self) -> float:
        return obs.total_mass(self.f, self.fluid_mask())

    def effect(self, cls):
        for e in self.effects:
            if isinstance(e, cls):
                return e
        return None


def grid_from_scene(scene, params) -> bnd.Grid:
    lat = get_lattice(scene.numerics.lattice)
    nx, ny, nz = params.shape
    if scene.domain.kind == "pipe":
        return bnd.pipe_grid(lat, nx, nz)
    w = scene.domain.walls
    return bnd.box_grid(lat, (nx, ny, nz), (w.x == "wall", w.y == "wall", w.z == "wall"))


def particle_system_from_scene(scene, params, grid):
    """The scene's particles on ``grid`` as a ``coupling.ParticleSystem`` and their static records,
    or ``(None, [])`` when the scene has none."""
    pspec = scene.particles
    if pspec is None or not (pspec.bodies or pspec.random or pspec.packed):
        return None, []
    from .coupling import ParticleSystem
    from .particles import bodies_from_scene

    info: dict = {}
    bodies, static = bodies_from_scene(scene, params, info)
    gravity = [params.units.acceleration(g) for g in pspec.gravity_m_s2]
    system = ParticleSystem(grid, bodies, gravity=gravity)
    system.packing_info = info
    return system, static


def collision_effect(scene, params, system):
    """The collision effect the scene asks for (``None`` without free particles or with
    ``particles.collisions.enabled: false``): the particles' domain in lattice units."""
    if system is None or not len(system.free_ids) or not scene.particles.collisions.enabled:
        return None
    from .collisions import CollisionEffect, CollisionParams, Domain
    from .particles import domain_geometry

    lo, hi, periodic, radius = domain_geometry(scene, params)
    dom = Domain.pipe(radius, hi[2] - lo[2], z0=lo[2]) if radius > 0 else Domain.box(lo, hi, periodic)
    c = scene.particles.collisions
    return CollisionEffect(system, dom, CollisionParams(restitution=c.restitution, contact_gap=c.contact_gap_dx,
                                                        overlap_tol=c.overlap_tol_dx), pairs=c.pairs)


def simulation_from_scene(scene, params, guard: bool = True) -> Simulation:
    """Assemble the simulation a scene declares: exactly its effects, and its initial state, with
    the run-time guard (``lbmpipe.guard``) unless ``guard=False``.

    With particles, the step is: wall fills, particle fills and velocity update (``coupling``),
    sweep, then the flow-rate flux correction, the controller, the collisions and the particle
    motion (in that order: the correction needs the owner map of the sweep, the collisions act on
    the updated velocities before the drift, the motion changes the owner map)."""
    grid = grid_from_scene(scene, params)
    num = scene.numerics
    walls = fx.wall_effects(grid, num.wall, dict(params.wall_velocities_lu))
    extra = list(walls)
    system, static = particle_system_from_scene(scene, params, grid)
    flux = scene.driving.kind == "flow_rate"
    after: list[fx.Effect] = []
    if system is not None:
        from .coupling import particle_effects

        bouzidi = [e.links for e in walls if isinstance(e, fx.WallBouzidi)]
        pre, before, after = particle_effects(system, flux_control=flux, bouzidi_links=bouzidi[0] if bouzidi else None,
                                              wall_links=[e.links for e in walls])
        extra += pre + before
    force = np.array(params.accel_lu, dtype=np.float64)  # force density = rho_0 g, rho_0 = 1
    if flux:
        ctl = fx.FlowRateControl(params.flow_rate_lu, grid.radius, params.nu_lu, grid.shape[2], grid.n_fluid)
        extra.append(ctl)
        force = np.array([0.0, 0.0, ctl.f_ref])
    collide = collision_effect(scene, params, system)
    if collide is not None:
        extra.append(collide)
    extra += after
    # the density floor (effects.StreamCollide) only where free particles can squeeze films
    floor = num.density_floor if system is not None and len(system.free_ids) else None
    sim = Simulation(grid, collision=num.collision, omega=params.omega, omega_minus=params.omega_minus,
                     precision=num.precision, force=force, flux=flux, extra_effects=extra, density_floor=floor)
    sim.particles = system
    sim.particle_static = static
    sim.packing = getattr(system, "packing_info", {}) if system is not None else {}
    if scene.initial.velocity == "parabolic" and grid.kind == "pipe":
        x, y, _ = grid.positions()
        r = np.sqrt(x[:, None] ** 2 + y[None, :] ** 2)
        uz = obs.poiseuille_pipe(r, grid.radius, 2.0 * params.u_mean_lu)[:, :, None]
        sim.set_equilibrium(1.0, (0.0, 0.0, uz))
    if scene.initial.velocity == "linear" and grid.kind == "box":
        a = next(b for b in range(3) if not grid.periodic[b])  # the walled axis (the scene checks it is one)
        w = params.wall_velocities_lu
        lo, hi = w.get(f"{'xyz'[a]}-", (0.0, 0.0, 0.0)), w.get(f"{'xyz'[a]}+", (0.0, 0.0, 0.0))
        u = obs.couette_box(grid.positions()[a], float(params.shape[a]), lo, hi)
        sim.set_equilibrium(1.0, [np.expand_dims(c, tuple(b for b in range(3) if b != a)) for c in u])
    if guard:
        from .guard import guard_for

        sim.guard = guard_for(sim, scene, params)
    return sim


class _Interrupt:
    """Turns SIGINT/SIGTERM into a flag checked between steps, so the state stays consistent."""

    def __init__(self):
        self.hit = False
        self._old = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self._handler)
            except ValueError:  # not the main thread
                pass
        return self

    def _handler(self, signum, frame):
        self.hit = True

    def __exit__(self, *exc):
        for sig, h in self._old.items():
            signal.signal(sig, h)
        return False


def run_scene(scene, params, out_dir: Path, progress: bool = True, max_steps: int | None = None,
              checkpoint: Path | None = None, checkpoint_every_s: float = 300.0, keep_checkpoint: bool = False,
              stop_at_step: int | None = None) -> dict:
    """Run ``scene`` and write its outputs into ``out_dir``; returns the summary (also written).

    Outputs (physical units; documented in the README): ``summary.json``, ``flow_rate.csv`` and,
    for a pipe, ``profile.csv`` (time-averaged axial velocity against radius). With particles,
    also ``particles.parquet`` (state per particle per sample) and ``particles_static.csv`` (shape
    and size per particle); particle nodes are excluded from the fluid observables, the flow rate
    is the mixture's (fluid plus particle volume flux) and the profile the fluid's.

    Stability: the run-time guard (``lbmpipe.guard``) checks the state every ``guard.every``
    steps; a failure ends the run with status ``unstable`` and a message naming what failed,
    where, at which step, the likely cause and a fix. The last good checkpoint is left in place.

    Checkpoints (``checkpoint`` a file path, ``lbmpipe.checkpoint``): if the file exists and was
    written for this scene, the run resumes from it (a checkpoint of another scene is refused
    with ``checkpoint.CheckpointError``); the complete state is written to it atomically every
    ``checkpoint_every_s`` seconds of wall time (at a sample, after a guard check) and at an
    interrupt. On completion the file is removed, or, with ``keep_checkpoint``, rewritten with the
    final state. An interrupted-then-resumed run gives bit-identical outputs to an uninterrupted
    one. ``stop_at_step`` stops the run as an interrupt would once that step is reached (to split
    a run into parts, and for tests).
    """
    from . import checkpoint as ckpt
    from . import outputs
    from .collisions import CollisionEffect
    from .fields import FieldWriter
    from .guard import Unstable
    from .profiles import PlaneProfile

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    units = params.units
    t_build = time.perf_counter()
    sim = simulation_from_scene(scene, params)
    grid = sim.grid
    n_steps = params.n_steps if max_steps is None else min(max_steps, params.n_steps)
    spinup = min(params.spinup_steps, n_steps)
    every = params.sample_every
    mass0 = sim.mass()
    uz_sum = np.zeros(grid.shape)
    uz_cnt = np.zeros(grid.shape)
    n_avg = 0
    ps = sim.particles
    recorder = None
    series = []
    wall_before = 0.0
    resumed_from = None
    fingerprint = ckpt.scene_fingerprint(scene) if checkpoint is not None else ""
    if ps is not None:
        from . import particles as particles_out

        recorder = particles_out.ParticleRecorder(ps, units)
    planes = PlaneProfile.for_grid(grid)  # a box's profile across its walls
    fields_out = FieldWriter.from_scene(scene, params, grid, out_dir, n_steps)
    if checkpoint is not None and Path(checkpoint).exists():
        run, arrs = ckpt.load(Path(checkpoint), sim, fingerprint)
        resumed_from = sim.step_count
        mass0, n_avg, wall_before = float(run["mass0"]), int(run["n_avg"]), float(run["wall_seconds"])
        uz_sum[...] = arrs["uz_sum"]
        uz_cnt[...] = arrs["uz_cnt"]
        series = [(int(r[0]), float(r[1]), float(r[2]), float(r[3])) for r in arrs["series"]]
        if recorder is not None and ps.n:
            rows = arrs["particle_rows"]
            recorder.rows = [rows[i:i + ps.n].copy() for i in range(0, len(rows), ps.n)]
        if planes is not None and "plane_samples" in arrs:
            planes.restore(arrs)
    elif recorder is not None:
        recorder.sample(0)
    if fields_out is not None:
        fields_out.start(sim, resumed=resumed_from is not None)

    def save_checkpoint(wall_so_far: float) -> None:
        rows = np.concatenate(recorder.rows) if recorder is not None and recorder.rows else np.zeros((0, 0))
        ckpt.write(Path(checkpoint), sim, fingerprint,
                   run={"mass0": mass0, "n_avg": n_avg, "wall_seconds": wall_so_far},
                   run_arrays={"uz_sum": uz_sum, "uz_cnt": uz_cnt,
                               "series": np.array(series, dtype=np.float64).reshape(-1, 4), "particle_rows": rows,
                               **(planes.state() if planes is not None else {})})
        n_written[0] += 1

    n_written = [0]
    status = "completed"
    message = ""
    bar = outputs.progress_bar(n_steps, units.dt_s, grid.n_fluid, enabled=progress)
    start_step = sim.step_count
    if start_step:
        bar.update(min(start_step, n_steps))
    # The first sweep compiles or loads the kernels; keep that out of the MLUPS figure.
    sim.step(0)
    t0 = time.perf_counter()
    last_ckpt = t0
    setup_seconds = t0 - t_build
    with _Interrupt() as stop:
        try:
            while sim.step_count < n_steps:
                chunk = min(every - sim.step_count % every, n_steps - sim.step_count)
                if stop_at_step is not None and sim.step_count < stop_at_step:
                    chunk = min(chunk, stop_at_step - sim.step_count)
                if fields_out is not None:
                    chunk = min(chunk, fields_out.steps_to_next(sim.step_count))
                sim.step(chunk)
                bar.update(chunk)
                if fields_out is not None and fields_out.due(sim.step_count):
                    fields_out.sample(sim, sim.step_count)
                if sim.step_count % every == 0 or sim.step_count == n_steps:
                    rho, ux, uy, uz = sim.moments()
                    fluid = sim.fluid_mask()
                    if not np.isfinite(rho[fluid]).all():
                        status, message = "unstable", f"non-finite density at step {sim.step_count}"
                        break
                    jz = float(uz[fluid].sum())
                    if ps is not None:
                        if not np.isfinite(ps.bodies.v).all():
                            status, message = "unstable", f"non-finite particle velocity at step {sim.step_count}"
                            break
                        jz += float(np.dot(ps.nown, ps.bodies.v[:, 2]))  # mixture: particle volume flux
                        recorder.sample(sim.step_count)
                    q_lu = jz / grid.shape[2]
                    series.append((sim.step_count, q_lu, float(sim.force[2]), float(np.abs(rho[fluid] - 1).max())))
                    if sim.step_count > spinup:
                        uz_sum += np.where(fluid, uz, 0.0)
                        uz_cnt += fluid
                        n_avg += 1
                        if planes is not None:
                            planes.add((ux, uy, uz), fluid)
                    elapsed = time.perf_counter() - t0
                    bar.set_postfix_str(outputs.progress_text(sim.step_count, units.dt_s, grid.n_fluid, elapsed))
                if stop.hit or (stop_at_step is not None and sim.step_count >= stop_at_step
                                and sim.step_count < n_steps):
                    status, message = "interrupted", f"interrupted at step {sim.step_count}"
                    break
                now = time.perf_counter()
                if checkpoint is not None and sim.step_count < n_steps and now - last_ckpt >= checkpoint_every_s:
                    if sim.guard is not None:
                        sim.guard.check(sim)  # only a state that passes the guard is a good checkpoint
                    save_checkpoint(wall_before + now - t0)
                    last_ckpt = time.perf_counter()
            if checkpoint is not None and (status == "interrupted" or (status == "completed" and keep_checkpoint)):
                if sim.guard is not None:
                    sim.guard.check(sim)
                save_checkpoint(wall_before + time.perf_counter() - t0)
        except Unstable as exc:
            status, message = "unstable", str(exc)
            if checkpoint is not None and Path(checkpoint).exists():
                message += f" The last good checkpoint is kept at {checkpoint} (resuming it with the same scene repeats the failure)."
    wall = wall_before + time.perf_counter() - t0
    bar.close()
    if checkpoint is not None and status == "completed" and not keep_checkpoint:
        Path(checkpoint).unlink(missing_ok=True)
    mass1 = sim.mass()
    files = {}
    summary = {
        "status": status,
        "message": message,
        "steps": sim.step_count,
        "steps_requested": n_steps,
        "simulated_seconds": sim.step_count * units.dt_s,
        "wall_seconds": wall,
        "setup_seconds": setup_seconds,
        "mlups": grid.n_fluid * sim.step_count / wall / 1e6 if wall > 0 else 0.0,
        "threads": numba.get_num_threads(),
        "fluid_nodes": grid.n_fluid,
        "mass_drift_rel": (mass1 - mass0) / mass0 if math.isfinite(mass1) else float("nan"),
        "effects": {e.name: sim.timers[e.name] for e in sim.effects},
        "samples_averaged": n_avg,
        "spinup_s": spinup * units.dt_s,
    }
    if sim.guard is not None:
        summary["guard"] = sim.guard.record()
    if checkpoint is not None:
        summary["checkpoint"] = {"path": str(checkpoint), "resumed_from_step": resumed_from, "written": n_written[0],
                                 "kept": Path(checkpoint).exists(), "every_s": checkpoint_every_s}
    files["flow_rate.csv"] = outputs.write_flow_rate(out_dir, series, units, scene)
    if ps is not None:
        summary["particles"] = {
            "count": ps.n, "fixed": int(len(ps.fixed_ids)),
            "volume_fraction": float(ps.vol.sum() / max(float(np.count_nonzero(grid.fluid)), 1.0)),
            "links": int(ps.lcnt.sum()),
            "collisions": sim.effect(CollisionEffect) is not None,
            **sim.packing,
        }
        sc = sim.effect(fx.StreamCollide)
        if sc.spec.floor:
            mass_fluid = max(mass0, 1e-300)
            summary["density_floor"] = {
                "rho_min": sc.rho_min, "mass_added_rel": float(sc.tally[0]) / mass_fluid,
                "node_updates": int(sc.tally[1]),
                "node_updates_per_step": float(sc.tally[1]) / max(sim.step_count, 1)}
        ce = sim.effect(CollisionEffect)
        summary["collisions"] = ce.record() if ce is not None else {
            "enabled": False, "reason": "switched off by the scene" if not scene.particles.collisions.enabled
            else "no free particles"}
        files[particles_out.write_static(out_dir, sim.particle_static)] = True
        files[recorder.write(out_dir)] = True
    if fields_out is not None:
        files.update(dict.fromkeys(fields_out.close(), True))
    if planes is not None and n_avg > 0 and scene.outputs.profile:
        files[planes.write(out_dir, units)] = True
    if grid.kind == "pipe" and n_avg > 0:
        x, y, _ = grid.positions()
        # time-weighted fluid mean per column (nodes count only while they are fluid), spread
        # along z so that radial_profile's column average returns it
        col = uz_sum.sum(axis=2) / np.maximum(uz_cnt.sum(axis=2), 1.0)
        r, u, count = obs.radial_profile(np.repeat(col[:, :, None], grid.shape[2], axis=2), grid.fluid, x, y,
                                         grid.radius)
        u_ref = obs.poiseuille_pipe(r, grid.radius, 2.0 * (params.u_mean_lu if params.flow_rate_lu else 0.0))
        if params.flow_rate_lu:
            summary["profile_error_rel_l2"] = obs.relative_l2(u, u_ref)
        if scene.outputs.profile:
            files["profile.csv"] = outputs.write_profile(out_dir, r, u, u_ref, count, units)
        if series:
            summary["flow_rate_m3_s"] = units.flow_rate_phys(float(np.mean([row[1] for row in series[-max(1, n_avg):]])))
    summary["files"] = sorted(files)
    outputs.write_summary(out_dir, summary, scene, params)
    return summary
