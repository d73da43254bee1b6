"""Run-time guard (lbmpipe.guard): each failure is caught, located and explained; a healthy flow
passes; a diverging run ends with status `unstable` (exit status 4) and keeps its last checkpoint."""

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from lbmpipe.cli import EXIT_FAILED, run_cli
from lbmpipe.guard import CS, Guard, GuardLimits, Unstable
from lbmpipe.scene import Scene
from lbmpipe.assemble import simulation_from_scene
from lbmpipe.run import run_scene
from lbmpipe.units import derive

PIPE = {
    "name": "guard_pipe",
    "domain": {"kind": "pipe", "diameter_mm": 16.0, "length_mm": 16.0},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "flow_rate", "flow_rate_m3_s": 1.0e-5},
    "initial": {"velocity": "parabolic"},
    "run": {"duration_s": 0.05, "spinup_s": 0.01, "sample_interval_s": 0.01},
}
PARTICLES = {"bodies": [{"shape": "cube", "edge_mm": 4.0, "position_mm": [0.0, 0.0, 8.0]},
                        {"shape": "cube", "edge_mm": 4.0, "position_mm": [0.0, 4.5, 8.0]}]}
# A shear layer driven far beyond the speed of sound: |u| passes 0.5 lattice units by step ~25.
RUNAWAY = {
    "name": "runaway", "domain": {"kind": "box", "size_mm": [4, 8, 4], "walls": {"y": "wall"}},
    "fluid": {"viscosity_m2_s": 1e-5}, "driving": {"kind": "body_force", "acceleration_m_s2": [20.0, 0.0, 0.0]},
    "numerics": {"mach_limit": 100.0}, "run": {"duration_s": 0.2, "spinup_s": 0.01, "sample_interval_s": 0.01},
}


def _sim(data=PIPE, particles=None):
    data = copy.deepcopy(data)
    if particles:
        data["particles"] = copy.deepcopy(particles)
        # the pair search of the 4 mm cubes needs a period of two interaction ranges (16.9 mm)
        data["domain"]["length_mm"] = 20.0
    scene = Scene.model_validate(data)
    params = derive(scene)
    return simulation_from_scene(scene, params), params


