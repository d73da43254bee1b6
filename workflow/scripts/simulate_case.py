import sys
from pathlib import Path

from lbmpipe.reproduction.cases import simulate_case

sys.stdout = sys.stderr = open(snakemake.log[0], "w")
summary = simulate_case(snakemake.input.scene, snakemake.input.get("packing_info"),
                        Path(snakemake.output.summary).parent, snakemake.threads,
                        checkpoint=snakemake.params.get("checkpoint"),
                        production=bool(snakemake.config["fidelities"][snakemake.wildcards.fidelity].get("production")),
                        allow_dirty=bool(snakemake.config.get("allow_dirty", False)))
print(f"{snakemake.wildcards.case}: {summary['status']} {summary.get('message', '')}")
if summary["status"] not in snakemake.params.accept:
    sys.exit(f"case {snakemake.wildcards.case} ended with status {summary['status']}: {summary.get('message', '')}")
