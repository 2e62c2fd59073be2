"""scipy's own tests of Delaunay and Voronoi, run on spokemesh.Delaunay and
spokemesh.Voronoi.

The test file is the one Debian's python3-scipy installs
(scipy/spatial/tests/test_qhull.py); nothing of it is copied here. It is loaded as a
module, its `qhull` name (scipy.spatial._qhull) is replaced by a namespace in which
Delaunay and Voronoi are spokemesh's and everything else is scipy's (and its own
`Voronoi` name by spokemesh.Voronoi), and its Delaunay and Voronoi test classes are
collected from this module, so pytest runs scipy's assertions unchanged.

Tests that cannot pass yet are marked strict xfail with the reason (a fixed one then
fails the run until it is taken off the list); tests that assert Qhull's own row order
on tiny inputs are left out for good: the order of simplices is unspecified in scipy's
documentation, and ours is the sweep order (docs/algorithm.md). Likewise the order in
which each Voronoi region lists its vertices: Qhull starts each cycle where its facet
lists happen to start and goes either way round (in TestVoronoi.test_simple it goes
clockwise around point 4 and counter-clockwise around point 1 of the same grid);
ours go counter-clockwise in 2-d from a fixed vertex (README, "Python"). Those tests'
other assertions are run below on the same data against scipy's own Voronoi, with
regions compared as cycles.
"""

import functools
import importlib.util
import math
import os
import types

import numpy as np
import pytest

from conftest import missing  # noqa: E402

try:
    import scipy.spatial as scipy_spatial
except ImportError:
    missing("scipy", "python3-scipy")
import scipy.spatial._qhull as scipy_qhull  # noqa: E402

import spokemesh  # noqa: E402

SCIPY_TESTS = os.path.join(os.path.dirname(scipy_spatial.__file__), "tests", "test_qhull.py")
if not os.path.exists(SCIPY_TESTS):
    missing(f"scipy's own tests ({SCIPY_TESTS})", "python3-scipy")

_spec = importlib.util.spec_from_file_location("scipy_test_qhull", SCIPY_TESTS)
scipy_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(scipy_tests)
scipy_tests.qhull = types.SimpleNamespace(**{**vars(scipy_qhull), "Delaunay": spokemesh.Delaunay,
                                             "Voronoi": spokemesh.Voronoi, "ConvexHull": spokemesh.ConvexHull,
                                             "HalfspaceIntersection": spokemesh.HalfspaceIntersection})
scipy_tests.Voronoi = spokemesh.Voronoi

# Qhull's own row order on tiny inputs (unspecified by scipy's documentation).
ROW_ORDER = {"test_2d_square", "test_find_simplex", "test_convex_hull",
             # Qhull's two rows, in its order, each with its vertex order ((1, 4, 0) is
             # clockwise; ours are positively oriented): the same two triangles as ours.
             "test_furthest_site"}
# Qhull's own order of the vertices within each Voronoi region (see above; in
# test_furthest_site it lists points 0 and 4's regions both as (-1, 1, 0), one going
# clockwise and one counter-clockwise).
REGION_ORDER = {"test_simple", "test_furthest_site"}

# What spokemesh.Delaunay does not do yet, and why.
NOT_YET = {
    # The set is degenerate (many cospherical points): half its simplices are broken
    # differently from Qhull's, both Delaunay. Ours (CGAL's symbolic perturbation) leave
    # 31 near-flat simplices, every one with NaN rows as the test asks, where Qhull's
    # leave 22 and the test allows at most 22.
    "test_degenerate_barycentric_transforms": "31 near-flat simplices where the test allows 22 (Qhull's count)",
}
# Where exactness and Qhull part ways, on scipy's dataset made to trip Qhull
# (pathological-2: a 3 x 3 grid with one corner moved down by one ulp). The moved
# corner leaves point 3 an ulp inside the hull, so the exact triangulation has a sliver
# triangle (0, 6, 3) whose circumcentre lies at y = -4.5e15, and the square (3, 4, 6, 7)
# is no longer cocircular, so its two circumcentres are two vertices 1e-16 apart. Qhull
# merges both away within its precision. test_ridges then probes the ridge out to
# -4.5e15 with a KD-tree in floating point (whose distances there cannot tell the
# points apart), and test_incremental maps vertices between two diagrams by
# np.allclose, which sends both close vertices to one. Merging by a tolerance is what
# spokemesh does not do (README, "exact"); both tests still run and must fail only
# there.
EXACT_NOT_MERGED = {"pathological-2", "pathological-2-chunk-1", "pathological-2-chunk-4", "pathological-2-chunk-16"}


