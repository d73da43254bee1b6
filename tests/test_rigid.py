"""Rigid-body motion: Newton, Euler's equations (13), quaternion kinematics (14)-(15)."""

import math

import numpy as np
import pytest
from scipy import stats
from scipy.integrate import solve_ivp

from lbmpipe.particles.rigid import (
    Bodies,
    advance,
    angular_momentum_lab,
    drift,
    kick_angular,
    kick_linear,
    kinetic_energy,
    omega_lab,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
    quat_to_matrices,
    quat_to_matrix,
    random_quaternions,
    rotate,
    rotate_inv,
)
from lbmpipe.particles.shapes import CUBE, CYLINDER, make_shape, principal_inertia, volume

ASYM = np.array([1.0, 2.0, 3.0])


def one_body(inertia, wb, q=None, mass=1.0, x=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0)):
    # kind/h only matter for geometry; the dynamics see mass and principal moments.
    return Bodies.from_arrays(
        CUBE, [0.5, 0.5, 0.5], mass, inertia, np.array([x]), v=np.array([v]),
        q=None if q is None else np.array([q]), wb=np.array([wb], dtype=float),
    )


def zeros(n=1):
    return np.zeros((n, 3))


def quat_distance(a, b):
    """Distance between the rotations of two unit quaternions (q and -q are the same)."""
    return min(np.linalg.norm(a - b), np.linalg.norm(a + b))


def test_torque_free_asymmetric_body_conserves_energy_and_lab_angular_momentum_over_1e5_steps():
    """I = (1, 2, 3), |omega| ~ 1.4, dt = 0.01, 1e5 steps (~150 tumbling periods): relative energy
    error stays below 1e-6 (O(dt^2) and bounded: measured 1.4e-7), lab angular momentum is
    conserved to round-off (< 1e-11 relative; measured ~2e-13)."""
    b = one_body(ASYM, [1.0, 0.5, 0.8], q=quat_normalize(np.array([0.3, -0.2, 0.9, 0.1])))
    e0 = kinetic_energy(b)[0]
    l0 = angular_momentum_lab(b)[0].copy()
    zero = zeros()
    worst_e = 0.0
    worst_l = 0.0
    min_w1 = 1.0
    for step in range(100_000):
        advance(b, zero, zero, 0.01)
        if step % 50 == 0:
            worst_e = max(worst_e, abs(kinetic_energy(b)[0] / e0 - 1.0))
            worst_l = max(worst_l, np.linalg.norm(angular_momentum_lab(b)[0] - l0) / np.linalg.norm(l0))
            min_w1 = min(min_w1, b.wb[0, 0])
    assert worst_e < 1e-6
    assert worst_l < 1e-11
    # the motion is a genuine tumble about axis 3: omega_1 swings from +1 to about -1.1
    assert min_w1 < -0.5


def _spin_about(axis, eps=1e-4, t_end=60.0, dt=0.01):
    wb = np.full(3, eps)
    wb[axis] = 1.0
    b = one_body(ASYM, wb, q=random_quaternions(1, np.random.default_rng(7))[0])
    a0 = quat_to_matrix(b.q[0])[:, axis].copy()
    zero = zeros()
    min_spin, max_angle = 1.0, 0.0
    for _ in range(int(round(t_end / dt))):
        advance(b, zero, zero, dt)
        min_spin = min(min_spin, b.wb[0, axis])
        cosang = np.clip(quat_to_matrix(b.q[0])[:, axis] @ a0, -1.0, 1.0)
        max_angle = max(max_angle, math.acos(cosang))
    return min_spin, max_angle


def test_spin_about_intermediate_axis_flips_while_extreme_axes_are_stable():
    """Tennis-racket theorem, I = (1, 2, 3), perturbation 1e-4: about the intermediate axis the
    perturbation grows like exp(t/sqrt(3)) and the spin reverses (body axis turns over); about the
    smallest and largest axes the body axis stays within 0.01 rad of its start."""
    min_spin, max_angle = _spin_about(1)
    assert min_spin < -0.9
    assert max_angle > 0.9 * math.pi
    for axis in (0, 2):
        min_spin, max_angle = _spin_about(axis)
        assert min_spin > 0.99
        assert max_angle < 0.01


