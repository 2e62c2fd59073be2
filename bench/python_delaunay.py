#!/usr/bin/python3
"""spokemesh.Delaunay (in-process, 2 threads) against scipy.spatial.Delaunay (Qhull,
one thread) on the same uniform points: construction time, then the simplices and
their neighbours (scipy computes both while it builds; spokemesh builds neighbours on
first use, counted here). Default sizes: 100k/100k/20k/5k/2k points for d = 2..6.

Usage: PYTHONPATH=build/python bench/python_delaunay.py [--repeat 3] [--sizes 2:1000000,3:300000]
"""

from __future__ import annotations

import argparse

import numpy as np
import spokemesh
from timing import best
from scipy.spatial import Delaunay as ScipyDelaunay

SIZES = {2: 100_000, 3: 100_000, 4: 20_000, 5: 5_000, 6: 2_000}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sizes", default=None, help="d:n,... (default: 100k/100k/20k/5k/2k for d = 2..6)")
    args = ap.parse_args()
    sizes = SIZES if args.sizes is None else {int(a): int(b) for a, b in (x.split(":") for x in args.sizes.split(","))}
    print("| d | points | spokemesh.Delaunay | scipy.spatial.Delaunay | ratio | simplices (same set) |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for d, n in sizes.items():
        points = np.random.default_rng(100 + d).random((n, d))

        def ours():
            tri = spokemesh.Delaunay(points, threads=args.threads)
            tri.neighbors
            return tri

        t_ours, tri = best(ours, args.repeat)
        t_scipy, ref = best(lambda: ScipyDelaunay(points), args.repeat)
        same = set(map(tuple, np.sort(tri.simplices, axis=1).tolist())) == \
            set(map(tuple, np.sort(ref.simplices, axis=1).tolist()))
        print(f"| {d} | {n:,} | {t_ours:.3f} s | {t_scipy:.3f} s | {t_ours / t_scipy:.2f}x | "
              f"{tri.nsimplex:,} ({'yes' if same else 'NO'}) |", flush=True)


if __name__ == "__main__":
    main()
