"""Answers at points that need not be in the set: REST :locate, :interpolate and
.../values, gRPC Locate, Interpolate and PutValues, and the Python Client. Every route
gives the in-process module's answer, the same bytes from any replica and batch; bad
input is named."""

from __future__ import annotations

import json

import grpc
import numpy as np
import pytest
import spokemesh
from spokemesh.interpolate import (LinearNDInterpolator, NaturalNeighborInterpolator, NearestNDInterpolator,
                                   natural_neighbor_coordinates)
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

from conftest import http, http_json, uniform


def ndjson(answer):
    status, headers, body = answer
    assert status == 200, body[:500]
    assert headers["Content-Type"] == "application/x-ndjson"
    return [json.loads(line) for line in body.decode().splitlines()]


def rest_lines(server, set_id, route, body):
    status, _, data = http("POST", f"{server.http}/v1/pointsets/{set_id}:{route}", body)
    assert status == 200, data[:500]
    return data.decode().splitlines()


def queries_for(points, m, seed):
    """Random points in the set's box and beyond it, some of the set's own points, and
    (for grids) points on shared edges and vertices."""
    rng = np.random.default_rng(seed)
    lo, hi = points.min(0), points.max(0)
    q = lo - 0.1 * (hi - lo) + rng.random((m, points.shape[1])) * 1.2 * (hi - lo)
    return np.vstack([q, points[:5], (points[0] + points[1]) / 2])


def grid(k, d):
    axes = np.meshgrid(*[np.arange(k, dtype=float)] * d, indexing="ij")
    return np.stack([a.ravel() for a in axes], axis=1)


@pytest.mark.parametrize("d", [2, 3])
def test_locate_equals_in_process_and_is_canonical(server, d):
    points = uniform(4000, d, seed=7 + d)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    xi = queries_for(points, 400, seed=d)
    got = client.locate(ps.id, xi)
    tri = spokemesh.Delaunay(points)
    # Natural neighbours: the in-process pairs, bit for bit.
    expected = natural_neighbor_coordinates(tri, xi)
    for i, ((ids, w), (eids, ew)) in enumerate(zip(got.natural, expected)):
        assert np.array_equal(ids, eids) and np.array_equal(w, ew), f"query {i}: {xi[i]}"
    # The simplex: one of the triangulation's, holding the point; none outside the hull.
    found = tri.find_simplex(xi)
    rows = {tuple(sorted(r)) for r in tri.simplices.tolist()}
    for i in range(len(xi)):
        if found[i] < 0:
            assert (got.simplices[i] == -1).all() and np.isnan(got.barycentric[i]).all()
            continue
        assert tuple(got.simplices[i]) in rows
        assert list(got.simplices[i]) == sorted(got.simplices[i])
        b = got.barycentric[i]
        assert abs(b.sum() - 1) < 1e-12 and b.min() > -1e-12
        assert np.allclose(b @ points[got.simplices[i]], xi[i], atol=1e-12)
    # REST: the same answers, and the same bytes whatever the batch.
    lines = rest_lines(server, ps.id, "locate", {"queries": xi.tolist()})
    assert len(lines) == len(xi)
    for i in range(0, len(xi), 37):
        one = rest_lines(server, ps.id, "locate", {"queries": [xi[i].tolist()]})[0]
        assert one.replace('"index":0,', f'"index":{i},', 1) == lines[i]
    for i, line in enumerate(lines):
        a = json.loads(line)
        assert a["index"] == i
        assert (a["simplex"] or [-1] * (d + 1)) == got.simplices[i].tolist()
        assert a["natural_neighbors"] == got.natural[i][0].tolist() and a["weights"] == got.natural[i][1].tolist()
    flat = rest_lines(server, ps.id, "locate", {"queries": xi.ravel().tolist(), "natural": False})
    assert [json.loads(x)["simplex"] for x in flat] == [json.loads(x)["simplex"] for x in lines]
    assert "natural_neighbors" not in json.loads(flat[0])


