"""spokemesh.ConvexHull in-process: scipy's answers in general position, exactness where
Qhull needs options (near-flat sets, points on faces, equal points), the same facets for
any input order and thread count, incremental use, and bad input named. scipy's own
TestConvexHull runs in test_scipy_contract.py."""

import numpy as np
import pytest

from conftest import missing  # noqa: E402

try:
    import scipy.spatial as scipy_spatial
except ImportError:
    missing("scipy", "python3-scipy")

import spokemesh  # noqa: E402
from spokemesh import _core  # noqa: E402


def _facets(simplices, back=None):
    rows = simplices if back is None else back[simplices]
    return sorted(tuple(sorted(r)) for r in rows.tolist())


def _beneath_or_on_every_facet(hull):
    # Exact: the core's sides of every point against every facet.
    return all((hull._hull.sides(hull.points, x) <= 0).all() for x in range(hull.npoints))


@pytest.mark.parametrize("d,n,seed", [(2, 200, 1), (3, 500, 2), (4, 120, 3), (5, 60, 4), (6, 30, 5), (8, 14, 6)])
def test_facets_measures_and_equations_equal_scipys(d, n, seed):
    points = np.random.default_rng(seed).standard_normal((n, d))
    ours, theirs = spokemesh.ConvexHull(points), scipy_spatial.ConvexHull(points)
    assert _facets(ours.simplices) == _facets(theirs.simplices), f"seed {seed}"
    assert ours.simplices.dtype == np.int32 and ours.neighbors.dtype == np.int32
    np.testing.assert_allclose(ours.volume, theirs.volume, rtol=1e-12)
    np.testing.assert_allclose(ours.area, theirs.area, rtol=1e-12)
    key = {tuple(sorted(r)): i for i, r in enumerate(theirs.simplices.tolist())}
    order = [key[tuple(sorted(r))] for r in ours.simplices.tolist()]
    np.testing.assert_allclose(ours.equations, theirs.equations[order], atol=1e-12)
    assert sorted(ours.vertices.tolist()) == sorted(theirs.vertices.tolist())
    # Neighbour k shares every vertex but k.
    for f, (row, nbs) in enumerate(zip(ours.simplices, ours.neighbors)):
        for k, g in enumerate(nbs):
            assert set(row) - {row[k]} <= set(ours.simplices[g]) and f in ours.neighbors[g]


def test_2d_vertices_run_counter_clockwise_and_skip_points_on_edges():
    t = np.linspace(0, 2 * np.pi, 13)[:-1]
    ring = np.c_[np.cos(t), np.sin(t)]
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [1, 0], [2, 1], [1, 2], [0, 1], [1, 1]], float)
    for points in (ring, square):
        hull = spokemesh.ConvexHull(points)
        x, y = points[hull.vertices].T
        angle = np.unwrap(np.arctan2(y - y.mean(), x - x.mean()))
        assert (np.diff(angle) > 0).all()
        assert hull.vertices[0] == hull.vertices.min()
    assert sorted(spokemesh.ConvexHull(square).vertices.tolist()) == [0, 1, 2, 3]  # midpoints are on edges


def test_points_on_faces_and_equal_points_are_coplanar_with_qc():
    corners = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float)
    faces = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 1.0], [0.0, 0.5, 0.5]])
    points = np.concatenate([corners, [[0.5, 0.5, 0.5]], faces, corners[:2]])
    hull = spokemesh.ConvexHull(points, qhull_options="Qc")
    assert hull.vertices.tolist() == list(range(8)) and hull.nsimplex == 12
    assert hull.coplanar[:, 0].tolist() == [9, 10, 11, 12, 13]  # not the centre (8)
    assert hull.coplanar[3:, 2].tolist() == [0, 1]  # an equal point's nearest vertex is its equal
    assert spokemesh.ConvexHull(points).coplanar.shape == (0, 3)
    assert hull.volume == pytest.approx(1.0, rel=1e-14) and hull.area == pytest.approx(6.0, rel=1e-14)


def test_near_flat_sets_give_their_exact_hull():
    # A slab 1e-13 thick: Qhull needs options or joggling for such sets; the exact
    # hull has every point beneath or on every facet, and a positive volume.
    rng = np.random.default_rng(11)
    points = np.c_[rng.random((300, 2)), 1e-13 * rng.random(300)]
    hull = spokemesh.ConvexHull(points)
    assert _beneath_or_on_every_facet(hull)
    assert hull.volume > 0


