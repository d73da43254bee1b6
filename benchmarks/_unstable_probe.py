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
    arrays, meta = state
    ckpt.restore(sim, arrays, json.loads(json.dumps(meta)))  # a copy: the effects' dicts change as they run
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
        # the method's particle components: the link rule of the coupling (``surface.RULES``; the
        # paper's Ladd coupling is half-way), the Galilean exchange, the lubrication effect
        from lbmpipe.particles.coupling.surface import HALF_WAY, RULES

        coupling = next((e for e in sim.effects if hasattr(e, "rule") and hasattr(e, "galilean")), None)
        self.rule = int(coupling.rule) if coupling is not None else HALF_WAY
        self.rule_name = {v: k for k, v in RULES.items()}[self.rule]
        self.galilean = bool(coupling.galilean) if coupling is not None else False
        self.lub = next((e for e in sim.effects if e.__class__.__name__ == "LubricationEffect"), None)

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
                "force_ratio": float(self.sim.force[2] / self.control.f_ref) if self.control is not None else float("nan"),
                # this step's: bodies the jam rule locked; the largest lubrication force on a body
                # (lattice units) and the films with a force (NaN: no lubrication in the step)
                "q_ratio": float(self.control.q / self.control.q_target) if self.control is not None else float("nan"),
                "locked_now": int(self.collide.last.get("locked_bodies", 0)) if self.collide is not None else 0,
                "lub_force_max": float(np.linalg.norm(self.lub.force, axis=1).max()) if self.lub is not None else float("nan"),
                "lub_films": int(self.lub.counts.sum()) if self.lub is not None else -1}

    def lub_force(self, ids) -> dict:
        """|lubrication force| of the last step on the bodies ``ids`` (empty without lubrication)."""
        if self.lub is None:
            return {}
        return {str(k): float(np.linalg.norm(self.lub.force[k])) for k in ids}

    def link_terms(self, f, step: int, node=None) -> dict:
        """What the ghost slots of the free particles' live links put into the fluid in the step
        from ``step`` (read before the sweep, after the coupling wrote them), beyond half-way
        bounce-back off a wall at rest (which returns ``f*_i(x)``): per link the fluid node ``x``
        pulls ``ghost = f[opp(i), s]`` (``s = x + e_i``), so its momentum gains ``-e_i (ghost -
        f*_i(x))``. Split by the link rule (``surface.link_base``): the moving-wall term ``c 6 w_i
        rho0 (e_i . u_w) e_i`` (half-way, Ladd's Eq. (8): ``c = 1``, ``u_w`` at the link's midpoint;
        CLI/Bouzidi: ``c`` from the fraction ``q`` of the link in the fluid and whether ``x - e_i``
        is fluid, ``u_w`` at ``x + q e_i``), and the rest (the interpolation ``G - f*_i(x)`` and
        its mass excess ``- w_i delta``; zero for half-way links). Returns per particle the
        staggered momentum (``(-1)^(p(x)+step+1)``) of each part, ``moving`` and ``interp``
        (n, 3); with ``node``, the mass each part brings to that node and its links (direction,
        particle, q, c, whether ``x - e_i`` is fluid). The Galilean exchange changes only what the
        particle is given, not the ghosts: it has no term here."""
        from lbmpipe.fluid.boundaries import plane_buffer
        from lbmpipe.particles.coupling.surface import CLI, HALF_WAY
        from lbmpipe.particles.rigid import quat_to_matrix

        ps = self.ps
        b = ps.bodies
        f2 = plane_buffer(f)
        own = ps.owner
        moving = np.zeros((ps.n, 3))
        interp = np.zeros((ps.n, 3))
        sgn = 1.0 if (step + 1) % 2 == 0 else -1.0
        flat = None if node is None else (node[0] * self.ny + node[1]) * self.az + node[2]
        out = {"moving": moving, "interp": interp, "node_mass_moving": 0.0, "node_mass_interp": 0.0, "node_links": []}
        for k in ps.free_ids:
            k = int(k)
            xn, sn, ii, rmid = ps.links(k)
            if not len(xn):
                continue
            e = self.e[ii]
            rx = rmid - 0.5 * e  # the fluid node about the centre (unwrapped, as the kernels)
            if self.rule == HALF_WAY:
                q = np.full(len(ii), 0.5)
                c = np.ones(len(ii))
                behind = np.ones(len(ii), dtype=bool)
            else:
                q = _fractions(int(b.kind[k]), b.h[k].astype(np.float64), quat_to_matrix(b.q[k]), rx, ii, ps.e)
                a, bb, z = xn // (self.ny * self.az), (xn // self.az) % self.ny, xn % self.az
                ex, ey, ez = ps.e[ii, 0], ps.e[ii, 1], ps.e[ii, 2]
                a2, b2, z2 = a - ex, bb - ey, (z - ez) % self.nz
                inside = (a2 >= 0) & (a2 < self.nx) & (b2 >= 0) & (b2 < self.ny)
                idx = (np.clip(a2, 0, self.nx - 1) * self.ny + np.clip(b2, 0, self.ny - 1)) * self.az + z2
                behind = inside & (own[idx] == FLUID)
                c = np.where(q < 0.5, 1.0, 0.5 / np.maximum(q, 1e-12))
                if self.rule == CLI:
                    c = np.where(behind, 2.0 / (1.0 + 2.0 * q), c)
            rw = rx + q[:, None] * e
            uw = b.v[k][None, :] + np.cross(ps.om[k][None, :], rw)
            mw = c * 6.0 * ps.w[ii] * ps.rho0 * np.einsum("ld,ld->l", e, uw)  # the ghost carries -mw
            extra = f2[ps.opp[ii], sn] - f2[ii, xn]  # ghost - f*_i(x)
            par = self.parity.reshape(-1)[_plain_index(xn, self.ny, self.az, self.nz)] * sgn
            moving[k] = ((mw * par)[:, None] * e).sum(axis=0)
            interp[k] = ((-(extra + mw) * par)[:, None] * e).sum(axis=0)
            if flat is not None:
                at = xn == flat
                if at.any():
                    out["node_mass_moving"] += float(-mw[at].sum())
                    out["node_mass_interp"] += float((extra + mw)[at].sum())
                    out["node_links"] += [{"dir": [int(v) for v in ps.e[i]], "particle": k, "q": round(float(qq), 4),
                                           "c": round(float(cc), 4), "behind_fluid": bool(bh)}
                                          for i, qq, cc, bh in zip(ii[at], q[at], c[at], behind[at])]
        return out


