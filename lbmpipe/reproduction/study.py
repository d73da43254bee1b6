"""What accuracy costs in time: error against a reference and wall time for each accuracy knob.

The knobs are the scene's numerics: lattice spacing ``dx_mm``, time step ``dt_s`` (at fixed
``dx`` it sets the Mach number and ``tau``), the static wall (staircase half-way ``bounce_back``
or interpolated ``bouzidi``), the collision operator (``bgk``, the paper's, or ``trt``), the
floating-point ``precision``, and, for the statistics, the averaging time. Each is varied one at
a time about a base setting (the fidelity level's ``dx_mm`` and ``dt_per_mm_s``, BGK, staircase
wall, float64), plus optional combinations (e.g. TRT + Bouzidi at every ``dx``).

References, each giving one error per run:

``pipe``
    The particle-free pipe at Re 9.4 (the paper's "LF" flow, paper/reading.md) driven at fixed flow rate:
    ``profile_error_rel_l2`` of ``summary.json``, the relative L2 distance of the time-averaged
    profile from Hagen-Poiseuille. The flow is z-invariant, so a short periodic pipe
    (``length_mm``) gives the same profile as the paper's 100 mm at a tenth of the cost.
``drag``
    A fixed sphere in a periodic cubic box driven by a body force: the drag coefficient
    ``K = F / (6 pi mu a U)`` of a simple cubic array against Zick & Homsy (1982), Table 2 (the
    Sangani & Acrivos (1982) series between tabulated points). As in tests/test_coupling.py,
    the total force per sphere is ``rho g L^3`` (a body force on the fluid is equivalent to the
    mean pressure gradient of Zick & Homsy) and ``U`` is the superficial velocity (flow rate
    over the box cross-section). The staircase sphere's drag depends on where it sits relative
    to the lattice, so each setting is run at ``offsets`` sub-lattice positions (the same
    lattice-relative positions at every ``dx``) and the error is that of the mean.
``omega``
    The paper's observable: mean |Omega| (x, y, z) of one particle case at every fidelity level
    whose results exist, against the finest level (relative L2 over the three components).
``averaging``
    The 95 % batch-means half-width of mean |Omega_x| (relative to the mean) against the
    averaging window, from one case's ``particles.parquet`` truncated to shorter windows.

Costs are wall seconds of the Snakemake ``benchmark:`` file of each run (process start-up
included), the solver's stepping seconds are kept beside them. ``fit_cost_model`` fits
``wall_s = c0 + (a node_updates + b link_updates + c particle_steps) / threads`` to the study's
runs and the case runs, and :func:`predict_seconds` evaluates it for any scene.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from ..outputs import write_json
from .pipe import DENSITY_KG_M3, DT_PER_MM_S, FLOWS, PIPE, time_step
from .pipe import pipe_scene as paper_pipe_scene
from . import steady

#: the interval estimator the averaging study names in its rows
BATCH_MEANS = f"{steady.mean_interval.__module__}.{steady.mean_interval.__name__}"

# ----------------------------------------------------------------------------------------------
# Settings

#: Zick & Homsy (1982), J. Fluid Mech. 115, 13-26, Table 2, simple cubic arrays: K(c).
ZICK_HOMSY_SC = {0.027: 2.008, 0.064: 2.810, 0.125: 4.292, 0.216: 7.442, 0.343: 15.4, 0.45: 28.1, 0.5236: 42.1}

#: The study's settings; ``config["study"][fidelity]`` overrides any key (nested dicts merge).
DEFAULTS: dict = {
    "threads": 1,
    # cost axis of the plots, the recommendation and the cost model's fit: "cpu_s" (benchmark CPU
    # seconds: for the single-threaded study runs the wall time of an idle machine, and unaffected
    # by other jobs sharing the cores) or "wall_s" (benchmark wall seconds, as measured)
    "cost": "cpu_s",
    # largest acceptable error per reference: the recommendation is the cheapest run within it
    "targets": {"pipe": 0.01, "drag": 0.05, "omega": 0.05, "averaging": 0.05},
    # a run whose driving force (pipe) or flow rate (drag) still changes by more than this over
    # the last fifth of the run is flagged as not steady
    "steady_tol": 1.0e-3,
    "pipe": {
        "reynolds": 9.4, "length_mm": 10.0,
        "duration_s": 2.0, "spinup_s": 1.5, "sample_interval_s": 0.05,
        "dx_mm": [2.5, 1.25, 1.0, 0.625, 0.5], "dt_factors": [1.0, 0.5, 0.25],
        "walls": ["bounce_back", "bouzidi"], "collisions": ["bgk", "trt"], "precisions": ["float64", "float32"],
        "combos": [{"collision": "trt", "wall": "bouzidi"}],
    },
    "drag": {
        # c = 0.064 in a 20 mm cell: a sphere of 9.93 mm, the size of the paper's particles
        "box_mm": 20.0, "concentration": 0.064, "reynolds_flow": 9.4, "superficial_velocity_m_s": 2.0e-4,
        # the superficial velocity relaxes with an e-folding time of ~0.1 s: 1 s leaves < 1e-4
        "duration_s": 1.0, "spinup_s": 0.9, "sample_interval_s": 0.02, "offsets": 3, "seed": 0,
        "dx_mm": [2.5, 1.25, 1.0, 0.625, 0.5], "dt_factors": [1.0, 0.5, 0.25],
        "collisions": ["bgk", "trt"], "precisions": ["float64", "float32"],
        "combos": [{"collision": "trt"}],
    },
    "observable": {"case": "cyl8x16_c30_re9.4"},
    "averaging": {"case": "cyl8x16_c30_re9.4", "component": "x", "min_samples": 4},
}

#: Per-level defaults (merged over DEFAULTS): smoke runs the whole study in about a minute of CPU.
LEVEL_DEFAULTS: dict = {
    "smoke": {
        "pipe": {"dx_mm": [5.0, 2.5, 1.25], "dt_factors": [1.0, 0.5, 0.25],
                 "combos": []},
        "drag": {"dx_mm": [2.5, 1.25, 0.625], "offsets": 1, "combos": []},
    },
    "quick": {
        "pipe": {"dx_mm": [5.0, 2.5, 2.0, 1.25, 1.0]},
        "drag": {"dx_mm": [2.5, 2.0, 1.25, 1.0], "offsets": 2},
    },
    "paper": {},
}

#: numerics keys of a setting and their base values
KNOB_KEYS = ("dx_mm", "dt_factor", "collision", "wall", "precision")
_ABBREV = {"bounce_back": "bb", "bouzidi": "bz", "float64": "f64", "float32": "f32"}
REFERENCES = ("pipe", "drag", "omega", "averaging")


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def study_settings(config: dict, fidelity: str) -> dict:
    """The study's settings at ``fidelity``: DEFAULTS, then LEVEL_DEFAULTS[fidelity], then
    ``config["study"][fidelity]`` (or ``config["study"]["default"]``), each merging over the
    previous; ``base`` holds the level's numerics (``dx_mm``, ``dt_per_mm_s``, and the level's
    ``numerics`` collision/wall/precision when it sets them)."""
    s = _merge(DEFAULTS, LEVEL_DEFAULTS.get(fidelity, {}))
    user = (config.get("study") or {})
    s = _merge(s, user.get(fidelity, user.get("default", {})) or {})
    fid = config["fidelities"][fidelity]
    dx = float(fid["dx_mm"])
    dt_per_mm = float(fid["dt_s"]) / dx if "dt_s" in fid else float(fid.get("dt_per_mm_s", DT_PER_MM_S))
    num = fid.get("numerics", {}) or {}
    base = {"dx_mm": dx, "dt_factor": 1.0, "collision": num.get("collision", "bgk"),
            "wall": num.get("wall", "bounce_back"), "precision": num.get("precision", "float64")}
    s["base"] = _merge(base, s.get("base", {}))
    s["dt_per_mm_s"] = float(s.get("dt_per_mm_s", dt_per_mm))
    return s


# ----------------------------------------------------------------------------------------------
# Scenes


def _fmt(x: float) -> str:
    return f"{x:g}"


def run_id(reference: str, setting: dict, offset: int | None = None) -> str:
    """File-system name of one run, from its numerics: ``pipe_dx2.5_dt1_bgk_bb_f64``,
    ``drag_dx1.25_dt0.5_trt_f64_o0`` (the drag runs have no static wall)."""
    parts = [reference, f"dx{_fmt(setting['dx_mm'])}", f"dt{_fmt(setting['dt_factor'])}", setting["collision"]]
    if reference == "pipe":
        parts.append(_ABBREV.get(setting["wall"], setting["wall"]))
    parts.append(_ABBREV.get(setting["precision"], setting["precision"]))
    if offset is not None:
        parts.append(f"o{offset}")
    return "_".join(parts)


def _numerics(setting: dict, dt_per_mm_s: float) -> dict:
    dx = float(setting["dx_mm"])
    return {"dx_mm": dx, "dt_s": time_step(dx, dt_per_mm_s, float(setting["dt_factor"])), "collision": setting["collision"],
            "wall": setting["wall"], "precision": setting["precision"],
            # the study measures what each dt costs in accuracy: report the Mach number, do not refuse it
            "mach_limit": 1.0, "min_diameter_nodes": 4}


def pipe_scene(settings: dict, setting: dict, name: str = "study_pipe") -> dict:
    """Scene dict of the particle-free pipe reference (50 mm, ``length_mm`` long, Re 9.4 at the
    paper's flow rate, parabolic start) at one setting of the knobs."""
    p = settings["pipe"]
    re = float(p["reynolds"])
    return paper_pipe_scene(name, re, _numerics(setting, settings["dt_per_mm_s"]),
                            {k: float(p[k]) for k in ("duration_s", "spinup_s", "sample_interval_s")},
                            length_mm=float(p["length_mm"]), outputs={"profile": True, "flow_rate": True})


def sc_drag_reference(c: float) -> float:
    """Dimensionless drag K of a simple cubic array of spheres at solid fraction ``c``: Zick &
    Homsy's Table 2 where tabulated, else the Sangani & Acrivos (1982) series
    ``1/K = 1 - 1.7601 c^(1/3) + c - 1.5593 c^2 + 3.9799 c^(8/3) - 3.0734 c^(10/3)`` (within
    0.1 % of the table up to c = 0.2)."""
    for cc, k in ZICK_HOMSY_SC.items():
        if abs(cc - c) < 1e-9:
            return k
    inv = 1 - 1.7601 * c ** (1 / 3) + c - 1.5593 * c**2 + 3.9799 * c ** (8 / 3) - 3.0734 * c ** (10 / 3)
    return 1.0 / inv


def pipe_viscosity(reynolds: float) -> float:
    """nu = U D / Re of the paper's pipe flow at ``reynolds`` (U = Q / A), m^2/s."""
    d = PIPE["diameter_mm"] * 1e-3
    return FLOWS[float(reynolds)] / (math.pi * d * d / 4.0) * d / float(reynolds)


def drag_geometry(settings: dict) -> dict:
    """Box edge ``L`` (m), sphere radius ``a`` (m), viscosity (m^2/s), reference K and the body
    force g (m/s^2) that gives the requested superficial velocity if K were exact."""
    d = settings["drag"]
    L = float(d["box_mm"]) * 1e-3
    c = float(d["concentration"])
    a = L * (3.0 * c / (4.0 * math.pi)) ** (1.0 / 3.0)
    nu = pipe_viscosity(d["reynolds_flow"])
    k_ref = sc_drag_reference(c)
    g = 6.0 * math.pi * nu * a * float(d["superficial_velocity_m_s"]) * k_ref / L**3
    return {"L_m": L, "a_m": a, "nu_m2_s": nu, "K_ref": k_ref, "g_m_s2": g, "concentration": c}


def drag_offsets(settings: dict) -> np.ndarray:
    """(n, 3) sub-lattice offsets of the sphere centre, in lattice spacings (the same at every dx)."""
    d = settings["drag"]
    return np.random.default_rng(int(d["seed"])).random((int(d["offsets"]), 3))


def drag_scene(settings: dict, setting: dict, offset: int, name: str = "study_drag") -> dict:
    """Scene dict of the sphere-array reference: one fixed sphere in a periodic box, the fluid
    driven along z by a body force (Stokes regime: particle Re ~ 2 U a / nu ~ 0.01)."""
    d = settings["drag"]
    geo = drag_geometry(settings)
    dx = float(setting["dx_mm"])
    centre = [float(float(d["box_mm"]) / 2.0 + dx * o) for o in drag_offsets(settings)[offset]]
    box = float(d["box_mm"])
    return {
        "name": name,
        "domain": {"kind": "box", "size_mm": [box, box, box]},
        "fluid": {"density_kg_m3": DENSITY_KG_M3, "viscosity_m2_s": geo["nu_m2_s"]},
        "driving": {"kind": "body_force", "acceleration_m_s2": [0.0, 0.0, geo["g_m_s2"]]},
        "initial": {"velocity": "rest"},
        "numerics": _numerics(setting, settings["dt_per_mm_s"]),
        "run": {k: float(d[k]) for k in ("duration_s", "spinup_s", "sample_interval_s")},
        "outputs": {"profile": False, "flow_rate": True},
        "particles": {"bodies": [{"shape": "sphere", "diameter_mm": 2e3 * geo["a_m"], "position_mm": centre,
                                  "fixed": True}]},
    }


def knob_settings(settings: dict, reference: str) -> list[tuple[str, str, dict]]:
    """(knob, label, setting) for every setting of ``reference`` (``pipe`` or ``drag``): each knob
    varied alone about the base, then the combinations at every dx. The base appears under every
    knob (it is the knob's reference point) but is one run."""
    spec = settings[reference]
    base = dict(settings["base"])
    if reference == "drag":
        base["wall"] = "bounce_back"  # a particle's surface is Ladd's bounce-back whatever the wall
    out = []
    lists = [("dx", "dx_mm", spec.get("dx_mm", [])), ("dt", "dt_factor", spec.get("dt_factors", [])),
             ("collision", "collision", spec.get("collisions", [])), ("precision", "precision", spec.get("precisions", []))]
    if reference == "pipe":
        lists.insert(2, ("wall", "wall", spec.get("walls", [])))
    for knob, key, values in lists:
        vals = list(values)
        if base[key] not in vals:
            vals.append(base[key])
        for v in vals:
            s = dict(base, **{key: float(v) if key in ("dx_mm", "dt_factor") else v})
            out.append((knob, _label(key, s[key]), s))
    for combo in spec.get("combos", []) or []:
        name = "+".join(str(v) for v in combo.values())
        for dx in spec.get("dx_mm", []):
            s = dict(base, **combo, dx_mm=float(dx))
            out.append((f"combo {name}", f"{name} dx={_fmt(float(dx))} mm", s))
    return out


def _label(key: str, value) -> str:
    if key == "dx_mm":
        return f"dx={_fmt(value)} mm"
    if key == "dt_factor":
        return f"dt={_fmt(value)} x paper"
    return str(value)


def plan(config: dict, fidelity: str) -> dict[str, dict]:
    """Every run of the study at ``fidelity``: run id -> {reference, setting, offset, scene}."""
    s = study_settings(config, fidelity)
    runs: dict[str, dict] = {}
    for _, _, setting in knob_settings(s, "pipe"):
        rid = run_id("pipe", setting)
        runs.setdefault(rid, {"reference": "pipe", "setting": setting, "offset": None,
                              "scene": pipe_scene(s, setting, name=rid)})
    for _, _, setting in knob_settings(s, "drag"):
        for o in range(int(s["drag"]["offsets"])):
            rid = run_id("drag", setting, o)
            runs.setdefault(rid, {"reference": "drag", "setting": setting, "offset": o,
                                  "scene": drag_scene(s, setting, o, name=rid)})
    return runs


def run_ids(config: dict, fidelity: str) -> list[str]:
    """Run ids of the study at ``fidelity`` (the Snakemake wildcard ``run``)."""
    return sorted(plan(config, fidelity))


def warm_up(config: dict, fidelity: str, out_json: Path) -> dict:
    """Compile (or load from numba's cache) every kernel the study's runs use, in one process,
    before the timed runs: the smallest run of each (reference, collision, wall, precision) for
    two steps. Without it the first run of a combination would carry the one-off compile time
    (about 20 s) in its benchmark. Writes and returns ``{signature: seconds}``."""
    import tempfile
    import time

    from ..scene import Scene
    from ..solver import run_scene
    from ..units import derive

    groups: dict[str, tuple[int, dict]] = {}
    for rid, spec in plan(config, fidelity).items():
        st = spec["setting"]
        sig = f"{spec['reference']} {st['collision']} {st['wall']} {st['precision']}"
        scene = Scene.model_validate(spec["scene"])
        params = derive(scene)
        if sig not in groups or params.fluid_nodes < groups[sig][0]:
            groups[sig] = (params.fluid_nodes, spec["scene"])
    seconds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for sig, (_, data) in sorted(groups.items()):
            scene = Scene.model_validate(data)
            t0 = time.perf_counter()
            run_scene(scene, derive(scene), Path(tmp) / sig.replace(" ", "_"), progress=False, max_steps=2)
            seconds[sig] = time.perf_counter() - t0
    Path(out_json).parent.mkdir(parents=True, exist_ok=True)
    write_json(out_json, {"seconds": seconds})
    return seconds


def write_run_scene(config: dict, fidelity: str, rid: str, path: Path):
    """Validate the scene of run ``rid`` and write it as YAML; returns the Scene."""
    import yaml

    from ..scene import Scene
    from ..units import derive

    runs = plan(config, fidelity)
    if rid not in runs:
        raise ValueError(f"{rid!r} is not a run of the study at fidelity {fidelity!r}")
    data = runs[rid]["scene"]
    scene = Scene.model_validate(data)
    derive(scene)  # tau > 1/2 and sane step counts, before the solver sees it
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))
    return scene


