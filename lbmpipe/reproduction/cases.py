"""The paper's cases as scenes: the case matrix of the pipeline's config turned into scene dicts.

The Snakemake layer only names cases and fidelity levels; this module decides what a case means
physically (paper/reading.md "Parameters"): the paper's pipe and flow rates (``pipe``), the particles (a
dense random packing of one shape at 30 % or 50 %, collisions on or off), and how a fidelity level
sets the lattice (``pipe.time_step``: the paper's Mach number at every level).

Packings are made in mm, independent of the lattice, so one packing (shape, concentration, seed)
serves every fidelity level and both Reynolds numbers: the Re 9.4 and Re 26 runs of a shape start
from the same particles, as do the runs with and without collisions.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import jsonschema
import numba
import pandas as pd
import yaml

from ..cost import predict
from ..outputs import git_commit, write_json
from ..particles.packing import count_for_concentration
from ..particles.placement import PACKING_COLUMNS, PARQUET_COLUMNS, STATIC_COLUMNS, packed_group, write_packing
from ..particles.shapes import make_shape
from ..scene import Scene, SceneError, load_scene
from ..run import run_scene
from ..units import derive
from . import unpackable
from .pipe import DT_PER_MM_S, FLOWS, PIPE, pipe_scene, time_step


#: The numerical methods a level can run (its ``method`` key; ``numerics`` of the scene, merged under
#: the level's own ``numerics``).
#:
#: - ``paper``: BGK, Eq. (2), with half-way bounce-back at the pipe wall and Ladd's coupling at the
#:   particles, Eqs. (8)-(12), as the paper (the scene's defaults); the wall then sits at a place that
#:   depends on tau (1.78 at Re 9.4).
#: - ``accurate_fluid``: TRT with the magic parameter 1/4 and the Bouzidi interpolated pipe wall, the
#:   paper's particle side (Ladd's bounce-back, momentum exchange, equilibrium refill). The level
#:   ``credible_accurate`` ran with it (it was ``accurate`` before issue 44).
#: - ``accurate``: the best particle options of issue 44 with TRT and the Bouzidi pipe wall
#:   (benchmarks/README.md, "Issue 44"): the CLI particle surface (within 0.9 % of Zick & Homsy and
#:   0.5 % of the rotating sphere's torque at tau 1 and 1.78), Galilean-invariant momentum exchange
#:   (17-33 times less force jitter when nodes are covered or uncovered), lubrication on (the
#:   Brenner check), TRT magic 3/16 (CLI's exact closure; the Bouzidi pipe wall is as good with it as
#:   with 1/4: ``benchmarks/trt_magic.py``). The refill stays the equilibrium one: the extrapolated
#:   refill did not reduce the mass the correction puts back and costs more.
METHODS = {
    "paper": {},
    "accurate_fluid": {"collision": "trt", "trt_magic": 0.25, "wall": "bouzidi"},
    "accurate": {"collision": "trt", "trt_magic": 0.1875, "wall": "bouzidi", "particle_boundary": "cli",
                 "momentum_exchange": "galilean", "lubrication": {"enabled": True}},
}


def method_numerics(config: dict, level: str, against: str | None = None) -> dict:
    """The scene ``numerics`` a level's method sets (:data:`METHODS` under the level's own
    ``numerics``), without the lattice (dx, dt); with ``against``, only the entries that differ from
    that level's (what the method comparison changes)."""
    def own(name):
        fid = config["fidelities"][name]
        return {k: v for k, v in {**METHODS[fid.get("method", "paper")], **fid.get("numerics", {})}.items()
                if k not in ("dx_mm", "dt_s")}
    mine = own(level)
    if against is None:
        return mine
    base = own(against)
    return {k: v for k, v in mine.items() if base.get(k) != v}


def numerics_text(numerics: dict) -> str:
    """``numerics`` as one line for a document: ``collision: trt, wall: bouzidi, lubrication.enabled:
    true`` (nested models flattened with dots); ``the scene's defaults`` if empty."""
    def flat(d, pre=""):
        for k, v in d.items():
            if isinstance(v, dict):
                yield from flat(v, f"{pre}{k}.")
            else:
                yield f"{pre}{k}: {str(v).lower() if isinstance(v, bool) else v}"
    return ", ".join(flat(numerics)) or "the scene's defaults"


