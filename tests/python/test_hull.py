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


# --- SphericalVoronoi -------------------------------------------------------------

def _on_sphere(n, d, seed, radius=1.0, center=None):
    x = np.random.default_rng(seed).standard_normal((n, d))
    x = radius * x / np.linalg.norm(x, axis=1)[:, None]
    return x if center is None else x + center


@pytest.mark.parametrize("d", [2, 3])
def test_spherical_areas_fill_the_sphere(d):
    center = np.arange(1.0, d + 1)
    points = _on_sphere(2000, d, 21, 2.5, center)
    sv = spokemesh.SphericalVoronoi(points, radius=2.5, center=center)
    whole = 2 * np.pi * 2.5 if d == 2 else 4 * np.pi * 2.5 ** 2
    assert sv.calculate_areas().sum() == pytest.approx(whole, rel=1e-12)
    assert (sv.calculate_areas() > 0).all()


def test_circle_arcs_are_each_points_own():
    # Point i's arc runs from the midpoint before it to the midpoint after it.
    angles = np.array([0.0, 1.0, 2.5, 4.0])
    sv = spokemesh.SphericalVoronoi(np.c_[np.cos(angles), np.sin(angles)])
    gaps = np.diff(np.r_[angles, 2 * np.pi])  # 1, 1.5, 1.5, 2pi - 4
    expected = (gaps + np.roll(gaps, 1)) / 2
    np.testing.assert_allclose(sv.calculate_areas(), expected, rtol=1e-12)


