"""Several packings per case (lbmpipe.reproduction.seeds, the `seeds` key of a level): the
combined interval holds the spread between packings as well as each run's own noise, diagnostics
of any seed flag the case, and the pipeline runs each case once per packing seed."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml
from scipy import stats as sps

from lbmpipe.reproduction import seeds as S
from lbmpipe.reproduction.cases import level_runs, packing_id, run_case, split_run

ROOT = Path(__file__).resolve().parents[1]


def test_combined_interval_of_scattered_packings_is_the_t_interval_of_the_seed_means():
    # three packings whose runs are each precise (half-width 0.01) but disagree by 0.1
    c = S.combine_means([1.0, 1.1, 1.2], [0.01, 0.01, 0.01], [30, 30, 30])
    se = pd.Series([1.0, 1.1, 1.2]).std(ddof=1) / 3 ** 0.5
    assert c["mean"] == pytest.approx(1.1)
    assert c["branch"] == "between-seed" and c["dof"] == 2
    assert c["ci95"] == pytest.approx(sps.t.ppf(0.975, 2) * se)
    assert c["ci95"] > 10 * 0.01  # far wider than any one run's interval


def test_a_seed_without_a_mean_is_left_out_and_one_without_an_interval_leaves_the_seeds_scatter():
    c = S.combine_means([2.0, None, 2.2], [0.3, 0.3, None], [40, 40, None])
    assert c["n_seeds"] == 2 and c["mean"] == pytest.approx(2.1)
    assert c["branch"] == "between-seed"


def _seed_stats(mean, ci, frozen=False, issues=(), steady=True):
    iv = {a: {"mean": mean, "ci95": ci, "dof": 40, "sufficient": True, "required_s": 10.0, "duration_s": 20.0}
          for a in "xyz"}
    return {"case": "c", "status": "completed", "shape": "cube", "size_label": "8 mm", "reynolds": 9.4,
            "concentration": 0.3, "collisions": True, "n_particles": 100, "samples": 500, "spinup_s": 3.0,
            "mean_abs_omega_rad_s": {a: mean for a in "xyz"}, "ci95_rad_s": {a: ci for a in "xyz"},
            "omega_intervals": iv, "tau_int_s": {a: 0.1 for a in "xyz"},
            "orientation": {"cube_axis_angle": {"mean_deg": 30.0 + mean, "ci95_deg": 1.0, "median_deg": 29.0,
                                                "interval": {"dof": 20}}},
            "orientation_memory": {"tau_orient_s": 0.5},
            "orientation_order": {"mean": 0.1, "ci95": 0.01, "dof": 20},
            "frozen": {"frozen": frozen, "remaining": 0.8 if frozen else 0.1, "threshold": 0.5},
            "locked": {"locked": False, "column": False, "neighbours_retained": 0.3},
            "health": {"issues": list(issues), "max_overlap_lu": 0.02, "healthy": not issues},
            "spinup": {"steady": steady, "spinup_s": 3.0, "required_s": 2.9, "message": "" if steady else "drifts"},
            "resolution": {"lattice_spacings": 8.0}, "flags": []}


def test_a_case_is_frozen_unhealthy_or_unsteady_when_any_packing_is_and_names_the_seed():
    per = [(1, _seed_stats(1.0, 0.02)), (2, _seed_stats(1.05, 0.02, frozen=True, issues=["mass drift"])),
           (3, _seed_stats(0.95, 0.02, steady=False))]
    out = S.combine_stats("c", per)
    assert out["status"] == "completed" and out["n_seeds"] == 3 and out["samples"] == 1500
    assert set(out["flags"]) == {"frozen", "unhealthy", "not steady"}
    assert out["frozen"]["seeds"] == [2] and out["spinup"]["seeds_not_steady"] == [3]
    assert out["health"]["issues"] == ["seed 2: mass drift"]
    assert out["health"]["max_overlap_lu"] == pytest.approx(0.02)
    assert out["mean_abs_omega_rad_s"]["x"] == pytest.approx(1.0)
    assert out["seed_spread_rel"]["x"] == pytest.approx(0.05)
    assert [s["seed"] for s in out["seeds"]] == [1, 2, 3]


def test_a_seed_not_yet_run_is_left_out_of_the_mean_and_counted():
    out = S.combine_stats("c", [(1, _seed_stats(1.0, 0.02)), (2, None), (3, _seed_stats(1.2, 0.02))])
    assert out["n_seeds"] == 2 and out["seed_status"] == {"1": "completed", "2": "not run", "3": "completed"}
    assert out["mean_abs_omega_rad_s"]["z"] == pytest.approx(1.1)


def test_a_packing_that_went_unstable_is_left_out_of_the_mean_and_makes_the_case_unhealthy():
    blown = {"case": "c", "status": "unstable", "samples": 0, "mean_abs_omega_rad_s": {a: None for a in "xyz"},
             "health": {"status": "unstable", "issues": ["status unstable", "largest density deviation 0.368 > 0.3"],
                        "density_deviation_max": 0.368, "healthy": False}}
    out = S.combine_stats("c", [(1, _seed_stats(1.0, 0.02)), (2, _seed_stats(1.2, 0.02)), (3, blown)])
    assert out["status"] == "completed" and out["n_seeds"] == 2 and out["seed_status"]["3"] == "unstable"
    assert out["mean_abs_omega_rad_s"]["x"] == pytest.approx(1.1)
    assert out["health"]["issues"] == ["seed 3: status unstable", "seed 3: largest density deviation 0.368 > 0.3"]
    assert "unhealthy" in out["flags"] and out["health"]["healthy"] is False


def test_combined_files_average_histograms_and_profiles_over_the_seeds(tmp_path):
    case = tmp_path / "cases" / "cube8_c30_re9.4"
    for k, (mean, frac) in enumerate([(1.0, 0.2), (1.2, 0.4)], start=1):
        d = case / f"seed{k}"
        d.mkdir(parents=True)
        (d / "stats.json").write_text(json.dumps(_seed_stats(mean, 0.02)))
        pd.DataFrame({"kind": ["cube_axis_angle"] * 2, "bin_lo_deg": [0.0, 10.0], "bin_hi_deg": [10.0, 20.0],
                      "fraction": [frac, 1 - frac], "ci95": [float("nan")] * 2}).to_csv(d / "orientation.csv", index=False)
        pd.DataFrame({"r_mm": [1.0, 2.0], "uz_m_s": [mean, mean / 2], "uz_poiseuille_m_s": [1.0, 0.5],
                      "nodes": [4, 8]}).to_csv(d / "profile.csv", index=False)
        (d / "summary.json").write_text(json.dumps({"status": "completed", "steps": 100, "wall_seconds": 5.0,
                                                    "simulated_seconds": 1.0}))
    S.write_combined("cube8_c30_re9.4", case, [1, 2])
    h = pd.read_csv(case / "orientation.csv")
    assert h["fraction"].tolist() == pytest.approx([0.3, 0.7])
    assert (h["ci95"] > 0).all()  # the seeds' scatter is the bins' interval
    assert pd.read_csv(case / "profile.csv")["uz_m_s"].tolist() == pytest.approx([1.1, 0.55])
    summary = json.loads((case / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["steps"] == 200
    assert json.loads((case / "stats.json").read_text())["n_seeds"] == 2
    # the level's table reports the packings and their spread
    from lbmpipe.reproduction.statistics import aggregate
    aggregate(tmp_path, {"cube8_c30_re9.4": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8,
                                                                             "concentration": 0.3}}})
    row = pd.read_csv(tmp_path / "tables" / "angular_velocity.csv").iloc[0]
    assert row.n_seeds == 2 and row.omega_x == pytest.approx(1.1)
    assert row.seed_sd_x == pytest.approx(pd.Series([1.0, 1.2]).std() / 1.1)


def _config():
    return yaml.safe_load((ROOT / "config.yaml").read_text())


def test_a_level_with_seeds_runs_every_particle_case_once_per_packing_and_flows_once():
    config = _config()
    config["fidelities"]["smoke"]["seeds"] = 3
    runs = level_runs(config, "smoke")
    # a case declared unpackable has no run (lbmpipe.reproduction.unpackable)
    particle = [c for c, v in config["cases"].items() if v.get("particles") and not v.get("unpackable")]
    flows = [c for c, v in config["cases"].items() if not v.get("particles")]
    assert len(runs) == 3 * len(particle) + len(flows)
    assert "flow_re9.4" in runs and "cyl8x8_c30_re9.4/seed3" in runs
    assert split_run("cyl8x8_c30_re9.4/seed2") == ("cyl8x8_c30_re9.4", 2)
    ids = {packing_id(run_case(config, f"cyl8x8_c30_re9.4/seed{k}")[1]) for k in (1, 2, 3)}
    assert ids == {"cyl8x8_c30_s1", "cyl8x8_c30_s2", "cyl8x8_c30_s3"}
    # the Re 9.4 and Re 26 runs of one seed start from the same packing
    assert packing_id(run_case(config, "cyl8x8_c30_re26/seed2")[1]) == "cyl8x8_c30_s2"


def _job_counts(text: str) -> dict[str, int]:
    """The job-stats table of a Snakemake dry run: rule -> number of jobs."""
    return {w[0]: int(w[1]) for w in (line.split() for line in text.splitlines()) if len(w) == 2 and w[1].isdigit()}


def _snakemake() -> str:
    return shutil.which("snakemake", path=str(Path(sys.executable).parent)) or "snakemake"


def test_seeded_level_dag_runs_each_seed_and_combines_them_per_case(tmp_path):
    config = _config()
    config["fidelities"]["smoke"]["seeds"] = 2
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump(config, sort_keys=False))
    run = subprocess.run([_snakemake(), "-n", "--nolock", "--configfile", str(cfg), "--config", "fidelity=smoke",
                          "new_runs=all", "--quiet", "rules"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    counts = _job_counts(run.stdout + run.stderr)
    particle = sum(1 for v in config["cases"].values() if v.get("particles") and not v.get("unpackable"))
    assert int(counts["simulate_particles"]) == 2 * particle
    assert int(counts["combine_seeds"]) == particle


@pytest.mark.skipif(not (ROOT / ".git").exists() or shutil.which("git") is None, reason="needs the git repository")
def test_fresh_clone_regenerates_the_committed_level_without_running_a_simulation(tmp_path):
    """What a newcomer's `snakemake -c2` plans on a fresh clone of the committed tree (arbitrary
    mtimes, no Snakemake metadata): figures, tables, claims and the document, no packing,
    simulation, statistics of a trajectory, study run or stability suite."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=300)
    run = subprocess.run([_snakemake(), "-n", "--quiet", "rules"], cwd=clone, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    planned = set(_job_counts(run.stdout + run.stderr)) - {"total"}
    costly = {"pack", "simulate_particles", "simulate_flow", "statistics", "study_run", "study_warmup",
              "stability_table"}
    assert planned and not planned & costly, run.stdout + run.stderr


def test_run_health_of_a_combined_case_is_its_worst_packings(tmp_path):
    from lbmpipe.reproduction import health

    case = tmp_path / "c"
    case.mkdir()
    stats = S.combine_stats("c", [(1, _seed_stats(1.0, 0.02)), (2, _seed_stats(1.1, 0.02, issues=["mass drift"]))])
    (case / "stats.json").write_text(json.dumps(S._jsonable(stats)))
    row = health.health_row("c", case, health.thresholds()["health"])
    assert row["issues"] == "seed 2: mass drift" and "unhealthy" in row["flags"]
    assert row["max_overlap_lu"] == pytest.approx(0.02) and row["status"] == "completed"


def test_two_packings_give_a_valid_interval_where_each_run_alone_is_too_short():
    short = _seed_stats(1.0, 0.05)
    for iv in short["omega_intervals"].values():
        iv["sufficient"] = False
    one = S.combine_stats("c", [(1, short)])
    two = S.combine_stats("c", [(1, short), (2, _seed_stats(1.1, 0.05))])
    assert not one["omega_intervals"]["x"]["sufficient"]
    assert two["omega_intervals"]["x"]["sufficient"]  # independent replications
    assert "seeds 1" in two["omega_intervals"]["x"]["message"]


def test_packings_needed_for_a_5_percent_interval_follow_from_the_seeds_scatter():
    # 20 % scatter between packings: t_{n-1} 0.2 / sqrt(n) <= 0.05 first at n = 64 (t ~ 2.0)
    n = S.seeds_needed(0.2, 0.05)
    assert sps.t.ppf(0.975, n - 1) * 0.2 / n ** 0.5 <= 0.05 < sps.t.ppf(0.975, n - 2) * 0.2 / (n - 1) ** 0.5
    assert 60 <= n <= 70
    assert S.seeds_needed(0.01, 0.05) == 3  # t_1 = 12.7 is too wide with two
    assert S.seeds_needed(None, 0.05) is None


def test_overlap_between_collision_calls_beyond_the_models_bound_is_unhealthy_when_the_seeds_are_combined(tmp_path):
    """The seed's stats.json was judged healthy before the between-call overlap had a threshold: the
    combined case judges it again from the run's summary and is flagged (issue 28: what the fluid
    sees between calls may exceed the bound in a dense jam at a coarse spacing)."""
    from lbmpipe.particles.collisions import OVERLAP_BOUND_FACTOR, CollisionParams
    from lbmpipe.reproduction import health

    bound = health.thresholds()["health"]["max_overlap_between_lu"]
    assert bound == pytest.approx(OVERLAP_BOUND_FACTOR * CollisionParams().overlap_tol)
    case = tmp_path / "c"
    for k, before in ((1, 0.5 * bound), (2, 1.34 * bound)):
        d = case / f"seed{k}"
        d.mkdir(parents=True)
        (d / "stats.json").write_text(json.dumps(S._jsonable(_seed_stats(1.0, 0.02))))
        coll = {"enabled": True, "max_overlap_before_lu": before, "max_overlap_after_lu": 0.01}
        (d / "summary.json").write_text(json.dumps({"status": "completed", "collisions": coll}))
    out = S.write_combined("c", case, [1, 2])
    assert out["health"]["issues"] == [f"seed 2: largest overlap between collision calls (lattice spacings) "
                                       f"{1.34 * bound:.3g} > {bound:.3g}"]
    assert "unhealthy" in out["flags"]
    assert out["health"]["max_overlap_between_lu"] == pytest.approx(1.34 * bound)
    row = health.health_row("c", case, health.thresholds()["health"])
    assert "unhealthy" in row["flags"] and row["max_overlap_between_lu"] == pytest.approx(1.34 * bound)
    # a seed without a summary keeps the health its statistics recorded
    (case / "seed2" / "summary.json").unlink()
    assert not S.write_combined("c", case, [1, 2])["health"]["issues"]
