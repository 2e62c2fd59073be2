"""Every RPC and REST route of a real spokemesh-server process, their errors,
deadlines, cancellation, TLS, bearer tokens, metrics, logs and graceful shutdown."""

from __future__ import annotations

import http.client as httplib
import json
import os
import signal
import ssl
import subprocess
import threading
import time

import grpc
import numpy as np
import pytest
import spokemesh
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import REPO, cli, http, http_json, local_mesh, star_of, uniform


def ndjson_shard(base: str, pid: str, k: int, n: int) -> np.ndarray:
    status, headers, body = http("GET", f"{base}/v1/pointsets/{pid}/simplices?shard={k}&shards={n}")
    assert status == 200, body
    assert headers["Content-Type"] == "application/x-ndjson"
    assert headers.get("Transfer-Encoding") == "chunked"
    rows = [json.loads(line) for line in body.decode().splitlines()]
    return np.array(rows, dtype=np.int64).reshape(len(rows), -1)


def test_rest_grpc_and_python_client_agree_with_the_local_mesh(server, tmp_path):
    points = uniform(3000, 3, seed=1)
    status, ps = http_json("POST", f"{server.http}/v1/pointsets", {"points": points.tolist(), "display_name": "cube"})
    assert status == 201 and ps["count"] == 3000 and ps["dimension"] == 3 and not ps["already_existed"]
    client = spokemesh.Client(server.grpc)
    again = client.upload(points)
    assert again.id == ps["id"] and again.already_existed and again.display_name == "cube"

    reference = local_mesh(points, tmp_path)
    # The whole mesh: REST NDJSON shards, gRPC shards, the Python client, the remote CLI.
    rest = np.concatenate([ndjson_shard(server.http, ps["id"], k, 3) for k in range(3)])
    assert np.array_equal(rest, reference)
    assert np.array_equal(client.simplices(ps["id"], shards=4).astype(np.int64), reference)
    out = tmp_path / "remote.simplices"
    cli("--server", server.grpc, "mesh", ps["id"], "-o", str(out), "--shards", "5", "-q")
    assert np.array_equal(np.loadtxt(out, dtype=np.int64), reference)

    for seed in (0, 1234, 2999):
        star_rest = http_json("GET", f"{server.http}/v1/pointsets/{ps['id']}/seeds/{seed}/star")[1]
        star_grpc = client.star(ps["id"], seed)
        expected = star_of(reference, seed)
        assert np.array_equal(np.array(star_rest["simplices"]), expected)
        assert np.array_equal(star_grpc.simplices.astype(np.int64), expected)
        assert np.allclose(np.array(star_rest["circumcenters"]), star_grpc.circumcenters, rtol=0, atol=0)
        neighbors = sorted(set(expected.ravel()) - {seed})
        assert http_json("GET", f"{server.http}/v1/pointsets/{ps['id']}/seeds/{seed}/neighbors")[1]["neighbors"] == neighbors
        assert list(client.neighbors(ps["id"], seed)) == neighbors
        cell = client.cell(ps["id"], seed)
        cell_rest = http_json("GET", f"{server.http}/v1/pointsets/{ps['id']}/seeds/{seed}/cell")[1]
        assert [f.neighbor for f in cell.facets] == neighbors == [f["neighbor"] for f in cell_rest["facets"]]
        assert cell.bounded == cell_rest["bounded"]
        assert (cell_rest["volume"] is None) == (not cell.bounded)
        # Remote CLI answers are the local CLI's, byte for byte.
        src = tmp_path / "points.npy"
        np.save(src, points)
        assert cli("--server", server.grpc, "star", ps["id"], "--seed", str(seed)).stdout == \
            cli("star", str(src), "--seed", str(seed)).stdout
        assert cli("--server", server.grpc, "cell", ps["id"], "--seed", str(seed), "--json").stdout == \
            cli("cell", str(src), "--seed", str(seed), "--json").stdout
    # One convention for unbounded cells (docs/service.md): +inf over gRPC and in Python,
    # null beside "bounded": false in JSON. The leftmost point is on the hull; seed 1234
    # (inside) is bounded.
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    for seed, bounded in ((int(np.argmin(points[:, 0])), False), (1234, True)):
        raw = stub.GetVoronoiCell(pb.GetVoronoiCellRequest(point_set_id=ps["id"], seed=seed), timeout=30)
        rest = http_json("GET", f"{server.http}/v1/pointsets/{ps['id']}/seeds/{seed}/cell")[1]
        assert raw.bounded == rest["bounded"] == client.cell(ps["id"], seed).bounded == bounded
        if bounded:
            assert 0 < raw.volume < float("inf") and rest["volume"] == raw.volume
        else:
            assert raw.volume == client.cell(ps["id"], seed).volume == float("inf") and rest["volume"] is None

    assert np.array_equal(client.download(ps["id"]), points)
    assert [p.id for p in client.list()] == [ps["id"]]
    assert http_json("GET", f"{server.http}/v1/pointsets/{ps['id']}")[1]["display_name"] == "cube"
    assert http_json("GET", f"{server.http}/v1/pointsets")[1]["point_sets"][0]["id"] == ps["id"]
    client.delete(ps["id"])
    assert http("GET", f"{server.http}/v1/pointsets/{ps['id']}")[0] == 404


