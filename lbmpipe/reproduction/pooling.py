"""A claim's comparisons pooled with their dependence: the runs and packings they share.

A claim pools its comparisons ``d_c`` (``claims.Cmp``) into their mean ``D``. The comparisons are
not independent: the three axes of one case pair come from the same runs, one case enters several
pairs, and the Re 9.4 and Re 26 runs of a shape (and the runs with and without collisions) start
from the same packings (``cases.packing_id``). ``sqrt(sum h_c^2) / n`` treats them as independent
and understates the half-width of ``D``. Here the interval of ``D`` is computed from the runs
themselves, the way :func:`lbmpipe.reproduction.steady.combine_seeds` combines the packings of one
case:

- **between packings**: a bootstrap that resamples whole packings of every case at once. Each of
  :data:`DRAWS` draws picks ``n`` packing seeds with replacement, the same seeds for every case
  (packing seed ``k`` is one packing of a shape at both Reynolds numbers and with collisions off,
  so the cases that share it move together); every case's mean over its drawn runs, every
  comparison and ``D`` are recomputed. The bootstrap standard deviation of ``D`` times
  ``sqrt(n / (n - 1))`` (the bootstrap's ``(n - 1) / n`` shrinkage of the variance of a mean)
  times Student's ``t_{n-1}`` is the method of independent replications applied to ``D``: for a
  linear ``D`` exactly ``t_{n-1} S_D / sqrt(n)``, ``S_D`` the scatter of ``D`` between packings.
  ``n``: the fewest completed packings of a case that has several. A case missing a drawn seed
  takes the seed at the same place of its own list (the draws are uniform numbers mapped onto
  each case's seeds);
- **within runs**: each run's mean drawn normal with its own standard error (its 95 % half-width
  over ``t`` at its degrees of freedom), every case's mean over its runs, ``D``; 1.96 standard
  deviations. A floor, as in ``combine_seeds``: packings that agree by chance must not give an
  interval narrower than the runs' own noise.

The half-width is the larger of the two. The draws are seeded (:data:`SEED`), so the same results
give the same interval. A case with one run (a level with one packing per case, or a table
without the runs' records) has no between part: its interval is the table's, as a within-run one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from . import health

#: seed of the draws (a fixed number: the intervals are reproducible)
SEED = 46
#: bootstrap and within-run draws per pooled interval
DRAWS = 4000
_Z = 1.959963984540054


def t_quantile(dof: float, confidence: float = 0.95) -> float:
    """Two-sided Student quantile at ``dof`` degrees of freedom (the normal one without a finite dof)."""
    if dof is None or not np.isfinite(dof) or dof <= 0:
        return _Z
    from scipy.stats import t

    return float(t.ppf(0.5 + confidence / 2, dof))


@dataclass(frozen=True)
class RunValue:
    """One run's (packing ``seed``'s) mean of an observable and its within-run standard error."""

    seed: int
    mean: float
    se: float


def _record_value(stats: dict, obs: tuple) -> tuple[float, float, float] | None:
    """(mean, 95 % half-width, dof) of observable ``obs`` in a run's ``stats.json``:
    ``("omega", axis)`` mean |Omega| about the axis, ``("angle", kind)`` the mean orientation angle."""
    kind, key = obs
    if kind == "omega":
        m = (stats.get("mean_abs_omega_rad_s") or {}).get(key)
        c = (stats.get("ci95_rad_s") or {}).get(key)
        dof = ((stats.get("omega_intervals") or {}).get(key) or {}).get("dof")
    elif kind == "angle":
        o = (stats.get("orientation") or {}).get(key) or {}
        m, c, dof = o.get("mean_deg"), o.get("ci95_deg"), (o.get("interval") or {}).get("dof")
    else:
        raise ValueError(f"unknown observable {obs!r}: ('omega', axis) or ('angle', kind)")
    if not health.finite(m):
        return None
    return float(m), health._num(c), health._num(dof)


class Replicates:
    """The runs behind each case's value: per case and observable, one :class:`RunValue` per
    completed packing (``cases/<case>/seed<k>/stats.json``, the seeds the case's combined
    ``stats.json`` lists as completed), or the table's value and half-width as one run when the
    runs' records are absent or do not average to the table's value.

    ``table(case, obs)`` gives the table's ``(mean, 95 % half-width)``."""

    def __init__(self, fid_dir: Path, table: Callable[[str, tuple], tuple[float, float]]):
        self.fid_dir = Path(fid_dir)
        self.table = table
        self._cache: dict = {}

    def runs(self, case: str, obs: tuple) -> list[RunValue]:
        key = (case, obs)
        if key not in self._cache:
            self._cache[key] = self._read(case, obs)
        return self._cache[key]

    def _read(self, case: str, obs: tuple) -> list[RunValue]:
        mean, ci = self.table(case, obs)
        cdir = self.fid_dir / "cases" / case
        combined = health.read_json(cdir / "stats.json") or {}
        seeds = [int(x["seed"]) for x in combined.get("seeds") or []
                 if isinstance(x, dict) and x.get("status") == "completed" and x.get("seed") is not None]
        runs = []
        for k in seeds:
            v = _record_value(health.read_json(cdir / f"seed{k}" / "stats.json") or {}, obs)
            if v is None:
                runs = []
                break
            m, c, dof = v
            runs.append(RunValue(k, m, c / t_quantile(dof) if np.isfinite(c) else float("nan")))
        if runs and math.isclose(float(np.mean([r.mean for r in runs])), mean, rel_tol=1e-6, abs_tol=1e-12):
            return sorted(runs, key=lambda r: r.seed)
        return [RunValue(0, float(mean), float(ci) / _Z if np.isfinite(ci) else float("nan"))]


