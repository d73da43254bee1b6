"""The narrow phase's scratch buffer: its layout (``_WS_*``), allocation and views."""

from __future__ import annotations

import numpy as np
from numba import njit

from .support import DISC_SIDES

_PATCH_POINTS = 2 * DISC_SIDES + 4 * DISC_SIDES * DISC_SIDES // 4 + 8  # vertices in + edge crossings


# layout of the scratch buffer (``new_scratch``): offsets of GJK's simplex W, its support points
# WA, WB (4 x 3 each), the barycentric weights (4), the witness points pa, pb, the search
# direction v, the witness midpoint (3 each), then the contact patch (``_manifold_point``): the
# two features and the body-frame points (DISC_SIDES x 3 each), the two plane polygons
# (DISC_SIDES x 2 each), -n, the plane basis t1, t2 (3 each), the patch point (2) and the patch
# points (_PATCH_POINTS x 2); last the exact cylinder path's candidate to try first and the one that
# won (``body_contact_ws``)
_WS_W = 0
_WS_WA = _WS_W + 12
_WS_WB = _WS_WA + 12
_WS_LAM = _WS_WB + 12
_WS_PA = _WS_LAM + 4
_WS_PB = _WS_PA + 3
_WS_V = _WS_PB + 3
_WS_BASE = _WS_V + 3
_WS_F1 = _WS_BASE + 3
_WS_F2 = _WS_F1 + 3 * DISC_SIDES
_WS_FB = _WS_F2 + 3 * DISC_SIDES
_WS_P1 = _WS_FB + 3 * DISC_SIDES
_WS_P2 = _WS_P1 + 2 * DISC_SIDES
_WS_MNEG = _WS_P2 + 2 * DISC_SIDES
_WS_T1 = _WS_MNEG + 3
_WS_T2 = _WS_T1 + 3
_WS_UV = _WS_T2 + 3
_WS_PTS = _WS_UV + 2
WS_HINT = _WS_PTS + 2 * _PATCH_POINTS
WS_WON = WS_HINT + 1
WS_SIZE = WS_WON + 1


@njit(cache=True)
def new_scratch(extra=0):
    """Scratch memory of ``body_contact_ws`` and ``bodies_overlap_ws`` (layout: ``_WS_*``). One
    per thread: the narrow phase runs ~10^3 times per step and must not allocate. One buffer,
    not a tuple of arrays: a function call takes a reference on every array it is passed, and
    for the 18 arrays of a tuple that cost more than most cylinder contacts (0.4 us of 1 us);
    views are made only where a path needs them. ``extra``: more room after ``WS_SIZE``, for a
    caller's own scratch in the same buffer."""
    ws = np.empty(WS_SIZE + extra)
    ws[WS_HINT] = -1.0
    return ws


@njit(cache=True, inline="always")
def ws_rows(ws, off, rows, cols):
    # a (rows, cols) view of the scratch buffer at offset off
    return ws[off:off + rows * cols].reshape((rows, cols))


@njit(cache=True, inline="always")
def _gjk_scratch(ws):
    """GJK's and EPA's working arrays in the scratch buffer (``new_scratch``): simplex W and its
    support points WA, WB, barycentric weights, witness points, search direction."""
    return (ws_rows(ws, _WS_W, 4, 3), ws_rows(ws, _WS_WA, 4, 3), ws_rows(ws, _WS_WB, 4, 3),
            ws[_WS_LAM:_WS_LAM + 4], ws[_WS_PA:_WS_PA + 3], ws[_WS_PB:_WS_PB + 3], ws[_WS_V:_WS_V + 3])
