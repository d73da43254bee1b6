"""The robustness controls of issue 47 (lbmpipe.reproduction.robustness): the verdict under each
control with "not run" / "not covered" / "partly run" stated, robust only when every covering
control holds, the systematic term from the largest measured shift, the convergence check, the
health side by side, and the control levels in the config and the DAG."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction import robustness as R
from lbmpipe.reproduction.cases import CONFIG_SCHEMA, case_scene, config_problems, level_runs

ROOT = Path(__file__).resolve().parents[1]


def _claims(verdicts: dict[int, str], uncovered=()) -> pd.DataFrame:
    rows = []
    for k, v in verdicts.items():
        miss = k in uncovered
        rows.append({"claim": k, "verdict": "inconclusive" if miss else v,
                     "reason": "inputs missing: x not run" if miss else "pooled interval ...",
                     "carried_by": "no comparison" if miss else "2 of 3 significant"})
    return pd.DataFrame(rows)


def test_a_control_not_run_says_not_run_and_a_claim_it_does_not_compare_is_not_covered():
    base = _claims({1: "reproduced", 2: "contradicted"}, uncovered=(2,))
    rows = R.control_rows(base, base, "Ma/2", "lvl", done=[], missing=["a/seed1", "b/seed1"])
    assert list(rows["status"]) == ["not run", "not covered by Ma/2"]
    assert rows["missing"].iloc[0] == "a/seed1; b/seed1"
    robust = R.robust_column({1: "reproduced", 2: "contradicted"}, rows)
    assert robust[1].startswith("pending: Ma/2") and robust[2] == "not covered by any control"


def test_robust_only_when_every_covering_control_holds_and_a_change_names_its_control():
    base = _claims({1: "reproduced", 2: "reproduced", 3: "contradicted"}, uncovered=(3,))
    same = _claims({1: "reproduced", 2: "reproduced", 3: "contradicted"})
    changed = _claims({1: "reproduced", 2: "inconclusive", 3: "reproduced"})
    a = R.control_rows(base, same, "Ma/2", "a", done=["x"], missing=[])
    b = R.control_rows(base, changed, "reference", "b", done=["x", "y"], missing=[])
    rows = pd.concat([a, b], ignore_index=True)
    assert list(b["status"]) == ["holds", "changes", "not covered by reference"]
    robust = R.robust_column({1: "reproduced", 2: "reproduced", 3: "contradicted"}, rows)
    assert robust[1] == "yes"
    assert robust[2] == "no: changes under reference"
    assert robust[3] == "not covered by any control"


def test_a_partly_run_control_names_its_missing_runs_and_keeps_the_claim_pending():
    base = _claims({1: "reproduced"})
    rows = R.control_rows(base, base, "reference", "b", done=["c/seed1"], missing=["c/seed2", "c/seed3"])
    assert rows["status"].iloc[0] == "partly run (holds on the runs present)"
    assert rows["missing"].iloc[0] == "c/seed2; c/seed3"
    assert R.robust_column({1: "reproduced"}, rows)[1] == "pending: reference"


def test_a_partly_run_control_without_the_claims_pair_is_pending_and_its_change_on_few_runs_is_not_a_change():
    """One Ma/2 run present of many: a claim whose cases it does not hold yet cannot change (the
    control's view lacks its inputs), and a verdict that differs on the runs present is pending."""
    base = _claims({1: "reproduced", 2: "contradicted"})
    on_present = _claims({1: "reproduced", 2: "contradicted"}, uncovered=(1,))  # claim 1's pair not run yet
    control = _claims({1: "reproduced", 2: "reproduced"}, uncovered=(1,))
    rows = R.control_rows(base, control, "Ma/2", "a", done=["x/seed1"], missing=["y/seed1", "z/seed1"],
                          baseline_present=on_present)
    assert list(rows["status"]) == ["partly run (no comparison on the runs present)",
                                    "partly run (changes on the runs present)"]
    assert list(rows["verdict"]) == ["", "reproduced"]
    robust = R.robust_column({1: "reproduced", 2: "contradicted"}, rows)
    assert robust == {1: "pending: Ma/2", 2: "pending: Ma/2"}


def test_only_cases_with_every_packing_present_enter_a_partly_run_controls_comparison():
    config = {"cases": {"a": {"particles": {}}, "b": {"particles": {}}, "flow": {}},
              "fidelities": {"c": {"seeds": 2, "cases": ["a", "b", "flow"]}}}
    assert R.cases_present(config, "c", ["a/seed1", "a/seed2", "b/seed1", "flow"]) == ["a", "flow"]


def test_floor_share_counts_samples_at_each_runs_own_density_floor_and_a_missing_scene_is_an_error(tmp_path):
    _run(tmp_path / "r03", floor_devs=(0.1, 0.5, 0.7, 0.7), floor=0.3)
    _run(tmp_path / "none", floor_devs=(0.1, 0.5, 0.7, 0.7), floor=None)
    assert R.run_health_figures(tmp_path / "r03")["floor_sample_share"] == pytest.approx(0.5)   # 0.7 = 1 - 0.3
    assert R.run_health_figures(tmp_path / "none")["floor_sample_share"] == 0.0
    (tmp_path / "r03" / "scene.yaml").unlink()
    with pytest.raises(FileNotFoundError, match="density floor"):
        R.run_health_figures(tmp_path / "r03")


def test_systematic_term_is_the_largest_shift_per_observable_and_a_config_value_overrides_it():
    shifts = pd.DataFrame([
        {"control": "Ma/2", "case": "a", "observable": "omega", "key": "mean_abs_omega_x", "base": 1.0,
         "base_ci95": 0.1, "control_value": 1.06, "control_ci95": 0.1, "shift": 0.06},
        {"control": "reference", "case": "b", "observable": "omega", "key": "mean_abs_omega_z", "base": 0.5,
         "base_ci95": 0.1, "control_value": 0.44, "control_ci95": 0.1, "shift": -0.12},
        {"control": "reference", "case": "b", "observable": "angle", "key": "mean_angle_deg", "base": 40.0,
         "base_ci95": 1.0, "control_value": 42.5, "control_ci95": 1.0, "shift": 2.5},
        {"control": "reference", "case": "flow_re9.4", "observable": "profile", "key": "profile_distance",
         "base": 0.02, "base_ci95": 0.0, "control_value": 0.01, "control_ci95": 0.0, "shift": -0.5},
        {"control": "reference", "case": "b", "observable": "profile", "key": "profile_distance",
         "base": 0.2, "base_ci95": 0.0, "control_value": 0.22, "control_ci95": 0.0, "shift": 0.1},
    ]).assign(sensitivity=False)
    # a sensitivity case (collisions off: no verdict rests on it) moves far and sets no term
    shifts.loc[len(shifts)] = {"control": "reference", "case": "c_nocoll", "observable": "angle",
                               "key": "mean_angle_deg", "base": 66.0, "base_ci95": 3.0, "control_value": 37.0,
                               "control_ci95": 1.0, "shift": -29.0, "sensitivity": True}
    assert R.is_sensitivity({"particles": {}, "collisions": False}) and not R.is_sensitivity({"particles": {}})
    got = R.systematic_from_shifts(shifts)
    assert got["terms"]["omega_rel"] == pytest.approx(0.12)
    assert got["terms"]["angle_deg"] == pytest.approx(2.5)
    assert got["terms"]["profile_rel_l2"] == pytest.approx(0.1)  # the particle cases', not the flow's wall error
    assert got["terms"]["fraction_abs"] == 0.0 and "no shift measured" in got["figures"]["fraction_abs"]
    assert "reference on b mean_abs_omega_z" in got["figures"]["omega_rel"]
    used = R.systematic_terms_for({"systematic": {"omega_rel": 0.0, "angle_deg": 5.0}}, got)
    assert used["omega_rel"] == pytest.approx(0.12) and used["angle_deg"] == 5.0


@pytest.mark.parametrize("coarse, fine, status", [
    ((1.00, 0.05), (1.03, 0.05), "converged"),                       # 3 % apart
    ((1.00, 0.08), (1.12, 0.08), "not converged"),                   # 10.7 % apart, combined 10.1 %
    ((1.00, 0.09), (1.10, 0.09), "converged"),                       # 9 % apart, within the combined 11.6 %
    ((1.00, 0.15), (1.01, 0.05), "not converged (interval wider than 10 %)"),
])
def test_reference_converges_when_the_two_finest_lattices_agree_within_5_percent_or_their_intervals(coarse, fine,
                                                                                                     status):
    got, figures = R.convergence_check(coarse, fine)
    assert got == status
    assert "differ by" in figures


def _run(d: Path, status="completed", floor_devs=(0.1, 0.5, 0.2, 0.6), mass_rel=0.2, floor: float | None = 0.5):
    d.mkdir(parents=True, exist_ok=True)
    (d / "scene.yaml").write_text(yaml.safe_dump({"numerics": {"density_floor": floor}}))
    (d / "summary.json").write_text(json.dumps({
        "status": status, "steps": 1000, "mass_correction": {"mass_added_rel": mass_rel},
        "lattice": {"fluid_nodes": 1000.0, "flow_rate_lu": 10.0}}))
    pd.DataFrame({"t_s": range(len(floor_devs)), "max_density_deviation": floor_devs}).to_csv(d / "flow_rate.csv",
                                                                                              index=False)


def test_health_side_by_side_gives_mass_put_back_with_its_sign_and_floor_share_and_not_run_for_a_missing_reference(tmp_path):
    config = {"cases": {"cube8_c30_re9.4": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8,
                                                                         "concentration": 0.3}},
                        "flow_re9.4": {"reynolds": 9.4}},
              "fidelities": {"base": {"seeds": 2}, "ref": {"seeds": 2, "control_of": "base", "control": "reference",
                                                           "cases": ["cube8_c30_re9.4", "flow_re9.4"]}}}
    _run(tmp_path / "base/cases/cube8_c30_re9.4/seed1")
    _run(tmp_path / "base/cases/cube8_c30_re9.4/seed2", floor_devs=(0.1, 0.1, 0.1, 0.1), mass_rel=0.4)
    _run(tmp_path / "ref/cases/cube8_c30_re9.4/seed1", floor_devs=(0.1, 0.1), mass_rel=0.0)
    rows = R.health_rows(config, "base", tmp_path).set_index(["case", "level"])
    b = rows.loc[("cube8_c30_re9.4", "base")]
    assert b["mass_corrected_fluid"] == pytest.approx(0.3)                    # mean of 0.2 and 0.4
    assert b["mass_corrected_throughflow"] == pytest.approx(0.3 * 1000 / (10 * 1000))
    assert b["floor_sample_share"] == pytest.approx(0.25)                     # 2 of 4, then 0 of 4
    r = rows.loc[("cube8_c30_re9.4", "ref")]
    assert r["status"] == "completed (1 of 2 runs)" and r["mass_corrected_fluid"] == 0.0
    # a correction that took mass out keeps its sign, in both columns
    _run(tmp_path / "out", mass_rel=-0.2)
    out = R.run_health_figures(tmp_path / "out")
    assert out["mass_corrected_fluid"] == pytest.approx(-0.2)
    assert out["mass_corrected_throughflow"] == pytest.approx(-0.2 * 1000 / (10 * 1000))
    assert rows.loc[("flow_re9.4", "ref"), "status"] == "not run"


