"""The paper's 14 claims (paper/reading.md), each a statistic computed from the results tables of one
fidelity level, with a verdict.

Inputs under ``results/<fid>/``: ``tables/angular_velocity.csv`` (mean |Omega_a| per case with its
95 % half-width), ``tables/orientation_summary.csv`` (mean orientation angle per case and kind with
its 95 % half-width), ``tables/orientation.csv`` (histograms with per-bin 95 % half-widths) and
``cases/<case>/profile.csv``. Cases are found by their config entry (shape, size, concentration,
Reynolds number, collisions), never by parsing names.

Statistics. Most claims are orderings ``a > b`` between two cases; each such comparison gives the
difference ``d = a - b`` with the 95 % half-width ``sqrt(ci_a^2 + ci_b^2)`` (independent runs).
A claim that covers several comparisons (several axes, sizes, concentrations or Reynolds numbers)
pools them: the mean difference ``D`` with half-width ``sqrt(sum ci_d^2) / n``.

Verdicts (ordering claims):

- ``reproduced``: the pooled interval lies above 0 and no single comparison is significantly
  reversed;
- ``contradicted``: the pooled interval lies below 0 and no single comparison significantly
  supports the claim;
- ``inconclusive``: otherwise (overlapping intervals, mixed significant results, or inputs
  missing: the reason names the cases that are not packable or not run).

Claims of *no effect* (11, 12) are equivalence tests against a stated margin, and claim 13
(profile "changed greatly") compares a distance with the particle-free discretisation error;
their rules are in their ``statistic`` text.

Reasons. A contradiction's reason is built from the measured diagnostics of the claim's own cases
(:func:`case_diagnoses`: frozen, locked, unhealthy, not steady, interval too short with the
duration needed, resolution in lattice spacings), each naming its case; any other verdict lists
the flagged cases it rests on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from . import health

AXES = ("x", "y", "z")
COLUMNS = ["claim", "statement", "statistic", "values", "verdict", "reason"]

STATEMENTS = {
    1: "Cylinders rotate more about the axial-plane axes (x, y) than about the pipe axis z.",
    2: "A larger cylinder-to-pipe size ratio lowers rotation about all axes.",
    3: "A larger cylinder aspect ratio (16x16 -> 16x24) lowers rotation.",
    4: "All rotations of cubes fall from 30 % to 50 % concentration.",
    5: "At 50 % the three cube angular velocities are closer to each other than at 30 %.",
    6: "Cubes rotate faster at Re 26 than at Re 9.4.",
    7: "Cubes rotate faster than cylinders of the same size.",
    8: "For the same shape, larger particles rotate more slowly.",
    9: "Cylinders with a higher aspect ratio align more with the flow.",
    10: "Cylinders align with the flow more at the lower Reynolds number.",
    11: "Cube orientations spread over 0-45 degrees with no significant preference.",
    12: "Reynolds number has no obvious effect on cube orientation.",
    13: "Particles change the velocity profile greatly from the particle-free parabola.",
    14: "Particles that interact (collide) align with the flow less than those that do not.",
}

CONCENTRATIONS = (0.30, 0.50)
REYNOLDS = (9.4, 26.0)
#: claim 12: largest mean-angle change (deg) still "no obvious effect": 10 % of the 0-45 deg range
CUBE_RE_MARGIN_DEG = 4.5
#: claim 11: a bin "prefers" when its fraction is off uniform by more than this share of uniform
CUBE_UNIFORM_TOLERANCE = 0.5
#: claim 13: "greatly" = relative L2 change at least this, and this many times the particle-free error
PROFILE_CHANGE_MIN = 0.10
PROFILE_NOISE_FACTOR = 3.0
#: the pair of claim 13 and of claim 14 (config names, paper/reading.md)
PROFILE_CASE, PROFILE_REFERENCE = "cyl16x16_c30_re26", "flow_re26"
ALIGN_CASE, ALIGN_NOCOLL_CASE = "cyl8x16_c30_re9.4", "cyl8x16_c30_re9.4_nocoll"


@dataclass
class Cmp:
    """One comparison ``a - b`` (claimed > 0) with its 95 % interval ``[lo, hi]``."""

    label: str
    a: float
    ca: float
    b: float
    cb: float
    d: float
    lo: float
    hi: float
    cases: tuple[str, ...] = ()

    @property
    def sign(self) -> int:
        return 1 if self.lo > 0 else -1 if self.hi < 0 else 0


def diff(label: str, a: float, ca: float, b: float, cb: float, cases=()) -> Cmp:
    d = a - b
    h = math.sqrt(ca * ca + cb * cb)
    return Cmp(label, a, ca, b, cb, d, d - h, d + h, tuple(cases))


@dataclass
class Outcome:
    statistic: str
    values: str = ""
    verdict: str = "inconclusive"
    reason: str = ""
    cases: list[str] = field(default_factory=list)


def _f(x: float) -> str:
    if x is None or not np.isfinite(x):
        return "nan"
    return f"{x:.3g}"


def _pm(v: float, c: float) -> str:
    return f"{_f(v)} ± {_f(c)}"


# --------------------------------------------------------------------------------------------------
# inputs


class Inputs:
    """The tables of one level, and case lookup by physical description."""

    def __init__(self, fid_dir: Path, config_cases: dict):
        self.fid_dir = Path(fid_dir)
        self.cases = config_cases or {}
        self.av = self._read("tables/angular_velocity.csv")
        self.osum = self._read("tables/orientation_summary.csv")
        self.orient = self._read("tables/orientation.csv")

    def _read(self, rel: str) -> pd.DataFrame | None:
        try:
            return pd.read_csv(self.fid_dir / rel)
        except (FileNotFoundError, pd.errors.EmptyDataError):
            return None

    def find(self, shape: str, size: tuple, concentration: float, reynolds: float, collisions: bool = True) -> str | None:
        """Config name of the case with this description (size: (d, l) mm for a cylinder, (edge,) for a cube)."""
        for name, c in self.cases.items():
            p = c.get("particles") or {}
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

    def _status_reason(self, name: str, status: str) -> str:
        s = health.read_json(self.fid_dir / "cases" / name / "summary.json") or {}
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
        path = self.fid_dir / "cases" / name / "profile.csv"
        s = health.read_json(self.fid_dir / "cases" / name / "summary.json")
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


def ordering_verdict(cmps: list[Cmp], missing: list[str], inputs: Inputs, unit: str = "rad/s") -> Outcome:
    """Pool the comparisons of an ordering claim and decide (rules in the module docstring)."""
    out = Outcome(statistic="")
    note_missing = ("; missing: " + "; ".join(missing)) if missing else ""
    if not cmps:
        out.values = "no comparison available"
        out.reason = "inputs missing: " + ("; ".join(missing) if missing else "no case of the claim in config.yaml")
        return out
    n = len(cmps)
    D = float(np.mean([c.d for c in cmps]))
    H = math.sqrt(sum(((c.hi - c.lo) / 2) ** 2 for c in cmps)) / n
    pos = sum(c.sign > 0 for c in cmps)
    neg = sum(c.sign < 0 for c in cmps)
    parts = [f"pooled D = {_pm(D, H)} {unit} over {n} comparison(s), {pos} significantly in the claimed "
             f"direction, {neg} significantly reversed"]
    parts += [f"{c.label}: {_pm(c.a, c.ca)} vs {_pm(c.b, c.cb)} (d = {_f(c.d)} [{_f(c.lo)}, {_f(c.hi)}])" for c in cmps]
    out.values = "; ".join(parts)
    out.cases = sorted({k for c in cmps for k in c.cases})
    if D - H > 0 and neg == 0:
        out.verdict = "reproduced"
        out.reason = f"the pooled 95 % interval excludes 0 in the claimed direction and no comparison is reversed{note_missing}"
    elif D + H < 0 and pos == 0:
        out.verdict = "contradicted"
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


# --------------------------------------------------------------------------------------------------
# the claims


CYL = {"8x8": (8, 8), "8x16": (8, 16), "16x16": (16, 16), "16x24": (16, 24)}
CUBE = {"8": (8,), "16": (16,), "24": (24,)}


def _omega_pairs(inp: Inputs, pairs, axes=AXES, combine=None) -> tuple[list[Cmp], list[str]]:
    """Comparisons of angular velocity between case descriptions ``(desc_a, desc_b)`` (a claimed
    larger), one per axis; ``combine`` maps the per-axis dict to a single (value, ci) instead."""
    cmps, missing = [], []
    for da, db in pairs:
        na, nb = inp.find(*da), inp.find(*db)
        wa, why_a = inp.omega(na, _desc(*da))
        wb, why_b = inp.omega(nb, _desc(*db))
        for why in (why_a, why_b):
            if why and why not in missing:
                missing.append(why)
        if wa is None or wb is None:
            continue
        if combine is not None:
            (a, ca), (b, cb) = combine(wa), combine(wb)
            cmps.append(diff(f"{na} vs {nb}", a, ca, b, cb, (na, nb)))
        else:
            for ax in axes:
                cmps.append(diff(f"{na} vs {nb} [{ax}]", *wa[ax], *wb[ax], (na, nb)))
    return cmps, missing


def claim1(inp: Inputs) -> Outcome:
    cmps, missing = [], []
    for size in CYL.values():
        for c in CONCENTRATIONS:
            for re_ in REYNOLDS:
                desc = ("cylinder", size, c, re_)
                name = inp.find(*desc)
                w, why = inp.omega(name, _desc(*desc))
                if w is None:
                    if why not in missing:
                        missing.append(why)
                    continue
                a = (w["x"][0] + w["y"][0]) / 2
                ca = math.sqrt(w["x"][1] ** 2 + w["y"][1] ** 2) / 2
                cmps.append(diff(f"{name} (x+y)/2 vs z", a, ca, *w["z"], (name,)))
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = ("per cylinder case (all sizes, 30/50 %, Re 9.4/26): d = (|Ωx| + |Ωy|)/2 - |Ωz|, "
                     "half-width sqrt(ci_x² + ci_y²)/2 ⊕ ci_z; pooled over the cases")
    return out


def claim2(inp: Inputs) -> Outcome:
    pairs = [(("cylinder", CYL[s], c, r), ("cylinder", CYL[l], c, r))
             for s, l in (("8x8", "16x16"), ("8x16", "16x24")) for c in CONCENTRATIONS for r in REYNOLDS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = ("d = |Ω_a|(smaller cylinder) - |Ω_a|(larger) for a in x, y, z, pairs 8x8 -> 16x16 (same "
                     "aspect ratio) and 8x16 -> 16x24 (larger in both dimensions), each concentration and Re; pooled")
    return out


def claim3(inp: Inputs) -> Outcome:
    pairs = [(("cylinder", CYL["16x16"], c, r), ("cylinder", CYL["16x24"], c, r))
             for c in CONCENTRATIONS for r in REYNOLDS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = "d = |Ω_a|(16x16) - |Ω_a|(16x24) for a in x, y, z, each concentration and Re; pooled"
    return out


def claim4(inp: Inputs) -> Outcome:
    pairs = [(("cube", e, 0.30, r), ("cube", e, 0.50, r)) for e in CUBE.values() for r in REYNOLDS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = "d = |Ω_a|(30 %) - |Ω_a|(50 %) for a in x, y, z, cubes 8/16/24 mm, Re 9.4 and 26; pooled"
    return out


def _relative_spread(w: dict, rng: np.random.Generator, n: int = 20000) -> tuple[float, np.ndarray]:
    """Coefficient of variation of the three components and Monte-Carlo draws of it (each component
    normal with sd = ci/1.96)."""
    m = np.array([w[a][0] for a in AXES])
    s = np.array([w[a][1] for a in AXES]) / 1.96
    draws = rng.normal(m, s, size=(n, 3))
    cv = lambda x: np.std(x, axis=-1) / np.mean(x, axis=-1)  # noqa: E731
    return float(cv(m)), cv(draws)


def claim5(inp: Inputs) -> Outcome:
    rng = np.random.default_rng(12345)
    cmps, missing = [], []
    for e in CUBE.values():
        for r in REYNOLDS:
            da, db = ("cube", e, 0.30, r), ("cube", e, 0.50, r)
            na, nb = inp.find(*da), inp.find(*db)
            wa, why_a = inp.omega(na, _desc(*da))
            wb, why_b = inp.omega(nb, _desc(*db))
            for why in (why_a, why_b):
                if why and why not in missing:
                    missing.append(why)
            if wa is None or wb is None:
                continue
            a, da_s = _relative_spread(wa, rng)
            b, db_s = _relative_spread(wb, rng)
            dd = da_s - db_s
            lo, hi = np.percentile(dd, [2.5, 97.5])
            ca = float(np.diff(np.percentile(da_s, [2.5, 97.5]))[0] / 2)
            cb = float(np.diff(np.percentile(db_s, [2.5, 97.5]))[0] / 2)
            cmps.append(Cmp(f"CV {na} vs {nb}", a, ca, b, cb, a - b, float(lo), float(hi), (na, nb)))
    out = ordering_verdict(cmps, missing, inp, unit="(CV)")
    out.statistic = ("relative spread of the three components, CV = std(|Ωx|, |Ωy|, |Ωz|)/mean, per cube case; "
                     "d = CV(30 %) - CV(50 %), interval by Monte Carlo (components normal, sd = ci/1.96); pooled "
                     "over cube sizes and Re")
    return out


def claim6(inp: Inputs) -> Outcome:
    pairs = [(("cube", e, c, 26.0), ("cube", e, c, 9.4)) for e in CUBE.values() for c in CONCENTRATIONS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = "d = |Ω_a|(Re 26) - |Ω_a|(Re 9.4) for a in x, y, z, cubes 8/16/24 mm, 30 % and 50 %; pooled"
    return out


def claim7(inp: Inputs) -> Outcome:
    pairs = [(("cube", (e,), c, r), ("cylinder", (e, e), c, r)) for e in (8, 16) for c in CONCENTRATIONS
             for r in REYNOLDS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = ("d = |Ω_a|(cube of edge a) - |Ω_a|(cylinder a x a) for a in x, y, z, sizes 8 and 16 mm, "
                     "30/50 %, Re 9.4/26; pooled")
    return out


def claim8(inp: Inputs) -> Outcome:
    pairs = [(("cube", CUBE[s], c, r), ("cube", CUBE[l], c, r)) for s, l in (("8", "16"), ("16", "24"))
             for c in CONCENTRATIONS for r in REYNOLDS]
    pairs += [(("cylinder", CYL[s], c, r), ("cylinder", CYL[l], c, r)) for s, l in (("8x8", "16x16"),)
              for c in CONCENTRATIONS for r in REYNOLDS]
    cmps, missing = _omega_pairs(inp, pairs)
    out = ordering_verdict(cmps, missing, inp)
    out.statistic = ("d = |Ω_a|(smaller) - |Ω_a|(larger) for a in x, y, z: cubes 8 -> 16 -> 24 mm, cylinders "
                     "8x8 -> 16x16 (same shape), 30/50 %, Re 9.4/26; pooled")
    return out


def _angle_pairs(inp: Inputs, pairs, kind: str) -> tuple[list[Cmp], list[str]]:
    cmps, missing = [], []
    for da, db in pairs:
        na, nb = inp.find(*da), inp.find(*db)
        a, why_a = inp.angle(na, kind, _desc(*da))
        b, why_b = inp.angle(nb, kind, _desc(*db))
        for why in (why_a, why_b):
            if why and why not in missing:
                missing.append(why)
        if a is None or b is None:
            continue
        cmps.append(diff(f"{na} vs {nb}", *a, *b, (na, nb)))
    return cmps, missing


def claim9(inp: Inputs) -> Outcome:
    pairs = [(("cylinder", CYL[lo], c, r), ("cylinder", CYL[hi], c, r))
             for lo, hi in (("16x16", "16x24"), ("8x8", "8x16")) for c in CONCENTRATIONS for r in REYNOLDS]
    cmps, missing = _angle_pairs(inp, pairs, "cyl_axis_angle")
    out = ordering_verdict(cmps, missing, inp, unit="deg")
    out.statistic = ("mean angle between cylinder axis and pipe axis (smaller = more aligned); d = mean(lower "
                     "aspect ratio) - mean(higher), pairs 16x16 -> 16x24 and 8x8 -> 8x16, 30/50 %, Re 9.4/26; pooled")
    return out


def claim10(inp: Inputs) -> Outcome:
    pairs = [(("cylinder", s, c, 26.0), ("cylinder", s, c, 9.4)) for s in CYL.values() for c in CONCENTRATIONS]
    cmps, missing = _angle_pairs(inp, pairs, "cyl_axis_angle")
    out = ordering_verdict(cmps, missing, inp, unit="deg")
    out.statistic = ("d = mean cylinder-axis angle at Re 26 - at Re 9.4 (positive = more aligned at Re 9.4), all "
                     "cylinder sizes, 30/50 %; pooled")
    return out


def claim11(inp: Inputs) -> Outcome:
    from scipy.stats import norm

    out = Outcome(statistic=(
        "cube_projected_angle histograms (cubes 8/16/24 mm, 30 %, Re 9.4/26, Fig. 9): per bin the deviation "
        "of the fraction from uniform (bin width / 45 deg) with its 95 % half-width widened by Bonferroni over "
        f"the bins. Contradicted if some bin's interval excludes uniform; reproduced if none does and every "
        f"bin's interval lies within ±{CUBE_UNIFORM_TOLERANCE:.0%} of uniform; otherwise inconclusive"))
    missing, vals, prefer, wide = [], [], [], []
    for e in CUBE.values():
        for r in REYNOLDS:
            desc = ("cube", e, 0.30, r)
            name = inp.find(*desc)
            h, why = inp.histogram(name, "cube_projected_angle", _desc(*desc))
            if h is None:
                missing.append(why)
                continue
            nb = len(h)
            widen = norm.ppf(1 - 0.025 / nb) / norm.ppf(0.975)
            u = (h["bin_hi_deg"] - h["bin_lo_deg"]).to_numpy() / (h["bin_hi_deg"].max() - h["bin_lo_deg"].min())
            f, ci = h["fraction"].to_numpy(), h["ci95"].to_numpy() * widen
            dev = f - u
            worst = int(np.argmax(np.abs(dev) / u))
            vals.append(f"{name}: max |f/u - 1| = {_f(abs(dev[worst]) / u[worst])} (bin "
                        f"{_f(h['bin_lo_deg'].iloc[worst])}-{_f(h['bin_hi_deg'].iloc[worst])} deg, f = "
                        f"{_pm(f[worst], ci[worst])}, uniform {_f(u[worst])})")
            if np.any(np.abs(dev) > ci):
                k = int(np.argmax(np.abs(dev) - ci))
                prefer.append(f"{name} bin {_f(h['bin_lo_deg'].iloc[k])}-{_f(h['bin_hi_deg'].iloc[k])} deg")
            if np.any(np.abs(dev) + ci > CUBE_UNIFORM_TOLERANCE * u):
                wide.append(name)
            out.cases.append(name)
    out.values = "; ".join(vals) or "no histogram available"
    note = ("; missing: " + "; ".join(missing)) if missing else ""
    if not vals:
        out.reason = "inputs missing: " + "; ".join(missing)
    elif prefer:
        out.verdict = "contradicted"
        out.reason = ("significant preference in " + ", ".join(prefer) + "; diagnosed: "
                      + diagnosed_reason(inp, out.cases) + note)
    elif not wide:
        out.verdict = "reproduced"
        out.reason = "every bin is uniform within the tolerance at 95 % (Bonferroni)" + note
    else:
        out.reason = "no significant preference, but the intervals are too wide to exclude one in " + ", ".join(wide) + note
    return out


def claim12(inp: Inputs) -> Outcome:
    pairs = [(("cube", e, 0.30, 26.0), ("cube", e, 0.30, 9.4)) for e in CUBE.values()]
    cmps, missing = _angle_pairs(inp, pairs, "cube_projected_angle")
    m = CUBE_RE_MARGIN_DEG
    out = Outcome(statistic=(
        f"equivalence test: d = mean projected cube angle at Re 26 - at Re 9.4 (cubes 8/16/24 mm, 30 %); "
        f"reproduced if every 95 % interval of d lies within ±{m:g} deg (10 % of the 0-45 deg range), "
        f"contradicted if one lies wholly outside it, otherwise inconclusive"))
    out.values = "; ".join(f"{c.label}: {_pm(c.a, c.ca)} vs {_pm(c.b, c.cb)} deg (d = {_f(c.d)} "
                           f"[{_f(c.lo)}, {_f(c.hi)}])" for c in cmps) or "no comparison available"
    out.cases = sorted({k for c in cmps for k in c.cases})
    note = ("; missing: " + "; ".join(missing)) if missing else ""
    if not cmps:
        out.reason = "inputs missing: " + "; ".join(missing)
    elif any(c.lo > m or c.hi < -m for c in cmps):
        out.verdict = "contradicted"
        out.reason = (f"the Reynolds number shifts the mean angle by more than {m:g} deg; diagnosed: "
                      + diagnosed_reason(inp, out.cases) + note)
    elif all(-m < c.lo and c.hi < m for c in cmps):
        out.verdict = "reproduced"
        out.reason = f"every difference is within ±{m:g} deg at 95 %" + note
    else:
        out.reason = f"the intervals straddle the ±{m:g} deg margin" + note
    return out


def rel_l2(r: np.ndarray, u: np.ndarray, u_ref: np.ndarray, weights: np.ndarray) -> float:
    """Relative L2 distance sqrt(sum w (u - u_ref)^2 / sum w u_ref^2) (w = nodes per radial bin: area weighting)."""
    return float(np.sqrt(np.sum(weights * (u - u_ref) ** 2) / np.sum(weights * u_ref**2)))


def claim13(inp: Inputs) -> Outcome:
    out = Outcome(statistic=(
        f"relative L2 distances (weighted by nodes per radial bin) of the time-averaged axial profile of "
        f"{PROFILE_CASE} from the particle-free {PROFILE_REFERENCE} profile (interpolated in r) and from the "
        f"Hagen-Poiseuille parabola; e0 = distance of {PROFILE_REFERENCE} from its parabola (discretisation "
        f"error). Reproduced if both exceed max({PROFILE_CHANGE_MIN:g}, {PROFILE_NOISE_FACTOR:g} e0), "
        f"contradicted if both are below {PROFILE_NOISE_FACTOR / 2:g} e0, otherwise inconclusive"))
    p, why_p = inp.profile(PROFILE_CASE)
    f, why_f = inp.profile(PROFILE_REFERENCE)
    missing = [w for w in (why_p, why_f) if w]
    if missing:
        out.values = "no profile available"
        out.reason = "inputs missing: " + "; ".join(missing)
        return out
    w = p["nodes"].to_numpy(float) if "nodes" in p else np.ones(len(p))
    u_free = np.interp(p["r_mm"], f["r_mm"], f["uz_m_s"])
    d_free = rel_l2(p["r_mm"], p["uz_m_s"].to_numpy(), u_free, w)
    d_par = rel_l2(p["r_mm"], p["uz_m_s"].to_numpy(), p["uz_poiseuille_m_s"].to_numpy(), w)
    wf = f["nodes"].to_numpy(float) if "nodes" in f else np.ones(len(f))
    e0 = rel_l2(f["r_mm"], f["uz_m_s"].to_numpy(), f["uz_poiseuille_m_s"].to_numpy(), wf)
    out.values = (f"{PROFILE_CASE} vs particle-free: {_f(d_free)}; vs parabola: {_f(d_par)}; particle-free vs "
                  f"parabola e0 = {_f(e0)}")
    out.cases = [PROFILE_CASE, PROFILE_REFERENCE]
    big = max(PROFILE_CHANGE_MIN, PROFILE_NOISE_FACTOR * e0)
    small = PROFILE_NOISE_FACTOR * e0 / 2
    if d_free > big and d_par > big:
        out.verdict = "reproduced"
        out.reason = f"the particles change the profile by more than {_f(big)} (relative L2)"
    elif d_free < small and d_par < small:
        out.verdict = "contradicted"
        out.reason = ("the profile with particles is indistinguishable from the particle-free one; diagnosed: "
                      + diagnosed_reason(inp, [PROFILE_CASE]))
    else:
        out.reason = f"a change between {_f(small)} and {_f(big)}: present but not clearly 'great'"
    return out


def claim14(inp: Inputs) -> Outcome:
    cmps, missing = [], []
    names = [ALIGN_CASE, ALIGN_NOCOLL_CASE]
    got = []
    for name in names:
        a, why = inp.angle(name if name in inp.cases else None, "cyl_axis_angle", name)
        if why:
            missing.append(why)
        got.append(a)
    if all(g is not None for g in got):
        cmps.append(diff(f"{ALIGN_CASE} vs {ALIGN_NOCOLL_CASE}", *got[0], *got[1], tuple(names)))
    out = ordering_verdict(cmps, missing, inp, unit="deg")
    out.statistic = (f"d = mean cylinder-axis angle with collisions ({ALIGN_CASE}) - without "
                     f"({ALIGN_NOCOLL_CASE}); positive = colliding particles align less")
    return out


CLAIMS = {1: claim1, 2: claim2, 3: claim3, 4: claim4, 5: claim5, 6: claim6, 7: claim7, 8: claim8, 9: claim9,
          10: claim10, 11: claim11, 12: claim12, 13: claim13, 14: claim14}


#: the columns a level's ``claims.csv`` takes from the comparison of methods (``methods.claim_rows``
#: names them on the left, ``write_claims`` on the right)
LEVEL_CLAIM_COLUMNS = {"verdict_paper_seed1": "verdict_paper_method_seed1",
                       "verdict_accurate_seed1": "verdict_accurate_method_seed1", "same": "same_under_both_methods"}


def evaluate_claims(fid_dir: Path, config_cases: dict) -> pd.DataFrame:
    """The 14 claims of one level: ``claim, statement, statistic, values, verdict, reason``."""
    inp = Inputs(fid_dir, config_cases)
    rows = []
    for k, fn in CLAIMS.items():
        o = fn(inp)
        if o.verdict != "contradicted" and o.cases:
            flagged = [d for name in o.cases for d in case_diagnoses(inp, name)
                       if "lattice spacings" not in d and health.NOT_COMPUTED not in d]
            if flagged:
                o.reason += "; flagged cases: " + "; ".join(flagged)
        rows.append({"claim": k, "statement": STATEMENTS[k], "statistic": o.statistic, "values": o.values,
                     "verdict": o.verdict, "reason": o.reason})
    return pd.DataFrame(rows, columns=COLUMNS)


def write_claims(fid_dir: Path, config_cases: dict, method_claims: Path | None = None) -> Path:
    """Write ``fid_dir/claims.csv`` and return its path. With ``method_claims`` (the comparison
    with the accurate method, ``method/claims.csv`` of ``lbmpipe.reproduction.methods``) each claim
    also carries its verdict under both methods from packing seed 1 and whether they agree."""
    path = Path(fid_dir) / "claims.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    claims = evaluate_claims(fid_dir, config_cases)
    if method_claims is not None:
        m = pd.read_csv(method_claims).set_index("claim")
        for src, dst in LEVEL_CLAIM_COLUMNS.items():
            claims[dst] = claims["claim"].map(m[src]) if src in m else None
        claims["same_under_both_methods"] = claims["same_under_both_methods"].fillna("not compared")
    claims.to_csv(path, index=False)
    return path
