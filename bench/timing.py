"""Timing helpers shared by the in-process Python benchmarks (python_delaunay.py,
python_voronoi.py, incremental.py): wall time by time.perf_counter()."""
from __future__ import annotations

import time
from typing import Callable, TypeVar

T = TypeVar("T")


def timed(fn: Callable[[], T]) -> tuple[T, float]:
    """fn's result and its wall time in seconds."""
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def best(fn: Callable[[], T], repeat: int) -> tuple[float, T]:
    """The least wall time of `repeat` calls of fn, and the last call's result."""
    times, out = [], None
    for _ in range(repeat):
        out, seconds = timed(fn)
        times.append(seconds)
    return min(times), out
