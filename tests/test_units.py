"""Unit conversion and derived lattice parameters (lbmpipe.units, lbmpipe.cost)."""

import math

import pytest

from lbmpipe import cost
from lbmpipe.scene import Scene, SceneError
from lbmpipe.units import CS, Units, derive


def pipe_scene(reynolds: float, flow_rate: float, dt_s: float = 1e-3, mach_limit: float = 0.6, **numerics) -> Scene:
    """The paper's particle-free pipe (paper/reading.md: D = 50 mm, L = 100 mm, dx = 1 mm)."""
    return Scene.model_validate({
        "name": "pipe",
        "domain": {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0},
        "fluid": {"reynolds": reynolds},
        "driving": {"kind": "flow_rate", "flow_rate_m3_s": flow_rate},
        "initial": {"velocity": "parabolic"},
        "numerics": {"dx_mm": 1.0, "dt_s": dt_s, "mach_limit": mach_limit, **numerics},
        "run": {"duration_s": 1.0, "spinup_s": 0.5, "sample_interval_s": 0.05},
    })


def channel_scene(**overrides) -> Scene:
    data = {
        "name": "channel",
        "domain": {"kind": "box", "size_mm": [1.0, 32.0, 1.0], "walls": {"y": "wall"}},
        "fluid": {"viscosity_m2_s": 1e-4},
        "driving": {"kind": "body_force", "acceleration_m_s2": [0.0390625, 0.0, 0.0]},
        "numerics": {"collision": "trt"},
        "run": {"duration_s": 1.0, "spinup_s": 0.5, "sample_interval_s": 0.1},
    }
    for key, value in overrides.items():
        data[key] = {**data.get(key, {}), **value}
    return Scene.model_validate(data)


# paper/reading.md "Derived" table: (Re, Q, dt) -> U (m/s), nu (m^2/s), u_mean, u_max, Ma, tau, with the
# number of digits printed there.
NOTES_TABLE = [
    (9.4, 1.577e-4, 1e-3, "0.0803", "4.27e-4", "0.080", "0.161", "0.28", "1.78"),
    (26.0, 3.154e-4, 1e-3, "0.1606", "3.09e-4", "0.161", "0.321", "0.56", "1.43"),
    (26.0, 3.154e-4, 5e-4, "0.1606", "3.09e-4", "0.080", "0.161", "0.28", "0.96"),
]


def _same_digits(value: float, printed: str) -> bool:
    """``value`` rounds to ``printed`` at the precision ``printed`` is written with."""
    if "e" in printed:
        mantissa, exp = printed.split("e")
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        return f"{value / 10 ** int(exp):.{decimals}f}" == mantissa
    decimals = len(printed.split(".")[1])
    return f"{value:.{decimals}f}" == printed


@pytest.mark.parametrize("re_, q, dt, u_phys, nu_phys, u_mean, u_max, mach, tau", NOTES_TABLE)
def test_pipe_lattice_parameters_reproduce_notes_derived_table(re_, q, dt, u_phys, nu_phys, u_mean, u_max, mach, tau):
    p = derive(pipe_scene(re_, q, dt_s=dt))
    u = p.units
    assert _same_digits(u.velocity_phys(p.u_mean_lu), u_phys)
    assert _same_digits(u.viscosity_phys(p.nu_lu), nu_phys)
    assert _same_digits(p.u_mean_lu, u_mean)
    assert _same_digits(p.u_max_lu, u_max)
    assert _same_digits(p.mach_max, mach)
    assert _same_digits(p.tau, tau)
    # Re = U D / nu is what defined nu, so it must come back exactly.
    assert p.reynolds == pytest.approx(re_, rel=1e-12)
    assert p.shape == (50, 50, 100)


def test_digit_comparison_rejects_a_wrong_value():
    assert not _same_digits(1.7749, "1.78")
    assert not _same_digits(4.31e-4, "4.27e-4")


UNITS = Units(dx_m=0.7e-3, dt_s=3e-4, rho_kg_m3=1234.0)
CONVERSIONS = ["length", "time", "velocity", "acceleration", "viscosity", "flow_rate", "angular_velocity",
               "density", "mass", "force", "torque", "moment_of_inertia", "pressure"]


@pytest.mark.parametrize("quantity", CONVERSIONS)
def test_each_conversion_round_trips(quantity):
    to_lu, to_phys = getattr(UNITS, quantity), getattr(UNITS, quantity + "_phys")
    for x in (-2.5e-3, 0.37, 1.9e4):
        assert to_phys(to_lu(x)) == pytest.approx(x, rel=1e-13)
        assert to_lu(to_phys(x)) == pytest.approx(x, rel=1e-13)


