"""Sub-grid lubrication (lbmpipe.particles.lubrication, numerics.lubrication): each pair of
features against its analytic film force, the cutoff and the saturation, the implicit impulses
(equal and opposite, stable), the assembly, and a sphere approaching a wall through the fluid
against Brenner's (1961) exact force. Lattice units (viscosity 1 in the formula tests)."""

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lbmpipe.assemble import simulation_from_scene
from lbmpipe.particles.collisions import CollisionEffect, Domain
from lbmpipe.particles.contact import contact_pair, contact_pipe, contact_plane
from lbmpipe.particles.coupling import ParticleCoupling
from lbmpipe.particles.lubrication import LubricationEffect
from lbmpipe.particles.lubrication import reference as ref
from lbmpipe.particles.lubrication.geometry import WALL_NONE, WALL_PIPE, WALL_PLANE, contact_resistance, new_scratch
from lbmpipe.particles.rigid import Bodies, quat_from_axis_angle, quat_to_matrix
from lbmpipe.particles.shapes import CUBE, CYLINDER, SPHERE
from lbmpipe.scene import Scene, SceneError
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]
EX, EY = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
Q0 = np.array([1.0, 0.0, 0.0, 0.0])
QY = quat_from_axis_angle(EX, math.pi / 2)  # a cylinder's axis along y
QX = quat_from_axis_angle(EY, math.pi / 2)  # along x
QE = quat_from_axis_angle(EX, math.pi / 4)  # a cube on its edge (along x)
BIG = 1e9  # a cutoff far away: the film's whole resistance, nothing subtracted


def _arr(*a):
    return [np.asarray(v, dtype=np.float64) for v in a]


def pair_zeta(k1, h1, x1, q1, k2, h2, x2, q2, hc=BIG, hmin=1e-9, re=1.0):
    """(gap, zeta_n, zeta_t) of two bodies from the collision narrow phase's contact."""
    g, n, c = contact_pair(k1, h1, x1, q1, k2, h2, x2, q2)
    h1, x1, h2, x2 = _arr(h1, x1, h2, x2)
    r = contact_resistance(k1, h1, x1, quat_to_matrix(np.asarray(q1)), k2, h2, x2, quat_to_matrix(np.asarray(q2)),
                           WALL_NONE, 0.0, n, c, g, 1.0, hc, hmin, re, 0.1, new_scratch())
    return g, r[0], r[1]


def wall_zeta(k, h, x, q, pipe_radius=None, hc=BIG, hmin=1e-9, re=1.0):
    """(gap, zeta_n, zeta_t) of a body against the plane z = 0 (below it) or a pipe about z."""
    if pipe_radius is None:
        g, n, c = contact_plane(k, h, x, q, 2, 0.0, -1)
        wall, rp = WALL_PLANE, 0.0
    else:
        g, n, c = contact_pipe(k, h, x, q, pipe_radius)
        wall, rp = WALL_PIPE, float(pipe_radius)
    h, x = _arr(h, x)
    R = quat_to_matrix(np.asarray(q))
    r = contact_resistance(k, h, x, R, k, h, x, R, wall, rp, n, c, g, 1.0, hc, hmin, re, 0.1, new_scratch())
    return g, r[0], r[1]


# ----------------------------------------------------------------------------------------------
# The reference solutions themselves


def test_brenner_series_meets_cox_brenner_at_small_gaps_and_lorentz_far_away():
    for eps in (1e-3, 1e-2):
        assert ref.brenner_sphere_plane(eps) == pytest.approx(ref.cox_brenner_sphere_plane(eps), abs=5e-3)
    # far from the wall: 1 + (9/8) a/d (Lorentz), d the centre's distance
    assert ref.brenner_sphere_plane(100.0) - 1.0 == pytest.approx(9.0 / 8.0 / 101.0, rel=2e-2)
    # two spheres far apart: each sees the other's Stokeslet, 1 + (3/2) a/D (D the centre distance)
    assert ref.brenner_two_spheres(100.0) - 1.0 == pytest.approx(1.5 / 202.0, rel=2e-2)
    # and close: the relative mode's 1/(4 eps) + (9/20) ln(1/eps) (Jeffrey & Onishi 1984)
    d = [ref.brenner_two_spheres(e) - 0.25 / e for e in (1e-4, 1e-3)]
    assert (d[0] - d[1]) / math.log(10.0) == pytest.approx(0.45, abs=0.01)


# ----------------------------------------------------------------------------------------------
# Each pair of features against its analytic film force


