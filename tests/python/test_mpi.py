"""spokemesh-mpi against spokemesh: the same bytes for every number of processes.

Real processes: Open MPI's mpirun (oversubscribed on small machines) runs
build/bin/spokemesh-mpi; the single-process CLI writes the reference files. Point sets
are made here with fixed seeds (printed on failure through the test ids).
"""

import json
import os
import shutil
import signal
import subprocess
import time

import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "bench"))
import shapes  # noqa: E402  (bench/shapes.py: the shape families)
from conftest import missing  # noqa: E402

BIN = os.environ.get("SPOKEMESH_BIN_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "build", "bin"))
CLI = os.path.join(BIN, "spokemesh")
MPI = os.path.join(BIN, "spokemesh-mpi")
MPIRUN = shutil.which("mpirun")

if MPIRUN is None:
    missing("Open MPI's mpirun", "openmpi-bin libopenmpi-dev")
if not os.path.exists(MPI):
    missing(f"{MPI} (built only where Open MPI's compilers are found)", "libopenmpi-dev")

RANKS = [1, 2, 3, 4, 7]


def mpi_env():
    env = dict(os.environ)
    # As root (containers, CI runners) Open MPI wants both variables; on 2 cores, 7
    # ranks need oversubscription (--oversubscribe below).
    env["OMPI_ALLOW_RUN_AS_ROOT"] = "1"
    env["OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"] = "1"
    env["OMPI_MCA_btl_vader_single_copy_mechanism"] = "none"
    env["OMPI_MCA_rmaps_base_oversubscribe"] = "1"
    return env


def run_mpi(ranks, *args, check=True, timeout=600):
    cmd = [MPIRUN, "--oversubscribe", "-np", str(ranks), MPI, *args]
    done = subprocess.run(cmd, capture_output=True, text=True, env=mpi_env(), timeout=timeout)
    if check and done.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} exited {done.returncode}:\n{done.stderr}")
    return done


def run_cli(*args):
    done = subprocess.run([CLI, *args], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done


def uniform(n, d, seed):
    return np.random.default_rng(seed).random((n, d))


def clustered(n, seed):
    rng = np.random.default_rng(seed)
    centres = rng.random((100, 3))
    pts = centres[rng.integers(0, 100, n)] + rng.normal(scale=0.01, size=(n, 3))
    return pts


def linspace_grid(k):
    g = np.linspace(0.0, 1.0, k)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], 1)


SETS = {
    "3d-uniform-50k": lambda: uniform(50_000, 3, 1),
    "3d-clustered-50k": lambda: clustered(50_000, 2),
    "3d-linspace-grid-37": lambda: linspace_grid(37),
    "2d-uniform-50k": lambda: uniform(50_000, 2, 3),
}


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("mpi")


@pytest.fixture(scope="module")
def reference(work):
    """Each set's file and the single process's mesh and graph of it."""
    out = {}
    for name, make in SETS.items():
        pts = make()
        # The 2-d set as text (read by rank 0 and scattered), the others as .npy (read
        # in slices by MPI-IO).
        path = work / (name + (".txt" if name.startswith("2d") else ".npy"))
        if path.suffix == ".txt":
            np.savetxt(path, pts, fmt="%.17g")
        else:
            np.save(path, pts)
        mesh = work / f"{name}.simplices"
        graph = work / f"{name}.edges"
        run_cli("mesh", str(path), "-o", str(mesh), "-q", "--threads", "2")
        run_cli("graph", str(path), "-o", str(graph), "-q", "--threads", "2")
        out[name] = (path, mesh.read_bytes(), graph.read_bytes(), len(pts))
    return out


@pytest.mark.parametrize("name", list(SETS))
@pytest.mark.parametrize("ranks", RANKS)
def test_mesh_is_byte_identical(reference, work, name, ranks):
    path, mesh, _, n = reference[name]
    out = work / f"{name}-{ranks}.simplices"
    stats = work / f"{name}-{ranks}.json"
    run_mpi(ranks, "mesh", str(path), "-o", str(out), "-q", "--stats", str(stats))
    assert out.read_bytes() == mesh, f"{name}: {ranks} ranks wrote other bytes than one process"
    report = json.loads(stats.read_text())
    rows = report["ranks"]
    assert [r["rank"] for r in rows] == list(range(ranks))
    for r in rows:
        assert set(r) == {"rank", "owned", "ghosts", "rounds", "bytes_sent", "bytes_received", "peak_rss_bytes",
                          "seconds", "sphere_queries"}
    owned = [r["owned"] for r in rows]
    assert sum(owned) == n
    # Balance by counts, whatever the distribution (clumps included).
    assert max(owned) / (n / ranks) <= 1.05, owned


