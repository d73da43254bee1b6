import os
import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w")
import numba  # noqa: E402

numba.set_num_threads(max(1, min(int(snakemake.threads), numba.config.NUMBA_NUM_THREADS)))
from lbmpipe.reproduction.study_plan import warm_up  # noqa: E402

print(warm_up(snakemake.config, snakemake.wildcards.fidelity, snakemake.output[0]), os.getpid())
