import sys
from pathlib import Path

from lbmpipe.reproduction import runcost
from lbmpipe.reproduction.cases import level_runs
from lbmpipe.reproduction.health import run_health_table
from lbmpipe.reproduction.statistics import aggregate, runtime_table

sys.stderr = open(snakemake.log[0], "w")
fid_dir = Path(snakemake.output.runtime).parent.parent
# run time and run health per simulation run (each seed of a case in a level with several packings)
runs = level_runs(snakemake.config, snakemake.wildcards.fidelity)
aggregate(fid_dir, snakemake.config["cases"])
runtime_table(fid_dir, runs)
run_health_table(fid_dir, runs, snakemake.config)
# wall-time cost model fitted to this level's runs, each run predicted with its family held out
runcost.write(fid_dir, runs, snakemake.wildcards.fidelity, snakemake.output.cost_model,
              fid_dir / "tables" / "cost_validation.csv")
