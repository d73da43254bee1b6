"""Fluid solver against analytic flows: Poiseuille (pipe and plane), Couette, conservation, control."""

import numba
import numpy as np
import pytest

from fluid_cases import omega_minus, observed_order, pipe_poiseuille, run_to_steady
from lbmpipe.fluid import boundaries as bnd
from lbmpipe.fluid import effects as fx
from lbmpipe.fluid import observables as obs
from lbmpipe.fluid.kernels import KernelSpec, render
from lbmpipe.fluid.lattice import get_lattice
from lbmpipe.solver import Simulation

PIPE_SIZES = [8, 12, 16, 20, 24, 32]


@pytest.fixture(autouse=True)
def one_thread():
    # These domains are tiny: on a loaded 2-core machine the wake-up of a second thread costs
    # more than the work. Thread-count independence is tested separately below.
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(old)


@pytest.fixture(scope="module")
def pipe_errors():
    return {scheme: [pipe_poiseuille(d, scheme, tol=1e-9)[0] for d in PIPE_SIZES]
            for scheme in ("bounce_back", "bouzidi")}


def test_pipe_poiseuille_staircase_wall_converges_at_first_order(pipe_errors):
    errs = pipe_errors["bounce_back"]
    order = observed_order(PIPE_SIZES, errs)
    print("staircase L2 errors", dict(zip(PIPE_SIZES, np.round(errs, 5))), "order", round(order, 2))
    assert 0.6 < order < 1.7
    assert errs[-1] < 0.03  # D = 32 nodes


def test_pipe_poiseuille_interpolated_wall_converges_at_second_order(pipe_errors):
    errs = pipe_errors["bouzidi"]
    order = observed_order(PIPE_SIZES, errs)
    print("Bouzidi L2 errors", dict(zip(PIPE_SIZES, np.round(errs, 5))), "order", round(order, 2))
    assert order > 1.6
    assert errs[-1] < 4e-3


def test_interpolated_wall_beats_staircase_at_every_resolution(pipe_errors):
    for d, stair, bouz in zip(PIPE_SIZES, pipe_errors["bounce_back"], pipe_errors["bouzidi"]):
        assert bouz < stair, d


@pytest.mark.parametrize("lattice", ["D3Q19", "D3Q27"])
def test_other_velocity_sets_solve_pipe_poiseuille_as_well(lattice):
    err, _ = pipe_poiseuille(16, "bouzidi", lattice=lattice, tol=1e-9)
    assert err < 0.02


def test_float32_pipe_poiseuille_agrees_with_float64():
    e64, s64 = pipe_poiseuille(12, "bouzidi", tol=1e-9)
    e32, s32 = pipe_poiseuille(12, "bouzidi", precision="float32", tol=1e-5)
    assert s32.f.dtype == np.float32
    assert abs(e32 - e64) < 2e-3


def _channel(walls_axis: int, n: int, tau: float, collision: str, force=(0.0, 0.0, 0.0), moving=None):
    size = [1, 1, 1]
    size[walls_axis] = n
    walls = [False, False, False]
    walls[walls_axis] = True
    grid = bnd.box_grid(get_lattice("D3Q15"), tuple(size), tuple(walls))
    effects = fx.wall_effects(grid, "bounce_back", moving or {})
    sim = Simulation.build(grid, collision=collision, omega=1 / tau, omega_minus=omega_minus(tau), force=force,
                     extra_effects=effects)
    return sim, grid


@pytest.mark.parametrize("tau", [0.6, 0.9, 1.7])
def test_plane_poiseuille_is_exact_to_round_off_with_trt_magic_parameter(tau):
    # With Lambda = 3/16 the half-way bounce-back wall sits exactly half-way for any tau (Ginzburg):
    # the parabola u = g y (H - y) / (2 nu) is reproduced at the nodes to machine precision.
    H = 10
    nu = (tau - 0.5) / 3.0
    g = 8.0 * nu * 0.02 / H**2
    sim, grid = _channel(1, H, tau, "trt", force=(g, 0.0, 0.0))
    y = grid.positions()[1][1:-1]
    exact = g * y * (H - y) / (2.0 * nu)
    sim.set_equilibrium(1.0, (np.pad(exact, 1)[None, :, None], 0.0, 0.0))
    run_to_steady(sim, chunk=500, tol=1e-13)
    _, ux, uy, _ = sim.moments()
    np.testing.assert_allclose(ux[0, 1:-1, 0], exact, rtol=1e-10, atol=0)
    assert np.abs(uy[0, 1:-1, 0]).max() < 1e-13


