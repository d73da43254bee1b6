"""Flow-field output (lbmpipe.fields): VTK files that ParaView's readers (vtk) read back equal to
the in-memory state, in physical units; the .pvd series survives an interrupt and resume; the
size per sample is printed by `lbmpipe check`; without vtk (the `fields` extra) files are still
written and the readers name the extra to install."""

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from lbmpipe import fields
from lbmpipe.particles.rigid import quat_to_matrices
from lbmpipe.scene import Scene
from lbmpipe.assemble import simulation_from_scene
from lbmpipe.run import run_scene
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]

# A Couette box (moving wall y+, body force along z) with one fixed cube: walls, a particle and
# all three velocity components are non-trivial.
BOX = {
    "name": "fields_box",
    "domain": {"kind": "box", "size_mm": [8.0, 10.0, 8.0], "walls": {"y": "wall"},
               "moving_walls": [{"side": "y+", "velocity_m_s": [0.02, 0.0, 0.0]}]},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "body_force", "acceleration_m_s2": [0.0, 0.0, 0.01]},
    "run": {"duration_s": 0.04, "spinup_s": 0.02, "sample_interval_s": 0.01},
    "outputs": {"fields": {"interval_s": 0.015}},
    "particles": {"bodies": [{"shape": "cube", "edge_mm": 3.0, "position_mm": [4.0, 5.0, 4.0], "fixed": True}]},
}

# A flow-rate pipe with free particles of each shape, tilted and spinning.
PIPE = {
    "name": "fields_pipe",
    "domain": {"kind": "pipe", "diameter_mm": 14.0, "length_mm": 16.0},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "flow_rate", "flow_rate_m3_s": 5e-6},
    "initial": {"velocity": "parabolic"},
    "run": {"duration_s": 0.02, "spinup_s": 0.01, "sample_interval_s": 0.01},
    "outputs": {"fields": {"interval_s": 0.01}},
    "particles": {
        "bodies": [
            {"shape": "cylinder", "diameter_mm": 3.0, "length_mm": 5.0, "position_mm": [-2.5, 0.0, 4.0],
             "orientation": [0.9238795, 0.3826834, 0.0, 0.0], "angular_velocity_rad_s": [0.0, 2.0, 1.0]},
            {"shape": "cube", "edge_mm": 3.0, "position_mm": [2.5, 1.0, 10.0], "velocity_m_s": [0.0, 0.0, 0.01],
             "orientation": [0.9659258, 0.0, 0.2588190, 0.0]},
            {"shape": "sphere", "diameter_mm": 3.0, "position_mm": [0.0, -3.0, 13.0]},
        ],
    },
}


def _scene(data):
    scene = Scene.model_validate(data)
    return scene, derive(scene)


def test_lattice_file_reads_back_as_the_in_memory_fields_in_physical_units(tmp_path):
    scene, params = _scene(BOX)
    sim = simulation_from_scene(scene, params)
    sim.step(30)
    w = fields.FieldWriter(scene, params, sim.grid, tmp_path)
    w.sample(sim, sim.step_count)
    lat = fields.read_lattice(tmp_path / "fields" / "lattice_00000030.vti")

    rho, ux, uy, uz = sim.moments()
    fluid = sim.fluid_mask()
    u = params.units
    assert lat["shape"] == sim.grid.shape  # ghost layers of the walls included
    np.testing.assert_allclose(lat["spacing"], [1.0, 1.0, 1.0])  # mm
    # cells centred on the nodes: the walls at y = 0 and 10 mm are the faces of the ghost cells
    np.testing.assert_allclose(lat["origin"], [0.0, -1.0, 0.0])
    for k, c in enumerate((ux, uy, uz)):
        expect = np.where(fluid, u.velocity_phys(1.0) * c, 0.0)
        np.testing.assert_allclose(lat["velocity_m_s"][..., k], expect, rtol=1e-6, atol=1e-12)
    assert np.abs(lat["velocity_m_s"][..., 0][fluid]).max() > 1e-3  # the moving wall has dragged the fluid
    np.testing.assert_allclose(lat["density_kg_m3"][fluid], 1000.0 * rho[fluid], rtol=1e-6)
    assert np.isnan(lat["density_kg_m3"][~fluid]).all()
    expect_solid = np.where(fluid, 0, np.where(sim.grid.solid, 1, 2))
    np.testing.assert_array_equal(lat["solid"], expect_solid)
    # particle nodes are the fixed cube's, wall nodes the two ghost planes of 8 x 8
    np.testing.assert_array_equal(lat["solid"] == 2, sim.particles.owner_grid() >= 0)
    assert (lat["solid"] == 2).sum() >= 27 and (lat["solid"] == 1).sum() == 2 * 8 * 8


