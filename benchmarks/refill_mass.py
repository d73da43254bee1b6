"""Mass put back and density-floor events on the paper's pipe, by method and refill of uncovered
nodes (issue 44 item 3 and the validation's mass item).

The paper's pipe (50 mm x 100 mm, dx = 1 mm) at the ``credible`` level's settings, built as a run
builds it from the COMMITTED scenes ``results/<level>/cases/<case>/seed<seed>/scene.yaml`` and
the packings they name (``benchmarks/step.py`` does the same); by default ``cube8_c50_re9.4``
(192 cubes at 50 %) and ``cyl8x16_c30_re9.4`` (73 cylinders at 30 %), seed 1. Each case runs
``--steps`` steps from the committed start (particles at rest in the parabolic flow) once per
method (``--methods``: ``paper``, the committed scene; ``accurate``, with the numerics of
``lbmpipe.reproduction.cases.METHODS["accurate"]``; ``accurate_fluid`` likewise; ``OPTIONS``: one
option of them on the paper's method, to find which moves the mass) and refill (``numerics.refill``):
``equilibrium`` (the paper's) and ``extrapolated`` (Grad's reconstruction with the neighbours'
non-equilibrium stress). ``--trt-magic`` adds runs of the paper's method with ``collision: trt`` at
each magic parameter Lambda (``bgk``: ``(tau - 1/2)^2``, where TRT's rates are BGK's); with
half-way bounce-back Lambda sets where the particle surfaces sit (``benchmarks/trt_wall_position.py``).
``--mach-factor`` multiplies ``dt`` at fixed dx as a level's ``mach_factor`` does
(``cases.fidelity_numerics``; tau - 1/2 and the lattice Mach number times it) and divides
``--steps`` by it: the same physical time.

Printed per run, from the simulation's own tallies (the ``summary.json`` records):
  * ``mass_correction``: the mass the particles' mass correction put back (lattice units, the
    fluid density being 1: in node volumes) and as a share of the pipe's fluid mass at the start;
  * ``density_floor``: node updates floored;
  * the largest ``|rho - 1|`` over the fluid, checked every 10 steps; the uncovered nodes per step
    (mean); ms per step, without the first step (it compiles what numba's cache lacks);
  * where the mass goes, as the deficit ``rho_t n_fluid - M`` the correction restores (``rho_t``:
    its target mean density): ``cover`` = sum over the nodes covered of ``rho - rho_t`` (a node
    denser than the mean leaves with more than its share), ``uncover`` = sum over the nodes
    uncovered of ``rho_t - rho`` (a refilled node lighter than the mean), and ``links`` the rest
    (the moving-wall and interpolated link rules, the pipe wall, forcing: the deficit's change over
    the step outside the remap); cover + uncover + links = the mass put back + the deficit left at
    the end; ``d cov`` and ``d unc``: ``cover`` and ``uncover`` per node event (the density step
    across a moving surface the remap carries, ``rho = 3 p``);
  * ``drive``: the flow-rate control's body force over Hagen-Poiseuille's, mean over the run's
    second half: the suspension's resistance, which grows as the surfaces move out;
  * ``mean|rho-1|``: over the fluid, mean of the samples every 10 steps.

Run (one thread; about 2-4 minutes per run on one core of a 2-core EPYC host with numba's cache
warm):

    python benchmarks/refill_mass.py [--cases cube8_c50_re9.4 cyl8x16_c30_re9.4] [--seed 1]
        [--level credible] [--methods paper] [--refills equilibrium extrapolated] [--steps 600] [--threads 1]
        [--trt-magic 3/16 bgk] [--mach-factor 0.5]
    python benchmarks/refill_mass.py --methods paper accurate --refills equilibrium   # the mass item
    python benchmarks/refill_mass.py --refills equilibrium --methods paper --trt-magic 3/16 1/4 1/2 1 bgk
    python benchmarks/refill_mass.py --refills equilibrium --methods paper accurate --mach-factor 0.5
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


def scene(level: str, case: str, seed: int, refill: str, method: str = "paper", magic: str | None = None,
          mach_factor: float = 1.0):
    """The committed scene of ``case`` (its packing file resolved by ``load_scene``) with the
    numerics of ``method`` (``cases.METHODS``) and ``numerics.refill`` set; ``magic`` (a
    ``--trt-magic`` entry) puts TRT with that Lambda on top; ``mach_factor`` multiplies ``dt_s`` as
    a level's ``mach_factor`` does (``cases.fidelity_numerics``)."""
    from lbmpipe.reproduction.cases import METHODS
    from lbmpipe.scene import Scene, load_scene

    path = ROOT / "results" / level / "cases" / case / f"seed{seed}" / "scene.yaml"
    if not path.exists():
        raise SystemExit(f"no committed scene {path.relative_to(ROOT)}: pick a case of the {level} level "
                         f"that has particles and a seed{seed} run")
    data = load_scene(path).model_dump(mode="json", exclude_unset=True)
    extra = METHODS[method] if method in METHODS else OPTIONS[method]
    num = {**data.get("numerics", {}), **extra, "refill": refill}
    num["dt_s"] = float(num.get("dt_s", Scene.model_validate(data).numerics.dt_s)) * mach_factor
    if magic is not None:
        num["collision"] = "trt"
        num["trt_magic"] = magic_value(magic, tau_of({**data, "numerics": num}))
    data["numerics"] = num
    data["name"] = f"{data['name']}_{method}_{refill}"
    return Scene.model_validate(data)