def _exact_where_qhull_merges(test):
    @functools.wraps(test)
    def run(self, name, *args, **kwargs):
        if name not in EXACT_NOT_MERGED:
            return test(self, name, *args, **kwargs)
        try:
            test(self, name, *args, **kwargs)
        except AssertionError:
            pytest.xfail("exact vertices and slivers where Qhull merges within its precision (see EXACT_NOT_MERGED)")
        raise AssertionError(f"{name} now passes: take it off EXACT_NOT_MERGED")
    return run


VORONOI_NOT_YET = {}

# scipy's ConvexHull tests that assert which rows Qhull lists first (its facet order):
# each is run below on the same data with the rows matched by their vertex sets.
HULL_ORDER = {"test_good2d", "test_good3d", "test_good2d_incremental_changes"}


def _wrap(cls, order=ROW_ORDER, not_yet=NOT_YET):
    """scipy's test class with its order tests left out and the others marked."""
    attrs = {}
    for name, value in vars(cls).items():
        if name in order:
            attrs[name] = None  # not collected
        elif name in not_yet and callable(value):
            attrs[name] = pytest.mark.xfail(reason=not_yet[name], strict=True)(value)
    return type(cls.__name__, (cls,), attrs)


TestDelaunay = _wrap(scipy_tests.TestDelaunay)
TestUtilities = _wrap(scipy_tests.TestUtilities)
TestVertexNeighborVertices = _wrap(scipy_tests.TestVertexNeighborVertices)
TestVoronoi = _wrap(scipy_tests.TestVoronoi, REGION_ORDER, VORONOI_NOT_YET)
TestConvexHull = _wrap(scipy_tests.TestConvexHull, HULL_ORDER, {})
# test_cube zips Qhull's dual facets with ours in Qhull's order, and
# test_cube_halfspace_intersection compares the vertices in Qhull's row order; both are
# run below with rows compared as sets.
Test_HalfspaceIntersection = _wrap(scipy_tests.Test_HalfspaceIntersection,
                                   {"test_cube", "test_cube_halfspace_intersection"}, {})
TestVoronoi.test_ridges = _exact_where_qhull_merges(scipy_tests.TestVoronoi.test_ridges)
TestVoronoi.test_incremental = _exact_where_qhull_merges(scipy_tests.TestVoronoi.test_incremental)


# --- spokemesh.Voronoi against scipy's Voronoi on the same points -------------------
# What the left-out region-order test checks, and more: vertices (matched by
# coordinates), ridges and regions, with each 2-d region compared as a cycle (either
# direction, any start) and 3-d regions as sets; on random sets (seeds in the ids) and
# on grids, where both merge cospherical simplices into one vertex (Qhull within its
# precision, spokemesh by an exact test).

def _grid(*sizes):
    axes = [np.arange(k, dtype=float) for k in sizes]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(sizes))


VORONOI_SETS = {
    "scipy-test-simple-3x3": lambda: _grid(3, 3),
    "random-2d-300-seed-1": lambda: np.random.default_rng(1).random((300, 2)),
    "random-3d-300-seed-2": lambda: np.random.default_rng(2).random((300, 3)),
    "grid-2d-7x5": lambda: _grid(7, 5),
    "grid-3d-4x4x3": lambda: _grid(4, 4, 3),
    "random-4d-60-seed-3": lambda: np.random.default_rng(3).random((60, 4)),
}