@pytest.mark.parametrize("a", [4.0, 6.0])
def test_sphere_plane_resistance_is_the_singular_term_of_brenners_exact_force(a):
    for eps in (1e-3, 1e-2, 0.05):
        g, zn, zt = wall_zeta(SPHERE, [a, a, a], [0.0, 0.0, a * (1 + eps)], Q0)
        lam = zn / (6 * math.pi * a)  # per unit speed and viscosity
        assert lam == pytest.approx(1.0 / eps, rel=1e-9)  # Nguyen & Ladd: 6 pi mu a^2 / h
        # what is left of the exact force is Cox & Brenner's regular part, (1/5) ln(1/eps) + 0.971
        assert ref.brenner_sphere_plane(eps) - lam == pytest.approx(0.2 * math.log(1 / eps) + 0.971, abs=0.02)
        assert zt == 0.0


def test_sphere_sphere_resistance_is_nguyen_ladd_and_the_singular_term_of_the_exact_force():
    # unequal spheres: 6 pi mu (a1 a2 / (a1 + a2))^2 / h (Jeffrey & Onishi's X11A leading term)
    for a1, a2 in ((4.0, 4.0), (6.0, 2.5), (3.0, 8.0)):
        for h in (0.01, 0.3):
            g, zn, _ = pair_zeta(SPHERE, [a1] * 3, [0, 0, 0], Q0, SPHERE, [a2] * 3, [0, 0, a1 + a2 + h], Q0)
            assert zn == pytest.approx(6 * math.pi * (a1 * a2 / (a1 + a2)) ** 2 / h, rel=1e-9)
    # equal spheres approaching each other at U each (relative 2U): the exact force's singular part
    a = 5.0
    for eps in (1e-3, 1e-2):  # half the gap over a
        g, zn, _ = pair_zeta(SPHERE, [a] * 3, [0, 0, 0], Q0, SPHERE, [a] * 3, [0, 0, 2 * a * (1 + eps)], Q0)
        lam = zn * 2.0 / (6 * math.pi * a)
        exact = ref.brenner_two_spheres(eps)
        assert lam == pytest.approx(0.25 / eps, rel=1e-9)
        assert 0.0 < exact - lam < 0.45 * math.log(1 / eps) + 1.5  # the logarithmic rest
        assert lam / exact > (0.98 if eps < 5e-3 else 0.85)


def test_parallel_plates_cap_discs_exactly_and_squares_within_saint_venants_8_percent():
    for h in (0.02, 0.2):
        g, zn, zt = wall_zeta(CUBE, [4, 4, 4], [0, 0, 4 + h], Q0)  # a face flat on the wall
        assert zn / ref.square_plates(1.0, 8.0, h) == pytest.approx(1.081, abs=0.003)
        assert zt == pytest.approx(64.0 / h, rel=1e-9)  # plane Couette, mu A / h
        g, zn, _ = pair_zeta(CUBE, [4, 4, 4], [0, 0, 0], Q0, CUBE, [4, 4, 4], [4, 4, 8 + h], Q0)  # a 4 x 4 overlap
        assert zn / ref.square_plates(1.0, 4.0, h) == pytest.approx(1.081, abs=0.003)
        g, zn, _ = wall_zeta(CYLINDER, [3, 3, 5], [0, 0, 5 + h], Q0)  # a cap on the wall: Stefan
        assert zn == pytest.approx(ref.stefan_disc(1.0, 3.0, h), rel=1e-3)
        g, zn, _ = pair_zeta(CYLINDER, [3, 3, 5], [0, 0, 0], Q0, CUBE, [4, 4, 4], [0, 0, 9 + h], Q0)  # cap on a face
        assert zn == pytest.approx(ref.stefan_disc(1.0, 3.0, h), rel=1e-3)


def line(R, L, h):
    """The two-dimensional squeeze of a cylinder of radius R on a plane, over a length L."""
    return 3 * math.sqrt(2) * math.pi * R**1.5 * L / h**1.5


