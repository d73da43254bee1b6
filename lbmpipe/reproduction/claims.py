"""The paper's 14 claims (paper/reading.md), each a statistic computed from the results tables of one
fidelity level, with a verdict.

Inputs under ``results/<fid>/``: ``tables/angular_velocity.csv`` (mean |Omega_a| per case with its
95 % half-width), ``tables/orientation_summary.csv`` (mean orientation angle per case and kind with
its 95 % half-width), ``tables/orientation.csv`` (histograms with per-bin 95 % half-widths),
``cases/<case>/profile.csv``, and the runs behind each case (``cases/<case>/seed<k>/stats.json``).
Cases are found by their config entry (shape, size, concentration, Reynolds number, collisions),
never by parsing names.

Statistics. Most claims are orderings ``a > b`` between two cases; each such comparison gives the
difference ``d = a - b`` with the 95 % half-width ``sqrt(ci_a^2 + ci_b^2)`` (the cases' intervals).
A claim that covers several comparisons (several axes, sizes, concentrations or Reynolds numbers)
pools them: the mean difference ``D`` with a half-width that keeps the comparisons' dependence (they
share runs and packings): :mod:`lbmpipe.reproduction.pooling`, a bootstrap over whole packings of
every case at once with a floor from the runs' own noise.

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

Beside each verdict (columns of ``claims.csv``):

- ``carried_by``: how many comparisons carry it (``1 of 9 significant in the claimed direction``);
- ``deciding``: the number that decides it (the pooled difference, the deciding comparison or bin);
- ``verdict_with_systematic`` and ``robust``: the verdict again with a systematic error per
  observable added to every interval (``config.yaml`` ``systematic``: ``omega_rel`` relative on
  |Omega|, ``angle_deg`` on a mean angle, ``fraction_abs`` on a histogram fraction,
  ``profile_rel_l2`` on a profile distance; measured shifts of the method and resolution controls,
  zero until measured). A shift can have either sign in each case, so it adds linearly: a
  difference ``a - b`` gets ``s_a + s_b``, and the pooled ``D`` the mean of those (a systematic
  error does not average down). ``robust``: ``yes`` when a decisive verdict holds with it, ``no``
  when it does not, ``not applicable`` for an inconclusive one;
- ``verdict_without_frozen_locked`` and ``verdict_without_flagged``: the verdict with the cases
  flagged frozen or locked (the dynamics the statistic describes are not there), and with every
  flagged case (frozen, locked or unhealthy), left out; ``left_out_*`` names them.

Reasons. A contradiction's reason is built from the measured diagnostics of the claim's own cases
(:func:`case_diagnoses`: frozen, locked, unhealthy, not steady, interval too short with the
duration needed, resolution in lattice spacings), each naming its case; any other verdict lists
the flagged cases it rests on.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from . import health
from .claim_rules import (AXES, SYSTEMATIC_KEYS, Cmp, Inputs, Outcome, _desc, _f, _pm,  # noqa: F401
                          case_diagnoses, diagnosed_reason, diff, ordering_verdict)
from .fractions import histogram_interval
from .profile_error import profile_error, rel_l2  # noqa: F401  (rel_l2: the distance of claim 13)

COLUMNS = ["claim", "statement", "statistic", "values", "verdict", "reason", "carried_by", "deciding",
           "verdict_with_systematic", "robust", "verdict_without_frozen_locked", "left_out_frozen_locked",
           "verdict_without_flagged", "left_out_flagged"]
#: the verdicts without flagged cases: column suffix -> the flags that leave a case out
WITHOUT = {"frozen_locked": ("frozen", "locked"), "flagged": ("frozen", "locked", "unhealthy")}

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
#: claim 11 (paper/reading.md): a bin "prefers" when its fraction is off uniform by more than this share of uniform
CUBE_UNIFORM_TOLERANCE = 0.5
#: claim 11: confidence of each one-sided test of the equivalence (TOST: the 90 % interval inside the margin)
TOST_ALPHA = 0.05
#: claim 13: "greatly" = relative L2 change at least this, and this many times the particle-free error
PROFILE_CHANGE_MIN = 0.10
PROFILE_NOISE_FACTOR = 3.0
#: the pair of claim 13 and of claim 14 (config names, paper/reading.md)
PROFILE_CASE, PROFILE_REFERENCE = "cyl16x16_c30_re26", "flow_re26"
ALIGN_CASE, ALIGN_NOCOLL_CASE = "cyl8x16_c30_re9.4", "cyl8x16_c30_re9.4_nocoll"
#: claim 14's no-interaction reference: the same cylinders dilute (2 %, collisions on) in the same flow
#: (config.yaml ``cyl8x16_c2_re9.4``); ``_nocoll`` (bodies overlap at 30 %) is a named sensitivity only
REFERENCE_DESC = ("cylinder", (8, 16), 0.02, 9.4)


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
                cmps.append(diff(f"{na} vs {nb} [{ax}]", *wa[ax], *wb[ax], (na, nb),
                                 keys=((na, ("omega", ax)), (nb, ("omega", ax))),
                                 sys=inp.sys_omega(wa[ax][0]) + inp.sys_omega(wb[ax][0])))
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
                cmp = diff(f"{name} (x+y)/2 vs z", a, ca, *w["z"], (name,), sys=inp.sys_omega(a) + inp.sys_omega(w["z"][0]))
                cmp.keys = tuple((name, ("omega", ax)) for ax in AXES)
                cmp.fn = (lambda n: lambda g: (g(n, ("omega", "x")) + g(n, ("omega", "y"))) / 2 - g(n, ("omega", "z")))(name)
                cmps.append(cmp)
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


def _cv(g, name: str):
    """CV of a case's three components from a getter (vectorised over draws)."""
    m = np.stack([np.asarray(g(name, ("omega", ax)), dtype=float) for ax in AXES])
    return np.std(m, axis=0) / np.mean(m, axis=0)


