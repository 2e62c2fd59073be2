"""Issue 17: a real spokemesh-server under hostile and careless clients. Each test is
the regression test of one finding (numbered as in the issue): it failed on the server
before the fix and passes after. Loopback only, bounded in time and request count."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import grpc
import numpy as np
import pytest
import spokemesh
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import as_root, http, http_json, unavailable, uniform


def rss_kib(pid: int, field: str = "VmRSS") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def healthy(server) -> bool:
    status, _, _ = http("GET", f"{server.http}/healthz", timeout=10)
    return status == 200 and server.proc.poll() is None


def raw_request(server, payload: bytes, half_close: bool = False, timeout: float = 30) -> bytes:
    """Sends raw bytes on one connection and reads until the server closes it."""
    host, port = server.http.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=timeout) as s:
        s.sendall(payload)
        if half_close:
            s.shutdown(socket.SHUT_WR)
        chunks = []
        while True:
            data = s.recv(65536)
            if not data:
                break
            chunks.append(data)
    return b"".join(chunks)


# Finding 2: a coordinate nested 60,000 levels deep killed the server (SIGSEGV).
def test_deeply_nested_json_is_refused_and_the_server_lives(server):
    depth = 60000
    body = '{"points": [[0, 0], [1, 0], [0, 1], [' + "[" * depth + "1" + "]" * depth + ", 2]]}"
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", body.encode(),
                              headers={"Content-Type": "application/json"})
    assert status == 400, reply
    assert "points[3][0]" in reply["error"]["message"] and "nested deeper" in reply["error"]["message"]
    # Nesting under an unknown key is bounded the same way.
    body = '{"meta": ' + "[" * depth + "]" * depth + ', "points": [[0, 0], [1, 0], [0, 1]]}'
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", body.encode(),
                              headers={"Content-Type": "application/json"})
    assert status == 400 and "nested deeper" in reply["error"]["message"], reply
    assert healthy(server)


# Finding 7: a JSON upload peaked at 5.6x its size (a DOM of every number first).
def test_json_upload_peak_memory_is_within_three_times_its_body(start_server):
    server = start_server("--max-body-bytes", "256M")
    assert healthy(server)
    points = uniform(400000, 3, 17)  # full precision: about 60 bytes of JSON per point
    body = json.dumps({"points": points.tolist()}).encode()
    before = rss_kib(server.proc.pid, "VmHWM")
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", body, headers={"Content-Type": "application/json"})
    assert status in (200, 201), reply
    grown = (rss_kib(server.proc.pid, "VmHWM") - before) * 1024
    assert grown <= 3 * len(body), f"peak grew by {grown / 2**20:.1f} MiB for a {len(body) / 2**20:.1f} MiB body"
    # The stored set is exactly what was sent.
    client = spokemesh.Client(server.grpc)
    assert client.get(reply["id"]).count == 400000


def test_json_upload_errors_name_the_field_and_index(server):
    url = f"{server.http}/v1/pointsets"
    cases = [
        ({"points": [[0, 0], [1, 0], [0, "x"]]}, 400, 'points[2][1]: expected a number, got "x"'),
        ({"points": [[0, 0], [1, 0], [0, 1, 2]]}, 400, "points[2]: 3 coordinates, but points[0] has 2"),
        ({"points": [[0, 0], 5]}, 400, "points[1]: expected an array of coordinates"),
        ({"points": []}, 400, "points: expected a non-empty array"),
        ({"dimension": 2, "coordinates": [0, 0, 1, 0, 0, None]}, 400, "coordinates[5]: expected a number, got null"),
        ({"dimension": 2, "coordinates": [0, 0, 1]}, 400, "not a multiple of dimension 2"),
        ({"coordinates": [0, 0, 1, 0]}, 400, "dimension: a positive integer is required"),
        ({"display_name": 7, "points": [[0, 0], [1, 0], [0, 1]]}, 400, "display_name: expected a string"),
        ([1, 2], 400, "body: expected a JSON object"),
    ]
    for body, code, text in cases:
        status, reply = http_json("POST", url, body)
        assert status == code and text in reply["error"]["message"], (body, reply)
    status, reply = http_json("POST", url, b'{"points": [[0, 0], [1, 0]', headers={"Content-Type": "application/json"})
    assert status == 400 and "invalid JSON near byte" in reply["error"]["message"], reply
    status, reply = http_json("POST", url, b'{"points": [[0, 0], [1, 0], [0, 1e999]]}',
                              headers={"Content-Type": "application/json"})
    assert status == 400 and reply["error"]["status"] == "INVALID_ARGUMENT", reply
    # Unknown keys with shallow values are ignored.
    status, reply = http_json("POST", url, {"points": [[0, 0], [1, 0], [0, 1]], "note": {"by": ["me"]}})
    assert status in (200, 201), reply


def test_json_upload_past_the_point_limit_stops_early(start_server):
    server = start_server("--max-points", "1000")
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", {"points": uniform(5000, 2, 3).tolist()})
    assert status == 429 and "--max-points=1000" in reply["error"]["message"], reply


# Finding 8: media types are case-insensitive; a 413 says 413; a full disk is 507 and
# names no server path.
def test_media_types_are_case_insensitive(server):
    body = json.dumps({"points": [[0, 0], [1, 0], [0, 1], [1, 1]]}).encode()
    for ctype in ("application/JSON", "Application/Json; charset=UTF-8", " application/json ;charset=utf-8"):
        status, reply = http_json("POST", f"{server.http}/v1/pointsets", body, headers={"Content-Type": ctype})
        assert status in (200, 201), (ctype, reply)
    raw = np.array([[0, 0], [1, 0], [0, 1], [2, 2.0]]).tobytes()
    status, reply = http_json("POST", f"{server.http}/v1/pointsets?dimension=2", raw,
                              headers={"Content-Type": "Application/Octet-Stream"})
    assert status in (200, 201), reply
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", body, headers={"Content-Type": "text/csv"})
    assert status == 400 and "text/csv" in reply["error"]["message"]


def test_payload_too_large_says_413_in_its_body(start_server):
    server = start_server("--max-body-bytes", "4K")
    status, reply = http_json("POST", f"{server.http}/v1/pointsets", {"points": uniform(400, 2, 7).tolist()})
    assert status == 413 and reply["error"]["code"] == 413 and reply["error"]["status"] == "RESOURCE_EXHAUSTED"


def test_a_full_data_volume_is_507_and_names_no_path(start_server, tmp_path):
    volume = tmp_path / "small"
    volume.mkdir()
    mount = as_root(["mount", "-t", "tmpfs", "-o", f"size=1m,uid={os.getuid()},gid={os.getgid()}", "tmpfs",
                     str(volume)])
    if mount is None:
        unavailable("mounting a small tmpfs needs root, or a sudo that asks no password")
    if subprocess.run(mount).returncode != 0:
        unavailable("cannot mount a tmpfs here")
    try:
        server = start_server(data_dir=volume / "data")
        status, reply = http_json("POST", f"{server.http}/v1/pointsets", {"points": uniform(60000, 3, 5).tolist()})
        assert status == 507, reply
        assert reply["error"]["status"] == "RESOURCE_EXHAUSTED" and reply["error"].get("reason") == "STORAGE_FULL"
        assert str(volume) not in reply["error"]["message"] and "/" not in reply["error"]["message"], reply
        client = spokemesh.Client(server.grpc)
        with pytest.raises(spokemesh.Error) as e:
            client.upload(uniform(60000, 3, 6))
        assert e.value.code == grpc.StatusCode.RESOURCE_EXHAUSTED and str(volume) not in e.value.details
        # Nothing half-written is left, and a set that fits is still stored.
        assert [p for p in (volume / "data").iterdir() if p.is_file()] == []
        assert client.upload(uniform(100, 2, 1)).count == 100
        server.stop()
    finally:
        subprocess.run(as_root(["umount", "-l", str(volume)]))


# Finding 6: a client that sends its request and shuts down its sending side got 499.
def test_a_half_closed_request_gets_its_answer(server):
    client = spokemesh.Client(server.grpc)
    info = client.upload(uniform(20000, 3, 4))
    request = (f"GET /v1/pointsets/{info.id}/seeds/5/star HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").encode()
    reply = raw_request(server, request, half_close=True)
    head, _, body = reply.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 200"), reply[:300]
    assert json.loads(body)["simplices"], body[:200]
    # A whole stream, half-closed too, arrives complete.
    request = (f"GET /v1/pointsets/{info.id}/simplices?batch_size=4096 HTTP/1.1\r\nHost: x\r\n"
               "Connection: close\r\n\r\n").encode()
    reply = raw_request(server, request, half_close=True, timeout=120)
    assert reply.startswith(b"HTTP/1.1 200") and reply.endswith(b"0\r\n\r\n"), reply[-200:]


# Finding 3: the first gRPC upload message reserved count x d x 8 bytes at once, and a
# client that then sent nothing held them (631 MB per stream) with no timeout.
def test_an_upload_header_reserves_nothing_and_a_stalled_upload_ends(start_server):
    server = start_server("--upload-idle-timeout", "1s")
    channel = grpc.insecure_channel(server.grpc)
    stub = pb_grpc.MesherStub(channel)
    before = rss_kib(server.proc.pid)
    release = threading.Event()

    def stalled():
        yield pb.UploadPointSetRequest(header=pb.PointSetHeader(dimension=3, count=9_000_000))
        release.wait(60)  # then nothing: the server must end it

    errors, started = [], time.time()

    def upload():
        try:
            stub.UploadPointSet(stalled(), timeout=60)
        except grpc.RpcError as e:
            errors.append(e)

    threads = [threading.Thread(target=upload) for _ in range(4)]
    for t in threads:
        t.start()
    time.sleep(0.5)
    grown = (rss_kib(server.proc.pid) - before) * 1024
    assert grown < 64 << 20, f"4 header-only uploads of 216 MB each grew RSS by {grown >> 20} MiB"
    for t in threads:
        t.join(30)
    release.set()
    assert len(errors) == 4 and time.time() - started < 20
    assert all(e.code() in (grpc.StatusCode.CANCELLED, grpc.StatusCode.DEADLINE_EXCEEDED) for e in errors), errors
    records = [r for r in server.log_records() if r.get("method") == "UploadPointSet"]
    assert any("--upload-idle-timeout" in r.get("message", "") for r in records), records
    # A slow but steady upload is not cut off: each message restarts the idle clock.
    points = uniform(3000, 3, 2)
    raw = points.tobytes()

    def steady():
        yield pb.UploadPointSetRequest(header=pb.PointSetHeader(dimension=3, count=3000))
        for k in range(3):
            time.sleep(0.6)
            yield pb.UploadPointSetRequest(coordinates=raw[k * 24000:(k + 1) * 24000])

    assert stub.UploadPointSet(steady(), timeout=30).count == 3000
    assert healthy(server)


def timed_get(url: str, timeout: float = 10) -> float:
    start = time.perf_counter()
    status, _, _ = http("GET", url, timeout=timeout)
    assert status == 200
    return time.perf_counter() - start


def raise_fd_limit() -> None:
    import resource
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


def open_connections(server, count: int, source: str, first_bytes: bytes = b""):
    """count TCP connections from `source` (another loopback address), each sending
    first_bytes and then nothing more; the server's caps answer some of them."""
    host, port = server.http.removeprefix("http://").split(":")
    socks = []
    for _ in range(count):
        s = socket.socket()
        s.bind((source, 0))
        s.settimeout(5)
        s.connect((host, int(port)))
        if first_bytes:
            s.sendall(first_bytes)
        socks.append(s)
    return socks


