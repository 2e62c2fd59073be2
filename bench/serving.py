#!/usr/bin/python3
"""Serving at the speed of the wire (issue 52): spokemesh-server beside Debian's nginx on
the same client, real processes on loopback.

  1. rates (Apache's `ab -k`, 20,000 requests, 1 and 16 connections): nginx serving a
     3.4 KB static file; spokemesh `GET /healthz`; `GET .../seeds/S/star` of a 3-d
     uniform set (default 1M points) once its triangulation is kept;
  2. latencies from one keep-alive connection (bench/serving_client.cpp): REST healthz
     and star, gRPC GetPointSet and GetStar, beside a bare gRPC server's constant answer
     (gRPC's floor here, as nginx is REST's): p50 and p99;
  3. batches: `stars:batch` of 1,000 and 10,000 random seeds over REST (JSON, and the
     compact .npy form when the server offers it) and gRPC BatchSeeds: microseconds a
     seed, and the batch's throughput against single requests' on one connection;
  4. sharded (--shards 2 or more; default 2): replicas of each shard over one data
     directory holding the set as pieces; a seed of shard 0 asked of shard 0's replica
     directly, through shard 1's (the REST relay), and through nginx proxying to shard
     0's replica (the best relay at hand, for comparison): p50 and p99;
  5. resident memory (VmRSS) of each server after its runs.

Usage: PYTHONPATH=build/python bench/serving.py [--points 1000000] [--sections rates,latency,batch,sharded]
        [--requests 20000] [--work /tmp/spokemesh-serving]
Prints a markdown table per section (bench/README.md, "Serving at the speed of the wire").
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
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build/bin"))
CLIENT = BIN / "spokemesh_serving_client"

NGINX_CONF = """
{user}
worker_processes auto;
pid {dir}/nginx.pid;
error_log {dir}/error.log warn;
events {{ worker_connections 1024; }}
http {{
  access_log off;
  sendfile on;
  keepalive_requests 1000000;
  client_body_temp_path {dir}/body;
  proxy_temp_path {dir}/proxy;
  fastcgi_temp_path {dir}/fastcgi;
  uwsgi_temp_path {dir}/uwsgi;
  scgi_temp_path {dir}/scgi;
  server {{
    listen 127.0.0.1:{port};
    root {dir}/www;
  }}
{proxy}}}
"""

# nginx as a reverse proxy to one replica, kept-alive upstream connections: the relay a
# sharded replica's REST relay is compared with.
NGINX_PROXY = """  upstream spokemesh {{ server {upstream}; keepalive 32; }}
  server {{
    listen 127.0.0.1:{port};
    location / {{ proxy_pass http://spokemesh; proxy_http_version 1.1; proxy_set_header Connection ""; }}
  }}
"""


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def vm_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


class Server:
    """spokemesh-server of this build on free ports; `extra` flags appended."""

    def __init__(self, data: Path, name: str, *extra: str, ports: tuple[int, int] | None = None,
                 wait: bool = True):
        self.grpc_port, self.http_port = ports or (free_port(), free_port())
        self.log = data.parent / f"{name}.log"
        self.proc = subprocess.Popen(
            [str(BIN / "spokemesh-server"), "--data-dir", str(data), "--grpc-listen", f"127.0.0.1:{self.grpc_port}",
             "--http-listen", f"127.0.0.1:{self.http_port}", *extra], stderr=open(self.log, "wb"))
        self.http = f"127.0.0.1:{self.http_port}"
        self.grpc = f"127.0.0.1:{self.grpc_port}"
        if wait:
            self.wait()

    def wait(self):
        """Returns once /healthz answers (raises if the server exits first)."""
        for _ in range(1500):
            try:
                if request(self.http, "GET", "/healthz")[0] == 200:
                    return
            except OSError:
                pass
            if self.proc.poll() is not None:
                raise RuntimeError(f"spokemesh-server exited: {self.log.read_text()[-2000:]}")
            time.sleep(0.02)
        raise RuntimeError("spokemesh-server did not start")

    def stop(self):
        self.proc.terminate()
        self.proc.wait(timeout=60)


def request(address: str, method: str, target: str, body: bytes = b"", headers=None, timeout=600):
    host, port = address.rsplit(":", 1)
    conn = http.client.HTTPConnection(host, int(port), timeout=timeout)
    conn.request(method, target, body=body, headers=headers or {})
    r = conn.getresponse()
    data = r.read()
    conn.close()
    return r.status, data


def upload(address: str, points: np.ndarray) -> str:
    status, body = request(address, "POST", f"/v1/pointsets?dimension={points.shape[1]}", points.tobytes(),
                           {"Content-Type": "application/octet-stream"})
    if status not in (200, 201):
        raise RuntimeError(f"upload: {status} {body[:300]!r}")
    return json.loads(body)["id"]


def wait_kept(server: Server, set_id: str, seconds: float = 300):
    """Asks one star (which asks for the set's triangulation to be kept), then waits until
    the server's memory stops growing: the triangulation is built in the background."""
    request(server.http, "GET", f"/v1/pointsets/{set_id}/seeds/0/star")
    last, steady, deadline = 0.0, 0, time.time() + seconds
    while time.time() < deadline and steady < 6:
        time.sleep(0.5)
        now = vm_rss_mb(server.proc.pid)
        steady = steady + 1 if abs(now - last) < 1 else 0
        last = now


def ab(url: str, requests: int, connections: int) -> float:
    out = subprocess.run(["ab", "-k", "-q", "-n", str(requests), "-c", str(connections), url], capture_output=True,
                         text=True, check=True).stdout
    failed = int(re.search(r"Failed requests:\s+(\d+)", out).group(1))
    non2xx = re.search(r"Non-2xx responses:\s+(\d+)", out)
    if failed or non2xx:
        raise RuntimeError(f"ab {url}: {failed} failed, {non2xx.group(1) if non2xx else 0} non-2xx")
    return float(re.search(r"Requests per second:\s+([\d.]+)", out).group(1))


def client(*args: str) -> dict:
    out = subprocess.run([str(CLIENT), *args], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"spokemesh_serving_client {' '.join(args)}: {out.stderr[-500:]}")
    return json.loads(out.stdout)


def targets_file(work: Path, name: str, lines: list[str]) -> str:
    path = work / f"{name}.targets"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def start_nginx(work: Path, proxy_to: str = "") -> tuple[subprocess.Popen, int]:
    """nginx serving a static file on its port; with proxy_to (HOST:PORT), a second port
    relaying every request there instead (that port is returned)."""
    ndir = work / ("nginx-proxy" if proxy_to else "nginx")
    (ndir / "www").mkdir(parents=True, exist_ok=True)
    # A 3.4 KB static file, as the measurement.
    (ndir / "www" / "static.html").write_bytes(b"<!doctype html>" + b"x" * (3400 - 15))
    port = free_port()
    proxy_port = free_port()
    proxy = NGINX_PROXY.format(upstream=proxy_to, port=proxy_port) if proxy_to else ""
    (ndir / "nginx.conf").write_text(NGINX_CONF.format(user="user root;" if os.geteuid() == 0 else "", dir=ndir,
                                                       port=port, proxy=proxy))
    proc = subprocess.Popen(["nginx", "-p", str(ndir), "-c", str(ndir / "nginx.conf"), "-g", "daemon off;"],
                            stderr=open(ndir / "stderr.log", "wb"))
    for _ in range(200):
        try:
            if request(f"127.0.0.1:{port}", "GET", "/static.html")[0] == 200:
                return proc, proxy_port if proxy_to else port
        except OSError:
            time.sleep(0.05)
    raise RuntimeError("nginx did not start: " + (ndir / "stderr.log").read_text())


def table(title: str, header: list[str], rows: list[list[str]]):
    print(f"\n### {title}\n")
    print("| " + " | ".join(header) + " |")
    print("| " + " | ".join(["---"] + ["---:"] * (len(header) - 1)) + " |")
    for row in rows:
        print("| " + " | ".join(row) + " |")
    sys.stdout.flush()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--sections", default="rates,latency,batch,sharded")
    ap.add_argument("--requests", type=int, default=20000)
    ap.add_argument("--shards", type=int, default=2)
    ap.add_argument("--work", default="")
    args = ap.parse_args()
    sections = set(args.sections.split(","))
    for tool in ("ab", "nginx"):
        if shutil.which(tool) is None:
            sys.exit(f"{tool} is missing: scripts/install-deps.sh installs it (apache2-utils, nginx)")
    if not CLIENT.exists():
        sys.exit(f"{CLIENT} is missing: cmake --build build --target spokemesh_serving_client")
    work = Path(args.work or tempfile.mkdtemp(prefix="spokemesh-serving-"))
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    rng = np.random.default_rng(52)
    points = rng.random((args.points, 3))
    n = args.points
    seeds = [int(s) for s in random.Random(52).sample(range(n), 2000)]
    data = work / "data"
    data.mkdir()
    server = Server(data, "whole")
    set_id = upload(server.http, points)
    wait_kept(server, set_id)
    star_targets = [f"/v1/pointsets/{set_id}/seeds/{s}/star" for s in seeds]
    results = {}
    try:
        if "rates" in sections:
            nginx, nginx_port = start_nginx(work)
            try:
                rows = []
                for label, url in [("nginx, a 3.4 KB static file", f"http://127.0.0.1:{nginx_port}/static.html"),
                                   ("spokemesh `GET /healthz`", f"http://{server.http}/healthz"),
                                   (f"spokemesh `GET .../seeds/{seeds[0]}/star`, 3-d uniform {n:,}, kept",
                                    f"http://{server.http}{star_targets[0]}")]:
                    one = ab(url, args.requests, 1)
                    sixteen = ab(url, args.requests, 16)
                    results[label] = (one, sixteen)
                    rows.append([label, f"{one:,.0f} req/s", f"{sixteen:,.0f} req/s"])
                table("Rates (ab -k, " + f"{args.requests:,} requests)", ["request", "1 connection", "16 connections"],
                      rows)
            finally:
                nginx.terminate()
                nginx.wait()
        if "latency" in sections:
            rows = []
            h = client("http", server.http, targets_file(work, "healthz", ["/healthz"]), "--requests",
                       str(args.requests))
            rows.append(["REST `GET /healthz`", f"{h['p50_us']:.0f}", f"{h['p99_us']:.0f}", f"{1e6 / h['mean_us']:,.0f}"])
            s = client("http", server.http, targets_file(work, "stars", star_targets), "--requests", str(args.requests))
            rows.append(["REST `GET .../star` (random seeds)", f"{s['p50_us']:.0f}", f"{s['p99_us']:.0f}",
                         f"{1e6 / s['mean_us']:,.0f}"])
            # gRPC's floor on this machine: a bare synchronous server answering a constant
            # (the serving client's grpc-floor-server), as nginx is REST's.
            floor_port = free_port()
            floor = subprocess.Popen([str(CLIENT), "grpc-floor-server", f"127.0.0.1:{floor_port}"])
            try:
                time.sleep(0.5)
                f = client("grpc-meta", f"127.0.0.1:{floor_port}", set_id, "--requests", str(args.requests))
            finally:
                floor.terminate()
                floor.wait()
            rows.append(["gRPC floor: a bare gRPC server's constant `GetPointSet`", f"{f['p50_us']:.0f}",
                         f"{f['p99_us']:.0f}", f"{1e6 / f['mean_us']:,.0f}"])
            m = client("grpc-meta", server.grpc, set_id, "--requests", str(args.requests))
            rows.append(["gRPC `GetPointSet`", f"{m['p50_us']:.0f}", f"{m['p99_us']:.0f}",
                         f"{1e6 / m['mean_us']:,.0f}"])
            g = client("grpc", server.grpc, set_id, "--seeds", str(n), "--requests", str(args.requests))
            rows.append(["gRPC `GetStar` (random seeds)", f"{g['p50_us']:.0f}", f"{g['p99_us']:.0f}",
                         f"{1e6 / g['mean_us']:,.0f}"])
            results["single_star_us"] = s["mean_us"]
            table("Latency, one keep-alive connection (bench/serving_client.cpp)",
                  ["request", "p50 us", "p99 us", "req/s"], rows)
        if "batch" in sections:
            rows = []
            single = results.get("single_star_us")
            for size in (1000, 10000):
                body = work / f"batch{size}.json"
                picked = [int(s) for s in np.random.default_rng(size).integers(0, n, size)]
                body.write_text(json.dumps({"seeds": picked}))
                target = targets_file(work, "batch", [f"/v1/pointsets/{set_id}/stars:batch"])
                b = client("http", server.http, target, "--post", str(body), "--requests", "5")
                per = b["p50_us"] / size
                ratio = f"{single / per:.1f}x" if single else "-"
                rows.append([f"REST `stars:batch`, {size:,} seeds (JSON)", f"{per:.1f}",
                             f"{b['bytes'] / b['requests'] / size:,.0f}", ratio])
                p = client("http", server.http, target, "--post", str(body), "--requests", "5", "--accept",
                           "application/x-protobuf")
                pper = p["p50_us"] / size
                rows.append([f"REST `stars:batch`, {size:,} seeds (compact: Accept application/x-protobuf)",
                             f"{pper:.1f}", f"{p['bytes'] / p['requests'] / size:,.0f}",
                             f"{single / pper:.1f}x" if single else "-"])
                g = client("grpc-batch", server.grpc, set_id, "--seeds", str(n), "--batch", str(size), "--requests",
                           "5")
                gper = g["p50_us"] / size
                rows.append([f"gRPC `BatchSeeds`, {size:,} seeds", f"{gper:.1f}",
                             f"{g['bytes'] / g['requests'] / size:,.0f}", f"{single / gper:.1f}x" if single else "-"])
            table("Batches (p50 of 5 calls, one connection)",
                  ["request", "us a seed", "bytes a seed", "throughput vs single REST stars"], rows)
        rss_whole = vm_rss_mb(server.proc.pid)
    finally:
        server.stop()
    if "sharded" in sections:
        shards = args.shards
        sdata = work / "sharded-data"
        sdata.mkdir()
        ports = [(free_port(), free_port()) for _ in range(shards)]
        http_peers = ";".join(f"127.0.0.1:{h}" for _, h in ports)
        grpc_peers = ";".join(f"127.0.0.1:{g}" for g, _ in ports)
        replicas = []
        try:
            # Every replica started before any is waited for: each names the others.
            for k in range(shards):
                replicas.append(Server(sdata, f"shard{k}", "--shard", f"{k}/{shards}", "--shard-http", http_peers,
                                       "--shard-grpc", grpc_peers, "--pieces-above", str(min(n, 100000)),
                                       "--piece-points", str(max(50000, n // (2 * shards))), ports=ports[k],
                                       wait=False))
            for srv in replicas:
                srv.wait()
            sid = upload(replicas[0].http, points)
            # Seeds of shard 0's pieces: the answers carry X-Spokemesh-Shard when relayed.
            mine = []
            for s in seeds:
                host, port = replicas[1].http.rsplit(":", 1)
                conn = http.client.HTTPConnection(host, int(port))
                conn.request("GET", f"/v1/pointsets/{sid}/seeds/{s}/star")
                r = conn.getresponse()
                r.read()
                if r.getheader("X-Spokemesh-Shard") == "0":
                    mine.append(s)
                conn.close()
                if len(mine) >= 500:
                    break
            for srv in replicas:
                wait_kept(srv, sid, 120)
            targets = targets_file(work, "shard0", [f"/v1/pointsets/{sid}/seeds/{s}/star" for s in mine])
            direct = client("http", replicas[0].http, targets, "--requests", str(args.requests // 2))
            relayed = client("http", replicas[1].http, targets, "--requests", str(args.requests // 2))
            proxy, proxy_port = start_nginx(work, proxy_to=replicas[0].http)
            try:
                proxied = client("http", f"127.0.0.1:{proxy_port}", targets, "--requests", str(args.requests // 2))
            finally:
                proxy.terminate()
                proxy.wait()

            def versus(r):
                return f"{r['p50_us'] / direct['p50_us']:.2f}x / {r['p99_us'] / direct['p99_us']:.2f}x"

            rows = [["straight to shard 0's replica", f"{direct['p50_us']:.0f}", f"{direct['p99_us']:.0f}", "1.00x"],
                    ["through shard 1's replica (REST relay)", f"{relayed['p50_us']:.0f}", f"{relayed['p99_us']:.0f}",
                     versus(relayed)],
                    ["through nginx proxying to shard 0's replica (kept-alive upstream)", f"{proxied['p50_us']:.0f}",
                     f"{proxied['p99_us']:.0f}", versus(proxied)]]
            table(f"Sharded: {shards} shard replicas, a seed of shard 0 (single REST stars, one connection)",
                  ["path", "p50 us", "p99 us", "vs direct (p50 / p99)"], rows)
            print("\nresident memory (VmRSS): whole replica %.0f MB; shard replicas %s" %
                  (rss_whole, ", ".join(f"{vm_rss_mb(s.proc.pid):.0f} MB" for s in replicas)))
        finally:
            for srv in replicas:
                srv.stop()
    else:
        print(f"\nresident memory (VmRSS) of the whole replica: {rss_whole:.0f} MB")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
