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
included), the solver's stepping seconds are kept beside them; ``runcost.fit_cost_model`` fits
``wall_s = c0 + (a node_updates + b link_updates + c particle_steps) / threads`` to the study's
runs and the case runs, and ``lbmpipe.cost.predict`` evaluates it for any scene.

This module plans the study (its settings, the scene of every run) and runs it;
:mod:`lbmpipe.reproduction.study_errors` reads each run's error, :mod:`lbmpipe.reproduction.study`
recommends a setting and writes the reports.
"""

from __future__ import annotations

import copy
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from ..outputs import write_json
from ..scene import Scene
from ..run import run_scene
from ..units import derive
from . import steady
from .pipe import DENSITY_KG_M3, DT_PER_MM_S, FLOWS, PIPE, time_step
from .pipe import pipe_scene as paper_pipe_scene


#: the interval estimator the averaging study names in its rows
BATCH_MEANS = f"{steady.mean_interval.__module__}.{steady.mean_interval.__name__}"


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
    if "mach_factor" in fid:  # the level's Mach knob (cases.fidelity_numerics)
        dt_per_mm *= float(fid["mach_factor"])
    num = fid.get("numerics", {}) or {}
    base = {"dx_mm": dx, "dt_factor": 1.0, "collision": num.get("collision", "bgk"),
            "wall": num.get("wall", "bounce_back"), "precision": num.get("precision", "float64")}
    s["base"] = _merge(base, s.get("base", {}))
    s["dt_per_mm_s"] = float(s.get("dt_per_mm_s", dt_per_mm))
    return s


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
