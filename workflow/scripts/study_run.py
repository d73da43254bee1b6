from pathlib import Path

from lbmpipe.reproduction.study_plan import run_timed

run_timed(snakemake.input.scene, Path(snakemake.output.summary).parent, snakemake.threads, snakemake.log[0],
          snakemake.output.process)