def tau_of(data: dict) -> float:
    """The relaxation time ``tau`` of a scene dict (its viscosity and dt)."""
    from lbmpipe.scene import Scene
    from lbmpipe.units import derive

    sc = Scene.model_validate(data)
    return derive(sc).tau


def magic_value(text: str, tau: float) -> float:
    """A ``--trt-magic`` entry: a number, a fraction (``3/16``) or ``bgk`` = ``(tau - 1/2)^2``, the
    Lambda at which TRT's rates equal BGK's (``omega_minus = omega``)."""
    if text == "bgk":
        return (tau - 0.5) ** 2
    num, _, den = text.partition("/")
    try:
        return float(num) / float(den) if den else float(num)
    except ValueError:
        raise SystemExit(f"--trt-magic {text!r}: give a number, a fraction like 3/16, or bgk") from None


def deviations(sim) -> tuple[float, float]:
    """Largest and mean |rho - 1| over the fluid nodes now."""
    fluid = sim.particles.fluid_mask()
    rho = np.asarray(sim.f)[..., :fluid.shape[2]].sum(axis=0)
    dev = np.abs(rho[fluid] - 1.0)
    return float(dev.max()), float(dev.mean())


class MassBudget:
    """Wraps the motion + remap effect: the densities of the nodes it covers (before) and uncovers
    (after), relative to the mass correction's target (module docstring)."""

    def __init__(self, sim, inner, correction):
        from lbmpipe.fluid.boundaries import plane_buffer
        from lbmpipe.particles.coupling.nodes import FLUID

        self.inner, self.mc, self.plane, self.fluid = inner, correction, plane_buffer, FLUID
        self.name, self.phase = inner.name, inner.phase
        self.cover = self.uncover = 0.0
        self.n_cover = self.n_uncover = 0  # node events counted in cover / uncover

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
        self.n_cover += int(cov.sum())
        self.n_uncover += int(unc.sum())


