"""Why a committed run ended unstable: the evidence at the failing node, and one change at a time
(issue 47 item 5, the paper-method half).

A run the guard stopped (``summary.json`` status ``unstable``; ``lbmpipe.guard``) is rebuilt from
its committed ``scene.yaml`` and the packing file it names, exactly as a run builds it
(``lbmpipe.scene.load_scene``, ``lbmpipe.units.derive``, ``lbmpipe.assemble.simulation_from_scene``,
with its guard), and stepped as ``lbmpipe.run`` steps it: the state is the run's, bit for bit.
Nothing in the solver is changed; every figure is read from the state between steps (or between
the effects of one step, through wrappers that only look).

1. **History** (0 to the failure, every ``--every`` steps): the guard's scan (max |u| and min/max
   density with their nodes), the particles' speeds, the collision totals (bodies locked by the
   jam rule, unresolved contacts), the flow-rate controller's force over its reference (the
   Poiseuille force of the target flow rate), the density floor's and the mass correction's
   tallies, and the **checkerboard mode**: D3Q15's velocities all join a node to a node of the
   other parity (``(-1)^(x+y+z)``), so a momentum field ``(-1)^(x+y+z+t) A`` is untouched by the
   collision (which conserves momentum) and by streaming (which maps it onto itself): no
   viscosity damps it. Its local amplitude is the high-pass ``c = (j - mean of the 6 axis
   neighbours' j) / 2`` (exactly ``A`` for the mode, ~0 for a smooth field), taken where the node
   and its 6 axis neighbours are fluid; ``P = sum (-1)^(x+y+z+t) j`` over the fluid is its
   staggered momentum.
2. **Window** (``--window`` steps before the failure, every step, from a copy of the state taken
   on the way): the failing node (the guard's), its 14 neighbours' owners (fluid / wall /
   particle id), the fluid nodes in the thinnest gap through it (along the 7 lattice lines, the
   fluid run between the two solids it meets), the gaps between the particles near it and to the
   pipe wall (``lbmpipe.particles.contact``: GJK/EPA and the pipe-wall contact), their velocities
   and angular velocities, the surface velocity ``u_b = U + Omega x r`` at the node against the
   fluid velocity there and the mean over its fluid 3x3x3 neighbourhood, its cover / uncover
   events, the density floor's events there (the node's pulled density below ``rho_min`` before
   the sweep) and in total, the mass correction's calls, and the staggered momentum's budget per
   effect: what the particle links' moving-wall term puts in, per particle (from the ghost slots
   the coupling wrote, the live links and the velocities of the step; ``Probe.link_terms``: Ladd's
   Eq. (8) on half-way links, or the method's link rule: CLI's coefficient ``c = 2/(1+2q)`` and
   the wall velocity at ``x + q e_i``), what the interpolation itself puts in (``G - f*_i(x)``;
   not applicable to half-way links), and what the remap puts in (nodes covered take theirs away;
   uncovered nodes come back with ``rho u_b``), per particle. At the failing node: its density
   every step, the mass its particle links bring beyond bounce-back at rest (moving-wall and
   interpolation parts), its links (``q``, whether ``x - e_i`` is fluid), the gaps of the
   particles near it every step and their lubrication forces. The Galilean exchange and the
   lubrication act on the particles only: no fluid budget term (the JSON says so, ``method``).
3. **One change at a time** (each from step 0 as far as ``--extra`` steps past the failure, guard
   on, as a run): half the time step (``numerics.dt_s / 2``, the step counts doubled: lattice
   Mach / 2), ``numerics.collision: trt``, the density floor off (``numerics.density_floor:
   null``; the runs have it on at 0.5), ``particles.collisions.contact_gap_dx`` doubled. The
   options that need no conversion of the state (all but dt) are also switched on the state at
   the window's start ("switched"): the same configuration, one change.
4. **Counterfactuals** (evidence, not options of the solver; ``_unstable_probe``): ``refill_rho0``
   (``RefillRho0``), the nodes the remap uncovers are refilled at ``rho0 = 1`` instead of their
   neighbours' density (the particle pays ``rho0 u_b``); ``force_cap`` (``ForceCap``), the
   flow-rate controller's force held at most its largest value before the first jam lock (or
   ``--force-cap`` times its reference); ``lubrication_off`` (``LubricationOff``), the lubrication
   effect does nothing. From step 0 (or the checkpoint) and switched at the window's start.

``--checkpoint PATH`` starts from a checkpoint the run left (read only) instead of step 0, the
run's state (the JSON's ``reproduced`` shows the failure again); ``--variants-from pre_jam``
starts the variants from the last state before the first jam lock.

The named mechanism follows from the figures (``mechanism``); the JSON (``--json``) keeps the
evidence small; the measurements live in ``benchmarks/_unstable_probe.py``; README: "Issue 47:
the two unstable runs".

Run (one core; about 10-40 minutes a case, most of it the variant runs; a cold numba cache adds
the TRT and floor-free kernels' compilation)::

    NUMBA_NUM_THREADS=1 nice -n 5 python benchmarks/unstable_cause.py results/credible/cases/cube24_c30_re26/seed3 \
        [--around STEP] [--window 300] [--extra 3000] [--variants dt_half trt floor_off gap_double refill_rho0] \
        [--checkpoint PATH] [--force-cap RATIO] [--no-switched] [--json results/credible/unstable/cube24_c30_re26.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _unstable_probe import (CHECKER_NODE, FLUID, ForceCap, LubricationOff, Probe, RefillRho0, Watch, capture,  # noqa: E402
                             checker_damping, restore, shown_path)

VARIANTS = {
    "dt_half": "numerics.dt_s / 2 (lattice Mach / 2; steps x 2)",
    "trt": "numerics.collision: trt",
    "floor_off": "numerics.density_floor: null (the run: 0.5)",
    "gap_double": "particles.collisions.contact_gap_dx x 2",
}
#: diagnostic counterfactuals (not options of the solver): the script changes the state between effects
COUNTERFACTUALS = {
    "refill_rho0": "counterfactual: uncovered nodes refilled at rho0 = 1, not their neighbours' density",
    "force_cap": "counterfactual: the flow-rate controller's force held at most its largest value before the first "
                 "jam lock (--force-cap: that many times its reference)",
    "lubrication_off": "counterfactual: the lubrication effect does nothing (no film impulses)",
}
#: the variants that can be switched on a state without converting it (dt changes the lattice units)
SWITCHABLE = ("trt", "floor_off", "gap_double", "refill_rho0", "force_cap", "lubrication_off")


# ------------------------------------------------------------------------------------------------
# the case and its variants


def load_case(case_dir: Path):
    from lbmpipe.scene import load_scene

    case_dir = Path(case_dir)
    scene_path = case_dir / "scene.yaml"
    if not scene_path.exists():
        raise SystemExit(f"{case_dir}: no scene.yaml; pass a committed run directory, e.g. "
                         "results/credible/cases/cube24_c30_re26/seed3")
    summary = json.loads((case_dir / "summary.json").read_text()) if (case_dir / "summary.json").exists() else {}
    return load_scene(scene_path), summary


def variant_scene(scene, variant: str | None):
    """The committed scene with one change (``VARIANTS``), or itself."""
    from lbmpipe.scene import Scene

    if variant is None or variant in COUNTERFACTUALS:
        return scene
    d = scene.model_dump(mode="json", exclude_unset=True)  # the scene as written: defaults stay defaults
    num = d.setdefault("numerics", {})
    if variant == "dt_half":
        num["dt_s"] = scene.numerics.dt_s / 2.0
    elif variant == "trt":
        num["collision"] = "trt"
    elif variant == "floor_off":
        num["density_floor"] = None
    elif variant == "gap_double":
        col = d.setdefault("particles", {}).setdefault("collisions", {})
        col["contact_gap_dx"] = 2.0 * scene.particles.collisions.contact_gap_dx
    else:
        raise SystemExit(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)}")
    d["name"] = f"{scene.name}_{variant}"
    return Scene.model_validate(d)


def build(scene):
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    params = derive(scene)
    return simulation_from_scene(scene, params), params


# ------------------------------------------------------------------------------------------------
# the runs


def _guard_row(guard, sim) -> dict:
    s = guard.scan(sim)
    return {k: s[k] for k in ("u_max", "u_node", "rho_min", "rho_min_node", "rho_max", "rho_max_node")}


def _failing_node(guard, sim, message: str) -> int:
    """The flat node the guard's failing check named: the density extreme for a density failure,
    the first non-finite node, else the fastest node."""
    s = guard.scan(sim)
    if "non-finite populations" in message and s["nonfinite_node"] >= 0:
        return s["nonfinite_node"]
    if "fluid density" in message:
        return s["rho_min_node"] if s["rho_min"] < guard.limits.rho_min else s["rho_max_node"]
    return s["u_node"]


def _node3(probe, flat: int):
    a, rest = divmod(int(flat), probe.ny * probe.az)
    b, z = divmod(rest, probe.az)
    return (a, b, z)


def history(sim, probe, until: int, every: int, capture_at: int, log) -> dict:
    """Steps the baseline from its state (step 0, or a checkpoint of the run) as the run did (guard
    every 50 steps) to its failure or ``until``; a row every ``every`` steps; the state copied at
    ``capture_at``, and every ``10 every`` steps while no body has been locked by the jam rule
    (``pre_jam``: the last such copy, a start for the variants just before the jam)."""
    from lbmpipe.errors import Unstable

    guard = sim.guard
    rows, state, failure, pre_jam = [], None, None, None
    locked0 = probe.tallies()["locked"]
    t0 = time.perf_counter()
    while sim.step_count < until:
        n = every - sim.step_count % every
        if sim.step_count < capture_at:
            n = min(n, capture_at - sim.step_count)
        try:
            sim.step(n)
        except Unstable as exc:
            failure = {"step": sim.step_count, "message": str(exc)}
        if sim.step_count == capture_at:
            state = capture(sim)
        if (not failure and sim.step_count % (10 * every) == 0 and sim.step_count < capture_at
                and probe.tallies()["locked"] == locked0):
            pre_jam = capture(sim)
        if sim.step_count % every == 0 or failure:
            g = _guard_row(guard, sim)
            st = probe.state()
            row = {"step": sim.step_count, **{k: g[k] for k in ("u_max", "rho_min", "rho_max")},
                   "u_node": _node3(probe, g["u_node"]), "checker_max": st["checker_max"],
                   "checker_node": st["checker_node"], "checker_nodes": st["checker_nodes"],
                   "Pz": float(st["P"][2]), **probe.particles(), **probe.tallies(), "rho_max_node": _node3(probe, g["rho_max_node"])}
            rows.append(row)
            if sim.step_count % (10 * every) == 0 or failure:
                log(f"  step {sim.step_count}: |u|max {row['u_max']:.3f} at {row['u_node']}, rho {row['rho_min']:.3f}.."
                    f"{row['rho_max']:.3f} at {row['rho_max_node']}, checker {row['checker_max']:.3f} "
                    f"({row['checker_nodes']} nodes), moving {row['moving']}/{row['free']}, locked {row['locked']}, "
                    f"F/F_ref {row['force_ratio']:.2f}, lub max {row['lub_force_max']:.3g} [{time.perf_counter() - t0:.0f} s]")
        if failure:
            failure["node"] = _node3(probe, _failing_node(guard, sim, failure["message"]))
            break
    return {"rows": rows, "state": state, "failure": failure, "pre_jam": pre_jam}


def window(sim, probe, state, stop: int, node, log) -> list[dict]:
    """Every step from the copied state to ``stop``: the failing node's evidence and the budget."""
    from lbmpipe.errors import Unstable

    restore(sim, state)
    guard = sim.guard
    sim.guard = None  # checked by hand below, at the run's steps
    watch = Watch(probe, node)
    recs = []
    prev = probe.tallies()
    o_prev = int(probe.owner()[node])
    try:
        while sim.step_count < stop:
            t = sim.step_count
            watch.rec = {}
            sim.step(1)
            r = watch.rec
            g = _guard_row(guard, sim)
            st = probe.state()
            rho, j, fluid = st["rho"], st["j"], st["fluid"]
            own = int(probe.owner()[node])
            a, b, z = node
            lo = [max(a - 1, 0), max(b - 1, 0)]
            sl = (slice(lo[0], a + 2), slice(lo[1], b + 2))
            zs = [(z + d) % probe.nz for d in (-1, 0, 1)]
            fl = fluid[sl][:, :, zs]
            jl = j[(slice(None),) + sl][:, :, :, zs]
            rl = rho[sl][:, :, zs]
            u_loc = (jl / np.maximum(rl, 1e-12) * fl).sum(axis=(1, 2, 3)) / max(int(fl.sum()), 1)
            tl = probe.tallies()
            near = probe.near_particles(node)
            box = st["amp"][max(a - 2, 0):a + 3, max(b - 2, 0):b + 3][:, :, [(z + d) % probe.nz for d in range(-2, 3)]]
            rec = {
                "step": sim.step_count, "u_max": g["u_max"], "u_node": _node3(probe, g["u_node"]),
                "rho_min": g["rho_min"], "rho_min_node": _node3(probe, g["rho_min_node"]),
                "rho_max": g["rho_max"], "rho_max_node": _node3(probe, g["rho_max_node"]),
                "owner": own, "rho": float(rho[node]), "u": (j[:, a, b, z] / rho[node]).tolist(),
                "u_local_mean": u_loc.tolist(), "checker": float(st["amp"][node]), "checker_near": float(box.max()),
                "checker_max": st["checker_max"], "checker_nodes": st["checker_nodes"],
                "neighbours": probe.neighbours(node), "near": near,
                "u_b": {str(k): probe.surface_velocity(k, node).tolist() for k in near},
                "P": st["P"].tolist(), "P_start": r["P0"].tolist(),
                "dP_sweep": (r["P_sweep"] - r["P0"]).tolist(), "dP_remap": (r["P_remap"] - r["P_sweep"]).tolist(),
                "ladd": r["ladd"].tolist(), "interp": r["interp"].tolist(), "remap": r["remap"].tolist(),
                "node_mass_moving": r["node_mass_moving"], "node_mass_interp": r["node_mass_interp"],
                "node_links": r["node_links"], "lub_near": probe.lub_force(near), "gaps": probe.gaps(near) if near else {},
                "locked_now": tl["locked_now"], "lub_force_max": tl["lub_force_max"],
                "covered": r["covered"], "uncovered": r["uncovered"],
                "pulled_rho": r.get("pulled_rho"), "floor_nodes": tl["floor_nodes"] - prev["floor_nodes"],
                "mass_corr": tl["mass_corr"] - prev["mass_corr"], "locked": tl["locked"] - prev["locked"],
                "unresolved": tl["unresolved"] - prev["unresolved"], "force_ratio": tl["force_ratio"],
                **probe.particles(),
            }
            if own != o_prev:
                rec["owner_change"] = [o_prev, own]
            o_prev = own
            prev = tl
            recs.append(rec)
            if sim.step_count % guard.every == 0:
                guard.check(sim)
    except Unstable as exc:
        log(f"  window: guard at step {sim.step_count}: {str(exc)[:120]}")
    finally:
        watch.remove()
        sim.guard = guard
    return recs


