"""The paper's pipe flow, defined once: the 50 mm x 100 mm periodic pipe, its two flow rates with
their Reynolds numbers, and the time-step rule (paper/reading.md "Parameters").

The paper runs dx = 1 mm with dt = 1 ms. Coarser or finer lattices keep its Mach number by
acoustic scaling (``dt`` proportional to ``dx``), so only the resolution changes; ``tau`` then
follows from the Reynolds number. The cases, the accuracy-cost study and the stability suite all
build their pipe scenes here.
"""

from __future__ import annotations

import copy

PIPE = {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0}
#: paper/reading.md: Q = 1.577e-4 m^3/s at Re 9.4 ("LF"), 3.154e-4 m^3/s at Re 26 ("HF").
FLOWS = {9.4: 1.577e-4, 26.0: 3.154e-4}
#: the paper's dt per mm of dx (dx = 1 mm, dt = 1 ms)
DT_PER_MM_S = 1.0e-3
#: fluid density (water), kg/m^3
DENSITY_KG_M3 = 1000.0


def time_step(dx_mm: float, dt_per_mm_s: float = DT_PER_MM_S, factor: float = 1.0) -> float:
    """Time step (s) at lattice spacing ``dx_mm`` by acoustic scaling, times ``factor``."""
    return dt_per_mm_s * dx_mm * factor


def pipe_scene(name: str, reynolds: float, numerics: dict, run: dict, *, fluid: dict | None = None,
               length_mm: float | None = None, outputs: dict | None = None) -> dict:
    """Scene dict (physical units) of the paper's pipe at the flow rate of ``reynolds``, started
    from the Poiseuille profile; ``fluid`` replaces the default (water at that Reynolds number),
    ``length_mm`` the pipe's length."""
    domain = copy.deepcopy(PIPE)
    if length_mm is not None:
        domain["length_mm"] = float(length_mm)
    data = {
        "name": name,
        "domain": domain,
        "fluid": fluid if fluid is not None else {"density_kg_m3": DENSITY_KG_M3, "reynolds": reynolds},
        "driving": {"kind": "flow_rate", "flow_rate_m3_s": FLOWS[reynolds]},
        "initial": {"velocity": "parabolic"},
        "numerics": numerics,
        "run": run,
    }
    if outputs is not None:
        data["outputs"] = outputs
    return data
