"""The least detection and impulses can cost on issue 4's case, against the sweep: a floor, not physics.

The case is ``cyl8x8_c50`` of ``benchmarks/collisions.py``: the paper's pipe at dx = 1 mm with 244
cylinders of 8 x 8 mm (50 %), after ``--warmup`` coupled steps with collisions. At that state the
script finds the contacts the collision model must treat in the next step: every pair and every
pipe-wall contact whose gap is within the contact gap (``collisions.contact_gap_dx``, one lattice
spacing: the fluid cannot hold a thinner film). Then it times two parts that any implementation of
the issue's model must do each step, each in the cheapest form we could give it:

* ``detection``: the gap of each pair within the contact gap by GJK (deliverable 1: "exact, or
  GJK/EPA"), started from the converged contact normal, i.e. the best warm start that temporal
  coherence could give, and stopped at 1e-7 of the body size, 100 times looser than lbmpipe's. It
  returns only the gap: no witness points, no contact point, no EPA. Pairs farther apart, the
  wall contacts and the broad phase are left out, since a method with temporal coherence could
  skip them for several steps.
* ``response``: Eqs. (16)-(21) by Gauss-Seidel over those contacts (pairs and pipe wall), from the
  state's velocities, until no contact approaches, with lbmpipe's sweep (``_gs_sweep``). Every
  contact's geometric terms (lever arms, ``J^-1 (l_s x p_s)``, the denominator of Eq. (19))
  are computed beforehand, outside the timing; a contact whose bodies have received no impulse
  since its last evaluation is skipped. There are no speculative contacts and no re-tests after
  the impulses.

* ``exact detection``: the same pairs by lbmpipe's exact cylinder path (``contact.cylinders._cylinder_gap``:
  closed forms for side-side and cap-rim, a one-dimensional Newton search for rim-side and
  rim-rim, each certified by the separating-axis bound), full accuracy, the gap, the normal and
  both witness points. As in the step, each pair first tries the candidate that won for it
  before (here: in an untimed first pass on the same state; in a run, the step before, where the
  closest features of nearly every touching pair are the same). Newton's method itself starts
  cold. Uncertified pairs (overlaps) are counted.

The script also counts the closest features of the GJK witness points (``features``), the mix
the exact path meets.

Two more parts that every step of the model must do, in lbmpipe's form:

* ``walls``: the pipe-wall contact (``pipe_wall_contact``) of the bodies within the contact gap
  of the wall;
* ``pair list``: the pairs within the step's margin taken from a Verlet list kept over steps
  (``listed_pairs``), the step's broad phase.

For scale it also times lbmpipe's own work on the same state:

* ``narrow phase``: ``_measure_pair`` on the same pairs (gap, normal, contact-patch point);
* ``collision step``: the whole ``resolve_collisions`` (broad and narrow phase, speculative
  contacts, impulses, projection) with its Verlet list and each pair's candidate kept from the
  call before, as in a run, on the state restored after each call.

Everything runs on one core. The contenders are interleaved over ``--repeats`` rounds, and each
is timed twice in a row: first right after an untimed sweep, as in a run, where the sweep's
~60 MB of populations have pushed the particles' data and the code out of the caches ("after a
sweep"), then again at once ("again"). Reported are medians of the time, and of the per-round
ratio to the sweep. The last line adds up the parts any implementation must do with lbmpipe's
exact detection (exact detection, response, walls, pair list): what is left of issue 4's target
of 0.25 for the whole collision step goes to everything else (the contact-patch points, the
penetration of overlapping pairs, the speculative contacts, the overlap projection).

Run: ``python benchmarks/collision_floor.py [--repeats 30] [--warmup 100]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import SweepOnly, machine_info, set_threads  # noqa: E402
from collisions import scene_dict  # noqa: E402

from lbmpipe.particles.collisions import (  # noqa: E402
    _NG,
    CollisionEffect,
    NeighbourList,
    _gs_sweep,
    _impulse_terms,
    _measure_pair,
    lab_omegas,
    resolve_collisions,
)  # noqa: E402
from lbmpipe.particles.contact.cylinders import _cylinder_gap  # noqa: E402
from lbmpipe.particles.contact.gjk import _gjk_from  # noqa: E402
from lbmpipe.particles.contact.scratch import _gjk_scratch  # noqa: E402
from lbmpipe.particles.contact import (  # noqa: E402
    bounding_radii,
    candidate_pairs,
    listed_pairs,
    neighbour_list,
    new_scratch,
    pipe_wall_contact,
)
from lbmpipe.particles.rigid import quat_to_matrices  # noqa: E402

WARM_REL_TOL = 1e-7


@njit(cache=True)
def _measure(kind, h, x, Rm, pi, pj, ps, max_gap, manifold_tol, g, nn, cc):
    """lbmpipe's narrow phase on the pairs pi, pj (body j shifted by ps): gap, normal, point."""
    ws = new_scratch()
    nrm = np.empty(3)
    c = np.empty(3)
    x2 = np.empty(3)
    for m in range(pi.shape[0]):
        _measure_pair(pi[m], pj[m], m, ps, kind, h, x, Rm, max_gap, manifold_tol, g, nn, cc, ws, nrm, c, x2)


