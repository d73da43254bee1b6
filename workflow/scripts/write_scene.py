import sys

from lbmpipe.cases import write_case_scene

sys.stderr = open(snakemake.log[0], "w")
write_case_scene(snakemake.config, snakemake.wildcards.fidelity, snakemake.wildcards.case, snakemake.output[0],
                 packing_csv=snakemake.input.get("packing"))
