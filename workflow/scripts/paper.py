import sys
from pathlib import Path

from lbmpipe.reproduction.literate import build_checked_document

sys.stderr = open(snakemake.log[0], "w")
out, stale = build_checked_document(Path.cwd(), snakemake.wildcards.fidelity, snakemake.config,
                                    Path(snakemake.output.md))
if stale:
    sys.exit("stale code links in the document:\n" + "\n".join(stale))