# The shapes whose Delaunay neighbours lie a scan line or a contour away: the
# same bytes on any number of ranks, and halos that do not grow round after round.
SHAPES = {
    "2d-contours-45k": lambda: shapes.contours(45_000, seed=1),
    "3d-scanner-rings-48k": lambda: shapes.rings(48_000, seed=2),
}


@pytest.mark.parametrize("name", list(SHAPES))
@pytest.mark.parametrize("ranks", [1, 3, 7])
def test_scans_and_contours_are_byte_identical(work, name, ranks):
    path = work / f"{name}.npy"
    reference = work / f"{name}.simplices"
    if not reference.exists():
        np.save(path, SHAPES[name]())
        run_cli("mesh", str(path), "-o", str(reference), "-q", "--threads", "2")
    out = work / f"{name}-{ranks}.simplices"
    stats = work / f"{name}-{ranks}.json"
    run_mpi(ranks, "mesh", str(path), "-o", str(out), "-q", "--stats", str(stats))
    assert out.read_bytes() == reference.read_bytes(), f"{name}: {ranks} ranks wrote other bytes than one process"
    # A few rounds: balls fetched, then the hull facets' regions growing 4x and 16x a
    # round until they hold the whole box (18 rounds before nearly flat simplices had
    # their balls placed exactly instead of their boxes doubled).
    rounds = [r["rounds"] for r in json.loads(stats.read_text())["ranks"]]
    assert max(rounds) <= 8, f"{name}: halo rounds {rounds}"


# Closed surfaces, whose Delaunay balls span their inside, and the scans and contours
# above: mesh, graph, cells and store at P = 1, 2, 3, each the single process's bytes. (A rank
# whose balls reach across the set fetches all of it, as one process then triangulates
# every point: docs/distributed.md.)
SURFACES = {
    "3d-torus-20k": lambda: shapes.torus(20_000, seed=3),
    "3d-sphere-12k": lambda: shapes.sphere(12_000, seed=4),
    **SHAPES,
}


@pytest.fixture(scope="module")
def surfaces(work):
    """Each family's file and the single process's mesh and graph of it."""
    out = {}
    for name, make in SURFACES.items():
        path = work / f"surface-{name}.npy"
        np.save(path, make())
        mesh, graph = work / f"surface-{name}.simplices", work / f"surface-{name}.edges"
        cells = work / f"surface-{name}.cells.npz"
        run_cli("mesh", str(path), "-o", str(mesh), "-q", "--threads", "2")
        run_cli("graph", str(path), "-o", str(graph), "-q", "--threads", "2")
        run_cli("cells", str(path), "-o", str(cells), "-q", "--threads", "2")
        out[name] = (path, mesh.read_bytes(), graph.read_bytes(), cells.read_bytes())
    return out


@pytest.mark.parametrize("name", list(SURFACES))
@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_surfaces_scans_and_contours_mesh_graph_cells_and_store_alike(surfaces, work, name, ranks):
    path, mesh, graph, cells = surfaces[name]
    out = work / f"surface-{name}-{ranks}.simplices"
    stats = work / f"surface-{name}-{ranks}.json"
    run_mpi(ranks, "mesh", str(path), "-o", str(out), "-q", "--stats", str(stats))
    assert out.read_bytes() == mesh, f"{name}: {ranks} ranks meshed other bytes than one process"
    rounds = [r["rounds"] for r in json.loads(stats.read_text())["ranks"]]
    assert max(rounds) <= 8, f"{name}: halo rounds {rounds}"
    edges = work / f"surface-{name}-{ranks}.edges"
    run_mpi(ranks, "graph", str(path), "-o", str(edges), "-q")
    assert edges.read_bytes() == graph, f"{name}: {ranks} ranks wrote another graph"
    # Clipped cells in the bounding box, their stars from the ranks' sweeps.
    npz = work / f"surface-{name}-{ranks}.cells.npz"
    run_mpi(ranks, "cells", str(path), "-o", str(npz), "-q")
    assert npz.read_bytes() == cells, f"{name}: {ranks} ranks wrote other cells"
    store = work / f"surface-store-{name}-{ranks}"
    store.mkdir()
    run_mpi(ranks, "store", str(path), "--data-dir", str(store), "--piece-points", STORE_PIECE_POINTS, "-q")
    if ranks == 1:
        return
    one = read_tree(work / f"surface-store-{name}-1")
    assert read_tree(store) == one, f"{name}: {ranks} ranks stored other pieces than one"


