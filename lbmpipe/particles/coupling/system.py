"""The particle system: rigid bodies on the grid with their owner map, column runs, link lists and
loads, and the per-step calls of the coupling kernels (lattice units).

External forces on particles
----------------------------
* The flow's driving body force stands for a pressure gradient, which pushes on the particle
  volume too: a particle gets ``f_drive V_p`` (force density times its volume).
* Optional gravity ``g`` acts on the particle's excess mass, ``(rho_p - rho0) V_p g``; the fluid
  carries no gravity (its hydrostatic pressure would only produce the buoyancy subtracted here).
``V_p`` is the geometric volume (``shapes.volume``), as is the mass ``rho_p V_p``.

State and bundles. Every array of the state is an attribute (checkpoints save the arrays of
``__dict__``; tuples are skipped as scratch); the kernels take them bundled in the named tuples
the properties build (``G``, ``L``, ``runs``, ``loads``, ...), unpacked at each kernel's top.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..rigid import Bodies, drift_arrays, omega_lab_arrays
from ..shapes import bounding_radius, volume
from .ladd import BodyState, Loads, accumulate_loads, couple_free, fixed_fill
from .links import LinkLists, clear_changed, mark_initial
from .nodes import FLUID, WALL, Grid, LatticeRef, wrap_table
from .observables import fluid_sums
from .refill import fill_uncovered
from .remap import RemapState, apply_changes, wrap_positions
from .runs import RunChanges, Runs, compute_runs, diff_runs


class ParticleSystem:
    """Rigid bodies on a grid: owner map, runs, link lists, forces (lattice units).

    ``bodies`` (``rigid.Bodies``) is updated in place: centres are wrapped into the periodic box.
    ``gravity`` (3,) acts on each particle's excess mass ``(rho_p - rho0) V_p``; the flow's body
    force density acts on ``V_p`` (module docstring). ``force``/``torque`` (N, 3) hold the
    hydrodynamic force and torque (lab frame, about the centre) of the last step.
    """

    def __init__(self, grid, bodies: Bodies, gravity=(0.0, 0.0, 0.0), rho0: float = 1.0):
        self.grid = grid
        self.bodies = bodies
        self.rho0 = float(rho0)
        lat = grid.lattice
        self.e = np.ascontiguousarray(lat.e.astype(np.int64))
        self.w = np.ascontiguousarray(lat.w.astype(np.float64))
        self.opp = np.ascontiguousarray(lat.opp.astype(np.int64))
        Q = lat.q
        nx, ny, nz = grid.shape
        self.dims = np.array([nx, ny, nz], dtype=np.int64)
        self.az = int(grid.alloc_z)
        self.periodic = np.array(grid.periodic, dtype=np.bool_)
        self.origin = np.array([p[0] for p in grid.positions()], dtype=np.float64)
        self.lo = self.origin - 0.5
        self.xmap = wrap_table(nx, grid.periodic[0])
        self.ymap = wrap_table(ny, grid.periodic[1])
        self.zmap = wrap_table(nz, grid.periodic[2])
        n = bodies.n
        self.n = n
        self.vol = np.array([volume(bodies.kind[k], bodies.h[k]) for k in range(n)], dtype=np.float64)
        self.gravity = np.asarray(gravity, dtype=np.float64).reshape(3)
        rb = np.array([bounding_radius(bodies.kind[k], bodies.h[k]) for k in range(n)], dtype=np.float64)
        self.rb = rb
        span = (2.0 * rb).astype(np.int64) + 2
        for d in range(3):
            # a node must not belong to a particle's runs twice (through the periodic image)
            if grid.periodic[d] and n and span.max() > self.dims[d]:
                raise ValueError(f"a particle's bounding diameter ({2 * rb.max():.3g} nodes) must be below the "
                                 f"periodic length along {'xyz'[d]} ({self.dims[d]} nodes) minus 2")
        self.fixed_ids = np.flatnonzero(bodies.fixed).astype(np.int64)
        self.free_ids = np.flatnonzero(~bodies.fixed).astype(np.int64)
        self.all_ids = np.concatenate([self.fixed_ids, self.free_ids])
        # runs (current and next)
        self.run_off = np.zeros(n + 1, dtype=np.int64)
        self.run_off[1:] = np.cumsum(span * span)
        ncol = int(self.run_off[-1])
        self.rect = np.zeros((n, 4), np.int64)
        self.z1 = np.ones(ncol, np.int64)
        self.z2 = np.zeros(ncol, np.int64)
        self.rect_n = np.zeros((n, 4), np.int64)
        self.z1_n = np.ones(ncol, np.int64)
        self.z2_n = np.zeros(ncol, np.int64)
        # change buffers of moving particles: a column changes by at most its old + new run
        cap = 2 * (span * span * span)[self.free_ids]
        self.chg_off = np.zeros(len(self.free_ids) + 1, np.int64)
        self.chg_off[1:] = np.cumsum(cap)
        tot = int(self.chg_off[-1])
        self.chg_node = np.zeros(tot, np.int64)
        self.chg_d = np.zeros(tot, np.int8)
        self.chg_n = np.zeros(len(self.free_ids), np.int64)
        self.touch_list = np.zeros(max(tot, 1), np.int64)
        self.unc_list = np.zeros(max(tot, 1), np.int64)
        self.unc_old = np.zeros(max(tot, 1), np.int64)
        # per touched node: new owner, covered momentum, uncovered (rho u_b, r); a tuple, so that
        # checkpoints skip it (scratch)
        self.remap_scratch = (np.zeros(max(tot, 1), np.int64), np.zeros((max(tot, 1), 3)), np.zeros((max(tot, 1), 6)))
        # node state
        size = nx * ny * self.az
        owner = np.full((nx, ny, self.az), WALL, dtype=np.int32)
        owner[:, :, :nz][grid.fluid] = FLUID
        self.owner = owner.reshape(-1)
        self.count = np.zeros(size, np.int16)
        self.touched = np.zeros(size, np.bool_)
        self.acq = np.full(size, -1, np.int32)
        # link lists: a lattice line through a convex particle enters it once, so direction i has
        # at most pi (r_b + 1)^2 |e_i| links (lines per unit area across e_i: |e_i|); padded
        norms = np.linalg.norm(self.e, axis=1)
        lcap = np.zeros((n, Q), np.int64)
        lcap[:, 1:] = (math.pi * (rb[:, None] + 2.0) ** 2 * norms[None, 1:]).astype(np.int64) + 16
        self.lcap = lcap
        self.lbase = np.zeros((n, Q), np.int64)
        flat = np.concatenate([[0], np.cumsum(lcap.reshape(-1))])
        self.lbase[:] = flat[:-1].reshape(n, Q)
        total = int(flat[-1])
        self.lcnt = np.zeros((n, Q), np.int64)
        if size >= 2**31 or self.dims.max() >= 10000:
            raise ValueError(f"grid {tuple(self.dims)} too large for particles: link lists hold node indices as "
                             "int32 and unwrapped coordinates as int16 (below 10000 nodes per axis)")
        self.LN = np.zeros((total, 2), np.int32)
        self.LC = np.zeros((total, 4), np.int16)
        self.lerr = np.zeros(1, np.int64)
        self.nown = np.zeros(n, np.int64)
        # nodes whose owner changed since the last link passes (a node changes at most once per
        # move, so a move's touched-node capacity bounds the list; mark_initial overflows it)
        self.chg = np.zeros(size, np.uint8)
        self.chg_list = np.zeros(max(tot, 1), np.int64)
        self.nchg = np.zeros(1, np.int64)
        nt = numba.config.NUMBA_NUM_THREADS
        per_particle = int(lcap.sum(axis=1).max()) if n else 1
        self.scratch = (np.zeros((nt, per_particle)), np.zeros((nt, 6, 7)))
        # dynamics and outputs
        self.fext = np.zeros((n, 6))
        self.imp = np.zeros((n, 6))
        self.om = np.zeros((n, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.force_sum = np.zeros((n, 3))
        self.torque_sum = np.zeros((n, 3))
        self.n_sum = np.zeros(n, np.int64)
        self.exch = np.zeros((n, 3))
        self.moved = np.zeros(3)
        self.last_cover = (0, 0)
        # the refill kernel of uncovered nodes (``remap.REFILLS``; the assembly sets the scene's)
        self.refill = fill_uncovered
        self._map_all()
        self.om[:] = omega_lab_arrays(bodies.q, bodies.wb)
        self.n_fluid = int(np.count_nonzero(self.owner == FLUID))

    # -- packed arguments of the kernels
    @property
    def G(self) -> Grid:
        return Grid(self.dims, self.az, self.origin, self.periodic, self.xmap, self.ymap, self.zmap, self.e)

    @property
    def L(self) -> LinkLists:
        return LinkLists(self.lbase, self.lcap, self.lcnt, self.LN, self.LC, self.lerr, self.nown, self.chg,
                         self.chg_list, self.nchg)

    def _check_links(self):
        if self.lerr[0]:
            raise RuntimeError(f"particle link list overflow ({int(self.lerr[0])} links dropped); please report")

    @property
    def lat(self) -> LatticeRef:
        return LatticeRef(self.w, self.opp, self.rho0)

    @property
    def body_state(self) -> BodyState:
        b = self.bodies
        return BodyState(b.x, b.mass, b.inertia, b.q, b.v, b.wb)

    @property
    def loads(self) -> Loads:
        return Loads(self.fext, self.imp, self.om, self.force, self.torque, self.exch)

    @property
    def runs(self) -> Runs:
        """The current column runs."""
        return Runs(self.run_off, self.rect, self.z1, self.z2)

    @property
    def runs_next(self) -> Runs:
        """The runs after the move being made (swapped with ``runs`` at its end)."""
        return Runs(self.run_off, self.rect_n, self.z1_n, self.z2_n)

    @property
    def changes(self) -> RunChanges:
        return RunChanges(self.chg_off, self.chg_node, self.chg_d, self.chg_n)

    @property
    def remap_state(self) -> RemapState:
        return RemapState(self.count, self.touched, self.acq, self.touch_list, self.unc_list, self.unc_old,
                          *self.remap_scratch)

    def _runs(self, ids, R):
        b = self.bodies
        compute_runs(ids, b.kind, b.h, b.x, b.q, self.G, R)

    def _map_all(self):
        b = self.bodies
        for d in range(3):
            if self.periodic[d]:
                b.x[:, d] = self.lo[d] + np.mod(b.x[:, d] - self.lo[d], self.dims[d])
        self._runs(self.all_ids, self.runs)
        self.rect_n[:] = self.rect
        self.z1_n[:] = self.z1
        self.z2_n[:] = self.z2
        mark_initial(self.all_ids, self.runs, self.owner, self.count, b.x, self.G, self.L)
        self._check_links()

    # -- per step ------------------------------------------------------------------------------
    def fill_fixed(self, f2):
        """Bounce-back and force of the fixed particles (``pre``)."""
        ids = self.fixed_ids
        if len(ids):
            fixed_fill(f2, self.owner, ids, self.body_state, self.loads, self.lat, self.G, self.L)
            accumulate_loads(ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)
            if not len(self.free_ids):  # the last link pass of the step
                clear_changed(self.chg, self.chg_list, self.nchg)

    def couple_free(self, f2, body_force):
        """Link sums -> implicit velocity update -> ghost fill of the free particles (``pre``)."""
        ids = self.free_ids
        if not len(ids):
            return
        self.external_loads(body_force)
        couple_free(f2, self.owner, ids, self.body_state, self.loads, self.lat, self.G, self.L, self.scratch)
        accumulate_loads(ids, self.force, self.torque, self.force_sum, self.torque_sum, self.n_sum)
        clear_changed(self.chg, self.chg_list, self.nchg)  # the last link pass of the step

    def external_loads(self, body_force):
        """``fext`` of the step: the flow's body force on each particle's volume and gravity on its
        excess mass (module docstring)."""
        b = self.bodies
        fb = np.asarray(body_force, dtype=np.float64)
        self.fext[:, :3] = self.vol[:, None] * (fb[None, :] + (b.mass / self.vol - self.rho0)[:, None] * self.gravity)

    def move(self, f2, remap=apply_changes):
        """Drift of the free particles over one step with their new velocities, then the remap
        (``post``; ``f2`` holds the post-collision populations of the new time; ``remap``:
        ``remap.apply_changes`` or ``remap_galilean.apply_changes_galilean``)."""
        ids = self.free_ids
        if not len(ids):
            return
        b = self.bodies
        drift_arrays(b.x, b.v, b.q, b.wb, b.inertia, b.fixed, 1.0)
        nxt = self.runs_next
        self._runs(ids, nxt)
        diff_runs(ids, self.runs, nxt, self.G, self.changes)
        # the drift turned wb with the body: the lab angular velocity for the surface velocities
        self.om[:] = omega_lab_arrays(b.q, b.wb)
        self.last_cover = remap(ids, self.changes, self.all_ids, nxt, b.x, b.v, self.om, self.owner, f2,
                                self.lat, self.imp, self.moved, self.G, self.L, self.remap_state, self.refill)
        self.n_fluid -= self.last_cover[0] - self.last_cover[1]
        self._check_links()
        wrap_positions(ids, b.x, self.lo, self.G, nxt, self.L)
        self.rect, self.rect_n = self.rect_n, self.rect
        self.z1, self.z1_n = self.z1_n, self.z1
        self.z2, self.z2_n = self.z2_n, self.z2

    def take_mean_force(self):
        """Mean hydrodynamic force and torque (lab) on each particle over the steps since the last
        call, (N, 3) each (the last step's values where no step ran)."""
        n = self.n_sum[:, None]
        f = np.where(n > 0, self.force_sum / np.maximum(n, 1), self.force)
        t = np.where(n > 0, self.torque_sum / np.maximum(n, 1), self.torque)
        self.force_sum[:] = 0.0
        self.torque_sum[:] = 0.0
        self.n_sum[:] = 0
        return f, t

    # -- observables and checks ----------------------------------------------------------------
    def owner_grid(self) -> np.ndarray:
        """(nx, ny, nz) int32 owner of each node: -2 wall, -1 fluid, k particle (a view)."""
        nx, ny, nz = self.dims
        return self.owner.reshape(nx, ny, self.az)[:, :, :nz]

    def covered(self) -> np.ndarray:
        """(nx, ny, nz) bool: nodes that belong to a particle."""
        return self.owner_grid() >= 0

    def fluid_mask(self) -> np.ndarray:
        """(nx, ny, nz) bool: fluid nodes (neither wall nor particle)."""
        return self.owner_grid() == FLUID

    def fluid_momentum(self, f2) -> np.ndarray:
        """(mass, px, py, pz) of the fluid nodes of ``f2`` (post-collision populations)."""
        return fluid_sums(f2, self.owner, self.e, 4)

    def fluid_mass(self, f2) -> float:
        """Mass of the fluid nodes of ``f2``: ``fluid_momentum(f2)[0]``, bit for bit."""
        return float(fluid_sums(f2, self.owner, self.e, 1)[0])

    def total_momentum(self, f2) -> np.ndarray:
        """Fluid + particle momentum (3,), with the impulses not yet applied to the particles."""
        b = self.bodies
        free = ~b.fixed
        p = self.fluid_momentum(f2)[1:].copy()
        p += (b.mass[free, None] * b.v[free]).sum(axis=0)
        p += self.imp[free, :3].sum(axis=0)
        return p

    def omega_lab(self) -> np.ndarray:
        """Lab-frame angular velocities (N, 3)."""
        return omega_lab_arrays(self.bodies.q, self.bodies.wb)

    def links(self, k: int):
        """Live links of particle ``k`` as arrays ``(fluid node, particle node, direction, lever
        arm)`` (a copy, for checks and diagnostics)."""
        xs, ss, ii, rr = [], [], [], []
        for i in range(1, len(self.w)):
            sl = slice(self.lbase[k, i], self.lbase[k, i] + self.lcnt[k, i])
            c = self.LC[sl, :3].astype(np.int64)
            xn, sn = self.LN[sl, 0].astype(np.int64), self.LN[sl, 1].astype(np.int64)
            live = (self.owner[sn] == k) & (self.owner[xn] == FLUID)
            xs.append(xn[live])
            ss.append(sn[live])
            ii.append(np.full(int(live.sum()), i))
            mid = self.origin + c[live] - 0.5 * self.e[i]
            rr.append(mid - self.bodies.x[k])
        return np.concatenate(xs), np.concatenate(ss), np.concatenate(ii), np.concatenate(rr)
