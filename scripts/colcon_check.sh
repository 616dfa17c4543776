#!/usr/bin/env bash
# Build sfs_ros and sfs_ros_interfaces with colcon in a temporary workspace, the way
# doc/ros_workspace.md tells a ROS workspace to (the repository cloned as src/sfs_ros, the
# nested interface package named as a second base path), and check what a ROS install
# needs: colcon finds exactly these two packages (not third_party/tf2_msgs), an executable
# lib/sfs_ros/<script> for every console script of setup.py, share/sfs_ros/{launch,config,
# urdf} with the repository's files, package.xml and the ament index entries; then, from
# the sourced install, two commands run and the interfaces (sfs_ros_interfaces.action.Scan)
# import and serialise from the workspace's install, not from the environment; last, a quick
# `colcon test` (doc/testing.md: the markers through --pytest-args) of a few test files
# passes, and the cell's tests among them are left out.
# Uses the environment of scripts/setup.sh ($SFS_VENV, default .venv) as the underlay (its
# ROS 2 wheels stand in for a ROS install) and installs colcon-common-extensions (PyPI)
# into it when missing. Exits non-zero on any failure; the workspace is removed in any
# case. Usage: scripts/colcon_check.sh
set -euo pipefail
cd "$(dirname "$0")/.."
repo="$PWD"
[[ -x "${SFS_VENV:-.venv}/bin/python" ]] || {
    echo "error: no environment at ${SFS_VENV:-.venv}: run scripts/setup.sh first" >&2
    exit 1
}
venv="$(cd "${SFS_VENV:-.venv}" && pwd)"
python="$venv/bin/python"
[[ -x "$venv/bin/colcon" ]] || "$python" -m pip install -q colcon-common-extensions

ws="$(mktemp -d "${TMPDIR:-/tmp}/sfs_colcon.XXXXXX")"
trap 'rm -rf "$ws"' EXIT
mkdir -p "$ws/src/sfs_ros"
# The package's files only (no environment, history or earlier builds).
tar -C "$repo" --exclude=./.venv --exclude=./.git --exclude=./build --exclude=./install \
    --exclude=./log --exclude='__pycache__' --exclude='*.egg-info' -cf - . |
    tar -C "$ws/src/sfs_ros" -xf -

# As doc/ros_workspace.md says: colcon stops descending at a package, so the interface
# package nested in the repository is named as a base path of its own.
base_paths=(src src/sfs_ros/sfs_ros_interfaces)
# colcon runs setup.py with the Python it runs under: the venv's, as in a sourced ROS install.
colcon() { (cd "$ws" && PATH="$venv/bin:$PATH" "$venv/bin/colcon" "$@"); }
found=$(colcon list --names-only --base-paths src | sort | xargs)
[[ "$found" == "sfs_ros" ]] || {
    echo "error: colcon finds '$found' in src, not sfs_ros alone (doc/ros_workspace.md)" >&2
    exit 1
}
# Exactly the two packages (the repository's third_party/tf2_msgs is not one), in order.
found=$(colcon list --names-only --topological-order --base-paths "${base_paths[@]}" | xargs)
[[ "$found" == "sfs_ros_interfaces sfs_ros" ]] || {
    echo "error: colcon finds '$found', not sfs_ros_interfaces then sfs_ros" >&2
    exit 1
}
# The interface package is built against the environment's PyPI wheels: their cmake
# packages are found through AMENT_PREFIX_PATH and CMAKE_PREFIX_PATH (what a sourced ROS
# install sets), and scripts/cmake/drop_missing_includes.cmake (as in
# scripts/build_interfaces.sh) drops the include directory the wheels' generator targets
# name but do not ship. A ROS install needs neither.
started=$SECONDS
AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv" \
    colcon build --event-handlers console_direct- --base-paths "${base_paths[@]}" \
    --packages-up-to sfs_ros --cmake-args -DPython3_EXECUTABLE="$python" \
    -DCMAKE_PROJECT_INCLUDE="$repo/scripts/cmake/drop_missing_includes.cmake" \
    -DBUILD_TESTING=OFF > "$ws/build.log" 2>&1 || {
    cat "$ws/build.log" >&2
    echo "error: colcon build failed" >&2
    exit 1
}
echo "colcon build of sfs_ros_interfaces and sfs_ros: $((SECONDS - started)) s"

