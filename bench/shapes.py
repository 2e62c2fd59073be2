"""The shapes users bring: point sets whose nearest neighbours lie along a
line, a curve or a surface while their Delaunay neighbours lie across it. Each
generator takes the point count it aims at (or its own natural size) and a seed, and
returns a float64 array of shape (n, d); the same arguments give the same points.

Families (FAMILIES maps a name to (generator, dimension, default n)):
- contours: 2-d contour lines, 60 nested closed curves (radius 5 + 8k, wobbled 5%),
  a point every 0.5 along each, rounded to 1e-3 (about 180k points);
- terrain: 2.5-d, x, y uniform over 1000 x 1000, z a smooth surface of amplitude 3
  plus noise 0.05 (a LiDAR ground model);
- rings: a scanner 2 m above a ground plane, 32 elevation rings x 3000 azimuths (more
  rings for more points), noise 2 mm, rounded to 0.1 mm (96,000 points, repeated
  returns dropped); rings_buildings: the same with box-shaped buildings around it;
- sphere, torus: points on the surfaces (float64);
- isosurface: the vertices of a marching-cubes isosurface of a blobby implicit (each
  on a grid edge where the function changes sign, linearly interpolated);
- contrast: nearest-neighbour spacing over six orders of magnitude (50 clumps of
  width 1e-5 in a box of width 100, plus uniform points);
- uniform, clustered (gaussian clumps), grid (integer grid) in 2-d and 3-d.

`n` sets each family's free count (curves, azimuths, samples, grid resolution); its
other parameters (spacing along a curve, noise) stay as the family defines them.
"""
from __future__ import annotations

import math

import numpy as np