def test_plane_poiseuille_with_bgk_has_the_known_tau_dependent_wall_slip():
    # BGK + bounce-back places the wall at a tau-dependent distance: at tau = 1.7 the error is
    # visible (a reference for what TRT removes).
    H, tau = 16, 1.7
    nu = (tau - 0.5) / 3.0
    g = 8.0 * nu * 0.02 / H**2
    sim, grid = _channel(1, H, tau, "bgk", force=(g, 0.0, 0.0))
    run_to_steady(sim, chunk=500, tol=1e-13)
    _, ux, _, _ = sim.moments()
    y = grid.positions()[1][1:-1]
    exact = g * y * (H - y) / (2.0 * nu)
    err = obs.relative_l2(ux[0, 1:-1, 0], exact)
    assert 1e-3 < err < 0.1


@pytest.mark.parametrize("collision", ["trt", "bgk"])
def test_couette_flow_is_linear_to_round_off(collision):
    H, U, tau = 10, 0.03, 0.8
    sim, grid = _channel(2, H, tau, collision, moving={"z+": (U, 0.0, 0.0)})
    z = grid.positions()[2][1:-1]
    run_to_steady(sim, chunk=500, tol=1e-12)
    _, ux, _, uz = sim.moments()
    np.testing.assert_allclose(ux[0, 0, 1:-1], U * z / H, rtol=1e-10, atol=1e-15)
    assert np.abs(uz[0, 0, 1:-1]).max() < 1e-14


def test_mass_is_conserved_to_round_off_over_ten_thousand_steps():
    lat = get_lattice("D3Q15")
    for scheme in ("bounce_back", "bouzidi"):
        grid = bnd.pipe_grid(lat, 10, 4)
        sim = Simulation.build(grid, collision="bgk", omega=1 / 0.7, force=(0.0, 0.0, 2e-5),
                         extra_effects=fx.wall_effects(grid, scheme, {}))
        m0 = sim.mass()
        sim.step(10_000)
        # Collision, forcing and both walls conserve mass exactly in exact arithmetic; what is left
        # is rounding, ~1e-16 per node update (measured 1.0e-12 relative here for the staircase).
        assert abs(sim.mass() - m0) / m0 < 1e-11, scheme


def test_flow_rate_controller_holds_q_within_a_tenth_of_a_percent():
    lat = get_lattice("D3Q15")
    grid = bnd.pipe_grid(lat, 16, 4)
    tau = 0.9
    nu = (tau - 0.5) / 3.0
    q_target = 0.02 * np.pi * grid.radius**2  # mean velocity 0.02
    ctl = fx.FlowRateControl(q_target, grid.radius, nu, grid.shape[2])
    sim = Simulation.build(grid, collision="bgk", omega=1 / tau, force=(0.0, 0.0, ctl.f_ref), flux=True,
                     extra_effects=fx.wall_effects(grid, "bounce_back", {}) + [ctl])
    tau_p = grid.radius**2 / (nu * 2.405**2)
    sim.step(int(20 * tau_p))
    _, _, _, uz = sim.moments()
    q = uz[grid.fluid].sum() / grid.shape[2]
    assert abs(q - q_target) / q_target < 1e-3
    assert abs(ctl.q - q_target) / q_target < 1e-3
    # The staircase wall is not at R, so the force differs from Hagen-Poiseuille's: the controller
    # had to find it.
    assert abs(sim.force[2] - ctl.f_ref) / ctl.f_ref > 1e-3


def test_scene_without_force_or_walls_assembles_only_the_bare_sweep():
    grid = bnd.box_grid(get_lattice("D3Q15"), (8, 8, 8), (False, False, False))
    sim = Simulation.build(grid, collision="bgk", omega=1.0, extra_effects=fx.wall_effects(grid, "bounce_back", {}))
    assert [e.phase for e in sim.effects] == ["fluid"]
    # The generated sweep holds no arithmetic for absent effects: no force, no TRT odd rate, no flux.
    bare = render(KernelSpec("D3Q15", "bgk", forcing=False, flux=False))
    assert "Fx" not in bare and "cf_p" not in bare and "om_m *" not in bare and "_block_flux" not in bare
    assert "d_rho" not in bare and "d_rho" in render(KernelSpec("D3Q15", "bgk", floor=True))
    assert "cf_p" in render(KernelSpec("D3Q15", "bgk", forcing=True))
    assert "om_m *" in render(KernelSpec("D3Q15", "trt"))
    assert "_block_flux" in render(KernelSpec("D3Q15", "bgk", forcing=True, flux=True))


def test_periodic_box_at_rest_stays_at_rest_and_uniform_flow_is_advected_unchanged():
    grid = bnd.box_grid(get_lattice("D3Q15"), (6, 5, 7), (False, False, False))
    sim = Simulation.build(grid, collision="trt", omega=1 / 0.7, omega_minus=omega_minus(0.7))
    sim.set_equilibrium(1.0, (0.01, -0.02, 0.03))
    sim.step(50)
    rho, ux, uy, uz = sim.moments()
    np.testing.assert_allclose(rho, 1.0, atol=1e-14)
    np.testing.assert_allclose(ux, 0.01, atol=1e-14)
    np.testing.assert_allclose(uy, -0.02, atol=1e-14)
    np.testing.assert_allclose(uz, 0.03, atol=1e-14)


