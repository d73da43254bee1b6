"""Statistics of steady results (lbmpipe.reproduction.steady) on synthetic series with a known answer: AR(1)
processes (known tau_int and mean), transients, several 'packings' with a real offset between them,
rotational diffusion (known decay rate of the orientation correlation) and bodies that do or do
not overtake each other."""

import json
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from lbmpipe.reproduction import steady


def ar1(phi: float, n: int, rng, reps: int | None = None) -> np.ndarray:
    """Stationary AR(1) of unit variance and zero mean: x_t = phi x_{t-1} + e_t;
    tau_int = (1 + phi) / (2 (1 - phi)) samples."""
    shape = (n,) if reps is None else (reps, n)
    e = rng.standard_normal(shape) * math.sqrt(1.0 - phi * phi)
    e[..., 0] /= math.sqrt(1.0 - phi * phi)  # start in the stationary distribution
    return lfilter([1.0], [1.0, -phi], e, axis=-1)


def tau_ar1(phi: float) -> float:
    return (1.0 + phi) / (2.0 * (1.0 - phi))


# ----------------------------------------------------------------------------------------------
# tau_int

@pytest.mark.parametrize("phi", [0.5, 0.9, 0.97])
def test_sokal_tau_int_of_ar1_within_15_percent_of_exact(phi):
    rng = np.random.default_rng(11)
    r = steady.integrated_autocorrelation_time(ar1(phi, 100_000, rng), dt=0.02)
    assert r["status"] == "ok"
    assert r["tau_int_s"] == pytest.approx(0.02 * tau_ar1(phi), rel=0.15)
    # the Madras-Sokal error estimate is of the size of the actual error's scale
    assert 0.0 < r["tau_err_s"] < 0.15 * r["tau_int_s"]


def test_tau_int_of_series_shorter_than_its_correlation_is_flagged_not_trusted():
    rng = np.random.default_rng(12)
    r = steady.integrated_autocorrelation_time(ar1(0.995, 150, rng))  # tau = 200 samples > n
    assert r["status"] in ("too_short", "short")
    assert r["message"]


def test_tau_int_of_white_noise_is_below_the_sampling_interval():
    rng = np.random.default_rng(13)
    r = steady.integrated_autocorrelation_time(rng.standard_normal(5000), dt=0.02)
    assert r["status"] == "below_sampling"
    assert r["tau_int_s"] == pytest.approx(0.01, rel=0.2)  # dt/2


def test_tau_int_of_constant_series_is_undefined():
    r = steady.integrated_autocorrelation_time(np.ones(100))
    assert r["status"] == "undefined" and math.isnan(r["tau_int_s"])


# ----------------------------------------------------------------------------------------------
# intervals

def test_batch_means_95_interval_covers_ar1_mean_in_90_to_99_percent_of_300_replicas():
    rng = np.random.default_rng(21)
    phi, n = 0.9, 4000  # tau_int 9.5 samples: 20 batches of 200 = 21 tau_int each
    x = ar1(phi, n, rng, reps=300)
    hits, methods = [], set()
    for row in x:
        r = steady.mean_interval(row, dt=1.0)
        methods.add(r["method"])
        hits.append(abs(r["mean"]) <= r["ci95"])
    assert methods == {"batch_means"}
    assert 0.90 <= np.mean(hits) <= 0.99


def test_batch_means_use_20_batches_of_at_least_5_tau_int():
    rng = np.random.default_rng(22)
    r = steady.mean_interval(ar1(0.9, 4000, rng), dt=0.02)
    assert r["sufficient"] and r["n_batches"] == 20 and r["dof"] == 19
    assert r["batch_s"] >= 5 * r["tau_int_s"]
    assert r["required_s"] <= r["duration_s"]


