import sys
from pathlib import Path

from lbmpipe.figures import velocity_profiles

sys.stderr = open(snakemake.log[0], "w")
profiles = {Path(p).parent.name: p for p in snakemake.input.profiles}
velocity_profiles(profiles, Path(snakemake.output.pdf).with_suffix(""),
                  title=f"particle-free pipe, fidelity {snakemake.wildcards.fidelity}")