def contours(n: int = 181_680, seed: int = 1) -> np.ndarray:
    """60 nested closed curves r(t) = (5 + 8k)(1 + 0.05 wobble(t)), a point every 0.5
    of arc length, coordinates rounded to 1e-3. `n` is ignored beyond choosing how many
    curves (60 at the default; fewer or more in proportion)."""
    rng = np.random.default_rng(seed)
    curves = max(1, int(round(60 * math.sqrt(n / 181_680))))
    out = []
    for k in range(curves):
        r0 = 5.0 + 8.0 * k
        phase = rng.uniform(0, 2 * math.pi, 3)
        freq = np.array([3, 5, 7])
        # Arc length of the wobbled curve, then points every 0.5 along it.
        t = np.linspace(0.0, 2 * math.pi, 20_000, endpoint=False)
        wobble = sum(np.sin(f * t + p) for f, p in zip(freq, phase)) / 3.0
        r = r0 * (1 + 0.05 * wobble)
        xy = np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
        seg = np.linalg.norm(np.roll(xy, -1, axis=0) - xy, axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        count = int(arc[-1] / 0.5)
        s = np.arange(count) * (arc[-1] / count)
        tt = np.interp(s, arc, np.concatenate([t, [2 * math.pi]]))
        ww = sum(np.sin(f * tt + p) for f, p in zip(freq, phase)) / 3.0
        rr = r0 * (1 + 0.05 * ww)
        out.append(np.stack([rr * np.cos(tt), rr * np.sin(tt)], axis=1))
    return np.round(np.concatenate(out), 3)


def terrain(n: int = 200_000, seed: int = 2) -> np.ndarray:
    """x, y uniform over [0, 1000]^2, z = a smooth surface of amplitude 3 + N(0, 0.05)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1000.0, (n, 2))
    x, y = xy[:, 0], xy[:, 1]
    z = (1.5 * np.sin(x / 97.0) * np.cos(y / 131.0) + 1.0 * np.sin((x + y) / 53.0)
         + 0.5 * np.cos(x / 23.0 - y / 41.0)) + rng.normal(0.0, 0.05, n)
    return np.column_stack([x, y, z])


def _scanner(rng: np.random.Generator, elevations: int, azimuths: int, boxes: list) -> np.ndarray:
    """Rays from a scanner at (0, 0, 2) hitting the ground z = 0 (or an axis-aligned box
    first), range up to 120 m; noise 2 mm along each coordinate, rounded to 0.1 mm."""
    origin = np.array([0.0, 0.0, 2.0])
    # Elevations from -25 to -1 degrees (every ring hits the ground within 120 m).
    elev = np.radians(np.linspace(-25.0, -1.0, elevations))
    az = np.linspace(0.0, 2 * math.pi, azimuths, endpoint=False)
    e, a = np.meshgrid(elev, az, indexing="ij")
    e, a = e.ravel(), a.ravel()
    # Every ring's azimuths are offset a little (a spinning head's timing).
    a = a + rng.uniform(0, 2 * math.pi / azimuths, elevations).repeat(azimuths)
    dirs = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    t = -origin[2] / dirs[:, 2]  # the ground
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo - origin) / dirs
            t2 = (hi - origin) / dirs
        tmin = np.nanmax(np.minimum(t1, t2), axis=1)
        tmax = np.nanmin(np.maximum(t1, t2), axis=1)
        hit = (tmax >= tmin) & (tmin > 0) & (tmin < t)
        t = np.where(hit, tmin, t)
    keep = t < 120.0
    pts = origin + dirs[keep] * t[keep, None]
    pts += rng.normal(0.0, 0.002, pts.shape)
    # Rounded to 0.1 mm, near the scanner two returns can coincide: one is kept.
    pts = np.round(pts, 4)
    _, first = np.unique(pts, axis=0, return_index=True)
    return pts[np.sort(first)]


def _ring_counts(n: int) -> tuple[int, int]:
    """(elevation rings, azimuths) for about n points: 32 x 3000 at the default; more
    rings (a denser scanner) for more points, fewer azimuths for fewer."""
    return (max(32, n // 3000), max(16, min(3000, n // 32)))


def rings(n: int = 96_000, seed: int = 3) -> np.ndarray:
    """Elevation rings over a ground plane: 32 x 3000 azimuths at the default n."""
    return _scanner(np.random.default_rng(seed), *_ring_counts(n), [])


def rings_buildings(n: int = 96_000, seed: int = 4) -> np.ndarray:
    """The scanner rings with eight box-shaped buildings around the scanner."""
    rng = np.random.default_rng(seed)
    boxes = []
    for k in range(8):
        angle = k * math.pi / 4 + rng.uniform(-0.2, 0.2)
        dist = rng.uniform(15.0, 40.0)
        cx, cy = dist * math.cos(angle), dist * math.sin(angle)
        w, l, h = rng.uniform(4.0, 10.0), rng.uniform(4.0, 10.0), rng.uniform(3.0, 12.0)
        boxes.append(((cx - w / 2, cy - l / 2, 0.0), (cx + w / 2, cy + l / 2, h)))
    return _scanner(rng, *_ring_counts(n), boxes)


def sphere(n: int = 20_000, seed: int = 5) -> np.ndarray:
    """n points uniform on the unit sphere (normalised gaussians, float64)."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def torus(n: int = 100_000, seed: int = 6) -> np.ndarray:
    """n points on a torus (major radius 3, minor 1), uniform in the angles' area
    measure (rejection on the minor angle)."""
    rng = np.random.default_rng(seed)
    out = np.empty((0, 3))
    big, small = 3.0, 1.0
    while len(out) < n:
        m = 2 * (n - len(out)) + 16
        u = rng.uniform(0, 2 * math.pi, m)
        v = rng.uniform(0, 2 * math.pi, m)
        keep = rng.uniform(0, 1, m) < (big + small * np.cos(v)) / (big + small)
        u, v = u[keep], v[keep]
        pts = np.stack([(big + small * np.cos(v)) * np.cos(u), (big + small * np.cos(v)) * np.sin(u),
                        small * np.sin(v)], axis=1)
        out = np.concatenate([out, pts])
    return out[:n]


def isosurface(n: int = 100_000, seed: int = 7) -> np.ndarray:
    """The vertices marching cubes puts on the level set f = 1 of a sum of gaussian
    blobs: a point on every grid edge whose ends straddle the level, interpolated
    linearly. The grid's resolution is chosen so that there are about n of them."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-0.5, 0.5, (6, 3))
    widths = rng.uniform(0.25, 0.4, 6)

    def f(x, y, z):
        out = np.zeros(np.broadcast(x, y, z).shape)
        for c, w in zip(centres, widths):
            out += np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / (w * w))
        return out

    # Vertices grow as side^2: about 0.41 side^2 for these blobs (measured at 149).
    side = max(8, int(round(math.sqrt(n / 0.41))))
    axis = np.linspace(-1.5, 1.5, side)
    X, Y, Z = np.meshgrid(axis, axis, axis, indexing="ij")
    F = f(X, Y, Z) - 1.0
    pts = []
    for ax in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[ax] = slice(0, -1)
        b[ax] = slice(1, None)
        fa, fb = F[tuple(a)], F[tuple(b)]
        cross = (fa < 0) != (fb < 0)
        t = fa[cross] / (fa[cross] - fb[cross])
        base = [G[tuple(a)][cross] for G in (X, Y, Z)]
        step = axis[1] - axis[0]
        base[ax] = base[ax] + t * step
        pts.append(np.stack(base, axis=1))
    return np.concatenate(pts)


def contrast(n: int = 100_000, seed: int = 8) -> np.ndarray:
    """Half the points in 50 gaussian clumps of width 1e-5, half uniform, in [0, 100]^3:
    nearest-neighbour spacing from about 1e-6 inside a clump to about 3 outside."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 100, (50, 3))
    k = n // 2
    clumped = centres[rng.integers(0, 50, k)] + rng.normal(0.0, 1e-5, (k, 3))
    return np.concatenate([clumped, rng.uniform(0, 100, (n - k, 3))])


def uniform3(n: int = 1_000_000, seed: int = 9) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 3))