def signed_volumes(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """det[s_1 - s_0, ..., s_d - s_0] of each simplex (d! times its signed volume)."""
    p = points[simplices]
    return np.linalg.det(p[:, 1:, :] - p[:, :1, :])


def read_vtu(path) -> np.ndarray:
    """The connectivity of our ASCII .vtu, (m, d + 1)."""
    text = path.read_text()
    block = text.split('Name="connectivity" format="ascii">\n')[1].split("</DataArray>")[0]
    types = text.split('Name="types" format="ascii">\n')[1].split("</DataArray>")[0].split()
    width = {"5": 3, "10": 4}[types[0]]
    return np.array(block.split(), dtype=np.int64).reshape(-1, width)


def read_msh(path) -> np.ndarray:
    """The elements of our gmsh 2.2 ASCII .msh, (m, d + 1), 0-based."""
    lines = path.read_text().split("$Elements\n")[1].split("$EndElements")[0].splitlines()[1:]
    rows = [[int(v) for v in line.split()[5:]] for line in lines]  # index type ntags tag tag nodes...
    return np.array(rows, dtype=np.int64) - 1


# Issue 18, part 1: every simplex in every output is positively oriented (finite-element
# solvers reject inverted elements): the local CLI's files and star, the gRPC and REST
# stars and streams, and the Python client. numpy's determinants must all be > 0.
def test_every_output_is_positively_oriented(server, tmp_path):
    client = spokemesh.Client(server.grpc)
    for d, n in ((2, 400), (3, 400), (4, 150)):
        points = uniform(n, d, seed=70 + d)
        src = tmp_path / f"p{d}.npy"
        np.save(src, points)
        outputs = {}
        for ext in (("npy", "simplices", "vtu", "msh") if d <= 3 else ("npy", "simplices")):
            out = tmp_path / f"m{d}.{ext}"
            cli("mesh", str(src), "-o", str(out), "-q")
            outputs[ext] = {"npy": np.load, "simplices": lambda f: np.loadtxt(f, dtype=np.int64, ndmin=2),
                            "vtu": read_vtu, "msh": read_msh}[ext](out)
        reference = outputs["simplices"]
        for ext, simplices in outputs.items():  # the same simplices, vertex order included
            assert np.array_equal(simplices, reference), ext
        outputs["cli star"] = np.loadtxt(cli("star", str(src), "--seed", "7").stdout.splitlines(), dtype=np.int64)
        pid = client.upload(points).id
        outputs["grpc stream"] = client.simplices(pid, shards=2).astype(np.int64)
        outputs["rest stream"] = ndjson_shard(server.http, pid, 0, 1)
        outputs["grpc star"] = client.star(pid, 7).simplices.astype(np.int64)
        outputs["rest star"] = np.array(http_json("GET", f"{server.http}/v1/pointsets/{pid}/seeds/7/star")[1]["simplices"])
        for what, simplices in outputs.items():
            volumes = signed_volumes(points, simplices)
            assert len(volumes) > 0 and (volumes > 0).all(), (d, what, simplices[volumes <= 0][:5])


def test_cli_remote_mode_upload_health_list_delete(server, tmp_path):
    example = REPO / "examples" / "disc-2d.txt"
    up = cli("--server", server.grpc, "upload", str(example), "--name", "disc")
    pid = up.stdout.strip()
    assert len(pid) == 64 and "stored" in up.stderr
    assert cli("--server", server.grpc, "upload", str(example)).stdout.strip() == pid
    assert cli("health", "--server", server.grpc).stdout.strip() == "SERVING"
    assert pid in cli("list", "--server", server.grpc).stdout
    vtu = tmp_path / "disc.vtu"
    cli("--server", server.grpc, "mesh", pid, "-o", str(vtu), "-q")
    local = tmp_path / "local.vtu"
    cli("mesh", str(example), "-o", str(local), "-q")
    assert vtu.read_bytes() == local.read_bytes()
    bad = cli("--server", server.grpc, "star", pid, "--seed", "100000", check=False)
    assert bad.returncode == 2 and "OUT_OF_RANGE" in bad.stderr and "seed: 100000" in bad.stderr
    assert cli("--server", server.grpc, "delete", pid).returncode == 0
    gone = cli("--server", server.grpc, "star", pid, "--seed", "0", check=False)
    assert gone.returncode == 2 and "NOT_FOUND" in gone.stderr
    bad_file = tmp_path / "bad.txt"
    bad_file.write_text("0 0\n1 x\n")
    r = cli("--server", server.grpc, "upload", str(bad_file), check=False)
    assert r.returncode == 2 and "bad.txt:2" in r.stderr
    down = cli("health", "--server", "127.0.0.1:1", "--deadline", "2s", check=False)
    assert down.returncode == 1 and "UNAVAILABLE" in down.stderr


def test_appending_points_makes_the_set_uploading_the_whole_would(server, tmp_path):
    # REST, gRPC (the Python client) and the CLI: the new set's id is the whole's
    # content hash, its answers are the whole set's, the parent stays as it was.
    old, new = uniform(2000, 3, seed=11), uniform(40, 3, seed=12)
    whole = np.concatenate([old, new])
    client = spokemesh.Client(server.grpc)
    parent = client.upload(old, name="old")
    status, rest = http_json("POST", f"{server.http}/v1/pointsets/{parent.id}:append",
                             {"points": new.tolist(), "display_name": "grown"})
    assert status == 201 and rest["parent_id"] == parent.id and rest["count"] == 2040, rest
    assert rest["display_name"] == "grown" and rest["already_existed"] is False
    again = client.append(parent.id, new)
    assert again.id == rest["id"] and again.already_existed and again.parent_id == parent.id
    assert client.upload(whole).id == rest["id"]
    assert client.get(parent.id).count == 2000
    # Raw float64 takes the parent's dimension when none is given.
    status, raw = http_json("POST", f"{server.http}/v1/pointsets/{parent.id}:append", new.astype("<f8").tobytes(),
                            {"Content-Type": "application/octet-stream"})
    assert status == 200 and raw["id"] == rest["id"], raw
    # The new set answers as the whole: stars of old and new seeds, the whole mesh.
    reference = local_mesh(whole, tmp_path)
    for seed in (0, 1999, 2000, 2039):
        assert np.array_equal(client.star(rest["id"], seed).simplices.astype(np.int64), star_of(reference, seed))
    assert np.array_equal(client.simplices(rest["id"], shards=2).astype(np.int64), reference)
    assert np.array_equal(client.download(rest["id"]), whole)
    # The CLI: `spokemesh append ID POINTS` prints the new id.
    more = tmp_path / "more.txt"
    np.savetxt(more, new[:5], fmt="%.17g")
    out = cli("--server", server.grpc, "append", parent.id, str(more), "--name", "five")
    five = out.stdout.strip()
    assert five == client.upload(np.concatenate([old, new[:5]])).id
    assert parent.id in out.stderr and "2005 points" in out.stderr
    # Errors name what and where: a point already there, the wrong dimension, an
    # unknown set, nothing to append, and a malformed file (before any network).
    status, dup = http_json("POST", f"{server.http}/v1/pointsets/{parent.id}:append", {"points": [old[17].tolist()]})
    assert status == 400 and dup["error"]["reason"] == "DUPLICATE_POINTS"
    assert "points 17 and 2000 are equal" in dup["error"]["message"]
    status, flat = http_json("POST", f"{server.http}/v1/pointsets/{parent.id}:append", {"points": [[1.0, 2.0]]})
    assert status == 400 and "2-d points cannot be appended" in flat["error"]["message"] and "3-d" in flat["error"]["message"]
    with pytest.raises(spokemesh.Error) as e:
        client.append("0" * 64, new)
    assert e.value.code == grpc.StatusCode.NOT_FOUND
    with pytest.raises(spokemesh.Error) as e:
        client.append(parent.id, np.zeros((0, 3)))
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "at least one point" in e.value.details
    bad = tmp_path / "bad.txt"
    bad.write_text("0.1 0.2 0.3\n0.4 x 0.6\n")
    r = cli("--server", server.grpc, "append", parent.id, str(bad), check=False)
    assert r.returncode == 2 and f"{bad}:2" in r.stderr
    r = cli("append", parent.id, str(more), check=False)
    assert r.returncode == 2 and "needs --server" in r.stderr


def test_unary_calls_cut_off_in_transit_are_sent_again(server):
    """A unary call that ends CANCELLED or UNAVAILABLE after gRPC's own retries gave up
    (a replica killed mid-answer, the proxy resetting the stream) is sent again by the
    client, twice at most, within its deadline; other errors are not."""
    client = spokemesh.Client(server.grpc, timeout=5)
    ps = client.upload(uniform(200, 3, 7))
    stub = pb_grpc.MesherStub(client._channel)

    class CutOff(grpc.RpcError):
        def __init__(self, code):
            self._code = code

        def code(self):
            return self._code

        def details(self):
            return self._code.name

    def failing(times, code):
        calls = []

        def method(request, timeout, metadata):
            calls.append(timeout)
            if len(calls) <= times:
                raise CutOff(code)
            return stub.GetStar(request, timeout=timeout, metadata=metadata)
        return method, calls

    request = pb.SeedRequest(point_set_id=ps.id, seed=3)
    for code in (grpc.StatusCode.CANCELLED, grpc.StatusCode.UNAVAILABLE):
        method, calls = failing(2, code)
        assert client._call(method, request).simplices == stub.GetStar(request).simplices
        assert len(calls) == 3 and all(0 < t <= 5 for t in calls)
        method, calls = failing(3, code)
        with pytest.raises(spokemesh.Error) as e:
            client._call(method, request)
        assert e.value.code == code and len(calls) == 3
    method, calls = failing(1, grpc.StatusCode.INVALID_ARGUMENT)
    with pytest.raises(spokemesh.Error):
        client._call(method, request)
    assert len(calls) == 1
    # A client stream cut off after it was consumed is sent again whole: upload and
    # append hand _call a function that makes the stream afresh.
    streams = []
    real_append = client._stub.AppendPoints

    def append_cut_once(messages, timeout, metadata):
        messages = list(messages)
        streams.append(len(messages))
        if len(streams) == 1:
            raise CutOff(grpc.StatusCode.UNAVAILABLE)
        return real_append(iter(messages), timeout=timeout, metadata=metadata)
    client._stub.AppendPoints = append_cut_once
    try:
        grown = client.append(ps.id, uniform(5, 3, 8))
    finally:
        client._stub.AppendPoints = real_append
    assert streams == [2, 2] and grown.count == 205


def test_list_clamps_page_size_and_only_uploads_say_already_existed(server):
    client = spokemesh.Client(server.grpc)
    first = client.upload(uniform(20, 2, 30))
    again = client.upload(uniform(20, 2, 30))
    assert not first.already_existed and again.already_existed
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    # AIP-158: a page size above the maximum (1000) is clamped, not refused.
    page = stub.ListPointSets(pb.ListPointSetsRequest(page_size=5000), timeout=10)
    assert [p.id for p in page.point_sets] == [first.id] and page.next_page_token == ""
    assert not page.point_sets[0].already_existed
    assert not stub.GetPointSet(pb.GetPointSetRequest(point_set_id=first.id), timeout=10).already_existed
    status, body = http_json("GET", f"{server.http}/v1/pointsets?page_size=5000")
    assert status == 200 and [p["id"] for p in body["point_sets"]] == [first.id]
    assert "already_existed" not in body["point_sets"][0]
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{first.id}")
    assert status == 200 and "already_existed" not in body
    status, body = http_json("POST", f"{server.http}/v1/pointsets", {"points": uniform(20, 2, 30).tolist()})
    assert status == 200 and body["already_existed"] is True


def test_errors_name_the_field_and_map_to_codes(start_server):
    server = start_server("--max-points", "5000", "--max-dimension", "4", "--max-body-bytes", "64K")
    client = spokemesh.Client(server.grpc)

    def code_of(fn):
        with pytest.raises(spokemesh.Error) as e:
            fn()
        return e.value.code, e.value.details

    pts = uniform(10, 2, 3)
    pts[7, 1] = np.nan
    code, msg = code_of(lambda: client.upload(pts))
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "point 7, coordinate 1" in msg
    code, msg = code_of(lambda: client.upload(np.vstack([uniform(5, 2, 4), uniform(5, 2, 4)[:1]])))
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "points 0 and 5" in msg
    # The advice fits the server (upload has no --merge-duplicates).
    assert "np.unique(points, axis=0)" in msg and "use --merge-duplicates" not in msg
    code, msg = code_of(lambda: client.upload(np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]])))
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "span only a 1" in msg
    code, msg = code_of(lambda: client.upload(uniform(6000, 2, 5)))
    assert code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-points=5000" in msg
    code, msg = code_of(lambda: client.upload(uniform(50, 5, 5)))
    assert code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-dimension=4" in msg
    # A header that disagrees with the bytes sent.
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    with pytest.raises(grpc.RpcError) as e:
        stub.UploadPointSet(iter([pb.UploadPointSetRequest(header=pb.PointSetHeader(dimension=2, count=10)),
                                  pb.UploadPointSetRequest(coordinates=b"\0" * 100)]), timeout=10)
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "received 100 bytes" in e.value.details()
    # A message over gRPC's 4 MiB limit is refused, not buffered.
    with pytest.raises(grpc.RpcError) as e:
        stub.UploadPointSet(iter([pb.UploadPointSetRequest(header=pb.PointSetHeader(dimension=2, count=400000)),
                                  pb.UploadPointSetRequest(coordinates=b"\0" * (5 << 20))]), timeout=10)
    assert e.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    good = client.upload(uniform(100, 2, 6))
    code, msg = code_of(lambda: client.star(good.id, 100))
    assert code == grpc.StatusCode.OUT_OF_RANGE and "seed: 100" in msg
    code, _ = code_of(lambda: client.star("0" * 64, 0))
    assert code == grpc.StatusCode.NOT_FOUND
    code, _ = code_of(lambda: client.star("not-an-id", 0))
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    # Bytes that are no protobuf message at all (found by fuzz_grpc_requests: gRPC
    # answered INTERNAL with no message).
    raw = grpc.insecure_channel(server.grpc).unary_unary("/spokemesh.v1.Mesher/GetStar")
    with pytest.raises(grpc.RpcError) as e:
        raw(b"\xff\xff\xff\xff", timeout=10)
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "not a valid protobuf encoding of /spokemesh.v1.Mesher/GetStar" in e.value.details()
    # REST: one error shape; an oversized body is refused from its Content-Length.
    status, body = http_json("POST", f"{server.http}/v1/pointsets", {"points": uniform(3000, 2, 7).tolist()})
    assert status == 413 and body["error"]["status"] == "RESOURCE_EXHAUSTED" and "--max-body-bytes" in body["error"]["message"]
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{good.id}/seeds/100/cell")
    assert status == 400 and body == {"error": {"code": 400, "status": "OUT_OF_RANGE", "message": body["error"]["message"]}}
    status, body = http_json("POST", f"{server.http}/v1/pointsets", {"points": [[0, 0], [1, 0], [0, 1], [1, 1e308 * 10]]})
    assert status == 400 and body["error"]["status"] == "INVALID_ARGUMENT"
    # A dimension beyond any the engine supports is refused while parsing, with the
    # range (core's kMaxApproxDimension); within it, --max-dimension decides.
    status, body = http_json("POST", f"{server.http}/v1/pointsets", {"dimension": 1025, "coordinates": [0.0] * 2050})
    assert status == 400 and "dimension: 1025 is not supported; it must be between 2 and 1024" in body["error"]["message"]
    status, body = http_json("POST", f"{server.http}/v1/pointsets", {"dimension": 5, "coordinates": [0.0] * 50})
    assert status == 429 and "--max-dimension=4" in body["error"]["message"]
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{good.id}/simplices?shard=9&shards=2")
    assert status == 400 and "shard_index: 9" in body["error"]["message"]
    # Nothing half-written was left in the data dir by the failed uploads.
    files = sorted(p.name for p in server.data_dir.iterdir() if p.is_file())
    assert files == [f"{good.id}.points"]


