"""Voronoi diagrams on a sphere, with the names and meanings of
scipy.spatial.SphericalVoronoi, from spokemesh's exact convex hull.

    import numpy as np, spokemesh
    x = np.random.default_rng(1).standard_normal((100_000, 3))
    sv = spokemesh.SphericalVoronoi(x / np.linalg.norm(x, axis=1)[:, None])
    sv.sort_vertices_of_regions(); areas = sv.calculate_areas()

The diagram's combinatorics (which generators meet at which vertex) are the facets of
the points' convex hull, decided by exact orientation tests: cospherical input, the
whole point of a spherical diagram, needs no tolerance. A vertex is a facet's unit
outward normal scaled to the sphere.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import _core
from .hull import _as_points

__all__ = ["SphericalVoronoi"]

# Above this many points the rank is read from the Gram matrix (one pass) rather than
# from an SVD of every point (numpy's takes about 0.9 s for 10M points in 3-d).
_SVD_RANK_AT_MOST = 100_000


class SphericalVoronoi:
    """The Voronoi diagram of `points` ((n, d), 2 <= d <= 8) on the sphere of `radius`
    about `center`.

    Parameters, as scipy's: points; radius (default 1; None raises ValueError, as scipy
    does); center ((d,), default the origin); threshold (default 1e-6: points closer
    than threshold * radius count as duplicates, and every point must lie within
    threshold * radius of the sphere). Beyond scipy: threads (for the hull; the diagram
    is the same for any count).

    Raises ValueError with scipy's messages: "Rank of input points must be at least d"
    (the points lie in a hyperplane: exactly, or within threshold * radius for up to
    100,000 points, where the SVD decides as scipy's does), "Duplicate generators
    present." (two points closer than threshold * radius: hull edges shorter than that,
    and points that are not hull vertices), "Radius inconsistent with generators.".

    Attributes: points, radius, center, vertices ((nfacets, d): the Voronoi vertices,
    one per hull facet), regions (list of lists of vertex indices, region i around
    points[i]; ascending until sort_vertices_of_regions()). Methods:
    sort_vertices_of_regions() (d = 3: each region counter-clockwise seen from outside
    the sphere, from its smallest vertex index; TypeError otherwise, as scipy),
    calculate_areas() (d = 2: arc lengths, d = 3: spherical polygon areas; region i's;
    TypeError otherwise). Vertex rows follow the hull's facet order, not Qhull's.

    Thread safety: sort_vertices_of_regions() changes `regions`; do not call it while
    another thread reads them.
    """

    def __init__(self, points, radius: Optional[float] = 1, center=None, threshold: float = 1e-06,
                 threads: Optional[int] = None):
        if radius is None:
            raise ValueError("`radius` is `None`. Please provide a floating point number (i.e. `radius=1`).")
        self.radius = float(radius)
        self.points = _as_points(np.array(points).astype(np.double))
        self._dim = self.points.shape[1]
        self.center = np.zeros(self._dim) if center is None else np.array(center, dtype=float)
        tol = threshold * self.radius
        if self._rank(tol) < self._dim:
            raise ValueError(f"Rank of input points must be at least {self._dim}")
        offsets = self.points - self.center
        radii = np.sqrt(np.einsum("ij,ij->i", offsets, offsets))
        try:
            self._hull = _core.Hull(self.points, -1, threads)
        except ValueError as e:
            if "the hull is flat" in str(e) or "needs at least" in str(e):
                raise ValueError(f"Rank of input points must be at least {self._dim} ({e})") from None
            raise
        self._simplices = self._hull.simplices()
        self._flat, self._ptr = self._hull.regions(len(self.points), False)
        self._check_duplicates(tol)
        if np.abs(radii - self.radius).max() >= tol:
            raise ValueError("Radius inconsistent with generators.")
        self.vertices = self.radius * self._hull.equations(self.points)[:, :-1] + self.center
        self._sorted = False
        self.regions = _core.split_lists(self._flat, self._ptr)

    def _rank(self, tol: float) -> int:
        a = self.points - self.points[0]
        if len(a) <= _SVD_RANK_AT_MOST:
            return int(np.linalg.matrix_rank(a, tol=tol))
        eig = np.linalg.eigvalsh(a.T @ a)
        return int((np.sqrt(np.clip(eig, 0, None)) > tol).sum())

    def _check_duplicates(self, tol: float) -> None:
        # Two points closer than tol: either both are hull vertices, and then (nearest
        # neighbours on a sphere being Delaunay neighbours) a hull edge is that short,
        # or one is not a vertex, and its nearest vertex is looked up.
        simplices = self._simplices
        d = self._dim
        for i in range(d):
            for j in range(i + 1, d):
                diff = self.points[simplices[:, i]] - self.points[simplices[:, j]]
                if (np.einsum("ij,ij->i", diff, diff) <= tol * tol).any():
                    raise ValueError("Duplicate generators present.")
        counts = np.diff(self._ptr)
        if counts.all():  # every point a vertex
            return
        vertices = np.flatnonzero(counts)
        others = np.setdiff1d(np.arange(len(self.points)), vertices)
        hull_points = self.points[vertices]
        for start in range(0, len(others), 256):
            chunk = self.points[others[start:start + 256]]
            dist2 = ((chunk[:, None, :] - hull_points[None, :, :]) ** 2).sum(axis=2)
            if (dist2.min(axis=1) <= tol * tol).any():
                raise ValueError("Duplicate generators present.")

    def sort_vertices_of_regions(self) -> None:
        """Orders each region's vertices counter-clockwise seen from outside the sphere,
        from its smallest index (d = 3 only: TypeError otherwise, as scipy's)."""
        if self._dim != 3:
            raise TypeError("Only supported for three-dimensional point sets")
        if not self._sorted:
            # In place, as scipy's: references to the region lists see the order.
            self._flat, self._ptr = self._hull.regions(len(self.points), True)
            _core.refill_lists(self.regions, self._flat, self._ptr)
            self._sorted = True

    def calculate_areas(self) -> np.ndarray:
        """Region i's area: its arc length for d = 2 (the sum is 2 pi r), its spherical
        polygon's area for d = 3 (the sum is 4 pi r^2); TypeError otherwise."""
        if self._dim == 2:
            return self._arc_lengths()
        if self._dim == 3:
            return self._polygon_areas()
        raise TypeError("Only supported for 2D and 3D point sets")

    def _unit(self, x: np.ndarray) -> np.ndarray:
        return (x - self.center) / self.radius

    def _arc_lengths(self) -> np.ndarray:
        # Point i's region runs between the vertices of its two edges, through i: the
        # angles from the point to each (at most pi each).
        counts = np.diff(self._ptr)
        owner = np.repeat(np.arange(len(self.points)), counts)
        a, b = self._unit(self.points)[owner], self._unit(self.vertices)[self._flat]
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        angles = np.arctan2(np.abs(cross), np.einsum("ij,ij->i", a, b))
        return self.radius * np.bincount(owner, weights=angles, minlength=len(self.points))

    def _polygon_areas(self) -> np.ndarray:
        # Each region as a fan of triangles (generator, vertex j, vertex j + 1) in cyclic
        # order, their solid angles summed (Van Oosterom and Strackee's formula).
        # Cyclic, whether or not `regions` were sorted.
        flat, ptr = (self._flat, self._ptr) if self._sorted else self._hull.regions(len(self.points), True)
        solid = _core.fan_solid_angles(np.ascontiguousarray(self._unit(self.points)),
                                       np.ascontiguousarray(self._unit(self.vertices)), flat, ptr)
        return self.radius ** 2 * solid

    def __repr__(self) -> str:
        return (f"spokemesh.SphericalVoronoi({len(self.points)} points in {self._dim}-d, "
                f"{len(self.vertices)} vertices)")
