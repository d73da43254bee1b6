"""The paper's 14 claims judged from results tables (lbmpipe.reproduction.claims), on small synthetic tables that
follow the pipeline contract: the verdict follows the data, never the claim."""

import json

import numpy as np
import pandas as pd
import pytest

from lbmpipe.reproduction import claims

AV_COLUMNS = ["case", "shape", "size_label", "diameter_mm", "length_mm", "edge_mm", "concentration", "reynolds",
              "collisions", "status", "concentration_achieved", "n_particles", "samples",
              "omega_x", "omega_y", "omega_z", "ci_x", "ci_y", "ci_z"]


def cube(edge, c, re, **extra):
    return {"reynolds": re, "particles": {"shape": "cube", "edge_mm": edge, "concentration": c}, **extra}


def cyl(d, l, c, re, **extra):
    return {"reynolds": re, "particles": {"shape": "cylinder", "diameter_mm": d, "length_mm": l, "concentration": c},
            **extra}


def av_row(name, case, omega, ci, status="completed"):
    p = case["particles"]
    return {"case": name, "shape": p["shape"], "size_label": "", "diameter_mm": p.get("diameter_mm", np.nan),
            "length_mm": p.get("length_mm", np.nan), "edge_mm": p.get("edge_mm", np.nan),
            "concentration": p["concentration"], "reynolds": case["reynolds"],
            "collisions": case.get("collisions", True), "status": status,
            "concentration_achieved": p["concentration"], "n_particles": 10, "samples": 100,
            **{f"omega_{a}": (w if status == "completed" else np.nan) for a, w in zip("xyz", omega)},
            **{f"ci_{a}": (c if status == "completed" else np.nan) for a, c in zip("xyz", ci)}}


def write_av(fid_dir, rows):
    (fid_dir / "tables").mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows, columns=AV_COLUMNS).to_csv(fid_dir / "tables" / "angular_velocity.csv", index=False)


CUBE_CASES = {"cube8_c30_re9.4": cube(8, 0.30, 9.4), "cube8_c50_re9.4": cube(8, 0.50, 9.4)}


def claim_row(fid_dir, cases, k):
    df = claims.evaluate_claims(fid_dir, cases)
    return df[df["claim"] == k].iloc[0]


def cube_table(tmp_path, low, high, ci):
    write_av(tmp_path, [av_row("cube8_c30_re9.4", CUBE_CASES["cube8_c30_re9.4"], low, [ci] * 3),
                        av_row("cube8_c50_re9.4", CUBE_CASES["cube8_c50_re9.4"], high, [ci] * 3)])


def test_claim4_reproduced_when_every_cube_rotation_clearly_falls_from_30_to_50_percent(tmp_path):
    cube_table(tmp_path, [1.2, 1.1, 0.8], [0.6, 0.55, 0.5], 0.05)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "reproduced", row.reason
    assert "cube8_c30_re9.4 vs cube8_c50_re9.4 [x]" in row["values"]


def test_claim4_contradicted_when_cube_rotations_clearly_rise_with_concentration(tmp_path):
    cube_table(tmp_path, [0.6, 0.55, 0.5], [1.2, 1.1, 0.8], 0.05)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "contradicted"
    assert "diagnosed" in row.reason and "averaging too short" not in row.reason


def test_claim4_inconclusive_when_the_confidence_intervals_overlap(tmp_path):
    cube_table(tmp_path, [1.0, 1.0, 0.8], [0.95, 0.97, 0.78], 0.1)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "inconclusive"
    assert "overlap" in row.reason


def test_claim4_inconclusive_with_a_single_significantly_reversed_axis(tmp_path):
    # x and y fall clearly, z rises clearly: "all rotations fall" does not hold
    cube_table(tmp_path, [1.2, 1.2, 0.5], [0.6, 0.6, 0.9], 0.05)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "inconclusive"
    assert "mixed" in row.reason


