#!/usr/bin/python3
"""Clipped Voronoi cells against Voro++ (3-d) and scipy/Qhull (2-d), same points.

3-d: uniform points in the unit cube; `voro++ -c "%i %v %n %f" 0 1 0 1 0 1 FILE`
(Debian's voro++ 0.4.6, single-threaded) against `spokemesh cells P.npy -o C.npz
--box 0,0,0,1,1,1 --threads 2`: wall time and peak RSS of each process, then the
agreement of volumes, neighbour sets and facet areas.

2-d: uniform points in the unit square; scipy.spatial.Voronoi (Qhull) plus clipping
as users write it (the points mirrored across the four sides, so every original cell
is bounded and lies inside the square; areas by the shoelace formula) against
`spokemesh cells ... --box 0,0,1,1`.

3-d grid: numpy linspace(0, 1, side) on each axis (50^3 by default), the same two
commands in a cube 1e-6 larger than its bounding box (Voro++ leaves out particles on
its container's upper walls).

Usage: bench/cells.py [--n3 1000000] [--n2 1000000] [--grid3 50] [--spokemesh build/bin/spokemesh]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import timing  # bench/timing.py (the script's directory is on sys.path)

REPO = Path(__file__).resolve().parent.parent


def timed(cmd: list[str], cwd: str) -> tuple[float, float]:
    """(wall seconds, peak RSS MB) of a process, from GNU time."""
    wall, rss, _ = timing.process(cmd, cwd=cwd)
    return wall, rss


def bench_3d(n: int, exe: str, work: str) -> None:
    rng = np.random.default_rng(20261125)
    compare_3d(f"3-d uniform {n:,} in the unit cube", rng.random((n, 3)), exe, work)


def bench_grid_3d(side: int, exe: str, work: str) -> None:
    # As users make a grid: numpy's linspace on each axis, so the cube is its bounding
    # box and every Voronoi vertex is a tie (Voro++ decides ties by tolerance, we by
    # symbolic perturbation, which keeps zero-area facets).
    g = np.linspace(0, 1, side)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    # Voro++ leaves out particles on the container's upper walls, so both take a cube
    # 1e-6 larger than the grid's bounding box.
    compare_3d(f"3-d linspace grid {side}^3 in [0, 1 + 1e-6]^3", np.column_stack([x.ravel(), y.ravel(), z.ravel()]),
               exe, work, hi="1.000001")


def compare_3d(name: str, pts: np.ndarray, exe: str, work: str, hi: str = "1") -> None:
    n = len(pts)
    np.save(f"{work}/p3.npy", pts)
    with open(f"{work}/p3.txt", "w") as f:
        np.savetxt(f, np.column_stack([np.arange(n), pts]), fmt="%d %.17g %.17g %.17g")
    box = f"0,0,0,{hi},{hi},{hi}"
    ours_t, ours_rss = timed([exe, "cells", "p3.npy", "-o", "c3.npz", "--box", box, "--threads", "2", "-q"], work)
    voro_t, voro_rss = timed(["voro++", "-c", "%i %v %n %f", "0", hi, "0", hi, "0", hi, "p3.txt"], work)
    print(f"{name}: spokemesh {ours_t:.2f} s, {ours_rss:.0f} MB (2 threads); "
          f"Voro++ {voro_t:.2f} s, {voro_rss:.0f} MB (1 thread); ratio {ours_t / voro_t:.2f}x")
    z = np.load(f"{work}/c3.npz")
    vol = np.empty(n)
    neighbours = [None] * n
    areas = [None] * n
    with open(f"{work}/p3.txt.vol") as f:
        for line in f:
            fields = line.split()
            i = int(fields[0])
            vol[i] = float(fields[1])
            k = (len(fields) - 2) // 2
            neighbours[i] = [int(v) for v in fields[2:2 + k]]
            areas[i] = [float(v) for v in fields[2 + k:]]
    # Voro++ leaves out particles on the container's upper walls: compare the cells it
    # kept, and say how many it left out.
    kept = np.array([v is not None for v in neighbours])
    if not kept.all():
        print(f"  Voro++ left out {n - kept.sum():,} of {n:,} particles (on the upper walls); compared the rest")
    rel = np.abs(z["volume"][kept] - vol[kept]) / vol[kept]
    print(f"  volumes: total {z['volume'].sum():.15f} (ours) vs {vol[kept].sum():.15f} (Voro++); "
          f"relative difference median {np.median(rel):.1e}, max {rel.max():.1e}")
    same = extra = missing = 0
    extra_area = []
    ptr, nb, area = z["facet_ptr"], z["facet_neighbor"], z["facet_area"]
    for i in np.flatnonzero(kept):
        ours = {int(j) if j >= 0 else -1 - (-1 - int(j)) for j in nb[ptr[i]:ptr[i + 1]] if j >= 0}
        theirs = {j for j in neighbours[i] if j >= 0}
        if ours == theirs:
            same += 1
        else:
            for j in ours - theirs:
                extra += 1
                k = ptr[i] + list(nb[ptr[i]:ptr[i + 1]]).index(j)
                extra_area.append(area[k])
            missing += len(theirs - ours)
    print(f"  neighbour sets: {same:,} of {kept.sum():,} cells identical; {extra} facets only ours, {missing} only Voro++'s")
    if extra_area:
        print(f"  the facets only we report have areas up to {max(extra_area):.1e} (median {np.median(extra_area):.1e})")


def bench_2d(n: int, exe: str, work: str) -> None:
    from scipy.spatial import Voronoi
    rng = np.random.default_rng(20261126)
    pts = rng.random((n, 2))
    np.save(f"{work}/p2.npy", pts)
    ours_t, ours_rss = timed([exe, "cells", "p2.npy", "-o", "c2.npz", "--box", "0,0,1,1", "--threads", "2", "-q"], work)
    start = time.perf_counter()
    # As users write it: mirror the points across the four sides, so the original
    # cells are bounded and clipped by the mirror bisectors, then shoelace areas.
    mirrored = np.vstack([pts, pts * [-1, 1], pts * [1, -1], [2, 0] - pts * [1, -1], [0, 2] - pts * [-1, 1]])
    vor = Voronoi(mirrored)
    areas = np.empty(n)
    for i in range(n):
        poly = vor.vertices[vor.regions[vor.point_region[i]]]
        x, y = poly[:, 0], poly[:, 1]
        areas[i] = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
    scipy_t = time.perf_counter() - start
    z = np.load(f"{work}/c2.npz")
    rel = np.abs(z["volume"] - areas) / areas
    print(f"2-d uniform {n:,} in the unit square: spokemesh {ours_t:.2f} s, {ours_rss:.0f} MB (2 threads); "
          f"scipy Voronoi + mirror clipping {scipy_t:.2f} s (1 thread, in-process); ratio {ours_t / scipy_t:.2f}x")
    print(f"  areas: relative difference median {np.median(rel):.1e}, max {rel.max():.1e}; "
          f"totals {z['volume'].sum():.15f} vs {areas.sum():.15f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n3", type=int, default=1_000_000)
    ap.add_argument("--n2", type=int, default=1_000_000)
    ap.add_argument("--grid3", type=int, default=50, help="side of the 3-d linspace grid (0: none)")
    ap.add_argument("--spokemesh", default=str(REPO / "build/bin/spokemesh"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR", "/tmp")) as work:
        if args.n3:
            bench_3d(args.n3, args.spokemesh, work)
        if args.grid3:
            bench_grid_3d(args.grid3, args.spokemesh, work)
        if args.n2:
            bench_2d(args.n2, args.spokemesh, work)


if __name__ == "__main__":
    main()
