"""Run time of a scene: the one cost model of the package, and the throughput bound before any run.

:func:`predict` is the prediction every caller uses (``lbmpipe check``, the cluster profile's time
limits through ``lbmpipe.reproduction.cases.estimate_minutes``, ``benchmarks/level_cost.py``): the
scene's work (fluid nodes, particle boundary links, particles, steps) under a fitted model,

``wall_s = (intercept_s + steps (s_per_node_update nodes + s_per_link_update links
+ s_per_particle_step particles + s_per_step) / threads) / share``,

with ``share`` the share of a core each thread gets (1: a core of its own). The coefficients are
fitted and validated in one place, :mod:`lbmpipe.reproduction.runcost`: the production runs of a
level (``tables/cost_model.json``), or the accuracy-cost study's runs (``study/cost_model.json``,
which has no ``s_per_step``). A particle's boundary links are estimated from its surface area
(``lbmpipe.particles.shapes.surface_area``) and the model's ``links_per_area_lu``.

Before any run there is only the throughput bound, :func:`estimate_seconds`: fluid node updates
divided by the solver's throughput. ``DEFAULT_MLUPS`` (million lattice-node updates per second)
is the whole fluid-only solver step on ``REFERENCE_THREADS`` threads, calibrated from
``benchmarks/fluid.py`` (row "lbmpipe BGK + bounce-back wall", the paper's pipe 50 x 50 x 100,
float64; the calibration run is recorded in benchmarks/README.md), rounded down. Scenes with a
body force and the flux sum, interpolated walls or particles do more work per step and run
slower. Throughput is assumed to scale linearly with the thread count, which over-estimates it
once memory bandwidth saturates: treat the estimate as a lower bound on wall time for many
threads.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .particles.shapes import scene_shape, surface_area, volume

DEFAULT_MLUPS = 150.0
REFERENCE_THREADS = 2
#: links per unit surface area (lattice units) of a D3Q15 surface: sum over i of max(e_i.n, 0)
#: is 5 for an axis-aligned plane and 4.96 averaged over orientations; what a model without a
#: measured ``links_per_area_lu`` assumes
D3Q15_LINKS_PER_AREA = 5.0


def pipe_fluid_nodes(n_d: int, n_len: int) -> int:
    """Nodes of an ``n_d x n_d x n_len`` block whose centres, at ``(i + 1/2) dx``, lie strictly
    inside the circle of diameter ``n_d dx`` centred in the cross-section."""
    c = (np.arange(n_d) + 0.5) - n_d / 2.0
    inside = (c[:, None] ** 2 + c[None, :] ** 2) < (n_d / 2.0) ** 2
    return int(np.count_nonzero(inside)) * int(n_len)


def fluid_nodes(kind: str, shape: tuple[int, int, int]) -> int:
    """Fluid node count of a ``pipe`` (circle cross-section) or ``box`` (all nodes) domain."""
    if kind == "pipe":
        return pipe_fluid_nodes(shape[0], shape[2])
    return int(shape[0]) * int(shape[1]) * int(shape[2])


def throughput_mlups(threads: int | None = None, mlups: float | None = None) -> float:
    """Expected MLUPS on ``threads`` threads (None: all cores), from ``mlups`` at REFERENCE_THREADS."""
    cores = os.cpu_count() or 1
    t = cores if threads is None else max(1, min(int(threads), cores))
    return (DEFAULT_MLUPS if mlups is None else mlups) * t / REFERENCE_THREADS


def estimate_seconds(params, threads: int | None = None, mlups: float | None = None) -> float:
    """Wall-clock seconds for ``params.n_steps`` steps over ``params.fluid_nodes`` fluid nodes."""
    return params.fluid_nodes * params.n_steps / (throughput_mlups(threads, mlups) * 1e6)


def particle_area_volume(shape: str, diameter_mm=None, length_mm=None, edge_mm=None) -> tuple[float, float]:
    """Surface area (mm^2) and volume (mm^3) of one particle as a scene gives it."""
    kind, h = scene_shape(shape, diameter_mm, length_mm, edge_mm)
    return surface_area(kind, h), volume(kind, h)


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
        a, _ = particle_area_volume(b.shape, b.diameter_mm, b.length_mm, b.edge_mm)
        n_tot += 1
        area += a
    for g in list(ps.random) + list(ps.packed):
        a, v = particle_area_volume(g.shape, g.diameter_mm, g.length_mm, g.edge_mm)
        count = getattr(g, "count", None)
        n = int(count) if count is not None else max(1, int(round(g.concentration * vol / v)))
        n_tot += n
        area += n * a
    return n_tot, area


def predict_work(model: dict, steps, nodes, links=0.0, particles=0.0, threads=1, share=1.0):
    """Wall seconds of runs given their work (scalars or arrays) under ``model``, each thread
    getting ``share`` of a core (1: a core of its own); the module docstring's formula. A model
    fitted on work summed over the steps (the study's) is evaluated on those sums with ``steps=1``."""
    t = np.maximum(np.asarray(threads, dtype=float), 1.0)
    per_step = (model["s_per_node_update"] * np.asarray(nodes, float) + model["s_per_link_update"] * np.asarray(links, float)
                + model["s_per_particle_step"] * np.asarray(particles, float) + model.get("s_per_step", 0.0))
    return (model["intercept_s"] + np.asarray(steps, float) * per_step / t) / np.asarray(share, float)


def scene_work(scene, params, model: dict) -> tuple[int, int, float, int, int]:
    """(steps, fluid nodes, particle boundary links, particles, threads) of a validated ``Scene``
    with lattice parameters ``params``: the links estimated from the particles' surface area (the
    model's ``links_per_area_lu``, else ``D3Q15_LINKS_PER_AREA``), their count as the packer or
    random placement would make it; threads are the scene's ``run.threads`` (else the model's
    ``threads``, else 1)."""
    count, area_mm2 = scene_particle_load(scene)
    lpa = model.get("links_per_area_lu")
    lpa = float(lpa) if lpa is not None and math.isfinite(float(lpa)) else D3Q15_LINKS_PER_AREA
    links = lpa * area_mm2 / scene.numerics.dx_mm**2
    threads = scene.run.threads or model.get("threads", 1)
    return params.n_steps, params.fluid_nodes, links, count, threads


def predict(scene, params, model: dict, share: float = 1.0) -> float:
    """Predicted wall seconds of a validated ``Scene`` with lattice parameters ``params``
    (``lbmpipe.units.derive``) under a fitted ``model`` (:mod:`lbmpipe.reproduction.runcost`; one
    processor's coefficients from :func:`for_host`), each thread getting ``share`` of a core: its
    work (:func:`scene_work`) through :func:`predict_work`."""
    steps, nodes, links, count, threads = scene_work(scene, params, model)
    return float(predict_work(model, steps, nodes, links, count, threads, share))


def for_host(model: dict, host: str | None) -> tuple[dict, bool]:
    """The coefficients that predict a run on processor ``host``: its own (``model["hosts"]``)
    if the model has validated them (runs of two families or more), else the fit to all runs.
    Returns (model, own)."""
    own = (model.get("hosts") or {}).get(host) if host else None
    return ({**model, **own}, True) if own else (model, False)
