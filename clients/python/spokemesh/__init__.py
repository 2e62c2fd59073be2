"""spokemesh: a Python client for spokemesh-server (exact Delaunay/Voronoi meshing).

    import numpy as np, spokemesh
    client = spokemesh.Client("localhost:50051")
    ps = client.upload(np.random.default_rng(1).random((1000, 3)))
    star = client.star(ps.id, 0)            # Star(simplices (m, 4), circumcenters (m, 3), ...)
    tets = client.simplices(ps.id, shards=4)  # np.ndarray (m, 4), lexicographic

Errors raise spokemesh.Error, which carries the gRPC status code (``.code``).
Needs Debian's python3-grpcio, python3-protobuf and python3-numpy; the stubs
(spokemesh.v1.mesher_pb2*) are generated at build time into build/python.
"""

from .client import Cell, Client, Error, Neighbors, PointSet, Star

__all__ = ["Client", "Error", "PointSet", "Star", "Cell", "Neighbors"]