def test_shear_wave_decays_at_the_lattice_viscosity():
    # u_x(z) = A sin(2 pi z / L) decays as exp(-nu k^2 t) with nu = (tau - 1/2)/3 (after Eq. (6)).
    L, tau, A = 64, 0.8, 1e-4
    grid = bnd.box_grid(get_lattice("D3Q15"), (1, 1, L), (False, False, False))
    sim = Simulation.build(grid, collision="bgk", omega=1 / tau)
    z = grid.positions()[2]
    k = 2 * np.pi / L
    sim.set_equilibrium(1.0, (A * np.sin(k * z)[None, None, :], 0.0, 0.0))
    # Start from equilibrium: let the non-equilibrium part build up before measuring the decay.
    sim.step(20)
    a0 = sim.moments()[1][0, 0, :] @ np.sin(k * z)
    steps = 400
    sim.step(steps)
    a1 = sim.moments()[1][0, 0, :] @ np.sin(k * z)
    nu_measured = -np.log(a1 / a0) / (k**2 * steps)
    # The lattice's own dispersion adds O(k^2) to nu: 2e-3 at L = 32, 5e-4 at L = 64.
    assert nu_measured == pytest.approx((tau - 0.5) / 3.0, rel=1e-3)


def test_results_do_not_depend_on_the_thread_count():
    def run(threads):
        numba.set_num_threads(threads)
        grid = bnd.pipe_grid(get_lattice("D3Q15"), 12, 8)
        sim = Simulation.build(grid, collision="trt", omega=1 / 0.8, omega_minus=omega_minus(0.8), force=(0, 0, 1e-5),
                         extra_effects=fx.wall_effects(grid, "bouzidi", {}))
        sim.step(200)
        return sim.f.copy()

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core")
    np.testing.assert_array_equal(run(1), run(2))


def test_power_of_two_box_gets_its_population_planes_in_distinct_cache_sets_and_the_same_results(monkeypatch):
    # 16 x 16 x (16 + 4) nodes per plane = 40 KiB: unpadded, all 15 planes start in one 4 KiB
    # cache-set window, and the sweep's 30 streams fight for one L1 set.
    lat = get_lattice("D3Q15")
    grid = bnd.box_grid(lat, (16, 16, 16), (False, False, False))

    def run():
        sim = Simulation.build(grid, collision="bgk", omega=1 / 0.7)
        u = np.sin(2 * np.pi * grid.positions()[2] / 16)[None, None, :]
        sim.set_equilibrium(1.0, (0.02 * u, -0.01 * u, 0.03))
        sim.step(30)
        return sim

    def distinct_l1_sets(f):  # of the planes' first elements (64-byte lines, 64 sets)
        return len({(f[i].ctypes.data - f[0].ctypes.data) // 64 % 64 for i in range(lat.q)})

    padded = run()
    f = padded.f
    assert distinct_l1_sets(f) == lat.q
    buf = bnd.plane_buffer(f)
    assert buf.flags.c_contiguous and np.shares_memory(buf, f)
    assert buf[7, grid.flat(3, 5, 11)] == f[7, 3, 5, 11]
    monkeypatch.setattr(bnd, "plane_stride", lambda plane, itemsize, q: plane)
    plain = run()
    assert plain.f.flags.c_contiguous
    assert distinct_l1_sets(plain.f) == 1
    # the nodes (not the row padding, where the sweep keeps its z-halo) hold the same bits
    np.testing.assert_array_equal(padded.f[..., :16], plain.f[..., :16])


def test_core_velocity_ratio_is_seven_quarters_for_poiseuille_and_one_for_plug_flow():
    from lbmpipe.fluid import observables as obs

    n, radius = 64, 30.0
    c = np.arange(n) - n / 2 + 0.5
    X, Y = np.meshgrid(c, c, indexing="ij")
    r2 = X**2 + Y**2
    fluid = np.repeat((r2 < radius**2)[:, :, None], 3, axis=2)
    core = obs.core_mask(c, c, radius, 3)
    parabola = np.repeat(np.where(r2 < radius**2, 1.0 - r2 / radius**2, 0.0)[:, :, None], 3, axis=2)
    assert obs.core_velocity_ratio(parabola, fluid, core) == pytest.approx(obs.CORE_RATIO_POISEUILLE, rel=0.01)
    assert obs.CORE_RATIO_POISEUILLE == 1.75
    assert obs.core_velocity_ratio(np.where(fluid, 0.3, 0.0), fluid, core) == pytest.approx(1.0)