def _plain_index(xn, ny, az, nz):
    """Flat index of the (nx, ny, nz) arrays from the flat node index of ``f`` (alloc z ``az``)."""
    a, rest = np.divmod(xn, ny * az)
    b, z = np.divmod(rest, az)
    return (a * ny + b) * nz + z


def _fractions(kind, h, A, r, ii, e):
    """``surface.link_fraction`` of each link (fluid node about the centre ``r``, direction ``ii``):
    the fraction of the link in the fluid, as the CLI/Bouzidi kernels compute it."""
    global _fractions_nb
    if _fractions_nb is None:
        from numba import njit

        from lbmpipe.particles.coupling.surface import link_fraction

        def loop(kind, h, A, r, ii, e):
            out = np.empty(len(ii))
            for n in range(len(ii)):
                i = ii[n]
                out[n] = link_fraction(kind, h, A, r[n, 0], r[n, 1], r[n, 2], e[i, 0], e[i, 1], e[i, 2])
            return out

        _fractions_nb = njit(loop)
    return _fractions_nb(kind, h, A, np.ascontiguousarray(r), np.ascontiguousarray(ii), np.ascontiguousarray(e))


_fractions_nb = None


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
            lt = self.p.link_terms(sim.f, t, self.node)
            self.rec["ladd"] = lt["moving"]  # the moving-wall term (the method's link rule)
            self.rec["interp"] = lt["interp"]
            self.rec["node_mass_moving"], self.rec["node_mass_interp"] = lt["node_mass_moving"], lt["node_mass_interp"]
            self.rec["node_links"] = lt["node_links"]
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


class _Wrapped:
    """Base of the counterfactuals around one effect: the wrapped effect's name, phase, record
    and attributes (the simulation's timers and summary see the same effect)."""

    def __init__(self, effect):
        self.e_ = effect
        self.name, self.phase = effect.name, effect.phase
        self.record_key = getattr(effect, "record_key", None)

    def record(self):
        return self.e_.record()

    def __getattr__(self, name):
        return getattr(self.e_, name)


class ForceCap(_Wrapped):
    """Diagnostic counterfactual around the flow-rate controller (``FlowRateControl``): after it
    sets the driving force, the force (and the controller's integral, so that it does not wind
    up) is held at most ``cap`` times its reference ``f_ref`` (Hagen-Poiseuille's force of the
    target flow rate). Below the cap the controller acts as in the run; at the cap the flow rate
    falls instead. Not a solver option: evidence for the mechanism."""

    def __init__(self, control, cap: float):
        super().__init__(control)
        self.cap = float(cap)
        self.capped_steps = 0

    def __call__(self, sim):
        ctl = self.e_
        ctl(sim)
        lim = self.cap * ctl.f_ref
        if sim.force[2] > lim:
            sim.force[2] = lim
            ctl.f_int = min(ctl.f_int, lim)
            self.capped_steps += 1


class LubricationOff(_Wrapped):
    """Diagnostic counterfactual: the lubrication effect does nothing (no film impulses; its force
    reads zero). Switched on a state of a run with lubrication, the effects keep their places (a
    scene without lubrication would have another list). Not a solver option."""

    def __call__(self, sim):
        self.e_.force[:] = 0.0
        self.e_.torque[:] = 0.0
        self.e_.counts[:] = 0


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


def shown_path(path) -> str:
    """``path`` as it is recorded in committed evidence: from its ``results/`` part on (a checkpoint of
    a run made in another checkout), else its name: never a machine's local directory."""
    s = str(path)
    i = s.find("results/")
    return s[i:] if i >= 0 else s.rsplit("/", 1)[-1]
