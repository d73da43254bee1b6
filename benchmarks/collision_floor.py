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

* ``exact detection``: the same pairs by lbmpipe's exact cylinder path (``cylinder_gap_exact``:
  closed forms for side-side and cap-rim, a one-dimensional Newton search for rim-side and
  rim-rim, each certified by the separating-axis bound), cold: no warm start, full accuracy, and
  it returns the gap, the normal and both witness points. Uncertified pairs (overlaps) are counted.

The script also counts the closest features of the GJK witness points (``features``), the mix
the exact path meets.

For scale it also times lbmpipe's own work on the same state:

* ``narrow phase``: ``_measure_pair`` on the same pairs (gap, normal, contact-patch point);
* ``collision step``: the whole ``resolve_collisions`` (broad and narrow phase, speculative
  contacts, impulses, projection), on a copy of the bodies.

Everything runs on one core. The contenders are interleaved over ``--repeats`` rounds; reported
are medians of the time, and of the per-round ratio to the sweep. Issue 4's target for the whole
collision step is 0.25 of the sweep.

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

from lbmpipe.collisions import (  # noqa: E402
    _NG,
    CollisionEffect,
    _gs_sweep,
    _impulse_terms,
    _measure_pair,
    lab_omegas,
    resolve_collisions,
)  # noqa: E402
from lbmpipe.contact import (  # noqa: E402
    _gjk_from,
    _gjk_scratch,
    bounding_radii,
    candidate_pairs,
    cylinder_gap_exact,
    new_scratch,
    pipe_wall_contact,
)
from lbmpipe.rigid import quat_to_matrices  # noqa: E402

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
def _walls(kind, h, x, Rm, Rp, cx, cy, manifold_tol, g, nn, cc):
    nrm = np.empty(3)
    c = np.empty(3)
    for i in range(x.shape[0]):
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
def _detect_exact(h, x, Rm, pi, pj, ps, gap, nn):
    """lbmpipe's exact cylinder path on each pair: gap, normal (and witness points). Returns the
    number of pairs without a certificate (gap -1: they would go to GJK/EPA)."""
    pa = np.empty(3)
    pb = np.empty(3)
    nrm = np.empty(3)
    x2 = np.empty(3)
    unc = 0
    for m in range(pi.shape[0]):
        i = pi[m]
        j = pj[m]
        for k in range(3):
            x2[k] = x[j, k] + ps[m, k]
        gap[m] = cylinder_gap_exact(h[i], x[i], Rm[i], h[j], x2, Rm[j], nrm, pa, pb)
        if gap[m] < 0.0:
            unc += 1
        for k in range(3):
            nn[m, k] = nrm[k]
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
        _impulse_terms(ci[t], cj[t], cs[t, 0], cs[t, 1], cs[t, 2], cc, cn, t, x, Rm, im, iinv, g, t)
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
    from lbmpipe.solver import simulation_from_scene
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
    _walls(b.kind, b.h, b.x, Rm, Rp, cx, cy, float(prm.manifold_tol), wg, wn, wc)
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

    def exact():
        counts["uncertified"] = _detect_exact(b.h, b.x, Rm, qi, qj, qs, ge, ne)

    def response():
        v, wb = v0.copy(), w0.copy()
        t0 = time.perf_counter()
        counts["impulses"], counts["sweeps"] = _respond(ci, cj, cn, terms, v, wb, Rm, im, float(prm.restitution), vtol,
                                                        int(prm.max_sweeps))
        return time.perf_counter() - t0

    def narrow():
        _measure(b.kind, b.h, b.x, Rm, qi, qj, qs, gap_max, float(prm.manifold_tol), cg, cn2, cc2)

    def step():
        t0 = time.perf_counter()
        st = resolve_collisions(b, coll.domain, prm, 1.0, pairs=True)
        dt = time.perf_counter() - t0
        counts["step impulses"] = st["impulses"]
        for f, a in saved.items():  # the other contenders read the state
            getattr(b, f)[:] = a
        return dt

    runs = {"sweep": sweep.run, "detection": detection, "exact detection": exact, "response": response,
            "narrow phase": narrow, "collision step": step}
    names = list(runs)
    t = {k: [] for k in names}
    for fn in runs.values():
        fn()
    for r in range(args.repeats):
        k = r % len(names)
        for name in names[k:] + names[:k]:
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
    print(f"  {'sweep':15s} {1e3 * med(sw):7.3f} ms")
    ratio = {}
    for name in names[1:]:
        ratio[name] = med([a / s for a, s in zip(t[name], sw)])
        print(f"  {name:15s} {1e3 * med(t[name]):7.3f} ms = {ratio[name]:.2f} of the sweep")
    floor = med([(a + c) / s for a, c, s in zip(t["detection"], t["response"], sw)])
    floor_x = med([(a + c) / s for a, c, s in zip(t["exact detection"], t["response"], sw)])
    print(f"  floor (detection + response) = {floor:.2f} of the sweep; with exact detection {floor_x:.2f}; "
          "target for the whole step: 0.25")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