def test_claim4_inconclusive_and_names_the_case_when_50_percent_was_not_packable(tmp_path):
    write_av(tmp_path, [av_row("cube8_c30_re9.4", CUBE_CASES["cube8_c30_re9.4"], [1.2, 1.1, 0.8], [0.05] * 3),
                        av_row("cube8_c50_re9.4", CUBE_CASES["cube8_c50_re9.4"], [0, 0, 0], [0] * 3,
                               status="unpackable")])
    case_dir = tmp_path / "cases" / "cube8_c50_re9.4"
    case_dir.mkdir(parents=True)
    (case_dir / "summary.json").write_text(json.dumps(
        {"status": "unpackable", "packing": {"concentration_reached": 0.284}}))
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "inconclusive"
    assert "cube8_c50_re9.4: not packable" in row.reason and "28.4 %" in row.reason


def test_claim4_inconclusive_when_a_case_was_not_run(tmp_path):
    write_av(tmp_path, [av_row("cube8_c30_re9.4", CUBE_CASES["cube8_c30_re9.4"], [1.2, 1.1, 0.8], [0.05] * 3)])
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "inconclusive"
    assert "cube8_c50_re9.4: not in tables/angular_velocity.csv (not run)" in row.reason


def test_every_claim_inconclusive_with_reason_when_no_table_was_built(tmp_path):
    path = claims.write_claims(tmp_path, {**CUBE_CASES, "cyl16x16_c30_re26": cyl(16, 16, 0.3, 26.0)})
    df = pd.read_csv(path)
    assert list(df.columns) == claims.COLUMNS and list(df["claim"]) == list(range(1, 15))
    assert (df["verdict"] == "inconclusive").all()
    assert df["reason"].str.contains("missing|no case|not run").all()


def test_claim1_cylinders_spinning_more_about_z_than_x_y_contradict_it(tmp_path):
    cases = {"cyl16x16_c30_re26": cyl(16, 16, 0.3, 26.0)}
    write_av(tmp_path, [av_row("cyl16x16_c30_re26", cases["cyl16x16_c30_re26"], [0.5, 0.5, 1.5], [0.05] * 3)])
    assert claim_row(tmp_path, cases, 1).verdict == "contradicted"
    write_av(tmp_path, [av_row("cyl16x16_c30_re26", cases["cyl16x16_c30_re26"], [1.5, 1.4, 0.5], [0.05] * 3)])
    assert claim_row(tmp_path, cases, 1).verdict == "reproduced"


def test_claim5_cube_components_closer_at_50_percent_by_relative_spread(tmp_path):
    # 30 %: components spread by a factor two; 50 %: all equal (CV 0), both well resolved
    cube_table(tmp_path, [1.2, 1.2, 0.6], [0.5, 0.5, 0.5], 0.02)
    assert claim_row(tmp_path, CUBE_CASES, 5).verdict == "reproduced"
    cube_table(tmp_path, [0.9, 0.9, 0.9], [0.6, 0.6, 0.3], 0.02)
    assert claim_row(tmp_path, CUBE_CASES, 5).verdict == "contradicted"


def write_orientation_summary(fid_dir, rows):
    (fid_dir / "tables").mkdir(parents=True, exist_ok=True)
    pd.DataFrame([{"case": c, "kind": k, "status": "completed", "mean_deg": m, "ci95_deg": ci, "median_deg": m}
                  for c, k, m, ci in rows]).to_csv(fid_dir / "tables" / "orientation_summary.csv", index=False)


REF14 = "cyl8x16_c2_re9.4"
PAIR14 = {claims.ALIGN_CASE: cyl(8, 16, 0.3, 9.4), claims.ALIGN_NOCOLL_CASE: cyl(8, 16, 0.3, 9.4, collisions=False),
          REF14: cyl(8, 16, 0.02, 9.4)}


@pytest.mark.parametrize("with_coll, reference, verdict", [(55.0, 40.0, "reproduced"), (40.0, 55.0, "contradicted"),
                                                           (50.0, 49.0, "inconclusive")])