def test_cospherical_corners_and_sorted_regions_in_place():
    cube = np.array([[i & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], float) * 2 - 1
    sv = spokemesh.SphericalVoronoi(cube / np.sqrt(3))
    np.testing.assert_allclose(sv.calculate_areas(), 4 * np.pi / 8, rtol=1e-12)
    held = sv.regions
    sv.sort_vertices_of_regions()
    assert held is sv.regions and all(len(r) >= 3 for r in held)
    # Counter-clockwise seen from outside: each consecutive pair turns left about the point.
    for i, region in enumerate(sv.regions):
        v = sv.vertices[region]
        turns = [np.dot(sv.points[i], np.cross(v[j] - sv.points[i], v[(j + 1) % len(v)] - sv.points[i]))
                 for j in range(len(v))]
        assert all(t >= -1e-12 for t in turns), (i, turns)


def test_spherical_regions_do_not_depend_on_input_order():
    points = _on_sphere(300, 3, 22)
    perm = np.random.default_rng(23).permutation(300)
    a, b = spokemesh.SphericalVoronoi(points), spokemesh.SphericalVoronoi(points[perm])
    a.sort_vertices_of_regions()
    b.sort_vertices_of_regions()

    def cycles(sv, order):
        out = {}
        for i, region in enumerate(sv.regions):
            coords = [tuple(np.round(sv.vertices[v], 12)) for v in region]
            k = coords.index(min(coords))
            out[int(order[i])] = coords[k:] + coords[:k]
        return out
    assert cycles(a, np.arange(300)) == cycles(b, perm)


def test_spherical_errors_are_scipys():
    points = _on_sphere(50, 3, 24)
    with pytest.raises(ValueError, match="Duplicate generators present"):
        spokemesh.SphericalVoronoi(np.concatenate([points, points[:1]]))  # an equal point: not a hull vertex
    near = points.copy()
    near[1] = points[0] + 1e-8 * np.array([0.0, 0.0, 1.0])
    near[1] /= np.linalg.norm(near[1])
    with pytest.raises(ValueError, match="Duplicate generators present"):
        spokemesh.SphericalVoronoi(near)
    with pytest.raises(ValueError, match="Radius inconsistent"):
        spokemesh.SphericalVoronoi(points * 1.01)
    circle = np.c_[_on_sphere(200_000, 2, 25), np.zeros(200_000)]  # the Gram path (above 100,000 points)
    with pytest.raises(ValueError, match="Rank of input points must be at least 3"):
        spokemesh.SphericalVoronoi(circle)
    with pytest.raises(TypeError, match="three-dimensional"):
        spokemesh.SphericalVoronoi(_on_sphere(20, 4, 26)).sort_vertices_of_regions()


# --- HalfspaceIntersection ---------------------------------------------------------

def _tangent_halfspaces(n, d, seed):
    # The halfspaces u . x <= 1 for random unit u: a polytope around the origin.
    u = np.random.default_rng(seed).standard_normal((n, d))
    u /= np.linalg.norm(u, axis=1)[:, None]
    return np.c_[u, -np.ones(n)]


@pytest.mark.parametrize("d,n,seed", [(2, 40, 31), (3, 200, 32), (4, 80, 33)])
def test_halfspace_vertices_are_scipys_and_feasible(d, n, seed):
    hs = _tangent_halfspaces(n, d, seed)
    ours = spokemesh.HalfspaceIntersection(hs, np.zeros(d))
    theirs = scipy_spatial.HalfspaceIntersection(hs, np.zeros(d))
    assert sorted(map(tuple, np.round(ours.intersections, 9).tolist())) == \
        sorted(map(tuple, np.round(theirs.intersections, 9).tolist()))
    assert (hs[:, :-1] @ ours.intersections.T + hs[:, -1:] <= 1e-12).all()
    assert sorted(map(sorted, ours.dual_facets)) == sorted(map(sorted, theirs.dual_facets))
    assert ours.dual_vertices.tolist() == sorted(theirs.dual_vertices.tolist())
    assert ours.dual_volume == pytest.approx(theirs.dual_volume, rel=1e-12)


def test_halfspace_redundant_merged_and_incremental():
    # The unit square's four sides, a redundant x <= 5, and a pyramid's apex where four
    # planes meet (merged into one vertex with four halfspaces).
    square = np.array([[-1, 0, 0], [1, 0, -1], [0, -1, 0], [0, 1, -1], [1, 0, -5.0]])
    hs = spokemesh.HalfspaceIntersection(square, np.array([0.5, 0.5]), incremental=True)
    assert 4 not in hs.dual_vertices.tolist() and len(hs.intersections) == 4
    pyramid = np.array([[0, 0, -1, 0], [1, 0, 1, -1], [-1, 0, 1, -1], [0, 1, 1, -1], [0, -1, 1, -1.0]])
    p = spokemesh.HalfspaceIntersection(pyramid, np.array([0.0, 0.0, 0.2]))
    apex = [f for f in p.dual_facets if len(f) == 4]
    assert len(p.intersections) == 5 and apex and sorted(apex[0]) == [1, 2, 3, 4]
    hs.add_halfspaces(np.array([[1, 1, -1.5]]))
    again = spokemesh.HalfspaceIntersection(np.concatenate([square, [[1, 1, -1.5]]]), np.array([0.5, 0.5]))
    assert sorted(map(tuple, np.round(hs.intersections, 12).tolist())) == \
        sorted(map(tuple, np.round(again.intersections, 12).tolist()))
    hs.close()
    with pytest.raises(RuntimeError, match="incremental"):
        hs.add_halfspaces(np.array([[1, 1, -1.5]]))


def test_halfspace_errors_are_named():
    square = np.array([[-1, 0, 0], [1, 0, -1], [0, -1, 0], [0, 1, -1.0]])
    with pytest.raises(spokemesh.QhullError, match="not strictly inside halfspace 1"):
        spokemesh.HalfspaceIntersection(square, np.array([1.0, 0.5]))  # on x <= 1
    with pytest.raises(spokemesh.QhullError, match="unbounded"):
        spokemesh.HalfspaceIntersection(np.array([[1, 0, -1], [0, 1, -1], [1, 1, -1.0]]), np.array([0.0, 0.0]))
    with pytest.raises(ValueError, match=r"interior_point: expected shape \(2,\)"):
        spokemesh.HalfspaceIntersection(square, np.array([0.5, 0.5, 0.5]))
    with pytest.raises(ValueError, match=r"halfspaces\[2\]\[1\]: not a finite number"):
        bad = square.copy()
        bad[2, 1] = np.nan
        spokemesh.HalfspaceIntersection(bad, np.array([0.5, 0.5]))


@pytest.mark.parametrize("d,seed", [(2, 41), (3, 42), (4, 43)])
def test_halfspace_duality_round_trip(d, seed):
    # A polytope's facets as halfspaces give back its vertices. In 2-d each vertex is the
    # meeting of exactly two lines: each comes back once. Above, the rounded planes of
    # the facets around a vertex or an edge do not meet exactly where the facets did: the
    # exact intersection has more vertices there (Qhull merges them within its
    # precision). Every one is feasible, and every vertex of the polytope has one within
    # 1e-9. (Sliver dual facets need their equations from rational cofactors: in 4-d the
    # double ones put vertices 0.77 outside a halfspace.)
    points = np.random.default_rng(seed).standard_normal((60, d))
    hull = spokemesh.ConvexHull(points)
    centre = points[hull.vertices].mean(axis=0)
    first = np.unique(hull._hull.groups(points), return_index=True)[1]  # one row per polytope facet
    halfspaces = hull.equations[first]
    hs = spokemesh.HalfspaceIntersection(halfspaces, centre)
    assert (halfspaces[:, :-1] @ hs.intersections.T + halfspaces[:, -1:]).max() < 1e-12
    vertices = points[hull.vertices]
    dist = np.linalg.norm(hs.intersections[:, None, :] - vertices[None, :, :], axis=2)
    assert dist.min(axis=0).max() < 1e-9
    if d == 2:
        assert len(hs.intersections) == len(vertices)
    assert len(hs.dual_vertices) == len(first)  # no facet's halfspace is redundant
