#!/usr/bin/python3
"""Weighted points as whole processes, against their peers on the same files.

Regular triangulations: `spokemesh mesh P.npy --weights W.npy -o M.npy` (its defaults:
every core) against CGAL 5.5's Regular_triangulation_2/_3 (`spokemesh_cgal_mesh P.npy
W.npy`: the same reader, single-threaded, no output file); the simplex and hidden
counts must agree.

Power cells: `spokemesh cells P.txt --radii R.txt --box 0,0,0,1,1,1 -o C.npz` against
`voro++ -r -c "%i %v %n" 0 1 0 1 0 1 FILE` (Debian's voro++ 0.4.6, single-threaded);
the volumes must sum to 1 and, on a sample, agree with Voro++'s.

Inputs (`--points`, bench/inputs.py): uniform points in the unit square or cube,
100 Gaussian clusters, or a numpy.linspace grid; weights uniform in [0, top) with `top`
a multiple of the squared mean spacing (n^(-2/d)): `--spread 1` leaves a few points
hidden, `--spread 10` most of them. Cells are clipped to the points' bounding box grown
by 1e-6 of its size on each side (Voro++ leaves out particles on its container's
upper walls), the same box for both.

Usage: bench/weighted.py [--n3 1000000] [--n2 1000000] [--spread 1 10] [--points uniform] [--data DIR]
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


def case(kind: str, n: int, d: int, spread: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    points = inputs.points(kind, n, d, seed)
    n = len(points)
    return points, np.random.default_rng(seed + 1).random(n) * spread * n ** (-2.0 / d)


def regular(kind: str, n: int, d: int, spread: float, work: Path) -> None:
    points, weights = case(kind, n, d, spread, 20261127 + d)
    n = len(points)
    np.save(work / "p.npy", points)
    np.save(work / "w.npy", weights)
    ours_t, ours_rss, _ = timing.process([str(BIN / "spokemesh"), "mesh", "p.npy", "--weights", "w.npy",
                                          "-o", "m.npy", "-q"], cwd=str(work))
    cgal_t, cgal_rss, out = timing.process([str(BIN / "spokemesh_cgal_mesh"), "p.npy", "w.npy"], cwd=str(work))
    simplices, hidden = (int(x) for x in out.replace(",", " ").split()[::2][:2])
    mesh = np.load(work / "m.npy")
    used = np.zeros(n, dtype=bool)
    used[mesh.ravel()] = True
    assert len(mesh) == simplices and int((~used).sum()) == hidden, (len(mesh), simplices, (~used).sum(), hidden)
    print(f"| {kind} {d}-d {n:,}, spread {spread:g} | {hidden:,} | {ours_t:.2f} s, {ours_rss:.0f} MB | "
          f"{cgal_t:.2f} s, {cgal_rss:.0f} MB | {ours_t / cgal_t:.2f}x |", flush=True)


def power_cells(kind: str, n: int, spread: float, work: Path) -> None:
    points, weights = case(kind, n, 3, spread, 20261130)
    n = len(points)
    radii = np.sqrt(weights)
    lo, hi = points.min(axis=0), points.max(axis=0)
    lo, hi = lo - 1e-6 * (hi - lo), hi + 1e-6 * (hi - lo)
    box = [repr(float(v)) for v in (*lo, *hi)]
    np.savetxt(work / "p.txt", points, fmt="%.17g")
    np.savetxt(work / "r.txt", radii, fmt="%.17g")
    with open(work / "voro.txt", "w") as f:
        for i in range(n):
            f.write(f"{i} {points[i, 0]!r} {points[i, 1]!r} {points[i, 2]!r} {radii[i]!r}\n")
    ours_t, ours_rss, _ = timing.process([str(BIN / "spokemesh"), "cells", "p.txt", "--radii", "r.txt",
                                          "--box", ",".join(box), "-o", "c.npz", "-q"], cwd=str(work))
    voro_box = [box[0], box[3], box[1], box[4], box[2], box[5]]
    voro_t, voro_rss, _ = timing.process(["voro++", "-r", "-c", "%i %v %n", *voro_box, "voro.txt"], cwd=str(work))
    volume = np.load(work / "c.npz")["volume"]
    total = float(np.prod(hi - lo))
    assert abs(volume.sum() - total) < 1e-9 * total, (volume.sum(), total)
    theirs = {}
    with open(work / "voro.txt.vol") as f:
        for line in f:
            t = line.split()
            theirs[int(t[0])] = float(t[1])
    worst = max(abs(volume[i] - v) / v for i, v in list(theirs.items())[:10000])
    empty = n - len(theirs)
    print(f"| power cells {kind} 3-d {n:,}, spread {spread:g} | {empty:,} | {ours_t:.2f} s, {ours_rss:.0f} MB | "
          f"{voro_t:.2f} s, {voro_rss:.0f} MB | {ours_t / voro_t:.2f}x | worst relative volume difference "
          f"{worst:.1e} (Voro++ prints 6 digits) |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n3", type=int, default=1_000_000)
    ap.add_argument("--n2", type=int, default=1_000_000)
    ap.add_argument("--spread", type=float, nargs="+", default=[1.0, 10.0])
    ap.add_argument("--points", choices=inputs.KINDS, default="uniform")
    ap.add_argument("--data", type=Path, help="keep the inputs here (default: a temporary directory)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.data or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print("| case | hidden | spokemesh | peer | ratio |")
        print("| --- | ---: | ---: | ---: | ---: |")
        for spread in args.spread:
            if args.n2:
                regular(args.points, args.n2, 2, spread, work)
            if args.n3:
                regular(args.points, args.n3, 3, spread, work)
                power_cells(args.points, args.n3, spread, work)


if __name__ == "__main__":
    main()
