"""Particles in scenes (lbmpipe.scene `particles`, lbmpipe.particles.placement) and their outputs."""

import copy
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lbmpipe.particles import placement as pt
from lbmpipe.scene import Scene, SceneError, load_scene
from lbmpipe.particles.shapes import CUBE, CYLINDER, SPHERE
from lbmpipe.assemble import simulation_from_scene
from lbmpipe.run import run_scene
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]

PIPE = {
    "name": "pipe_particles",
    "domain": {"kind": "pipe", "diameter_mm": 20.0, "length_mm": 32.0},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "body_force", "acceleration_m_s2": [0.0, 0.0, 0.02]},
    "initial": {"velocity": "parabolic"},
    "run": {"duration_s": 0.06, "spinup_s": 0.02, "sample_interval_s": 0.02},
    "particles": {
        "bodies": [
            {"shape": "cylinder", "diameter_mm": 6.0, "length_mm": 8.0, "position_mm": [1.0, -2.0, 8.0],
             "orientation": [0.0, 1.0, 0.0, 0.0], "velocity_m_s": [0.0, 0.0, 0.01],
             "angular_velocity_rad_s": [0.0, 0.0, 2.0]},
            {"shape": "sphere", "diameter_mm": 6.0, "position_mm": [0.0, 0.0, 24.0], "fixed": True},
        ],
        "random": [{"shape": "cube", "edge_mm": 4.0, "count": 3, "seed": 7, "density_ratio": 1.5}],
    },
}


def edit(base, path, value):
    data = copy.deepcopy(base)
    keys = path.split(".")
    node = data
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node[k]
    last = int(keys[-1]) if keys[-1].isdigit() else keys[-1]
    if value is ...:
        node.pop(last)
    else:
        node[last] = value
    return data


def test_particle_scene_builds_bodies_in_lattice_units():
    scene = Scene.model_validate(PIPE)
    params = derive(scene)
    bodies, static = pt.bodies_from_scene(scene, params)
    assert bodies.n == 5 and len(static) == 5
    assert list(bodies.kind) == [CYLINDER, SPHERE, CUBE, CUBE, CUBE]
    np.testing.assert_allclose(bodies.h[0], [3.0, 3.0, 4.0])  # dx = 1 mm
    np.testing.assert_allclose(bodies.x[:2], [[1.0, -2.0, 8.0], [0.0, 0.0, 24.0]])
    # 0.01 m/s with dx = 1 mm, dt = 1 ms is 0.01 lattice units; 2 rad/s lab about z is 0.002
    np.testing.assert_allclose(bodies.v[0], [0.0, 0.0, 0.01])
    # orientation [0, 1, 0, 0] turns by pi about x: the lab z axis is the body's -z axis
    np.testing.assert_allclose(bodies.wb[0], [0.0, 0.0, -0.002], atol=1e-15)
    assert list(bodies.fixed) == [False, True, False, False, False]
    # mass from the density ratio: lattice density 1 is the fluid's
    assert bodies.mass[2] == pytest.approx(1.5 * 4.0**3)
    assert [r["density_kg_m3"] for r in static] == [1000.0, 1000.0, 1500.0, 1500.0, 1500.0]
    assert static[0]["shape"] == "cylinder" and math.isnan(static[0]["edge_mm"])


def test_random_placement_is_seeded_non_overlapping_and_inside_the_pipe():
    scene = Scene.model_validate(PIPE)
    params = derive(scene)
    b1, _ = pt.bodies_from_scene(scene, params)
    b2, _ = pt.bodies_from_scene(scene, params)
    np.testing.assert_array_equal(b1.x, b2.x)
    np.testing.assert_array_equal(b1.q, b2.q)
    rb = np.array([math.hypot(3.0, 4.0), 3.0] + [2.0 * math.sqrt(3.0)] * 3)
    x = b1.x
    for i in range(5):
        for j in range(i + 1, 5):
            d = x[i] - x[j]
            d[2] -= 32.0 * round(d[2] / 32.0)
            assert np.linalg.norm(d) >= rb[i] + rb[j] - 1e-9 or i < 2 and j < 2
    r = np.hypot(x[2:, 0], x[2:, 1])
    assert np.all(r <= 10.0 - rb[2] + 1e-9)
    assert np.all((x[2:, 2] >= 0.0) & (x[2:, 2] < 32.0))


def test_concentration_sets_the_particle_count():
    data = edit(PIPE, "particles.random.0", {"shape": "sphere", "diameter_mm": 4.0, "concentration": 0.02})
    scene = Scene.model_validate(data)
    bodies, _ = pt.bodies_from_scene(scene, derive(scene))
    expected = round(0.02 * math.pi * 10.0**2 * 32.0 / (4.0 / 3.0 * math.pi * 2.0**3))
    assert bodies.n == 2 + expected


