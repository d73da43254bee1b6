"""A sphere approaching a plane wall: the force against Brenner's (1961) exact result, without and
with the lubrication correction (``numerics.lubrication``; issue 44, item 4).

The sphere (radius ``a`` lattice spacings) moves towards the wall z = 0 of a box (periodic in x
and y, walls at both z faces) at the small constant speed ``U``. Stokes flow is quasi-static: the
force on the sphere at gap ``h`` is the steady force on a sphere held at that gap whose surface
moves at ``U``. So each gap is its own steady problem: the scene's sphere is given a huge mass
(density ratio 10^6), its velocity is reset to ``U`` after every step, its nodes never move
(no drift, no remap: Ladd's fill with the sphere's velocity on a fixed node set conserves mass,
since every lattice line enters and leaves it once, but for the links the wall cuts off: the
mass correction stays), and the run goes on until the force is steady. The force of a staircase
sphere depends on where its centre sits between the nodes: each gap is the mean over
``--offsets`` lateral positions (the spread column is their standard deviation). The
hydrodynamic force is the coupling's (``ParticleSystem.force``); the lubrication effect (on, in the
same run) adds its own force, which the sphere's held velocity keeps out of the fluid.

    lambda = F_z / (6 pi mu a U)   against   brenner_sphere_plane(h / a).

The box is finite: its walls and periodic images add drag (a Stokeslet's images); ``--box`` and
``--height`` set it, and the rows above the cutoff show what it adds where lubrication is off.

``--particle-boundary`` and ``--trt-magic`` (TRT instead of BGK) run another particle surface (the
accurate method's: ``--particle-boundary cli --trt-magic 0.1875``).

Run (the README's table): ``PYTHONPATH=. python benchmarks/lubrication.py``; the test
(``tests/test_lubrication.py``) runs a smaller box through ``mean_approach_force``. With
``--cost [CASE ...]`` it times the effect on committed credible runs of the paper's pipe instead.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from lbmpipe.assemble import simulation_from_scene
from lbmpipe.effect import Effect
from lbmpipe.particles.coupling import ParticleMotion
from lbmpipe.particles.lubrication import LubricationEffect
from lbmpipe.particles.lubrication.reference import brenner_sphere_plane
from lbmpipe.particles.lubrication_params import Lubrication
from lbmpipe.scene import Scene
from lbmpipe.units import derive


class HoldVelocity(Effect):
    """The sphere's velocity reset to ``u`` after each step (the motion is prescribed)."""

    name = "hold the sphere's velocity"
    phase = "post"

    def __init__(self, bodies, u):
        self.bodies = bodies
        self.u = np.asarray(u, dtype=np.float64)

    def __call__(self, sim) -> None:
        self.bodies.v[0] = self.u
        self.bodies.wb[0] = 0.0


def approach_scene(a: float, gap: float, box: int, height: int, U: float, tau: float, cutoff: float | None,
                   offset=(0.0, 0.0), numerics: dict | None = None) -> Scene:
    """The scene of one gap: dx = 1 mm, dt = 1 ms, so lattice and SI numbers coincide up to 10^-3
    (lengths in mm, speeds in m/s per lattice unit, viscosity nu_lu 1e-3 m^2/s). ``numerics``: more
    scene numerics (e.g. ``particle_boundary: cli``, ``collision: trt``, ``trt_magic``)."""
    nu_lu = (tau - 0.5) / 3.0
    return Scene.model_validate({
        "name": "sphere_approaching_wall",
        "domain": {"kind": "box", "size_mm": [float(box), float(box), float(height)], "walls": {"z": "wall"}},
        "fluid": {"viscosity_m2_s": nu_lu * 1e-3},
        "numerics": {**(numerics or {}),
                     "lubrication": {"enabled": True} | ({} if cutoff is None else {"cutoff_dx": cutoff})},
        "run": {"duration_s": 10.0, "spinup_s": 1.0, "sample_interval_s": 1.0},
        "outputs": {"profile": False, "flow_rate": False},
        "particles": {"bodies": [{"shape": "sphere", "diameter_mm": 2.0 * a,
                                  "position_mm": [box / 2.0 + offset[0], box / 2.0 + offset[1], a + gap],
                                  "velocity_m_s": [0.0, 0.0, -U], "density_ratio": 1e6}],
                      "collisions": {"enabled": False}},
    })


