# lbmpipe: regenerate the figures of Ku & Lin from the solver.
#   snakemake -c2                                   every figure at the default fidelity
#   snakemake -c1 results/<fidelity>/cases/<case>/summary.json   one case
import sys

from snakemake.utils import min_version, validate

from pathlib import Path

from lbmpipe.reproduction.cases import CONFIG_SCHEMA, config_problems, level_runs, run_case, split_run
from lbmpipe.reproduction.convergence import write as write_convergence
from lbmpipe.reproduction.methods import comparison_level
from lbmpipe.reproduction.methods import write as write_method_comparison
from lbmpipe.reproduction.robustness import write as write_robustness
from lbmpipe.pipeline_config import config_file_problems
from lbmpipe.reproduction.seeds import write_combined
from lbmpipe.reproduction.statistics import write_case_outputs
from lbmpipe.reproduction import stability as lbm_stability
from lbmpipe.reproduction import study_plan as lbm_study

sys.path.insert(0, str(Path(workflow.basedir) / "workflow" / "rules"))
from common import Pipeline, level_regex, run_present  # noqa: E402  (workflow/rules/common.py)

min_version("8.0")

configfile: "config.yaml"


# One line per problem and exit status 2, before any job: the config files read strictly (Snakemake's
# loader keeps the last of a key given twice), the schema and the levels here, every case's scene
# below (once the schema's defaults are in, through the scenes the rules then use).
_CONFIG_PROBLEMS = (config_file_problems(workflow.configfiles)
                    or config_problems(config, Path(workflow.basedir) / CONFIG_SCHEMA, check=lambda case, level: None))
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


if NEW_RUNS == "all":
    ACTIVE_RUNS = RUNS
else:
    ACTIVE_RUNS = [r for r in RUNS if run_present(FIDELITY, r)]
    if len(ACTIVE_RUNS) < len(RUNS):
        print(f"new_runs={NEW_RUNS}: building {FIDELITY} from the {len(ACTIVE_RUNS)} of {len(RUNS)} runs present; "
              "`--config new_runs=all` runs the others", file=sys.stderr)
ACTIVE_CASES = sorted({split_run(r)[0] for r in ACTIVE_RUNS})
ACTIVE_PARTICLE_CASES = [c for c in ACTIVE_CASES if c in PARTICLE_CASES]

# Input functions, resources and each case's scene (built and validated once, here)
PIPE = Pipeline(config, FIDELITY, NEW_RUNS, RUNS, PARTICLE_CASES, SEEDED_LEVELS)
_CONFIG_PROBLEMS = config_problems(config, Path(workflow.basedir) / CONFIG_SCHEMA, check=PIPE.check)
if _CONFIG_PROBLEMS:
    print("\n".join(_CONFIG_PROBLEMS), file=sys.stderr)
    sys.exit(2)


# a level's name is one path component (results/<level>/...): results/<level>/method/claims.csv is
# the method comparison's, never the claims of a level "<level>/method"
wildcard_constraints:
    fidelity="[^/]+",


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
