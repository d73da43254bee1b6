"""The simulation: state, the time step assembled from effects, the run loop, and a scene's run
with its outputs.

State lives in lattice units. ``f`` holds the post-collision populations of the current time
(Eq. (2) applied), ``f_next`` receives the next ones; the two swap every step. The step is

1. ``pre`` effects fill the ghost slots of solid nodes (walls, particles) in ``f``;
2. the ``fluid`` effect streams and collides ``f -> f_next`` (one generated kernel);
3. ``post`` effects (flux correction, flow-rate control, collisions, rigid-body motion);
4. swap;
5. every ``guard.every`` steps, the run-time guard (``lbmpipe.guard``): NaN/Inf, lattice speed,
   density range, particles inside and overlaps within the collision bound; a failure raises
   ``errors.Unstable``, which the run loop reports as status ``unstable``.

``effects.assemble`` decides the effects; ``run_loop`` steps a simulation and hands each sample to
its reporters (flow-rate series, profile average, particle samples, progress, checkpoints), which
write the outputs after it. ``run_scene`` (the CLI and the pipeline) and the stability suite share
the loop. Checkpoints (``lbmpipe.checkpoint``) are written every few minutes of wall time and at an
interrupt; a resumed run is bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from . import effects as fx
from .errors import Unstable
from .fluid import boundaries as bnd
from .fluid import observables as obs
from .fluid.kernels import dtype_of
from .fluid.lattice import get_lattice

#: column chunks of the fluid sweep: 4 per thread up to 16 threads
SWEEP_CHUNKS = 64


class Simulation:
    """A lattice Boltzmann run on a grid with the finished, ordered list of its effects
    (``effects.assemble``): ``pre`` effects, the one ``fluid`` sweep, ``post`` effects."""

    def __init__(self, grid: bnd.Grid, effects: list[fx.Effect], *, omega: float, omega_minus: float | None = None,
                 force=(0.0, 0.0, 0.0)):
        phases = [e.phase for e in effects]
        if phases.count("fluid") != 1 or phases != sorted(phases, key=("pre", "fluid", "post").index):
            raise ValueError(f"effects must be pre..., one fluid sweep, post... in that order, got {effects}")
        self.grid = grid
        self.lattice = grid.lattice
        self.omega = float(omega)
        self.omega_minus = float(omega if omega_minus is None else omega_minus)
        self.force = np.array(force, dtype=np.float64)
        sweep = effects[phases.index("fluid")]
        self.dtype = dtype_of(sweep.spec.precision)
        q = self.lattice.q
        self.f = bnd.alloc_populations(q, grid, self.dtype)
        self.f_next = bnd.alloc_populations(q, grid, self.dtype)
        self.last_flux = 0.0
        self.step_count = 0
        self.effects: list[fx.Effect] = list(effects)
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

    @classmethod
    def build(cls, grid: bnd.Grid, *, collision: str = "bgk", omega: float, omega_minus: float | None = None,
              precision: str = "float64", force=(0.0, 0.0, 0.0), flux: bool = False,
              extra_effects: list[fx.Effect] | None = None, density_floor: float | None = None) -> "Simulation":
        """A simulation assembled by hand (tests, benchmarks): the sweep for ``collision`` and
        ``precision`` between the ``pre`` and the ``post`` effects of ``extra_effects``."""
        spec = fx.fluid_spec(grid.lattice.name, collision, precision, force, flux, density_floor)
        extra = list(extra_effects or [])
        effects = ([e for e in extra if e.phase == "pre"] + [fx.StreamCollide(spec, density_floor if spec.floor else 0.0)]
                   + [e for e in extra if e.phase == "post"])
        return cls(grid, effects, omega=omega, omega_minus=omega_minus, force=force)

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

    def records(self) -> dict[str, dict]:
        """The effects' own tallies, by ``record_key`` (``Effect.record``)."""
        out = {}
        for e in self.effects:
            rec = e.record() if e.record_key else None
            if rec is not None:
                out[e.record_key] = rec
        return out


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
    from .particles.coupling import ParticleSystem
    from .particles.placement import bodies_from_scene

    info: dict = {}
    bodies, static = bodies_from_scene(scene, params, info)
    gravity = [params.units.acceleration(g) for g in pspec.gravity_m_s2]
    system = ParticleSystem(grid, bodies, gravity=gravity)
    system.packing_info = info
    return system, static


