"""Matplotlib set up once for every figure of the package: the non-interactive back end, the
style ``lbmpipe/reproduction/lbmpipe.mplstyle`` (package data beside this module), and
:func:`save`, which writes a figure as PDF and PNG reproducibly (no creation date in the PDF)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: The style of every figure of the package (package data beside this module).
STYLE = Path(__file__).with_name("lbmpipe.mplstyle")
plt.style.use(STYLE)


def save(fig, stem: Path) -> list[Path]:
    """Write ``stem``.pdf and ``stem``.png (``stem`` without extension; dots in it are kept)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    out = []
    for ext in ("pdf", "png"):
        path = stem.parent / f"{stem.name}.{ext}"  # not with_suffix: "re9.4" is no suffix
        # no creation date in the PDF: a figure rebuilt from the same results is the same file
        fig.savefig(path, dpi=150, bbox_inches="tight", **({"metadata": {"CreationDate": None}} if ext == "pdf" else {}))
        out.append(path)
    plt.close(fig)
    return out
