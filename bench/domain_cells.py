#!/usr/bin/python3
"""Voronoi cells in domains of any shape (docs/cells.md) against the same seeds' cells
clipped to the domain's bounding box (issue 44's target: at most 2x), one process each,
2 threads, wall time and peak RSS; then the tiling checks (volumes sum to the domain's,
wall facets to its boundary).

Shapes (about 100k faces each, seeds inside):
  torus      a torus of 400 x 128 quads (102,400 triangles), 1M uniform seeds
  cavity     a cube (2 x 2 per side) with a spherical cavity (a UV sphere of 102,400
             triangles), 1M seeds in clusters (Gaussian blobs) and uniform
  surface    the same torus, 1M seeds 1% to 3% of its minor radius inside its surface
             (cells that nearly all meet a wall: the worst case)
  grid       the cube with the cavity, seeds on a 100^3 numpy linspace grid over the
             cube (ties everywhere; those in the cavity get empty cells)
  holes      a 2-d disc (20,000 edges) with 50 round holes (1,600 edges each), 1M
             uniform seeds

Usage: bench/domain_cells.py [--n 1000000] [--only torus,holes] [--spokemesh build/bin/spokemesh]
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

import timing  # bench/timing.py

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests" / "python"))
import domain_files as df  # noqa: E402  (the suites' generators)


def torus_seeds(n, rng, near_surface=False, major=1.0, minor=0.4):
    out = []
    while sum(len(p) for p in out) < n:
        p = rng.uniform([-1.4, -1.4, -0.4], [1.4, 1.4, 0.4], size=(n, 3))
        r = np.hypot(np.hypot(p[:, 0], p[:, 1]) - major, p[:, 2])
        keep = (r < 0.99 * minor) & ((r > 0.97 * minor) if near_surface else True)
        out.append(p[keep])
    return np.concatenate(out)[:n]


def cavity_mesh():
    v, f = [], []
    # The cube [-1, 1]^3, two by two squares a side, outward.
    m = []
    for axis in range(3):
        for side in (0, 1):
            u, w = (axis + 1) % 3, (axis + 2) % 3
            ids = {}
            for i in range(3):
                for j in range(3):
                    p = [0.0, 0.0, 0.0]
                    p[axis] = 1.0 if side else -1.0
                    p[u], p[w] = -1 + i, -1 + j
                    ids[i, j] = len(v)
                    v.append(p)
            for i in range(2):
                for j in range(2):
                    a, b, c, d = ids[i, j], ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]
                    f += [(a, b, c), (a, c, d)] if side else [(a, d, c), (a, c, b)]
    rings, segs = 161, 320  # a UV sphere of radius 0.5: 2 * 320 * 160 = 102,400 triangles
    base = len(v)
    v.append([0, 0, -0.5])
    for i in range(1, rings):
        phi = np.pi * i / rings - np.pi / 2
        for j in range(segs):
            th = 2 * np.pi * j / segs
            v.append([0.5 * np.cos(phi) * np.cos(th), 0.5 * np.cos(phi) * np.sin(th), 0.5 * np.sin(phi)])
    north = len(v)
    v.append([0, 0, 0.5])
    at = lambda i, j: base + 1 + (i - 1) * segs + (j % segs)  # noqa: E731
    for j in range(segs):
        f.append((base, at(1, j + 1), at(1, j)))
    for i in range(1, rings - 1):
        for j in range(segs):
            f += [(at(i, j), at(i, j + 1), at(i + 1, j + 1)), (at(i, j), at(i + 1, j + 1), at(i + 1, j))]
    for j in range(segs):
        f.append((north, at(rings - 1, j), at(rings - 1, j + 1)))
    f = np.array(f)
    f[len(f) - 2 * segs * (rings - 1):] = f[len(f) - 2 * segs * (rings - 1):, ::-1]  # the cavity faces inward
    return np.array(v), f


def cavity_seeds(n, rng):
    out = []
    centres = rng.uniform(-0.9, 0.9, size=(40, 3))
    while sum(len(p) for p in out) < n:
        blob = centres[rng.integers(0, 40, n // 2)] + rng.normal(0, 0.05, (n // 2, 3))
        p = np.concatenate([blob, rng.uniform(-1, 1, (n // 2, 3))])
        keep = (np.abs(p) < 0.999).all(1) & (np.linalg.norm(p, axis=1) > 0.51)
        out.append(p[keep])
    return np.concatenate(out)[:n]


def holes_rings(rng):
    t = 2 * np.pi * np.arange(20000) / 20000
    rings = [np.stack([10 * np.cos(t), 10 * np.sin(t)], -1)]
    centres = []
    while len(centres) < 50:
        c = rng.uniform(-8, 8, 2)
        if np.linalg.norm(c) < 8.5 and all(np.linalg.norm(c - o) > 1.3 for o in centres):
            centres.append(c)
    s = 2 * np.pi * np.arange(1600) / 1600
    for c in centres:
        rings.append(np.stack([c[0] + 0.5 * np.cos(s), c[1] + 0.5 * np.sin(s)], -1))
    return rings, centres


def holes_seeds(n, rng, centres):
    out = []
    while sum(len(p) for p in out) < n:
        p = rng.uniform(-10, 10, size=(2 * n, 2))
        keep = np.linalg.norm(p, axis=1) < 9.99
        for c in centres:
            keep &= np.linalg.norm(p - c, axis=1) > 0.51
        out.append(p[keep])
    return np.concatenate(out)[:n]


def run(name, seeds, domain_path, volume, boundary, exe, work):
    pts = work / f"{name}.npy"
    np.save(pts, seeds)
    lo, hi = seeds.min(0), seeds.max(0)
    # The box: the domain's bounding box (holding the seeds).
    if domain_path.suffix == ".off":
        dv = np.loadtxt(domain_path, skiprows=2, max_rows=int(open(domain_path).readlines()[1].split()[0]))
        lo, hi = np.minimum(lo, dv.min(0)), np.maximum(hi, dv.max(0))
    else:
        lo, hi = np.minimum(lo, [-10, -10]), np.maximum(hi, [10, 10])
    box = ",".join(repr(float(x)) for x in [*lo, *hi])
    shaped, shaped_rss, _ = timing.process([exe, "cells", str(pts), "--domain", str(domain_path), "-o",
                                            str(work / f"{name}-domain.npz"), "--threads", "2", "-q"])
    boxed, boxed_rss, _ = timing.process([exe, "cells", str(pts), f"--box={box}", "-o", str(work / f"{name}-box.npz"),
                                          "--threads", "2", "-q"])
    z = np.load(work / f"{name}-domain.npz")
    walls = z["facet_neighbor"] < 0
    vol_err = abs(z["volume"].sum() - volume) / volume
    wall_err = abs(z["facet_area"][walls].sum() - boundary) / boundary
    print(f"| {name} | {len(seeds):,} | {shaped:.1f} s ({shaped_rss:.0f} MB) | {boxed:.1f} s ({boxed_rss:.0f} MB) | "
          f"**{shaped / boxed:.2f}x** | {vol_err:.1e} / {wall_err:.1e} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--only", default="torus,cavity,surface,grid,holes")
    ap.add_argument("--spokemesh", default=str(REPO / "build" / "bin" / "spokemesh"))
    a = ap.parse_args()
    rng = np.random.default_rng(44)
    print("| shape | seeds | `--domain` | `--box` (bounding box) | ratio | volume / wall sums, relative error |")
    print("| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        only = a.only.split(",")
        if "torus" in only or "surface" in only:
            v, f = df.torus(400, 128, 1.0, 0.4)
            df.write_off(work / "torus.off", v, f)
            vol, area = df.mesh_volume(v, f), df.mesh_area(v, f)
            if "torus" in only:
                run("torus", torus_seeds(a.n, rng), work / "torus.off", vol, area, a.spokemesh, work)
            if "surface" in only:
                run("surface", torus_seeds(a.n, rng, True), work / "torus.off", vol, area, a.spokemesh, work)
        if "cavity" in only or "grid" in only:
            v, f = cavity_mesh()
            df.write_off(work / "cavity.off", v, f)
            if "cavity" in only:
                run("cavity", cavity_seeds(a.n, rng), work / "cavity.off", df.mesh_volume(v, f), df.mesh_area(v, f),
                    a.spokemesh, work)
            if "grid" in only:
                side = round(a.n ** (1 / 3))
                axis = np.linspace(-0.995, 0.995, side)
                grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
                run("grid", grid, work / "cavity.off", df.mesh_volume(v, f), df.mesh_area(v, f), a.spokemesh, work)
        if "holes" in only:
            rings, centres = holes_rings(rng)
            df.write_rings(work / "holes.rings", rings)
            # Compensated sums: a plain one over 20,000 terms loses digits below 1e-12.
            area = sum((1 if k == 0 else -1) * abs(math.fsum(r[:, 0] * np.roll(r[:, 1], -1) -
                                                             r[:, 1] * np.roll(r[:, 0], -1))) / 2
                       for k, r in enumerate(rings))
            perimeter = sum(float(np.linalg.norm(r - np.roll(r, -1, axis=0), axis=1).sum()) for r in rings)
            run("holes", holes_seeds(a.n, rng, centres), work / "holes.rings", area, perimeter, a.spokemesh, work)


if __name__ == "__main__":
    main()