def _cycle(region):
    if not region:
        return ()
    turns = []
    for seq in (list(region), list(region)[::-1]):
        turns += [tuple(seq[i:] + seq[:i]) for i in range(len(seq))]
    return min(turns)


FURTHEST_SETS = {
    "scipy-test-furthest-site": lambda: np.array([(0, 0), (0, 1), (1, 0), (0.5, 0.5), (1.1, 1.1)], float),
    "random-2d-300-seed-6": lambda: np.random.default_rng(6).random((300, 2)),
    "random-3d-400-seed-7": lambda: np.random.default_rng(7).random((400, 3)),
    "disc-2d-200-seed-8": lambda: _on_circle(200, 8),
    # Every side holds more points than its ends, and the corners are cocircular.
    "grid-2d-5x4": lambda: _grid(5, 4),
    "grid-2d-3x3": lambda: _grid(3, 3),
    # A cube grid whose hull two outside points make partly clean: the wrap starts on a
    # clean facet and crosses the degenerate ones.
    "grid-3d-3x3x3-plus-2": lambda: np.concatenate([_grid(3, 3, 3), [[1.0, 1.2, 4.0], [0.7, -3.0, 1.1]]]),
    # Every facet of the hull holds more than d points: the wrap starts from a simplex
    # of the hull's corners (their spheres all meet in one Voronoi vertex).
    "grid-3d-3x3x3": lambda: _grid(3, 3, 3),
    "grid-3d-4x3x2": lambda: _grid(4, 3, 2),
}


def _on_circle(n, seed):
    # Points near a circle: every one on the hull, many furthest-site simplices.
    rng = np.random.default_rng(seed)
    angle = np.sort(rng.random(n)) * 2 * np.pi
    return np.stack([np.cos(angle), np.sin(angle)], 1) * (1 + 0.01 * rng.random((n, 1)))


@pytest.mark.parametrize("name", sorted(VORONOI_SETS) + [f"furthest:{k}" for k in sorted(FURTHEST_SETS)])
def test_voronoi_is_scipys_diagram(name):
    furthest = name.startswith("furthest:")
    points = FURTHEST_SETS[name.split(":", 1)[1]]() if furthest else VORONOI_SETS[name]()
    ours = spokemesh.Voronoi(points, furthest_site=furthest)
    theirs = scipy_spatial.Voronoi(points, furthest_site=furthest)
    # Vertices: the same coordinates, one to one.
    assert ours.vertices.shape == theirs.vertices.shape, name
    tree = scipy_spatial.cKDTree(theirs.vertices)
    dist, to_theirs = tree.query(ours.vertices)
    scale = max(1.0, float(np.abs(points).max()))
    assert dist.max() <= 1e-9 * scale and len(set(to_theirs.tolist())) == len(to_theirs), name
    mapped = {-1: -1, **{i: int(j) for i, j in enumerate(to_theirs)}}
    # Ridges: the same pairs of points, each between the same vertices.
    ridges_ours = {tuple(sorted(p)): frozenset(mapped[v] for v in vs) for p, vs in ours.ridge_dict.items()}
    ridges_theirs = {tuple(sorted(p)): frozenset(vs) for p, vs in theirs.ridge_dict.items()}
    assert ridges_ours == ridges_theirs, name
    # Regions: each point's, as a cycle in 2-d, as a set above.
    for i in range(len(points)):
        a = [mapped[v] for v in ours.regions[ours.point_region[i]]]
        b = list(theirs.regions[theirs.point_region[i]])
        if points.shape[1] == 2:
            assert _cycle(a) == _cycle(b), (name, i, a, b)
        else:
            assert sorted(a) == sorted(b), (name, i, a, b)
    if furthest:
        # The triangulation underneath: scipy's furthest-site simplices, as sets.
        tri, ref = ours.delaunay, scipy_spatial.Delaunay(points, furthest_site=True)
        if "grid" in name:
            # Cocircular corners: any diagonal is furthest-site (ours by the symbolic
            # perturbation, Qhull's by Qt); the same corners, covering the same hull.
            assert set(tri.simplices.ravel().tolist()) == set(ref.simplices.ravel().tolist())
            size = lambda s: np.abs(np.linalg.det(points[s[:, 1:]] - points[s[:, :1]])).sum()  # noqa: E731
            assert np.isclose(size(tri.simplices), size(ref.simplices))
            assert np.isclose(size(tri.simplices) / math.factorial(points.shape[1]), scipy_spatial.ConvexHull(points).volume)
        else:
            assert {tuple(sorted(t)) for t in tri.simplices.tolist()} == \
                {tuple(sorted(t)) for t in ref.simplices.tolist()}
        assert (tri.find_simplex(points.mean(axis=0, keepdims=True)) >= 0).all()
        assert len(ours.regions) == len(points)
        return
    # scipy's extra empty region (Qz), and every point's region listed once.
    assert len(ours.regions) == len(points) + 1 and ours.regions[0] == []
    assert sorted(ours.point_region.tolist()) == list(range(1, len(points) + 1))


