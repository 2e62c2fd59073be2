"""In-process exact Delaunay triangulations and Voronoi cells, with the names and
meanings of scipy.spatial.Delaunay where they exist.

    import numpy as np, spokemesh
    tri = spokemesh.Delaunay(np.random.default_rng(1).random((100_000, 3)))
    tri.simplices            # (m, 4) int32, every tetrahedron positively oriented
    tri.neighbors            # (m, 4) simplex adjacency, -1 across the hull
    tri.find_simplex(q)      # exact point location, -1 outside
    tri.cell(17, box=[0, 0, 0, 1, 1, 1]).volume

Unlike Qhull, the triangulation is exact: topology comes from exact predicates with
symbolic perturbation, so degenerate inputs (grids, cospherical points) need no `Qt`
or `QJ` and give the same mesh as CGAL, for any thread count.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from . import _core
from .types import Cell, Facet

__all__ = ["Delaunay", "ApproximateGraph", "approximate_graph"]


def _cell(c: dict) -> Cell:
    d = c["vertices"].shape[1]
    facets = [Facet(neighbor=f["neighbor"], wall=f["wall"], vertices=f["vertices"], area=f["area"],
                    normal=f["normal"]) for f in c["facets"]]
    return Cell(seed=c["seed"], vertices=c["vertices"], vertex_simplices=np.zeros((0, d + 1), dtype=np.uint32),
                facets=facets, bounded=c["bounded"], volume=c["volume"], centroid=c["centroid"],
                clipped=c["clipped"])


class Delaunay:
    """The exact Delaunay triangulation of `points` ((n, d) array, 2 <= d <= 8).

    Parameters: points (array_like, converted once to C-ordered float64); threads
    (worker threads; None: all cores). The mesh is the same for any thread count.
    Raises ValueError for bad input (NaN, duplicates, fewer than d + 1 points, points
    in a lower-dimensional subspace), naming the index.

    Attributes, as scipy.spatial.Delaunay's: points, ndim, npoints, nsimplex,
    simplices, neighbors, vertex_neighbor_vertices, convex_hull, transform; methods
    find_simplex(xi). Beyond scipy: star(i), neighbors_of(i), cell(i, box, halfspaces),
    cells(box, halfspaces).

    Thread safety: immutable after construction; methods may be called from several
    threads (each releases the GIL while it works).
    """

    def __init__(self, points: np.ndarray, threads: Optional[int] = None):
        self.points: np.ndarray = np.ascontiguousarray(points, dtype=np.float64)
        if self.points.ndim != 2:
            raise ValueError(f"points: expected an (n, d) array, got shape {self.points.shape}")
        self._tri = _core.Triangulation(self.points, threads)
        self.ndim: int = self.points.shape[1]
        self.npoints: int = self.points.shape[0]
        #: (nsimplex, ndim + 1) int32: vertex indices, each simplex positively oriented
        #: (det[p1 - p0, ..., pd - p0] > 0), rows in sweep order (docs/algorithm.md), the same for any thread count.
        self.simplices: np.ndarray = self._tri.simplices()
        self.nsimplex: int = self.simplices.shape[0]

    @functools.cached_property
    def neighbors(self) -> np.ndarray:
        """(nsimplex, ndim + 1) int32: the simplex opposite vertex k of simplex i, -1 on the hull."""
        return self._tri.neighbors()

    @functools.cached_property
    def vertex_neighbor_vertices(self) -> Tuple[np.ndarray, np.ndarray]:
        """(indptr, indices): the Delaunay neighbours of vertex k are indices[indptr[k]:indptr[k + 1]], ascending."""
        s = self.simplices.astype(np.int64)
        w = s.shape[1]
        a = np.concatenate([s[:, i] for i in range(w) for j in range(w) if i != j])
        b = np.concatenate([s[:, j] for i in range(w) for j in range(w) if i != j])
        key = np.unique(a * self.npoints + b)
        src, dst = key // self.npoints, key % self.npoints
        indptr = np.zeros(self.npoints + 1, dtype=np.int32)
        np.add.at(indptr, src + 1, 1)
        return np.cumsum(indptr, dtype=np.int32), dst.astype(np.int32)

    @functools.cached_property
    def convex_hull(self) -> np.ndarray:
        """(nfacets, ndim) int32: the hull's facets, as vertex indices."""
        i, k = np.nonzero(self.neighbors == -1)
        rows = self.simplices[i]
        keep = np.arange(self.ndim + 1)[None, :] != k[:, None]
        return rows[keep].reshape(len(i), self.ndim)

    @functools.cached_property
    def transform(self) -> np.ndarray:
        """(nsimplex, ndim + 1, ndim): scipy's affine maps to barycentric coordinates:
        c = T[:ndim] @ (x - T[ndim]) gives the first ndim of them, the last is 1 - sum(c)."""
        v = self.points[self.simplices]
        r = v[:, -1, :]
        t = np.linalg.inv(np.transpose(v[:, :-1, :] - r[:, None, :], (0, 2, 1)))
        return np.concatenate([t, r[:, None, :]], axis=1)

    def find_simplex(self, xi: np.ndarray) -> np.ndarray:
        """The simplex containing each point of xi (shape (..., ndim)), -1 outside the
        hull; decided by exact orientation tests (a point on a shared face gets one of
        its simplices)."""
        q = np.ascontiguousarray(xi, dtype=np.float64)
        flat = q.reshape(-1, self.ndim)
        return self._tri.find_simplex(flat).reshape(q.shape[:-1])

    def star(self, i: int) -> np.ndarray:
        """(k, ndim + 1) uint32: the simplices incident to vertex i (its Delaunay star)."""
        return self._tri.star(int(i))

    def neighbors_of(self, i: int) -> np.ndarray:
        """uint32, ascending: the Delaunay neighbours of vertex i."""
        return self._tri.neighbors_of(int(i))

    def cell(self, i: int, box: Optional[Sequence[float]] = None,
             halfspaces: Optional[np.ndarray] = None) -> Cell:
        """The Voronoi cell of vertex i, clipped to box (lo_1..lo_d, hi_1..hi_d) or to
        halfspaces ((m, ndim + 1) rows a, b with a.x <= b) when given, with its measures
        (docs/cells.md). Unbounded: volume inf, centroid None. A seed outside the domain
        raises ValueError."""
        b = None if box is None else [float(v) for v in np.asarray(box, dtype=np.float64).ravel()]
        h = None if halfspaces is None else np.ascontiguousarray(halfspaces, dtype=np.float64)
        return _cell(self._tri.cell(int(i), b, h))

    def cells(self, box: Optional[Sequence[float]] = None,
              halfspaces: Optional[np.ndarray] = None) -> Dict[str, np.ndarray]:
        """Every cell's measures, as `spokemesh cells` writes them to .npz: volume (n,),
        centroid (n, d), bounded (n,), facet_ptr (n + 1,), facet_neighbor (m,) (the
        neighbour, or -1 - k for wall k), facet_area (m,), facet_normal (m, d). Clipped
        to box or halfspaces, by default to the points' bounding box."""
        b = None if box is None else [float(v) for v in np.asarray(box, dtype=np.float64).ravel()]
        h = None if halfspaces is None else np.ascontiguousarray(halfspaces, dtype=np.float64)
        return self._tri.cells(b, h, True)


@dataclasses.dataclass(frozen=True)
class ApproximateGraph:
    """A certified approximate Delaunay graph: every edge is a true Delaunay edge; some
    may be missing where a seed's walk stopped early (walk_exhausted False)."""
    indptr: np.ndarray          # (n + 1,) int64
    indices: np.ndarray         # int32: neighbours of k are indices[indptr[k]:indptr[k + 1]]
    walk_exhausted: np.ndarray  # (n,) bool: seed k's walk tried everything (its list is complete)


def approximate_graph(points: np.ndarray, misses: int = 100, seed: int = 0x5eed, max_vertices: int = 20000,
                      mode: str = "rsd", threads: Optional[int] = None) -> ApproximateGraph:
    """The certified approximate Delaunay graph in any dimension (Recursive Spoke Darts
    with a budget of `misses` consecutive misses per seed, the paper's M; mode "spokes"
    for plain Spoke Darts). Deterministic for a given `seed` and any thread count."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    indptr, indices, exhausted = _core.approximate_graph(pts, misses, max_vertices, seed, mode, threads)
    return ApproximateGraph(indptr=indptr, indices=indices, walk_exhausted=exhausted)
