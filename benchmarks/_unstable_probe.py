"""Read-only probes of a coupled simulation for ``benchmarks/unstable_cause.py`` (issue 47 item 5):
moments on the fluid nodes, the D3Q15 checkerboard mode and its staggered momentum, a node's
neighbourhood and gaps, and wrappers around a step's effects that record the staggered momentum
each effect puts in (``Watch``); plus the one diagnostic counterfactual that changes the state
between effects (``RefillRho0``), which is not an option of the solver. Lattice units; node
indices are the guard's ``(ix, iy, iz)`` of ``f``.
"""

from __future__ import annotations

import json
import math

import numpy as np

#: checkerboard amplitude (lattice units) above which a node counts as carrying the mode
CHECKER_NODE = 0.05
FLUID, WALL = -1, -2


def capture(sim):
    """A deep copy of the simulation's state (``lbmpipe.checkpoint``'s arrays and plain values)."""
    from lbmpipe import checkpoint as ckpt

    arrays, meta = ckpt.capture(sim)
    return {k: v.copy() for k, v in arrays.items()}, json.loads(json.dumps(meta))


def restore(sim, state) -> None:
    """Put a captured state into ``sim`` (built from the same scene, or from a variant whose
    effects stand in the same places); the sweep keeps its own name and floor, the simulation its
    timers (keyed by the effects' names)."""
    from lbmpipe import checkpoint as ckpt

    sweep = sim.sweep
    name, rho_min, timers = sweep.name, sweep.rho_min, sim.timers
    ckpt.restore(sim, *state)
    sweep.name, sweep.rho_min, sim.timers = name, rho_min, timers


# ------------------------------------------------------------------------------------------------
# measurements (read only)