def test_voronoi_regions_go_counter_clockwise_and_do_not_depend_on_order():
    # 2-d regions: counter-clockwise (positive signed area), bounded ones from their
    # smallest vertex; the diagram of a permuted set is the same diagram renumbered.
    rng = np.random.default_rng(4)
    points = rng.random((500, 2))
    vor = spokemesh.Voronoi(points)
    for i, r in enumerate(vor.regions[1:]):
        if -1 in r:
            assert r[0] == -1, (i, r)
            continue
        assert r[0] == min(r), (i, r)
        x, y = vor.vertices[r].T
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0, (i, r)
    perm = rng.permutation(len(points))
    other = spokemesh.Voronoi(points[perm])
    assert sorted(map(tuple, np.round(other.vertices, 12).tolist())) == \
        sorted(map(tuple, np.round(vor.vertices, 12).tolist()))
    pairs = {tuple(sorted((int(perm[p]), int(perm[q])))) for p, q in other.ridge_points}
    assert pairs == {tuple(p) for p in vor.ridge_points.tolist()}


def test_voronoi_options_duplicates_and_extras():
    points = np.random.default_rng(5).random((50, 2))
    plain = spokemesh.Voronoi(points, qhull_options="Qbb Qc")
    assert len(plain.regions) == 50 and plain.point_region.tolist() == list(range(50))
    with pytest.raises(ValueError, match="not an option"):
        spokemesh.Voronoi(points, qhull_options="Qbogus")
    # Equal points: one region for both (Qc, the default), or none for the copy.
    twice = np.concatenate([points, points[:3]])
    vor = spokemesh.Voronoi(twice)
    assert vor.point_region[50:].tolist() == vor.point_region[:3].tolist()
    assert spokemesh.Voronoi(twice, qhull_options="Qbb").point_region[50:].tolist() == [-1] * 3
    # Cell measures beside scipy's attributes: the clipped areas fill the box.
    areas = plain.cells(box=[0, 0, 1, 1])["volume"]
    assert abs(areas.sum() - 1.0) < 1e-12
    # Incremental: the same diagram as at once.
    inc = spokemesh.Voronoi(points[:20], incremental=True)
    inc.add_points(points[20:])
    once = spokemesh.Voronoi(points, qhull_options="Qc")
    assert np.array_equal(inc.vertices, once.vertices) and inc.regions == once.regions
    assert inc.ridge_vertices == once.ridge_vertices
    # The furthest-site triangulation; stars and cells are the nearest-site one's.
    far = spokemesh.Delaunay(points, furthest_site=True)
    assert far.furthest_site and (far.equations[:, -2] > 0).all()
    with pytest.raises(ValueError, match="furthest-site"):
        far.cell(0)
    grown = spokemesh.Delaunay(points[:30], furthest_site=True, incremental=True)
    grown.add_points(points[30:])
    assert np.array_equal(grown.simplices, far.simplices)
    import pickle
    assert pickle.loads(pickle.dumps(far)).furthest_site
    back = pickle.loads(pickle.dumps(plain))
    assert back.regions == plain.regions and np.array_equal(back.vertices, plain.vertices)


