import sys
from pathlib import Path

from lbmpipe.reproduction.health import run_health_table
from lbmpipe.reproduction.statistics import aggregate, runtime_table

sys.stderr = open(snakemake.log[0], "w")
fid_dir = Path(snakemake.output.runtime).parent.parent
aggregate(fid_dir, snakemake.config["cases"])
runtime_table(fid_dir, snakemake.config["cases"])
run_health_table(fid_dir, snakemake.config["cases"], snakemake.config)
