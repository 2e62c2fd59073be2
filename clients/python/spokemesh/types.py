"""Value types shared by the in-process module and the remote client (no gRPC here)."""

from __future__ import annotations

import dataclasses
from typing import List, Optional

import numpy as np


@dataclasses.dataclass(frozen=True)
class Facet:
    """One facet of a Voronoi cell: across a Delaunay neighbour, or on a domain wall."""
    neighbor: Optional[int]   # the Delaunay neighbour; None for a wall
    wall: Optional[int]       # the domain wall's index; None for a neighbour
    vertices: np.ndarray      # uint32 indices into Cell.vertices (3-d: counter-clockwise from outside)
    area: float               # (d-1)-measure; inf when unbounded
    normal: np.ndarray        # (d,) unit outward normal
    offset: Optional[np.ndarray] = None  # (d,) int32 on a torus: the neighbour's image offset


@dataclasses.dataclass(frozen=True)
class Cell:
    """A Voronoi cell with its measures (docs/cells.md), from either client."""
    seed: int
    vertices: np.ndarray          # (k, d) float64 (2-d: counter-clockwise)
    vertex_simplices: np.ndarray  # (k, d + 1) uint32; unclipped cells only (else empty)
    facets: List[Facet]           # neighbours ascending, then walls ascending
    bounded: bool
    volume: float                 # inf when unbounded
    centroid: Optional[np.ndarray] = None  # (d,); None when unbounded (or hidden)
    clipped: bool = False
    hidden: bool = False          # weighted points: the power cell is empty (volume 0, no facets)
