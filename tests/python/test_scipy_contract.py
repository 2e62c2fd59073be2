"""scipy's own tests of Delaunay, run on spokemesh.Delaunay (issue 27).

The test file is the one Debian's python3-scipy installs
(scipy/spatial/tests/test_qhull.py); nothing of it is copied here. It is loaded as a
module, its `qhull` name (scipy.spatial._qhull) is replaced by a namespace in which
Delaunay is spokemesh.Delaunay and everything else is scipy's, and its Delaunay test
classes are collected from this module, so pytest runs scipy's assertions unchanged.

Tests that cannot pass yet are marked strict xfail with the reason (a fixed one then
fails the run until it is taken off the list); tests that assert Qhull's own row order
on tiny inputs are left out for good: the order of simplices is unspecified in scipy's
documentation, and ours is the sweep order (docs/algorithm.md).
"""

import importlib.util
import os
import types

import pytest

scipy_spatial = pytest.importorskip("scipy.spatial", reason="python3-scipy is not installed")
import scipy.spatial._qhull as scipy_qhull  # noqa: E402

import spokemesh  # noqa: E402

SCIPY_TESTS = os.path.join(os.path.dirname(scipy_spatial.__file__), "tests", "test_qhull.py")
if not os.path.exists(SCIPY_TESTS):
    pytest.skip(f"{SCIPY_TESTS} is not installed", allow_module_level=True)

_spec = importlib.util.spec_from_file_location("scipy_test_qhull", SCIPY_TESTS)
scipy_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(scipy_tests)
scipy_tests.qhull = types.SimpleNamespace(**{**vars(scipy_qhull), "Delaunay": spokemesh.Delaunay})

# Qhull's own row order on tiny inputs (unspecified by scipy's documentation).
ROW_ORDER = {"test_2d_square", "test_find_simplex", "test_convex_hull"}

# What spokemesh.Delaunay does not do yet, and why (issue 27).
NOT_YET = {
    "test_furthest_site": "furthest_site=True is not implemented yet",
    # The set is degenerate (many cospherical points): half its simplices are broken
    # differently from Qhull's, both Delaunay. Ours (CGAL's symbolic perturbation) leave
    # 31 near-flat simplices, every one with NaN rows as the test asks, where Qhull's
    # leave 22 and the test allows at most 22.
    "test_degenerate_barycentric_transforms": "31 near-flat simplices where the test allows 22 (Qhull's count)",
}


def _wrap(cls):
    """scipy's test class with its row-order tests left out and the others marked."""
    attrs = {}
    for name, value in vars(cls).items():
        if name in ROW_ORDER:
            attrs[name] = None  # not collected
        elif name in NOT_YET and callable(value):
            attrs[name] = pytest.mark.xfail(reason=NOT_YET[name], strict=True)(value)
    return type(cls.__name__, (cls,), attrs)


TestDelaunay = _wrap(scipy_tests.TestDelaunay)
TestUtilities = _wrap(scipy_tests.TestUtilities)
TestVertexNeighborVertices = _wrap(scipy_tests.TestVertexNeighborVertices)