def test_claim14_colliding_cylinders_align_less_only_if_their_mean_angle_exceeds_the_dilute_references(
        tmp_path, with_coll, reference, verdict):
    # the collisions-off run says the opposite each time: it is a sensitivity and never decides
    write_orientation_summary(tmp_path, [(claims.ALIGN_CASE, "cyl_axis_angle", with_coll, 2.0),
                                         (REF14, "cyl_axis_angle", reference, 2.0),
                                         (claims.ALIGN_NOCOLL_CASE, "cyl_axis_angle", 2 * with_coll - reference, 2.0)])
    row = claim_row(tmp_path, PAIR14, 14)
    assert row.verdict == verdict
    assert f"{claims.ALIGN_CASE} vs {REF14}" in row["values"] and "sensitivity, collisions off" in row["values"]


def test_claim14_without_its_reference_run_says_reference_not_run_and_does_not_decide_on_the_overlapping_control(
        tmp_path):
    write_orientation_summary(tmp_path, [(claims.ALIGN_CASE, "cyl_axis_angle", 40.0, 2.0),
                                         (claims.ALIGN_NOCOLL_CASE, "cyl_axis_angle", 60.0, 2.0)])
    row = claim_row(tmp_path, PAIR14, 14)
    assert row.verdict == "inconclusive"
    assert "reference of claim 14 not run" in row.reason and REF14 in row.reason and "runs it" in row.reason
    assert "sensitivity, collisions off" in row["values"] and "d = -20" in row["values"]


def test_claim14_with_a_reference_run_whose_angle_has_no_interval_does_not_call_it_not_run(tmp_path):
    # one packing of the dilute reference (a control's look at packing 1): it ran, its mean has no interval
    write_orientation_summary(tmp_path, [(claims.ALIGN_CASE, "cyl_axis_angle", 56.3, 2.0),
                                         (REF14, "cyl_axis_angle", 33.5, np.nan)])
    row = claim_row(tmp_path, PAIR14, 14)
    assert row.verdict == "inconclusive"
    assert "reference of claim 14 gives no interval" in row.reason and "33.5 deg without an interval" in row.reason
    assert "not run" not in row.reason and "runs it" not in row.reason


def test_claim14_with_a_mean_angle_but_no_interval_says_so_instead_of_calling_the_statistics_missing(tmp_path):
    # one packing averaged for less than two batches of the orientation's correlation time: a mean
    # without an interval cannot decide the claim, and the reason names the mean it has
    write_orientation_summary(tmp_path, [(claims.ALIGN_CASE, "cyl_axis_angle", 55.2, np.nan),
                                         (REF14, "cyl_axis_angle", 40.0, 2.0)])
    row = claim_row(tmp_path, PAIR14, 14)
    assert row.verdict == "inconclusive"
    assert f"{claims.ALIGN_CASE}: mean cyl_axis_angle 55.2 deg without an interval" in row.reason
    assert "no orientation statistics" not in row.reason


def test_claim12_equivalence_margin_decides_no_effect_of_reynolds_on_cubes(tmp_path):
    cases = {"cube8_c30_re9.4": cube(8, 0.3, 9.4), "cube8_c30_re26": cube(8, 0.3, 26.0)}
    write_orientation_summary(tmp_path, [("cube8_c30_re9.4", "cube_projected_angle", 22.0, 0.5),
                                         ("cube8_c30_re26", "cube_projected_angle", 22.5, 0.5)])
    assert claim_row(tmp_path, cases, 12).verdict == "reproduced"
    write_orientation_summary(tmp_path, [("cube8_c30_re9.4", "cube_projected_angle", 15.0, 0.5),
                                         ("cube8_c30_re26", "cube_projected_angle", 28.0, 0.5)])
    assert claim_row(tmp_path, cases, 12).verdict == "contradicted"
    write_orientation_summary(tmp_path, [("cube8_c30_re9.4", "cube_projected_angle", 20.0, 5.0),
                                         ("cube8_c30_re26", "cube_projected_angle", 22.0, 5.0)])
    assert claim_row(tmp_path, cases, 12).verdict == "inconclusive"


