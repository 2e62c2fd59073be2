"""In-process exact Voronoi diagrams with the names and meanings of
scipy.spatial.Voronoi.

    import numpy as np, spokemesh
    vor = spokemesh.Voronoi(np.random.default_rng(1).random((100_000, 2)))
    vor.vertices, vor.regions, vor.point_region, vor.ridge_points, vor.ridge_vertices
    vor.cells(box=[0, 0, 1, 1])["volume"]     # every cell's area, clipped to the box

The diagram is read off spokemesh's exact Delaunay triangulation: simplices that share
a circumsphere (a grid's squares, cospherical points) share one Voronoi vertex, decided
by an exact test, as Qhull's merged facets do, so a grid gives one vertex per square and
no ridge of zero length.
"""

from __future__ import annotations

import functools
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import _core
from .delaunay import Delaunay, _check_qhull_options
from .types import Cell

__all__ = ["Voronoi"]


def _default_options(incremental: bool, ndim: int) -> str:
    """scipy's default Qhull options for Voronoi (what decides the extra empty region)."""
    options = "Qc" if incremental else "Qbb Qc Qz"
    return options + " Qx" if ndim >= 5 else options


def _lists(flat: np.ndarray, ptr: np.ndarray) -> List[List[int]]:
    return _core.split_lists(flat, ptr)


