import sys
from pathlib import Path

from lbmpipe.reproduction.snapshots import snapshots

sys.stderr = open(snakemake.log[0], "w")
cases = {c: cfg for c, cfg in snakemake.config["cases"].items() if cfg.get("particles") is not None}
seeded = "seeds" in snakemake.config["fidelities"][snakemake.wildcards.fidelity]
snapshots(Path(snakemake.output[0]).parent.parent, cases, fidelity=snakemake.wildcards.fidelity,
          run="seed1" if seeded else "")
