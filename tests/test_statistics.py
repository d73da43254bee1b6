"""Per-case statistics: batch-means confidence intervals of correlated series, the |Omega|
statistic with spin-up removed, orientation angles of known rotations, and the aggregated tables."""

import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy.signal import lfilter

from lbmpipe.reproduction import health, steady
from lbmpipe.reproduction import series as SR
from lbmpipe.reproduction import statistics as S
from lbmpipe.particles.rigid import quat_from_axis_angle, quat_mul, rotate
from roundoff import same_file_to_round_off

PARQUET_COLUMNS = ["t_s", "id", "x_mm", "y_mm", "z_mm", "vx_m_s", "vy_m_s", "vz_m_s", "qw", "qx", "qy", "qz",
                   "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_N", "fy_N", "fz_N", "tx_N_m", "ty_N_m", "tz_N_m"]


def _q(axis, deg):
    return quat_from_axis_angle(np.asarray(axis, float), math.radians(deg))


def _ar1(phi, n, reps, mean, rng):
    """``reps`` AR(1) series x_t = phi x_{t-1} + e_t started in the stationary state."""
    e = rng.standard_normal((reps, n))
    e[:, 0] /= math.sqrt(1 - phi * phi)
    return mean + lfilter([1.0], [1.0, -phi], e, axis=1)


def write_case(case_dir, t, omega, q=None, spinup_s=0.3, status="completed", shape="cylinder", summary_extra=None,
               flow=True):
    """A synthetic case directory: ``omega`` (T, N, 3) rad/s at times ``t`` (T,), quaternions
    ``q`` (T, N, 4) (identity if None); with ``flow``, a steady ``flow_rate.csv`` sampled at the
    times after t = 0 (a run samples its particles at t = 0 and its flow one interval later)."""
    case_dir.mkdir(parents=True, exist_ok=True)
    T, N, _ = omega.shape
    if q is None:
        q = np.zeros((T, N, 4))
        q[..., 0] = 1.0
    rows = {c: np.zeros(T * N) for c in PARQUET_COLUMNS}
    rows["t_s"] = np.repeat(t, N)
    rows["id"] = np.tile(np.arange(N), T)
    for k, c in enumerate(("qw", "qx", "qy", "qz")):
        rows[c] = q[..., k].ravel()
    for k, a in enumerate("xyz"):
        rows[f"w{a}_rad_s"] = omega[..., k].ravel()
    rows["z_mm"] = np.tile(np.linspace(10, 90, N), T)
    df = pd.DataFrame(rows)
    df["id"] = df["id"].astype("int64")
    df.to_parquet(case_dir / "particles.parquet", index=False)
    st = pd.DataFrame({"id": np.arange(N), "shape": shape, "diameter_mm": 16.0 if shape == "cylinder" else np.nan,
                       "length_mm": 16.0 if shape == "cylinder" else np.nan,
                       "edge_mm": 8.0 if shape == "cube" else np.nan, "density_kg_m3": 1000.0, "fixed": False})
    st.to_csv(case_dir / "particles_static.csv", index=False)
    summary = {"status": status, "message": "", "steps": 100, "simulated_seconds": float(t[-1]), "wall_seconds": 2.0,
               "mlups": 1.5, "spinup_s": spinup_s,
               "particles": {"count": N, "concentration_target": 0.3, "concentration_achieved": 0.29,
                             "collisions": True}}
    summary.update(summary_extra or {})
    (case_dir / "summary.json").write_text(json.dumps(summary))
    (case_dir / "profile.csv").write_text("r_mm,uz_m_s,uz_poiseuille_m_s,nodes\n1.0,0.1,0.1,4\n")
    if flow:
        tf = np.asarray(t, float)[np.asarray(t, float) > 0]
        pd.DataFrame({"t_s": tf, "q_m3_s": 1e-4, "force_density_N_m3": 700.0 + 0.1 * np.sin(tf),
                      "max_density_deviation": 0.01, "core_velocity_ratio": 1.6 + 0.01 * np.cos(tf)}).to_csv(
            case_dir / "flow_rate.csv", index=False)


CYL_CFG = {"reynolds": 26, "particles": {"shape": "cylinder", "diameter_mm": 16, "length_mm": 16,
                                         "concentration": 0.30}}
CUBE_CFG = {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.30}}


# ---------------------------------------------------------------- time-series statistics

def test_batch_means_ci_covers_true_mean_of_correlated_ar1_and_is_wider_than_iid():
    rng = np.random.default_rng(1)
    phi, n, reps, mu = 0.9, 4000, 200, 3.0
    x = _ar1(phi, n, reps, mu, rng)
    res = [S.batch_means(s, n_batches=10) for s in x]
    means = np.array([r[0] for r in res])
    hw = np.array([r[1] for r in res])
    assert all(r[2] == 10 for r in res)
    np.testing.assert_allclose(means, x.mean(axis=1))
    coverage = np.mean(np.abs(means - mu) <= hw)
    iid_hw = 1.96 * x.std(axis=1, ddof=1) / math.sqrt(n)
    iid_coverage = np.mean(np.abs(means - mu) <= iid_hw)
    # nominal 95 %; the iid interval ignores sqrt((1+phi)/(1-phi)) = 4.4 of variance inflation
    assert 0.88 <= coverage <= 0.99, coverage
    assert iid_coverage < 0.6, iid_coverage
    assert np.median(hw / iid_hw) > 3.0