def _fluid_node(sim):
    g = sim.grid
    ix, iy = int(g.cols_x[len(g.cols_x) // 2]), int(g.cols_y[len(g.cols_y) // 2])
    return ix, iy, 5


def test_healthy_poiseuille_flow_passes_and_the_scan_reports_its_centre_line_speed():
    sim, params = _sim()
    sim.step(10)
    res = sim.guard.check(sim)
    assert res["nonfinite"] == 0
    # the parabolic start: the largest speed is the centre line's 2 u_mean (within the staircase error)
    assert res["u_max"] == pytest.approx(params.u_max_lu, rel=0.1)
    assert 0.99 < res["rho_min"] <= res["rho_max"] < 1.01


def test_nan_population_is_caught_with_its_node_and_step():
    sim, _ = _sim()
    sim.step(3)
    ix, iy, iz = _fluid_node(sim)
    sim.f[4, ix, iy, iz] = np.nan
    with pytest.raises(Unstable) as err:
        sim.guard.check(sim)
    msg = str(err.value)
    assert "non-finite" in msg and f"node ({ix}, {iy}, {iz})" in msg and "step 3" in msg
    assert "Fix:" in msg and err.value.step == 3


def test_infinite_population_is_caught_like_nan():
    sim, _ = _sim()
    ix, iy, iz = _fluid_node(sim)
    sim.f[7, ix, iy, iz] = np.inf
    with pytest.raises(Unstable, match="non-finite"):
        sim.guard.check(sim)


def test_lattice_speed_above_the_limit_is_caught_where_it_occurs():
    sim, _ = _sim()
    ix, iy, iz = _fluid_node(sim)
    lat = sim.lattice
    u = np.array([0.0, 0.0, 0.6])  # 1.04 c_s
    eu = lat.e @ u
    sim.f[:, ix, iy, iz] = lat.w * (1 + 3 * eu + 4.5 * eu**2 - 1.5 * u @ u)
    with pytest.raises(Unstable) as err:
        sim.guard.check(sim)
    assert "fluid speed |u| = 0.6" in str(err.value) and f"({ix}, {iy}, {iz})" in str(err.value)
    assert f"{0.6 / CS:.2f} c_s" in str(err.value)


def test_density_outside_the_range_is_caught():
    sim, _ = _sim()
    ix, iy, iz = _fluid_node(sim)
    sim.f[:, ix, iy, iz] *= 3.4 / sim.f[:, ix, iy, iz].sum()
    with pytest.raises(Unstable, match=r"density 3.4 outside \[0.2, 3\]"):
        sim.guard.check(sim)


def test_solid_and_particle_nodes_are_not_checked():
    sim, _ = _sim(particles=PARTICLES)
    own = sim.particles.owner_grid()
    ix, iy, iz = map(int, np.argwhere(own == 0)[0])  # a node inside particle 0
    sim.f[:, ix, iy, iz] = np.nan
    sim.f[:, 0, 0, 0] = np.nan  # a wall node outside the pipe
    sim.guard.check(sim)


def test_particle_outside_the_pipe_is_caught_with_its_id():
    sim, _ = _sim(particles=PARTICLES)
    sim.particles.bodies.x[1, :2] = [0.0, sim.grid.radius + 0.5]
    with pytest.raises(Unstable, match=r"particle 1 at .*Likely cause: a wall contact was missed"):
        sim.guard.check(sim)


def test_non_finite_particle_state_is_caught():
    sim, _ = _sim(particles=PARTICLES)
    sim.particles.bodies.wb[0, 2] = np.nan
    with pytest.raises(Unstable, match="non-finite particle state .* particle 0"):
        sim.guard.check(sim)


def test_overlap_beyond_the_collision_bound_is_caught_and_within_it_passes():
    sim, _ = _sim(particles=PARTICLES)
    ce = sim.guard.collide
    assert ce is not None
    bound = ce.params.overlap_tol * sim.guard.limits.overlap_factor
    assert bound == pytest.approx(0.1)  # the bound the collision tests hold between calls
    ce.totals["max_overlap_after_lu"] = bound  # exactly the bound: fine
    sim.guard.check(sim)
    ce.totals["max_overlap_after_lu"] = 3 * bound
    with pytest.raises(Unstable, match="overlap 0.3 lattice spacings .* above the bound 0.1"):
        sim.guard.check(sim)


def test_guard_runs_every_n_steps_inside_step():
    sim, _ = _sim()
    sim.guard = Guard(sim, every=7, limits=GuardLimits())
    sim.step(20)
    assert sim.guard.checks == 2
    with pytest.raises(ValueError):
        Guard(sim, every=0)


def test_diverging_run_ends_unstable_with_exit_status_4_and_keeps_the_last_good_checkpoint(tmp_path):
    scene_path = tmp_path / "runaway.yaml"
    scene_path.write_text(yaml.safe_dump(RUNAWAY))
    ck = tmp_path / "c.npz"
    code = run_cli(["run", str(scene_path), "--out", str(tmp_path / "out"), "--quiet", "--checkpoint", str(ck),
                    "--checkpoint-every-s", "0"])
    assert code == EXIT_FAILED == 4
    import json

    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "unstable"
    assert "fluid speed" in summary["message"] and "Fix: reduce numerics.dt_s" in summary["message"]
    assert summary["steps"] < summary["steps_requested"]
    assert ck.exists() and "last good checkpoint" in summary["message"]
    from lbmpipe import checkpoint as ckpt

    head, arrays = ckpt.read(ck)
    assert head["step"] < summary["steps"]
    rho = arrays["sim/f"].sum(axis=0)
    assert np.isfinite(rho).all()