@pytest.mark.parametrize("inertia", [(2.0, 2.0, 1.0), (1.0, 1.0, 1.8)], ids=["prolate", "oblate"])
def test_torque_free_symmetric_top_precesses_at_analytic_rate(inertia):
    """I1 = I2 != I3: omega_3 is constant and (omega_1, omega_2) rotate in the body frame at
    Omega = omega_3 (I3 - I1)/I1 (Euler's equations (13)); in the lab the symmetry axis precesses
    about L at rate |L|/I1 (quaternion kinematics (15)). Checked over 3 body periods with dt = 1e-3
    against the closed form to 2e-5 (error is O(dt^2))."""
    inertia = np.array(inertia)
    w3, wperp, phi0 = 2.0, 0.4, 0.3
    b = one_body(inertia, [wperp * math.cos(phi0), wperp * math.sin(phi0), w3],
                 q=random_quaternions(1, np.random.default_rng(11))[0])
    big_omega = w3 * (inertia[2] - inertia[0]) / inertia[0]
    ell = angular_momentum_lab(b)[0]
    lhat, lmag = ell / np.linalg.norm(ell), np.linalg.norm(ell)
    n0 = quat_to_matrix(b.q[0])[:, 2].copy()
    dt = 1e-3
    steps = int(round(3 * 2 * math.pi / abs(big_omega) / dt))
    zero = zeros()
    for _ in range(steps):
        advance(b, zero, zero, dt)
    t = steps * dt
    expected = [wperp * math.cos(phi0 + big_omega * t), wperp * math.sin(phi0 + big_omega * t), w3]
    np.testing.assert_allclose(b.wb[0], expected, atol=2e-5)
    n_expected = rotate(quat_from_axis_angle(lhat, lmag / inertia[0] * t), n0)
    np.testing.assert_allclose(quat_to_matrix(b.q[0])[:, 2], n_expected, atol=2e-5)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("w0", [0.0, 0.7])
def test_constant_torque_about_principal_axis_spins_up_linearly_with_quadratic_angle(axis, w0):
    """Torque T along body principal axis k (fixed in the lab as the body turns about it):
    omega(t) = omega0 + T t/I_k and angle omega0 t + T t^2/(2 I_k). The kick-drift-kick scheme
    is exact here (like velocity Verlet under constant acceleration), so to 1e-10."""
    q0 = random_quaternions(1, np.random.default_rng(3 + axis))[0]
    e = np.zeros(3)
    e[axis] = 1.0
    b = one_body(ASYM, w0 * e, q=q0)
    torque = 0.35 * rotate(q0, e)[None, :]
    dt, steps = 0.01, 500
    for _ in range(steps):
        advance(b, zeros(), torque, dt)
    t = dt * steps
    np.testing.assert_allclose(b.wb[0], (w0 + 0.35 * t / ASYM[axis]) * e, atol=1e-10)
    angle = w0 * t + 0.35 * t * t / (2 * ASYM[axis])
    assert quat_distance(b.q[0], quat_mul(q0, quat_from_axis_angle(e, angle))) < 1e-10


def test_constant_force_gives_uniform_acceleration():
    b = one_body(ASYM, [0.0, 0.0, 0.0], mass=2.5, x=(1.0, -2.0, 0.5), v=(0.1, 0.0, -0.3))
    force = np.array([[0.2, -0.5, 1.0]])
    for _ in range(400):
        advance(b, force, zeros(), 0.025)
    t = 10.0
    np.testing.assert_allclose(b.v[0], [0.1, 0.0, -0.3] + force[0] * t / 2.5, atol=1e-12)
    np.testing.assert_allclose(b.x[0], [1.0, -2.0, 0.5] + np.array([0.1, 0.0, -0.3]) * t + force[0] * t * t / 5.0,
                               atol=1e-10)