def simulation_from_scene(scene, params, guard: bool = True) -> Simulation:
    """Assemble the simulation a scene declares: exactly its effects (``effects.assemble``), and
    its initial state, with the run-time guard (``lbmpipe.guard``) unless ``guard=False``."""
    grid = grid_from_scene(scene, params)
    system, static = particle_system_from_scene(scene, params, grid)
    step = fx.assemble(scene, params, grid, system)
    sim = Simulation(grid, step.effects, omega=params.omega, omega_minus=params.omega_minus, force=step.force)
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

    def __init__(self, enabled: bool = True, signals=(signal.SIGINT, signal.SIGTERM)):
        self.hit = False
        self.enabled = enabled
        self.signals = signals
        self._old = {}

    def __enter__(self):
        for sig in self.signals if self.enabled else ():
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


class Sample:
    """The state at a sample time, its moments computed once and only when a reporter asks."""

    def __init__(self, sim: Simulation):
        self.sim = sim
        self.step = sim.step_count
        self._moments = None

    @property
    def moments(self):
        """``(rho, ux, uy, uz, fluid)``: the moments and the fluid mask now."""
        if self._moments is None:
            self._moments = (*self.sim.moments(), self.sim.fluid_mask())
        return self._moments


class Reporter:
    """What runs beside the run loop without changing the state: sampling, averaging, checkpoints.

    ``advanced`` after every stretch of steps, ``sample`` at every sample time (a message returned
    ends the run as ``unstable``), ``between`` after a sample time that is not the last step (where
    a checkpoint may be written), ``finish`` with the loop's status once it ends (inside the loop's
    guard: it may raise ``Unstable``). Reporters that write outputs do so in ``write``, after."""

    def steps_to_next(self, step: int) -> int | None:
        """Steps from ``step`` to the next one this reporter must see in ``advanced`` (None: any)."""
        return None

    def advanced(self, sim: Simulation, steps: int) -> None:
        pass

    def sample(self, sim: Simulation, sample: Sample) -> str | None:
        return None

    def between(self, sim: Simulation) -> None:
        pass

    def finish(self, sim: Simulation, status: str) -> None:
        pass


@dataclass
class Outcome:
    """How a run loop ended: ``completed``, ``unstable`` (``error`` the guard's ``Unstable``, or
    None for a non-finite sample) or ``interrupted``."""

    status: str = "completed"
    message: str = ""
    error: Unstable | None = None


def _no_limit(step: int) -> None:
    return None


def run_loop(sim: Simulation, n_steps: int, every: int, reporters=(), *, stop_at_step: int | None = None,
             interruptible: bool = True, interrupt: "_Interrupt | None" = None) -> Outcome:
    """Step ``sim`` to ``n_steps`` with a sample every ``every`` steps (and at the last step),
    handing each sample to ``reporters`` in order. SIGINT/SIGTERM (when ``interruptible``) and
    ``stop_at_step`` end the run as ``interrupted`` between steps, with the state consistent; an
    ``Unstable`` raised by the guard, the collision step or a reporter ends it as ``unstable``.
    ``interrupt``: a caller's handler installed before the loop (a Ctrl-C during the set-up then
    ends the run before its first step)."""
    out = Outcome()
    with _Interrupt(enabled=interruptible) as stop:
        try:
            while sim.step_count < n_steps:
                if stop.hit or (interrupt is not None and interrupt.hit):
                    out.status, out.message = "interrupted", f"interrupted at step {sim.step_count}"
                    break
                chunk = min(every - sim.step_count % every, n_steps - sim.step_count)
                if stop_at_step is not None and sim.step_count < stop_at_step:
                    chunk = min(chunk, stop_at_step - sim.step_count)
                for r in reporters:
                    limit = getattr(r, "steps_to_next", _no_limit)(sim.step_count)
                    if limit is not None:
                        chunk = min(chunk, limit)
                sim.step(chunk)
                for r in reporters:
                    r.advanced(sim, chunk)
                if sim.step_count % every == 0 or sim.step_count == n_steps:
                    sample = Sample(sim)
                    bad = next((m for m in (r.sample(sim, sample) for r in reporters) if m), None)
                    if bad:
                        out.status, out.message = "unstable", bad
                        break
                if stop.hit or (stop_at_step is not None and stop_at_step <= sim.step_count < n_steps):
                    out.status, out.message = "interrupted", f"interrupted at step {sim.step_count}"
                    break
                if sim.step_count < n_steps:
                    for r in reporters:
                        r.between(sim)
            for r in reporters:
                r.finish(sim, out.status)
        except Unstable as exc:
            out.status, out.message, out.error = "unstable", str(exc), exc
    return out