def test_short_series_falls_back_to_overlapping_batch_means_and_states_required_duration():
    rng = np.random.default_rng(23)
    phi = 0.95  # tau_int 19.5 samples: 20 batches of 5 tau need ~2000 samples
    r = steady.mean_interval(ar1(phi, 600, rng), dt=0.02)
    assert not r["sufficient"]
    assert r["method"] == "overlapping_batch_means"
    assert r["required_s"] > r["duration_s"]
    assert 0.0 < r["dof"] < 19 and r["ci95"] > 0
    assert "overlapping" in r["message"]


def test_overlapping_batch_means_cover_short_ar1_series():
    rng = np.random.default_rng(24)
    x = ar1(0.9, 600, rng, reps=300)  # 600 samples = 63 tau_int < 100 needed
    hits = [abs(r["mean"]) <= r["ci95"] for r in (steady.mean_interval(row, 1.0) for row in x)]
    assert 0.88 <= np.mean(hits) <= 0.99


def test_given_slower_correlation_time_lengthens_the_batches():
    rng = np.random.default_rng(25)
    x = rng.standard_normal(2000)
    own = steady.mean_interval(x, dt=0.02)
    slow = steady.mean_interval(x, dt=0.02, tau_s=1.0)  # e.g. the orientation correlation time
    assert own["sufficient"] and not slow["sufficient"]
    assert slow["tau_status"] == "given" and slow["required_s"] == pytest.approx(100.0)


# ----------------------------------------------------------------------------------------------
# stationarity

def test_mser_truncation_lands_after_exponential_transient():
    rng = np.random.default_rng(31)
    n, T, amp, phi = 4000, 100.0, 3.0, 0.5
    t = np.arange(n)
    transient = amp * np.exp(-t / T)
    se = lambda m: math.sqrt(2 * tau_ar1(phi) / m)  # noqa: E731 -- standard error of a mean of m samples
    assert transient.mean() > 2.5 * se(n)  # keeping the transient would bias the mean visibly
    for _ in range(20):
        r = steady.mser_truncation(transient + ar1(phi, n, rng))
        d = r["index"]
        assert r["settled"]
        assert T / 2 <= d <= n // 4  # cut inside the decay (1.8 noise SDs left at T/2), not later
        assert transient[d:].mean() < 1.5 * se(n - d)  # what is left biases the kept mean by < 1.5 SE


def test_mser_keeps_a_stationary_series_nearly_whole():
    rng = np.random.default_rng(32)
    cut = [steady.mser_truncation(ar1(0.5, 4000, rng))["index"] for _ in range(20)]
    assert np.median(cut) <= 200


def test_mser_says_a_drifting_series_has_not_settled():
    rng = np.random.default_rng(33)
    x = np.linspace(0.0, 10.0, 2000) + 0.1 * rng.standard_normal(2000)
    assert not steady.mser_truncation(x)["settled"]


def test_spinup_end_is_the_latest_observable_and_never_before_the_minimum():
    rng = np.random.default_rng(34)
    dt, n = 0.02, 5000
    t = dt * np.arange(1, n + 1)
    force = 700 + 300 * np.exp(-t / 0.5) + 5 * ar1(0.8, n, rng)  # fast transient
    omega = 1.2 - 0.6 * np.exp(-t / 4.0) + 0.02 * ar1(0.9, n, rng)  # slow spin-up
    obs = {"force": force, "omega_x": omega}
    r = steady.spinup_end(t, obs, min_spinup_s=3.0)
    assert r["limited_by"] == "omega_x"
    assert r["spinup_s"] == pytest.approx(r["observables"]["omega_x"]["mser_s"])
    assert r["observables"]["omega_x"]["mser_s"] > r["observables"]["force"]["mser_s"]
    assert r["spinup_s"] > 4.0 and r["steady"]
    assert all(v["agree"] for v in r["observables"].values())
    json.dumps(r)  # goes into stats.json as is
    r2 = steady.spinup_end(t, obs, min_spinup_s=40.0)
    assert r2["spinup_s"] == 40.0 and r2["limited_by"] == "min_spinup"