def fidelity_numerics(fidelity: dict, reynolds: float | None = None) -> dict:
    """Scene ``numerics`` for a fidelity level: its ``method`` (:data:`METHODS`; the ``paper``
    method is the scene's defaults), ``dx_mm`` and ``dt_s`` (or ``dt_per_mm_s``); at Re 26 the
    time step is multiplied by ``re26_dt_factor`` (default 1): the paper's dt gives a centre-line
    Mach number of 0.56 there; 0.5 halves it (Mach 0.28, paper/reading.md's third row).

    ``mach_factor`` (default 1, the Mach knob) multiplies every time step of the level, at both
    Reynolds numbers, at fixed dx: the same physical case (viscosity, flow rate, run length) at a
    lattice Mach number times the factor, ``tau - 1/2`` times the factor. A level without it
    writes the same scenes as before it existed."""
    num = {**METHODS[fidelity.get("method", "paper")], **fidelity.get("numerics", {})}
    dx = float(fidelity["dx_mm"])
    num["dx_mm"] = dx
    num["dt_s"] = float(fidelity.get("dt_s", time_step(dx, fidelity.get("dt_per_mm_s", DT_PER_MM_S))))
    if reynolds is not None and float(reynolds) == 26.0:
        num["dt_s"] *= float(fidelity.get("re26_dt_factor", 1.0))
    if "mach_factor" in fidelity:
        num["dt_s"] *= float(fidelity["mach_factor"])
    return num


def mach_factor_problems(name: str, fidelity: dict) -> list[str]:
    """Problems of level ``name``'s ``mach_factor``, one line each: the run's duration, spin-up and
    sample interval (and ``duration_s_by_case``) must stay whole numbers of the time step it gives
    at each Reynolds number (a scene rounds them to whole steps, which would change the sampling
    silently). Empty without a ``mach_factor``."""
    if "mach_factor" not in fidelity:
        return []
    run = fidelity["run"]
    times = {f"run.{k}": float(run[k]) for k in ("duration_s", "spinup_s", "sample_interval_s")}
    times.update({f"duration_s_by_case.{c}": float(t) for c, t in fidelity.get("duration_s_by_case", {}).items()})
    out = []
    for re in sorted(FLOWS):
        dt = fidelity_numerics(fidelity, re)["dt_s"]
        for key, t in times.items():
            steps = t / dt
            if t > 0 and abs(steps - round(steps)) > 1e-6 * max(steps, 1.0):
                out.append(f"config error in fidelities.{name}.mach_factor: {fidelity['mach_factor']:g} gives dt = "
                           f"{dt:.6g} s at Re {re:g}, and {key} = {t:g} s is {steps:.6g} steps, not a whole number. "
                           "Fix: a factor that keeps every run time a whole number of steps (0.5 or 0.25 for the "
                           "committed levels), or adjust the run times")
                return out
    return out


def case_scene(name: str, case: dict, fidelity_name: str, fidelity: dict, packing_file: str | Path | None = None) -> dict:
    """Scene dict (physical units) for one case of the config at one fidelity level; a particle
    case reads its packing from ``packing_file`` when given (relative to the scene file)."""
    re = float(case["reynolds"])
    if re not in FLOWS:
        raise ValueError(f"case {name}: reynolds must be one of {sorted(FLOWS)} (the paper's flows), got {re}")
    run = fidelity["run"]
    # Few large particles give few independent samples per second: such cases average longer.
    part = case.get("particles")
    label = name if part is None or "seed" not in part else f"{name}_s{int(part['seed'])}"
    scene = pipe_scene(f"{label}_{fidelity_name}", re, fidelity_numerics(fidelity, re),
                       {"duration_s": float(fidelity.get("duration_s_by_case", {}).get(name, run["duration_s"])),
                        "spinup_s": run["spinup_s"], "sample_interval_s": run["sample_interval_s"]})
    if "mach_limit" in fidelity:
        scene["numerics"]["mach_limit"] = fidelity["mach_limit"]
    if part is not None:
        group = {k: part[k] for k in ("shape", "diameter_mm", "length_mm", "edge_mm", "concentration") if k in part}
        group["seed"] = int(part.get("seed", DEFAULT_SEED))
        if packing_file is not None:
            group["file"] = str(packing_file)
        # A case without collisions (claim 14) switches off the particle-particle contacts only: the
        # pipe wall still holds the particles in (with the wall contacts off too they leave the pipe).
        scene["particles"] = {"packed": [group], "collisions": {"pairs": bool(case.get("collisions", True)),
                                                                **fidelity.get("particle_collisions", {})}}
    return scene


