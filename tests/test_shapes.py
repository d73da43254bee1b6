"""Shapes: inside test, volume, principal moments, support function, bounding radius."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from lbmpipe.cost import particle_area_volume
from lbmpipe.inputs import body_volume_mm3
from lbmpipe.particles import shapes
from lbmpipe.particles.shapes import (
    CUBE,
    CYLINDER,
    SPHERE,
    bounding_radius,
    inside_body,
    inside_points,
    make_shape,
    principal_inertia,
    sample_surface,
    support_body,
    volume,
)

# The paper's particles (cylinder 8x16 prolate, 16x8 added as oblate) plus a sphere.
SPECS = [
    {"shape": "sphere", "diameter": 10},
    {"shape": "cylinder", "diameter": 8, "length": 16},
    {"shape": "cylinder", "diameter": 16, "length": 8},
    {"shape": "cube", "edge": 8},
]
IDS = ["sphere10", "cyl8x16", "cyl16x8", "cube8"]


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_volume_and_principal_inertia_match_monte_carlo_integration_of_inside_body(spec):
    """Volume, principal moments and vanishing products of inertia, from a Monte-Carlo integral
    of the indicator ``inside_body`` over a box 25 % larger than the shape (so the cube's test is
    not trivially full). 4e5 points, seed 1; tolerance 5 standard errors of each estimate."""
    kind, h = make_shape(spec)
    density = 1.7
    rng = np.random.default_rng(1)
    n = 400_000
    half = 1.25 * h
    p = rng.uniform(-1.0, 1.0, (n, 3)) * half
    box = 8.0 * half.prod()
    ind = inside_points(kind, h, p).astype(np.float64)

    def check(integrand, exact):
        samples = box * density * ind * integrand
        est, se = samples.mean(), samples.std(ddof=1) / math.sqrt(n)
        assert abs(est - exact) < 5.0 * se + 1e-12, (est, exact, se)

    check(1.0 / density, volume(kind, h))
    x, y, z = p.T
    inertia = principal_inertia(kind, h, density)
    check(y * y + z * z, inertia[0])
    check(x * x + z * z, inertia[1])
    check(x * x + y * y, inertia[2])
    check(x * y, 0.0)
    check(x * z, 0.0)
    check(y * z, 0.0)


def test_principal_inertia_textbook_formulas_from_mass():
    """Sphere 2/5 m r^2, cylinder I_zz = m r^2/2 and I_xx = m (3 r^2 + L^2)/12, cube m a^2/6."""
    rho = 2.0
    k, h = make_shape({"shape": "sphere", "diameter": 10})
    m = rho * 4 / 3 * math.pi * 5**3
    np.testing.assert_allclose(principal_inertia(k, h, rho), [0.4 * m * 25] * 3, rtol=1e-14)
    k, h = make_shape({"shape": "cylinder", "diameter": 8, "length": 16})
    m = rho * math.pi * 16 * 16
    ixx = m * (3 * 16 + 256) / 12
    np.testing.assert_allclose(principal_inertia(k, h, rho), [ixx, ixx, m * 16 / 2], rtol=1e-14)
    k, h = make_shape({"shape": "cube", "edge": 8})
    m = rho * 512
    np.testing.assert_allclose(principal_inertia(k, h, rho), [m * 64 / 6] * 3, rtol=1e-14)


def _analytic_support_value(kind, h, d):
    if kind == SPHERE:
        return h[0] * np.linalg.norm(d)
    if kind == CYLINDER:
        return h[0] * math.hypot(d[0], d[1]) + h[2] * abs(d[2])
    return float(np.abs(d) @ h)


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_support_function_is_max_of_projection_over_surface_samples(spec):
    """For 300 random directions: the support point lies on the surface, its projection is at
    least the largest projection of 40000 area-uniform surface samples (to round-off), exceeds it
    by less than 3 % of the bounding radius (sampling gap), and equals the analytic support
    value sum/|.| formula to 1e-12."""
    kind, h = make_shape(spec)
    rng = np.random.default_rng(2)
    pts = sample_surface(kind, h, 40_000, rng)
    r_bound = bounding_radius(kind, h)
    s = np.empty(3)
    for d in rng.standard_normal((300, 3)):
        support_body(kind, h, d, s)
        proj = s @ d
        best = (pts @ d).max()
        assert proj >= best - 1e-12 * r_bound * np.linalg.norm(d)
        assert proj - best < 0.03 * r_bound * np.linalg.norm(d)
        assert proj == pytest.approx(_analytic_support_value(kind, h, d), rel=1e-12)
        assert inside_body(kind, h, *(s * (1 - 1e-9)))
        assert not inside_body(kind, h, *(s * (1 + 1e-9)))


def test_support_ties_resolve_consistently():
    """Directions along face normals pick one fixed point (sign(0) = +1, +x side for zero
    lateral direction), which is on the face."""
    s = np.empty(3)
    k, h = make_shape({"shape": "cube", "edge": 2})
    support_body(k, h, np.array([0.0, 0.0, -1.0]), s)
    np.testing.assert_array_equal(s, [1.0, 1.0, -1.0])
    k, h = make_shape({"shape": "cylinder", "diameter": 4, "length": 6})
    support_body(k, h, np.array([0.0, 0.0, 1.0]), s)
    np.testing.assert_array_equal(s, [2.0, 0.0, 3.0])
    support_body(k, h, np.array([0.0, -1.0, 0.0]), s)
    np.testing.assert_array_equal(s, [0.0, -2.0, 3.0])


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_bounding_radius_circumscribes_and_is_attained(spec):
    kind, h = make_shape(spec)
    r = bounding_radius(kind, h)
    pts = sample_surface(kind, h, 20_000, np.random.default_rng(3))
    assert np.linalg.norm(pts, axis=1).max() <= r * (1 + 1e-12)
    # attained at a cube corner / cylinder rim / any sphere point
    s = np.empty(3)
    support_body(kind, h, np.array([1.0, 1.0, 1.0]), s)
    assert np.linalg.norm(s) == pytest.approx(r, rel=1e-12)


def _surface_points_with_normals(kind, h):
    """(point, outward direction) pairs on faces, edges, corners and the curved surface."""
    out = []
    if kind == SPHERE:
        rng = np.random.default_rng(4)
        for u in rng.standard_normal((50, 3)):
            u /= np.linalg.norm(u)
            out.append((h[0] * u, u))
        return out
    if kind == CYLINDER:
        r, hz = h[0], h[2]
        for phi in np.linspace(0, 2 * math.pi, 13)[:-1]:
            c, s = math.cos(phi), math.sin(phi)
            radial = np.array([c, s, 0.0])
            for z in (-0.9 * hz, 0.0, 0.5 * hz):  # curved surface
                out.append((np.array([r * c, r * s, z]), radial))
            for sz in (-1.0, 1.0):
                axial = np.array([0.0, 0.0, sz])
                out.append((np.array([0.5 * r * c, 0.5 * r * s, sz * hz]), axial))  # caps
                rim = radial + axial
                out.append((np.array([r * c, r * s, sz * hz]), rim / np.linalg.norm(rim)))  # edges
        return out
    for axis in range(3):
        for sgn in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sgn
            p = np.array([0.3, -0.6, 0.2]) * h
            p[axis] = sgn * h[axis]
            out.append((p, n))  # faces
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                sg = np.array([sx, sy, sz], dtype=float)
                out.append((sg * h, sg / math.sqrt(3)))  # corners
                e = sg.copy()
                e[2] = 0.0
                out.append((sg * h * np.array([1, 1, 0.4]), e / math.sqrt(2)))  # edges
    return out


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_points_just_inside_and_outside_faces_edges_and_curved_surface(spec):
    kind, h = make_shape(spec)
    eps = 1e-7 * bounding_radius(kind, h)
    for p, n in _surface_points_with_normals(kind, h):
        assert inside_body(kind, h, *(p - eps * n)), (p, n)
        assert not inside_body(kind, h, *(p + eps * n)), (p, n)


def test_closed_set_flat_faces_and_shape_specific_regions():
    """Exact face points count as inside; box corners are outside a cylinder and a sphere of
    the same half-extents (the inside test is not a bounding box)."""
    k, h = make_shape({"shape": "cube", "edge": 8})
    assert inside_body(k, h, 4.0, 4.0, 4.0) and inside_body(k, h, 4.0, 0.0, -1.0)
    assert not inside_body(k, h, 4.0 + 1e-12, 0.0, 0.0)
    k, h = make_shape({"shape": "cylinder", "diameter": 8, "length": 16})
    assert inside_body(k, h, 4.0, 0.0, 8.0) and inside_body(k, h, 0.0, -4.0, -8.0)
    assert not inside_body(k, h, 3.0, 3.0, 0.0)  # radius 4.24 > 4, inside the box
    assert not inside_body(k, h, 0.0, 0.0, 8.0 + 1e-12)
    k, h = make_shape({"shape": "sphere", "diameter": 10})
    assert inside_body(k, h, 5.0, 0.0, 0.0) and inside_body(k, h, 0.0, 0.0, -5.0)
    assert not inside_body(k, h, 3.0, 3.0, 3.0)  # |p| = 5.2


def test_inside_points_matches_scalar_inside_body():
    rng = np.random.default_rng(5)
    for spec in SPECS:
        kind, h = make_shape(spec)
        p = rng.uniform(-1.2, 1.2, (2000, 3)) * h
        expected = np.array([inside_body(kind, h, *row) for row in p])
        np.testing.assert_array_equal(inside_points(kind, h, p), expected)
        assert 0 < expected.sum() < len(p)


def test_make_shape_half_extents_and_errors():
    k, h = make_shape({"shape": "cylinder", "diameter": 8, "length": 16})
    assert k == CYLINDER
    np.testing.assert_array_equal(h, [4, 4, 8])
    k, h = make_shape({"shape": "Cube", "edge": 24, "density": 1.05})  # extra keys ignored
    assert k == CUBE
    np.testing.assert_array_equal(h, [12, 12, 12])
    k, h = make_shape({"shape": "sphere", "diameter": 10})
    assert k == SPHERE
    np.testing.assert_array_equal(h, [5, 5, 5])
    for bad in (
        {"shape": "cone", "diameter": 3},
        {"shape": "cylinder", "diameter": 8},
        {"shape": "cylinder", "diameter": 8, "lenght": 16},
        {"shape": "cube", "edge": -1},
        {"shape": "cube", "edge": float("nan")},
        {"shape": "cube", "edge": "big"},
        {"diameter": 3},
        "cube",
    ):
        with pytest.raises(ValueError):
            make_shape(bad)
    with pytest.raises(ValueError):
        volume(7, np.ones(3))


def test_shape_kind_codes_are_the_contract_values():
    assert (shapes.SPHERE, shapes.CYLINDER, shapes.CUBE) == (0, 1, 2)


def test_surface_area_is_the_closed_form_of_each_shape_and_of_a_box():
    assert shapes.surface_area(SPHERE, [2.0, 2.0, 2.0]) == pytest.approx(4 * math.pi * 4.0)
    assert shapes.surface_area(CYLINDER, [4.0, 4.0, 8.0]) == pytest.approx(2 * math.pi * 16 + 2 * math.pi * 4 * 16)
    assert shapes.surface_area(CUBE, [4.0, 4.0, 4.0]) == 6 * 8.0**2
    assert shapes.surface_area(CUBE, [1.0, 2.0, 3.0]) == pytest.approx(2 * (2 * 4 + 4 * 6 + 2 * 6))


def test_scene_sizes_give_the_same_volume_everywhere_the_package_needs_one():
    # the scene checks (inputs), the run-time model (cost) and the lattice estimates (units) all
    # take a particle's volume from shapes.volume
    for p, exact in ((SimpleNamespace(shape="cylinder", diameter_mm=8.0, length_mm=16.0, edge_mm=None), math.pi * 16 * 16),
                     (SimpleNamespace(shape="cube", diameter_mm=None, length_mm=None, edge_mm=8.0), 512.0),
                     (SimpleNamespace(shape="sphere", diameter_mm=6.0, length_mm=None, edge_mm=None), 36 * math.pi)):
        v = shapes.volume(*shapes.scene_shape(p.shape, p.diameter_mm, p.length_mm, p.edge_mm))
        assert v == pytest.approx(exact)
        assert body_volume_mm3(p) == v and particle_area_volume(p.shape, p.diameter_mm, p.length_mm, p.edge_mm)[1] == v