def uniform2(n: int = 1_000_000, seed: int = 10) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 2))


def clustered3(n: int = 1_000_000, seed: int = 11) -> np.ndarray:
    """1,000 gaussian clumps (sigma 0.01) at uniform centres in the unit cube."""
    rng = np.random.default_rng(seed)
    centres = rng.random((1000, 3))
    return centres[rng.integers(0, 1000, n)] + rng.normal(0, 0.01, (n, 3))


def grid3(n: int = 125_000, seed: int = 0) -> np.ndarray:
    side = max(2, int(round(n ** (1 / 3))))
    a = np.arange(side, dtype=float)
    return np.stack(np.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3)


FAMILIES = {
    "contours": (contours, 2, 181_680),
    "terrain": (terrain, 3, 200_000),
    "rings": (rings, 3, 96_000),
    "rings_buildings": (rings_buildings, 3, 96_000),
    "sphere": (sphere, 3, 100_000),
    "torus": (torus, 3, 100_000),
    "isosurface": (isosurface, 3, 100_000),
    "contrast": (contrast, 3, 100_000),
    "uniform3": (uniform3, 3, 1_000_000),
    "uniform2": (uniform2, 2, 1_000_000),
    "clustered3": (clustered3, 3, 1_000_000),
    "grid3": (grid3, 3, 125_000),
}


def make(name: str, n: int | None = None, seed: int | None = None) -> np.ndarray:
    """Points of family `name`: its default size and seed unless given."""
    if name not in FAMILIES:
        raise ValueError(f"unknown shape family {name!r}: one of {', '.join(FAMILIES)}")
    gen, _, default_n = FAMILIES[name]
    kwargs = {"n": n if n is not None else default_n}
    if seed is not None:
        kwargs["seed"] = seed
    return gen(**kwargs)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="write one shape family's points as text (%.17g)")
    ap.add_argument("family", choices=sorted(FAMILIES))
    ap.add_argument("out")
    ap.add_argument("-n", type=int, default=None)
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args()
    pts = make(args.family, args.n, args.seed)
    if args.out.endswith(".npy"):
        np.save(args.out, pts)
    else:
        np.savetxt(args.out, pts, fmt="%.17g")
    print(f"{args.family}: {len(pts)} points, d = {pts.shape[1]}")
