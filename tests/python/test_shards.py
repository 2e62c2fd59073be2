"""Sharded serving (docs/service.md, "Sharded serving"): real spokemesh-server processes
sharing one data dir, sets kept as pieces, replicas of 2 and 3 shards each holding only
their shard's pieces. Every seed of a few sets (uniform, clustered, a grid, 2-d; the
clustered set's clipped cells often reach past their piece's halo and are completed
from the store) gets the same bytes from any shard replica, through REST and gRPC, as
from one replica holding the whole set; batches and whole-mesh streams too. A killed
replica costs no request; a shard with no replica answers 503 / UNAVAILABLE naming it;
tenants' sets stay invisible to others."""

from __future__ import annotations

import http.client
import json
import random

import grpc
import numpy as np
import pytest
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import free_port, http as http_request, http_json, local_mesh, uniform

PIECE_FLAGS = ("--pieces-above", "500", "--piece-points", "300")


def clustered(n: int, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.random((5, d))
    return centres[np.arange(n) % 5] + rng.normal(0, 0.02, (n, d))


def grid(side: int, d: int) -> np.ndarray:
    axes = np.meshgrid(*[np.arange(side, dtype=float)] * d, indexing="ij")
    return np.stack([a.ravel() for a in axes], axis=1)


SETS = {
    "uniform 3-d": lambda: uniform(1500, 3, seed=5),
    "clustered 3-d": lambda: clustered(1500, 3, seed=6),
    "grid 3-d": lambda: grid(9, 3),
    "uniform 2-d": lambda: uniform(2000, 2, seed=7),
}


class Rest:
    """One kept-alive REST connection: GET -> (status, headers, body)."""

    def __init__(self, url: str):
        host, port = url.removeprefix("http://").split(":")
        self.conn = http.client.HTTPConnection(host, int(port), timeout=60)

    def get(self, path: str, headers=None):
        self.conn.request("GET", path, headers=headers or {})
        r = self.conn.getresponse()
        return r.status, dict(r.getheaders()), r.read()


def start_shards(start_server, data, shards: int, replicas: int, *extra: str, name: str = "shard"):
    """shards x replicas servers on ports chosen first, each told where the others are."""
    ports = [[(free_port(), free_port()) for _ in range(replicas)] for _ in range(shards)]
    rest = ";".join(",".join(f"127.0.0.1:{h}" for _, h in ports[k]) for k in range(shards))
    grpc_list = ";".join(",".join(f"127.0.0.1:{g}" for g, _ in ports[k]) for k in range(shards))
    servers = []
    for k in range(shards):
        row = []
        for r in range(replicas):
            g, h = ports[k][r]
            row.append(start_server("--shard", f"{k}/{shards}", "--shard-http", rest, "--shard-grpc", grpc_list,
                                    *PIECE_FLAGS, *extra, data_dir=data, name=f"{name}{k}-{r}", grpc_port=g,
                                    http_port=h))
        servers.append(row)
    return servers


def upload(url: str, points: np.ndarray, headers=None) -> str:
    status, body = http_json("POST", f"{url}/v1/pointsets",
                             {"dimension": points.shape[1], "coordinates": points.ravel().tolist()}, headers)
    assert status in (200, 201), body
    return body["id"]


def piece_count(data, set_id: str) -> int:
    manifest = (data / "pieces" / set_id / "manifest").read_text().splitlines()
    return int(next(line.split()[1] for line in manifest if line.startswith("pieces ")))


def metric(url: str, name: str) -> float:
    _, _, body = http_request("GET", f"{url}/metrics")
    total = 0.0
    for line in body.decode().splitlines():
        if line.startswith(name):
            total += float(line.split()[-1])
    return total


@pytest.fixture
def stored(start_server, tmp_path):
    """The sets uploaded through a whole-set replica (which cuts them into pieces)."""
    data = tmp_path / "shared"
    whole = start_server(*PIECE_FLAGS, data_dir=data, name="whole")
    ids = {}
    for name, make in SETS.items():
        points = make()
        ids[name] = (upload(whole.http, points), points)
        assert piece_count(data, ids[name][0]) >= 4, name
    return data, whole, ids


@pytest.mark.parametrize("shards", [2, 3])
def test_every_seed_from_any_shard_is_the_whole_sets_answer(stored, start_server, shards):
    data, whole, ids = stored
    cluster = start_shards(start_server, data, shards, 1)
    replicas = [row[0] for row in cluster]
    rest = [Rest(r.http) for r in replicas]
    reference = Rest(whole.http)
    stubs = [pb_grpc.MesherStub(grpc.insecure_channel(r.grpc)) for r in replicas]
    whole_stub = pb_grpc.MesherStub(grpc.insecure_channel(whole.grpc))
    rng = random.Random(shards)
    for name, (set_id, points) in ids.items():
        n = points.shape[0]
        for seed in range(n):
            at = rng.randrange(len(replicas))
            routes = ["star", "cell?bounding_box=true"] + (["neighbors", "cell"] if seed % 5 == 0 else [])
            for route in routes:
                path = f"/v1/pointsets/{set_id}/seeds/{seed}/{route}"
                got = rest[at].get(path)
                want = reference.get(path)
                assert got[0] == want[0] == 200, (name, seed, route, got[2][:300])
                assert got[2] == want[2], f"{name}: seed {seed} {route} differs through shard replica {at}"
            if seed % 4 == 0:
                request = pb.SeedRequest(point_set_id=set_id, seed=seed)
                assert (stubs[at].GetStar(request, timeout=30).SerializeToString() ==
                        whole_stub.GetStar(request, timeout=30).SerializeToString()), (name, seed)
                cell = pb.GetVoronoiCellRequest(point_set_id=set_id, seed=seed, domain=pb.Domain(bounding_box=True))
                assert (stubs[at].GetVoronoiCell(cell, timeout=30).SerializeToString() ==
                        whole_stub.GetVoronoiCell(cell, timeout=30).SerializeToString()), (name, seed)
        # Every answer came from pieces alone: no replica loaded a whole set.
        for r in replicas:
            assert metric(r.http, "spokemesh_pieces_loaded") > 0
            assert metric(r.http, "spokemesh_store_loaded_point_sets") == 0
        # Out of range: the same error from a shard as from the whole set.
        got = rest[0].get(f"/v1/pointsets/{set_id}/seeds/{n}/star")
        want = reference.get(f"/v1/pointsets/{set_id}/seeds/{n}/star")
        assert got[0] == want[0] == 400 and got[2] == want[2]
        # A batch of every seed, and the whole mesh's stream, through one shard replica.
        seeds = list(range(n))
        for what in ("stars", "cells"):
            body = {"seeds": seeds}
            if what == "cells":
                body["bounding_box"] = True
            got = http_request("POST", f"{replicas[-1].http}/v1/pointsets/{set_id}/{what}:batch", body)
            want = http_request("POST", f"{whole.http}/v1/pointsets/{set_id}/{what}:batch", body)
            assert got[0] == want[0] == 200 and got[2] == want[2], (name, what)
            # gRPC: the same answers, in order (messages may be cut elsewhere).
            request = pb.BatchSeedsRequest(point_set_id=set_id, seeds=seeds[::-1],
                                           kind=pb.BATCH_KIND_STARS if what == "stars" else pb.BATCH_KIND_CELLS,
                                           domain=pb.Domain(bounding_box=what == "cells"))

            def answers(stub):
                out = []
                for m in stub.BatchSeeds(request, timeout=120):
                    out += [a.SerializeToString() for a in (m.stars if what == "stars" else m.cells)]
                return out
            assert answers(stubs[0]) == answers(whole_stub), (name, what, "gRPC")
        for stream_path in ("simplices", "simplices?shard=1&shards=3", "cells", "cells?measures_only=true&shard=2&shards=3"):
            status, _, stream = http_request("GET", f"{replicas[0].http}/v1/pointsets/{set_id}/{stream_path}")
            assert status == 200
            assert stream == http_request("GET", f"{whole.http}/v1/pointsets/{set_id}/{stream_path}")[2], \
                (name, stream_path)
    # Each replica holds only its own shard's pieces: batches went to their shards, and
    # the streams gave back the other shards' pieces they read.
    for k, r in enumerate(replicas):
        own = 0
        for set_id, _ in ids.values():
            p = piece_count(data, set_id)
            own += sum(1 for q in range(p) if q * shards // p == k)
        assert metric(r.http, "spokemesh_pieces_loaded") <= own, (k, own)
    forwarded = sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas)
    assert forwarded > 0
    for r in replicas:
        assert 'spokemesh_shard_info{shard="' in http_request("GET", f"{r.http}/metrics")[2].decode()


def test_mesh_stream_equals_the_cli(stored, start_server, tmp_path):
    data, _, ids = stored
    replica = start_shards(start_server, data, 2, 1)[1][0]
    set_id, points = ids["uniform 3-d"]
    status, _, stream = http_request("GET", f"{replica.http}/v1/pointsets/{set_id}/simplices")
    assert status == 200
    rows = np.array([json.loads(line) for line in stream.decode().splitlines()])
    assert np.array_equal(rows, local_mesh(points, tmp_path))


def test_a_killed_replica_costs_nothing_and_a_shard_with_none_is_named(stored, start_server):
    data, whole, ids = stored
    cluster = start_shards(start_server, data, 2, 2)
    front = Rest(cluster[0][0].http)
    set_id, points = ids["uniform 3-d"]
    reference = Rest(whole.http)
    owners = np.fromfile(data / "pieces" / set_id / "owners", dtype="<u4")
    pieces = piece_count(data, set_id)
    on_shard1 = [s for s in range(points.shape[0]) if owners[s] * 2 // pieces == 1][:200]
    on_shard0 = [s for s in range(points.shape[0]) if owners[s] * 2 // pieces == 0][:50]
    assert on_shard1 and on_shard0

    def all_answered(seeds):
        for seed in seeds:
            path = f"/v1/pointsets/{set_id}/seeds/{seed}/star"
            got = front.get(path)
            assert got[0] == 200, got[2][:300]
            assert got[2] == reference.get(path)[2]

    all_answered(on_shard1)
    cluster[1][0].kill()  # one replica of shard 1: its twin answers
    all_answered(on_shard1)
    cluster[1][0].start()
    cluster[1][1].kill()
    all_answered(on_shard1)
    cluster[1][0].kill()  # shard 1 has no replica now
    status, _, body = front.get(f"/v1/pointsets/{set_id}/seeds/{on_shard1[0]}/star")
    assert status == 503, body
    error = json.loads(body)["error"]
    assert error["status"] == "UNAVAILABLE" and "shard 1 of 2" in error["message"], error
    stub = pb_grpc.MesherStub(grpc.insecure_channel(cluster[0][1].grpc))
    with pytest.raises(grpc.RpcError) as e:
        stub.GetStar(pb.SeedRequest(point_set_id=set_id, seed=on_shard1[0]), timeout=30)
    assert e.value.code() == grpc.StatusCode.UNAVAILABLE and "shard 1 of 2" in e.value.details()
    # Nothing else degrades: shard 0's seeds, and a small set held whole.
    all_answered(on_shard0)
    small = upload(cluster[0][0].http, uniform(100, 3, seed=1))
    assert front.get(f"/v1/pointsets/{small}/seeds/99/star")[0] == 200


def test_tenants_sets_stay_invisible(start_server, tmp_path):
    data = tmp_path / "tenants"
    keys = tmp_path / "keys"
    keys.write_text("alice-key-0123456789 alice\nbob-key-0123456789ab bob\n")
    cluster = start_shards(start_server, data, 2, 1, "--keys", str(keys))
    alice = {"Authorization": "Bearer alice-key-0123456789"}
    bob = {"Authorization": "Bearer bob-key-0123456789ab"}
    set_id = upload(cluster[0][0].http, uniform(1200, 3, seed=9), alice)
    assert piece_count(data, set_id) >= 4
    for row in cluster:
        r = Rest(row[0].http)
        for seed in (0, 600, 1199):
            assert r.get(f"/v1/pointsets/{set_id}/seeds/{seed}/star", alice)[0] == 200
            status, _, body = r.get(f"/v1/pointsets/{set_id}/seeds/{seed}/star", bob)
            assert status == 404, body
        stub = pb_grpc.MesherStub(grpc.insecure_channel(row[0].grpc))
        with pytest.raises(grpc.RpcError) as e:
            stub.GetStar(pb.SeedRequest(point_set_id=set_id, seed=600), metadata=[("authorization", "Bearer bob-key-0123456789ab")],
                         timeout=30)
        assert e.value.code() == grpc.StatusCode.NOT_FOUND


def test_the_sharded_deployments_agree_with_themselves():
    """docker/k8s/spokemesh-sharded.yaml and docker/compose-sharded.yaml: every shard
    K of N has replicas started with --shard K/N under the name the others reach it by
    (the servers' default spokemesh-shard-{shard}), a budget keeping one up (k8s), and
    the front door reaches every shard."""
    import pathlib
    import yaml
    docker = pathlib.Path(__file__).resolve().parents[2] / "docker"
    docs = list(yaml.safe_load_all((docker / "k8s" / "spokemesh-sharded.yaml").read_text()))
    kinds = {}
    for d in docs:
        kinds.setdefault(d["kind"], {})[d["metadata"]["name"]] = d
    shards = sorted(kinds["Deployment"])
    n = len(shards)
    assert n >= 2
    for k, name in enumerate(shards):
        assert name == f"spokemesh-shard-{k}"
        pod = kinds["Deployment"][name]["spec"]["template"]
        args = pod["spec"]["containers"][0]["args"]
        assert args[args.index("--shard") + 1] == f"{k}/{n}"
        labels = pod["metadata"]["labels"]
        service = kinds["Service"][name]
        assert service["spec"]["clusterIP"] == "None" and service["spec"]["selector"] == labels
        assert kinds["PodDisruptionBudget"][name]["spec"]["minAvailable"] == 1
        assert kinds["Service"]["spokemesh"]["spec"]["selector"].items() <= labels.items()
    compose = yaml.safe_load((docker / "compose-sharded.yaml").read_text())["services"]
    names = sorted(s for s in compose if s.startswith("spokemesh-shard-"))
    assert len(names) == 2
    for k, name in enumerate(names):
        command = compose[name]["command"]
        assert name == f"spokemesh-shard-{k}" and command[command.index("--shard") + 1] == f"{k}/2"
        assert compose[name]["deploy"]["replicas"] == 2
    nginx = " ".join(compose["nginx"]["command"])
    assert all(name in nginx for name in names)


def test_the_python_client_and_the_cli_work_unchanged(stored, start_server, tmp_path):
    """The Python Client and the CLI's remote mode pointed at any one replica of a
    sharded deployment: the same answers as against the whole-set replica."""
    import spokemesh
    from conftest import cli
    data, whole, ids = stored
    cluster = start_shards(start_server, data, 2, 1)
    set_id, points = ids["uniform 3-d"]
    front, reference = spokemesh.Client(cluster[1][0].grpc), spokemesh.Client(whole.grpc)
    seeds = list(range(0, points.shape[0], 37))
    for seed in seeds[:20]:
        a, b = front.star(set_id, seed), reference.star(set_id, seed)
        assert np.array_equal(a.simplices, b.simplices) and np.array_equal(a.circumcenters, b.circumcenters)
        assert list(front.neighbors(set_id, seed)) == list(reference.neighbors(set_id, seed))
    assert [s.simplices.tolist() for s in front.batch_stars(set_id, seeds)] == \
        [s.simplices.tolist() for s in reference.batch_stars(set_id, seeds)]
    assert np.array_equal(front.simplices(set_id, shards=3), reference.simplices(set_id))
    out = tmp_path / "remote.simplices"
    cli("--server", cluster[0][0].grpc, "mesh", set_id, "-o", str(out), "--shards", "3", "-q")
    assert np.array_equal(np.loadtxt(out, dtype=np.int64), local_mesh(points, tmp_path))
    got = cli("--server", cluster[0][0].grpc, "batch", set_id, "stars", "--seeds", ",".join(map(str, seeds))).stdout
    want = cli("--server", whole.grpc, "batch", set_id, "stars", "--seeds", ",".join(map(str, seeds))).stdout
    assert got == want


def test_answers_at_any_point_from_every_shard(stored, start_server):
    """:locate and :interpolate through any replica of a sharded deployment: the bytes
    of the whole-set replica; on the uniform sets most of them answered from pieces
    (the rest from the set's own file, counted by spokemesh_point_queries_from_whole_set).
    These sets are small for their pieces (300 points): at 50,000 points in pieces of
    5,000, 4% of queries in a 3-d set's box and none of those in its inner 80% go to the
    whole set."""
    data, whole, ids = stored
    cluster = start_shards(start_server, data, 2, 1)
    rng = np.random.default_rng(5)

    def from_whole():
        return sum(metric(row[0].http, "spokemesh_point_queries_from_whole_set") for row in cluster)

    for name, (set_id, points) in ids.items():
        if points.shape[1] not in (2, 3):
            continue
        lo, hi = points.min(0), points.max(0)
        xi = (lo + rng.random((200, points.shape[1])) * (hi - lo)).tolist()
        values = (points[:, 0] - 2 * points[:, 1]).tolist()
        before = from_whole()
        for route, body in ((":locate", {"queries": xi}), (":interpolate", {"queries": xi, "values": values})):
            want = http_request("POST", f"{whole.http}/v1/pointsets/{set_id}{route}", body)
            assert want[0] == 200, (name, want[2][:300])
            for row in cluster:
                got = http_request("POST", f"{row[0].http}/v1/pointsets/{set_id}{route}", body)
                assert got[0] == 200 and got[2] == want[2], f"{name}: {route} differs through a shard replica"
        if name.startswith("uniform"):
            assert from_whole() - before < 0.25 * 2 * 2 * len(xi), name
    # The Python client over gRPC, values kept through one replica and named through another.
    import spokemesh
    set_id, points = ids["uniform 3-d"]
    xi = rng.random((300, 3))
    values = np.stack([points[:, 0], points[:, 2] ** 2], axis=1)
    reference = spokemesh.Client(whole.grpc)
    values_id = spokemesh.Client(cluster[0][0].grpc).put_values(set_id, values)
    got = spokemesh.Client(cluster[1][0].grpc).interpolate(set_id, xi, values_id=values_id)
    assert np.array_equal(got, reference.interpolate(set_id, xi, values), equal_nan=True)
    a, b = spokemesh.Client(cluster[1][0].grpc).locate(set_id, xi), reference.locate(set_id, xi)
    assert np.array_equal(a.simplices, b.simplices) and np.array_equal(a.barycentric, b.barycentric, equal_nan=True)


def test_clients_route_themselves(stored, start_server):
    """The shard map (GetShardMap, REST .../shards and .../shards/seeds) says which shard
    answers each seed and where its replicas are; the Python Client sends each seed
    there (no replica relays anything) and splits batches by shard, with the whole-set
    replica's answers, errors included; without routing, the front replica relays."""
    import spokemesh
    data, whole, ids = stored
    cluster = start_shards(start_server, data, 2, 1, name="routed")
    replicas = [row[0] for row in cluster]
    set_id, points = ids["uniform 3-d"]
    n = points.shape[0]
    # The map, by REST and gRPC, the same from every replica.
    status, headers, body = http_request("GET", f"{replicas[1].http}/v1/pointsets/{set_id}/shards")
    assert status == 200
    description = json.loads(body)
    assert description["sharded"] and description["shard_count"] == 2 and description["count"] == n
    assert description["grpc_addresses"] == [r.grpc for r in replicas]
    assert headers["X-Spokemesh-Shard-Map"] == description["version"] and len(description["version"]) == 16
    status, _, npy = http_request("GET", f"{replicas[0].http}/v1/pointsets/{set_id}/shards/seeds")
    assert status == 200
    seed_shards = np.load(__import__("io").BytesIO(npy))
    assert seed_shards.dtype == np.uint16 and seed_shards.shape == (n,) and set(seed_shards.tolist()) == {0, 1}
    chunks = list(pb_grpc.MesherStub(grpc.insecure_channel(replicas[0].grpc)).GetShardMap(
        pb.GetPointSetRequest(point_set_id=set_id)))
    assert chunks[0].version == description["version"]
    assert np.array_equal(np.frombuffer(b"".join(c.seed_shards for c in chunks[1:]), "<u2"), seed_shards)
    # Whole sets are answered anywhere.
    status, _, body = http_request("GET", f"{whole.http}/v1/pointsets/{set_id}/shards")
    assert status == 200 and not json.loads(body)["sharded"]
    # A routing client pointed at shard 1's replica: nothing is relayed.
    routed, plain, reference = (spokemesh.Client(replicas[1].grpc), spokemesh.Client(replicas[1].grpc, route=False),
                                spokemesh.Client(whole.grpc))
    before = sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas)
    seeds = list(range(0, n, 29))
    for seed in seeds[:30]:
        a, b = routed.star(set_id, seed), reference.star(set_id, seed)
        assert np.array_equal(a.simplices, b.simplices) and np.array_equal(a.circumcenters, b.circumcenters)
        assert list(routed.neighbors(set_id, seed)) == list(reference.neighbors(set_id, seed))
        assert routed.cell(set_id, seed, bounding_box=True).volume == reference.cell(set_id, seed,
                                                                                     bounding_box=True).volume
    assert [s.simplices.tolist() for s in routed.batch_stars(set_id, seeds)] == \
        [s.simplices.tolist() for s in reference.batch_stars(set_id, seeds)]
    # The CLI's batches route themselves too (the map weighs less than the answers).
    from conftest import cli
    seed_text = ",".join(map(str, seeds))
    want = cli("--server", whole.grpc, "batch", set_id, "stars", "--seeds", seed_text).stdout
    assert cli("--server", replicas[1].grpc, "batch", set_id, "stars", "--seeds", seed_text).stdout == want
    assert sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas) == before
    box_text = "0,0,0,0.5,1,1"
    routed_error = cli("--server", replicas[1].grpc, "batch", set_id, "cells", "--seeds", seed_text, "--box", box_text,
                       check=False)
    whole_error = cli("--server", whole.grpc, "batch", set_id, "cells", "--seeds", seed_text, "--box", box_text,
                      check=False)
    assert routed_error.returncode == whole_error.returncode != 0
    # The same error but for the address each names ("spokemesh: HOST:PORT: ...").
    assert routed_error.stderr.split(": ", 2)[2] == whole_error.stderr.split(": ", 2)[2]
    assert "lies outside the domain" in whole_error.stderr
    # --no-route: the front replica relays (answers unchanged).
    assert cli("--server", replicas[1].grpc, "batch", set_id, "stars", "--no-route", "--seeds",
               seed_text).stdout == want
    assert sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas) > before
    before = sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas)
    # Without routing, shard 1's replica relays shard 0's seeds.
    shard0 = [s for s in seeds if seed_shards[s] == 0][:5]
    for seed in shard0:
        assert np.array_equal(plain.star(set_id, seed).simplices, reference.star(set_id, seed).simplices)
    assert sum(metric(r.http, "spokemesh_forwarded_requests_total") for r in replicas) >= before + len(shard0)
    # A batch's error is one replica's: the first seed outside the box, in order.
    box = [0.0, 0.0, 0.0, 0.5, 1.0, 1.0]
    with pytest.raises(spokemesh.Error) as got:
        routed.batch_cells(set_id, seeds, box=box)
    with pytest.raises(spokemesh.Error) as want:
        reference.batch_cells(set_id, seeds, box=box)
    assert got.value.details == want.value.details and "lies outside the domain" in want.value.details
    # And through the front replica's scatter-gather (no routing) too.
    with pytest.raises(spokemesh.Error) as relayed:
        plain.batch_cells(set_id, seeds, box=box)
    assert relayed.value.details == want.value.details
    status, _, body = http_request("POST", f"{replicas[1].http}/v1/pointsets/{set_id}/cells:batch",
                                   {"seeds": seeds, "box": box})
    _, _, whole_body = http_request("POST", f"{whole.http}/v1/pointsets/{set_id}/cells:batch",
                                    {"seeds": seeds, "box": box})
    assert body == whole_body
