# Functions the rules use (Snakemake's lint wants them apart from the rules).
import functools
import json

from lbmpipe.reproduction import stability as lbm_stability
from lbmpipe.reproduction import study as lbm_study


def _packing_input(wildcards):
    pid = packing_id(run_case(config, wildcards.case)[1])
    return {} if pid is None else {"packing": f"results/packings/{pid}.csv"}


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
    return {"case_summary": f"results/{wildcards.fidelity}/cases/{case}/summary.json",
            "case_particles": f"results/{wildcards.fidelity}/cases/{case}/particles.parquet"}


def _study_threads(wildcards):
    return int(lbm_study.study_settings(config, wildcards.fidelity)["threads"])