def test_same_facets_for_any_input_order_and_thread_count():
    rng = np.random.default_rng(12)
    grid = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    points = np.concatenate([grid, rng.random((200, 3)) * 3])
    hull = spokemesh.ConvexHull(points)
    assert _beneath_or_on_every_facet(hull)
    perm = rng.permutation(len(points))
    again = spokemesh.ConvexHull(points[perm])
    assert _facets(again.simplices, perm) == _facets(hull.simplices)
    big = rng.random((300_000, 3))
    one, many = spokemesh.ConvexHull(big, threads=1), spokemesh.ConvexHull(big)
    assert one.simplices.tobytes() == many.simplices.tobytes()
    assert one.neighbors.tobytes() == many.neighbors.tobytes()


def test_incremental_restart_and_close():
    rng = np.random.default_rng(13)
    first, more = rng.random((20, 3)), rng.random((30, 3)) * 1.5
    hull = spokemesh.ConvexHull(first, incremental=True)
    old = [tuple(r) for r in hull.simplices.tolist()]
    hull.add_points(more)
    whole = spokemesh.ConvexHull(np.concatenate([first, more]))
    assert _facets(hull.simplices) == _facets(whole.simplices)
    survivors = [r for r in old if r in {tuple(x) for x in hull.simplices.tolist()}]
    assert [tuple(r) for r in hull.simplices.tolist()[:len(survivors)]] == survivors  # kept first, in order
    restarted = spokemesh.ConvexHull(first, incremental=True)
    restarted.add_points(more, restart=True)
    assert _facets(restarted.simplices) == _facets(whole.simplices)
    hull.close()
    with pytest.raises(RuntimeError, match="incremental"):
        hull.add_points(more)
    with pytest.raises(RuntimeError, match="incremental"):
        spokemesh.ConvexHull(first).add_points(more)


def test_bad_input_is_named():
    # Exactly on the plane z = x + 2 y (a product of random matrices would be rounded
    # off it, and its exact hull is then a thin solid).
    xy = np.random.default_rng(14).integers(-50, 50, (50, 2)).astype(float)
    flat = np.c_[xy, xy[:, 0] + 2 * xy[:, 1]]
    with pytest.raises(spokemesh.QhullError, match="2-dimensional affine subspace of R\\^3.*the hull is flat") as e:
        spokemesh.ConvexHull(flat)
    assert isinstance(e.value, scipy_spatial.QhullError) and isinstance(e.value, ValueError)
    with pytest.raises(spokemesh.QhullError, match="at least 4"):
        spokemesh.ConvexHull(np.eye(3))
    bad = np.random.default_rng(15).random((10, 3))
    bad[6, 2] = np.inf
    with pytest.raises(ValueError, match=r"points\[6\]\[2\]: not a finite number"):
        spokemesh.ConvexHull(bad)
    with pytest.raises(ValueError, match="masked"):
        spokemesh.ConvexHull(np.ma.masked_all((5, 2)))
    with pytest.raises(ValueError, match=r"shape \(5,\)"):
        spokemesh.ConvexHull(np.zeros(5))
    with pytest.raises(ValueError, match="'Qfoo' is not an option"):
        spokemesh.ConvexHull(np.random.default_rng(1).random((10, 2)), qhull_options="Qt Qfoo")
    with pytest.raises(ValueError, match="QG12: no point 12 among 10"):
        spokemesh.ConvexHull(np.random.default_rng(1).random((10, 2)), qhull_options="QG12")
    with pytest.raises(ValueError, match="dimension 3 is not the hull's 2"):
        spokemesh.ConvexHull(np.random.default_rng(1).random((10, 2)), incremental=True).add_points(np.zeros((1, 3)))


def test_core_hull_sides_are_exact_on_a_sliver():
    # Four points a hair off one plane and a fifth exactly on the plane of three: the
    # filter cannot tell; the rationals do.
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 2.0 ** -60], [0.5, 0.5, 0.0]])
    hull = _core.Hull(points)
    assert sorted(hull.vertices().tolist()) == [0, 1, 2, 3]  # point 4 lies on the base's edge plane
    sides = hull.sides(points, 4)
    assert set(sides.tolist()) <= {-1, 0} and 0 in sides.tolist()