def _config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text())


def test_control_levels_validate_and_each_changes_one_thing_of_credible():
    config = _config()
    assert config_problems(config, ROOT / CONFIG_SCHEMA) == []
    levels = R.control_levels(config, "credible")
    assert [R.control_label(config, lvl) for lvl in levels] == ["Ma/2", "reference", "dx 0.625 mm",
                                                                 "gap 0.5 + lubrication"]
    assert R.reference_level(config, "credible") == "credible_reference"
    fid = config["fidelities"]
    assert len(level_runs(config, "credible_reference")) == 3 * 13 + 2  # 3 packings on every particle case
    # (d): the scene's contact gap halved and lubrication on, the rest the paper's
    sc = case_scene("cube8_c30_re9.4", config["cases"]["cube8_c30_re9.4"], "credible_gap05", fid["credible_gap05"])
    assert sc["particles"]["collisions"]["contact_gap_dx"] == 0.5
    assert sc["numerics"]["lubrication"] == {"enabled": True}
    plain = case_scene("cube8_c30_re9.4", config["cases"]["cube8_c30_re9.4"], "credible", fid["credible"])
    assert "contact_gap_dx" not in plain["particles"]["collisions"]
    assert sc["numerics"]["dt_s"] == plain["numerics"]["dt_s"]
    half = case_scene("cube8_c30_re9.4", config["cases"]["cube8_c30_re9.4"], "credible_ma2", fid["credible_ma2"])
    assert half["numerics"]["dt_s"] == pytest.approx(plain["numerics"]["dt_s"] / 2)


