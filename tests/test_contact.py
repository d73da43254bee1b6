"""Contact geometry (lbmpipe.particles.contact): GJK/EPA gaps, normals and contact points against exact
values, the pipe and planar walls, and the cell-list broad phase."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.optimize import minimize

from lbmpipe.particles.contact import (bodies_overlap_ws, candidate_pairs, contact_pair, contact_pipe, contact_plane, list_displacement,
                             listed_pairs, neighbour_list, new_scratch)
from lbmpipe.particles.rigid import quat_from_axis_angle, quat_to_matrix, random_quaternions
from lbmpipe.particles.shapes import CUBE, CYLINDER, SPHERE, support_body

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _rot(axis, angle):
    return quat_from_axis_angle(np.asarray(axis, dtype=np.float64), float(angle))


def _apply(q, v):
    return quat_to_matrix(q) @ np.asarray(v, dtype=np.float64)


# ------------------------------------------------------------------------------------------------
# exact pair geometry


@pytest.mark.parametrize("distance", [3.7, 2.95, 2.5])
def test_sphere_sphere_gap_normal_and_contact_point_are_exact(distance):
    rng = np.random.default_rng(0)
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    x1 = np.array([0.3, -1.0, 2.0])
    x2 = x1 + distance * u
    g, n, c = contact_pair(SPHERE, [1.0] * 3, x1, IDENTITY, SPHERE, [2.0] * 3, x2, IDENTITY)
    assert g == pytest.approx(distance - 3.0, abs=1e-12)
    np.testing.assert_allclose(n, u, atol=1e-12)
    # midway between the two surfaces along the centre line
    np.testing.assert_allclose(c, x1 + u * (1.0 + 0.5 * (distance - 3.0)), atol=1e-12)


@pytest.mark.parametrize("dx", [2.4, 2.0001, 1.97, 1.8])
def test_cube_cube_face_to_face_gap_normal_and_patch_centroid_are_exact(dx):
    # two unit-half-edge cubes, faces parallel, laterally offset; any common rotation of the pair
    # must give the same answer rotated
    q = _rot([0.3, -0.5, 0.8], 1.1)
    off = np.array([dx, 0.6, 0.2])
    x1 = np.array([1.0, 2.0, 3.0])
    x2 = x1 + _apply(q, off)
    g, n, c = contact_pair(CUBE, [1.0] * 3, x1, q, CUBE, [1.0] * 3, x2, q)
    assert g == pytest.approx(dx - 2.0, abs=1e-9)
    np.testing.assert_allclose(n, _apply(q, [1.0, 0.0, 0.0]), atol=1e-9)
    # patch: y in [-0.4, 1], z in [-0.8, 1] -> centroid (0.3, 0.1); x midway between the faces
    np.testing.assert_allclose(c, x1 + _apply(q, [1.0 + 0.5 * (dx - 2.0), 0.3, 0.1]), atol=1e-9)


@pytest.mark.parametrize("d_perp", [3.1, 2.0, 1.93])
def test_parallel_cylinders_side_by_side_gap_is_centre_distance_minus_diameter(d_perp):
    q = _rot([1.0, 2.0, -0.5], 0.7)
    x1 = np.array([0.0, 0.0, 0.0])
    # radius 1, half-length 2; axial offset 1.0 so that the side lines overlap over length 3
    x2 = x1 + _apply(q, [d_perp, 0.0, 1.0])
    g, n, c = contact_pair(CYLINDER, [1.0, 1.0, 2.0], x1, q, CYLINDER, [1.0, 1.0, 2.0], x2, q)
    assert g == pytest.approx(d_perp - 2.0, abs=2e-6)
    np.testing.assert_allclose(n, _apply(q, [1.0, 0.0, 0.0]), atol=2e-3)
    # contact line from z = -1 to z = 2 (body frame of 1): its middle
    np.testing.assert_allclose(c, _apply(q, [1.0 + 0.5 * (d_perp - 2.0), 0.0, 0.5]), atol=2e-3)


@pytest.mark.parametrize("dz", [4.5, 4.0, 3.9])
def test_coaxial_cylinders_end_to_end_gap_is_centre_distance_minus_length(dz):
    q = _rot([0.2, 1.0, 0.1], 2.0)
    x1 = np.array([5.0, -1.0, 0.5])
    x2 = x1 + _apply(q, [0.3, -0.2, dz])
    g, n, c = contact_pair(CYLINDER, [1.0, 1.0, 2.0], x1, q, CYLINDER, [1.0, 1.0, 2.0], x2, q)
    assert g == pytest.approx(dz - 4.0, abs=1e-9)
    np.testing.assert_allclose(n, _apply(q, [0.0, 0.0, 1.0]), atol=1e-9)
    # the two caps overlap in a lens centred on the midpoint of the two axes
    np.testing.assert_allclose(c, x1 + _apply(q, [0.15, -0.1, 2.0 + 0.5 * (dz - 4.0)]), atol=1e-6)


def test_swapping_the_bodies_flips_the_normal_and_keeps_gap_and_point():
    rng = np.random.default_rng(3)
    q = random_quaternions(2, rng)
    for x2 in ([2.2, 0.5, 0.4], [1.6, 0.3, 0.2]):
        a = contact_pair(CUBE, [1.0, 1.0, 1.0], [0, 0, 0], q[0], CYLINDER, [0.8, 0.8, 1.5], x2, q[1])
        b = contact_pair(CYLINDER, [0.8, 0.8, 1.5], x2, q[1], CUBE, [1.0, 1.0, 1.0], [0, 0, 0], q[0])
        assert a[0] == pytest.approx(b[0], abs=1e-7)
        np.testing.assert_allclose(a[1], -b[1], atol=1e-4)


def _support_value(kind, h, x, q, n):
    out = np.empty(3)
    R = quat_to_matrix(q)
    support_body(kind, np.asarray(h, dtype=np.float64), R.T @ n, out)
    return float(n @ (np.asarray(x) + R @ out))


def _separating_axis_gap(kind1, h1, x1, q1, kind2, h2, x2, q2):
    """max over unit n of [min_B n.y - max_A n.y] = -(h_A(n) + h_B(-n)): the signed gap of two
    convex bodies (distance if apart, minus the penetration depth if overlapping), computed
    from the support functions alone, without GJK/EPA."""

    def f(angles):
        t, p = angles
        n = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
        return _support_value(kind1, h1, x1, q1, n) + _support_value(kind2, h2, x2, q2, -n)

    m = 600
    i = np.arange(m) + 0.5
    th = np.arccos(1.0 - 2.0 * i / m)
    ph = math.pi * (1.0 + 5.0**0.5) * i
    vals = np.array([f((a, b)) for a, b in zip(th, ph)])
    best = np.inf
    for k in np.argsort(vals)[:4]:
        r = minimize(f, [th[k], ph[k]], method="Nelder-Mead", options=dict(xatol=1e-11, fatol=1e-13, maxiter=3000))
        best = min(best, r.fun)
    return -best


def _random_pairs(seed, count, r_min, r_max):
    """Random pairs of the test shapes, random orientations, body 1 at the origin and body 2 at
    a random direction and distance in [r_min, r_max]: (k1, h1, q1, k2, h2, x2, q2)."""
    rng = np.random.default_rng(seed)
    shapes = [(SPHERE, [1.0, 1.0, 1.0]), (CYLINDER, [1.0, 1.0, 2.0]), (CUBE, [1.0, 1.0, 1.0]), (CYLINDER, [2.0, 2.0, 0.7])]
    for _ in range(count):
        k1, h1 = shapes[rng.integers(4)]
        k2, h2 = shapes[rng.integers(4)]
        q = random_quaternions(2, rng)
        d = rng.standard_normal(3)
        yield k1, h1, q[0], k2, h2, d / np.linalg.norm(d) * rng.uniform(r_min, r_max), q[1]


def test_signed_gap_and_normal_match_the_separating_axis_maximum_for_random_pairs():
    n_overlap = 0
    x1 = np.zeros(3)
    for k1, h1, q1, k2, h2, x2, q2 in _random_pairs(11, 24, 1.8, 4.0):
        g, n, _ = contact_pair(k1, h1, x1, q1, k2, h2, x2, q2)
        ref = _separating_axis_gap(k1, h1, x1, q1, k2, h2, x2, q2)
        assert g == pytest.approx(ref, abs=1e-5)
        # the normal attains the maximum: it is the separating (or minimum-translation) axis
        assert -(_support_value(k1, h1, x1, q1, n) + _support_value(k2, h2, x2, q2, -n)) == pytest.approx(g, abs=1e-5)
        n_overlap += g < 0
    assert 3 <= n_overlap <= 21  # both regimes were exercised


def test_overlap_test_without_epa_agrees_with_the_sign_of_the_gap_for_random_pairs():
    # the time-of-impact bisection asks only "do they overlap?"; it must answer as the full
    # contact query would, on both sides of touching
    ws = new_scratch()
    n_overlap = 0
    for k1, h1, q1, k2, h2, x2, q2 in _random_pairs(5, 400, 0.5, 4.5):
        g, _, _ = contact_pair(k1, h1, np.zeros(3), q1, k2, h2, x2, q2)
        if abs(g) < 1e-9:
            continue  # touching: EPA's degenerate case, where the two may differ by design
        ov = bodies_overlap_ws(k1, np.asarray(h1, float), np.zeros(3), quat_to_matrix(q1),
                               k2, np.asarray(h2, float), x2, quat_to_matrix(q2), ws)
        assert ov == (g < 0.0), (k1, k2, g)
        n_overlap += ov
    assert 80 <= n_overlap <= 320  # both sides were exercised


def _gjk_gap(h1, x1, R1, h2, x2, R2):
    """Gap and unit normal of two separated cylinders by GJK alone (the reference for the exact
    path, which body_contact now takes for cylinder pairs)."""
    from lbmpipe.particles.contact.gjk import _gjk
    from lbmpipe.particles.contact.scratch import _gjk_scratch

    W, WA, WB, lam, pa, pb, v = _gjk_scratch(new_scratch())
    scale = math.hypot(h1[0], h1[2]) + math.hypot(h2[0], h2[2])
    st, dist, _ = _gjk(CYLINDER, h1, x1, R1, False, CYLINDER, h2, x2, R2, False, scale, np.inf, W, WA, WB, lam, pa, pb,
                       v)
    return (dist if st == 0 else -1.0), -v / np.linalg.norm(v)


def _on_cylinder_surface(p, h, x, R, tol):
    s = R.T @ (p - x)
    r, z = math.hypot(s[0], s[1]), abs(s[2])
    return (r <= h[0] + tol and z <= h[2] + tol) and (abs(r - h[0]) <= tol or abs(z - h[2]) <= tol)


@pytest.mark.parametrize("shapes", [((4.0, 4.0), (4.0, 4.0)), ((8.0, 8.0), (8.0, 12.0)), ((4.0, 4.0), (8.0, 12.0))])
def test_exact_cylinder_gap_equals_gjk_for_random_separated_pairs_of_the_paper_shapes(shapes):
    # (radius, half length) of the paper's 8x8, 16x16 and 16x24 mm cylinders at dx = 1 mm
    from lbmpipe.particles.contact import cylinder_gap_exact

    rng = np.random.default_rng(7)
    h1, h2 = (np.array([r, r, l]) for r, l in shapes)
    reach = math.hypot(*shapes[0]) + math.hypot(*shapes[1])
    nrm, pa, pb = np.empty(3), np.empty(3), np.empty(3)
    separated = certified = 0
    for _ in range(1500):
        q = random_quaternions(2, rng)
        if rng.random() < 0.2:
            q[1] = q[0]  # parallel axes: side on side and cap on cap, flat patches
        R1, R2 = quat_to_matrix(q[0]), quat_to_matrix(q[1])
        d = rng.standard_normal(3)
        x2 = d / np.linalg.norm(d) * rng.uniform(0.45, 1.0) * reach
        ref, n_ref = _gjk_gap(h1, np.zeros(3), R1, h2, x2, R2)
        if ref <= 1e-6:
            continue
        separated += 1
        g = cylinder_gap_exact(h1, np.zeros(3), R1, h2, x2, R2, nrm, pa, pb)
        if g < 0.0:
            continue  # no certificate: the caller falls back to GJK
        certified += 1
        assert g == pytest.approx(ref, abs=1e-8 * reach)
        assert np.linalg.norm(pb - pa) == pytest.approx(g, rel=1e-12)
        assert _on_cylinder_surface(pa, h1, np.zeros(3), R1, 1e-9 * reach)
        assert _on_cylinder_surface(pb, h2, x2, R2, 1e-9 * reach)
        np.testing.assert_allclose(nrm, (pb - pa) / g, atol=1e-12)
        # GJK's normal is the less accurate of the two on curved surfaces (~sqrt of its gap error)
        assert float(nrm @ n_ref) > math.cos(1e-3)
    assert separated > 300
    assert certified >= 0.98 * separated


def test_exact_cylinder_gap_is_certified_by_one_feature_pair_only_so_the_try_order_changes_no_bit():
    # _cylinder_gap tries the rim-side searches in an order set by the axes' lean towards the
    # centre line, after the candidate that won the step before if it is given one; the result
    # is the fixed order's as long as no two candidates are certified
    from lbmpipe.particles.contact import cylinder_gap_exact
    from lbmpipe.particles.contact.cylinders import (_EXACT_TOL, _N_CANDIDATES, _certified_gap, _cyl_candidate,
                                                     _cyl_frames, _cylinder_gap)

    rng = np.random.default_rng(11)
    nrm, pa, pb = np.empty(3), np.empty(3), np.empty(3)
    checked = reordered = 0
    for shapes in (((4.0, 4.0), (4.0, 4.0)), ((4.0, 4.0), (8.0, 12.0)), ((8.0, 8.0), (4.0, 8.0))):
        h1, h2 = (np.array([r, r, l]) for r, l in shapes)
        reach = math.hypot(*shapes[0]) + math.hypot(*shapes[1])
        for _ in range(400):
            q = random_quaternions(2, rng)
            R1, R2 = quat_to_matrix(q[0]), quat_to_matrix(q[1])
            d = rng.standard_normal(3)
            x2 = d / np.linalg.norm(d) * rng.uniform(0.5, 1.0) * reach
            fr = _cyl_frames(h1, np.zeros(3), R1, h2, x2, R2)
            X1, E1, U1, V1, r1, l1, X2, E2, U2, V2, r2, l2 = fr
            tol = _EXACT_TOL * (math.hypot(r1, l1) + math.hypot(r2, l2))
            found = []
            for k in range(_N_CANDIDATES):
                ok, a, b = _cyl_candidate(k, *fr)
                if ok:
                    g = _certified_gap(X1, E1, r1, l1, X2, E2, r2, l2, *a, *b, tol)
                    if g >= 0.0:
                        found.append((k, g, a, b))
            assert len(found) <= 1
            g = cylinder_gap_exact(h1, np.zeros(3), R1, h2, x2, R2, nrm, pa, pb)
            if not found:
                assert g == -1.0
                assert all(_cylinder_gap(h1, np.zeros(3), R1, h2, x2, R2, f)[3] == -1 for f in range(_N_CANDIDATES))
                continue
            k, g0, a, b = found[0]
            checked += 1
            reordered += k in (4, 5)
            assert g == g0 and tuple(pa) == a and tuple(pb) == b  # bit for bit
            for first in range(-1, _N_CANDIDATES):
                assert _cylinder_gap(h1, np.zeros(3), R1, h2, x2, R2, first) == (g0, a, b, k)
    assert checked > 400 and reordered > 80


def test_exact_cylinder_gap_of_crossed_sides_a_cap_under_a_tilted_rim_and_two_rims():
    from lbmpipe.particles.contact import cylinder_gap_exact

    h = np.array([1.0, 1.0, 2.0])
    nrm, pa, pb = np.empty(3), np.empty(3), np.empty(3)
    # sides: axes along x and y, 3 apart along z: gap 3 - 2 radii, normal +z, points on the axes' line
    Rx = quat_to_matrix(_rot([0.0, 1.0, 0.0], math.pi / 2))
    Ry = quat_to_matrix(_rot([1.0, 0.0, 0.0], math.pi / 2))
    assert cylinder_gap_exact(h, np.zeros(3), Rx, h, np.array([0.3, -0.4, 3.0]), Ry, nrm, pa, pb) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(nrm, [0.0, 0.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(pa, [0.3, 0.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(pb, [0.3, 0.0, 2.0], atol=1e-14)
    # rim over a cap: body 2 tilted by a about x above the upright body 1's top cap; its lowest
    # point is the rim point at height z2 - l cos a - r sin a
    a = 0.3
    Rt = quat_to_matrix(_rot([1.0, 0.0, 0.0], a))
    z2 = 5.0
    g = cylinder_gap_exact(h, np.zeros(3), np.eye(3), h, np.array([0.1, 0.2, z2]), Rt, nrm, pa, pb)
    assert g == pytest.approx(z2 - 2.0 - 2.0 * math.cos(a) - math.sin(a), abs=1e-13)
    np.testing.assert_allclose(nrm, [0.0, 0.0, 1.0], atol=1e-14)
    # two rims: equal cylinders tilted by +-a about y, side by side along x and mirrored in the
    # plane x = d/2, their caps facing up: by symmetry the closest points are the two rim points
    # nearest that plane, at the same height, so the gap is d - 2 (l sin a + r cos a)
    a = 0.6
    d = 2.0 * (2.0 * math.sin(a) + math.cos(a)) + 0.25
    R1 = quat_to_matrix(_rot([0.0, 1.0, 0.0], a))
    R2 = quat_to_matrix(_rot([0.0, 1.0, 0.0], -a))
    g = cylinder_gap_exact(h, np.zeros(3), R1, h, np.array([d, 0.0, 0.0]), R2, nrm, pa, pb)
    assert g == pytest.approx(0.25, abs=1e-12)
    np.testing.assert_allclose(nrm, [1.0, 0.0, 0.0], atol=1e-12)
    # overlapping bodies get no certificate (GJK/EPA measure the depth)
    assert cylinder_gap_exact(h, np.zeros(3), Rx, h, np.array([0.0, 0.0, 1.5]), Ry, nrm, pa, pb) == -1.0


def test_exact_cylinder_overlap_test_never_contradicts_gjk_and_settles_almost_every_pair():
    # the time-of-impact bisection asks "do they overlap?" of cylinder pairs near touching; the
    # exact test answers from a point inside the other body or a separating direction, else -1
    from lbmpipe.particles.contact import cylinders_overlap_exact
    from lbmpipe.particles.contact.gjk import _gjk
    from lbmpipe.particles.contact.scratch import _gjk_scratch

    rng = np.random.default_rng(3)
    W, WA, WB, lam, pa, pb, v = _gjk_scratch(new_scratch())
    answers = {1: 0, 0: 0, -1: 0}
    for shapes in (((4.0, 4.0), (4.0, 4.0)), ((4.0, 4.0), (8.0, 12.0))):
        h1, h2 = (np.array([r, r, l]) for r, l in shapes)
        reach = math.hypot(*shapes[0]) + math.hypot(*shapes[1])
        for _ in range(1000):
            q = random_quaternions(2, rng)
            if rng.random() < 0.2:
                q[1] = q[0]
            R1, R2 = quat_to_matrix(q[0]), quat_to_matrix(q[1])
            d = rng.standard_normal(3)
            x2 = d / np.linalg.norm(d) * rng.uniform(0.3, 1.0) * reach
            st, _, _ = _gjk(CYLINDER, h1, np.zeros(3), R1, False, CYLINDER, h2, x2, R2, False, reach, 0.0, W, WA, WB, lam,
                            pa, pb, v)
            got = cylinders_overlap_exact(h1, np.zeros(3), R1, h2, x2, R2)
            answers[got] += 1
            if got >= 0:
                assert got == (1 if st == 1 else 0)
    assert answers[1] > 500 and answers[0] > 300 and answers[-1] <= 10


# ------------------------------------------------------------------------------------------------
# walls


def test_pipe_wall_gap_is_radius_minus_farthest_vertex_for_random_cubes():
    rng = np.random.default_rng(5)
    h = np.array([1.0, 1.5, 0.5])
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
    for q in random_quaternions(20, rng):
        x = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), 1.0])
        g, n, c = contact_pipe(CUBE, h, x, q, 6.0, center=(0.5, -0.5))
        verts = x + (quat_to_matrix(q) @ (signs * h).T).T
        rho = np.hypot(verts[:, 0] - 0.5, verts[:, 1] + 0.5)
        assert g == pytest.approx(6.0 - rho.max(), abs=1e-12)
        assert n[2] == 0.0 and np.linalg.norm(n) == pytest.approx(1.0)


def test_pipe_wall_gap_is_radius_minus_farthest_rim_point_for_random_cylinders():
    rng = np.random.default_rng(6)
    h = np.array([1.2, 1.2, 2.5])
    t = np.linspace(0.0, 2.0 * np.pi, 200001)
    for q in random_quaternions(20, rng):
        x = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), -3.0])
        g, n, c = contact_pipe(CYLINDER, h, x, q, 7.0)
        R = quat_to_matrix(q)
        best = 0.0
        for s in (-1.0, 1.0):
            pts = x + s * h[2] * R[:, 2] + h[0] * (np.outer(np.cos(t), R[:, 0]) + np.outer(np.sin(t), R[:, 1]))
            best = max(best, np.hypot(pts[:, 0], pts[:, 1]).max())
        assert g == pytest.approx(7.0 - best, abs=1e-9)


def test_flat_face_or_side_against_the_pipe_wall_gets_a_torque_free_contact():
    # a cube face parallel to the wall touches along two edges; a cylinder lying along the pipe
    # touches along a line; in both cases the contact normal passes through the centre
    for kind, h, q, x in [
        (CUBE, [1.0, 1.0, 1.0], _rot([0, 0, 1], 0.3), None),
        (CYLINDER, [1.0, 1.0, 3.0], IDENTITY, None),
        (CYLINDER, [1.0, 1.0, 3.0], _rot([0, 1, 0], math.pi / 2), None),
    ]:
        ang = 0.3
        R = quat_to_matrix(q)
        radial = np.array([math.cos(ang), math.sin(ang), 0.0])
        if kind == CUBE:
            x = 3.5 * radial
        elif abs(R[2, 2]) > 0.5:
            x = 4.0 * radial
        else:
            x = 1.2 * np.array([1.0, 0.0, 0.0])
            radial = np.array([1.0, 0.0, 0.0])
        g, n, c = contact_pipe(kind, h, x, q, 5.0)
        np.testing.assert_allclose(n, radial, atol=1e-9)
        lever = c - x
        assert np.linalg.norm(np.cross(lever, n)) < 1e-9


def test_plane_wall_gap_and_face_centroid():
    q = _rot([1, 1, 0], 0.4)
    x = np.array([0.0, 0.0, 2.0])
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
    verts = x + (quat_to_matrix(q) @ (signs * 1.0).T).T
    g, n, c = contact_plane(CUBE, [1.0] * 3, x, q, axis=2, coord=0.0, side=-1)
    assert g == pytest.approx(verts[:, 2].min(), abs=1e-12)
    np.testing.assert_allclose(n, [0, 0, -1])
    # axis-aligned cube resting on its face: contact point = face centre below the centre
    g, n, c = contact_plane(CUBE, [1.0] * 3, [3.0, 4.0, 1.05], IDENTITY, axis=2, coord=0.0, side=-1)
    assert g == pytest.approx(0.05)
    np.testing.assert_allclose(c, [3.0, 4.0, 0.05], atol=1e-12)


# ------------------------------------------------------------------------------------------------
# broad phase


def test_cell_list_finds_exactly_the_pairs_of_an_all_pairs_search_with_periodic_images():
    rng = np.random.default_rng(9)
    n = 400
    lo = np.array([0.0, -5.0, 0.0])
    hi = np.array([30.0, 25.0, 40.0])
    periodic = np.array([True, False, True])
    x = rng.uniform(lo, hi, (n, 3))
    x[:10, 0] += 30.0  # unwrapped positions on a periodic axis must work too
    rb = rng.uniform(0.5, 1.5, n)
    margin = 0.3
    pi, pj, ps = candidate_pairs(x, rb, margin, lo, hi, periodic)
    found = {(int(i), int(j)): s for i, j, s in zip(pi, pj, ps)}
    L = hi - lo
    expected = {}
    for i in range(n):
        for j in range(i + 1, n):
            d = x[j] - x[i]
            s = np.where(periodic, -L * np.floor(d / L + 0.5), 0.0)
            if np.linalg.norm(d + s) <= rb[i] + rb[j] + margin:
                expected[(i, j)] = s
    assert set(found) == set(expected)
    for k in expected:
        np.testing.assert_allclose(found[k], expected[k])


def test_a_verlet_list_gives_the_cell_scans_pairs_while_bodies_stay_within_half_its_skin_of_a_common_drift():
    # the collision step keeps a list over time steps and must see the same pairs, shifts and
    # order (its Gauss-Seidel order) as a fresh cell scan: boxes with periodic axes of 1, 2 and
    # more cells, bodies moved by up to half the list's extra margin and wrapped into the period
    rng = np.random.default_rng(5)
    lo = np.array([-25.0, -25.0, 0.0])
    pairs = 0
    for trial in range(60):
        n = int(rng.integers(2, 250))
        hi = np.array([25.0, 25.0, rng.uniform(20.0, 100.0)])
        periodic = rng.random(3) < 0.5
        x = rng.uniform(lo, hi, (n, 3))
        rb = rng.uniform(0.5, 5.0, n) if trial % 2 else np.full(n, 4.0)
        margin = rng.uniform(0.0, 2.0)
        big = margin + rng.uniform(0.0, 3.0)
        periodic &= (hi - lo) >= 2.0 * (2.0 * rb.max() + big)
        start, js = neighbour_list(x, rb, big, lo, hi, periodic)
        d = 0.5 * (big - margin)
        # half the trials also carry all bodies along by a common shift longer than the skin, as
        # the flow carries a suspension: the list holds on relative displacements. Steps within
        # d / sqrt(3) keep every body within d of the middle of their range on each axis.
        # (The shift stays within a quarter period: with the steps that keeps every
        # displacement's minimum image.)
        shifted = trial % 2 == 1
        step = rng.standard_normal((n, 3))
        step *= (d * (3.0 ** -0.5 if shifted else 1.0) * rng.random(n) / np.linalg.norm(step, axis=1))[:, None]
        drift = rng.uniform(-1.0, 1.0, 3) * np.minimum(3.0 * (big - margin), 0.25 * (hi - lo)) * shifted
        drift = np.where(periodic, drift, 0.0)
        x1 = x + step + drift
        x1 = np.where(periodic, lo + np.mod(x1 - lo, hi - lo), x1)
        moved = list_displacement(x1, x, lo, hi, periodic)
        assert moved <= d * (1.0 + 1e-9)
        # what the list relies on: no two bodies have moved apart by more than twice that
        rel = np.linalg.norm(step[:, None, :] - step[None, :, :], axis=-1)
        assert rel.max() <= 2.0 * moved * (1.0 + 1e-9)
        expected = candidate_pairs(x1, rb, margin, lo, hi, periodic)
        got = listed_pairs(x1, rb, margin, lo, hi, periodic, start, js)
        for a, b in zip(got, expected):
            np.testing.assert_array_equal(a, b)
        pairs += len(expected[0])
    assert pairs > 2000


def test_contact_across_a_periodic_boundary_uses_the_nearest_image():
    q = np.tile(IDENTITY, (2, 1))
    x = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 29.6]])
    pi, pj, ps = candidate_pairs(x, np.array([1.0, 1.0]), 0.1, np.array([-5.0, -5.0, 0.0]), np.array([5.0, 5.0, 30.0]),
                                 np.array([False, False, True]))
    assert list(zip(pi, pj)) == [(0, 1)]
    g, n, _ = contact_pair(SPHERE, [1.0] * 3, x[0], q[0], SPHERE, [1.0] * 3, x[1] + ps[0], q[1])
    assert g == pytest.approx(-1.1, abs=1e-12)
    np.testing.assert_allclose(n, [0, 0, -1])



def test_scalar_support_point_is_bit_identical_to_shapes_support_body():
    # the GJK loop uses a scalar copy of shapes.support_body (no allocation); the two must agree
    # bit for bit, including ties (zero components, directions along the cylinder axis)
    from lbmpipe.particles.contact import support3

    rng = np.random.default_rng(11)
    dirs = list(rng.standard_normal((200, 3))) + [np.array(d, float) for d in
                                                   ([0, 0, 1], [0, 0, -1], [1, 0, 0], [0, -1, 0], [0, 0, 0], [1, 1, 0])]
    for kind, h in ((SPHERE, [1.3] * 3), (CYLINDER, [0.8, 0.8, 1.7]), (CUBE, [0.9, 1.1, 1.4])):
        for q in list(random_quaternions(3, rng)) + [IDENTITY]:
            R = quat_to_matrix(q)
            x = rng.standard_normal(3)
            for d in dirs:
                body = np.empty(3)
                support_body(kind, np.asarray(h), np.array(
                    [R[0, k] * d[0] + R[1, k] * d[1] + R[2, k] * d[2] for k in range(3)]), body)
                expect = [x[k] + R[k, 0] * body[0] + R[k, 1] * body[1] + R[k, 2] * body[2] for k in range(3)]
                got = support3(kind, np.asarray(h), x, R, False, d[0], d[1], d[2])
                assert list(got) == expect


def test_side_against_side_contact_point_is_bit_identical_to_the_general_patch_code():
    # body_contact_ws finds the contact point of two cylinder sides on scalars (_side_side_patch)
    # instead of through _manifold_point's scratch views; the two must agree bit for bit, for
    # parallel, nearly parallel and crossed sides, overlapping, touching end to end or apart
    from lbmpipe.particles.contact.features import _F_SIDE, _cyl_feature_kind, _manifold_point, _side_side_patch

    def frame(e, rng):
        u = np.cross(e, rng.standard_normal(3))
        u /= np.linalg.norm(u)
        return np.column_stack([u, np.cross(e, u), e])

    rng = np.random.default_rng(5)
    ws = new_scratch()
    kinds = {"crossed": 0, "parallel": 0, "apart": 0}
    for t in range(3000):
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
        h1 = np.array([4.0, 4.0, 4.0])
        h2 = np.array([4.0, 4.0, 4.0]) if t % 2 else np.array([1.5, 1.5, 6.0])
        e1 = np.cross(n, rng.standard_normal(3))
        e1 /= np.linalg.norm(e1)
        angle = (0.0, 1e-3, 0.02, rng.uniform(0.0, math.pi))[t % 4]
        e2 = math.cos(angle) * e1 + math.sin(angle) * np.cross(n, e1)
        # tilts within manifold_tol keep both features sides
        e2 = e2 + rng.uniform(-1.0, 1.0) * 0.004 * n
        e2 /= np.linalg.norm(e2)
        R1, R2 = frame(e1, rng), frame(e2, rng)
        x1 = rng.standard_normal(3)
        along = rng.uniform(-11.0, 11.0) * e1 + rng.uniform(-1.0, 1.0) * (0.15 if t % 3 else 3.0) * np.cross(n, e1)
        x2 = x1 + (h1[0] + h2[0] + rng.uniform(0.0, 0.5)) * n + along
        base = x1 + h1[0] * n + rng.uniform(-0.1, 0.1, 3)
        tol = 0.1
        assert _cyl_feature_kind(h1, R1, n[0], n[1], n[2], tol) == _F_SIDE
        assert _cyl_feature_kind(h2, R2, -n[0], -n[1], -n[2], tol) == _F_SIDE
        expect = np.empty(3)
        _manifold_point(CYLINDER, h1, x1, R1, CYLINDER, h2, x2, R2, n, base, tol, expect, ws)
        got = _side_side_patch(h1, x1, R1, h2, x2, R2, n[0], n[1], n[2], base[0], base[1], base[2], tol)
        assert list(got) == list(expect)
        key = "apart" if list(got) == list(base) else ("crossed" if angle > 0.1 else "parallel")
        kinds[key] += 1
    # every branch of the patch was taken many times
    assert min(kinds.values()) > 100, kinds


def test_rim_sample_table_is_bit_identical_to_the_trigonometry_it_replaces():
    # pipe_wall_contact samples each cylinder rim from a table of cos and sin; the table must hold
    # exactly what numba's math.cos and math.sin give at those angles, or the gaps (and every
    # committed result) would change in the last bits
    from numba import njit

    from lbmpipe.particles.contact import RIM_SAMPLES
    from lbmpipe.particles.contact.walls import _RIM_COS, _RIM_SIN

    @njit
    def trig(n):
        out = np.empty((2, n))
        for s in range(n):
            out[0, s] = math.cos(2.0 * math.pi * s / n)
            out[1, s] = math.sin(2.0 * math.pi * s / n)
        return out

    expect = trig(RIM_SAMPLES)
    assert _RIM_COS.tobytes() == expect[0].tobytes() and _RIM_SIN.tobytes() == expect[1].tobytes()


# ------------------------------------------------------------------------------------------------
# EPA's tables

# Recorded in a production run (244 dense 8 x 8 mm cylinders, dx 1 mm): two cylinders overlapping
# by 0.012 lu, one's cap on the other's rim. The faces the expansion's new vertex saw there were a
# patchwork (round-off on the finely sampled curved surfaces), whose boundary held more edges than
# the face table had room left for: the compiled EPA wrote past the table, and the run died many
# steps later with a heap corruption.
_EPA_RECORDED = {
    "k1": 1, "h1": [4.0, 4.0, 4.0],
    "x1": [11.417106449870905, -16.826991791689412, 68.62623684114274],
    "R1": [[0.2428449724236158, 0.8665432476789334, 0.436037979160784],
           [-0.9437724618837657, 0.1071074887150687, 0.3127643298891477],
           [0.22432088524796223, -0.487473882134416, 0.8438301693340741]],
    "k2": 1, "h2": [4.0, 4.0, 4.0],
    "x2": [14.974198406591656, -14.315203485166196, 75.38592211737362],
    "R2": [[-0.21640445002018205, 0.7768782174103778, -0.5912946383358608],
           [-0.5304696791731908, -0.6020099498575562, -0.5968131531311912],
           [-0.8196163941072401, 0.18451085492668587, 0.5423879708519252]],
    "scale": 11.313708498984761,
    "W": [[1.1905073664890473, -2.5926168580868296, 0.35967473324592447],
          [3.2410389267784154, 5.978498188570635, -4.01000325798006],
          [-2.7110668392926662, 1.447028586587992, 0.8783490140700678],
          [-0.10526490040494707, 0.1354106391854888, 0.018162618879216552]],
    "WA": [[16.7414885636613, -15.789126402913716, 70.23054059702265],
           [14.235820368235455, -12.177237921752772, 70.18657039376129],
           [12.87622055065292, -11.789057488315425, 70.7452469864197],
           [15.459724934099125, -13.076438577867425, 69.8874213562974]],
    "WB": [[15.550981197172252, -13.196509544826887, 69.87086586377673],
           [10.99478144145704, -18.155736110323407, 74.19657365174135],
           [15.587287389945587, -13.236086074903417, 69.86689797234963],
           [15.564989834504072, -13.211849217052913, 69.86925873741818]],
    "n": 4,
}

_EPA_RUN = """
import json, sys
import numpy as np
import lbmpipe.particles.contact.epa as E
d = json.loads(sys.argv[1])
def run(max_faces):
    E.EPA_MAX_FACES = max_faces
    nrm, pa, pb = np.empty(3), np.empty(3), np.empty(3)
    depth = E._epa(d["k1"], np.array(d["h1"]), np.array(d["x1"]), np.array(d["R1"]), d["k2"], np.array(d["h2"]),
                   np.array(d["x2"]), np.array(d["R2"]), d["scale"], np.array(d["W"]), np.array(d["WA"]),
                   np.array(d["WB"]), d["n"], nrm, pa, pb)
    return [depth, nrm.tolist(), pa.tolist(), pb.tolist()]
