#!/usr/bin/env bash
# Set up, then run a complete simulated scan: writes out/demo/mesh.ply and
# out/demo/mesh.png (a picture of it). Extra arguments go to sfs-demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec "${SFS_VENV:-.venv}/bin/sfs-demo" "$@"
