"""The repository stands on its own: no tracked file names a path outside it, the paper's reading
is inside it and names only code that exists, and the report captions are valid reStructuredText."""

from __future__ import annotations

import importlib
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Paths that point outside a clone: the sibling directory CI puts beside it, absolute paths of
#: this or another machine (home directories, the work area, temporary directories).
OUTSIDE = re.compile(
    r"\.\./shared\b"                 # the read-only sibling beside the clone in CI
    r"|(?<![\w.~])/work/"            # absolute work-area paths
    r"|(?<![\w.~])/home/\w"          # home directories (Linux)
    r"|(?<![\w.~])/Users/\w"         # home directories (macOS)
    r"|(?<![\w.~])/root/"            # root's home
    r"|(?<![\w.~])/tmp/(?!lbmpipe-)\w"  # a file left in a temporary directory (the local SLURM's
                                     # own state folder, /tmp/lbmpipe-*, is made by the repo's script)
    r"|[A-Za-z]:\\\\Users\\\\"       # Windows home directories
)

#: generated or binary content that may quote anything; each is rebuilt from the tracked sources
SKIP_SUFFIXES = {".png", ".pdf", ".parquet", ".npz", ".gz", ".zip"}


def tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        pytest.skip("not a git checkout")
    return [ROOT / p for p in out.stdout.decode().split("\0") if p]


def outside_references(text: str) -> list[str]:
    """Lines of ``text`` that name a path outside the repository."""
    return [line.strip() for line in text.splitlines() if OUTSIDE.search(line)]


def test_outside_path_pattern_catches_the_ways_a_path_leaves_the_repository():
    leaking = ["see ../shared/paper/NOTES.md", "# /work/shared/paper/NOTES.md", "cache in /home/alice/.cache",
               "open('/Users/bob/x.csv')", "/root/data", "written to /tmp/run1/summary.json",
               r"C:\\Users\\carol\\x"]
    staying = ["paper/reading.md", "~/.cache/lbmpipe/numba", "results/paper/work/x", "a shared machine",
               "https://example.org/home/x", "$NUMBA_CACHE_DIR", "tests/tmp/x", "runs/re9.4",
               "state under /tmp/lbmpipe-slurm"]
    assert all(outside_references(s) for s in leaking)
    assert not any(outside_references(s) for s in staying)


def test_no_tracked_file_names_a_path_outside_the_repository():
    problems = []
    for path in tracked_files():
        if path.suffix in SKIP_SUFFIXES or not path.is_file() or path == Path(__file__).resolve():
            continue  # this file spells the patterns out on purpose
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        problems += [f"{path.relative_to(ROOT)}: {line[:120]}" for line in outside_references(text)]
    assert not problems, "paths outside the repository:\n" + "\n".join(problems)


def test_the_papers_reading_is_in_the_repository_and_linked():
    reading = ROOT / "paper" / "reading.md"
    assert reading.is_file()
    text = reading.read_text()
    for n in range(1, 22):  # every equation of the paper has its row
        assert re.search(rf"^\| \({n}\)|^\| \(\d+\), \({n}\)", text, re.M), f"Eq. ({n}) missing from paper/reading.md"
    assert "(paper/reading.md)" in (ROOT / "README.md").read_text()
    assert "[paper/reading.md]({{ reading_link }})" in (ROOT / "paper" / "reproduction.md.j2").read_text()


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def test_every_code_name_in_the_papers_reading_exists():
    """The reading names the module and function implementing each equation and decision: a
    rename or move in the package must update it."""
    text = (ROOT / "paper" / "reading.md").read_text()
    names = sorted(set(re.findall(r"`(lbmpipe(?:\.\w+)+)`", text)))
    assert len(names) > 20
    missing = [n for n in names if not _resolves(n)]
    assert not missing, f"paper/reading.md names code that does not exist: {missing}"
    files = sorted(set(re.findall(r"`((?:tests|lbmpipe|workflow)/[\w/.]+\.\w+)`", text)))
    assert not [f for f in files if not (ROOT / f).exists()], "paper/reading.md names files that do not exist"


def test_citation_and_licence_are_present():
    import yaml

    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"].startswith("1.2") and cff["title"] and cff["authors"]
    assert any("Lattice Boltzmann simulation of motion and orientation" in r["title"] for r in cff["references"])
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert "CITATION.cff" in (ROOT / "README.md").read_text()


def test_every_relative_link_of_the_committed_documents_resolves():
    """The HTML and Markdown reproductions link code, figures and the reading by relative paths."""
    docs = sorted((ROOT / "paper").glob("reproduction_*.html")) + sorted((ROOT / "paper").glob("reproduction_*.md"))
    if not docs:
        pytest.skip("no document built (lbmpipe document --fidelity LEVEL)")
    broken = []
    for doc in docs:
        text = doc.read_text()
        targets = re.findall(r'(?:href|src)="([^"]+)"', text) + re.findall(r"\]\(([^)\s]+)", text)
        for t in targets:
            path = t.split("#")[0]
            if path and "://" not in path and not (doc.parent / path).exists():
                broken.append(f"{doc.name}: {t}")
    assert not broken, "links to missing files:\n" + "\n".join(broken[:20])
