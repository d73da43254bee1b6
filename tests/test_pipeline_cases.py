"""The paper's cases as scenes (lbmpipe.reproduction.cases), packed particle groups, collisions as an effect,
mass correction and the flow-rate controller with particles."""

import copy
from pathlib import Path
import json

import numpy as np
import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction import cases
from lbmpipe.fluid import effects as fx
from lbmpipe.particles.collisions import CollisionEffect
from lbmpipe.particles.coupling import MassCorrection
from lbmpipe.outputs import write_summary
from lbmpipe.scene import Scene, SceneError, load_scene
from lbmpipe.assemble import assemble, simulation_from_scene
from lbmpipe.run import run_scene
from lbmpipe.units import derive

SMOKE = {"dx_mm": 5.0, "dt_per_mm_s": 1.0e-3, "re26_dt_factor": 0.5, "mach_limit": 0.6,
         "run": {"duration_s": 0.2, "spinup_s": 0.05, "sample_interval_s": 0.05}}
CUBE8 = {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.30}}
CONFIG = {"fidelities": {"tiny": SMOKE}, "packing_max_seconds": 60,
          "cases": {"flow_re9.4": {"reynolds": 9.4}, "cube8_c30_re9.4": CUBE8,
                    "cube8_c30_re26": {**CUBE8, "reynolds": 26},
                    "cube8_c30_re9.4_nocoll": {**CUBE8, "collisions": False},
                    "cube24_c50_re9.4": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 24,
                                                                         "concentration": 0.5}}}}


def small_pipe(particles: dict, dx=2.5, re=9.4) -> dict:
    return {"name": "t", "domain": {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0},
            "fluid": {"density_kg_m3": 1000.0, "reynolds": re},
            "driving": {"kind": "flow_rate", "flow_rate_m3_s": cases.FLOWS[re]},
            "initial": {"velocity": "parabolic"},
            "numerics": {"dx_mm": dx, "dt_s": 1e-3 * dx, "mach_limit": 0.6},
            "run": {"duration_s": 0.05, "spinup_s": 0.025, "sample_interval_s": 0.025},
            "particles": particles}


def test_cases_sharing_shape_concentration_and_seed_share_one_packing():
    assert cases.packing_id(CUBE8) == "cube8_c30_s1"
    assert cases.packing_id(CONFIG["cases"]["cube8_c30_re26"]) == "cube8_c30_s1"
    assert cases.packing_id(CONFIG["cases"]["cube8_c30_re9.4_nocoll"]) == "cube8_c30_s1"
    assert cases.packing_id({"reynolds": 9.4}) is None
    cyl = {"reynolds": 26, "particles": {"shape": "cylinder", "diameter_mm": 16, "length_mm": 24,
                                         "concentration": 0.5, "seed": 3}}
    assert cases.packing_id(cyl) == "cyl16x24_c50_s3"


def test_re26_dt_factor_halves_the_time_step_and_keeps_the_reynolds_number():
    s94 = Scene.model_validate(cases.case_scene("a", CUBE8, "tiny", SMOKE))
    s26 = Scene.model_validate(cases.case_scene("b", {**CUBE8, "reynolds": 26}, "tiny", SMOKE))
    assert s94.numerics.dt_s == pytest.approx(5e-3)
    assert s26.numerics.dt_s == pytest.approx(2.5e-3)
    p26 = derive(s26)
    assert p26.reynolds == pytest.approx(26.0, rel=1e-6)
    assert p26.mach_max == pytest.approx(0.28, abs=0.01)  # paper/reading.md: Re 26 at dt 0.5 ms


def test_nocoll_case_switches_pair_collisions_off_keeps_the_wall_and_the_packing(tmp_path):
    data = cases.case_scene("x", CONFIG["cases"]["cube8_c30_re9.4_nocoll"], "tiny", SMOKE, "p.csv")
    assert data["particles"]["collisions"] == {"pairs": False}
    assert data["particles"]["packed"][0] == {"shape": "cube", "edge_mm": 8, "concentration": 0.3, "seed": 1,
                                              "file": "p.csv"}


