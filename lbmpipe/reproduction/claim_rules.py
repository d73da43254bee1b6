"""The machinery of the claims (:mod:`lbmpipe.reproduction.claims`, whose docstring states the
rules): a comparison (:class:`Cmp`) and a claim's outcome (:class:`Outcome`), the inputs of one level
with case lookup by physical description (:class:`Inputs`), the ordering rule with its pooled
interval (:func:`ordering_verdict`, :mod:`lbmpipe.reproduction.pooling`) and the reasons from the
cases' measured diagnostics (:func:`case_diagnoses`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from . import health, pooling
from .unpackable import read_summary

AXES = ("x", "y", "z")
#: the systematic error per observable (``config.yaml`` ``systematic``), zero until measured
SYSTEMATIC_KEYS = ("omega_rel", "angle_deg", "fraction_abs", "profile_rel_l2")

@dataclass
class Cmp:
    """One comparison ``a - b`` (claimed > 0) with its 95 % interval ``[lo, hi]``; ``keys`` the
    ``(case, observable)`` values it is made of and ``fn`` its ``d`` from a getter of them (both
    for :func:`lbmpipe.reproduction.pooling.pooled`), ``sys`` its systematic half-width."""

    label: str
    a: float
    ca: float
    b: float
    cb: float
    d: float
    lo: float
    hi: float
    cases: tuple[str, ...] = ()
    keys: tuple = ()
    fn: Callable | None = None
    sys: float = 0.0

    @property
    def sign(self) -> int:
        return 1 if self.lo > 0 else -1 if self.hi < 0 else 0

    def sign_with(self, s: float) -> int:
        """The sign with the interval widened by ``s`` on each side."""
        return 1 if self.lo - s > 0 else -1 if self.hi + s < 0 else 0


def diff(label: str, a: float, ca: float, b: float, cb: float, cases=(), keys=None, sys: float = 0.0) -> Cmp:
    """``a - b`` with the half-width ``sqrt(ca^2 + cb^2)``; ``keys = (key_a, key_b)`` (each ``(case,
    observable)``) makes it poolable with its dependence."""
    d = a - b
    h = math.sqrt(ca * ca + cb * cb)
    fn = None
    if keys is not None:
        ka, kb = keys
        fn = lambda g: g(*ka) - g(*kb)  # noqa: E731
    return Cmp(label, a, ca, b, cb, d, d - h, d + h, tuple(cases), tuple(keys or ()), fn, sys)


@dataclass
class Outcome:
    statistic: str
    values: str = ""
    verdict: str = "inconclusive"
    reason: str = ""
    cases: list[str] = field(default_factory=list)
    carried: str = ""
    deciding: str = ""
    #: the verdict with the systematic term (None: as ``verdict``)
    verdict_sys: str | None = None


def _f(x: float) -> str:
    if x is None or not np.isfinite(x):
        return "nan"
    return f"{x:.3g}"


def _pm(v: float, c: float) -> str:
    return f"{_f(v)} ± {_f(c)}"


# --------------------------------------------------------------------------------------------------
# inputs


def find_case(cases: dict, shape: str, size: tuple, concentration: float, reynolds: float,
              collisions: bool = True) -> str | None:
    """Config name of the case of ``cases`` with this description (size: (d, l) mm for a cylinder,
    (edge,) for a cube), or None."""
    for name, c in cases.items():
        p = (c or {}).get("particles") or {}
        if p.get("shape") != shape or not math.isclose(float(c["reynolds"]), reynolds):
            continue
        if not math.isclose(float(p.get("concentration", -1)), concentration):
            continue
        if bool(c.get("collisions", True)) != collisions:
            continue
        got = (float(p["diameter_mm"]), float(p["length_mm"])) if shape == "cylinder" else (float(p["edge_mm"]),)
        if all(math.isclose(g, float(s)) for g, s in zip(got, size)) and len(got) == len(size):
            return name
    return None


class Inputs:
    """The tables of one level, and case lookup by physical description."""

    def __init__(self, fid_dir: Path, config_cases: dict, systematic: dict | None = None,
                 exclude: dict[str, str] | None = None):
        self.fid_dir = Path(fid_dir)
        self.cases = config_cases or {}
        self.systematic = {k: float((systematic or {}).get(k, 0.0)) for k in SYSTEMATIC_KEYS}
        #: cases left out of this evaluation: name -> why (their flags)
        self.exclude = dict(exclude or {})
        self.av = self._read("tables/angular_velocity.csv")
        self.osum = self._read("tables/orientation_summary.csv")
        self.orient = self._read("tables/orientation.csv")
        self.replicates = pooling.Replicates(self.fid_dir, self._table_value)

    def without(self, flags: tuple[str, ...]) -> "Inputs":
        """The same inputs with every case flagged with one of ``flags`` left out."""
        out = {}
        for name in self.cases:
            got = [f for f in self.flags(name) if f in flags]
            if got:
                out[name] = ", ".join(got)
        return Inputs(self.fid_dir, self.cases, self.systematic, out)

    def flags(self, name: str) -> list[str]:
        """The flags of a case's ``stats.json`` (frozen, locked, unhealthy, not steady)."""
        s = health.read_json(self.fid_dir / "cases" / name / "stats.json") or {}
        return list(s.get("flags") or health.case_flags(s))

    def _table_value(self, name: str, obs: tuple) -> tuple[float, float]:
        """The table's (mean, 95 % half-width) of a case's observable (``pooling`` observables)."""
        if obs[0] == "omega":
            w, _ = self.omega(name)
            return w[obs[1]] if w else (float("nan"), float("nan"))
        a, _ = self.angle(name, obs[1])
        return a if a else (float("nan"), float("nan"))

    def sys_omega(self, value: float) -> float:
        """Systematic half-width of a mean |Omega|."""
        return self.systematic["omega_rel"] * abs(value)

    def _left_out(self, name: str | None) -> str | None:
        return f"{name}: left out ({self.exclude[name]})" if name in self.exclude else None

    def _read(self, rel: str) -> pd.DataFrame | None:
        try:
            return pd.read_csv(self.fid_dir / rel)
        except (FileNotFoundError, pd.errors.EmptyDataError):
            return None

    def find(self, shape: str, size: tuple, concentration: float, reynolds: float, collisions: bool = True) -> str | None:
        """Config name of the case with this description (:func:`find_case`)."""
        return find_case(self.cases, shape, size, concentration, reynolds, collisions)

    def _status_reason(self, name: str, status: str) -> str:
        s = read_summary(self.fid_dir / "cases" / name, self.cases.get(name)) or {}
        if status == "unpackable":
            reached = (s.get("packing") or {}).get("concentration_reached")
            if reached is None:
                reached = (s.get("particles") or {}).get("concentration_achieved")
            return f"{name}: not packable" + (f" (highest concentration reached {100 * float(reached):.3g} %)"
                                              if reached is not None else "")
        if status == "not run":
            return f"{name}: not run"
        msg = s.get("message") or ""
        return f"{name}: status {status}" + (f" ({msg})" if msg else "")

    def _row(self, table: pd.DataFrame | None, table_name: str, name: str | None, desc: str,
             kind: str | None = None) -> tuple[pd.Series | None, str | None]:
        if name is None:
            return None, f"no case {desc} in config.yaml"
        if self._left_out(name):
            return None, self._left_out(name)
        if table is None:
            return None, f"{table_name} missing"
        rows = table[table["case"] == name]
        if kind is not None and len(rows):
            rows = rows[rows["kind"] == kind]
        if not len(rows):
            return None, f"{name}: not in {table_name} (not run)"
        r = rows.iloc[0]
        status = str(r.get("status", "completed"))
        if status != "completed" and status != "nan":
            return None, self._status_reason(name, status)
        return r, None

    def omega(self, name: str | None, desc: str = "") -> tuple[dict | None, str | None]:
        """{axis: (mean, ci)} of a case, or the reason it is not available."""
        r, why = self._row(self.av, "tables/angular_velocity.csv", name, desc)
        if r is None:
            return None, why
        out = {a: (float(r[f"omega_{a}"]), float(r[f"ci_{a}"])) for a in AXES}
        if not all(np.isfinite(v) and np.isfinite(c) for v, c in out.values()):
            return None, f"{name}: no angular-velocity statistics (NaN)"
        return out, None

    def angle(self, name: str | None, kind: str, desc: str = "") -> tuple[tuple[float, float] | None, str | None]:
        """(mean angle, ci) in degrees of a case and orientation kind, or the reason it is not available."""
        r, why = self._row(self.osum, "tables/orientation_summary.csv", name, desc, kind)
        if r is None:
            return None, why
        v, c = float(r["mean_deg"]), float(r["ci95_deg"])
        if not np.isfinite(v):
            return None, f"{name}: no orientation statistics for {kind} (NaN)"
        if not np.isfinite(c):
            # one packing averaged for less than two batches of the orientation's own correlation
            # time has a mean but no interval (the run's stats.json says how long it would need)
            return None, f"{name}: mean {kind} {v:.1f} deg without an interval (averaged too short for its correlation time)"
        return (v, c), None

    def has_angle_row(self, name: str | None, kind: str) -> bool:
        """Whether the case ran: a completed row of ``kind`` in the orientation summary, with or without
        an interval (what tells :meth:`angle`'s "not run" from "without an interval")."""
        return self._row(self.osum, "tables/orientation_summary.csv", name, "", kind)[0] is not None

    def histogram(self, name: str | None, kind: str, desc: str = "") -> tuple[pd.DataFrame | None, str | None]:
        r, why = self._row(self.orient, "tables/orientation.csv", name, desc, kind)
        if r is None:
            return None, why
        h = self.orient[(self.orient["case"] == name) & (self.orient["kind"] == kind)].sort_values("bin_lo_deg")
        if not np.isfinite(h["fraction"]).all() or not np.isfinite(h["ci95"]).all():
            return None, f"{name}: orientation histogram {kind} has NaN"
        return h, None

    def profile(self, name: str) -> tuple[pd.DataFrame | None, str | None]:
        if name not in self.cases:
            return None, f"no case {name} in config.yaml"
        if self._left_out(name):
            return None, self._left_out(name)
        path = self.fid_dir / "cases" / name / "profile.csv"
        s = read_summary(self.fid_dir / "cases" / name, self.cases.get(name))
        if s is not None and s.get("status") != "completed":
            return None, self._status_reason(name, str(s.get("status")))
        try:
            df = pd.read_csv(path)
        except (FileNotFoundError, pd.errors.EmptyDataError):
            return None, f"{name}: cases/{name}/profile.csv missing (not run)"
        df = df.dropna(subset=["r_mm", "uz_m_s"])
        if not len(df):
            return None, f"{name}: profile.csv is empty"
        return df, None


