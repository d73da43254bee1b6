import sys
from pathlib import Path

import pandas as pd

from lbmpipe.reproduction.claims import systematic_terms, write_claims
from lbmpipe.reproduction.half_window import second_half_verdicts

sys.stderr = open(snakemake.log[0], "w")
method = snakemake.input.get("method")
path = write_claims(Path(snakemake.output[0]).parent, snakemake.config["cases"], Path(method[0]) if method else None,
                   systematic_terms(snakemake.config))
# each verdict from the second half of every run's window, beside the full window's
claims = pd.read_csv(path)
claims["verdict_second_half"] = claims["claim"].map(second_half_verdicts(path.parent, snakemake.config,
                                                                          systematic_terms(snakemake.config)))
claims.to_csv(path, index=False)
