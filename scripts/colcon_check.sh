#!/usr/bin/env bash
# Build sfs_ros with colcon in a temporary workspace, as a ROS workspace would, and
# check what a ROS install needs: an executable lib/sfs_ros/<script> for every console
# script of setup.py, share/sfs_ros/{launch,config,urdf} with the repository's files,
# package.xml and the ament index entry; then run two commands from the install.
# Uses the environment of scripts/setup.sh ($SFS_VENV, default .venv) and installs
# colcon-common-extensions (PyPI) into it when missing. Exits non-zero on any failure;
# the workspace is removed in any case. Usage: scripts/colcon_check.sh
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

# colcon runs setup.py with the Python it runs under: the venv's, as in a sourced ROS install.
(cd "$ws" && PATH="$venv/bin:$PATH" colcon build --event-handlers console_direct- \
    --base-paths src > "$ws/build.log" 2>&1) || {
    cat "$ws/build.log" >&2
    echo "error: colcon build failed" >&2
    exit 1
}

prefix="$ws/install/sfs_ros"
failures=0
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
for pattern in "launch/*.launch.py" "config/*.yaml" "urdf/*.urdf"; do
    files=( $pattern )
    [[ -e "${files[0]}" ]] || fail "the repository has no $pattern"
    for file in "${files[@]}"; do
        cmp -s "$file" "$share/$file" || fail "share/sfs_ros/$file is missing or differs"
    done
done
cmp -s package.xml "$share/package.xml" || fail "share/sfs_ros/package.xml is missing"
[[ -f "$prefix/share/ament_index/resource_index/packages/sfs_ros" ]] ||
    fail "no ament index entry share/ament_index/resource_index/packages/sfs_ros"

# From the install, with the workspace sourced and outside the source tree: the
# commands start, the bag reader imports (rosbags), the share folder is found.
(
    set +u
    # shellcheck disable=SC1091
    source "$ws/install/setup.bash"
    set -u
    cd "$ws"
    PATH="$venv/bin:$PATH"
    "$prefix/lib/sfs_ros/sfs-reconstruct" --help > /dev/null
    python -c "import sfs_ros.cell.bag, sfs_ros, sys; \
assert sfs_ros.__file__.startswith('$ws/install/'), sfs_ros.__file__"
    found=$(python -c "from ament_index_python.packages import get_package_share_directory as g; \
print(g('sfs_ros'))")
    [[ "$found" == "$share" ]] || { echo "ament index gives $found, not $share" >&2; exit 1; }
) || fail "the installed package does not run (above)"

if ((failures)); then
    echo "colcon check: $failures failure(s)" >&2
    exit 1
fi
echo "colcon check passed: $(echo "$scripts" | wc -w) executables, share/sfs_ros/{launch,config,urdf}"