def write_histogram(fid_dir, case, fractions, ci):
    (fid_dir / "tables").mkdir(parents=True, exist_ok=True)
    edges = np.linspace(0.0, 45.0, len(fractions) + 1)
    pd.DataFrame({"case": case, "kind": "cube_projected_angle", "status": "completed", "bin_lo_deg": edges[:-1],
                  "bin_hi_deg": edges[1:], "fraction": fractions, "ci95": ci}).to_csv(
        fid_dir / "tables" / "orientation.csv", index=False)


def test_claim11_uniform_cube_angles_reproduce_no_preference_and_a_peak_contradicts_it(tmp_path):
    cases = {"cube8_c30_re9.4": cube(8, 0.3, 9.4)}
    write_histogram(tmp_path, "cube8_c30_re9.4", np.full(9, 1 / 9), 0.005)
    assert claim_row(tmp_path, cases, 11).verdict == "reproduced"
    peaked = np.full(9, 0.5 / 8)
    peaked[0] = 0.5
    write_histogram(tmp_path, "cube8_c30_re9.4", peaked, 0.005)
    row = claim_row(tmp_path, cases, 11)
    assert row.verdict == "contradicted" and "bin 0-5 deg" in row.reason
    write_histogram(tmp_path, "cube8_c30_re9.4", np.full(9, 1 / 9), 0.1)  # no resolution
    assert claim_row(tmp_path, cases, 11).verdict == "inconclusive"


def write_profile(fid_dir, case, u, u_ref):
    d = fid_dir / "cases" / case
    d.mkdir(parents=True, exist_ok=True)
    r = np.linspace(0.5, 24.5, len(u))
    pd.DataFrame({"r_mm": r, "uz_m_s": u, "uz_poiseuille_m_s": u_ref, "nodes": np.round(8 * r)}).to_csv(
        d / "profile.csv", index=False)
    (d / "summary.json").write_text(json.dumps({"status": "completed"}))


def test_claim13_a_flattened_profile_with_particles_differs_greatly_from_the_parabola(tmp_path):
    cases = {claims.PROFILE_REFERENCE: {"reynolds": 26.0}, claims.PROFILE_CASE: cyl(16, 16, 0.3, 26.0)}
    r = np.linspace(0.5, 24.5, 25)
    parabola = 0.32 * (1 - (r / 25.0) ** 2)
    write_profile(tmp_path, claims.PROFILE_REFERENCE, parabola * 1.01, parabola)
    plug = np.where(r < 20, 0.2, 0.2 * (25 - r) / 5)
    write_profile(tmp_path, claims.PROFILE_CASE, plug, parabola)
    row = claim_row(tmp_path, cases, 13)
    assert row.verdict == "reproduced"
    d_par = claims.rel_l2(r, plug, parabola, np.round(8 * r))
    assert f"vs parabola: {d_par:.3g}" in row["values"]
    write_profile(tmp_path, claims.PROFILE_CASE, parabola * 1.005, parabola)
    assert claim_row(tmp_path, cases, 13).verdict == "contradicted"


def _stats(tmp_path, name, **extra):
    d = tmp_path / "cases" / name
    d.mkdir(parents=True, exist_ok=True)
    base = {"frozen": {"frozen": False, "remaining": 0.1, "threshold": 0.5}, "locked": {"locked": False},
            "health": {"issues": []}, "spinup": {"steady": True},
            "omega_intervals": {a: {"sufficient": True, "required_s": 1.0, "duration_s": 5.0} for a in "xyz"},
            "resolution": {"lattice_spacings": 3.2}}
    base.update(extra)
    (d / "stats.json").write_text(json.dumps(base))


