"""Intervals of the bin fractions of an orientation histogram (Figs. 8-9, claim 11).

A histogram's per-bin 95 % half-widths (``orientation.csv``: batch means within a run, the
packings' scatter when seeds are combined) are symmetric and can exceed the fraction itself
(``0.53 ± 1.62`` for a case locked in two bins) or vanish in an empty bin (``0 ± 0``): neither is an
interval of a fraction. Here each bin gets the **Wilson score interval** of its fraction on the
case's *effective sample size*: the number of independent samples a binomial fraction would need
for the measured uncertainty, ``n_eff = f (1 - f) / se^2`` with ``se = ci95 / 1.96``, taken as the
median over the case's occupied bins (``0 < f < 1`` with a positive half-width), so that an empty
bin borrows the case's sample size instead of claiming certainty. The interval lies in ``[0, 1]``,
is asymmetric near 0 and 1, and has width ``~ z^2 / (n_eff + z^2)`` in an empty bin (Wilson 1927,
J. Am. Stat. Assoc. 22, 209; Brown, Cai & DasGupta 2001, Stat. Sci. 16, 101: it keeps its coverage
at small ``n`` and near 0 and 1 where the symmetric interval fails).
"""

from __future__ import annotations

import numpy as np

Z95 = 1.959963984540054


def effective_samples(fraction, ci95) -> float:
    """``n_eff`` of one histogram: the median over its bins with ``0 < f < 1`` and a positive
    finite half-width of ``f (1 - f) / (ci95 / 1.96)^2``; NaN when no bin has one."""
    f = np.asarray(fraction, dtype=float)
    c = np.asarray(ci95, dtype=float)
    ok = np.isfinite(f) & np.isfinite(c) & (f > 0) & (f < 1) & (c > 0)
    if not ok.any():
        return float("nan")
    return float(np.median(f[ok] * (1 - f[ok]) / (c[ok] / Z95) ** 2))


def wilson(fraction, n_eff: float, z: float = Z95) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval ``(lo, hi)`` of each fraction at ``n_eff`` samples and normal
    quantile ``z`` (1.96: 95 %); NaN where ``n_eff`` is not a positive number."""
    f = np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)
    if not (np.isfinite(n_eff) and n_eff > 0):
        nan = np.full(f.shape, np.nan)
        return nan, nan.copy()
    z2n = z * z / n_eff
    centre = (f + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * np.sqrt(f * (1 - f) / n_eff + z2n / (4 * n_eff))
    return np.clip(centre - half, 0.0, 1.0), np.clip(centre + half, 0.0, 1.0)


def histogram_interval(fraction, ci95, z: float = Z95) -> tuple[np.ndarray, np.ndarray, float]:
    """``(lo, hi, n_eff)`` of one case's histogram: :func:`wilson` on :func:`effective_samples`."""
    n = effective_samples(fraction, ci95)
    lo, hi = wilson(fraction, n, z)
    return lo, hi, n
