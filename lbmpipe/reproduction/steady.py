"""Statistically steady results: where the spin-up ends, how correlated the samples are, what
interval a mean deserves, how several packings combine, and whether the bodies move at all.

Every function takes plain arrays (one value per sample, samples every ``dt`` seconds) and returns
numbers or a small JSON-able dict for ``stats.json``; none reads files. The methods and their
references:

- :func:`mser_truncation`, :func:`spinup_end`: MSER-5 truncation (White 1997; White, Cobb & Spratt
  2000; Franklin & White 2008), applied to several observables, the latest one taken, never
  before a given minimum (two viscous times ``R^2/nu``); evidence: the two halves of the kept
  window agree within the interval of their difference; :func:`steady_corrected` reads that
  verdict again at a family-wise 95 % over the observables (Bonferroni).
- :func:`integrated_autocorrelation_time`: ``tau_int`` with Sokal's automatic window (Madras &
  Sokal 1988; Sokal 1997, "Monte Carlo methods in statistical mechanics"), with its statistical
  error and a status saying when the series cannot resolve it.
- :func:`mean_interval`: non-overlapping batch means (Schmeiser 1982; Law & Kelton) with at least
  20 batches of at least 5 ``tau_int``; when the series is shorter than that, overlapping batch
  means (Meketon & Schmeiser 1984) with the Student t of their effective degrees of freedom
  ``1.5 (n/m - 1)``, flagged, with the duration that would be needed.
- :func:`combine_seeds`: several packings (independent runs): between-run variance of the run
  means with ``k - 1`` degrees of freedom, never below the within-run variance
  (Hartung-Knapp with the "ad hoc" truncation, Knapp & Hartung 2003, Roever et al. 2015), and the
  seed-to-seed spread; Cochran's Q (1954) says whether the seeds disagree beyond their noise.
- :func:`orientation_memory`: orientation autocorrelation, ``<P2(e(0).e(t))>`` of the cylinder
  axis or the cubic-symmetric fourth-rank invariant of a cube, relative to the first sample
  (frozen or decorrelated) and averaged over time origins (orientation correlation time).
- :func:`locking_diagnostics`: do bodies pass each other along the pipe, do they keep their
  nearest neighbours, and can two of them sit side by side in the cross-section at all (a
  column of bodies that cannot pass each other is locked whatever the flow does).

Conventions: ``tau_int = dt (1/2 + sum_{k>=1} rho_k)`` (white noise ``dt/2``, an exponential
``rho = exp(-t/T)`` sampled finely ``T``); the variance of the mean of ``n`` samples is then
``2 tau_int / (n dt)`` times the variance of one sample. Half-widths are of two-sided intervals
at ``confidence`` (default 95 %).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats as _st

_NAN = float("nan")

#: Sokal's window constant: the autocorrelation is summed up to the first lag ``M >= C tau(M)``
SOKAL_C = 5.0
#: a series shorter than this many tau_int gives a rough tau_int (Madras-Sokal relative error
#: ``sqrt(2 (2M + 1)/n)`` ~ 0.6 at ``M = 5 tau``; 0.14 needs ``n ~ 1000 tau``); 50 is the usual rule
MIN_TAUS_FOR_TAU = 50.0
#: batch-means design: at least this many batches, each at least ``BATCH_TAUS`` tau_int long
MIN_BATCHES = 20
BATCH_TAUS = 5.0


def _clean(series) -> np.ndarray:
    x = np.asarray(series, dtype=float).ravel()
    return x[np.isfinite(x)]


def _tq(confidence: float, dof: float) -> float:
    return float(_st.t.ppf(0.5 + confidence / 2.0, dof))


# ----------------------------------------------------------------------------------------------
# integrated autocorrelation time

def autocorrelation(series, max_lag: int | None = None) -> np.ndarray:
    """Normalised autocorrelation ``rho_k``, ``k = 0 .. max_lag`` (default ``n - 1``), of a
    series, by FFT with the usual biased estimator ``(1/n) sum_t y_t y_{t+k} / var`` (``rho_0 = 1``),
    which keeps the estimate positive definite (Priestley 1981)."""
    x = _clean(series)
    n = x.size
    y = x - x.mean()
    var = float(np.dot(y, y)) / n if n else 0.0
    if n < 2 or var <= 0.0:
        return np.full(1 if max_lag is None else max_lag + 1, _NAN)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(y, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[:n] / (n * var)
    return acf if max_lag is None else acf[: max_lag + 1]


def _sokal_window(rho: np.ndarray, c: float) -> tuple[float, int, bool]:
    """``tau(M) = 1/2 + sum_{k=1}^{M} rho_k`` (in samples) at the smallest ``M >= c tau(M)``;
    (tau, M, found). Without such an M the last lag is returned, found False."""
    tau = 0.5 + np.cumsum(rho[1:])
    m = np.arange(1, rho.size)
    ok = np.nonzero(m >= c * tau)[0]
    if ok.size:
        return float(tau[ok[0]]), int(m[ok[0]]), True
    return float(tau[-1]), int(m[-1]), False


def integrated_autocorrelation_time(series, dt: float = 1.0, c: float = SOKAL_C,
                                    min_taus: float = MIN_TAUS_FOR_TAU) -> dict:
    """Integrated autocorrelation time of a series sampled every ``dt`` with Sokal's automatic
    window (Madras & Sokal 1988, J. Stat. Phys. 50, 109; Sokal 1997, Sec. 3): ``tau(M) = dt (1/2 +
    sum_{k=1}^{M} rho_k)`` summed to the smallest ``M >= c tau(M)/dt`` (``c`` 5-6: the bias of the
    cut tail ``~ exp(-c)`` against the noise of the summed lags ``~ sqrt(M/n)``). Statistical
    error (Madras-Sokal): ``tau sqrt(2 (2M + 1) / n)``.

    Returns ``{tau_int_s, tau_err_s, window, n, status, message}``. ``status``:

    - ``ok``: resolved, ``n >= min_taus * tau``;
    - ``short``: window found but the series is shorter than ``min_taus`` correlation times: the
      value is probably low (the biased estimator shrinks long lags), take it as a lower bound;
    - ``too_short``: no window fits in the series: ``tau_int`` is comparable to the series length
      and the value (the sum over all lags) is only a lower bound;
    - ``below_sampling``: ``tau_int < dt``: the samples are nearly independent; the correlation
      time of the underlying process is not resolved by the sampling (``<~ dt``); the value is
      safe for intervals;
    - ``undefined``: fewer than 4 samples or a constant series (``tau_int_s`` NaN).
    """
    x = _clean(series)
    n = x.size
    out = {"tau_int_s": _NAN, "tau_err_s": _NAN, "window": 0, "n": int(n), "status": "undefined", "message": ""}
    rho = autocorrelation(x) if n >= 4 else np.array([_NAN])
    if n < 4 or not np.isfinite(rho[0]):
        out["message"] = "fewer than 4 samples or a constant series"
        return out
    tau, m, found = _sokal_window(rho, c)
    tau = max(tau, 0.5)  # rho summed past its noise can dip below white noise; dt/2 is the floor
    out.update(tau_int_s=tau * dt, tau_err_s=tau * dt * math.sqrt(2.0 * (2 * m + 1) / n), window=m)
    if not found:
        out["status"] = "too_short"
        out["message"] = (f"no Sokal window within {n} samples: tau_int is comparable to the series length "
                          f"({n * dt:.3g} s); {tau * dt:.3g} s is a lower bound")
    elif n < min_taus * tau:
        out["status"] = "short"
        out["message"] = (f"series of {n * dt:.3g} s is {n / tau:.0f} tau_int long (< {min_taus:g}): tau_int "
                          f"{tau * dt:.3g} s is uncertain and probably low")
    elif tau < 1.0:
        out["status"] = "below_sampling"
        out["message"] = f"tau_int {tau * dt:.3g} s < sampling interval {dt:g} s: samples nearly independent"
    else:
        out["status"] = "ok"
    return out


# ----------------------------------------------------------------------------------------------
# intervals

def _nbm(x: np.ndarray, b: int) -> tuple[float, float]:
    """Non-overlapping batch means: (variance of the grand mean, dof); the oldest ``n - b m``
    samples are left out of the batches."""
    n = x.size
    m = n // b
    means = x[n - b * m:].reshape(b, m).mean(axis=1)
    return float(means.var(ddof=1) / b), float(b - 1)


def _obm(x: np.ndarray, m: int) -> tuple[float, float]:
    """Overlapping batch means (Meketon & Schmeiser 1984, Proc. Winter Simulation Conf.): all
    ``n - m + 1`` batches of ``m`` consecutive samples; ``sigma^2 = n m / ((n - m + 1)(n - m))
    sum_j (Ybar_j - Ybar)^2`` estimates ``n Var(Ybar)``; its variance is ~2/3 that of
    non-overlapping batches of the same size, hence ``dof = 1.5 (n/m - 1)``."""
    n = x.size
    c = np.concatenate(([0.0], np.cumsum(x - x.mean())))
    means = (c[m:] - c[:-m]) / m  # deviations of the batch means from the grand mean
    s2 = n * m / ((n - m + 1) * (n - m)) * float(np.dot(means, means))
    return s2 / n, 1.5 * (n / m - 1.0)


def mean_interval(series, dt: float, tau_s: float | None = None, confidence: float = 0.95,
                  min_batches: int = MIN_BATCHES, batch_taus: float = BATCH_TAUS) -> dict:
    """Mean of a time-correlated series and a valid confidence half-width.

    ``tau_s``: correlation time to design the batches with (default: the series' own
    :func:`integrated_autocorrelation_time`; pass the larger of that and a known slower time, e.g.
    the orientation correlation time of :func:`orientation_memory`, when the series can hide it).
    Design: batches at least ``batch_taus * tau`` long (``L`` samples) and at least
    ``min_batches`` of them.

    - ``n >= min_batches * L``: ``min_batches`` non-overlapping batches of ``n // min_batches``
      samples (Schmeiser 1982, Oper. Res. 30, 556: 10-30 batches; the longest batches that give
      that many keep the bias of the batch variance smallest), half-width ``t_{b-1} s_b/sqrt(b)``.
    - shorter: ``sufficient`` False, ``required_s = min_batches * L * dt``, and the best
      estimator available: overlapping batch means with batches of ``L`` samples, Student t
      with ``1.5 (n/L - 1)`` dof (Meketon & Schmeiser 1984); NaN half-width when ``n < 2 L``.

    Returns ``{mean, ci95, method, batch_s, n_batches, dof, tau_int_s, tau_status, sufficient,
    required_s, duration_s, message}`` (``ci95`` holds the half-width at ``confidence``).
    """
    x = _clean(series)
    n = x.size
    own = integrated_autocorrelation_time(x, dt)
    tau = own["tau_int_s"]
    status = own["status"]
    if tau_s is not None and np.isfinite(tau_s) and (not np.isfinite(tau) or tau_s > tau):
        tau, status = float(tau_s), "given"
    out = {"mean": float(x.mean()) if n else _NAN, "ci95": _NAN, "method": "none", "batch_s": _NAN,
           "n_batches": 0, "dof": _NAN, "tau_int_s": tau, "tau_status": status, "sufficient": False,
           "required_s": _NAN, "duration_s": n * dt, "message": ""}
    if n < 4 or not np.isfinite(tau):
        out["message"] = "fewer than 4 samples or a constant series: no interval"
        if n >= 1 and np.all(x == x[0]):
            out["ci95"] = 0.0 if n >= 4 else _NAN
            out["message"] = "constant series"
        return out
    L = max(1, int(math.ceil(batch_taus * tau / dt)))
    out["required_s"] = min_batches * L * dt
    if status == "too_short":
        # tau_int is only a lower bound: the needed duration is at least this, the run too short
        out["message"] = own["message"] + "; "
    if n >= min_batches * L and status != "too_short":
        b = int(min_batches)
        var, dof = _nbm(x, b)
        out.update(method="batch_means", batch_s=(n // b) * dt, n_batches=b, dof=dof, sufficient=True)
    elif n >= 2 * L:
        var, dof = _obm(x, L)
        out.update(method="overlapping_batch_means", batch_s=L * dt, n_batches=int(n // L), dof=dof)
        out["message"] += (f"{n * dt:.3g} s < {min_batches} batches of {batch_taus:g} tau_int "
                           f"({out['required_s']:.3g} s): overlapping batch means, {dof:.1f} dof")
        var = float(var)
    else:
        out["message"] += (f"{n * dt:.3g} s is shorter than two batches of {batch_taus:g} tau_int "
                           f"({2 * L * dt:.3g} s): no interval")
        return out
    out["ci95"] = _tq(confidence, out["dof"]) * math.sqrt(max(var, 0.0))
    return out


# ----------------------------------------------------------------------------------------------
# stationarity

def mser_truncation(series, batch: int = 5, min_kept: int = 10) -> dict:
    """MSER-``batch`` truncation point (White 1997, Simulation 69, 323; White, Cobb & Spratt 2000,
    Proc. Winter Simulation Conf.; MSER-5: Franklin & White 2008): the series is reduced to the
    means ``Z_j`` of ``batch`` consecutive samples (an incomplete last batch dropped) and ``d``
    batches are cut where

        MSER(d) = sum_{j > d} (Z_j - Zbar_d)^2 / (nb - d)^2

    (the squared standard error of the kept mean, iid-style) is smallest. Candidates keep at least
    ``min_kept`` batches (with only a few left the statistic can be ~0 by chance). White's rule: a
    minimum in the second half means the series has not settled within it (``settled`` False);
    the cut is then the best one in the first half (a lower bound on the spin-up).

    Returns ``{index, batches_cut, settled}``: ``index`` the first kept sample.
    """
    x = _clean(series)
    nb = x.size // batch
    if nb < max(4, 2 * int(min_kept)):
        return {"index": 0, "batches_cut": 0, "settled": False}
    z = x[: nb * batch].reshape(nb, batch).mean(axis=1)
    s1 = np.cumsum(z[::-1])[::-1]  # sum_{j >= d} z_j
    s2 = np.cumsum((z * z)[::-1])[::-1]
    m = nb - np.arange(nb)
    ss = np.maximum(s2 - s1 * s1 / m, 0.0)
    mser = ss / (m * m)
    last = max(1, nb - int(min_kept))  # candidates d = 0 .. last - 1
    mser = mser[:last]
    half = nb // 2
    d_all = int(np.argmin(mser))
    settled = d_all <= half
    d = d_all if settled else int(np.argmin(mser[: half + 1]))
    return {"index": d * batch, "batches_cut": d, "settled": settled}


def spinup_end(t, observables: dict, min_spinup_s: float, confidence: float = 0.95, batch: int = 5) -> dict:
    """End of the spin-up of a run, jointly over several observables, with the evidence.

    ``t`` (n,) sample times (s, uniform spacing); ``observables``: name -> (n,) series (e.g. the
    driving force density, a flow-profile scalar, the particle-mean ``|Omega_a|`` per axis, an
    orientation order parameter from :func:`orientation_order`). Each gets its MSER-``batch``
    truncation (:func:`mser_truncation`); the spin-up ends at the latest of these and never before
    ``min_spinup_s`` (two viscous times ``R^2/nu``). Evidence per observable: the kept window is cut
    in two halves, each gets its :func:`mean_interval`; the halves ``agree`` when
    ``|m1 - m2| <= sqrt(h1^2 + h2^2)`` (the half-width of the difference of two independent
    means), and ``overlap`` when their intervals overlap (weaker).

    Returns the ``stats.json`` dict ``{method, spinup_s, min_spinup_s, limited_by, window_s,
    steady, observables: {name: {mser_s, settled, first, first_ci95, second, second_ci95, agree,
    overlap}}, message}``. ``steady``: every observable settled within the first half of its
    series (MSER) and every pair of halves agrees.
    """
    t = np.asarray(t, dtype=float).ravel()
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else _NAN
    per = {}
    t_end = []
    for name, s in observables.items():
        s = np.asarray(s, dtype=float).ravel()
        if s.size != n:
            raise ValueError(f"observable {name!r} has {s.size} samples, t has {n}")
        r = mser_truncation(s, batch)
        t_end.append((float(t[r["index"]]) if n else _NAN, name))
        per[name] = {"mser_s": float(t[r["index"]]) if n else _NAN, "settled": r["settled"]}
    t_mser, who = max(t_end) if t_end else (-np.inf, "")
    spin = max(float(min_spinup_s), t_mser)
    limited_by = who if t_mser > min_spinup_s else "min_spinup"
    keep = t > spin - 1e-9 * max(1.0, abs(spin))
    steady = bool(keep.sum() >= 4)
    msgs = []
    for name, s in observables.items():
        s = np.asarray(s, dtype=float).ravel()[keep]
        h = s.size // 2
        a = mean_interval(s[:h], dt, confidence=confidence)
        b = mean_interval(s[s.size - h:], dt, confidence=confidence)
        diff = abs(a["mean"] - b["mean"])
        half = math.hypot(a["ci95"], b["ci95"])
        agree = bool(diff <= half) if np.isfinite(half) else False
        overlap = bool(diff <= a["ci95"] + b["ci95"]) if np.isfinite(half) else False
        per[name].update(first=a["mean"], first_ci95=a["ci95"], second=b["mean"], second_ci95=b["ci95"],
                         agree=agree, overlap=overlap)
        if not per[name]["settled"]:
            msgs.append(f"{name}: MSER minimum in the second half (not settled)")
        if not np.isfinite(half):
            why = a["message"] or b["message"]
            msgs.append(f"{name}: halves of the window too short for an interval ({why})")
        elif not agree:
            msgs.append(f"{name}: halves differ by {diff:.3g} > {half:.3g}")
        steady = steady and agree and per[name]["settled"]
    return {"method": f"MSER-{batch} (White 1997), latest over observables, >= min_spinup_s; halves of the "
                      "kept window compared within the interval of their difference",
            "spinup_s": spin, "min_spinup_s": float(min_spinup_s), "limited_by": limited_by,
            "window_s": float(t[keep][-1] - t[keep][0] + dt) if keep.any() else 0.0, "steady": steady,
            "observables": per, "message": "; ".join(msgs)}


def steady_corrected(spinup: dict, confidence: float = 0.95) -> dict:
    """:func:`spinup_end`'s verdict of one run read again with its ``k`` observables' halves
    compared at a family-wise ``confidence`` (Bonferroni: each at ``1 - (1 - confidence)/k``), so
    that a run is not called unsteady because one of several tests misses by chance.

    Each comparison becomes ``z = z_{(1+confidence)/2} |m1 - m2| / sqrt(h1^2 + h2^2)`` from the
    halves and half-widths ``spinup_end`` stored (the half-widths use Student's t, so this ``z`` is
    if anything too small), against the bound ``z_{1 - (1 - confidence)/(2k)}``. Returns
    ``{verdict, k, bound, worst_z, worst, unsettled}``; ``verdict``: ``steady`` (as stored),
    ``drift`` (some halves differ beyond the bound), ``mser`` (halves within it, but MSER has not
    settled some observable in the first half of its series), ``chance`` (halves differ only at
    ``confidence`` each: steady once corrected), ``no interval`` (halves too short to compare).
    """
    obs = spinup.get("observables") or {}
    k = max(len(obs), 1)
    z_each = float(_st.norm.ppf(0.5 + confidence / 2))
    bound = float(_st.norm.ppf(1 - (1 - confidence) / (2 * k)))
    z = {}
    for name, o in obs.items():
        h = math.hypot(float(o.get("first_ci95") or _NAN), float(o.get("second_ci95") or _NAN))
        if math.isfinite(h) and h > 0:
            z[name] = z_each * abs(float(o["first"]) - float(o["second"])) / h
    worst = max(z, key=z.get) if z else None
    unsettled = [n for n, o in obs.items() if not o.get("settled")]
    if spinup.get("steady"):
        verdict = "steady"
    elif worst is not None and z[worst] > bound:
        verdict = "drift"
    elif unsettled:
        verdict = "mser"
    elif any(v > z_each for v in z.values()):
        verdict = "chance"
    else:
        verdict = "no interval"
    return {"verdict": verdict, "k": len(obs), "bound": bound, "worst_z": z[worst] if worst else _NAN,
            "worst": worst, "unsettled": unsettled}


def viscous_time_s(diameter_mm: float, nu_m2_s: float) -> float:
    """Viscous time ``R^2/nu`` (s) of a pipe of diameter ``diameter_mm``: the e-folding time of
    the slowest decaying Poiseuille start-up mode is ``R^2/(j_0^2 nu)`` = 0.17 ``R^2/nu``, so two
    viscous times leave ``exp(-11.6)`` of the initial transient."""
    r = 0.5e-3 * float(diameter_mm)
    return r * r / float(nu_m2_s)


# ----------------------------------------------------------------------------------------------
# several packings

def combine_seeds(means, halfwidths, dofs, confidence: float = 0.95) -> dict:
    """One case mean and interval from ``k`` independent runs (packings, seeds) of equal length.

    Each run ``i`` gives its mean ``m_i`` and a within-run half-width ``h_i`` with ``nu_i`` dof
    (:func:`mean_interval`), hence a within-run variance ``s_i^2 = (h_i / t_{nu_i})^2``. The case
    mean is the plain average ``M`` (equal-length runs weigh equally; inverse-variance weights
    would trust a run's noisy own error estimate). Its variance:

    - between runs, ``V_b = S^2 / k`` with ``S^2`` the sample variance of the ``m_i``, ``k - 1``
      dof: valid whether or not the packing shifts the mean (it contains both the within-run noise
      and any between-seed variance ``sigma_b^2``, ``E S^2 = mean s_i^2 + sigma_b^2``);
    - within runs, ``V_w = sum s_i^2 / k^2``, dof by Welch-Satterthwaite: what the variance would
      be if all packings had the same mean.

    The half-width is the larger of the between-run interval ``t_{k-1} sqrt(V_b)`` (the method of
    independent replications, Law & Kelton, "Simulation Modeling and Analysis", Ch. 9: exact for
    normal run means whatever the between-seed variance) and the within-run interval of the mean
    ``t_{nu_w} sqrt(V_w)`` (a floor: three seeds that agree by chance must not give an interval
    narrower than the noise of the runs themselves). The interval thus widens as soon as the seeds
    disagree more than their within-run noise says; its coverage is >= nominal for any
    between-seed variance (with 3 seeds: 95-99 %; the Hartung-Knapp "ad hoc" rule
    ``t_{k-1} sqrt(max(V_b, V_w))``, Roever, Knapp & Friede 2015, BMC Med. Res. Methodol. 15, 99,
    covers 100 % and is 25 % wider when the seeds agree). ``tau2 = max(0, S^2 - mean s_i^2)`` is
    the moment estimate of the between-seed variance; Cochran's ``Q = sum (m_i - M)^2 / s_i^2``
    (``chi^2_{k-1}`` if all seeds share one mean) gives ``heterogeneous`` at ``p < 1 - confidence``.

    With ``k = 1`` the run's own interval is returned with ``single_packing`` True.

    Returns ``{mean, ci95, dof, branch, n_seeds, single_packing, seed_sd, seed_range, tau2,
    q, q_p, heterogeneous}``.
    """
    m = np.asarray(means, dtype=float).ravel()
    h = np.asarray(halfwidths, dtype=float).ravel()
    nu = np.asarray(dofs, dtype=float).ravel()
    if not (m.size == h.size == nu.size):
        raise ValueError("means, halfwidths and dofs must have one entry per seed")
    ok = np.isfinite(m)
    m, h, nu = m[ok], h[ok], nu[ok]
    k = m.size
    out = {"mean": _NAN, "ci95": _NAN, "dof": _NAN, "branch": "none", "n_seeds": int(k), "single_packing": k == 1,
           "seed_sd": _NAN, "seed_range": _NAN, "tau2": _NAN, "q": _NAN, "q_p": _NAN, "heterogeneous": False}
    if k == 0:
        return out
    out["mean"] = float(m.mean())
    if k == 1:
        out.update(ci95=float(h[0]), dof=float(nu[0]), branch="single run")
        return out
    tq = np.array([_tq(confidence, d) if np.isfinite(d) and d > 0 else _NAN for d in nu])
    s2 = (h / tq) ** 2
    S2 = float(m.var(ddof=1))
    out.update(seed_sd=math.sqrt(S2), seed_range=float(m.max() - m.min()))
    vb, dof_b = S2 / k, float(k - 1)
    if np.all(np.isfinite(s2)):
        vw = float(s2.sum()) / k ** 2
        dof_w = float(s2.sum() ** 2 / np.sum(s2 ** 2 / nu)) if np.all(s2 > 0) else _NAN
        out["tau2"] = max(0.0, S2 - float(s2.mean()))
        if np.all(s2 > 0):
            q = float(np.sum((m - m.mean()) ** 2 / s2))
            out.update(q=q, q_p=float(_st.chi2.sf(q, k - 1)))
            out["heterogeneous"] = bool(out["q_p"] < 1.0 - confidence)
    else:
        vw, dof_w = _NAN, _NAN
    hb = _tq(confidence, dof_b) * math.sqrt(vb)
    hw = _tq(confidence, dof_w) * math.sqrt(vw) if np.isfinite(vw) and np.isfinite(dof_w) else _NAN
    if np.isfinite(hw) and hw > hb:
        out.update(ci95=hw, dof=dof_w, branch="within-run")
    else:
        out.update(ci95=hb, dof=dof_b, branch="between-seed")
    return out


# ----------------------------------------------------------------------------------------------
# orientation

def rotation_matrices(q) -> np.ndarray:
    """Body -> lab rotation matrices (..., 3, 3) of unit quaternions ``(w, x, y, z)`` (..., 4)
    (Eq. (20); the convention of ``lbmpipe.rigid.quat_to_matrix``): column ``k`` is body axis ``k``
    in the lab frame."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    a = np.empty(q.shape[:-1] + (3, 3))
    a[..., 0, 0] = 1 - 2 * (y * y + z * z)
    a[..., 0, 1] = 2 * (x * y - w * z)
    a[..., 0, 2] = 2 * (x * z + w * y)
    a[..., 1, 0] = 2 * (x * y + w * z)
    a[..., 1, 1] = 1 - 2 * (x * x + z * z)
    a[..., 1, 2] = 2 * (y * z - w * x)
    a[..., 2, 0] = 2 * (x * z - w * y)
    a[..., 2, 1] = 2 * (y * z + w * x)
    a[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return a


def _orientation_tensor(q, shape: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Components ``T_c`` (..., nc) and multiplicities ``w_c`` of the symmetric orientation
    tensor whose full contraction ``sum_c w_c T_c(a) T_c(b)`` is the raw correlation of two
    orientations, and the value of that contraction for uncorrelated (isotropic) orientations.

    cylinder: ``Q = e e`` of the axis ``e`` (body z): ``Q:Q' = (e.e')^2``, isotropic mean 1/3.
    cube: ``T = sum_i e_i e_i e_i e_i`` over the three body axes: ``T:T' = sum_ij (e_i.f_j)^4``,
    3 for equal orientations (or any cube symmetry), 9/5 for independent isotropic ones.
    """
    a = rotation_matrices(q)
    if shape == "cylinder":
        e = a[..., :, 2]
        idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
        comp = np.stack([e[..., i] * e[..., j] for i, j in idx], axis=-1)
        return comp, np.array([1, 1, 1, 2, 2, 2], float), 1.0 / 3.0
    if shape == "cube":
        ex = [(nx, ny, 4 - nx - ny) for nx in range(5) for ny in range(5 - nx)]
        mult = np.array([math.factorial(4) / (math.factorial(i) * math.factorial(j) * math.factorial(k))
                         for i, j, k in ex])
        axes = np.moveaxis(a, -1, -2)  # (..., body axis, lab component)
        pw = [np.ones_like(axes), axes, axes * axes]
        pw += [pw[2] * axes, pw[2] * pw[2]]  # powers 0..4 of every component
        comp = np.stack([np.sum(pw[i][..., 0] * pw[j][..., 1] * pw[k][..., 2], axis=-1) for i, j, k in ex],
                        axis=-1)
        return comp, mult, 9.0 / 5.0
    raise ValueError(f"shape {shape!r}: orientation correlation is defined for 'cylinder' and 'cube'")


def _normalise(raw: np.ndarray, shape: str, rand: float) -> np.ndarray:
    """Map the raw contraction to 1 (same orientation) .. 0 (independent isotropic): for the
    cylinder this is ``P2(e.e') = (3 (e.e')^2 - 1)/2``."""
    top = 1.0 if shape == "cylinder" else 3.0
    return (raw - rand) / (top - rand)


def orientation_order(q, shape: str) -> np.ndarray:
    """Order parameter of the orientations along the pipe axis (lab z), per sample: the mean
    over bodies of ``P2(e_z)`` of the cylinder axis (1 aligned with the pipe, -1/2 across, 0
    isotropic), for cubes ``(sum_k A[2,k]^4 - 3/5)/(2/5)`` (1 with a face normal along z, 0
    isotropic, -1/4 with the body diagonal along z). ``q`` (n_t, n_b, 4)."""
    a = rotation_matrices(q)
    if shape == "cylinder":
        c = a[..., 2, 2]
        return np.mean(1.5 * c * c - 0.5, axis=-1)
    if shape == "cube":
        return np.mean((np.sum(a[..., 2, :] ** 4, axis=-1) - 0.6) / 0.4, axis=-1)
    raise ValueError(f"shape {shape!r}: orientation order is defined for 'cylinder' and 'cube'")


def orientation_memory(q, dt: float, shape: str, frozen_threshold: float = 0.5, c: float = SOKAL_C) -> dict:
    """How far the body orientations move away from where they started.

    ``q`` (n_t, n_b, 4): quaternions of ``n_b`` bodies at ``n_t`` samples ``dt`` apart. The
    correlation of two orientations is 1 when equal (up to the body's symmetry) and 0 when
    independent: for cylinders ``P2(e.e')`` of the axis ``e`` (the nematic autocorrelation, e.g.
    Allen & Tildesley), for cubes the cubic-symmetric invariant ``(sum_ij (e_i.f_j)^4 - 9/5)/(6/5)``
    over the body axes ``e_i``, ``f_j`` (invariant under the 24 rotations of the cube).

    - ``c_start(t)``: body-averaged correlation with the first sample (the packing as it starts to
      move); ``remaining`` = its mean over the last 10 % of the run; ``frozen`` when
      ``remaining > frozen_threshold``.
    - ``c_lag(l)``: correlation averaged over bodies and all time origins (FFT of the tensor
      components of :func:`_orientation_tensor`), the orientation autocorrelation function;
      ``tau_orient_s = dt (1/2 + sum_{l=1}^{M} c_lag(l))`` with Sokal's window, status as in
      :func:`integrated_autocorrelation_time` (``too_short``: the orientations did not decorrelate
      within the run, the value is a lower bound). It is the correlation time to design the
      intervals of orientation statistics with (:func:`mean_interval` ``tau_s``); the spin's is
      often much shorter.

    Returns ``{c_start, c_lag, remaining, frozen, frozen_threshold, tau_orient_s, tau_status,
    e_fold_s}`` (``e_fold_s``: first lag with ``c_lag < 1/e``, NaN if none).
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 3 or q.shape[-1] != 4:
        raise ValueError(f"q must be (n_t, n_b, 4), got {q.shape}")
    nt = q.shape[0]
    comp, w, rand = _orientation_tensor(q, shape)  # (nt, nb, nc)
    c_start = _normalise(np.einsum("tbc,bc,c->t", comp, comp[0], w) / q.shape[1], shape, rand)
    nfft = 1 << int(math.ceil(math.log2(2 * nt)))
    f = np.fft.rfft(comp, nfft, axis=0)
    acf = np.fft.irfft(np.einsum("fbc,c->f", (f * np.conj(f)).real, w), nfft)[:nt]
    raw = acf / (q.shape[1] * (nt - np.arange(nt)))  # unbiased over time origins
    c_lag = _normalise(raw, shape, rand)
    tail = max(1, nt // 10)
    remaining = float(c_start[-tail:].mean())
    # the tail of c_lag rests on few origins; window on the biased form (weights (nt-l)/nt)
    biased = c_lag * (nt - np.arange(nt)) / nt
    tau, m, found = _sokal_window(biased, c)
    tau = max(tau, 0.5)
    if not found:
        status = "too_short"
    elif nt < MIN_TAUS_FOR_TAU * tau:
        status = "short"
    elif tau < 1.0:
        status = "below_sampling"
    else:
        status = "ok"
    below = np.nonzero(c_lag < math.exp(-1.0))[0]
    return {"c_start": c_start, "c_lag": c_lag, "remaining": remaining, "frozen": bool(remaining > frozen_threshold),
            "frozen_threshold": float(frozen_threshold), "tau_orient_s": tau * dt, "tau_status": status,
            "e_fold_s": float(below[0] * dt) if below.size else _NAN}


# ----------------------------------------------------------------------------------------------
# locking and jamming

def body_extents_mm(shape: str, diameter_mm: float | None = None, length_mm: float | None = None,
                    edge_mm: float | None = None) -> np.ndarray:
    """The three principal extents (mm, ascending) of a body: cube ``(a, a, a)``, cylinder
    ``(D, D, L)`` sorted."""
    if shape == "cube":
        return np.array([edge_mm] * 3, dtype=float)
    if shape == "cylinder":
        return np.sort(np.array([diameter_mm, diameter_mm, length_mm], dtype=float))
    raise ValueError(f"shape {shape!r}: extents are defined for 'cylinder' and 'cube'")


def can_pass(shape: str, pipe_diameter_mm: float, **size) -> bool:
    """Can two such bodies be side by side in the pipe cross-section (a necessary condition for
    one to overtake the other)? Each is turned to its thinnest footprint, its two smallest extents
    ``s1 <= s2`` across the pipe (the largest along it). Cylinder with ``D <= L`` (footprint a disk
    of diameter ``D``): two disks fit when ``2 D <= D_pipe``. Otherwise the footprints are
    rectangles ``s1 x s2``, side by side a ``2 s1 x s2`` rectangle, which fits when its diagonal
    ``sqrt((2 s1)^2 + s2^2) <= D_pipe``. Four 24 mm cubes in a 50 mm pipe: ``sqrt(48^2 + 24^2)``
    = 53.7 mm > 50 mm, they cannot pass each other; 16 mm cubes: 35.8 mm, they can."""
    s = body_extents_mm(shape, **size)
    if shape == "cylinder" and size.get("diameter_mm") <= size.get("length_mm"):
        return bool(2.0 * size["diameter_mm"] <= pipe_diameter_mm)
    return bool(math.hypot(2.0 * s[0], s[1]) <= pipe_diameter_mm)


def axial_half_extent_mm(q, shape: str, diameter_mm: float | None = None, length_mm: float | None = None,
                         edge_mm: float | None = None) -> np.ndarray:
    """Half of a body's extent along the pipe axis (lab z), per orientation ``q`` (..., 4):
    cube ``(a/2) sum_k |A[2, k]|``; cylinder with axis ``e``: ``(L/2) |e_z| + (D/2) sqrt(1 - e_z^2)``."""
    a = rotation_matrices(q)
    if shape == "cube":
        return 0.5 * edge_mm * np.abs(a[..., 2, :]).sum(axis=-1)
    if shape == "cylinder":
        ez = np.abs(a[..., 2, 2])
        return 0.5 * length_mm * ez + 0.5 * diameter_mm * np.sqrt(np.clip(1.0 - ez * ez, 0.0, 1.0))
    raise ValueError(f"shape {shape!r}: extents are defined for 'cylinder' and 'cube'")


def unwrap_axial(z, period: float) -> np.ndarray:
    """Continuous axial positions (n_t, n_b) from positions wrapped into ``[0, period)``: a jump
    of more than half a period between two samples is a crossing of the periodic boundary."""
    z = np.asarray(z, dtype=float)
    jumps = np.diff(z, axis=0)
    corr = -period * np.round(jumps / period)
    return z + np.concatenate([np.zeros((1,) + z.shape[1:]), np.cumsum(corr, axis=0)])


def _axial_coverage(z, h, period: float) -> np.ndarray:
    """Fraction of the periodic length covered by the union of the intervals ``[z - h, z + h]``,
    per sample (z, h: (n_t, n_b))."""
    nt, nb = z.shape
    out = np.empty(nt)
    for i in range(nt):  # n_t x n_b log n_b; a few thousand samples of tens of bodies
        lo = np.mod(z[i] - h[i], period)
        length = np.minimum(2.0 * h[i], period)
        # intervals on a circle: split those that wrap, then merge on the line
        hi = lo + length
        wrap = hi > period
        starts = np.concatenate([lo, np.zeros(int(wrap.sum()))])
        ends = np.concatenate([np.minimum(hi, period), hi[wrap] - period])
        order = np.argsort(starts)
        s, e = starts[order], ends[order]
        run_end = np.maximum.accumulate(e)
        gaps = np.maximum(s[1:] - run_end[:-1], 0.0)
        uncovered = s[0] + gaps.sum() + max(period - run_end[-1], 0.0)
        out[i] = 1.0 - uncovered / period
    return out


def _neighbours(x, period: float, k: int) -> np.ndarray:
    """Indices (n_b, k) of the ``k`` nearest bodies of each (periodic in z)."""
    d = x[:, None, :] - x[None, :, :]
    d[..., 2] -= period * np.round(d[..., 2] / period)
    r2 = np.einsum("ijk,ijk->ij", d, d)
    np.fill_diagonal(r2, np.inf)
    return np.argsort(r2, axis=1)[:, :k]


def locking_diagnostics(x, q, shape: str, pipe_diameter_mm: float, period_mm: float, k_neighbours: int = 3,
                        coverage_tol_mm: float = 1.0, retained_locked: float = 0.9, **size) -> dict:
    """Are the bodies locked (never overtake each other, keep their neighbours) or a column?

    ``x`` (n_t, n_b, 3) centres in mm (z wrapped into ``[0, period_mm)``), ``q`` (n_t, n_b, 4);
    ``size``: ``edge_mm`` or ``diameter_mm``, ``length_mm``.

    - ``pairs_passed``: share of body pairs whose axial order changed net over the run: with
      unwrapped ``z`` (:func:`unwrap_axial`), ``floor((z_i - z_j)/period)`` differs between the
      first and the last sample (one overtook the other, modulo whole periods).
    - ``neighbours_retained``: share of the ``k_neighbours`` nearest neighbours (periodic 3-D
      distance) of each body at the start that are still among its ``k`` nearest at the end;
      ``neighbours_random`` = ``k/(n_b-1)``, its value for a full reshuffle.
    - ``can_pass``: :func:`can_pass` (geometry only); ``axial_coverage``: median over samples of
      the fraction of the period covered by the bodies' axial extents
      (:func:`axial_half_extent_mm`); ``spans_period``: share of samples in which the extents
      leave less than ``coverage_tol_mm`` of the period uncovered.
    - ``column``: the bodies cannot pass each other (``can_pass`` False): a column along the
      pipe whose order is fixed by geometry (and, if it ``spans_period``, end to end).
    - ``locked``: no pair passed and ``neighbours_retained >= retained_locked``, or ``column``.
    """
    x = np.asarray(x, dtype=float)
    q = np.asarray(q, dtype=float)
    if x.ndim != 3 or x.shape[-1] != 3 or q.shape[:2] != x.shape[:2]:
        raise ValueError(f"x must be (n_t, n_b, 3) and q (n_t, n_b, 4), got {x.shape} and {q.shape}")
    nt, nb, _ = x.shape
    zu = unwrap_axial(x[..., 2], period_mm)
    iu = np.triu_indices(nb, 1)
    d0 = np.floor((zu[0][:, None] - zu[0][None, :]) / period_mm)[iu]
    d1 = np.floor((zu[-1][:, None] - zu[-1][None, :]) / period_mm)[iu]
    passed = float(np.mean(d0 != d1)) if nb > 1 else 0.0
    k = max(1, min(int(k_neighbours), nb - 1))
    if nb > 1:
        n0, n1 = _neighbours(x[0], period_mm, k), _neighbours(x[-1], period_mm, k)
        kept = float(np.mean([np.isin(n0[i], n1[i]).mean() for i in range(nb)]))
        rnd = k / (nb - 1)
    else:
        kept, rnd = 1.0, 1.0
    h = axial_half_extent_mm(q, shape, **size)
    cov = _axial_coverage(x[..., 2], h, period_mm)
    spans = float(np.mean(cov >= 1.0 - coverage_tol_mm / period_mm))
    passable = can_pass(shape, pipe_diameter_mm, **size)
    column = not passable and nb > 1
    locked = (passed == 0.0 and kept >= retained_locked) or column
    return {"pairs_passed": passed, "neighbours_retained": kept, "neighbours_random": rnd, "k_neighbours": k,
            "can_pass": passable, "axial_coverage": float(np.median(cov)), "spans_period": spans,
            "column": bool(column), "locked": bool(locked)}
