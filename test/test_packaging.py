"""Every import of the package is declared for both ways of installing it.

* a ROS workspace: ``package.xml`` names a rosdep key for it: for a Python library one of
  ros/rosdistro's ``rosdep/python.yaml`` (:data:`ROSDISTRO_KEYS`, looked up there) that
  resolves on Debian and on Ubuntu noble, the base of Jazzy and Kilted (no private rosdep
  source); for a ROS package its name, a package of the ROS install or ours
  (``sfs_ros_interfaces``, built in the same workspace);
* ``pip install .``: ``setup.py``'s ``install_requires`` names its PyPI distribution
  with a lower bound, the version in ``requirements-min.txt`` the suite was run with;
  ROS packages come from ``requirements-ros.txt`` (PyPI wheels) or the ROS install, the
  interface packages without a wheel from ``scripts/build_interfaces.sh``.

The interface packages of the repository are complete: ament_cmake, members of
``rosidl_interface_packages``, every dependency a ROS package that
``requirements-ros-build.txt`` provides where no ROS install does, and their
``CMakeLists.txt`` generates exactly the files of ``msg/``, ``srv/`` and ``action/``.
"""

import ast
import functools
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Import name -> (rosdep key, PyPI distribution) of each third-party Python package.
THIRD_PARTY = {
    "cv2": ("python3-opencv", "opencv-python-headless"),
    "numba": ("python3-numba", "numba"),
    "numpy": ("python3-numpy", "numpy"),
    "PIL": ("python3-pil", "pillow"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "scipy": ("python3-scipy", "scipy"),
    "serial": ("python3-serial", "pyserial"),
    "skimage": ("python3-skimage", "scikit-image"),
    "trimesh": ("python3-trimesh-pip", "trimesh"),
    "yaml": ("python3-yaml", "pyyaml"),
}
#: The decompressors rosbags reads bags with (its own requirements: lz4, and zstd from the
#: standard library's ``compression`` from Python 3.14, ``backports.zstd`` before): the bag
#: reader caps what they expand, so it calls them itself; rosbags brings them.
WITH_ROSBAGS = {"lz4", "compression", "backports"}
#: ROS 2 packages imported by the package (rosdep key = package name).
ROS_PACKAGES = {"rclpy", "ament_index_python", "builtin_interfaces", "rcl_interfaces",
                "std_msgs", "std_srvs", "sensor_msgs", "geometry_msgs", "shape_msgs",
                "visualization_msgs", "diagnostic_msgs", "tf2_msgs", "action_msgs", "lifecycle_msgs",
                "sfs_ros_interfaces"}
#: Message packages the PyPI ``ros-kilted-rclpy`` wheel brings along.
WITH_RCLPY = {"builtin_interfaces", "rcl_interfaces"}
#: Message packages without a wheel, built into the environment by scripts/build_interfaces.sh.
BUILT_INTERFACES = {"tf2_msgs", "sfs_ros_interfaces"}
#: Their sources: ours, built beside sfs_ros in a ROS workspace; upstream's tf2_msgs, built
#: only where no ROS install provides it (a workspace never builds it: it is inside sfs_ros).
INTERFACE_FOLDERS = {"sfs_ros_interfaces": REPO / "sfs_ros_interfaces",
                     "tf2_msgs": REPO / "third_party" / "tf2_msgs"}
#: Keys of ros/rosdistro's rosdep/python.yaml used here, looked up there (its 2025 version),
#: with the releases their debian and ubuntu rules cover ("*": every release). Not there:
#: python3-rosbags-pip (rosbags has no rule in that version). A key package.xml uses that
#: does not resolve on :data:`PLATFORMS` must be skipped by the documented rosdep install.
ROSDISTRO_KEYS = {
    "python3-numpy": {"debian": "*", "ubuntu": "*"},
    "python3-opencv": {"debian": "*", "ubuntu": "*"},
    "python3-pil": {"debian": "*", "ubuntu": "*"},
    "python3-scipy": {"debian": "*", "ubuntu": "*"},
    "python3-serial": {"debian": "*", "ubuntu": "*"},
    "python3-skimage": {"debian": "*", "ubuntu": "*"},
    "python3-trimesh-pip": {"debian": "*", "ubuntu": "*"},  # pip: trimesh
    "python3-yaml": {"debian": "*", "ubuntu": "*"},
    "python3-pytest": {"debian": "*", "ubuntu": "*"},
    "python3-numba": {"debian": "*", "ubuntu": ("bionic", "focal")},
}
#: (OS, release) every rosdep key must resolve on: Debian, and Ubuntu 24.04 (Jazzy, Kilted).
PLATFORMS = (("debian", "bookworm"), ("ubuntu", "noble"))
#: ROS packages the launch files import (not imported by the Python package).
LAUNCH_PACKAGES = {"launch", "launch_ros"}


@functools.cache
def imported_top_levels() -> frozenset[str]:
    found = set()
    for path in (REPO / "sfs_ros").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                found.add(node.module.split(".")[0])
    return frozenset(found - set(sys.stdlib_module_names) - {"sfs_ros"})


def package_xml() -> dict[str, set[str]]:
    root = ET.parse(REPO / "package.xml").getroot()
    deps: dict[str, set[str]] = {}
    for element in root:
        if element.tag.endswith("depend"):
            deps.setdefault(element.tag, set()).add(element.text.strip())
    return deps


def setup_keywords() -> dict:
    tree = ast.parse((REPO / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and isinstance(n.func, ast.Name) and n.func.id == "setup")
    return {k.arg: k.value for k in call.keywords}


def requirement_bounds() -> dict[str, str]:
    """``{distribution: lower bound}`` of install_requires (each must have one)."""
    bounds = {}
    for requirement in ast.literal_eval(setup_keywords()["install_requires"]):
        match = re.fullmatch(r"([A-Za-z0-9_.-]+)>=([0-9][0-9.]*)(,<[0-9.]+)?", requirement)
        assert match, f"install_requires {requirement!r}: expected NAME>=LOWER[,<UPPER]"
        bounds[match[1].lower()] = match[2]
    return bounds


def test_every_import_is_known_here():
    unknown = imported_top_levels() - set(THIRD_PARTY) - ROS_PACKAGES - WITH_ROSBAGS
    assert not unknown, f"new third-party imports {sorted(unknown)}: declare them in " \
                        "package.xml and setup.py, then add them to THIRD_PARTY"


def test_the_decompressors_come_with_rosbags():
    from importlib.metadata import requires

    wanted = {re.split(r"[ ;<>=!~\[]", r, maxsplit=1)[0].lower() for r in requires("rosbags")}
    assert {"lz4", "backports.zstd"} <= wanted, wanted


def test_package_xml_declares_every_import_with_a_rosdep_key():
    exec_deps = package_xml()["exec_depend"]
    imported = imported_top_levels()
    for module, (key, _) in THIRD_PARTY.items():
        assert module in imported, f"{module} is no longer imported: drop it from THIRD_PARTY"
        assert key in exec_deps, f"package.xml: no exec_depend {key} (import {module})"
    for module in imported & ROS_PACKAGES:
        assert module in exec_deps, f"package.xml: no exec_depend {module}"
    assert LAUNCH_PACKAGES <= exec_deps
    # The interfaces the nodes use, whether or not a module imports them yet.
    assert {"sfs_ros_interfaces", "action_msgs", "tf2_msgs"} <= exec_deps


def unresolved_keys() -> dict[str, list[str]]:
    """``{key: [why, ...]}`` of package.xml's Python keys that rosdistro cannot install on
    one of :data:`PLATFORMS`."""
    keys = {k for deps in package_xml().values() for k in deps if k.startswith("python3-")}
    problems: dict[str, list[str]] = {}
    for key in sorted(keys):
        if key not in ROSDISTRO_KEYS:
            problems.setdefault(key, []).append("not a key of rosdistro's rosdep/python.yaml")
            continue
        for os_name, release in PLATFORMS:
            releases = ROSDISTRO_KEYS[key].get(os_name, ())
            if releases != "*" and release not in releases:
                problems.setdefault(key, []).append(
                    f"rosdistro's {os_name} rule covers {', '.join(releases) or 'no release'}, "
                    f"not {release}")
    return problems


def test_every_key_of_package_xml_is_a_rosdistro_key_or_a_ros_package():
    keys = {k for deps in package_xml().values() for k in deps}
    unknown = {k for k in keys if not k.startswith("python3-")} - ROS_PACKAGES - LAUNCH_PACKAGES
    assert not unknown, f"package.xml: {sorted(unknown)} are neither rosdistro keys nor " \
                        "ROS packages known here"


def test_the_workspace_docs_skip_exactly_the_keys_rosdistro_cannot_install():
    """rosdep stops at a key it cannot resolve: the documented ``rosdep install`` skips
    exactly those keys, and the docs install each with pip instead."""
    doc = (REPO / "doc" / "ros_workspace.md").read_text()
    skipped = re.search(r'--skip-keys "([^"]*)"', doc)
    assert skipped, "doc/ros_workspace.md: the rosdep install line has no --skip-keys"
    problems = unresolved_keys()
    assert set(skipped[1].split()) == set(problems), \
        "rosdep install cannot install:\n" + "\n".join(
            f"{key}: {'; '.join(why)}" for key, why in problems.items())
    pip_line = re.search(r"pip install ((?:[a-z0-9_-]+ ?)+)", doc)
    assert pip_line, "doc/ros_workspace.md: no pip install line for the skipped keys"
    wheels = {dist for key, dist in THIRD_PARTY.values() if key in problems}
    assert wheels <= set(pip_line[1].split())


def test_no_private_rosdep_source():
    assert not (REPO / "rosdep").exists()


def test_setup_py_requires_every_third_party_import_with_a_tested_lower_bound():
    bounds = requirement_bounds()
    assert set(bounds) == {dist for _, dist in THIRD_PARTY.values()}
    tested = {}
    for line in (REPO / "requirements-min.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, version = line.split("==")
            tested[name.lower()] = version
    # The lower bound of each requirement is the version the suite passed with.
    assert bounds == {name: tested[name] for name in bounds}


def test_ros_packages_come_from_requirements_ros_txt():
    wheels = {line.strip() for line in (REPO / "requirements-ros.txt").read_text().splitlines()
              if line.strip() and not line.startswith("#")}
    for module in (imported_top_levels() & ROS_PACKAGES) - WITH_RCLPY - BUILT_INTERFACES:
        assert "ros-kilted-" + module.replace("_", "-") in wheels, module
    assert "rosbags" in wheels or "rosbags" in requirement_bounds()


def test_interface_packages_are_built_by_build_interfaces_sh():
    script = (REPO / "scripts" / "build_interfaces.sh").read_text()
    assert set(INTERFACE_FOLDERS) == BUILT_INTERFACES
    for name, folder in INTERFACE_FOLDERS.items():
        root = ET.parse(folder / "package.xml").getroot()
        assert root.findtext("name") == name == folder.name
        assert f'build "$repo/{folder.relative_to(REPO)}"' in script, name


def cmake_calls(text: str, command: str) -> list[list[str]]:
    """The arguments of every ``command(...)`` call in CMake ``text`` (comments dropped)."""
    text = re.sub(r"#[^\n]*", "", text)
    calls = re.findall(rf"^\s*{command}\s*\(([^)]*)\)", text, flags=re.MULTILINE)
    return [[a or b for a, b in re.findall(r'"([^"]*)"|([^\s"]+)', call)] for call in calls]


@pytest.mark.parametrize("name", sorted(INTERFACE_FOLDERS))
def test_interface_package_is_complete(name):
    folder = INTERFACE_FOLDERS[name]
    root = ET.parse(folder / "package.xml").getroot()
    assert root.findtext("export/build_type") == "ament_cmake"
    assert [g.text for g in root.findall("member_of_group")] == ["rosidl_interface_packages"]
    deps = {tag: {e.text.strip() for e in root.findall(tag)}
            for tag in ("buildtool_depend", "build_depend", "depend", "exec_depend",
                        "build_export_depend", "test_depend")}
    assert "rosidl_default_generators" in deps["buildtool_depend"]
    assert "rosidl_default_runtime" in deps["exec_depend"] | deps["depend"]
    # Every dependency a ROS package, each a wheel of requirements-ros-build.txt.
    wheels = {line.strip() for line in (REPO / "requirements-ros-build.txt").read_text()
              .splitlines() if line.strip() and not line.startswith("#")}
    for dep in set().union(*deps.values()):
        assert "ros-kilted-" + dep.replace("_", "-") in wheels, \
            f"{name}/package.xml: {dep} is not a ROS package of requirements-ros-build.txt"

    cmake = (folder / "CMakeLists.txt").read_text()
    [generate] = cmake_calls(cmake, "rosidl_generate_interfaces")
    assert generate[0] == "${PROJECT_NAME}"
    assert cmake_calls(cmake, "project") == [[name]]
    keywords = {"DEPENDENCIES", "LIBRARY_NAME", "ADD_LINTER_TESTS", "SKIP_INSTALL",
                "SKIP_GROUP_MEMBERSHIP_CHECK"}
    split = next((i for i, a in enumerate(generate) if a in keywords), len(generate))
    listed = generate[1:split]
    assert all(not a.startswith("$") for a in listed), f"list the files themselves: {listed}"
    on_disk = sorted(str(p.relative_to(folder)) for kind in ("msg", "srv", "action")
                     for p in (folder / kind).glob(f"*.{kind}"))
    assert on_disk, f"{name} defines no interface"
    assert sorted(listed) == on_disk, "rosidl_generate_interfaces lists other files than " \
                                      f"msg/, srv/, action/ hold: {sorted(listed)} != {on_disk}"
    assert len(set(listed)) == len(listed), listed
    # What CMake looks for and generates against is declared as a build dependency.
    found = {call[0] for call in cmake_calls(cmake, "find_package")}
    assert found <= deps["buildtool_depend"] | deps["build_depend"] | deps["depend"], found
    generated_with = generate[generate.index("DEPENDENCIES") + 1:] \
        if "DEPENDENCIES" in generate else []
    generated_with = [a for a in generated_with if a not in keywords]
    assert set(generated_with) <= found & deps["depend"], generated_with


def test_sfs_ros_interfaces_has_the_version_of_sfs_ros():
    ours = ET.parse(REPO / "sfs_ros_interfaces" / "package.xml").getroot()
    assert ours.findtext("version") == ET.parse(REPO / "package.xml").getroot().findtext("version")