def test_a_control_naming_an_unknown_level_is_a_config_error():
    config = _config()
    config["fidelities"]["credible_ma2"]["control_of"] = "credibel"
    problems = config_problems(config, ROOT / CONFIG_SCHEMA)
    assert any("fidelities.credible_ma2.control_of" in p and "credibel" in p for p in problems)


def _snakemake() -> str:
    return shutil.which("snakemake", path=str(Path(sys.executable).parent)) or "snakemake"


def test_controls_target_plans_only_the_control_levels_runs_and_nothing_under_new_runs_none():
    config = _config()
    levels = R.control_levels(config, "credible") + R.unstable_levels(config, "credible")
    res = subprocess.run([_snakemake(), "-n", "--nolock", "controls", "--config", "new_runs=all"], cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    fids = {line.split("fidelity=")[1].split(",")[0].strip() for line in out.splitlines() if "fidelity=" in line}
    assert fids and fids <= set(levels), fids
    runs = [r for lvl in levels for r in level_runs(config, lvl)]
    done = [r for lvl in levels for r in level_runs(config, lvl)
            if (ROOT / "results" / lvl / "cases" / r / "summary.json").exists()]
    assert out.count("rule simulate_") == len(runs) - len(done)
    none = subprocess.run([_snakemake(), "-n", "--nolock", "controls"], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert none.returncode == 0 and "rule simulate_" not in none.stdout + none.stderr


def test_document_section_counts_robust_changed_pending_and_not_covered_apart(tmp_path):
    (tmp_path / "tables").mkdir()
    (tmp_path / "robustness").mkdir()
    claims = pd.DataFrame({"claim": [1, 2, 3, 4], "verdict": ["reproduced"] * 4,
                           "verdict_with_systematic": ["inconclusive"] * 4})
    row = {"control": "reference", "level": "b", "runs_done": 2, "runs_planned": 3, "missing": "", "interim_cases": 0}
    ma2 = {**row, "control": "Ma/2", "level": "a", "runs_done": 0, "verdict": "", "status": "not run"}
    controls = pd.DataFrame(
        [{**row, "claim": 1, "verdict": "reproduced", "baseline": "reproduced", "status": "holds"},
         {**row, "claim": 2, "verdict": "inconclusive", "baseline": "reproduced", "status": "changes"},
         {**row, "claim": 3, "verdict": "reproduced", "baseline": "reproduced",
          "status": "partly run (holds on the runs present)"},
         {**row, "claim": 4, "verdict": "", "baseline": "reproduced", "status": "not covered by reference"}]
        + [{**ma2, "claim": 2, "baseline": "reproduced"}]
        + [{**ma2, "claim": k, "baseline": "reproduced", "status": "not covered by Ma/2"} for k in (1, 3, 4)],
        columns=R.CONTROL_COLUMNS)
    controls.to_csv(tmp_path / "robustness/controls.csv", index=False)
    R.add_to_claims(_write(claims, tmp_path / "claims.csv"), tmp_path / "robustness/controls.csv",
                    tmp_path / "tables/robustness.csv")
    pd.DataFrame([{"control": "Ma/2", "level": "a", "runs_done": 0, "runs_planned": 3, "core_hours_measured": 0.0,
                   "core_hours_planned": 1.5, "source": "cost model", "claims_changed": ""},
                  {"control": "reference", "level": "b", "runs_done": 2, "runs_planned": 2, "core_hours_measured": 2.0,
                   "core_hours_planned": 2.0, "source": "measured", "claims_changed": "2"}]).to_csv(
        tmp_path / "robustness/cost.csv", index=False)
    sec = R.robustness_section(tmp_path, tmp_path)
    assert sec["counts"] == {"robust": 1, "changed": 1, "pending": 1, "not covered": 1}
    assert sec["not_run"] == ["Ma/2"]
    assert sec["cost"]["rows"][0][-1] == "not run" and sec["cost"]["rows"][1][-1] == "complete"
    # the document's table: a verdict that holds is said once; a change keeps its baseline; the verdicts
    # with the systematic term stand in the claims summary, not again here
    assert "verdict_with_systematic" not in sec["table"]["columns"]
    col = sec["table"]["columns"].index("under reference")
    assert [r[col] for r in sec["table"]["rows"]] == ["reproduced (holds)", "inconclusive (changes; baseline reproduced)",
                                                      "reproduced (holds so far)", "–"]
    assert [r[sec["table"]["columns"].index("under Ma/2")] for r in sec["table"]["rows"]] == ["–", "not run", "–", "–"]
    # the committed table keeps the baseline beside every verdict
    full = pd.read_csv(tmp_path / "tables/robustness.csv", keep_default_na=False)
    assert full.loc[0, "under reference"] == "reproduced (holds; baseline reproduced)"
    # a table that names controls without their rows is an error, not a section without them
    (tmp_path / "robustness/controls.csv").unlink()
    with pytest.raises(FileNotFoundError, match="controls.csv"):
        R.robustness_section(tmp_path, tmp_path)


def _write(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False)
    return path


def test_the_unstable_runs_name_the_measured_mechanism_not_the_guards_guess():
    causes = {c["case"]: c for c in R.unstable_causes(ROOT / "results" / "credible")}
    assert "checkerboard" in causes["cube24_c30_re26"]["mechanism"]
    assert "refill of nodes uncovered" in causes["cube24_c30_re26"]["mechanism"]
    assert "dt_half (from 0): completed" in causes["cube24_c30_re26"]["variants"]
    assert "jam lock" in causes["cyl16x16_c50_re26"]["mechanism"]
    assert not causes["cyl16x16_c50_re26"]["complete"]


def _copied_control(tmp_path: Path, name: str, seeds: int) -> tuple[dict, list[str]]:
    """A control level ``name`` of ``credible`` on claim 6's pair (8 mm cubes at 30 %, Re 9.4 and 26)
    with ``seeds`` packings planned, its packing-1 runs copies of the committed base's."""
    config = _config()
    cases = ["cube8_c30_re9.4", "cube8_c30_re26"]
    config["fidelities"] = {"credible": config["fidelities"]["credible"],
                            name: {**config["fidelities"]["credible"], "seeds": seeds, "control_of": "credible",
                                   "control": name, "cases": cases}}
    for case in cases:
        src = ROOT / "results/credible/cases" / case
        shutil.copytree(src, tmp_path / "credible/cases" / case)
        shutil.copytree(src / "seed1", tmp_path / name / "cases" / case / "seed1")
    return config, cases


def test_a_control_identical_to_the_base_holds_every_claim_it_covers_with_zero_shifts(tmp_path):
    """End to end on committed runs: the control level's seed-1 runs are copies of the base's, so every
    covered verdict holds, the shifts are 0 and the systematic term is 0 (measured, not defaulted)."""
    config, cases = _copied_control(tmp_path, "copy", seeds=1)
    for case in cases:  # one packing: the run is the case
        shutil.copytree(ROOT / "results/credible/cases" / case / "seed1", tmp_path / "copy/cases" / case,
                        dirs_exist_ok=True)
    rows = R.control_verdicts(config, "credible", tmp_path)
    covered = rows[~rows["status"].str.startswith("not covered")]
    assert set(covered["claim"]) >= {6} and set(covered["status"]) == {"holds"}
    assert (rows.loc[rows["claim"] == 3, "status"] == "not covered by copy").all()
    shifts = R.shift_rows(config, "credible", tmp_path)
    assert len(shifts) and set(shifts["observable"]) >= {"omega", "angle", "fraction", "profile"}
    assert shifts["shift"].abs().max() == 0.0
    sys_ = R.systematic_from_shifts(shifts)
    assert sys_["terms"] == {"omega_rel": 0.0, "angle_deg": 0.0, "fraction_abs": 0.0, "profile_rel_l2": 0.0}
    assert "over" in sys_["figures"]["omega_rel"]  # measured, with its figures


def test_a_several_packing_control_with_only_packing_1_run_gives_an_interim_verdict_that_never_decides_robustness(
        tmp_path):
    """Three packings planned, packing 1 present as copies of the base's: the control itself has no
    case complete (no comparison), its first packing alone holds every covered claim against the
    base's packing 1 (labelled interim), and the robustness column stays pending, not "yes"."""
    config, cases = _copied_control(tmp_path, "ref", seeds=3)
    rows = R.control_verdicts(config, "credible", tmp_path)
    assert R.interim_counts(rows) == {"ref, packing 1": 2}
    interim = rows[rows["interim_cases"] > 0]
    assert set(interim["control"]) == {"ref, packing 1"}
    covered = interim[~interim["status"].str.startswith("not covered")]
    assert 6 in set(covered["claim"])
    assert set(covered["status"]) == {"interim (holds on packing 1 of 2 cases)"}
    assert (covered["verdict"] == covered["baseline"]).all()
    robust = R.robust_column({6: "reproduced"}, rows)
    assert robust[6] == "pending: ref"
    claims = pd.DataFrame({"claim": [6], "verdict": ["reproduced"], "verdict_with_systematic": ["reproduced"]})
    table = R.robustness_table(claims, rows[rows["claim"] == 6])
    assert table.loc[0, "under ref, packing 1 (interim, 2 cases)"] == "reproduced (holds; baseline reproduced)"
    short = R.robustness_table(claims, rows[rows["claim"] == 6], short=True)  # the document's cells
    assert (short.loc[0, "under ref"], short.loc[0, "under ref, packing 1 (interim, 2 cases)"]) == (
        "no pair yet", "reproduced (holds)")
    # a claim with no pair on one packing (claim 9): the interim look has none to wait for
    none = pd.DataFrame([{"claim": 9, "control": "ref", "verdict": "", "baseline": "inconclusive", "interim_cases": 0,
                          "status": "partly run (no comparison on the runs present)"},
                         {"claim": 9, "control": "ref, packing 1", "verdict": "", "baseline": "inconclusive",
                          "interim_cases": 2, "status": "interim (no comparison on packing 1 of 2 cases)"}],
                        columns=R.CONTROL_COLUMNS)
    assert list(R.robustness_table(claims.assign(claim=9), none, short=True).iloc[0, 3:5]) == ["no pair yet", "no pair"]
    # a controls table of an older lbmpipe (no interim_cases) is refused, not read as having no interim rows
    with pytest.raises(ValueError, match="interim_cases"):
        R.robust_column({6: "reproduced"}, rows.drop(columns=["interim_cases"]))
    # its shifts set packing 1 beside the base's packing 1 (identical copies: 0), never the base's three
    shifts = R.shift_rows(config, "credible", tmp_path)
    assert len(shifts) and shifts["shift"].abs().max() == 0.0
    # once every packing is present there is nothing interim left to show
    for case in cases:
        for k in (2, 3):
            shutil.copytree(ROOT / "results/credible/cases" / case / f"seed{k}", tmp_path / "ref/cases" / case / f"seed{k}")
    assert not R.interim_counts(R.control_verdicts(config, "credible", tmp_path))


def test_a_control_run_copied_in_asks_for_its_statistics_and_changes_the_robustness_rules_trigger(tmp_path,
                                                                                                   monkeypatch):
    """`snakemake -c2` must rebuild the robustness outputs when a control run appears: the rule's
    inputs ask for the new run's statistics (built where missing) and its params (a rerun trigger)
    list the runs present."""
    sys.path.insert(0, str(ROOT / "workflow" / "rules"))
    from common import Pipeline  # workflow/rules/common.py
    config = _config()
    lvl = R.control_levels(config, "credible")[0]
    first, second = [r for r in level_runs(config, lvl) if "/seed" in r][:2]
    monkeypatch.chdir(tmp_path)
    pipe = Pipeline(config, "credible", "none", [], [], [])
    wc = type("W", (), {"fidelity": "credible"})()
    assert pipe.robustness_inputs(wc) == [] and pipe.robustness_present(wc) == ""
    _run(tmp_path / "results" / lvl / "cases" / first)
    inputs = [str(f) for f in pipe.robustness_inputs(wc)]
    assert f"results/{lvl}/cases/{first}/stats.json" in inputs   # not there yet: the statistics rule builds it
    digest = pipe.inputs_digest(pipe.robustness_inputs)  # the content trigger takes an input still to be built
    unbuilt = digest(wc)
    (tmp_path / "results" / lvl / "cases" / first / "stats.json").write_text("{}")
    assert digest(wc) != unbuilt
    before = pipe.robustness_present(wc)
    assert before == f"{lvl}/{first}=completed"
    _run(tmp_path / "results" / lvl / "cases" / second, status="unstable")
    assert pipe.robustness_present(wc) == f"{before}; {lvl}/{second}=unstable"


def test_an_unstable_runs_diagnosis_written_later_makes_the_document_rebuild(tmp_path, monkeypatch):
    """The document prints each unstable run's measured cause (``unstable/<case>.json``, of the level and
    of its reruns): those files are inputs of the paper rule, so a new diagnosis is never left out of it
    silently."""
    sys.path.insert(0, str(ROOT / "workflow" / "rules"))
    from common import Pipeline  # workflow/rules/common.py
    config = _config()
    again = R.unstable_levels(config, "credible")[0]
    monkeypatch.chdir(tmp_path)
    pipe = Pipeline(config, "credible", "none", [], [], [])
    wc = type("W", (), {"fidelity": "credible"})()
    assert not [f for f in pipe.paper_extra_inputs(wc) if "/unstable/" in str(f)]
    for lvl in ("credible", again):
        (tmp_path / "results" / lvl / "unstable").mkdir(parents=True)
        (tmp_path / "results" / lvl / "unstable" / "cyl16x16_c50_re26.json").write_text("{}")
    assert [f for f in pipe.paper_extra_inputs(wc) if "/unstable/" in str(f)] == [
        "results/credible/unstable/cyl16x16_c50_re26.json", f"results/{again}/unstable/cyl16x16_c50_re26.json"]


def test_an_unstable_packing_rerun_with_the_reference_method_says_how_each_ended_beside_the_base(tmp_path):
    """Issue 47 item 5: a level with `unstable_of` reruns named packings (`seeds: [3]`) of the base's
    unstable runs; the table gives both endings and the document's cause list carries the rerun's."""
    config = {"cases": {"cube24_c30_re26": {"reynolds": 26, "particles": {"shape": "cube", "edge_mm": 24,
                                                                        "concentration": 0.3}}},
              "fidelities": {"base": {"seeds": 3},
                             "again": {"seeds": [3], "method": "accurate", "mach_factor": 0.5, "unstable_of": "base",
                                       "cases": ["cube24_c30_re26"]}}}
    assert level_runs(config, "again") == ["cube24_c30_re26/seed3"]
    assert R.unstable_levels(config, "base") == ["again"]
    _run(tmp_path / "base/cases/cube24_c30_re26/seed3", status="unstable")
    rows = R.unstable_rows(config, "base", tmp_path)
    assert rows[["base_status", "status"]].values.tolist() == [["unstable", "not run"]]
    _run(tmp_path / "again/cases/cube24_c30_re26/seed3")
    rows = R.unstable_rows(config, "base", tmp_path)
    assert rows[["base_status", "status", "steps", "method"]].values.tolist() == [["unstable", "completed", 1000,
                                                                                   "accurate"]]
    (tmp_path / "base/robustness").mkdir()
    rows.to_csv(tmp_path / "base/robustness/unstable.csv", index=False)
    (tmp_path / "base/unstable").mkdir()
    (tmp_path / "base/unstable/cube24_c30_re26.json").write_text(json.dumps({"case": "cube24_c30_re26",
                                                                             "mechanism": ["checkerboard mode"]}))
    cause = R.unstable_causes(tmp_path / "base")[0]
    assert cause["rerun"] == "accurate at Mach x 0.5 (again): completed after 1000 steps"
    assert cause["outcome"] == "completed after 1000 steps"
    assert cause["mechanism"] == "checkerboard mode"
    assert cause["rerun_mechanism"] == ""  # the rerun has no diagnosis of its own
    (tmp_path / "again/unstable").mkdir()
    (tmp_path / "again/unstable/cube24_c30_re26.json").write_text(json.dumps({"mechanism": ["jam lock", "(figures)"]}))
    assert R.unstable_causes(tmp_path / "base")[0]["rerun_mechanism"] == "again: jam lock; (figures)"
    (tmp_path / "again/unstable/cube24_c30_re26.json").write_text(json.dumps({
        "mechanism": ["jam lock"], "variants": [{"variant": "force_cap", "mode": "switched", "status": "completed"}]}))
    assert R.unstable_causes(tmp_path / "base")[0]["rerun_mechanism"] == (
        "again: jam lock. One change at a time: force_cap (switched): completed")


def test_a_partly_run_controls_plan_scales_the_cost_model_by_what_its_methods_runs_measured(tmp_path):
    """The planned core-hours of a control: its runs present as measured, the missing ones as the cost
    model predicts them times what runs of the same method took against the model (the level's own,
    else another level's of its method), so a particle side the model never saw is in the plan once
    one run shows its cost."""
    config = _config()
    root = tmp_path / "results"
    (root / "credible" / "tables").mkdir(parents=True)
    shutil.copy(ROOT / "results" / "credible" / "tables" / "cost_model.json", root / "credible" / "tables")
    ref, fine = R.reference_level(config, "credible"), "credible_dx0625"
    assert config["fidelities"][fine]["method"] == config["fidelities"][ref]["method"]
    m0, plan0, src0 = R.level_core_hours(config, ref, root)
    _, fine0, _ = R.level_core_hours(config, fine, root)
    assert m0 == 0 and plan0 > 0 and src0 == "cost model"
    first = [r for r in level_runs(config, ref) if "/seed" in r][0]
    d = root / ref / "cases" / first
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({"status": "completed", "wall_seconds": 1.0}))
    model = R.wall_model("credible", root.parent)
    _, pred, _, _ = R._wall_against_model(config, ref, root, model)
    (d / "summary.json").write_text(json.dumps({"status": "completed", "wall_seconds": 3.0 * pred}))
    m1, plan1, src1 = R.level_core_hours(config, ref, root)
    assert src1 == "measured + cost model" and m1 == pytest.approx(3.0 * pred / 3600)
    assert plan1 == pytest.approx(3.0 * plan0)          # the model times 3 on every run
    assert R.level_core_hours(config, fine, root)[1] == pytest.approx(3.0 * fine0)  # same method, no run of its own


def test_committed_method_comparison_convergence_and_robustness_equal_a_rebuild_from_the_committed_runs(
        tmp_path, monkeypatch):
    # these read their runs as ancient() inputs: a run's statistics rebuilt in place must rebuild them
    # (the content digest in workflow/rules/paper.smk); a committed table older than its runs fails here
    from lbmpipe.reproduction import convergence, methods
    from roundoff import same_file_to_round_off

    monkeypatch.chdir(ROOT)  # the writers take the results folder as the pipeline passes it
    config = _config()
    for name, write in (("method", methods.write), ("convergence", convergence.write), ("robustness", R.write)):
        out = tmp_path / name
        out.mkdir()
        write(config, "credible", Path("results"), out)
        committed = Path("results") / "credible" / name
        files = sorted(committed.glob("*.csv")) + sorted(committed.glob("*.json"))
        assert files and sorted(p.name for p in files) == sorted(p.name for p in out.glob("*.[cj]s*"))
        for old in files:
            same_file_to_round_off(out / old.name, old)
