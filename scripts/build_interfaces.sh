#!/usr/bin/env bash
# Build the interface packages into the environment of scripts/setup.sh ($SFS_VENV, default
# .venv) with plain cmake, as colcon would in a ROS workspace: sfs_ros_interfaces (the
# cell's typed messages, services and actions), and tf2_msgs (TFMessage, upstream's
# definition) where the environment has none. ROS 2's code generators come from PyPI
# (requirements-ros-build.txt); g++ and make from Debian. A package already installed with
# the same definitions is not built again. Usage: scripts/build_interfaces.sh
set -euo pipefail
cd "$(dirname "$0")/.."
repo="$PWD"
venv="$(cd "${SFS_VENV:-.venv}" && pwd)"
python="$venv/bin/python"

debian=()
command -v g++ >/dev/null || debian+=(g++)
command -v make >/dev/null || debian+=(make)
# shellcheck source=scripts/debian_packages.sh
source scripts/debian_packages.sh
install_debian "${debian[@]}"
"$python" -m pip install -q -r requirements-ros-build.txt

# The wheels' exported *__rosidl_generator_py targets name an include directory of the
# machine that built them, which cmake refuses: scripts/cmake/drop_missing_includes.cmake,
# given as CMAKE_PROJECT_INCLUDE, drops the missing ones (shared with scripts/colcon_check.sh).
filter="$repo/scripts/cmake/drop_missing_includes.cmake"

# A package is built when its definitions differ from those installed (or none are).
build() {
    local source="$1" name
    name="$(basename "$source")"
    local stamp="$venv/share/$name/sfs_ros_build.sha256"
    local digest
    digest="$(cd "$source" && find . -type f | sort | xargs sha256sum | sha256sum | cut -d' ' -f1)"
    if [[ -f "$stamp" && "$(cat "$stamp")" == "$digest" ]] &&
        "$python" -c "import $name.msg" 2>/dev/null; then
        return
    fi
    echo "building $name into $venv"
    local work
    work="$(mktemp -d "${TMPDIR:-/tmp}/sfs_build_$name.XXXXXX")"
    (
        export AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv"
        "$venv/bin/cmake" -S "$source" -B "$work" -DCMAKE_INSTALL_PREFIX="$venv" \
            -DCMAKE_PREFIX_PATH="$venv" -DPython3_EXECUTABLE="$python" \
            -DCMAKE_PROJECT_INCLUDE="$filter" \
            -DBUILD_TESTING=OFF > "$work/configure.log" 2>&1 &&
        "$venv/bin/cmake" --build "$work" -j "$(nproc)" > "$work/build.log" 2>&1 &&
        "$venv/bin/cmake" --install "$work" > "$work/install.log" 2>&1
    ) || {
        cat "$work"/*.log >&2
        rm -rf "$work"
        echo "error: building $name failed (above)" >&2
        exit 1
    }
    rm -rf "$work"
    echo "$digest" > "$stamp"
}

"$python" -c "import tf2_msgs.msg" 2>/dev/null && [[ ! -f "$venv/share/tf2_msgs/sfs_ros_build.sha256" ]] ||
    build "$repo/third_party/tf2_msgs"
build "$repo/sfs_ros_interfaces"
"$python" -c "import sfs_ros_interfaces.action, sfs_ros_interfaces.srv, tf2_msgs.msg" || {
    echo "error: the interface packages do not import in $venv" >&2
    exit 1
}
