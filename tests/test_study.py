"""The accuracy-cost study (lbmpipe.reproduction.study_plan, study_errors, study): its scenes, Pareto front,
recommendation and cost model (fitted by lbmpipe.reproduction.runcost, evaluated by lbmpipe.cost.predict).

The study's physics is the solver's (validated elsewhere); here: every knob setting builds a
valid scene that differs from the base in that knob alone, the bookkeeping picks the right
points, the cost fit recovers known coefficients, and one tiny pipe run yields a finite error.
"""

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml

from lbmpipe import cost
from lbmpipe.reproduction import runcost, study, study_errors, study_plan
from lbmpipe.scene import Scene
from lbmpipe.units import derive

CONFIG = {
    "fidelities": {
        "smoke": {"dx_mm": 2.5, "dt_per_mm_s": 1.0e-3, "threads": 1,
                  "run": {"duration_s": 0.3, "spinup_s": 0.1, "sample_interval_s": 0.025}},
        "paper": {"dx_mm": 1.0, "dt_per_mm_s": 1.0e-3, "threads": 2,
                  "run": {"duration_s": 3.0, "spinup_s": 1.0, "sample_interval_s": 0.02}},
    },
    "cases": {"cyl8x16_c30_re9.4": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8,
                                                                     "length_mm": 16, "concentration": 0.30}}},
}


@pytest.mark.parametrize("fidelity", ["smoke", "paper"])
def test_every_knob_setting_is_a_valid_scene_differing_from_the_base_in_its_knob_only(fidelity):
    s = study_plan.study_settings(CONFIG, fidelity)
    runs = study_plan.plan(CONFIG, fidelity)
    for ref in ("pipe", "drag"):
        settings = study_plan.knob_settings(s, ref)
        knobs = {k for k, _, _ in settings}
        assert {"dx", "dt", "collision", "precision"} <= knobs
        assert ("wall" in knobs) == (ref == "pipe")  # a particle surface has no wall scheme to choose
        dx_values = {st["dx_mm"] for k, _, st in settings if k == "dx"}
        assert len(dx_values) >= 3
        base = dict(s["base"], **({"wall": "bounce_back"} if ref == "drag" else {}))
        for knob, _, st in settings:
            if knob.startswith("combo"):
                continue
            changed = {k for k in study_plan.KNOB_KEYS if st[k] != base[k]}
            key = {"dx": "dx_mm", "dt": "dt_factor"}.get(knob, knob)
            assert changed <= {key}, (knob, changed)
    for rid, spec in runs.items():
        scene = Scene.model_validate(spec["scene"])
        params = derive(scene)
        st = spec["setting"]
        assert scene.numerics.dx_mm == st["dx_mm"] and scene.numerics.collision == st["collision"]
        assert scene.numerics.precision == st["precision"]
        # dt follows the level's acoustic scaling times the knob's factor
        assert scene.numerics.dt_s == pytest.approx(s["dt_per_mm_s"] * st["dx_mm"] * st["dt_factor"])
        assert params.tau > 0.5
        if spec["reference"] == "pipe":
            assert scene.numerics.wall == st["wall"] and params.reynolds == pytest.approx(9.4, rel=1e-9)
        else:
            # Stokes regime: the particle Reynolds number stays far below 1
            geo = study_plan.drag_geometry(s)
            re_p = 2 * geo["a_m"] * s["drag"]["superficial_velocity_m_s"] / geo["nu_m2_s"]
            assert re_p < 0.05
            assert scene.particles.bodies[0].fixed


def test_drag_sphere_keeps_its_lattice_relative_offset_at_every_resolution():
    s = study_plan.study_settings(CONFIG, "paper")
    geo = study_plan.drag_geometry(s)
    # c = 4/3 pi a^3 / L^3
    assert 4 / 3 * math.pi * geo["a_m"] ** 3 / geo["L_m"] ** 3 == pytest.approx(s["drag"]["concentration"])
    offs = []
    for dx in (2.5, 1.25):
        sc = study_plan.drag_scene(s, dict(s["base"], dx_mm=dx), 0)
        offs.append((np.array(sc["particles"]["bodies"][0]["position_mm"]) - s["drag"]["box_mm"] / 2) / dx)
    assert np.allclose(offs[0], offs[1]) and np.all((offs[0] >= 0) & (offs[0] < 1))