@dataclass
class Pooled:
    """The pooled difference ``D``, its 95 % half-width ``H`` (the larger of ``between`` and
    ``within``), the packings per case it rests on and which part decided."""

    D: float
    H: float
    between: float
    within: float
    packings: int
    branch: str

    def text(self) -> str:
        if self.branch == "independent":
            return "comparisons taken as independent (no run records)"
        if self.packings >= 2:
            return (f"shared runs and packings pooled: bootstrap over {self.packings} packings {_short(self.between)}, "
                    f"within-run {_short(self.within)}; {self.branch} decides")
        return f"one run per case: within-run noise of the shared runs {_short(self.within)}"


def _short(x: float) -> str:
    return f"±{x:.3g}" if np.isfinite(x) else "–"


def pooled(cmps: list, reps: Replicates) -> Pooled:
    """The mean ``D`` of the comparisons ``cmps`` (each with ``d``, ``keys``: the ``(case,
    observable)`` values it uses, and ``fn``: ``d`` from a getter ``g(case, obs)`` of values,
    vectorised over draws) and its 95 % half-width with their dependence (module docstring).
    Comparisons without ``fn`` fall back to ``sqrt(sum h^2) / n``."""
    n = len(cmps)
    D = float(np.mean([c.d for c in cmps]))
    if any(getattr(c, "fn", None) is None for c in cmps):
        H = math.sqrt(sum(((c.hi - c.lo) / 2) ** 2 for c in cmps)) / n
        return Pooled(D, H, float("nan"), H, 1, "independent")
    keys = sorted({k for c in cmps for k in c.keys}, key=lambda k: (k[0], k[1][0], str(k[1][1])))
    runs = {k: reps.runs(*k) for k in keys}
    rng = np.random.default_rng(SEED)
    n_max = max(len(r) for r in runs.values())

    # between packings: whole packings resampled, the same draws for every case
    u = rng.random((DRAWS, n_max))
    boot = {}
    for k, rr in runs.items():
        m = np.array([r.mean for r in rr])
        idx = np.minimum((u[:, :len(rr)] * len(rr)).astype(int), len(rr) - 1)
        boot[k] = m[idx].mean(axis=1)
    several = [len(rr) for rr in runs.values() if len(rr) >= 2]
    between = float("nan")
    if several:
        p = min(several)
        d_boot = np.mean([c.fn(lambda case, obs: boot[(case, obs)]) for c in cmps], axis=0)
        between = t_quantile(p - 1) * math.sqrt(p / (p - 1)) * float(np.std(d_boot, ddof=1))

    # within runs: each run's mean drawn with its own standard error
    noisy = {}
    for k, rr in runs.items():
        m = np.array([r.mean for r in rr])
        se = np.array([r.se if np.isfinite(r.se) else 0.0 for r in rr])
        noisy[k] = (m + se * rng.standard_normal((DRAWS, len(rr)))).mean(axis=1)
    d_w = np.mean([c.fn(lambda case, obs: noisy[(case, obs)]) for c in cmps], axis=0)
    within = _Z * float(np.std(d_w, ddof=1))
    if np.isfinite(between) and between >= within:
        return Pooled(D, between, between, within, min(several), "between-packing")
    return Pooled(D, within, between, within, min(several) if several else 1, "within-run")