def test_deadlines_and_cancellation(start_server):
    server = start_server("--default-deadline", "30s")
    client = spokemesh.Client(server.grpc)
    # Large enough that a whole shard takes seconds even with the facet cache, so the
    # dropped streams below are stopped mid-way, not finished.
    big = client.upload(uniform(150000, 3, 8))
    with pytest.raises(spokemesh.Error) as e:
        client.shard(big.id, 0, 1, timeout=0.05)
    assert e.value.code == grpc.StatusCode.DEADLINE_EXCEEDED
    # REST: 504 if the deadline passes before the first chunk; after it, the stream
    # ends with an error line and no terminating chunk, so it cannot pass as complete.
    conn = httplib.HTTPConnection(server.http.removeprefix("http://"), timeout=60)
    conn.request("GET", f"/v1/pointsets/{big.id}/simplices", headers={"X-Timeout-Ms": "20"})
    resp = conn.getresponse()
    try:
        body = resp.read()
        assert resp.status == 504 and b"DEADLINE_EXCEEDED" in body and b"deadline" in body
    except httplib.IncompleteRead as partial:
        assert resp.status == 200
        last = partial.partial.decode().splitlines()[-1]
        assert json.loads(last)["error"]["status"] == "DEADLINE_EXCEEDED"
    conn.close()
    # Cancel a gRPC stream after one batch, and drop a REST stream after a few bytes.
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    stream = stub.StreamSimplices(pb.StreamSimplicesRequest(point_set_id=big.id, batch_size=64), timeout=60)
    next(stream)
    stream.cancel()
    conn = httplib.HTTPConnection(server.http.removeprefix("http://"), timeout=60)
    conn.request("GET", f"/v1/pointsets/{big.id}/simplices?batch_size=16")
    resp = conn.getresponse()
    resp.read(64)
    conn.close()
    deadline = time.time() + 20
    while time.time() < deadline:
        stopped = [r for r in server.log_records() if r.get("method") == "StreamSimplices" and r.get("status") == "CANCELLED"]
        # (the 50 ms gRPC deadline above may itself be logged as CANCELLED, when the
        # client's cancellation reaches the server before its own deadline check)
        if {r["transport"] for r in stopped} >= {"grpc", "http"}:
            break
        time.sleep(0.05)
    assert {r["transport"] for r in stopped} == {"grpc", "http"}, server.log()
    assert all(r["duration_ms"] < 15000 for r in stopped)  # stopped early, not after the whole shard
    # The server is healthy and answers.
    assert cli("health", "--server", server.grpc).returncode == 0
    assert client.star(big.id, 0).simplices.shape[1] == 4
    # A star in 8-d is large work: it ends at the deadline, and says which limit it hit.
    eight = client.upload(uniform(3000, 8, 9))
    with pytest.raises(spokemesh.Error) as e:
        client.star(eight.id, 0, timeout=0.3)
    assert e.value.code == grpc.StatusCode.DEADLINE_EXCEEDED
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{eight.id}/seeds/0/star", headers={"X-Timeout-Ms": "300"})
    assert status == 504 and "stopped at the request deadline (300 ms)" in body["error"]["message"]
    assert client.star(big.id, 1).simplices.shape[1] == 4
    # A default deadline applies to requests that carry none.
    short = start_server("--default-deadline", "30ms", data_dir=server.data_dir, name="short")
    status, body = http_json("GET", f"{short.http}/v1/pointsets/{big.id}/simplices?batch_size=65536")
    assert status == 504 and "30 ms" in body["error"]["message"]