def _desc(shape, size, c, re_, coll=True) -> str:
    s = f"cylinder {size[0]:g}x{size[1]:g} mm" if shape == "cylinder" else f"cube {size[0]:g} mm"
    return f"({s}, {round(100 * c)} %, Re {re_:g}" + ("" if coll else ", no collisions") + ")"


# --------------------------------------------------------------------------------------------------
# verdict rules


def _ordering_rule(D: float, H: float, signs: list[int]) -> str:
    """reproduced / contradicted / inconclusive from the pooled interval ``D ± H`` and the signs of
    the single comparisons (module docstring)."""
    pos, neg = sum(x > 0 for x in signs), sum(x < 0 for x in signs)
    if D - H > 0 and neg == 0:
        return "reproduced"
    if D + H < 0 and pos == 0:
        return "contradicted"
    return "inconclusive"


def ordering_verdict(cmps: list[Cmp], missing: list[str], inputs: Inputs, unit: str = "rad/s") -> Outcome:
    """Pool the comparisons of an ordering claim with their dependence and decide (rules in the
    module docstring); the same with the systematic term beside it."""
    out = Outcome(statistic="")
    note_missing = ("; missing: " + "; ".join(missing)) if missing else ""
    if not cmps:
        out.values = "no comparison available"
        out.reason = "inputs missing: " + ("; ".join(missing) if missing else "no case of the claim in config.yaml")
        out.carried = "no comparison"
        return out
    n = len(cmps)
    pool = pooling.pooled(cmps, inputs.replicates)
    D, H = pool.D, pool.H
    pos = sum(c.sign > 0 for c in cmps)
    neg = sum(c.sign < 0 for c in cmps)
    parts = [f"pooled D = {_pm(D, H)} {unit} over {n} comparison(s) ({pool.text()}), {pos} significantly in the "
             f"claimed direction, {neg} significantly reversed"]
    parts += [f"{c.label}: {_pm(c.a, c.ca)} vs {_pm(c.b, c.cb)} (d = {_f(c.d)} [{_f(c.lo)}, {_f(c.hi)}])" for c in cmps]
    out.values = "; ".join(parts)
    out.cases = sorted({k for c in cmps for k in c.cases})
    out.carried = f"{pos} of {n} significant in the claimed direction, {neg} reversed"
    out.verdict = _ordering_rule(D, H, [c.sign for c in cmps])
    S = float(np.mean([c.sys for c in cmps]))
    out.verdict_sys = _ordering_rule(D, H + S, [c.sign_with(c.sys) for c in cmps])
    if n == 1:
        c = cmps[0]
        out.deciding = f"d = {_f(c.d)} [{_f(c.lo)}, {_f(c.hi)}] {unit} ({c.label})"
    else:
        out.deciding = f"pooled D = {_pm(D, H)} {unit}"
        if out.verdict == "inconclusive" and pos and neg:
            worst = min(cmps, key=lambda c: c.hi)
            out.deciding += f"; reversed: {worst.label} d = {_f(worst.d)} [{_f(worst.lo)}, {_f(worst.hi)}]"
    if out.verdict == "reproduced":
        out.reason = f"the pooled 95 % interval excludes 0 in the claimed direction and no comparison is reversed{note_missing}"
    elif out.verdict == "contradicted":
        out.reason = "the opposite ordering holds significantly; diagnosed: " + diagnosed_reason(inputs, out.cases) + note_missing
    else:
        why = ("mixed: some comparisons significant each way" if pos and neg else
               "the 95 % intervals overlap (difference not significant)")
        out.reason = why + note_missing
    return out


