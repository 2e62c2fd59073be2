#!/usr/bin/python3
"""Incremental insertion: a 3-d set triangulated with its last 1%, 10% or
50% added afterwards (add_points), against triangulating everything at once, and
against scipy's incremental Qhull (--scipy). Every spokemesh result is checked to be
the whole set's triangulation, the same simplices in the same order.

    PYTHONPATH=build/python /usr/bin/python3 bench/incremental.py [--n 1000000] [--scipy]
        [--fractions 0.01,0.10,0.50] [--runs 1]
"""
import argparse

import numpy as np

import spokemesh
from inputs import KINDS, points as make_points
from timing import timed


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--scipy", action="store_true", help="also scipy.spatial.Delaunay(incremental=True)")
    ap.add_argument("--fractions", default="0.01,0.10,0.50", help="shares of the points added (comma-separated)")
    ap.add_argument("--runs", type=int, default=1, help="times each share is measured (each a fresh pair)")
    ap.add_argument("--points", choices=KINDS, default="uniform", help="how the points are made (bench/inputs.py)")
    a = ap.parse_args()
    pts = make_points(a.points, a.n, 3, 7)
    # (shuffled: a grid's last points would otherwise be one face of it)
    pts = pts[np.random.default_rng(8).permutation(len(pts))] if a.points == "grid" else pts
    print(f"3-d {a.points} {len(pts):,} points, {a.threads} threads")
    for frac in [float(f) for f in a.fractions.split(",") for _ in range(a.runs)]:
        k = int(len(pts) * (1 - frac))
        tri = spokemesh.Delaunay(pts[:k], incremental=True, threads=a.threads)
        _, t_add = timed(lambda: tri.add_points(pts[k:]))
        whole, t_whole = timed(lambda: spokemesh.Delaunay(pts, threads=a.threads))
        assert np.array_equal(tri.simplices, whole.simplices), "incremental != whole"
        line = (f"add {frac:4.0%}: spokemesh add_points {t_add:6.2f} s ({tri._tri.stars_computed:,} stars), "
                f"whole {t_whole:6.2f} s, ratio {t_add / t_whole:.3f}")
        if a.scipy:
            from scipy.spatial import Delaunay as ScipyDelaunay
            ref = ScipyDelaunay(pts[:k], incremental=True)
            _, t_sadd = timed(lambda: ref.add_points(pts[k:]))
            _, t_swhole = timed(lambda: ScipyDelaunay(pts))
            line += f"; scipy add_points {t_sadd:6.2f} s, whole {t_swhole:6.2f} s"
        print(line, flush=True)


if __name__ == "__main__":
    main()
