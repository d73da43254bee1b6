"""The cluster path: ``snakemake --profile workflow/profiles/slurm`` on a real (one-node) SLURM.

The profile is checked against the pinned Snakemake and executor plugin (an option renamed between
versions is caught here). The cluster test (marker ``slurm``) needs the local cluster of
``workflow/profiles/slurm/local-cluster.sh start`` (CI starts it; root only) and is skipped, saying
so, where it is not running. It sends a subset of the smoke DAG through sbatch - two particle
cases, their statistics and their Fig. 3 snapshots, from packings made by a local run - checks
the job records against the resources Snakemake asked for, cancels one simulation mid-run with
``scancel`` and checks that the retry resumed from its checkpoint, and that every output is
bit-identical to the same subset run locally (``snakemake -c2``).
"""
import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "workflow" / "profiles" / "slurm"
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
FIDELITY = "smoke"
# Two cases of different shape and Reynolds number; the second (the longer one) is cancelled.
CASES = ["cyl8x8_c30_re9.4", "cube24_c30_re26"]
CANCELLED = "cube24_c30_re26"
# The local cluster's job records (jobcomp/filetxt; local-cluster.sh).
SLURM_DIR = Path(os.environ.get("LBMPIPE_SLURM_DIR", "/tmp/lbmpipe-slurm"))
# The local cluster has no accounting database: the plugin polls squeue (MinJobAge 600 s there);
# with no account given it fails to guess one and submits without (its --slurm-no-account is
# declared but unused in the pinned 2.8.0).
LOCAL_CLUSTER_ARGS = ["--slurm-status-command", "squeue", "--slurm-init-seconds-before-status-checks", "5",
                      "--slurm-keep-successful-logs"]
# Per-case outputs that must be the same bits whichever executor ran them.
CASE_FILES = ["flow_rate.csv", "profile.csv", "particles.parquet", "particles_static.csv", "stats.json",
              "orientation.csv"]
# summary.json fields that do not depend on wall time.
SUMMARY_KEYS = ["status", "steps", "steps_requested", "simulated_seconds", "fluid_nodes", "mass_drift_rel",
                "samples_averaged", "particles", "density_floor"]


def _locked(name):
    lock = (ROOT / "requirements.lock").read_text()
    m = re.search(rf"^{re.escape(name)}==(\S+)", lock, re.M)
    assert m, f"{name} is not pinned in requirements.lock"
    return m.group(1)


def test_slurm_profile_options_exist_in_the_pinned_snakemake_and_plugin():
    """Every key of the slurm profile is an option of the installed Snakemake (``--key``), every
    ``slurm-*`` key a setting of the installed executor plugin, every ``slurm_*`` resource one the
    plugin reads - and the installed versions are the ones requirements.lock pins."""
    for pkg in ("snakemake", "snakemake-executor-plugin-slurm", "snakemake-executor-plugin-slurm-jobstep"):
        assert version(pkg) == _locked(pkg), f"{pkg} {version(pkg)} installed, the lock pins {_locked(pkg)}"
    from snakemake.cli import get_argument_parser
    import snakemake_executor_plugin_slurm as plugin

    options = {s for a in get_argument_parser()._actions for s in a.option_strings}
    settings = {f.name for f in dataclasses.fields(plugin.ExecutorSettings)}
    profile = yaml.safe_load((PROFILE / "config.yaml").read_text())
    assert profile["executor"] == "slurm"
    for key in profile:
        assert f"--{key}" in options, f"profile key {key!r}: Snakemake {version('snakemake')} has no --{key}"
        if key.startswith("slurm-"):
            assert key[len("slurm-"):].replace("-", "_") in settings, f"profile key {key!r} is not a plugin setting"
    plugin_source = "".join(p.read_text() for p in Path(plugin.__file__).parent.glob("*.py"))
    resources = dict(profile.get("default-resources") or {})
    for per_rule in (profile.get("set-resources") or {}).values():
        resources.update(per_rule)
    resources.update(dict.fromkeys(LOCAL_RESOURCE_HINTS))
    for name in resources:
        if name.startswith("slurm_"):
            assert f'"{name}"' in plugin_source, f"resource {name!r} is not read by the slurm plugin"
    for arg in LOCAL_CLUSTER_ARGS[::2]:
        if arg.startswith("--slurm-"):
            assert arg in options, f"{arg} (used for the local cluster) is not an option of the pinned plugin"


# The resources the profile's comments tell a user to set.
LOCAL_RESOURCE_HINTS = re.findall(r"#\s*(slurm_\w+):", (PROFILE / "config.yaml").read_text())


