#!/usr/bin/python3
"""A worked terrain example (docs/interpolation.md): a synthetic scan of a hillside
(scattered points, denser along survey lines, no point on a grid) gridded onto a raster
with natural-neighbour interpolation, by the CLI and in Python, and drawn as a PNG.

Usage: PYTHONPATH=build/python examples/terrain_raster.py [OUT_DIR]   (default: /tmp/terrain)
Writes scan.npy, heights.npy, raster.npy (CLI), and terrain.png (the Python raster,
coloured by height, shaded from the north-west); checks that both rasters agree.
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np

import spokemesh.interpolate as si

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build/bin"))


def hillside(xy: np.ndarray) -> np.ndarray:
    x, y = xy[:, 0], xy[:, 1]
    return (120 * np.exp(-((x - 300) ** 2 + (y - 650) ** 2) / 9e4) + 60 * np.exp(-((x - 750) ** 2 + (y - 300) ** 2) / 4e4)
            + 0.05 * x + 8 * np.sin(x / 45) * np.cos(y / 70))


def scan(n: int = 200_000, seed: int = 7) -> np.ndarray:
    """Points over a 1000 m x 1000 m square: 60% scattered, 40% along 25 survey lines."""
    rng = np.random.default_rng(seed)
    scattered = rng.random((int(0.6 * n), 2)) * 1000
    lines = rng.integers(0, 25, n - len(scattered))
    along = rng.random(len(lines)) * 1000
    across = 40 * lines + 20 + rng.normal(0, 1.5, len(lines))
    return np.concatenate([scattered, np.c_[along, across]])


def png(path: Path, rgb: np.ndarray) -> None:
    """An 8-bit RGB PNG (zlib-compressed rows with filter byte 0), written by hand."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[j].astype(np.uint8).tobytes() for j in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def draw(z: np.ndarray) -> np.ndarray:
    """Heights coloured from green (low) through brown to white (high), shaded by the
    slope towards a north-west light; NaN (outside the scan's hull) in grey."""
    lo, hi = np.nanmin(z), np.nanmax(z)
    t = np.clip((z - lo) / (hi - lo), 0, 1)
    stops = np.array([[40, 110, 60], [150, 140, 80], [130, 90, 50], [245, 245, 240]], float)
    at = t * (len(stops) - 1)
    k = np.clip(np.floor(np.nan_to_num(at)).astype(int), 0, len(stops) - 2)
    f = (np.nan_to_num(at) - k)[..., None]
    colour = stops[k] * (1 - f) + stops[k + 1] * f
    gy, gx = np.gradient(np.nan_to_num(z, nan=lo))
    shade = np.clip(0.75 + 0.04 * (-gx + gy), 0.45, 1.15)[..., None]
    rgb = np.clip(colour * shade, 0, 255)
    rgb[np.isnan(z)] = 180
    return rgb[::-1]  # north up


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/terrain")
    out.mkdir(parents=True, exist_ok=True)
    xy = scan()
    heights = hillside(xy)
    np.save(out / "scan.npy", xy)
    np.save(out / "heights.npy", heights)
    side = 500
    subprocess.run([str(BIN / "spokemesh"), "interpolate", str(out / "scan.npy"), str(out / "heights.npy"),
                    "--grid", f"0,0,1000,1000,{side},{side}", "-o", str(out / "raster.npy")], check=True)
    gx, gy = np.meshgrid(np.linspace(0, 1000, side), np.linspace(0, 1000, side))
    z = si.griddata(xy, heights, (gx, gy), method="natural")
    cli = np.load(out / "raster.npy")
    assert cli.shape == z.shape and np.allclose(cli, z, equal_nan=True, atol=1e-9), "CLI and Python rasters differ"
    truth = hillside(np.c_[gx.ravel(), gy.ravel()]).reshape(z.shape)
    error = np.nanmax(np.abs(z - truth))
    png(out / "terrain.png", draw(z))
    print(f"{len(xy):,} points -> {side} x {side} raster; largest error against the surface {error:.2f} m; "
          f"{int(np.isnan(z).sum())} cells outside the scan; {out / 'terrain.png'}")


if __name__ == "__main__":
    main()