def test_spinup_end_is_not_steady_when_halves_of_the_window_disagree():
    rng = np.random.default_rng(35)
    dt, n = 0.02, 3000
    t = dt * np.arange(1, n + 1)
    drift = 1.0 + 0.05 * t + 0.05 * ar1(0.8, n, rng)  # still drifting: the halves differ
    r = steady.spinup_end(t, {"omega_z": drift}, min_spinup_s=1.0)
    assert not r["steady"]
    assert not r["observables"]["omega_z"]["agree"]


def test_stationary_runs_called_unsteady_by_one_of_four_tests_are_mostly_chance_and_a_drift_is_not():
    # four independent stationary AR(1) observables per run: at 95 % each, about 1 - 0.95^4 = 19 %
    # of runs have some pair of halves that differ; corrected over the four (Bonferroni) about 5 %
    # are left as drift (10 % allows for 200 replicas and MSER's choice of window), while a real
    # drift stays one
    rng = np.random.default_rng(53)
    dt, n, reps = 0.02, 2000, 200
    t = dt * np.arange(1, n + 1)
    verdicts = []
    for _ in range(reps):
        obs = {f"o{i}": 1.0 + ar1(0.5, n, rng) for i in range(4)}
        r = steady.spinup_end(t, obs, min_spinup_s=0.0)
        c = steady.steady_corrected(r)
        assert c["k"] == 4 and c["bound"] == pytest.approx(2.498, abs=1e-3)
        if not any(o["agree"] for o in r["observables"].values()) and r["steady"]:
            raise AssertionError("steady with disagreeing halves")
        verdicts.append((c["verdict"], any(not o["agree"] for o in r["observables"].values())))
    raw = sum(d for _, d in verdicts) / reps
    drift = sum(v == "drift" for v, _ in verdicts) / reps
    assert 0.10 <= raw <= 0.35
    assert drift <= 0.10 and drift < raw and any(v == "chance" for v, _ in verdicts)
    # a series that still drifts stays unsteady whatever the correction: its halves differ far
    # beyond the bound, or (a strong trend) MSER finds no settled window
    for slope in (0.002, 0.05):
        obs = {"o0": 1.0 + slope * t + 0.05 * ar1(0.8, n, rng), **{f"o{i}": 1.0 + ar1(0.5, n, rng) for i in range(1, 4)}}
        c = steady.steady_corrected(steady.spinup_end(t, obs, min_spinup_s=0.0))
        assert c["verdict"] in ("drift", "mser"), (slope, c)
        assert c["verdict"] == "mser" or (c["worst"] == "o0" and c["worst_z"] > c["bound"])


# ----------------------------------------------------------------------------------------------
# several packings

def test_seed_combined_interval_covers_a_real_between_seed_offset_where_pooling_undercovers():
    rng = np.random.default_rng(41)
    phi, n, k, reps = 0.7, 500, 3, 200
    sd_run_mean = math.sqrt((1 + phi) / (1 - phi) / n)
    sigma_b = 2.0 * sd_run_mean  # packings shift the mean by 2 within-run standard errors
    hit_comb, hit_pool = [], []
    for _ in range(reps):
        x = ar1(phi, n, rng, reps=k) + rng.normal(0.0, sigma_b, (k, 1))
        runs = [steady.mean_interval(row, 1.0) for row in x]
        c = steady.combine_seeds([r["mean"] for r in runs], [r["ci95"] for r in runs], [r["dof"] for r in runs])
        hit_comb.append(abs(c["mean"]) <= c["ci95"])
        # naive: all samples of all seeds as one series, within-run noise only
        s2 = np.array([(r["ci95"] / steady._tq(0.95, r["dof"])) ** 2 for r in runs])
        hit_pool.append(abs(c["mean"]) <= 1.96 * math.sqrt(s2.sum()) / k)
    assert np.mean(hit_comb) >= 0.92
    assert np.mean(hit_pool) < 0.80