def test_sc_drag_reference_is_zick_homsy_at_tabulated_points_and_the_series_between():
    assert study_plan.sc_drag_reference(0.125) == 4.292
    assert study_plan.sc_drag_reference(0.064) == 2.810
    # Sangani & Acrivos's series agrees with the table to 0.1 % at c = 0.125 and 0.064
    assert study_plan.sc_drag_reference(0.1250001) == pytest.approx(4.292, rel=2e-3)
    assert study_plan.sc_drag_reference(0.0640001) == pytest.approx(2.810, rel=2e-3)


def test_config_overrides_merge_over_the_level_defaults():
    cfg = dict(CONFIG, study={"smoke": {"drag": {"offsets": 2}, "targets": {"pipe": 0.02}}})
    s = study_plan.study_settings(cfg, "smoke")
    assert s["drag"]["offsets"] == 2 and s["targets"]["pipe"] == 0.02
    assert s["targets"]["drag"] == study_plan.DEFAULTS["targets"]["drag"]  # untouched keys survive
    assert s["pipe"]["dx_mm"] == study_plan.LEVEL_DEFAULTS["smoke"]["pipe"]["dx_mm"]
    assert sum(r.startswith("drag_") for r in study_plan.run_ids(cfg, "smoke")) == 2 * sum(
        r.startswith("drag_") for r in study_plan.run_ids(CONFIG, "smoke"))


def test_pareto_front_keeps_exactly_the_undominated_points():
    cost = np.array([1.0, 2.0, 3.0, 4.0, 2.5, 5.0, np.nan, 3.0])
    err = np.array([0.5, 0.2, 0.25, 0.05, 0.2, 0.05, 0.001, 0.1])
    front = study.pareto_front(cost, err)
    # 1 (cheapest), 2 (0.2 at 2 s), 8th (0.1 at 3 s), 4th (0.05 at 4 s); 3rd, 5th and 6th are dominated;
    # the NaN-cost point is never on the front
    assert front.tolist() == [True, True, False, True, False, False, False, True]
    rng = np.random.default_rng(1)
    c, e = rng.random(200), rng.random(200)
    f = study.pareto_front(c, e)
    for i in np.flatnonzero(f):  # brute force: no point is at least as good in both and better in one
        assert not np.any((c <= c[i]) & (e <= e[i]) & ((c < c[i]) | (e < e[i])))
    order = np.argsort(c[f])
    assert np.all(np.diff(e[f][order]) < 0)  # along the front, paying more buys accuracy


def _table(rows):
    base = {"status": "completed", "note": "", "knob": "dx", "dt_factor": 1.0, "collision": "bgk", "wall": "bounce_back",
            "precision": "float64", "dt_s": 1e-3}
    return pd.DataFrame([{**base, **r} for r in rows])