def test_contradiction_reason_names_the_frozen_case_and_the_duration_its_interval_needs(tmp_path):
    cube_table(tmp_path, [0.6, 0.55, 0.5], [1.2, 1.1, 0.8], 0.05)
    _stats(tmp_path, "cube8_c30_re9.4")
    _stats(tmp_path, "cube8_c50_re9.4", frozen={"frozen": True, "remaining": 0.97, "threshold": 0.5},
           omega_intervals={"z": {"sufficient": False, "required_s": 42.0, "duration_s": 1.5}})
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "contradicted"
    assert "cube8_c50_re9.4: frozen (orientation correlation with the packing 0.97" in row.reason
    assert "cube8_c50_re9.4: interval too short for |Omega_z| (1.5 s averaged, 42 s needed" in row.reason
    assert "cube8_c30_re9.4: frozen" not in row.reason
    assert "cube8_c30_re9.4: smallest particle dimension 3.2 lattice spacings" in row.reason  # a fact, not a blame


def test_contradiction_of_healthy_unflagged_cases_is_called_a_genuine_difference(tmp_path):
    cube_table(tmp_path, [0.6, 0.55, 0.5], [1.2, 1.1, 0.8], 0.05)
    for name in CUBE_CASES:
        _stats(tmp_path, name)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert "genuine difference" in row.reason and "frozen" not in row.reason


def test_reproduced_claim_still_lists_its_locked_and_unhealthy_cases(tmp_path):
    cube_table(tmp_path, [1.2, 1.1, 0.8], [0.6, 0.55, 0.5], 0.05)
    _stats(tmp_path, "cube8_c30_re9.4", locked={"locked": True, "column": True},
           health={"issues": ["mass drift 0.0485 > 0.001"]})
    _stats(tmp_path, "cube8_c50_re9.4")
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert row.verdict == "reproduced"
    assert "cube8_c30_re9.4: locked (a column" in row.reason
    assert "cube8_c30_re9.4: unhealthy (mass drift 0.0485 > 0.001)" in row.reason


def test_claim_reason_of_stats_without_diagnostics_asks_for_a_rerun(tmp_path):
    cube_table(tmp_path, [0.6, 0.55, 0.5], [1.2, 1.1, 0.8], 0.05)
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert "not computed by this version of the statistics" in row.reason


# --------------------------------------------------------------------------------------------------
# the verdict rule (issue 46): flags, shared runs, systematic error, how many comparisons carry it


def test_claim4_verdict_without_the_frozen_cases_stands_beside_the_verdict_with_them(tmp_path):
    # 8 mm cubes fall clearly with concentration; the frozen 16 mm pair says the opposite
    cases = {**CUBE_CASES, "cube16_c30_re9.4": cube(16, 0.30, 9.4), "cube16_c50_re9.4": cube(16, 0.50, 9.4)}
    write_av(tmp_path, [av_row("cube8_c30_re9.4", cases["cube8_c30_re9.4"], [1.2, 1.1, 0.8], [0.05] * 3),
                        av_row("cube8_c50_re9.4", cases["cube8_c50_re9.4"], [0.6, 0.55, 0.5], [0.05] * 3),
                        av_row("cube16_c30_re9.4", cases["cube16_c30_re9.4"], [0.2, 0.2, 0.2], [0.02] * 3),
                        av_row("cube16_c50_re9.4", cases["cube16_c50_re9.4"], [0.5, 0.5, 0.5], [0.02] * 3)])
    for name in cases:
        _stats(tmp_path, name, **({"frozen": {"frozen": True, "remaining": 0.9, "threshold": 0.5}}
                                  if name == "cube16_c50_re9.4" else {}))
    row = claim_row(tmp_path, cases, 4)
    assert row.verdict == "inconclusive" and "mixed" in row.reason
    assert row.verdict_without_frozen_locked == "reproduced" and row.verdict_without_flagged == "reproduced"
    assert row.left_out_frozen_locked == "cube16_c50_re9.4 (frozen)"


