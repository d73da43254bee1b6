import json
import sys
from pathlib import Path

import pandas as pd

from lbmpipe.reproduction.study import report

sys.stdout = sys.stderr = open(snakemake.log[0], "w")
table = pd.read_csv(snakemake.input.table)
cost_runs = pd.read_csv(snakemake.input.runs)
model = json.loads(Path(snakemake.input.model).read_text())
rec = report(snakemake.config, snakemake.wildcards.fidelity, table, cost_runs, model,
             Path(snakemake.output.rec_json).parent)
print(json.dumps(rec, indent=2))
