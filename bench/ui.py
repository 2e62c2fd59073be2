#!/usr/bin/python3
"""The browser page's first view: a stored 1M-point 3-d set opened at
http://HOST/#set=ID in Debian's headless Chromium (software WebGL, as on a machine with
no GPU), timed from navigation start to the first frame drawn with every point.

The page records performance.now() marks (window.spokemeshUi.timing): fetchStart (the
page's scripts ran, the list and the set's info arrived), fetched (the .npy of float32
coordinates, 12 MB for 1M 3-d points, read and decoded), built (the point cloud's buffer
made) and firstFrame (drawn, at the next animation frame, the GPU's work finished). The target: firstFrame <= 3 s.

Usage: bench/ui.py [--n 1000000] [--d 3] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

REPO = Path(__file__).resolve().parent.parent
BIN = Path(os.environ.get("SPOKEMESH_BIN_DIR", REPO / "build" / "bin"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--d", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        log = Path(work) / "server.log"
        server = subprocess.Popen([str(BIN / "spokemesh-server"), "--data-dir", f"{work}/data", "--grpc-listen",
                                   "127.0.0.1:0", "--http-listen", "127.0.0.1:0"], stderr=open(log, "wb"))
        try:
            base = None
            for _ in range(300):
                m = re.search(r"HTTP on ([\d.]+):(\d+)", log.read_text())
                if m:
                    base = f"http://{m.group(1)}:{m.group(2)}"
                    break
                time.sleep(0.05)
            assert base, log.read_text()
            points = np.random.default_rng(20261128).random((args.n, args.d))
            request = urllib.request.Request(f"{base}/v1/pointsets?dimension={args.d}&display_name=bench",
                                             data=points.tobytes(), method="POST",
                                             headers={"Content-Type": "application/octet-stream"})
            pid = json.loads(urllib.request.urlopen(request, timeout=600).read())["id"]
            options = webdriver.ChromeOptions()
            for flag in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                         "--enable-unsafe-swiftshader", "--window-size=1400,900"]:
                options.add_argument(flag)
            driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
            marks = []
            try:
                for _ in range(args.repeats):
                    driver.get("about:blank")
                    driver.get(f"{base}/#set={pid}")
                    deadline = time.time() + 60
                    while time.time() < deadline:
                        timing = driver.execute_script("return window.spokemeshUi && window.spokemeshUi.timing")
                        if timing and "firstFrame" in timing:
                            break
                        time.sleep(0.02)
                    marks.append(timing)
            finally:
                driver.quit()
        finally:
            server.send_signal(signal.SIGTERM)
            server.wait(60)
    print(f"first view of a stored {args.n}-point {args.d}-d set in headless Chromium, {args.repeats} runs (ms "
          "from navigation start; median, min, max):")
    for key in ["fetchStart", "fetched", "built", "firstFrame"]:
        values = [m[key] for m in marks]
        print(f"  {key:10s} {statistics.median(values):8.0f} {min(values):8.0f} {max(values):8.0f}")


if __name__ == "__main__":
    main()