def _seeded_case(fid_dir, name, per_seed, ci=0.01, dof=20.0):
    """A case combined over packings: its seeds' stats.json (|Omega| x, y, z per seed) and the
    combined record listing them."""
    d = fid_dir / "cases" / name
    for k, w in enumerate(per_seed, start=1):
        (d / f"seed{k}").mkdir(parents=True, exist_ok=True)
        (d / f"seed{k}" / "stats.json").write_text(json.dumps({
            "status": "completed", "mean_abs_omega_rad_s": dict(zip("xyz", w)), "ci95_rad_s": dict.fromkeys("xyz", ci),
            "omega_intervals": {a: {"dof": dof} for a in "xyz"}}))
    (d / "stats.json").write_text(json.dumps({"seeds": [{"seed": k, "status": "completed"}
                                                        for k in range(1, len(per_seed) + 1)]}))


def test_pooled_interval_of_axes_that_share_their_packings_does_not_shrink_as_if_they_were_independent(tmp_path):
    # Each packing shifts all three axes of the 30 % case together (1.3, 1.2, 1.1): the three
    # comparisons are one comparison three times. Independent pooling, h / sqrt(3), called it
    # reproduced; the packings' own scatter of the pooled difference (t_2 * 0.1 / sqrt(3) = 0.248) does not.
    lo = [[v] * 3 for v in (1.3, 1.2, 1.1)]
    _seeded_case(tmp_path, "cube8_c30_re9.4", lo)
    _seeded_case(tmp_path, "cube8_c50_re9.4", [[1.0] * 3] * 3)
    h = 4.302652729911275 * 0.1 / np.sqrt(3)
    write_av(tmp_path, [av_row("cube8_c30_re9.4", CUBE_CASES["cube8_c30_re9.4"], [1.2] * 3, [h] * 3),
                        av_row("cube8_c50_re9.4", CUBE_CASES["cube8_c50_re9.4"], [1.0] * 3, [0.01] * 3)])
    row = claim_row(tmp_path, CUBE_CASES, 4)
    assert 0.2 - np.hypot(h, 0.01) / np.sqrt(3) > 0  # what independent pooling said
    pooled = float(row["values"].split("± ")[1].split(" ")[0])
    assert pooled == pytest.approx(h, rel=0.05)
    assert row.verdict == "inconclusive"
    # the same data again give the same interval (seeded draws)
    assert claim_row(tmp_path, CUBE_CASES, 4)["values"] == row["values"]


def test_pooled_interval_of_packings_that_cancel_in_a_paired_comparison_is_narrower_than_independent(tmp_path):
    # Re 9.4 and Re 26 start from the same packings: a packing that spins faster at one Reynolds
    # number spins faster at the other, and the difference keeps only the runs' own noise
    cases = {"cube8_c30_re9.4": cube(8, 0.30, 9.4), "cube8_c30_re26": cube(8, 0.30, 26.0)}
    _seeded_case(tmp_path, "cube8_c30_re9.4", [[v] * 3 for v in (1.0, 1.3, 0.7)])
    _seeded_case(tmp_path, "cube8_c30_re26", [[v + 0.1] * 3 for v in (1.0, 1.3, 0.7)])
    h = 4.302652729911275 * 0.3 / np.sqrt(3)
    write_av(tmp_path, [av_row("cube8_c30_re9.4", cases["cube8_c30_re9.4"], [1.0] * 3, [h] * 3),
                        av_row("cube8_c30_re26", cases["cube8_c30_re26"], [1.1] * 3, [h] * 3)])
    row = claim_row(tmp_path, cases, 6)
    assert row.verdict == "reproduced", row["values"]
    assert row.carried_by == "0 of 3 significant in the claimed direction, 0 reversed"


