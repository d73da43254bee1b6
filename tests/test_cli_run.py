"""`lbmpipe run` end to end: outputs as documented, profile against Hagen-Poiseuille, Ctrl-C."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def _coarse_pipe(tmp_path: Path, dx_mm: float = 2.5, duration: float = 3.0, **numerics) -> Path:
    """The paper's Re 9.4 pipe at a coarser lattice (same Mach number: dt proportional to dx)."""
    scene = yaml.safe_load((ROOT / "scenes" / "pipe_re9.4.yaml").read_text())
    scene["numerics"].update({"dx_mm": dx_mm, "dt_s": 1e-3 * dx_mm, **numerics})
    scene["run"].update({"duration_s": duration, "spinup_s": duration / 2, "sample_interval_s": 0.05})
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    return path


def _run(*args, **kw):
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "lbmpipe", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=600, **kw)


def test_run_writes_documented_outputs_and_reaches_poiseuille_profile(tmp_path):
    scene = _coarse_pipe(tmp_path)
    out = tmp_path / "out"
    res = _run("run", scene, "--out", out, "--quiet")
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "summary.json").read_text())
    for key in ("status", "steps", "wall_seconds", "mlups", "mass_drift_rel", "effects", "scene", "lattice",
                "versions", "git_commit", "host", "profile_error_rel_l2", "flow_rate_m3_s"):
        assert key in summary, key
    assert summary["status"] == "completed"
    assert summary["lattice"]["tau"] > 0.5 and "mach_max" in summary["lattice"]
    assert set(summary["effects"]) == {
        "stream+collide D3Q15 BGK, Guo body force, flux sum, float64", "wall: half-way bounce-back",
        "flow-rate control"}
    assert abs(summary["mass_drift_rel"]) < 1e-11
    # A 20-node staircase pipe: ~1.6 % from the parabola; the flow rate is held at the paper's Q.
    assert summary["profile_error_rel_l2"] < 0.03
    assert summary["flow_rate_m3_s"] == pytest.approx(1.577e-4, rel=2e-3)
    profile = pd.read_csv(out / "profile.csv")
    assert list(profile.columns) == ["r_mm", "uz_m_s", "uz_poiseuille_m_s", "nodes"]
    assert profile.r_mm.max() < 25.0
    flow = pd.read_csv(out / "flow_rate.csv")
    assert list(flow.columns) == ["t_s", "q_m3_s", "force_density_N_m3", "max_density_deviation", "core_velocity_ratio"]
    assert flow.t_s.iloc[-1] == pytest.approx(3.0)
    # the developed profile's core velocity ratio is Hagen-Poiseuille's 1.75 (staircase wall: ~2 %)
    assert flow.core_velocity_ratio.iloc[-1] == pytest.approx(1.75, rel=0.03)


def test_interpolated_wall_halves_the_profile_error_of_the_staircase(tmp_path):
    errors = {}
    for wall in ("bounce_back", "bouzidi"):
        sub = tmp_path / wall
        sub.mkdir()
        res = _run("run", _coarse_pipe(sub, wall=wall), "--out", sub / "out", "--quiet")
        assert res.returncode == 0, res.stderr
        errors[wall] = json.loads((sub / "out" / "summary.json").read_text())["profile_error_rel_l2"]
    assert errors["bouzidi"] < 0.5 * errors["bounce_back"]


def test_ctrl_c_leaves_a_consistent_summary_marked_interrupted(tmp_path):
    scene = _coarse_pipe(tmp_path, duration=500.0)
    out = tmp_path / "out"
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "lbmpipe", "run", str(scene), "--out", str(out), "--quiet"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # wait until it is stepping (the flow-rate file only appears at the end, so poll the process)
    deadline = time.time() + 120
    time.sleep(3.0)
    while time.time() < deadline and proc.poll() is None and not (out.exists()):
        time.sleep(0.2)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert 0 < summary["steps"] < summary["steps_requested"]
    assert (out / "flow_rate.csv").exists()


def test_a_packing_file_that_cannot_be_read_is_a_scene_error_naming_the_field_not_a_traceback(tmp_path):
    path = _coarse_pipe(tmp_path, duration=0.1)
    scene = yaml.safe_load(path.read_text())
    scene["particles"] = {"packed": [{"shape": "cube", "edge_mm": 8.0, "concentration": 0.1,
                                      "file": str(tmp_path / "missing.csv")}]}
    path.write_text(yaml.safe_dump(scene))
    res = _run("run", path, "--out", tmp_path / "out", "--quiet")
    assert res.returncode == 2
    assert "particles.packed[0].file" in res.stderr and "Fix:" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out" / "summary.json").exists()