class Voronoi:
    """The exact Voronoi diagram of `points` ((n, d) array, 2 <= d <= 8).

    Parameters, as scipy.spatial.Voronoi's: points; furthest_site (the furthest-site
    diagram, read off the furthest-site triangulation: points inside the hull have empty
    regions; as Delaunay's furthest_site for degenerate hulls);
    incremental (allow add_points);
    qhull_options (Qhull's option string: accepted and ignored, except that "Qz" adds
    scipy's empty region for Qhull's point at infinity and "Qc" gives equal points
    their twin's region; default "Qbb Qc Qz", "Qc" when incremental, as scipy's);
    threads (worker threads; None: all cores; the diagram is the same for any number).
    Raises ValueError for bad input (NaN, too few points, a flat set), naming the index.

    Attributes, as scipy's: points, ndim, npoints, vertices (k, ndim) float64,
    ridge_points (r, 2) int32, ridge_vertices (list of lists; -1 is the point at
    infinity), ridge_dict, regions (list of lists), point_region (npoints,) intp,
    furthest_site, min_bound, max_bound; methods add_points(points, restart), close().
    Orders (scipy leaves them unspecified): vertex k is the k-th smallest Delaunay
    simplex of its group as a sorted tuple of point indices; ridges by (p, q) with p <
    q; regions in point order (after the empty one with Qz), each counter-clockwise in
    2-d (from -1 when unbounded, else from its smallest vertex) and ascending above.
    Ridge vertices go around the ridge in 3-d, from the -1 when unbounded.

    Beyond scipy: delaunay (the spokemesh.Delaunay underneath), cell(i, box,
    halfspaces) and cells(box, halfspaces): cells with volumes, centroids, facet areas
    and normals, clipped to a box or halfspaces (docs/cells.md; nearest-site only).

    Thread safety: immutable between add_points calls; reads may come from several
    threads.
    """

    def __init__(self, points: np.ndarray, furthest_site: bool = False, incremental: bool = False,
                 qhull_options: Optional[str] = None, threads: Optional[int] = None):
        if np.ma.isMaskedArray(points):
            raise ValueError("Input points cannot be a masked array")
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2:
            raise ValueError(f"points: expected an (n, d) array, got shape {pts.shape}")
        if qhull_options is None:
            qhull_options = _default_options(incremental, pts.shape[1])
        text = qhull_options.decode() if isinstance(qhull_options, bytes) else str(qhull_options)
        _check_qhull_options(text)
        words = text.split()
        # (Qhull adds no point at infinity to a furthest-site diagram.)
        self._point_at_infinity = "Qz" in words and not furthest_site
        self._coplanar_regions = "Qc" in words
        #: True for the furthest-site diagram (each region: where its point is the furthest).
        self.furthest_site: bool = bool(furthest_site)
        #: The Delaunay triangulation the diagram is read from (the furthest-site one when furthest_site).
        self.delaunay: Delaunay = Delaunay(pts, furthest_site=self.furthest_site, incremental=incremental,
                                           qhull_options=text, threads=threads)
        self._read()

    def _read(self) -> None:
        tri = self.delaunay
        self.points: np.ndarray = tri.points
        self.ndim: int = tri.ndim
        self.npoints: int = tri.npoints
        self.min_bound: np.ndarray = tri.min_bound
        self.max_bound: np.ndarray = tri.max_bound
        v = tri._tri.voronoi()
        kept = tri._kept if tri._first is not None else None
        #: (nvertices, ndim) float64: the Voronoi vertices (circumcentres).
        self.vertices: np.ndarray = v["vertices"]
        rp = v["ridge_points"].astype(np.int32)
        #: (nridges, 2) int32: the points each ridge lies between (p < q, ascending).
        self.ridge_points: np.ndarray = rp if kept is None else kept[rp].astype(np.int32)
        self._ridge = (v["ridge_vertices"], v["ridge_ptr"])
        self._region = (v["regions"], v["region_ptr"])
        extra = 1 if self._point_at_infinity else 0
        position = np.arange(self.npoints, dtype=np.intp) if kept is None else \
            np.searchsorted(kept, tri._first).astype(np.intp)
        point_region = position + extra
        if kept is not None and not self._coplanar_regions:
            point_region[tri._first != np.arange(self.npoints)] = -1
        #: (npoints,) intp: the index in `regions` of each point's region.
        self.point_region: np.ndarray = point_region
        for cached in ("ridge_vertices", "regions", "ridge_dict"):
            self.__dict__.pop(cached, None)

    @functools.cached_property
    def ridge_vertices(self) -> List[List[int]]:
        """The Voronoi vertices of each ridge (-1: it reaches infinity), a list per ridge."""
        return _lists(*self._ridge)

    @functools.cached_property
    def regions(self) -> List[List[int]]:
        """The Voronoi vertices of each region (-1: unbounded); with Qz the first is empty
        (Qhull's point at infinity); point_region says which region is whose."""
        out = _lists(*self._region)
        return [[]] + out if self._point_at_infinity else out

    @functools.cached_property
    def ridge_dict(self) -> Dict[Tuple[int, int], List[int]]:
        """{(p, q): ridge vertices} for every ridge."""
        return {(int(p), int(q)): v for (p, q), v in zip(self.ridge_points.tolist(), self.ridge_vertices)}

    def add_points(self, points: np.ndarray, restart: bool = False) -> None:
        """Append points (shape (k, ndim)) to a diagram made with incremental=True: the
        triangulation computes only the new points' stars (restart=True:
        everything), and the diagram equals the one of all the points made at once.
        Raises RuntimeError when not incremental or closed."""
        self.delaunay.add_points(points, restart=restart)
        self._read()

    def close(self) -> None:
        """Ends incremental mode: add_points raises RuntimeError from now on."""
        self.delaunay.close()

    def cell(self, i: int, box: Optional[Sequence[float]] = None, halfspaces: Optional[np.ndarray] = None) -> Cell:
        """Point i's cell with its measures, clipped to box or halfspaces when given
        (spokemesh.Delaunay.cell)."""
        return self.delaunay.cell(i, box=box, halfspaces=halfspaces)

    def cells(self, box: Optional[Sequence[float]] = None,
              halfspaces: Optional[np.ndarray] = None) -> Dict[str, np.ndarray]:
        """Every cell's volume, centroid and facets, clipped to box or halfspaces (by
        default the points' bounding box; spokemesh.Delaunay.cells)."""
        return self.delaunay.cells(box=box, halfspaces=halfspaces)

    def __reduce__(self):
        return (_rebuild, (self.points, self.delaunay._incremental, self._options_text(), self.delaunay._threads,
                           self.furthest_site))

    def _options_text(self) -> str:
        words = []
        if self._point_at_infinity:
            words.append("Qz")
        if self._coplanar_regions:
            words.append("Qc")
        if self.delaunay._joggle:
            words.append("QJ")
        return " ".join(words)


def _rebuild(points, incremental, qhull_options, threads, furthest_site=False):
    return Voronoi(points, furthest_site=furthest_site, incremental=incremental, qhull_options=qhull_options,
                   threads=threads)
