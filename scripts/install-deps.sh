#!/usr/bin/env bash
# Installs the Debian bookworm packages spokemesh needs, skipping those present.
# Usage: scripts/install-deps.sh            (build + tests + benchmarks)
set -euo pipefail

packages=(
  build-essential cmake pkg-config
  libnanoflann-dev libeigen3-dev libgmp-dev
  libcli11-dev nlohmann-json3-dev
  # tests and benchmarks: GoogleTest, rapidcheck, and the oracles CGAL and Qhull
  libgtest-dev librapidcheck-dev libcgal-dev libboost-dev libmpfr-dev qhull-bin
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
echo "Installing: ${missing[*]}" >&2
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