@njit(cache=True)
def _walls(kind, h, x, Rm, Rp, cx, cy, manifold_tol, idx, g, nn, cc):
    """Pipe-wall contact (gap, normal, point) of the bodies idx."""
    nrm = np.empty(3)
    c = np.empty(3)
    for i in idx:
        g[i] = pipe_wall_contact(kind[i], h[i], x[i], Rm[i], Rp, cx, cy, manifold_tol, nrm, c)
        for k in range(3):
            nn[i, k] = nrm[k]
            cc[i, k] = c[k]


@njit(cache=True)
def _detect_warm(kind, h, x, Rm, rb, pi, pj, ps, nn, rel_tol, gap, rz, features):
    """GJK on each pair from its converged normal (the search direction is body 1 - body 2, so
    -normal), stopped at ``rel_tol`` of the size; only the gap. With ``features``, also where each
    body's witness point lies, in body-frame cylinder coordinates: rz[m, b] = (radius, |axial
    coordinate|) for body b = 0, 1."""
    ws = new_scratch()
    W, WA, WB, lam, pa, pb, v = _gjk_scratch(ws)
    x2 = np.empty(3)
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
            v[k] = -nn[m, k]
        st, d, n = _gjk_from(kind[i], h[i], x[i], Rm[i], False, kind[j], h[j], x2, Rm[j], False, rb[i] + rb[j], np.inf,
                             rel_tol, W, WA, WB, lam, pa, pb, v)
        gap[m] = d if st == 0 else 0.0
        if not features:
            continue
        for b in range(2):
            body = i if b == 0 else j
            xb = x[i] if b == 0 else x2
            w = pa if b == 0 else pb
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for k in range(3):
                dk = w[k] - xb[k]
                s0 += Rm[body, k, 0] * dk
                s1 += Rm[body, k, 1] * dk
                s2 += Rm[body, k, 2] * dk
            rz[m, b, 0] = np.sqrt(s0 * s0 + s1 * s1)
            rz[m, b, 1] = abs(s2)


@njit(cache=True)
def _detect_exact(h, x, Rm, pi, pj, ps, gap, nn, first):
    """lbmpipe's exact cylinder path on each pair: gap, normal (and witness points), trying the
    candidate ``first[m]`` first and keeping the one certified there. Returns the number of pairs
    without a certificate (gap -1: they would go to GJK/EPA)."""
    x2 = np.empty(3)
    unc = 0
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
        g, a, b, won = _cylinder_gap(h[i], x[i], Rm[i], h[j], x2, Rm[j], first[m])
        first[m] = won
        gap[m] = g
        if g < 0.0:
            unc += 1
            continue
        for k in range(3):
            nn[m, k] = (b[k] - a[k]) / g
    return unc


def _feature_counts(h1, h2, rz, tol=1e-6) -> dict:
    """Closest-feature pairs (side, cap, rim) of cylinder pairs (shape parameters h1, h2: radius,
    -, half length) from ``_detect_warm``'s witness coordinates."""
    names = []
    for m in range(rz.shape[0]):
        f = []
        for b in range(2):
            r, z = rz[m, b]
            hb = h1[m] if b == 0 else h2[m]
            on_side = abs(r - hb[0]) < tol
            on_cap = abs(z - hb[2]) < tol
            f.append("rim" if on_side and on_cap else "side" if on_side else "cap" if on_cap else "inside")
        names.append("-".join(sorted(f)))
    return {k: names.count(k) for k in sorted(set(names))}


@njit(cache=True)
def _terms(ci, cj, cs, cn, cc, x, Rm, im, iinv):
    """Eq. (19)'s geometric terms of every contact (cj < 0: wall), as lbmpipe's impulse loop keeps
    them (``_impulse_terms``)."""
    g = np.empty((ci.shape[0], _NG))
    for t in range(ci.shape[0]):
        _impulse_terms(ci[t], cj[t], cs[t, 0], cs[t, 1], cs[t, 2], cc, cc, cn, t, x, Rm, im, iinv, g, t)
    return g