#: packing seed of a case that names none
DEFAULT_SEED = 1


def packing_id(case: dict) -> str | None:
    """Name of the packing a case starts from (shared by the cases with the same shape, size,
    concentration and seed), e.g. ``cube8_c30_s1``; ``None`` for a particle-free case."""
    p = case.get("particles")
    if p is None:
        return None
    size = {"cube": lambda: f"cube{p['edge_mm']:g}", "cylinder": lambda: f"cyl{p['diameter_mm']:g}x{p['length_mm']:g}",
            "sphere": lambda: f"sphere{p['diameter_mm']:g}"}[p["shape"]]()
    return f"{size}_c{round(100 * p['concentration']):d}_s{int(p.get('seed', DEFAULT_SEED))}"


def with_seed(case: dict, seed: int | None) -> dict:
    """The case with its packing seed set to ``seed`` (unchanged when ``None`` or particle-free)."""
    if seed is None or case.get("particles") is None:
        return case
    out = copy.deepcopy(case)
    out["particles"]["seed"] = int(seed)
    return out


def split_run(run: str) -> tuple[str, int | None]:
    """``"cyl8x8_c30_re9.4/seed2"`` -> ``("cyl8x8_c30_re9.4", 2)``; a run without a seed part
    (levels with one packing per case, particle-free cases) -> ``(run, None)``."""
    name, _, seed = run.partition("/seed")
    return name, (int(seed) if seed else None)


def run_case(config: dict, run: str) -> tuple[str, dict]:
    """Case name and case dict of a run (a case, or one seed of it: ``split_run``)."""
    name, seed = split_run(run)
    return name, with_seed(config["cases"][name], seed)


def level_seeds(fidelity: dict) -> list[int]:
    """The packing seeds a fidelity level runs for every particle case: ``[1, ..., seeds]``, or the
    seeds a list names (``seeds: [3]``: one packing of another level again)."""
    seeds = fidelity.get("seeds", 1)
    if isinstance(seeds, list):
        return sorted(int(k) for k in seeds)
    return list(range(1, int(seeds) + 1))


def level_cases(config: dict, fidelity_name: str) -> list[str]:
    """The cases a level runs: those of its ``cases`` list (a subset of the config's, e.g. a second
    method run on the cases its claims need) that the config defines, else every case of the
    config. Names the config does not define are skipped, so a config trimmed to fewer cases (a
    test, a quick look) keeps its levels valid."""
    subset = config["fidelities"][fidelity_name].get("cases")
    return sorted(config["cases"] if subset is None else [c for c in subset if c in config["cases"]])


def level_runs(config: dict, fidelity_name: str) -> list[str]:
    """Every simulation run of a level: each particle-free case, and each particle case once per
    packing seed (``case/seed<k>``) in a level with ``seeds``, else once (``case``); only the
    level's ``cases`` when it names them. A case the config declares unpackable
    (:mod:`lbmpipe.reproduction.unpackable`) has no run: nothing is planned for it."""
    fid = config["fidelities"][fidelity_name]
    runs = []
    for name in level_cases(config, fidelity_name):
        if unpackable.declared(config["cases"][name]):
            continue
        if config["cases"][name].get("particles") is None or "seeds" not in fid:
            runs.append(name)
        else:
            runs += [f"{name}/seed{k}" for k in level_seeds(fid)]
    return runs


def packing_case(config: dict, pid: str) -> tuple[str, dict]:
    """A case of the config that uses packing ``pid`` (any one: they share it), with the seed
    the packing names."""
    seed = int(pid.rsplit("_s", 1)[1])
    for name, case in config["cases"].items():
        if case.get("particles") is not None and packing_id(with_seed(case, seed)) == pid:
            return name, with_seed(case, seed)
    raise ValueError(f"no case of the config uses packing {pid!r}")