def test_recommendation_is_the_cheapest_completed_steady_run_within_the_target():
    df = _table([
        {"reference": "pipe", "run": "a", "setting": "a", "dx_mm": 2.5, "error": 0.03, "cpu_s": 1.0},
        {"reference": "pipe", "run": "b", "setting": "b", "dx_mm": 1.25, "error": 0.009, "cpu_s": 4.0},
        {"reference": "pipe", "run": "c", "setting": "c", "dx_mm": 1.0, "error": 0.004, "cpu_s": 9.0},
        {"reference": "pipe", "run": "d", "setting": "d", "dx_mm": 2.0, "error": 0.005, "cpu_s": 2.0,
         "note": "not steady: drift 0.01 > 0.001"},
        {"reference": "pipe", "run": "e", "setting": "e", "dx_mm": 1.5, "error": 0.001, "cpu_s": 3.0, "status": "unstable"},
        {"reference": "drag", "run": "f", "setting": "f", "dx_mm": 1.25, "error": 0.2, "cpu_s": 2.0},
        {"reference": "drag", "run": "g", "setting": "g", "dx_mm": 1.0, "error": 0.03, "cpu_s": 5.0},
    ])
    rec = study.recommend(df, {"pipe": 0.01, "drag": 0.05, "omega": 0.05, "averaging": 0.05}, cost="cpu_s")
    assert rec["references"]["pipe"]["recommended"]["run"] == "b"
    assert rec["references"]["drag"]["recommended"]["run"] == "g"
    assert rec["references"]["omega"]["verdict"] == "not measurable"
    # the joint setting needs one dx meeting both targets: only dx = 1.0 does
    assert rec["joint"]["verdict"] == "met" and rec["joint"]["dx_mm"] == 1.0
    strict = study.recommend(df, {"pipe": 1e-4, "drag": 0.05}, cost="cpu_s")
    assert strict["references"]["pipe"]["verdict"] == "not met"
    assert strict["references"]["pipe"]["most_accurate"]["run"] == "e"
    assert strict["joint"]["verdict"] == "not met"
    json.dumps(rec)  # the recommendation is plain JSON


def test_cost_fit_recovers_known_coefficients_from_synthetic_runs():
    rng = np.random.default_rng(3)
    n = 40
    nu = 10 ** rng.uniform(5, 9, n)
    lu = np.where(rng.random(n) < 0.5, 0.0, 10 ** rng.uniform(5, 8, n))
    ps = np.where(lu > 0, 10 ** rng.uniform(3, 6, n), 0.0)
    threads = rng.choice([1, 2], n)
    truth = {"intercept_s": 1.3, "s_per_node_update": 5e-8, "s_per_link_update": 2e-8, "s_per_particle_step": 3e-6}
    wall = truth["intercept_s"] + (truth["s_per_node_update"] * nu + truth["s_per_link_update"] * lu
                                   + truth["s_per_particle_step"] * ps) / threads
    df = pd.DataFrame({"node_updates": nu, "link_updates": lu, "particle_steps": ps, "threads": threads,
                       "wall_s": wall * (1 + 0.01 * rng.standard_normal(n))})
    model = runcost.fit_cost_model(df, target="wall_s")
    for k, v in truth.items():
        assert model[k] == pytest.approx(v, rel=0.1), k
    assert model["rel_rms_error"] < 0.03
    # fitted on CPU time (work summed over threads), it predicts the same wall times
    df["cpu_s"] = truth["intercept_s"] + (wall - truth["intercept_s"]) * threads
    cpu_model = runcost.fit_cost_model(df, target="cpu_s")
    assert runcost.model_predict_work(cpu_model, nu, lu, ps, threads) == pytest.approx(wall, rel=1e-3)
    # without particle runs the particle terms are not identified rather than invented
    bare = runcost.fit_cost_model(df[df["link_updates"] == 0], target="wall_s")
    assert set(bare["not_identified"]) == {"link_updates", "particle_steps"} and bare["s_per_link_update"] == 0.0


def test_cost_prediction_counts_nodes_steps_and_particle_links_of_a_scene():
    model = {"intercept_s": 2.0, "s_per_node_update": 1e-7, "s_per_link_update": 1e-7, "s_per_particle_step": 0.0,
             "links_per_area_lu": 5.0}
    data = {"name": "t", "domain": {"kind": "box", "size_mm": [20.0, 20.0, 20.0]},
            "fluid": {"viscosity_m2_s": 1e-4}, "numerics": {"dx_mm": 1.0, "dt_s": 1e-3},
            "run": {"duration_s": 0.1, "spinup_s": 0.05, "sample_interval_s": 0.01, "threads": 1}}
    sc = Scene.model_validate(data)
    p = derive(sc)
    assert cost.predict(sc, p, model) == pytest.approx(2.0 + 1e-7 * 8000 * 100)
    data["particles"] = {"bodies": [{"shape": "cube", "edge_mm": 4.0, "position_mm": [10.0, 10.0, 10.0], "fixed": True}]}
    sc2 = Scene.model_validate(data)
    links = 5.0 * 6 * 16.0  # links per area x cube area in lattice units
    assert cost.predict(sc2, derive(sc2), model) == pytest.approx(2.0 + 1e-7 * (8000 + links) * 100)
    data["run"]["threads"] = 2
    sc3 = Scene.model_validate(data)
    assert cost.predict(sc3, derive(sc3), model) == pytest.approx(2.0 + 1e-7 * (8000 + links) * 50)


