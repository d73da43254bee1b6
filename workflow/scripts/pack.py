import sys

from lbmpipe.reproduction.cases import pack_case

sys.stderr = open(snakemake.log[0], "w")
info = pack_case(snakemake.config, snakemake.wildcards.packing, snakemake.output.csv, snakemake.output.info)
print(f"packing {snakemake.wildcards.packing}: {info['status']}", file=sys.stderr)