def _cv_shift(w: dict, r: float) -> float:
    """Largest change of the CV when each component moves by up to ``r`` of itself (the corners)."""
    if r <= 0:
        return 0.0
    m = np.array([w[a][0] for a in AXES])
    corners = np.array(np.meshgrid(*[(1 - r, 1 + r)] * 3)).reshape(3, -1).T * m
    cv = lambda x: np.std(x, axis=-1) / np.mean(x, axis=-1)  # noqa: E731
    return float(np.max(np.abs(cv(corners) - cv(m))))


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
            sys = _cv_shift(wa, inp.systematic["omega_rel"]) + _cv_shift(wb, inp.systematic["omega_rel"])
            cmps.append(Cmp(f"CV {na} vs {nb}", a, ca, b, cb, a - b, float(lo), float(hi), (na, nb),
                            keys=tuple((n, ("omega", ax)) for n in (na, nb) for ax in AXES),
                            fn=(lambda p, q: lambda g: _cv(g, p) - _cv(g, q))(na, nb), sys=sys))
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
        cmps.append(diff(f"{na} vs {nb}", *a, *b, (na, nb), keys=((na, ("angle", kind)), (nb, ("angle", kind))),
                         sys=2 * inp.systematic["angle_deg"]))
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


def _bin(h: pd.DataFrame, k: int) -> str:
    return f"{_f(h['bin_lo_deg'].iloc[k])}-{_f(h['bin_hi_deg'].iloc[k])} deg"


