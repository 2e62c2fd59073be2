"""Durability: kill -9 during uploads; after a restart every acknowledged point set is
present and verified, and no partial file is served. A flipped byte quarantines that
point set only."""

from __future__ import annotations

import threading
import time

import grpc
import numpy as np
import pytest
import spokemesh

from conftest import http_json, uniform


def test_kill_9_during_uploads_loses_nothing_acknowledged(start_server, tmp_path):
    server = start_server()
    acknowledged = {}  # id -> points
    rounds = 4
    for r in range(rounds):
        stop = threading.Event()
        client = spokemesh.Client(server.grpc, timeout=20)

        def upload_until_killed(r=r):
            k = 0
            while not stop.is_set():
                pts = uniform(20000 + 10 * k, 3, seed=1000 * r + k)
                try:
                    ps = client.upload(pts)
                except spokemesh.Error:
                    return  # the server died mid-upload: not acknowledged, may be absent
                acknowledged[ps.id] = pts
                k += 1

        t = threading.Thread(target=upload_until_killed)
        t.start()
        time.sleep(0.4 + 0.15 * r)  # kill at varying points of an upload
        server.kill()
        stop.set()
        t.join(30)
        client.close()
        # No temporary file is ever visible as a point set.
        server.start()
        listed = {p.id for p in spokemesh.Client(server.grpc).list()}
        assert set(acknowledged) <= listed
        assert listed == {p.name[:64] for p in server.data_dir.glob("*.points")}
    assert len(acknowledged) >= rounds
    client = spokemesh.Client(server.grpc)
    for pid, pts in acknowledged.items():
        assert np.array_equal(client.download(pid), pts)  # verified on load against its SHA-256
        assert client.star(pid, 0).simplices.shape[1] == 4
    assert "quarantined" not in server.log()
    assert server.stop() == 0


def test_a_flipped_byte_quarantines_only_that_point_set(start_server):
    server = start_server()
    client = spokemesh.Client(server.grpc)
    keep = client.upload(uniform(300, 2, 1))
    spoil = client.upload(uniform(300, 2, 2))
    client.close()  # an idle connection holds up gRPC's shutdown for seconds
    assert server.stop() == 0
    path = server.data_dir / f"{spoil.id}.points"
    data = bytearray(path.read_bytes())
    data[100] ^= 0x01
    path.write_bytes(bytes(data))
    server.start()
    records = [r for r in server.log_records() if "quarantined" in r.get("message", "")]
    assert len(records) == 1 and spoil.id in records[0]["message"] and records[0]["level"] == "error"
    assert not path.exists() and any((server.data_dir / "quarantine").iterdir())
    client = spokemesh.Client(server.grpc)
    with pytest.raises(spokemesh.Error) as e:
        client.star(spoil.id, 0)
    assert e.value.code == grpc.StatusCode.NOT_FOUND
    assert client.star(keep.id, 0).simplices.shape[1] == 3
    assert http_json("GET", f"{server.http}/readyz")[0] == 200
    # Uploading it again restores it.
    again = client.upload(uniform(300, 2, 2))
    assert again.id == spoil.id and not again.already_existed


def test_a_corrupt_file_met_lazily_is_quarantined(start_server):
    server = start_server()
    other = start_server(data_dir=server.data_dir, name="other")  # running before the upload
    ps = spokemesh.Client(server.grpc).upload(uniform(200, 2, 3))
    path = server.data_dir / f"{ps.id}.points"
    path.write_bytes(path.read_bytes()[:1000])  # truncated behind both servers' backs
    # `other` has never loaded it: it loads it on first use, finds it corrupt, quarantines it.
    with pytest.raises(spokemesh.Error) as e:
        spokemesh.Client(other.grpc).star(ps.id, 0)
    assert e.value.code == grpc.StatusCode.NOT_FOUND and "quarantined" in e.value.details
    assert "quarantined" in other.log()
    # `server` had it in memory, but follows the data dir: the set is gone there too.
    with pytest.raises(spokemesh.Error) as e:
        spokemesh.Client(server.grpc).star(ps.id, 0)
    assert e.value.code == grpc.StatusCode.NOT_FOUND


def _loaded_sets(server) -> float:
    from conftest import http
    status, _, body = http("GET", f"{server.http}/metrics")
    assert status == 200
    line = next(l for l in body.decode().splitlines() if l.startswith("spokemesh_store_loaded_point_sets "))
    return float(line.split()[1])


def test_appending_streams_the_parent_and_a_corrupt_one_is_quarantined(start_server):
    server = start_server()
    other = start_server(data_dir=server.data_dir, name="other")  # running before the uploads: loads nothing
    old, new = uniform(3000, 3, 11), uniform(30, 3, 12)
    parent = spokemesh.Client(server.grpc).upload(old)
    # `other` appends to a set it never loaded: the parent's file is read as it is
    # streamed (verified against its id), not loaded with its tree.
    child = spokemesh.Client(other.grpc).append(parent.id, new)
    assert _loaded_sets(other) == 0
    whole = spokemesh.Client(server.grpc).upload(np.vstack([old, new]))
    assert child.id == whole.id and whole.already_existed
    assert spokemesh.Client(other.grpc).star(child.id, 5).simplices.shape[1] == 4
    # A parent whose file was corrupted behind the servers' backs: the append fails
    # NOT_FOUND, the parent is quarantined, and no new set is stored.
    spoil_points = uniform(2000, 3, 13)
    spoil = spokemesh.Client(server.grpc).upload(spoil_points)
    path = server.data_dir / f"{spoil.id}.points"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0x40
    path.write_bytes(bytes(raw))
    with pytest.raises(spokemesh.Error) as e:
        spokemesh.Client(other.grpc).append(spoil.id, new)
    assert e.value.code == grpc.StatusCode.NOT_FOUND and "quarantined" in e.value.details
    assert "quarantined" in other.log() and not path.exists()
    before = {p.name for p in server.data_dir.iterdir() if p.suffix == ".points"}
    assert len(before) == 2  # the parent and its child only