def test_batch_means_too_short_series_gives_nan_half_width():
    m, hw, b = S.batch_means(np.array([1.0, 2.0, 3.0]))
    assert m == pytest.approx(2.0) and math.isnan(hw) and b == 0
    assert math.isnan(S.batch_means(np.array([]))[0])
    # few samples: at least two per batch
    assert S.batch_means(np.arange(8.0), n_batches=10)[2] == 4


# ---------------------------------------------------------------- orientation angles

def test_cylinder_rotated_30_deg_about_x_has_axis_angle_30():
    q = np.array([_q([1, 0, 0], 30.0), _q([0, 1, 0], -30.0), _q([1, 0, 0], 150.0), _q([1, 1, 0], 90.0)])
    np.testing.assert_allclose(S.cylinder_axis_angle(q), [30.0, 30.0, 30.0, 90.0], atol=1e-9)


def test_cylinder_axis_angle_agrees_with_rigid_rotation_of_body_z():
    rng = np.random.default_rng(3)
    from lbmpipe.particles.rigid import random_quaternions
    q = random_quaternions(50, rng)
    ref = [math.degrees(math.acos(abs(rotate(qi, np.array([0.0, 0.0, 1.0]))[2]))) for qi in q]
    np.testing.assert_allclose(S.cylinder_axis_angle(q), ref, atol=1e-9)


@pytest.mark.parametrize("deg, projected, axis3d", [(20.0, 20.0, 20.0), (70.0, 20.0, 20.0), (-20.0, 20.0, 20.0),
                                                    (45.0, 45.0, 45.0), (90.0, 0.0, 0.0)])
def test_cube_turned_about_camera_axis_y_shows_folded_angle(deg, projected, axis3d):
    q = _q([0, 1, 0], deg)[None, :]
    assert S.cube_projected_angle(q)[0] == pytest.approx(projected, abs=1e-9)
    assert S.cube_axis_angle(q)[0] == pytest.approx(axis3d, abs=1e-9)


def test_cube_angles_are_invariant_under_the_cube_symmetry_group_and_bounded():
    rng = np.random.default_rng(4)
    from lbmpipe.particles.rigid import random_quaternions
    q = random_quaternions(200, rng)
    for axis in ([1, 0, 0], [0, 1, 0], [0, 0, 1]):  # body quarter turns map the cube onto itself
        q2 = np.array([quat_mul(qi, _q(axis, 90.0)) for qi in q])
        np.testing.assert_allclose(S.cube_projected_angle(q2), S.cube_projected_angle(q), atol=1e-9)
        np.testing.assert_allclose(S.cube_axis_angle(q2), S.cube_axis_angle(q), atol=1e-9)
    p, a = S.cube_projected_angle(q), S.cube_axis_angle(q)
    assert p.min() >= 0 and p.max() <= 45.0
    assert a.min() >= 0 and a.max() <= S.CUBE_MAX_AXIS_ANGLE_DEG + 1e-9
    # the body diagonal along the pipe axis is the farthest a cube axis can be from it
    diag = quat_from_axis_angle(np.cross([1.0, 1.0, 1.0], [0.0, 0.0, 1.0]),
                                math.acos(1 / math.sqrt(3)))[None, :]
    assert S.cube_axis_angle(diag)[0] == pytest.approx(54.7356, abs=1e-3)


# ---------------------------------------------------------------- per-case statistics

def _omega_case(tmp_path):
    """3 particles, 10 samples t = 0, 0.1, ..., 0.9; spin-up 0.3 s carries huge |Omega| that
    must not leak into the statistics (the sample at exactly t = 0.3 s is spin-up)."""
    t = np.round(np.arange(10) * 0.1, 10)
    rng = np.random.default_rng(5)
    omega = rng.normal(0.0, 1.0, (10, 3, 3))
    omega[t <= 0.3] = 1000.0
    write_case(tmp_path / "c", t, omega, spinup_s=0.3)
    return t, omega


def test_mean_abs_omega_is_mean_over_particles_and_samples_after_spinup_with_mean_interval(tmp_path):
    t, omega = _omega_case(tmp_path)
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    keep = t > 0.3 + 1e-12
    # no scene in the summary: no viscous time, the run's own spin-up is the floor; 6 samples left
    assert s["samples"] == 6 and s["spinup_s"] == 0.3 and s["status"] == "completed"
    for k, a in enumerate("xyz"):
        hand = np.abs(omega[keep, :, k]).mean()
        assert s["mean_abs_omega_rad_s"][a] == pytest.approx(hand, rel=1e-8)  # the series keeps 9 digits
        series = np.abs(omega[keep, :, k]).mean(axis=1)
        ref = steady.mean_interval(series, 0.1)
        assert s["ci95_rad_s"][a] == pytest.approx(ref["ci95"], nan_ok=True)
        assert s["omega_intervals"][a]["sufficient"] is False  # 6 samples are never 20 batches of 5 tau_int
        assert s["omega_intervals"][a]["required_s"] > 0.6
    assert s["n_particles"] == 3
    assert (s["shape"], s["size_label"], s["reynolds"], s["concentration"]) == ("cylinder", "16x16 mm", 26.0, 0.3)