def make_pki(d):
    """A CA, a server certificate for 127.0.0.1/localhost and a client certificate."""
    def run(*args):
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=d)
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=spokemesh test CA")
    for name, ext in (("server", "subjectAltName=IP:127.0.0.1,DNS:localhost"), ("client", "extendedKeyUsage=clientAuth")):
        run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}")
        (d / f"{name}.ext").write_text(ext + "\n")
        run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.ext")


def test_tls_mtls_and_bearer_token(start_server, tmp_path):
    make_pki(tmp_path)
    token = tmp_path / "token"
    token.write_text("tok-123\n")
    server = start_server("--tls-cert", str(tmp_path / "server.pem"), "--tls-key", str(tmp_path / "server.key"),
                          "--tls-client-ca", str(tmp_path / "ca.pem"), "--auth-token-file", str(token))
    https = server.http.replace("http://", "https://")
    ctx = ssl.create_default_context(cafile=str(tmp_path / "ca.pem"))
    ctx.load_cert_chain(str(tmp_path / "client.pem"), str(tmp_path / "client.key"))
    assert http_json("GET", f"{https}/healthz", context=ctx)[0] == 200
    status, body = http_json("GET", f"{https}/v1/pointsets", context=ctx)
    assert status == 401 and body["error"]["status"] == "UNAUTHENTICATED"
    assert http_json("GET", f"{https}/v1/pointsets", headers={"Authorization": "Bearer tok-123"}, context=ctx)[0] == 200
    assert http_json("GET", f"{https}/metrics", headers={"Authorization": "Bearer nope"}, context=ctx)[0] == 401
    # Without a client certificate the TLS handshake is refused.
    no_cert = ssl.create_default_context(cafile=str(tmp_path / "ca.pem"))
    with pytest.raises(Exception):
        http("GET", f"{https}/healthz", context=no_cert, timeout=10)

    pem = lambda name: (tmp_path / name).read_bytes()
    client = spokemesh.Client(server.grpc, token="tok-123", root_certificates=pem("ca.pem"),
                              private_key=pem("client.key"), certificate_chain=pem("client.pem"))
    ps = client.upload(uniform(200, 2, 9))
    assert client.star(ps.id, 3).simplices.shape[1] == 3
    anonymous = spokemesh.Client(server.grpc, root_certificates=pem("ca.pem"), private_key=pem("client.key"),
                                 certificate_chain=pem("client.pem"))
    with pytest.raises(spokemesh.Error) as e:
        anonymous.star(ps.id, 3)
    assert e.value.code == grpc.StatusCode.UNAUTHENTICATED
    r = cli("--server", server.grpc, "--tls-ca", str(tmp_path / "ca.pem"), "--tls-cert", str(tmp_path / "client.pem"),
            "--tls-key", str(tmp_path / "client.key"), "--token-file", str(token), "neighbors", ps.id, "--seed", "3")
    assert [int(v) for v in r.stdout.split()] == list(client.neighbors(ps.id, 3))
    assert cli("--server", server.grpc, "--tls-ca", str(tmp_path / "ca.pem"), "--tls-cert", str(tmp_path / "client.pem"),
               "--tls-key", str(tmp_path / "client.key"), "health").stdout.strip() == "SERVING"


