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
import os
import warnings
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from . import _core
from .types import Cell, Facet

__all__ = ["Delaunay", "ApproximateGraph", "approximate_graph"]


# Qhull's options that scipy users pass to Delaunay, and why none changes an exact
# triangulation: Qt/QJ ask Qhull to triangulate or joggle degenerate facets (ours are
# resolved by symbolic perturbation), Qbb/QbB/Qz/Qx/Q12 tune Qhull's floating-point
# arithmetic, Qc/Qi keep coplanar or interior points (duplicates are refused here),
# Pp silences precision warnings. They are accepted and have no effect.
_IGNORED_QHULL_OPTIONS = {"Qt", "QJ", "Qbb", "QbB", "Qz", "Qx", "Q12", "Qc", "Qi", "Pp"}


def _check_qhull_options(options) -> bool:
    """Whether the options ask for QJ (then duplicates are joggled apart, as Qhull's
    joggle makes every input point a vertex); unknown options raise ValueError."""
    if options is None:
        return False
    text = options.decode() if isinstance(options, bytes) else str(options)
    joggle = False
    for word in text.split():
        if word not in _IGNORED_QHULL_OPTIONS and not word.startswith("QJ"):
            raise ValueError(f"qhull_options: '{word}' is not an option spokemesh accepts "
                             f"(accepted and ignored: {' '.join(sorted(_IGNORED_QHULL_OPTIONS))})")
        joggle = joggle or word.startswith("QJ")
    return joggle


def _joggled(points: np.ndarray, first: np.ndarray) -> np.ndarray:
    """The points with each one equal to an earlier one moved by about 1e-10 of its own
    magnitude in a direction drawn from its index (so a whole build and an incremental
    one move it alike), until no two points are equal."""
    out = points.copy()
    for j in np.flatnonzero(first != np.arange(len(points))):
        rng = np.random.default_rng([0x5EED, int(j)])
        scale = 1e-10 * max(float(np.abs(points[j]).max()), 1e-300)
        out[j] = points[j] + scale * rng.uniform(-1.0, 1.0, points.shape[1])
    if len(np.unique(out, axis=0)) != len(out):
        raise ValueError("qhull_options QJ: could not joggle the equal points apart")
    return out


def _rebuild(points, incremental, qhull_options, threads, furthest_site=False, weights=None):
    return Delaunay(points, furthest_site=furthest_site, incremental=incremental, qhull_options=qhull_options,
                    threads=threads, weights=weights)


def _cell(c: dict) -> Cell:
    d = c["vertices"].shape[1]
    facets = [Facet(neighbor=f["neighbor"], wall=f["wall"], vertices=f["vertices"], area=f["area"],
                    normal=f["normal"]) for f in c["facets"]]
    return Cell(seed=c["seed"], vertices=c["vertices"], vertex_simplices=np.zeros((0, d + 1), dtype=np.uint32),
                facets=facets, bounded=c["bounded"], volume=c["volume"], centroid=c["centroid"],
                clipped=c["clipped"], hidden=c["hidden"])


