#!/usr/bin/python3
"""Per-seed cost on the shapes users bring: the stars of 10,000 random seeds
in one gRPC BatchSeeds call, on each shape family (bench/shapes.py) and on uniform
points of the same count and dimension, against a server of this build on loopback
(tree warm: one call first). Prints microseconds per seed of the first batch call (a
closed surface's builds the triangulation of every point, which the set then keeps)
and the best of the later ones, and the ratios to uniform.

Usage: PYTHONPATH=build/python bench/batch_shapes.py [--seeds 10000] [--only NAME] [--scale 1.0]
  --scale multiplies each family's default size (0.1: quick look)
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import spokemesh

import shapes  # bench/ (the script's directory is on sys.path)
from local_server import local_server


def per_seed(client, points: np.ndarray, seeds: list[int], repeat: int) -> tuple[float, float]:
    """Microseconds per seed of the first batch call and the best of `repeat` later ones
    (a closed surface's first batch builds the triangulation the set then keeps)."""
    ps = client.upload(points)
    client.star(ps.id, 0)  # loads the set and its tree
    times = []
    for _ in range(1 + repeat):
        t = time.perf_counter()
        stars = client.batch_stars(ps.id, seeds)
        times.append(time.perf_counter() - t)
        assert len(stars) == len(seeds)
    client.delete(ps.id)
    return times[0] / len(seeds) * 1e6, min(times[1:]) / len(seeds) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10_000)
    ap.add_argument("--only", default="")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    names = [f for f in shapes.FAMILIES if f not in ("uniform2", "uniform3", "clustered3", "grid3")]
    print(f"{args.seeds:,} random seeds in one BatchSeeds call (stars), loopback, server with 2 threads:")
    print("| family | points | us per seed, first call | later calls | uniform, same n (later) | ratio (later) | ratio (first) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    with local_server("--max-points", "10000000") as (grpc_target, _):
        client = spokemesh.Client(grpc_target)
        for name in names:
            if args.only and args.only not in name:
                continue
            _, _, default_n = shapes.FAMILIES[name]
            points = shapes.make(name, max(1000, int(default_n * args.scale)))
            n, d = points.shape
            seeds = [int(s) for s in np.random.default_rng(2).integers(0, n, args.seeds)]
            first, later = per_seed(client, points, seeds, args.repeat)
            u_first, u_later = per_seed(client, np.random.default_rng(3).random((n, d)), seeds, args.repeat)
            print(f"| {name} | {n:,} | {first:.1f} | {later:.1f} | {u_later:.1f} | {later / u_later:.2f}x | "
                  f"{first / u_first:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
