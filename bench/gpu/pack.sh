#!/usr/bin/env bash
# pack.sh: ../shared/tools/gpu-bundle.sh for this project, less the structured-light scanner.
#
# reflcap-scan and acquire_scan_test load Open3D, VTK and assimp: 20 of the bundle's 58 MB
# (xz), which with the working tree (6 MB) passed the device tool's 64 MiB carry limit at
# ae2cc8d. The scanner has no GPU path, so they stay here: moved aside while the bundle is made,
# put back afterwards (also on failure). device_check.sh leaves their tests out of its ctest run.
#   usage, from the project's root after building:  bash bench/gpu/pack.sh [BUILD_DIR]
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
build=${1:-build}
aside=$(mktemp -d)
moved=()
restore() {
  for rel in "${moved[@]}"; do mv "$aside/$(basename "$rel")" "$build/$rel"; done
  rmdir "$aside"
}
trap restore EXIT
for rel in bin/reflcap-scan tests/acquire/scan/acquire_scan_test; do
  if [ -e "$build/$rel" ]; then
    mv "$build/$rel" "$aside/"
    moved+=("$rel")
  fi
done
../shared/tools/gpu-bundle.sh "$build"
du -sh .gpu .gl
