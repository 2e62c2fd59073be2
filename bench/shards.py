#!/usr/bin/python3
"""Sharded serving against one replica holding the whole set (docs/service.md,
"Sharded serving"; issue 43's targets), real processes on loopback:

  1. a 3-d uniform set (default 20M points) stored as pieces by `mpirun -np 2
     spokemesh-mpi store` (time and peak memory printed);
  2. one whole-set replica answers the stars of --seeds random seeds over REST; then
     --shards shard replicas (one each) answer the same seeds, each sent to a replica at
     random (as a front door spreads them); resident memory (VmRSS) of each afterwards;
  3. --check random seeds plus 200 hull seeds: REST star, REST clipped cell and gRPC
     GetStar from a random shard replica against the whole replica's bytes;
  4. --latency single REST GETs on keep-alive of seeds of shard 0's pieces: straight to
     shard 0's replica, and through shard 1's (relayed): p50 and p99;
  5. the whole mesh streamed (gRPC) from a shard replica against `spokemesh mesh`
     (--no-stream skips it).

Usage: PYTHONPATH=build/python bench/shards.py [--points 20000000] [--shards 4]
        [--seeds 100000] [--check 10000] [--latency 10000] [--piece-points 2097152]
        [--work /tmp/spokemesh-shards]
"""
from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import re
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
BIN = REPO / "build" / "bin"


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, data: Path, log: Path, *flags: str):
        self.grpc_port, self.http_port = free_port(), free_port()
        self.start(data, log, *flags)

    def start(self, data: Path, log: Path, *flags: str) -> None:
        self.log = open(log, "wb")
        self.proc = subprocess.Popen(
            [str(BIN / "spokemesh-server"), "--data-dir", str(data), "--grpc-listen", f"127.0.0.1:{self.grpc_port}",
             "--http-listen", f"127.0.0.1:{self.http_port}", "--threads", "2", "--max-memory", "16G",
             "--max-points", "1000000000", *flags], stderr=self.log)
        for _ in range(6000):
            if "serving gRPC" in log.read_text(errors="replace"):
                return
            if self.proc.poll() is not None:
                raise RuntimeError(log.read_text()[-2000:])
            time.sleep(0.05)
        raise RuntimeError("spokemesh-server did not start")

    def rss(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        return 0

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(60)


class Rest:
    def __init__(self, port: int):
        self.conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)

    def get(self, path: str) -> tuple[int, bytes]:
        self.conn.request("GET", path)
        r = self.conn.getresponse()
        return r.status, r.read()


def ask_stars(ports: list[int], set_id: str, seeds: list[int], threads: int = 4) -> float:
    """Every seed's star over REST, each to a port at random; seconds taken."""
    def worker(part: list[int], k: int) -> None:
        rng = random.Random(k)
        conns = [Rest(p) for p in ports]
        for s in part:
            status, body = conns[rng.randrange(len(conns))].get(f"/v1/pointsets/{set_id}/seeds/{s}/star")
            assert status == 200, body[:300]
    t = time.perf_counter()
    pool = [threading.Thread(target=worker, args=(seeds[k::threads], k)) for k in range(threads)]
    for th in pool:
        th.start()
    for th in pool:
        th.join()
    return time.perf_counter() - t


