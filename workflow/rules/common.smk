# Functions the rules use (Snakemake's lint wants them apart from the rules).
import functools
import json
import re

from lbmpipe.reproduction import stability as lbm_stability
from lbmpipe.reproduction import study_plan as lbm_study


def _packing_input(wildcards):
    pid = packing_id(run_case(config, wildcards.case)[1])
    return {} if pid is None else {"packing": ancient(f"results/packings/{pid}.csv")}


def _packing_info(wildcards):
    return f"results/packings/{packing_id(run_case(config, wildcards.case)[1])}.json"


def _scene_settings(wildcards):
    # The case's scene as a param: an edit of config.yaml that changes it (a level's dx, dt or
    # duration, a case's particles) reruns that case under Snakemake's params rerun trigger, and
    # only the cases it changes.
    fid = config["fidelities"][wildcards.fidelity]
    scene = case_scene(*run_case(config, wildcards.case), wildcards.fidelity, fid)
    return json.dumps(scene, sort_keys=True)


def _threads(wildcards):
    return int(config["fidelities"][wildcards.fidelity].get("threads", 2))


@functools.cache
def _estimate(fidelity, case):
    return estimate_minutes(config, fidelity, case)


def _runtime(wildcards):
    return _estimate(wildcards.fidelity, wildcards.case)


# Minutes a simulation job spends before its first step: the job's Snakemake, the imports and the
# kernels (loaded from numba's cache, or compiled: about a minute cold). The cost estimate covers
# the steps only; a smoke case's estimate is 1 minute, which on the local test cluster ran out
# before the first step.
STARTUP_MINUTES = 2


def _time_limit(wildcards, attempt):
    # The cluster's time limit (`runtime`, minutes): the estimate plus the start-up; a retry (after
    # a time-limit kill, resuming from the checkpoint) gets twice as long.
    return (_estimate(wildcards.fidelity, wildcards.case) + STARTUP_MINUTES) * attempt


def _packing_priority(wildcards):
    # The longest case waiting for this packing (at the default level): priorities on the
    # simulations alone did not reach their packings, and the paper level's two longest cases
    # (13 min each) waited 18 min for theirs.
    return max((_estimate(FIDELITY, r) for r in RUNS if packing_id(run_case(config, r)[1]) == wildcards.packing),
               default=1)


def _study_run_dirs(wildcards):
    return expand("results/{fidelity}/study/runs/{run}", fidelity=wildcards.fidelity,
                  run=lbm_study.run_ids(config, wildcards.fidelity))


def _study_case_inputs(wildcards):
    # The averaging-time reference reads one particle case of this level; it is an input so that
    # the study waits for it. Other levels and the other cases are read if present, not required.
    case = lbm_study.study_settings(config, wildcards.fidelity)["averaging"]["case"]
    if case not in config["cases"]:
        return {}
    # ancient, and the case's trajectory (particles.parquet) read if present, not declared: the
    # committed study is regenerated on a fresh clone without rerunning the case (cases.smk)
    return {"case_summary": ancient(f"results/{wildcards.fidelity}/cases/{case}/summary.json"),
            "case_stats": ancient(f"results/{wildcards.fidelity}/cases/{case}/stats.json")}


def _study_threads(wildcards):
    return int(lbm_study.study_settings(config, wildcards.fidelity)["threads"])


def _seed_files(name):
    # The seeds' files a case's combined record reads (lbmpipe.reproduction.seeds).
    def files(wildcards):
        runs = [f"{wildcards.case}/seed{k}" for k in level_seeds(config["fidelities"][wildcards.fidelity])]
        if NEW_RUNS != "all":  # the seeds present (Snakefile)
            runs = [r for r in runs if run_present(wildcards.fidelity, r)]
        return [f"results/{wildcards.fidelity}/cases/{r}/{name}" for r in runs]
    return files


def _level_regex(levels):
    # a wildcard constraint matching exactly these fidelity levels (none: matches nothing)
    return "|".join(re.escape(x) for x in levels) if levels else "(?!)"


def _snapshot_files(name):
    # The run each snapshot (Fig. 3) draws: the case's, or its first seed's in a seeded level.
    def files(wildcards):
        sub = "/seed1" if wildcards.fidelity in SEEDED_LEVELS else ""
        # under new_runs=none the runs whose last frame is here or can be made from their trajectory
        # (a snapshot drawn from a trajectory no longer here is kept as it is)
        def drawable(d):
            return any(Path(d, f).exists() for f in ("last_frame.csv", "particles.parquet"))

        ran = set(level_cases(config, wildcards.fidelity))  # a level may run a subset of the cases
        return [f"results/{wildcards.fidelity}/cases/{c}{sub}/{name}" for c in PARTICLE_CASES
                if c in ran and (NEW_RUNS == "all" or drawable(f"results/{wildcards.fidelity}/cases/{c}{sub}"))]
    return files
