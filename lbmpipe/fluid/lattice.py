"""Discrete velocity sets D3Q15 (the paper's), D3Q19 and D3Q27.

D3Q15 follows the paper exactly: the index order of Table 1 and the weights of Eq. (7)
(``w_0 = 2/9``, ``w_1..6 = 1/9``, ``w_7..14 = 1/72``). Opposite directions of D3Q15 are the
pairs (1,2) (3,4) (5,6) (7,8) (9,10) (11,12) (13,14). D3Q19 and D3Q27 use the ordering
"rest, axis pairs, then diagonal pairs", each direction followed by its opposite, so that
``opp[i] = i + 1`` for odd ``i`` in all three sets.

All quantities are in lattice units: ``dx = dt = 1``, so the lattice speed ``c = 1`` and the
speed of sound squared ``c_s^2 = 1/3`` (paper, after Eq. (6)).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

CS2 = 1.0 / 3.0


@dataclass(frozen=True)
class Lattice:
    """A velocity set: ``e`` (Q, 3) integer velocities, ``w`` (Q,) weights, ``opp`` (Q,)."""

    name: str
    e: np.ndarray
    w: np.ndarray
    opp: np.ndarray

    @property
    def q(self) -> int:
        return len(self.w)

    @property
    def cs2(self) -> float:
        return CS2

    def bytes_per_node(self, itemsize: int = 8) -> int:
        """Minimum memory traffic of one fused stream-collide update: read + write each f_i."""
        return 2 * self.q * itemsize


def _paired(vectors: list[tuple[int, int, int]]) -> list[tuple[int, int, int]]:
    out = [(0, 0, 0)]
    for v in vectors:
        out.append(v)
        out.append((-v[0], -v[1], -v[2]))
    return out


def _build(name: str, e: list[tuple[int, int, int]], w_by_norm: dict[int, float]) -> Lattice:
    e_arr = np.array(e, dtype=np.int64)
    w = np.array([w_by_norm[int(np.sum(np.abs(v)))] for v in e_arr], dtype=np.float64)
    opp = np.array([int(np.flatnonzero((e_arr == -v).all(axis=1))[0]) for v in e_arr])
    return Lattice(name, e_arr, w, opp)


_AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
_EDGES = [(1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1)]
_CORNERS_PAPER = [(1, 1, 1), (-1, 1, 1), (-1, -1, 1), (1, -1, 1)]  # Table 1: 7, 9, 11, 13


@lru_cache(maxsize=None)
def get_lattice(name: str) -> Lattice:
    """Return the velocity set called ``name`` (``D3Q15`` as Table 1 and Eq. (7), ``D3Q19`` or ``D3Q27``)."""
    key = name.upper()
    if key == "D3Q15":
        # Eq. (7) and Table 1.
        return _build("D3Q15", _paired(_AXES + _CORNERS_PAPER), {0: 2 / 9, 1: 1 / 9, 3: 1 / 72})
    if key == "D3Q19":
        return _build("D3Q19", _paired(_AXES + _EDGES), {0: 1 / 3, 1: 1 / 18, 2: 1 / 36})
    if key == "D3Q27":
        return _build(
            "D3Q27", _paired(_AXES + _EDGES + _CORNERS_PAPER), {0: 8 / 27, 1: 2 / 27, 2: 1 / 54, 3: 1 / 216}
        )
    raise ValueError(f"unknown lattice {name!r}: choose one of D3Q15, D3Q19, D3Q27")


LATTICES = ("D3Q15", "D3Q19", "D3Q27")