def test_sphere_queries_per_point_do_not_grow_with_n_on_a_sphere(work):
    # On a sphere's surface every Delaunay ball spans the inside: per-seed sphere
    # queries each skimmed the whole set (quadratic). Now a rank whose balls reach across
    # the set takes all of it and certifies nothing by queries: per point, the count
    # must stay flat as n grows eightfold.
    per_point = []
    for n in (3_000, 24_000):
        path = work / f"sphere-{n}.npy"
        np.save(path, shapes.sphere(n, seed=6))
        stats = work / f"sphere-{n}.json"
        run_mpi(2, "mesh", str(path), "-o", str(work / f"sphere-{n}.simplices"), "-q", "--stats", str(stats))
        ranks = json.loads(stats.read_text())["ranks"]
        per_point.append(max(r["sphere_queries"] / r["owned"] for r in ranks))
    assert per_point[1] <= 1.5 * per_point[0] + 0.05, f"sphere queries per point {per_point}"


@pytest.mark.parametrize("name,suffix", [("3d-uniform-50k", ".vtu"), ("3d-linspace-grid-37", ".msh"),
                                         ("2d-uniform-50k", ".svg"), ("2d-uniform-50k", ".vtu")])
@pytest.mark.parametrize("ranks", [1, 3, 7])
def test_vtu_msh_and_svg_meshes_are_byte_identical(reference, work, name, suffix, ranks):
    # The points in index order from each rank's slice, the rows from each rank's part
    # of the sweep, the fixed text from rank 0: the CLI's file.
    path = reference[name][0]
    one = work / f"{name}{suffix}"
    if not one.exists():
        run_cli("mesh", str(path), "-o", str(one), "-q", "--threads", "2")
    many = work / f"{name}-{ranks}{suffix}"
    run_mpi(ranks, "mesh", str(path), "-o", str(many), "-q")
    assert many.read_bytes() == one.read_bytes(), f"{name}{suffix}: {ranks} ranks wrote other bytes"


@pytest.mark.parametrize("name", list(SETS))
@pytest.mark.parametrize("ranks", RANKS)
def test_graph_is_byte_identical(reference, work, name, ranks):
    path, _, graph, _ = reference[name]
    out = work / f"{name}-{ranks}.edges"
    run_mpi(ranks, "graph", str(path), "-o", str(out), "-q")
    assert out.read_bytes() == graph


def test_npy_output_and_seed_ranges_are_byte_identical(reference, work):
    path, _, _, _ = reference["3d-uniform-50k"]
    one = work / "one.npy"
    run_cli("mesh", str(path), "-o", str(one), "-q")
    many = work / "many.npy"
    run_mpi(3, "mesh", str(path), "-o", str(many), "-q")
    assert many.read_bytes() == one.read_bytes()
    one_part = work / "one-part.simplices"
    run_cli("mesh", str(path), "--seeds", "1000:20000", "-o", str(one_part), "-q")
    many_part = work / "many-part.simplices"
    run_mpi(4, "mesh", str(path), "--seeds", "1000:20000", "-o", str(many_part), "-q")
    assert many_part.read_bytes() == one_part.read_bytes()


@pytest.fixture(scope="module")
def cells_reference(reference, work):
    """The single process's clipped cells of each set (.npz, the bounding box)."""
    out = {}
    for name in SETS:
        path = reference[name][0]
        cells = work / f"{name}.cells.npz"
        run_cli("cells", str(path), "-o", str(cells), "-q", "--threads", "2")
        out[name] = cells.read_bytes()
    return out