def test_metrics_and_structured_logs(server):
    client = spokemesh.Client(server.grpc)
    ps = client.upload(uniform(500, 2, 10))
    client.star(ps.id, 1)
    http("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/2/star")
    http("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/999/star")
    status, headers, body = http("GET", f"{server.http}/metrics")
    text = body.decode()
    assert status == 200 and headers["Content-Type"].startswith("text/plain")
    assert 'spokemesh_requests_total{method="GetStar",status="OK",transport="grpc"} 1' in text
    assert 'spokemesh_requests_total{method="GetStar",status="OUT_OF_RANGE",transport="http"} 1' in text
    assert 'spokemesh_request_duration_seconds_count{method="UploadPointSet",status="OK",transport="grpc"} 1' in text
    assert "spokemesh_points_uploaded_total 500" in text
    assert "spokemesh_simplices_served_total" in text
    for gauge in ("spokemesh_memory_budget_used_bytes", "spokemesh_memory_budget_limit_bytes",
                  "spokemesh_heap_in_use_bytes", "spokemesh_heap_held_bytes"):
        assert float(text.split(f"\n{gauge} ")[1].split()[0]) > 0, gauge
    records = server.log_records()  # every line is one JSON object
    assert len(records) == len(server.log().splitlines())
    star = [r for r in records if r.get("method") == "GetStar" and r.get("transport") == "grpc"][0]
    assert star["point_set"] == ps.id and star["seed"] == 1 and star["status"] == "OK"
    assert {"time", "level", "duration_ms"} <= set(star)
    bad = [r for r in records if r.get("status") == "OUT_OF_RANGE"][0]
    assert bad["level"] == "warning" and "seed: 999" in bad["message"]


