"""Run-time guard: stop a diverging run early, say what diverged, where, and what to change.

Every ``every`` steps (``DEFAULT_EVERY`` for a scene's run) the guard checks, on the
post-collision populations of the current time:

* fluid: a non-finite population (NaN/Inf), the lattice speed ``|u| = |sum_i f_i e_i| / rho``
  (Eq. (4)) above ``u_max`` (default 0.5, i.e. 0.87 c_s with ``c_s = 1/sqrt(3)``: the equilibrium
  Eq. (3) is a low-Mach expansion and loses positivity near there), and the density outside
  ``[rho_min, rho_max]`` (default [0.2, 3.0]). In dense suspensions at dx = 1 mm single nodes
  in pockets between particles and in films at the wall swing by +-50 % (measured: 8 mm cubes at
  30 %, density 0.87-1.56 within 300 steps) and recover, so the weakly compressible bound of
  Eqs. (5)-(6) would stop runs that go on; the guard stops a node that is emptying or has tripled,
  the runaway that precedes negative populations and NaN. The summary reports the extremes seen. All three come from one parallel reduction over the fluid nodes (``_scan``): no
  moment arrays are formed; NaN or Inf in any ``f_i`` propagates into the sum ``rho``, so testing
  the sums covers every population.
* particles: a non-finite centre, velocity, orientation or angular velocity, a particle faster
  than ``u_max``, a centre outside the domain (pipe: farther than R from the axis; box: beyond a
  wall), and an overlap beyond the collision model's ``overlap_bound``
  (``lbmpipe.particles.collisions.OVERLAP_BOUND_FACTOR`` times ``overlap_tol``, 0.1 lattice spacing by
  default: the bound on overlaps at any time, whose sources the collisions module lists; in a
  jammed 50 % packing the projection can run out of iterations at a few hundredths of a spacing,
  harmless for the fluid, which cannot resolve it). The guard reads the running maximum the ``CollisionEffect``
  keeps, so an excess at any step is seen.

A failed check raises :class:`Unstable`, whose message names what failed, where (node index and
position in mm, or particle id), at which step, the likely cause and a fix (smaller dt, TRT,
finer dx, ...). ``run.run_scene`` turns it into the summary status ``unstable`` (``lbmpipe
run`` exits with status 4) and leaves the last good checkpoint in place.

Cost: the scan reads every population once (a sweep reads and writes them once and does the
collision arithmetic), about a fifth of a step on the paper's pipe, so checking every
``DEFAULT_EVERY = 50`` steps costs well under 1 % (``benchmarks/guard.py`` measures it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from .errors import Unstable  # noqa: F401  (raised here; guard.Unstable is the name callers used)
from .particles.collision_params import OVERLAP_BOUND_FACTOR
from .particles.collisions import CollisionEffect

#: steps between checks when the scene does not say (cost < 1 % of the step: benchmarks/guard.py)
DEFAULT_EVERY = 50

FLUID = -1
WALL = -2
#: a density floor that has added more than this share of the fluid mass is named as the cause
FLOOR_SHARE_CAUSE = 0.01
CS = 1.0 / math.sqrt(3.0)  # lattice speed of sound

# columns of the per-chunk result of _scan
_NBAD, _IBAD, _U2, _IU, _RMIN, _IRMIN, _RMAX, _IRMAX, _NCOL = range(9)


@njit(parallel=True, cache=True)
def _scan(f, ex, ey, ez, cols_x, cols_y, z0, z1, owner, n_chunks, out):
    """Per chunk of fluid columns: count and first flat index of non-finite nodes, max |u|^2,
    min and max rho (with flat indices), over nodes with ``owner == FLUID``."""
    q, ny, az = f.shape[0], f.shape[2], f.shape[3]
    ncol = cols_x.shape[0]
    for c in prange(n_chunks):
        lo = c * ncol // n_chunks
        hi = (c + 1) * ncol // n_chunks
        nbad = 0.0
        ibad = -1.0
        u2max = -1.0
        iu = -1.0
        rmin = np.inf
        irmin = -1.0
        rmax = -np.inf
        irmax = -1.0
        for k in range(lo, hi):
            x = cols_x[k]
            y = cols_y[k]
            base = (x * ny + y) * az
            for z in range(z0, z1):
                node = base + z
                if owner[node] != FLUID:
                    continue
                rho = 0.0
                jx = 0.0
                jy = 0.0
                jz = 0.0
                for i in range(q):
                    fi = f[i, x, y, z]
                    rho += fi
                    jx += fi * ex[i]
                    jy += fi * ey[i]
                    jz += fi * ez[i]
                if not (math.isfinite(rho) and math.isfinite(jx) and math.isfinite(jy) and math.isfinite(jz)):
                    if nbad == 0.0:
                        ibad = node
                    nbad += 1.0
                    continue
                if rho < rmin:
                    rmin = rho
                    irmin = node
                if rho > rmax:
                    rmax = rho
                    irmax = node
                if rho > 0.0:
                    u2 = (jx * jx + jy * jy + jz * jz) / (rho * rho)
                    if u2 > u2max:
                        u2max = u2
                        iu = node
        out[c, _NBAD] = nbad
        out[c, _IBAD] = ibad
        out[c, _U2] = u2max
        out[c, _IU] = iu
        out[c, _RMIN] = rmin
        out[c, _IRMIN] = irmin
        out[c, _RMAX] = rmax
        out[c, _IRMAX] = irmax


@dataclass(frozen=True)
class GuardLimits:
    """Bounds the guard enforces (lattice units)."""

    u_max: float = 0.5  # fluid and particle speed, 0.87 c_s
    rho_min: float = 0.2
    rho_max: float = 3.0
    overlap_factor: float = OVERLAP_BOUND_FACTOR  # times the collision model's overlap_tol


class Guard:
    """Checks a ``Simulation`` every ``every`` steps (see the module docstring).

    ``dx_mm`` converts node indices into positions for the messages; ``tau``, ``mach`` and
    ``collision`` (``"bgk"``/``"trt"``) tailor the suggested fix. ``checks`` and ``seconds`` count
    the checks done and their cost; ``last`` holds the last scan's values (``u_max``,
    ``rho_min``, ``rho_max``)."""

    def __init__(self, sim, every: int = DEFAULT_EVERY, limits: GuardLimits = GuardLimits(), dx_mm: float = 1.0,
                 tau: float | None = None, mach: float | None = None, collision: str = "bgk"):
        if int(every) < 1:
            raise ValueError(f"guard interval must be at least 1 step, got {every}")
        self.every = int(every)
        self.limits = limits
        self.dx_mm = float(dx_mm)
        self.tau, self.mach, self.collision = tau, mach, collision
        g = sim.grid
        self.grid = g
        e = sim.lattice.e.astype(np.float64)
        self.ex, self.ey, self.ez = (np.ascontiguousarray(e[:, a]) for a in range(3))
        nx, ny, nz = g.shape
        if sim.particles is None:
            own = np.full((nx, ny, g.alloc_z), WALL, dtype=np.int32)
            own[:, :, :nz][g.fluid] = FLUID
            self._own = own.reshape(-1)
        else:
            self._own = None  # the particle system's owner map, which changes every step
        self.n_chunks = max(1, min(len(g.cols_x), 4 * numba.get_num_threads()))
        self._out = np.zeros((self.n_chunks, _NCOL))
        pos = g.positions()
        self._pos = pos
        # particle domain (lattice coordinates of the particle system: pipe axis at x = y = 0)
        self.radius = g.radius if g.kind == "pipe" else 0.0
        inner = [g.shape[a] - 2 * g.ghost[a] for a in range(3)]
        self.lo = np.zeros(3)
        self.hi = np.array(inner, dtype=np.float64)
        self.periodic = np.array(g.periodic)
        self.collide = None  # the collision effect, whose running maximum overlap the guard bounds
        if sim.particles is not None:
            self.collide = sim.effect(CollisionEffect)
        self.checks = 0
        self.seconds = 0.0
        self.last: dict = {}
        self.mass0 = 0.0  # fluid mass when the guard starts (guard_for), for the density floor's share

    # -- fluid ---------------------------------------------------------------------------------
    def scan(self, sim) -> dict:
        """One reduction over the fluid nodes: ``nonfinite`` (count), ``u_max`` (lattice),
        ``rho_min``, ``rho_max`` and the flat node index of each extreme (``*_node``)."""
        g = self.grid
        owner = self._own if self._own is not None else sim.particles.owner
        out = self._out
        _scan(sim.f, self.ex, self.ey, self.ez, g.cols_x, g.cols_y, g.z0, g.z1, owner, self.n_chunks, out)
        nbad = out[:, _NBAD]
        bad = np.flatnonzero(nbad > 0)
        c_u = int(np.argmax(out[:, _U2]))
        c_lo = int(np.argmin(out[:, _RMIN]))
        c_hi = int(np.argmax(out[:, _RMAX]))
        res = {
            "nonfinite": int(nbad.sum()),
            "nonfinite_node": int(out[bad[0], _IBAD]) if len(bad) else -1,
            "u_max": math.sqrt(max(out[c_u, _U2], 0.0)), "u_node": int(out[c_u, _IU]),
            "rho_min": float(out[c_lo, _RMIN]), "rho_min_node": int(out[c_lo, _IRMIN]),
            "rho_max": float(out[c_hi, _RMAX]), "rho_max_node": int(out[c_hi, _IRMAX]),
        }
        self.last = {k: res[k] for k in ("u_max", "rho_min", "rho_max")}
        return res

    def where_node(self, node: int) -> str:
        """``node (ix, iy, iz) at (x, y, z) mm`` for a flat index of ``f``'s node layout."""
        g = self.grid
        az, ny = g.alloc_z, g.shape[1]
        ix, rest = divmod(int(node), ny * az)
        iy, iz = divmod(rest, az)
        x, y, z = (float(self._pos[a][i]) * self.dx_mm for a, i in enumerate((ix, iy, iz)))
        text = f"node ({ix}, {iy}, {iz}) at ({x:.3g}, {y:.3g}, {z:.3g}) mm"
        if g.kind == "pipe":
            text += f", r = {math.hypot(x, y):.3g} mm of R = {g.radius * self.dx_mm:.3g} mm"
        return text

    def node_context(self, sim, node: int) -> tuple[str, int]:
        """Where a failing node lies: ``("particle", k)`` if a lattice link joins it to a node of
        particle ``k``, ``("wall", -1)`` within 2 spacings of a wall, else ``("bulk", -1)``."""
        g = self.grid
        az, ny, nx = g.alloc_z, g.shape[1], g.shape[0]
        ix, rest = divmod(int(node), ny * az)
        iy, iz = divmod(rest, az)
        if sim.particles is not None:
            owner = sim.particles.owner
            for ex, ey, ez in zip(self.ex, self.ey, self.ez):
                jx, jy, jz = (ix + int(ex)) % nx, (iy + int(ey)) % ny, iz + int(ez)
                if 0 <= jz < az and owner[(jx * ny + jy) * az + jz] >= 0:
                    return "particle", int(owner[(jx * ny + jy) * az + jz])
        if g.kind == "pipe":
            if math.hypot(float(self._pos[0][ix]), float(self._pos[1][iy])) > g.radius - 2.0:
                return "wall", -1
            return "bulk", -1
        for a, i in enumerate((ix, iy, iz)):
            if g.ghost[a] and (i - g.ghost[a] < 2 or g.shape[a] - g.ghost[a] - 1 - i < 2):
                return "wall", -1
        return "bulk", -1

    def floor_share(self, sim) -> float:
        """Fluid mass the density floor has added so far, as a fraction of the mass at the start
        of the guard (0 without a floor)."""
        for e in sim.effects:
            tally = getattr(e, "tally", None)
            if tally is not None and getattr(e, "rho_min", 0.0) > 0.0 and self.mass0:
                return float(tally[0]) / self.mass0
        return 0.0

    def _located_fix(self, sim, node: int) -> tuple[str, str]:
        """Cause and fix from what was measured: mass added by the density floor, then the position
        of the failing node (particle surface, wall or bulk), then the run's Mach number and tau."""
        causes, fixes = [], []
        share = self.floor_share(sim)
        if share > FLOOR_SHARE_CAUSE:
            causes.append(f"the density floor has added {100 * share:.3g} % of the fluid mass since the start: "
                          "films thinner than one spacing (particles pressed together or against the wall, e.g. "
                          "a fast impact) are drained by Eq. (8) faster than they refill")
            fixes.append("slow the impacts (reduce numerics.dt_s, which also lowers the lattice speeds), or raise "
                         "particles.collisions.contact_gap_dx to keep bodies a spacing apart")
        where, k = self.node_context(sim, node)
        if where == "particle" and not causes:
            causes.append(f"the failing node touches particle {k}: the moving bounce-back of Eq. (8) at a fast "
                          "or light particle, or a thin film between it and a neighbour or the wall")
            fixes.append("reduce numerics.dt_s; check the particle's density_ratio and particles.gravity_m_s2")
        elif where == "wall" and not causes:
            if sim.particles is not None and sim.particles.n:
                causes.append("the failing node is next to the wall, where a particle pressing against the wall "
                              "squeezes the fluid film")
                fixes.append("raise particles.collisions.contact_gap_dx or reduce numerics.dt_s")
            else:  # no particle to blame: the wall first, then what the run's parameters suggest
                cause, fix = self._fluid_fix()
                return f"the failing node is next to the wall (a moving wall, or the staircase wall); {cause}", fix
        if causes:
            return "; ".join(causes), "; ".join(fixes)
        return self._fluid_fix()

    def _fluid_fix(self) -> tuple[str, str]:
        causes, fixes = [], []
        if self.mach is not None and self.mach > 0.35:
            causes.append(f"the centre-line Mach number {self.mach:.2f} is high (the equilibrium Eq. (3) is a "
                          f"low-Mach expansion)")
            fixes.append("reduce numerics.dt_s (halving dt halves the lattice velocity and the Mach number)")
        if self.tau is not None and self.tau < 0.55:
            causes.append(f"tau = {self.tau:.3f} is close to 1/2 (under-resolved shear, little numerical damping)")
            fixes.append("use numerics.collision: trt, or a finer numerics.dx_mm with dt_s proportional to dx "
                         "(tau - 1/2 = 3 nu dt / dx^2 then grows as 1/dx)")
        if not causes:
            causes.append("a local velocity or density excursion grew (large particle velocities near walls or "
                          "between particles, or too coarse a lattice for the flow)")
            fixes.append("reduce numerics.dt_s, or use numerics.collision: trt, or refine numerics.dx_mm")
        elif self.collision == "bgk" and not any("trt" in f for f in fixes):
            fixes.append("or use numerics.collision: trt")
        return "; ".join(causes), "; ".join(fixes)

    def check_fluid(self, sim) -> dict:
        res = self.scan(sim)
        lim = self.limits
        step = sim.step_count
        if res["nonfinite"]:
            cause, fix = self._located_fix(sim, res["nonfinite_node"])
            raise Unstable(f"non-finite populations (NaN/Inf) at {res['nonfinite']} fluid nodes, the first",
                           self.where_node(res["nonfinite_node"]), step, cause, fix)
        if res["u_max"] > lim.u_max:
            cause, fix = self._located_fix(sim, res["u_node"])
            raise Unstable(f"fluid speed |u| = {res['u_max']:.3g} lattice units ({res['u_max'] / CS:.2f} c_s) above "
                           f"the limit {lim.u_max:g}", self.where_node(res["u_node"]), step, cause, fix)
        if res["rho_min"] < lim.rho_min or res["rho_max"] > lim.rho_max:
            low = res["rho_min"] < lim.rho_min
            val, node = (res["rho_min"], res["rho_min_node"]) if low else (res["rho_max"], res["rho_max_node"])
            cause, fix = self._located_fix(sim, node)
            raise Unstable(f"fluid density {val:.4g} outside [{lim.rho_min:g}, {lim.rho_max:g}]",
                           self.where_node(node), step, cause, fix)
        return res

    # -- particles -----------------------------------------------------------------------------
    def check_particles(self, sim) -> None:
        ps = sim.particles
        if ps is None or ps.n == 0:
            return
        b = ps.bodies
        step = sim.step_count
        finite = (np.isfinite(b.x).all(axis=1) & np.isfinite(b.v).all(axis=1) & np.isfinite(b.q).all(axis=1)
                  & np.isfinite(b.wb).all(axis=1))
        if not finite.all():
            k = int(np.flatnonzero(~finite)[0])
            raise Unstable("non-finite particle state (centre, velocity, orientation or angular velocity)",
                           f"particle {k}", step,
                           "the fluid around it diverged, or the particle is very light (density_ratio well below 1) "
                           "so that its velocity update amplifies the hydrodynamic force",
                           "reduce numerics.dt_s, use numerics.collision: trt, or raise the particle density_ratio")
        speed = np.linalg.norm(b.v, axis=1)
        if speed.max() > self.limits.u_max:
            k = int(np.argmax(speed))
            raise Unstable(f"particle speed {speed[k]:.3g} lattice units above the limit {self.limits.u_max:g}",
                           f"particle {k} at {self._pmm(b.x[k])}", step,
                           "a runaway particle (a light particle kicked by the flow, or a collision impulse in a jam)",
                           "reduce numerics.dt_s; check particles.gravity_m_s2 and density_ratio")
        x = b.x
        if self.radius > 0:
            r = np.hypot(x[:, 0], x[:, 1])
            out = r > self.radius
            detail = lambda k: f"r = {r[k] * self.dx_mm:.3g} mm > R = {self.radius * self.dx_mm:.3g} mm"  # noqa: E731
        else:
            walled = ~self.periodic
            out = ((x < self.lo) | (x > self.hi))[:, walled].any(axis=1) if walled.any() else np.zeros(len(x), bool)
            detail = lambda k: "beyond a wall of the box"  # noqa: E731
        if out.any():
            k = int(np.flatnonzero(out)[0])
            raise Unstable(f"particle centre outside the domain ({detail(k)})", f"particle {k} at {self._pmm(x[k])}",
                           step, "a wall contact was missed: particles.collisions.enabled is false, or the particle "
                           "moved too far in one step", "enable particles.collisions, or reduce numerics.dt_s")
        ce = self.collide
        if ce is not None:
            bound = ce.params.overlap_tol * self.limits.overlap_factor
            ova = float(ce.totals.get("max_overlap_after_lu", 0.0))
            if ova > bound * (1.0 + 1e-9) + 1e-12:
                raise Unstable(f"particle overlap {ova:.3g} lattice spacings after the collision step, above the bound "
                               f"{bound:g} (particles.collisions.overlap_tol_dx)", "the densest contact", step,
                               "a jammed configuration exhausted the overlap projection (max_projection_iters)",
                               "reduce numerics.dt_s or the concentration, or raise particles.collisions.overlap_tol_dx")

    def _pmm(self, x) -> str:
        return "(" + ", ".join(f"{c * self.dx_mm:.3g}" for c in x) + ") mm"

    # -- both ----------------------------------------------------------------------------------
    def check(self, sim) -> dict:
        """All checks on ``sim`` now; raises :class:`Unstable` on the first failure, else returns
        the fluid scan."""
        self.checks += 1
        res = self.check_fluid(sim)
        self.check_particles(sim)
        return res

    def record(self) -> dict:
        """Summary entry: interval, limits, checks done and their cost."""
        lim = self.limits
        return {"every": self.every, "u_max_lu": lim.u_max, "rho_range": [lim.rho_min, lim.rho_max],
                "overlap_factor": lim.overlap_factor, "checks": self.checks, "seconds": self.seconds}


def guard_for(sim, scene, params) -> Guard:
    """The guard a scene's simulation gets: every ``DEFAULT_EVERY`` steps, its fixes tailored to
    the sweep's collision operator."""
    guard = Guard(sim, every=DEFAULT_EVERY, dx_mm=params.units.dx_m * 1e3, tau=params.tau, mach=params.mach_max,
                  collision=sim.sweep.relaxation.operator)
    guard.mass0 = sim.mass()
    return guard
