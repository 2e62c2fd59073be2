"""Clipped Voronoi cells and their measures through every way users reach
them: the CLI's `cell` and `cells` (.npz, .vtu), GetVoronoiCell and StreamCells over
gRPC, the REST routes, the Python client and the remote CLI. scipy's ConvexHull of the
clipped vertices is the oracle for volumes, surface areas and centroids."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import spokemesh
from scipy.spatial import ConvexHull
from spokemesh.v1 import mesher_pb2 as pb
from spokemesh.v1 import mesher_pb2_grpc as pb_grpc

import grpc
from conftest import cli, http, http_json, missing, uniform


def box_of(d: int, lo: float = 0.0, hi: float = 1.0) -> str:
    return ",".join([str(lo)] * d + [str(hi)] * d)


def check_npz(z, n: int, d: int, volume: float) -> None:
    """The tiling invariants on a .npz: volumes sum to the domain's, each facet i->j
    has a partner j->i of equal area and opposite normal, and every cell is closed
    (sum of area x normal = 0)."""
    assert z["volume"].shape == (n,) and z["centroid"].shape == (n, d) and z["facet_ptr"].shape == (n + 1,)
    m = z["facet_ptr"][-1]
    assert z["facet_neighbor"].shape == (m,) and z["facet_area"].shape == (m,) and z["facet_normal"].shape == (m, d)
    assert z["bounded"].all()
    assert abs(z["volume"].sum() - volume) <= 1e-12 * volume
    owner = np.repeat(np.arange(n), np.diff(z["facet_ptr"]))
    nb = z["facet_neighbor"]
    inner = nb >= 0
    pairs = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(owner, nb)) if j >= 0}
    for (i, j), k in pairs.items():
        back = pairs[(j, i)]
        assert abs(z["facet_area"][k] - z["facet_area"][back]) <= 1e-11
        assert np.allclose(z["facet_normal"][k], -z["facet_normal"][back], rtol=0, atol=1e-14)
    flux = np.zeros((n, d))
    np.add.at(flux, owner, z["facet_area"][:, None] * z["facet_normal"])
    assert np.abs(flux).max() <= 1e-11
    assert (nb[~inner] >= -2 * d).all()  # box walls -1 .. -2d


@pytest.mark.parametrize("d,n", [(2, 400), (3, 300), (4, 120)])
def test_cells_npz_tiles_the_box_and_agrees_with_scipy(tmp_path, d, n):
    points = uniform(n, d, seed=10 + d)
    src = tmp_path / "p.npy"
    np.save(src, points)
    out = tmp_path / "cells.npz"
    r = cli("cells", str(src), "-o", str(out), "--box", box_of(d), "--threads", "2")
    assert f"{n} cells" in r.stderr
    z = np.load(out)
    check_npz(z, n, d, 1.0)
    # Per seed: the CLI's vertices, hulled by scipy (Qhull), give the same measures.
    for seed in range(0, n, max(1, n // 12)):
        cell = json.loads(cli("cell", str(src), "--seed", str(seed), "--box", box_of(d), "--json").stdout)
        assert cell["clipped"] and cell["bounded"]
        hull = ConvexHull(np.array([v["position"] for v in cell["vertices"]]))
        assert abs(hull.volume - cell["volume"]) <= 1e-9 * hull.volume
        assert abs(hull.area - sum(f["area"] for f in cell["facets"])) <= 1e-9 * hull.area
        assert cell["volume"] == z["volume"][seed]
        assert np.array_equal(np.array(cell["centroid"]), z["centroid"][seed])
        begin, end = z["facet_ptr"][seed], z["facet_ptr"][seed + 1]
        got = [f.get("neighbor", -1 - f.get("wall", 0)) for f in cell["facets"]]
        assert got == z["facet_neighbor"][begin:end].tolist()
        # The centroid: scipy's hull, split into simplices from its first vertex.
        pts = hull.points
        apex = pts[hull.vertices[0]]
        vol, moment = 0.0, np.zeros(d)
        for simplex in hull.simplices:
            corners = np.vstack([apex, pts[simplex]])
            v = abs(np.linalg.det(corners[1:] - corners[0])) / np.math.factorial(d)
            vol += v
            moment += v * corners.mean(axis=0)
        assert np.allclose(moment / vol, cell["centroid"], rtol=0, atol=1e-9)


def test_cells_default_domain_is_the_bounding_box_and_vtu_is_valid(tmp_path):
    points = uniform(500, 3, seed=3)
    src = tmp_path / "p.npy"
    np.save(src, points)
    z_out, v_out = tmp_path / "c.npz", tmp_path / "c.vtu"
    cli("cells", str(src), "-o", str(z_out), "-q")
    z = np.load(z_out)
    volume = float(np.prod(points.max(axis=0) - points.min(axis=0)))
    check_npz(z, 500, 3, volume)
    cli("cells", str(src), "-o", str(v_out), "-q")
    piece = ET.parse(v_out).getroot().find("UnstructuredGrid/Piece")
    assert piece.get("NumberOfCells") == "500"
    arrays = {a.get("Name"): a.text.split() for a in piece.iter("DataArray") if a.get("Name")}
    assert set(arrays["types"]) == {"42"}  # VTK_POLYHEDRON
    assert np.allclose(np.array(arrays["volume"], dtype=float), z["volume"], rtol=1e-15, atol=0)
    # The faces stream: per cell its face count, then each face's size and points.
    faces = np.array(arrays["faces"], dtype=np.int64)
    offsets = np.array(arrays["faceoffsets"], dtype=np.int64)
    assert offsets[-1] == len(faces)
    # 2-d: polygons.
    p2 = tmp_path / "p2.npy"
    np.save(p2, uniform(200, 2, seed=4))
    cli("cells", str(p2), "-o", str(tmp_path / "c2.vtu"), "-q")
    piece = ET.parse(tmp_path / "c2.vtu").getroot().find("UnstructuredGrid/Piece")
    assert {a.get("Name"): a.text.split() for a in piece.iter("DataArray") if a.get("Name")}["types"] == ["7"] * 200


def test_cells_errors_name_what_and_where(tmp_path):
    src = tmp_path / "p.npy"
    np.save(src, uniform(100, 2, seed=5))
    r = cli("cells", str(src), "-o", str(tmp_path / "x.npz"), "--box", "0,0,0.5,0.5", check=False)
    assert r.returncode == 2 and "lies outside the domain" in r.stderr and "seed " in r.stderr
    assert not (tmp_path / "x.npz").exists()
    r = cli("cells", str(src), "-o", str(tmp_path / "x.npz"), "--box", "0,0,1", check=False)
    assert r.returncode == 2 and "--box" in r.stderr
    r = cli("cells", str(src), "-o", str(tmp_path / "x.vtk"), check=False)
    assert r.returncode == 2 and "unknown cell format" in r.stderr
    np.save(tmp_path / "p4.npy", uniform(50, 4, seed=6))
    r = cli("cells", str(tmp_path / "p4.npy"), "-o", str(tmp_path / "x.vtu"), check=False)
    assert r.returncode == 2 and ".vtu" in r.stderr and "4-d" in r.stderr
    walls = tmp_path / "walls.txt"
    walls.write_text("# a.x <= b\n1 0 1\n0 1 1\n-1 0 0\n0 -1 zero\n")
    r = cli("cells", str(src), "-o", str(tmp_path / "x.npz"), "--halfspaces", str(walls), check=False)
    assert r.returncode == 2 and "walls.txt:5" in r.stderr and "'zero'" in r.stderr
    r = cli("cells", str(src), "-o", str(src), check=False)
    assert r.returncode == 2 and "would overwrite the input" in r.stderr


def test_halfspace_domain_from_a_file(tmp_path):
    # A triangle x >= 0, y >= 0, x + y <= 1.
    points = uniform(2000, 2, seed=7)
    points = points[points.sum(axis=1) <= 1][:400]
    src = tmp_path / "p.npy"
    np.save(src, points)
    walls = tmp_path / "triangle.txt"
    walls.write_text("-1 0 0\n0 -1 0\n1 1 1\n")
    out = tmp_path / "c.npz"
    cli("cells", str(src), "-o", str(out), "--halfspaces", str(walls), "-q")
    z = np.load(out)
    assert abs(z["volume"].sum() - 0.5) <= 1e-12
    assert set(z["facet_neighbor"][z["facet_neighbor"] < 0].tolist()) == {-1, -2, -3}
    # The hypotenuse wall's pieces sum to its length.
    assert abs(z["facet_area"][z["facet_neighbor"] == -3].sum() - np.sqrt(2)) <= 1e-12


def test_cells_over_grpc_rest_python_and_remote_cli_equal_the_local_ones(server, tmp_path):
    points = uniform(600, 3, seed=8)
    src = tmp_path / "p.npy"
    np.save(src, points)
    local = tmp_path / "local.npz"
    cli("cells", str(src), "-o", str(local), "--box", box_of(3), "-q")
    z = np.load(local)
    client = spokemesh.Client(server.grpc)
    ps = client.upload(points)
    box = [0, 0, 0, 1, 1, 1]

    # StreamCells through the Python client, in two shards, measures only.
    cells = [c for k in range(2) for c in client.cells(ps.id, box=box, shard_index=k, shard_count=2, measures_only=True)]
    assert [c.seed for c in cells] == list(range(600))
    assert np.array_equal(np.array([c.volume for c in cells]), z["volume"])
    assert np.array_equal(np.array([c.centroid for c in cells]), z["centroid"])
    flat = [(f.neighbor if f.wall is None else -1 - f.wall, f.area) for c in cells for f in c.facets]
    assert [n for n, _ in flat] == z["facet_neighbor"].tolist()
    assert np.array_equal(np.array([a for _, a in flat]), z["facet_area"])

    # GetVoronoiCell (gRPC, REST, client) equals the local CLI's `cell`.
    for seed in (0, 17, 599):
        local_cell = json.loads(cli("cell", str(src), "--seed", str(seed), "--box", box_of(3), "--json").stdout)
        one = client.cell(ps.id, seed, box=box)
        rest = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/{seed}/cell?box=0,0,0,1,1,1")[1]
        assert one.volume == rest["volume"] == local_cell["volume"] == z["volume"][seed]
        assert np.array_equal(one.vertices, np.array(rest["vertices"]))
        assert np.array_equal(one.vertices, np.array([v["position"] for v in local_cell["vertices"]]))
        assert [f.get("neighbor", -1 - f.get("wall", 0)) for f in rest["facets"]] == \
            [f.neighbor if f.wall is None else -1 - f.wall for f in one.facets]
        streamed = next(c for c in client.cells(ps.id, box=box) if c.seed == seed)
        assert np.array_equal(streamed.vertices, one.vertices) and streamed.volume == one.volume

    # The unit cube as six halfspaces, in the box's wall order, gives the same cells:
    # the same facets (exact), and measures equal to rounding (a 3-d box is clipped
    # directly by bisectors, halfspaces clip the cell built from the star).
    cube = np.array([[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])
    for seed in (3, 300):
        a, b = client.cell(ps.id, seed, halfspaces=cube), client.cell(ps.id, seed, box=box)
        assert a.volume == pytest.approx(b.volume, rel=1e-12)
        assert np.allclose(a.centroid, b.centroid, rtol=0, atol=1e-13)
        assert [(f.wall, f.neighbor) for f in a.facets] == [(f.wall, f.neighbor) for f in b.facets]
        assert np.allclose([f.area for f in a.facets], [f.area for f in b.facets], rtol=1e-10, atol=1e-16)
    flat_h = ",".join(str(v) for v in cube.ravel())
    rest = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/3/cell?halfspaces={flat_h}")[1]
    assert rest["volume"] == pytest.approx(z["volume"][3], rel=1e-12)

    # REST NDJSON /cells: one object per line, in seed order.
    status, headers, body = http("GET", f"{server.http}/v1/pointsets/{ps.id}/cells?box=0,0,0,1,1,1&measures_only=true")
    assert status == 200 and headers["Content-Type"] == "application/x-ndjson"
    rows = [json.loads(line) for line in body.decode().splitlines()]
    assert [r["seed"] for r in rows] == list(range(600))
    assert np.array_equal(np.array([r["volume"] for r in rows]), z["volume"])

    # The remote CLI writes the same arrays as the local one.
    remote = tmp_path / "remote.npz"
    cli("--server", server.grpc, "cells", ps.id, "-o", str(remote), "--box", box_of(3), "-q")
    r = np.load(remote)
    for name in z.files:
        assert np.array_equal(r[name], z[name]), name
    out = cli("--server", server.grpc, "cell", ps.id, "--seed", "17", "--box", box_of(3), "--json").stdout
    assert json.loads(out)["volume"] == z["volume"][17]

    # Default domain of a stream: the bounding box.
    volume = float(np.prod(points.max(axis=0) - points.min(axis=0)))
    total = sum(c.volume for c in client.cells(ps.id, measures_only=True))
    assert abs(total - volume) <= 1e-12 * volume


def test_cell_domain_errors_over_both_transports(server):
    client = spokemesh.Client(server.grpc)
    points = uniform(100, 2, seed=9)
    ps = client.upload(points)
    stub = pb_grpc.MesherStub(grpc.insecure_channel(server.grpc))
    bad = [
        (pb.Domain(box=[0, 0, 1]), "domain.box"),
        (pb.Domain(box=[0, 0, 0.5, 0.5]), "lies outside the domain"),
        (pb.Domain(halfspaces=[1, 0]), "domain.halfspaces"),
        (pb.Domain(halfspaces=[0, 0, 1]), "zero normal"),
        (pb.Domain(box=[0, 0, 1, 1], bounding_box=True), "one of box, halfspaces, bounding_box and shape"),
    ]
    seed = int(np.argmax(points.max(axis=1)))  # beyond [0, 0.5]^2
    for domain, message in bad:
        with pytest.raises(grpc.RpcError) as e:
            stub.GetVoronoiCell(pb.GetVoronoiCellRequest(point_set_id=ps.id, seed=seed, domain=domain), timeout=30)
        assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT, e.value.details()
        assert message in e.value.details()
        if "outside" in message:
            assert f"seed {seed} " in e.value.details()
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/0/cell?box=0,0,x,1")
    assert status == 400 and "box" in body["error"]["message"]
    status, body = http_json("GET", f"{server.http}/v1/pointsets/{ps.id}/seeds/0/cell?box=0,0,1")
    assert status == 400 and "domain.box" in body["error"]["message"]
    status, _, body = http("GET", f"{server.http}/v1/pointsets/{ps.id}/cells?batch_size=5000")
    assert status == 400 and b"batch_size" in body
    with pytest.raises(spokemesh.Error) as e:
        list(client.cells(ps.id, box=[0.4, 0.4, 0.5, 0.5]))
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "lies outside the domain" in e.value.details


# --- Power (Laguerre) cells: weighted points ------------------------------

def voro(points: np.ndarray, tmp_path, radii=None, periodic: bool = False, lo: float = 0.0, hi: float = 1.0) -> dict:
    """Voro++'s cells of the particles in the cube [lo, hi]^3 ({id: (volume, neighbours)},
    walls left out): -r with radii (radical, i.e. power, cells), -p for a periodic cube.
    Voro++ leaves out the particles whose cells are empty."""
    import shutil
    import subprocess
    if shutil.which("voro++") is None:
        missing("Voro++", "voro++")
    src = tmp_path / "voro.txt"
    with open(src, "w") as f:
        for i, p in enumerate(points):
            f.write(f"{i} {p[0]!r} {p[1]!r} {p[2]!r}" + ("\n" if radii is None else f" {radii[i]!r}\n"))
    flags = (["-r"] if radii is not None else []) + (["-p"] if periodic else [])
    subprocess.run(["voro++", *flags, "-c", "%i %v %n", *([repr(lo), repr(hi)] * 3), str(src)], check=True)
    out = {}
    for line in open(str(src) + ".vol"):
        t = line.split()
        out[int(t[0])] = (float(t[1]), {int(x) for x in t[2:] if int(x) >= 0})
    return out


def match_voro(z: dict, theirs: dict, n: int) -> int:
    """Asserts that each cell of a cells .npz has Voro++'s neighbour set (walls left out)
    and volume (to its printed digits), and that the cells Voro++ leaves out are empty
    here (volume 0, no facets); returns how many it left out."""
    ptr, nb, vol = z["facet_ptr"], z["facet_neighbor"], z["volume"]
    empty = 0
    for i in range(n):
        mine = {int(j) for j in nb[ptr[i]:ptr[i + 1]] if j >= 0}
        if i not in theirs:
            empty += 1
            assert vol[i] == 0 and ptr[i] == ptr[i + 1], f"cell {i}: Voro++ finds it empty"
            continue
        v, nbs = theirs[i]
        assert mine == nbs, f"cell {i}: neighbours {sorted(mine ^ nbs)} differ from Voro++'s"
        assert abs(vol[i] - v) <= 5e-6 * max(v, 1e-300) + 1e-12, f"cell {i}: volume {vol[i]} against {v}"
    return empty


def voro_radical(points: np.ndarray, radii: np.ndarray, tmp_path) -> dict:
    return voro(points, tmp_path, radii=radii)


@pytest.mark.parametrize("top", [0.02, 0.06])
def test_power_cells_equal_voro_radical_cells(tmp_path, top):
    """`spokemesh cells --radii` against `voro++ -r` on the same particles: the same
    neighbour sets and volumes to Voro++'s printed digits; the cells Voro++ leaves out
    (empty) are ours with volume 0 and no facets; the volumes tile the box."""
    rng = np.random.default_rng(61)
    n = 3000
    pts, radii = rng.random((n, 3)), rng.random(n) * top
    np.savetxt(tmp_path / "p.txt", pts, fmt="%.17g")
    np.savetxt(tmp_path / "r.txt", radii, fmt="%.17g")
    cli("cells", str(tmp_path / "p.txt"), "--radii", str(tmp_path / "r.txt"), "--box", box_of(3),
        "-o", str(tmp_path / "c.npz"), "-q")
    z = dict(np.load(tmp_path / "c.npz"))  # (an NpzFile reads an array again at every access)
    check_npz(z, n, 3, 1.0)
    empty = match_voro(z, voro_radical(pts, radii, tmp_path), n)
    if top > 0.05:
        assert empty > 10, "the larger radii should empty some cells"


def test_power_cells_of_equal_weights_are_the_voronoi_cells_and_cell_says_hidden(tmp_path):
    pts = uniform(500, 3, 62)
    np.savetxt(tmp_path / "p.txt", pts, fmt="%.17g")
    np.savetxt(tmp_path / "w.txt", np.full(500, 0.01), fmt="%.17g")
    cli("cells", str(tmp_path / "p.txt"), "--weights", str(tmp_path / "w.txt"), "-o", str(tmp_path / "w.npz"), "-q")
    cli("cells", str(tmp_path / "p.txt"), "-o", str(tmp_path / "u.npz"), "-q")
    w, u = np.load(tmp_path / "w.npz"), np.load(tmp_path / "u.npz")
    assert np.array_equal(w["facet_ptr"], u["facet_ptr"]) and np.array_equal(w["facet_neighbor"], u["facet_neighbor"])
    assert np.allclose(w["volume"], u["volume"], rtol=1e-12, atol=0)
    # A point inside a heavy neighbour's sphere is hidden: `cell` says so.
    grid = np.array([[x, y] for x in range(3) for y in range(3)], dtype=float)
    np.savetxt(tmp_path / "g.txt", grid)
    weights = np.zeros(9)
    weights[4] = -2.0
    np.savetxt(tmp_path / "gw.txt", weights)
    out = cli("cell", str(tmp_path / "g.txt"), "--seed", "4", "--weights", str(tmp_path / "gw.txt"), "--json")
    cell = json.loads(out.stdout)
    assert cell["hidden"] is True and cell["volume"] == 0 and cell["facets"] == [] and cell["vertices"] == []
    out = cli("cell", str(tmp_path / "g.txt"), "--seed", "1", "--weights", str(tmp_path / "gw.txt"), "--json",
              "--box", "0,0,2,2")
    cell = json.loads(out.stdout)
    assert 4 not in [f.get("neighbor") for f in cell["facets"]]


# --- Periodic cells: the flat torus ---------------------------------------

@pytest.mark.parametrize("box", [(0.0, 1.0), (-2.0, 3.0)])
def test_periodic_cells_equal_voro_periodic_cells(tmp_path, box):
    """`spokemesh cells --periodic` against `voro++ -p` on the same particles: the same
    neighbour sets and volumes to Voro++'s printed digits; the volumes sum to the box's;
    each facet's offset puts the neighbour's image where the facet's normal points
    (the facet lies on the bisector of the seed and that image), and each facet i->j at
    offset k has its partner j->i at offset -k with the same area."""
    lo, hi = box
    side = hi - lo
    rng = np.random.default_rng(71)
    n = 3000
    pts = lo + rng.random((n, 3)) * side
    pts[pts >= hi] = lo
    np.savetxt(tmp_path / "p.txt", pts, fmt="%.17g")
    box_text = ",".join([repr(lo)] * 3 + [repr(hi)] * 3)
    cli("cells", str(tmp_path / "p.txt"), "--periodic", box_text, "-o", str(tmp_path / "c.npz"), "-q")
    z = dict(np.load(tmp_path / "c.npz"))
    ptr, nb, vol, off = z["facet_ptr"], z["facet_neighbor"], z["volume"], z["facet_offset"]
    assert off.shape == (ptr[-1], 3) and off.dtype == np.int32
    assert abs(vol.sum() - side ** 3) <= 1e-12 * side ** 3
    owner = np.repeat(np.arange(n), np.diff(ptr))
    image = pts[nb] + off * side
    towards = image - pts[owner]
    towards /= np.linalg.norm(towards, axis=1)[:, None]
    assert np.abs(towards - z["facet_normal"]).max() < 1e-9
    pairs = {(int(i), int(j), tuple(k)): a for i, j, k, a in zip(owner, nb, off.tolist(), z["facet_area"])}
    for (i, j, k), a in pairs.items():
        back = pairs[(j, i, tuple(-x for x in k))]
        assert abs(back - a) <= 1e-9 * a
    assert match_voro(z, voro(pts, tmp_path, periodic=True, lo=lo, hi=hi), n) == 0


def test_periodic_cells_refuse_what_does_not_apply(tmp_path):
    pts = uniform(200, 3, 72)
    np.savetxt(tmp_path / "p.txt", pts, fmt="%.17g")
    for extra, needle in [(["--box", box_of(3)], "do not apply"),
                          (["--periodic", "0,0,0,0.5,1,1"], "lies outside the periodic box"),
                          (["--periodic", "0,0,1,1"], "3-d points")]:
        args = ["cells", str(tmp_path / "p.txt"), "-o", str(tmp_path / "x.npz")] + extra
        if "--periodic" not in extra:
            args += ["--periodic", box_of(3)]
        done = cli(*args, check=False)
        assert done.returncode == 2 and needle in done.stderr, done.stderr
        assert not (tmp_path / "x.npz").exists()


def test_periodic_power_cells_equal_voro_periodic_radical_cells(tmp_path):
    """`spokemesh cells --periodic --radii` against `voro++ -p -r`: the same neighbour
    sets and volumes; the cells Voro++ leaves out (empty) are ours with volume 0 and no
    facets; the volumes sum to the box's."""
    rng = np.random.default_rng(73)
    n = 3000
    pts, radii = rng.random((n, 3)), rng.random(n) * 0.04
    np.savetxt(tmp_path / "p.txt", pts, fmt="%.17g")
    np.savetxt(tmp_path / "r.txt", radii, fmt="%.17g")
    cli("cells", str(tmp_path / "p.txt"), "--radii", str(tmp_path / "r.txt"), "--periodic", box_of(3),
        "-o", str(tmp_path / "c.npz"), "-q")
    z = dict(np.load(tmp_path / "c.npz"))
    assert abs(z["volume"].sum() - 1) <= 1e-12
    empty = match_voro(z, voro(pts, tmp_path, radii=radii, periodic=True), n)
    assert empty > 3, "the radii should empty some cells"