def test_graceful_shutdown_drains_in_flight_requests(start_server):
    server = start_server("--drain-delay", "1s", "--grace-period", "30s")
    client = spokemesh.Client(server.grpc)
    ps = client.upload(uniform(30000, 3, 11))
    result = {}

    def fetch():
        result["mesh"] = client.shard(ps.id, 0, 1, batch_size=256)

    t = threading.Thread(target=fetch)
    t.start()
    time.sleep(0.2)
    server.proc.send_signal(signal.SIGTERM)
    time.sleep(0.3)
    # During the drain delay: not ready, health NOT_SERVING, still answering.
    assert http("GET", f"{server.http}/readyz")[0] == 503
    assert http("GET", f"{server.http}/healthz")[0] == 200
    r = cli("health", "--server", server.grpc, check=False)
    assert r.returncode == 1 and r.stdout.strip() == "NOT_SERVING"
    t.join(60)
    assert server.proc.wait(60) == 0
    assert result["mesh"].shape[0] > 100000  # the in-flight stream finished whole
    assert "stopped" in server.log()


def test_health_and_reflection_services(server):
    # Raw calls with hand-encoded messages: the Python side has no stubs for these.
    channel = grpc.insecure_channel(server.grpc)
    identity = lambda b: b  # noqa: E731
    check = channel.unary_unary("/grpc.health.v1.Health/Check", request_serializer=identity,
                                response_deserializer=identity)
    assert check(b"", timeout=10) == b"\x08\x01"  # status: SERVING
    reflect = channel.stream_stream("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
                                    request_serializer=identity, response_deserializer=identity)
    answer = b"".join(reflect(iter([b"\x3a\x00"]), timeout=10))  # list_services: ""
    assert b"spokemesh.v1.Mesher" in answer and b"grpc.health.v1.Health" in answer


