#!/usr/bin/python3
"""Restarts replicas of the compose set under load (run by scripts/container-test.sh).

With docker/compose.yaml up (three spokemesh replicas sharing a volume, nginx in
front), several client threads ask for stars over REST and gRPC through nginx while
this script, in turn:
  1. stops replica 2 gracefully (SIGTERM: the server drains) and starts it again;
  2. kills replica 3 (SIGKILL: in-flight requests die with it) and starts it again.
With --sharded (docker/compose-sharded.yaml: 2 shards x 2 replicas, the set cut into
pieces), it kills one replica of each shard in turn and starts it again, while the
other replicas relay each seed to a live replica of its shard.
Each restarted replica comes back on a new address (the script checks that it did).
The test fails unless:
  * every request is answered, correctly: each star equals the one computed by the
    local CLI (build/bin/spokemesh, when built) and the one first received;
  * no request takes longer than MAX_SECONDS (a dead address costs nginx one short
    connect timeout and a retry, not seconds);
  * each restarted replica answers requests again (nginx's access log names the
    upstream address that answered), reading the set uploaded before its restart
    from the shared volume;
  * the replicas run as a non-root user.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "build" / "python"))

MAX_SECONDS = 2.0
SEEDS = 60


def podman(*args: str) -> str:
    return subprocess.run(["podman", *args], check=True, capture_output=True, text=True).stdout.strip()


def address_of(container: str) -> str:
    return podman("inspect", "-f", "{{range .NetworkSettings.Networks}}{{.IPAddress}} {{end}}", container).split()[0]


def http(method: str, url: str, body: bytes | None = None, timeout: float = 10):
    req = urllib.request.Request(url, data=body, method=method,
                                 headers={"Content-Type": "application/octet-stream"} if body else {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


class Load:
    """Client threads asking for stars through nginx; every answer is checked."""

    def __init__(self, rest: str, grpc_target: str | None, pid: str, expected: dict[int, list]):
        self.rest, self.grpc_target, self.pid, self.expected = rest, grpc_target, pid, expected
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.latencies: list[float] = []
        self.failures: list[str] = []

    def record(self, started: float, failure: str | None) -> None:
        with self.lock:
            self.latencies.append(time.perf_counter() - started)
            if failure:
                self.failures.append(failure)

    def rest_client(self, k: int) -> None:
        rng = random.Random(k)
        while not self.stop.is_set():
            seed = rng.randrange(SEEDS)
            started = time.perf_counter()
            try:
                status, body = http("GET", f"{self.rest}/v1/pointsets/{self.pid}/seeds/{seed}/star", timeout=30)
                got = json.loads(body)["simplices"] if status == 200 else None
                failure = None if got == self.expected[seed] else f"REST seed {seed}: {status} {body[:200]!r}"
            except Exception as e:  # noqa: BLE001 - any error is a failed request
                failure = f"REST seed {seed}: {type(e).__name__}: {e}"
            self.record(started, failure)

    def grpc_client(self, k: int) -> None:
        import spokemesh
        client = spokemesh.Client(self.grpc_target)
        rng = random.Random(100 + k)
        while not self.stop.is_set():
            seed = rng.randrange(SEEDS)
            started = time.perf_counter()
            try:
                got = client.star(self.pid, seed).simplices.tolist()
                failure = None if got == self.expected[seed] else f"gRPC seed {seed}: wrong star"
            except Exception as e:  # noqa: BLE001
                failure = f"gRPC seed {seed}: {type(e).__name__}: {e}"
            self.record(started, failure)

    def count(self) -> int:
        with self.lock:
            return len(self.latencies)


def answered_by(nginx: str, address: str, since: str) -> int:
    """Requests nginx's access log says `address` answered with 200 since `since`."""
    logs = subprocess.run(["podman", "logs", "--since", since, nginx], capture_output=True, text=True).stdout
    return sum(1 for line in logs.splitlines()
               if " 200 upstream=" in line and line.split("upstream=")[1].split()[0].split(",")[-1].strip()
               .startswith(address + ":"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--project", required=True)
    parser.add_argument("--grpc", required=True)
    parser.add_argument("--http", required=True)
    parser.add_argument("--workdir", default=str(REPO / "build-container"))
    parser.add_argument("--sharded", action="store_true", help="docker/compose-sharded.yaml's set")
    args = parser.parse_args()
    if args.sharded:
        replicas = [f"{args.project}_spokemesh-shard-{s}_{k}" for s in (0, 1) for k in (1, 2)]
        plan = [(replicas[1], "kill"), (replicas[2], "kill")]  # one replica of each shard
    else:
        replicas = [f"{args.project}_spokemesh_{k}" for k in (1, 2, 3)]
        plan = [(replicas[1], "stop"), (replicas[2], "kill")]
    nginx = f"{args.project}_nginx_1"

    deadline = time.time() + 120
    while True:
        try:
            if http("GET", f"{args.http}/healthz", timeout=2)[0] == 200:
                break
        except OSError:
            pass
        if time.time() > deadline:
            print("FAILED: the compose set did not answer /healthz through nginx within 120 s")
            return 1
        time.sleep(0.5)
    for r in replicas:
        uid = podman("exec", r, "id", "-u")
        assert uid != "0", f"{r} runs as root"

    points = np.random.default_rng(17).random((20000, 3))
    npy = Path(args.workdir) / "points.npy"
    np.save(npy, points)
    # Raw float64 over REST (the fast path), through nginx.
    status, body = http("POST", f"{args.http}/v1/pointsets?dimension=3", points.astype("<f8").tobytes(), timeout=60)
    assert status in (200, 201), (status, body)
    pid = json.loads(body)["id"]
    if args.sharded:
        pieces = podman("exec", replicas[0], "ls", f"/data/pieces/{pid}").split()
        assert "manifest" in pieces and len(pieces) > 4, f"the set was not cut into pieces: {pieces}"
        print(f"set {pid[:12]}...: {len(pieces) - 2} pieces on the shared volume")

    cli = REPO / "build" / "bin" / "spokemesh"
    expected: dict[int, list] = {}
    for seed in range(SEEDS):
        status, body = http("GET", f"{args.http}/v1/pointsets/{pid}/seeds/{seed}/star")
        assert status == 200, body
        expected[seed] = json.loads(body)["simplices"]
        if cli.exists():
            out = subprocess.run([str(cli), "star", str(npy), "--seed", str(seed)], check=True,
                                 capture_output=True, text=True).stdout
            local = [[int(v) for v in line.split()] for line in out.splitlines() if line.strip()]
            assert local == expected[seed], f"seed {seed}: the compose set and the local CLI disagree"
    print(f"set {pid[:12]}...: {SEEDS} stars agree with the local CLI" if cli.exists() else
          f"set {pid[:12]}...: {SEEDS} reference stars taken")

    grpc_target = args.grpc
    try:
        import spokemesh  # noqa: F401 - gRPC stubs from build/python
    except ImportError:
        grpc_target = None
        print("(gRPC stubs not built: REST load only)")
    load = Load(args.http, grpc_target, pid, expected)
    threads = [threading.Thread(target=load.rest_client, args=(k,)) for k in range(3)]
    if grpc_target:
        threads += [threading.Thread(target=load.grpc_client, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    failures = []
    try:
        time.sleep(5)
        for replica, how in plan:
            before = address_of(replica)
            served_before = load.count()
            if how == "stop":
                podman("stop", "-t", "30", replica)  # SIGTERM: drains, then exits
            else:
                podman("kill", "-s", "KILL", replica)
            time.sleep(3)  # load runs on the other two replicas meanwhile
            since = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            podman("start", replica)
            after = address_of(replica)
            print(f"{how} {replica}: {before} -> {after}; {load.count() - served_before} requests meanwhile")
            if after == before:
                failures.append(f"{replica} came back on its old address {before}: the test proves nothing")
            # The restarted replica must get traffic again (nginx re-resolves every 2 s).
            wait_until = time.time() + 30
            while time.time() < wait_until and answered_by(nginx, after, since) < 20:
                time.sleep(1)
            served = answered_by(nginx, after, since)
            print(f"  {replica} at {after} answered {served} requests after its restart")
            if served < 20:
                failures.append(f"{replica} at its new address {after} answered {served} requests in 30 s")
        time.sleep(5)
    finally:
        load.stop.set()
        for t in threads:
            t.join()
    lat = sorted(load.latencies)
    print(f"{len(lat)} requests through nginx: p50 {1e3 * lat[len(lat) // 2]:.1f} ms, "
          f"p99 {1e3 * lat[int(len(lat) * 0.99)]:.1f} ms, max {1e3 * lat[-1]:.0f} ms; "
          f"{len(load.failures)} failed")
    failures += load.failures[:10]
    slow = [t for t in lat if t > MAX_SECONDS]
    if slow:
        failures.append(f"{len(slow)} requests took longer than {MAX_SECONDS} s (slowest {max(slow):.2f} s)")
    for f in failures:
        print("FAILED:", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