class FiniteState(Reporter):
    """Ends the run at a sample whose fluid density or particle velocity is not finite."""

    def sample(self, sim, sample):
        rho, _, _, _, fluid = sample.moments
        if not np.isfinite(rho[fluid]).all():
            return f"non-finite density at step {sim.step_count}"
        ps = sim.particles
        if ps is not None and not np.isfinite(ps.bodies.v).all():
            return f"non-finite particle velocity at step {sim.step_count}"
        return None


class FlowRateSeries(Reporter):
    """``flow_rate.csv``: per sample the flow rate (the mixture's: fluid plus particle volume flux),
    the driving force density, the largest density deviation and, in a pipe, the profile's core
    velocity ratio (``observables.core_velocity_ratio``; NaN in a box)."""

    COLUMNS = 5

    def __init__(self):
        self.rows: list[tuple[int, float, float, float, float]] = []
        self._core = None

    def sample(self, sim, sample):
        rho, _, _, uz, fluid = sample.moments
        jz = float(uz[fluid].sum())
        ps = sim.particles
        if ps is not None:
            jz += float(np.dot(ps.nown, ps.bodies.v[:, 2]))  # mixture: particle volume flux
        grid = sim.grid
        q_lu = jz / grid.shape[2]
        core = float("nan")
        if grid.kind == "pipe":
            if self._core is None:
                x, y, _ = grid.positions()
                self._core = obs.core_mask(x, y, grid.radius, grid.shape[2])
            core = obs.core_velocity_ratio(uz, fluid, self._core)
        self.rows.append((sim.step_count, q_lu, float(sim.force[2]), float(np.abs(rho[fluid] - 1).max()), core))
        return None

    def restore(self, series: np.ndarray) -> None:
        """Rows from a checkpoint's (n, columns) array (a checkpoint written before the core ratio
        has 4 columns: NaN)."""
        a = np.asarray(series, dtype=np.float64)
        if a.shape[1] < self.COLUMNS:
            a = np.hstack([a, np.full((a.shape[0], self.COLUMNS - a.shape[1]), np.nan)])
        self.rows = [(int(r[0]), *map(float, r[1:])) for r in a]

    def write(self, out_dir, summary, files, scene, units) -> None:
        from . import outputs

        files["flow_rate.csv"] = outputs.write_flow_rate(out_dir, self.rows, units, scene)


class ParticleSamples(Reporter):
    """``particles.parquet`` and ``particles_static.csv``, and the summary's particle entries (the
    effects' tallies: density floor, collisions)."""

    def __init__(self, sim, units):
        from .particles import placement

        self.recorder = placement.ParticleRecorder(sim.particles, units)

    def sample(self, sim, sample):
        self.recorder.sample(sim.step_count)
        return None

    def write(self, out_dir, summary, files, scene, sim, mass0) -> None:
        from .particles import placement

        ps, grid = sim.particles, sim.grid
        records = sim.records()
        summary["particles"] = {
            "count": ps.n, "fixed": int(len(ps.fixed_ids)),
            "volume_fraction": float(ps.vol.sum() / max(float(np.count_nonzero(grid.fluid)), 1.0)),
            "links": int(ps.lcnt.sum()),
            "collisions": "collisions" in records,
            **sim.packing,
        }
        floor = records.get("density_floor")
        if floor is not None:
            summary["density_floor"] = {
                "rho_min": floor["rho_min"], "mass_added_rel": floor["mass_added"] / max(mass0, 1e-300),
                "node_updates": int(floor["node_updates"]),
                "node_updates_per_step": floor["node_updates"] / max(sim.step_count, 1)}
        mc = records.get("mass_correction")
        if mc is not None:
            # the mass the correction added in total (net, signed), relative to the initial mass
            summary["mass_correction"] = {"mass_added_rel": mc["mass_added"] / max(mass0, 1e-300),
                                          "calls": int(mc["calls"])}
        summary["collisions"] = records.get("collisions") or {
            "enabled": False, "reason": "switched off by the scene" if not scene.particles.collisions.enabled
            else "no free particles"}
        files[placement.write_static(out_dir, sim.particle_static)] = True
        files[self.recorder.write(out_dir)] = True


