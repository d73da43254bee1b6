"""The paper's cases as scenes: the case matrix of the pipeline's config turned into scene dicts.

The Snakemake layer only names cases and fidelity levels; this module decides what a case means
physically (NOTES.md "Parameters"): the 50 mm x 100 mm periodic pipe, the two flow rates with their
Reynolds numbers, and how a fidelity level sets the lattice. Coarser levels keep the paper's Mach
number (acoustic scaling, ``dt`` proportional to ``dx``), so that only the resolution changes;
``tau`` then follows from the Reynolds number.
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

from .scene import Scene

PIPE = {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0}
#: NOTES.md: Q = 1.577e-4 m^3/s at Re 9.4 ("LF"), 3.154e-4 m^3/s at Re 26 ("HF").
FLOWS = {9.4: 1.577e-4, 26.0: 3.154e-4}


def fidelity_numerics(fidelity: dict) -> dict:
    """Scene ``numerics`` for a fidelity level: ``dx_mm`` and ``dt_s`` (or ``dt_per_mm_s``)."""
    num = {k: v for k, v in fidelity.get("numerics", {}).items()}
    dx = float(fidelity["dx_mm"])
    num["dx_mm"] = dx
    num["dt_s"] = float(fidelity.get("dt_s", fidelity.get("dt_per_mm_s", 1.0e-3) * dx))
    return num


def case_scene(name: str, case: dict, fidelity_name: str, fidelity: dict) -> dict:
    """Scene dict (physical units) for one case of the config at one fidelity level."""
    re = float(case["reynolds"])
    if re not in FLOWS:
        raise ValueError(f"case {name}: reynolds must be one of {sorted(FLOWS)} (the paper's flows), got {re}")
    run = fidelity["run"]
    scene = {
        "name": f"{name}_{fidelity_name}",
        "domain": copy.deepcopy(PIPE),
        "fluid": {"density_kg_m3": 1000.0, "reynolds": re},
        "driving": {"kind": "flow_rate", "flow_rate_m3_s": FLOWS[re]},
        "initial": {"velocity": "parabolic"},
        "numerics": fidelity_numerics(fidelity),
        "run": {k: run[k] for k in ("duration_s", "spinup_s", "sample_interval_s")},
    }
    if "mach_limit" in fidelity:
        scene["numerics"]["mach_limit"] = fidelity["mach_limit"]
    return scene


def write_case_scene(config: dict, fidelity_name: str, case_name: str, path: Path) -> Scene:
    """Validate the case's scene and write it as YAML (the file ``lbmpipe run`` reads)."""
    fid = config["fidelities"][fidelity_name]
    data = case_scene(case_name, config["cases"][case_name], fidelity_name, fid)
    scene = Scene.model_validate(data)  # fail here, naming the field, rather than in the solver
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))
    return scene