@pytest.mark.parametrize("name", list(SETS))
@pytest.mark.parametrize("ranks", RANKS)
def test_cells_are_byte_identical(reference, cells_reference, work, name, ranks):
    path = reference[name][0]
    out = work / f"{name}-{ranks}.cells.npz"
    stats = work / f"{name}-{ranks}.cells.json"
    run_mpi(ranks, "cells", str(path), "-o", str(out), "-q", "--stats", str(stats))
    assert out.read_bytes() == cells_reference[name], f"{name}: {ranks} ranks wrote other cells than one process"
    # numpy reads it, and it describes every point.
    with np.load(out) as z:
        assert z["volume"].shape == (reference[name][3],)
        assert z["facet_ptr"][-1] == len(z["facet_neighbor"])
    assert sum(r["owned"] for r in json.loads(stats.read_text())["ranks"]) == reference[name][3]


def test_cells_in_a_box_and_in_halfspaces_are_byte_identical(reference, work):
    path = reference["3d-uniform-50k"][0]
    walls = work / "walls.txt"
    walls.write_text("# a cube with one corner cut off\n-1 0 0 0.01\n1 0 0 1.01\n0 -1 0 0.01\n0 1 0 1.01\n"
                     "0 0 -1 0.01\n0 0 1 1.01\n1 1 1 3.01\n")
    for flags in (["--box", "-0.5,-0.25,0,1.5,1.25,1"], ["--halfspaces", str(walls)]):
        one = work / "domain-one.npz"
        many = work / "domain-many.npz"
        run_cli("cells", str(path), "-o", str(one), "-q", *flags)
        run_mpi(3, "cells", str(path), "-o", str(many), "-q", *flags)
        assert many.read_bytes() == one.read_bytes(), flags
    # A seed outside the domain: the CLI's error for the lowest one, once.
    outside = work / "outside.npz"
    cli = subprocess.run([CLI, "cells", str(path), "-o", str(outside), "--box", "0,0,0,0.5,1,1"], capture_output=True,
                         text=True)
    assert cli.returncode == 2
    done = run_mpi(3, "cells", str(path), "-o", str(outside), "--box", "0,0,0,0.5,1,1", check=False)
    assert done.returncode == 2
    message = cli.stderr.strip().splitlines()[-1]
    assert "lies outside the domain" in message
    assert done.stderr.count(message.split("spokemesh: ", 1)[-1]) == 1, (cli.stderr, done.stderr)
    assert not outside.exists()
    # A mesh format the dimension refuses, and a graph format: the CLI's words, once.
    done = run_mpi(2, "mesh", str(path), "-o", str(work / "m.svg"), check=False)
    assert done.returncode == 2 and done.stderr.count(".svg output is for 2-d meshes") == 1, done.stderr
    done = run_mpi(2, "graph", str(path), "-o", str(work / "g.vtu"), check=False)
    assert done.returncode == 2 and done.stderr.count("graphs are written as text") == 1, done.stderr
    # A cell format the dimension refuses: the CLI's words, once, and nothing written.
    cli = subprocess.run([CLI, "cells", str(path), "-o", str(work / "c.svg")], capture_output=True, text=True)
    done = run_mpi(2, "cells", str(path), "-o", str(work / "c.svg"), check=False)
    assert cli.returncode == 2 and done.returncode == 2
    message = cli.stderr.strip().splitlines()[-1].split("spokemesh: ", 1)[-1]
    assert ".svg pictures are of 2-d cells" in message
    assert done.stderr.count(message) == 1, done.stderr
    assert not (work / "c.svg").exists()


@pytest.fixture(scope="module")
def shape_domains(work):
    """Domains of any shape (tests/python/domain_files.py) and seeds in and around them."""
    import domain_files as df
    out = {}
    tv, tf = df.torus(48, 16)
    df.write_off(work / "torus.off", tv, tf)
    rng = np.random.default_rng(21)
    torus_points = np.concatenate([df.inside_torus(20_000, 22), rng.uniform(-1.4, 1.4, (2_000, 3))])
    np.save(work / "torus-seeds.npy", torus_points)
    out["torus"] = (work / "torus-seeds.npy", work / "torus.off")
    rings, _, _ = df.three_holes()
    df.write_geojson(work / "holes.geojson", rings, "FeatureCollection")
    np.save(work / "holes-seeds.npy", rng.random((20_000, 2)) * 10)
    out["holes"] = (work / "holes-seeds.npy", work / "holes.geojson")
    v, f = df.l_part()
    df.write_stl(work / "l.stl", v, f, binary=True)
    grid = np.stack(np.meshgrid(*[np.arange(0.0625, 2, 0.125)] * 2, np.arange(0.0625, 1, 0.125), indexing="ij"), -1)
    np.save(work / "l-grid.npy", grid.reshape(-1, 3))
    out["l-grid"] = (work / "l-grid.npy", work / "l.stl")
    return out


