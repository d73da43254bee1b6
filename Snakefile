# lbmpipe: regenerate the figures of Ku & Lin from the solver.
#   snakemake -c2                                   every figure at the default fidelity
#   snakemake -c1 results/<fidelity>/cases/<case>/summary.json   one case
import sys

from snakemake.utils import min_version, validate

from pathlib import Path

from lbmpipe.reproduction.cases import (CONFIG_SCHEMA, case_scene, config_problems, estimate_minutes, level_cases,
                                       level_runs, level_seeds, packing_id, run_case, split_run, write_case_scene)
from lbmpipe.reproduction.convergence import levels as convergence_levels
from lbmpipe.reproduction.convergence import write as write_convergence
from lbmpipe.reproduction.literate import study_level
from lbmpipe.reproduction.methods import comparison_level
from lbmpipe.reproduction.methods import write as write_method_comparison
from lbmpipe.pipeline_config import config_file_problems
from lbmpipe.reproduction.seeds import write_combined
from lbmpipe.reproduction.statistics import write_case_outputs

min_version("8.0")

configfile: "config.yaml"


# One line per problem and exit status 2, before any job: the config files read strictly (Snakemake's
# loader keeps the last of a key given twice), the schema, the level, every case's scene.
_CONFIG_PROBLEMS = (config_file_problems(workflow.configfiles)
                    or config_problems(config, Path(workflow.basedir) / CONFIG_SCHEMA))
if _CONFIG_PROBLEMS:
    print("\n".join(_CONFIG_PROBLEMS), file=sys.stderr)
    sys.exit(2)
validate(config, "workflow/schemas/config.schema.yaml")  # fills the schema's defaults

FIDELITY = config["fidelity"]
if FIDELITY not in config["fidelities"]:
    raise ValueError(f"config fidelity={FIDELITY!r} is not one of {sorted(config['fidelities'])}: "
                     "add it under `fidelities` or pick an existing level")
CASES = sorted(config["cases"])
FLOW_CASES = [c for c in CASES if config["cases"][c].get("particles") is None]
PARTICLE_CASES = [c for c in CASES if c not in FLOW_CASES]
# Simulation runs of the default level: a level with `seeds` runs each particle case once per packing
# seed, in cases/<case>/seed<k>/.
RUNS = level_runs(config, FIDELITY)
# Levels with several packings per case: their cases/<case>/ holds the seeds' combined record.
SEEDED_LEVELS = [f for f, fid in config["fidelities"].items() if "seeds" in fid]
# `new_runs: none` (config.yaml) builds the figures, tables, claims and the document from the runs
# present - the committed ones on a fresh clone - and starts no simulation; `new_runs=all` runs
# every missing one too (a level's production, finished in parts: each run checkpoints and is kept).
NEW_RUNS = config.get("new_runs", "all")


def run_present(level, run):
    return Path(f"results/{level}/cases/{run}/summary.json").exists()


if NEW_RUNS == "all":
    ACTIVE_RUNS = RUNS
else:
    ACTIVE_RUNS = [r for r in RUNS if run_present(FIDELITY, r)]
    if len(ACTIVE_RUNS) < len(RUNS):
        print(f"new_runs={NEW_RUNS}: building {FIDELITY} from the {len(ACTIVE_RUNS)} of {len(RUNS)} runs present; "
              "`--config new_runs=all` runs the others", file=sys.stderr)
ACTIVE_CASES = sorted({split_run(r)[0] for r in ACTIVE_RUNS})
ACTIVE_PARTICLE_CASES = [c for c in ACTIVE_CASES if c in PARTICLE_CASES]


# Inputs the document reads beyond figures and claims (the stability table, the study), as
# patterns of {fidelity}.
PAPER_EXTRA_INPUTS = [
    "results/{fidelity}/tables/stability.csv",
    "results/{fidelity}/study/recommendation.json",
    "results/{fidelity}/study/accuracy_cost.png",
    "results/{fidelity}/study/cost_model.png",
]


def paper_extra_inputs(wildcards):
    # a level with `study_level` shows that level's stability table and study (the same lattice);
    # a level another one compares its method with shows that comparison
    level = study_level(config, wildcards.fidelity)
    extra = [pattern.format(fidelity=level) for pattern in PAPER_EXTRA_INPUTS]
    if comparison_level(config, wildcards.fidelity) is not None:
        extra += [f"results/{wildcards.fidelity}/method/{name}" for name in ("summary.json", "method_comparison.png")]
    if len(convergence_levels(config, wildcards.fidelity)) > 1:
        extra.append(f"results/{wildcards.fidelity}/convergence/summary.json")
    return extra


# a level's name is one path component (results/<level>/...): results/<level>/method/claims.csv is
# the method comparison's, never the claims of a level "<level>/method"
wildcard_constraints:
    fidelity="[^/]+",


include: "workflow/rules/common.smk"
include: "workflow/rules/cases.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/study.smk"
include: "workflow/rules/stability.smk"
include: "workflow/rules/paper.smk"


report: "workflow/report/workflow.rst"


rule all:
    """Every figure, table, the claims and the document at the default fidelity level."""
    input:
        expand("results/{fidelity}/figures/{fig}.{ext}", fidelity=FIDELITY, fig=FIGURES, ext=["pdf", "png"]),
        expand("results/{fidelity}/figures/fig3_{case}.png", fidelity=FIDELITY, case=PARTICLE_CASES),
        expand("results/{fidelity}/tables/{table}.csv", fidelity=FIDELITY, table=TABLES),
        expand("results/{fidelity}/claims.csv", fidelity=FIDELITY),
        expand("paper/reproduction_{fidelity}.{ext}", fidelity=FIDELITY, ext=["md", "html"]),