def test_random_placement_that_cannot_fit_fails_with_the_number_reached():
    data = edit(PIPE, "particles.random.0", {"shape": "cube", "edge_mm": 4.0, "concentration": 0.3})
    scene = Scene.model_validate(data)
    with pytest.raises(SceneError) as err:
        pt.bodies_from_scene(scene, derive(scene))
    assert err.value.field == "particles.random[0].concentration"
    assert "fitted only" in err.value.message and "lbmpipe.particles.packing" in err.value.fix


BAD = [
    ("cylinder_without_length", edit(PIPE, "particles.bodies.0.length_mm", ...), "particles.bodies[0].length_mm", "needs length_mm"),
    ("cube_with_diameter", edit(PIPE, "particles.random.0.diameter_mm", 3.0), "particles.random[0].diameter_mm", "takes no diameter_mm"),
    ("count_and_concentration", edit(PIPE, "particles.random.0.concentration", 0.1), "particles.random[0].count", "exactly one of count"),
    ("centre_outside_pipe", edit(PIPE, "particles.bodies.1.position_mm", [8.0, 8.0, 3.0]), "particles.bodies[1].position_mm", "outside the pipe"),
    ("too_long_for_period", edit(PIPE, "particles.bodies.0.length_mm", 40.0), "particles.bodies[0]", "periodic length along z"),
    ("unknown_shape", edit(PIPE, "particles.bodies.1.shape", "cone"), "particles.bodies[1].shape", "not an allowed value"),
    ("zero_quaternion", edit(PIPE, "particles.bodies.0.orientation", [0.0, 0.0, 0.0, 0.0]), "particles.bodies[0].orientation", "zero"),
]


@pytest.mark.parametrize("name,data,field,words", BAD, ids=[b[0] for b in BAD])
def test_bad_particle_scene_names_the_field_and_the_fix(name, data, field, words):
    with pytest.raises(SceneError) as err:
        Scene.model_validate(data)
    fields = [e.field for e in err.value.errors]
    assert field in fields, str(err.value)
    assert words in str(err.value)
    assert "Fix:" in str(err.value)


def test_run_with_particles_writes_the_documented_outputs(tmp_path):
    scene = Scene.model_validate(PIPE)
    params = derive(scene)
    summary = run_scene(scene, params, tmp_path, progress=False)
    assert summary["status"] == "completed", summary["message"]
    assert {"particles.parquet", "particles_static.csv", "flow_rate.csv"} <= set(summary["files"])
    assert (tmp_path / "summary.json").exists()
    names = [n for n in summary["effects"] if n.startswith("particles:")]
    assert len(names) == 4  # fixed obstacles, free coupling, motion, mass correction: timed separately
    df = pd.read_parquet(tmp_path / "particles.parquet")
    assert list(df.columns) == list(pt.PARQUET_COLUMNS)
    assert len(df) == 5 * 4  # samples at t = 0, 0.02, 0.04, 0.06 s
    assert np.isfinite(df.to_numpy()).all()
    first = df[(df.t_s == 0.0) & (df.id == 0)].iloc[0]
    assert first.vz_m_s == pytest.approx(0.01) and first.wz_rad_s == pytest.approx(2.0)
    assert (first.x_mm, first.y_mm, first.z_mm) == pytest.approx((1.0, -2.0, 8.0))
    fixed = df[df.id == 1]
    assert (fixed[["vx_m_s", "vy_m_s", "vz_m_s", "wx_rad_s", "wy_rad_s", "wz_rad_s"]].to_numpy() == 0).all()
    assert (fixed.z_mm == 24.0).all()
    # the flow pushes the fixed sphere along +z; the force is in newtons (order rho nu U a)
    assert (fixed.fz_N.iloc[1:] > 0).all() and fixed.fz_N.iloc[-1] < 1e-3
    static = pd.read_csv(tmp_path / "particles_static.csv")
    assert list(static.columns) == list(pt.STATIC_COLUMNS)
    assert list(static["shape"]) == ["cylinder", "sphere", "cube", "cube", "cube"]
    assert list(static["fixed"]) == [False, True, False, False, False]
    assert summary["particles"]["count"] == 5 and summary["particles"]["fixed"] == 1
    # the summary records the net mass the mean-density correction added, relative to the initial
    # mass (coupling module docstring: moving particles change the fluid mass), a small fraction
    mc = summary["mass_correction"]
    assert mc["calls"] >= 1 and abs(mc["mass_added_rel"]) < 0.05
    # mass per fluid node: the correction holds the mean fluid density
    assert abs(summary["density_drift_rel"]) < 1e-3 and np.isfinite(summary["fluid_nodes_change_rel"])


def test_demo_scene_loads_and_places_its_particles():
    scene = load_scene(ROOT / "scenes" / "pipe_cylinders_demo.yaml")
    params = derive(scene)
    sim = simulation_from_scene(scene, params)
    assert sim.particles is not None and sim.particles.n == 21
    assert (sim.particles.covered().sum() > 0.9 * sim.particles.vol.sum())