def approach_force(a: float, gap: float, box: int, height: int, U: float = 1e-3, tau: float = 1.0,
                   cutoff: float | None = None, tol: float = 1e-4, max_steps: int = 20000, offset=(0.0, 0.0),
                   numerics: dict | None = None) -> dict:
    """Steady drag factors of the held sphere at ``gap`` (lattice spacings), its centre moved by
    ``offset`` (x, y) from the box's middle: ``without`` (the coupling's force alone) and ``with``
    (plus the lubrication effect's), and Brenner's. Steady: at least 8 decay times of the box's
    slowest mode, ``1 / (nu ((2 pi / box)^2 + (pi / height)^2))``, then until the force changes by
    less than ``tol`` (relative) over 400 steps."""
    scene = approach_scene(a, gap, box, height, U, tau, cutoff, offset, numerics)
    params = derive(scene)
    sim = simulation_from_scene(scene, params, guard=False)
    system = sim.particles
    # the node set stays put: no drift and no remap. The mass correction stays: links the wall
    # cuts off leave the held sphere's mass flux unbalanced, and the mean density would drift.
    sim.effects = [e for e in sim.effects if not isinstance(e, ParticleMotion)]
    sim.effects.append(HoldVelocity(system.bodies, (0.0, 0.0, -U)))
    sim.timers = {e.name: 0.0 for e in sim.effects}
    lub = next(e for e in sim.effects if isinstance(e, LubricationEffect))
    mu = params.nu_lu * system.rho0
    scale = 6.0 * math.pi * mu * a * U
    t_decay = 1.0 / (params.nu_lu * ((2.0 * math.pi / box) ** 2 + (math.pi / height) ** 2))
    steps = 400 * max(1, math.ceil(8.0 * t_decay / 400))
    sim.step(steps)
    f = float(system.force[0, 2])
    while steps < max_steps:
        sim.step(400)
        steps += 400
        prev, f = f, float(system.force[0, 2])
        if abs(f - prev) < tol * abs(f):
            break
    return {"gap": gap, "brenner": brenner_sphere_plane(gap / a), "without": f / scale,
            "with": (f + float(lub.force[0, 2])) / scale, "steps": steps}


def lateral_offsets(n: int, seed: int = 0) -> np.ndarray:
    """``n`` offsets of the sphere's centre in the lattice cell (x, y), seeded: a staircase
    sphere's force depends on where its centre sits between the nodes; their mean removes most
    of that scatter (as for the drag in tests/test_coupling.py)."""
    return np.random.default_rng(seed).random((n, 2))


def mean_approach_force(a, gap, box, height, offsets, **kw) -> dict:
    """``approach_force`` averaged over the lateral ``offsets``; ``spread``: the standard
    deviation of ``without`` over them."""
    runs = [approach_force(a, gap, box, height, offset=tuple(o), **kw) for o in offsets]
    out = {k: float(np.mean([r[k] for r in runs])) for k in ("brenner", "without", "with")}
    out.update(gap=gap, spread=float(np.std([r["without"] for r in runs])), steps=max(r["steps"] for r in runs))
    return out


COST_CASES = ["cube8_c30_re9.4", "cyl8x16_c50_re9.4"]


