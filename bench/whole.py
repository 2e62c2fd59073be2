#!/usr/bin/python3
"""Whole meshes as whole processes: `spokemesh mesh FILE -o OUT.simplices` (2 threads,
its defaults) against CGAL (`spokemesh_cgal_mesh FILE`: the same reader, then CGAL 5.5's
Delaunay_triangulation_2/_3, or the dD one for d >= 4, single-threaded, no output
file) and Qhull (`qdelaunay Qt i` on the same points in Qhull's format, writing the
simplices to /dev/null), on the same files, one after the other. Wall time and peak
RSS of each process (GNU time), and the simplex counts (which must agree; Qhull
triangulates cospherical facets its own way, so on grids only CGAL's count is checked).

Inputs, made the way users make them (numpy, fixed seeds): uniform points, gaussian
clumps, grids written as integers, dyadic steps i/32, decimal steps i*0.1, and
numpy.linspace, and the shapes users bring (bench/shapes.py: contour lines, terrain,
scanner rings, surfaces, density contrast).

Usage: bench/whole.py [--only SUBSTRING] [--shapes] [--big] [--huge] [--repeat N] [--threads N] [--data DIR]
  --shapes  the shape families only (at 100k-200k and 1M points)
  --big     adds 3-d uniform 4M (.npy) with CGAL
  --huge    adds 3-d uniform 16M (.npy), spokemesh alone (CGAL would need about 10 GB)
  --threads spokemesh's worker threads (default 2, its own default)
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

import numpy as np

import shapes  # bench/shapes.py (the script's directory is on sys.path)
import timing  # bench/timing.py

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build" / "bin"))


def timed(cmd: list[str], stdin: Path | None = None) -> tuple[float, float, str]:
    """(wall seconds, peak RSS MB, stdout) of a process, from GNU time."""
    return timing.process(cmd, stdin=stdin)


def uniform(n: int, d: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((n, d))


def clumps(n: int, seed: int) -> np.ndarray:
    # 1,000 gaussian clumps (sigma 0.01) at uniform centres in the unit cube: a
    # hundred times the mean density inside a clump, empty space between.
    rng = np.random.default_rng(seed)
    centres = rng.random((1000, 3))
    return centres[rng.integers(0, 1000, n)] + rng.normal(0, 0.01, (n, 3))


def grid(side: int, d: int, kind: str) -> np.ndarray:
    axis = {"integer": np.arange(side, dtype=float), "dyadic": np.arange(side) / 32.0,
            "decimal": np.arange(side) * 0.1, "linspace": np.linspace(0, 1, side)}[kind]
    mesh = np.meshgrid(*([axis] * d), indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def shape_cases() -> list[tuple[str, str, callable, bool]]:
    """The shape families (bench/shapes.py) at their default sizes (96k-200k) and at 1M."""
    out = []
    for name, (_, d, n) in shapes.FAMILIES.items():
        if name in ("uniform2", "uniform3", "clustered3", "grid3"):
            continue
        out.append((f"{name} {n // 1000}k", ".txt", lambda f=name: shapes.make(f), False))
    for name in ("terrain", "rings", "sphere", "torus", "contrast"):
        out.append((f"{name} 1M", ".txt", lambda f=name: shapes.make(f, 1_000_000), False))
    out.append(("contours 1M", ".txt", lambda: shapes.contours(1_000_000), False))
    return out


def cases(big: bool, huge: bool, shapes_only: bool) -> list[tuple[str, str, callable, bool]]:
    """(name, file suffix, points, with Qhull)."""
    if shapes_only:
        return shape_cases()
    out = [
        ("3-d uniform 200k", ".txt", lambda: uniform(200_000, 3, 1), False),
        ("3-d uniform 1M", ".txt", lambda: uniform(1_000_000, 3, 2), False),
        ("2-d uniform 1M", ".txt", lambda: uniform(1_000_000, 2, 3), False),
        ("3-d clustered 1M", ".txt", lambda: clumps(1_000_000, 4), False),
    ]
    for kind in ("integer", "dyadic", "decimal", "linspace"):
        out.append((f"3-d {kind} grid 25^3", ".txt", lambda k=kind: grid(25, 3, k), False))
    for kind in ("integer", "linspace"):
        out.append((f"3-d {kind} grid 50^3", ".txt", lambda k=kind: grid(50, 3, k), False))
        out.append((f"2-d {kind} grid 1000^2", ".txt", lambda k=kind: grid(1000, 2, k), False))
    out += [
        ("4-d uniform 20k", ".txt", lambda: uniform(20_000, 4, 5), True),
        ("5-d uniform 5k", ".txt", lambda: uniform(5_000, 5, 6), True),
        ("6-d uniform 2k", ".txt", lambda: uniform(2_000, 6, 7), True),
    ]
    if big:
        out.append(("3-d uniform 4M", ".npy", lambda: uniform(4_000_000, 3, 8), False))
    if huge:
        out.append(("3-d uniform 16M", ".npy", lambda: uniform(16_000_000, 3, 9), False))
    return out


def materialise(name: str, suffix: str, make, data: Path) -> Path:
    path = data / (re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") + suffix)
    if not path.exists():
        points = make()
        tmp = path.with_name(path.name + ".part" + suffix)
        if suffix == ".npy":
            np.save(tmp, points)
        else:
            np.savetxt(tmp, points, fmt="%.17g")
        tmp.rename(path)
    return path


def qhull_file(points_file: Path) -> Path:
    out = points_file.with_suffix(".qhull")
    if not out.exists():
        points = np.load(points_file) if points_file.suffix == ".npy" else np.loadtxt(points_file, ndmin=2)
        with open(out, "w") as f:
            f.write(f"{points.shape[1]}\n{points.shape[0]}\n")
            np.savetxt(f, points, fmt="%.17g")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="")
    ap.add_argument("--big", action="store_true")
    ap.add_argument("--huge", action="store_true")
    ap.add_argument("--shapes", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="runs of each process; the best is reported")
    ap.add_argument("--data", default="/tmp/spokemesh-whole", help="where the generated inputs are kept")
    args = ap.parse_args()
    data = Path(args.data)
    data.mkdir(parents=True, exist_ok=True)
    print("| input | points | spokemesh | CGAL | Qhull | ratio to the faster peer | simplices |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, suffix, make, with_qhull in cases(args.big, args.huge, args.shapes):
        if args.only and args.only not in name:
            continue
        path = materialise(name, suffix, make, data)
        out = data / "out.simplices"
        best = lambda runs: min(runs, key=lambda r: r[0])  # noqa: E731
        ours = best([timed([str(BIN / "spokemesh"), "mesh", str(path), "-o", str(out), "-q", "--threads",
                            str(args.threads)]) for _ in range(args.repeat)])
        with open(out) as f:
            count = sum(1 for _ in f)
        out.unlink()
        cgal = None if "16M" in name else best([timed([str(BIN / "spokemesh_cgal_mesh"), str(path)])
                                                 for _ in range(args.repeat)])
        if cgal is not None and int(cgal[2]) != count:
            sys.exit(f"{name}: CGAL has {cgal[2].strip()} simplices, spokemesh {count}")
        qhull = None
        if with_qhull:
            q = qhull_file(path)
            qhull = best([timed(["sh", "-c", f"qdelaunay Qt i < {q} > /dev/null"]) for _ in range(args.repeat)])
        peers = [p[0] for p in (cgal, qhull) if p is not None]
        ratio = f"{ours[0] / min(peers):.2f}x" if peers else ""
        fmt = lambda r: f"{r[0]:.2f} s, {r[1]:.0f} MB" if r else ""  # noqa: E731
        points = sum(1 for _ in open(path)) if suffix == ".txt" else np.load(path, mmap_mode="r").shape[0]
        print(f"| {name} | {points:,} | {fmt(ours)} | {fmt(cgal)} | {fmt(qhull)} | {ratio} | {count:,} |", flush=True)


if __name__ == "__main__":
    main()