def percentile(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=20_000_000)
    ap.add_argument("--shards", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=100_000)
    ap.add_argument("--check", type=int, default=10_000)
    ap.add_argument("--latency", type=int, default=10_000)
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--piece-points", type=int, default=2_097_152)
    ap.add_argument("--work", default="/tmp/spokemesh-shards")
    ap.add_argument("--no-stream", action="store_true")
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    src = work / f"uniform-3d-{args.points}.npy"
    if not src.exists():
        np.save(src, np.random.default_rng(43).random((args.points, 3)))
    data = work / f"data-{args.points}"
    pieces_root = data / "pieces"
    if not pieces_root.exists() or not any(pieces_root.iterdir()):
        shutil.rmtree(data, ignore_errors=True)
        data.mkdir()
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                   OMPI_MCA_btl_vader_single_copy_mechanism="none")
        t = time.perf_counter()
        done = subprocess.run(["mpirun", "--oversubscribe", "-np", str(args.ranks), str(BIN / "spokemesh-mpi"),
                               "store", str(src), "--data-dir", str(data), "--piece-points", str(args.piece_points), "--stats", str(work / "store-stats.json")],
                              capture_output=True, text=True, env=env)
        assert done.returncode == 0, done.stderr
        stats = json.loads((work / "store-stats.json").read_text())
        peak = max(r["peak_rss_bytes"] for r in stats["ranks"])
        print(f"store: {time.perf_counter() - t:.1f} s on {args.ranks} ranks, peak {peak / 2**20:.0f} MB a rank")
        print("  " + done.stderr.strip().splitlines()[-1])
    set_id = next(p.name for p in pieces_root.iterdir() if not p.name.startswith("."))
    manifest = (pieces_root / set_id / "manifest").read_text().splitlines()
    pieces = int(next(line.split()[1] for line in manifest if line.startswith("pieces ")))
    owners = np.memmap(pieces_root / set_id / "owners", dtype="<u4", mode="r")
    n = args.points
    on_disk = sum(f.stat().st_size for f in (pieces_root / set_id).iterdir())
    print(f"set {set_id[:12]}...: {n} points, {pieces} pieces, {on_disk / 2**20:.0f} MB of pieces on disk")

    rng = random.Random(7)
    seeds = [rng.randrange(n) for _ in range(args.seeds)]
    rows = []

    # Whole-set replica.
    whole = Server(data, work / "whole.log")
    try:
        t = time.perf_counter()
        assert Rest(whole.http_port).get(f"/v1/pointsets/{set_id}/seeds/0/star")[0] == 200
        print(f"whole replica: first star (set loaded, tree built) {time.perf_counter() - t:.1f} s")
        secs = ask_stars([whole.http_port], set_id, seeds)
        whole_rss = whole.rss()
        print(f"whole replica: {args.seeds} stars in {secs:.1f} s ({args.seeds / secs:.0f}/s); RSS {whole_rss / 2**20:.0f} MB")

        # Hull seeds: near the box's boundary, kept when their star has hull facets.
        pts = np.load(src, mmap_mode="r")
        depth = np.minimum(np.asarray(pts).min(axis=1), (1 - np.asarray(pts)).min(axis=1))
        candidates = np.argsort(depth)[:5000]
        hull_seeds = []
        probe = Rest(whole.http_port)
        for s in candidates:
            if json.loads(probe.get(f"/v1/pointsets/{set_id}/seeds/{int(s)}/star")[1])["hull_facets"] > 0:
                hull_seeds.append(int(s))
            if len(hull_seeds) == 200:
                break
        del pts, depth

        # Shard replicas.
        ports = [(free_port(), free_port()) for _ in range(args.shards)]
        rest_list = ";".join(f"127.0.0.1:{h}" for _, h in ports)
        grpc_list = ";".join(f"127.0.0.1:{g}" for g, _ in ports)
        shards = []
        for k in range(args.shards):
            s = Server.__new__(Server)
            s.grpc_port, s.http_port = ports[k]
            s.start(data, work / f"shard{k}.log", "--shard", f"{k}/{args.shards}", "--shard-http", rest_list,
                    "--shard-grpc", grpc_list)
            shards.append(s)
        try:
            t = time.perf_counter()
            for k in range(args.shards):
                # One seed of each shard first: its pieces' first loads.
                first = next(s for s in seeds if owners[s] * args.shards // pieces == k)
                assert Rest(shards[k].http_port).get(f"/v1/pointsets/{set_id}/seeds/{first}/star")[0] == 200
            print(f"shards: a first seed each {time.perf_counter() - t:.1f} s")
            secs = ask_stars([s.http_port for s in shards], set_id, seeds)
            rss = [s.rss() for s in shards]
            print(f"{args.shards} shard replicas: {args.seeds} stars in {secs:.1f} s ({args.seeds / secs:.0f}/s); "
                  f"RSS " + ", ".join(f"{r / 2**20:.0f}" for r in rss) + " MB")
            ratio = max(rss) / whole_rss
            rows.append(("largest shard replica's RSS / whole replica's", f"{ratio:.3f}", "<= 0.35",
                         "met" if ratio <= 0.35 else "not met"))

            # Byte identity.
            import grpc
            from spokemesh.v1 import mesher_pb2 as pb
            from spokemesh.v1 import mesher_pb2_grpc as pb_grpc
            whole_rest = Rest(whole.http_port)
            shard_rest = [Rest(s.http_port) for s in shards]
            whole_stub = pb_grpc.MesherStub(grpc.insecure_channel(f"127.0.0.1:{whole.grpc_port}"))
            stubs = [pb_grpc.MesherStub(grpc.insecure_channel(f"127.0.0.1:{s.grpc_port}")) for s in shards]
            check = [rng.randrange(n) for _ in range(args.check)] + hull_seeds
            differ = 0
            for s in check:
                at = rng.randrange(len(shards))
                for route in ("star", "cell?bounding_box=true"):
                    path = f"/v1/pointsets/{set_id}/seeds/{s}/{route}"
                    differ += shard_rest[at].get(path) != whole_rest.get(path)
                req = pb.SeedRequest(point_set_id=set_id, seed=s)
                differ += (stubs[at].GetStar(req, timeout=600).SerializeToString() !=
                           whole_stub.GetStar(req, timeout=600).SerializeToString())
            rows.append((f"answers differing from the whole replica's ({args.check} random + {len(hull_seeds)} hull "
                         "seeds; REST star, REST clipped cell, gRPC star)", str(differ), "0",
                         "met" if differ == 0 else "not met"))

            # Latency: shard 0's seeds straight and relayed through shard 1.
            mine = [s for s in (rng.randrange(n) for _ in range(20 * args.latency))
                    if owners[s] * args.shards // pieces == 0][:args.latency]
            lat = {}
            for name, port in (("direct", shards[0].http_port), ("relayed", shards[1].http_port)):
                conn = Rest(port)
                for s in mine[:200]:
                    conn.get(f"/v1/pointsets/{set_id}/seeds/{s}/star")  # warm
                times = []
                for s in mine:
                    t = time.perf_counter()
                    status, _ = conn.get(f"/v1/pointsets/{set_id}/seeds/{s}/star")
                    times.append(time.perf_counter() - t)
                    assert status == 200
                lat[name] = (percentile(times, 0.5), percentile(times, 0.99))
                print(f"{name}: p50 {lat[name][0] * 1e3:.3f} ms, p99 {lat[name][1] * 1e3:.3f} ms")
            for i, q in ((0, "p50"), (1, "p99")):
                r = lat["relayed"][i] / lat["direct"][i]
                rows.append((f"relayed / direct REST latency, {q}", f"{r:.2f}", "<= 1.5", "met" if r <= 1.5 else "not met"))

            if not args.no_stream:
                import spokemesh
                mesh = work / f"mesh-{n}.npy"
                if not mesh.exists():
                    t = time.perf_counter()
                    subprocess.run([str(BIN / "spokemesh"), "mesh", str(src), "-o", str(mesh), "-q"], check=True)
                    print(f"spokemesh mesh: {time.perf_counter() - t:.1f} s")
                expected = np.load(mesh, mmap_mode="r")
                t = time.perf_counter()
                got = spokemesh.Client(f"127.0.0.1:{shards[0].grpc_port}", timeout=3600).simplices(set_id, shards=2)
                print(f"stream from shard replica 0: {len(got)} simplices in {time.perf_counter() - t:.1f} s")
                same = got.shape == expected.shape and all(
                    np.array_equal(got[i:i + 10_000_000], expected[i:i + 10_000_000])
                    for i in range(0, len(got), 10_000_000))
                rows.append(("whole-mesh stream from a shard replica = spokemesh mesh", "yes" if same else "no",
                             "yes", "met" if same else "not met"))
        finally:
            for s in shards:
                s.stop()
    finally:
        whole.stop()
    print("\n| measure | value | target | |\n| --- | --- | --- | --- |")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
