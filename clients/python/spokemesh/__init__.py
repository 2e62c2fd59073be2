"""spokemesh: exact Delaunay triangulations and Voronoi cells, in-process or from a
spokemesh-server.

In-process (the compiled module spokemesh._core; no server, no gRPC):

    import numpy as np, spokemesh
    tri = spokemesh.Delaunay(np.random.default_rng(1).random((10_000, 3)))
    tri.simplices, tri.neighbors, tri.find_simplex(q), tri.cell(0, box=[0, 0, 0, 1, 1, 1])
    vor = spokemesh.Voronoi(points)   # scipy.spatial.Voronoi's attributes
    hull = spokemesh.ConvexHull(points)  # scipy.spatial.ConvexHull's attributes, exact
    sv = spokemesh.SphericalVoronoi(points_on_a_sphere)  # scipy's, from the exact hull
    f = spokemesh.interpolate.LinearNDInterpolator(points, values)  # and griddata
    g = spokemesh.approximate_graph(points_in_20d, misses=100)

Remote (spokemesh.remote.Client, also spokemesh.Client; needs python3-grpcio):

    client = spokemesh.Client("localhost:50051")
    ps = client.upload(points)
    star = client.star(ps.id, 0)

Errors: ValueError in-process; spokemesh.Error (with the gRPC status code) remotely.
"""

from __future__ import annotations

import importlib
from typing import Any

from .types import Cell, Facet

__all__ = ["Delaunay", "PeriodicDelaunay", "Voronoi", "ConvexHull", "QhullError", "SphericalVoronoi",
           "HalfspaceIntersection", "ApproximateGraph", "approximate_graph", "Cell", "Facet",
           "Client", "Error", "PointSet", "Star", "Neighbors", "Locations", "read_compact_batches"]

_REMOTE = {"Client", "Error", "PointSet", "Star", "Neighbors", "Locations", "read_compact_batches"}
_LOCAL = {"Delaunay", "PeriodicDelaunay", "ApproximateGraph", "approximate_graph"}


def __getattr__(name: str) -> Any:
    # Imported on first use: in-process users need not have gRPC, remote users need not
    # have the compiled module.
    if name == "Voronoi":
        return getattr(importlib.import_module(".voronoi", __name__), name)
    if name in ("ConvexHull", "QhullError"):
        return getattr(importlib.import_module(".hull", __name__), name)
    if name == "HalfspaceIntersection":
        return getattr(importlib.import_module(".halfspace", __name__), name)
    if name == "SphericalVoronoi":
        return getattr(importlib.import_module(".spherical", __name__), name)
    if name in _LOCAL:
        return getattr(importlib.import_module(".delaunay", __name__), name)
    if name in _REMOTE:
        return getattr(importlib.import_module(".remote", __name__), name)
    if name in ("remote", "delaunay", "voronoi", "hull", "spherical", "halfspace", "interpolate"):
        return importlib.import_module("." + name, __name__)
    raise AttributeError(f"module 'spokemesh' has no attribute {name!r}")
