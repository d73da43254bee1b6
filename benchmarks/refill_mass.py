"""Mass put back and density-floor events on the paper's pipe, by method and refill of uncovered
nodes (issue 44 item 3 and the validation's mass item).

The paper's pipe (50 mm x 100 mm, dx = 1 mm) at the ``credible`` level's settings, built as a run
builds it from the COMMITTED scenes ``results/<level>/cases/<case>/seed<seed>/scene.yaml`` and
the packings they name (``benchmarks/step.py`` does the same); by default ``cube8_c50_re9.4``
(192 cubes at 50 %) and ``cyl8x16_c30_re9.4`` (56 cylinders at 30 %), seed 1. Each case runs
``--steps`` steps from the committed start (particles at rest in the parabolic flow) once per
method (``--methods``: ``paper``, the committed scene; ``accurate``, with the numerics of
``lbmpipe.reproduction.cases.METHODS["accurate"]``; ``accurate_fluid`` likewise; ``OPTIONS``: one
option of them on the paper's method, to find which moves the mass) and refill (``numerics.refill``):
``equilibrium`` (the paper's) and ``extrapolated`` (Grad's reconstruction with the neighbours'
non-equilibrium stress).

Printed per run, from the simulation's own tallies (the ``summary.json`` records):
  * ``mass_correction``: the mass the particles' mass correction put back (lattice units, the
    fluid density being 1: in node volumes) and as a share of the pipe's fluid mass at the start;
  * ``density_floor``: node updates floored and the mass the floor added;
  * the largest ``|rho - 1|`` over the fluid, checked every 10 steps; the uncovered nodes per step
    (mean); ms per step of the remap effect (the refill runs inside it) and of the whole step,
    without the first step (it compiles what numba's cache lacks);
  * where the mass goes, as the deficit ``rho_t n_fluid - M`` the correction restores (``rho_t``:
    its target mean density): ``cover`` = sum over the nodes covered of ``rho - rho_t`` (a node
    denser than the mean leaves with more than its share), ``uncover`` = sum over the nodes
    uncovered of ``rho_t - rho`` (a refilled node lighter than the mean), and ``links`` the rest
    (the moving-wall and interpolated link rules, the pipe wall, forcing: the deficit's change over
    the step outside the remap); cover + uncover + links = the mass put back + the deficit left at
    the end.

Run (one thread; about 2-4 minutes per run on one core of a 2-core EPYC host with numba's cache
warm):

    python benchmarks/refill_mass.py [--cases cube8_c50_re9.4 cyl8x16_c30_re9.4] [--seed 1]
        [--level credible] [--methods paper] [--refills equilibrium extrapolated] [--steps 600] [--threads 1]
    python benchmarks/refill_mass.py --methods paper accurate --refills equilibrium   # the mass item
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import set_threads  # noqa: E402

DEFAULT_CASES = ["cube8_c50_re9.4", "cyl8x16_c30_re9.4"]
REFILLS = ["equilibrium", "extrapolated"]
REMAP = "particles: motion + remap (cover/uncover)"
#: single options of the accurate method on the paper's (to find which one moves the mass)
OPTIONS = {"cli": {"particle_boundary": "cli"}, "galilean": {"momentum_exchange": "galilean"},
           "lubrication": {"lubrication": {"enabled": True}},
           "trt": {"collision": "trt", "trt_magic": 0.25}, "bouzidi_wall": {"wall": "bouzidi"},
           # the accurate method without the Galilean exchange and lubrication
           "cli_trt_bouzidi": {"particle_boundary": "cli", "collision": "trt", "trt_magic": 0.1875, "wall": "bouzidi"}}
METHOD_NAMES = ["paper", "accurate", "accurate_fluid", *OPTIONS]


def scene(level: str, case: str, seed: int, refill: str, method: str = "paper"):
    """The committed scene of ``case`` (its packing file resolved by ``load_scene``) with the
    numerics of ``method`` (``cases.METHODS``) and ``numerics.refill`` set."""
    from lbmpipe.reproduction.cases import METHODS
    from lbmpipe.scene import Scene, load_scene

    path = ROOT / "results" / level / "cases" / case / f"seed{seed}" / "scene.yaml"
    if not path.exists():
        raise SystemExit(f"no committed scene {path.relative_to(ROOT)}: pick a case of the {level} level "
                         f"that has particles and a seed{seed} run")
    data = load_scene(path).model_dump(mode="json", exclude_unset=True)
    extra = METHODS[method] if method in METHODS else OPTIONS[method]
    data["numerics"] = {**data.get("numerics", {}), **extra, "refill": refill}
    data["name"] = f"{data['name']}_{method}_{refill}"
    return Scene.model_validate(data)


def peak_deviation(sim) -> float:
    """Largest |rho - 1| over the fluid nodes now."""
    fluid = sim.particles.fluid_mask()
    rho = np.asarray(sim.f)[..., :fluid.shape[2]].sum(axis=0)
    return float(np.abs(rho[fluid] - 1.0).max())


class MassBudget:
    """Wraps the motion + remap effect: the densities of the nodes it covers (before) and uncovers
    (after), relative to the mass correction's target (module docstring)."""

    def __init__(self, sim, inner, correction):
        from lbmpipe.fluid.boundaries import plane_buffer
        from lbmpipe.particles.coupling.nodes import FLUID

        self.inner, self.mc, self.plane, self.fluid = inner, correction, plane_buffer, FLUID
        self.name, self.phase = inner.name, inner.phase
        self.cover = self.uncover = 0.0

    def __getattr__(self, k):  # everything else (records, timers' bookkeeping) is the inner effect's
        return getattr(self.inner, k)

    def __call__(self, sim) -> None:
        ps = sim.particles
        f2 = self.plane(sim.f_next)
        before = ps.owner.copy()
        rho_b = np.asarray(f2).sum(axis=0)
        self.inner(sim)
        rho_a = np.asarray(f2).sum(axis=0)
        cov = (before == self.fluid) & (ps.owner >= 0)
        unc = (before >= 0) & (ps.owner == self.fluid)
        rt = self.mc.rho_target
        if rt is None:
            return  # the correction takes its target after this motion: the deficit starts at 0 then
        self.cover += float(rho_b[cov].sum()) - rt * int(cov.sum())
        self.uncover += rt * int(unc.sum()) - float(rho_a[unc].sum())