class Probe:
    """Reads a coupled simulation's state: moments on the fluid nodes, the checkerboard mode,
    the neighbourhood of a node, particle geometry. Lattice units; node indices are the guard's
    ``(ix, iy, iz)`` of ``f``."""

    def __init__(self, sim, scene, params):
        from lbmpipe.particles.collisions import CollisionEffect
        from lbmpipe.particles.coupling import MassCorrection
        from lbmpipe.particles.placement import domain_geometry

        self.sim, self.scene, self.params = sim, scene, params
        ps = sim.particles
        self.ps = ps
        self.nx, self.ny, self.nz = (int(v) for v in ps.dims)
        self.az = ps.az
        self.e = ps.e.astype(np.float64)
        self.w = ps.w
        self.parity = (np.indices((self.nx, self.ny, self.nz)).sum(axis=0) % 2 * 2 - 1).astype(np.float64)
        self.radius = float(domain_geometry(scene, params)[3])
        self.collide = sim.effect(CollisionEffect)
        self.mass_corr = sim.effect(MassCorrection)
        self.control = next((e for e in sim.effects if hasattr(e, "f_ref")), None)

    # -- fields
    def owner(self) -> np.ndarray:
        return self.ps.owner.reshape(self.nx, self.ny, self.az)[:, :, :self.nz]

    def moments(self, f) -> tuple[np.ndarray, np.ndarray]:
        """(rho, j) of the post-collision populations ``f`` (q, nx, ny, alloc_z): (nx, ny, nz), (3, ...)."""
        g = f[:, :, :, :self.nz]
        return g.sum(axis=0), np.einsum("iabc,id->dabc", g, self.e)

    def staggered(self, j, fluid, step: int) -> np.ndarray:
        """``P = sum (-1)^(x+y+z+t) j`` over the fluid nodes (3,)."""
        s = self.parity * (1.0 if step % 2 == 0 else -1.0) * fluid
        return np.einsum("dabc,abc->d", j, s)

    def checker(self, j, fluid) -> tuple[np.ndarray, np.ndarray]:
        """Checkerboard amplitude |c| per node (0 where the node or an axis neighbour is not fluid)
        and the vector field c (3, ...)."""
        ok = fluid.copy()
        acc = np.zeros_like(j)
        for ax in range(3):
            for s in (-1, 1):
                ok &= np.roll(fluid, s, axis=ax)
                acc += np.roll(j, s, axis=ax + 1)
        c = 0.5 * (j - acc / 6.0)
        return np.where(ok, np.sqrt((c * c).sum(axis=0)), 0.0), c

    def state(self, f=None, step=None) -> dict:
        """The global figures of the state now: P, the checkerboard's peak and extent."""
        f = self.sim.f if f is None else f
        step = self.sim.step_count if step is None else step
        fluid = self.owner() == FLUID
        rho, j = self.moments(f)
        amp, _ = self.checker(j, fluid)
        i = np.unravel_index(int(np.argmax(amp)), amp.shape)
        return {"P": self.staggered(j, fluid, step), "checker_max": float(amp[i]), "checker_node": tuple(int(v) for v in i),
                "checker_nodes": int(np.count_nonzero(amp > CHECKER_NODE)), "rho": rho, "j": j, "amp": amp,
                "fluid": fluid}

    # -- a node and its neighbourhood
    def wrap(self, a, b, z):
        return a, b, z % self.nz  # x, y: walls (never wrapped in a pipe); z periodic

    def neighbours(self, node) -> list[int]:
        o = self.owner()
        a, b, z = node
        out = []
        for ex, ey, ez in self.ps.e[1:]:
            i, k, m = self.wrap(a + ex, b + ey, z + ez)
            out.append(int(o[i, k, m]) if 0 <= i < self.nx and 0 <= k < self.ny else WALL)
        return out

    def gap_lines(self, node, reach: int = 12) -> dict:
        """Along each of the 7 lattice lines through ``node``: the fluid run between the first
        solid each way (its length in nodes, and what bounds it); the thinnest line."""
        o = self.owner()
        best = None
        lines = []
        for i in range(1, 15, 2):
            e = self.ps.e[i]
            ends = []
            for sgn in (1, -1):
                d = 1
                hit = None
                while d <= reach:
                    a, b, z = self.wrap(node[0] + sgn * d * e[0], node[1] + sgn * d * e[1], node[2] + sgn * d * e[2])
                    if not (0 <= a < self.nx and 0 <= b < self.ny) or o[a, b, z] != FLUID:
                        hit = WALL if not (0 <= a < self.nx and 0 <= b < self.ny) else int(o[a, b, z])
                        break
                    d += 1
                ends.append((d, hit))
            n_fluid = ends[0][0] + ends[1][0] - 1
            rec = {"dir": [int(v) for v in e], "fluid_nodes": int(n_fluid),
                   "bounds": [ends[0][1], ends[1][1]]}
            lines.append(rec)
            if ends[0][1] is not None and ends[1][1] is not None and (best is None or n_fluid < best["fluid_nodes"]):
                best = rec
        return {"thinnest": best, "lines": lines}

    def near_particles(self, node, reach: int = 3) -> list[int]:
        o = self.owner()
        a, b, z = node
        ids = set()
        for da in range(-reach, reach + 1):
            for db in range(-reach, reach + 1):
                for dz in range(-reach, reach + 1):
                    i, k, m = self.wrap(a + da, b + db, z + dz)
                    if 0 <= i < self.nx and 0 <= k < self.ny and o[i, k, m] >= 0:
                        ids.add(int(o[i, k, m]))
        return sorted(ids)

    def position(self, node) -> np.ndarray:
        return self.ps.origin + np.asarray(node, dtype=np.float64)

    def surface_velocity(self, k: int, node) -> np.ndarray:
        """``u_b = U + Omega x r`` of particle ``k`` at the node's position (minimum image in z)."""
        b = self.ps.bodies
        r = self.position(node) - b.x[k]
        r[2] -= self.nz * math.floor(r[2] / self.nz + 0.5)
        return b.v[k] + np.cross(self.ps.om[k], r)

    def gaps(self, ids) -> dict:
        """Signed gaps (lattice spacings) between the particles ``ids`` (nearest periodic image
        along z) and from each to the pipe wall."""
        from lbmpipe.particles.contact import contact_pair, contact_pipe

        b = self.ps.bodies
        out = {"pairs": {}, "wall": {}}
        for n, k in enumerate(ids):
            if self.radius > 0:
                out["wall"][str(k)] = round(contact_pipe(b.kind[k], b.h[k], b.x[k], b.q[k], self.radius)[0], 4)
            for j in ids[n + 1:]:
                dz = b.x[j, 2] - b.x[k, 2]
                shift = -self.nz * math.floor(dz / self.nz + 0.5)
                g = contact_pair(b.kind[k], b.h[k], b.x[k], b.q[k], b.kind[j], b.h[j], b.x[j] + [0, 0, shift], b.q[j])[0]
                out["pairs"][f"{k}-{j}"] = round(g, 4)
        return out

    def nearest_surface(self, node) -> dict:
        """Distance from the node to the nearest particle node and to the pipe wall (lattice)."""
        o = self.owner()
        idx = np.argwhere(o >= 0)
        p = np.asarray(node)
        d = idx - p
        d[:, 2] -= self.nz * np.floor(d[:, 2] / self.nz + 0.5).astype(int)
        dist = np.sqrt((d * d).sum(axis=1))
        m = int(np.argmin(dist)) if len(dist) else -1
        x = self.position(node)
        return {"particle": int(o[tuple(idx[m])]) if m >= 0 else None,
                "particle_distance": round(float(dist[m]), 3) if m >= 0 else None,
                "wall_distance": round(self.radius - math.hypot(x[0], x[1]), 3) if self.radius > 0 else None}

    # -- the particles and the step's other effects
    def particles(self) -> dict:
        b = self.ps.bodies
        speed = np.linalg.norm(b.v, axis=1)
        free = ~b.fixed
        return {"moving": int(np.count_nonzero(speed[free] > 0.0)), "free": int(free.sum()),
                "speed_max": float(speed.max()), "vz_mean": float(b.v[free, 2].mean()),
                "spin_max": float(np.linalg.norm(self.ps.om, axis=1).max())}

    def tallies(self) -> dict:
        sweep = self.sim.sweep
        t = self.collide.totals if self.collide is not None else {}
        return {"floor_mass": float(sweep.tally[0]), "floor_nodes": float(sweep.tally[1]),
                "mass_corr": float(self.mass_corr.added) if self.mass_corr is not None else 0.0,
                "locked": int(t.get("locked_bodies", 0)), "unresolved": int(t.get("unresolved", 0)),
                "force_ratio": float(self.sim.force[2] / self.control.f_ref) if self.control is not None else float("nan")}

    def ladd_injection(self, step: int) -> np.ndarray:
        """(n, 3): the staggered momentum Ladd's moving-wall term of Eq. (8) puts into the fluid in
        the step from ``step`` (with the velocities the coupling has just set): per live link,
        ``(-1)^(p(x)+step+1) 6 w_i rho0 (e_i . u_b) e_i`` at the fluid node x."""
        ps = self.ps
        b = ps.bodies
        out = np.zeros((ps.n, 3))
        sgn = 1.0 if (step + 1) % 2 == 0 else -1.0
        for k in ps.free_ids:
            xn, _, ii, r = ps.links(int(k))
            if not len(xn):
                continue
            a = xn // (self.ny * self.az)
            bb = (xn // self.az) % self.ny
            z = xn % self.az
            par = self.parity[a, bb, z] * sgn
            ub = b.v[k][None, :] + np.cross(ps.om[k][None, :], r)
            e = self.e[ii]
            c = 6.0 * ps.w[ii] * ps.rho0 * np.einsum("ld,ld->l", e, ub) * par
            out[k] = (c[:, None] * e).sum(axis=0)
        return out


class Watch:
    """Wrappers around the step's effects that only look: the owner map and the moments around
    the sweep and the remap (the staggered-momentum budget per effect), the failing node's pulled
    density before the sweep (the density floor's test)."""

    def __init__(self, probe: Probe, node=None):
        self.p = probe
        self.node = node
        self.rec: dict = {}
        sim = probe.sim
        self._orig = list(sim.effects)
        sim.effects = [_Look(e, self) for e in sim.effects]

    def remove(self):
        self.p.sim.effects = self._orig

    def before(self, e, sim):
        if e.phase == "fluid":
            t = sim.step_count
            self.rec["ladd"] = self.p.ladd_injection(t)
            fluid = self.p.owner() == FLUID
            _, j = self.p.moments(sim.f)
            self.rec["P0"] = self.p.staggered(j, fluid, t)
            if self.node is not None:
                self.rec["pulled_rho"] = self._pulled(sim.f, self.node)
        elif e.__class__.__name__ == "ParticleMotion":
            self.rec["own_before"] = self.p.owner().copy()
            rho, j = self.p.moments(sim.f_next)
            self.rec["j_before"] = j
            self.rec["P_sweep"] = self.p.staggered(j, self.rec["own_before"] == FLUID, sim.step_count + 1)

    def after(self, e, sim):
        if e.__class__.__name__ == "ParticleMotion":
            t1 = sim.step_count + 1
            ob, oa = self.rec.pop("own_before"), self.p.owner()
            jb = self.rec.pop("j_before")
            rho, ja = self.p.moments(sim.f_next)
            s = self.p.parity * (1.0 if t1 % 2 == 0 else -1.0)
            cov = (ob == FLUID) & (oa >= 0)
            unc = (ob >= 0) & (oa == FLUID)
            n = self.p.ps.n
            # per particle: staggered momentum of the covered nodes (taken away), of the uncovered
            # nodes (rho u_b put in), and the part of the latter from the refill density's excess
            per = np.zeros((n, 3, 3))
            u = np.where(unc, ja / np.maximum(rho, 1e-12), 0.0)
            for k in np.unique(oa[cov]):
                m = cov & (oa == k)
                per[k, 0] = -np.einsum("dabc,abc->d", jb, s * m)
            for k in np.unique(ob[unc]):
                m = unc & (ob == k)
                per[k, 1] = np.einsum("dabc,abc->d", ja, s * m)
                per[k, 2] = np.einsum("dabc,abc->d", u * (rho - 1.0), s * m)
            self.rec["remap"] = per
            self.rec["covered"], self.rec["uncovered"] = int(cov.sum()), int(unc.sum())
            self.rec["P_remap"] = self.p.staggered(ja, oa == FLUID, t1)

    def _pulled(self, f, node) -> float:
        """Density node ``node`` receives by streaming (before the collision and the floor)."""
        a, b, z = node
        tot = 0.0
        for i, (ex, ey, ez) in enumerate(self.p.ps.e):
            tot += f[i, a - ex, b - ey, (z - ez) % self.p.nz]
        return float(tot)


class _Look:
    def __init__(self, e, watch: Watch):
        self.e, self.watch = e, watch
        self.name, self.phase = e.name, e.phase
        self.record_key = getattr(e, "record_key", None)

    def record(self):
        return self.e.record()

    def __call__(self, sim):
        self.watch.before(self.e, sim)
        self.e(sim)
        self.watch.after(self.e, sim)

    def __getattr__(self, name):  # everything else (tally, rho_min, ...) from the wrapped effect
        return getattr(self.e, name)




class RefillRho0:
    """Diagnostic counterfactual around the motion effect (``ParticleMotion``): every node the
    remap has just uncovered gets the equilibrium at ``rho0 = 1`` and its surface velocity
    ``u_b`` instead of the paper's neighbours' density, and the particle's pending impulse is
    corrected so that it pays ``rho0 u_b`` (momentum stays conserved). The mass correction that
    follows restores the mean density as usual. Not a solver option: evidence for the mechanism."""

    def __init__(self, motion, probe: "Probe"):
        from lbmpipe.fluid.boundaries import plane_buffer

        self.e_ = motion
        self.name, self.phase = motion.name, motion.phase
        self.record_key = getattr(motion, "record_key", None)
        self.p = probe
        self._plane = plane_buffer
        self.nodes = 0

    def record(self):
        return self.e_.record()

    def __getattr__(self, name):
        return getattr(self.e_, name)

    def __call__(self, sim):
        ps = self.p.ps
        before = ps.owner.copy()
        self.e_(sim)
        unc = np.flatnonzero((before >= 0) & (ps.owner == FLUID))
        if not len(unc):
            return
        f2 = self._plane(sim.f_next)
        e = self.p.e
        fv = f2[:, unc]
        rho = fv.sum(axis=0)
        u = (e.T @ fv) / rho
        eu = e @ u
        usq = 1.5 * (u * u).sum(axis=0)
        f2[:, unc] = ps.w[:, None] * (1.0 + 3.0 * eu + 4.5 * eu * eu - usq[None, :])
        k = before[unc]
        ny, az = self.p.ny, self.p.az
        pos = ps.origin[None, :] + np.stack([unc // (ny * az), (unc // az) % ny, unc % az], axis=1)
        r = pos - ps.bodies.x[k]
        r[:, 2] -= self.p.nz * np.floor(r[:, 2] / self.p.nz + 0.5)
        dj = ((rho - 1.0)[None, :] * u).T  # what the particle paid too much
        np.add.at(ps.imp[:, :3], k, dj)
        np.add.at(ps.imp[:, 3:], k, np.cross(r, dj))
        self.nodes += len(unc)


def checker_damping(e, w, opp, omega: float, omega_minus: float, u=(0.0, 0.0, 0.1), dk: float = 0.0) -> float:
    """Largest |eigenvalue| of one linearised step (collision, then streaming) of a uniform flow
    ``u`` at the wavevector ``(pi, pi, pi - dk)``: 1 means the checkerboard mode is not damped at
    all. Two-relaxation-time collision (``omega`` on the symmetric, ``omega_minus`` on the
    antisymmetric part; BGK when equal) about the second-order equilibrium Eq. (3)."""
    e = np.asarray(e, dtype=np.float64)
    q = len(w)
    u = np.asarray(u, dtype=np.float64)

    def feq(f):
        rho = f.sum()
        v = e.T @ f / rho
        eu = e @ v
        return w * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - 1.5 * v @ v)

    eu = e @ u
    f0 = w * (1.0 + 3.0 * eu + 4.5 * eu * eu - 1.5 * u @ u)
    jac = np.zeros((q, q))
    h = 1e-7
    for k in range(q):
        d = np.zeros(q)
        d[k] = h
        jac[:, k] = (feq(f0 + d) - feq(f0 - d)) / (2 * h)
    eye = np.eye(q)
    sym = 0.5 * (eye + eye[:, opp])
    neq = eye - jac
    coll = eye - omega * sym @ neq - omega_minus * (eye - sym) @ neq
    k = np.array([np.pi, np.pi, np.pi - dk])
    stream = np.diag(np.exp(-1j * (e @ k)))
    return float(np.abs(np.linalg.eigvals(stream @ coll)).max())
