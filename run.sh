#!/usr/bin/env bash
# The main job: install what is missing, build, and mesh the bundled examples.
set -euo pipefail
cd "$(dirname "$0")"
scripts/install-deps.sh
scripts/build.sh spokemesh_cli
mkdir -p out
for example in examples/*.txt; do
  name=$(basename "$example" .txt)
  ext=vtu
  case "$name" in *-2d*) ext=svg ;; *-4d*|*-5d*|*-6d*) ext=simplices ;; esac
  build/bin/spokemesh mesh "$example" -o "out/$name.$ext"
  build/bin/spokemesh mesh -q "$example" -o "out/$name.simplices"
  build/bin/spokemesh check "$example" "out/$name.simplices"
done
echo "Meshes are in out/ (open the .vtu files in ParaView, the .svg in a browser)."
