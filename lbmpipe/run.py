"""A scene's run with its outputs: ``run_scene`` assembles the simulation (``lbmpipe.assemble``),
steps it in the run loop (``lbmpipe.solver.run_loop``) with the reporters that sample, average and
checkpoint, and writes ``summary.json``, ``flow_rate.csv``, ``profile.csv``, the particle files and
the fields. Checkpoints (``lbmpipe.checkpoint``) are written every few minutes of wall time and at
an interrupt; a resumed run is bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from . import checkpoint as ckpt
from . import outputs
from .assemble import simulation_from_scene
from .fields import FieldWriter
from .compile_clock import CLOCK
from .fluid import observables as obs
from .particles import placement
from .profiles import PlaneProfile
from .solver import FiniteState, Reporter, _Interrupt, run_loop


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
        files["flow_rate.csv"] = outputs.write_flow_rate(out_dir, self.rows, units, scene)


class ParticleSamples(Reporter):
    """``particles.parquet`` and ``particles_static.csv``, and the summary's particle entries (the
    effects' tallies: density floor, collisions)."""

    def __init__(self, sim, units):


        self.recorder = placement.ParticleRecorder(sim.particles, units)

    def sample(self, sim, sample):
        self.recorder.sample(sim.step_count)
        return None

    def write(self, out_dir, summary, files, scene, sim, mass0) -> None:


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
    """The progress bar: steps done, simulated time and throughput (the time spent compiling
    kernels left out); "compiling kernels" while numba compiles (``compile_clock``)."""

    COMPILING = "compiling kernels"

    def __init__(self, n_steps: int, units, n_fluid: int, enabled: bool):
        self.bar = outputs.progress_bar(n_steps, units.dt_s, n_fluid, enabled=enabled)
        self.dt_s, self.n_fluid = units.dt_s, n_fluid
        self.start()
        self.text = ""

    def start(self) -> None:
        """The throughput counts from now, and the compilations from now on are left out of it."""
        self.t0, self.c0 = time.perf_counter(), CLOCK.seconds

    def advanced(self, sim, steps):
        self.bar.update(steps)

    def sample(self, sim, sample):
        elapsed = time.perf_counter() - self.t0 - (CLOCK.seconds - self.c0)
        self.text = outputs.progress_text(sim.step_count, self.dt_s, self.n_fluid, elapsed)
        self.bar.set_postfix_str(self.text)
        return None

    def compiling(self, now: bool) -> None:
        """``CompileClock.watch`` callback: say so while kernels compile, then the last throughput."""
        self.bar.set_postfix_str(self.COMPILING if now else self.text)


class CheckpointWriter(Reporter):
    """Writes the complete state (the simulation plus the other reporters' accumulators) to
    ``path`` every ``every_s`` seconds of wall time, after a guard check, and when the run is
    interrupted (or, with ``keep``, completed); restores them with ``resume``."""

    def __init__(self, path: Path, scene, every_s: float, keep: bool, run: "_RunState"):
        self.path, self.every_s, self.keep, self.run = Path(path), every_s, keep, run
        self.fingerprint = ckpt.scene_fingerprint(scene)
        self.written = 0
        self.resumed_from = None
        self.last = time.perf_counter()

    def resume(self, sim) -> bool:
        """Restore ``sim`` and the accumulators from the file if there is one; True if so."""
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
    t_build = (time.perf_counter(), CLOCK.seconds)
    # Ctrl-C from here on (the set-up compiles for minutes on a cold cache) ends the run as
    # interrupted, with its summary, instead of killing it with nothing written; SIGTERM is caught
    # from the time loop on (a batch system's kill before it leaves no checkpoint to resume)
    early = _Interrupt(signals=(signal.SIGINT,))
    with early:
        return _run_scene(scene, params, out_dir, progress, max_steps, checkpoint, checkpoint_every_s,
                          keep_checkpoint, stop_at_step, early, t_build)


def _run_scene(scene, params, out_dir, progress, max_steps, checkpoint, checkpoint_every_s, keep_checkpoint,
               stop_at_step, early, t_build) -> dict:
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
    # Kernels compile at their first call (a cold cache: minutes, in the first steps and at the
    # first collision): the compile clock keeps that time out of the effects' timers and MLUPS.
    bar.start()
    run.t0 = bar.t0
    compile0 = CLOCK.seconds
    if writer is not None:
        writer.last = run.t0
    setup_seconds = run.t0 - t_build[0]
    reporters = [*([fields] if fields else []), FiniteState(), run.flow, *([run.particles] if run.particles else []),
                 profile, *([run.planes] if run.planes else []), bar, *([writer] if writer else [])]
    with CLOCK.watch(bar.compiling):
        outcome = run_loop(sim, n_steps, every, reporters, stop_at_step=stop_at_step, interrupt=early)
    wall = run.wall()
    compile_seconds = CLOCK.seconds - compile0
    stepping = wall - compile_seconds
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
        # numba compilations during the time loop (out of the effects' timers and MLUPS) and the set-up
        "compile_seconds": compile_seconds,
        "setup_compile_seconds": compile0 - t_build[1],
        "mlups": grid.n_fluid * sim.step_count / stepping / 1e6 if stepping > 0 else 0.0,
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
