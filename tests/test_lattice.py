"""Velocity sets: the paper's D3Q15 (Table 1, Eq. (7)) and the moment identities every set needs."""

import itertools

import numpy as np
import pytest

from lbmpipe.fluid.lattice import CS2, LATTICES, get_lattice


def test_d3q15_matches_table1_order_weights_and_opposites():
    lat = get_lattice("D3Q15")
    table1 = [(0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (1, 1, 1),
              (-1, -1, -1), (-1, 1, 1), (1, -1, -1), (-1, -1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, -1)]
    assert lat.e.tolist() == [list(v) for v in table1]
    assert lat.w[0] == pytest.approx(2 / 9)
    np.testing.assert_allclose(lat.w[1:7], 1 / 9)
    np.testing.assert_allclose(lat.w[7:], 1 / 72)
    pairs = [(1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14)]
    for a, b in pairs:
        assert lat.opp[a] == b and lat.opp[b] == a
    assert lat.opp[0] == 0


@pytest.mark.parametrize("name,q", [("D3Q15", 15), ("D3Q19", 19), ("D3Q27", 27)])
def test_weights_sum_to_one_and_first_moment_vanishes(name, q):
    lat = get_lattice(name)
    assert lat.q == q
    assert lat.w.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(lat.w @ lat.e, 0.0, atol=1e-16)
    np.testing.assert_array_equal(lat.e[lat.opp], -lat.e)


@pytest.mark.parametrize("name", LATTICES)
def test_second_moment_is_isotropic_with_cs2_one_third(name):
    lat = get_lattice(name)
    m2 = np.einsum("i,ia,ib->ab", lat.w, lat.e, lat.e)
    np.testing.assert_allclose(m2, CS2 * np.eye(3), atol=1e-15)


@pytest.mark.parametrize("name", LATTICES)
def test_odd_moments_vanish_to_fifth_order(name):
    lat = get_lattice(name)
    e = lat.e.astype(float)
    for order in (1, 3, 5):
        for idx in itertools.product(range(3), repeat=order):
            assert abs(np.sum(lat.w * np.prod(e[:, idx], axis=1))) < 1e-15


@pytest.mark.parametrize("name", LATTICES)
def test_fourth_moment_is_isotropic_so_navier_stokes_is_recovered(name):
    # sum w e_a e_b e_c e_d = cs^4 (d_ab d_cd + d_ac d_bd + d_ad d_bc): needed for Eqs. (5)-(6).
    lat = get_lattice(name)
    e = lat.e.astype(float)
    d = np.eye(3)
    m4 = np.einsum("i,ia,ib,ic,id->abcd", lat.w, e, e, e, e)
    iso = CS2**2 * (np.einsum("ab,cd->abcd", d, d) + np.einsum("ac,bd->abcd", d, d) + np.einsum("ad,bc->abcd", d, d))
    np.testing.assert_allclose(m4, iso, atol=1e-15)


def test_unknown_lattice_is_a_clear_error():
    with pytest.raises(ValueError, match="D3Q15, D3Q19, D3Q27"):
        get_lattice("D2Q9")