def cpu_seconds(pid: int) -> float:
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def test_a_stalled_reader_stalls_the_shard(server):
    """Flow control: a client that stops reading stops the server's work once the
    transport's windows and the engine's bounded window are full (a region of the
    sweep per worker beyond the one being written, 50,000 points each here, and the
    stream's own window of 16 MB), instead of the server computing and buffering the
    rest of the shard."""
    client = spokemesh.Client(server.grpc)
    ps = client.upload(uniform(800000, 3, 12))  # 16 regions, about 6 CPU-seconds of meshing
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    start = cpu_seconds(server.proc.pid)
    stream = stub.StreamSimplices(pb.StreamSimplicesRequest(point_set_id=ps.id, batch_size=256), timeout=600)
    first = next(stream)
    # Wait until the server goes idle (however loaded this machine is).
    last = cpu_seconds(server.proc.pid)
    for _ in range(240):
        time.sleep(0.5)
        now = cpu_seconds(server.proc.pid)
        if now - last < 0.02:
            break
        last = now
    else:
        pytest.fail("the server never stopped working while its client read nothing")
    stalled_at = now - start
    total = (len(first.simplices) + sum(len(b.simplices) for b in stream)) // 4
    whole = cpu_seconds(server.proc.pid) - start
    assert total > 5_300_000  # the stream then completed (5,397,181 simplices for this set)
    assert stalled_at < 0.5 * whole, f"stalled after {stalled_at:.1f} of {whole:.1f} CPU-s: no backpressure"


def test_approximate_neighbors_in_high_dimensions(start_server, tmp_path):
    server = start_server()
    other = start_server(data_dir=server.data_dir, name="replica")
    points = uniform(400, 16, 13)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    # Exact work above d = 8 is refused, pointing to the approximate mode.
    for call in (lambda: client.star(ps.id, 0), lambda: client.neighbors(ps.id, 0), lambda: client.shard(ps.id, 0, 1)):
        with pytest.raises(spokemesh.Error) as e:
            call()
        assert e.value.code == grpc.StatusCode.RESOURCE_EXHAUSTED and "APPROXIMATE" in e.value.details
    walk = client.neighbor_walk(ps.id, 3, mode="approximate", max_consecutive_misses=40)
    assert not walk.exact and walk.vertices_visited > 0 and len(walk.neighbors) > 0
    # The same request on another replica, through REST, and from the local CLI: identical.
    again = spokemesh.Client(other.grpc).neighbors(ps.id, 3, mode="approximate", max_consecutive_misses=40)
    assert np.array_equal(again, walk.neighbors)
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/3/neighbors"
                                    "?mode=approximate&max_consecutive_misses=40")
    assert status == 200 and body["neighbors"] == walk.neighbors.tolist() and body["exact"] is False
    src = tmp_path / "p16.npy"
    np.save(src, points)
    local = cli("neighbors", str(src), "--seed", "3", "--approx", "--misses", "40")
    assert [int(v) for v in local.stdout.split()] == walk.neighbors.tolist()
    remote = cli("--server", server.grpc, "neighbors", ps.id, "--seed", "3", "--approx", "--misses", "40")
    assert remote.stdout == local.stdout
    spokes = client.neighbor_walk(ps.id, 3, mode="spokes", max_consecutive_misses=40)
    assert len(spokes.neighbors) > 0 and not spokes.exact
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/3/neighbors?mode=fuzzy")
    assert status == 400 and "mode" in body["error"]["message"]


