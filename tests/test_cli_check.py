"""Command line: `lbmpipe check` and the safety rules of `lbmpipe run`."""

import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

from lbmpipe import cli

ROOT = Path(__file__).resolve().parents[1]
PIPE_RE94 = ROOT / "scenes" / "pipe_re9.4.yaml"
COUETTE = ROOT / "scenes" / "box_couette.yaml"


def _exit_code(argv: list[str]) -> int:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    return info.value.code


def _snapshot(directory: Path) -> dict:
    return {p.relative_to(directory): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(directory.rglob("*")) if p.is_file()} | {
        "__dirs__": sorted(str(p.relative_to(directory)) for p in directory.rglob("*") if p.is_dir())}


@pytest.fixture
def fake_solver(monkeypatch):
    """Stand-in for lbmpipe.run recording its calls; `status` sets what run_scene returns."""
    module = types.ModuleType("lbmpipe.run")
    module.calls = []
    module.status = "completed"

    def run_scene(scene, params, out_dir, progress, max_steps):
        module.calls.append(dict(scene=scene, params=params, out_dir=out_dir, progress=progress, max_steps=max_steps))
        if module.status == "raise_interrupt":
            raise KeyboardInterrupt
        return {"status": module.status}

    module.run_scene = run_scene
    monkeypatch.setitem(sys.modules, "lbmpipe.run", module)
    return module


def test_check_paper_pipe_prints_tau_1_78_and_mach_and_exits_0():
    proc = subprocess.run([sys.executable, "-m", "lbmpipe", "check", str(PIPE_RE94)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 0, proc.stderr
    tau = float(re.search(r"^\s*tau\s*=\s*([0-9.]+)", proc.stdout, re.M).group(1))
    mach = float(re.search(r"^\s*Mach\s*=\s*([0-9.]+)", proc.stdout, re.M).group(1))
    assert tau == pytest.approx(1.78, abs=0.005)
    assert mach == pytest.approx(0.278, abs=0.001)
    for label in ("shape (nx, ny, nz) = 50 x 50 x 100", "fluid nodes", "omega", "nu_lu", "u_mean_lu", "u_max_lu",
                  "Re", "steps", "estimated run time"):
        assert label in proc.stdout


def test_check_of_several_files_fails_if_any_is_bad(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(COUETTE.read_text().replace("viscosity_m2_s", "viscosity"))
    assert _exit_code(["check", str(COUETTE), str(bad)]) == 2
    out, err = capsys.readouterr()
    assert "Scene box_couette" in out
    assert "scene error in fluid.viscosity: unknown key 'viscosity'. Fix: did you mean 'viscosity_m2_s'?" in err
    assert _exit_code(["check", str(COUETTE), str(PIPE_RE94)]) == 0


def test_run_refuses_a_finished_output_dir_without_force_and_leaves_it_untouched(tmp_path, fake_solver, capsys):
    out = tmp_path / "run"
    (out / "sub").mkdir(parents=True)
    (out / "summary.json").write_text('{"status": "completed"}\n')
    (out / "sub" / "profile.csv").write_bytes(b"r,u\n0,1\n")
    before = _snapshot(out)
    assert _exit_code(["run", str(COUETTE), "--out", str(out)]) == 3
    assert _snapshot(out) == before
    assert fake_solver.calls == []
    assert "--force" in capsys.readouterr().err


def test_run_with_force_passes_scene_params_and_step_limit_to_solver(tmp_path, fake_solver):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    assert _exit_code(["run", str(COUETTE), "--out", str(out), "--force", "--steps", "7", "--quiet"]) == 0
    (call,) = fake_solver.calls
    assert call["scene"].name == "box_couette"
    assert call["params"].shape == (1, 32, 1) and call["params"].tau == pytest.approx(0.8)
    assert call["out_dir"] == out and call["max_steps"] == 7 and call["progress"] is False


@pytest.mark.parametrize("status, code", [("completed", 0), ("interrupted", 130), ("failed", 4), ("raise_interrupt", 130)])
def test_run_exit_status_follows_the_solver_summary(tmp_path, fake_solver, status, code):
    fake_solver.status = status
    assert _exit_code(["run", str(COUETTE), "--out", str(tmp_path / "new"), "--quiet"]) == code


def test_run_of_a_bad_scene_exits_2_without_creating_the_output(tmp_path, fake_solver):
    bad = tmp_path / "bad.yaml"
    bad.write_text(COUETTE.read_text().replace("spinup_s: 8.0", "spinup_s: 12.0"))
    out = tmp_path / "out"
    assert _exit_code(["run", str(bad), "--out", str(out)]) == 2
    assert not out.exists() and fake_solver.calls == []


def test_unknown_command_is_an_argument_error():
    assert _exit_code(["frobnicate"]) == 2


def test_check_predicts_run_time_from_the_calibrated_cost_model(tmp_path, capsys):
    # A model of 1 s fixed plus 1e-7 s per node update must predict 1 + 1e-7 * nodes * steps.
    import json

    from lbmpipe.scene import load_scene
    from lbmpipe.units import derive
    model = {"intercept_s": 1.0, "s_per_node_update": 1e-7, "s_per_link_update": 0.0, "s_per_particle_step": 0.0,
             "n_runs": 7, "rel_rms_error": 0.1, "threads": 1}
    path = tmp_path / "cost_model.json"
    path.write_text(json.dumps(model))
    scene_path = ROOT / "scenes" / "pipe_re9.4.yaml"
    params = derive(load_scene(scene_path))
    assert cli.run_cli(["check", str(scene_path), "--cost-model", str(path)]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "predicted run time" in ln)
    expected = 1.0 + 1e-7 * params.fluid_nodes * params.n_steps
    shown = cli._duration(expected)
    assert shown in line and "cost model of 7 runs" in line