print(json.dumps({"table": run(E.EPA_MAX_FACES), "large": run(16 * E.EPA_MAX_FACES)}))
"""


def _epa_recorded(nrm, pa, pb):
    from lbmpipe.particles.contact.epa import _epa
    d = _EPA_RECORDED
    a = {k: (np.array(v) if isinstance(v, list) else v) for k, v in d.items()}
    return _epa(a["k1"], a["h1"], a["x1"], a["R1"], a["k2"], a["h2"], a["x2"], a["R2"], a["scale"], a["W"], a["WA"],
                a["WB"], a["n"], nrm, pa, pb)


def test_epa_on_a_patchwork_horizon_stays_within_its_face_table_and_finds_the_cap_depth():
    """Run as plain Python (every index checked), EPA on the recorded pair neither writes past its
    face table nor answers differently from a table 16 times larger; compiled, it gives the same
    depth and normal. The depth is the cap's: along cylinder 1's axis."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    out = subprocess.run([sys.executable, "-c", _EPA_RUN, json.dumps(_EPA_RECORDED)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    depth, nrm = res["table"][0], np.array(res["table"][1])
    assert res["table"] == res["large"]
    assert 0.005 < depth < 0.02
    axis = np.array(_EPA_RECORDED["R1"])[:, 2]
    assert abs(abs(nrm @ axis) - 1.0) < 1e-6
    nrm_c, pa_c, pb_c = np.empty(3), np.empty(3), np.empty(3)
    depth_c = _epa_recorded(nrm_c, pa_c, pb_c)
    assert depth_c == pytest.approx(depth, rel=1e-6)
    np.testing.assert_allclose(nrm_c, nrm, atol=1e-6)