def run(sc, steps: int, every: int = 10) -> dict:
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.fluid.boundaries import plane_buffer
    from lbmpipe.particles.coupling import ParticleMotion
    from lbmpipe.particles.coupling.mass_correction import MassCorrection
    from lbmpipe.units import derive

    sim = simulation_from_scene(sc, derive(sc))
    ps = sim.particles
    mc = next(e for e in sim.effects if isinstance(e, MassCorrection))
    k = next(i for i, e in enumerate(sim.effects) if isinstance(e, ParticleMotion))
    budget = sim.effects[k] = MassBudget(sim, sim.effects[k], mc)
    mass0 = ps.fluid_mass(sim.f2)
    sim.step(1)  # compiles what the cache lacks: not timed (its tallies count)
    uncovered = ps.last_cover[1]
    remap0 = sim.timers.get(REMAP, 0.0)
    peak = peak_deviation(sim)
    secs = 0.0
    for s in range(1, steps):
        t0 = time.perf_counter()
        sim.step(1)
        secs += time.perf_counter() - t0
        uncovered += ps.last_cover[1]
        if (s + 1) % every == 0:
            peak = max(peak, peak_deviation(sim))
    rec = sim.records()
    mcr = rec.get("mass_correction", {})
    fl = rec.get("density_floor", {})
    timed = max(steps - 1, 1)
    corrected = float(mcr.get("mass_added", 0.0))
    deficit = mc.rho_target * ps.n_fluid - ps.fluid_mass(plane_buffer(sim.f_next))
    return {"mass0": mass0, "corrected": corrected, "floor_updates": float(fl.get("node_updates", 0.0)),
            "cover": budget.cover, "uncover": budget.uncover,
            "links": corrected + deficit - budget.cover - budget.uncover,
            "floor_mass": float(fl.get("mass_added", 0.0)), "peak_dev": peak, "uncovered": uncovered / steps,
            "remap_ms": 1e3 * (sim.timers.get(REMAP, 0.0) - remap0) / timed, "step_ms": 1e3 * secs / timed,
            "particles": int(ps.n)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="committed credible runs (with particles)")
    ap.add_argument("--seed", type=int, default=1, help="packing seed of the committed run")
    ap.add_argument("--level", default="credible", help="the level whose committed scenes are read")
    ap.add_argument("--methods", nargs="+", default=["paper"], choices=METHOD_NAMES,
                    help="paper: the committed scene; accurate (accurate_fluid): with cases.METHODS['accurate'] "
                    "(['accurate_fluid']); cli, galilean, lubrication: that option alone on the paper's method")
    ap.add_argument("--refills", nargs="+", default=REFILLS, choices=REFILLS)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), committed {args.level} scenes, seed {args.seed}, by method and "
          f"refill; {args.steps} steps from the committed start; {args.threads} thread(s)")
    head = (f"{'case':<20} {'method':<9} {'refill':<13} {'N':>4} {'corrected':>10} {'/ M0':>9} {'floor upd':>10} "
            f"{'floor mass':>11} {'peak|rho-1|':>11} {'unc/step':>9} {'cover':>9} {'uncover':>9} {'links':>9} "
            f"{'remap ms':>9} {'step ms':>8}")
    print(head)
    print("-" * len(head))
    for case in args.cases:
        for method in args.methods:
            for refill in args.refills:
                r = run(scene(args.level, case, args.seed, refill, method), args.steps)
                print(f"{case:<20} {method:<9} {refill:<13} {r['particles']:>4} {r['corrected']:>10.4g} "
                      f"{r['corrected'] / r['mass0']:>9.2e} {r['floor_updates']:>10.0f} {r['floor_mass']:>11.4g} "
                      f"{r['peak_dev']:>11.4f} {r['uncovered']:>9.1f} {r['cover']:>9.4g} {r['uncover']:>9.4g} "
                      f"{r['links']:>9.4g} {r['remap_ms']:>9.2f} {r['step_ms']:>8.1f}", flush=True)
    print("corrected: mass the particles' mass correction put back (lattice units; / M0: share of the fluid mass at "
          "the start); floor upd / floor mass: node updates the density floor (0.5) raised and the mass it added; "
          "peak|rho-1|: over the fluid, every 10 steps; cover / uncover / links: where the deficit the correction "
          "restores comes from (module docstring)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
