import sys
from pathlib import Path

from lbmpipe.literate import build_document, check_links

sys.stderr = open(snakemake.log[0], "w")
fid = snakemake.wildcards.fidelity
out = build_document(Path.cwd(), Path("results") / fid, fid, snakemake.config, Path(snakemake.output.md))
stale = check_links(out, Path.cwd())
if stale:
    sys.exit("stale code links in the document:\n" + "\n".join(stale))