def _uniform_test(hists: list, sys: float) -> tuple[list, list, list]:
    """Claim 11's bins against the margin: ``(within, beyond, straddle)``, each a list of
    ``(case, bin, text)`` (one entry per case), intervals widened by the systematic ``sys``."""
    from scipy.stats import norm

    m = CUBE_UNIFORM_TOLERANCE
    z_tost = float(norm.ppf(1 - TOST_ALPHA))
    z_bonf = float(norm.ppf(1 - 0.025 / max(sum(len(h) for _, h in hists), 1)))
    within, beyond, straddle = [], [], []
    for name, h in hists:
        u = (h["bin_hi_deg"] - h["bin_lo_deg"]).to_numpy() / (h["bin_hi_deg"].max() - h["bin_lo_deg"].min())
        f, ci = h["fraction"].to_numpy(float), h["ci95"].to_numpy(float)
        lo90, hi90, n_eff = histogram_interval(f, ci, z_tost)
        lo_b, hi_b, _ = histogram_interval(f, ci, z_bonf)
        lo90, hi90, lo_b, hi_b = lo90 - sys, hi90 + sys, lo_b - sys, hi_b + sys
        band = lambda k: f"u(1 ± {m:g}) = [{_f(u[k] * (1 - m))}, {_f(u[k] * (1 + m))}]"  # noqa: E731
        # how far each bin's interval reaches past (> 0) or stays inside (< 0) the margin, in units of u
        reach = np.maximum(hi90 - u * (1 + m), u * (1 - m) - lo90) / u
        shown = np.maximum(lo_b - u * (1 + m), u * (1 - m) - hi_b) / u
        if not np.isfinite(n_eff):
            straddle.append((name, "all", "no interval (no bin with a finite half-width)"))
        elif np.nanmax(shown) > 0:
            k = int(np.nanargmax(shown))
            beyond.append((name, _bin(h, k), f"f = {_f(f[k])}, 95 % Bonferroni [{_f(lo_b[k])}, {_f(hi_b[k])}] "
                           f"wholly beyond {band(k)}"))
        elif np.nanmax(reach) < 0:
            k = int(np.nanargmax(reach))
            within.append((name, _bin(h, k), f"closest bin f = {_f(f[k])}, 90 % [{_f(lo90[k])}, {_f(hi90[k])}] "
                           f"within {band(k)}"))
        else:
            k = int(np.nanargmax(reach))
            straddle.append((name, _bin(h, k), f"f = {_f(f[k])}, 90 % [{_f(lo90[k])}, {_f(hi90[k])}] reaches past "
                             f"{band(k)}"))
    return within, beyond, straddle


def _equivalence_verdict(within: list, beyond: list, n: int) -> str:
    return "contradicted" if beyond else "reproduced" if len(within) == n else "inconclusive"


def claim11(inp: Inputs) -> Outcome:
    """An equivalence test at paper/reading.md's margin: a preference is a bin off uniform by more
    than :data:`CUBE_UNIFORM_TOLERANCE` of uniform. Per bin, the fraction's Wilson interval on the
    case's effective sample size (:mod:`lbmpipe.reproduction.fractions`)."""
    m = CUBE_UNIFORM_TOLERANCE
    out = Outcome(statistic=(
        "equivalence test on the cube_projected_angle histograms (cubes 8/16/24 mm, 30 %, Re 9.4/26, Fig. 9); a "
        f"preference is a bin whose fraction f is off uniform u (bin width / 45 deg) by more than {m:.0%} of u "
        "(paper/reading.md). Per bin a Wilson score interval of f on the case's effective sample size. Reproduced "
        f"if every bin's 90 % interval lies within u(1 ± {m:g}) (two one-sided tests at 5 % per bin: an "
        "intersection-union test needs no correction); contradicted if some bin's 95 % interval, Bonferroni over "
        "all bins, lies wholly beyond the margin (the deviation is shown to exceed it); otherwise inconclusive. "
        "Locked cases are left out and named"))
    missing, vals, locked, hists = [], [], [], []
    for e in CUBE.values():
        for r in REYNOLDS:
            desc = ("cube", e, 0.30, r)
            name = inp.find(*desc)
            h, why = inp.histogram(name, "cube_projected_angle", _desc(*desc))
            if h is None:
                missing.append(why)
                continue
            if "locked" in inp.flags(name):
                locked.append(name)
                continue
            hists.append((name, h))
            f, ci = h["fraction"].to_numpy(float), h["ci95"].to_numpy(float)
            u = (h["bin_hi_deg"] - h["bin_lo_deg"]).to_numpy() / (h["bin_hi_deg"].max() - h["bin_lo_deg"].min())
            lo, hi, n_eff = histogram_interval(f, ci)
            k = int(np.argmax(np.abs(f - u) / u))
            vals.append(f"{name}: max |f/u - 1| = {_f(abs(f[k] - u[k]) / u[k])} (bin {_bin(h, k)}, f = {_f(f[k])}, "
                        f"95 % [{_f(lo[k])}, {_f(hi[k])}], uniform {_f(u[k])}; n_eff = {_f(n_eff)})")
            out.cases.append(name)
    out.values = "; ".join(vals) or "no histogram available"
    notes = (("; left out (locked): " + ", ".join(locked)) if locked else "") + (
        ("; missing: " + "; ".join(missing)) if missing else "")
    n = len(hists)
    if not n:
        out.reason = "inputs missing: " + "; ".join(missing + [f"{c}: left out (locked)" for c in locked])
        out.carried = "no case"
        return out
    within, beyond, straddle = _uniform_test(hists, 0.0)
    out.verdict = _equivalence_verdict(within, beyond, n)
    out.verdict_sys = _equivalence_verdict(*_uniform_test(hists, inp.systematic["fraction_abs"])[:2], n)
    out.carried = f"{len(within)} of {n} cases within the margin at 90 %, {len(beyond)} shown beyond it"
    name, b, text = (beyond or (within if out.verdict == "reproduced" else straddle))[0]
    out.deciding = f"{name} bin {b}: {text}"
    if beyond:
        out.reason = ("a preference beyond the margin in " + ", ".join(f"{c} bin {b}" for c, b, _ in beyond)
                      + "; diagnosed: " + diagnosed_reason(inp, [c for c, _, _ in beyond]) + notes)
    elif out.verdict == "reproduced":
        out.reason = f"every bin of every case is uniform within ±{m:.0%} at 90 % (two one-sided tests)" + notes
    else:
        out.reason = ("no bin is shown beyond the margin, but the intervals reach past it in "
                      + ", ".join(c for c, _, _ in straddle) + notes)
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
        out.carried = "no comparison"
        return out

    def rule(w: float) -> str:
        if any(c.lo - c.sys * w > m or c.hi + c.sys * w < -m for c in cmps):
            return "contradicted"
        return "reproduced" if all(-m < c.lo - c.sys * w and c.hi + c.sys * w < m for c in cmps) else "inconclusive"

    out.verdict, out.verdict_sys = rule(0.0), rule(1.0)
    inside = [c for c in cmps if -m < c.lo and c.hi < m]
    outside = [c for c in cmps if c.lo > m or c.hi < -m]
    out.carried = f"{len(inside)} of {len(cmps)} within ±{m:g} deg, {len(outside)} shown beyond it"
    # the deciding comparison: one beyond the margin, else the one reaching closest to (or past) it
    c = outside[0] if outside else max(cmps, key=lambda c: max(c.hi, -c.lo))
    out.deciding = f"{c.label}: d = {_f(c.d)} [{_f(c.lo)}, {_f(c.hi)}] deg against ±{m:g}"
    if out.verdict == "contradicted":
        out.reason = (f"the Reynolds number shifts the mean angle by more than {m:g} deg; diagnosed: "
                      + diagnosed_reason(inp, out.cases) + note)
    elif out.verdict == "reproduced":
        out.reason = f"every difference is within ±{m:g} deg at 95 %" + note
    else:
        out.reason = f"the intervals straddle the ±{m:g} deg margin" + note
    return out


