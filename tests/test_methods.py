"""The method dimension: the paper's BGK with half-way bounce-back against TRT (magic 1/4) with the
Bouzidi pipe wall (``accurate_fluid``, the committed ``credible_accurate``) or with issue 44's particle
options too (``accurate``), on the same lattice and packings, compared run by run and claim by claim."""

import copy
import json
from pathlib import Path
from unittest import mock

import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction import cases, methods
from lbmpipe.reproduction import claims as claims_mod
from lbmpipe.scene import Scene
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text())


def test_accurate_level_changes_only_collision_and_wall_on_the_same_packing():
    name, case = cases.run_case(CONFIG, "cyl8x16_c30_re9.4/seed1")
    paper = cases.case_scene(name, case, "credible", CONFIG["fidelities"]["credible"])
    acc = cases.case_scene(name, case, "credible_accurate", CONFIG["fidelities"]["credible_accurate"])
    assert acc["numerics"] == {**paper["numerics"], "collision": "trt", "trt_magic": 0.25, "wall": "bouzidi"}
    assert acc["particles"] == paper["particles"] and acc["run"] == paper["run"]
    # the same relaxation time: the method changes the operator, not the physics asked for
    p_params, a_params = derive(Scene.model_validate(paper)), derive(Scene.model_validate(acc))
    assert a_params.tau == pytest.approx(p_params.tau) and a_params.n_steps == p_params.n_steps
    # magic 1/4: (tau+ - 1/2)(tau- - 1/2) = 1/4
    tau_minus = 1.0 / a_params.omega_minus
    assert (a_params.tau - 0.5) * (tau_minus - 0.5) == pytest.approx(0.25)


def test_accurate_method_uses_the_interpolated_particle_surface_galilean_exchange_and_lubrication():
    num = cases.fidelity_numerics({"dx_mm": 1.0, "method": "accurate"}, 9.4)
    assert num["particle_boundary"] == "cli" and num["momentum_exchange"] == "galilean"
    assert num["lubrication"] == {"enabled": True}
    assert num["collision"] == "trt" and num["trt_magic"] == pytest.approx(3 / 16) and num["wall"] == "bouzidi"
    assert num.get("refill", "equilibrium") == "equilibrium"  # the extrapolated refill measured no gain
    # a level's own numerics still win over its method's, and the scene validates
    over = cases.fidelity_numerics({"dx_mm": 1.0, "method": "accurate", "numerics": {"trt_magic": 0.25}}, 9.4)
    assert over["trt_magic"] == 0.25
    name, case = cases.run_case(CONFIG, "cyl8x16_c30_re9.4/seed1")
    acc = cases.case_scene(name, case, "x", {**CONFIG["fidelities"]["credible"], "method": "accurate"})
    sc = Scene.model_validate(acc)
    assert sc.numerics.particle_boundary == "cli" and sc.numerics.lubrication.enabled


def test_method_comparison_reports_the_numerics_the_compared_level_changes():
    changed = cases.method_numerics(CONFIG, "credible_accurate", against="credible")
    assert changed == {"collision": "trt", "trt_magic": 0.25, "wall": "bouzidi"}
    cfg = copy.deepcopy(CONFIG)
    cfg["fidelities"]["credible_accurate"]["method"] = "accurate"
    text = cases.numerics_text(cases.method_numerics(cfg, "credible_accurate", against="credible"))
    assert "particle_boundary: cli" in text and "momentum_exchange: galilean" in text
    assert "lubrication.enabled: true" in text and "trt_magic: 0.1875" in text
    assert cases.numerics_text({}) == "the scene's defaults"


@pytest.mark.parametrize("run", ["cyl8x16_c30_re9.4/seed1", "cube8_c50_re9.4/seed1", "flow_re26"])
def test_committed_credible_accurate_scenes_are_rebuilt_byte_for_byte(run, tmp_path):
    # the level ran with the method now called accurate_fluid: the workflow's path
    # (write_case_scene, the packing referenced relative to the scene) writes the committed file again
    committed = ROOT / "results" / "credible_accurate" / "cases" / run / "scene.yaml"
    pid = cases.packing_id(cases.run_case(CONFIG, run)[1])
    out = tmp_path / "results" / "credible_accurate" / "cases" / run / "scene.yaml"
    cases.write_case_scene(CONFIG, "credible_accurate", run, out,
                           packing_csv=tmp_path / "results" / "packings" / f"{pid}.csv" if pid else None)
    assert out.read_bytes() == committed.read_bytes()


def test_paper_method_level_scenes_are_unchanged_by_the_method_dimension():
    name, case = cases.run_case(CONFIG, "cube16_c30_re9.4/seed2")
    num = cases.case_scene(name, case, "credible", CONFIG["fidelities"]["credible"])["numerics"]
    assert "collision" not in num and "wall" not in num  # the scene's defaults: BGK, half-way bounce-back


