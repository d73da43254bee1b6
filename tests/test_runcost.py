"""The wall-time cost model of production runs (lbmpipe.reproduction.runcost): each group of the
step charged to its own work, validated with every case family held out of its own fit."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lbmpipe import cost
from lbmpipe.reproduction import runcost

NODE, LINK, PART, STEP, SETUP = 50e-9, 30e-9, 10e-6, 5e-4, 3.0


def _summary(steps, nodes=197600, links=0, count=0, scale=1.0, threads=1, loop_extra=0.0):
    eff = {"stream+collide D3Q15 BGK": 0.9 * scale * NODE * nodes * steps / threads,
           "wall: half-way bounce-back": 0.1 * scale * NODE * nodes * steps / threads}
    if links:
        eff["particles: Ladd coupling"] = 0.7 * scale * LINK * links * steps / threads
        eff["particles: motion + remap"] = 0.3 * scale * LINK * links * steps / threads
    if count:
        eff["collisions: impulses + overlap removal"] = scale * PART * count * steps / threads
    loop = sum(eff.values()) + scale * STEP * steps / threads + loop_extra
    return {"status": "completed", "steps": steps, "wall_seconds": loop, "setup_seconds": 1.0, "threads": threads,
            "fluid_nodes": nodes, "particles": {"links": links, "count": count}, "effects": eff}


def _write_level(tmp_path, runs):
    for run, (summary, bench) in runs.items():
        d = tmp_path / "cases" / run
        d.mkdir(parents=True)
        (d / "summary.json").write_text(json.dumps(summary))
        if bench is not None:
            b = tmp_path / "benchmarks" / f"{run}.simulate.tsv"
            b.parent.mkdir(parents=True, exist_ok=True)
            b.write_text(f"s\th:m:s\tmax_rss\tcpu_time\n{bench}\t0:00:01\t100\t{bench}\n")
    return list(runs)


def test_family_holds_both_reynolds_numbers_and_every_seed_of_a_case():
    assert runcost.family("cyl8x16_c30_re9.4_nocoll/seed2") == "cyl8x16_c30_nocoll"
    assert runcost.family("cyl8x16_c30_re26/seed1") == runcost.family("cyl8x16_c30_re9.4/seed3") == "cyl8x16_c30"
    assert runcost.family("flow_re26") == runcost.family("flow_re9.4") == "flow"


def test_each_group_of_the_step_is_charged_to_its_own_work(tmp_path):
    # runs on the same host (one scale): the fit recovers every coefficient and predicts every
    # held-out family exactly, however different its mix of fluid, links and particles
    specs = {"flow_re9.4": (1000, 0, 0), "cube16_c30_re9.4/seed1": (2000, 110000, 14),
             "cyl8x8_c30_re9.4/seed1": (3000, 220000, 146), "cyl8x16_c50_re26/seed1": (1500, 280000, 122)}
    runs = {r: (s := _summary(n, links=lk, count=c), s["wall_seconds"] + SETUP) for r, (n, lk, c) in specs.items()}
    names = _write_level(tmp_path, runs)
    model, val = runcost.build(tmp_path, names, "test")
    assert model["s_per_node_update"] == pytest.approx(NODE)
    assert model["s_per_link_update"] == pytest.approx(LINK)
    assert model["s_per_particle_step"] == pytest.approx(PART)
    assert model["s_per_step"] == pytest.approx(STEP)
    assert model["intercept_s"] == pytest.approx(SETUP)
    assert model["families"] == 4 and model["n_validated"] == 4
    assert np.allclose(val["rel_error"], 0.0, atol=1e-9)
    assert model["median_abs_rel_error"] == pytest.approx(0.0, abs=1e-9)


def test_a_family_is_never_predicted_by_its_own_runs(tmp_path):
    # one family runs twice as slow as the rest: held out, the others' model under-predicts it by
    # half; fitted with it, the model would have absorbed part of that
    runs = {}
    for k, (case, scale) in enumerate([("cube8_c30_re9.4", 2.0), ("cyl16x16_c30_re9.4", 1.0),
                                       ("cyl8x8_c30_re9.4", 1.0), ("cube16_c30_re9.4", 1.0)]):
        for seed in (1, 2):
            s = _summary(2000, links=100000 * (k + 1), count=10 * (k + 1), scale=scale)
            runs[f"{case}/seed{seed}"] = (s, s["wall_seconds"] + SETUP * scale)
    names = _write_level(tmp_path, runs)
    _, val = runcost.build(tmp_path, names, "test")
    slow = val[val["family"] == "cube8_c30"]
    assert np.allclose(slow["rel_error"], -0.5, atol=1e-9)
    assert (slow["fitted_on"] == 6).all()
    assert np.allclose(val.loc[val["family"] != "cube8_c30", "rel_error"], 0.0, atol=1e-9)


def test_a_resumed_run_counts_its_loop_and_set_up_not_its_last_process_alone(tmp_path):
    s = _summary(4000, links=100000, count=10)
    row = runcost.run_row("cube16_c30_re9.4/seed1", s, bench_s=0.25 * s["wall_seconds"])
    assert row["resumed"] and row["wall_s"] == pytest.approx(s["wall_seconds"] + 1.0)
    fresh = runcost.run_row("cube16_c30_re9.4/seed1", s, bench_s=s["wall_seconds"] + 2.0)
    assert not fresh["resumed"] and fresh["overhead_s"] == pytest.approx(2.0)
    assert runcost.run_row("x", {**s, "status": "failed"}) is None


def test_work_divides_over_threads_in_the_prediction():
    model = {"intercept_s": 2.0, "s_per_step": 1e-3, "s_per_node_update": 1e-8, "s_per_link_update": 2e-8,
             "s_per_particle_step": 1e-5}
    one = cost.predict_work(model, 1000, 100000, 50000, 20, threads=1)
    two = cost.predict_work(model, 1000, 100000, 50000, 20, threads=2)
    assert one == pytest.approx(2.0 + 1000 * (1e-3 + 1e-3 + 1e-3 + 2e-4))
    assert two - 2.0 == pytest.approx((one - 2.0) / 2)


def _check_line(tmp_path, capsys, model: dict, ns_per_node: float):
    """``lbmpipe check``'s prediction line for the pipe scene under ``model``, and the wall seconds
    a model of ``ns_per_node`` per fluid node (2 s set-up, 0.5 ms a step) gives with a core of its own."""
    from lbmpipe.cli import run_cli
    from lbmpipe.scene import load_scene
    from lbmpipe.units import derive

    mpath = tmp_path / "cost_model.json"
    mpath.write_text(json.dumps(model))
    scene = Path(__file__).resolve().parents[1] / "scenes" / "pipe_re9.4.yaml"
    params = derive(load_scene(scene))
    assert run_cli(["check", str(scene), "--cost-model", str(mpath)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "predicted run time" in ln)
    threads = load_scene(scene).run.threads or 1
    return line, 2.0 + params.n_steps * (ns_per_node * 1e-9 * params.fluid_nodes + 5e-4) / threads


def test_lbmpipe_check_prints_the_wall_time_prediction_with_its_validated_error(tmp_path, capsys):
    from lbmpipe.cli import _duration

    model = {"intercept_s": 2.0, "s_per_step": 5e-4, "s_per_node_update": 5e-8, "s_per_link_update": 5e-8,
             "s_per_particle_step": 1e-5, "median_abs_rel_error": 0.083, "median_abs_rel_error_median_share": 0.121,
             "n_validated": 21, "threads_measured": [1], "links_per_area_lu": 5.0, "median_cpu_share": 0.8}
    line, expected = _check_line(tmp_path, capsys, model, 50.0)
    assert _duration(expected) in line and _duration(expected / 0.8) in line
    assert "median error 8 % given a run's share, 12 % at the median share, on 21 production runs held out" in line
    assert str(tmp_path / "cost_model.json") in line


def test_validation_table_and_model_are_written_beside_the_level_tables(tmp_path):
    runs = {"flow_re9.4": (s := _summary(1000), s["wall_seconds"] + SETUP),
            "cube16_c30_re9.4/seed1": (t := _summary(1000, links=1000, count=2), t["wall_seconds"] + SETUP)}
    names = _write_level(tmp_path, runs)
    model = runcost.write(tmp_path, names, "test", tmp_path / "tables" / "cost_model.json",
                          tmp_path / "tables" / "cost_validation.csv")
    assert json.loads((tmp_path / "tables" / "cost_model.json").read_text())["n_runs"] == model["n_runs"] == 2
    val = pd.read_csv(tmp_path / "tables" / "cost_validation.csv")
    assert list(val["run"]) == names and {"predicted_s", "rel_error", "family"} <= set(val.columns)


def test_a_run_slowed_by_other_jobs_is_predicted_from_its_share_of_a_core(tmp_path):
    # the same work in every family; one family's runs got half a core (its wall time doubled,
    # its effects' wall timings with it): given its share, every run is predicted exactly
    runs = {}
    for case, share in (("cube8_c30_re9.4", 0.5), ("cyl16x16_c30_re9.4", 1.0), ("cyl8x8_c30_re9.4", 1.0)):
        s = _summary(2000, links=100000, count=10, scale=1.0 / share)
        wall = s["wall_seconds"] + SETUP / share
        runs[f"{case}/seed1"] = (s, wall)
    names = _write_level(tmp_path, runs)
    for run, (s, wall) in runs.items():  # the benchmark's CPU seconds: the share times the wall
        share = 0.5 if run.startswith("cube8") else 1.0
        (tmp_path / "benchmarks" / f"{run}.simulate.tsv").write_text(
            f"s\th:m:s\tmax_rss\tcpu_time\n{wall}\t0:00:01\t100\t{share * wall}\n")
    model, val = runcost.build(tmp_path, names, "test")
    assert model["s_per_link_update"] == pytest.approx(LINK)
    assert np.allclose(val["rel_error"], 0.0, atol=1e-9)
    slow = val[val["run"].str.startswith("cube8")]
    assert float(slow["cpu_share"].iloc[0]) == pytest.approx(0.5)
    assert float(slow["rel_error_median_share"].iloc[0]) == pytest.approx(-0.5)


def test_a_cluster_time_limit_follows_the_wall_time_model_and_never_falls_below_the_node_estimate(tmp_path):
    import yaml

    from lbmpipe.reproduction import cases

    root = tmp_path
    config = yaml.safe_load((Path(__file__).resolve().parents[1] / "config.yaml").read_text())
    without = cases.estimate_minutes(config, "credible", "cyl16x16_c30_re26/seed1", root)
    model = {"n_runs": 5, "intercept_s": 10.0, "s_per_step": 1e-3, "s_per_node_update": 2e-7,
             "s_per_link_update": 1e-7, "s_per_particle_step": 1e-5, "links_per_area_lu": 5.0}
    path = root / "results" / "credible" / "tables" / "cost_model.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(model))
    slow = cases.estimate_minutes(config, "credible", "cyl16x16_c30_re26/seed1", root)
    # 120000 steps of ~2e5 nodes at 2e-7 s a node update: over 80 minutes, times the margin
    assert slow > without and slow >= 1.5 * 80
    path.write_text(json.dumps({**model, **{k: 0.0 for k in model if k.startswith("s_per")}, "intercept_s": 0.0}))
    assert cases.estimate_minutes(config, "credible", "cyl16x16_c30_re26/seed1", root) == without


def test_unrecorded_runs_of_several_families_are_predicted_from_each_other_not_from_a_faster_processor(tmp_path):
    # the unrecorded runs came from a machine whose fluid step costs 2.3 times more per node than
    # the recorded processor's: validated within their group they are predicted exactly
    runs = {}
    for run, links, count, cpu, scale in (
            ("flow_re9.4", 0, 0, None, 1.0), ("cube16_c30_re9.4/seed1", 110000, 14, None, 1.0),
            ("cyl8x8_c30_re9.4/seed1", 220000, 146, None, 1.0),
            ("flow_re26", 0, 0, "fast", 1 / 2.3), ("cube16_c30_re9.4/seed2", 110000, 14, "fast", 1 / 2.3),
            ("cyl8x8_c30_re9.4/seed2", 220000, 146, "fast", 1 / 2.3)):
        s = _summary(1000 + len(runs) * 300, links=links, count=count)
        for name in s["effects"]:
            if name.startswith("stream+collide"):
                s["effects"][name] *= scale
        s["wall_seconds"] = sum(s["effects"].values()) + STEP * s["steps"]
        if cpu:
            s["host"] = {"cpu": cpu, "cores": 2}
        runs[run] = (s, s["wall_seconds"] + SETUP)
    names = _write_level(tmp_path, runs)
    model, val = runcost.build(tmp_path, names, "test")
    old = val[val["host"] == runcost.UNRECORDED]
    assert len(old) == 3 and (old["fitted_host"] == runcost.UNRECORDED).all()
    assert np.allclose(val["rel_error"], 0.0, atol=1e-9)
    assert set(model["hosts"]) == {"fast"}


def test_each_processor_is_predicted_from_its_own_runs_and_a_lone_unrecorded_family_from_all(tmp_path):
    # the fluid step costs 2.3 times less per node on processor "fast": validated within their own
    # processor, both processors' runs are predicted exactly; pooled, neither would be
    runs = {}
    specs = {"slow": ["flow_re9.4", "cube16_c30_re9.4/seed1", "cyl8x8_c30_re9.4/seed1"],
             "fast": ["flow_re26", "cube16_c30_re9.4/seed2", "cyl8x8_c30_re9.4/seed2"]}
    for cpu, scale in (("slow", 1.0), ("fast", 1.0 / 2.3)):
        for k, (run, links, count) in enumerate(zip(specs[cpu], (0, 110000, 220000), (0, 14, 146))):
            s = _summary(1000 * (k + 1), links=links, count=count)
            for name in s["effects"]:
                if name.startswith("stream+collide"):
                    s["effects"][name] *= scale
            s["wall_seconds"] = sum(s["effects"].values()) + STEP * s["steps"]
            s["host"] = {"cpu": cpu, "cores": 2}
            runs[run] = (s, s["wall_seconds"] + SETUP)
    legacy = _summary(2500, links=150000, count=40)  # a run from before the processor was recorded
    runs["cyl16x16_c30_re9.4/seed1"] = (legacy, legacy["wall_seconds"] + SETUP)
    lonely = {**_summary(1800, links=90000, count=12), "host": {"cpu": "lonely", "cores": 2}}  # one family only
    runs["cube16_c30_re26/seed3"] = (lonely, lonely["wall_seconds"] + SETUP)
    names = _write_level(tmp_path, runs)
    model, val = runcost.build(tmp_path, names, "test")
    recorded = val[val["host"].isin(["slow", "fast"])]
    assert (recorded["fitted_host"] == recorded["host"]).all()
    assert np.allclose(recorded["rel_error"], 0.0, atol=1e-9)
    old = val[val["host"].isin([runcost.UNRECORDED, "lonely"])]
    assert (old["fitted_host"] == "all").all()
    assert (old.loc[old["host"] == runcost.UNRECORDED, "fitted_on"] == 7).all()
    # a processor with runs of one family cannot validate coefficients of its own: none are kept
    assert set(model["hosts"]) == {"slow", "fast"} and model["runs_by_host"] == {"fast": 3, "lonely": 1, "slow": 3,
                                                                                   runcost.UNRECORDED: 1}
    assert model["hosts"]["fast"]["s_per_node_update"] == pytest.approx(NODE * (0.9 / 2.3 + 0.1))
    assert model["hosts"]["slow"]["s_per_node_update"] == pytest.approx(NODE)
    assert model["hosts"]["fast"]["median_abs_rel_error"] == pytest.approx(0.0, abs=1e-9)
    # a prediction for a processor the model knows uses its coefficients; an unknown one, all runs'
    own, is_own = cost.for_host(model, "fast")
    assert is_own and own["s_per_node_update"] == model["hosts"]["fast"]["s_per_node_update"]
    pooled, is_own = cost.for_host(model, "another")
    assert not is_own and pooled["s_per_node_update"] == model["s_per_node_update"]


def test_lbmpipe_check_predicts_from_the_runs_of_its_own_processor(tmp_path, capsys):
    from lbmpipe.cli import _duration
    from lbmpipe.outputs import host

    base = {"intercept_s": 2.0, "s_per_step": 5e-4, "s_per_node_update": 5e-8, "s_per_link_update": 5e-8,
            "s_per_particle_step": 1e-5, "median_abs_rel_error": 0.3, "median_abs_rel_error_median_share": 0.4,
            "n_validated": 30, "threads_measured": [1], "links_per_area_lu": 5.0, "median_cpu_share": 0.8}
    here = {"intercept_s": 2.0, "s_per_step": 5e-4, "s_per_node_update": 2e-8, "s_per_link_update": 5e-8,
            "s_per_particle_step": 1e-5, "median_abs_rel_error": 0.07, "median_abs_rel_error_median_share": 0.09,
            "n_validated": 9, "median_cpu_share": 0.9}
    line, expected = _check_line(tmp_path, capsys, {**base, "hosts": {host()["cpu"]: here}}, 20.0)
    assert _duration(expected) in line and _duration(expected / 0.9) in line
    assert "median error 7 % given a run's share, 9 % at the median share, on 9 production runs on this processor" in line


def test_a_runs_host_record_names_the_blas_kernel_that_rounds_its_flux_dot_product(monkeypatch):
    # the paper method's bits depend on OpenBLAS's kernel (AVX-512 and Haswell round the flux
    # correction's dot product differently): the summary says which one the environment forced
    from lbmpipe.outputs import host

    monkeypatch.setenv("OPENBLAS_CORETYPE", "Haswell")
    assert host()["openblas_coretype"] == "Haswell"
    monkeypatch.delenv("OPENBLAS_CORETYPE")
    assert host()["openblas_coretype"] == "auto"