class Delaunay:
    """The exact Delaunay triangulation of `points` ((n, d) array, 2 <= d <= 8).

    Parameters, in scipy's order: points (array_like, converted once to C-ordered
    float64); furthest_site (the furthest-site triangulation: the simplices whose
    circumspheres hold every point, over the hull's vertices; cospherical corners, as a
    box grid's, are triangulated by the symbolic perturbation; above 2-d, a hull with
    more than d points on every facet and too many corners to search raises ValueError);
    incremental (allow add_points, as
    scipy's); qhull_options (scipy's string of Qhull options:
    accepted and ignored, since an exact triangulation needs none of them; unknown
    options raise ValueError); threads (worker threads; None: all cores). The mesh is
    the same for any thread count. Beyond scipy: weights ((n,) power weights, CGAL's
    convention: a weight is a squared radius), which gives the regular (weighted
    Delaunay) triangulation: a point whose power cell is empty is in no simplex and
    listed in `hidden`; equal weights give the Delaunay triangulation; cell(i) and
    cells() are then power (Laguerre) cells. Weighted triangulations do not offer
    furthest_site, incremental or Voronoi yet (ValueError), and refuse equal points.
    Raises ValueError for bad input (NaN, fewer than d + 1 points, points in a
    lower-dimensional subspace), naming the index. Equal points are merged into their
    first occurrence and listed in `coplanar`, as scipy does (with QJ in qhull_options
    they are moved apart by about 1e-10 of their magnitude instead, so that every
    point is a vertex, as Qhull's joggle does).

    Attributes, as scipy.spatial.Delaunay's: points, ndim, npoints, nsimplex,
    simplices, neighbors, vertex_neighbor_vertices, vertex_to_simplex, convex_hull,
    coplanar, transform (NaN rows for simplices too flat for it), equations (with
    weights: the lifted points (p, |p|^2 - w)), weights, hidden,
    paraboloid_scale, paraboloid_shift, min_bound, max_bound, vertices (deprecated);
    methods find_simplex(xi, bruteforce, tol), lift_points(x), plane_distance(xi),
    add_points(points, restart), close(); pickling. The rows' order is the sweep's,
    not Qhull's (scipy leaves it unspecified). Beyond scipy: star(i), neighbors_of(i), cell(i, box, halfspaces),
    cells(box, halfspaces).

    periodic ((2, d): the box's low and high corners) gives the Delaunay triangulation of
    the flat torus instead: a PeriodicDelaunay (see there).

    Thread safety: immutable after construction; methods may be called from several
    threads (each releases the GIL while it works).
    """

    def __new__(cls, points: np.ndarray, *args, periodic: Optional[np.ndarray] = None, **kwargs):
        # With a periodic box, the triangulation of the torus (PeriodicDelaunay).
        if periodic is not None and cls is Delaunay:
            return super().__new__(PeriodicDelaunay)
        return super().__new__(cls)

    def __init__(self, points: np.ndarray, furthest_site: bool = False, incremental: bool = False,
                 qhull_options: Optional[str] = None, threads: Optional[int] = None,
                 weights: Optional[np.ndarray] = None, periodic: Optional[np.ndarray] = None):
        if np.ma.isMaskedArray(points):
            raise ValueError("Input points cannot be a masked array")
        #: Whether this is the furthest-site triangulation.
        self.furthest_site: bool = bool(furthest_site)
        self._joggle = _check_qhull_options(qhull_options)
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2:
            raise ValueError(f"points: expected an (n, d) array, got shape {pts.shape}")
        self._incremental = bool(incremental)
        self._threads = threads
        #: (npoints,) float64 power weights, or None for the Delaunay triangulation.
        self.weights: Optional[np.ndarray] = None
        if weights is not None:
            self.weights = np.ascontiguousarray(weights, dtype=np.float64)
            for flag, what in ((self.furthest_site, "furthest_site"), (self._incremental, "incremental"),
                               (self._joggle, "qhull_options QJ")):
                if flag:
                    raise ValueError(f"weights: {what} is not available for a weighted triangulation yet")
        #: Paraboloid of the lifted points (scipy's lift_points): z = scale |x|^2 + shift.
        self.paraboloid_scale: float = 1.0
        self.paraboloid_shift: float = 0.0
        self._set(*self._triangulate(pts), pts)

    def _triangulate(self, pts: np.ndarray):
        """The core triangulation of pts and the first occurrence of each point (None
        when no two points are equal). Equal points are merged (the first kept; scipy's
        `coplanar` reports the others) or, with QJ, joggled apart."""
        if self.weights is not None:
            try:
                return _core.Triangulation(pts, self._threads, self.weights), None
            except _core.DuplicatePointsError as e:
                raise ValueError(f"{e} (a weighted set cannot merge equal points: which weight would count?)") from None
        try:
            tri, first = _core.Triangulation(pts, self._threads), None
        except _core.DuplicatePointsError:
            first = _core.first_occurrences(pts)
            if self._joggle:
                tri, first = _core.Triangulation(_joggled(pts, first), self._threads), None
            else:
                tri = _core.Triangulation(pts[first == np.arange(len(pts))], self._threads)
        return (tri.furthest_site() if self.furthest_site else tri), first

    def _set(self, tri, first: Optional[np.ndarray], points: np.ndarray,
             bounds: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> None:
        self._tri = tri
        self._first = first
        self.points: np.ndarray = points
        self.ndim: int = self.points.shape[1]
        self.npoints: int = self.points.shape[0]
        #: (nsimplex, ndim + 1) int32: vertex indices, each simplex positively oriented
        #: (det[p1 - p0, ..., pd - p0] > 0), rows in sweep order (docs/algorithm.md), the same for any thread count.
        self.simplices: np.ndarray = self._tri.simplices()
        if first is not None:
            self._kept = np.flatnonzero(first == np.arange(len(first)))  # the triangulated points
            self.simplices = self._kept[self.simplices].astype(np.int32)
        self.nsimplex: int = self.simplices.shape[0]
        #: The box of the points (scipy's min_bound, max_bound).
        if bounds is None:
            bounds = (self.points.min(axis=0), self.points.max(axis=0))
        self.min_bound: np.ndarray = bounds[0]
        self.max_bound: np.ndarray = bounds[1]
        for cached in ("neighbors", "vertex_neighbor_vertices", "convex_hull", "transform", "equations",
                       "vertex_to_simplex", "coplanar", "hidden"):
            self.__dict__.pop(cached, None)

    def add_points(self, points: np.ndarray, restart: bool = False) -> None:
        """Append points (shape (k, ndim)) to a triangulation made with incremental=True.

        The result is the triangulation of all the points, the same simplices in the same
        order as `Delaunay` of them at once. restart=False computes only the new points'
        stars (their old neighbours' rows are filtered by an exact circumsphere test); restart=True
        triangulates everything again. Raises RuntimeError when the triangulation was
        not made incremental or was closed, ValueError for bad points (named by their
        index in the whole set)."""
        if not self._incremental:
            raise RuntimeError("add_points: this triangulation was not made with incremental=True, or was closed")
        more = np.ascontiguousarray(points, dtype=np.float64)
        if more.ndim != 2 or more.shape[1] != self.ndim:
            raise ValueError(f"points: expected shape (k, {self.ndim}), got {more.shape}")
        everything = np.concatenate([self.points, more], axis=0)
        if restart:
            self._set(*self._triangulate(everything), everything)
            return
        if self.furthest_site:
            # The furthest-site triangulation is made whole each time (its simplices are
            # not the nearest-site stars insertion recomputes).
            self._set(*self._triangulate(everything), everything)
            return
        n_old = self.npoints
        # (The box grows by the new points' box: no pass over the old ones.)
        bounds = (np.minimum(self.min_bound, more.min(axis=0, initial=np.inf)),
                  np.maximum(self.max_bound, more.max(axis=0, initial=-np.inf)))
        if self._first is None:
            try:
                self._set(self._tri.inserted(more), None, everything, bounds)
                return
            except _core.DuplicatePointsError:
                pass
        # Equal points: each new point equal to an earlier one is merged into it (or,
        # with QJ, moved apart by its own index, as a whole build moves it).
        every_first = _core.first_occurrences(everything)
        first = None
        if self._joggle:
            new = _joggled(everything, every_first)[n_old:]
        else:
            first = every_first
            new = more[every_first[n_old:] == np.arange(n_old, len(everything))]
        self._set(self._tri.inserted(new) if len(new) else self._tri, first, everything, bounds)

    def close(self) -> None:
        """Ends incremental mode: add_points raises RuntimeError from now on."""
        self._incremental = False

    def __reduce__(self):
        # The triangulation is a function of the points: pickling keeps them and the
        # mode, and unpickling triangulates again (the same simplices, the same order).
        return (_rebuild, (self.points, self._incremental, "QJ" if self._joggle else None, self._threads,
                           self.furthest_site, self.weights))

    @property
    def vertices(self) -> np.ndarray:
        """Deprecated alias of simplices (as in scipy 1.10)."""
        warnings.warn("Delaunay attribute 'vertices' is deprecated in favour of 'simplices' and will be removed "
                      "in Scipy 1.11.0.", DeprecationWarning, stacklevel=2)
        return self.simplices

    @functools.cached_property
    def coplanar(self) -> np.ndarray:
        """(k, 3) int32, scipy's: points that are not vertices (here: points equal to an
        earlier one), each with a simplex containing its twin and the twin's index."""
        if self._first is None:
            return np.zeros((0, 3), dtype=np.int32)
        dup = np.flatnonzero(self._first != np.arange(self.npoints))
        twin = self._first[dup]
        return np.stack([dup, self.vertex_to_simplex[twin], twin], axis=1).astype(np.int32)

    @functools.cached_property
    def hidden(self) -> np.ndarray:
        """int32, ascending: the points in no simplex because their power cell is empty
        (weighted triangulations; always empty without weights)."""
        if self.weights is None:
            return np.zeros(0, dtype=np.int32)
        used = np.zeros(self.npoints, dtype=bool)
        used[self.simplices.ravel()] = True
        return np.flatnonzero(~used).astype(np.int32)

    @functools.cached_property
    def vertex_to_simplex(self) -> np.ndarray:
        """(npoints,) int32: a simplex each point is a vertex of (a merged duplicate:
        its twin's)."""
        out = np.full(self.npoints, -1, dtype=np.int32)
        out[self.simplices.ravel()] = np.repeat(np.arange(self.nsimplex, dtype=np.int32), self.ndim + 1)
        if self._first is not None:
            out = out[self._first]
        return out

    def lift_points(self, x: np.ndarray) -> np.ndarray:
        """Points lifted onto the paraboloid: (..., ndim + 1), the last coordinate
        paraboloid_scale |x|^2 + paraboloid_shift (scipy's)."""
        x = np.asarray(x, dtype=np.float64)
        z = self.paraboloid_scale * np.sum(x * x, axis=-1, keepdims=True) + self.paraboloid_shift
        return np.concatenate([x, z], axis=-1)

    @functools.cached_property
    def equations(self) -> np.ndarray:
        """(nsimplex, ndim + 2): each simplex's hyperplane through its lifted vertices,
        unit normal (last component negative: the lower hull; positive for the
        furthest-site triangulation, the upper hull) and offset, as scipy's."""
        lifted = self.lift_points(self.points[self.simplices])           # (m, d + 1, d + 1)
        if self.weights is not None:  # the power lift |p|^2 - w_p
            lifted[..., -1] -= self.paraboloid_scale * self.weights[self.simplices]
        base = lifted[:, -1, :]
        edges = lifted[:, :-1, :] - base[:, None, :]                     # (m, d, d + 1)
        d1 = self.ndim + 1
        # The normal: the cofactors of the edge matrix (a generalised cross product).
        normal = np.empty((self.nsimplex, d1))
        for k in range(d1):
            minor = np.delete(edges, k, axis=2)
            normal[:, k] = (-1) ** k * np.linalg.det(minor)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        normal *= (1.0 if self.furthest_site else -1.0) * np.sign(normal[:, -1:])
        offset = -np.einsum("ij,ij->i", normal, base)
        return np.concatenate([normal, offset[:, None]], axis=1)

    def plane_distance(self, xi: np.ndarray) -> np.ndarray:
        """(..., nsimplex): the signed distance of each lifted point of xi to each
        simplex's hyperplane in the lifted space (scipy's)."""
        z = self.lift_points(np.asarray(xi, dtype=np.float64))
        eq = self.equations
        return z @ eq[:, :-1].T + eq[:, -1]

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
        c = T[:ndim] @ (x - T[ndim]) gives the first ndim of them, the last is 1 - sum(c).
        A simplex too flat for them to mean anything in floating point (reciprocal
        condition number in the 1-norm below 100 eps; scipy's rule with LAPACK's
        estimate) gets NaN rows, as scipy's do."""
        v = self.points[self.simplices]
        r = v[:, -1, :]
        a = np.transpose(v[:, :-1, :] - r[:, None, :], (0, 2, 1))
        with np.errstate(all="ignore"):
            # Exactly singular rows cannot be inverted: replaced by the identity first
            # (their rows become NaN below).
            singular = np.linalg.det(a) == 0  # (an LU each; inv raises on these)
            a_safe = np.where(singular[:, None, None], np.eye(self.ndim), a)
            t = np.linalg.inv(a_safe)
            rcond = 1.0 / (np.abs(a).sum(axis=1).max(axis=1) * np.abs(t).sum(axis=1).max(axis=1))
        bad = singular | ~(rcond >= 100 * np.finfo(np.float64).eps)
        t[bad] = np.nan
        out = np.concatenate([t, r[:, None, :]], axis=1)
        out[bad, -1, :] = np.nan
        return out

    def find_simplex(self, xi: np.ndarray, bruteforce: bool = False, tol: Optional[float] = None) -> np.ndarray:
        """The simplex containing each point of xi (shape (..., ndim)), -1 outside the
        hull; decided by exact orientation tests (a point on a shared face gets one of
        its simplices). bruteforce and tol are scipy's and have no effect: the walk is
        exact, so no point needs a tolerance or a second, exhaustive search."""
        q = np.ascontiguousarray(xi, dtype=np.float64)
        flat = q.reshape(-1, self.ndim)
        if self.furthest_site:
            return self._find_simplex_by_barycentric(flat, tol).reshape(q.shape[:-1])
        return self._tri.find_simplex(flat).reshape(q.shape[:-1])

    def _find_simplex_by_barycentric(self, flat: np.ndarray, tol: Optional[float]) -> np.ndarray:
        """The furthest-site triangulation's point location: every simplex's barycentric
        coordinates (in floating point, as scipy's), the first simplex where none is below
        -tol (default 100 eps), -1 elsewhere."""
        eps = 100 * np.finfo(np.float64).eps if tol is None else float(tol)
        t = self.transform
        out = np.full(len(flat), -1, dtype=np.int32)
        for s in range(self.nsimplex):
            if not np.isfinite(t[s]).all():
                continue
            c = (flat - t[s, self.ndim]) @ t[s, :self.ndim].T
            bary = np.concatenate([c, 1 - c.sum(axis=1, keepdims=True)], axis=1)
            hit = (out < 0) & (bary >= -eps).all(axis=1)
            out[hit] = s
        return out

    def _vertex(self, i: int) -> int:
        """The core's index of point i (equal points: their first occurrence's)."""
        i = int(i)
        if self._first is None:
            return i
        if not 0 <= i < self.npoints:
            raise ValueError(f"point {i} is not one of the {self.npoints} points")
        return int(np.searchsorted(self._kept, self._first[i]))

    def _no_merged_points(self, what: str) -> None:
        if self._first is not None:
            dup = int(np.flatnonzero(self._first != np.arange(self.npoints))[0])
            raise ValueError(f"{what}: points {int(self._first[dup])} and {dup} are equal, and equal points share "
                             "one cell; remove duplicates first")

    def _nearest_site_only(self, what: str) -> None:
        if self.furthest_site:
            raise ValueError(f"{what}: this is the furthest-site triangulation; stars, neighbours and cells are "
                             "those of the nearest-site one (Delaunay(points))")

    def star(self, i: int) -> np.ndarray:
        """(k, ndim + 1) uint32: the simplices incident to vertex i (its Delaunay star)."""
        self._nearest_site_only("star")
        out = self._tri.star(self._vertex(i))
        return out if self._first is None else self._kept[out].astype(np.uint32)

    def neighbors_of(self, i: int) -> np.ndarray:
        """uint32, ascending: the Delaunay neighbours of vertex i."""
        self._nearest_site_only("neighbors_of")
        out = self._tri.neighbors_of(self._vertex(i))
        return out if self._first is None else self._kept[out].astype(np.uint32)

    def cell(self, i: int, box: Optional[Sequence[float]] = None,
             halfspaces: Optional[np.ndarray] = None, domain=None) -> Cell:
        """The Voronoi cell of vertex i, clipped to box (lo_1..lo_d, hi_1..hi_d), to
        halfspaces ((m, ndim + 1) rows a, b with a.x <= b) or to a domain of any shape
        (a path to a .off/.obj/.stl mesh or a .geojson/.rings polygon, or a (format,
        bytes) pair) when given, with its measures (docs/cells.md). Unbounded: volume
        inf, centroid None. A seed outside a convex domain raises ValueError; in a
        domain of any shape its cell is the part of its Voronoi cell inside the domain
        (often empty). Cells in a domain of any shape carry measures only: their facets
        list neighbours, then walls (`wall` = the domain's face index)."""
        self._nearest_site_only("cell")
        self._no_merged_points("cell")
        b = None if box is None else [float(v) for v in np.asarray(box, dtype=np.float64).ravel()]
        h = None if halfspaces is None else np.ascontiguousarray(halfspaces, dtype=np.float64)
        f, data = domain_bytes(domain)
        return _cell(self._tri.cell(int(i), b, h, f, data))

    def cells(self, box: Optional[Sequence[float]] = None,
              halfspaces: Optional[np.ndarray] = None, domain=None) -> Dict[str, np.ndarray]:
        """Every cell's measures, as `spokemesh cells` writes them to .npz: volume (n,),
        centroid (n, d), bounded (n,), facet_ptr (n + 1,), facet_neighbor (m,) (the
        neighbour, or -1 - k for wall k), facet_area (m,), facet_normal (m, d). Clipped
        to box, halfspaces or a domain of any shape (as cell(); wall k is its face k),
        by default to the points' bounding box."""
        self._nearest_site_only("cells")
        self._no_merged_points("cells")
        b = None if box is None else [float(v) for v in np.asarray(box, dtype=np.float64).ravel()]
        h = None if halfspaces is None else np.ascontiguousarray(halfspaces, dtype=np.float64)
        f, data = domain_bytes(domain)
        return self._tri.cells(b, h, True, f, data)


_DOMAIN_FORMATS = {".off": "off", ".obj": "obj", ".stl": "stl", ".rings": "rings", ".geojson": "geojson",
                   ".json": "geojson"}


def domain_bytes(domain):
    """(format, bytes) of a domain of any shape: a path (its extension names the format:
    .off .obj .stl .rings .geojson/.json, anything else rings), a (format, bytes or str)
    pair, or None for none."""
    if domain is None:
        return None, None
    if isinstance(domain, tuple):
        if len(domain) != 2 or domain[0] not in set(_DOMAIN_FORMATS.values()):
            raise ValueError("domain: a path, or (format, data) with format one of off, obj, stl, rings, geojson")
        data = domain[1].encode() if isinstance(domain[1], str) else bytes(domain[1])
        return domain[0], data
    path = os.fspath(domain)
    suffix = os.path.splitext(path)[1].lower()
    with open(path, "rb") as f:
        return _DOMAIN_FORMATS.get(suffix, "rings"), f.read()


def _rebuild_periodic(points, threads, periodic, weights=None):
    return Delaunay(points, threads=threads, periodic=periodic, weights=weights)


# Why each scipy member a torus lacks is unavailable: its docstring, and help()'s.
_UNAVAILABLE_ON_A_TORUS = {
    "neighbors": "a simplex's neighbours across its facets: on the torus they would need offsets too",
    "vertex_neighbor_vertices": "neighbours in CSR form: on the torus a neighbour is an image; use neighbors_of(i)",
    "convex_hull": "the torus has no hull",
    "transform": "barycentric transforms of the simplices: on the torus they depend on the images' offsets",
    "equations": "the lifted hull's facet planes: the torus has no hull",
    "vertex_to_simplex": "a simplex per vertex: use star(i), which gives every simplex around point i",
    "coplanar": "Qhull's coplanar points: every point of a torus is a vertex",
    "hidden": "the points in no simplex (weighted sets) are not listed on a torus; such a point's cell(i) has "
              "volume 0",
    "vertices": "scipy's old name for simplices: use simplices and offsets",
    "find_simplex": "point location is not implemented on a torus yet (a query point would have to be located "
                    "among the images of the simplices; scipy's answer, one row index, cannot name the image)",
    "lift_points": "the paraboloid lift is defined on the plane, not on the torus (no global lift exists)",
    "plane_distance": "distances to the lifted hull's facet planes: the torus has no hull and no global lift",
    "add_points": "incremental insertion is not implemented on a torus yet: the triangulation is built in one "
                  "pass from all its points (make a new PeriodicDelaunay with the points added)",
}
# The ones scipy calls as methods (the rest are attributes).
_UNAVAILABLE_METHODS = ("find_simplex", "lift_points", "plane_distance", "add_points")


def _unavailable(name: str):
    """A member of scipy's Delaunay that a periodic triangulation lacks: raises
    ValueError saying why, and says so in help() too."""
    why = _UNAVAILABLE_ON_A_TORUS[name]

    def fail(self, *args, **kwargs):
        raise ValueError(f"{name} is not available for a periodic triangulation: {why}")
    fail.__name__ = name
    fail.__qualname__ = f"PeriodicDelaunay.{name}"
    fail.__doc__ = (f"Not available on a torus: {why}. Raises ValueError (scipy.spatial.Delaunay has it; "
                    f"PeriodicDelaunay keeps the name so that code written for scipy fails saying why).")
    if name in _UNAVAILABLE_METHODS:
        return fail
    return property(fail, doc=fail.__doc__)


class PeriodicDelaunay(Delaunay):
    """The exact Delaunay triangulation of the flat torus: `Delaunay(points, periodic=box)`.

    box: (2, d) array_like, the low and high corners of [lo, hi), whose opposite sides are
    identified; every point must lie inside (ValueError naming the first outside). Each
    simplex of the torus appears once, as d + 1 point indices (`simplices`, (m, d + 1)
    int32, positively oriented, the first vertex its smallest index) and each vertex's
    image offset in box lengths (`offsets`, (m, d + 1, d) int32; the first vertex's is
    0): vertex v of simplex s stands at points[simplices[s, v]] + offsets[s, v] * (hi - lo).
    The same triangulation as CGAL's Periodic_2/3_Delaunay_triangulation, exactly (README
    "Periodic boxes"); the same rows for any thread count.

    Attributes: points, ndim, npoints, nsimplex, simplices, offsets, periodic (the box,
    (2, d)), min_bound and max_bound (its corners). Methods: star(i) -> (simplices,
    offsets) of the simplices around point i (i at offset 0 in each); neighbors_of(i) ->
    (indices, offsets) of its neighbour images; cell(i) -> Cell (facets name the
    neighbour's point and its image `offset`); cells() -> the measures `spokemesh cells
    --periodic` writes (with facet_offset). scipy's other attributes (neighbors,
    convex_hull, transform, find_simplex, ...) raise ValueError; furthest_site,
    incremental and QJ are not available on a torus yet (ValueError). weights ((n,) power
    weights) give the regular triangulation of the torus and its power cells (a point
    whose cell is empty is in no simplex; its cell has volume 0). Pickling keeps the
    points, the box and the weights.

    Thread safety: immutable after construction; methods may be called from several
    threads (each releases the GIL while it works).
    """

    def __init__(self, points: np.ndarray, furthest_site: bool = False, incremental: bool = False,
                 qhull_options: Optional[str] = None, threads: Optional[int] = None,
                 weights: Optional[np.ndarray] = None, periodic: Optional[np.ndarray] = None):
        if np.ma.isMaskedArray(points):
            raise ValueError("Input points cannot be a masked array")
        joggle = _check_qhull_options(qhull_options)
        for flag, what in ((furthest_site, "furthest_site"), (incremental, "incremental"),
                           (joggle, "qhull_options QJ")):
            if flag:
                raise ValueError(f"periodic: {what} is not available on a torus yet")
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2:
            raise ValueError(f"points: expected an (n, d) array, got shape {pts.shape}")
        box = np.asarray(periodic, dtype=np.float64)
        if box.shape != (2, pts.shape[1]):
            raise ValueError(f"periodic: expected the box's corners as shape (2, {pts.shape[1]}), got {box.shape}")
        self.furthest_site = False
        #: (npoints,) float64 power weights (the regular triangulation of the torus), or None.
        self.weights = None if weights is None else np.ascontiguousarray(weights, dtype=np.float64)
        self._threads = threads
        self._incremental = False
        #: (2, d) float64: the box [periodic[0], periodic[1]) of the torus.
        self.periodic: np.ndarray = box
        self._periodic = _core.PeriodicTriangulation(pts, box[0].tolist(), box[1].tolist(), threads, self.weights)
        self.points: np.ndarray = pts
        self.ndim: int = pts.shape[1]
        self.npoints: int = pts.shape[0]
        #: (nsimplex, ndim + 1) int32 point indices, positively oriented on their images.
        self.simplices: np.ndarray = self._periodic.simplices()
        #: (nsimplex, ndim + 1, ndim) int32: each vertex's image offset in box lengths.
        self.offsets: np.ndarray = self._periodic.offsets()
        self.nsimplex: int = self.simplices.shape[0]
        self.min_bound: np.ndarray = box[0].copy()
        self.max_bound: np.ndarray = box[1].copy()

    def __reduce__(self):
        return (_rebuild_periodic, (self.points, self._threads, self.periodic, self.weights))

    def star(self, i: int) -> Tuple[np.ndarray, np.ndarray]:
        """Point i's simplices on the torus and their vertices' offsets (i at offset 0)."""
        return self._periodic.star(int(i))

    def neighbors_of(self, i: int) -> Tuple[np.ndarray, np.ndarray]:
        """Point i's Delaunay neighbours as images: (k,) indices and (k, d) offsets,
        sorted by index then offset (a neighbour may appear at several offsets)."""
        s, o = self.star(i)
        rows = {(int(p),) + tuple(int(x) for x in k) for p, k in zip(s.ravel(), o.reshape(-1, self.ndim))}
        rows.discard((int(i),) + (0,) * self.ndim)
        ordered = np.array(sorted(rows), dtype=np.int32).reshape(-1, self.ndim + 1)
        return ordered[:, 0].copy(), ordered[:, 1:].copy()

    def cell(self, i: int, box=None, halfspaces=None) -> Cell:
        """Point i's cell on the torus (unclipped: box and halfspaces must be None)."""
        if box is not None or halfspaces is not None:
            raise ValueError("periodic: a cell of the torus is not clipped (box and halfspaces do not apply)")
        c = self._periodic.cell(int(i))
        d = self.ndim
        facets = [Facet(neighbor=f["neighbor"], wall=None, vertices=f["vertices"], area=f["area"], normal=f["normal"],
                        offset=f["offset"]) for f in c["facets"]]
        return Cell(seed=c["seed"], vertices=c["vertices"], vertex_simplices=np.zeros((0, d + 1), dtype=np.uint32),
                    facets=facets, bounded=c["bounded"], volume=c["volume"], centroid=c["centroid"],
                    clipped=False, hidden=False)

    def cells(self, box=None, halfspaces=None) -> Dict[str, np.ndarray]:
        """Every cell's measures: volume (n,), centroid (n, d), facet_ptr (n + 1,),
        facet_neighbor (m,), facet_area (m,), facet_normal (m, d), facet_offset (m, d)."""
        if box is not None or halfspaces is not None:
            raise ValueError("periodic: the cells of the torus are not clipped (box and halfspaces do not apply)")
        return self._periodic.cells()

    neighbors = _unavailable("neighbors")
    vertex_neighbor_vertices = _unavailable("vertex_neighbor_vertices")
    convex_hull = _unavailable("convex_hull")
    transform = _unavailable("transform")
    equations = _unavailable("equations")
    vertex_to_simplex = _unavailable("vertex_to_simplex")
    coplanar = _unavailable("coplanar")
    hidden = _unavailable("hidden")
    vertices = _unavailable("vertices")
    find_simplex = _unavailable("find_simplex")
    lift_points = _unavailable("lift_points")
    plane_distance = _unavailable("plane_distance")
    add_points = _unavailable("add_points")


@dataclasses.dataclass(frozen=True)
class ApproximateGraph:
    """A certified approximate Delaunay graph: every edge is a true Delaunay edge; some
    may be missing where a seed's walk stopped early (walk_exhausted False)."""
    indptr: np.ndarray          # (n + 1,) int64
    indices: np.ndarray         # int32: neighbours of k are indices[indptr[k]:indptr[k + 1]]
    walk_exhausted: np.ndarray  # (n,) bool: seed k's walk tried everything (its list is complete)


def approximate_graph(points: np.ndarray, misses: int = _core.DEFAULT_MAX_MISSES, seed: int = 0x5eed,
                      max_vertices: int = _core.DEFAULT_MAX_VERTICES, mode: str = "rsd",
                      threads: Optional[int] = None) -> ApproximateGraph:
    """The certified approximate Delaunay graph in any dimension (Recursive Spoke Darts
    with a budget of `misses` consecutive misses per seed, the paper's M; mode "spokes"
    for plain Spoke Darts). Deterministic for a given `seed` and any thread count."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    indptr, indices, exhausted = _core.approximate_graph(pts, misses, max_vertices, seed, mode, threads)
    return ApproximateGraph(indptr=indptr, indices=indices, walk_exhausted=exhausted)