def test_a_level_with_a_case_list_runs_only_those_cases_once_per_seed():
    runs = cases.level_runs(CONFIG, "credible_accurate")
    subset = CONFIG["fidelities"]["credible_accurate"]["cases"]
    assert {cases.split_run(r)[0] for r in runs} == set(subset)
    assert all(r.endswith("/seed1") for r in runs if CONFIG["cases"][cases.split_run(r)[0]].get("particles"))
    assert methods.comparison_level(CONFIG, "credible") == "credible_accurate"


def test_config_naming_an_unknown_level_is_an_error_and_a_trimmed_case_list_is_skipped():
    bad = copy.deepcopy(CONFIG)
    bad["fidelities"]["credible_accurate"]["compare_with"] = "nosuchlevel"
    probs = cases.config_problems(bad, ROOT / cases.CONFIG_SCHEMA)
    assert any("fidelities.credible_accurate.compare_with" in p and "Fix:" in p for p in probs)
    bad = copy.deepcopy(CONFIG)
    bad["fidelities"]["credible_dx2"]["convergence_of"] = "nosuchlevel"
    probs = cases.config_problems(bad, ROOT / cases.CONFIG_SCHEMA)
    assert any("fidelities.credible_dx2.convergence_of" in p and "Fix:" in p for p in probs)
    # a config trimmed to two cases keeps every level valid; a level runs the cases it names that remain
    trimmed = copy.deepcopy(CONFIG)
    trimmed["cases"] = {k: CONFIG["cases"][k] for k in ("flow_re9.4", "cube8_c30_re9.4")}
    assert cases.config_problems(trimmed, ROOT / cases.CONFIG_SCHEMA) == []
    assert cases.level_cases(trimmed, "credible_accurate") == ["cube8_c30_re9.4", "flow_re9.4"]
    assert cases.level_cases(trimmed, "credible_dx2") == ["flow_re9.4"]


def _run(root, level, run, omega, ci, angle=None, profile=0.01, flags=()):
    d = root / level / "cases" / run
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({"status": "completed", "profile_error_rel_l2": profile}))
    if omega is not None:
        stats = {"shape": "cylinder", "mean_abs_omega_rad_s": dict(zip("xyz", omega)), "ci95_rad_s": dict(zip("xyz", ci)),
                 "orientation": {"cyl_axis_angle": {"mean_deg": angle, "ci95_deg": 1.0}}, "flags": list(flags)}
        (d / "stats.json").write_text(json.dumps(stats))


def _config():
    return {"cases": {"flow_re9.4": {"reynolds": 9.4},
                      "cyl8x16_c30_re9.4": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8,
                                                                            "length_mm": 16, "concentration": 0.3}}},
            "fidelities": {"base": {"dx_mm": 1.0, "seeds": 3, "run": {}},
                           "acc": {"dx_mm": 1.0, "seeds": 1, "method": "accurate", "compare_with": "base",
                                   "cases": ["flow_re9.4", "cyl8x16_c30_re9.4"], "run": {}}}}


def test_paired_runs_differ_significantly_only_beyond_both_intervals(tmp_path):
    # x differs by 0.3 with intervals 0.1 each (combined 0.14): significant; y by 0.1: not
    _run(tmp_path, "base", "cyl8x16_c30_re9.4/seed1", (1.0, 1.0, 0.5), (0.1, 0.1, 0.05), angle=40.0)
    _run(tmp_path, "acc", "cyl8x16_c30_re9.4/seed1", (1.3, 1.1, 0.5), (0.1, 0.1, 0.05), angle=40.5, flags=("frozen",))
    _run(tmp_path, "base", "flow_re9.4", None, None, profile=0.05)
    _run(tmp_path, "acc", "flow_re9.4", None, None, profile=0.004)
    runs = methods.run_rows(_config(), "base", "acc", tmp_path)
    r = runs.set_index(["run", "observable"])
    assert r.loc[("cyl8x16_c30_re9.4/seed1", "mean_abs_omega_x"), "significant"] == True  # noqa: E712
    assert r.loc[("cyl8x16_c30_re9.4/seed1", "mean_abs_omega_x"), "rel_diff"] == pytest.approx(0.3)
    assert r.loc[("cyl8x16_c30_re9.4/seed1", "mean_abs_omega_y"), "significant"] == False  # noqa: E712
    assert r.loc[("cyl8x16_c30_re9.4/seed1", "mean_angle_deg"), "significant"] == False  # noqa: E712
    assert r.loc[("cyl8x16_c30_re9.4/seed1", "mean_abs_omega_x"), "accurate_flags"] == "frozen"
    assert r.loc[("flow_re9.4", "profile_error_rel_l2"), "accurate"] == pytest.approx(0.004)
    s = methods.summary(runs, pd.DataFrame(columns=methods.CLAIM_COLUMNS))
    assert s["pairs"] == 2 and s["omega_compared"] == 3 and s["omega_significant"] == 1
    assert s["flows"] == [{"run": "flow_re9.4", "paper": 0.05, "accurate": 0.004}]


def test_an_accurate_run_without_its_paper_method_partner_is_not_compared(tmp_path):
    _run(tmp_path, "acc", "cyl8x16_c30_re9.4/seed1", (1.3, 1.1, 0.5), (0.1, 0.1, 0.05), angle=40.0)
    assert len(methods.run_rows(_config(), "base", "acc", tmp_path)) == 0