def case_diagnoses(inputs: Inputs, name: str) -> list[str]:
    """What the measured diagnostics of one case's ``stats.json`` say about it
    (:mod:`lbmpipe.reproduction.health`): frozen, locked, unhealthy, not steady, intervals too short
    (with the duration needed), and its resolution in lattice spacings as a fact. Each item names
    the case."""
    s = health.read_json(inputs.fid_dir / "cases" / name / "stats.json") or {}
    if not health.health_is_computed(s):
        return [f"{name}: diagnostics {health.NOT_COMPUTED}"]
    out = []
    fr = s.get("frozen") or {}
    if fr.get("frozen"):
        out.append(f"{name}: frozen (orientation correlation with the packing {_f(fr.get('remaining'))} left at the "
                   f"end > {_f(fr.get('threshold'))})")
    lk = s.get("locked") or {}
    if lk.get("locked"):
        why = ("a column: two bodies cannot sit side by side in the pipe" if lk.get("column") else
               f"no pair passed, {_f(lk.get('neighbours_retained'))} of the nearest neighbours kept")
        out.append(f"{name}: locked ({why})")
    issues = (s.get("health") or {}).get("issues") or []
    if issues:
        out.append(f"{name}: unhealthy ({'; '.join(issues)})")
    spin = s.get("spinup") or {}
    if spin and not spin.get("steady", True):
        out.append(f"{name}: not steady ({spin.get('message') or 'halves of the window disagree'})")
    short = [(a, r) for a, r in (s.get("omega_intervals") or {}).items() if not r.get("sufficient")]
    if short:
        need = max(float(r.get("required_s") or 0.0) for _, r in short)
        have = max(float(r.get("duration_s") or 0.0) for _, r in short)
        out.append(f"{name}: interval too short for |Omega_{','.join(a for a, _ in short)}| ({_f(have)} s averaged, "
                   f"{_f(need)} s needed for 20 batches of 5 tau_int)")
    res = (s.get("resolution") or {}).get("lattice_spacings")
    if res is not None and np.isfinite(res):
        out.append(f"{name}: smallest particle dimension {_f(res)} lattice spacings")
    return out


def diagnosed_reason(inputs: Inputs, cases: list[str]) -> str:
    """The reason of a verdict from the measured diagnostics of its own cases (:func:`case_diagnoses`);
    when none flags a case, a genuine difference from the paper (or the unstated statistic)."""
    bits = [d for name in cases for d in case_diagnoses(inputs, name)]
    flagged = [d for d in bits if "lattice spacings" not in d]
    if not flagged:
        bits.append("no diagnostic flags these cases: a genuine difference from the paper, or a difference in "
                    "the unstated statistic")
    return "; ".join(bits)