def test_spinup_argument_overrides_summary_and_removes_samples(tmp_path):
    t, omega = _omega_case(tmp_path)
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG, spinup_s=0.65)
    assert s["samples"] == 3
    assert s["mean_abs_omega_rad_s"]["y"] == pytest.approx(np.abs(omega[t > 0.65, :, 1]).mean())
    # no spin-up at all: the large spin-up values are then in the mean
    s0 = S.case_statistics("c", tmp_path / "c", CYL_CFG, spinup_s=-1.0)
    assert s0["samples"] == 10 and s0["mean_abs_omega_rad_s"]["x"] > 100


def test_statistics_are_nan_when_the_case_did_not_complete(tmp_path):
    t = np.arange(10) * 0.1
    write_case(tmp_path / "c", t, np.ones((10, 2, 3)), status="unstable")
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    assert s["status"] == "unstable" and s["samples"] == 0
    assert all(math.isnan(v) for v in s["mean_abs_omega_rad_s"].values())
    assert S.case_statistics("gone", tmp_path / "gone", CYL_CFG)["status"] == "not run"


def test_orientation_histogram_fractions_of_known_angles(tmp_path):
    # 2 cylinders: one at 5 deg to the pipe axis, one at 45 deg in the first 2 samples then 85 deg
    t = np.arange(5) * 0.1
    q = np.zeros((5, 2, 4))
    q[:, 0] = _q([1, 0, 0], 5.0)
    q[:, 1] = _q([0, 1, 0], 85.0)
    q[:2, 1] = _q([0, 1, 0], 45.0)
    write_case(tmp_path / "c", t, np.zeros((5, 2, 3)), q=q, spinup_s=0.05)
    h = S.orientation_histograms(tmp_path / "c", "cylinder", 0.05)
    assert list(h.columns) == S.ORIENTATION_COLUMNS
    assert set(h.kind) == {"cyl_axis_angle"} and len(h) == 9
    frac = dict(zip(h.bin_lo_deg.round(6), h.fraction))
    # samples after spin-up: t = 0.1..0.4 (4) x 2 particles = 8; the 45 deg one only at t = 0.1
    assert frac[0.0] == pytest.approx(4 / 8)
    assert frac[40.0] == pytest.approx(1 / 8)
    assert frac[80.0] == pytest.approx(3 / 8)
    assert h.fraction.sum() == pytest.approx(1.0)
    assert h.loc[h.bin_lo_deg == 0.0, "ci95"].iloc[0] == pytest.approx(0.0)  # always exactly half


def test_write_case_outputs_writes_stats_json_and_cube_orientation_csv(tmp_path):
    t = np.arange(8) * 0.1
    q = np.zeros((8, 4, 4))
    q[:] = _q([0, 1, 0], 68.0)  # folds to 22 deg, clear of the 5 deg bin edges
    write_case(tmp_path / "c", t, np.ones((8, 4, 3)), q=q, shape="cube", spinup_s=0.0)
    S.write_case_outputs("c", tmp_path / "c", CUBE_CFG)
    s = json.loads((tmp_path / "c" / "stats.json").read_text())
    for key in ("case", "status", "shape", "size_label", "reynolds", "concentration", "collisions", "n_particles",
                "spinup_s", "samples", "mean_abs_omega_rad_s", "ci95_rad_s", "n_batches", "tau_int_s"):
        assert key in s
    assert s["mean_abs_omega_rad_s"]["z"] == pytest.approx(1.0)
    assert s["orientation"]["cube_projected_angle"]["mean_deg"] == pytest.approx(22.0)
    o = pd.read_csv(tmp_path / "c" / "orientation.csv")
    assert set(o.kind) == {"cube_projected_angle", "cube_axis_angle"}
    proj = o[o.kind == "cube_projected_angle"]
    assert proj.loc[(proj.bin_lo_deg <= 22) & (proj.bin_hi_deg > 22), "fraction"].iloc[0] == pytest.approx(1.0)


# ---------------------------------------------------------------- aggregated tables

