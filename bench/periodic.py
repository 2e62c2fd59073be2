#!/usr/bin/python3
"""Periodic boxes as whole processes, against CGAL on the same files.

`spokemesh mesh P.npy --periodic 0,..,0,1,..,1 -o M.npz` (its defaults: every core)
against CGAL 5.5's Periodic_2/_3_Delaunay_triangulation (`spokemesh_cgal_mesh P.npy
--periodic 1`: the same reader, single-threaded, inserted as a large point set, no output
file); the simplex counts must agree (the suite's test_periodic compares the simplices
themselves). Where CGAL cannot use one copy of the box (clustered points leave voids
wider than its 1-sheeted condition allows) it keeps 27, and the table says so.

Cells: `spokemesh cells P.txt --periodic 0,0,0,1,1,1 -o C.npz` against `voro++ -p -c
"%i %v %n" 0 1 0 1 0 1 FILE` (Debian's voro++ 0.4.6, single-threaded, text in and out
as it takes them); the volumes must sum to 1 and agree with Voro++'s on a sample.

Inputs (`--points`, bench/inputs.py): uniform points in the unit square or cube, 100
Gaussian clusters, or a numpy.linspace grid (its points at 1.0 are dropped: the torus
identifies them with those at 0).

Usage: bench/periodic.py [--n3 1000000] [--n2 1000000] [--cells 1000000] [--points uniform grid] [--data DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

import inputs  # bench/inputs.py and bench/timing.py (the script's directory is on sys.path)
import timing

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build" / "bin"))


def periodic(kind: str, n: int, d: int, work: Path) -> None:
    points = inputs.points(kind, n, d, 20261128 + d)
    points = points[(points >= 0).all(axis=1) & (points < 1).all(axis=1)]
    n = len(points)
    np.save(work / "p.npy", points)
    box = ",".join(["0"] * d + ["1"] * d)
    ours_t, ours_rss, _ = timing.process([str(BIN / "spokemesh"), "mesh", "p.npy", "--periodic", box,
                                          "-o", "m.npz", "-q"], cwd=str(work))
    cgal_t, cgal_rss, out = timing.process([str(BIN / "spokemesh_cgal_mesh"), "p.npy", "--periodic", "1"],
                                           cwd=str(work))
    with np.load(work / "m.npz") as z:
        ours = len(z["simplices"])
    assert ours == int(out.split()[0]), (ours, out)
    sheeted = " (CGAL: 27-sheeted)" if "sheeted" in out else ""
    print(f"| periodic {kind} {d}-d {n:,}{sheeted} | {ours:,} | {ours_t:.2f} s, {ours_rss:.0f} MB | "
          f"{cgal_t:.2f} s, {cgal_rss:.0f} MB | {ours_t / cgal_t:.2f}x |", flush=True)


def cells(kind: str, n: int, work: Path, radii: bool = False) -> None:
    """The torus's cells; with radii (uniform in [0, mean spacing / 2)), power cells
    against `voro++ -p -r`."""
    points = inputs.points(kind, n, 3, 20261129)
    points = points[(points >= 0).all(axis=1) & (points < 1).all(axis=1)]
    n = len(points)
    r = np.random.default_rng(20261130).random(n) * 0.5 * n ** (-1.0 / 3)
    np.savetxt(work / "p.txt", points, fmt="%.17g")
    np.savetxt(work / "r.txt", r, fmt="%.17g")
    with open(work / "voro.txt", "w") as f:
        for i, p in enumerate(points):
            f.write(f"{i} {p[0]!r} {p[1]!r} {p[2]!r}" + (f" {r[i]!r}\n" if radii else "\n"))
    ours_t, ours_rss, _ = timing.process([str(BIN / "spokemesh"), "cells", "p.txt", "--periodic", "0,0,0,1,1,1",
                                          *(["--radii", "r.txt"] if radii else []), "-o", "c.npz", "-q"],
                                         cwd=str(work))
    voro_t, voro_rss, _ = timing.process(["voro++", "-p", *(["-r"] if radii else []), "-c", "%i %v %n",
                                          "0", "1", "0", "1", "0", "1", "voro.txt"], cwd=str(work))
    z = dict(np.load(work / "c.npz"))
    assert abs(z["volume"].sum() - 1) < 1e-12
    with open(work / "voro.txt.vol") as f:
        for line, _ in zip(f, range(2000)):
            t = line.split()
            i, v = int(t[0]), float(t[1])
            assert abs(z["volume"][i] - v) <= 5e-6 * v, (i, z["volume"][i], v)
    what = "power cells" if radii else "cells"
    print(f"| periodic {what} {kind} 3-d {n:,} | {int(z['facet_ptr'][-1]):,} facets | {ours_t:.2f} s, "
          f"{ours_rss:.0f} MB | Voro++ {voro_t:.2f} s, {voro_rss:.0f} MB | {ours_t / voro_t:.2f}x |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n3", type=int, default=1_000_000)
    parser.add_argument("--n2", type=int, default=1_000_000)
    parser.add_argument("--cells", type=int, default=1_000_000, help="points for the 3-d cells (0: none)")
    parser.add_argument("--points", nargs="+", default=["uniform"], choices=inputs.KINDS)
    parser.add_argument("--data", type=Path, default=None, help="work directory (default: a temporary one)")
    args = parser.parse_args()
    print("| case | simplices | spokemesh (all cores) | CGAL (1 thread) | ratio |")
    print("| --- | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.data or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for kind in args.points:
            if args.n2:
                periodic(kind, args.n2, 2, work)
            if args.n3:
                periodic(kind, args.n3, 3, work)
            if args.cells:
                cells(kind, args.cells, work)
                cells(kind, args.cells, work, radii=True)


if __name__ == "__main__":
    main()