def pack_case(config: dict, pid: str, out_csv: Path, out_json: Path) -> dict:
    """Make packing ``pid`` (in mm; ``lbmpipe.particles.packing``) and write it as CSV plus a JSON record
    (``status`` packed | unpackable, target and achieved concentration, seconds, message).

    An unreachable target is a result, not a failure: the record says ``unpackable`` with the
    highest concentration reached, the CSV holds only its header, and the cases that use it are
    reported as not packable instead of stopping the pipeline."""
    name, case = packing_case(config, pid)
    fid_name = next(iter(config["fidelities"]))
    data = case_scene(name, case, fid_name, config["fidelities"][fid_name])
    data["particles"]["packed"][0]["max_seconds"] = float(config.get("packing_max_seconds", 60.0))
    scene = Scene.model_validate(data)
    group = scene.particles.packed[0]
    Path(out_csv).parent.mkdir(parents=True, exist_ok=True)
    try:
        x, q, info = packed_group(group, scene)
    except SceneError as exc:

        size = {k.removesuffix("_mm"): getattr(group, k) for k in ("diameter_mm", "length_mm", "edge_mm")
                if getattr(group, k) is not None}
        kind, h = make_shape({"shape": group.shape, **size})
        reached = float(getattr(exc, "reached", float("nan")))
        info = {"status": "unpackable", "packing": pid, "concentration_target": group.concentration,
                "concentration_reached": reached, "seed": group.seed, "message": exc.message,
                "count": count_for_concentration(kind, h, PIPE["diameter_mm"] / 2, PIPE["length_mm"], group.concentration)}
        Path(out_csv).write_text(",".join(PACKING_COLUMNS) + "\n")
    else:
        info = {"status": "packed", "packing": pid, **info}
        write_packing(Path(out_csv), x, q)
    write_json(out_json, info)
    return info


def write_unpackable(case_dir: Path, case_name: str, packing_info: dict) -> None:
    """Outputs of a case whose packing could not be made: a summary with status ``unpackable``
    (target, highest concentration reached, message) and empty tables, so that statistics and
    figures list the case as not packable."""

    case_dir = Path(case_dir)
    case_dir.mkdir(parents=True, exist_ok=True)
    summary = {"status": "unpackable", "case": case_name,
               "message": f"not run: the packing could not be made ({packing_info.get('message', '')})",
               "steps": 0, "simulated_seconds": 0.0, "wall_seconds": 0.0, "spinup_s": 0.0,
               "packing": {k: packing_info.get(k) for k in ("packing", "concentration_target", "concentration_reached",
                                                             "count", "seed", "message")},
               "particles": {"count": 0, "concentration_target": packing_info.get("concentration_target"),
                             "concentration_achieved": packing_info.get("concentration_reached")}}
    write_json(case_dir / "summary.json", summary)
    pd.DataFrame(columns=list(PARQUET_COLUMNS), dtype="float64").to_parquet(case_dir / "particles.parquet", index=False)
    (case_dir / "particles_static.csv").write_text(",".join(STATIC_COLUMNS) + "\n")
    (case_dir / "profile.csv").write_text("r_mm,uz_m_s,uz_poiseuille_m_s,nodes\n")
    (case_dir / "flow_rate.csv").write_text("t_s,q_m3_s,force_density_N_m3,max_density_deviation,core_velocity_ratio\n")


