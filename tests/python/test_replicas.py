"""Three spokemesh-server replicas sharing one data dir behind Debian's nginx (grpc_pass
for gRPC, proxy_pass for REST), all on loopback. Uploads through nginx are served by
every replica; shards fetched through nginx and directly from each replica unite to
the local mesh; per-seed answers are byte-identical on every replica."""

from __future__ import annotations

import json
import os

import grpc
import numpy as np
import pytest
import spokemesh
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import free_port, http, http_json, local_mesh, start_nginx, uniform

CONF = """
{user}
worker_processes 1;
pid {dir}/nginx.pid;
error_log {dir}/error.log warn;
events {{ worker_connections 256; }}
http {{
  access_log {dir}/access.log;
  client_body_temp_path {dir}/body;
  proxy_temp_path {dir}/proxy;
  fastcgi_temp_path {dir}/fastcgi;
  uwsgi_temp_path {dir}/uwsgi;
  scgi_temp_path {dir}/scgi;
  client_max_body_size 256m;
  upstream spokemesh_grpc {{ {grpc_servers} }}
  upstream spokemesh_rest {{ {rest_servers} keepalive 8; }}
  server {{
    listen 127.0.0.1:{grpc_port} http2;
    location / {{ grpc_pass grpc://spokemesh_grpc; grpc_read_timeout 300s; }}
  }}
  server {{
    listen 127.0.0.1:{rest_port};
    location / {{
      proxy_pass http://spokemesh_rest;
      proxy_http_version 1.1;
      proxy_set_header Connection "";
      proxy_buffering off;
      proxy_read_timeout 300s;
    }}
  }}
}}
"""


@pytest.fixture
def cluster(start_server, tmp_path):
    data = tmp_path / "shared-data"
    replicas = [start_server(data_dir=data, name=f"replica{k}") for k in range(3)]
    ndir = tmp_path / "nginx"
    ndir.mkdir()
    grpc_port, rest_port = free_port(), free_port()
    conf = CONF.format(
        user="user root;" if os.geteuid() == 0 else "",  # workers must reach the test's temp dir
        dir=ndir, grpc_port=grpc_port, rest_port=rest_port,
        grpc_servers=" ".join(f"server {r.grpc};" for r in replicas),
        rest_servers=" ".join(f"server {r.http.removeprefix('http://')};" for r in replicas))
    (ndir / "nginx.conf").write_text(conf)
    proc = start_nginx(ndir, f"http://127.0.0.1:{rest_port}")
    yield replicas, f"127.0.0.1:{grpc_port}", f"http://127.0.0.1:{rest_port}"
    proc.terminate()
    proc.wait(20)


def test_replicas_behind_nginx_agree(cluster, tmp_path):
    replicas, grpc_lb, rest_lb = cluster
    points = uniform(4000, 3, seed=21)
    reference = local_mesh(points, tmp_path)

    lb = spokemesh.Client(grpc_lb)
    ps = lb.upload(points, name="through nginx")
    # REST upload of the same data through nginx: same id, no work.
    status, body = http_json("POST", f"{rest_lb}/v1/pointsets", {"dimension": 3, "coordinates": points.ravel().tolist()})
    assert status == 200 and body["id"] == ps.id and body["already_existed"]

    # Shards: each from a different place (nginx and the replicas directly), united.
    direct = [spokemesh.Client(r.grpc) for r in replicas]
    sources = [lb, *direct, lb, direct[0]]
    parts = [src.shard(ps.id, k, len(sources)) for k, src in enumerate(sources)]
    assert np.array_equal(np.concatenate(parts).astype(np.int64), reference)
    # The whole mesh through nginx: gRPC and REST NDJSON.
    assert np.array_equal(lb.simplices(ps.id, shards=3).astype(np.int64), reference)
    rows = []
    for k in range(3):
        status, _, data = http("GET", f"{rest_lb}/v1/pointsets/{ps.id}/simplices?shard={k}&shards=3")
        assert status == 200
        rows += [json.loads(line) for line in data.decode().splitlines()]
    assert np.array_equal(np.array(rows), reference)
    # Every replica, and nginx, give byte-identical GetStar answers.
    stubs = [pb_grpc.MesherStub(grpc.insecure_channel(a)) for a in [grpc_lb] + [r.grpc for r in replicas]]
    for seed in (0, 7, 1999, 3999):
        answers = {stub.GetStar(pb.SeedRequest(point_set_id=ps.id, seed=seed), timeout=30).SerializeToString()
                   for stub in stubs}
        assert len(answers) == 1, f"seed {seed}: replicas disagree"
        rest = {http("GET", f"{r.http}/v1/pointsets/{ps.id}/seeds/{seed}/star")[2] for r in replicas}
        rest.add(http("GET", f"{rest_lb}/v1/pointsets/{ps.id}/seeds/{seed}/star")[2])
        assert len(rest) == 1
    # A delete through one replica is seen by all.
    direct[2].delete(ps.id)
    for c in (lb, *direct):
        with pytest.raises(spokemesh.Error) as e:
            c.star(ps.id, 0)
        assert e.value.code == grpc.StatusCode.NOT_FOUND