@pytest.mark.parametrize("name", ["torus", "holes", "l-grid"])
def test_cells_in_a_domain_of_any_shape_are_byte_identical(shape_domains, work, name):
    # The convex cell is certified as any clipped cell is; its intersection with the
    # domain depends on it and its neighbours' points only: the CLI's bytes at any P.
    points, domain = shape_domains[name]
    one = work / f"shape-{name}-cli.npz"
    run_cli("cells", str(points), "--domain", str(domain), "-o", str(one), "-q")
    for ranks in (1, 3, 7):
        many = work / f"shape-{name}-{ranks}.npz"
        run_mpi(ranks, "cells", str(points), "--domain", str(domain), "-o", str(many), "-q")
        assert many.read_bytes() == one.read_bytes(), (name, ranks)
    # A bad domain: the CLI's words, once, nothing written.
    bad = work / "open.off"
    bad.write_text("OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n")
    done = run_mpi(3, "cells", str(points), "--domain", str(bad), "-o", str(work / "bad.npz"), check=False)
    assert done.returncode == 2 and done.stderr.count("open boundary") == 1, done.stderr
    assert not (work / "bad.npz").exists()


DRAWN_CELL_SETS = {
    "3d-uniform-8k": lambda: uniform(8_000, 3, 4),
    "3d-linspace-grid-20": lambda: linspace_grid(20),
    "2d-uniform-20k": lambda: uniform(20_000, 2, 5),
}


@pytest.mark.parametrize("name,suffix,flags", [
    ("3d-uniform-8k", ".vtu", []),
    ("3d-uniform-8k", ".vtu", ["--box", "-0.5,-0.25,0,1.5,1.25,1"]),
    ("3d-linspace-grid-20", ".vtu", []),
    ("2d-uniform-20k", ".vtu", []),
    ("2d-uniform-20k", ".svg", []),
    ("2d-uniform-20k", ".svg", ["--halfspaces", "walls-2d"]),
])
@pytest.mark.parametrize("ranks", [1, 3, 7])
def test_vtu_and_svg_cells_are_byte_identical(work, name, suffix, flags, ranks):
    # Each cell's vertices and facet loops go with its record to its seed's rank, which
    # writes its slice's lines of every section at offsets from the ranks' counts: the
    # CLI's file (numbering of vertices and faces, and an .svg's extent and shading,
    # included).
    path = work / f"{name}.npy"
    if not path.exists():
        np.save(path, DRAWN_CELL_SETS[name]())
    walls = work / "walls-2d.txt"
    walls.write_text("1 -1 1.005\n-1 0 0.01\n0 -1 0.01\n1 0 1.01\n0 1 1.01\n")
    flags = [str(walls) if f == "walls-2d" else f for f in flags]
    tag = "-".join(f.strip("-").replace(",", "_").replace("/", "_")[:12] for f in flags)
    one = work / f"{name}{tag}.cells{suffix}"
    if not one.exists():
        run_cli("cells", str(path), "-o", str(one), "-q", *flags)
    many = work / f"{name}{tag}-{ranks}.cells{suffix}"
    run_mpi(ranks, "cells", str(path), "-o", str(many), "-q", *flags)
    assert many.read_bytes() == one.read_bytes(), f"{name}{suffix} {flags}: {ranks} ranks wrote other bytes"


def test_vtu_cells_fetched_in_rounds_are_byte_identical(work):
    path = work / "3d-uniform-8k.npy"
    if not path.exists():
        np.save(path, DRAWN_CELL_SETS["3d-uniform-8k"]())
    one = work / "rounds-one.cells.vtu"
    run_cli("cells", str(path), "-o", str(one), "-q")
    many = work / "rounds-many.cells.vtu"
    stats = work / "rounds-cells-vtu.json"
    run_mpi(4, "cells", str(path), "-o", str(many), "-q", "--first-halo", "0", "--stats", str(stats))
    assert many.read_bytes() == one.read_bytes()
    assert max(r["rounds"] for r in json.loads(stats.read_text())["ranks"]) > 1