def _run_free(dt, t_end, q0):
    b = one_body(ASYM, [1.0, 0.5, 0.8], q=q0)
    zero = zeros()
    for _ in range(int(round(t_end / dt))):
        advance(b, zero, zero, dt)
    return b


def test_integrator_is_second_order_on_torque_free_asymmetric_rotation():
    """Errors of (q, omega_body) at t = 4 for dt = 0.1, 0.05, 0.025 against dt = 0.1/256:
    observed order log2(e(dt)/e(dt/2)) >= 1.9 (measured ~1.99)."""
    q0 = quat_normalize(np.array([0.9, 0.1, -0.3, 0.2]))
    ref = _run_free(0.1 / 256, 4.0, q0)
    errs = []
    for dt in (0.1, 0.05, 0.025):
        b = _run_free(dt, 4.0, q0)
        errs.append(quat_distance(b.q[0], ref.q[0]) + np.linalg.norm(b.wb[0] - ref.wb[0]))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders >= 1.9), (errs, orders)


def _euler_rhs(_t, y, inertia, torque_lab):
    """Eqs. (13) and (15) written out directly: body-frame omega, quaternion q (w, x, y, z)."""
    w, q = y[:3], y[3:]
    tb = quat_to_matrix(q / np.linalg.norm(q)).T @ torque_lab
    i1, i2, i3 = inertia
    dw = np.array([
        tb[0] / i1 + (i2 - i3) * w[1] * w[2] / i1,
        tb[1] / i2 + (i3 - i1) * w[2] * w[0] / i2,
        tb[2] / i3 + (i1 - i2) * w[0] * w[1] / i3,
    ])
    dq = 0.5 * quat_mul(q, np.array([0.0, w[0], w[1], w[2]]))
    return np.concatenate([dw, dq])


def test_converges_at_second_order_to_direct_integration_of_euler_equations_with_lab_torque():
    """Asymmetric body under a constant lab-frame torque off the principal axes: the scheme
    converges to an independent high-accuracy integration (RK45, rtol 1e-12) of Eqs. (13)/(15)
    as written, at order >= 1.9; this pins the sign of the gyroscopic term and the frames."""
    q0 = quat_normalize(np.array([0.8, 0.3, -0.4, 0.2]))
    w0 = np.array([0.6, -0.9, 0.4])
    torque = np.array([0.3, -0.2, 0.5])
    t_end = 3.0
    sol = solve_ivp(_euler_rhs, (0.0, t_end), np.concatenate([w0, q0]), args=(ASYM, torque),
                    rtol=1e-12, atol=1e-12, method="RK45")
    w_ref, q_ref = sol.y[:3, -1], sol.y[3:, -1] / np.linalg.norm(sol.y[3:, -1])
    errs = []
    for dt in (0.1, 0.05, 0.025):
        b = one_body(ASYM, w0, q=q0)
        for _ in range(int(round(t_end / dt))):
            advance(b, zeros(), torque[None, :], dt)
        errs.append(quat_distance(b.q[0], q_ref) + np.linalg.norm(b.wb[0] - w_ref))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert errs[-1] < 1e-3
    assert np.all(orders >= 1.9), (errs, orders)


def test_quaternion_norm_stays_one_to_round_off_over_1e5_steps():
    rng = np.random.default_rng(5)
    n = 8
    b = Bodies.from_arrays(CUBE, [0.5] * 3, 1.0, rng.uniform(0.5, 3.0, (n, 3)), np.zeros((n, 3)),
                           q=random_quaternions(n, rng), wb=rng.normal(0.0, 2.0, (n, 3)))
    torque = rng.normal(0.0, 0.1, (n, 3))
    worst = 0.0
    for step in range(100_000):
        advance(b, zeros(n), torque, 0.01)
        if step % 10 == 0:
            worst = max(worst, np.abs(np.einsum("ij,ij->i", b.q, b.q) - 1.0).max())
    assert worst < 1e-14