def _exact_sphere_holds(points, simplex):
    """Whether every point lies in the closed circumsphere of `simplex`, in rationals."""
    from fractions import Fraction
    p = [[Fraction(float(x)) for x in points[i]] for i in simplex]
    d = len(p) - 1
    # Centre c: 2 (p_i - p_0) . c = |p_i|^2 - |p_0|^2, by Gauss-Jordan elimination.
    rows = [[2 * (p[i][k] - p[0][k]) for k in range(d)] + [sum(x * x for x in p[i]) - sum(x * x for x in p[0])]
            for i in range(1, d + 1)]
    for col in range(d):
        piv = next(r for r in range(col, d) if rows[r][col] != 0)
        rows[col], rows[piv] = rows[piv], rows[col]
        for r in range(d):
            if r != col and rows[r][col] != 0:
                f = rows[r][col] / rows[col][col]
                rows[r] = [a - f * b for a, b in zip(rows[r], rows[col])]
    c = [rows[k][d] / rows[k][k] for k in range(d)]
    radius2 = sum((a - b) ** 2 for a, b in zip(p[0], c))
    return all(sum((Fraction(float(x)) - b) ** 2 for x, b in zip(q, c)) <= radius2 for q in points)


@pytest.mark.parametrize("shape", [(2, 2, 2), (3, 3, 3), (4, 3, 2), (2, 2, 2, 2), (3, 3, 3, 3)])
def test_furthest_site_of_a_hull_degenerate_on_every_facet(shape):
    # Every facet of a box grid's hull holds more than d points, and all the corners are
    # cospherical: the furthest-site triangulation is a triangulation of the corners
    # chosen by the symbolic perturbation. It must tile the hull, every sphere must hold
    # every point (exactly), and it must not depend on the input order. (Qhull refuses
    # the 2x2x2 and 2x2x2x2 cases as cospherical input.)
    points = _grid(*shape)
    d = points.shape[1]
    tri = spokemesh.Delaunay(points, furthest_site=True)
    corners = {i for i, p in enumerate(points) if all(x in (0, n - 1) for x, n in zip(p, shape))}
    assert set(tri.simplices.ravel().tolist()) == corners
    volume = sum(abs(np.linalg.det(points[s[1:]] - points[s[0]])) for s in tri.simplices) / math.factorial(d)
    assert abs(volume - np.prod(np.array(shape) - 1.0)) < 1e-9
    assert all(_exact_sphere_holds(points, s) for s in tri.simplices)
    perm = np.random.default_rng(sum(shape)).permutation(len(points))
    again = spokemesh.Delaunay(points[perm], furthest_site=True)
    assert sorted(tuple(sorted(s)) for s in tri.simplices) == sorted(tuple(sorted(perm[s])) for s in again.simplices)
    # One Voronoi vertex, the box's centre, shared by every region.
    vor = spokemesh.Voronoi(points, furthest_site=True)
    assert np.allclose(vor.vertices, [(np.array(shape) - 1) / 2])


def test_furthest_site_refuses_a_degenerate_hull_with_many_corners():
    # A prism over a 40-gon in three layers: every facet holds more than 3 points and
    # the 80 corners are too many to search for a first simplex; the error names them.
    angle = np.arange(40) * 2 * np.pi / 40
    ring = np.stack([np.cos(angle), np.sin(angle)], 1)
    points = np.concatenate([np.column_stack([ring, np.full(40, z)]) for z in (0.0, 1.0, 2.0)])
    with pytest.raises(ValueError, match="lie on one facet of the convex hull.*too many corners"):
        spokemesh.Delaunay(points, furthest_site=True)


