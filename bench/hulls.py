#!/usr/bin/python3
"""spokemesh.ConvexHull against scipy.spatial.ConvexHull (Qhull) on the same points:
seconds (best of --repeat runs in one process, the points made once) and peak memory
above the points (each tool in its own process), facet counts checked equal where the
hull is unique (no four points on one plane).

Usage: PYTHONPATH=build/python bench/hulls.py [--only NAME] [--repeat 3] [--others-only]
Prints a markdown table (bench/README.md, "Convex hulls").
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

# name -> (points maker, whether the facets are unique: general position)
def _uniform(n, d, seed):
    return np.random.default_rng(seed).random((n, d))


def _ball(n, seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 3))
    return x / np.linalg.norm(x, axis=1)[:, None] * rng.random((n, 1)) ** (1 / 3)


def _sphere(n, seed):
    x = np.random.default_rng(seed).standard_normal((n, 3))
    return x / np.linalg.norm(x, axis=1)[:, None]


def _clusters(n, seed):
    rng = np.random.default_rng(seed)
    centres = rng.random((20, 3)) * 10
    return centres[rng.integers(0, 20, n)] + rng.standard_normal((n, 3)) * 0.3


def _grid(k):
    axis = np.arange(k, dtype=float)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


CASES = {
    "uniform-3d-1M": (lambda: _uniform(1_000_000, 3, 1), True),
    "uniform-3d-10M": (lambda: _uniform(10_000_000, 3, 2), True),
    "ball-3d-1M": (lambda: _ball(1_000_000, 3), True),
    "clusters-3d-1M": (lambda: _clusters(1_000_000, 4), True),
    "sphere-surface-3d-100k": (lambda: _sphere(100_000, 5), True),
    "grid-3d-100^3": (lambda: _grid(100), False),
    "uniform-2d-1M": (lambda: _uniform(1_000_000, 2, 6), True),
    "uniform-4d-100k": (lambda: _uniform(100_000, 4, 7), True),
}


def _tangent_halfspaces(n, d, seed):
    u = np.random.default_rng(seed).standard_normal((n, d))
    u /= np.linalg.norm(u, axis=1)[:, None]
    return np.c_[u, -np.ones(n)]


# SphericalVoronoi (with sorted regions and areas) and HalfspaceIntersection cases.
OTHER = {
    "spherical-voronoi-100k": lambda: _sphere(100_000, 11),
    "spherical-voronoi-1M": lambda: _sphere(1_000_000, 12),
    "spherical-voronoi-10M": lambda: _sphere(10_000_000, 16),
    "halfspaces-3d-100k": lambda: _tangent_halfspaces(100_000, 3, 13),
    "halfspaces-3d-1M-random-offsets": lambda: np.c_[_tangent_halfspaces(1_000_000, 3, 14)[:, :3],
                                                      -1 - np.random.default_rng(15).random(1_000_000)],
}


def run_other(tool: str, name: str, repeat: int) -> dict:
    data = OTHER[name]()
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    import spokemesh
    import scipy.spatial
    mod = spokemesh if tool == "spokemesh" else scipy.spatial
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        if name.startswith("spherical"):
            # 10M random points on the unit sphere have pairs nearer than scipy's default
            # duplicate threshold (1e-6): both tools are given a smaller one.
            sv = mod.SphericalVoronoi(data, threshold=1e-6 if len(data) < 5_000_000 else 1e-9)
            sv.sort_vertices_of_regions()
            total = float(sv.calculate_areas().sum())
            count = len(sv.vertices)
        else:
            hs = mod.HalfspaceIntersection(data, np.zeros(3))
            total = float(hs.dual_volume)
            count = len(hs.intersections)
        best = min(best, time.perf_counter() - t)
    peak = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
    return {"seconds": best, "count": count, "peak_mb": peak, "total": total}


def run_one(tool: str, name: str, repeat: int) -> dict:
    if name in OTHER:
        return run_other(tool, name, repeat)
    points = CASES[name][0]()
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if tool == "spokemesh":
        import spokemesh
        make = spokemesh.ConvexHull
    else:
        import scipy.spatial
        make = lambda p: scipy.spatial.ConvexHull(p, qhull_options="Qt" if not CASES[name][1] else None)  # noqa: E731
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        hull = make(points)
        _ = hull.volume, hull.area, hull.equations
        best = min(best, time.perf_counter() - t)
    peak = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
    return {"seconds": best, "facets": len(hull.simplices), "vertices": len(hull.vertices), "peak_mb": peak,
            "volume": float(hull.volume)}


def both(name: str, repeat: int) -> tuple[dict, dict]:
    """spokemesh's and scipy's run of one case, each in its own process."""
    out = {}
    for tool in ("spokemesh", "scipy"):
        proc = subprocess.run([sys.executable, __file__, "--repeat", str(repeat), "--child", tool, name],
                              capture_output=True, text=True, check=True)
        out[tool] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out["spokemesh"], out["scipy"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--others-only", action="store_true", help="only the SphericalVoronoi and halfspace rows")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(run_one(args.child[0], args.child[1], args.repeat)))
        return
    print("| points | spokemesh s | scipy (Qhull) s | speed-up | spokemesh MB | scipy MB | facets | vertices |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, (_, unique) in CASES.items():
        if args.only and args.only not in name or args.others_only:
            continue
        ours, theirs = both(name, args.repeat)
        if unique:
            assert ours["facets"] == theirs["facets"], (name, ours, theirs)
        assert abs(ours["volume"] - theirs["volume"]) <= 1e-9 * abs(theirs["volume"]), (name, ours, theirs)
        facets = f"{ours['facets']:,}" if ours["facets"] == theirs["facets"] else f"{ours['facets']:,} ({theirs['facets']:,})"
        print(f"| {name} | {ours['seconds']:.3f} | {theirs['seconds']:.3f} | {theirs['seconds'] / ours['seconds']:.1f}x "
              f"| {ours['peak_mb']:.0f} | {theirs['peak_mb']:.0f} | {facets} | {ours['vertices']:,} |", flush=True)
    print("\n| SphericalVoronoi (sorted regions, areas) / HalfspaceIntersection | spokemesh s | scipy s | speed-up "
          "| spokemesh MB | scipy MB | vertices |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name in OTHER:
        if args.only and args.only not in name:
            continue
        ours, theirs = both(name, args.repeat)
        assert abs(ours["total"] - theirs["total"]) <= 1e-9 * abs(theirs["total"]), (name, ours, theirs)
        count = f"{ours['count']:,}" if ours["count"] == theirs["count"] else f"{ours['count']:,} ({theirs['count']:,})"
        print(f"| {name} | {ours['seconds']:.3f} | {theirs['seconds']:.3f} | {theirs['seconds'] / ours['seconds']:.1f}x "
              f"| {ours['peak_mb']:.0f} | {theirs['peak_mb']:.0f} | {count} |", flush=True)


if __name__ == "__main__":
    main()
