#!/usr/bin/python3
"""Soak test: two spokemesh-server replicas sharing one data dir under mixed, partly
hostile load from several clients at once, for a while.

Load, per client thread, at random: uploads (gRPC and REST JSON), stars and cells (both
transports, either replica), whole-mesh streams (finished, cancelled mid-way, or with a
reader that stalls), deletes of the client's own sets, and bad inputs (NaN, malformed
JSON, unknown ids, out-of-range seeds). It fails if:
  * either server's RSS ever exceeds its --max-memory plus the stated allowance;
  * an acknowledged set is lost or changed (every set a client still owns is
    downloaded at the end and compared byte for byte);
  * a well-formed request gets a wrong answer (stars are compared across the replicas
    and transports; errors must be the expected ones);
  * a server dies.

  bench/soak.py [--minutes 30] [--short]    (--short: about 2 minutes, as CI runs it)

Run from the repository root after ./test.sh has built build/ (PYTHONPATH and the
binaries are found there). Prints RSS figures and request counts at the end.
"""

from __future__ import annotations

import argparse
import os
import random
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "build" / "python"))
sys.path.insert(0, str(REPO / "tests" / "python"))
os.environ.setdefault("SPOKEMESH_BIN_DIR", str(REPO / "build" / "bin"))

import grpc  # noqa: E402
import numpy as np  # noqa: E402
import spokemesh  # noqa: E402
from spokemesh.v1 import mesher_pb2 as pb  # noqa: E402
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc  # noqa: E402

from conftest import Server, http, http_json  # noqa: E402

BUDGET_MB = 256
ALLOWANCE_MB = 96  # the process's fixed cost and a tree build's transients


def rss_mb(pid: int, field: str = "VmRSS") -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return 0.0