def test_random_quaternions_are_uniform_on_so3():
    """20000 samples (seed 0): every entry of the mean rotation matrix is 0 within 0.02
    (~5 standard errors of sqrt(1/3/n)); the image of body z is uniform on the sphere:
    cos(theta) uniform on [-1, 1] and azimuth uniform on [0, 2 pi) (KS p > 1e-3)."""
    n = 20_000
    q = random_quaternions(n, np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-14)
    a = quat_to_matrices(q)
    assert np.abs(a.mean(axis=0)).max() < 0.02
    z = a[:, :, 2]
    assert stats.kstest(z[:, 2], stats.uniform(loc=-1, scale=2).cdf).pvalue > 1e-3
    phi = np.mod(np.arctan2(z[:, 1], z[:, 0]), 2 * math.pi)
    assert stats.kstest(phi, stats.uniform(loc=0, scale=2 * math.pi).cdf).pvalue > 1e-3
    # the same check rejects a classic wrong sampler (uniform Euler angles), so it has power
    rng = np.random.default_rng(0)
    beta = rng.uniform(0, math.pi, n)
    assert stats.kstest(np.cos(beta), stats.uniform(loc=-1, scale=2).cdf).pvalue < 1e-3


def test_quaternion_conventions_body_to_lab_and_omega_body_on_the_right():
    """A(q) rotates body -> lab (right-handed), A(a (x) b) = A(a) A(b), rotate_inv undoes rotate,
    and a short drift with body-frame omega moves lab points with velocity (A wb) x r, i.e.
    dA/dt = A [wb]_x as in dq/dt = 1/2 q (x) (0, wb)."""
    qz = quat_from_axis_angle(np.array([0.0, 0.0, 2.0]), math.pi / 2)
    np.testing.assert_allclose(rotate(qz, np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0], atol=1e-15)
    rng = np.random.default_rng(9)
    qa, qb = random_quaternions(2, rng)
    v = rng.normal(size=3)
    np.testing.assert_allclose(quat_to_matrix(qa) @ v, rotate(qa, v), atol=1e-14)
    np.testing.assert_allclose(rotate_inv(qa, rotate(qa, v)), v, atol=1e-14)
    np.testing.assert_allclose(quat_to_matrix(quat_mul(qa, qb)), quat_to_matrix(qa) @ quat_to_matrix(qb), atol=1e-14)
    np.testing.assert_allclose(quat_to_matrix(qa).T @ quat_to_matrix(qa), np.eye(3), atol=1e-14)

    b = one_body(ASYM, [0.3, -0.7, 1.1], q=qa, x=(1.0, 2.0, 3.0))
    p_body = np.array([0.4, -0.2, 0.3])
    r0 = rotate(b.q[0], p_body)
    wl = omega_lab(b)[0]
    np.testing.assert_allclose(wl, quat_to_matrix(qa) @ b.wb[0], atol=1e-14)
    h = 1e-6
    drift(b, h)
    velocity = (rotate(b.q[0], p_body) - r0) / h
    np.testing.assert_allclose(velocity, np.cross(wl, r0), atol=1e-6)


def test_kick_and_drift_pieces_compose_to_advance():
    rng = np.random.default_rng(12)
    n = 5
    args = dict(kind=CUBE, h=[0.5] * 3, mass=rng.uniform(1, 2, n), inertia=rng.uniform(0.5, 3.0, (n, 3)),
                x=rng.normal(size=(n, 3)), v=rng.normal(size=(n, 3)), q=random_quaternions(n, rng),
                wb=rng.normal(size=(n, 3)))
    a = Bodies.from_arrays(**args)
    b = Bodies.from_arrays(**args)
    force, torque, dt = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), 0.05
    advance(a, force, torque, dt)
    kick_linear(b, force, dt / 2)
    kick_angular(b, torque, dt / 2)
    drift(b, dt)
    kick_linear(b, force, dt / 2)
    kick_angular(b, torque, dt / 2)
    for name in ("x", "v", "q", "wb"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-14)