def test_aggregate_lists_every_particle_case_including_unpackable_and_not_run(tmp_path):
    fid = tmp_path / "smoke"
    t = np.arange(8) * 0.1
    write_case(fid / "cases" / "a", t, np.full((8, 2, 3), 0.5), spinup_s=0.1)
    unp = fid / "cases" / "b"
    unp.mkdir(parents=True)
    (unp / "summary.json").write_text(json.dumps({
        "status": "unpackable", "message": "not run: the packing could not be made", "steps": 0, "spinup_s": 0.0,
        "packing": {"concentration_target": 0.5, "concentration_reached": 0.2839, "message": "cannot pack"},
        "particles": {"count": 0, "concentration_target": 0.5, "concentration_achieved": 0.2839}}))
    pd.DataFrame(columns=PARQUET_COLUMNS, dtype="float64").to_parquet(unp / "particles.parquet", index=False)
    cases = {"flow": {"reynolds": 26}, "a": CYL_CFG,
             "b": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 24, "concentration": 0.5}},
             "c": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.3},
                   "collisions": False}}
    S.write_case_outputs("a", fid / "cases" / "a", CYL_CFG)
    S.aggregate(fid, cases)
    av = pd.read_csv(fid / "tables" / "angular_velocity.csv")
    assert list(av.columns) == S.ANGULAR_VELOCITY_COLUMNS
    assert list(av.case) == ["a", "b", "c"]  # the particle-free case is not a particle case
    a, b, c = (av.set_index("case").loc[k] for k in "abc")
    assert a.status == "completed" and a.omega_x == pytest.approx(0.5) and a.samples == 6
    assert b.status == "unpackable" and math.isnan(b.omega_x) and b.concentration_achieved == pytest.approx(0.2839)
    assert b.size_label == "24 mm" and b.concentration == 0.5
    assert c.status == "not run" and not c.collisions
    # one packing: counted, and no seed-to-seed spread
    assert a.n_seeds == 1 and c.n_seeds == 0 and math.isnan(a.seed_sd_x)
    pk = pd.read_csv(fid / "tables" / "packing.csv").set_index("case")
    assert list(pk.columns) == S.PACKING_COLUMNS[1:]
    assert pk.loc["b", "status"] == "unpackable" and pk.loc["b", "concentration_achieved"] == pytest.approx(0.2839)
    assert pk.loc["b", "concentration_target"] == 0.5 and "packing" in pk.loc["b", "message"]
    o = pd.read_csv(fid / "tables" / "orientation.csv")
    assert set(o.case) == {"a", "b", "c"}
    assert o[o.case == "a"].fraction.sum() == pytest.approx(1.0)
    assert o[o.case == "b"].fraction.isna().all() and set(o[o.case == "b"].kind) == {"cube_projected_angle",
                                                                                   "cube_axis_angle"}
    osum = pd.read_csv(fid / "tables" / "orientation_summary.csv")
    assert len(osum) == 1 + 2 + 2
    assert osum.loc[osum.case == "a", "mean_deg"].iloc[0] == pytest.approx(0.0, abs=1e-6)


def test_runtime_table_reads_benchmarks_and_tolerates_missing_ones(tmp_path):
    fid = tmp_path / "smoke"
    write_case(fid / "cases" / "a", np.arange(4) * 0.1, np.zeros((4, 1, 3)))
    (fid / "benchmarks").mkdir(parents=True)
    (fid / "benchmarks" / "a.simulate.tsv").write_text(
        "s\th:m:s\tmax_rss\tmax_vms\n3.5\t0:00:03\t280.5\t1700\n")
    out = S.runtime_table(fid, {"a": CYL_CFG, "b": {"reynolds": 26}})
    rt = pd.read_csv(out).set_index("case")
    assert list(rt.columns) == S.RUNTIME_COLUMNS[1:]
    assert rt.loc["a", "wall_s"] == 3.5 and rt.loc["a", "max_rss_mb"] == 280.5
    assert rt.loc["a", "s_per_step"] == pytest.approx(2.0 / 100)  # summary wall_seconds / steps
    assert rt.loc["b", "status"] == "not run" and math.isnan(rt.loc["b", "wall_s"])


# ---------------------------------------------------------------- steady state and diagnostics

PIPE_SCENE = {"scene": {"domain": {"diameter_mm": 50.0, "length_mm": 100.0}, "fluid": {"viscosity_m2_s": None},
                        "numerics": {"dx_mm": 2.0}, "driving": {"flow_rate_m3_s": 1.0e-4}},
              "lattice": {"nu_lu": 0.5, "units": {"dx_m": 1.0e-3, "dt_s": 1.0e-3}}}  # nu 5e-4 m^2/s: R^2/nu 1.25 s


