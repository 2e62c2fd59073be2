"""Voronoi cells in domains of any shape (docs/cells.md, "Domains of any shape") through
every route: the CLI (every file format), the in-process module, gRPC, REST, the
Python client and the remote CLI all give the same cells, byte for byte; the cells
tile the domain, their wall facets tile its boundary; bad domains are refused with
their fault named, with the CLI's exit code 2, gRPC INVALID_ARGUMENT and HTTP 400.
(The unit and CGAL oracle checks are tests/test_shape.cpp and test_shape_oracle.cpp;
spokemesh-mpi's bytes, tests/python/test_mpi.py.)"""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import spokemesh
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

import domain_files as df
import grpc
from conftest import CLI, cli, http, http_json


def npz(path):
    z = np.load(path)
    return {k: z[k] for k in z.files}


def same(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        nan = a[k].dtype.kind == "f"  # empty cells' centroids are NaN
        assert np.array_equal(a[k], b[k], equal_nan=nan), k


def check_tiling(z: dict, volume: float, boundary: float):
    assert abs(z["volume"].sum() - volume) <= 1e-12 * volume
    walls = z["facet_neighbor"] < 0
    assert abs(z["facet_area"][walls].sum() - boundary) <= 1e-12 * boundary
    # Each cell is closed: sum of area x normal = 0.
    owner = np.repeat(np.arange(len(z["volume"])), np.diff(z["facet_ptr"]))
    flux = np.zeros((len(z["volume"]), z["facet_normal"].shape[1]))
    np.add.at(flux, owner, z["facet_area"][:, None] * z["facet_normal"])
    assert np.abs(flux).max() <= 1e-9 * max(1.0, boundary)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("domains")
    v, f = df.l_part()
    df.write_off(d / "l.off", v, f)
    df.write_obj(d / "l.obj", v, f)
    df.write_stl(d / "l.stl", v, f, binary=False)
    df.write_stl(d / "lb.stl", v, f, binary=True)
    np.save(d / "l.npy", df.inside_l(1500, 1))
    tv, tf = df.torus()
    df.write_off(d / "torus.off", tv, tf)
    np.save(d / "torus.npy", df.inside_torus(1500, 2))
    rings, area, perimeter = df.three_holes()
    df.write_rings(d / "holes.rings", rings)
    for kind in ("Polygon", "MultiPolygon", "FeatureCollection"):
        df.write_geojson(d / f"holes-{kind}.geojson", rings, kind)
    rng = np.random.default_rng(3)
    np.save(d / "holes.npy", rng.random((2000, 2)) * 10)
    return {"dir": d, "torus": (df.mesh_volume(tv, tf), df.mesh_area(tv, tf)), "holes": (area, perimeter)}


def test_every_file_format_gives_the_same_cells_which_tile_the_domain(files):
    d = files["dir"]
    out = {}
    for name in ("l.off", "l.obj", "l.stl", "lb.stl"):
        cli("cells", str(d / "l.npy"), "--domain", str(d / name), "-o", str(d / f"{name}.npz"), "-q")
        out[name] = npz(d / f"{name}.npz")
    for name in out:
        same(out[name], out["l.off"])  # the L's coordinates are exact in float32 too
    check_tiling(out["l.off"], 3.0, 14.0)
    cli("cells", str(d / "torus.npy"), "--domain", str(d / "torus.off"), "-o", str(d / "torus.npz"), "-q")
    check_tiling(npz(d / "torus.npz"), *files["torus"])
    ring_cells = None
    for name in ("holes.rings", "holes-Polygon.geojson", "holes-MultiPolygon.geojson",
                 "holes-FeatureCollection.geojson"):
        cli("cells", str(d / "holes.npy"), "--domain", str(d / name), "-o", str(d / f"{name}.npz"), "-q")
        z = npz(d / f"{name}.npz")
        check_tiling(z, *files["holes"])
        if ring_cells is None:
            ring_cells = z
        same(z, ring_cells)


def test_seeds_outside_get_their_part_of_the_domain(files, tmp_path):
    # Points all over the L's box: those in the notch mostly get empty cells (volume 0,
    # no facets); together the cells still tile the L.
    pts = np.random.default_rng(4).uniform([0, 0, 0], [2, 2, 1], size=(800, 3))
    np.save(tmp_path / "p.npy", pts)
    cli("cells", str(tmp_path / "p.npy"), "--domain", str(files["dir"] / "l.off"), "-o", str(tmp_path / "c.npz"), "-q")
    z = npz(tmp_path / "c.npz")
    check_tiling(z, 3.0, 14.0)
    notch = (pts[:, 0] > 1) & (pts[:, 1] > 1)
    empty = z["volume"] == 0
    assert empty.sum() > 0 and (empty <= notch).all()
    assert (np.diff(z["facet_ptr"])[empty] == 0).all()


def test_cell_prints_wall_facets(files):
    d = files["dir"]
    out = json.loads(cli("cell", str(d / "l.npy"), "--seed", "5", "--domain", str(d / "l.off"), "--json").stdout)
    z = npz(d / "l.off.npz")
    assert out["volume"] == z["volume"][5]
    row = slice(z["facet_ptr"][5], z["facet_ptr"][6])
    assert [f.get("neighbor", -1 - f.get("wall", 0)) for f in out["facets"]] == z["facet_neighbor"][row].tolist()
    assert any("wall" in f for f in out["facets"]) or z["volume"][5] > 0


def test_in_process_module_equals_the_cli(files):
    d = files["dir"]
    tri = spokemesh.Delaunay(np.load(d / "l.npy"))
    same(tri.cells(domain=d / "l.off"), npz(d / "l.off.npz"))
    tri2 = spokemesh.Delaunay(np.load(d / "holes.npy"))
    same(tri2.cells(domain=("geojson", (d / "holes-Polygon.geojson").read_bytes())), npz(d / "holes.rings.npz"))
    c = tri.cell(7, domain=d / "l.stl")
    assert c.volume == npz(d / "l.off.npz")["volume"][7]
    with pytest.raises(ValueError, match="open boundary"):
        tri.cells(domain=("off", b"OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n"))


BAD = [
    ("open.off", "OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n", "open boundary"),
    ("flip.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n3 1 2 3\n3 0 3 2\n",
     "inconsistent orientation"),
    ("flat.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n2 0 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n", "zero area"),
    ("cross.off", "OFF\n8 8 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n.2 .2 .2\n1.2 .2 .2\n.2 1.2 .2\n.2 .2 1.2\n"
     "3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n3 4 6 5\n3 4 5 7\n3 5 6 7\n3 4 7 6\n", "self-intersection"),
    ("word.off", "OFF\n4 4 0\n0 0 0\n1 x 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n", "word.off:4"),
]


def test_bad_domains_are_refused_and_named_by_the_cli(files, tmp_path):
    for name, text, message in BAD:
        (tmp_path / name).write_text(text)
        r = subprocess.run([str(CLI), "cells", str(files["dir"] / "l.npy"), "--domain", str(tmp_path / name), "-o",
                            str(tmp_path / "x.npz")], capture_output=True, text=True)
        assert r.returncode == 2, (name, r.stderr)
        assert message in r.stderr and name in r.stderr, r.stderr
        assert not (tmp_path / "x.npz").exists()
    r = subprocess.run([str(CLI), "cells", str(files["dir"] / "holes.npy"), "--domain", str(files["dir"] / "l.off"),
                        "-o", str(tmp_path / "x.npz")], capture_output=True, text=True)
    assert r.returncode == 2 and "3-d" in r.stderr
    r = subprocess.run([str(CLI), "cells", str(files["dir"] / "l.npy"), "--domain", str(files["dir"] / "l.off"),
                        "-o", str(tmp_path / "x.vtu")], capture_output=True, text=True)
    assert r.returncode == 2 and "use .npz" in r.stderr
    (tmp_path / "bad.geojson").write_text('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0], "x"]]}')
    r = subprocess.run([str(CLI), "cells", str(files["dir"] / "holes.npy"), "--domain", str(tmp_path / "bad.geojson"),
                        "-o", str(tmp_path / "x.npz")], capture_output=True, text=True)
    assert r.returncode == 2 and "bad.geojson.coordinates[0][2]" in r.stderr, r.stderr


def test_service_routes_equal_the_cli(server, files, tmp_path):
    d = files["dir"]
    client = spokemesh.Client(server.grpc)
    points = np.load(d / "l.npy")
    ps = client.upload(points)
    want = npz(d / "l.off.npz")
    # StreamCells (gRPC, Python client) with the domain's bytes.
    cells = list(client.cells(ps.id, domain=d / "l.off", measures_only=True))
    assert np.array_equal(np.array([c.volume for c in cells]), want["volume"])
    flat = [(f.neighbor if f.wall is None else -1 - f.wall, f.area) for c in cells for f in c.facets]
    assert [n for n, _ in flat] == want["facet_neighbor"].tolist()
    assert np.array_equal(np.array([a for _, a in flat]), want["facet_area"])
    # GetVoronoiCell, BatchSeeds, and REST's POST routes.
    body = (d / "l.off").read_bytes()
    for seed in (0, 11, len(points) - 1):
        one = client.cell(ps.id, seed, domain=("off", body))
        assert one.volume == want["volume"][seed]
        status, rest = http_json("POST", f"{server.http}/v1/pointsets/{ps.id}/seeds/{seed}/cell?domain=off", body)
        assert status == 200 and rest["volume"] == one.volume
        assert [f.get("neighbor", -1 - f.get("wall", 0)) for f in rest["facets"]] == \
            [f.neighbor if f.wall is None else -1 - f.wall for f in one.facets]
    batch = client.batch_cells(ps.id, [3, 1, 4], domain=d / "l.stl")
    assert [c.volume for c in batch] == [want["volume"][s] for s in (3, 1, 4)]
    status, _, ndjson = http("POST", f"{server.http}/v1/pointsets/{ps.id}/cells?domain=off&measures_only=true", body)
    assert status == 200
    rows = [json.loads(line) for line in ndjson.decode().splitlines()]
    assert np.array_equal(np.array([r["volume"] for r in rows]), want["volume"])
    status, _, ndjson = http("POST", f"{server.http}/v1/pointsets/{ps.id}/cells:batch",
                             json.dumps({"seeds": [5, 6], "domain": {"format": "off", "data": body.decode()}}).encode())
    assert status == 200
    assert [json.loads(line)["volume"] for line in ndjson.decode().splitlines()] == [want["volume"][5],
                                                                                     want["volume"][6]]
    # The remote CLI writes the local one's bytes.
    cli("--server", server.grpc, "cells", ps.id, "--domain", str(d / "l.off"), "-o", str(tmp_path / "r.npz"), "-q")
    same(npz(tmp_path / "r.npz"), want)
    out = cli("--server", server.grpc, "cell", ps.id, "--seed", "9", "--domain", str(d / "l.obj"), "--json").stdout
    assert json.loads(out)["volume"] == want["volume"][9]


def test_service_refuses_bad_domains_by_name(server, files):
    client = spokemesh.Client(server.grpc)
    ps = client.upload(np.load(files["dir"] / "l.npy"))
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    for name, text, message in BAD[:4]:
        domain = pb.Domain(shape=pb.ShapeDomain(format="off", data=text.encode()))
        with pytest.raises(grpc.RpcError) as e:
            stub.GetVoronoiCell(pb.GetVoronoiCellRequest(point_set_id=ps.id, seed=0, domain=domain), timeout=30)
        assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and message in e.value.details()
        status, body = http_json("POST", f"{server.http}/v1/pointsets/{ps.id}/seeds/0/cell?domain=off", text.encode())
        assert status == 400 and message in body["error"]["message"]
    domain = pb.Domain(shape=pb.ShapeDomain(format="dxf", data=b""))
    with pytest.raises(grpc.RpcError) as e:
        stub.GetVoronoiCell(pb.GetVoronoiCellRequest(point_set_id=ps.id, seed=0, domain=domain), timeout=30)
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "not one of off, obj" in e.value.details()
    holes = (files["dir"] / "holes.rings").read_bytes()
    status, body = http_json("POST", f"{server.http}/v1/pointsets/{ps.id}/seeds/0/cell?domain=rings", holes)
    assert status == 400 and "2-d" in body["error"]["message"]
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/0/cell?domain=off")
    assert status == 400 and "POST" in body["error"]["message"]
    # A number beyond double's range in GeoJSON (once a crash, found by fuzz_domains).
    status, body = http_json("POST", f"{server.http}/v1/domains:check?domain=geojson",
                             b'{"type": "Polygon", "coordinates": [[[0, 0], [609E609, 0], [0, 1]]]}')
    assert status == 400 and "number overflow" in body["error"]["message"]
    status, checked = http_json("POST", f"{server.http}/v1/domains:check?domain=rings", holes)
    assert status == 200 and checked["components"] == 4 and checked["dimension"] == 2
    assert abs(checked["volume"] - df.three_holes()[1]) < 1e-12 * checked["volume"]
