import sys
from pathlib import Path

from lbmpipe.outputs import strict_json, write_json
from lbmpipe.reproduction.study import collect

sys.stdout = sys.stderr = open(snakemake.log[0], "w")
root = Path(snakemake.output.table).parents[2]  # results/
table, cost_runs, model = collect(snakemake.config, snakemake.wildcards.fidelity, root)
table.to_csv(snakemake.output.table, index=False)
cost_runs.to_csv(snakemake.output.runs, index=False)
write_json(snakemake.output.model, model)
print(table[["reference", "knob", "setting", "error", "wall_s"]].to_string())
print(strict_json(model, indent=2))