def test_lattice_unit_of_each_quantity_is_its_dimension_built_from_dx_dt_rho():
    dx, dt, rho = UNITS.dx_m, UNITS.dt_s, UNITS.rho_kg_m3
    m = rho * dx**3
    expected_one = {
        "length": dx, "time": dt, "velocity": dx / dt, "acceleration": dx / dt**2, "viscosity": dx**2 / dt,
        "flow_rate": dx**3 / dt, "angular_velocity": 1 / dt, "density": rho, "mass": m,
        "force": m * dx / dt**2, "torque": m * dx**2 / dt**2, "moment_of_inertia": m * dx**2,
        "pressure": m / (dx * dt**2),
    }
    assert set(expected_one) == set(CONVERSIONS)
    for quantity, phys in expected_one.items():
        assert getattr(UNITS, quantity)(phys) == pytest.approx(1.0, rel=1e-12), quantity


def test_conversions_respect_newtons_law_and_lever_arms():
    m_lu, a_lu, r_lu, w_lu = 3.3, 0.012, 7.5, 0.004
    force = UNITS.force_phys(m_lu * a_lu)
    assert force == pytest.approx(UNITS.mass_phys(m_lu) * UNITS.acceleration_phys(a_lu), rel=1e-12)
    assert UNITS.torque_phys(r_lu * m_lu * a_lu) == pytest.approx(UNITS.length_phys(r_lu) * force, rel=1e-12)
    assert UNITS.velocity_phys(w_lu * r_lu) == pytest.approx(UNITS.angular_velocity_phys(w_lu) * UNITS.length_phys(r_lu), rel=1e-12)
    assert UNITS.pressure_phys(m_lu * a_lu / r_lu**2) == pytest.approx(force / UNITS.length_phys(r_lu) ** 2, rel=1e-12)


def test_units_reject_non_positive_scales():
    with pytest.raises(ValueError, match="dt_s"):
        Units(dx_m=1e-3, dt_s=0.0)


def test_tau_from_viscosity_follows_nu_equals_cs2_times_tau_minus_half():
    p = derive(channel_scene())
    assert p.nu_lu == pytest.approx(0.1, rel=1e-12)  # 1e-4 m^2/s * 1 ms / (1 mm)^2
    assert p.tau == pytest.approx(0.8, rel=1e-12)
    assert p.omega == pytest.approx(1 / 0.8, rel=1e-12)


def test_trt_odd_rate_gives_the_requested_magic_parameter():
    p = derive(channel_scene(numerics={"collision": "trt", "trt_magic": 0.25}))
    magic = (1 / p.omega - 0.5) * (1 / p.omega_minus - 0.5)
    assert magic == pytest.approx(0.25, rel=1e-12)
    bgk = derive(channel_scene(numerics={"collision": "bgk"}))
    assert bgk.omega_minus == bgk.omega


def test_the_scene_collision_operator_travels_as_one_relaxation_value_into_the_kernel_spec():
    from lbmpipe.fluid.collision import CollisionOperator
    from lbmpipe.fluid.effects import fluid_spec

    p = derive(channel_scene(numerics={"collision": "trt", "trt_magic": 0.25}))
    assert p.relaxation.operator is CollisionOperator.TRT
    assert (p.omega, p.omega_minus) == (p.relaxation.omega, p.relaxation.omega_minus)
    spec = fluid_spec("D3Q15", p.relaxation, "float64", (0.0, 0.0, 0.0), False, None)
    assert spec.collision is CollisionOperator.TRT and spec.describe().startswith("stream+collide D3Q15 TRT")


def test_an_unknown_collision_operator_is_refused_by_the_scene_and_by_the_kernel_spec():
    from lbmpipe.fluid.kernels import KernelSpec

    with pytest.raises(SceneError, match="numerics.collision.*'mrt'.*bgk.*trt"):
        channel_scene(numerics={"collision": "mrt"})
    with pytest.raises(ValueError, match="unknown collision operator 'mrt': choose bgk or trt"):
        KernelSpec("D3Q15", "mrt")


def test_plane_poiseuille_centre_velocity_is_g_h2_over_8nu():
    p = derive(channel_scene())
    g = p.accel_lu[0]
    assert g == pytest.approx(0.0390625 * 1e-6 / 1e-3, rel=1e-12)
    assert p.u_max_lu == pytest.approx(g * 32**2 / (8 * 0.1), rel=1e-12)
    assert p.u_mean_lu == pytest.approx(2 / 3 * p.u_max_lu, rel=1e-12)
    assert p.mach_max == pytest.approx(p.u_max_lu / math.sqrt(1 / 3), rel=1e-12)


