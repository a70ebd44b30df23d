"""Tests of nespm_cli.nav.earth: WGS-84 radii, normal gravity, earth and transport rates.

pos = [lat rad, lon rad, h m] with h positive up; vectors are NED.
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.nav import earth

PI = np.pi
A = 6378137.0
INV_F = 298.257223563
LAT_HAIFA = np.radians(32.8)


def pos(lat, h=0.0, lon=0.0) -> np.ndarray:
    lat = np.asarray(lat, dtype=float)
    return np.stack(np.broadcast_arrays(lat, np.asarray(lon, float), np.asarray(h, float)), axis=-1)


def somigliana(lat: np.ndarray) -> np.ndarray:
    """WGS-84 closed-form normal gravity on the ellipsoid with the full-precision constants."""
    s2 = np.sin(lat) ** 2
    k = 0.00193185265241
    e2 = 0.00669437999013
    return 9.7803253359 * (1.0 + k * s2) / np.sqrt(1.0 - e2 * s2)


# ----------------------------------------------------------------------------- constants


def test_wgs84_constants():
    assert earth.A == A
    assert abs(1.0 / earth.F - INV_F) < 1e-9
    assert abs(earth.E2 - 0.00669437999014) < 1e-14
    assert abs(earth.B - 6356752.314245) < 1e-6
    assert earth.OMEGA_IE == 7.292115e-5


# ----------------------------------------------------------------------------- radii


def test_radii_known_values():
    R_N, R_E = earth.radii(0.0)
    assert abs(R_N - 6335439.327) < 1e-3
    assert abs(R_E - 6378137.0) < 1e-3
    R_N, R_E = earth.radii(PI / 2)
    assert abs(R_N - 6399593.626) < 1e-3
    assert abs(R_E - 6399593.626) < 1e-3
    R_N, R_E = earth.radii(-PI / 2)
    assert abs(R_N - 6399593.626) < 1e-3 and abs(R_E - 6399593.626) < 1e-3


def test_radii_against_ellipse_geometry():
    """R_N = d(meridian arc)/d(lat) by numerical differentiation of the meridian ellipse;
    R_E = distance from the surface point to the polar axis along the normal."""
    a, b = A, A * (1.0 - 1.0 / INV_F)
    lat = np.radians(np.array([0.0, 10.0, 32.8, 45.0, 60.0, 80.0]))

    def meridian_point(phi):
        # surface point of the meridian ellipse with geodetic latitude phi
        beta = np.arctan((b / a) * np.tan(phi))  # reduced latitude
        return np.stack([a * np.cos(beta), b * np.sin(beta)], axis=-1)

    d = 1e-6
    ds = np.linalg.norm(meridian_point(lat + d) - meridian_point(lat - d), axis=-1)
    R_N_geo = ds / (2 * d)
    R_E_geo = meridian_point(lat)[:, 0] / np.cos(lat)
    R_N, R_E = earth.radii(lat)
    np.testing.assert_allclose(R_N, R_N_geo, rtol=1e-9)
    np.testing.assert_allclose(R_E, R_E_geo, rtol=1e-12)


def test_radii_relation_and_symmetry():
    lat = np.linspace(-1.5, 1.5, 101)
    R_N, R_E = earth.radii(lat)
    # R_N = R_E^3 (1 - e^2) / a^2
    np.testing.assert_allclose(R_N, R_E**3 * (1.0 - earth.E2) / A**2, rtol=1e-14)
    np.testing.assert_allclose(R_N, R_N[::-1], rtol=1e-15)
    assert np.all(np.diff(R_N[50:]) > 0) and np.all(np.diff(R_E[50:]) > 0)
    assert np.all(R_N <= R_E + 1e-6)


def test_radii_batched():
    lat = np.random.default_rng(1).uniform(-1.5, 1.5, (7, 25))
    R_N, R_E = earth.radii(lat)
    assert R_N.shape == R_E.shape == (7, 25)
    R_N1, R_E1 = earth.radii(lat[3, 4])
    assert R_N[3, 4] == R_N1 and R_E[3, 4] == R_E1


# ----------------------------------------------------------------------------- gravity


def test_gravity_equator_and_pole_sea_level():
    g_eq = earth.gravity_n(pos(0.0))
    np.testing.assert_allclose(g_eq, [0.0, 0.0, 9.7803253359], rtol=0, atol=1e-6)
    for lat in (PI / 2, -PI / 2):
        g_pole = earth.gravity_n(pos(lat))
        np.testing.assert_allclose(g_pole[[1, 2]], [0.0, 9.8321849378], rtol=0, atol=1e-6)
        assert abs(g_pole[0]) < 1e-20
    # points down (NED +D), positive
    assert g_eq[2] > 0


def test_gravity_matches_full_precision_somigliana():
    """The Somigliana formula to 1e-8 m/s^2 at every latitude (the module rounds Somigliana's
    constant to 1.931853e-3 instead of 1.93185265241e-3: ~3.4e-9 m/s^2 at the poles)."""
    lat = np.linspace(-PI / 2, PI / 2, 181)
    g = earth.gravity_n(pos(lat))
    np.testing.assert_allclose(g[:, 2], somigliana(lat), rtol=0, atol=1e-8)
    np.testing.assert_allclose(g[:, 0], 0.0, atol=1e-20)
    np.testing.assert_array_equal(g[:, 1], 0.0)


def test_free_air_gradient_45deg():
    hs = np.array([-50.0, 50.0])
    g = earth.gravity_n(pos(PI / 4, hs))[:, 2]
    grad = (g[1] - g[0]) / (hs[1] - hs[0])
    assert abs(grad - (-3.086e-6)) < 1e-9, grad
    # analytic derivative at h = 0 of Groves eq 2.139: -2 g0 / a (1 + f + m - 2 f sin^2 L)
    m = earth.OMEGA_IE**2 * A**2 * earth.B / earth.MU
    g0 = earth.gravity_n(pos(PI / 4))[2]
    expected = -2.0 * g0 / A * (1.0 + earth.F + m - 2.0 * earth.F * 0.5)
    assert abs(grad - expected) < 1e-12


def test_gravity_increases_with_depth_and_latitude():
    lat = np.radians(np.array([0.0, 20.0, 32.8, 50.0, 89.0]))
    g_surface = earth.gravity_n(pos(lat, 0.0))[:, 2]
    g_deep = earth.gravity_n(pos(lat, -35.0))[:, 2]  # 35 m below the surface (h < 0)
    assert np.all(np.diff(g_surface) > 0)
    np.testing.assert_allclose(g_deep - g_surface, 35.0 * 3.08e-6, rtol=3e-3)


def test_gravity_north_component():
    """Groves eq 2.140: g_N = -8.08e-9 h sin(2L) (north component at height h)."""
    g = earth.gravity_n(pos(PI / 4, 1000.0))
    assert abs(g[0] - (-8.08e-6)) < 1e-15
    g = earth.gravity_n(pos(LAT_HAIFA, -20.0))
    assert abs(g[0] - 8.08e-9 * 20.0 * np.sin(2 * LAT_HAIFA)) < 1e-20


def test_gravity_batched():
    r = np.random.default_rng(2)
    p = np.stack([r.uniform(-1.5, 1.5, (7, 25)), r.uniform(-3, 3, (7, 25)), r.uniform(-40, 10, (7, 25))], -1)
    g = earth.gravity_n(p)
    assert g.shape == (7, 25, 3)
    np.testing.assert_array_equal(g[6, 24], earth.gravity_n(p[6, 24]))


# ----------------------------------------------------------------------------- rates


def test_earth_rate():
    w = earth.w_ie_n(pos(LAT_HAIFA, -20.0, 0.6))
    np.testing.assert_allclose(
        w, 7.292115e-5 * np.array([np.cos(LAT_HAIFA), 0.0, -np.sin(LAT_HAIFA)]), rtol=0, atol=1e-20
    )
    assert abs(np.linalg.norm(w) - 7.292115e-5) < 1e-19
    np.testing.assert_allclose(earth.w_ie_n(pos(0.0)), [7.292115e-5, 0.0, 0.0], atol=1e-20)
    np.testing.assert_allclose(earth.w_ie_n(pos(PI / 2)), [0.0, 0.0, -7.292115e-5], atol=1e-20)
    assert earth.w_ie_n(pos(np.zeros((7, 25)))).shape == (7, 25, 3)


def test_transport_rate_east_velocity_at_equator():
    """v_E = 1 m/s at the equator: w_en = 1/R_E about the north axis."""
    w = earth.w_en_n(pos(0.0), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(w, [1.0 / 6378137.0, 0.0, 0.0], rtol=0, atol=1e-22)


def test_transport_rate_north_velocity():
    """v_N = 1 m/s: w_en = -1/(R_N + h) about east (the frame pitches down going north)."""
    p = pos(LAT_HAIFA, -30.0)
    R_N, _ = earth.radii(LAT_HAIFA)
    w = earth.w_en_n(p, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(w, [0.0, -1.0 / (R_N - 30.0), 0.0], rtol=0, atol=1e-22)


def test_transport_rate_general_and_jacobian():
    r = np.random.default_rng(3)
    p = np.stack([r.uniform(-1.3, 1.3, 50), r.uniform(-3, 3, 50), r.uniform(-40, 10, 50)], -1)
    v = r.normal(size=(50, 3)) * 2.0
    w = earth.w_en_n(p, v)
    R_N, R_E = earth.radii(p[:, 0])
    h = p[:, 2]
    ref = np.stack([v[:, 1] / (R_E + h), -v[:, 0] / (R_N + h), -v[:, 1] * np.tan(p[:, 0]) / (R_E + h)], -1)
    np.testing.assert_allclose(w, ref, rtol=1e-14, atol=0)
    assert np.all(w[:, 2] * v[:, 1] * np.tan(p[:, 0]) <= 0)  # -v_E tan L sign
    J = earth.d_w_en_d_v(p)
    assert J.shape == (50, 3, 3)
    np.testing.assert_allclose((J @ v[..., None])[..., 0], w, rtol=1e-14, atol=1e-24)
    # the vertical velocity does not enter the transport rate
    np.testing.assert_array_equal(J[:, :, 2], 0.0)


def test_transport_rate_is_craft_rate_of_a_great_circle():
    """Going east along the equator at v the nav frame turns at v / (R_E + h) about north,
    the time derivative of longitude times the earth-fixed north axis."""
    v = 2.0
    h = -15.0
    w = earth.w_en_n(pos(0.0, h), np.array([0.0, v, 0.0]))
    lon_rate = v / (A + h)
    np.testing.assert_allclose(w, [lon_rate, 0.0, 0.0], rtol=1e-15)


# ----------------------------------------------------------------------------- ned_offset


def test_ned_offset():
    p0 = pos(LAT_HAIFA, -10.0, 0.61)
    R_N, R_E = earth.radii(LAT_HAIFA)
    p = p0 + np.array([100.0 / (R_N - 10.0), 50.0 / ((R_E - 10.0) * np.cos(LAT_HAIFA)), -5.0])
    np.testing.assert_allclose(earth.ned_offset(p, p0), [100.0, 50.0, 5.0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(earth.ned_offset(p0, p0), 0.0)
    assert earth.ned_offset(np.broadcast_to(p, (7, 25, 3)), p0).shape == (7, 25, 3)


@pytest.mark.parametrize("lat_deg", [0.0, 32.8, 60.0])
def test_radii_consistent_with_ned_offset_distance(lat_deg):
    """1 arc-second of latitude is R_N * 4.848e-6 m of northing."""
    lat = np.radians(lat_deg)
    d = np.radians(1.0 / 3600.0)
    p0 = pos(lat)
    off = earth.ned_offset(p0 + np.array([d, d, 0.0]), p0)
    R_N, R_E = earth.radii(lat)
    # rtol limited by the round-off of (lat + d) - lat
    np.testing.assert_allclose(off[:2], [R_N * d, R_E * np.cos(lat) * d], rtol=1e-9)
