"""The exact convex hull, with the names and meanings of scipy.spatial.ConvexHull.

    import numpy as np, spokemesh
    hull = spokemesh.ConvexHull(np.random.default_rng(1).random((1_000_000, 3)))
    hull.vertices, hull.simplices, hull.neighbors, hull.equations, hull.volume, hull.area

Unlike Qhull, every facet is decided by exact orientation tests (a floating-point
filter with its error bound, then rationals): there is no precision option to choose,
and near-flat input gives the exact hull, not a precision error. The facets are those
of Quickhull run in an order that depends only on the point set, so the same points in
any order give the same facets (their rows mapped back).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from . import _core

__all__ = ["ConvexHull", "QhullError"]

try:  # scipy's own error type, so that `except scipy.spatial.QhullError` catches ours
    from scipy.spatial import QhullError as _ScipyQhullError
except ImportError:  # pragma: no cover - scipy is optional
    _ScipyQhullError = RuntimeError


class QhullError(ValueError, _ScipyQhullError):
    """A hull that cannot be built from the points: they are flat (every point in one
    hyperplane) or too few. A ValueError, and scipy's QhullError where scipy is
    installed, so that code written for either catches it."""


# Qhull options scipy users pass to ConvexHull and why none changes an exact hull: Qt and
# QJ triangulate or joggle degenerate facets (ours are exact triangles of the facets),
# Qbb, QbB, Qz, Qx, Q12 tune Qhull's floating point, Pp silences its precision warnings,
# Qi keeps interior points (never listed here). Qc asks for `coplanar`; QGn / QG-n for
# `good`.
_IGNORED = {"Qt", "QJ", "Qbb", "QbB", "Qz", "Qx", "Q12", "Pp", "Qi"}


def _parse_options(options):
    """(coplanar wanted, viewpoint index or None, viewpoint sign +1 / -1)."""
    if options is None:
        return False, None, 1
    text = options.decode() if isinstance(options, bytes) else str(options)
    coplanar, viewpoint, sign = False, None, 1
    for word in text.split():
        if word == "Qc":
            coplanar = True
        elif word.startswith("QG"):
            rest = word[2:]
            if rest.startswith("-"):
                sign, rest = -1, rest[1:]
            if not rest.isdigit():
                raise ValueError(f"qhull_options: '{word}' is not QGn or QG-n with a point index n")
            viewpoint = int(rest)
        elif word not in _IGNORED and not word.startswith("QJ"):
            raise ValueError(f"qhull_options: '{word}' is not an option spokemesh's ConvexHull accepts "
                             f"(Qc, QGn, QG-n; accepted and ignored: {' '.join(sorted(_IGNORED))})")
    return coplanar, viewpoint, sign


def _as_points(points, what: str = "points") -> np.ndarray:
    if isinstance(points, np.ma.MaskedArray):
        raise ValueError(f"{what}: a masked array is not accepted (fill or drop the masked points first)")
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2:
        raise ValueError(f"{what}: expected an (n, d) array, got shape {pts.shape}")
    return pts  # the core names a non-finite coordinate by its index


class ConvexHull:
    """The exact convex hull of `points` ((n, d) array, 2 <= d <= 8).

    Parameters, in scipy's order: points (array_like, converted once to C-ordered
    float64); incremental (allow add_points); qhull_options (scipy's Qhull options:
    `Qc` fills `coplanar`, `QGn` / `QG-n` fill `good` and leave point n out of the
    hull, as Qhull does; Qt, QJ, Qbb, QbB, Qz, Qx, Q12, Pp, Qi are accepted and change
    nothing, since exact facets need none of them; others raise ValueError). Beyond
    scipy: threads (worker threads for the large steps; None: all cores; the hull is the
    same for any count).

    Raises QhullError (a ValueError, and scipy's QhullError when scipy is installed)
    when the points are flat (all in one hyperplane: the message gives the dimension of
    their span) or fewer than d + 1; ValueError for NaN or infinite coordinates (naming
    the index), masked arrays and other shapes.

    Attributes, as scipy.spatial.ConvexHull's: points, ndim, npoints, nsimplex,
    vertices (2-d: counter-clockwise from the smallest index; otherwise ascending),
    simplices ((nfacet, d) int32, each facet's vertex ids), neighbors ((nfacet, d)
    int32, the facet across the ridge opposite vertex k), equations ((nfacet, d + 1):
    unit outward normal, then offset, normal . x + offset <= 0 inside), coplanar
    ((k, 3) int32: point, facet, nearest vertex, for the points on the boundary that
    are not vertices, equal points included; only with Qc, else empty), good (bool per
    facet: visible from point n for QGn, not visible for QG-n; None without them),
    volume, area, min_bound, max_bound; methods add_points(points, restart) and close().
    Facet rows are in the order Quickhull made them; add_points keeps the facets that
    survive in their order and appends the new ones.

    What a vertex is: a point strictly outside the hull of the points before it in
    Quickhull's order. Points exactly on a facet are never made vertices (Qhull's
    `Qt` behaviour without its precision merging); a vertex added while it was strictly
    outside stays one if later points put it exactly on a flat face.

    Thread safety: not to be shared with add_points running; otherwise read-only.
    """

    def __init__(self, points, incremental: bool = False, qhull_options: Optional[str] = None,
                 threads: Optional[int] = None):
        self._coplanar_wanted, self._viewpoint, self._view_sign = _parse_options(qhull_options)
        self._incremental = bool(incremental)
        self._threads = threads
        pts = _as_points(points)
        if self._viewpoint is not None and not 0 <= self._viewpoint < len(pts):
            raise ValueError(f"qhull_options QG{self._viewpoint}: no point {self._viewpoint} among {len(pts)}")
        self._build(pts)

    def _build(self, pts: np.ndarray) -> None:
        exclude = -1 if self._viewpoint is None else self._viewpoint
        try:
            self._hull = _core.Hull(pts, exclude, self._threads)
        except ValueError as e:
            if "the hull is flat" in str(e) or "needs at least" in str(e):
                raise QhullError(str(e)) from None
            raise
        self._set(pts)

    def _set(self, pts: np.ndarray) -> None:
        self.points: np.ndarray = pts
        self.ndim: int = pts.shape[1]
        self.npoints: int = pts.shape[0]
        self.min_bound, self.max_bound = _core.Hull.bounds(pts)  # one pass (numpy's axis-0 min is strided)
        self.simplices: np.ndarray = self._hull.simplices()
        self.neighbors: np.ndarray = self._hull.neighbors()
        self.nsimplex: int = len(self.simplices)
        self.equations: np.ndarray = self._hull.equations(pts)
        self.vertices: np.ndarray = self._vertices()
        if self._coplanar_wanted:
            self.coplanar: np.ndarray = self._hull.coplanar(pts)
        else:
            self.coplanar = np.zeros((0, 3), dtype=np.int32)
        if self._viewpoint is None:
            self.good: Optional[np.ndarray] = None
        else:
            sides = self._hull.sides(pts, self._viewpoint)
            self.good = sides > 0 if self._view_sign > 0 else sides <= 0
        self.volume, self.area = self._measures()

    def _vertices(self) -> np.ndarray:
        vertices = self._hull.vertices()
        if self.ndim != 2:
            return vertices
        # Each edge v0 -> v1 runs clockwise (the core's orientation): follow them
        # backwards from the smallest vertex.
        before = dict(zip(self.simplices[:, 1].tolist(), self.simplices[:, 0].tolist()))
        start = int(vertices[0])
        ring = [start]
        at = before[start]
        while at != start and len(ring) <= len(vertices):
            ring.append(at)
            at = before[at]
        return np.asarray(ring, dtype=np.int32)

    def _measures(self):
        """(volume, area): the signed cones from the vertices' centroid over every
        facet, and the facets' (d - 1)-volumes, in double."""
        d = self.ndim
        facets = self.points[self.simplices]  # (m, d, d)
        centre = self.points[self.vertices].mean(axis=0)
        edges = facets[:, 1:, :] - facets[:, :1, :]  # (m, d - 1, d)
        cones = np.concatenate([edges, (centre - facets[:, 0, :])[:, None, :]], axis=1)
        volume = float(-np.linalg.det(cones).sum() / math.factorial(d))
        gram = edges @ np.transpose(edges, (0, 2, 1))
        area = float(np.sqrt(np.clip(np.linalg.det(gram), 0, None)).sum() / math.factorial(d - 1))
        return volume, area

    def add_points(self, points, restart: bool = False) -> None:
        """Adds points (shape (k, ndim)) to a hull made with incremental=True; restart
        builds the hull of all points afresh (the same facets, rows in a fresh order).
        RuntimeError when not incremental or closed; ValueError for bad points."""
        if not self._incremental:
            raise RuntimeError("add_points: this hull was not made with incremental=True, or was closed")
        more = _as_points(points)
        if more.shape[1] != self.ndim:
            raise ValueError(f"points: dimension {more.shape[1]} is not the hull's {self.ndim}")
        everything = np.concatenate([self.points, more], axis=0)
        if restart:
            self._build(everything)
            return
        self._hull.extend(everything)
        self._set(everything)

    def close(self) -> None:
        """Ends incremental mode: add_points raises RuntimeError from now on."""
        self._incremental = False

    def __repr__(self) -> str:
        return f"spokemesh.ConvexHull({self.npoints} points in {self.ndim}-d, {self.nsimplex} facets)"