# Finding 5: 520 connections trickling header bytes, or 700 idle ones, locked every
# other REST client out until a 120 s reaper ran; the 503 said Content-Length 94 for
# a 92-byte body.
def test_slowloris_and_idle_connections_do_not_lock_other_clients_out(start_server):
    raise_fd_limit()
    server = start_server("--http-max-connections-per-address", "400", "--http-header-timeout", "3s")
    url = f"{server.http}/healthz"
    baseline = min(timed_get(url) for _ in range(5))
    trickling = open_connections(server, 600, "127.0.0.2", b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
    idle = open_connections(server, 700, "127.0.0.3")
    stop = threading.Event()

    def trickle():
        while not stop.is_set():
            for s in trickling:
                try:
                    s.send(b"a")
                except OSError:
                    pass
            stop.wait(0.5)

    t = threading.Thread(target=trickle)
    t.start()
    try:
        time.sleep(0.5)
        delays = sorted(timed_get(url, timeout=5) for _ in range(9))
        # A well-behaved client from its own address is served at once (measured on the
        # development VM: a few ms; the target is under 100 ms more than idle).
        assert delays[4] - baseline < 0.1, (baseline, delays)
        # The header timeout ends the trickling connections (they never finish a header).
        time.sleep(4)
        closed = 0
        for s in trickling:
            try:
                s.settimeout(0.01)
                closed += s.recv(1) == b""
            except (socket.timeout, BlockingIOError):
                pass
            except OSError:
                closed += 1
        assert closed >= 390, f"only {closed} of the admitted trickling connections were closed"
    finally:
        stop.set()
        t.join()
        for s in trickling + idle:
            s.close()
    assert healthy(server)


def test_connection_caps_answer_a_complete_503_with_retry_after(start_server):
    raise_fd_limit()
    server = start_server("--http-max-connections-per-address", "8")
    held = open_connections(server, 8, "127.0.0.4")
    try:
        reply = open_connections(server, 1, "127.0.0.4")[0]
        data = b""
        while True:
            chunk = reply.recv(4096)
            if not chunk:
                break
            data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 503"), data
        headers = dict(line.split(": ", 1) for line in head.decode().split("\r\n")[1:])
        assert int(headers["Content-Length"]) == len(body), data
        assert headers["Retry-After"] == "1"
        assert json.loads(body)["error"]["code"] == 503
        # Other addresses are not affected by this one's cap.
        assert timed_get(f"{server.http}/healthz") < 5
    finally:
        for s in held:
            s.close()


def test_tls_handshakes_that_never_finish_do_not_lock_other_clients_out(start_server, tmp_path):
    import ssl
    from test_server import make_pki
    raise_fd_limit()
    make_pki(tmp_path)
    server = start_server("--tls-cert", str(tmp_path / "server.pem"), "--tls-key", str(tmp_path / "server.key"),
                          "--tls-handshake-timeout", "2s")
    https = server.http.replace("http://", "https://")
    context = ssl.create_default_context(cafile=str(tmp_path / "ca.pem"))
    silent = open_connections(server, 300, "127.0.0.5")  # TCP connected, no ClientHello
    try:
        start = time.perf_counter()
        status, _, _ = http("GET", f"{https}/healthz", context=context, timeout=5)
        assert status == 200 and time.perf_counter() - start < 2
        time.sleep(3)  # past the handshake timeout: the server has closed them
        closed = 0
        for s in silent:
            try:
                s.settimeout(0.05)
                closed += s.recv(1) == b""
            except socket.timeout:
                pass
            except OSError:
                closed += 1
        assert closed == len(silent)
    finally:
        for s in silent:
            s.close()


# Finding 1: every whole-mesh stream leaked its facet cache (20 cancelled streams of a
# 3-d 150k set: RSS 118 MB -> 1,747 MB). The core's fix has a unit test; this one shows
# that no stream path of the server holds memory afterwards.
def test_no_stream_path_holds_memory_afterwards(start_server):
    server = start_server("--stream-cache", "64M", "--http-write-timeout", "2s")
    client = spokemesh.Client(server.grpc)
    info = client.upload(uniform(60000, 3, 21))
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    host, port = server.http.removeprefix("http://").split(":")

    def grpc_finished():
        client.shard(info.id, 0, 1, batch_size=4096)

    def grpc_sharded():
        for k in range(3):
            client.shard(info.id, k, 3, batch_size=4096)

    def grpc_cancelled():
        stream = stub.StreamSimplices(pb.StreamSimplicesRequest(point_set_id=info.id, batch_size=64), timeout=60)
        next(stream)
        stream.cancel()

    def rest_finished():
        status, _, body = http("GET", f"{server.http}/v1/pointsets/{info.id}/simplices?batch_size=4096", timeout=120)
        assert status == 200 and body.count(b"\n") > 300000

    def rest_dropped():
        with socket.create_connection((host, int(port)), timeout=30) as s:
            s.sendall(f"GET /v1/pointsets/{info.id}/simplices?batch_size=16 HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            s.recv(4096)

    def rest_stalled():
        # Reads nothing: the write timeout (2 s) ends it and returns its memory.
        with socket.create_connection((host, int(port)), timeout=30) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.sendall(f"GET /v1/pointsets/{info.id}/simplices?batch_size=16 HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            time.sleep(4)

    paths = [grpc_finished, grpc_sharded, grpc_cancelled, rest_finished, rest_dropped, rest_stalled]
    for run in paths:  # warm-up: the set loaded, the allocator's arenas grown once
        run()
    time.sleep(1)
    settled = rss_kib(server.proc.pid)
    for _ in range(3):
        for run in paths:
            run()
    time.sleep(2)  # the dropped and stalled streams notice and end
    grown = (rss_kib(server.proc.pid) - settled) * 1024
    # Each leaked cache would be tens of MB (18 streams here); allow allocator noise.
    assert grown < 48 << 20, f"RSS grew by {grown >> 20} MiB over 18 more streams"
    assert healthy(server)


# Finding 4: --max-memory 200M with 8 sets of 500k 3-d points queried in turn reached
# 467-599 MB of RSS: caches, trees being built, streams and freed-but-kept memory were
# outside the budget.
def test_the_memory_budget_bounds_the_process(start_server):
    budget = 200 << 20
    server = start_server("--max-memory", "200M")
    assert "memory budget: 209715200 bytes (--max-memory)" in server.log()
    client = spokemesh.Client(server.grpc)
    ids = [client.upload(uniform(500000, 3, 40 + k)).id for k in range(8)]
    for _ in range(2):
        for pid in ids:
            assert client.star(pid, 5).simplices.shape[1] == 4
    for pid in ids[:2]:  # whole meshes: their caches shrink to what the budget leaves
        status, _, body = http("GET", f"{server.http}/v1/pointsets/{pid}/simplices?batch_size=4096", timeout=300)
        assert status == 200 and body.count(b"\n") > 3_000_000
    peak = rss_kib(server.proc.pid, "VmHWM") * 1024
    # The allowance: the process's fixed cost (about 30 MB) and the transients of a tree
    # build beyond its estimate; the issue measured 467-599 MB here.
    assert peak < budget + (80 << 20), f"peak RSS {peak >> 20} MiB with a {budget >> 20} MiB budget"


def test_over_the_memory_budget_is_503_with_retry_after(start_server):
    # 100 MiB: a stream of a 450k-point set holds about 42 MB (set and tree) + 16 MB
    # (its window; no cache), leaving less than the 48 MB a 24 MB upload needs (its
    # body, then its coordinates).
    server = start_server("--max-memory", "100M", "--stream-cache", "0", "--http-write-timeout", "20s")
    client = spokemesh.Client(server.grpc)
    busy = client.upload(uniform(450000, 3, 1))
    host, port = server.http.removeprefix("http://").split(":")
    # A whole-mesh stream whose reader reads nothing holds its set, window and cache.
    stalled = socket.create_connection((host, int(port)), timeout=30)
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stalled.sendall(f"GET /v1/pointsets/{busy.id}/simplices?batch_size=16 HTTP/1.1\r\nHost: x\r\n\r\n".encode())
    time.sleep(1.5)
    try:
        raw = uniform(1_000_000, 3, 2).tobytes()  # 24 MB: would fit an idle server's budget
        status, headers, body = http("POST", f"{server.http}/v1/pointsets?dimension=3", raw,
                                     headers={"Content-Type": "application/octet-stream"})
        reply = json.loads(body)
        assert status == 503 and headers.get("Retry-After") == "1", (status, reply)
        assert reply["error"]["status"] == "RESOURCE_EXHAUSTED" and reply["error"]["reason"] == "OVER_BUDGET"
        assert "--max-memory" in reply["error"]["message"]
    finally:
        stalled.close()
    # Once the stream has ended, the same upload fits.
    deadline = time.time() + 30
    while True:
        status, _, body = http("POST", f"{server.http}/v1/pointsets?dimension=3", raw,
                               headers={"Content-Type": "application/octet-stream"})
        if status != 503 or time.time() > deadline:
            break
        time.sleep(0.5)
    assert status == 201, body[:300]
    assert healthy(server)


# Finding 10: one shared token let anyone list, read and delete everyone's sets, and
# gRPC reflection answered without it.
def test_api_keys_with_tenants(start_server, tmp_path):
    keys = tmp_path / "keys"
    alice, bob, root = "alice-key-0123456789", "bob-key-0123456789ab", "root-key-0123456789ab"
    keys.write_text(f"# key tenant [admin]\n{alice} alice\n{bob} bob\n{root} ops admin\n")
    token = tmp_path / "token"
    token.write_text("legacy-admin-token-0123\n")
    server = start_server("--keys", str(keys), "--auth-token-file", str(token))
    base = f"{server.http}/v1/pointsets"

    def as_(key):
        return {"Authorization": f"Bearer {key}"}

    shared = {"points": [[0, 0], [1, 0], [0, 1], [1, 1]]}
    mine = {"points": [[0, 0], [2, 0], [0, 2], [3, 3]]}
    status, a = http_json("POST", base, json.dumps(shared).encode(), {**as_(alice), "Content-Type": "application/json"})
    assert status == 201 and a["already_existed"] is False
    status, b = http_json("POST", base, json.dumps(shared).encode(), {**as_(bob), "Content-Type": "application/json"})
    # Stored once (the id is the content's hash); new for bob.
    assert status == 201 and b["id"] == a["id"] and b["already_existed"] is False, b
    status, own = http_json("POST", base, json.dumps(mine).encode(), {**as_(alice), "Content-Type": "application/json"})
    assert status == 201
    files = [p.name for p in server.data_dir.iterdir() if p.name.endswith(".points")]
    assert sorted(files) == sorted({f"{a['id']}.points", f"{own['id']}.points"})

    def listed(key):
        status, body = http_json("GET", base, headers=as_(key))
        assert status == 200
        return {s["id"] for s in body["point_sets"]}

    assert listed(alice) == {a["id"], own["id"]}
    assert listed(bob) == {a["id"]}
    assert listed(root) == {a["id"], own["id"]} == listed("legacy-admin-token-0123")
    # Another tenant's set is answered as absent, on every route and both transports.
    for route in ("", "/seeds/0/star", "/seeds/0/cell", "/simplices"):
        status, body = http_json("GET", f"{base}/{own['id']}{route}", headers=as_(bob))
        assert status == 404, (route, body)
    status, body = http_json("DELETE", f"{base}/{own['id']}", headers=as_(bob))
    assert status == 404
    # Appending to another tenant's set: absent too; to one's own: a new set of one's own.
    status, body = http_json("POST", f"{base}/{own['id']}:append", json.dumps({"points": [[5, 5]]}).encode(),
                             {**as_(bob), "Content-Type": "application/json"})
    assert status == 404, body
    status, grown = http_json("POST", f"{base}/{own['id']}:append", json.dumps({"points": [[5, 5]]}).encode(),
                              {**as_(alice), "Content-Type": "application/json"})
    assert status == 201 and grown["parent_id"] == own["id"] and grown["count"] == 5, grown
    assert http_json("GET", f"{base}/{grown['id']}", headers=as_(bob))[0] == 404
    assert http_json("DELETE", f"{base}/{grown['id']}", headers=as_(alice))[0] == 200
    bob_client = spokemesh.Client(server.grpc, token=bob)
    with pytest.raises(spokemesh.Error) as e:
        bob_client.star(own["id"], 0)
    assert e.value.code == grpc.StatusCode.NOT_FOUND
    assert {p.id for p in bob_client.list()} == {a["id"]}
    assert bob_client.star(a["id"], 0).simplices.shape[1] == 3
    # No key, or a wrong one: 401 / UNAUTHENTICATED; health stays open.
    assert http_json("GET", base)[0] == 401
    assert http_json("GET", base, headers=as_("not-a-key-0123456789"))[0] == 401
    with pytest.raises(spokemesh.Error) as e:
        spokemesh.Client(server.grpc).list()
    assert e.value.code == grpc.StatusCode.UNAUTHENTICATED
    assert healthy(server)
    # Reflection needs a key too.
    identity = lambda b: b  # noqa: E731
    reflect = grpc.insecure_channel(server.grpc).stream_stream(
        "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
        request_serializer=identity, response_deserializer=identity)
    with pytest.raises(grpc.RpcError):
        b"".join(reflect(iter([b"\x3a\x00"]), timeout=10))
    answer = b"".join(reflect(iter([b"\x3a\x00"]), timeout=10, metadata=[("authorization", f"Bearer {alice}")]))
    assert b"spokemesh.v1.Mesher" in answer
    # A tenant's delete gives up its own ownership; the set goes with its last owner.
    assert http_json("DELETE", f"{base}/{a['id']}", headers=as_(alice))[0] == 200
    assert listed(alice) == {own["id"]} and listed(bob) == {a["id"]}
    assert http_json("DELETE", f"{base}/{a['id']}", headers=as_(bob))[0] == 200
    assert not (server.data_dir / f"{a['id']}.points").exists()
    # SIGHUP re-reads the keys: a new tenant's key works, a removed one stops working.
    carol = "carol-key-0123456789"
    keys.write_text(f"{alice} alice\n{carol} carol\n{root} ops admin\n")
    server.proc.send_signal(signal.SIGHUP)
    deadline = time.time() + 10
    while http_json("GET", base, headers=as_(carol))[0] != 200 and time.time() < deadline:
        time.sleep(0.1)
    assert http_json("GET", base, headers=as_(carol))[0] == 200
    assert http_json("GET", base, headers=as_(bob))[0] == 401
    # A broken keys file keeps the previous keys.
    keys.write_text("short alice\n")
    server.proc.send_signal(signal.SIGHUP)
    time.sleep(0.5)
    assert http_json("GET", base, headers=as_(carol))[0] == 200
    assert "previous keys stay in force" in server.log()


# Finding 8 (last part): two identical concurrent uploads raced on already_existed and
# on the display name.
def test_identical_concurrent_uploads_create_once(start_server, tmp_path):
    server = start_server()
    second = start_server(data_dir=server.data_dir, name="replica")  # another replica, same data dir
    for trial in range(8):
        points = uniform(20000, 3, 100 + trial).tolist()
        barrier = threading.Barrier(2)
        results = {}

        def upload(name, base):
            body = json.dumps({"points": points, "display_name": name}).encode()
            barrier.wait()
            results[name] = http_json("POST", f"{base}/v1/pointsets", body, {"Content-Type": "application/json"})

        threads = [threading.Thread(target=upload, args=(n, b)) for n, b in (("first", server.http),
                                                                           ("second", second.http))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        statuses = sorted(r[0] for r in results.values())
        assert statuses == [200, 201], (trial, results)
        winner = next(n for n, r in results.items() if r[0] == 201)
        pid = results[winner][1]["id"]
        assert [r[1]["already_existed"] for n, r in sorted(results.items())] == [n != winner for n in sorted(results)]
        for base in (server.http, second.http):
            status, info = http_json("GET", f"{base}/v1/pointsets/{pid}")
            assert status == 200 and info["display_name"] == winner, (trial, info)


class TinyDns:
    """A loopback DNS server answering A queries for one name from a list the test
    changes (as Docker's or podman's DNS does when a replica restarts elsewhere)."""

    def __init__(self, name: str, addresses: list):
        import struct
        self.struct, self.name, self.addresses = struct, name, addresses
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.queries = 0
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self):
        st = self.struct
        while True:
            try:
                query, peer = self.sock.recvfrom(512)
            except OSError:
                return
            self.queries += 1
            qid = query[:2]
            end = 12
            while query[end] != 0:
                end += query[end] + 1
            question = query[12:end + 5]
            labels, i = [], 12
            while query[i] != 0:
                labels.append(query[i + 1:i + 1 + query[i]].decode())
                i += query[i] + 1
            qtype = st.unpack(">H", query[end + 1:end + 3])[0]
            answers = list(self.addresses) if ".".join(labels) == self.name and qtype == 1 else []
            reply = qid + st.pack(">HHHHH", 0x8180, 1, len(answers), 0, 0) + question
            for a in answers:
                reply += st.pack(">HHHIH", 0xC00C, 1, 1, 1, 4) + socket.inet_aton(a)
            self.sock.sendto(reply, peer)

    def close(self):
        self.sock.close()


# Finding 9: nginx resolved `spokemesh` once at start, so a replica restarted with a new
# address never got traffic again. docker/nginx.conf itself, run here against replicas
# on other loopback addresses and a DNS server whose answer the test changes.
def test_nginx_re_resolves_replicas_that_restart_elsewhere(start_server, tmp_path):
    from conftest import free_port, start_nginx
    grpc_port, rest_port = free_port(), free_port()
    data = tmp_path / "shared"
    first = start_server(data_dir=data, name="first", host="127.0.0.2", grpc_port=grpc_port, http_port=rest_port)
    dns = TinyDns("spokemesh", ["127.0.0.2"])
    ndir = tmp_path / "nginx"
    ndir.mkdir()
    front_grpc, front_rest = free_port(), free_port()
    conf = (Path(__file__).resolve().parents[2] / "docker" / "nginx.conf").read_text()
    conf = (conf.replace("@RESOLVER@", f"127.0.0.1:{dns.port}")
            .replace("@HOSTS@", "default spokemesh;")
            .replace("listen 50051 http2;", f"listen 127.0.0.1:{front_grpc} http2;")
            .replace("listen 8080;", f"listen 127.0.0.1:{front_rest};")
            .replace("$spokemesh_host:50051", f"$spokemesh_host:{grpc_port}")
            .replace("$spokemesh_host:8080", f"$spokemesh_host:{rest_port}")
            .replace("worker_processes auto;", ("user root;\n" if os.geteuid() == 0 else "") +
                     f"worker_processes 1;\npid {ndir}/nginx.pid;\nerror_log {ndir}/error.log warn;")
            .replace("http {", f"http {{\n  access_log {ndir}/access.log;\n  client_body_temp_path {ndir}/body;\n"
                               f"  proxy_temp_path {ndir}/proxy;\n  fastcgi_temp_path {ndir}/fastcgi;\n"
                               f"  uwsgi_temp_path {ndir}/uwsgi;\n  scgi_temp_path {ndir}/scgi;", 1))
    assert "@RESOLVER@" not in conf
    (ndir / "nginx.conf").write_text(conf)
    front = f"http://127.0.0.1:{front_rest}"
    proc = start_nginx(ndir, front)
    try:
        status, info = http_json("POST", f"{front}/v1/pointsets", {"points": uniform(2000, 3, 9).tolist()})
        assert status == 201, info
        client = spokemesh.Client(f"127.0.0.1:{front_grpc}")
        assert client.star(info["id"], 0).simplices.shape[1] == 4
        # The replica restarts with a new address; DNS now says so.
        first.kill()
        second = start_server(data_dir=data, name="second", host="127.0.0.3", grpc_port=grpc_port,
                              http_port=rest_port)
        dns.addresses[:] = ["127.0.0.3"]
        deadline = time.time() + 15
        while time.time() < deadline:
            if http("GET", f"{front}/v1/pointsets/{info['id']}/seeds/1/star", timeout=5)[0] == 200:
                break
            time.sleep(0.2)
        # From now on every request reaches the new replica, promptly, on both fronts.
        slowest = 0.0
        for k in range(20):
            start = time.perf_counter()
            assert http("GET", f"{front}/v1/pointsets/{info['id']}/seeds/{k}/star", timeout=5)[0] == 200
            assert client.star(info["id"], k).simplices.shape[1] == 4
            slowest = max(slowest, time.perf_counter() - start)
        served = [r for r in second.log_records() if r.get("method") == "GetStar"]
        assert len(served) >= 40, len(served)
        assert slowest < 1.0, slowest
        # A dead address among the answers costs a retry on the next one, not an error.
        dns.addresses[:] = ["127.0.0.4", "127.0.0.3"]
        time.sleep(2.5)  # past valid=2s
        for k in range(10):
            assert http("GET", f"{front}/v1/pointsets/{info['id']}/seeds/{k}/star", timeout=5)[0] == 200
        assert dns.queries >= 2
    finally:
        proc.terminate()
        proc.wait(10)
        dns.close()


# Every limit and default is defined once (service/limits.hpp); the flag table of
# docs/service.md must say what `spokemesh-server --help` says.
def test_documented_flag_defaults_match_the_server():
    import re
    from conftest import REPO, SERVER
    help_text = subprocess.run([str(SERVER), "--help"], capture_output=True, text=True, check=True).stdout
    actual = dict(re.findall(r"^\s+(--[\w-]+) [A-Z]+[^=\s]*(?:\s+in \[[^\]]*\])?=(\S+)", help_text, re.M))
    documented = {}
    in_table = False
    for line in (REPO / "docs" / "service.md").read_text().splitlines():
        if line.startswith("## Flags"):
            in_table = True
        elif line.startswith("## "):
            in_table = False
        elif in_table and line.startswith("| `--"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            for flag in re.findall(r"`(--[\w-]+)`", cells[0]):
                documented[flag] = cells[1].strip("`").replace(",", "")
    assert documented, "no flag table found in docs/service.md"
    # Documented in words where the default depends on the machine.
    machine = {"--threads": "cores"}
    checked = 0
    for flag, default in actual.items():
        assert flag in documented, f"{flag} is not in docs/service.md's flag table"
        if flag in machine:
            assert documented[flag] == machine[flag], (flag, documented[flag])
            continue
        assert documented[flag] == default, f"{flag}: docs say {documented[flag]!r}, the server {default!r}"
        checked += 1
    undocumented = set(documented) - set(actual) - {f for f in documented if documented[f] == "–"}
    assert not undocumented, f"documented flags the server does not have: {undocumented}"
    assert checked >= 20