def test_line_and_point_contacts_of_sides_edges_and_rims():
    h = 0.05
    # a cylinder's side on the wall and two parallel sides: lines of length 2 h_z
    assert wall_zeta(CYLINDER, [3, 3, 6], [0, 0, 3 + h], QY)[1] == pytest.approx(line(3.0, 12.0, h), rel=1e-9)
    g, zn, _ = pair_zeta(CYLINDER, [3, 3, 6], [0, 0, 0], QY, CYLINDER, [3, 3, 6], [0, 0, 6 + h], QY)
    assert zn == pytest.approx(line(1.5, 12.0, h), rel=1e-9)
    # sides overlapping over half their length
    g, zn, _ = pair_zeta(CYLINDER, [3, 3, 6], [0, 0, 0], QY, CYLINDER, [3, 3, 6], [0, 6, 6 + h], QY)
    assert zn == pytest.approx(line(1.5, 6.0, h), rel=1e-9)
    # crossed sides: a point contact of the two radii (Cox), slightly cut by the sides' ends
    g, zn, _ = pair_zeta(CYLINDER, [3, 3, 6], [0, 0, 0], QY, CYLINDER, [2, 2, 6], [0, 0, 5 + h], QX)
    cox = 12 * math.pi * (3.0 * 2.0) ** 1.5 / (5.0 * h)
    assert zn == pytest.approx(cox, rel=0.02) and zn < cox
    # a cube's edge on the wall: a line of the edge radius over the edge
    for re in (1.0, 0.5):
        g, zn, _ = wall_zeta(CUBE, [4, 4, 4], [0, 0, 4 * math.sqrt(2) + h], QE, re=re)
        assert zn == pytest.approx(line(re, 8.0, h), rel=1e-9)
    # a cube's vertex on the wall: a sphere of the edge radius
    qv = quat_from_axis_angle(np.cross([1.0, 1.0, 1.0], [0.0, 0.0, -1.0]) / math.sqrt(2), math.acos(-1 / math.sqrt(3)))
    g, zn, _ = wall_zeta(CUBE, [4, 4, 4], [0, 0, 4 * math.sqrt(3) + h], qv)
    assert g == pytest.approx(h, abs=1e-9) and zn == pytest.approx(6 * math.pi / h, rel=1e-6)
    # a cylinder on its rim (tilted 45 degrees): the rim torus, edge radius across and the rim
    # circle's normal curvature cos(45)/r along
    qr = quat_from_axis_angle(EX, math.pi / 4)
    r, hz = 3.0, 5.0
    z = hz * math.cos(math.pi / 4) + r * math.sin(math.pi / 4)
    g, zn, _ = wall_zeta(CYLINDER, [r, r, hz], [0, 0, z + h], qr)
    rx, ry = 1.0, r / math.cos(math.pi / 4)
    assert g == pytest.approx(h, abs=1e-6)
    assert zn == pytest.approx(12 * math.pi * (rx * ry) ** 1.5 / ((rx + ry) * h), rel=1e-3)


def test_the_concave_pipe_wall_adds_its_curvature_along_the_azimuth():
    Rp, a, h = 25.0, 4.0, 0.05
    g, zn, _ = wall_zeta(SPHERE, [a] * 3, [Rp - a - h, 0.0, 3.0], Q0, pipe_radius=Rp)
    rx, ry = a, 1.0 / (1.0 / a - 1.0 / Rp)
    assert zn == pytest.approx(12 * math.pi * (rx * ry) ** 1.5 / ((rx + ry) * h), rel=1e-9)
    assert zn > 6 * math.pi * a**2 / h  # a concave wall holds more fluid close than a plane
    # a cylinder lying along the pipe axis: a line of the side's radius less the wall's
    g, zn, _ = wall_zeta(CYLINDER, [3, 3, 6], [Rp - 3 - h, 0.0, 8.0], Q0, pipe_radius=Rp)
    assert zn == pytest.approx(line(1.0 / (1 / 3 - 1 / Rp), 12.0, h), rel=1e-9)
    # one lying across (along y): the film is thinnest at its two rims, so it gives far less
    g2, zn2, _ = wall_zeta(CYLINDER, [3, 3, 6], [Rp - 3 - 0.75 - h, 0.0, 8.0], QY, pipe_radius=Rp)
    assert g2 == pytest.approx(h, abs=0.02) and zn2 < 0.2 * zn


# ----------------------------------------------------------------------------------------------
# Cutoff and saturation