def test_kick_angular_adds_lab_torque_impulse_to_lab_angular_momentum():
    rng = np.random.default_rng(13)
    b = one_body(ASYM, rng.normal(size=3), q=random_quaternions(1, rng)[0])
    l0 = angular_momentum_lab(b)[0].copy()
    torque = rng.normal(size=(1, 3))
    kick_angular(b, torque, 0.3)
    np.testing.assert_allclose(angular_momentum_lab(b)[0], l0 + 0.3 * torque[0], atol=1e-14)


def test_fixed_bodies_never_move():
    rng = np.random.default_rng(14)
    b = Bodies.from_arrays(CUBE, [0.5] * 3, 1.0, ASYM, rng.normal(size=(3, 3)), v=rng.normal(size=(3, 3)),
                           q=random_quaternions(3, rng), wb=rng.normal(size=(3, 3)), fixed=[False, True, False])
    assert np.all(b.v[1] == 0) and np.all(b.wb[1] == 0)
    x1, q1 = b.x[1].copy(), b.q[1].copy()
    for _ in range(10):
        advance(b, rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), 0.1)
    kick_linear(b, np.ones((3, 3)), 1.0)
    kick_angular(b, np.ones((3, 3)), 1.0)
    drift(b, 1.0)
    np.testing.assert_array_equal(b.x[1], x1)
    np.testing.assert_array_equal(b.q[1], q1)
    assert np.all(b.v[1] == 0) and np.all(b.wb[1] == 0)
    assert np.all(b.v[0] != 0)


def test_bodies_make_takes_mass_and_inertia_from_shape_and_owns_its_arrays():
    kind, h = make_shape({"shape": "cylinder", "diameter": 8, "length": 16})
    x = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    b = Bodies.make(kind, h, 1.05, x)
    assert len(b) == 2 and b.kind.dtype == np.int64 and b.fixed.dtype == np.bool_
    np.testing.assert_allclose(b.mass, 1.05 * volume(kind, h))
    np.testing.assert_allclose(b.inertia, np.tile(principal_inertia(kind, h, 1.05), (2, 1)))
    np.testing.assert_array_equal(b.q, np.tile([1.0, 0, 0, 0], (2, 1)))
    x[0, 0] = 99.0
    assert b.x[0, 0] == 1.0  # a copy: stepping bodies never writes into the caller's arrays
    assert b.x.flags.writeable and b.h.flags.writeable and b.x.flags.c_contiguous
    both = Bodies.concatenate([b, Bodies.make(CUBE, [4.0] * 3, 1.0, [0.0, 0.0, 0.0])])
    assert both.n == 3 and list(both.kind) == [CYLINDER, CYLINDER, CUBE]
    assert Bodies.empty().n == 0
    advance(Bodies.empty(), zeros(0), zeros(0), 0.1)
    with pytest.raises(ValueError):
        Bodies.make(kind, h, 1.0, x, q=np.array([[2.0, 0, 0, 0], [1.0, 0, 0, 0]]))
    with pytest.raises(ValueError):
        advance(b, zeros(3), zeros(2), 0.1)


def test_kinetic_energy_and_lab_angular_momentum_values():
    q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.pi / 2)  # body y -> lab z
    b = one_body(ASYM, [0.0, 2.0, 0.0], q=q, mass=3.0, x=(1.0, 0.0, 0.0), v=(0.0, 1.0, 0.0))
    assert kinetic_energy(b)[0] == pytest.approx(0.5 * 3.0 * 1.0 + 0.5 * 2.0 * 4.0)
    np.testing.assert_allclose(angular_momentum_lab(b)[0], [0.0, 0.0, 4.0], atol=1e-14)
    np.testing.assert_allclose(omega_lab(b)[0], [0.0, 0.0, 2.0], atol=1e-14)
    # orbital part about the origin: r x m v = (1,0,0) x (0,3,0) = (0,0,3)
    np.testing.assert_allclose(angular_momentum_lab(b, origin=[0, 0, 0])[0], [0.0, 0.0, 7.0], atol=1e-14)
