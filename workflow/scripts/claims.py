import json
import sys
from pathlib import Path

import pandas as pd

from lbmpipe.reproduction.claims import write_claims
from lbmpipe.reproduction.half_window import second_half_verdicts
from lbmpipe.reproduction.robustness import add_to_claims, systematic_terms_for

sys.stderr = open(snakemake.log[0], "w")
method = snakemake.input.get("method")
# the systematic term: measured by the robustness controls where the level has them (config.yaml's
# `systematic` values above zero override), else config.yaml's
measured = json.loads(Path(snakemake.input.systematic).read_text()) if snakemake.input.get("systematic") else None
systematic = systematic_terms_for(snakemake.config, measured)
path = write_claims(Path(snakemake.output.claims).parent, snakemake.config["cases"], Path(method[0]) if method else None,
                    systematic)
# each verdict from the second half of every run's window, beside the full window's
claims = pd.read_csv(path)
claims["verdict_second_half"] = claims["claim"].map(second_half_verdicts(path.parent, snakemake.config, systematic))
claims.to_csv(path, index=False)
# the verdicts under the robustness controls (not run / not covered stated) and the robustness table
add_to_claims(path, Path(snakemake.input.controls) if snakemake.input.get("controls") else Path("/nonexistent"),
              Path(snakemake.output.robustness))