def test_pipe_body_force_centre_velocity_is_hagen_poiseuille():
    scene = Scene.model_validate({
        "name": "p", "domain": {"kind": "pipe", "diameter_mm": 20.0, "length_mm": 4.0},
        "fluid": {"viscosity_m2_s": 1e-4}, "driving": {"kind": "body_force", "acceleration_m_s2": [0, 0, 0.01]},
        "run": {"duration_s": 1.0, "spinup_s": 0.5},
    })
    p = derive(scene)
    g, nu = 0.01 * 1e-6 / 1e-3, 0.1
    assert p.u_max_lu == pytest.approx(g * 10**2 / (4 * nu), rel=1e-12)
    assert p.u_mean_lu == pytest.approx(p.u_max_lu / 2, rel=1e-12)


def test_couette_speed_is_the_wall_speed_and_mean_is_half():
    p = derive(channel_scene(
        domain={"moving_walls": [{"side": "y+", "velocity_m_s": [0.03, 0.0, 0.0]}]},
        driving={"kind": "none", "acceleration_m_s2": [0, 0, 0]},
    ))
    assert p.wall_velocities_lu == {"y+": pytest.approx((0.03, 0.0, 0.0))}
    assert p.u_max_lu == pytest.approx(0.03)
    assert p.u_mean_lu == pytest.approx(0.015)
    assert p.reynolds == pytest.approx(0.03 * 32 / 0.1)


def test_mach_error_suggests_a_dt_that_satisfies_the_limit():
    scene = pipe_scene(26.0, 3.154e-4, mach_limit=0.35)
    with pytest.raises(SceneError) as info:
        derive(scene)
    err = info.value
    assert err.field == "numerics.dt_s"
    assert "Mach 0.556 exceeds numerics.mach_limit 0.35" in err.message
    suggested = float(err.fix.split("<= ")[1].split(" s")[0])
    assert suggested < 1e-3
    p = derive(pipe_scene(26.0, 3.154e-4, dt_s=suggested, mach_limit=0.35))
    assert 0.34 < p.mach_max <= 0.35


def test_vanishing_viscosity_gives_tau_half_error_naming_dt():
    with pytest.raises(SceneError) as info:
        derive(channel_scene(fluid={"viscosity_m2_s": 1e-20}))
    err = info.value
    assert err.field == "numerics.dt_s"
    assert "<= 1/2" in err.message and "Fix:" in str(err)


def test_step_counts_round_durations_and_warn_when_rounding_changes_them():
    p = derive(channel_scene(run={"duration_s": 1.0, "spinup_s": 0.25, "sample_interval_s": 0.01}))
    assert (p.n_steps, p.spinup_steps, p.sample_every) == (1000, 250, 10)
    assert not any("multiple of dt" in w for w in p.warnings)
    q = derive(channel_scene(run={"duration_s": 1.0, "spinup_s": 0.25, "sample_interval_s": 0.0104}))
    assert q.sample_every == 10
    assert any("run.sample_interval_s" in w for w in q.warnings)


def test_pipe_fluid_nodes_approach_the_circle_area():
    for n_d in (8, 50, 200):
        area = cost.pipe_fluid_nodes(n_d, 1)
        assert abs(area - math.pi * n_d**2 / 4) < 2.0 * n_d  # staircase error ~ perimeter
    assert derive(pipe_scene(9.4, 1.577e-4)).fluid_nodes == cost.pipe_fluid_nodes(50, 1) * 100


def test_run_time_estimate_is_node_updates_over_throughput(monkeypatch):
    monkeypatch.setattr(cost.os, "cpu_count", lambda: 8)
    p = derive(pipe_scene(9.4, 1.577e-4))
    ref = cost.estimate_seconds(p, threads=cost.REFERENCE_THREADS)
    assert ref == pytest.approx(p.fluid_nodes * p.n_steps / (cost.DEFAULT_MLUPS * 1e6))
    assert cost.estimate_seconds(p, threads=2 * cost.REFERENCE_THREADS) == pytest.approx(ref / 2)
    assert cost.estimate_seconds(p, threads=cost.REFERENCE_THREADS, mlups=2 * cost.DEFAULT_MLUPS) == pytest.approx(ref / 2)
    assert CS == pytest.approx(math.sqrt(1 / 3))
