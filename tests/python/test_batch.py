"""Many seeds in one call: BatchSeeds over gRPC, the REST
.../{stars,neighbors,cells}:batch routes, the Python client and the remote CLI. Every
answer equals the single call's."""

from __future__ import annotations

import json

import grpc
import numpy as np
import pytest
import spokemesh
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import cli, http, uniform


def ndjson(status_headers_body):
    status, headers, body = status_headers_body
    assert status == 200, body[:500]
    assert headers["Content-Type"] == "application/x-ndjson"
    return [json.loads(line) for line in body.decode().splitlines()]


def test_batches_equal_single_calls_everywhere(server, tmp_path):
    points = uniform(3000, 3, seed=21)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    seeds = [int(s) for s in np.random.default_rng(1).integers(0, 3000, 300)] + [5, 5, 2999]

    stars = client.batch_stars(ps.id, seeds)
    assert [s.seed for s in stars] == seeds
    for seed, s in zip(seeds[::20], stars[::20]):
        one = client.star(ps.id, seed)
        assert np.array_equal(s.simplices, one.simplices) and np.array_equal(s.circumcenters, one.circumcenters)
        assert s.hull_facets == one.hull_facets

    for mode in ("exact", "approximate"):
        many = client.batch_neighbors(ps.id, seeds, mode=mode, max_consecutive_misses=40)
        for seed, n in zip(seeds[::15], many[::15]):
            one = client.neighbor_walk(ps.id, seed, mode=mode, max_consecutive_misses=40)
            assert np.array_equal(n.neighbors, one.neighbors) and n.walk_exhausted == one.walk_exhausted
            assert n.vertices_visited == one.vertices_visited

    box = [0, 0, 0, 1, 1, 1]
    cells = client.batch_cells(ps.id, seeds[:50], box=box)
    for seed, c in zip(seeds[:50:7], cells[::7]):
        one = client.cell(ps.id, seed, box=box)
        assert c.volume == one.volume and np.array_equal(c.vertices, one.vertices)
        assert [(f.neighbor, f.wall, f.area) for f in c.facets] == [(f.neighbor, f.wall, f.area) for f in one.facets]

    # REST: one line per seed, each the single route's body.
    base = f"{server.http}/v1/pointsets/{ps.id}"
    rows = ndjson(http("POST", f"{base}/stars:batch", {"seeds": seeds[:40]}))
    assert [r["seed"] for r in rows] == seeds[:40]
    for r in rows[::9]:
        single = json.loads(http("GET", f"{base}/seeds/{r['seed']}/star")[2])
        assert r == single
    rows = ndjson(http("POST", f"{base}/neighbors:batch",
                       {"seeds": seeds[:40], "mode": "approximate", "max_consecutive_misses": 40}))
    for r in rows[::9]:
        single = json.loads(http("GET", f"{base}/seeds/{r['seed']}/neighbors?mode=approximate&max_consecutive_misses=40")[2])
        assert r == single
    rows = ndjson(http("POST", f"{base}/cells:batch", {"seeds": seeds[:20], "box": box}))
    for r in rows[::5]:
        single = json.loads(http("GET", f"{base}/seeds/{r['seed']}/cell?box=0,0,0,1,1,1")[2])
        assert r == single

    # The remote CLI prints the same objects, one per line.
    out = cli("--server", server.grpc, "batch", ps.id, "neighbors", "--seeds", ",".join(map(str, seeds[:30]))).stdout
    lines = [json.loads(line) for line in out.splitlines()]
    assert [line["seed"] for line in lines] == seeds[:30]
    assert [line["neighbors"] for line in lines] == [list(map(int, n.neighbors)) for n in
                                                     client.batch_neighbors(ps.id, seeds[:30])]
    seeds_file = tmp_path / "seeds.txt"
    seeds_file.write_text("\n".join(map(str, seeds[:10])))
    out = cli("--server", server.grpc, "batch", ps.id, "cells", "--seeds-file", str(seeds_file),
              "--box", "0,0,0,1,1,1").stdout
    assert [json.loads(line)["volume"] for line in out.splitlines()] == [c.volume for c in cells[:10]]


def test_batch_errors_name_the_seed_and_the_limit(server):
    client = spokemesh.Client(server.grpc)
    ps = client.upload(uniform(100, 2, seed=22))
    with pytest.raises(spokemesh.Error) as e:
        client.batch_stars(ps.id, [0, 1, 100])
    assert e.value.code == grpc.StatusCode.OUT_OF_RANGE and "seeds[2]: seed 100" in e.value.details
    with pytest.raises(spokemesh.Error) as e:
        client.batch_stars(ps.id, [])
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "seeds" in e.value.details
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    with pytest.raises(grpc.RpcError) as e:
        list(stub.BatchSeeds(pb.BatchSeedsRequest(point_set_id=ps.id, seeds=[0] * 100001), timeout=30))
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "100000" in e.value.details()
    base = f"{server.http}/v1/pointsets/{ps.id}"
    status, _, body = http("POST", f"{base}/stars:batch", {"seeds": [0, -1]})
    assert status == 400 and b"seeds[1]" in body
    status, _, body = http("POST", f"{base}/stars:batch", {"seed": [0]})
    assert status == 400 and b"seeds" in body
    status, _, body = http("POST", f"{base}/stars:batch", {"seeds": [0, 100]})
    assert status == 400 and b"seeds[1]: seed 100" in body
    status, _, _ = http("GET", f"{base}/stars:batch")
    assert status == 501  # as every route answers a method it does not support
    r = cli("--server", server.grpc, "batch", ps.id, "stars", "--seeds", "1,x", check=False)
    assert r.returncode == 2 and "'x'" in r.stderr


def test_compact_batches_are_the_grpc_answers(server):
    """REST batches in the compact form (Accept: application/x-protobuf): gRPC's
    BatchSeedsResponse messages, varint-delimited, with the gRPC answers' bytes; their
    done counts close at the request's length; a refusal is the JSON error as ever."""
    points = uniform(2000, 3, seed=23)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    seeds = [int(s) for s in np.random.default_rng(3).integers(0, 2000, 700)]
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    for kind, field, extra in (("stars", "stars", {}), ("neighbors", "neighbors", {}),
                               ("cells", "cells", {"bounding_box": True})):
        status, headers, body = http("POST", f"{server.http}/v1/pointsets/{ps.id}/{kind}:batch",
                                     {"seeds": seeds, **extra}, headers={"Accept": "application/x-protobuf"})
        assert status == 200 and headers["Content-Type"].startswith("application/x-protobuf"), body[:300]
        messages = spokemesh.read_compact_batches(body)
        assert messages[-1].done == len(seeds)
        got = [a.SerializeToString() for m in messages for a in getattr(m, field)]
        request = pb.BatchSeedsRequest(point_set_id=ps.id, seeds=seeds, kind={
            "stars": pb.BATCH_KIND_STARS, "neighbors": pb.BATCH_KIND_NEIGHBORS, "cells": pb.BATCH_KIND_CELLS}[kind])
        if extra:
            request.domain.bounding_box = True
        want = [a.SerializeToString() for m in stub.BatchSeeds(request) for a in getattr(m, field)]
        assert got == want, kind
    status, headers, body = http("POST", f"{server.http}/v1/pointsets/{ps.id}/stars:batch", {"seeds": [1, 99999]},
                                 headers={"Accept": "application/x-protobuf"})
    assert status == 400 and json.loads(body)["error"]["status"] == "OUT_OF_RANGE"
