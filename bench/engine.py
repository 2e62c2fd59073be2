#!/usr/bin/python3
"""One engine everywhere (issue 51): each path that computes stars, timed on the shape
families of bench/shapes.py against what it is measured by, whole processes on the same
text files, with peak RSS.

  mpi      `mpirun -np P spokemesh-mpi mesh` and `store` (P = 1, 2) against `spokemesh
           mesh` (--threads 2) on the same file; the bytes are compared.
  cells    `spokemesh cells` (the bounding box, --threads 2) against Voro++ (`voro++ -c
           "%i %v %n %f"`, one thread: it computes volumes, neighbours and areas) on the
           same points and box.
  serve    single star requests (REST, median) and a batch of random seeds (gRPC) on
           each family against uniform points of the same n, the set's triangulation kept.
  insert   in-process add_points of the last 1% of a 3-d set against building it again
           (bench/incremental.py's measure at other shapes).

    PYTHONPATH=build/python /usr/bin/python3 bench/engine.py [--sections mpi,cells,serve,insert]
        [--families a,b] [--n N]

Each row is one run (the machine's noise is a few percent; --runs takes the least of
several). Files go to a temporary directory (--work to keep them).
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import shapes  # noqa: E402
from timing import process  # noqa: E402

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))
BIN = os.environ.get("SPOKEMESH_BIN_DIR", os.path.join(ROOT, "build", "bin"))
CLI = os.path.join(BIN, "spokemesh")
MPI = os.path.join(BIN, "spokemesh-mpi")

# The families of issue 51's targets: shapes.py's at their default sizes (100k-1M).
DEFAULT_FAMILIES = ["contours", "terrain", "rings", "rings_buildings", "sphere", "torus", "isosurface",
                    "contrast", "uniform3", "uniform2", "clustered3", "grid3"]


def least(runs: int, cmd: list[str], timeout: float | None = None) -> tuple[float, float]:
    """The least wall time of `runs` runs of cmd, and the peak RSS (MB) of that run (inf
    when stopped after `timeout` seconds)."""
    best = None
    for _ in range(runs):
        wall, rss, _ = process(cmd, timeout=timeout)
        if best is None or wall < best[0]:
            best = (wall, rss)
    return best


def mpirun(ranks: int) -> list[str]:
    return ["mpirun", "--allow-run-as-root", "-np", str(ranks)]


def section_mpi(files: dict, work: str, runs: int) -> None:
    print("\n### spokemesh-mpi mesh and store against spokemesh mesh (2 threads)\n")
    print("| family | n | CLI mesh s | MB | P=1 mesh s | MB | P=2 mesh s | ratio | largest rank MB | "
          "P=2 store s | ratio |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    os.environ.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
    os.environ.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    for name, (path, n) in files.items():
        ref = os.path.join(work, f"{name}.cli.simplices")
        cli_t, cli_m = least(runs, [CLI, "mesh", path, "-o", ref, "-q", "--threads", "2"])
        cells = []
        for p in (1, 2):
            out = os.path.join(work, f"{name}.mpi{p}.simplices")
            t, m = least(runs, [*mpirun(p), MPI, "mesh", path, "-o", out, "-q"])
            same = open(out, "rb").read() == open(ref, "rb").read()
            os.remove(out)
            if not same:
                sys.exit(f"{name}: spokemesh-mpi at P = {p} wrote other bytes")
            cells.append((t, m))
        data = os.path.join(work, f"store-{name}")
        shutil.rmtree(data, ignore_errors=True)
        os.makedirs(data)
        store_t, _ = least(1, [*mpirun(2), MPI, "store", path, "--data-dir", data, "-q"])
        shutil.rmtree(data, ignore_errors=True)
        os.remove(ref)
        # (GNU time's RSS of mpirun is the largest of its children's.)
        print(f"| {name} | {n:,} | {cli_t:.2f} | {cli_m:.0f} | {cells[0][0]:.2f} | {cells[0][1]:.0f} | "
              f"{cells[1][0]:.2f} | {cells[1][0] / cli_t:.2f}x | {cells[1][1]:.0f} | {store_t:.2f} | "
              f"{store_t / cli_t:.2f}x |", flush=True)


def section_cells(files: dict, work: str, runs: int, voro_timeout: float) -> None:
    print("\n### spokemesh cells against Voro++ (the points' bounding box)\n")
    print("| family | n | spokemesh s | MB | Voro++ s | MB | ratio |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, (path, n) in files.items():
        pts = np.loadtxt(path)
        if pts.shape[1] != 3:
            continue
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        voro_in = os.path.join(work, f"{name}.voro")
        with open(voro_in, "w") as f:
            for i, p in enumerate(pts):
                f.write(f"{i} {p[0]:.17g} {p[1]:.17g} {p[2]:.17g}\n")
        box = [f"{v:.17g}" for c in range(3) for v in (lo[c], hi[c])]
        out = os.path.join(work, f"{name}.npz")
        ours_t, ours_m = least(runs, [CLI, "cells", path, "-o", out, "-q", "--threads", "2"])
        voro_t, voro_m = least(runs, ["voro++", "-c", "%i %v %n %f", *box, voro_in], timeout=voro_timeout)
        for f in (voro_in, voro_in + ".vol", out):
            if os.path.exists(f):
                os.remove(f)
        if voro_t == float("inf"):  # Voro++ stopped
            print(f"| {name} | {n:,} | {ours_t:.2f} | {ours_m:.0f} | stopped after {voro_timeout:.0f} | | "
                  f"< {ours_t / voro_timeout:.2f}x |", flush=True)
            continue
        print(f"| {name} | {n:,} | {ours_t:.2f} | {ours_m:.0f} | {voro_t:.2f} | {voro_m:.0f} | "
              f"{ours_t / voro_t:.2f}x |", flush=True)


def section_serve(families: list[str], n: int | None, seeds_count: int) -> None:
    """Single star requests (REST, one keep-alive connection, the median of random seeds)
    and a batch of random seeds (gRPC BatchSeeds), on each family and on uniform points
    of the same n and d, once the set's kept triangulation is built."""
    import http.client
    import time

    import spokemesh
    from local_server import local_server

    def budget_used(conn) -> float:
        conn.request("GET", "/metrics")
        r = conn.getresponse()
        for line in r.read().decode().splitlines():
            if line.startswith("spokemesh_memory_budget_used_bytes"):
                return float(line.split()[-1])
        return 0.0

    def measure(client, http_target: str, points: np.ndarray) -> tuple[float, float]:
        ps = client.upload(points)
        client.star(ps.id, 0)  # loads the set; its triangulation is built in the background
        host, port = http_target.split(":")
        conn = http.client.HTTPConnection(host, int(port))
        # Kept once the budget's use stops growing (the triangulation is charged as it
        # is built): a degenerate set's walked stars can look steady before that.
        last, steady, until = -1.0, 0, time.time() + 300
        while steady < 6 and time.time() < until:
            time.sleep(0.5)
            used = budget_used(conn)
            steady = steady + 1 if used == last else 0
            last = used
        rng = np.random.default_rng(4)
        seeds = [int(s) for s in rng.integers(0, len(points), seeds_count)]

        def one(seed: int) -> float:
            t = time.perf_counter()
            conn.request("GET", f"/v1/pointsets/{ps.id}/seeds/{seed}/star")
            r = conn.getresponse()
            r.read()
            assert r.status == 200, r.status
            return time.perf_counter() - t

        # Warm: until the medians of two samples agree (the triangulation is in).
        last = None
        for _ in range(60):
            med = float(np.median([one(s) for s in seeds[:200]]))
            if last is not None and abs(med - last) < 0.1 * last:
                break
            last = med
            time.sleep(0.5)
        single = float(np.median([one(s) for s in seeds]))
        t = time.perf_counter()
        client.batch_stars(ps.id, seeds)
        batch = (time.perf_counter() - t) / len(seeds)
        conn.close()
        client.delete(ps.id)
        return single * 1e6, batch * 1e6

    print(f"\n### Per-seed requests once the set's triangulation is kept (median of {seeds_count:,} random "
          f"single stars over REST, one keep-alive connection; a gRPC batch of them)\n")
    print("| family | n | single us | uniform us | ratio | batch us a seed | uniform | ratio |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    with local_server("--max-points", "10000000") as (grpc_target, http_target):
        client = spokemesh.Client(grpc_target)
        for name in families:
            pts = shapes.make(name, n)
            single, batch = measure(client, http_target, pts)
            u_single, u_batch = measure(client, http_target, np.random.default_rng(3).random(pts.shape))
            print(f"| {name} | {len(pts):,} | {single:.0f} | {u_single:.0f} | {single / u_single:.2f}x | "
                  f"{batch:.1f} | {u_batch:.1f} | {batch / u_batch:.2f}x |", flush=True)


def section_insert(families: list[str], n: int | None) -> None:
    import time

    import spokemesh

    print("\n### add_points of the last 1% against building again (in process, 2 threads)\n")
    print("| family | n | add s | stars | build again s | ratio |")
    print("|---|---:|---:|---:|---:|---:|")
    for name in families:
        pts = shapes.make(name, n)
        k = int(len(pts) * 0.99)
        tri = spokemesh.Delaunay(pts[:k], incremental=True, threads=2)
        t0 = time.perf_counter()
        tri.add_points(pts[k:])
        add = time.perf_counter() - t0
        t0 = time.perf_counter()
        whole = spokemesh.Delaunay(pts, threads=2)
        again = time.perf_counter() - t0
        if not np.array_equal(tri.simplices, whole.simplices):
            sys.exit(f"{name}: insertion differs from the rebuild")
        print(f"| {name} | {len(pts):,} | {add:.3f} | {tri._tri.stars_computed:,} | {again:.2f} | "
              f"{add / again:.3f}x |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", default="mpi,cells,serve,insert")
    ap.add_argument("--families", default=",".join(DEFAULT_FAMILIES))
    ap.add_argument("--n", type=int, default=None, help="points per family (default: each family's own)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--seeds", type=int, default=2000, help="serve: random seeds asked")
    ap.add_argument("--voro-timeout", type=float, default=600, help="cells: Voro++ stopped after this many seconds")
    ap.add_argument("--work", default=None, help="keep the files here")
    a = ap.parse_args()
    families = a.families.split(",")
    sections = a.sections.split(",")
    work = a.work or tempfile.mkdtemp(prefix="spokemesh-engine-")
    os.makedirs(work, exist_ok=True)
    files = {}
    if "mpi" in sections or "cells" in sections:
        for name in families:
            pts = shapes.make(name, a.n)
            path = os.path.join(work, f"{name}.txt")
            np.savetxt(path, pts, fmt="%.17g")
            files[name] = (path, len(pts))
    try:
        if "mpi" in sections:
            section_mpi(files, work, a.runs)
        if "cells" in sections:
            section_cells(files, work, a.runs, a.voro_timeout)
        if "serve" in sections:
            section_serve(families, a.n, a.seeds)
        if "insert" in sections:
            section_insert(families, a.n)
    finally:
        if a.work is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
