"""spokemesh.interpolate in-process: linear functions reproduced, scipy's answers on
the same points, vector and complex values, queries outside the hull, rescaling,
nearest neighbours against brute force, griddata's shapes, and bad input named.
scipy's own LinearNDInterpolator tests run in test_scipy_contract.py."""

import pickle

import numpy as np
import pytest

from conftest import missing  # noqa: E402

try:
    import scipy.interpolate as scipy_interpolate
except ImportError:
    missing("scipy", "python3-scipy")

import spokemesh  # noqa: E402
import spokemesh.interpolate as si  # noqa: E402


@pytest.mark.parametrize("d,seed", [(2, 1), (3, 2), (4, 3)])
def test_linear_functions_are_reproduced(d, seed):
    rng = np.random.default_rng(seed)
    points = rng.random((400, d))
    a, b = rng.standard_normal(d), 0.7
    f = si.LinearNDInterpolator(points, points @ a + b)
    # Inside the hull: convex combinations of three points each.
    w = rng.random((2000, 3))
    q = np.einsum("mk,mkd->md", w / w.sum(axis=1, keepdims=True), points[rng.integers(0, 400, (2000, 3))])
    np.testing.assert_allclose(f(q), q @ a + b, atol=1e-12)


def test_equals_scipys_in_general_position():
    rng = np.random.default_rng(4)
    points, values = rng.random((3000, 2)), rng.standard_normal(3000)
    q = rng.random((5000, 2)) * 1.2 - 0.1  # some outside
    ours = si.LinearNDInterpolator(points, values)(q)
    theirs = scipy_interpolate.LinearNDInterpolator(points, values)(q)
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
    np.testing.assert_allclose(ours[~np.isnan(ours)], theirs[~np.isnan(theirs)], atol=1e-12)


def test_vector_complex_values_fill_and_shapes():
    rng = np.random.default_rng(5)
    points = rng.random((200, 2))
    values = np.stack([points[:, 0] + 1j * points[:, 1], 2 * points[:, 0]], axis=1)[:, :, None]  # (200, 2, 1)
    f = si.LinearNDInterpolator(points, values, fill_value=-7)
    out = f(np.array([[[0.5, 0.5], [5.0, 5.0]]]))  # (1, 2) queries
    assert out.shape == (1, 2, 2, 1) and out.dtype == np.complex128
    np.testing.assert_allclose(out[0, 0, :, 0], [0.5 + 0.5j, 1.0], atol=1e-12)
    assert (out[0, 1] == -7).all()
    # ndim coordinate arrays, broadcast; a Delaunay given; pickling.
    g = si.LinearNDInterpolator(spokemesh.Delaunay(points), points[:, 0])
    np.testing.assert_allclose(g(np.array([0.3, 0.4]), 0.5), [0.3, 0.4], atol=1e-12)
    h = pickle.loads(pickle.dumps(g))
    np.testing.assert_allclose(h(0.35, 0.5), 0.35, atol=1e-12)


def test_rescale_and_grids():
    rng = np.random.default_rng(6)
    points = rng.random((500, 2)) * [1000.0, 0.001]
    values = points[:, 0] / 1000 + points[:, 1] * 1000
    gx, gy = np.meshgrid(np.linspace(100, 900, 7), np.linspace(1e-4, 9e-4, 5))
    z = si.griddata(points, values, (gx, gy), method="linear", rescale=True)
    assert z.shape == (5, 7)
    np.testing.assert_allclose(z, gx / 1000 + gy * 1000, atol=1e-12)


def test_nearest_is_brute_force():
    rng = np.random.default_rng(7)
    points, values = rng.random((1000, 3)), np.arange(1000.0)
    q = rng.random((500, 3))
    got = si.griddata(points, values, q, method="nearest")
    brute = ((q[:, None, :] - points[None, :, :]) ** 2).sum(axis=2).argmin(axis=1)
    np.testing.assert_array_equal(got, values[brute])
    np.testing.assert_array_equal(si.NearestNDInterpolator(points, values)(q), got)


