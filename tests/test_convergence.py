"""The paper's observables by dx: values with intervals, the observed order only where both changes
between halving spacings stand out of the noise."""

import json
import math

import numpy as np
import pandas as pd
import pytest

from lbmpipe.reproduction import convergence


def _config():
    case = {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 16, "length_mm": 16, "concentration": 0.3}}
    return {"cases": {"flow_re9.4": {"reynolds": 9.4}, "cyl16x16_c30_re9.4": case, "cube8_c30_re9.4": case},
            "fidelities": {"base": {"dx_mm": 1.0, "run": {}},
                           "coarse": {"dx_mm": 2.0, "convergence_of": "base", "cases": ["flow_re9.4", "cyl16x16_c30_re9.4"],
                                      "run": {}},
                           "fine": {"dx_mm": 0.5, "convergence_of": "base", "cases": ["flow_re9.4", "cyl16x16_c30_re9.4"],
                                    "run": {}}}}


def _profile(d, profile_scale):
    r = np.linspace(0.5, 24.5, 25)
    ref = 1.0 - (r / 25.0) ** 2
    d.mkdir(parents=True, exist_ok=True)
    pd.DataFrame({"r_mm": r, "uz_m_s": ref * (1 - profile_scale), "uz_poiseuille_m_s": ref, "nodes": 4 * r}).to_csv(
        d / "profile.csv", index=False)


def _case(root, level, case, omega, ci, profile_scale, seeds=3):
    d = root / level / "cases" / case
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({"status": "completed"}))
    _profile(d, profile_scale)
    if omega is not None:
        # the packings' own profiles scatter by 1 % about the combined one
        for k in range(1, seeds + 1):
            _profile(d / f"seed{k}", profile_scale * (1 + 0.01 * (k - 2)))
        (d / "stats.json").write_text(json.dumps({"shape": "cylinder", "n_seeds": seeds, "flags": [],
                                                  "seeds": [{"seed": k, "status": "completed"} for k in range(1, seeds + 1)],
                                                  "mean_abs_omega_rad_s": {"x": omega, "y": omega, "z": omega / 2},
                                                  "ci95_rad_s": {"x": ci, "y": 10 * ci, "z": ci}}))


def test_levels_run_from_the_coarsest_to_the_finest_spacing():
    assert convergence.levels(_config(), "base") == ["coarse", "base", "fine"]
    assert convergence.levels(_config(), "fine") == ["fine"]


def test_profile_distance_is_the_relative_l2_gap_from_poiseuille(tmp_path):
    _case(tmp_path, "base", "flow_re9.4", None, None, profile_scale=0.03)
    assert convergence.profile_distance(tmp_path / "base" / "cases" / "flow_re9.4" / "profile.csv") == pytest.approx(0.03)
    assert math.isnan(convergence.profile_distance(tmp_path / "nothing.csv"))


def test_second_order_convergence_is_observed_when_both_changes_exceed_the_noise(tmp_path):
    # omega_x = 1 + 0.1 h^2 with tight intervals: changes 0.3 and 0.075 -> order log2(4) = 2;
    # omega_y has ten times wider intervals (0.5): the finer change drowns; the profile error
    # 0.04 h^2 converges at order 2 and carries no interval
    for level, h in (("coarse", 2.0), ("base", 1.0), ("fine", 0.5)):
        _case(tmp_path, level, "cyl16x16_c30_re9.4", 1.0 + 0.1 * h * h, 0.02, profile_scale=0.04 * h * h)
    vals = convergence.value_rows(_config(), "base", tmp_path)
    order = convergence.order_rows(vals).set_index("observable")
    assert order.loc["mean_abs_omega_x", "order"] == pytest.approx(2.0)
    assert order.loc["mean_abs_omega_x", "status"] == "observed"
    assert order.loc["profile_distance", "order"] == pytest.approx(2.0)
    assert math.isnan(order.loc["mean_abs_omega_y", "order"])
    assert order.loc["mean_abs_omega_y", "status"].startswith("noise hides the order: the finer change")
    assert set(vals["level"]) == {"coarse", "base", "fine"} and (vals["n_seeds"] == 3).all()


def test_changes_of_opposite_sign_give_no_order(tmp_path):
    for level, v in (("coarse", 1.3), ("base", 1.0), ("fine", 1.2)):
        _case(tmp_path, level, "cyl16x16_c30_re9.4", v, 0.01, profile_scale=0.01)
    order = convergence.order_rows(convergence.value_rows(_config(), "base", tmp_path)).set_index("observable")
    assert order.loc["mean_abs_omega_x", "status"] == "not monotone: the two changes differ in sign"


def test_a_case_missing_at_a_spacing_says_how_many_were_run(tmp_path):
    _case(tmp_path, "base", "flow_re9.4", None, None, profile_scale=0.01)
    _case(tmp_path, "coarse", "flow_re9.4", None, None, profile_scale=0.04)
    s = convergence.write(_config(), "base", tmp_path, tmp_path / "base" / "convergence")
    order = pd.read_csv(tmp_path / "base" / "convergence" / "order.csv")
    assert order["status"].tolist() == ["2 of 3 spacings run; the change exceeds its interval"] and s["observed"] == 0
    assert order["d1"].iloc[0] == pytest.approx(0.03)  # profile distance 0.04 at 2 mm, 0.01 at 1 mm
    assert s["levels"] == {"coarse": 2.0, "base": 1.0, "fine": 0.5}