def test_seed_interval_widens_when_seeds_disagree_beyond_their_noise():
    agree = steady.combine_seeds([1.00, 1.01, 0.99], [0.05, 0.05, 0.05], [19, 19, 19])
    disagree = steady.combine_seeds([1.0, 1.3, 0.7], [0.05, 0.05, 0.05], [19, 19, 19])
    assert agree["branch"] == "within-run" and not agree["heterogeneous"]
    assert disagree["branch"] == "between-seed" and disagree["heterogeneous"]
    assert disagree["ci95"] > 5 * agree["ci95"]
    assert disagree["seed_sd"] == pytest.approx(0.3) and disagree["seed_range"] == pytest.approx(0.6)
    # never narrower than the runs' own noise of the mean
    assert agree["ci95"] >= 1.96 * (0.05 / 2.093) / math.sqrt(3) * 0.99


def test_single_seed_is_flagged_single_packing():
    c = steady.combine_seeds([1.2], [0.1], [19])
    assert c["single_packing"] and c["ci95"] == 0.1 and math.isnan(c["seed_sd"])


# ----------------------------------------------------------------------------------------------
# orientation

def _quat_mul(a, b):
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def _rotvec_quat(v):
    ang = np.linalg.norm(v, axis=-1, keepdims=True)
    axis = np.where(ang > 0, v / np.where(ang > 0, ang, 1.0), 0.0)
    return np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * axis], axis=-1)


def rotational_diffusion(n_t, n_b, d_rot_dt, rng):
    """Quaternions (n_t, n_b, 4) of bodies in free rotational diffusion (lab-frame random
    rotations, ``<theta_a^2> = 2 D dt`` per axis and step), from random initial orientations."""
    q0 = rng.standard_normal((n_b, 4))
    q = np.empty((n_t, n_b, 4))
    q[0] = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    steps = _rotvec_quat(rng.normal(0.0, math.sqrt(2 * d_rot_dt), (n_t, n_b, 3)))
    for i in range(1, n_t):
        q[i] = _quat_mul(steps[i], q[i - 1])
    return q


@pytest.mark.parametrize("shape,rank", [("cylinder", 2), ("cube", 4)])
def test_orientation_correlation_time_of_rotational_diffusion_is_one_over_l_l_plus_1_d(shape, rank):
    # a rank-l orientation correlation of free rotational diffusion decays as exp(-l(l+1) D t):
    # P2 of the cylinder axis at 6 D, the cubic (l = 4) invariant at 20 D
    rng = np.random.default_rng(51)
    dt, d = 0.02, 0.25  # 1/(6D) = 0.67 s, 1/(20D) = 0.2 s
    q = rotational_diffusion(2000, 40, d * dt, rng)
    r = steady.orientation_memory(q, dt, shape)
    assert r["tau_status"] == "ok"
    assert r["tau_orient_s"] == pytest.approx(1.0 / (rank * (rank + 1) * d), rel=0.2)
    assert not r["frozen"] and abs(r["remaining"]) < 0.2
    assert r["c_lag"][0] == pytest.approx(1.0) and r["c_start"][0] == pytest.approx(1.0)


@pytest.mark.parametrize("shape", ["cylinder", "cube"])
def test_orientations_rattling_in_place_are_frozen(shape):
    rng = np.random.default_rng(52)
    n_t, n_b = 500, 20
    q0 = rng.standard_normal((n_b, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    jitter = _rotvec_quat(rng.normal(0.0, math.radians(5.0), (n_t, n_b, 3)))  # +-5 deg about rest
    q = _quat_mul(jitter, np.broadcast_to(q0, (n_t, n_b, 4)))
    r = steady.orientation_memory(q, 0.02, shape, frozen_threshold=0.5)
    assert r["frozen"] and r["remaining"] > 0.8


def test_cube_orientation_correlation_ignores_the_cubes_own_symmetry():
    rng = np.random.default_rng(53)
    q0 = rng.standard_normal((10, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    quarter = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])  # 90 deg about body z
    q = np.stack([q0, _quat_mul(q0, np.broadcast_to(quarter, q0.shape))])
    assert steady.orientation_memory(q, 1.0, "cube")["c_start"][1] == pytest.approx(1.0)
    assert steady.orientation_memory(q, 1.0, "cylinder")["c_start"][1] == pytest.approx(1.0)


def test_orientation_order_parameter_of_aligned_and_isotropic_bodies():
    rng = np.random.default_rng(54)
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, 5, 1))
    assert steady.orientation_order(ident, "cylinder")[0] == pytest.approx(1.0)
    assert steady.orientation_order(ident, "cube")[0] == pytest.approx(1.0)
    q = rng.standard_normal((1, 20000, 4))
    assert abs(steady.orientation_order(q, "cylinder")[0]) < 0.02
    assert abs(steady.orientation_order(q, "cube")[0]) < 0.02