def test_bad_input_is_named():
    points = np.random.default_rng(8).random((20, 2))
    with pytest.raises(ValueError, match="values: 19 rows for 20 points"):
        si.LinearNDInterpolator(points, np.zeros(19))
    with pytest.raises(ValueError, match="'cubic' is not available"):
        si.griddata(points, np.zeros(20), points, method="cubic")
    with pytest.raises(ValueError, match="xi: the last axis has 3 coordinates; the points have 2"):
        si.LinearNDInterpolator(points, np.zeros(20))(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="Rescaling is not supported"):
        si.LinearNDInterpolator(spokemesh.Delaunay(points), np.zeros(20), rescale=True)
    bad = points.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"points\[3\]\[1\]: not a finite number"):
        si.NearestNDInterpolator(bad, np.zeros(20))


# --- natural neighbours (Sibson) ----------------------------------------------------

@pytest.mark.parametrize("d,seed", [(2, 11), (3, 12)])
def test_natural_neighbours_are_the_star_of_the_query_and_reproduce_linear_functions(d, seed):
    rng = np.random.default_rng(seed)
    points = rng.random((500, d))
    a = rng.standard_normal(d)
    f = si.NaturalNeighborInterpolator(points, points @ a - 0.5)
    w = rng.random((300, 3))
    q = np.einsum("mk,mkd->md", w / w.sum(axis=1, keepdims=True), points[rng.integers(0, 500, (300, 3))])
    np.testing.assert_allclose(f(q), q @ a - 0.5, atol=1e-12)
    for x in q[:20]:
        ids, weights = si.natural_neighbor_coordinates(points, x)
        assert (weights >= 0).all() and abs(weights.sum() - 1) < 1e-12
        np.testing.assert_allclose(weights @ points[ids], x, atol=1e-12)
        # The neighbours of x in the set with x added (ids with a positive weight).
        star = spokemesh.Delaunay(np.concatenate([points, x[None, :]])).neighbors_of(500)
        assert sorted(ids[weights > 0].tolist()) == sorted(int(s) for s in star)


def test_natural_outside_on_points_duplicates_and_grids():
    rng = np.random.default_rng(13)
    points = rng.random((200, 2))
    values = np.sin(points[:, 0])
    f = si.NaturalNeighborInterpolator(points, values, fill_value=-1.0)
    assert f(5.0, 5.0) == -1.0
    np.testing.assert_allclose(f(points[:10]), values[:10], atol=1e-14)  # at data points: their values
    twice = np.concatenate([points, points[:5]])  # equal points: merged into the first
    ids, weights = si.natural_neighbor_coordinates(twice, points[3] + 1e-3)
    assert ids.max() < 200
    # A grid and queries on its lines: exact ties in the in-circle tests.
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0), indexing="ij"), -1).reshape(-1, 2)
    q = np.c_[rng.random(200) * 5, np.round(rng.random(200) * 10) / 2]
    z = si.griddata(g, 2 * g[:, 0] - g[:, 1], q, method="natural")
    np.testing.assert_allclose(z, 2 * q[:, 0] - q[:, 1], atol=1e-12)
    with pytest.raises(ValueError, match="dimension 4 is not supported"):
        si.NaturalNeighborInterpolator(rng.random((50, 4)), np.zeros(50))


def test_natural_vector_complex_values_and_equal_points():
    rng = np.random.default_rng(14)
    points = rng.random((300, 2))
    twice = np.concatenate([points, points[:7]])  # equal points: the first occurrence's value counts
    values = np.stack([points[:, 0] + 2j * points[:, 1], 3 * points[:, 1]], axis=1)
    values = np.concatenate([values, values[:7] + 100])  # the duplicates' values are not used
    f = si.NaturalNeighborInterpolator(twice, values)
    q = 0.2 + 0.6 * rng.random((50, 2))
    out = f(q)
    assert out.shape == (50, 2) and out.dtype == np.complex128
    np.testing.assert_allclose(out[:, 0], q[:, 0] + 2j * q[:, 1], atol=1e-12)
    np.testing.assert_allclose(out[:, 1], 3 * q[:, 1], atol=1e-12)
    assert np.isnan(f(np.array([[3.0, 3.0]]))[0, 1])