@pytest.mark.parametrize("d", [2, 3])
def test_points_on_shared_faces_get_the_least_simplex(server, d):
    """A grid: query points on shared edges, faces and vertices lie in several simplices;
    the answer is the least by ascending vertex list (brute force over every simplex)."""
    points = grid(6 if d == 2 else 4, d)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    rng = np.random.default_rng(3)
    xi = np.vstack([points[rng.integers(0, len(points), 30)] + 0.5 * rng.integers(0, 2, (30, d)),
                    points[:8] + 0.25])
    xi = np.clip(xi, 0, points.max())
    got = client.locate(ps.id, xi)
    tri = spokemesh.Delaunay(points)
    for i, q in enumerate(xi):
        holding = []
        for row in tri.simplices:
            m = np.vstack([points[row].T, np.ones(d + 1)])
            b = np.linalg.solve(m, np.append(q, 1))
            if b.min() > -1e-9:
                holding.append(tuple(sorted(row.tolist())))
        assert tuple(got.simplices[i]) == min(holding), f"query {q}: {got.simplices[i]} of {sorted(holding)}"
        ids, w = got.natural[i]
        assert w.min() >= 0 and abs(w.sum() - 1) < 1e-12
        assert np.allclose(w @ points[ids], q, atol=1e-12)


def test_interpolate_every_route_equals_in_process(server):
    points = uniform(5000, 2, seed=31)
    rng = np.random.default_rng(4)
    values = np.stack([np.sin(3 * points[:, 0]) + points[:, 1] ** 2, 2 * points[:, 0] - points[:, 1] + 0.5], axis=1)
    xi = queries_for(points, 500, seed=5)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    tri = spokemesh.Delaunay(points)
    natural = client.interpolate(ps.id, xi, values, method="natural")
    assert natural.shape == (len(xi), 2)
    assert np.array_equal(natural, NaturalNeighborInterpolator(tri, values)(xi), equal_nan=True)
    # Linear functions are reproduced (Sibson's coordinates reproduce them).
    inside = ~np.isnan(natural[:, 1])
    assert np.abs(natural[inside, 1] - (2 * xi[inside, 0] - xi[inside, 1] + 0.5)).max() < 1e-12
    linear = client.interpolate(ps.id, xi, values, method="linear", fill_value=-7.0)
    scipy_like = LinearNDInterpolator(tri, values, fill_value=-7.0)(xi)
    assert np.allclose(linear, scipy_like, rtol=0, atol=1e-12)
    nearest = client.interpolate(ps.id, xi, values[:, 0], method="nearest")
    assert nearest.shape == (len(xi),)
    assert np.array_equal(nearest, NearestNDInterpolator(points, values[:, 0])(xi))
    # Kept values: put once (gRPC and REST give the same id), then named.
    values_id = client.put_values(ps.id, values)
    status, info = http_json("POST", f"{server.http}/v1/pointsets/{ps.id}/values", {"values": values.tolist()})
    assert status == 200 and info["values_id"] == values_id and info["already_existed"] and info["width"] == 2
    assert np.array_equal(client.interpolate(ps.id, xi, values_id=values_id), natural, equal_nan=True)
    # REST: the same numbers, inline or kept; null outside the hull without a fill.
    for body in ({"values": values.tolist()}, {"values_id": values_id}):
        lines = [json.loads(x) for x in rest_lines(server, ps.id, "interpolate", {"queries": xi.tolist(), **body})]
        for i, a in enumerate(lines):
            assert a["index"] == i
            if np.isnan(natural[i, 0]):
                assert a["values"] is None
            else:
                assert a["values"] == natural[i].tolist()
    lines = rest_lines(server, ps.id, "interpolate",
                       {"queries": xi.tolist(), "values": values[:, 0].tolist(), "method": "nearest"})
    assert [json.loads(x)["values"][0] for x in lines] == nearest.tolist()
    assert all("nearest" in json.loads(x) for x in lines)
    flat = rest_lines(server, ps.id, "interpolate",
                      {"queries": xi.tolist(), "values": values.ravel().tolist(), "width": 2, "method": "linear",
                       "fill_value": -7.0})
    assert [json.loads(x)["values"] for x in flat] == linear.tolist()