class ProfileAccumulator(Reporter):
    """``profile.csv`` (pipe): the time-weighted fluid mean of u_z per column after spin-up, against
    radius, with the Poiseuille profile of the target flow rate; also the mean flow rate over the
    averaged samples."""

    def __init__(self, grid, spinup: int):
        self.grid = grid
        self.spinup = spinup
        self.uz_sum = np.zeros(grid.shape)
        self.uz_cnt = np.zeros(grid.shape)
        self.n_avg = 0

    def sample(self, sim, sample):
        if sim.step_count > self.spinup:
            _, _, _, uz, fluid = sample.moments
            self.uz_sum += np.where(fluid, uz, 0.0)
            self.uz_cnt += fluid
            self.n_avg += 1
        return None

    def write(self, out_dir, summary, files, scene, params, series) -> None:
        from . import outputs

        grid, units = self.grid, params.units
        if grid.kind != "pipe" or self.n_avg == 0:
            return
        x, y, _ = grid.positions()
        # time-weighted fluid mean per column (nodes count only while they are fluid), spread
        # along z so that radial_profile's column average returns it
        col = self.uz_sum.sum(axis=2) / np.maximum(self.uz_cnt.sum(axis=2), 1.0)
        r, u, count = obs.radial_profile(np.repeat(col[:, :, None], grid.shape[2], axis=2), grid.fluid, x, y,
                                         grid.radius)
        u_ref = obs.poiseuille_pipe(r, grid.radius, 2.0 * (params.u_mean_lu if params.flow_rate_lu else 0.0))
        if params.flow_rate_lu:
            summary["profile_error_rel_l2"] = obs.relative_l2(u, u_ref)
        if scene.outputs.profile:
            files["profile.csv"] = outputs.write_profile(out_dir, r, u, u_ref, count, units)
        if series:
            q = float(np.mean([row[1] for row in series[-max(1, self.n_avg):]]))
            summary["flow_rate_m3_s"] = units.flow_rate_phys(q)


class PlaneSamples(Reporter):
    """A box's ``profile.csv`` (``profiles.PlaneProfile``): plane averages of each velocity
    component across its walled axes, over the samples after spin-up."""

    def __init__(self, profile, spinup: int):
        self.profile, self.spinup = profile, spinup

    def sample(self, sim, sample):
        if sim.step_count > self.spinup:
            _, ux, uy, uz, fluid = sample.moments
            self.profile.add((ux, uy, uz), fluid)
        return None


class FieldSamples(Reporter):
    """VTK files of the fields and the particles (``fields.FieldWriter``, ``outputs.fields``) at
    their own interval: the loop stops at each of their steps."""

    def __init__(self, writer, sim, resumed: bool):
        self.writer = writer
        writer.start(sim, resumed=resumed)

    def steps_to_next(self, step: int) -> int:
        return self.writer.steps_to_next(step)

    def advanced(self, sim, steps):
        if self.writer.due(sim.step_count):
            self.writer.sample(sim, sim.step_count)


class Progress(Reporter):
    """The progress bar: steps done, simulated time and throughput."""

    def __init__(self, n_steps: int, units, n_fluid: int, enabled: bool):
        from . import outputs

        self.bar = outputs.progress_bar(n_steps, units.dt_s, n_fluid, enabled=enabled)
        self.dt_s, self.n_fluid, self.t0 = units.dt_s, n_fluid, time.perf_counter()

    def advanced(self, sim, steps):
        self.bar.update(steps)

    def sample(self, sim, sample):
        from . import outputs

        elapsed = time.perf_counter() - self.t0
        self.bar.set_postfix_str(outputs.progress_text(sim.step_count, self.dt_s, self.n_fluid, elapsed))
        return None