# --- spokemesh.ConvexHull's `good` against scipy's, rows matched by vertex sets -----
# What the left-out HULL_ORDER tests check (which facets a viewpoint sees), on their data
# and on random sets, without Qhull's row order.

_SQUARE_AND_VIEWPOINT = np.array([[0.2, 0.2], [0.2, 0.4], [0.4, 0.4], [0.4, 0.2], [0.3, 0.6]])
_GOOD3D = np.array([[0.0, 0.0, 0.0], [0.90029516, -0.39187448, 0.18948093], [0.48676420, -0.72627633, 0.48536925],
                    [0.57651530, -0.81179274, -0.09285832], [0.67846893, -0.71119562, 0.18406710]])
GOOD_CASES = {
    "good2d": (_SQUARE_AND_VIEWPOINT, None, "QG4"),
    "good2d-hidden": (_SQUARE_AND_VIEWPOINT, None, "QG-4"),
    "good2d-inside": (np.array([[0.2, 0.2], [0.2, 0.4], [0.4, 0.4], [0.4, 0.2], [0.3, 0.3]]), None, "QG4"),
    "good3d": (_GOOD3D, None, "QG0"),
    # test_good2d_incremental_changes's five additions, seen (QG4) and not (QG-4).
    **{f"good2d-added-{k}{view}": (_SQUARE_AND_VIEWPOINT, added, view)
       for k, added in enumerate([np.array([[0.3, 0.7]]), np.array([[0.3, -0.7]]), np.array([[0.3, 0.41]]),
                                  np.array([[0.5, 0.6], [0.6, 0.6]]), np.array([[0.3, 0.6 + 1e-16]])])
       for view in ("QG4", "QG-4")},
    "random-3d-seed-5": (np.random.default_rng(5).random((40, 3)), None, "QG7"),
    "random-4d-seed-6": (np.random.default_rng(6).random((40, 4)), np.random.default_rng(7).random((5, 4)), "QG-3"),
}


def _good_by_facet(hull):
    return {tuple(sorted(row)): bool(g) for row, g in zip(hull.simplices.tolist(), hull.good)}


@pytest.mark.parametrize("name", sorted(GOOD_CASES))
@pytest.mark.parametrize("incremental", [False, True])
def test_hull_good_is_scipys(name, incremental):
    points, more, options = GOOD_CASES[name]
    if more is not None and not incremental:
        points, more = np.concatenate([points, more]), None
    ours = spokemesh.ConvexHull(points, incremental=incremental, qhull_options=options)
    theirs = scipy_spatial.ConvexHull(points, incremental=incremental, qhull_options=options)
    if more is not None:
        ours.add_points(more)
        theirs.add_points(more)
    assert _good_by_facet(ours) == _good_by_facet(theirs), name


# --- scipy's own SphericalVoronoi tests on spokemesh.SphericalVoronoi ----------------
# test_spherical_voronoi.py, loaded as test_qhull.py is, with its SphericalVoronoi name
# replaced. Left out: the test that lists Qhull's facet numbers (its expected regions
# name vertices by Qhull's facet order); what it checks is run below with vertices
# matched by coordinates.
SCIPY_SV_TESTS = os.path.join(os.path.dirname(scipy_spatial.__file__), "tests", "test_spherical_voronoi.py")
_sv_spec = importlib.util.spec_from_file_location("scipy_test_spherical_voronoi", SCIPY_SV_TESTS)
scipy_sv_tests = importlib.util.module_from_spec(_sv_spec)
_sv_spec.loader.exec_module(scipy_sv_tests)
scipy_sv_tests.SphericalVoronoi = spokemesh.SphericalVoronoi
SV_ORDER = {"test_sort_vertices_of_regions_flattened"}
TestSphericalVoronoi = _wrap(scipy_sv_tests.TestSphericalVoronoi, SV_ORDER, {})