def run_variant(scene, variant, until_base: int, every: int, peak_from: int, state=None, log=print,
                force_cap: float | None = None) -> dict:
    """The scene with one change, from step 0 (``state`` None) or switched on a copied state (the
    window's start, or the run's checkpoint), to ``until_base`` steps of the run (twice as many at
    dt/2); guard on. The peaks are taken from base step ``peak_from`` on (the window's start:
    after the start-up). ``force_cap``: the cap of ``force_cap`` (times the reference force)."""
    from lbmpipe.errors import Unstable

    from lbmpipe.particles.coupling import ParticleMotion

    vs = variant_scene(scene, variant)
    sim, params = build(vs)
    probe = Probe(sim, vs, params)
    scale = 2 if variant == "dt_half" else 1
    if state is not None:
        restore(sim, state)
    if variant == "refill_rho0":
        sim.effects = [RefillRho0(e, probe) if isinstance(e, ParticleMotion) else e for e in sim.effects]
    wrapped = None
    if variant == "force_cap":
        if probe.control is None or not force_cap:
            raise SystemExit("force_cap: the scene has no flow-rate controller, or no cap was measured (--force-cap)")
        wrapped = ForceCap(probe.control, force_cap)
        sim.effects = [wrapped if e is probe.control else e for e in sim.effects]
    if variant == "lubrication_off":
        if probe.lub is None:
            raise SystemExit("lubrication_off: the scene has no lubrication (numerics.lubrication.enabled: false)")
        wrapped = LubricationOff(probe.lub)
        sim.effects = [wrapped if e is probe.lub else e for e in sim.effects]
    until = until_base * scale
    out = {"variant": variant, "start": sim.step_count // scale, "status": "completed", "steps_base": None}
    peak = {"u_max": 0.0, "checker_max": 0.0, "all_locked_samples": 0, "force_ratio_max": 0.0, "rho_max": 0.0,
            "rho_min": 9.0, "lub_force_max": 0.0, "q_ratio_min": 9.0}
    series = []
    t0 = time.perf_counter()
    f0 = probe.tallies()
    stride = every * scale
    while sim.step_count < until:
        failed = False
        try:
            sim.step(min(stride - sim.step_count % stride, until - sim.step_count))
        except Unstable as exc:
            out["status"] = "unstable"
            out["message"] = str(exc)[:240]
            out["node"] = _node3(probe, _failing_node(sim.guard, sim, str(exc)))
            failed = True
        if sim.step_count >= peak_from * scale or failed:  # a sample (the failing state's too)
            st = probe.state()
            g = sim.guard.scan(sim)
            pa = probe.particles()
            tl = probe.tallies()
            if failed:
                out["at_failure"] = {"u_max": round(g["u_max"] * scale, 4), "checker_max": round(st["checker_max"] * scale, 4),
                                     "rho_max": round(g["rho_max"], 4), "moving": pa["moving"],
                                     "force_ratio": round(tl["force_ratio"], 3), "q_ratio": round(tl["q_ratio"], 4),
                                     "locked_bodies": tl["locked"] - f0["locked"],
                                     "floor_node_updates": tl["floor_nodes"] - f0["floor_nodes"]}
            peak["u_max"] = max(peak["u_max"], g["u_max"] * scale)
            peak["checker_max"] = max(peak["checker_max"], st["checker_max"] * scale)
            peak["all_locked_samples"] += int(pa["moving"] == 0)
            peak["force_ratio_max"] = max(peak["force_ratio_max"], tl["force_ratio"])
            peak["rho_max"] = max(peak["rho_max"], g["rho_max"])
            peak["rho_min"] = min(peak["rho_min"], g["rho_min"])
            if tl["lub_force_max"] == tl["lub_force_max"]:
                peak["lub_force_max"] = max(peak["lub_force_max"], tl["lub_force_max"])
            peak["q_ratio_min"] = min(peak["q_ratio_min"], tl["q_ratio"])
        if sim.step_count % (10 * stride) == 0 or failed:
            g = sim.guard.scan(sim)
            pa, tl = probe.particles(), probe.tallies()
            series.append([sim.step_count // scale, round(g["u_max"] * scale, 4), round(g["rho_max"], 4), pa["moving"],
                           tl["locked"] - f0["locked"], round(tl["force_ratio"], 3), round(tl["q_ratio"], 4)])
        if failed:
            break
    out["steps_base"] = sim.step_count / scale
    tl = probe.tallies()
    out.update(peak)
    out["floor_node_updates"] = tl["floor_nodes"] - f0["floor_nodes"]
    out["mass_corr_added"] = tl["mass_corr"] - f0["mass_corr"]
    out["locked_bodies"] = tl["locked"] - f0["locked"]
    out["unresolved"] = tl["unresolved"] - f0["unresolved"]
    out["series_columns"] = ["step", "u_max", "rho_max", "moving", "locked_bodies", "force_ratio", "q_ratio"]
    out["series"] = series
    if wrapped is not None and hasattr(wrapped, "capped_steps"):
        out["force_cap"], out["capped_steps"] = wrapped.cap, wrapped.capped_steps
    out["seconds"] = round(time.perf_counter() - t0, 1)
    if "at_failure" in out:
        log(f"    at the failure: {out['at_failure']}; {out['message'][:200]}")
    log(f"  {variant} ({'switched at ' + str(out['start']) if state is not None else 'from 0'}): {out['status']} at base "
        f"step {out['steps_base']:g}; from step {peak_from}: peak |u| {out['u_max']:.3f} (the run's lattice units), rho "
        f"{out['rho_min']:.3f}..{out['rho_max']:.3f}, checker {out['checker_max']:.3f}, samples with every body at rest "
        f"{out['all_locked_samples']}, locked bodies {out['locked_bodies']}, F/F_ref max {out['force_ratio_max']:.2f}, "
        f"Q/Q* min {out['q_ratio_min']:.3f}, lub max {out['lub_force_max']:.3g} [{out['seconds']} s]")
    return out


# ------------------------------------------------------------------------------------------------
# the evidence and the mechanism


def damping_table(scene) -> dict:
    """Per step, the largest |eigenvalue| of the linearised step at (pi, pi, pi - dk) in a uniform
    flow at the run's centre-line speed, for the run's collision and the TRT and dt/2 variants
    (``_unstable_probe.checker_damping``): 1 = the checkerboard mode is not damped."""
    from lbmpipe.fluid.lattice import get_lattice
    from lbmpipe.units import derive

    lat = get_lattice(scene.numerics.lattice)
    out = {}
    for v in (None, "trt", "dt_half"):
        prm = derive(variant_scene(scene, v))
        r = prm.relaxation
        out[v or "run"] = {"omega": round(r.omega, 4), "omega_minus": round(r.omega_minus, 4),
                           "u_lu": round(prm.u_max_lu, 4),
                           **{f"dk={dk}": round(checker_damping(lat.e, lat.w, lat.opp, r.omega, r.omega_minus,
                                                                (0.0, 0.0, prm.u_max_lu), dk), 6)
                              for dk in (0.0, 0.1, 0.3)}}
    return out


def _period2(values) -> tuple[float, float]:
    """(mean, period-2 amplitude) of a series: the amplitude of the (-1)^t component."""
    v = np.asarray(values, dtype=np.float64)
    if len(v) < 4:
        return float(v.mean()) if len(v) else float("nan"), 0.0
    s = np.where(np.arange(len(v)) % 2 == 0, 1.0, -1.0)
    return float(v.mean()), float(abs((v * s).mean()))


def _sums(arr, n) -> dict:
    """Per particle sums over the window of a (steps, n) series, the particles whose share is at
    least 5 % of the largest (as {id: value})."""
    tot = arr.sum(axis=0) if len(arr) else np.zeros(n)
    big = max(float(np.abs(tot).max()) if n else 0.0, 1e-12)
    return {str(k): round(float(tot[k]), 3) for k in range(n) if abs(tot[k]) >= 0.05 * big}


def evidence(case: str, scene, summary, hist, recs, node, probe) -> dict:
    """The figures that name the mechanism (small; JSON)."""
    rows = hist["rows"]
    fail = hist["failure"] or {}
    last = recs[-1] if recs else {}
    ev = {"case": case, "scene": scene.name, "committed": {k: summary.get(k) for k in ("status", "steps", "message")},
          "reproduced": {"step": fail.get("step"), "node": list(node) if node else None,
                         "message": fail.get("message", "")[:300]}}
    # the node in its last fluid steps
    tail = []  # its last stretch as a fluid node (at most 20 steps)
    for r in reversed(recs):
        if r["owner"] != FLUID or len(tail) == 20:
            break
        tail.insert(0, r)
    uz = [r["u"][2] for r in tail]
    mean, amp2 = _period2(uz)
    unc = [r for r in recs if r.get("owner_change") and r["owner_change"][1] == FLUID]
    covd = [r for r in recs if r.get("owner_change") and r["owner_change"][0] == FLUID and r["owner_change"][1] >= 0]
    near = last.get("near", [])
    rel = [float(np.linalg.norm(np.subtract(r["u"], r["u_local_mean"]))) for r in unc]
    ev["node"] = {
        "neighbours": last.get("neighbours"), "near_particles": near,
        "gap": probe.gap_lines(tuple(node))["thinnest"] if node else None,
        "nearest": probe.nearest_surface(tuple(node)) if node else None,
        "u_last": [round(v, 4) for v in last.get("u", [])], "rho_last": round(last.get("rho", float("nan")), 4),
        "u_local_mean_last": [round(v, 4) for v in last.get("u_local_mean", [])],
        "u_b_last": {k: [round(x, 4) for x in v] for k, v in last.get("u_b", {}).items()},
        "uz_last_fluid_steps": [round(v, 4) for v in uz], "uz_mean": round(mean, 4), "uz_period2_amplitude": round(amp2, 4),
        "checker_near": round(last.get("checker_near", 0.0), 4),
        "uncovered_at": [r["step"] for r in unc], "covered_at": [r["step"] for r in covd],
        "u_at_uncover": [[round(v, 4) for v in r["u"]] for r in unc][-3:],
        "u_local_at_uncover": [[round(v, 4) for v in r["u_local_mean"]] for r in unc][-3:],
        "relative_speed_at_uncover": [round(v, 4) for v in rel][-3:],
        "floor_events_at_node": int(sum(1 for r in recs if r.get("pulled_rho") is not None
                                        and r["pulled_rho"] < probe.sim.sweep.rho_min and r["owner"] == FLUID)),
        "pulled_rho_min": round(min((r["pulled_rho"] for r in recs if r.get("pulled_rho") is not None
                                     and r["owner"] == FLUID), default=float("nan")), 4),
    }
    # the node's density and what its links bring (beyond bounce-back at rest), over the window
    fl = [r for r in recs if r["owner"] == FLUID]
    ev["node"]["rho_every_10"] = [[r["step"], round(r["rho"], 4)] for r in fl if r["step"] % 10 == 0 or r is fl[-1]]
    ev["node"]["rho_last_steps"] = [round(r["rho"], 4) for r in fl[-20:]]
    ev["node"]["link_mass_window"] = {"moving_wall": round(sum(r["node_mass_moving"] for r in fl), 4),
                                      "interpolation": round(sum(r["node_mass_interp"] for r in fl), 4),
                                      "last_20_moving_wall": round(sum(r["node_mass_moving"] for r in fl[-20:]), 4),
                                      "last_20_interpolation": round(sum(r["node_mass_interp"] for r in fl[-20:]), 4)}
    ev["node"]["links_last"] = last.get("node_links", [])
    ev["node"]["lub_force_near"] = {w: {k: round(v, 5) for k, v in r.get("lub_near", {}).items()}
                                    for w, r in (("first", recs[0] if recs else {}), ("last", last))}
    gp = [r["gaps"] for r in recs if r.get("gaps")]
    ev["node"]["gaps_min_window"] = {kind: {k: round(min(g[kind].get(k, float("inf")) for g in gp), 4)
                                            for k in gp[-1][kind]} for kind in ("pairs", "wall")} if gp else {}
    ev["node"]["gaps_first"] = gp[0] if gp else {}
    ev["particles"] = {"gaps": probe.gaps(near) if near else {},
                       "v": {str(k): [round(x, 5) for x in probe.ps.bodies.v[k]] for k in near},
                       "omega": {str(k): [round(x, 6) for x in probe.ps.om[k]] for k in near}}
    # the window's totals; the staggered momentum's budget (z component) by effect and particle
    n = probe.ps.n
    ladd = np.array([r["ladd"] for r in recs])[:, :, 2] if recs else np.zeros((0, n))
    remap = np.array([r["remap"] for r in recs])[:, :, :, 2] if recs else np.zeros((0, n, 3))
    ev["window"] = {
        "steps": [recs[0]["step"] - 1, recs[-1]["step"]] if recs else None,
        "floor_node_updates": float(sum(r["floor_nodes"] for r in recs)),
        "mass_correction_calls": int(sum(1 for r in recs if r["mass_corr"] != 0.0)),
        "mass_correction_added": round(float(sum(r["mass_corr"] for r in recs)), 3),
        "steps_every_body_at_rest": int(sum(1 for r in recs if r["moving"] == 0)),
        "first_step_every_body_at_rest": next((r["step"] for r in recs if r["moving"] == 0), None),
        "locked_per_step_last": recs[-1]["locked"] if recs else None,
        "force_ratio": [round(recs[0]["force_ratio"], 3), round(recs[-1]["force_ratio"], 3)] if recs else None,
        "u_max": [round(recs[0]["u_max"], 4), round(recs[-1]["u_max"], 4)] if recs else None,
        "checker_max": [round(recs[0]["checker_max"], 4), round(recs[-1]["checker_max"], 4)] if recs else None,
        "checker_nodes": [recs[0]["checker_nodes"], recs[-1]["checker_nodes"]] if recs else None,
        "Pz": [round(recs[0]["P_start"][2], 3), round(recs[-1]["P"][2], 3)] if recs else None,
        "dPz_sweep": round(float(sum(r["dP_sweep"][2] for r in recs)), 3),
        "dPz_sweep_not_moving_wall": round(float(sum(r["dP_sweep"][2] for r in recs) - ladd.sum()), 4),
        "dPz_remap": round(float(sum(r["dP_remap"][2] for r in recs)), 3),
        "dPz_moving_wall_by_particle": _sums(ladd, n),
        "dPz_covered_by_particle": _sums(remap[:, :, 0], n),
        "dPz_uncovered_by_particle": _sums(remap[:, :, 1], n),
        "dPz_uncovered_density_excess_by_particle": _sums(remap[:, :, 2], n),
        "dPz_interpolation_by_particle": (_sums(np.array([r["interp"] for r in recs])[:, :, 2], n) if recs else {})
        if probe.rule_name != "bounce_back" else "not applicable: half-way links interpolate nothing",
        "lub_force_max": ([round(recs[0]["lub_force_max"], 5), round(recs[-1]["lub_force_max"], 5),
                           round(max(r["lub_force_max"] for r in recs), 5)] if recs and probe.lub is not None
                          else "not applicable: no lubrication in the step"),
        "locked_now": [recs[0]["locked_now"], recs[-1]["locked_now"]] if recs else None,
        "rho_max": [round(recs[0]["rho_max"], 4), round(recs[-1]["rho_max"], 4)] if recs else None,
    }
    ev["method"] = {
        "link_rule": probe.rule_name, "momentum_exchange": "galilean" if probe.galilean else "ladd",
        "lubrication": probe.lub is not None,
        "budget": ("the moving-wall term with the link rule's coefficient c and the wall velocity at the link's surface "
                   "point (CLI: c = 2/(1+2q), Bouzidi's local rule where x - e_i is not fluid); the interpolation's "
                   "part (G - f*_i(x) - w_i delta) separately" if probe.rule_name != "bounce_back" else
                   "Ladd's moving-wall term of Eq. (8) on half-way links"),
        "not_in_the_fluid_budget": [t for t, on in (
            ("the Galilean exchange changes the particles' impulses only (link force, remap): no fluid term", probe.galilean),
            ("lubrication changes the particles' velocities only (reported as forces)", probe.lub is not None)) if on],
    }
    # the history: growth of the peaks
    hs = [r for r in rows if r["step"] % 250 == 0 or r is rows[-1]]
    ev["history"] = {k: [round(float(r[k]), 4) if isinstance(r[k], float) else r[k] for r in hs]
                     for k in ("step", "u_max", "rho_min", "rho_max", "checker_max", "checker_nodes", "Pz", "moving",
                               "speed_max", "force_ratio", "q_ratio", "locked", "locked_now", "unresolved",
                               "lub_force_max", "floor_nodes", "mass_corr")}
    ev["history"]["rho_max_node"] = [list(r["rho_max_node"]) for r in hs]
    ev["history"]["u_node"] = [list(r["u_node"]) for r in hs]
    ev["history"]["checker_node"] = [list(r["checker_node"]) for r in hs]
    ev["checker_growth"] = _growth(rows)
    ev["mechanism"] = mechanism(ev)
    return ev


def _growth(rows) -> dict:
    """e-folding steps of the checkerboard peak over the stretch before the failure where it
    grows (least squares on log amplitude over the last half of the rows above its median)."""
    steps = np.array([r["step"] for r in rows], dtype=np.float64)
    amp = np.array([r["checker_max"] for r in rows])
    if len(rows) < 8:
        return {}
    half = len(rows) // 2
    s, a = steps[half:], amp[half:]
    ok = a > 0
    if ok.sum() < 4:
        return {}
    slope = np.polyfit(s[ok], np.log(a[ok]), 1)[0]
    return {"from_step": int(s[0]), "to_step": int(s[-1]), "amplitude": [round(float(a[0]), 4), round(float(a[-1]), 4)],
            "e_folding_steps": round(1.0 / slope, 1) if slope > 0 else None}


def _largest_pump(w) -> str:
    """The budget term that grows |P_z| most in the window (same sign as P_z at its end)."""
    sign = 1.0 if w["Pz"][1] >= 0 else -1.0
    terms = [(f"moving-wall term of particle {k}", v) for k, v in w["dPz_moving_wall_by_particle"].items()]
    terms += [(f"nodes covered by particle {k}", v) for k, v in w["dPz_covered_by_particle"].items()]
    terms += [(f"refill of nodes uncovered by particle {k}", v) for k, v in w["dPz_uncovered_by_particle"].items()]
    if not terms:
        return "no budget term"
    name, v = max(terms, key=lambda t: sign * t[1])
    text = f"{name}: {v:+.2f}"
    if name.startswith("refill"):
        k = name.rsplit(" ", 1)[1]
        text += f", of which {w['dPz_uncovered_density_excess_by_particle'].get(k, 0.0):+.2f} from the refill density's excess (rho - 1) u_b"
    return text


def _links_said(links) -> str:
    """The failing node's particle links in words (the list itself stays in the evidence, ``node``)."""
    if not links:
        return "no particle links"
    qs = [d["q"] for d in links]
    solid = sum(not d["behind_fluid"] for d in links)
    return (f"its {len(links)} links to particles {sorted({d['particle'] for d in links})} have q {min(qs):.2f}-"
            f"{max(qs):.2f}, {solid} of them with no fluid node behind (the interpolation's local fallback)")


def mechanism(ev) -> list[str]:
    """The mechanisms the figures show, each with its numbers. Criteria: jam lock, every free
    body at rest for at least 20 steps of the window; density build-up, the node's density rose by
    more than 0.5 over the window; lubrication blow-up, the largest lubrication force on a particle
    near the node grew tenfold over the window; checkerboard, u_z at the node alternating
    every step with a period-2 amplitude above half its mean (over its last stretch as a fluid
    node, the last 20 steps of it, at least 6) and a checkerboard amplitude above CHECKER_NODE within 2 nodes; thin film, at most 2
    fluid nodes between two solids along a lattice line through the node; fast uncover, the node
    uncovered within 20 steps of the failure at a relative speed above 0.1 (against the mean of
    its fluid 3x3x3 neighbourhood)."""
    out = []
    w, nd = ev["window"], ev["node"]
    rest = w["steps_every_body_at_rest"]
    if rest >= 20:
        fr = w["force_ratio"]
        out.append(
            f"jam lock with the flow-rate controller: from step {w['first_step_every_body_at_rest']} every free body is "
            f"at rest ({rest} steps of the window; {w['locked_per_step_last']} bodies locked in the last step by the jam "
            f"rule), the controller raises the driving force from {fr[0]:.2f} to {fr[1]:.2f} times its reference to "
            f"push the target flow rate through the fixed packing, and max |u| grows from {w['u_max'][0]:.3f} to "
            f"{w['u_max'][1]:.3f}; the failing node {ev['reproduced']['node']} is {nd['nearest']['wall_distance']} "
            f"spacings from the wall and {nd['nearest']['particle_distance']} from particle {nd['nearest']['particle']}")
    if (len(nd["uz_last_fluid_steps"]) >= 6 and nd["uz_period2_amplitude"] > 0.5 * abs(nd["uz_mean"])
            and nd["checker_near"] > CHECKER_NODE):
        g = ev["checker_growth"]
        out.append(
            f"checkerboard mode: u_z at the node alternates every step (mean {nd['uz_mean']:.3f}, period-2 amplitude "
            f"{nd['uz_period2_amplitude']:.3f}; checkerboard amplitude {nd['checker_near']:.3f} within 2 nodes, peak "
            f"{w['checker_max'][1]:.3f}, {w['checker_nodes'][1]} nodes above {CHECKER_NODE}); the peak grew from "
            f"{g.get('amplitude', ['?'])[0]} at step {g.get('from_step')} (e-folding {g.get('e_folding_steps')} steps); "
            f"staggered momentum P_z {w['Pz'][0]} -> {w['Pz'][1]} over the window, largest term: {_largest_pump(w)}")
    gap = nd["gap"]
    if gap is not None and gap["fluid_nodes"] <= 2:
        out.append(f"thin film: {gap['fluid_nodes']} fluid node(s) along {gap['dir']} between {gap['bounds']}; "
                   f"floor events at the node {nd['floor_events_at_node']}, pulled density min {nd['pulled_rho_min']}")
    step = ev["reproduced"]["step"]
    if nd["uncovered_at"] and step and step - nd["uncovered_at"][-1] <= 20 and nd["relative_speed_at_uncover"][-1] > 0.1:
        out.append(f"fast uncover: the node was uncovered at step {nd['uncovered_at'][-1]}, refilled at "
                   f"{nd['u_at_uncover'][-1]} against the local fluid mean {nd['u_local_at_uncover'][-1]}")
    rho = nd.get("rho_every_10") or []
    if len(rho) >= 2 and rho[-1][1] - rho[0][1] > 0.5:
        lm = nd["link_mass_window"]
        out.append(f"density build-up at the node: rho {rho[0][1]} at step {rho[0][0]} -> {rho[-1][1]} at step "
                   f"{rho[-1][0]}; mass its particle links brought beyond bounce-back at rest over the window: "
                   f"moving-wall {lm['moving_wall']:+.3f}, interpolation {lm['interpolation']:+.3f} (last 20 steps "
                   f"{lm['last_20_moving_wall']:+.3f}, {lm['last_20_interpolation']:+.3f}); {_links_said(nd['links_last'])}")
    lf = nd.get("lub_force_near") or {}
    first, lastf = max(lf.get("first", {}).values(), default=0.0), max(lf.get("last", {}).values(), default=0.0)
    if lastf > 10.0 * max(first, 1e-12) and lastf > 0.0:
        out.append(f"lubrication force blow-up near the node: {first:.3g} -> {lastf:.3g} (largest on a particle "
                   f"near the node, lattice units) over the window")
    if not out:
        out.append("none of the tested mechanisms (jam lock, checkerboard mode, thin film, fast uncover, density "
                   "build-up, lubrication blow-up) meets its criterion: see the figures")
    return out


# ------------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case_dir", type=Path, help="a committed run directory with scene.yaml (and summary.json)")
    ap.add_argument("--around", type=int, default=None, help="the failure step (default: summary.json's steps)")
    ap.add_argument("--window", type=int, default=300, help="steps before the failure recorded every step")
    ap.add_argument("--every", type=int, default=50, help="steps between history rows (a multiple of the guard's 50)")
    ap.add_argument("--extra", type=int, default=3000, help="steps past the failure for the variant runs")
    ap.add_argument("--variants", nargs="*", default=[*VARIANTS, *COUNTERFACTUALS],
                    help=f"of {', '.join([*VARIANTS, *COUNTERFACTUALS])}")
    ap.add_argument("--no-switched", action="store_true", help="skip the variants switched at the window's start")
    ap.add_argument("--json", type=Path, default=None, help="write the evidence here (after every variant run too)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the variant runs an interrupted invocation wrote to --json (same command and failure)")
    ap.add_argument("--checkpoint", type=Path, default=None,
                    help="start the baseline and the variants from this checkpoint of the run (lbmpipe.checkpoint; "
                         "read only) instead of step 0")
    ap.add_argument("--variants-from", choices=("start", "pre_jam"), default="start",
                    help="variants from the baseline's start (step 0 or --checkpoint) or the last state before the jam")
    ap.add_argument("--force-cap", type=float, default=None,
                    help="force_cap's cap over the reference force (default: the history's largest before the jam)")
    args = ap.parse_args(argv)
    import numba

    def log(msg):
        print(msg, flush=True)

    scene, summary = load_case(args.case_dir)
    case = args.case_dir.resolve().parent.name if args.case_dir.name.startswith("seed") else args.case_dir.name
    around = args.around or int(summary.get("steps") or 0)
    if around <= 0:
        raise SystemExit("no failure step: pass --around STEP (summary.json has no 'steps')")
    if args.every % 50:
        raise SystemExit(f"--every {args.every}: must be a multiple of the guard's 50 steps")
    start = max(around - args.window, 0)
    log(f"{case} ({scene.name}): committed {summary.get('status')} at step {summary.get('steps')}; threads "
        f"{numba.get_num_threads()}; window {start}..{around}")
    sim, params = build(scene)
    if sim.particles is None:
        raise SystemExit(f"{args.case_dir}: the scene has no particles; this diagnosis is for coupled runs")
    probe = Probe(sim, scene, params)
    cstate, cinfo = None, None
    if args.checkpoint:
        cstate, cinfo = read_checkpoint(args.checkpoint, scene, sim, log)
        restore(sim, cstate)
        if start < sim.step_count:
            raise SystemExit(f"the window's start {start} is before the checkpoint's step {sim.step_count}: lower --window")
    log(f"  method: link rule {probe.rule_name}, exchange {'galilean' if probe.galilean else 'ladd'}, lubrication "
        f"{probe.lub is not None}; baseline from step {sim.step_count}")
    t0 = time.perf_counter()
    hist = history(sim, probe, around + args.every, args.every, start, log)
    fail = hist["failure"]
    if fail is None:
        log(f"  no failure up to step {sim.step_count}: the run does not reproduce (or pass a later --around)")
        node = None
        recs = []
    else:
        node = tuple(fail["node"])
        log(f"  reproduced: {fail['message'][:160]}")
        if hist["state"] is None:
            raise SystemExit(f"failure at step {fail['step']} before the window's start {start}: pass --around "
                             f"{fail['step']}")
        recs = window(sim, probe, hist["state"], fail["step"], node, log)
    log(f"  baseline and window: {time.perf_counter() - t0:.0f} s")
    ev = evidence(case, scene, summary, hist, recs, node, probe)
    for m in ev["mechanism"]:
        log(f"  MECHANISM: {m}")
    until = (fail["step"] if fail else around) + args.extra
    ev["checker_damping"] = damping_table(scene)
    ev["command"] = "NUMBA_NUM_THREADS=1 python benchmarks/unstable_cause.py " + " ".join(
        [str(args.case_dir)] + (["--around", str(args.around)] if args.around else [])
        + ["--window", str(args.window), "--extra", str(args.extra)]
        + (["--checkpoint", shown_path(args.checkpoint)] if args.checkpoint else [])
        + (["--force-cap", str(args.force_cap)] if args.force_cap else [])
        + (["--variants-from", args.variants_from] if args.variants_from != "start" else [])
        + ["--variants", *args.variants] + ["--no-switched"] * args.no_switched)
    cap = args.force_cap or _pre_jam_force(hist["rows"])
    ev["force_cap"] = cap
    ev["baseline_start"] = int(cstate[1]["sim"]["step_count"]) if cstate else 0
    if cinfo:
        ev["checkpoint"] = cinfo
    described = {**VARIANTS, **COUNTERFACTUALS}
    for v in args.variants:
        if v not in described:
            raise SystemExit(f"unknown variant {v!r}; choose from {', '.join(described)}")
    origin = f"from checkpoint {ev['baseline_start']}" if cstate else "from 0"
    if args.variants_from == "pre_jam":
        if hist["pre_jam"] is None:
            raise SystemExit("--variants-from pre_jam: no state before the first jam lock was copied")
        cstate = hist["pre_jam"]
        origin = f"switched at {cstate[1]['sim']['step_count']} (before the first jam lock)"
        ev["variants_start"] = int(cstate[1]["sim"]["step_count"])
    plan = [(v, origin) for v in args.variants]
    if not args.no_switched and hist["state"] is not None:
        plan += [(v, f"switched at {start}") for v in args.variants if v in SWITCHABLE]
    done = _resumable(args, ev) if args.resume else {}
    ev["variants"] = []
    _write(args.json, ev, t0, complete=False, log=None)
    for v, mode in plan:
        if (v, mode) in done:
            ev["variants"].append({**done[(v, mode)], "resumed": True})  # run by the interrupted invocation
            log(f"  {v} ({mode}): kept from {args.json}")
            continue
        state = cstate if mode == origin else hist["state"]  # cstate None: from step 0
        ev["variants"].append({"description": described[v], "mode": mode,
                               **run_variant(scene, v, until, args.every, start, state=state, log=log, force_cap=cap)})
        _write(args.json, ev, t0, complete=False, log=None)  # a part done is kept if the process ends
    _write(args.json, ev, t0, complete=True, log=log)
    return 0


def read_checkpoint(path: Path, scene, sim, log):
    """The state ``(arrays, meta)`` of a run's checkpoint (``lbmpipe.checkpoint``) and what it is,
    checked against the simulation's effects (the fingerprint may differ by the packing's path)."""
    from lbmpipe import checkpoint as ckpt

    head, arrays = ckpt.read(path)
    same = head.get("fingerprint") == ckpt.scene_fingerprint(scene)
    if not same:
        log(f"  note: {path} carries the fingerprint {str(head.get('fingerprint'))[:12]}, the committed scene "
            f"{ckpt.scene_fingerprint(scene)[:12]}; its effects must match and the failure must reproduce")
    if head.get("effects") != [e.name for e in sim.effects]:
        raise SystemExit(f"{path}: the checkpoint's effects {head.get('effects')} are not this scene's")
    log(f"  checkpoint {path}: step {head['step']}")
    info = {"path": shown_path(path), "step": int(head["step"]), "fingerprint_matches_committed_scene": same}
    return ({k: v for k, v in arrays.items() if not k.startswith("run/")}, head["state"]), info


def _pre_jam_force(rows) -> float | None:
    """The largest controller force over its reference in the history before the first jam lock."""
    if not rows:
        return None
    free = [r["force_ratio"] for r in rows if r["locked"] == rows[0]["locked"] and r["force_ratio"] == r["force_ratio"]]
    return round(max(free), 3) if free and rows[0]["locked"] == 0 else None


def _write(path, ev, t0, complete: bool, log) -> None:
    if not path:
        return
    ev["complete"] = complete
    ev["seconds"] = round(time.perf_counter() - t0, 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(ev, indent=1, default=_jsonable) + "\n")
    tmp.replace(path)
    if log:
        log(f"  wrote {path}")


def _resumable(args, ev) -> dict:
    """The variant runs of an earlier, interrupted invocation (``--json``) with the same command
    whose baseline failed at the same step and node: {(variant, mode): entry}."""
    if not args.json or not args.json.exists():
        return {}
    old = json.loads(args.json.read_text())
    if old.get("command") != ev["command"] or old.get("reproduced", {}).get("step") != ev["reproduced"]["step"] \
            or old.get("reproduced", {}).get("node") != ev["reproduced"]["node"]:
        raise SystemExit(f"{args.json} was written by another command or failure; remove it or drop --resume")
    return {(r["variant"], r["mode"]): r for r in old.get("variants", [])}


def _jsonable(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


if __name__ == "__main__":
    raise SystemExit(main())