def test_tiny_pipe_run_through_the_study_gives_a_finite_profile_error(tmp_path):
    cfg = dict(CONFIG, study={"smoke": {"pipe": {"duration_s": 1.0, "spinup_s": 0.5, "sample_interval_s": 0.05,
                                                 "dx_mm": [5.0], "dt_factors": [1.0], "walls": [], "collisions": [],
                                                 "precisions": [], "length_mm": 10.0},
                                        "drag": {"dx_mm": [], "dt_factors": [], "collisions": [], "precisions": [],
                                                 "offsets": 0}}})
    s = study_plan.study_settings(cfg, "smoke")
    setting = dict(s["base"], dx_mm=5.0)
    rid = study_plan.run_id("pipe", setting)
    assert rid in study_plan.run_ids(cfg, "smoke")
    run_dir = tmp_path / "smoke" / "study" / "runs" / rid
    scene = study_plan.write_run_scene(cfg, "smoke", rid, run_dir / "scene.yaml")
    assert yaml.safe_load((run_dir / "scene.yaml").read_text())["numerics"]["dx_mm"] == 5.0
    assert derive(scene).n_steps == 200  # a few hundred steps
    proc = study_plan.run_timed(run_dir / "scene.yaml", run_dir, 1, tmp_path / "run.log", run_dir / "process.json")
    assert proc["returncode"] == 0 and 0 < proc["cpu_s"] < 10 * proc["wall_s"]
    bench = tmp_path / "smoke" / "study" / "benchmarks" / f"{rid}.tsv"
    bench.parent.mkdir(parents=True)
    bench.write_text("s\th:m:s\tmax_rss\tcpu_time\n3.5\t0:00:03\t200\t3.0\n")
    table, cost_runs, model = study.collect(cfg, "smoke", tmp_path)
    row = table[(table["reference"] == "pipe") & (table["run"] == rid)].iloc[0]
    # a 10-node pipe with a staircase wall: a few per cent from Hagen-Poiseuille, not zero, not wild
    assert 0.005 < row["error"] < 0.2
    # wall time from the benchmark, CPU time measured on the child process
    assert row["wall_s"] == 3.5 and row["cpu_s"] == pytest.approx(proc["cpu_s"]) and row["steps"] == 200
    assert cost_runs["source"].tolist() == ["study"]
    # the particle references say why they are empty instead of failing
    assert table[table["reference"] == "averaging"]["status"].iloc[0] == "missing"


def _fake_case(root, level, case, dx, omega, duration=1.0):
    d = root / level / "cases" / case
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({
        "status": "completed", "steps": 100, "fluid_nodes": 1000, "simulated_seconds": duration, "threads": 1,
        "scene": {"numerics": {"dx_mm": dx, "dt_s": dx * 1e-3}}, "particles": {"count": 3, "links": 50}}))
    (d / "stats.json").write_text(json.dumps({"mean_abs_omega_rad_s": dict(zip("xyz", omega)),
                                              "ci95_rad_s": {"x": 0.01, "y": 0.01, "z": 0.01}}))