# ----------------------------------------------------------------------------------------------
# locking

def test_two_24mm_cubes_cannot_pass_in_a_50mm_pipe_but_16mm_cubes_and_cylinders_can():
    assert not steady.can_pass("cube", 50.0, edge_mm=24.0)
    assert steady.can_pass("cube", 50.0, edge_mm=16.0)
    assert steady.can_pass("cylinder", 50.0, diameter_mm=16.0, length_mm=24.0)
    assert not steady.can_pass("cylinder", 50.0, diameter_mm=30.0, length_mm=30.0)


def test_axial_extent_of_a_turned_cube_and_cylinder():
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    tilt = np.array([math.cos(math.pi / 8), math.sin(math.pi / 8), 0.0, 0.0])  # 45 deg about x
    assert steady.axial_half_extent_mm(ident, "cube", edge_mm=24.0) == pytest.approx(12.0)
    assert steady.axial_half_extent_mm(tilt, "cube", edge_mm=24.0) == pytest.approx(12.0 * math.sqrt(2))
    lying = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])  # axis across the pipe
    assert steady.axial_half_extent_mm(lying, "cylinder", diameter_mm=8.0, length_mm=16.0) == pytest.approx(4.0)


def test_unwrap_axial_recovers_motion_through_the_periodic_boundary():
    z_true = np.linspace(0.0, 350.0, 200)[:, None] + np.array([0.0, 30.0])
    z = steady.unwrap_axial(np.mod(z_true, 100.0), 100.0)
    assert np.allclose(z - z[0], z_true - z_true[0])


def test_column_of_large_cubes_is_locked_and_a_sheared_suspension_is_not():
    rng = np.random.default_rng(61)
    n_t, period = 400, 100.0
    t = np.arange(n_t)[:, None]
    # four 24 mm cubes moving together along the axis, rattling 1 mm, tumbling slowly
    z0 = np.array([10.0, 35.0, 60.0, 85.0])
    x = np.zeros((n_t, 4, 3))
    x[..., 0] = rng.normal(0.0, 1.0, (n_t, 4))
    x[..., 2] = np.mod(z0 + 0.8 * t + rng.normal(0.0, 1.0, (n_t, 4)), period)
    q = rotational_diffusion(n_t, 4, 1e-4, rng)
    col = steady.locking_diagnostics(x, q, "cube", 50.0, period, edge_mm=24.0)
    assert col["column"] and col["locked"] and col["pairs_passed"] == 0.0
    assert col["axial_coverage"] > 0.95
    # 40 small cubes in Poiseuille-like shear: the central ones overtake those near the wall
    nb = 40
    r = 20.0 * np.sqrt(rng.random(nb))
    phi = 2 * math.pi * rng.random(nb)
    u = 2.0 * (1.0 - (r / 25.0) ** 2)
    y = np.zeros((n_t, nb, 3))
    y[..., 0], y[..., 1] = r * np.cos(phi), r * np.sin(phi)
    y[..., 2] = np.mod(period * rng.random(nb) + u * t, period)
    sheared = steady.locking_diagnostics(y, rotational_diffusion(n_t, nb, 1e-3, rng), "cube", 50.0, period,
                                         edge_mm=8.0)
    assert sheared["can_pass"] and not sheared["column"] and not sheared["locked"]
    assert sheared["pairs_passed"] > 0.2
    assert sheared["neighbours_retained"] < 0.5
