#!/usr/bin/python3
"""Answers at any point over the service against stars of seeds: 10,000 query points
in one :interpolate / Interpolate call (natural, linear, nearest; values kept with
PutValues) and one :locate / Locate call, beside 10,000 seeds in one stars:batch /
BatchSeeds call, on the same set (uniform 1M in 2-d and 3-d, and a terrain-like 2-d
scan). Each figure: the median of --repeat calls after one warm call (which builds the
set's arrays). Starts its own server (build/bin/spokemesh-server) on loopback.

Usage: PYTHONPATH=build/python bench/points_service.py [--points 1000000] [--queries 10000]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import urllib.request

import numpy as np
import spokemesh

from local_server import local_server  # bench/ (the script's directory is on sys.path)


def timed(fn, repeat: int) -> float:
    fn()  # warm
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def rest(http_target: str, path: str, body: dict) -> int:
    req = urllib.request.Request(f"http://{http_target}{path}", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(req, timeout=600) as r:
        return len(r.read().splitlines())


def terrain(n: int, rng) -> np.ndarray:
    """Scan lines: rows of points along y with jitter (a LiDAR swath's shape)."""
    rows = int(np.sqrt(n / 8))
    per = n // rows
    y = np.repeat(np.arange(rows) / rows, per) + rng.normal(0, 1e-4, rows * per)
    x = np.tile(np.arange(per) / per, rows) + rng.normal(0, 1e-5, rows * per)
    return np.stack([x, y], axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--queries", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    sets = [("uniform 2-d", rng.random((args.points, 2))), ("scan lines 2-d", terrain(args.points, rng)),
            ("uniform 3-d", rng.random((args.points, 3)))]
    print(f"{'set':16} {'call (10k)':28} {'median s':>9} {'x stars:batch':>14}")
    with local_server("--max-points", "10000000") as (grpc_target, http_target):
        client = spokemesh.Client(grpc_target)
        for name, points in sets:
            ps = client.upload(points)
            values = np.sin(7 * points[:, 0]) + points[:, 1]
            values_id = client.put_values(ps.id, values)
            lo, hi = points.min(0), points.max(0)
            xi = lo + rng.random((args.queries, points.shape[1])) * (hi - lo)
            seeds = [int(s) for s in rng.integers(0, len(points), args.queries)]
            base = f"/v1/pointsets/{ps.id}"
            stars_grpc = timed(lambda: client.batch_stars(ps.id, seeds), args.repeat)
            stars_rest = timed(lambda: rest(http_target, base + "/stars:batch", {"seeds": seeds}), args.repeat)
            rows = [("gRPC BatchSeeds stars", stars_grpc, stars_grpc),
                    ("REST stars:batch", stars_rest, stars_rest)]
            for method in ("natural", "linear", "nearest"):
                t = timed(lambda: client.interpolate(ps.id, xi, values_id=values_id, method=method), args.repeat)
                rows.append((f"gRPC Interpolate {method}", t, stars_grpc))
                body = {"queries": xi.tolist(), "values_id": values_id, "method": method}
                t = timed(lambda: rest(http_target, base + ":interpolate", body), args.repeat)
                rows.append((f"REST :interpolate {method}", t, stars_rest))
            t = timed(lambda: client.locate(ps.id, xi), args.repeat)
            rows.append(("gRPC Locate", t, stars_grpc))
            t = timed(lambda: rest(http_target, base + ":locate", {"queries": xi.tolist()}), args.repeat)
            rows.append(("REST :locate", t, stars_rest))
            for call, t, ref in rows:
                print(f"{name:16} {call:28} {t:9.3f} {t / ref:14.2f}", flush=True)


if __name__ == "__main__":
    main()