def _local_cluster_reason():
    """None if the local cluster of local-cluster.sh answers with an idle node, else why not."""
    if shutil.which("sinfo") is None:
        return "SLURM is not installed (as root: bash workflow/profiles/slurm/local-cluster.sh start)"
    try:
        conf = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        return "slurmctld does not answer"
    if conf.returncode != 0:
        return ("no SLURM controller answers: start the local one as root with "
                "bash workflow/profiles/slurm/local-cluster.sh start")
    if not re.search(r"^ClusterName\s*=\s*lbmpipe\s*$", conf.stdout, re.M):
        return "the SLURM answering is not the local test cluster of local-cluster.sh (no jobs sent to it)"
    states = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True).stdout.split()
    if not {"idle", "mixed"} & set(states):
        return f"the local cluster's node is not idle ({states})"
    return None


def _workdir(tmp: Path, name: str) -> Path:
    """A copy of the workflow whose config holds the two cases at the smoke level."""
    d = tmp / name
    d.mkdir()
    shutil.copy(ROOT / "Snakefile", d)
    for sub in ("workflow", "profiles"):
        if (ROOT / sub).exists():
            shutil.copytree(ROOT / sub, d / sub, ignore=shutil.ignore_patterns("__pycache__"))
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["fidelity"] = FIDELITY
    config["new_runs"] = "all"
    config["cases"] = {c: config["cases"][c] for c in CASES}
    (d / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return d


def _targets():
    return ([f"results/{FIDELITY}/cases/{c}/stats.json" for c in CASES]
            + [f"results/{FIDELITY}/figures/fig3_{c}.png" for c in CASES])


def _jobcomp():
    """{job id: record} from the local cluster's job completion log."""
    records = {}
    path = SLURM_DIR / "jobcomp.log"
    for line in path.read_text().splitlines() if path.exists() else []:
        rec = dict(re.findall(r"(\w+)=(\S*)", line))
        records[rec["JobId"]] = rec
    return records


def _submissions(log: str):
    """[(rule, wildcards, resources, slurm job id)] from the main Snakemake log, in order: each
    submission with the job block Snakemake printed last for that job (a retry prints a new one)."""
    blocks, out = {}, []
    # a job block: "rule NAME:" and its indented lines
    event = re.compile(r"^(?:local)?rule (\w+):((?:\n[ \t]+.*)*)|Job (\d+) has been submitted with SLURM jobid (\d+)",
                       re.M)
    for m in event.finditer(log):
        if m.group(1):
            body = m.group(2)
            jobid = re.search(r"^\s+jobid: (\d+)", body, re.M)
            if jobid is None:
                continue
            wc = re.search(r"^\s+wildcards: (.*)$", body, re.M)
            res = re.search(r"^\s+resources: (.*)$", body, re.M)
            resources = dict(kv.split("=", 1) for kv in res.group(1).split(", ")) if res else {}
            threads = re.search(r"^\s+threads: (\d+)", body, re.M)
            resources["threads"] = threads.group(1) if threads else "1"
            blocks[jobid.group(1)] = (m.group(1), wc.group(1) if wc else "", resources)
        else:
            out.append((*blocks[m.group(3)], m.group(4)))
    return out


def _solver_running(slurm_job: str) -> bool:
    """Whether the simulation of this SLURM job is in its time loop: the solver catches SIGTERM
    there (lbmpipe.solver._Interrupt), so the process's caught-signal mask has bit 15."""
    for proc in Path("/proc").iterdir():
        try:
            if not proc.name.isdigit() or b"simulate_case.py" not in (proc / "cmdline").read_bytes():
                continue
            if f"SLURM_JOB_ID={slurm_job}".encode() not in (proc / "environ").read_bytes().split(b"\0"):
                continue
            caught = re.search(r"^SigCgt:\s*([0-9a-f]+)", (proc / "status").read_text(), re.M)
        except OSError:
            continue
        if caught and int(caught.group(1), 16) >> 14 & 1:
            return True
    return False


def _queue():
    """{slurm job id: (comment, state)} of this cluster's queue (finished jobs included)."""
    out = subprocess.run(["squeue", "--states=all", "--noheader", "--format=%i|%k|%T"],
                         capture_output=True, text=True).stdout
    return {line.split("|")[0]: tuple(line.split("|")[1:]) for line in out.splitlines()}


@pytest.mark.slurm
def test_smoke_subset_through_sbatch_matches_the_local_run_and_a_cancelled_case_resumes(tmp_path):
    reason = _local_cluster_reason()
    if reason and os.environ.get("LBMPIPE_REQUIRE_SLURM"):
        pytest.fail(f"LBMPIPE_REQUIRE_SLURM is set but {reason}")
    if reason:
        pytest.skip(reason)
    env = dict(os.environ, NUMBA_NUM_THREADS="1")

    # The reference: the subset on this machine with Snakemake's local executor.
    local = _workdir(tmp_path, "local")
    run = subprocess.run(SNAKEMAKE + ["-c2", *_targets()], cwd=local, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-3000:]

    # The same subset through sbatch, from the same packings (a packing's outcome is budgeted in
    # wall time, so it is made once).
    cluster = _workdir(tmp_path, "slurm")
    shutil.copytree(local / "results" / "packings", cluster / "results" / "packings")
    before = set(_jobcomp())
    cmd = SNAKEMAKE + ["--profile", str(PROFILE), *LOCAL_CLUSTER_ARGS, *_targets()]
    log_path = tmp_path / "slurm_snakemake.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, cwd=cluster, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
        # Cancel the long case once its solver is in the time loop (it then finishes the sample
        # interval it is in, writes its checkpoint and exits; the retry resumes from it). The
        # local run put the kernels in numba's cache, so the first interval does not compile
        # them and ends well within the cluster's KillWait.
        cancelled = target = None
        deadline = time.time() + 1800
        while proc.poll() is None and time.time() < deadline:
            if cancelled is None and target is None:
                target = next((jid for jid, (com, state) in _queue().items()
                               if com.startswith("rule_simulate_particles") and com.endswith(CANCELLED)
                               and state == "RUNNING"), None)
            if cancelled is None and target is not None and _solver_running(target):
                subprocess.run(["scancel", target], check=True)
                cancelled = target
            # a smoke case's time loop lasts seconds: watch its process closely once it runs
            time.sleep(0.02 if target is not None and cancelled is None else 0.5)
        if proc.poll() is None:
            proc.kill()
    log = log_path.read_text()
    assert proc.returncode == 0, log[-4000:]
    assert cancelled is not None, f"the {CANCELLED} job was never seen in its time loop"

    # Every job that is not a local rule went through sbatch, with the resources Snakemake asked
    # for: the time limit in minutes (runtime), the memory (mem_mb), the CPUs (threads).
    subs = _submissions(log)
    records = {k: v for k, v in _jobcomp().items() if k not in before}
    assert sorted(r for r, *_ in subs) == sorted(["simulate_particles"] * 3 + ["snapshots"]), subs
    rows = []
    for rule, wc, res, jid in subs:
        rec = records[jid]
        tres = dict(kv.split("=") for kv in rec["Tres"].split(","))
        assert int(rec["TimeLimit"]) == int(res["runtime"]), (rule, wc, rec)
        assert tres["mem"] == f"{res['mem_mb']}M", (rule, wc, rec)
        assert int(tres["cpu"]) == int(res["threads"]), (rule, wc, rec)
        rows.append((jid, rule, wc, rec["JobState"], res["runtime"], res["mem_mb"], rec["StartTime"], rec["EndTime"]))
    states = {jid: rec["JobState"] for jid, rec in records.items()}
    assert states.pop(cancelled) == "CANCELLED"
    assert set(states.values()) == {"COMPLETED"}, states
    print("\nslurm job records (id, rule, wildcards, state, runtime min, mem_mb, start, end):")
    for row in rows:
        print("  ", *row)

    # The cancelled case resumed from the checkpoint its solver wrote at SIGTERM ...
    summary = json.loads((cluster / f"results/{FIDELITY}/cases/{CANCELLED}/summary.json").read_text())
    resumed = summary["checkpoint"]["resumed_from_step"]
    assert resumed is not None and 0 < resumed < summary["steps"], summary["checkpoint"]
    print(f"{CANCELLED}: job {cancelled} cancelled, resumed from step {resumed} of {summary['steps']}")
    # ... and every output is the local run's, bit for bit.
    for case in CASES:
        a, b = local / f"results/{FIDELITY}/cases/{case}", cluster / f"results/{FIDELITY}/cases/{case}"
        for name in CASE_FILES:
            assert (a / name).read_bytes() == (b / name).read_bytes(), f"{case}/{name} differs from the local run"
        sa, sb = json.loads((a / "summary.json").read_text()), json.loads((b / "summary.json").read_text())
        assert {k: sa.get(k) for k in SUMMARY_KEYS} == {k: sb.get(k) for k in SUMMARY_KEYS}, case
    for case in CASES:
        png = f"results/{FIDELITY}/figures/fig3_{case}.png"
        assert (local / png).read_bytes() == (cluster / png).read_bytes(), f"{png} differs from the local run"
