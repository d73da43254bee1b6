"""Checkpoints (lbmpipe.checkpoint) and resume in ``run_scene``: an interrupted-then-resumed run is
bit-identical to an uninterrupted one; a checkpoint of another scene is refused."""

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from lbmpipe import checkpoint as ckpt
from lbmpipe.scene import Scene
from lbmpipe.assemble import simulation_from_scene
from lbmpipe.run import run_scene
from lbmpipe.units import derive

# A small flow-rate-driven pipe with free particles: two cubes and a cylinder launched so that a
# pair collision and a wall collision happen in the run, plus seeded random cubes.
SCENE = {
    "name": "checkpoint_pipe",
    "domain": {"kind": "pipe", "diameter_mm": 20.0, "length_mm": 32.0},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "flow_rate", "flow_rate_m3_s": 1.5e-5},
    "initial": {"velocity": "parabolic"},
    "run": {"duration_s": 0.08, "spinup_s": 0.02, "sample_interval_s": 0.01},
    "particles": {
        "bodies": [
            {"shape": "cube", "edge_mm": 4.0, "position_mm": [-2.6, 0.0, 16.0], "velocity_m_s": [0.06, 0.0, 0.0]},
            {"shape": "cube", "edge_mm": 4.0, "position_mm": [2.6, 0.0, 16.0], "velocity_m_s": [-0.06, 0.0, 0.0],
             "orientation": [0.9238795, 0.0, 0.0, 0.3826834]},
            {"shape": "cylinder", "diameter_mm": 4.0, "length_mm": 6.0, "position_mm": [6.0, 0.0, 4.0],
             "velocity_m_s": [0.08, 0.0, 0.0]},
        ],
        "random": [{"shape": "cube", "edge_mm": 4.0, "count": 4, "seed": 3}],
    },
}


def _scene(data=SCENE):
    scene = Scene.model_validate(data)
    return scene, derive(scene)


def _read(out: Path, name: str):
    return pd.read_parquet(out / name) if name.endswith(".parquet") else pd.read_csv(out / name)


def test_interrupted_then_resumed_run_is_bit_identical_to_an_uninterrupted_one(tmp_path):
    scene, params = _scene()
    full = run_scene(scene, params, tmp_path / "full", progress=False, checkpoint=tmp_path / "full.npz",
                     keep_checkpoint=True)
    assert full["status"] == "completed"
    # the run must exercise the collision model, or the test would not cover its state
    assert full["collisions"]["impulses"] > 0 and full["collisions"]["wall_contacts"] + \
        full["collisions"]["pair_contacts"] > 0
    ck = tmp_path / "part.npz"
    # stop between two samples (step 45 of 80, samples every 10), as an interrupt would
    part = run_scene(scene, params, tmp_path / "part", progress=False, checkpoint=ck, stop_at_step=45)
    assert part["status"] == "interrupted" and part["steps"] == 45 and ck.exists()
    rest = run_scene(scene, params, tmp_path / "part", progress=False, checkpoint=ck, keep_checkpoint=True)
    assert rest["status"] == "completed" and rest["checkpoint"]["resumed_from_step"] == 45
    for name in ("particles.parquet", "flow_rate.csv", "profile.csv"):
        a, b = _read(tmp_path / "full", name), _read(tmp_path / "part", name)
        assert a.shape == b.shape and len(a) > 0, name
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    _, fa = ckpt.read(tmp_path / "full.npz")
    _, fb = ckpt.read(ck)
    np.testing.assert_array_equal(fa["sim/f"], fb["sim/f"])  # final populations, exactly
    np.testing.assert_array_equal(fa["bodies/x"], fb["bodies/x"])
    for key in ("mass_drift_rel", "samples_averaged", "profile_error_rel_l2", "flow_rate_m3_s"):
        assert full[key] == rest[key], key
    assert full["collisions"] == rest["collisions"]


def test_completed_run_removes_its_checkpoint(tmp_path):
    scene, params = _scene()
    ck = tmp_path / "c.npz"
    s = run_scene(scene, params, tmp_path / "o", progress=False, max_steps=20, checkpoint=ck, checkpoint_every_s=0.0)
    assert s["status"] == "completed" and s["checkpoint"]["written"] >= 1  # written at the samples ...
    assert not ck.exists() and not s["checkpoint"]["kept"]  # ... and removed at the end


def test_same_seed_gives_identical_outputs(tmp_path):
    scene, params = _scene()
    for d in ("a", "b"):
        run_scene(scene, params, tmp_path / d, progress=False, max_steps=30)
    for name in ("particles.parquet", "flow_rate.csv", "particles_static.csv"):
        pd.testing.assert_frame_equal(_read(tmp_path / "a", name), _read(tmp_path / "b", name), check_exact=True)


def test_checkpoint_of_another_scene_is_refused_with_a_clear_error(tmp_path):
    scene, params = _scene()
    ck = tmp_path / "c.npz"
    run_scene(scene, params, tmp_path / "a", progress=False, checkpoint=ck, stop_at_step=10)
    other = copy.deepcopy(SCENE)
    other["particles"]["random"][0]["seed"] = 4
    scene2, params2 = _scene(other)
    with pytest.raises(ckpt.CheckpointError, match="different scene"):
        run_scene(scene2, params2, tmp_path / "b", progress=False, checkpoint=ck)
    assert ck.exists()  # untouched


def test_restore_writes_arrays_in_place_and_keeps_aliases():
    scene, params = _scene()
    sim = simulation_from_scene(scene, params)
    sim.step(3)
    arrays, meta = ckpt.capture(sim)
    arrays = {k: v.copy() for k, v in arrays.items()}
    saved_f = sim.f.copy()
    f_obj, x_obj = sim.f, sim.particles.bodies.x
    sim.step(2)
    ckpt.restore(sim, arrays, json.loads(json.dumps(meta)))
    assert sim.f is f_obj and sim.particles.bodies.x is x_obj  # same objects, new contents
    assert sim.step_count == 3
    np.testing.assert_array_equal(sim.f, saved_f)


def test_checkpoint_of_another_lbmpipe_version_with_other_state_arrays_is_refused():
    scene, params = _scene()
    sim = simulation_from_scene(scene, params)
    sim.step(2)
    arrays, meta = ckpt.capture(sim)
    meta = json.loads(json.dumps(meta))
    # an older layout of the particle link lists: one array under a name this version lacks
    key = next(k for k in arrays if k.startswith("particles/"))
    old = dict(arrays)
    old[key.split("/")[0] + "/LX_old_layout"] = old.pop(key)
    fresh = simulation_from_scene(scene, params)
    with pytest.raises(ckpt.CheckpointError, match="another version of lbmpipe"):
        ckpt.restore(fresh, old, meta)
    ckpt.restore(fresh, arrays, meta)  # the matching set restores
    assert fresh.step_count == 2


def test_cli_run_resumes_from_checkpoint_after_an_interrupted_summary(tmp_path):
    scene_path = tmp_path / "scene.yaml"
    scene_path.write_text(yaml.safe_dump(SCENE))
    scene, params = _scene()
    out, ck = tmp_path / "out", tmp_path / "c.npz"
    part = run_scene(scene, params, out, progress=False, checkpoint=ck, stop_at_step=30)
    assert part["status"] == "interrupted"
    res = subprocess.run([sys.executable, "-m", "lbmpipe", "run", str(scene_path), "--out", str(out), "--quiet",
                          "--checkpoint", str(ck)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["checkpoint"]["resumed_from_step"] == 30
    assert not ck.exists()
