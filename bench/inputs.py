"""Point sets for the in-process Python benchmarks, made the way users make them:
uniform random, Gaussian clusters, a grid from numpy.linspace (every sphere a tie), or
one of the shapes users bring (bench/shapes.py: contour lines, terrain, scanner rings,
surfaces, density contrast)."""
from __future__ import annotations

import numpy as np

import shapes

KINDS = ("uniform", "clustered", "grid", *shapes.FAMILIES)


def points(kind: str, n: int, d: int, seed: int) -> np.ndarray:
    """About n points in [0, 1]^d (a grid has round(n^(1/d))^d of them)."""
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return rng.random((n, d))
    if kind == "clustered":
        # 100 clusters of n / 100 points each, standard deviation 1% of the box.
        centres = rng.random((100, d))
        return (centres[rng.integers(0, 100, n)] + rng.normal(0.0, 0.01, (n, d))).astype(np.float64)
    if kind == "grid":
        side = int(round(n ** (1.0 / d)))
        axes = [np.linspace(0.0, 1.0, side)] * d
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)
    if kind in shapes.FAMILIES:  # its own dimension: d must agree
        pts = shapes.make(kind, n, seed)
        if pts.shape[1] != d:
            raise ValueError(f"{kind} points are {pts.shape[1]}-d, not {d}-d")
        return pts
    raise ValueError(f"unknown kind {kind!r}: one of {', '.join(KINDS)}")