def test_packing_file_round_trip_reproduces_the_packed_bodies(tmp_path):
    info = cases.pack_case(CONFIG, "cube8_c30_s1", tmp_path / "p.csv", tmp_path / "p.json")
    assert info["status"] == "packed" and info["count"] == 115  # paper/reading.md: 115 cubes of 8 mm at 30 %
    assert abs(info["concentration_achieved"] - 0.30) < 0.002
    assert info["max_overlap_mm"] <= 1e-3
    scene_path = tmp_path / "case" / "scene.yaml"
    cases.write_case_scene(CONFIG, "tiny", "cube8_c30_re9.4", scene_path, packing_csv=tmp_path / "p.csv")
    scene = load_scene(scene_path)  # the file path is relative to the scene file
    sim = simulation_from_scene(scene, derive(scene))
    x = pd.read_csv(tmp_path / "p.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy() / SMOKE["dx_mm"]
    np.testing.assert_allclose(sim.particles.bodies.x, x, atol=1e-12)
    assert sim.packing["source"].endswith("p.csv")


def test_summary_names_the_packing_file_from_the_working_directory_not_the_clone(tmp_path, monkeypatch):
    # a summary made in one clone must read the same in another: no absolute paths of the clone
    monkeypatch.chdir(tmp_path)
    packing = tmp_path / "results" / "packings" / "p.csv"
    scene = Scene.model_validate(cases.case_scene("x", CUBE8, "tiny", SMOKE, str(packing)))
    (tmp_path / "out").mkdir()
    path = write_summary(tmp_path / "out", {"particles": {"source": str(packing)}}, scene, derive(scene))
    doc = json.loads(path.read_text())
    assert doc["particles"]["source"] == "results/packings/p.csv"
    assert doc["scene"]["particles"]["packed"][0]["file"] == "results/packings/p.csv"
    assert str(tmp_path) not in path.read_text()


def test_packing_file_with_the_wrong_count_is_rejected_naming_the_field(tmp_path):
    pd.DataFrame({"id": [0], "x_mm": [0.0], "y_mm": [0.0], "z_mm": [0.0], "qw": [1.0], "qx": [0.0], "qy": [0.0],
                  "qz": [0.0]}).to_csv(tmp_path / "bad.csv", index=False)
    data = cases.case_scene("x", CUBE8, "tiny", SMOKE, str(tmp_path / "bad.csv"))
    scene = Scene.model_validate(data)
    with pytest.raises(SceneError, match=r"particles.packed\[0\].file.*115 rows"):
        simulation_from_scene(scene, derive(scene))


def test_unreachable_packing_is_recorded_with_the_highest_concentration_and_the_case_is_marked(tmp_path):
    cfg = copy.deepcopy(CONFIG)
    cfg["packing_max_seconds"] = 2.0
    info = cases.pack_case(cfg, "cube24_c50_s1", tmp_path / "q.csv", tmp_path / "q.json")
    assert info["status"] == "unpackable"
    assert 0.0 < info["concentration_reached"] < 0.5
    assert "highest concentration reached" in info["message"]
    assert pd.read_csv(tmp_path / "q.csv").empty
    summary = cases.simulate_case(tmp_path / "none.yaml", tmp_path / "q.json", tmp_path / "case", threads=1)
    assert summary["status"] == "unpackable"
    assert summary["packing"]["concentration_reached"] == info["concentration_reached"]
    for name in ("particles.parquet", "particles_static.csv", "profile.csv", "flow_rate.csv"):
        assert (tmp_path / "case" / name).exists()


def test_packed_group_is_pipe_only_and_alone():
    box = small_pipe({"packed": [{"shape": "cube", "edge_mm": 8, "concentration": 0.3}],
                      "random": [{"shape": "sphere", "diameter_mm": 4, "count": 2}]})
    with pytest.raises(SceneError, match="particles.packed"):
        Scene.model_validate(box)


def test_one_particle_meets_walls_only_and_switched_off_collisions_assemble_no_effect():
    one = small_pipe({"bodies": [{"shape": "sphere", "diameter_mm": 10, "position_mm": [0, 0, 50]}]})
    sim = simulation_from_scene(Scene.model_validate(one), derive(Scene.model_validate(one)))
    ce = sim.effect(CollisionEffect)
    assert ce is not None and ce.pairs is False and "walls only" in ce.name
    off = copy.deepcopy(one)
    off["particles"]["collisions"] = {"enabled": False}
    sim = simulation_from_scene(Scene.model_validate(off), derive(Scene.model_validate(off)))
    assert sim.effect(CollisionEffect) is None



def test_pairs_off_keeps_particles_inside_the_pipe_while_they_pass_through_each_other():
    # Two spheres on a collision course, one heading into the wall: without pair contacts they
    # overlap freely, but the wall contact still turns the second one back.
    data = small_pipe({"bodies": [
        {"shape": "sphere", "diameter_mm": 10, "position_mm": [6, 0, 50], "velocity_m_s": [0.1, 0, 0]},
        {"shape": "sphere", "diameter_mm": 10, "position_mm": [17, 0, 50], "velocity_m_s": [0.1, 0, 0]}]})
    data["particles"]["collisions"] = {"pairs": False}
    scene = Scene.model_validate(data)
    sim = simulation_from_scene(scene, derive(scene))
    ce = sim.effect(CollisionEffect)
    assert ce is not None and ce.pairs is False and "pairs switched off" in ce.name
    sim.step(100)
    assert ce.totals["pair_contacts"] == 0 and ce.totals["wall_contacts"] > 0
    assert sim.guard is not None
    sim.guard.check(sim)  # every particle inside the pipe


def test_dense_run_holds_flow_rate_mean_density_and_the_overlap_bound(tmp_path):
    data = small_pipe({"packed": [{"shape": "cube", "edge_mm": 8, "concentration": 0.3, "seed": 1}]})
    data["run"] = {"duration_s": 0.75, "spinup_s": 0.5, "sample_interval_s": 0.025}
    scene = Scene.model_validate(data)
    params = derive(scene)
    sim = simulation_from_scene(scene, params)
    ctl = sim.effect(fx.FlowRateControl)
    mc = sim.effect(MassCorrection)
    rho0 = sim.mass() / sim.fluid_mask().sum()
    sim.step(params.n_steps)
    rho1 = sim.mass() / sim.fluid_mask().sum()
    # the PI controller holds the mixture's flux with 115 cubes (the old integral one reached 0.6 Q*)
    assert abs(ctl.q / ctl.q_target - 1.0) < 0.02
    # without the correction the mean density fell 0.6 % per 100 steps here
    assert abs(rho1 / rho0 - 1.0) < 2e-3 and mc.added != 0.0
    ce = sim.effect(CollisionEffect)
    assert ce.totals["max_overlap_after_lu"] <= ce.params.overlap_tol + 1e-12
    assert ce.totals["impulses"] > 0
    assert np.isfinite(sim.particles.bodies.v).all()


def test_summary_records_packing_and_collisions(tmp_path):
    data = small_pipe({"packed": [{"shape": "cylinder", "diameter_mm": 16, "length_mm": 16, "concentration": 0.3}],
                       "collisions": {"restitution": 0.5}})
    scene = Scene.model_validate(data)
    summary = run_scene(scene, derive(scene), tmp_path, progress=False)
    assert summary["status"] == "completed"
    assert summary["particles"]["count"] == 18 and summary["particles"]["collisions"] is True
    assert summary["particles"]["concentration_target"] == 0.3
    assert summary["collisions"]["enabled"] and summary["collisions"]["restitution"] == 0.5
    assert summary["collisions"]["pairs"] is True
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["collisions"]["calls"] == summary["steps"]


def test_a_case_named_in_duration_s_by_case_averages_longer_and_only_that_case():
    from lbmpipe.reproduction.cases import case_scene
    fid = {"dx_mm": 2.5, "run": {"duration_s": 0.3, "spinup_s": 0.1, "sample_interval_s": 0.025},
           "duration_s_by_case": {"cube24_c30_re26": 3.0}}
    case = {"reynolds": 26, "particles": {"shape": "cube", "edge_mm": 24, "concentration": 0.3}}
    assert case_scene("cube24_c30_re26", case, "smoke", fid)["run"]["duration_s"] == 3.0
    assert case_scene("cube24_c30_re9.4", dict(case, reynolds=9.4), "smoke", fid)["run"]["duration_s"] == 0.3
    assert case_scene("cube24_c30_re26", case, "smoke", fid)["run"]["spinup_s"] == 0.1


def test_assembled_step_orders_walls_particle_fills_sweep_flux_correction_control_collisions_motion():
    from lbmpipe.particles.coupling import ParticleCoupling, ParticleFluxCorrection, ParticleMotion
    from lbmpipe.assemble import grid_from_scene, particle_system_from_scene

    data = small_pipe({"random": [{"shape": "cube", "edge_mm": 8, "count": 3, "seed": 1}]})
    scene = Scene.model_validate(data)
    params = derive(scene)
    grid = grid_from_scene(scene, params)
    system, _ = particle_system_from_scene(scene, params, grid)
    step = assemble(scene, params, grid, system)
    kinds = [type(e) for e in step.effects]
    assert kinds == [fx.WallBounceBack, ParticleCoupling, fx.StreamCollide, ParticleFluxCorrection,
                     fx.FlowRateControl, CollisionEffect, ParticleMotion, MassCorrection]
    # decided once: forcing and the flux sum (flow-rate driving), the density floor (free particles)
    spec = step.fluid.spec
    assert spec.forcing and spec.flux and spec.floor and step.fluid.rho_min == scene.numerics.density_floor
    assert step.force[2] == step.control[0].f_ref
    sim = simulation_from_scene(scene, params)
    assert [type(e) for e in sim.effects] == kinds
    # without particles: no floor in the kernel
    flow = Scene.model_validate({k: v for k, v in data.items() if k != "particles"})
    bare = assemble(flow, derive(flow), grid_from_scene(flow, derive(flow)))
    assert not bare.fluid.spec.floor and bare.fluid.rho_min == 0.0


def test_cases_study_and_stability_build_the_same_paper_pipe_flow_and_time_step():
    from lbmpipe.reproduction import pipe, stability, study_plan

    case = cases.case_scene("flow_re26", {"reynolds": 26}, "tiny", {**SMOKE, "re26_dt_factor": 1.0})
    stab = stability.StabilityCase("x", "", reynolds=26.0, particles=None, kind="flow").scene(5.0, 10)
    settings = study_plan.study_settings({"study": {}, "fidelities": {"tiny": SMOKE}}, "tiny")
    for data in (case, stab):
        assert data["domain"] == pipe.PIPE
        assert data["driving"]["flow_rate_m3_s"] == pipe.FLOWS[26.0]
        assert data["numerics"]["dt_s"] == pipe.time_step(5.0)
    s = study_plan.pipe_scene(settings, {"dx_mm": 5.0, "dt_factor": 1.0, "collision": "bgk", "wall": "bounce_back",
                                    "precision": "float64"})
    assert s["domain"]["diameter_mm"] == pipe.PIPE["diameter_mm"]
    assert s["driving"]["flow_rate_m3_s"] == pipe.FLOWS[9.4]
    assert s["numerics"]["dt_s"] == pipe.time_step(5.0)


def test_config_schema_rejects_a_misspelt_study_or_stability_key():
    from pathlib import Path

    from snakemake.utils import validate

    root = Path(__file__).resolve().parents[1]
    schema = str(root / "workflow" / "schemas" / "config.schema.yaml")
    config = yaml.safe_load((root / "config.yaml").read_text())
    validate(copy.deepcopy(config), schema)
    for section, level, key in (("study", "smoke", "dx"), ("stability", "smoke", "step")):
        bad = copy.deepcopy(config)
        bad[section][level][key] = 1
        with pytest.raises(Exception, match="config"):
            validate(bad, schema)


def test_a_production_run_refuses_a_source_tree_with_uncommitted_changes(monkeypatch):
    # the committed results must name a commit whose code ran them
    monkeypatch.setattr(cases, "git_commit", lambda: "abc123-dirty")
    with pytest.raises(cases.DirtyTreeError, match="allow_dirty=true"):
        cases.require_clean_tree(production=True, allow_dirty=False)
    rec = cases.require_clean_tree(production=True, allow_dirty=True)  # an experiment: let through, recorded
    assert rec == {"git_commit": "abc123-dirty", "production": True, "dirty": True, "allow_dirty": True}
    assert cases.require_clean_tree(production=False, allow_dirty=False)["dirty"] is True  # smoke, tests
    monkeypatch.setattr(cases, "git_commit", lambda: "abc123")
    assert cases.require_clean_tree(production=True, allow_dirty=True)["allow_dirty"] is False


def test_the_committed_levels_are_production_levels():
    cfg = yaml.safe_load((Path(__file__).resolve().parents[1] / "config.yaml").read_text())
    assert all(cfg["fidelities"][k].get("production") for k in ("paper", "credible", "credible_accurate"))
    assert not cfg["fidelities"]["smoke"].get("production")