def claim13(inp: Inputs) -> Outcome:
    out = Outcome(statistic=(
        f"relative L2 distances (weighted by nodes per radial bin, lbmpipe.reproduction.profile_error) of the "
        f"time-averaged axial profile of {PROFILE_CASE} from the particle-free {PROFILE_REFERENCE} profile "
        f"(interpolated in r) and from the Hagen-Poiseuille parabola; e0 = distance of {PROFILE_REFERENCE} from its "
        f"parabola (discretisation error). Reproduced if both exceed max({PROFILE_CHANGE_MIN:g}, "
        f"{PROFILE_NOISE_FACTOR:g} e0), contradicted if both are below {PROFILE_NOISE_FACTOR / 2:g} e0, otherwise "
        f"inconclusive"))
    p, why_p = inp.profile(PROFILE_CASE)
    f, why_f = inp.profile(PROFILE_REFERENCE)
    missing = [w for w in (why_p, why_f) if w]
    if missing:
        out.values = "no profile available"
        out.reason = "inputs missing: " + "; ".join(missing)
        out.carried = "no comparison"
        return out
    d_free, d_par, e0 = profile_error(p, f), profile_error(p), profile_error(f)
    out.values = (f"{PROFILE_CASE} vs particle-free: {_f(d_free)}; vs parabola: {_f(d_par)}; particle-free vs "
                  f"parabola e0 = {_f(e0)}")
    out.cases = [PROFILE_CASE, PROFILE_REFERENCE]

    def rule(s: float) -> str:
        big = max(PROFILE_CHANGE_MIN, PROFILE_NOISE_FACTOR * e0)
        if d_free - s > big and d_par - s > big:
            return "reproduced"
        return "contradicted" if d_free + s < PROFILE_NOISE_FACTOR * e0 / 2 and d_par + s < PROFILE_NOISE_FACTOR * e0 / 2 \
            else "inconclusive"

    big, small = max(PROFILE_CHANGE_MIN, PROFILE_NOISE_FACTOR * e0), PROFILE_NOISE_FACTOR * e0 / 2
    out.verdict, out.verdict_sys = rule(0.0), rule(inp.systematic["profile_rel_l2"])
    out.carried = f"{sum(d > big for d in (d_free, d_par))} of 2 distances above {_f(big)}"
    out.deciding = f"smaller distance {_f(min(d_free, d_par))} against {_f(big)} (e0 = {_f(e0)})"
    if out.verdict == "reproduced":
        out.reason = f"the particles change the profile by more than {_f(big)} (relative L2)"
    elif out.verdict == "contradicted":
        out.reason = ("the profile with particles is indistinguishable from the particle-free one; diagnosed: "
                      + diagnosed_reason(inp, [PROFILE_CASE]))
    else:
        out.reason = f"a change between {_f(small)} and {_f(big)}: present but not clearly 'great'"
    return out


