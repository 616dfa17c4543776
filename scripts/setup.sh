#!/usr/bin/env bash
# Set up a virtual environment with sfs_ros and its dependencies on a fresh
# Debian machine with Python 3.11, including ROS 2 Kilted's Python packages
# from PyPI (requirements-ros.txt; a colcon build in a ROS install uses the
# install's packages instead) and the interface packages built from source
# (scripts/build_interfaces.sh). Usage: scripts/setup.sh [--test]
#   --test  also install what the tests need (pytest; Debian's assimp-utils,
#           an independent mesh reader the export tests open files with, and
#           chromium, the headless browser the HTML viewer is tested in).
# The environment goes to $SFS_VENV (default: .venv in the repository).
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${SFS_VENV:-.venv}"

debian=()
python3 -c 'import ensurepip, venv' 2>/dev/null || debian+=(python3-venv)
if [[ "${1:-}" == "--test" ]]; then
    command -v assimp >/dev/null || debian+=(assimp-utils)
    command -v chromium >/dev/null || debian+=(chromium)
fi
# shellcheck source=scripts/debian_packages.sh
source scripts/debian_packages.sh
install_debian "${debian[@]}"

[[ -x "$venv/bin/python" ]] || python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
extras=""
[[ "${1:-}" == "--test" ]] && extras="[test]"
"$venv/bin/python" -m pip install -q -r requirements-ros.txt ".$extras"
"$venv/bin/python" -c "import rclpy, sensor_msgs.msg" || {
    echo "error: rclpy does not import in $venv" >&2
    exit 1
}
# The cell's typed interfaces (and tf2_msgs, which has no wheel), built with cmake.
SFS_VENV="$venv" bash scripts/build_interfaces.sh
# The compiled kernels are cached beside the installed modules: the first scan need not
# compile them (about a minute on 2 cores the first time, seconds after).
"$venv/bin/sfs-warm-up"
echo "environment ready: $venv"