def test_a_verdict_is_robust_only_if_it_holds_with_the_systematic_error_of_its_observable(tmp_path):
    cube_table(tmp_path, [1.2, 1.1, 0.8], [1.0, 0.95, 0.7], 0.02)
    df = claims.evaluate_claims(tmp_path, CUBE_CASES, systematic={"omega_rel": 0.0})
    row = df[df["claim"] == 4].iloc[0]
    assert row.verdict == "reproduced" and row.robust == "yes"
    df = claims.evaluate_claims(tmp_path, CUBE_CASES, systematic={"omega_rel": 0.1})  # ±10 % on each value
    row = df[df["claim"] == 4].iloc[0]
    assert row.verdict == "reproduced" and row.verdict_with_systematic == "inconclusive" and row.robust == "no"


def test_claim11_a_significant_but_small_deviation_from_uniform_is_no_preference_at_the_readings_margin(tmp_path):
    # every bin within 30 % of uniform, measured to 0.3 %: significantly non-uniform (a point null
    # contradicts) but inside paper/reading.md's 50 % margin with certainty: reproduced
    cases = {"cube8_c30_re9.4": cube(8, 0.3, 9.4)}
    f = np.array([1.3, 0.7, 1.3, 0.7, 1.0, 1.0, 1.2, 0.8, 1.0]) / 9
    write_histogram(tmp_path, "cube8_c30_re9.4", f, 0.003)
    row = claim_row(tmp_path, cases, 11)
    assert row.verdict == "reproduced", row.reason
    assert row.carried_by == "1 of 1 cases within the margin at 90 %, 0 shown beyond it"
    # 80 % off uniform in one bin, measured well: a preference shown beyond the margin
    f = np.array([1.8, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9]) / 9
    write_histogram(tmp_path, "cube8_c30_re9.4", f / f.sum(), 0.003)
    assert claim_row(tmp_path, cases, 11).verdict == "contradicted"


def test_claim11_leaves_a_locked_case_out_and_names_it(tmp_path):
    cases = {"cube8_c30_re9.4": cube(8, 0.3, 9.4), "cube24_c30_re9.4": cube(24, 0.3, 9.4)}
    (tmp_path / "tables").mkdir(parents=True, exist_ok=True)
    edges = np.linspace(0.0, 45.0, 10)
    rows = []
    for case, f in (("cube8_c30_re9.4", np.full(9, 1 / 9)), ("cube24_c30_re9.4", np.eye(9)[0])):
        rows += [{"case": case, "kind": "cube_projected_angle", "status": "completed", "bin_lo_deg": edges[k],
                  "bin_hi_deg": edges[k + 1], "fraction": f[k], "ci95": 0.003} for k in range(9)]
    pd.DataFrame(rows).to_csv(tmp_path / "tables" / "orientation.csv", index=False)
    _stats(tmp_path, "cube24_c30_re9.4", locked={"locked": True, "column": True})
    row = claim_row(tmp_path, cases, 11)
    assert row.verdict == "reproduced"
    assert "left out (locked): cube24_c30_re9.4" in row.reason


def test_claim12_deciding_number_is_the_comparison_that_decides_not_the_first(tmp_path):
    cases = {f"cube{e}_c30_re{r:g}": cube(e, 0.3, r) for e in (8, 16) for r in (9.4, 26.0)}
    write_orientation_summary(tmp_path, [("cube8_c30_re9.4", "cube_projected_angle", 22.0, 0.5),
                                         ("cube8_c30_re26", "cube_projected_angle", 22.5, 0.5),
                                         ("cube16_c30_re9.4", "cube_projected_angle", 20.0, 5.0),
                                         ("cube16_c30_re26", "cube_projected_angle", 22.0, 5.0)])
    row = claim_row(tmp_path, cases, 12)
    assert row.verdict == "inconclusive"
    assert row.deciding.startswith("cube16_c30_re26 vs cube16_c30_re9.4: d = 2")
    assert row.carried_by == "1 of 2 within ±4.5 deg, 0 shown beyond it"