def claim14(inp: Inputs) -> Outcome:
    """Colliding cylinders (30 %) against the no-interaction reference (:data:`REFERENCE_DESC`, a
    dilute suspension in the same flow); the collisions-off run of the same packing (bodies overlap)
    is shown as a sensitivity and never decides."""
    kind = "cyl_axis_angle"
    ref = inp.find(*REFERENCE_DESC)
    a, why_a = inp.angle(ALIGN_CASE if ALIGN_CASE in inp.cases else None, kind, ALIGN_CASE)
    r, why_r = inp.angle(ref, kind, _desc(*REFERENCE_DESC))
    nc, why_nc = inp.angle(ALIGN_NOCOLL_CASE if ALIGN_NOCOLL_CASE in inp.cases else None, kind, ALIGN_NOCOLL_CASE)
    statistic = (f"d = mean cylinder-axis angle of the colliding suspension ({ALIGN_CASE}) - of the no-interaction "
                 f"reference {ref or _desc(*REFERENCE_DESC)} (8x16 mm cylinders at {REFERENCE_DESC[2]:.0%}, collisions "
                 f"on, same flow, several packings: rare contacts); positive = colliding particles align less. "
                 f"Sensitivity only: the same packing with particle-particle collisions off ({ALIGN_NOCOLL_CASE}; "
                 f"bodies overlap, not a physical reference)")
    sens = (f"sensitivity, collisions off ({ALIGN_NOCOLL_CASE}, bodies overlap): d = {_f(a[0] - nc[0])} "
            f"[{_f(a[0] - nc[0] - math.hypot(a[1], nc[1]))}, {_f(a[0] - nc[0] + math.hypot(a[1], nc[1]))}] deg"
            if a is not None and nc is not None else f"sensitivity, collisions off: {why_nc or why_a}")
    if r is None:
        ran = inp.has_angle_row(ref, kind)
        state = "gives no interval" if ran else "not run"
        out = Outcome(statistic=statistic, values=f"no comparison: the reference {state}; {sens}",
                      carried="no comparison", deciding=f"reference {state} ({ref or _desc(*REFERENCE_DESC)})")
        fix = ("its angle needs several packings or a longer window" if ran else
               f"it has no results at this level (`snakemake -c2 --config fidelity={inp.fid_dir.name} new_runs=all -- "
               f"results/{inp.fid_dir.name}/cases/{ref or '<reference case>'}/stats.json` runs it)")
        out.reason = (f"inputs missing: the no-interaction reference of claim 14 {state} ({why_r}): {fix}; the "
                      "collisions-off run is a sensitivity and does not decide" + (f"; missing: {why_a}" if why_a else ""))
        return out
    cmps, missing = [], [w for w in (why_a,) if w]
    if a is not None:
        cmps.append(diff(f"{ALIGN_CASE} vs {ref}", *a, *r, (ALIGN_CASE, ref),
                         keys=((ALIGN_CASE, ("angle", kind)), (ref, ("angle", kind))),
                         sys=2 * inp.systematic["angle_deg"]))
    out = ordering_verdict(cmps, missing, inp, unit="deg")
    out.statistic = statistic
    out.values += f"; {sens}"
    return out