def cost(cases, seed: int = 1, steps: int = 50, warmup: int = 50, repeats: int = 3) -> None:
    """ms per step of the lubrication effect against the sweep and the whole step, on the
    committed credible scenes (their packings), built as a run builds them: ``paper`` (as
    committed), ``lubrication`` (``numerics.lubrication.enabled``) and ``lubrication, gap 0.1``
    (also ``particles.collisions.contact_gap_dx: 0.1``, so that films thinner than the paper's
    contact gap of one spacing occur). Rounds interleave the contenders; medians over them."""
    from pathlib import Path

    from lbmpipe.scene import load_scene

    root = Path(__file__).resolve().parents[1]
    print("| case | variant | sweep ms | lubrication ms | collisions ms | step ms | step / paper | films a step |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for case in cases:
        base = load_scene(root / "results" / "credible" / "cases" / case / f"seed{seed}" / "scene.yaml")
        data = base.model_dump(mode="json", exclude_unset=True)
        variants = {"paper": data}
        lub = dict(data, numerics={**data["numerics"], "lubrication": {"enabled": True}})
        variants["lubrication"] = lub
        thin = dict(lub, particles={**lub["particles"], "collisions": {**lub["particles"].get("collisions", {}),
                                                                      "contact_gap_dx": 0.1}})
        variants["lubrication, gap 0.1"] = thin
        sims = {}
        for name, d in variants.items():
            sc = Scene.model_validate(d)
            sim = simulation_from_scene(sc, derive(sc))
            sim.step(warmup)
            sims[name] = sim
        rows = {name: [] for name in sims}
        for r in range(repeats):
            order = list(sims) if r % 2 == 0 else list(sims)[::-1]
            for name in order:
                sim = sims[name]
                before = dict(sim.timers)
                t0 = time.perf_counter()
                sim.step(steps)
                wall = time.perf_counter() - t0
                eff = {k: 1e3 * (v - before[k]) / steps for k, v in sim.timers.items()}
                rows[name].append((eff, 1e3 * wall / steps))
        med = {}
        for name, rs in rows.items():
            def part(prefix):
                return float(np.median([sum(v for k, v in e.items() if k.startswith(prefix)) for e, _ in rs]))
            med[name] = (part("stream+collide"), part("particles: lubrication"), part("collisions"),
                         float(np.median([w for _, w in rs])))
        for name, (sw, lu, co, st) in med.items():
            lubs = [e for e in sims[name].effects if isinstance(e, LubricationEffect)]
            films = ""
            if lubs:
                t = lubs[0].totals
                films = f"{(t['pair_contacts'] + t['wall_contacts']) / max(t['calls'], 1):.1f}"
            print(f"| {case} | {name} | {sw:.2f} | {lu:.2f} | {co:.2f} | {st:.2f} | {st / med['paper'][3]:.2f} | {films} |",
                  flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius", type=float, default=8.0, help="sphere radius, lattice spacings")
    ap.add_argument("--box", type=int, default=64, help="periodic box side (x, y), lattice spacings")
    ap.add_argument("--height", type=int, default=64, help="distance between the z walls")
    ap.add_argument("--gaps", type=float, nargs="+", default=[0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0])
    ap.add_argument("--offsets", type=int, default=4, help="lateral positions averaged per gap")
    ap.add_argument("--tau", type=float, default=1.0)
    ap.add_argument("--cutoff", type=float, default=Lubrication().cutoff_dx, help="numerics.lubrication.cutoff_dx")
    ap.add_argument("--speed", type=float, default=1e-3, help="approach speed, lattice units")
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--particle-boundary", default="bounce_back", choices=["bounce_back", "bouzidi", "cli"],
                    help="numerics.particle_boundary")
    ap.add_argument("--trt-magic", type=float, default=None,
                    help="run TRT with this magic parameter (e.g. 0.1875 for CLI's exact closure); default BGK")
    ap.add_argument("--cost", nargs="*", default=None, metavar="CASE",
                    help=f"time the effect on committed credible runs instead (default {' '.join(COST_CASES)})")
    args = ap.parse_args()
    if args.cost is not None:
        cost(args.cost or COST_CASES)
        return
    offsets = lateral_offsets(args.offsets)
    numerics = {"particle_boundary": args.particle_boundary}
    if args.trt_magic is not None:
        numerics.update(collision="trt", trt_magic=args.trt_magic)
    print(f"sphere a = {args.radius:g}, box {args.box} x {args.box} x {args.height} (walls at z = 0 and "
          f"{args.height}), tau = {args.tau:g}, U = {args.speed:g}, cutoff {args.cutoff:g}, "
          f"{args.offsets} lateral offsets per gap, numerics {numerics}")
    print("| gap h (dx) | h/a | Brenner | without | err | spread | with lubrication | err | steps |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for h in args.gaps:
        t0 = time.perf_counter()
        r = mean_approach_force(args.radius, h, args.box, args.height, offsets, U=args.speed, tau=args.tau,
                                cutoff=args.cutoff, tol=args.tol, numerics=numerics)
        b = r["brenner"]
        print(f"| {h:g} | {h / args.radius:.4f} | {b:.3f} | {r['without']:.3f} | {100 * (r['without'] / b - 1):+.1f} % | "
              f"{r['spread']:.3f} | {r['with']:.3f} | {100 * (r['with'] / b - 1):+.1f} % | {r['steps']} "
              f"({time.perf_counter() - t0:.0f} s) |", flush=True)


if __name__ == "__main__":
    main()
