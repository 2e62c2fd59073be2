#!/usr/bin/python3
"""Periodic boxes (issue 28) as whole processes, against CGAL on the same files.

`spokemesh mesh P.npy --periodic 0,..,0,1,..,1 -o M.npz` (its defaults: every core)
against CGAL 5.5's Periodic_2/_3_Delaunay_triangulation (`spokemesh_cgal_mesh P.npy
--periodic 1`: the same reader, single-threaded, inserted as a large point set, no output
file); the simplex counts must agree (the suite's test_periodic compares the simplices
themselves). Where CGAL cannot use one copy of the box (clustered points leave voids
wider than its 1-sheeted condition allows) it keeps 27, and the table says so.

Inputs (`--points`, bench/inputs.py): uniform points in the unit square or cube, 100
Gaussian clusters, or a numpy.linspace grid (its points at 1.0 are dropped: the torus
identifies them with those at 0).

Usage: bench/periodic.py [--n3 1000000] [--n2 1000000] [--points uniform grid] [--data DIR]
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n3", type=int, default=1_000_000)
    parser.add_argument("--n2", type=int, default=1_000_000)
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


if __name__ == "__main__":
    main()