prefix="$ws/install/sfs_ros"
failures=0
# What follows compares the install with the sources colcon built (their copy in src/).
cd "$ws/src/sfs_ros"
fail() { echo "error: $*" >&2; failures=$((failures + 1)); }

scripts=$("$python" - <<'EOF'
import ast
tree = ast.parse(open("setup.py").read())
setup = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
             and getattr(n.func, "id", None) == "setup")
entry_points = ast.literal_eval(next(k.value for k in setup.keywords if k.arg == "entry_points"))
for line in entry_points["console_scripts"]:
    print(line.split("=")[0].strip())
EOF
)
[[ -n "$scripts" ]] || fail "no console scripts found in setup.py"
for script in $scripts; do
    [[ -x "$prefix/lib/sfs_ros/$script" ]] || fail "lib/sfs_ros/$script is not installed"
done

share="$prefix/share/sfs_ros"
for pattern in "launch/*.launch.py" "config/*.yaml" "urdf/*.urdf" "urdf/*.urdf.xacro"; do
    files=( $pattern )
    [[ -e "${files[0]}" ]] || fail "the repository has no $pattern"
    for file in "${files[@]}"; do
        cmp -s "$file" "$share/$file" || fail "share/sfs_ros/$file is missing or differs"
    done
done
cmp -s package.xml "$share/package.xml" || fail "share/sfs_ros/package.xml is missing"
[[ -f "$prefix/share/ament_index/resource_index/packages/sfs_ros" ]] ||
    fail "no ament index entry share/ament_index/resource_index/packages/sfs_ros"

# The interface package: its definitions, package.xml and index entries installed; the
# repository's third_party/tf2_msgs is not a package of the workspace (a ROS install has its own).
iprefix="$ws/install/sfs_ros_interfaces"
ishare="$iprefix/share/sfs_ros_interfaces"
isource="$ws/src/sfs_ros/sfs_ros_interfaces"
definitions=( $(cd "$isource" && echo msg/*.msg srv/*.srv action/*.action) )
[[ -e "$isource/${definitions[0]}" ]] || fail "the repository has no interface definitions"
for file in "${definitions[@]}" package.xml; do
    cmp -s "$isource/$file" "$ishare/$file" ||
        fail "share/sfs_ros_interfaces/$file is missing or differs"
done
for resource in packages rosidl_interfaces; do
    [[ -f "$iprefix/share/ament_index/resource_index/$resource/sfs_ros_interfaces" ]] ||
        fail "no ament index entry share/ament_index/resource_index/$resource/sfs_ros_interfaces"
done
[[ ! -e "$ws/install/tf2_msgs" && ! -e "$ws/build/tf2_msgs" ]] ||
    fail "third_party/tf2_msgs was built in the workspace"

# From the install, with the workspace sourced and outside the source tree: the
# commands start, the bag reader imports (rosbags), the share folder is found, and every
# interface type imports and serialises from the workspace's install: its Python modules
# and every shared library of sfs_ros_interfaces the process maps.
(
    set +u
    # shellcheck disable=SC1091
    source "$ws/install/setup.bash"
    set -u
    cd "$ws"
    PATH="$venv/bin:$PATH"
    "$prefix/lib/sfs_ros/sfs-reconstruct" --help > /dev/null
    python -c "import sfs_ros.cell_logic.bag, sfs_ros, sys; \
assert sfs_ros.__file__.startswith('$ws/install/'), sfs_ros.__file__"
    found=$(python -c "from ament_index_python.packages import get_package_share_directory as g; \
print(g('sfs_ros'))")
    [[ "$found" == "$share" ]] || { echo "ament index gives $found, not $share" >&2; exit 1; }
    # The wheels' start-up hook (ros_wheels_bootstrapper) would put the environment's
    # library folders on LD_LIBRARY_PATH in no fixed order, the environment's own build of
    # sfs_ros_interfaces among them: here they follow the workspace's, as an underlay's do.
    libs=("$venv/lib" "$venv"/lib/python3.*/site-packages/ros_*.libs)
    LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}$(IFS=:; echo "${libs[*]}")" \
        _ROS_WHEELS_BOOTSTRAP_COMPLETE=1 python - "$iprefix/" "${definitions[@]}" <<'EOF'
