"""CI check: the Snakemake report renders every caption without a docutils message.

    python workflow/scripts/check_report.py REPORT.html

Snakemake renders each caption (``workflow/report/*.rst``) with Jinja2 and then docutils; a
reStructuredText problem (``|Omega|`` read as an undefined substitution, a malformed table) does
not stop the report but leaves a "System Message" block or a "problematic" span in the HTML. This
lists them and exits 1 if there is any.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

#: what docutils leaves in rendered HTML where it met a problem (HTML or JSON-escaped HTML)
MARKERS = re.compile(r"System Message: \w+/\d|class=\\?\"problematic\\?\"")


def docutils_problems(html: str, context: int = 80) -> list[str]:
    """Each place in ``html`` where docutils reported a problem, with some text around it."""
    return [html[max(0, m.start() - context):m.end() + context].replace("\n", " ") for m in MARKERS.finditer(html)]


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    path = Path(argv[0])
    problems = docutils_problems(path.read_text(encoding="utf-8", errors="replace"))
    for p in problems:
        print(f"{path}: docutils problem: ...{p}...", file=sys.stderr)
    if not problems:
        print(f"{path}: every caption rendered without a docutils message")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