def test_particle_file_holds_each_bodys_pose_motion_shape_and_size(tmp_path):
    scene, params = _scene(PIPE)
    sim = simulation_from_scene(scene, params)
    sim.step(5)
    w = fields.FieldWriter(scene, params, sim.grid, tmp_path)
    w.sample(sim, sim.step_count)
    p = fields.read_particles(tmp_path / "fields" / "particles_00000005.vtp")
    b, u = sim.particles.bodies, params.units
    assert p["n_verts"] == b.n == 3
    np.testing.assert_allclose(p["points"], b.x * 1.0, rtol=1e-12)  # dx = 1 mm
    np.testing.assert_allclose(p["velocity_m_s"], b.v * u.velocity_phys(1.0), rtol=1e-12)
    np.testing.assert_allclose(p["angular_velocity_rad_s"], sim.particles.omega_lab() / u.dt_s, rtol=1e-12)
    q = np.stack([p["qw"], p["qx"], p["qy"], p["qz"]], axis=1)
    np.testing.assert_allclose(q, b.q, rtol=1e-12)
    rot = quat_to_matrices(np.ascontiguousarray(b.q))
    for k, name in enumerate(("axis_x", "axis_y", "axis_z")):
        np.testing.assert_allclose(p[name], rot[:, :, k], atol=1e-12)
    # the first cylinder started tilted 45 degrees about x (axis in the y-z plane) and has turned
    # by at most |omega| t = 2.2 rad/s x 5 ms = 0.011 rad since
    np.testing.assert_allclose(p["axis_z"][0], [0.0, -np.sqrt(0.5), np.sqrt(0.5)], atol=0.012)
    np.testing.assert_array_equal(p["shape_id"], [1, 2, 0])  # cylinder, cube, sphere
    np.testing.assert_allclose(p["half_extents_mm"], [[1.5, 1.5, 2.5], [1.5, 1.5, 1.5], [1.5, 1.5, 1.5]])
    np.testing.assert_allclose(p["bounding_radius_mm"], [np.hypot(1.5, 2.5), 1.5 * np.sqrt(3), 1.5])
    # the lattice file of the same sample marks the particle nodes
    lat = fields.read_lattice(tmp_path / "fields" / "lattice_00000005.vti")
    np.testing.assert_array_equal(lat["solid"] == 2, sim.particles.owner_grid() >= 0)


def test_box_and_pipe_runs_write_a_series_of_every_sample(tmp_path):
    for data, n_steps, every in ((BOX, 40, 15), (PIPE, 20, 10)):
        scene, params = _scene(data)
        out = tmp_path / data["name"]
        summary = run_scene(scene, params, out, progress=False)
        assert summary["status"] == "completed"
        assert "fields.pvd" in summary["files"]
        entries = fields.read_series(out / "fields.pvd")
        steps = sorted(set(range(0, n_steps + 1, every)) | {n_steps})
        assert sorted({round(t / params.units.dt_s) for t, _, _ in entries}) == steps
        assert len(entries) == 2 * len(steps)  # lattice and particles at each time
        for t, part, name in entries:
            assert (out / name).is_file() and name.endswith(".vti" if part == 0 else ".vtp")
        last = fields.read_lattice(out / f"fields/lattice_{n_steps:08d}.vti")
        assert np.isfinite(last["velocity_m_s"]).all()


def test_resumed_run_keeps_the_series_without_duplicates_or_gaps_and_the_same_files(tmp_path):
    scene, params = _scene(BOX)
    run_scene(scene, params, tmp_path / "full", progress=False)
    ck = tmp_path / "part.npz"
    part = run_scene(scene, params, tmp_path / "part", progress=False, checkpoint=ck, stop_at_step=20)
    assert part["status"] == "interrupted"
    assert len(fields.read_series(tmp_path / "part" / "fields.pvd")) == 2 * 2  # steps 0 and 15
    rest = run_scene(scene, params, tmp_path / "part", progress=False, checkpoint=ck)
    assert rest["status"] == "completed" and rest["checkpoint"]["resumed_from_step"] == 20
    full_series = (tmp_path / "full" / "fields.pvd").read_text()
    assert (tmp_path / "part" / "fields.pvd").read_text() == full_series
    for f in sorted((tmp_path / "full" / "fields").iterdir()):
        assert (tmp_path / "part" / "fields" / f.name).read_bytes() == f.read_bytes(), f.name