def diagnose(server) -> str:
    """What the server says it holds, beside what the kernel says it uses."""
    status = {}
    for line in Path(f"/proc/{server.proc.pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        status[key] = value.strip()
    metrics = {}
    try:
        _, _, body = http("GET", f"{server.http}/metrics", timeout=5)
        for line in body.decode().splitlines():
            if line.startswith(("spokemesh_memory_budget", "spokemesh_store_", "spokemesh_heap_")):
                name, _, value = line.partition(" ")
                metrics[name] = float(value)
    except Exception as e:  # noqa: BLE001 - a diagnosis must not hide the failure
        return f"(metrics unavailable: {e})"
    mib = lambda v: f"{v / 2**20:.0f} MB"  # noqa: E731
    return (f"budget used {mib(metrics.get('spokemesh_memory_budget_used_bytes', 0))}, "
            f"store {mib(metrics.get('spokemesh_store_memory_bytes', 0))} in "
            f"{metrics.get('spokemesh_store_loaded_point_sets', 0):.0f} sets; "
            f"heap in use {mib(metrics.get('spokemesh_heap_in_use_bytes', 0))} of "
            f"{mib(metrics.get('spokemesh_heap_held_bytes', 0))} held; "
            f"RssAnon {status.get('RssAnon')}, RssFile {status.get('RssFile')}, threads {status.get('Threads')}")


class Soak:
    def __init__(self, servers, seconds: float, seed: int):
        self.servers, self.deadline = servers, time.time() + seconds
        self.rng = random.Random(seed)
        self.lock = threading.Lock()
        self.owned = {}  # id -> sha of the coordinates, sets a client uploaded and has not deleted
        self.counts = {}
        self.failures = []
        self.peak = {s.proc.pid: 0.0 for s in servers}

    def count(self, what: str) -> None:
        with self.lock:
            self.counts[what] = self.counts.get(what, 0) + 1

    def fail(self, what: str) -> None:
        with self.lock:
            self.failures.append(what)

    def pick(self):
        return self.rng.choice(self.servers)

    def some_set(self):
        with self.lock:
            return self.rng.choice(list(self.owned)) if self.owned else None

    def client(self, index: int) -> None:
        rng = random.Random(index)
        while time.time() < self.deadline and not self.failures:
            op = rng.choice(["upload", "upload", "star", "star", "cell", "stream", "cancel", "stall", "bad", "delete"])
            try:
                getattr(self, "op_" + op)(rng)
                self.count(op)
            except Exception as e:  # noqa: BLE001 - every unexpected error is a failure
                self.fail(f"{op}: {type(e).__name__}: {e}")

    def op_upload(self, rng):
        n, d = rng.choice([(2000, 2), (5000, 3), (20000, 3), (1500, 4)])
        points = np.random.default_rng(rng.randrange(1 << 30)).random((n, d))
        server = self.pick()
        if rng.random() < 0.5:
            try:
                pid = spokemesh.Client(server.grpc).upload(points).id
            except spokemesh.Error as e:
                if e.code != grpc.StatusCode.RESOURCE_EXHAUSTED:
                    raise
                return
        else:
            status, body = http_json("POST", f"{server.http}/v1/pointsets", {"points": points.tolist()})
            if status == 503:
                return  # over budget right now: allowed, retried later by the load itself
            assert status in (200, 201), body
            pid = body["id"]
        with self.lock:
            self.owned[pid] = points.tobytes()

    def op_star(self, rng):
        pid = self.some_set()
        if pid is None:
            return
        seed = rng.randrange(100)
        try:
            a = spokemesh.Client(self.servers[0].grpc).star(pid, seed).simplices
        except spokemesh.Error as e:  # deleted meanwhile, or over the budget right now
            if e.code not in (grpc.StatusCode.NOT_FOUND, grpc.StatusCode.RESOURCE_EXHAUSTED):
                raise
            return
        status, body = http_json("GET", f"{self.servers[1].http}/v1/pointsets/{pid}/seeds/{seed}/star")
        if status in (404, 503):
            return  # deleted meanwhile by another thread, or over the budget right now
        assert status == 200, body
        assert np.array_equal(a, np.array(body["simplices"])), f"replicas disagree on {pid} seed {seed}"

    def op_cell(self, rng):
        pid = self.some_set()
        if pid is None:
            return
        status, body = http_json("GET", f"{self.pick().http}/v1/pointsets/{pid}/seeds/{rng.randrange(50)}/cell")
        assert status in (200, 404, 503), body

    def op_stream(self, rng):
        pid = self.some_set()
        if pid is None:
            return
        status, _, body = http("GET", f"{self.pick().http}/v1/pointsets/{pid}/simplices?batch_size=4096", timeout=120)
        assert status in (200, 404, 503), body[:200]

    def op_cancel(self, rng):
        pid = self.some_set()
        if pid is None:
            return
        stub = pb_grpc.MesherStub(grpc.insecure_channel(self.pick().grpc))
        stream = stub.StreamSimplices(pb.StreamSimplicesRequest(point_set_id=pid, batch_size=64), timeout=60)
        try:
            next(stream)
        except grpc.RpcError as e:
            if e.code() not in (grpc.StatusCode.NOT_FOUND, grpc.StatusCode.RESOURCE_EXHAUSTED):
                raise
        stream.cancel()

    def op_stall(self, rng):
        pid = self.some_set()
        if pid is None:
            return
        host, port = self.pick().http.removeprefix("http://").split(":")
        with socket.create_connection((host, int(port)), timeout=30) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.sendall(f"GET /v1/pointsets/{pid}/simplices?batch_size=16 HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            time.sleep(rng.uniform(0.5, 3))

    def op_bad(self, rng):
        server = self.pick()
        kind = rng.randrange(4)
        if kind == 0:
            status, body = http_json("POST", f"{server.http}/v1/pointsets", b'{"points": [[0, 0], [1',
                                     {"Content-Type": "application/json"})
            assert status == 400 and "invalid JSON" in body["error"]["message"], body
        elif kind == 1:
            status, body = http_json("POST", f"{server.http}/v1/pointsets", {"points": [[0, 0], [1, 0], [0, "x"]]})
            assert status == 400 and "points[2][1]" in body["error"]["message"], body
        elif kind == 2:
            status, body = http_json("GET", f"{server.http}/v1/pointsets/{'0' * 64}/seeds/0/star")
            assert status == 404, body
        else:
            pid = self.some_set()
            if pid is not None:
                status, body = http_json("GET", f"{server.http}/v1/pointsets/{pid}/seeds/99999999/star")
                assert status in (400, 404), body

    def op_delete(self, rng):
        if rng.random() < 0.7:
            return  # deletes are rarer than uploads
        with self.lock:
            if len(self.owned) < 4:
                return
            pid = self.rng.choice(list(self.owned))
            del self.owned[pid]
        status, body = http_json("DELETE", f"{self.pick().http}/v1/pointsets/{pid}")
        # A duplicate upload of the same data by another thread may have deleted it first.
        assert status in (200, 404), body

    def watch(self):
        start = last_report = time.time()
        while time.time() < self.deadline + 5 and not self.failures:
            for s in self.servers:
                if s.proc.poll() is not None:
                    self.fail(f"server {s.proc.pid} exited with {s.proc.returncode}")
                    return
                mb = rss_mb(s.proc.pid)
                self.peak[s.proc.pid] = max(self.peak[s.proc.pid], mb)
                if mb > BUDGET_MB + ALLOWANCE_MB:
                    self.fail(f"server {s.proc.pid}: RSS {mb:.0f} MB over {BUDGET_MB} + {ALLOWANCE_MB} MB "
                              f"({diagnose(s)})")
            if time.time() - last_report >= 60:  # progress on long runs
                last_report = time.time()
                with self.lock:
                    done = sum(self.counts.values())
                for s in self.servers:
                    print(f"[{last_report - start:5.0f} s] {done} requests; server {s.proc.pid}: "
                          f"RSS {rss_mb(s.proc.pid):.0f} MB, {diagnose(s)}", flush=True)
            time.sleep(0.2)

    def verify(self):
        """Every set still owned is intact on both replicas."""
        for pid, raw in list(self.owned.items()):
            for s in self.servers:
                got = spokemesh.Client(s.grpc).download(pid)
                if got.tobytes() != raw:
                    self.fail(f"set {pid} changed or lost on {s.grpc}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=30)
    parser.add_argument("--short", action="store_true", help="about 2 minutes (CI)")
    parser.add_argument("--clients", type=int, default=6)
    args = parser.parse_args()
    seconds = 100 if args.short else args.minutes * 60
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        flags = ("--max-memory", f"{BUDGET_MB}M", "--http-write-timeout", "5s", "--upload-idle-timeout", "5s")
        servers = [Server(data, Path(tmp) / f"server{k}.log", *flags) for k in range(2)]
        soak = Soak(servers, seconds, seed=2026)
        threads = [threading.Thread(target=soak.client, args=(k,)) for k in range(args.clients)]
        watcher = threading.Thread(target=soak.watch)
        for t in threads + [watcher]:
            t.start()
        for t in threads + [watcher]:
            t.join()
        if not soak.failures:
            soak.verify()
        for s in servers:
            hwm = rss_mb(s.proc.pid, "VmHWM")
            print(f"server {s.grpc}: peak RSS {soak.peak[s.proc.pid]:.0f} MB sampled, {hwm:.0f} MB high-water "
                  f"(budget {BUDGET_MB} MB + allowance {ALLOWANCE_MB} MB)")
            s.stop()
        print(f"{seconds:.0f} s, {args.clients} clients: " + ", ".join(f"{k} {v}" for k, v in sorted(soak.counts.items())))
        print(f"sets owned at the end: {len(soak.owned)}, all intact on both replicas" if not soak.failures else "")
        for f in soak.failures[:20]:
            print("FAILED:", f)
        return 1 if soak.failures else 0


if __name__ == "__main__":
    sys.exit(main())
