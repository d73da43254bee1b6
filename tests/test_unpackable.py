"""Cases the config declares unpackable (lbmpipe.reproduction.unpackable; the 24 mm cubes at 50 %):
planned at no level, whatever `new_runs` says, and shown as "unpackable" in the tables with the
concentration the measured attempt reached, never as "not run"."""

from __future__ import annotations

import copy
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction import unpackable as U
from lbmpipe.reproduction.cases import config_problems, level_runs
from lbmpipe.reproduction.statistics import aggregate

ROOT = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text())
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"
DECLARED = sorted(c for c, v in CONFIG["cases"].items() if v.get("unpackable"))


def _attempt(tmp_path, status="unpackable", reached=0.2819) -> Path:
    path = tmp_path / "cube24_c50_s1.json"
    path.write_text(json.dumps({"status": status, "packing": "cube24_c50_s1", "concentration_target": 0.5,
                                "concentration_reached": reached, "seed": 1, "count": 7,
                                "message": "no overlap-free packing found"}))
    return path


def _tiny_config(attempt: Path) -> dict:
    cube = {"shape": "cube", "edge_mm": 24, "concentration": 0.5}
    return {"fidelity": "lvl", "fidelities": {"lvl": {"dx_mm": 5.0, "dt_per_mm_s": 1e-3, "seeds": 3,
                                                       "run": {"duration_s": 0.2, "spinup_s": 0.05,
                                                               "sample_interval_s": 0.05}}},
            "cases": {"flow_re9.4": {"reynolds": 9.4},
                      "cube24_c30_re9.4": {"reynolds": 9.4, "particles": {**cube, "concentration": 0.3}},
                      "cube24_c50_re9.4": {"reynolds": 9.4, "particles": cube,
                                           "unpackable": {"reason": "does not fit", "attempt": str(attempt)}}}}


def test_the_24mm_cubes_at_50_percent_are_declared_unpackable_with_a_committed_failed_attempt():
    assert DECLARED == ["cube24_c50_re26", "cube24_c50_re9.4"]
    for case in DECLARED:
        att = json.loads((ROOT / CONFIG["cases"][case]["unpackable"]["attempt"]).read_text())
        assert att["status"] == "unpackable" and att["concentration_reached"] < 0.5
    assert U.problems(CONFIG, ROOT) == []


def test_a_case_declared_unpackable_has_no_run_at_any_level():
    for level in CONFIG["fidelities"]:
        runs = level_runs(CONFIG, level)
        assert not [r for r in runs if r.split("/")[0] in DECLARED], level
    assert "cube24_c30_re9.4/seed3" in level_runs(CONFIG, "credible")  # its packable neighbour runs


def test_tables_say_unpackable_with_the_concentration_the_attempt_reached(tmp_path):
    config = _tiny_config(_attempt(tmp_path))
    fid = tmp_path / "results" / "lvl"
    aggregate(fid, config["cases"])  # nothing ran: no case directory at all
    av = pd.read_csv(fid / "tables" / "angular_velocity.csv").set_index("case")
    pk = pd.read_csv(fid / "tables" / "packing.csv").set_index("case")
    osum = pd.read_csv(fid / "tables" / "orientation_summary.csv")
    assert av.loc["cube24_c50_re9.4", "status"] == "unpackable"
    assert av.loc["cube24_c30_re9.4", "status"] == "not run"  # undeclared and absent: not run, as before
    assert pk.loc["cube24_c50_re9.4", "status"] == "unpackable"
    assert pk.loc["cube24_c50_re9.4", "concentration_achieved"] == pytest.approx(0.2819)
    assert "does not fit" in pk.loc["cube24_c50_re9.4", "message"]
    assert set(osum.loc[osum["case"] == "cube24_c50_re9.4", "status"]) == {"unpackable"}


def test_a_declaration_whose_attempt_packed_is_a_config_error_and_a_missing_one_is_named(tmp_path):
    config = _tiny_config(_attempt(tmp_path, status="packed", reached=0.5))
    problems = config_problems(config, SCHEMA)
    assert any("cases.cube24_c50_re9.4.unpackable.attempt" in p and "Fix: remove the declaration" in p
               for p in problems), problems
    config = _tiny_config(tmp_path / "nowhere.json")  # a working directory without the packings: allowed
    assert config_problems(config, SCHEMA) == []
    assert "nowhere.json not found" in U.record("cube24_c50_re9.4", config["cases"]["cube24_c50_re9.4"])["message"]
    bad = copy.deepcopy(config)
    del bad["cases"]["cube24_c50_re9.4"]["unpackable"]["reason"]
    assert any("reason" in p for p in config_problems(bad, SCHEMA))


def _snakemake() -> str:
    return shutil.which("snakemake", path=str(Path(sys.executable).parent)) or "snakemake"


def test_new_runs_all_plans_no_job_for_an_unpackable_case():
    """`snakemake -n --config new_runs=all` at the default level: no packing, scene, run, statistics
    or combination job names an unpackable case (the snapshots job draws every case in one job).
    `-F` plans the whole DAG, so the check holds when every other run is already present."""
    run = subprocess.run([_snakemake(), "-n", "-F", "--nolock", "--config", "new_runs=all"], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    out = run.stdout + run.stderr
    wildcards = re.findall(r"^\s*wildcards: (.*)$", out, flags=re.M)
    assert wildcards  # the dry run lists its jobs
    hits = [w for w in wildcards if any(c in w for c in DECLARED) or "packing=cube24_c50" in w]
    assert hits == [], hits


def test_the_committed_tables_and_document_of_the_default_level_say_unpackable():
    level = ROOT / "results" / CONFIG["fidelity"]
    for table in ("angular_velocity", "packing", "orientation_summary"):
        df = pd.read_csv(level / "tables" / f"{table}.csv")
        assert set(df.loc[df["case"].isin(DECLARED), "status"]) == {"unpackable"}, table
    runs = pd.read_csv(level / "tables" / "runtime.csv")["case"].str.split("/").str[0]
    assert not set(runs) & set(DECLARED)  # no run: nothing to time
    doc = (ROOT / "paper" / f"reproduction_{CONFIG['fidelity']}.md").read_text()
    rows = [ln for ln in doc.splitlines() if ln.startswith(tuple(f"| {c} |" for c in DECLARED))]
    assert rows and all("| unpackable |" in ln for ln in rows) and not any("not run" in ln for ln in rows)