CLAIMS = {1: claim1, 2: claim2, 3: claim3, 4: claim4, 5: claim5, 6: claim6, 7: claim7, 8: claim8, 9: claim9,
          10: claim10, 11: claim11, 12: claim12, 13: claim13, 14: claim14}


#: the columns a level's ``claims.csv`` takes from the comparison of methods (``methods.claim_rows``
#: names them on the left, ``write_claims`` on the right)
LEVEL_CLAIM_COLUMNS = {"verdict_paper_seed1": "verdict_paper_method_seed1",
                       "verdict_accurate_seed1": "verdict_accurate_method_seed1", "same": "same_under_both_methods"}


def systematic_terms(config: dict | None = None) -> dict:
    """The ``systematic`` block of a pipeline config (default: the repository's ``config.yaml``);
    zero for an observable it does not name."""
    if config is None or "systematic" not in config:
        import yaml

        config = yaml.safe_load(health.CONFIG_PATH.read_text()) if health.CONFIG_PATH.is_file() else {}
    got = (config or {}).get("systematic") or {}
    return {k: float(got.get(k, 0.0)) for k in SYSTEMATIC_KEYS}


def _robust(verdict: str, with_sys: str) -> str:
    if verdict == "inconclusive":
        return "not applicable"
    return "yes" if with_sys == verdict else "no"


def compares_anything(row) -> bool:
    """Whether a claim's row of :func:`evaluate_claims` compares anything (not "inputs missing" with
    no comparison): on a level holding only some cases, whether those cases bear on the claim."""
    return not (str(row["reason"]).startswith("inputs missing") and str(row["carried_by"]).startswith("no "))


def evaluate_claims(fid_dir: Path, config_cases: dict, systematic: dict | None = None) -> pd.DataFrame:
    """The 14 claims of one level (:data:`COLUMNS`): each verdict with its reason, how many
    comparisons carry it, the deciding number, the verdict with the systematic term
    (``systematic``, default ``config.yaml``'s) and the verdicts without the flagged cases."""
    systematic = systematic_terms() if systematic is None else systematic
    inp = Inputs(fid_dir, config_cases, systematic)
    without = {key: inp.without(flags) for key, flags in WITHOUT.items()}
    rows = []
    for k, fn in CLAIMS.items():
        o = fn(inp)
        if o.verdict != "contradicted" and o.cases:
            flagged = [d for name in o.cases for d in case_diagnoses(inp, name)
                       if "lattice spacings" not in d and health.NOT_COMPUTED not in d]
            if flagged:
                o.reason += "; flagged cases: " + "; ".join(flagged)
        with_sys = o.verdict_sys or o.verdict
        row = {"claim": k, "statement": STATEMENTS[k], "statistic": o.statistic, "values": o.values,
               "verdict": o.verdict, "reason": o.reason, "carried_by": o.carried, "deciding": o.deciding,
               "verdict_with_systematic": with_sys, "robust": _robust(o.verdict, with_sys)}
        for key, sub in without.items():
            left = [f"{n} ({sub.exclude[n]})" for n in o.cases if n in sub.exclude]
            row[f"verdict_without_{key}"] = fn(sub).verdict
            row[f"left_out_{key}"] = "; ".join(left) or "none"
        rows.append(row)
    return pd.DataFrame(rows, columns=COLUMNS)


def write_claims(fid_dir: Path, config_cases: dict, method_claims: Path | None = None,
                 systematic: dict | None = None) -> Path:
    """Write ``fid_dir/claims.csv`` and return its path. With ``method_claims`` (the comparison
    with the accurate method, ``method/claims.csv`` of ``lbmpipe.reproduction.methods``) each claim
    also carries its verdict under both methods from packing seed 1 and whether they agree."""
    path = Path(fid_dir) / "claims.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    claims = evaluate_claims(fid_dir, config_cases, systematic)
    if method_claims is not None:
        m = pd.read_csv(method_claims).set_index("claim")
        for src, dst in LEVEL_CLAIM_COLUMNS.items():
            claims[dst] = claims["claim"].map(m[src]) if src in m else None
        claims["same_under_both_methods"] = claims["same_under_both_methods"].fillna("not compared")
    claims.to_csv(path, index=False)
    return path
