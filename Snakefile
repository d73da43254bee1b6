# lbmpipe: regenerate the figures of Ku & Lin from the solver.
#   snakemake -c2                                   every figure at the default fidelity
#   snakemake -c1 results/<fidelity>/cases/<case>/summary.json   one case
import sys

from snakemake.utils import min_version, validate

from lbmpipe.cases import estimate_minutes, packing_id

min_version("8.0")

configfile: "config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")

FIDELITY = config["fidelity"]
if FIDELITY not in config["fidelities"]:
    raise ValueError(f"config fidelity={FIDELITY!r} is not one of {sorted(config['fidelities'])}: "
                     "add it under `fidelities` or pick an existing level")
CASES = sorted(config["cases"])
FLOW_CASES = [c for c in CASES if config["cases"][c].get("particles") is None]
PARTICLE_CASES = [c for c in CASES if c not in FLOW_CASES]
# The interpreter running snakemake has lbmpipe installed, whether or not its venv is activated.
LBMPIPE = f"{sys.executable} -m lbmpipe"


include: "workflow/rules/cases.smk"
include: "workflow/rules/figures.smk"


rule all:
    input:
        expand("results/{fidelity}/figures/fig10_profiles.{ext}", fidelity=FIDELITY, ext=["pdf", "png"]),
        expand("results/{fidelity}/cases/{case}/summary.json", fidelity=FIDELITY, case=CASES),