def test_cells_fetch_what_they_need_in_rounds(reference, cells_reference, work):
    path = reference["3d-uniform-50k"][0]
    out = work / "cells-rounds.npz"
    stats = work / "cells-rounds.json"
    run_mpi(4, "cells", str(path), "-o", str(out), "-q", "--first-halo", "0", "--stats", str(stats))
    assert out.read_bytes() == cells_reference["3d-uniform-50k"]
    assert max(r["rounds"] for r in json.loads(stats.read_text())["ranks"]) > 1


def test_halos_grow_in_rounds_when_the_first_is_empty(reference, work):
    # No first halo: every star near a rank's boundary is refused at first and fetches
    # what its balls and hull facets need, round after round.
    path, mesh, _, _ = reference["3d-clustered-50k"]
    out = work / "rounds.simplices"
    stats = work / "rounds.json"
    run_mpi(3, "mesh", str(path), "-o", str(out), "-q", "--first-halo", "0", "--stats", str(stats))
    assert out.read_bytes() == mesh
    rounds = max(r["rounds"] for r in json.loads(stats.read_text())["ranks"])
    assert rounds > 1


def test_bad_input_is_reported_once_with_the_cli_exit_code(work):
    bad = work / "dup.txt"
    bad.write_text("0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n0.5 0.5 0.5\n1 0 0\n0.2 0.3 0.9\n")
    out = work / "dup.simplices"
    done = run_mpi(3, "mesh", str(bad), "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count("points 1 and 6 are equal") == 1, done.stderr
    assert not out.exists()
    text = work / "bad.txt"
    text.write_text("0 0 0\n1 0 0\n0 1 zz\n0 0 1\n")
    done = run_mpi(3, "mesh", str(text), "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count(f"{text}:3: cannot parse 'zz' as a number") == 1, done.stderr
    flat = work / "flat.npy"
    np.save(flat, np.c_[np.random.default_rng(4).random((1000, 2)), np.zeros(1000)])
    done = run_mpi(2, "mesh", str(flat), "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count("span only a 2-dimensional affine subspace") == 1, done.stderr
    done = run_mpi(2, "mesh", str(work / "missing.npy"), "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count("cannot open for reading (No such file or directory)") == 1, done.stderr
    done = run_mpi(2, "cells", str(flat), "-o", str(work / "c.npz"), check=False)
    assert done.returncode == 2
    assert done.stderr.count("span only a 2-dimensional affine subspace") == 1, done.stderr
    weights = work / "w.txt"
    weights.write_text("0\n" * 8)
    done = run_mpi(2, "mesh", str(text), "--weights", str(weights), "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count("not supported by spokemesh-mpi yet") == 1, done.stderr
    done = run_mpi(2, "mesh", str(text), "--periodic", "0,0,0,1,1,1", "-o", str(out), check=False)
    assert done.returncode == 2
    assert done.stderr.count("--periodic is not supported by spokemesh-mpi yet") == 1, done.stderr


def test_an_unwritable_output_fails_before_meshing(reference, work):
    path, _, _, _ = reference["3d-uniform-50k"]
    done = run_mpi(2, "mesh", str(path), "-o", str(work / "no-such-dir" / "m.simplices"), check=False)
    assert done.returncode == 2
    assert done.stderr.count("cannot open for writing (No such file or directory)") == 1, done.stderr


def test_a_killed_rank_fails_the_job_and_leaves_the_output_as_it_was(work):
    pts = uniform(400_000, 3, 9)
    path = work / "big.npy"
    np.save(path, pts)
    out = work / "kept.simplices"
    out.write_text("the previous contents\n")
    cmd = [MPIRUN, "--oversubscribe", "-np", "3", MPI, "mesh", str(path), "-o", str(out), "-q", "--threads", "1"]
    job = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=mpi_env(), text=True)
    # Kill one rank while it meshes (the ranks are mpirun's children).
    victim = None
    deadline = time.time() + 30
    while victim is None and time.time() < deadline:
        time.sleep(0.3)
        found = subprocess.run(["pgrep", "-P", str(job.pid), "-f", "spokemesh-mpi"], capture_output=True, text=True)
        pids = found.stdout.split()
        if len(pids) == 3:
            victim = int(pids[-1])
    assert victim is not None, "the ranks did not start"
    time.sleep(1.0)
    os.kill(victim, signal.SIGKILL)
    _, err = job.communicate(timeout=120)
    assert job.returncode != 0, err
    assert out.read_text() == "the previous contents\n"


# ------------------------------------------------------------------ store (sharded serving)

STORE_PIECE_POINTS = "4096"


def read_tree(root):
    """Every file under root, as {relative path: bytes}."""
    out = {}
    for dirpath, _, files in os.walk(root):
        for f in files:
            full = os.path.join(dirpath, f)
            out[os.path.relpath(full, root)] = open(full, "rb").read()
    return out


@pytest.fixture(scope="module")
def stored(reference, work):
    """Each set stored as pieces at P = 1, 2, 3: {name: [tree at P=1, P=2, P=3]}."""
    out = {}
    for name, (path, *_rest) in reference.items():
        trees = []
        for ranks in (1, 2, 3):
            d = work / f"store-{name}-{ranks}"
            d.mkdir()
            run_mpi(ranks, "store", str(path), "--data-dir", str(d), "--piece-points", STORE_PIECE_POINTS, "-q")
            trees.append(read_tree(d))
        out[name] = trees
    return out


@pytest.mark.parametrize("name", list(SETS))
def test_store_writes_the_same_pieces_on_any_number_of_processes(stored, name):
    trees = stored[name]
    names = sorted(trees[0])
    assert any(n.endswith("manifest") for n in names) and any(n.endswith(".points") for n in names)
    assert sum(n.endswith(".piece") for n in names) >= 8
    for ranks, tree in zip((2, 3), trees[1:]):
        assert sorted(tree) == names, f"P={ranks}: other files"
        for n in names:
            assert tree[n] == trees[0][n], f"{name}: {n} differs at P={ranks}"


def test_stored_pieces_are_what_a_server_writes_and_serves(stored, reference, work, start_server):
    import urllib.request
    name = "3d-clustered-50k"
    path, _, _, count = reference[name]
    pts = np.load(path)
    # A server cutting the same upload writes the same files.
    data = work / "server-cut"
    server = start_server("--pieces-above", "1000", "--piece-points", STORE_PIECE_POINTS, data_dir=data,
                          name="cutting")
    req = urllib.request.Request(f"{server.http}/v1/pointsets?dimension=3", data=pts.astype("<f8").tobytes(),
                                 method="POST", headers={"Content-Type": "application/octet-stream"})
    with urllib.request.urlopen(req, timeout=120) as r:
        set_id = json.loads(r.read())["id"]
    tree = read_tree(data)
    for n, b in stored[name][0].items():
        assert tree.get(n) == b, f"{n}: the server's cut differs from spokemesh-mpi store's"
    # A one-shard replica over spokemesh-mpi's directory answers as the whole set does.
    mpi_dir = work / f"store-{name}-3"
    shard = start_server("--shard", "0/1", "--shard-http", "127.0.0.1:1", "--shard-grpc", "127.0.0.1:1",
                         data_dir=mpi_dir, name="shard")
    for seed in range(0, count, count // 97):
        for route in ("star", "cell?bounding_box=true"):
            with urllib.request.urlopen(f"{shard.http}/v1/pointsets/{set_id}/seeds/{seed}/{route}") as a, \
                    urllib.request.urlopen(f"{server.http}/v1/pointsets/{set_id}/seeds/{seed}/{route}") as b:
                assert a.read() == b.read(), (seed, route)


def test_store_refuses_what_cannot_be_pieces(work):
    pts = uniform(500, 4, 5)
    src = work / "four-d.npy"
    np.save(src, pts)
    d = work / "store-4d"
    d.mkdir()
    done = run_mpi(2, "store", str(src), "--data-dir", str(d), check=False)
    assert done.returncode == 2 and "dimension 4" in done.stderr, done.stderr
    assert os.listdir(d) == []
    done = run_mpi(1, "store", str(src), "--data-dir", str(work / "absent"), check=False)
    assert done.returncode == 2 and "--data-dir" in done.stderr, done.stderr
