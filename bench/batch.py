#!/usr/bin/python3
"""Many seeds in one call against one call per seed, over loopback: 10,000 seeds of a
3-d uniform 1M set, as BatchSeeds (gRPC) and REST neighbors:batch against 10,000
GetNeighbors / GetStar calls made one after another (what a loop in user code does).
Starts its own server (build/bin/spokemesh-server) on loopback.

Usage: PYTHONPATH=build/python bench/batch.py [--points 1000000] [--seeds 10000]
"""

from __future__ import annotations

import argparse
import json
import time
import urllib.request

import numpy as np
import spokemesh

from local_server import local_server  # bench/ (the script's directory is on sys.path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--seeds", type=int, default=10_000)
    args = ap.parse_args()
    with local_server("--max-points", "10000000") as (grpc_target, http_target):
        client = spokemesh.Client(grpc_target)
        ps = client.upload(np.random.default_rng(1).random((args.points, 3)))
        seeds = [int(s) for s in np.random.default_rng(2).integers(0, args.points, args.seeds)]
        client.neighbors(ps.id, 0)  # warm the set
        rows = []
        for kind in ("neighbors", "stars"):
            t = time.perf_counter()
            many = client.batch_neighbors(ps.id, seeds) if kind == "neighbors" else client.batch_stars(ps.id, seeds)
            batch = time.perf_counter() - t
            t = time.perf_counter()
            for s in seeds:
                client.neighbors(ps.id, s) if kind == "neighbors" else client.star(ps.id, s)
            single = time.perf_counter() - t
            rows.append((f"gRPC {kind}", batch, single))
            assert len(many) == len(seeds)
        body = json.dumps({"seeds": seeds}).encode()
        t = time.perf_counter()
        req = urllib.request.Request(f"http://{http_target}/v1/pointsets/{ps.id}/neighbors:batch", data=body,
                                     headers={"Content-Type": "application/json"}, method="POST")
        with urllib.request.urlopen(req, timeout=600) as r:
            lines = r.read().decode().splitlines()
        batch = time.perf_counter() - t
        assert len(lines) == len(seeds)
        t = time.perf_counter()
        for s in seeds:
            with urllib.request.urlopen(f"http://{http_target}/v1/pointsets/{ps.id}/seeds/{s}/neighbors", timeout=60) as r:
                r.read()
        single = time.perf_counter() - t
        rows.append(("REST neighbors", batch, single))
        print(f"{args.seeds:,} seeds of a 3-d uniform {args.points:,} set, loopback, server with 2 threads:")
        print("| call | one batch | one call per seed | throughput ratio |")
        print("| --- | ---: | ---: | ---: |")
        for name, b, s in rows:
            print(f"| {name} | {b:.2f} s ({args.seeds / b:,.0f}/s) | {s:.2f} s ({args.seeds / s:,.0f}/s) | **{s / b:.1f}x** |")


if __name__ == "__main__":
    main()