def _regions_by_coordinates(sv):
    """Each generator's region as the cycle of its vertices' rounded coordinates."""
    out = []
    for region in sv.regions:
        cycle = [tuple(np.round(sv.vertices[v], 9)) for v in region]
        out.append(_cycle(cycle))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sorted_spherical_regions_are_scipys_cycles(seed):
    points = scipy_sv_tests._sample_sphere(50, 3, seed=seed)
    ours, theirs = spokemesh.SphericalVoronoi(points), scipy_spatial.SphericalVoronoi(points)
    ours.sort_vertices_of_regions()
    theirs.sort_vertices_of_regions()
    assert _regions_by_coordinates(ours) == _regions_by_coordinates(theirs)
    np.testing.assert_allclose(ours.calculate_areas(), theirs.calculate_areas(), rtol=1e-10)


def test_halfspace_cube_facets_are_qhalfs_as_a_set():
    # scipy's test_cube's data and Qhull's answer (qhalf H0.5,0.5,0.5), in any order.
    halfspaces = np.array([[-1., 0., 0., 0.], [1., 0., 0., -1.], [0., -1., 0., 0.], [0., 1., 0., -1.],
                           [0., 0., -1., 0.], [0., 0., 1., -1.]])
    hs = spokemesh.HalfspaceIntersection(halfspaces, np.array([0.5, 0.5, 0.5]))
    qhalf_facets = [[2, 4, 0], [4, 2, 1], [5, 2, 0], [2, 5, 1], [3, 4, 1], [4, 3, 0], [5, 3, 1], [3, 5, 0]]
    assert sorted(map(sorted, hs.dual_facets)) == sorted(map(sorted, qhalf_facets))
    np.testing.assert_allclose(hs.dual_points, [[-2, 0, 0], [2, 0, 0], [0, -2, 0], [0, 2, 0], [0, 0, -2], [0, 0, 2]])
    corners = {tuple(np.round(x, 12)) for x in hs.intersections}
    assert corners == {(float(i & 1), float(i >> 1 & 1), float(i >> 2 & 1)) for i in range(8)}


@pytest.mark.parametrize("dt", [np.float64, int])
def test_halfspace_square_vertices_are_scipys_as_a_set(dt):
    # scipy's test_cube_halfspace_intersection's data, rows in any order.
    halfspaces = np.array([[-1, 0, 0], [0, -1, 0], [1, 0, -2], [0, 1, -2]], dtype=dt)
    hs = spokemesh.HalfspaceIntersection(halfspaces, np.array([1, 1], dtype=dt))
    assert sorted(map(tuple, hs.intersections.tolist())) == [(0.0, 0.0), (0.0, 2.0), (2.0, 0.0), (2.0, 2.0)]


# --- scipy's own LinearNDInterpolator tests on spokemesh.interpolate ------------------
# test_interpnd.py, loaded as above, with LinearNDInterpolator and Delaunay spokemesh's.
# Only its TestLinearNDInterpolation class is collected (the rest tests scipy's
# Clough-Tocher interpolator and gradient estimation, which spokemesh does not offer).
import scipy.interpolate as scipy_interpolate  # noqa: E402

import spokemesh.interpolate as spokemesh_interpolate  # noqa: E402

SCIPY_INTERPND_TESTS = os.path.join(os.path.dirname(scipy_interpolate.__file__), "tests", "test_interpnd.py")
_interpnd_spec = importlib.util.spec_from_file_location("scipy_test_interpnd", SCIPY_INTERPND_TESTS)
scipy_interpnd_tests = importlib.util.module_from_spec(_interpnd_spec)
_interpnd_spec.loader.exec_module(scipy_interpnd_tests)
scipy_interpnd_tests.interpnd = types.SimpleNamespace(LinearNDInterpolator=spokemesh_interpolate.LinearNDInterpolator)
scipy_interpnd_tests.qhull = types.SimpleNamespace(Delaunay=spokemesh.Delaunay)
TestLinearNDInterpolation = _wrap(scipy_interpnd_tests.TestLinearNDInterpolation, set(), {})