def _row_keys(simplices: np.ndarray, offsets: np.ndarray) -> list:
    """A periodic mesh's rows as sorted tuples (index, offset...) per vertex."""
    return sorted(tuple(int(x) for v in range(s.shape[0]) for x in (s[v], *o[v]))
                  for s, o in zip(simplices, offsets))


def test_weighted_periodic_sets_answer_as_the_local_engine(server, tmp_path):
    """A set with weights and a periodic box, uploaded over gRPC, REST and the CLI: the
    same id each way, and every answer the in-process engine's."""
    points = uniform(600, 2, seed=28)
    weights = uniform(600, 1, seed=29).ravel() * 2e-4
    box = [[0.0, 0.0], [1.0, 1.0]]
    local = spokemesh.Delaunay(points, periodic=box, weights=weights)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points, weights=weights, periodic=box)
    assert ps.weighted and np.array_equal(ps.periodic_box, np.array(box))
    status, rest = http_json("POST", f"{server.http}/v1/pointsets",
                             {"points": points.tolist(), "weights": weights.tolist(), "periodic_box": [0, 0, 1, 1]})
    assert status == 200 and rest["id"] == ps.id and rest["weighted"] and rest["periodic_box"] == [0, 0, 1, 1]
    np.savetxt(tmp_path / "p.txt", points, fmt="%.17g")
    np.savetxt(tmp_path / "w.txt", weights, fmt="%.17g")
    up = cli("--server", server.grpc, "upload", str(tmp_path / "p.txt"), "--weights", str(tmp_path / "w.txt"),
             "--periodic", "0,0,1,1")
    assert up.stdout.strip() == ps.id

    # The whole torus: the same simplices and offsets as in-process, for any shards.
    expected = _row_keys(local.simplices, local.offsets)
    for shards in (1, 3):
        simplices, offsets = client.simplices(ps.id, shards=shards, offsets=True)
        assert _row_keys(simplices, offsets) == expected
    status, _, body = http("GET", f"{server.http}/v1/pointsets/{ps.id}/simplices?shard=0&shards=1")
    lines = [json.loads(line) for line in body.decode().splitlines()]
    assert _row_keys(np.array([x["simplex"] for x in lines]), np.array([x["offsets"] for x in lines])) == expected
    out = tmp_path / "remote.npz"
    cli("--server", server.grpc, "mesh", ps.id, "-o", str(out), "-q")
    with np.load(out) as z:
        assert _row_keys(z["simplices"], z["offsets"]) == expected

    for seed in (0, 77, 599):
        s, o = local.star(seed)
        star = client.star(ps.id, seed)
        assert np.array_equal(star.simplices, s) and np.array_equal(star.offsets, o)
        walk = client.neighbor_walk(ps.id, seed)
        k, ko = local.neighbors_of(seed)
        assert np.array_equal(walk.neighbors, k) and np.array_equal(walk.offsets, ko)
        cell, here = client.cell(ps.id, seed), local.cell(seed)
        assert cell.volume == here.volume and [f.neighbor for f in cell.facets] == [f.neighbor for f in here.facets]
        assert all(np.array_equal(f.offset, g.offset) for f, g in zip(cell.facets, here.facets))
    # Cells stream: they tile the torus.
    volumes = [c.volume for c in client.cells(ps.id, measures_only=True)]
    assert len(volumes) == 600 and abs(sum(volumes) - 1.0) < 1e-12
    # What the torus does not take is refused, naming why; bad weights name the row.
    with pytest.raises(spokemesh.Error) as e:
        client.cell(ps.id, 0, bounding_box=True)
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "periodic" in e.value.details
    bad = weights.copy()
    bad[9] = np.inf
    with pytest.raises(spokemesh.Error) as e:
        client.upload(points, weights=bad)
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "weights: index 9" in e.value.details
    outside = points.copy()
    outside[4, 0] = 1.0
    with pytest.raises(spokemesh.Error) as e:
        client.upload(outside, periodic=box)
    assert "point 4 lies outside the periodic box" in e.value.details
