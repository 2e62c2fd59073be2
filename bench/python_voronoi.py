#!/usr/bin/python3
"""spokemesh.Voronoi (in-process, 2 threads) against scipy.spatial.Voronoi (Qhull, one
thread) on the same uniform points (2-d 1M and 3-d 300k). Timed: the
constructor and reading vertices, regions, point_region, ridge_points and
ridge_vertices (scipy builds all of them in its constructor; spokemesh makes the
Python lists on first use, counted here). Checked: the same numbers of vertices and
ridges and the same ridge point pairs.

Usage: PYTHONPATH=build/python bench/python_voronoi.py [--repeat 2] [--sizes 2:1000000,3:300000]
"""

from __future__ import annotations

import argparse

import numpy as np
import spokemesh
from inputs import KINDS, points as make_points
from timing import best
from scipy.spatial import Voronoi as ScipyVoronoi


def read_all(vor):
    return vor.vertices, vor.regions, vor.point_region, vor.ridge_points, vor.ridge_vertices


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sizes", default="2:1000000,3:300000")
    ap.add_argument("--points", choices=KINDS, default="uniform", help="how the points are made (bench/inputs.py)")
    args = ap.parse_args()
    print("| d | points | spokemesh.Voronoi | scipy.spatial.Voronoi | ratio | vertices, ridges (same pairs) |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for item in args.sizes.split(","):
        d, n = (int(v) for v in item.split(":"))
        points = make_points(args.points, n, d, 200 + d)
        n = len(points)

        def ours():
            vor = spokemesh.Voronoi(points, threads=args.threads)
            read_all(vor)
            return vor

        def theirs():
            vor = ScipyVoronoi(points)
            read_all(vor)
            return vor

        t_ours, mine = best(ours, args.repeat)
        t_scipy, ref = best(theirs, args.repeat)
        pairs = np.sort(ref.ridge_points, axis=1)
        pairs = pairs[np.lexsort(pairs.T[::-1])]
        same = len(mine.vertices) == len(ref.vertices) and np.array_equal(mine.ridge_points, pairs)
        print(f"| {d} | {n:,} | {t_ours:.2f} s | {t_scipy:.2f} s | {t_scipy / t_ours:.1f}x faster | "
              f"{len(mine.vertices):,}, {len(mine.ridge_points):,} ({'yes' if same else 'NO'}) |", flush=True)


if __name__ == "__main__":
    main()