def _long_case(tmp_path, n=600, dt=0.02, transient_s=0.0, frozen=True, summary_extra=None, seed=3, core="steady"):
    """4 cylinders, AR(1) spins about 1 rad/s (with a decaying spin-up excess lasting ``transient_s``),
    orientations fixed (frozen) or tumbling with random steps; flow_rate.csv with the driving force."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(1, n + 1) * dt, 9)
    omega = 1.0 + 0.2 * _ar1(0.5, n, 12, 0.0, rng).T.reshape(n, 4, 3)
    if transient_s:
        omega += 5.0 * np.exp(-t / (transient_s / 5.0))[:, None, None]
    q = np.zeros((n, 4, 4))
    q[..., 0] = 1.0
    if not frozen:
        steps = rng.normal(0.0, 0.3, (n, 4, 4))
        q = np.cumsum(steps, axis=0) + q
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
    write_case(tmp_path / "c", t, omega, q=q, spinup_s=0.1, summary_extra={**PIPE_SCENE, **(summary_extra or {})})
    force = 700.0 + 5.0 * rng.standard_normal(n) + (300.0 * np.exp(-t / (transient_s / 5.0)) if transient_s else 0.0)
    cols = {"t_s": t, "q_m3_s": 1e-4, "force_density_N_m3": force, "max_density_deviation": np.linspace(0.01, 0.05, n)}
    if core == "steady":
        cols["core_velocity_ratio"] = 1.6 + 0.002 * rng.standard_normal(n)
    elif core is not None:
        cols["core_velocity_ratio"] = core(t, rng)
    pd.DataFrame(cols).to_csv(tmp_path / "c" / "flow_rate.csv", index=False)
    return t


def test_spinup_is_never_shorter_than_two_viscous_times_and_records_the_halves_evidence(tmp_path):
    _long_case(tmp_path)  # stationary from the start: MSER cuts almost nothing
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    sp = s["spinup"]
    assert sp["viscous_time_s"] == pytest.approx(0.025 ** 2 / 5e-4)
    assert s["spinup_s"] >= 2 * sp["viscous_time_s"] - 1e-9
    assert {"force_density", "mean_abs_omega_x", "orientation_order"} <= set(sp["observables"])
    for ev in sp["observables"].values():
        assert {"first", "second", "first_ci95", "second_ci95", "agree"} <= set(ev)
    assert sp["profile_observable"] == S.PROFILE_OBSERVABLE


def test_spinup_detected_on_a_transient_longer_than_two_viscous_times(tmp_path):
    _long_case(tmp_path, n=1500, transient_s=6.0)
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    assert s["spinup"]["limited_by"] != "min_spinup"
    assert s["spinup_s"] > 2 * s["spinup"]["viscous_time_s"]
    # the |Omega| mean is of the stationary part (1 rad/s plus |AR noise| bias), not of the spin-up excess
    assert s["mean_abs_omega_rad_s"]["x"] < 1.2


def test_run_shorter_than_two_viscous_times_is_flagged_not_steady(tmp_path):
    _long_case(tmp_path, n=100)  # 2 s < 2.5 s
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    assert s["spinup"]["steady"] is False and s["spinup_s"] == 0.1
    assert s["spinup"]["required_s"] == pytest.approx(2.5)
    assert "not steady" in s["flags"]


def test_a_flow_profile_still_blunting_sets_the_spinup_through_the_core_velocity_ratio(tmp_path):
    # force and spins stationary from the start; the profile's core velocity ratio relaxes from
    # Poiseuille's 1.75 to 1.5 with a 1 s time constant: the spin-up must wait for the profile
    def core(t, rng):
        return 1.5 + 0.25 * np.exp(-t / 1.0) + 0.002 * rng.standard_normal(t.size)

    _long_case(tmp_path, n=1200, core=core)
    sp = S.case_statistics("c", tmp_path / "c", CYL_CFG)["spinup"]
    assert "core_velocity_ratio" in sp["observables"] and sp["profile_observable"] == S.PROFILE_OBSERVABLE
    assert sp["limited_by"] == "core_velocity_ratio"
    assert sp["spinup_s"] > 3.0  # 0.25 exp(-t) falls below the noise (0.002) only after ~5 s
    _long_case(tmp_path / "old", core=None)  # a flow_rate.csv without the column: a loud error, not a quiet omission
    with pytest.raises(SR.SeriesError, match="core_velocity_ratio"):
        S.case_statistics("c", tmp_path / "old" / "c", CYL_CFG)


def test_fixed_orientations_are_frozen_and_tumbling_ones_are_not(tmp_path):
    _long_case(tmp_path / "a", frozen=True)
    _long_case(tmp_path / "b", frozen=False)
    fa = S.case_statistics("c", tmp_path / "a" / "c", CYL_CFG)
    fb = S.case_statistics("c", tmp_path / "b" / "c", CYL_CFG)
    assert fa["frozen"]["frozen"] and fa["frozen"]["remaining"] == pytest.approx(1.0)
    assert not fb["frozen"]["frozen"] and fb["frozen"]["remaining"] < 0.5
    assert "frozen" in fa["flags"] and "frozen" not in fb["flags"]
    assert fa["frozen"]["threshold"] == health.thresholds()["frozen_remaining"]


def test_orientation_interval_is_designed_on_the_orientation_correlation_time_not_the_spins(tmp_path):
    _long_case(tmp_path, frozen=False)
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    tau_o = s["orientation_memory"]["tau_orient_s"]
    iv = s["orientation"]["cyl_axis_angle"]["interval"]
    assert tau_o > max(s["tau_int_s"].values())  # a random walk of orientations decorrelates slower than the spins
    assert iv["tau_int_s"] >= tau_o - 1e-12


def test_mass_drift_beyond_its_threshold_makes_the_case_unhealthy(tmp_path):
    _long_case(tmp_path, summary_extra={"mass_drift_rel": 0.0485, "steps": 600,
                                        "collisions": {"rotation_projections": 3, "max_overlap_after_lu": 0.01}})
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    h = s["health"]
    assert h["density_deviation_median"] == pytest.approx(0.03) and h["density_deviation_max"] == pytest.approx(0.05)
    assert h["rotation_projection_share"] == pytest.approx(3 / 600)
    assert any(i.startswith("mass drift") for i in h["issues"]) and "unhealthy" in s["flags"]
    _long_case(tmp_path / "ok", summary_extra={"mass_drift_rel": 1e-6})
    assert "unhealthy" not in S.case_statistics("c", tmp_path / "ok" / "c", CYL_CFG)["flags"]


def test_a_fluid_volume_change_without_a_density_drift_is_healthy(tmp_path):
    # collisions off: overlapping bodies cover fewer nodes, the total fluid mass grows by 4.85 %
    # with the mean density per fluid node unchanged to 4e-4: not a leak
    _long_case(tmp_path, summary_extra={"mass_drift_rel": 0.0485, "density_drift_rel": 3.8e-4,
                                        "fluid_nodes_change_rel": 0.0484})
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    assert s["health"]["mass_drift_rel"] == pytest.approx(3.8e-4)
    assert not any(i.startswith("mass drift") for i in s["health"]["issues"])
    _long_case(tmp_path / "leak", summary_extra={"mass_drift_rel": 0.0485, "density_drift_rel": 0.0485})
    assert "unhealthy" in S.case_statistics("c", tmp_path / "leak" / "c", CYL_CFG)["flags"]


def test_renormalised_mass_is_judged_against_the_mass_through_the_pipe_not_the_runs_length():
    # a steady loss of 1.5e-5 of the mass per step, made up by the correction: 0.9 of the initial
    # mass over 60,000 steps and 0.09 over 6,000, the same 1.9 % of what flowed through the pipe
    lat = {"fluid_nodes": 197600, "flow_rate_lu": 157.7}
    long_ = {"steps": 60000, "lattice": lat, "mass_correction": {"mass_added_rel": 0.9}}
    short = {"steps": 6000, "lattice": lat, "mass_correction": {"mass_added_rel": 0.09}}
    assert health.mass_corrected_throughflow(long_) == pytest.approx(health.mass_corrected_throughflow(short))
    assert health.mass_corrected_throughflow(long_) == pytest.approx(0.9 * 197600 / (157.7 * 60000))
    limits = health.thresholds()["health"]
    h = health.run_health({"status": "completed", **long_}, None, limits)
    assert any(i.startswith("mass renormalised / mass through the pipe") for i in h["issues"])
    h = health.run_health({"status": "completed", **long_, "mass_correction": {"mass_added_rel": 0.1}}, None, limits)
    assert h["issues"] == [] and h["mass_corrected_rel"] == pytest.approx(0.1)


def test_a_mass_correction_that_took_mass_out_is_judged_by_its_size_and_keeps_its_sign():
    # a dilute run whose correction removed 1 % of the mass: the limit sees 0.01, the table says -0.01
    lat = {"fluid_nodes": 197600, "flow_rate_lu": 157.7}
    s = {"status": "completed", "steps": 60000, "lattice": lat, "mass_correction": {"mass_added_rel": -0.01}}
    h = health.run_health(s, None, health.thresholds()["health"])
    assert h["mass_corrected_rel"] == pytest.approx(0.01) and health.mass_corrected_signed(s) == pytest.approx(-0.01)
    assert h["mass_corrected_throughflow"] == pytest.approx(0.01 * 197600 / (157.7 * 60000))
    assert np.isnan(health.mass_corrected_signed({"status": "completed"}))


def test_the_run_health_table_keeps_the_sign_of_the_mass_correction_and_stats_json_does_not_change(tmp_path):
    run = tmp_path / "c" / "seed1"
    run.mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"status": "completed", "steps": 100,
                                                  "mass_correction": {"mass_added_rel": -0.02}}))
    row = health.health_row("c/seed1", run, health.thresholds()["health"])
    assert row["mass_corrected_rel"] == pytest.approx(0.02) and row["mass_corrected_signed"] == pytest.approx(-0.02)
    # the health block a run's stats.json embeds is unchanged (stats.json rebuilds bit for bit from the series)
    assert "mass_corrected_signed" not in health.run_health(json.loads((run / "summary.json").read_text()), None,
                                                            health.thresholds()["health"])


def test_run_health_table_has_a_row_per_case_and_flags_the_one_beyond_a_threshold(tmp_path):
    fid = tmp_path / "lvl"
    _long_case(fid / "cases", summary_extra={"mass_drift_rel": 0.05})
    cases = {"c": CYL_CFG, "gone": CYL_CFG}
    S.write_case_outputs("c", fid / "cases" / "c", CYL_CFG)
    health.run_health_table(fid, cases)
    t = pd.read_csv(fid / "tables" / "run_health.csv").set_index("case")
    assert list(t.index) == ["c", "gone"]
    assert "unhealthy" in t.loc["c", "flags"] and "mass drift" in t.loc["c", "issues"]
    assert t.loc["gone", "status"] == "not run"


def test_diagnostics_thresholds_are_validated_by_check_config():
    import copy
    from pathlib import Path

    import yaml
    from lbmpipe.reproduction.cases import config_problems

    root = Path(__file__).resolve().parents[1]
    cfg = yaml.safe_load((root / "config.yaml").read_text())
    bad = copy.deepcopy(cfg)
    bad["diagnostics"]["frozen_remaining"] = 2.0
    schema = root / "workflow" / "schemas" / "config.schema.yaml"
    assert any("diagnostics.frozen_remaining" in p for p in config_problems(bad, schema))


def test_statistics_of_a_run_without_trajectory_or_series_refuse_and_keep_the_committed_ones(tmp_path):
    _long_case(tmp_path, frozen=False)
    case = tmp_path / "c"
    S.write_case_outputs("c", case, CYL_CFG)
    before = (case / "stats.json").read_text(), (case / "orientation.csv").read_text()
    (case / "particles.parquet").unlink()
    (case / SR.SERIES).unlink()
    with pytest.raises(SR.SeriesError, match="rerun the case"):
        S.write_case_outputs("c", case, CYL_CFG)
    assert ((case / "stats.json").read_text(), (case / "orientation.csv").read_text()) == before


# ---------------------------------------------------------------- the compact series and the alignment

def test_force_and_profile_series_enter_the_stationarity_test_although_particles_start_at_t0(tmp_path):
    # particles sampled from t = 0, flow_rate.csv one interval later: both fluid series still count
    t = np.round(np.arange(0, 601) * 0.02, 9)
    rng = np.random.default_rng(9)
    write_case(tmp_path / "c", t, 1.0 + 0.1 * rng.standard_normal((t.size, 3, 3)), spinup_s=0.1,
               summary_extra=PIPE_SCENE)
    sp = S.case_statistics("c", tmp_path / "c", CYL_CFG)["spinup"]
    assert {"force_density", "core_velocity_ratio"} <= set(sp["observables"])


def test_a_particle_sample_without_its_fluid_sample_is_a_loud_error(tmp_path):
    t = np.round(np.arange(0, 50) * 0.02, 9)
    write_case(tmp_path / "c", t, np.ones((t.size, 2, 3)), spinup_s=0.1)
    fr = pd.read_csv(tmp_path / "c" / "flow_rate.csv")
    fr.drop(index=20).to_csv(tmp_path / "c" / "flow_rate.csv", index=False)
    with pytest.raises(SR.SeriesError, match="do not align"):
        S.case_statistics("c", tmp_path / "c", CYL_CFG)
    (tmp_path / "c" / "flow_rate.csv").unlink()
    with pytest.raises(SR.SeriesError, match="flow_rate.csv is missing"):
        S.case_statistics("c", tmp_path / "c", CYL_CFG)


def test_statistics_rebuilt_from_the_committed_series_without_the_trajectory_are_identical(tmp_path):
    _long_case(tmp_path, frozen=False)
    d = tmp_path / "c"
    S.write_case_outputs("c", d, CYL_CFG)
    with_traj = (d / "stats.json").read_text(), (d / "orientation.csv").read_text()
    (d / "particles.parquet").unlink()  # what a fresh clone has: series.csv.gz, trajectory.json, last_frame.csv
    S.write_case_outputs("c", d, CYL_CFG)
    assert ((d / "stats.json").read_text(), (d / "orientation.csv").read_text()) == with_traj
    s = json.loads(with_traj[0])
    # the half-window sensitivity is there, over the later half of the samples
    assert s["second_half"]["samples"] == s["samples"] // 2 + s["samples"] % 2
    assert s["second_half"]["spinup_s"] > s["spinup_s"]


def test_series_statistics_agree_with_the_direct_trajectory_averages(tmp_path):
    t, omega = _omega_case(tmp_path)
    s = S.case_statistics("c", tmp_path / "c", CYL_CFG)
    keep = t > 0.3 + 1e-12
    for k, a in enumerate("xyz"):  # 9 significant digits in the series
        assert s["mean_abs_omega_rad_s"][a] == pytest.approx(np.abs(omega[keep, :, k]).mean(), rel=1e-8)


def test_a_changed_spinup_without_the_trajectory_is_a_loud_error_not_stale_diagnostics(tmp_path):
    _long_case(tmp_path, frozen=False)
    d = tmp_path / "c"
    S.write_case_outputs("c", d, CYL_CFG)
    (d / "particles.parquet").unlink()
    with pytest.raises(SR.SeriesError, match="rerun the case"):
        S.case_statistics("c", d, CYL_CFG, spinup_s=5.0)
    (d / SR.SERIES).unlink()
    with pytest.raises(SR.SeriesError, match="series.csv.gz is missing"):
        S.case_statistics("c", d, CYL_CFG)


def test_every_committed_series_rebuilds_its_runs_committed_statistics_to_round_off(tmp_path):
    # what a fresh clone can do without the trajectories: stats.json and orientation.csv from
    # series.csv.gz, trajectory.json, flow_rate.csv and summary.json alone; on the processor that
    # wrote them the text is the same, on another one the numbers agree to round-off
    import shutil
    from pathlib import Path

    import yaml
    from lbmpipe.reproduction.cases import run_case

    root = Path(__file__).resolve().parents[1]
    config = yaml.safe_load((root / "config.yaml").read_text())
    runs = sorted((root / "results").glob(f"*/cases/*/seed*/{SR.SERIES}"))
    assert runs, "no committed run has its compact series"
    for series in runs:
        src = series.parent
        run = f"{src.parent.name}/{src.name}"
        dst = tmp_path / src.parent.parent.parent.name / run
        dst.mkdir(parents=True)
        for name in ("summary.json", "flow_rate.csv", "particles_static.csv", "last_frame.csv", SR.SERIES, SR.TRAJECTORY):
            shutil.copy2(src / name, dst / name)
        S.write_case_outputs(run, dst, run_case(config, run)[1], config)
        for name in ("stats.json", "orientation.csv"):
            same_file_to_round_off(dst / name, src / name)


def test_half_window_level_takes_every_runs_second_half_and_says_when_a_run_lacks_it(tmp_path):
    from lbmpipe.reproduction import half_window as HW

    _long_case(tmp_path / "lvl" / "cases", frozen=False)  # one run: cases/c
    d = tmp_path / "lvl" / "cases" / "c"
    S.write_case_outputs("c", d, CYL_CFG)
    config = {"cases": {"c": CYL_CFG}}
    s = json.loads((d / "stats.json").read_text())
    level = HW.half_window_level(tmp_path / "lvl", config, tmp_path / "half")
    av = pd.read_csv(level / "tables" / "angular_velocity.csv").set_index("case")
    assert av.loc["c", "omega_x"] == pytest.approx(s["second_half"]["mean_abs_omega_rad_s"]["x"])
    assert av.loc["c", "omega_x"] != pytest.approx(s["mean_abs_omega_rad_s"]["x"], rel=1e-9)
    verdicts = HW.second_half_verdicts(tmp_path / "lvl", config)
    assert len(verdicts) == 14 and not any(str(v).startswith("not available") for v in verdicts)
    del s["second_half"]  # a run made before the compact series
    (d / "stats.json").write_text(json.dumps(s))
    assert set(HW.second_half_verdicts(tmp_path / "lvl", config)) == {
        "not available: 1 of 1 runs lack the second-half statistics (made before the compact series; rerun them, "
        "e.g. c); no comparison on the 0 cases complete"}


def test_half_window_look_ahead_judges_each_claim_on_the_cases_whose_runs_all_have_their_second_half(tmp_path):
    # three cylinder cases (Re 26 and 9.4 at 30 %, Re 26 at 50 %); the 50 % run lacks its second half
    import shutil

    from lbmpipe.reproduction import half_window as HW
    from lbmpipe.reproduction.claims import evaluate_claims

    cases = {"a": CYL_CFG, "b": {**CYL_CFG, "reynolds": 9.4},
             "c": {**CYL_CFG, "particles": {**CYL_CFG["particles"], "concentration": 0.5}}}
    for i, (name, cfg) in enumerate(cases.items()):
        _long_case(tmp_path / "work" / name, frozen=False, seed=3 + i)
        shutil.copytree(tmp_path / "work" / name / "c", tmp_path / "lvl" / "cases" / name)
        S.write_case_outputs(name, tmp_path / "lvl" / "cases" / name, cfg)
    s = json.loads((tmp_path / "lvl" / "cases" / "c" / "stats.json").read_text())
    del s["second_half"]
    (tmp_path / "lvl" / "cases" / "c" / "stats.json").write_text(json.dumps(s))
    verdicts = HW.second_half_verdicts(tmp_path / "lvl", {"cases": cases})
    assert all(v.startswith("not available: 1 of 3 runs lack the second-half statistics") for v in verdicts)
    # on a and b alone: the second halves' verdict beside the full windows', each as the level of a and b gives it
    ab = {"cases": {k: cases[k] for k in "ab"}}
    half = HW.half_window_level(tmp_path / "lvl", ab, tmp_path / "half")
    full = HW.half_window_level(tmp_path / "lvl", ab, tmp_path / "full", half_window=False)
    h, f = (evaluate_claims(d, ab["cases"]).set_index("claim")["verdict"] for d in (half, full))
    assert verdicts[1].endswith(f"; on the 2 cases complete: {h[1]} (full window: {f[1]})")
    # the full-window rebuild of a and b holds their committed statistics
    av = pd.read_csv(full / "tables" / "angular_velocity.csv").set_index("case")
    a = json.loads((tmp_path / "lvl" / "cases" / "a" / "stats.json").read_text())
    assert av.loc["a", "omega_x"] == pytest.approx(a["mean_abs_omega_rad_s"]["x"])
    # claim 2 compares concentrations: the 30 % cases alone compare nothing of it
    assert verdicts[2].endswith("; no comparison on the 2 cases complete")
