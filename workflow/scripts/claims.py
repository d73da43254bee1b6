import sys
from pathlib import Path

from lbmpipe.reproduction.claims import systematic_terms, write_claims

sys.stderr = open(snakemake.log[0], "w")
method = snakemake.input.get("method")
write_claims(Path(snakemake.output[0]).parent, snakemake.config["cases"], Path(method[0]) if method else None,
             systematic_terms(snakemake.config))