def test_accuracy_against_cost_draws_each_observable_at_each_spacing_with_its_cost(tmp_path, monkeypatch):
    # three spacings at costs 1, 8 and 64 loop-s per simulated s; the flagged finest value is hollow
    from lbmpipe.reproduction import comparison_figures as figures

    for level, h, cost in (("coarse", 2.0, 1.0), ("base", 1.0, 8.0), ("fine", 0.5, 64.0)):
        _case(tmp_path, level, "cyl16x16_c30_re9.4", 1.0 + 0.1 * h * h, 0.02, profile_scale=0.04 * h * h)
        (tmp_path / level / "tables").mkdir()
        pd.DataFrame([{"case": "cyl16x16_c30_re9.4/seed1", "status": "completed", "steps": 100, "simulated_s": 2.0,
                       "s_per_step": cost * 2.0 / 100}]).to_csv(tmp_path / level / "tables" / "runtime.csv", index=False)
    vals = convergence.value_rows(_config(), "base", tmp_path)
    vals.loc[vals["level"] == "fine", "flags"] = "not steady"
    drawn = {}
    monkeypatch.setattr(figures, "save", lambda fig, stem: drawn.setdefault("fig", fig) and [])
    figures.convergence_accuracy_cost(vals, tmp_path / "fig")
    profile, omega, angle = drawn["fig"].axes[:3]
    xs = sorted({round(float(x), 6) for line in omega.lines for x in line.get_xdata()})
    assert xs == [1.0, 8.0, 64.0]
    assert len([t for t in omega.texts if t.get_text().endswith("mm")]) == 9  # x, y, z at three spacings
    markers = [line for line in profile.lines if line.get_marker() == "o"]
    assert [m.get_markerfacecolor() for m in markers].count("white") == 1  # the flagged finest spacing
    assert not angle.axison  # no angle in these records: the panel is left empty
    monkeypatch.undo()
    convergence.write(_config(), "base", tmp_path, tmp_path / "out")
    assert (tmp_path / "out" / "accuracy_cost.png").stat().st_size > 0


def test_a_value_too_short_for_an_interval_gives_no_order_and_says_so(tmp_path):
    # omega converges at order 2 as in the test above, but the finest run was too short for a valid
    # interval of omega_x (null ci): its noise is unknown, so no order and no sign test; the
    # profile's distance has its interval from the packings' spread
    for level, h in (("coarse", 2.0), ("base", 1.0), ("fine", 0.5)):
        _case(tmp_path, level, "cyl16x16_c30_re9.4", 1.0 + 0.1 * h * h, 0.02, profile_scale=0.04 * h * h)
    vals = convergence.value_rows(_config(), "base", tmp_path)
    fine_x = (vals["level"] == "fine") & (vals["observable"] == "mean_abs_omega_x")
    vals.loc[fine_x, "ci95"] = float("nan")
    order = convergence.order_rows(vals).set_index("observable")
    assert math.isnan(order.loc["mean_abs_omega_x", "order"])
    assert order.loc["mean_abs_omega_x", "status"] == "no valid interval at dx 0.5 mm: the noise cannot be judged"
    assert order.loc["mean_abs_omega_z", "status"] == "observed"
    assert order.loc["profile_distance", "status"] == "observed"
    prof = vals[(vals["observable"] == "profile_distance") & (vals["level"] == "base")]
    assert float(prof["ci95"].iloc[0]) == pytest.approx(4.303 * 0.0004 / math.sqrt(3), rel=1e-3)  # t(2) sd / sqrt(3)
    two = convergence.order_rows(vals[vals["level"] != "coarse"]).set_index("observable")
    assert two.loc["mean_abs_omega_x", "status"].endswith("the noise cannot be judged")


def test_a_particle_cases_profile_from_one_packing_has_unknown_noise_and_a_flow_none(tmp_path):
    for level, h in (("coarse", 2.0), ("base", 1.0), ("fine", 0.5)):
        _case(tmp_path, level, "cyl16x16_c30_re9.4", 1.0 + 0.1 * h * h, 0.02, profile_scale=0.04 * h * h,
              seeds=1 if level == "fine" else 3)
        _case(tmp_path, level, "flow_re9.4", None, None, profile_scale=0.01 * h * h)
    vals = convergence.value_rows(_config(), "base", tmp_path)
    order = convergence.order_rows(vals).set_index(["case", "observable"])
    assert order.loc[("cyl16x16_c30_re9.4", "profile_distance"), "status"] == (
        "no valid interval at dx 0.5 mm: the noise cannot be judged")
    assert order.loc[("flow_re9.4", "profile_distance"), "order"] == pytest.approx(2.0)  # steady: interval 0
