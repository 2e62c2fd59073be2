#!/usr/bin/python3
"""Load benchmark for spokemesh-server: N concurrent clients call GetStar on random
seeds for a fixed number of calls; prints throughput and p50/p99 latency.

    bench/load.py [--points 100000] [--dimension 3] [--calls 4000] [--concurrency 1,4,16]

Starts its own server (build/bin/spokemesh-server) on loopback with a temporary data
dir unless --server HOST:PORT is given. Needs Debian's python3-grpcio/numpy and the
stubs in build/python (PYTHONPATH is set up below)."""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "build" / "python"))

import numpy as np  # noqa: E402
import spokemesh  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--dimension", type=int, default=3)
    ap.add_argument("--calls", type=int, default=4000)
    ap.add_argument("--concurrency", default="1,4,16")
    ap.add_argument("--server", help="HOST:PORT of a running server (default: start one)")
    args = ap.parse_args()

    proc = None
    target = args.server
    if target is None:
        data = tempfile.mkdtemp(prefix="spokemesh-load-")
        log = open(os.path.join(data, "server.log"), "wb")
        proc = subprocess.Popen([str(REPO / "build/bin/spokemesh-server"), "--data-dir", data, "--grpc-listen",
                                 "127.0.0.1:0", "--http-listen", "127.0.0.1:0"], stderr=log)
        for _ in range(500):
            m = re.search(r"serving gRPC on ([\d.]+:\d+)", Path(data, "server.log").read_text())
            if m:
                target = m.group(1)
                break
            time.sleep(0.02)
    try:
        client = spokemesh.Client(target)
        points = np.random.default_rng(1).random((args.points, args.dimension))
        t = time.perf_counter()
        ps = client.upload(points)
        print(f"upload of {args.points} {args.dimension}-d points: {time.perf_counter() - t:.2f} s ({ps.id[:12]}...)")
        rng = np.random.default_rng(2)
        print(f"{'clients':>8} {'calls':>7} {'calls/s':>9} {'p50 ms':>8} {'p99 ms':>8}")
        for concurrency in [int(c) for c in args.concurrency.split(",")]:
            seeds = rng.integers(0, args.points, args.calls)

            def one(seed):
                start = time.perf_counter()
                client.star(ps.id, int(seed))
                return time.perf_counter() - start

            t = time.perf_counter()
            with concurrent.futures.ThreadPoolExecutor(max_workers=concurrency) as pool:
                latencies = np.array(list(pool.map(one, seeds)))
            wall = time.perf_counter() - t
            p50, p99 = np.percentile(latencies, [50, 99]) * 1e3
            print(f"{concurrency:>8} {args.calls:>7} {args.calls / wall:>9.0f} {p50:>8.2f} {p99:>8.2f}")
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait()


if __name__ == "__main__":
    main()
