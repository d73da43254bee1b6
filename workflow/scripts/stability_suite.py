"""Snakemake script of rule stability_table: the stability suite at the fidelity's size."""
import sys
from pathlib import Path

from lbmpipe.reproduction import stability

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)
fid = snakemake.wildcards.fidelity
settings = stability.fidelity_settings(snakemake.config, fid)
print(f"stability suite at fidelity {fid}: {settings}")
work = Path(snakemake.output.table).parent.parent / "stability_work"
df = stability.run_suite(settings, Path(snakemake.output.table), work_dir=work, threads=snakemake.threads)
print(df.attrs.get("recommendation", ""))