def estimate_minutes(config: dict, fidelity_name: str, case_name: str, root: Path = Path("."),
                     scene: Scene | None = None) -> int:
    """Wall-time estimate of one case in whole minutes, for the cluster profile's ``runtime``
    resource (its time limit) and the jobs' priorities: the wall-time model of the production runs
    (``lbmpipe.cost.predict`` with the coefficients of the first of ``WALL_MODELS`` under ``root``,
    fitted by ``lbmpipe.reproduction.runcost``) at a core of the case's own, times
    ``TIME_LIMIT_MARGIN``; never less than the node-count estimate
    (``lbmpipe.cost``, with a factor for particle work), which is all there is before any run.
    ``scene``: the case's scene already validated (the workflow's), not built again."""
    fid = config["fidelities"][fidelity_name]
    case_name, case = run_case(config, case_name)
    if scene is None:
        scene = Scene.model_validate(case_scene(case_name, case, fidelity_name, fid))
    params = derive(scene.model_copy(update={"particles": None}))
    part = case.get("particles")
    factor = 1.0 if part is None else PARTICLE_COST_FACTOR[part["concentration"] > 0.4]
    minutes = max(1, int(2 * factor * params.estimated_seconds / 60.0) + 1)
    model = wall_model(fidelity_name, root)
    if model is not None:
        seconds = predict(scene, derive(scene), model, 1.0)
        minutes = max(minutes, int(TIME_LIMIT_MARGIN * seconds / 60.0) + 1)
    return minutes


#: whole step with particles relative to the particle-free step, at 30 % and at 50 % (the paper
#: level's measured steps: benchmarks/README.md; collisions dominate the dense cases).
PARTICLE_COST_FACTOR = (8.0, 20.0)
#: the wall-time models a level's time limits come from, its own first (``tables/cost_model.json``
#: of ``lbmpipe.reproduction.runcost``; the coefficients are the host's, not the level's)
WALL_MODELS = ("results/{level}/tables/cost_model.json", "results/credible/tables/cost_model.json",
               "results/paper/tables/cost_model.json")
#: a time limit over the model's prediction: its largest error on runs it was not fitted to, given
#: the run's share of a core, stays under 20 % (``max_abs_rel_error`` of the credible level's
#: model), and a cluster node is shared too
TIME_LIMIT_MARGIN = 1.5


def wall_model(level: str, root: Path = Path(".")) -> dict | None:
    """The first fitted model of ``WALL_MODELS`` under ``root`` (None if none is there)."""
    for pattern in WALL_MODELS:
        try:
            model = json.loads((Path(root) / pattern.format(level=level)).read_text())
        except (OSError, ValueError):
            continue
        if int(model.get("n_runs", 0)) > 0:
            return model
    return None


def write_case_scene(config: dict, fidelity_name: str, case_name: str, path: Path,
                     packing_csv: Path | None = None, scene: Scene | None = None) -> Scene:
    """Validate the case's scene and write it as YAML (the file ``lbmpipe run`` reads); the
    packing file is referenced relative to the scene file. ``scene``: the case's scene already
    validated (the workflow's), not validated again."""
    fid = config["fidelities"][fidelity_name]
    rel = os.path.relpath(Path(packing_csv).resolve(), Path(path).resolve().parent) if packing_csv else None
    name, case = run_case(config, case_name)
    data = case_scene(name, case, fidelity_name, fid, rel)
    if scene is None:
        probe = copy.deepcopy(data)
        for g in (probe.get("particles") or {}).get("packed", []):
            g.pop("file", None)  # validate without reading the file
        scene = Scene.model_validate(probe)  # fail here, naming the field, rather than in the solver
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))
    return scene


class DirtyTreeError(RuntimeError):
    """A production run asked of a source tree with uncommitted changes."""


def require_clean_tree(production: bool, allow_dirty: bool) -> dict:
    """The provenance record of a pipeline run (``summary.json`` ``provenance``). A run of a
    ``production`` level (one whose results are committed) refuses a source tree with
    uncommitted changes: its commit could not recover the code. ``allow_dirty`` (the config key,
    for experiments) lets it run and is recorded."""
    commit = git_commit()
    dirty = bool(commit and commit.endswith("-dirty"))
    if production and dirty and not allow_dirty:
        raise DirtyTreeError(
            f"the source tree has uncommitted changes ({commit}): a production run must come from a clean commit, "
            "or its code cannot be recovered. Fix: commit (or stash) the changes, or, for an experiment, run with "
            "`--config allow_dirty=true` (recorded in the summary's provenance)")
    return {"git_commit": commit, "production": bool(production), "dirty": dirty,
            "allow_dirty": bool(allow_dirty) and dirty}


