"""A spokemesh-server of this build on loopback, for the benchmarks that call one:
started with a temporary data directory and free ports, stopped on exit."""
from __future__ import annotations

import contextlib
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


@contextlib.contextmanager
def local_server(*extra: str):
    """Yields (gRPC target, HTTP target) of a server started with `extra` flags."""
    data = tempfile.mkdtemp(prefix="spokemesh-bench-")
    log_path = os.path.join(data, "server.log")
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([str(REPO / "build/bin/spokemesh-server"), "--data-dir", data, "--grpc-listen",
                                 "127.0.0.1:0", "--http-listen", "127.0.0.1:0", *extra], stderr=log)
        try:
            for _ in range(1500):
                text = Path(log_path).read_text()
                g, h = re.search(r"serving gRPC on ([\d.]+:\d+)", text), re.search(r"HTTP on ([\d.]+:\d+)", text)
                if g and h:
                    yield g.group(1), h.group(1)
                    return
                if proc.poll() is not None:
                    raise RuntimeError(f"spokemesh-server exited: {text[-2000:]}")
                time.sleep(0.02)
            raise RuntimeError("spokemesh-server did not start")
        finally:
            proc.terminate()
            proc.wait(timeout=60)
