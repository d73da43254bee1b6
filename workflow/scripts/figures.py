import sys
from pathlib import Path

from lbmpipe.reproduction.figures import make_figures

sys.stderr = open(snakemake.log[0], "w")
fid_dir = Path(snakemake.output.pdf[0]).parent.parent
make_figures(fid_dir, snakemake.wildcards.fidelity, snakemake.config["cases"])
