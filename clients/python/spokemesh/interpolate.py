"""Values at any point, with the names and meanings of scipy.interpolate's
LinearNDInterpolator, NearestNDInterpolator and griddata, on spokemesh's exact
Delaunay triangulation.

    import numpy as np, spokemesh.interpolate as si
    xy = np.random.default_rng(1).random((100_000, 2)); z = np.sin(6 * xy[:, 0]) * xy[:, 1]
    f = si.LinearNDInterpolator(xy, z)          # or a spokemesh.Delaunay
    f(0.3, 0.7); f(np.random.default_rng(2).random((10, 2)))
    grid = si.griddata(xy, z, (gx, gy), method="linear")

Which simplex holds each query point is decided exactly (the triangulation's exact
point location, so a point on a shared face gets one of its simplices, and a point
just outside the hull is outside); the value is then the barycentric combination in
double, as scipy's. NaturalNeighborInterpolator and natural_neighbor_coordinates give
Sibson's natural-neighbour coordinates in 2-d and 3-d (CGAL's, to 1e-12): the query's
natural neighbours come from an exact in-sphere test, their weights are the shares of
the query's Voronoi cell each would lose, in double. scipy has none.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import _core
from .delaunay import Delaunay

__all__ = ["LinearNDInterpolator", "NearestNDInterpolator", "NaturalNeighborInterpolator", "griddata",
           "natural_neighbor_coordinates"]


def _coords(args, ndim: Optional[int] = None) -> np.ndarray:
    """Query points from scipy's calling conventions: one (..., ndim) array, a tuple of
    coordinate arrays, or ndim coordinate arrays as separate arguments (broadcast)."""
    if len(args) == 1:
        args = args[0]
    if isinstance(args, tuple):
        arrays = np.broadcast_arrays(*[np.asarray(a) for a in args])
        out = np.empty(arrays[0].shape + (len(arrays),), dtype=np.float64)
        for j, a in enumerate(arrays):
            out[..., j] = a
        return out
    out = np.asanyarray(args, dtype=np.float64)
    if ndim is not None and out.ndim == 1 and out.shape[0] == ndim:
        return out  # one point
    if ndim == 1 and out.ndim == 1:
        return out[:, None]
    return out


def _points_array(points, what: str = "points") -> np.ndarray:
    """An (n, ndim) float64 array from an array or a tuple of coordinate arrays."""
    pts = _coords((points,)) if isinstance(points, tuple) else np.asarray(points, dtype=np.float64)
    if pts.ndim != 2:
        raise ValueError(f"{what}: expected an (n, ndim) array, got shape {pts.shape}")
    return pts


class _Interpolant:
    """What the interpolators share: the points (rescaled if asked), the values as an
    (n, k) array of their trailing shape, and the query conventions."""

    def _set_values(self, values, npoints: int) -> None:
        v = np.asarray(values)
        if v.shape[0] != npoints:
            raise ValueError(f"values: {v.shape[0]} rows for {npoints} points")
        if not (np.issubdtype(v.dtype, np.number) or v.dtype == bool):
            raise ValueError(f"values: numbers expected, got dtype {v.dtype}")
        self._trailing = v.shape[1:]
        dtype = np.complex128 if np.iscomplexobj(v) else np.float64
        self.values = np.ascontiguousarray(v.reshape(npoints, -1), dtype=dtype)

    def _triangulate(self, points, rescale: bool, threads: Optional[int]) -> None:
        """self.points, self.tri (the given Delaunay, or one of the points, rescaled to
        the unit cube when asked), self.ndim and self.scale."""
        self.scale = None
        if isinstance(points, Delaunay):
            if rescale:
                raise ValueError("Rescaling is not supported when passing a Delaunay triangulation as ``points``.")
            self.tri, self.points = points, points.points
        else:
            pts = self.points = _points_array(points)
            self.tri = Delaunay(self._rescale_from(pts) if rescale else pts, threads=threads)
        self.ndim = self.points.shape[1]

    def _rescale_from(self, points: np.ndarray) -> np.ndarray:
        self.offset = points.mean(axis=0)
        scale = np.ptp(points, axis=0)
        scale[~(scale > 0)] = 1.0
        self.scale = scale
        return (points - self.offset) / self.scale

    def _queries(self, args):
        xi = _coords(args, self.ndim)
        if xi.shape[-1] != self.ndim:
            raise ValueError(f"xi: the last axis has {xi.shape[-1]} coordinates; the points have {self.ndim}")
        shape = xi.shape[:-1]
        flat = np.ascontiguousarray(xi.reshape(-1, self.ndim))
        if self.scale is not None:
            flat = (flat - self.offset) / self.scale
        return flat, shape

    def _shaped(self, out: np.ndarray, shape) -> np.ndarray:
        return out.reshape(shape + self._trailing)


class LinearNDInterpolator(_Interpolant):
    """Piecewise-linear interpolation on the Delaunay triangulation of the points
    (scipy.interpolate.LinearNDInterpolator's meaning).

    points_or_triangulation: (n, ndim) points, a tuple of ndim coordinate arrays, or a
    spokemesh.Delaunay (then rescale must be False, as scipy's). values: (n, ...) real
    or complex; the trailing shape is kept. fill_value: the value outside the hull
    (default NaN). rescale: scale the points to the unit cube before triangulating (and
    the queries alike), as scipy's. Beyond scipy: threads (for the triangulation).

    Call with an (..., ndim) array, a tuple of coordinate arrays, or ndim coordinate
    arrays: the result has the queries' shape followed by the values' trailing shape.
    Equal points are merged into their first occurrence (its value is used).

    Thread safety: immutable after construction; calls may run concurrently.
    """

    def __init__(self, points, values, fill_value=np.nan, rescale: bool = False, threads: Optional[int] = None):
        self._triangulate(points, rescale, threads)
        self._set_values(values, self.points.shape[0])
        self.fill_value = fill_value
        self._rescale = bool(rescale)
        self._threads = threads

    def __call__(self, *args) -> np.ndarray:
        flat, shape = self._queries(args)
        tri = self.tri
        simplex = tri.find_simplex(flat)
        inside = np.flatnonzero(simplex >= 0)
        out = np.empty((len(flat), self.values.shape[1]), dtype=self.values.dtype)
        out[...] = self.fill_value
        if len(inside):
            s = simplex[inside]
            bary = self._barycentric(flat[inside], s)
            corners = self.values[tri.simplices[s]]  # (m, ndim + 1, k)
            out[inside] = np.einsum("mj,mjk->mk", bary, corners)
        return self._shaped(out, shape)

    def _barycentric(self, q: np.ndarray, s: np.ndarray) -> np.ndarray:
        # scipy's transform when the triangulation already has it; else only the hit
        # simplices' systems are solved (the transform of every simplex costs more than
        # the queries of a raster).
        if "transform" in self.tri.__dict__:
            t = self.tri.transform[s]
            c = np.einsum("mij,mj->mi", t[:, :self.ndim, :], q - t[:, self.ndim, :])
            bary = np.concatenate([c, 1 - c.sum(axis=1, keepdims=True)], axis=1)
        else:
            v = self.tri.points[self.tri.simplices[s]]  # (m, ndim + 1, ndim)
            r = v[:, -1, :]
            a = np.transpose(v[:, :-1, :] - r[:, None, :], (0, 2, 1))
            with np.errstate(all="ignore"):
                singular = ~(np.abs(np.linalg.det(a)) > 0)
                a[singular] = np.eye(self.ndim)
                c = np.linalg.solve(a, (q - r)[:, :, None])[:, :, 0]
            c[singular] = np.nan
            bary = np.concatenate([c, 1 - c.sum(axis=1, keepdims=True)], axis=1)
        # A simplex too flat for that (NaN): its coordinates by a least-squares solve of
        # the point's affine combination instead.
        for m in np.flatnonzero(~np.isfinite(bary).all(axis=1)):
            v = self.tri.points[self.tri.simplices[s[m]]]
            a = np.vstack([v.T, np.ones(self.ndim + 1)])
            bary[m] = np.linalg.lstsq(a, np.append(q[m], 1.0), rcond=None)[0]
        return bary

    def __reduce__(self):
        source = self.tri if not self._rescale else self.points
        values = self.values.reshape((self.values.shape[0],) + self._trailing)
        return (LinearNDInterpolator, (source, values, self.fill_value, self._rescale, self._threads))


class NearestNDInterpolator(_Interpolant):
    """The value of the nearest point (scipy.interpolate.NearestNDInterpolator's
    meaning): x ((n, ndim) points or a tuple of coordinate arrays), y ((n, ...) values),
    rescale as LinearNDInterpolator's. Distances are in double; of two equally near
    points, either may be chosen (as with scipy's k-d tree).

    Thread safety: immutable after construction; calls may run concurrently.
    """

    def __init__(self, x, y, rescale: bool = False, tree_options=None):
        self.scale = None
        pts = self.points = _points_array(x, "x")
        self.ndim = pts.shape[1]
        self._tree = _core.NearestTree(np.ascontiguousarray(self._rescale_from(pts) if rescale else pts))
        self._set_values(y, len(pts))

    def __call__(self, *args) -> np.ndarray:
        flat, shape = self._queries(args)
        return self._shaped(self.values[self._tree.query(flat)], shape)


def _triangulation(points_or_triangulation, threads=None) -> Delaunay:
    if isinstance(points_or_triangulation, Delaunay):
        return points_or_triangulation
    return Delaunay(_points_array(points_or_triangulation), threads=threads)


def _check_natural(tri: Delaunay) -> None:
    if tri.furthest_site or tri.weights is not None:
        raise ValueError("natural neighbours need the Delaunay triangulation (not furthest-site, not weighted)")
    if tri.ndim not in (2, 3):
        raise ValueError(f"natural neighbours: dimension {tri.ndim} is not supported (2-d and 3-d)")


def _natural(tri: Delaunay, flat: np.ndarray):
    """(ptr, neighbours as input indices, weights, where) for the rows of flat."""
    _check_natural(tri)
    ptr, ids, weights, where = tri._tri.natural_neighbors(np.ascontiguousarray(flat, dtype=np.float64))
    if tri._first is not None:
        ids = tri._kept[ids]
    return ptr, ids.astype(np.int64), weights, where


def natural_neighbor_coordinates(points_or_triangulation, xi):
    """Sibson's natural-neighbour coordinates of xi with respect to the points (an
    (n, ndim) array, ndim 2 or 3, or a spokemesh.Delaunay): for one point (shape
    (ndim,)) the pair (indices of its natural neighbours, ascending; their weights),
    for many (shape (m, ndim)) a list of such pairs. The weights are non-negative, sum
    to 1 and reproduce linear functions. A point outside the hull gets empty arrays; on
    the hull's boundary, its simplex's barycentric coordinates (the limit in 2-d); on a
    data point, that point with weight 1. Nothing is inserted into the triangulation."""
    tri = _triangulation(points_or_triangulation)
    q = np.asarray(xi, dtype=np.float64)
    one = q.ndim == 1
    flat = q.reshape(1, -1) if one else q
    if flat.ndim != 2 or flat.shape[1] != tri.ndim:
        raise ValueError(f"xi: expected shape ({tri.ndim},) or (m, {tri.ndim}), got {q.shape}")
    ptr, ids, weights, _ = _natural(tri, flat)
    pairs = [(ids[ptr[i]:ptr[i + 1]], weights[ptr[i]:ptr[i + 1]]) for i in range(len(flat))]
    return pairs[0] if one else pairs


class NaturalNeighborInterpolator(_Interpolant):
    """Sibson's natural-neighbour interpolation (C1 away from the data points, exact
    for linear functions): points ((n, ndim), ndim 2 or 3, a tuple of coordinate arrays,
    or a spokemesh.Delaunay), values ((n, ...), real or complex), fill_value outside the
    hull (default NaN), rescale as LinearNDInterpolator's. Called like
    LinearNDInterpolator. Beyond 3-d: ValueError (the split of a query's cell is
    written for 2-d and 3-d; use LinearNDInterpolator).

    Thread safety: immutable after construction; calls may run concurrently.
    """

    def __init__(self, points, values, fill_value=np.nan, rescale: bool = False, threads: Optional[int] = None):
        self._triangulate(points, rescale, threads)
        if self.ndim not in (2, 3):
            raise ValueError(f"points: dimension {self.ndim} is not supported (natural neighbours in 2-d and 3-d)")
        self._set_values(values, self.points.shape[0])
        self.fill_value = fill_value

    def __call__(self, *args) -> np.ndarray:
        flat, shape = self._queries(args)
        tri = self.tri
        _check_natural(tri)
        # The core applies the coordinates as it finds them (rows of the triangulated
        # points: equal points were merged into their first occurrence).
        rows = self.values if tri._first is None else self.values[tri._kept]
        if np.iscomplexobj(rows):  # the real and imaginary parts in turn
            fill = complex(self.fill_value)
            parts = [(rows.real, fill.real), (rows.imag, fill.imag)]
        else:
            parts = [(rows, self.fill_value)]
        q = np.ascontiguousarray(flat, dtype=np.float64)
        outs = [tri._tri.natural_interpolate(q, np.ascontiguousarray(part, dtype=np.float64), float(f))
                for part, f in parts]
        out = outs[0] if len(outs) == 1 else outs[0] + 1j * outs[1]
        return self._shaped(out, shape)


def griddata(points, values, xi, method: str = "linear", fill_value=np.nan, rescale: bool = False):
    """scipy.interpolate.griddata's meaning for method "linear" (LinearNDInterpolator),
    "nearest" (NearestNDInterpolator) and, beyond scipy, "natural" (Sibson's
    natural-neighbour interpolation, 2-d and 3-d): the values interpolated at xi (an
    (..., ndim) array or a tuple of coordinate arrays), shaped like xi's points. "cubic"
    (scipy's Clough-Tocher) raises ValueError."""
    if method == "linear":
        f = LinearNDInterpolator(points, values, fill_value=fill_value, rescale=rescale)
    elif method == "nearest":
        f = NearestNDInterpolator(points, values, rescale=rescale)
    elif method == "natural":
        f = NaturalNeighborInterpolator(points, values, fill_value=fill_value, rescale=rescale)
    else:
        raise ValueError(f"method: {method!r} is not available "
                         f"(spokemesh's griddata offers 'linear', 'nearest' and 'natural')")
    return f(xi)
