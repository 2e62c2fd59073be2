"""Intersections of halfspaces, with the names and meanings of
scipy.spatial.HalfspaceIntersection, from spokemesh's exact convex hull of the dual
points.

    import numpy as np, spokemesh
    halfspaces = np.array([[-1, 0, 0], [0, -1, 0], [1, 0, -2], [0, 1, -2.]])  # A x + b <= 0
    hs = spokemesh.HalfspaceIntersection(halfspaces, interior_point=np.array([1.0, 1.0]))
    hs.intersections  # the polytope's vertices

Halfspace i, A_i x + b_i <= 0, becomes the dual point A_i / h_i with
h_i = -(A_i c + b_i) > 0 the interior point c's slack; the polytope's vertices are the
facets of the dual points' hull, and its non-redundant halfspaces that hull's
vertices. Which dual points form which facet is decided exactly (on the dual points as
computed in double); facets of the hull that lie in one hyperplane are merged into one
polytope vertex, as Qhull's non-triangulated output gives them. Planes that meet near,
but not exactly at, one point or line (the rounded facet equations of a polytope whose
vertices or edges have more facets than the dimension needs) define more vertices
there, each feasible, and each is returned: Qhull merges them within its precision; an
exact intersection does not.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import _core
from .hull import _IGNORED, ConvexHull, QhullError

__all__ = ["HalfspaceIntersection"]


def _check_options(options) -> None:
    if options is None:
        return
    text = options.decode() if isinstance(options, bytes) else str(options)
    for word in text.split():
        # H (the interior point, given as an argument here) and the options ConvexHull
        # accepts and ignores.
        if not (word.startswith("H") or word in _IGNORED or word == "Qc" or word.startswith("QJ")):
            raise ValueError(f"qhull_options: '{word}' is not an option spokemesh's HalfspaceIntersection accepts")


class HalfspaceIntersection:
    """The intersection of the halfspaces A x + b <= 0 given as rows [A, b] of
    `halfspaces` ((n, d + 1), 2 <= d <= 8) around `interior_point` ((d,), strictly inside
    every halfspace).

    Parameters, in scipy's order: halfspaces, interior_point, incremental (allow
    add_halfspaces), qhull_options (H... and the options ConvexHull accepts are
    accepted; they change nothing). Beyond scipy: threads (for the hull).

    Raises ValueError for shapes that do not fit (naming them) and non-finite values;
    QhullError (a ValueError, and scipy's QhullError where scipy is installed) when the
    interior point is not strictly inside every halfspace (naming the first it is not
    inside), when the intersection is unbounded, or when the dual points are flat.

    Attributes, as scipy's: halfspaces, interior_point, intersections ((nvertices, d):
    the polytope's vertices, one per dual facet), dual_points ((n, d)), dual_facets
    (list of lists: the halfspaces meeting at each vertex; more than d where several
    dual facets lie in one hyperplane), dual_equations ((nvertices, d + 1)),
    dual_vertices (the non-redundant halfspaces, ascending), dual_volume, dual_area,
    ndim, nineq; methods add_halfspaces(halfspaces, restart), close(). Vertex rows are
    in the dual hull's facet order, not Qhull's.

    Thread safety: not to be shared with add_halfspaces running; otherwise read-only.
    """

    def __init__(self, halfspaces, interior_point, incremental: bool = False,
                 qhull_options: Optional[str] = None, threads: Optional[int] = None):
        _check_options(qhull_options)
        hs = self._as_halfspaces(halfspaces)
        point = np.ascontiguousarray(interior_point, dtype=np.float64)
        if point.ndim != 1 or point.shape[0] != hs.shape[1] - 1:
            raise ValueError(f"interior_point: expected shape ({hs.shape[1] - 1},) for halfspaces of shape "
                             f"{hs.shape}, got {point.shape}")
        if not np.isfinite(point).all():
            raise ValueError("interior_point: not finite")
        self.interior_point: np.ndarray = point
        self._incremental = bool(incremental)
        self._threads = threads
        self._build(hs)

    @staticmethod
    def _as_halfspaces(halfspaces, ndim: Optional[int] = None) -> np.ndarray:
        if isinstance(halfspaces, np.ma.MaskedArray):
            raise ValueError("halfspaces: a masked array is not accepted")
        hs = np.ascontiguousarray(halfspaces, dtype=np.float64)
        if hs.ndim != 2 or hs.shape[1] < 3:
            raise ValueError(f"halfspaces: expected an (n, d + 1) array with d >= 2, got shape {hs.shape}")
        if ndim is not None and hs.shape[1] != ndim + 1:
            raise ValueError(f"halfspaces: expected {ndim + 1} columns, got {hs.shape[1]}")
        bad = ~np.isfinite(hs)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ValueError(f"halfspaces[{i}][{j}]: not a finite number")
        return hs

    def _dual(self, hs: np.ndarray) -> np.ndarray:
        slack = -(hs[:, :-1] @ self.interior_point + hs[:, -1])
        outside = np.flatnonzero(~(slack > 0))
        if len(outside):
            i = int(outside[0])
            raise QhullError(f"interior_point is not strictly inside halfspace {i} "
                             f"(A x + b = {-slack[i]!r} at it; it must be negative)")
        return hs[:, :-1] / slack[:, None]

    def _build(self, hs: np.ndarray) -> None:
        self.halfspaces: np.ndarray = hs
        self.dual_points: np.ndarray = self._dual(hs)
        self._hull = ConvexHull(self.dual_points, incremental=self._incremental, threads=self._threads)
        self._set()

    def _set(self) -> None:
        hull = self._hull
        self.ndim: int = self.halfspaces.shape[1] - 1
        self.nineq: int = self.halfspaces.shape[0]
        # The dual hull must hold the dual origin strictly inside: else some vertex of
        # the intersection is at infinity.
        with_origin = np.concatenate([self.dual_points, np.zeros((1, self.ndim))])
        if (hull._hull.sides(with_origin, len(self.dual_points)) >= 0).any():
            raise QhullError("the intersection is unbounded: the halfspaces' normals do not surround the "
                             "interior point (no bounded polytope has these facets)")
        groups = hull._hull.groups(self.dual_points)
        first = np.unique(groups, return_index=True)[1]
        self.dual_equations: np.ndarray = hull.equations[first]
        facets: list = [[] for _ in range(len(first))]
        for g, row in zip(groups.tolist(), hull.simplices.tolist()):
            members = facets[g]
            for v in row:
                if v not in members:
                    members.append(v)
        self.dual_facets: list = facets
        self.dual_vertices: np.ndarray = np.sort(hull.vertices)
        self.dual_volume: float = hull.volume
        self.dual_area: float = hull.area
        self.intersections: np.ndarray = (-self.dual_equations[:, :-1] / self.dual_equations[:, -1:]
                                          + self.interior_point)

    def add_halfspaces(self, halfspaces, restart: bool = False) -> None:
        """Adds rows [A, b] (shape (k, ndim + 1)) to an intersection made with
        incremental=True; restart builds it afresh. RuntimeError when not incremental
        or closed; ValueError / QhullError as the constructor."""
        if not self._incremental:
            raise RuntimeError("add_halfspaces: this intersection was not made with incremental=True, or was closed")
        more = self._as_halfspaces(halfspaces, self.ndim)
        everything = np.concatenate([self.halfspaces, more])
        if restart:
            self._build(everything)
            return
        dual = self._dual(more)
        self._hull.add_points(dual)
        self.halfspaces = everything
        self.dual_points = self._hull.points
        self._set()

    def close(self) -> None:
        """Ends incremental mode: add_halfspaces raises RuntimeError from now on."""
        self._incremental = False
        self._hull.close()
