"""Timing helpers shared by the benchmarks: wall time of in-process calls by
time.perf_counter() (python_delaunay.py, python_voronoi.py, incremental.py), and wall
time and peak RSS of whole processes by GNU time (whole.py, cells.py, weighted.py)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional, TypeVar

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


def process(cmd: list[str], cwd: Optional[str] = None, stdin: Optional[Path] = None,
            timeout: Optional[float] = None) -> tuple[float, float, str]:
    """(wall seconds, peak RSS MB, stdout) of a process, from GNU time; exits with its
    stderr when it fails. With `timeout`: a process still running after that many
    seconds is stopped (with its children) and reported as (inf, nan, "")."""
    start = time.perf_counter()
    with open(stdin, "rb") if stdin else open(os.devnull, "rb") as inp:
        # Its own process group, so that a stop reaches the measured process under time.
        child = subprocess.Popen(["/usr/bin/time", "-v", *cmd], cwd=cwd, stdin=inp, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            out, err = child.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(child.pid, 9)
            child.communicate()
            return float("inf"), float("nan"), ""
        r = subprocess.CompletedProcess(child.args, child.returncode, out, err)
    wall = time.perf_counter() - start
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr).group(1)) / 1024
    return wall, rss, r.stdout