def run_timed(scene_path: Path, out_dir: Path, threads: int, log_path: Path, process_json: Path) -> dict:
    """Run ``lbmpipe run SCENE --out DIR`` in a child process on ``threads`` numba threads and
    write its exact CPU seconds (``getrusage`` of the child: user + system) and wall seconds to
    ``process_json``. Snakemake's benchmark samples CPU time every 30 s once a job is older than
    about 30 s, so for runs of a minute or two its ``cpu_time`` can miss a large part of the
    run. Exit status 4 (the run went unstable) is a result of the study, not an error."""
    import os
    import resource
    import subprocess
    import sys
    import time

    env = dict(os.environ, NUMBA_NUM_THREADS=str(int(threads)))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log_path, "w") as log:
        proc = subprocess.run([sys.executable, "-m", "lbmpipe", "run", str(scene_path), "--out", str(out_dir),
                               "--quiet", "--force"], stdout=log, stderr=subprocess.STDOUT, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    rec = {"cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), "wall_s": wall,
           "returncode": proc.returncode, "threads": int(threads)}
    if proc.returncode not in (0, 4):
        raise RuntimeError(f"lbmpipe run {scene_path} failed with exit status {proc.returncode}; see {log_path}")
    write_json(process_json, rec)
    return rec


# ----------------------------------------------------------------------------------------------
# Reading runs


def read_benchmark(path: Path) -> dict:
    """Wall seconds ``s``, ``cpu_time`` and ``max_rss`` (MB) of a Snakemake benchmark file (the
    mean over its repeats); NaN when the file is missing."""
    try:
        df = pd.read_csv(path, sep="\t")
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return {"s": float("nan"), "cpu_time": float("nan"), "max_rss": float("nan")}
    out = {}
    for k in ("s", "cpu_time", "max_rss"):
        # snakemake writes "-" where it could not measure
        out[k] = float(pd.to_numeric(df[k], errors="coerce").mean()) if k in df else float("nan")
    return out


def steady_change(series: np.ndarray, fraction: float = 0.2) -> float:
    """|x_end - x_(end - fraction of the run)| / |x_end|: how much a series still drifts."""
    x = np.asarray(series, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return float("nan")
    back = max(1, int(round(fraction * x.size)))
    ref = abs(x[-1]) if x[-1] != 0 else float("nan")
    return float(abs(x[-1] - x[-1 - back]) / ref)


def _lattice_info(summary: dict) -> dict:
    lat = summary.get("lattice", {}) or {}
    return {"tau": lat.get("tau", float("nan")), "mach": lat.get("mach_max", float("nan"))}


def _work(summary: dict) -> dict:
    steps = int(summary.get("steps", 0) or 0)
    nodes = int(summary.get("fluid_nodes", 0) or 0)
    part = summary.get("particles", {}) or {}
    links = int(part.get("links", 0) or 0)
    count = int(part.get("count", 0) or 0)
    return {"steps": steps, "nodes": nodes, "node_updates": float(nodes) * steps, "particles": count,
            "links": links, "link_updates": float(links) * steps, "particle_steps": float(count) * steps,
            "threads": int(summary.get("threads", 1) or 1), "solver_s": float(summary.get("wall_seconds", np.nan)),
            "setup_s": float(summary.get("setup_seconds", np.nan)),
            "simulated_s": float(summary.get("simulated_seconds", np.nan))}


def run_record(rid: str, spec: dict, run_dir: Path, bench: Path, settings: dict) -> dict:
    """One run's measurements: work, times, status, and its raw result (pipe: profile error;
    drag: K and the force-balance check)."""
    summary = json.loads((Path(run_dir) / "summary.json").read_text())
    rec = {"run": rid, "reference": spec["reference"], **spec["setting"], "offset": spec["offset"],
           "status": summary.get("status", "missing"), "dt_s": spec["scene"]["numerics"]["dt_s"],
           **_lattice_info(summary), **_work(summary)}
    b = read_benchmark(bench)
    rec["wall_s"], rec["cpu_s"] = b["s"], b["cpu_time"]
    proc = Path(run_dir) / "process.json"
    if proc.exists():  # exact child CPU time (run_timed) rather than the benchmark's sampled one
        rec["cpu_s"] = float(json.loads(proc.read_text())["cpu_s"])
    fr_path = Path(run_dir) / "flow_rate.csv"
    fr = pd.read_csv(fr_path) if fr_path.exists() else pd.DataFrame()
    if spec["reference"] == "pipe":
        rec["value"] = float(summary.get("profile_error_rel_l2", np.nan))
        rec["steady_rel_change"] = steady_change(fr["force_density_N_m3"]) if len(fr) else float("nan")
    else:
        geo = drag_geometry(settings)
        rec["steady_rel_change"] = steady_change(fr["q_m3_s"]) if len(fr) else float("nan")
        if len(fr) and rec["status"] == "completed":
            u_s = float(fr["q_m3_s"].iloc[-1]) / geo["L_m"] ** 2
            rec["value"] = geo["g_m_s2"] * geo["L_m"] ** 3 / (6 * math.pi * geo["nu_m2_s"] * geo["a_m"] * u_s)
        else:
            rec["value"] = float("nan")
        # at steady state the momentum exchange balances the body force on the fluid
        pq = Path(run_dir) / "particles.parquet"
        vf = float((summary.get("particles") or {}).get("volume_fraction", np.nan))
        if pq.exists() and np.isfinite(vf):
            p = pd.read_parquet(pq, columns=["t_s", "fz_N"])
            fz = float(p["fz_N"].iloc[-1]) if len(p) else float("nan")
            rec["force_balance_rel"] = fz / (1000.0 * geo["g_m_s2"] * geo["L_m"] ** 3 * (1 - vf)) - 1.0
    return rec


def _rows_for_reference(recs: pd.DataFrame, settings: dict, reference: str) -> list[dict]:
    """Accuracy-cost rows of ``pipe`` or ``drag``: one per (knob, setting)."""
    tol = float(settings["steady_tol"])
    rows = []
    base_id = run_id(reference, dict(settings["base"], **({"wall": "bounce_back"} if reference == "drag" else {})))
    geo = drag_geometry(settings) if reference == "drag" else None
    for knob, label, setting in knob_settings(settings, reference):
        rid = run_id(reference, setting)
        sel = recs[recs["run"] == rid] if reference == "pipe" else recs[recs["run"].str.startswith(rid + "_o")]
        if sel.empty:
            continue
        first = sel.iloc[0]
        row = {"reference": reference, "knob": knob, "setting": label, "run": rid,
               "is_base": rid == base_id, **{k: setting[k] for k in KNOB_KEYS},
               "dt_s": first["dt_s"], "tau": first["tau"], "mach": first["mach"]}
        if reference == "drag":
            row["wall"] = "n/a (Ladd bounce-back)"
        ok = sel[sel["status"] == "completed"]
        notes = []
        if len(ok) < len(sel):
            notes.append(f"{len(sel) - len(ok)} of {len(sel)} runs {','.join(sorted(set(sel['status']) - {'completed'}))}")
        if reference == "pipe":
            row["value"] = float(ok["value"].iloc[0]) if len(ok) else float("nan")
            row["error"] = row["value"]
            row["error_signed"] = row["value"]
            row["error_spread"] = float("nan")
            row["reference_value"] = 0.0
            row["error_what"] = "relative L2 of the averaged profile vs Hagen-Poiseuille"
        else:
            k = ok["value"].to_numpy(float)
            kmean = float(np.mean(k)) if k.size else float("nan")
            row["value"] = kmean
            row["reference_value"] = geo["K_ref"]
            row["error_signed"] = kmean / geo["K_ref"] - 1.0
            row["error"] = abs(row["error_signed"])
            row["error_spread"] = float(np.std(k, ddof=1) / geo["K_ref"]) if k.size > 1 else float("nan")
            row["error_what"] = (f"|mean K / K_ref - 1| over {len(sel)} sphere position(s), K_ref = {geo['K_ref']:.4g} "
                                 f"(Zick & Homsy SC, c = {geo['concentration']:g})")
            if "force_balance_rel" in ok:
                fb = ok["force_balance_rel"].abs().max()
                row["force_balance_rel"] = float(fb)
        steady = float(sel["steady_rel_change"].max())
        row["steady_rel_change"] = steady
        if not (steady <= tol):
            notes.append(f"not steady: drift {steady:.2g} > {tol:g}")
        for c in ("wall_s", "cpu_s", "solver_s", "setup_s"):
            row[c] = float(sel[c].mean())
        for c in ("steps", "nodes", "node_updates", "particles", "links", "link_updates", "threads", "simulated_s"):
            row[c] = first[c]
        row["n_runs"] = len(sel)
        row["status"] = "completed" if len(ok) == len(sel) else ",".join(sorted(set(sel["status"])))
        row["note"] = "; ".join(notes)
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Paper observable across fidelity levels, and averaging time


def mean_abs_omega(parquet: Path, spinup_s: float) -> dict:
    """Mean |Omega_a| (lab frame, rad/s) over particles and samples with t > spinup."""
    df = pd.read_parquet(parquet, columns=["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s"])
    df = df[df["t_s"] > spinup_s + 1e-12]
    return {a: float(df[f"w{a}_rad_s"].abs().mean()) if len(df) else float("nan") for a in "xyz"}


def case_omega(root: Path, fidelity: str, case: str) -> dict | None:
    """Mean |Omega| of ``case`` at ``fidelity``: from ``stats.json`` when the statistics exist,
    else from ``particles.parquet``; ``None`` when the case has not run (or did not complete)."""
    cdir = Path(root) / fidelity / "cases" / case
    summ = cdir / "summary.json"
    if not summ.exists():
        return None
    summary = json.loads(summ.read_text())
    if summary.get("status") != "completed":
        return None
    stats = cdir / "stats.json"
    ci = None
    if stats.exists():
        st = json.loads(stats.read_text())
        om = st.get("mean_abs_omega_rad_s")
        ci = st.get("ci95_rad_s")
        source = "stats.json"
    else:
        if not (cdir / "particles.parquet").exists():
            return None
        om = mean_abs_omega(cdir / "particles.parquet", float(summary.get("spinup_s", 0.0)))
        source = "particles.parquet"
    if om is None:
        return None
    bench = read_benchmark(Path(root) / fidelity / "benchmarks" / f"{case}.simulate.tsv")
    scene = summary.get("scene", {}) or {}
    return {"omega": np.array([float(om[a]) for a in "xyz"]),
            "ci": np.array([float(ci[a]) for a in "xyz"]) if ci else np.full(3, np.nan),
            "source": source, "summary": summary, "wall_s": bench["s"], "cpu_s": bench["cpu_time"],
            "dx_mm": float((scene.get("numerics") or {}).get("dx_mm", np.nan)),
            "dt_s": float((scene.get("numerics") or {}).get("dt_s", np.nan)),
            "duration_s": float(summary.get("simulated_seconds", np.nan))}


def observable_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Convergence of mean |Omega| of the study's case towards the finest fidelity level that has
    results (smallest dx, then longest run)."""
    s = study_settings(config, fidelity)
    case = s["observable"]["case"]
    found = {}
    for lvl in config["fidelities"]:
        r = case_omega(root, lvl, case)
        if r is not None and np.all(np.isfinite(r["omega"])):
            found[lvl] = r
    if not found:
        return [{"reference": "omega", "knob": "fidelity", "setting": "(none)", "run": case, "error": np.nan,
                 "status": "missing", "note": f"no completed run of {case} at any fidelity level"}]
    finest = min(found, key=lambda k: (found[k]["dx_mm"], -found[k]["duration_s"]))
    ref = found[finest]["omega"]
    rows = []
    for lvl, r in sorted(found.items(), key=lambda kv: -kv[1]["dx_mm"]):
        err = float(np.linalg.norm(r["omega"] - ref) / np.linalg.norm(ref))
        note = f"mean |Omega| from {r['source']}; the levels differ in run length as well as dx"
        if lvl == finest:
            err = float("nan")
            note = (f"reference (finest level with results); 95 % CI / mean = "
                    f"{np.linalg.norm(r['ci']) / np.linalg.norm(ref):.2g}" if np.isfinite(r["ci"]).all()
                    else "reference (finest level with results)")
            if len(found) == 1:
                note = "only one fidelity level has results: no convergence measurable yet"
        w = _work(r["summary"])
        rows.append({"reference": "omega", "knob": "fidelity", "setting": lvl, "run": f"{lvl}/{case}",
                     "is_base": lvl == fidelity, "dx_mm": r["dx_mm"], "dt_s": r["dt_s"],
                     "value": float(np.linalg.norm(r["omega"])), "reference_value": float(np.linalg.norm(ref)),
                     "error": err, "error_signed": err, "error_what": f"|Omega - Omega_{finest}| / |Omega_{finest}| (x, y, z)",
                     "wall_s": r["wall_s"], "cpu_s": r["cpu_s"], **w, "status": "completed", "note": note,
                     **_lattice_info(r["summary"])})
    return rows


def averaging_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Relative 95 % half-width of mean |Omega_c| (c = ``averaging.component``) against the
    averaging window: the particle-averaged series after spin-up, truncated to its first
    T / 2^k (k = 0, 1, ...) while at least ``min_samples`` remain. Cost: the case's wall time
    pro-rated to spin-up plus window."""
    s = study_settings(config, fidelity)
    a = s["averaging"]
    case, comp = a["case"], a["component"]
    cdir = Path(root) / fidelity / "cases" / case
    base = {"reference": "averaging", "knob": "averaging time"}
    if not (cdir / "summary.json").exists() or not (cdir / "particles.parquet").exists():
        return [{**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": "missing",
                 "note": f"{case} has no results at {fidelity}"}]
    summary = json.loads((cdir / "summary.json").read_text())
    if summary.get("status") != "completed":
        return [{**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": summary.get("status"),
                 "note": f"{case} did not complete at {fidelity}"}]
    spin = float(summary.get("spinup_s", 0.0))
    df = pd.read_parquet(cdir / "particles.parquet", columns=["t_s", f"w{comp}_rad_s"])
    df = df[df["t_s"] > spin + 1e-12]
    series = df.assign(w=df[f"w{comp}_rad_s"].abs()).groupby("t_s")["w"].mean().sort_index()
    t = series.index.to_numpy(float)
    x = series.to_numpy(float)
    dt_sample = float(np.median(np.diff(t))) if t.size > 1 else float("nan")
    bench = read_benchmark(Path(root) / fidelity / "benchmarks" / f"{case}.simulate.tsv")
    wall, cpu = bench["s"], bench["cpu_time"]
    total = float(summary.get("simulated_seconds", np.nan))
    work = _work(summary)
    rows = []
    n = x.size
    k = 0
    while n // 2**k >= int(a["min_samples"]):
        m = n // 2**k
        # the interval of steady.mean_interval: >= 20 batches of >= 5 correlation times, else
        # overlapping batch means marked insufficient; only a sufficient window is recommended
        iv = steady.mean_interval(x[:m], dt_sample)
        mean, hw = iv["mean"], iv["ci95"]
        window = m * dt_sample
        frac = (spin + window) / total if total > 0 else float("nan")
        rows.append({**base, "run": f"{fidelity}/{case}/window_{window:.4g}s", "setting": f"{window:.3g} s", "is_base": k == 0, "value": mean, "reference_value": mean,
                     "error": hw / mean if mean > 0 else float("nan"), "error_signed": hw / mean if mean > 0 else float("nan"),
                     "error_what": f"95 % half-width / mean of |Omega_{comp}| ({BATCH_MEANS})",
                     "averaging_s": window, "simulated_s": spin + window, "samples": m,
                     "wall_s": wall * frac, "cpu_s": cpu * frac, "solver_s": work["solver_s"] * frac,
                     "steps": int(round(work["steps"] * frac)), "nodes": work["nodes"],
                     "node_updates": work["node_updates"] * frac, "particles": work["particles"],
                     "links": work["links"], "link_updates": work["link_updates"] * frac, "threads": work["threads"],
                     "dx_mm": float(summary["scene"]["numerics"]["dx_mm"]), "dt_s": float(summary["scene"]["numerics"]["dt_s"]),
                     "n_batches": iv["n_batches"], "batch_s": iv["batch_s"], "interval": iv["method"],
                     "status": "completed" if iv["sufficient"] else "insufficient",
                     "note": "cost pro-rated from the case's wall time to spin-up + window"
                             + ("" if iv["sufficient"] else f"; not recommendable: {iv['message']}")})
        k += 1
    if not rows:
        rows.append({**base, "run": f"{fidelity}/{case}", "setting": "(none)", "error": np.nan, "status": "completed",
                     "note": f"only {n} samples after spin-up: fewer than min_samples = {a['min_samples']}"})
    return rows


# ----------------------------------------------------------------------------------------------
# Pareto front and recommendation


def pareto_front(cost, error) -> np.ndarray:
    """Boolean mask of the points no other point beats: none is at most as costly and at most as
    wrong while strictly better in one of the two. Points with a non-finite value are never on
    the front."""
    c = np.asarray(cost, dtype=float)
    e = np.asarray(error, dtype=float)
    ok = np.isfinite(c) & np.isfinite(e)
    front = np.zeros(c.size, dtype=bool)
    idx = np.flatnonzero(ok)
    for i in idx:
        dominated = (c[idx] <= c[i]) & (e[idx] <= e[i]) & ((c[idx] < c[i]) | (e[idx] < e[i]))
        front[i] = not dominated.any()
    return front


def _unique_points(df: pd.DataFrame) -> pd.DataFrame:
    """One row per run of a reference (a base run is listed under several knobs)."""
    return df.drop_duplicates(subset=["reference", "run"]).reset_index(drop=True)


def cheapest_within(df: pd.DataFrame, target: float, cost: str = "wall_s") -> dict | None:
    """The cheapest row with ``error <= target`` (completed and, where measured, steady);
    ``None`` if no row qualifies."""
    ok = df[np.isfinite(df["error"].astype(float)) & (df["error"].astype(float) <= target)
            & (df.get("status", "completed") == "completed")]
    if "note" in ok:
        ok = ok[~ok["note"].fillna("").str.contains("not steady")]
    ok = ok[np.isfinite(ok[cost].astype(float))]
    if ok.empty:
        return None
    return ok.loc[ok[cost].astype(float).idxmin()].to_dict()


def _jsonable(v):
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return v


_KEEP = ("knob", "setting", "run", "dx_mm", "dt_factor", "dt_s", "collision", "wall", "precision", "tau", "mach",
         "error", "error_signed", "error_spread", "wall_s", "cpu_s", "solver_s", "steps", "nodes", "averaging_s", "simulated_s",
         "n_batches", "batch_s", "interval")


def recommend(df: pd.DataFrame, targets: dict, cost: str = "cpu_s", model: dict | None = None,
              case_scene=None, case_threads: int | None = None) -> dict:
    """The cheapest measured setting meeting each reference's target, the Pareto front of each
    reference, and a joint numerics setting (same dx, dt, collision, precision) meeting both the
    pipe and the drag targets, with its predicted wall time on ``case_scene`` (a Scene) when a
    cost ``model`` is given."""
    out: dict = {"targets": dict(targets), "cost": cost, "references": {}}
    for ref in REFERENCES:
        sub = _unique_points(df[df["reference"] == ref])
        entry: dict = {"target": targets.get(ref), "points": int(len(sub)),
                       "measured": int(np.isfinite(sub["error"].astype(float)).sum()) if len(sub) else 0}
        if len(sub):
            front = pareto_front(sub[cost], sub["error"])
            entry["pareto_front"] = [
                {k: sub.loc[i, k] for k in _KEEP if k in sub} for i in np.flatnonzero(front)]
            entry["pareto_front"].sort(key=lambda r: r[cost])
        target = targets.get(ref)
        best = cheapest_within(sub, target, cost) if (len(sub) and target is not None) else None
        if best is not None:
            entry["recommended"] = {k: best[k] for k in _KEEP if k in best}
            entry["verdict"] = "met"
        else:
            entry["verdict"] = "not met" if entry["measured"] else "not measurable"
            fin = sub[np.isfinite(sub["error"].astype(float))] if len(sub) else sub
            # an error whose interval rests on too few batches is no measurement of accuracy
            valid = fin[fin["status"].astype(str) != "insufficient"] if "status" in fin else fin
            if len(valid):
                most = valid.loc[valid["error"].astype(float).idxmin()]
                entry["most_accurate"] = {k: most[k] for k in _KEEP if k in most}
            elif len(fin):
                longest = fin.loc[fin[cost].astype(float).idxmax()]
                entry["no_valid_interval"] = {k: longest[k] for k in _KEEP if k in longest}
        out["references"][ref] = entry
    out["joint"] = _joint(df, targets, cost, model, case_scene, case_threads)
    return _jsonable(out)


def _joint(df, targets, cost, model, case_scene, case_threads=None) -> dict:
    keys = ["dx_mm", "dt_factor", "collision", "precision"]
    pipe = _unique_points(df[df["reference"] == "pipe"])
    drag = _unique_points(df[df["reference"] == "drag"])
    if pipe.empty or drag.empty:
        return {"verdict": "not measurable", "reason": "pipe or drag reference has no runs"}
    t_p, t_d = targets.get("pipe"), targets.get("drag")
    good_p = pipe[(pipe["error"].astype(float) <= t_p) & (pipe["status"] == "completed")]
    good_d = drag[(drag["error"].astype(float) <= t_d) & (drag["status"] == "completed")]
    both = good_p.merge(good_d, on=keys, suffixes=("_pipe", "_drag"))
    if both.empty:
        return {"verdict": "not met", "reason": (f"no tested setting of {', '.join(keys)} meets both the pipe "
                                                  f"({t_p:g}) and the drag ({t_d:g}) target")}
    both = both.assign(total=both[f"{cost}_pipe"] + both[f"{cost}_drag"])
    best = both.loc[both["total"].idxmin()]
    rec = {"verdict": "met", **{k: best[k] for k in keys}, "wall": best["wall_pipe"],
           "pipe_error": best["error_pipe"], "drag_error": best["error_drag"],
           "pipe_run": best["run_pipe"], "drag_run": best["run_drag"]}
    if model is not None and case_scene is not None:
        from ..scene import Scene
        from ..units import derive

        data = case_scene.model_dump(mode="json") if hasattr(case_scene, "model_dump") else copy.deepcopy(case_scene)
        dt_per_mm = float(best["dt_s_pipe"]) / float(best["dx_mm"])
        data["numerics"].update({"dx_mm": float(best["dx_mm"]), "dt_s": dt_per_mm * float(best["dx_mm"]),
                                 "collision": best["collision"], "wall": best["wall_pipe"],
                                 "precision": best["precision"], "mach_limit": 1.0})
        for g in (data.get("particles") or {}).get("packed", []):
            g.pop("file", None)
        if case_threads:
            data.setdefault("run", {})["threads"] = int(case_threads)
        try:
            sc = Scene.model_validate(data)
            rec["predicted_case_seconds"] = predict_seconds(sc, derive(sc), model)
            rec["predicted_case"] = sc.name
            rec["predicted_case_threads"] = sc.run.threads
        except Exception as exc:  # a recommendation is still useful without the prediction
            rec["predicted_case_error"] = str(exc)
    return rec


# ----------------------------------------------------------------------------------------------
# Cost model

COST_FEATURES = ("node_updates", "link_updates", "particle_steps")
#: links per unit surface area (lattice units) of a D3Q15 surface: sum over i of max(e_i.n, 0)
#: is 5 for an axis-aligned plane and 4.96 averaged over orientations
D3Q15_LINKS_PER_AREA = 5.0


def fit_cost_model(df: pd.DataFrame, target: str = "cpu_s") -> dict:
    """Fit ``seconds = c0 + (a node_updates + b link_updates + c particle_steps) / threads`` with
    non-negative coefficients, minimising the relative (not absolute) residuals, so that short
    and long runs count alike. On ``target = "cpu_s"`` (CPU seconds summed over threads) the work
    terms are not divided by the threads; the model then predicts wall time as the CPU time
    spread ideally over the threads. A feature that is zero in every row is left out
    (coefficient 0, listed under ``not_identified``). Returns the model dict
    :func:`predict_seconds` reads."""
    from scipy.optimize import nnls

    d = df[np.isfinite(df[target].astype(float)) & (df[target].astype(float) > 0)].copy()
    for c in COST_FEATURES:
        d[c] = d[c].astype(float).fillna(0.0) if c in d else 0.0
    per_thread = target != "cpu_s"
    thr = d["threads"].astype(float).clip(lower=1) if ("threads" in d and per_thread) else pd.Series(1.0, index=d.index)
    y = d[target].to_numpy(float)
    used = [c for c in COST_FEATURES if (d[c] > 0).any()]
    cols = [np.ones(len(d))] + [(d[c] / thr).to_numpy(float) for c in used]
    X = np.stack(cols, axis=1)
    # the formula names what was fitted: CPU seconds of the study's runs are not a wall time (the
    # production runs' wall-time model is lbmpipe.reproduction.runcost)
    model = {"formula": f"{target} = intercept_s + (s_per_node_update * node_updates + s_per_link_update * link_updates"
                        " + s_per_particle_step * particle_steps)" + (" / threads" if per_thread else ""),
             "target": target, "work_per_thread_in_fit": per_thread, "n_runs": int(len(d)),
             "intercept_s": 0.0, "s_per_node_update": 0.0, "s_per_link_update": 0.0, "s_per_particle_step": 0.0,
             "links_per_area_lu": D3Q15_LINKS_PER_AREA,
             "not_identified": [c for c in COST_FEATURES if c not in used]}
    if len(d) < X.shape[1]:
        model["note"] = f"{len(d)} runs for {X.shape[1]} coefficients: not fitted"
        return model
    w = 1.0 / y
    scale = np.abs(X).max(axis=0)
    scale[scale == 0] = 1.0
    coef, _ = nnls((X / scale) * w[:, None], y * w)
    coef = coef / scale
    names = {"node_updates": "s_per_node_update", "link_updates": "s_per_link_update",
             "particle_steps": "s_per_particle_step"}
    model["intercept_s"] = float(coef[0])
    for c, v in zip(used, coef[1:]):
        model[names[c]] = float(v)
    pred = X @ coef
    rel = pred / y - 1.0
    model["rel_rms_error"] = float(np.sqrt(np.mean(rel**2)))
    model["max_rel_error"] = float(np.max(np.abs(rel)))
    if model["s_per_node_update"] > 0:
        model["mlups_equivalent"] = 1e-6 / model["s_per_node_update"]
    return model


def model_predict_work(model: dict, node_updates, link_updates=0.0, particle_steps=0.0, threads=1,
                       wall: bool = True):
    """The cost model on work counts (arrays or scalars): wall seconds, or with ``wall=False``
    the quantity the model was fitted on (CPU seconds for a ``cpu_s`` model)."""
    per_thread = wall or model.get("work_per_thread_in_fit", True)
    t = np.maximum(np.asarray(threads, dtype=float), 1.0) if per_thread else 1.0
    return (model["intercept_s"] + (model["s_per_node_update"] * np.asarray(node_updates, float)
                                    + model["s_per_link_update"] * np.asarray(link_updates, float)
                                    + model["s_per_particle_step"] * np.asarray(particle_steps, float)) / t)


def _shape_area_volume(shape: str, diameter_mm=None, length_mm=None, edge_mm=None) -> tuple[float, float]:
    """Surface area (mm^2) and volume (mm^3) of one particle."""
    if shape == "sphere":
        r = diameter_mm / 2.0
        return 4 * math.pi * r * r, 4.0 / 3.0 * math.pi * r**3
    if shape == "cylinder":
        r = diameter_mm / 2.0
        return 2 * math.pi * r * r + 2 * math.pi * r * length_mm, math.pi * r * r * length_mm
    if shape == "cube":
        return 6 * edge_mm**2, edge_mm**3
    raise ValueError(f"unknown shape {shape!r}")


def scene_particle_load(scene) -> tuple[int, float]:
    """(particle count, total surface area in mm^2) a scene asks for: explicit bodies, random
    groups (count, or concentration of the domain volume) and the packed group (concentration
    of the pipe volume, rounded as the packer rounds it)."""
    ps = scene.particles
    if ps is None:
        return 0, 0.0
    dom = scene.domain
    vol = (math.pi * dom.diameter_mm**2 / 4 * dom.length_mm if dom.kind == "pipe"
           else float(np.prod(dom.size_mm)))
    n_tot, area = 0, 0.0
    for b in ps.bodies:
        a, _ = _shape_area_volume(b.shape, b.diameter_mm, b.length_mm, b.edge_mm)
        n_tot += 1
        area += a
    for g in list(ps.random) + list(ps.packed):
        a, v = _shape_area_volume(g.shape, g.diameter_mm, g.length_mm, g.edge_mm)
        count = getattr(g, "count", None)
        n = int(count) if count is not None else max(1, int(round(g.concentration * vol / v)))
        n_tot += n
        area += n * a
    return n_tot, area


def predict_seconds(scene, params, model: dict) -> float:
    """Predicted wall seconds of ``scene`` (a validated ``Scene``) with lattice parameters
    ``params`` (``lbmpipe.units.derive``) under a cost ``model`` (``fit_cost_model`` or
    ``cost_model.json``). Particle links are estimated from the particles' surface area,
    ``links_per_area_lu * area / dx^2``; threads are the scene's ``run.threads`` (or the model's
    ``threads``, default 1)."""
    steps = float(params.n_steps)
    node_updates = float(params.fluid_nodes) * steps
    count, area_mm2 = scene_particle_load(scene)
    links = float(model.get("links_per_area_lu", D3Q15_LINKS_PER_AREA)) * area_mm2 / scene.numerics.dx_mm**2
    threads = scene.run.threads or model.get("threads", 1)
    return float(model_predict_work(model, node_updates, links * steps, count * steps, threads))


def links_per_area(summary: dict, static_csv: Path | None = None, scene_data: dict | None = None) -> float:
    """Measured links per unit particle area (lattice units) of one run: ``particles.links`` of
    the summary over the particles' area from ``particles_static.csv`` (or the scene's bodies)."""
    links = float((summary.get("particles") or {}).get("links", 0) or 0)
    dx = float(((summary.get("scene") or {}).get("numerics") or {}).get("dx_mm", np.nan))
    area = 0.0
    if static_csv is not None and Path(static_csv).exists():
        st = pd.read_csv(static_csv)
        for _, r in st.iterrows():
            kw = {k: (None if pd.isna(r.get(k)) else float(r[k])) for k in ("diameter_mm", "length_mm", "edge_mm")}
            area += _shape_area_volume(r["shape"], **kw)[0]
    elif scene_data is not None:
        for b in (scene_data.get("particles") or {}).get("bodies", []):
            area += _shape_area_volume(b["shape"], b.get("diameter_mm"), b.get("length_mm"), b.get("edge_mm"))[0]
    if not (links > 0 and area > 0 and np.isfinite(dx)):
        return float("nan")
    return links / (area / dx**2)


def case_cost_rows(config: dict, fidelity: str, root: Path = Path("results")) -> list[dict]:
    """Work and wall time of the pipeline's case runs at ``fidelity`` that have a benchmark file
    and a completed summary (the cases are not inputs of the study: whatever exists is used)."""
    rows = []
    bdir = Path(root) / fidelity / "benchmarks"
    for bench in sorted(bdir.glob("*.simulate.tsv")) if bdir.exists() else []:
        case = bench.name.removesuffix(".simulate.tsv")
        summ = Path(root) / fidelity / "cases" / case / "summary.json"
        if not summ.exists():
            continue
        summary = json.loads(summ.read_text())
        if summary.get("status") != "completed":
            continue
        b = read_benchmark(bench)
        row = {"source": "case", "run": case, **_work(summary), "wall_s": b["s"], "cpu_s": b["cpu_time"],
               "links_per_area_lu": links_per_area(summary, Path(root) / fidelity / "cases" / case / "particles_static.csv")}
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Collect, report


def collect(config: dict, fidelity: str, root: Path = Path("results")) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Read every study run, the case runs and the other fidelity levels; returns
    (accuracy-cost table, per-run cost table with the model's prediction, cost model)."""
    s = study_settings(config, fidelity)
    runs = plan(config, fidelity)
    sdir = Path(root) / fidelity / "study"
    recs = []
    for rid, spec in sorted(runs.items()):
        rdir = sdir / "runs" / rid
        if not (rdir / "summary.json").exists():
            continue
        recs.append(run_record(rid, spec, rdir, sdir / "benchmarks" / f"{rid}.tsv", s))
    rec_df = pd.DataFrame(recs)
    rows: list[dict] = []
    if len(rec_df):
        for ref in ("pipe", "drag"):
            rows += _rows_for_reference(rec_df[rec_df["reference"] == ref], s, ref)
    rows += observable_rows(config, fidelity, root)
    rows += averaging_rows(config, fidelity, root)
    table = pd.DataFrame(rows)
    first = ["reference", "knob", "setting", "error", "wall_s", "cpu_s", "steps", "nodes", "is_base", "run", "dx_mm",
             "dt_factor", "dt_s", "collision", "wall", "precision", "tau", "mach", "error_signed", "error_spread",
             "value", "reference_value", "error_what", "solver_s", "setup_s", "node_updates", "particles", "links",
             "link_updates", "threads", "simulated_s", "steady_rel_change", "status", "note"]
    table = table[[c for c in first if c in table] + [c for c in table if c not in first]]

    cost_rows = []
    for r in recs:
        cost_rows.append({"source": "study", "run": r["run"], **{k: r[k] for k in (
            "steps", "nodes", "node_updates", "particles", "links", "link_updates", "particle_steps", "threads",
            "solver_s", "setup_s", "simulated_s", "wall_s", "cpu_s")},
            "links_per_area_lu": links_per_area({"particles": {"links": r["links"]},
                                                 "scene": {"numerics": {"dx_mm": r["dx_mm"]}}},
                                                scene_data=runs[r["run"]]["scene"]) if r["links"] else np.nan})
    cost_rows += case_cost_rows(config, fidelity, root)
    cost_df = pd.DataFrame(cost_rows)
    model = fit_cost_model(cost_df, target=s["cost"]) if len(cost_df) else {"n_runs": 0, "note": "no runs"}
    lpa = cost_df["links_per_area_lu"].astype(float) if "links_per_area_lu" in cost_df else pd.Series(dtype=float)
    if lpa.notna().any():
        model["links_per_area_lu"] = float(lpa.median())
    model["threads"] = int(s["threads"])
    model["fidelity"] = fidelity
    model["sources"] = {k: int(v) for k, v in cost_df["source"].value_counts().items()} if len(cost_df) else {}
    if len(cost_df) and "intercept_s" in model:
        cost_df["predicted_s"] = model_predict_work(model, cost_df["node_updates"], cost_df["link_updates"],
                                                    cost_df["particle_steps"], cost_df["threads"], wall=False)
    return table, cost_df, model


def markdown_table(table: pd.DataFrame) -> str:
    """The accuracy-cost table as Markdown, one section per reference."""
    lines = []
    titles = {"pipe": "Pipe Poiseuille (analytic), Re 9.4", "drag": "Sphere drag in a simple cubic array (Zick & Homsy)",
              "omega": "Mean |Omega| of a particle case towards the finest level",
              "averaging": "Averaging time: 95 % half-width of mean |Omega_x|"}

    def f(v, spec):
        try:
            return "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)
        except (TypeError, ValueError):
            return str(v)

    for ref in REFERENCES:
        sub = table[table["reference"] == ref]
        if sub.empty:
            continue
        lines += [f"### {titles[ref]}", ""]
        what = sub["error_what"].dropna().unique() if "error_what" in sub else []
        if len(what):
            lines += [f"error: {what[0]}", ""]
        lines += ["| knob | setting | error | wall s | CPU s | solver s | steps | nodes | tau | Mach | note |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for _, r in sub.iterrows():
            base = " (base)" if r.get("is_base") is True and ref in ("pipe", "drag") else ""
            lines.append(f"| {r['knob']} | {r['setting']}{base} | {f(r.get('error'), '.3g')} | {f(r.get('wall_s'), '.3g')} | "
                         f"{f(r.get('cpu_s'), '.3g')} | {f(r.get('solver_s'), '.3g')} | {f(r.get('steps'), '.0f')} | {f(r.get('nodes'), '.0f')} | "
                         f"{f(r.get('tau'), '.3f')} | {f(r.get('mach'), '.3f')} | {r.get('note') if isinstance(r.get('note'), str) else ''} |")
        lines.append("")
    return "\n".join(lines)


def recommendation_markdown(rec: dict, model: dict | None = None) -> str:
    """``recommendation.md``: the targets, the cheapest setting meeting each, the joint setting."""
    out = ["# Accuracy against cost: recommendation", "",
           f"Computed by `lbmpipe.reproduction.study.recommend` from `accuracy_cost.csv`; cost = `{rec['cost']}` "
           + ("(CPU seconds of each run's process, start-up included; for the case runs the benchmark's sampled "
              "CPU time)" if rec["cost"] == "cpu_s" else "(wall seconds of the Snakemake benchmark, start-up included)")
           + ".", ""]
    names = {"pipe": "pipe profile error", "drag": "sphere drag error", "omega": "mean |Omega| vs finest level",
             "averaging": "relative 95 % half-width of mean |Omega_x|"}
    for ref, e in rec["references"].items():
        t = e.get("target")
        head = f"- **{names[ref]}** (target {t:g}): " if t is not None else f"- **{names[ref]}**: "
        if e.get("verdict") == "met":
            r = e["recommended"]
            desc = _describe(ref, r)
            rests = (f" (the interval rests on {r['n_batches']} batches of {r['batch_s']:.3g} s, {r['interval']})"
                     if r.get("n_batches") else "")
            out.append(head + f"cheapest meeting it: {desc}, error {r['error']:.3g}, "
                              f"{r.get(rec['cost'], float('nan')):.3g} s{rests}.")
        elif e.get("verdict") == "not met" and "no_valid_interval" in e:
            r = e["no_valid_interval"]
            out.append(head + "not met: no tested setting has an interval that rests on 20 batches of 5 correlation "
                              f"times; the longest, {_describe(ref, r)}, has {r.get('n_batches', 0):g} batch(es) of "
                              f"{r.get('batch_s', float('nan')):.3g} s ({r.get('interval', '')}).")
        elif e.get("verdict") == "not met":
            r = e.get("most_accurate", {})
            out.append(head + f"not met by any tested setting; the most accurate was {_describe(ref, r)} "
                              f"(error {r.get('error', float('nan')):.3g}, {r.get(rec['cost'], float('nan')):.3g} s).")
        else:
            out.append(head + "not measurable with the results present.")
    j = rec.get("joint", {})
    out.append("")
    if j.get("verdict") == "met":
        line = (f"**Joint setting** meeting the pipe and drag targets at the least cost: dx = {j['dx_mm']:g} mm, "
                f"dt = {j['dt_factor']:g} x the paper's dt per mm, {j['collision']}, wall {j['wall']}, {j['precision']} "
                f"(pipe error {j['pipe_error']:.3g}, drag error {j['drag_error']:.3g}).")
        if j.get("predicted_case_seconds") is not None:
            what = "CPU time" if (model or {}).get("target") == "cpu_s" else "wall time"
            line += (f" Predicted {what} of case `{j['predicted_case']}` with it on {j.get('predicted_case_threads')} "
                     f"thread(s): {j['predicted_case_seconds']:.3g} s (the study's cost model below; a production "
                     f"run's wall time: the level's `tables/cost_model.json`).")
        out.append(line)
    else:
        out.append(f"**Joint setting**: {j.get('verdict')}: {j.get('reason', '')}")
    if model:
        out += ["", f"Cost model ({model.get('n_runs')} runs, relative rms error {model.get('rel_rms_error', float('nan')):.2g}): "
                    f"{model.get('formula')}, intercept {model.get('intercept_s', 0):.3g} s, "
                    f"{model.get('s_per_node_update', 0):.3g} s/node update, {model.get('s_per_link_update', 0):.3g} s/link update, "
                    f"{model.get('s_per_particle_step', 0):.3g} s/particle step."]
    return "\n".join(out) + "\n"


def _describe(ref: str, r: dict) -> str:
    if not r:
        return "(none)"
    if ref in ("pipe", "drag"):
        wall = f", wall {r.get('wall')}" if ref == "pipe" else ""
        return (f"dx = {r.get('dx_mm', float('nan')):g} mm, dt = {r.get('dt_factor', float('nan')):g} x paper "
                f"({r.get('dt_s', float('nan')):.3g} s), {r.get('collision')}{wall}, {r.get('precision')} [{r.get('knob')}]")
    if ref == "averaging":
        return f"averaging {r.get('averaging_s', float('nan')):.3g} s after spin-up"
    return f"level {r.get('setting')} (dx = {r.get('dx_mm', float('nan')):g} mm)"


def _log_axes(ax) -> None:
    """Log axes labelled at 1, 2, 5 x 10^k in plain numbers: the study's ranges are often
    narrower than a decade, where matplotlib would print overlapping minor labels."""
    from matplotlib import ticker

    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        axis.set_minor_formatter(ticker.NullFormatter())


_KNOB_STYLE = {"dx": ("C0", "o"), "dt": ("C1", "s"), "wall": ("C2", "^"), "collision": ("C3", "D"),
               "precision": ("C4", "v"), "fidelity": ("C5", "o"), "averaging time": ("C6", "o")}


def plot_accuracy_cost(table: pd.DataFrame, rec: dict, stem: Path, title: str = "") -> list[Path]:
    """Log-log error against wall time, one panel per reference; knobs by colour, the base
    setting as a black star, the Pareto front as a line, the target dashed, the recommendation
    circled."""
    from .figures import plt, save

    cost = rec.get("cost", "wall_s")
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    titles = {"pipe": "pipe Poiseuille profile (L2)", "drag": "sphere-array drag K",
              "omega": "mean |Omega| vs finest level", "averaging": "95 % half-width of mean |Omega_x|"}
    for ax, ref in zip(axes.ravel(), REFERENCES):
        sub = table[table["reference"] == ref]
        ax.set_title(titles[ref], fontsize=9)
        what = {"wall_s": "wall time (s, benchmark)", "cpu_s": "CPU time (s)"}.get(cost, cost)
        ax.set_xlabel(what if ref != "averaging" else f"{what}, pro-rated from the case run")
        ax.set_ylabel("relative error")
        pts = sub[np.isfinite(sub["error"].astype(float)) & (sub["error"].astype(float) > 0)] if len(sub) else sub
        pts = pts[np.isfinite(pts[cost].astype(float))] if len(pts) else pts
        if pts.empty:
            note = "; ".join(str(n) for n in sub.get("note", pd.Series(dtype=str)).dropna().unique()) if len(sub) else ""
            ax.text(0.5, 0.5, "no measurable points\n" + note, ha="center", va="center", fontsize=8,
                    transform=ax.transAxes, wrap=True)
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        seen = set()
        k = 0
        for _, r in pts.iterrows():
            knob = r["knob"]
            if knob not in _KNOB_STYLE:
                _KNOB_STYLE[knob] = (f"C{7 + k % 3}", "P")
                k += 1
            color, marker = _KNOB_STYLE[knob]
            if r.get("is_base") is True and ref in ("pipe", "drag"):
                color, marker, label = "k", "*", "base"
            else:
                label = knob
            ax.plot(r[cost], r["error"], marker=marker, color=color, ls="none", ms=7 if marker == "*" else 5,
                    label=None if label in seen else label)
            seen.add(label)
            if ref in ("pipe", "drag") and not r.get("is_base"):
                ax.annotate(str(r["setting"]).replace(" x paper", ""), (r[cost], r["error"]), fontsize=5,
                            xytext=(3, 2), textcoords="offset points")
            elif ref in ("omega", "averaging"):
                ax.annotate(str(r["setting"]), (r[cost], r["error"]), fontsize=6, xytext=(3, 2), textcoords="offset points")
        u = _unique_points(pts)
        front = pareto_front(u[cost], u["error"])
        fr = u[front].sort_values(cost)
        ax.step(fr[cost], fr["error"], where="post", color="0.4", lw=1.0, zorder=0, label="Pareto front")
        ent = rec["references"].get(ref, {})
        if ent.get("target") is not None:
            ax.axhline(ent["target"], color="0.5", ls="--", lw=0.8, label=f"target {ent['target']:g}")
        if ent.get("verdict") == "met":
            rr = ent["recommended"]
            ax.plot(rr[cost], rr["error"], "o", mfc="none", mec="r", ms=13, mew=1.5, label="recommended")
        _log_axes(ax)
        ax.legend(fontsize=6, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, stem)


def plot_cost_model(cost_df: pd.DataFrame, model: dict, stem: Path, title: str = "") -> list[Path]:
    """Predicted against measured time (the quantity the model was fitted on) of every run the
    cost model was fitted on."""
    from .figures import plt, save

    target = model.get("target", "wall_s")
    what = {"wall_s": "wall time", "cpu_s": "CPU time"}.get(target, target)
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    d = cost_df[np.isfinite(cost_df[target].astype(float))] if (len(cost_df) and target in cost_df) else cost_df.iloc[0:0]
    if len(d) and "predicted_s" in d:
        for src, marker in (("study", "o"), ("case", "s")):
            s = d[d["source"] == src]
            if len(s):
                ax.plot(s[target], s["predicted_s"], marker, ls="none", ms=4, label=f"{src} runs ({len(s)})")
        lo = float(np.nanmin([d[target].min(), d["predicted_s"].min()])) * 0.8
        hi = float(np.nanmax([d[target].max(), d["predicted_s"].max()])) * 1.25
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="predicted = measured")
        _log_axes(ax)
        ax.legend(fontsize=7, frameon=False)
    ax.set_xlabel(f"measured {what} (s, Snakemake benchmark)")
    ax.set_ylabel(f"predicted {what} (s)")
    ax.set_title((title + "\n" if title else "") + f"relative rms error {model.get('rel_rms_error', float('nan')):.2g}",
                 fontsize=8)
    fig.tight_layout()
    return save(fig, stem)


def report(config: dict, fidelity: str, table: pd.DataFrame, cost_df: pd.DataFrame, model: dict,
           out_dir: Path) -> dict:
    """Write the figures, ``accuracy_cost.md``, ``recommendation.json`` and ``.md`` into
    ``out_dir``; returns the recommendation."""
    from .cases import case_scene

    s = study_settings(config, fidelity)
    out_dir = Path(out_dir)
    table = table.copy()
    if "is_base" in table:  # a CSV round trip turns the column into strings or objects
        table["is_base"] = table["is_base"].map(lambda v: str(v) == "True")
    case = s["observable"]["case"]
    scene = None
    if case in config.get("cases", {}):
        fid = config["fidelities"][fidelity]
        scene = case_scene(case, config["cases"][case], fidelity, fid)
    rec = recommend(table, s["targets"], cost=s["cost"], model=model, case_scene=scene,
                    case_threads=int(config["fidelities"][fidelity].get("threads", 1)))
    rec["fidelity"] = fidelity
    write_json(out_dir / "recommendation.json", rec)
    (out_dir / "recommendation.md").write_text(recommendation_markdown(rec, model))
    (out_dir / "accuracy_cost.md").write_text(f"# Accuracy against cost ({fidelity})\n\n" + markdown_table(table))
    plot_accuracy_cost(table, rec, out_dir / "accuracy_cost", title=f"accuracy against cost, fidelity {fidelity}")
    plot_cost_model(cost_df, model, out_dir / "cost_model", title=f"cost model, fidelity {fidelity}")
    return rec
