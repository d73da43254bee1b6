import sys
from pathlib import Path

from lbmpipe.reproduction.figures import snapshots

sys.stderr = open(snakemake.log[0], "w")
cases = {c: cfg for c, cfg in snakemake.config["cases"].items() if cfg.get("particles") is not None}
snapshots(Path(snakemake.output[0]).parent.parent, cases, fidelity=snakemake.wildcards.fidelity)
