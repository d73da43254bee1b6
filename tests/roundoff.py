"""Equality of results to round-off: what the same code writes on another processor (its BLAS and
NumPy SIMD kernels may round the last bits differently); any other difference is a change."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd


def same_to_round_off(a, b, where: str, rtol: float = 1e-9):
    """``a`` and ``b`` (parsed JSON) equal, numbers to ``rtol``: another processor's BLAS and NumPy
    SIMD kernels may round the last bits differently, any other difference is a change of the statistics."""
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), f"{where}: keys {sorted(set(a) ^ set(b))} differ"
        for k in a:
            same_to_round_off(a[k], b[k], f"{where}.{k}", rtol)
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), f"{where}: lengths {len(a)} and {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            same_to_round_off(x, y, f"{where}[{i}]", rtol)
    elif isinstance(a, float) and isinstance(b, (int, float)) and not isinstance(b, bool):
        assert (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=rtol, abs_tol=1e-15), \
            f"{where}: {a!r} against {b!r}"
    else:
        assert a == b, f"{where}: {a!r} against {b!r}"


def same_file_to_round_off(new: Path, old: Path) -> None:
    """A CSV or JSON file equal to another to round-off: floats to relative 1e-9; integers, strings,
    keys, columns and shape exactly."""
    if Path(old).suffix == ".json":
        same_to_round_off(json.loads(Path(new).read_text()), json.loads(Path(old).read_text()), str(old))
    else:
        pd.testing.assert_frame_equal(pd.read_csv(new), pd.read_csv(old), check_exact=False, rtol=1e-9, atol=1e-15,
                                      obj=str(old))
