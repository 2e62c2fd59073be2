"""Domains of any shape as files, for the suites (docs/cells.md, "Domains of any
shape"): an L-shaped part, a torus and a cube with a cavity as .off/.obj/.stl, a
square with three holes as .rings and GeoJSON, and seeds inside them."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np


def l_part():
    """The L ([0,2]^2 minus [1,2]^2) times [0, 1]: (vertices, triangles), outward."""
    L = [(0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2), (0, 1)]
    v = [(x, y, 0.0) for x, y in L] + [(x, y, 1.0) for x, y in L]
    f = []
    for a, b, c, d in [(0, 1, 4, 7), (1, 2, 3, 4), (7, 4, 5, 6)]:
        f += [(8 + a, 8 + b, 8 + c), (8 + a, 8 + c, 8 + d), (a, d, c), (a, c, b)]
    for i in range(8):
        j = (i + 1) % 8
        f += [(i, j, 8 + j), (i, 8 + j, 8 + i)]
    return np.array(v, dtype=np.float64), np.array(f, dtype=np.int64)


def torus(nu=24, nv=12, major=1.0, minor=0.375):
    u = 2 * np.pi * np.arange(nu) / nu
    w = 2 * np.pi * np.arange(nv) / nv
    U, W = np.meshgrid(u, w, indexing="ij")
    v = np.stack([(major + minor * np.cos(W)) * np.cos(U), (major + minor * np.cos(W)) * np.sin(U),
                  minor * np.sin(W)], -1).reshape(-1, 3)
    at = lambda i, j: (i % nu) * nv + (j % nv)  # noqa: E731
    f = []
    for i in range(nu):
        for j in range(nv):
            f += [(at(i, j), at(i + 1, j), at(i + 1, j + 1)), (at(i, j), at(i + 1, j + 1), at(i, j + 1))]
    return v, np.array(f, dtype=np.int64)


def mesh_volume(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def mesh_area(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2)


def write_off(path: Path, v, f):
    with open(path, "w") as out:
        out.write(f"OFF\n{len(v)} {len(f)} 0\n")
        out.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in v)
        out.writelines(f"3 {a} {b} {c}\n" for a, b, c in f)


def write_obj(path: Path, v, f):
    with open(path, "w") as out:
        out.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in v)
        out.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)


def write_stl(path: Path, v, f, binary: bool):
    if binary:
        with open(path, "wb") as out:
            out.write(b"spokemesh test".ljust(80, b" "))
            out.write(struct.pack("<I", len(f)))
            for t in f:
                out.write(struct.pack("<12fH", 0, 0, 0, *v[t].ravel().tolist(), 0))
        return
    with open(path, "w") as out:
        out.write("solid part\n")
        for t in f:
            out.write("facet normal 0 0 0\nouter loop\n")
            out.writelines(f"vertex {x!r} {y!r} {z!r}\n" for x, y, z in v[t])
            out.write("endloop\nendfacet\n")
        out.write("endsolid part\n")


def three_holes():
    """Rings of a 10 x 10 square with three holes (mixed orientations), area and perimeter."""
    t = 2 * np.pi * np.arange(24) / 24
    circle = np.stack([5 + 1.5 * np.cos(-t), 7 + 1.5 * np.sin(-t)], -1)
    rings = [np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float),
             np.array([[1, 1], [1, 3], [3, 3], [3, 1]], float),
             np.array([[6, 1], [9, 1], [7.5, 4]], float), circle]
    def area(r):
        x, y = r[:, 0], r[:, 1]
        return abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))) / 2
    def perimeter(r):
        return float(np.linalg.norm(r - np.roll(r, -1, axis=0), axis=1).sum())
    return rings, area(rings[0]) - sum(area(r) for r in rings[1:]), sum(perimeter(r) for r in rings)


def write_rings(path: Path, rings):
    with open(path, "w") as out:
        out.write("# a square with three holes\n")
        out.write("\n\n".join("\n".join(f"{x!r} {y!r}" for x, y in r) for r in rings) + "\n")


def write_geojson(path: Path, rings, kind="Feature"):
    coords = [[[float(x), float(y)] for x, y in np.vstack([r, r[:1]])] for r in rings]
    polygon = {"type": "Polygon", "coordinates": coords}
    if kind == "Polygon":
        doc = polygon
    elif kind == "MultiPolygon":
        doc = {"type": "MultiPolygon", "coordinates": [coords]}
    else:
        doc = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, "geometry": polygon}]}
    path.write_text(json.dumps(doc))


def inside_torus(n, seed, major=1.0, minor=0.375):
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        p = rng.uniform([-1.4, -1.4, -0.4], [1.4, 1.4, 0.4], size=(4 * n, 3))
        q = np.hypot(p[:, 0], p[:, 1])
        out.extend(p[(q - major) ** 2 + p[:, 2] ** 2 < (0.9 * minor) ** 2])
    return np.array(out[:n])


def inside_l(n, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform([0, 0, 0], [2, 2, 1], size=(3 * n, 3))
    return p[~((p[:, 0] > 1) & (p[:, 1] > 1))][:n]