def test_claim_verdicts_side_by_side_mark_the_changed_ones(tmp_path):
    cols = ["claim", "statement", "statistic", "values", "verdict", "reason"]
    paper = pd.DataFrame([[1, "a", "", "", "reproduced", "interval excludes 0"],
                          [2, "b", "", "", "inconclusive", "inputs missing: x: not run"]], columns=cols)
    acc = pd.DataFrame([[1, "a", "", "", "contradicted", "the opposite ordering"],
                        [2, "b", "", "", "inconclusive", "inputs missing: x: not run"]], columns=cols)
    c = methods.claim_rows(paper, acc)
    by = c.set_index("claim")
    assert by.loc[1, "same"] == "no" and by.loc[1, "verdict_accurate_seed1"] == "contradicted"
    assert by.loc[2, "same"] == "not compared"
    assert methods.summary(pd.DataFrame(columns=methods.RUN_COLUMNS), c)["claims_changed"] == [1]
    # the level's claims.csv carries both methods' verdicts beside its own
    c.to_csv(tmp_path / "method_claims.csv", index=False)
    level = pd.DataFrame([[1, "a", "", "", "reproduced", ""], [2, "b", "", "", "reproduced", ""]], columns=cols)
    with mock.patch.object(claims_mod, "evaluate_claims", return_value=level):
        out = pd.read_csv(claims_mod.write_claims(tmp_path / "lvl", {}, tmp_path / "method_claims.csv")).set_index("claim")
    assert list(out.loc[1, ["verdict", "verdict_paper_method_seed1", "verdict_accurate_method_seed1",
                            "same_under_both_methods"]]) == ["reproduced", "reproduced", "contradicted", "no"]
    assert out.loc[2, "same_under_both_methods"] == "not compared"


def test_claims_from_seed_one_of_the_same_cases_under_each_method(tmp_path):
    # the paper method's level has three packings: its seed-1 view holds seed 1's record only
    cfg = _config()
    _run(tmp_path, "base", "cyl8x16_c30_re9.4/seed1", (1.0, 1.0, 0.5), (0.1, 0.1, 0.05), angle=40.0)
    _run(tmp_path, "base", "cyl8x16_c30_re9.4/seed2", (9.0, 9.0, 9.0), (0.1, 0.1, 0.05), angle=40.0)
    claims = methods.seed1_claims(cfg, "base", ["cyl8x16_c30_re9.4"], tmp_path, tmp_path / "work")
    assert sorted(claims["claim"]) == list(range(1, 15))
    av = pd.read_csv(tmp_path / "work" / "base" / "tables" / "angular_velocity.csv").set_index("case")
    assert av.loc["cyl8x16_c30_re9.4", "omega_x"] == pytest.approx(1.0)


def test_comparison_writes_its_tables_even_before_any_accurate_run(tmp_path):
    cols = ["claim", "statement", "statistic", "values", "verdict", "reason"]
    (tmp_path / "base").mkdir()
    pd.DataFrame([[k, "s", "", "", "inconclusive", "inputs missing"] for k in range(1, 15)], columns=cols).to_csv(
        tmp_path / "base" / "claims.csv", index=False)
    s = methods.write(_config(), "base", tmp_path, tmp_path / "base" / "method")
    assert s["accurate_level"] == "acc" and s["accurate_runs_planned"] == 2 and s["pairs"] == 0
    # the record names the method and the numerics it changes against the paper level
    assert s["accurate_method"] == "accurate" and s["accurate_numerics"]["particle_boundary"] == "cli"
    assert (tmp_path / "base" / "method" / "runs.csv").exists() and (tmp_path / "base" / "method" / "claims.csv").exists()
    assert (tmp_path / "base" / "method" / "method_comparison.png").stat().st_size > 0


def test_a_paired_runs_flags_are_judged_against_todays_health_thresholds(tmp_path):
    # the run's stats.json was written with no health issue; its summary shows an overlap between
    # collision calls beyond the collision model's bound, which makes the run unhealthy today
    _run(tmp_path, "base", "cyl8x16_c30_re9.4/seed1", (1.0, 1.0, 0.5), (0.1, 0.1, 0.05), angle=40.0)
    _run(tmp_path, "acc", "cyl8x16_c30_re9.4/seed1", (1.0, 1.0, 0.5), (0.1, 0.1, 0.05), angle=40.0)
    d = tmp_path / "acc" / "cases" / "cyl8x16_c30_re9.4" / "seed1"
    (d / "summary.json").write_text(json.dumps({"status": "completed", "profile_error_rel_l2": 0.01,
                                                "collisions": {"max_overlap_before_lu": 0.2}}))
    runs = methods.run_rows(_config(), "base", "acc", tmp_path).set_index(["run", "observable"])
    row = runs.loc[("cyl8x16_c30_re9.4/seed1", "mean_abs_omega_x")]
    assert row["accurate_flags"] == "unhealthy" and row["paper_flags"] == ""