@njit(cache=True)
def _respond(ci, cj, cn, g, v, wb, Rm, im, k_rest, vtol, max_sweeps):
    """lbmpipe's Gauss-Seidel sweeps of Eqs. (16)-(21) (``_gs_sweep``) over all the contacts until
    none approaches. Returns (impulses, sweeps)."""
    act = np.arange(ci.shape[0])
    ver = np.zeros(v.shape[0], dtype=np.int64)
    e1 = np.full(ci.shape[0], -1, dtype=np.int64)
    e2 = np.full(ci.shape[0], -1, dtype=np.int64)
    wl = lab_omegas(wb, Rm)
    nimp = 0
    for s in range(max_sweeps):
        applied = _gs_sweep(act, ci.shape[0], ci, cj, cn, g, v, wb, wl, Rm, im, k_rest, vtol, ver, e1, e2)
        nimp += applied
        if applied == 0:
            return nimp, s + 1
    return nimp, max_sweeps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=100)
    args = ap.parse_args(argv)

    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    set_threads(1)
    scene = Scene.model_validate(scene_dict("cyl8x8_c50"))
    sim = simulation_from_scene(scene, derive(scene))
    sim.step(args.warmup)
    coll = next(e for e in sim.effects if isinstance(e, CollisionEffect))
    b, prm = coll.system.bodies, coll.params
    dcode, Rp, cx, cy, lo, hi, periodic = coll.domain.arrays()
    gap_max = float(prm.contact_gap)
    Rm = quat_to_matrices(b.q)
    rb = bounding_radii(b.kind, b.h)
    im = np.where(b.fixed, 0.0, 1.0 / b.mass)
    iinv = np.where(b.fixed[:, None], 0.0, 1.0 / b.inertia)

    pi, pj, ps = candidate_pairs(b.x, rb, gap_max + float(prm.skin), lo, hi, periodic)
    g = np.empty(len(pi))
    nn = np.empty((len(pi), 3))
    cc = np.empty((len(pi), 3))
    _measure(b.kind, b.h, b.x, Rm, pi, pj, ps, gap_max, float(prm.manifold_tol), g, nn, cc)
    near = np.flatnonzero(g <= gap_max)
    qi, qj, qs, qn, qc = pi[near], pj[near], ps[near], nn[near], cc[near]
    rz = np.empty((len(near), 2, 2))
    _detect_warm(b.kind, b.h, b.x, Rm, rb, qi, qj, qs, qn, 1e-9, np.empty(len(near)), rz, True)
    features = _feature_counts(b.h[qi], b.h[qj], rz)
    wg = np.empty(b.n)
    wn = np.empty((b.n, 3))
    wc = np.empty((b.n, 3))
    _walls(b.kind, b.h, b.x, Rm, Rp, cx, cy, float(prm.manifold_tol), np.arange(b.n), wg, wn, wc)
    wall = np.flatnonzero(wg <= gap_max)

    ci = np.concatenate([qi, wall])
    cj = np.concatenate([qj, -np.ones(len(wall), dtype=np.int64)])
    cs = np.concatenate([qs, np.zeros((len(wall), 3))])
    cn = np.ascontiguousarray(np.concatenate([qn, wn[wall]]))
    ccat = np.ascontiguousarray(np.concatenate([qc, wc[wall]]))
    terms = _terms(ci, cj, cs, cn, ccat, b.x, Rm, im, iinv)
    speed = np.linalg.norm(b.v, axis=1) + np.linalg.norm(b.wb, axis=1) * rb
    vtol = 1e-12 * float(speed.max())  # as lbmpipe's impulse loop
    v0, w0 = b.v.copy(), b.wb.copy()

    gw = np.empty(len(near))
    sweep = SweepOnly(sim)
    cg, cn2, cc2 = np.empty(len(near)), np.empty((len(near), 3)), np.empty((len(near), 3))
    counts = {}
    saved = {f: getattr(b, f).copy() for f in ("x", "v", "q", "wb")}

    def detection():
        _detect_warm(b.kind, b.h, b.x, Rm, rb, qi, qj, qs, qn, WARM_REL_TOL, gw, rz, False)

    ge, ne = np.empty(len(near)), np.empty((len(near), 3))
    won = np.full(len(near), -1, dtype=np.int64)

    def exact():
        counts["uncertified"] = _detect_exact(b.h, b.x, Rm, qi, qj, qs, ge, ne, won)

    def response():
        v, wb = v0.copy(), w0.copy()
        t0 = time.perf_counter()
        counts["impulses"], counts["sweeps"] = _respond(ci, cj, cn, terms, v, wb, Rm, im, float(prm.restitution), vtol,
                                                        int(prm.max_sweeps))
        return time.perf_counter() - t0

    def narrow():
        _measure(b.kind, b.h, b.x, Rm, qi, qj, qs, gap_max, float(prm.manifold_tol), cg, cn2, cc2)

    nlist = NeighbourList()

    def step():
        t0 = time.perf_counter()
        st = resolve_collisions(b, coll.domain, prm, 1.0, pairs=True, nlist=nlist)
        dt = time.perf_counter() - t0
        counts["step impulses"] = st["impulses"]
        for f, a in saved.items():  # the other contenders read the state
            getattr(b, f)[:] = a
        return dt

    wg2, wn2, wc2 = np.empty(b.n), np.empty((b.n, 3)), np.empty((b.n, 3))

    def walls():
        _walls(b.kind, b.h, b.x, Rm, Rp, cx, cy, float(prm.manifold_tol), wall, wg2, wn2, wc2)

    # the pair search as the step does it: a Verlet list kept over steps, of the step's margin
    # (contact gap, speculative reach of the fastest body, skin) plus the list's skin
    margin = gap_max + (2.0 * float(speed.max()) if prm.speculative else 0.0) + float(prm.skin)
    lstart, ljs = neighbour_list(b.x, rb, margin + float(prm.list_skin), lo, hi, periodic)

    def pair_list():
        listed_pairs(b.x, rb, margin, lo, hi, periodic, lstart, ljs)

    runs = {"sweep": sweep.run, "detection": detection, "exact detection": exact, "response": response,
            "walls": walls, "pair list": pair_list, "narrow phase": narrow, "collision step": step}
    names = list(runs)
    t = {k: [] for k in names}
    cold = {k: [] for k in names}  # each right after an untimed sweep, as in a run
    for fn in runs.values():
        fn()
    for r in range(args.repeats):
        k = r % len(names)
        for name in names[k:] + names[:k]:
            if name != "sweep":
                sweep.run()
                t0 = time.perf_counter()
                inner = runs[name]()
                cold[name].append(inner if inner is not None else time.perf_counter() - t0)
            t0 = time.perf_counter()
            inner = runs[name]()
            t[name].append(inner if inner is not None else time.perf_counter() - t0)
    sep = g[near] > 0.0
    d_err = float(np.max(np.abs(gw[sep] - g[near][sep])))
    cert = ge >= 0.0
    e_err = float(np.max(np.abs(ge[cert] - g[near][cert])))

    med = statistics.median
    m = machine_info()
    print(f"{m['cpu_model']}; one core; {b.n} cylinders 8x8 mm at 50 % after {args.warmup} steps; "
          f"median of {args.repeats} interleaved rounds")
    print(f"contacts within the contact gap ({gap_max:g} dx): {len(near)} pairs (of {len(pi)} candidates), "
          f"{len(wall)} walls; response: {counts['impulses']} impulses in {counts['sweeps']} sweeps; warm GJK gap error at most {d_err:.1e} dx "
          f"({int(sep.sum())} separated pairs); lbmpipe's step: {counts['step impulses']:.0f} impulses")
    print("closest features of those pairs (GJK witness points): "
          + ", ".join(f"{k} {v}" for k, v in features.items()))
    print(f"exact detection: {len(near) - counts['uncertified']} pairs certified, {counts['uncertified']} not "
          f"({int((~sep).sum())} overlapping); gap against lbmpipe's narrow phase at most {e_err:.1e} dx")
    sw = t["sweep"]
    print(f"  {'':15s} {'again':>9s} {'':>15s} {'after a sweep':>15s}")
    print(f"  {'sweep':15s} {1e3 * med(sw):6.3f} ms")
    for name in names[1:]:
        r_hot = med([a / s for a, s in zip(t[name], sw)])
        r_cold = med([a / s for a, s in zip(cold[name], sw)])
        print(f"  {name:15s} {1e3 * med(t[name]):6.3f} ms = {r_hot:.3f}  {1e3 * med(cold[name]):6.3f} ms = {r_cold:.3f} "
              "of the sweep")

    def share(parts, tt):
        return med([sum(tt[p][r] for p in parts) / sw[r] for r in range(len(sw))])

    floor = share(("detection", "response"), t)
    floor_x = share(("exact detection", "response"), t)
    print(f"  floor (detection + response) = {floor:.2f} of the sweep; with exact detection {floor_x:.2f}; "
          "target for the whole step: 0.25")
    parts = ("exact detection", "response", "walls", "pair list")
    print(f"  exact detection + response + walls + pair list = {share(parts, t):.2f} of the sweep run again, "
          f"{share(parts, cold):.2f} right after a sweep (the whole step: {share(('collision step',), t):.2f} and "
          f"{share(('collision step',), cold):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