def test_check_prints_the_field_output_size_per_sample(tmp_path):
    data = yaml.safe_load((ROOT / "scenes" / "pipe_re9.4.yaml").read_text())
    data["outputs"] = {"fields": {"interval_s": 0.5}}
    scene, params = _scene(data)
    lat, parts = fields.bytes_per_sample(scene, params)
    # 52 x 52 x 100 nodes (wall ghosts included) x 17 bytes (3 + 1 float32, 1 uint8)
    assert lat == 52 * 52 * 100 * 17 + fields.HEADER_BYTES["lattice"] and parts == 0
    assert fields.sample_count(scene, params) == 1 + 6000 // 500
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    res = subprocess.run([sys.executable, "-m", "lbmpipe", "check", str(path)], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert res.returncode == 0, res.stderr
    line = next(ln for ln in res.stdout.splitlines() if "field output" in ln)
    assert f"{lat / 1e6:.3g} MB lattice per sample, 13 samples" in line


def test_field_sizes_match_the_files_written(tmp_path):
    """The size `check` prints is the size of the files (within the XML headers)."""
    scene, params = _scene(PIPE)
    run_scene(scene, params, tmp_path, progress=False, max_steps=1)
    lat, parts = fields.bytes_per_sample(scene, params, n_particles=3)
    real_lat = (tmp_path / "fields" / "lattice_00000000.vti").stat().st_size
    real_parts = (tmp_path / "fields" / "particles_00000000.vtp").stat().st_size
    assert abs(real_lat - lat) < fields.HEADER_BYTES["lattice"]
    assert abs(real_parts - parts) < fields.HEADER_BYTES["particles"]


def test_fields_are_opt_in_and_a_bad_interval_is_named():
    data = copy.deepcopy(BOX)
    del data["outputs"]
    scene, params = _scene(data)
    assert scene.outputs.fields is None and fields.bytes_per_sample(scene, params) == (0, 0)
    data["outputs"] = {"fields": {"interval_s": 1.0}}
    with pytest.raises(Exception, match=r"outputs\.fields\.interval_s"):
        _scene(data)
    data["outputs"] = {"fields": {"interval_s": 0.01, "fields": ["pressure"]}}
    with pytest.raises(Exception, match=r"outputs\.fields\.fields"):
        _scene(data)


def test_example_picture_renders_from_the_read_back_arrays(tmp_path):
    scene, params = _scene(PIPE)
    run_scene(scene, params, tmp_path / "run", progress=False)
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import fields_example
    finally:
        sys.path.pop(0)
    png = fields_example.render(tmp_path / "run", tmp_path / "f.png")
    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 400
    assert img[..., :3].std() > 0.05  # not a blank canvas


#: vtk's modules, mocked away as in the main job's environment (vtk is the `fields` extra)
VTK_MODULES = ("vtk", "vtkmodules", "vtkmodules.vtkIOXML", "vtkmodules.util", "vtkmodules.util.numpy_support")


def test_fields_are_written_without_vtk_and_reading_them_back_names_the_extra_in_one_line(tmp_path, monkeypatch):
    """The main install (no vtk) writes field files (pyevtk); the readers then fail with one line
    that names the `fields` extra, not a traceback into vtkmodules."""
    for name in VTK_MODULES:
        monkeypatch.setitem(sys.modules, name, None)  # `import name` now raises ImportError
    with pytest.raises(ImportError):
        import vtkmodules.vtkIOXML  # noqa: F401  (the mock holds)
    base = str(tmp_path / "lattice")
    solid = np.zeros((2, 3, 4), dtype=np.uint8)
    path = Path(fields._write_image(base, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), solid.shape, {"solid": solid}))
    assert path.is_file() and path.stat().st_size > solid.size
    for reader in (fields.read_lattice, fields.read_particles):
        with pytest.raises(ImportError) as err:
            reader(path)
        message = str(err.value)
        assert "\n" not in message and "pip install -e '.[fields]'" in message and "vtk" in message
        assert err.value.__suppress_context__  # `from None`: the one line is the whole message
