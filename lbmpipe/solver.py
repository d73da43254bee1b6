"""The simulation: state, the time step made of effects, and the run loop.

State lives in lattice units. ``f`` holds the post-collision populations of the current time
(Eq. (2) applied), ``f_next`` receives the next ones; the two swap every step. The step is

1. ``pre`` effects fill the ghost slots of solid nodes (walls, particles) in ``f``;
2. the ``fluid`` effect streams and collides ``f -> f_next`` (one generated kernel);
3. ``post`` effects (flux correction, flow-rate control, collisions, rigid-body motion);
4. swap;
5. every ``guard.every`` steps, the run-time guard (``lbmpipe.guard``): NaN/Inf, lattice speed,
   density range, particles inside and overlaps within the collision bound; a failure raises
   ``errors.Unstable``, which the run loop reports as status ``unstable``.

``lbmpipe.assemble`` decides the effects from a scene; ``run_loop`` steps a simulation and hands
each sample to its reporters (``Reporter``). ``lbmpipe.run.run_scene`` (the CLI and the pipeline,
with the reporters that write a run's outputs and checkpoints) and the stability suite share the
loop. This module imports nothing above the fluid package, the ``Effect`` base class and the compile
clock (``lbmpipe.compile_clock``, which keeps numba's compilations out of the effects' timers).
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass

import numpy as np

from .compile_clock import CLOCK
from .effect import Effect
from .errors import Unstable
from .fluid import boundaries as bnd
from .fluid import observables as obs
from .fluid.collision import Relaxation
from .fluid.effects import StreamCollide, stream_collide
from .fluid.kernels import dtype_of

#: column chunks of the fluid sweep: 4 per thread up to 16 threads
SWEEP_CHUNKS = 64


class Simulation:
    """A lattice Boltzmann run on a grid with the finished, ordered list of its effects
    (``assemble.assemble``): ``pre`` effects, the one ``fluid`` sweep (which holds the collision
    operator and its rates, ``fluid.collision.Relaxation``), ``post`` effects."""

    def __init__(self, grid: bnd.Grid, effects: list[Effect], *, force=(0.0, 0.0, 0.0)):
        phases = [e.phase for e in effects]
        if phases.count("fluid") != 1 or phases != sorted(phases, key=("pre", "fluid", "post").index):
            raise ValueError(f"effects must be pre..., one fluid sweep, post... in that order, got {effects}")
        self.grid = grid
        self.lattice = grid.lattice
        self.force = np.array(force, dtype=np.float64)
        sweep = effects[phases.index("fluid")]
        self.sweep: StreamCollide = sweep
        self.dtype = dtype_of(sweep.spec.precision)
        q = self.lattice.q
        self.f = bnd.alloc_populations(q, grid, self.dtype)
        self.f_next = bnd.alloc_populations(q, grid, self.dtype)
        self.last_flux = 0.0
        self.step_count = 0
        self.effects: list[Effect] = list(effects)
        self.timers = {e.name: 0.0 for e in self.effects}
        self.compile_seconds = 0.0  # numba compilations inside the steps, out of the timers
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
              extra_effects: list[Effect] | None = None, density_floor: float | None = None) -> "Simulation":
        """A simulation assembled by hand (tests, benchmarks): the sweep for ``collision`` (with
        rates ``omega``, ``omega_minus``) and ``precision`` between the ``pre`` and the ``post``
        effects of ``extra_effects``."""
        sweep = stream_collide(grid.lattice.name, Relaxation.of(collision, omega, omega_minus), precision, force,
                               flux, density_floor)
        extra = list(extra_effects or [])
        effects = [e for e in extra if e.phase == "pre"] + [sweep] + [e for e in extra if e.phase == "post"]
        return cls(grid, effects, force=force)

    @property
    def omega(self) -> float:
        """The sweep's even-moment (viscous) relaxation rate."""
        return self.sweep.relaxation.omega

    @property
    def omega_minus(self) -> float:
        """The sweep's odd-moment relaxation rate (``omega`` for BGK)."""
        return self.sweep.relaxation.omega_minus

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
        """``n`` time steps. Each effect's timer gets its wall time without the numba compilations
        it triggered (``compile_clock``: a cold cache compiles a kernel at its first call);
        those go to ``compile_seconds``."""
        perf = time.perf_counter
        timers = self.timers
        guard = self.guard
        clock = CLOCK
        for _ in range(n):
            for e in self.effects:
                c0 = clock.seconds
                t0 = perf()
                e(self)
                dc = clock.seconds - c0
                timers[e.name] += perf() - t0 - dc
                self.compile_seconds += dc
            self.f, self.f_next = self.f_next, self.f
            self.step_count += 1
            if guard is not None and self.step_count % guard.every == 0:
                c0 = clock.seconds
                t0 = perf()
                try:
                    guard.check(self)
                finally:
                    dc = clock.seconds - c0
                    guard.seconds += perf() - t0 - dc
                    self.compile_seconds += dc

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
