#!/usr/bin/python3
"""Weighted points (issue 28) as whole processes, against their peers on the same files.

Regular triangulations: `spokemesh mesh P.npy --weights W.npy -o M.npy` (its defaults:
every core) against CGAL 5.5's Regular_triangulation_2/_3 (`spokemesh_cgal_mesh P.npy
W.npy`: the same reader, single-threaded, no output file); the simplex and hidden
counts must agree.

Power cells: `spokemesh cells P.txt --radii R.txt --box 0,0,0,1,1,1 -o C.npz` against
`voro++ -r -c "%i %v %n" 0 1 0 1 0 1 FILE` (Debian's voro++ 0.4.6, single-threaded);
the volumes must sum to 1 and, on a sample, agree with Voro++'s.

Inputs: uniform points in the unit square or cube; weights uniform in [0, top) with
`top` a multiple of the squared mean spacing (n^(-2/d)): `--spread 1` leaves a few
points hidden, `--spread 10` most of them.

Usage: bench/weighted.py [--n3 1000000] [--n2 1000000] [--spread 1] [--data DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

import timing  # bench/timing.py (the script's directory is on sys.path)

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build" / "bin"))


def case(n: int, d: int, spread: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.random((n, d)), rng.random(n) * spread * n ** (-2.0 / d)


def regular(n: int, d: int, spread: float, work: Path) -> None:
    points, weights = case(n, d, spread, 20261127 + d)
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
    print(f"| {d}-d {n:,}, spread {spread:g} | {hidden:,} | {ours_t:.2f} s, {ours_rss:.0f} MB | "
          f"{cgal_t:.2f} s, {cgal_rss:.0f} MB | {ours_t / cgal_t:.2f}x |", flush=True)


def power_cells(n: int, spread: float, work: Path) -> None:
    points, weights = case(n, 3, spread, 20261130)
    radii = np.sqrt(weights)
    np.savetxt(work / "p.txt", points, fmt="%.17g")
    np.savetxt(work / "r.txt", radii, fmt="%.17g")
    with open(work / "voro.txt", "w") as f:
        for i in range(n):
            f.write(f"{i} {points[i, 0]!r} {points[i, 1]!r} {points[i, 2]!r} {radii[i]!r}\n")
    ours_t, ours_rss, _ = timing.process([str(BIN / "spokemesh"), "cells", "p.txt", "--radii", "r.txt",
                                          "--box", "0,0,0,1,1,1", "-o", "c.npz", "-q"], cwd=str(work))
    voro_t, voro_rss, _ = timing.process(["voro++", "-r", "-c", "%i %v %n", "0", "1", "0", "1", "0", "1", "voro.txt"],
                                         cwd=str(work))
    volume = np.load(work / "c.npz")["volume"]
    assert abs(volume.sum() - 1) < 1e-9, volume.sum()
    theirs = {}
    with open(work / "voro.txt.vol") as f:
        for line in f:
            t = line.split()
            theirs[int(t[0])] = float(t[1])
    worst = max(abs(volume[i] - v) / v for i, v in list(theirs.items())[:10000])
    empty = n - len(theirs)
    print(f"| power cells 3-d {n:,}, spread {spread:g} | {empty:,} | {ours_t:.2f} s, {ours_rss:.0f} MB | "
          f"{voro_t:.2f} s, {voro_rss:.0f} MB | {ours_t / voro_t:.2f}x | worst relative volume difference "
          f"{worst:.1e} (Voro++ prints 6 digits) |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n3", type=int, default=1_000_000)
    ap.add_argument("--n2", type=int, default=1_000_000)
    ap.add_argument("--spread", type=float, nargs="+", default=[1.0, 10.0])
    ap.add_argument("--data", type=Path, help="keep the inputs here (default: a temporary directory)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.data or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print("| case | hidden | spokemesh | peer | ratio |")
        print("| --- | ---: | ---: | ---: | ---: |")
        for spread in args.spread:
            if args.n2:
                regular(args.n2, 2, spread, work)
            if args.n3:
                regular(args.n3, 3, spread, work)
                power_cells(args.n3, spread, work)


if __name__ == "__main__":
    main()
