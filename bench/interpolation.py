#!/usr/bin/python3
"""Values at any point (issue 53): spokemesh.interpolate against scipy.interpolate and
CGAL on the same files.

  1. natural-neighbour coordinates of 1M query points over 1M scattered terrain-like
     points: spokemesh (2 threads, the triangulation built first, untimed) against
     CGAL's natural_neighbor_coordinates_2 (build/bin/spokemesh_cgal_natural, one
     thread, each query located from the one before), on a 1000 x 1000 raster (row by
     row) and on random queries;
  2. gridding the same points onto a 1000 x 1000 raster, triangulation included:
     spokemesh's griddata linear and natural against scipy's griddata linear.

Usage: PYTHONPATH=build/python bench/interpolation.py [--points 1000000] [--side 1000]
Prints markdown tables (bench/README.md, "Values at any point").
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", Path(__file__).resolve().parent.parent / "build/bin"))


def terrain(n: int, seed: int = 53):
    """Scattered points over the unit square, denser in patches (as a survey's), with a
    height field of hills."""
    rng = np.random.default_rng(seed)
    dense = rng.random((n // 2, 2))
    centres = rng.random((40, 2))
    patch = centres[rng.integers(0, 40, n - n // 2)] + 0.03 * rng.standard_normal((n - n // 2, 2))
    xy = np.mod(np.concatenate([dense, patch]), 1.0)  # wrapped, not clipped: no runs of points on the edges
    xy = np.unique(xy, axis=0)
    z = np.sin(7 * xy[:, 0]) * np.cos(5 * xy[:, 1]) + 0.3 * xy[:, 0]
    return xy, z


def best(f, repeat=2):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--side", type=int, default=1000)
    args = ap.parse_args()
    import spokemesh
    import spokemesh.interpolate as si
    import scipy.interpolate as scipy_interpolate

    xy, z = terrain(args.points)
    side = args.side
    gx, gy = np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side))
    raster = np.c_[gx.ravel(), gy.ravel()]
    scattered = np.random.default_rng(54).random((side * side, 2))
    work = Path(tempfile.mkdtemp(prefix="spokemesh-interp-"))
    np.save(work / "points.npy", xy)
    np.save(work / "queries.npy", scattered)

    tri = spokemesh.Delaunay(xy)
    tri.find_simplex(raster[:1])  # the adjacency, once
    rows = []
    for label, queries, cgal_args in [("raster, row by row", raster, ["--raster", f"0,0,1,1,{side},{side}"]),
                                      ("random points", scattered, ["--queries", str(work / "queries.npy")])]:
        ours_s, (ptr, ids, weights, where) = best(lambda: tri._tri.natural_neighbors(queries))
        check = float((weights * xy[ids.astype(np.int64) if tri._first is None else tri._kept[ids], 0]).sum())
        cgal = json.loads(subprocess.run([str(BIN / "spokemesh_cgal_natural"), str(work / "points.npy"), *cgal_args],
                                         capture_output=True, text=True, check=True).stdout)
        assert abs(check - cgal["checksum"]) <= 1e-6 * abs(cgal["checksum"]), (label, check, cgal)
        rows.append(f"| {label}, {len(queries):,} queries | {ours_s:.2f} | {cgal['query_s']:.2f} "
                    f"| {ours_s / cgal['query_s']:.2f}x |")
    print(f"\n### Natural-neighbour coordinates, {len(xy):,} terrain points (triangulations built first)\n")
    print("| queries | spokemesh s (2 threads) | CGAL s (1 thread) | ratio |")
    print("|---|---:|---:|---:|")
    print("\n".join(rows))

    lin_s, ours_lin = best(lambda: si.griddata(xy, z, (gx, gy), method="linear"), 1)
    nat_s, ours_nat = best(lambda: si.griddata(xy, z, (gx, gy), method="natural"), 1)
    sci_s, theirs = best(lambda: scipy_interpolate.griddata(xy, z, (gx, gy), method="linear"), 1)
    same = np.nanmax(np.abs(ours_lin - theirs))
    print(f"\n### Gridding {len(xy):,} terrain points onto a {side} x {side} raster (triangulation included)\n")
    print("| method | seconds | against scipy's linear |")
    print("|---|---:|---:|")
    print(f"| scipy griddata linear | {sci_s:.2f} | 1.00x |")
    print(f"| spokemesh griddata linear | {lin_s:.2f} | {lin_s / sci_s:.2f}x (max difference {same:.1e}) |")
    print(f"| spokemesh griddata natural | {nat_s:.2f} | {nat_s / sci_s:.2f}x |")


if __name__ == "__main__":
    main()