class CheckpointWriter(Reporter):
    """Writes the complete state (the simulation plus the other reporters' accumulators) to
    ``path`` every ``every_s`` seconds of wall time, after a guard check, and when the run is
    interrupted (or, with ``keep``, completed); restores them with ``resume``."""

    def __init__(self, path: Path, scene, every_s: float, keep: bool, run: "_RunState"):
        from . import checkpoint as ckpt

        self.path, self.every_s, self.keep, self.run = Path(path), every_s, keep, run
        self.fingerprint = ckpt.scene_fingerprint(scene)
        self.written = 0
        self.resumed_from = None
        self.last = time.perf_counter()

    def resume(self, sim) -> bool:
        """Restore ``sim`` and the accumulators from the file if there is one; True if so."""
        from . import checkpoint as ckpt

        if not self.path.exists():
            return False
        run, arrs = ckpt.load(self.path, sim, self.fingerprint)
        st = self.run
        self.resumed_from = sim.step_count
        st.mass0, st.profile.n_avg, st.wall_before = float(run["mass0"]), int(run["n_avg"]), float(run["wall_seconds"])
        st.n_fluid0 = float(run.get("n_fluid0", float("nan")))  # NaN: a checkpoint written before it was kept
        st.profile.uz_sum[...] = arrs["uz_sum"]
        st.profile.uz_cnt[...] = arrs["uz_cnt"]
        st.flow.restore(arrs["series"])
        if st.particles is not None and sim.particles.n:
            rows, n = arrs["particle_rows"], sim.particles.n
            st.particles.recorder.rows = [rows[i:i + n].copy() for i in range(0, len(rows), n)]
        if st.planes is not None and "plane_samples" in arrs:
            st.planes.profile.restore(arrs)
        return True

    def save(self, sim) -> None:
        from . import checkpoint as ckpt

        if sim.guard is not None:
            sim.guard.check(sim)  # only a state that passes the guard is a good checkpoint
        st = self.run
        rec = st.particles.recorder if st.particles is not None else None
        rows = np.concatenate(rec.rows) if rec is not None and rec.rows else np.zeros((0, 0))
        ckpt.write(self.path, sim, self.fingerprint,
                   run={"mass0": st.mass0, "n_avg": st.profile.n_avg, "wall_seconds": st.wall(),
                        "n_fluid0": st.n_fluid0},
                   run_arrays={"uz_sum": st.profile.uz_sum, "uz_cnt": st.profile.uz_cnt,
                               "series": np.array(st.flow.rows, dtype=np.float64).reshape(-1, st.flow.COLUMNS),
                               "particle_rows": rows,
                               **(st.planes.profile.state() if st.planes is not None else {})})
        self.written += 1

    def between(self, sim):
        if time.perf_counter() - self.last >= self.every_s:
            self.save(sim)
            self.last = time.perf_counter()

    def finish(self, sim, status):
        if status == "interrupted" or (status == "completed" and self.keep):
            self.save(sim)

    def drops(self, status: str) -> bool:
        """Whether the run's end removes the checkpoint (completed, not asked to keep it)."""
        return status == "completed" and not self.keep

    def record(self, status: str) -> dict:
        return {"path": str(self.path), "resumed_from_step": self.resumed_from, "written": self.written,
                "kept": self.path.exists() and not self.drops(status), "every_s": self.every_s}

    def drop(self, status: str) -> None:
        """Remove the checkpoint of a completed run; called only once the final outputs are
        written, so a kill in between leaves it and the rerun resumes instead of starting over."""
        if self.drops(status):
            self.path.unlink(missing_ok=True)


def _fluid_volume_drift(mass0: float, mass1: float, n_fluid0: float, n_fluid1: int) -> dict:
    """With particles: moving bodies cover and uncover nodes, so the fluid's total mass follows its
    volume (bodies free to overlap, collisions off, cover fewer nodes); the mean density per fluid
    node is what a leak would change. Both drifts, relative (NaN without the start's node count)."""
    if not n_fluid0 > 0 or n_fluid1 <= 0:
        return {"fluid_nodes_change_rel": float("nan"), "density_drift_rel": float("nan")}
    return {"fluid_nodes_change_rel": n_fluid1 / n_fluid0 - 1.0,
            "density_drift_rel": (mass1 / n_fluid1) / (mass0 / n_fluid0) - 1.0}


@dataclass
class _RunState:
    """The accumulators of one ``run_scene`` call that a checkpoint carries."""

    flow: FlowRateSeries
    profile: ProfileAccumulator
    particles: ParticleSamples | None
    mass0: float
    planes: PlaneSamples | None = None
    n_fluid0: float = float("nan")  # fluid nodes at the start (particle scenes: bodies cover and uncover nodes)
    wall_before: float = 0.0
    t0: float = 0.0

    def wall(self) -> float:
        return self.wall_before + time.perf_counter() - self.t0