def test_observable_converges_towards_the_finest_level_present_and_says_when_there_is_only_one(tmp_path):
    case = "cyl8x16_c30_re9.4"
    _fake_case(tmp_path, "smoke", case, 2.5, (1.2, 1.0, 0.5))
    rows = study_errors.observable_rows(CONFIG, "smoke", tmp_path)
    assert len(rows) == 1 and math.isnan(rows[0]["error"]) and "only one fidelity level" in rows[0]["note"]
    _fake_case(tmp_path, "paper", case, 1.0, (1.0, 1.0, 0.5))
    rows = {r["setting"]: r for r in study_errors.observable_rows(CONFIG, "smoke", tmp_path)}
    assert rows["smoke"]["error"] == pytest.approx(0.2 / math.sqrt(2.25))  # |(0.2, 0, 0)| / |(1, 1, 0.5)|
    assert math.isnan(rows["paper"]["error"]) and rows["paper"]["note"].startswith("reference")


def test_averaging_recommendation_rests_on_at_least_20_batches_and_names_them(tmp_path):
    # |Omega_x| of 3 particles: an AR(1) series with a correlation time of 0.1 s, sampled every
    # 0.01 s for 40 s; windows shorter than 20 batches of 5 correlation times (10 s) are not
    # recommendable, however small their apparent error
    rng = np.random.default_rng(1)
    n, dt, phi = 4000, 0.01, math.exp(-0.01 / 0.1)
    w = np.empty(n)
    w[0] = 0.0
    for i in range(1, n):
        w[i] = phi * w[i - 1] + math.sqrt(1 - phi * phi) * 0.1 * rng.standard_normal()
    t = np.arange(n) * dt
    d = tmp_path / "paper" / "cases" / "cyl8x16_c30_re9.4"
    d.mkdir(parents=True)
    pd.DataFrame({"t_s": np.repeat(t, 3), "wx_rad_s": np.repeat(1.0 + w, 3)}).to_parquet(d / "particles.parquet")
    (d / "summary.json").write_text(json.dumps({
        "status": "completed", "steps": n, "fluid_nodes": 1000, "simulated_seconds": n * dt, "spinup_s": 0.0,
        "threads": 1, "scene": {"numerics": {"dx_mm": 1.0, "dt_s": dt}}, "particles": {"count": 3, "links": 50}}))
    cfg = {"study": {}, "fidelities": {"paper": {"dx_mm": 1.0}}}
    rows = pd.DataFrame(study_errors.averaging_rows(cfg, "paper", tmp_path))
    ok = rows[rows["status"] == "completed"]
    assert len(ok) and (ok["n_batches"] >= 20).all() and (ok["averaging_s"] >= 9.0).all()
    short = rows[rows["status"] == "insufficient"]
    assert len(short) and (short["averaging_s"] < 10.0).all()
    rec = study.recommend(rows.assign(cpu_s=rows["averaging_s"]), {"averaging": 0.5}, cost="cpu_s")
    best = rec["references"]["averaging"]["recommended"]
    assert best["n_batches"] >= 20
    assert "rests on" in study.recommendation_markdown(rec)


def test_no_averaging_window_with_too_few_batches_is_called_the_most_accurate():
    # two windows, both on fewer than 20 batches: the target is not met, and the report names the
    # longest window's batches instead of the smaller, meaningless error of the shorter one
    rows = pd.DataFrame([
        {"reference": "averaging", "knob": "averaging time", "setting": f"{s} s", "run": f"w{s}", "error": e, "cpu_s": c,
         "averaging_s": s, "n_batches": b, "batch_s": 0.1, "interval": "overlapping batch means", "status": "insufficient"}
        for s, e, c, b in ((0.5, 0.01, 10.0, 5), (1.5, 0.04, 30.0, 15))])
    rec = study.recommend(rows, {"averaging": 0.05}, cost="cpu_s")
    entry = rec["references"]["averaging"]
    assert entry["verdict"] == "not met" and "most_accurate" not in entry
    assert entry["no_valid_interval"]["averaging_s"] == 1.5
    text = study.recommendation_markdown(rec)
    assert "no tested setting has an interval that rests on 20 batches" in text and "15 batch(es)" in text
