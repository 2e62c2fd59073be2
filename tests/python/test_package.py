"""README's Python section from a clean venv: `pip install --no-build-isolation
./clients/python` with Debian's Python (nothing downloaded), then the in-process module
against scipy and the remote client against a real server, from the installed package
only (not build/python)."""

from __future__ import annotations

import os
import subprocess
import sys

from conftest import REPO

SCRIPT = r"""
import sys
import numpy as np, spokemesh
from scipy.spatial import Delaunay as ScipyDelaunay
assert spokemesh.__file__.startswith(sys.prefix), spokemesh.__file__  # the installed copy
points = np.random.default_rng(1).random((2000, 3))
tri = spokemesh.Delaunay(points)
ref = ScipyDelaunay(points)
assert set(map(tuple, np.sort(tri.simplices, 1).tolist())) == set(map(tuple, np.sort(ref.simplices, 1).tolist()))
assert tri.cell(0, box=[0, 0, 0, 1, 1, 1]).volume > 0
client = spokemesh.remote.Client(sys.argv[1])
ps = client.upload(points)
assert np.array_equal(client.simplices(ps.id).astype(np.int64), tri.simplices.astype(np.int64))
many = client.batch_neighbors(ps.id, [i % 2000 for i in range(10_000)])   # 10,000 seeds, one call
assert len(many) == 10_000 and all(np.array_equal(m.neighbors, tri.neighbors_of(m.seed)) for m in many[:200])
print("ok")
"""


def test_pip_install_in_a_clean_venv_then_in_process_and_remote(server, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run(["/usr/bin/python3", "-m", "venv", "--system-site-packages", str(venv)], check=True)
    py = str(venv / "bin" / "python")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PIP_INDEX_URL")}
    env["PIP_NO_INDEX"] = "1"  # prove nothing is downloaded
    r = subprocess.run([py, "-m", "pip", "install", "--no-build-isolation", "--quiet", str(REPO / "clients" / "python")],
                       env=env, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    r = subprocess.run([py, "-c", SCRIPT, server.grpc], env=env, capture_output=True, text=True, timeout=300,
                       cwd=str(tmp_path))
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-3000:]
