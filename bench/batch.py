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
import os
import re
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import spokemesh

REPO = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--seeds", type=int, default=10_000)
    args = ap.parse_args()
    data = tempfile.mkdtemp(prefix="spokemesh-batch-")
    log = open(os.path.join(data, "server.log"), "wb")
    proc = subprocess.Popen([str(REPO / "build/bin/spokemesh-server"), "--data-dir", data, "--grpc-listen",
                             "127.0.0.1:0", "--http-listen", "127.0.0.1:0", "--max-points", "10000000"], stderr=log)
    grpc_target = http_target = None
    for _ in range(500):
        text = Path(data, "server.log").read_text()
        g, h = re.search(r"serving gRPC on ([\d.]+:\d+)", text), re.search(r"HTTP on ([\d.]+:\d+)", text)
        if g and h:
            grpc_target, http_target = g.group(1), h.group(1)
            break
        time.sleep(0.02)
    try:
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
    finally:
        proc.terminate()
        proc.wait(timeout=60)


if __name__ == "__main__":
    main()