CASES = {
    "sphere-plane": lambda h, **k: wall_zeta(SPHERE, [5] * 3, [0, 0, 5 + h], Q0, **k),
    "sphere-pipe": lambda h, **k: wall_zeta(SPHERE, [4] * 3, [25 - 4 - h, 0, 3], Q0, pipe_radius=25.0, **k),
    "face-face": lambda h, **k: pair_zeta(CUBE, [4] * 3, [0, 0, 0], Q0, CUBE, [4] * 3, [1, 2, 8 + h], Q0, **k),
    "side-side": lambda h, **k: pair_zeta(CYLINDER, [3, 3, 6], [0] * 3, QY, CYLINDER, [3, 3, 6], [0, 0, 6 + h], QY, **k),
    "edge-plane": lambda h, **k: wall_zeta(CUBE, [4] * 3, [0, 0, 4 * math.sqrt(2) + h], QE, **k),
    "edge-sphere": lambda h, **k: pair_zeta(CUBE, [4] * 3, [0] * 3, QE, SPHERE, [3] * 3, [0, 0, 4 * math.sqrt(2) + 3 + h],
                                            Q0, **k),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_force_is_zero_above_the_cutoff_continuous_at_it_and_saturates_below_the_minimum_gap(case):
    f = CASES[case]
    hc, hmin = 0.8, 0.02
    zs = [f(h, hc=hc, hmin=hmin) for h in (0.5 * hmin, hmin, 0.1, 0.4, hc * (1 - 1e-6), hc, 1.2 * hc)]
    zn = [z[1] for z in zs]
    assert zn[-1] == 0.0 and 0.0 <= zn[-2] < 1e-12 * zn[2]  # above the cutoff, and at it (to round-off in the gap)
    assert 0.0 < zn[-3] < 1e-4 * zn[2]  # just below it: continuous
    assert zn[0] == pytest.approx(zn[1], rel=1e-12)  # saturated below min_gap
    assert zn[1] > zn[2] > zn[3] > zn[-3]  # and growing as the gap closes
    assert all(z[2] >= 0.0 for z in zs) and zs[-1][2] == 0.0


# ----------------------------------------------------------------------------------------------
# The impulses: equal and opposite, implicit


def _free_system(bodies):
    from lbmpipe.particles.contact import bounding_radii  # the effect reads the system's radii
    return SimpleNamespace(bodies=bodies, n=bodies.n, rb=bounding_radii(bodies.kind, bodies.h))


def _momenta(b):
    from lbmpipe.particles.rigid import quat_to_matrices
    R = quat_to_matrices(b.q)
    p = (b.mass[:, None] * b.v).sum(axis=0)
    L = np.cross(b.x, b.mass[:, None] * b.v).sum(axis=0)
    for k in range(b.n):
        L += R[k] @ (b.inertia[k] * b.wb[k])
    e = 0.5 * (b.mass * (b.v**2).sum(1)).sum() + 0.5 * (b.inertia * b.wb**2).sum()
    return p, L, e


@pytest.mark.parametrize("shape", [SPHERE, CUBE, CYLINDER])
def test_pair_impulses_are_equal_and_opposite_conserve_momentum_and_remove_energy(shape):
    rng = np.random.default_rng(3)
    h = [3.0, 3.0, 3.0] if shape != CYLINDER else [3.0, 3.0, 5.0]
    x = [[10.0, 10.0, 10.0], [10.3, 9.8, {SPHERE: 16.2, CUBE: 16.5, CYLINDER: 20.4}[shape]]]
    bodies = Bodies.make(shape, h, 1.0, x, q=[Q0, Q0], v=rng.normal(0, 0.01, (2, 3)), wb=rng.normal(0, 0.005, (2, 3)))
    bodies.v[0, 2], bodies.v[1, 2] = 0.02, -0.02  # approaching
    dom = Domain.box((0.0, 0.0, 0.0), (40.0, 40.0, 40.0), (True, True, True))
    eff = LubricationEffect(_free_system(bodies), dom, mu=0.5, cutoff=1.0, min_gap=0.01)
    g0 = contact_pair(shape, h, bodies.x[0], Q0, shape, h, bodies.x[1], Q0)[0]
    assert 0.0 < g0 < 1.0
    p0, L0, e0 = _momenta(bodies)
    vn0 = bodies.v[1, 2] - bodies.v[0, 2]
    eff(None)
    p1, L1, e1 = _momenta(bodies)
    assert eff.totals["pair_contacts"] == 1
    assert np.abs(eff.force[0] + eff.force[1]).max() < 1e-12 * np.abs(eff.force).max()
    assert eff.force[0, 2] < 0.0 < eff.force[1, 2]  # pushed apart
    np.testing.assert_allclose(p1, p0, atol=1e-14)
    np.testing.assert_allclose(L1, L0, atol=1e-12)
    assert e1 < e0
    vn1 = bodies.v[1, 2] - bodies.v[0, 2]
    assert vn0 < vn1 < 0.0  # slowed, never reversed (implicit)


def test_a_stiff_film_brings_the_pair_to_rest_without_overshoot():
    # a light sphere at the saturation gap: zeta dt / m ~ 10^3, far beyond an explicit step's limit
    bodies = Bodies.make(SPHERE, [2.0] * 3, 0.01, [[5.0, 5.0, 2.001]], v=[[0.003, 0.0, -0.05]])
    dom = Domain.box((0.0, 0.0, 0.0), (10.0, 10.0, 10.0), (True, True, False))
    eff = LubricationEffect(_free_system(bodies), dom, mu=1.0, cutoff=1.0, min_gap=0.01)
    eff(None)
    assert eff.totals["wall_contacts"] == 1
    assert -1e-3 * 0.05 < bodies.v[0, 2] < 0.0  # nearly stopped, still approaching
    assert bodies.v[0, 0] == pytest.approx(0.003)  # no tangential resistance on a curved film


# ----------------------------------------------------------------------------------------------
# The scene option and its assembly

BOX = {
    "name": "lub",
    "domain": {"kind": "box", "size_mm": [24.0, 24.0, 24.0], "walls": {"z": "wall"}},
    "fluid": {"viscosity_m2_s": 1.0 / 6.0 * 1e-3},
    "run": {"duration_s": 0.1, "spinup_s": 0.01, "sample_interval_s": 0.01},
    "particles": {"bodies": [{"shape": "sphere", "diameter_mm": 8.0, "position_mm": [12.0, 12.0, 12.0]},
                             {"shape": "cube", "edge_mm": 6.0, "position_mm": [12.0, 12.0, 20.0]}],
                  "collisions": {"contact_gap_dx": 0.1}},
}


def test_the_default_scene_assembles_no_lubrication_and_the_option_one_effect_before_the_collisions():
    scene = Scene.model_validate(BOX)
    assert not scene.numerics.lubrication.enabled
    sim = simulation_from_scene(scene, derive(scene), guard=False)
    assert not any(isinstance(e, LubricationEffect) for e in sim.effects)
    assert "lubrication" not in sim.records()
    data = dict(BOX, numerics={"lubrication": {"enabled": True, "cutoff_dx": 0.8}})
    scene = Scene.model_validate(data)
    sim = simulation_from_scene(scene, derive(scene), guard=False)
    kinds = [type(e) for e in sim.effects]
    assert kinds.count(LubricationEffect) == 1
    assert kinds.index(ParticleCoupling) < kinds.index(LubricationEffect) < kinds.index(CollisionEffect)
    sim.step(3)
    rec = sim.records()["lubrication"]
    assert rec["calls"] == 3 and rec["cutoff_lu"] == 0.8


def test_bad_lubrication_options_name_the_field_and_the_fix():
    for opts, field in (({"enabled": True, "cutoff_dx": 0.5, "min_gap_dx": 0.5}, "numerics.lubrication.min_gap_dx"),
                        ({"cutoff_dx": -1.0}, "numerics.lubrication.cutoff_dx"),
                        ({"enable": True}, "numerics.lubrication.enable")):
        with pytest.raises(SceneError) as err:
            Scene.model_validate(dict(BOX, numerics={"lubrication": opts}))
        assert err.value.field == field and err.value.fix


# ----------------------------------------------------------------------------------------------
# Through the fluid: a sphere approaching a plane wall (benchmarks/lubrication.py, a smaller box)


def _approach():
    spec = importlib.util.spec_from_file_location("bench_lubrication", ROOT / "benchmarks" / "lubrication.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.mean_approach_force


def test_sphere_approaching_a_wall_meets_brenners_exact_force_within_5_percent_at_gaps_0_1_to_0_3_and_2():
    # a = 6 spacings in a 32^3 box (walls at z = 0 and 32), tau = 1, the default cutoff (0.8), two
    # lateral positions per gap. Without the correction the force at 0.1 spacing is 13 % of
    # Brenner's; at 2 spacings (above the cutoff: nothing added) the box's images add ~4 %. Between
    # 0.5 and 1 spacing the staircase sphere's resolved force is off by up to 7.5 % even with the
    # correction (benchmarks/README.md, "Issue 44: lubrication"), so those gaps are not asserted.
    mean_approach_force = _approach()
    offsets = np.random.default_rng(0).random((2, 2))
    for gap, without_max in ((0.1, 0.2), (0.2, 0.3), (0.3, 0.5), (2.0, 1.1)):
        r = mean_approach_force(6.0, gap, 32, 32, offsets)
        print(f"h = {gap}: Brenner {r['brenner']:.3f}, without {r['without']:.3f}, with {r['with']:.3f}")
        assert r["with"] == pytest.approx(r["brenner"], rel=0.05)
        assert r["without"] < without_max * r["brenner"]