def test_answers_equal_across_replicas_and_3d_values(start_server, tmp_path):
    """Two replicas with their own data directories give the same bytes."""
    a = start_server(data_dir=tmp_path / "a", name="a")
    b = start_server(data_dir=tmp_path / "b", name="b")
    points = uniform(3000, 3, seed=12)
    values = points @ np.array([1.0, -2.0, 0.5]) + 3
    xi = queries_for(points, 300, seed=9)
    answers = []
    for server in (a, b):
        ps = spokemesh.Client(server.grpc).upload(points)
        answers.append((rest_lines(server, ps.id, "locate", {"queries": xi.tolist()}),
                        rest_lines(server, ps.id, "interpolate", {"queries": xi.tolist(), "values": values.tolist()})))
    assert answers[0] == answers[1]
    got = np.array([np.nan if json.loads(x)["values"] is None else json.loads(x)["values"][0] for x in answers[0][1]])
    inside = ~np.isnan(got)
    assert inside.sum() > 150
    assert np.abs(got[inside] - (xi[inside] @ np.array([1.0, -2.0, 0.5]) + 3)).max() < 1e-12


def test_above_3d_linear_and_locate(server):
    points = uniform(400, 4, seed=2)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    xi = queries_for(points, 50, seed=1)
    got = client.locate(ps.id, xi)
    assert got.natural is None
    found = spokemesh.Delaunay(points).find_simplex(xi)
    assert ((got.simplices[:, 0] >= 0) == (found >= 0)).all()
    f = points @ np.array([1.0, 2.0, 3.0, 4.0])
    lin = client.interpolate(ps.id, xi, f)  # linear is the default above 3-d
    inside = found >= 0
    assert np.abs(lin[inside] - xi[inside] @ np.array([1.0, 2.0, 3.0, 4.0])).max() < 1e-11
    with pytest.raises(spokemesh.Error) as e:
        client.interpolate(ps.id, xi, f, method="natural")
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "method" in e.value.details


def test_bad_input_is_named(server):
    points = uniform(500, 2, seed=3)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    url = f"{server.http}/v1/pointsets/{ps.id}"
    cases = [
        (":locate", {}, "queries: required"),
        (":locate", {"queries": [[0.5, 0.5], [0.1, "a"]]}, "queries[1][1]"),
        (":locate", {"queries": [[0.5, 0.5, 0.5]]}, "queries[0]: 3 coordinates"),
        (":locate", {"queries": [0.5, 0.5, 0.5]}, "not whole 2-d points"),
        (":locate", {"queries": [[0.5, 0.5]], "natural": 3}, "natural"),
        (":interpolate", {"queries": [[0.5, 0.5]], "values": [1.0] * 499}, "values: expected 500 rows"),
        (":interpolate", {"queries": [[0.5, 0.5]], "values": [1.0] * 500, "method": "cubic"}, "method"),
        (":interpolate", {"queries": [[0.5, 0.5]], "values_id": "0" * 64}, "values_id"),
        (":interpolate", {"queries": [[0.5, 0.5]], "values": [[1.0, 2.0]] * 499 + [[1.0]]}, "values[499]"),
        (":interpolate", {"queries": [[0.5, 0.5]], "values": [[1.0, 2.0]] * 499 + [1.0]}, "numbers and rows mixed"),
        (":locate", {"queries": [[]]}, "queries[0]: an empty row"),
        ("/values", {"values": [1.0] * 3}, "values: expected 500 rows"),
    ]
    for route, body, named in cases:
        status, answer = http_json("POST", url + route, body)
        assert status in (400, 404), (route, body, answer)
        assert named in answer["error"]["message"], (named, answer)
    status, answer = http_json("POST", f"{server.http}/v1/pointsets/{'f' * 64}:locate", {"queries": [[0, 0]]})
    assert status == 404
    # Over gRPC: a NaN coordinate, named; a periodic set refused.
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    with pytest.raises(grpc.RpcError) as e:
        list(stub.Locate(pb.LocateRequest(point_set_id=ps.id, queries=[0.5, 0.5, 0.2, float("nan")])))
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "queries[1][1]" in e.value.details()
    torus = client.upload(uniform(200, 2, seed=4), periodic=[[0, 0], [1, 1]])
    with pytest.raises(spokemesh.Error) as e2:
        client.locate(torus.id, [[0.5, 0.5]])
    assert e2.value.code == grpc.StatusCode.FAILED_PRECONDITION and "periodic" in e2.value.details
    # Kept values go with their set.
    values_id = client.put_values(ps.id, points[:, 0])
    client.delete(ps.id)
    ps = client.upload(points)
    with pytest.raises(spokemesh.Error) as e3:
        client.interpolate(ps.id, [[0.5, 0.5]], values_id=values_id)
    assert e3.value.code == grpc.StatusCode.NOT_FOUND and "values_id" in e3.value.details
