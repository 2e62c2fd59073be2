"""Fixtures for the real-process tests: spokemesh-server processes on loopback ports,
the CLI, and small HTTP helpers. Run with Debian's interpreter (/usr/bin/python3),
which has python3-grpcio and python3-numpy; ctest sets PYTHONPATH to build/python."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import openapi_check
import pytest

REPO = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build" / "bin"))
SERVER = BIN / "spokemesh-server"
CLI = BIN / "spokemesh"

def unavailable(message: str) -> None:
    """The suite's one skip policy: under CI (CI=true) a test that cannot run fails the
    run, since a green CI must mean everything was tested; elsewhere it is skipped,
    saying why. Call it at module level or inside a test or fixture."""
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(message + "; CI=true, so this is a failure, not a skip", pytrace=False)
    pytest.skip(message, allow_module_level=True)


def missing(what: str, packages: str) -> None:
    """unavailable() for a tool or package this machine lacks, naming how to install it."""
    unavailable(f"{what} is missing: install it with `sudo apt-get install {packages}` "
                "(scripts/install-deps.sh installs everything the suite needs)")


def as_root(command: list) -> list:
    """The command run as root: directly when the suite runs as root, else through a
    sudo that asks no password; None when neither can."""
    if os.geteuid() == 0:
        return command
    if shutil.which("sudo") and subprocess.run(["sudo", "-n", "true"], capture_output=True).returncode == 0:
        return ["sudo", "-n", *command]
    return None


_SERVING = re.compile(r"serving gRPC on ([\d.]+):(\d+) and HTTP on ([\d.]+):(\d+)")


class Server:
    """One spokemesh-server process. Ports are chosen by the kernel (port 0) and read
    back from the server's own start-up log line."""

    def __init__(self, data_dir: Path, log_path: Path, *args: str, grpc_port: int = 0, http_port: int = 0,
                 host: str = "127.0.0.1"):
        self.data_dir, self.log_path, self.args, self.host = data_dir, log_path, args, host
        self.requested = (grpc_port, http_port)
        self.proc = None
        self.start()

    def start(self) -> None:
        self._log = open(self.log_path, "ab")
        self._offset = self.log_path.stat().st_size
        self.proc = subprocess.Popen(
            [str(SERVER), "--data-dir", str(self.data_dir), "--grpc-listen", f"{self.host}:{self.requested[0]}",
             "--http-listen", f"{self.host}:{self.requested[1]}", "--threads", "2", *self.args],
            stderr=self._log, stdout=subprocess.DEVNULL)
        deadline = time.time() + 30
        while time.time() < deadline:
            text = self.log_path.read_bytes()[self._offset:].decode(errors="replace")
            m = _SERVING.search(text)
            if m:
                self.grpc = f"{m.group(1)}:{m.group(2)}"
                self.http = f"http://{m.group(3)}:{m.group(4)}"
                self.requested = (int(m.group(2)), int(m.group(4)))  # a restart keeps the ports
                return
            if self.proc.poll() is not None:
                raise RuntimeError(f"spokemesh-server exited with {self.proc.returncode}:\n{text}")
            time.sleep(0.02)
        raise RuntimeError("spokemesh-server did not start within 30 s:\n" + self.log())

    def log(self) -> str:
        # A finished request's line is written within 100 ms (Telemetry::kLogFlushEvery).
        if self.proc is not None and self.proc.poll() is None:
            time.sleep(0.25)
        return self.log_path.read_text(errors="replace")

    def log_records(self) -> list:
        return [json.loads(line) for line in self.log().splitlines() if line.startswith("{")]

    def stop(self, timeout: float = 30) -> int:
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout)
        self._log.close()
        return self.proc.returncode

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        self._log.close()


@pytest.fixture
def start_server(tmp_path):
    servers = []

    def start(*args: str, data_dir: Path | None = None, name: str = "server", **where) -> Server:
        d = data_dir or tmp_path / "data"
        s = Server(d, tmp_path / f"{name}-{len(servers)}.log", *args, **where)
        servers.append(s)
        return s

    yield start
    for s in servers:
        if s.proc.poll() is None:
            s.kill()


@pytest.fixture
def server(start_server) -> Server:
    return start_server()


def http(method: str, url: str, body=None, headers=None, timeout: float = 60, context=None):
    """(status, headers, body bytes) for a request; never raises for HTTP errors."""
    data = body
    hdrs = dict(headers or {})
    if isinstance(body, (dict, list)):
        data = json.dumps(body).encode()
        hdrs.setdefault("Content-Type", "application/json")
    req = urllib.request.Request(url, data=data, method=method, headers=hdrs)
    try:
        with urllib.request.urlopen(req, timeout=timeout, context=context) as r:
            status, got_headers, got = r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        status, got_headers, got = e.code, dict(e.headers), e.read()
    # Every REST answer the suite receives must match docs/openapi.yaml.
    openapi_check.check(method, url, status, got_headers, got)
    return status, got_headers, got


def http_json(method: str, url: str, body=None, headers=None, context=None):
    status, _, data = http(method, url, body, headers, context=context)
    return status, json.loads(data)


def cli(*args: str, check: bool = True, timeout: float = 120) -> subprocess.CompletedProcess:
    r = subprocess.run([str(CLI), *args], capture_output=True, text=True, timeout=timeout)
    if check and r.returncode != 0:
        raise AssertionError(f"spokemesh {' '.join(args)} -> {r.returncode}\n{r.stderr}")
    return r


def uniform(n: int, d: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((n, d))


def local_mesh(points: np.ndarray, tmp_path: Path) -> np.ndarray:
    """The mesh from the local CLI, (m, d + 1), as the reference for remote answers."""
    src = tmp_path / f"points-{points.shape[0]}-{abs(hash(points.tobytes())) % 10**8}.npy"
    np.save(src, points)
    out = src.with_suffix(".simplices")
    cli("mesh", str(src), "-o", str(out), "-q")
    return np.loadtxt(out, dtype=np.int64, ndmin=2)


def star_of(mesh: np.ndarray, seed: int) -> np.ndarray:
    """The rows of a whole mesh (in sweep order) that contain `seed`, in a star's order:
    lexicographic by their sorted indices."""
    rows = mesh[(mesh == seed).any(axis=1)]
    return rows[np.lexsort(np.sort(rows, axis=1).T[::-1])]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_nginx(ndir: Path, rest_url: str) -> subprocess.Popen:
    """Debian's nginx on ndir/nginx.conf, in the foreground; returns once rest_url's
    /healthz answers through it (fails the test if nginx exits first)."""
    nginx = shutil.which("nginx") or "/usr/sbin/nginx"
    if not os.path.exists(nginx):
        missing("nginx", "nginx")
    proc = subprocess.Popen([nginx, "-p", str(ndir), "-c", str(ndir / "nginx.conf"), "-g", "daemon off;"],
                            stderr=open(ndir / "stderr.log", "wb"))
    deadline = time.time() + 20
    while time.time() < deadline:
        try:
            if http("GET", f"{rest_url}/healthz", timeout=2)[0] == 200:
                return proc
        except OSError:
            pass
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    logs = "".join(p.read_text() for p in (ndir / "stderr.log", ndir / "error.log") if p.exists())
    proc.kill()
    pytest.fail("nginx did not come up: " + logs)

