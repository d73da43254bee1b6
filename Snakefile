# lbmpipe: regenerate the figures of Ku & Lin from the solver.
#   snakemake -c2                                   every figure at the default fidelity
#   snakemake -c1 results/<fidelity>/cases/<case>/summary.json   one case
import sys

from snakemake.utils import min_version, validate

min_version("8.0")

configfile: "config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")

FIDELITY = config["fidelity"]
if FIDELITY not in config["fidelities"]:
    raise ValueError(f"config fidelity={FIDELITY!r} is not one of {sorted(config['fidelities'])}: "
                     "add it under `fidelities` or pick an existing level")
CASES = sorted(config["cases"])
# The interpreter running snakemake has lbmpipe installed, whether or not its venv is activated.
LBMPIPE = f"{sys.executable} -m lbmpipe"


include: "workflow/rules/cases.smk"
include: "workflow/rules/figures.smk"


rule all:
    input:
        expand("results/{fidelity}/figures/fig10_profiles.{ext}", fidelity=FIDELITY, ext=["pdf", "png"]),
