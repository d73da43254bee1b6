"""Support points of the shapes in the lab frame and small vector helpers of the contact kernels;
the discretisation of a cap disc and of a rim shared by the contact patch and the walls."""

from __future__ import annotations

import math

from numba import njit

from ..shapes import CYLINDER, SPHERE

DISC_SIDES = 16
RIM_SAMPLES = 32


# ------------------------------------------------------------------------------------------------
# small vector helpers


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _cross_into(a, b, out):
    x = a[1] * b[2] - a[2] * b[1]
    y = a[2] * b[0] - a[0] * b[2]
    z = a[0] * b[1] - a[1] * b[0]
    out[0] = x
    out[1] = y
    out[2] = z


@njit(cache=True, inline="always")
def support3(kind, h, x, R, core, d0, d1, d2):
    """Lab-frame support point of a body along the lab direction (d0, d1, d2), as a tuple.
    ``shapes.support_body`` written out on scalars (same operations, so the same bits; a test
    pins the two together): the GJK loop calls it twice per iteration and must not allocate.
    ``core``: the body is replaced by its centre (a sphere treated as point + margin)."""
    if core:
        return x[0], x[1], x[2]
    b0 = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2
    b1 = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
    b2 = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
    if kind == SPHERE:
        nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        if nb > 0.0:
            s0 = h[0] * b0 / nb
            s1 = h[0] * b1 / nb
            s2 = h[0] * b2 / nb
        else:
            s0 = h[0]
            s1 = 0.0
            s2 = 0.0
    elif kind == CYLINDER:
        r = math.sqrt(b0 * b0 + b1 * b1)
        if r > 0.0:
            s0 = h[0] * b0 / r
            s1 = h[0] * b1 / r
        else:
            s0 = h[0]
            s1 = 0.0
        s2 = h[2] * (1.0 if b2 >= 0.0 else -1.0)
    else:
        s0 = h[0] * (1.0 if b0 >= 0.0 else -1.0)
        s1 = h[1] * (1.0 if b1 >= 0.0 else -1.0)
        s2 = h[2] * (1.0 if b2 >= 0.0 else -1.0)
    return (x[0] + R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * s2,
            x[1] + R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * s2,
            x[2] + R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * s2)


@njit(cache=True)
def _support_lab(kind, h, x, R, core, d, out):
    out[0], out[1], out[2] = support3(kind, h, x, R, core, d[0], d[1], d[2])