import importlib
import sys
from pathlib import Path

from rclpy.serialization import deserialize_message, serialize_message

import sfs_ros_interfaces

install, definitions = sys.argv[1], sys.argv[2:]
assert sfs_ros_interfaces.__file__.startswith(install), sfs_ros_interfaces.__file__
# Every type of every definition (sfs_ros_interfaces.action.Scan: its goal, result,
# feedback and the action's services and feedback message) survives a round trip.
parts = {"msg": [""], "srv": ["Request", "Response"],
         "action": ["Goal", "Result", "Feedback", "Impl.SendGoalService.Request",
                    "Impl.GetResultService.Response", "Impl.FeedbackMessage"]}
for definition in map(Path, definitions):
    kind = definition.suffix[1:]
    interface = getattr(importlib.import_module(f"sfs_ros_interfaces.{kind}"), definition.stem)
    for part in parts[kind]:
        message_type = interface
        for name in filter(None, part.split(".")):
            message_type = getattr(message_type, name)
        message = message_type()
        assert deserialize_message(serialize_message(message), message_type) == message, \
            (definition, part)
with open("/proc/self/maps") as maps:
    mapped = {line.split()[-1] for line in maps if "sfs_ros_interfaces" in line}
assert mapped, "no library of sfs_ros_interfaces is mapped"
elsewhere = sorted(path for path in mapped if not path.startswith(install))
assert not elsewhere, f"mapped from outside {install}: {elsewhere}"
EOF
) || fail "the installed packages do not run (above)"

# A quick colcon test, as doc/testing.md gives it: pytest in the package's source folder
# (the tests import the sources there), the workspace's install on the path (node processes
# import sfs_ros_interfaces from it), `-m "not cell"` passed through --pytest-args. The test
# files: pure checks, node processes, and two tests that bring the cell up (left out).
# The numba kernels the tests' node processes load are cached beside the sources: the
# repository's cache (its sources are the same, and numba keys the cache on their content)
# is copied in when there is one, else the session compiles them first (test/conftest.py).
quick=(test/test_bringup.py test/test_config_files.py test/test_launch_files.py)
(cd "$repo" && find sfs_ros -path '*/__pycache__/*' \( -name '*.nbi' -o -name '*.nbc' \
    -o -name 'sfs_warm_up.stamp' \) -print0) | tar -C "$repo" --null -T - -cf - |
    tar -C "$ws/src/sfs_ros" -xf -
started=$SECONDS
tested=0
colcon test --event-handlers console_direct- console_cohesion+ --base-paths "${base_paths[@]}" \
    --packages-select sfs_ros --return-code-on-test-failure \
    --pytest-args " -m" "not cell" "${quick[@]}" > "$ws/test.log" 2>&1 || tested=$?
summary=$(colcon test-result --test-result-base build/sfs_ros --all 2>&1 | tail -n 1) || true
# The cell's tests are deselected: neither run nor counted as skipped.
if ((tested == 0)) && grep -q " deselected" "$ws/test.log" &&
        [[ "$summary" =~ ^Summary:\ ([0-9]+)\ tests,\ 0\ errors,\ 0\ failures,\ 0\ skipped$ ]]
then
    kernels=$(grep -o "kernels compiled and cached in [0-9]* s" "$ws/test.log" ||
              echo "the kernels cached")
    echo "colcon test -m 'not cell' of ${quick[*]}: ${BASH_REMATCH[1]} tests passed," \
        "$(grep -o '[0-9]* deselected' "$ws/test.log" | tail -n 1) ($((SECONDS - started)) s;" \
        "$kernels)"
else
    cat "$ws/test.log" >&2
    fail "the quick colcon test did not pass with the cell's tests left out ($summary)"
fi

if ((failures)); then
    echo "colcon check: $failures failure(s)" >&2
    exit 1
fi
echo "colcon check passed: $(echo "$scripts" | wc -w) executables, share/sfs_ros/{launch,config,urdf}," \
    "${#definitions[@]} interfaces of sfs_ros_interfaces (${SECONDS} s in all)"