def run_scene(scene, params, out_dir: Path, progress: bool = True, max_steps: int | None = None,
              checkpoint: Path | None = None, checkpoint_every_s: float = 300.0, keep_checkpoint: bool = False,
              stop_at_step: int | None = None) -> dict:
    """Run ``scene`` and write its outputs into ``out_dir``; returns the summary (also written).

    Outputs (physical units; documented in docs/outputs.md): ``summary.json``, ``flow_rate.csv`` and,
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
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t_build = time.perf_counter()
    # Ctrl-C from here on (the set-up compiles for minutes on a cold cache) ends the run as
    # interrupted, with its summary, instead of killing it with nothing written; SIGTERM is caught
    # from the time loop on (a batch system's kill before it leaves no checkpoint to resume)
    early = _Interrupt(signals=(signal.SIGINT,))
    with early:
        return _run_scene(scene, params, out_dir, progress, max_steps, checkpoint, checkpoint_every_s,
                          keep_checkpoint, stop_at_step, early, t_build)


def _run_scene(scene, params, out_dir, progress, max_steps, checkpoint, checkpoint_every_s, keep_checkpoint,
               stop_at_step, early, t_build) -> dict:
    from . import outputs
    from .fields import FieldWriter
    from .profiles import PlaneProfile

    units = params.units
    sim = simulation_from_scene(scene, params)
    grid = sim.grid
    n_steps = params.n_steps if max_steps is None else min(max_steps, params.n_steps)
    spinup = min(params.spinup_steps, n_steps)
    every = params.sample_every
    profile = ProfileAccumulator(grid, spinup)
    planes = PlaneProfile.for_grid(grid)  # a box's profile across its walls
    run = _RunState(flow=FlowRateSeries(), profile=profile,
                    particles=ParticleSamples(sim, units) if sim.particles is not None else None, mass0=sim.mass(),
                    planes=PlaneSamples(planes, spinup) if planes is not None else None,
                    n_fluid0=float(sim.particles.n_fluid) if sim.particles is not None else float("nan"))
    field_writer = FieldWriter.from_scene(scene, params, grid, out_dir, n_steps)
    writer = CheckpointWriter(checkpoint, scene, checkpoint_every_s, keep_checkpoint, run) if checkpoint else None
    if not (writer is not None and writer.resume(sim)) and run.particles is not None:
        run.particles.recorder.sample(0)
    fields = FieldSamples(field_writer, sim, resumed=writer is not None and writer.resumed_from is not None) \
        if field_writer is not None else None
    bar = Progress(n_steps, units, grid.n_fluid, progress)
    if sim.step_count:
        bar.bar.update(min(sim.step_count, n_steps))
    # The first sweep compiles or loads the kernels; keep that out of the MLUPS figure.
    sim.step(0)
    run.t0 = bar.t0 = time.perf_counter()
    if writer is not None:
        writer.last = run.t0
    setup_seconds = run.t0 - t_build
    reporters = [*([fields] if fields else []), FiniteState(), run.flow, *([run.particles] if run.particles else []),
                 profile, *([run.planes] if run.planes else []), bar, *([writer] if writer else [])]
    outcome = run_loop(sim, n_steps, every, reporters, stop_at_step=stop_at_step, interrupt=early)
    wall = run.wall()
    bar.bar.close()
    status, message = outcome.status, outcome.message
    if outcome.error is not None and checkpoint is not None and Path(checkpoint).exists():
        message += f" The last good checkpoint is kept at {checkpoint} (resuming it with the same scene repeats the failure)."
    mass0, mass1 = run.mass0, sim.mass()
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
        **(_fluid_volume_drift(mass0, mass1, run.n_fluid0, sim.particles.n_fluid) if sim.particles is not None else {}),
        "effects": {e.name: sim.timers[e.name] for e in sim.effects},
        "samples_averaged": profile.n_avg,
        "spinup_s": spinup * units.dt_s,
    }
    if sim.guard is not None:
        summary["guard"] = sim.guard.record()
    if writer is not None:
        summary["checkpoint"] = writer.record(status)
    run.flow.write(out_dir, summary, files, scene, units)
    if run.particles is not None:
        run.particles.write(out_dir, summary, files, scene, sim, mass0)
    profile.write(out_dir, summary, files, scene, params, run.flow.rows)
    if fields is not None:
        files.update(dict.fromkeys(field_writer.close(), True))
    if run.planes is not None and run.planes.profile.samples[0] > 0 and scene.outputs.profile:
        files[planes.write(out_dir, units)] = True
    summary["files"] = sorted(files)
    outputs.write_summary(out_dir, summary, scene, params)
    if writer is not None:
        writer.drop(status)
    return summary