def run(sc, steps: int, every: int = 10) -> dict:
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.fluid.boundaries import plane_buffer
    from lbmpipe.fluid.effects import FlowRateControl
    from lbmpipe.particles.coupling import ParticleMotion
    from lbmpipe.particles.coupling.mass_correction import MassCorrection
    from lbmpipe.units import derive

    params = derive(sc)
    sim = simulation_from_scene(sc, params)
    ps = sim.particles
    ctl = next((e for e in sim.effects if isinstance(e, FlowRateControl)), None)
    drive = []  # body force of each step over Hagen-Poiseuille's (the suspension's resistance)
    mc = next(e for e in sim.effects if isinstance(e, MassCorrection))
    k = next(i for i, e in enumerate(sim.effects) if isinstance(e, ParticleMotion))
    budget = sim.effects[k] = MassBudget(sim, sim.effects[k], mc)
    mass0 = ps.fluid_mass(sim.f2)
    sim.step(1)  # compiles what the cache lacks: not timed (its tallies count)
    uncovered = ps.last_cover[1]
    remap0 = sim.timers.get(REMAP, 0.0)
    peak, mean = deviations(sim)
    means = [mean]
    secs = 0.0
    for s in range(1, steps):
        t0 = time.perf_counter()
        sim.step(1)
        secs += time.perf_counter() - t0
        uncovered += ps.last_cover[1]
        if ctl is not None:
            drive.append(float(sim.force[2]) / ctl.f_ref)
        if (s + 1) % every == 0:
            p, m = deviations(sim)
            peak = max(peak, p)
            means.append(m)
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
            "mean_dev": float(np.mean(means)), "tau": params.tau, "omega_minus": params.relaxation.omega_minus,
            # per node event: a covered node's excess over the target, a refilled node's shortfall
            "d_cover": budget.cover / max(budget.n_cover, 1), "d_uncover": budget.uncover / max(budget.n_uncover, 1),
            "drive": float(np.mean(drive[len(drive) // 2:])) if drive else float("nan"),
            "remap_ms": 1e3 * (sim.timers.get(REMAP, 0.0) - remap0) / timed, "step_ms": 1e3 * secs / timed,
            "particles": int(ps.n)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="committed credible runs (with particles)")
    ap.add_argument("--seed", type=int, default=1, help="packing seed of the committed run")
    ap.add_argument("--level", default="credible", help="the level whose committed scenes are read")
    ap.add_argument("--methods", nargs="*", default=["paper"], choices=METHOD_NAMES,
                    help="paper: the committed scene; accurate (accurate_fluid): with cases.METHODS['accurate'] "
                    "(['accurate_fluid']); cli, galilean, lubrication: that option alone on the paper's method; "
                    "none (an empty list) with --trt-magic runs only the sweep")
    ap.add_argument("--trt-magic", nargs="*", default=[], metavar="LAMBDA",
                    help="after the methods, the paper's method with collision trt at each of these magic parameters "
                    "(numbers, fractions like 3/16, or bgk = (tau - 1/2)^2, where TRT's rates are BGK's)")
    ap.add_argument("--mach-factor", type=float, default=1.0,
                    help="dt times this at fixed dx (a level's mach_factor: the lattice Mach number times it, "
                    "tau - 1/2 times it); --steps is divided by it, so the runs cover the same physical time")
    ap.add_argument("--refills", nargs="+", default=REFILLS, choices=REFILLS)
    ap.add_argument("--steps", type=int, default=600, help="steps at mach factor 1 (the physical time of the run)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    if not 0 < args.mach_factor <= 1:
        raise SystemExit(f"--mach-factor {args.mach_factor:g}: give a factor in (0, 1] (0.5: half the Mach number)")
    steps = int(round(args.steps / args.mach_factor))
    set_threads(args.threads)
    print(f"Paper pipe 50 x 50 x 100 (dx 1 mm), committed {args.level} scenes, seed {args.seed}, by method and "
          f"refill; mach factor {args.mach_factor:g}: {steps} steps from the committed start; {args.threads} thread(s)")
    head = (f"{'case':<20} {'method':<12} {'refill':<11} {'tau':>5} {'om_m':>6} {'corrected':>10} {'/ M0':>9} "
            f"{'floor upd':>9} {'peak|rho-1|':>11} {'mean|rho-1|':>11} {'unc/step':>8} {'cover':>8} {'uncover':>8} "
            f"{'links':>8} {'d cov':>9} {'d unc':>9} {'drive':>6} {'step ms':>7}")
    print(head)
    print("-" * len(head))
    runs = [(m, None) for m in args.methods] + [("trt " + L, L) for L in args.trt_magic]
    for case in args.cases:
        for label, magic in runs:
            method = "paper" if magic is not None else label
            for refill in args.refills:
                r = run(scene(args.level, case, args.seed, refill, method, magic, args.mach_factor), steps)
                print(f"{case:<20} {label:<12} {refill[:11]:<11} {r['tau']:>5.3f} {r['omega_minus']:>6.4f} "
                      f"{r['corrected']:>10.4g} {r['corrected'] / r['mass0']:>9.2e} {r['floor_updates']:>9.0f} "
                      f"{r['peak_dev']:>11.4f} {r['mean_dev']:>11.3e} {r['uncovered']:>8.1f} {r['cover']:>8.4g} "
                      f"{r['uncover']:>8.4g} {r['links']:>8.4g} {r['d_cover']:>9.3e} {r['d_uncover']:>9.3e} "
                      f"{r['drive']:>6.3f} {r['step_ms']:>7.1f}", flush=True)
    print("tau, om_m: the even (viscous) relaxation time and the odd rate (1/tau for BGK); corrected: mass the "
          "particles' mass correction put back (lattice units; / M0: share of the fluid mass at the start); floor upd: "
          "node updates the density floor (0.5) raised; peak|rho-1|, mean|rho-1|: over the fluid, every 10 steps; "
          "cover / uncover / links: where the deficit the correction restores comes from (module docstring); d cov, "
          "d unc: the same per node event (a covered node's density above the target, a refilled node's below it); "
          "drive: the flow-rate control's body force over Hagen-Poiseuille's, mean over the second half (the "
          "suspension's resistance)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