def simulate_case(scene_path: Path, packing_json: Path | None, out_dir: Path, threads: int,
                  checkpoint: Path | None = None, production: bool = False, allow_dirty: bool = False) -> dict:
    """Run one case of the pipeline: the scene's solver run, or, when its packing could not be
    made, the ``unpackable`` record (``write_unpackable``). Returns the summary, with its
    ``provenance`` (:func:`require_clean_tree`, checked before anything runs)."""
    out_dir = Path(out_dir)
    provenance = require_clean_tree(production, allow_dirty)
    if packing_json is not None:
        info = json.loads(Path(packing_json).read_text())
        if info.get("status") != "packed":
            write_unpackable(out_dir, out_dir.name, info)
            return json.loads((out_dir / "summary.json").read_text())

    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    scene = load_scene(scene_path)
    kwargs = {"checkpoint": checkpoint} if checkpoint is not None else {}
    run_scene(scene, derive(scene), out_dir, progress=False, **kwargs)
    summary = json.loads((out_dir / "summary.json").read_text())
    summary["provenance"] = provenance
    write_json(out_dir / "summary.json", summary)
    # A run stopped as unstable before the averaging window has no profile: say so in an empty
    # table rather than leave the pipeline without the file.
    if not (out_dir / "profile.csv").exists():
        (out_dir / "profile.csv").write_text("r_mm,uz_m_s,uz_poiseuille_m_s,nodes\n")
    return summary


CONFIG_SCHEMA = "workflow/schemas/config.schema.yaml"


def config_problems(config: dict, schema_path: str | Path, check=None) -> list[str]:
    """Problems of a pipeline config, each one line ``config error in <key>: ... Fix: ...``:
    the JSON schema (``schema_path``), the selected fidelity, and every case's scene at every
    fidelity level (validated as ``lbmpipe check`` would, before a job starts). Empty if none.
    ``check(case, level)`` validates one case's scene (the workflow's, which keeps it); by
    default here."""

    if not isinstance(config, dict):
        return [f"config error in the config file: it must hold a mapping, got {type(config).__name__}. "
                f"Fix: write it as in config.yaml ({CONFIG_SCHEMA})"]
    schema = yaml.safe_load(Path(schema_path).read_text())
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(config), key=lambda e: list(e.absolute_path))
    out = []
    for err in errors:
        where = ".".join(str(p) for p in err.absolute_path) or "the config"
        desc = err.schema.get("description") if isinstance(err.schema, dict) else None
        msg = " ".join(err.message.split())
        if len(msg) > 200:
            msg = msg[:200] + " ..."
        hint = f" ({' '.join(desc.split())})" if desc else ""
        out.append(f"config error in {where}: {msg}. Fix: give a value the schema accepts{hint}; see {CONFIG_SCHEMA}")
    if out:
        return out
    if config["fidelity"] not in config["fidelities"]:
        return [f"config error in fidelity: {config['fidelity']!r} is not one of {sorted(config['fidelities'])}. "
                "Fix: add it under `fidelities` or pick an existing level (--config fidelity=smoke)"]
    for fname, fid in config["fidelities"].items():
        out.extend(mach_factor_problems(fname, fid))
        for key in ("compare_with", "convergence_of", "control_of", "refines", "unstable_of"):  # levels naming a level
            other = fid.get(key)
            if other is not None and other not in config["fidelities"]:
                out.append(f"config error in fidelities.{fname}.{key}: {other!r} is not a level. "
                           f"Fix: one of {sorted(config['fidelities'])}")
    out.extend(unpackable.problems(config, Path(schema_path).resolve().parents[2]))  # the repository
    if out:
        return out
    for cname, case in config["cases"].items():
        for fname, fid in config["fidelities"].items():
            n_before = len(out)
            try:
                if check is not None:
                    check(cname, fname)
                else:
                    derive(Scene.model_validate(case_scene(cname, case, fname, fid)))
            except SceneError as exc:
                e = exc.errors[0]
                out.append(f"config error in cases.{cname} at fidelities.{fname}: its scene's {e.field}: {e.message}. "
                           f"Fix: {e.fix}")
            except (ValueError, KeyError, TypeError) as exc:
                out.append(f"config error in cases.{cname} at fidelities.{fname}: {' '.join(str(exc).split())}. "
                           f"Fix: see {CONFIG_SCHEMA}")
            if len(out) > n_before:  # one line per case: its first failing level
                break
    return out
