"""Every import of the package is declared for both ways of installing it.

* a ROS workspace: ``package.xml`` names a rosdep key for it, one that exists in
  ros/rosdistro's ``rosdep/python.yaml`` (:data:`ROSDISTRO_KEYS`, looked up there) or in
  the package's own ``rosdep/sfs_ros.yaml`` for what rosdistro cannot install;
* ``pip install .``: ``setup.py``'s ``install_requires`` names its PyPI distribution
  with a lower bound, the version in ``requirements-min.txt`` the suite was run with;
  ROS packages come from ``requirements-ros.txt`` (PyPI wheels) or the ROS install.
"""

import ast
import functools
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]

#: Import name -> (rosdep key, PyPI distribution) of each third-party Python package.
THIRD_PARTY = {
    "cv2": ("python3-opencv", "opencv-python-headless"),
    "numba": ("python3-numba-pip", "numba"),
    "numpy": ("python3-numpy", "numpy"),
    "PIL": ("python3-pil", "pillow"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "scipy": ("python3-scipy", "scipy"),
    "serial": ("python3-serial", "pyserial"),
    "skimage": ("python3-skimage", "scikit-image"),
    "trimesh": ("python3-trimesh-pip", "trimesh"),
    "yaml": ("python3-yaml", "pyyaml"),
}
#: ROS 2 packages imported by the package (rosdep key = package name).
ROS_PACKAGES = {"rclpy", "ament_index_python", "builtin_interfaces", "rcl_interfaces",
                "std_msgs", "std_srvs", "sensor_msgs", "geometry_msgs", "shape_msgs",
                "visualization_msgs", "diagnostic_msgs"}
#: Message packages the PyPI ``ros-kilted-rclpy`` wheel brings along.
WITH_RCLPY = {"builtin_interfaces", "rcl_interfaces"}
#: Keys of ros/rosdistro rosdep/python.yaml used here, each defined for debian and ubuntu
#: (without a release list); python3-numba is not among them: its ubuntu entry lists
#: bionic and focal only, so it does not resolve on noble (Jazzy, Kilted).
ROSDISTRO_KEYS = {"python3-numpy", "python3-opencv", "python3-pil", "python3-scipy",
                  "python3-serial", "python3-skimage", "python3-trimesh-pip", "python3-yaml",
                  "python3-pytest"}
#: ROS packages the launch files start or import (not imported by the Python package).
LAUNCH_PACKAGES = {"launch", "launch_ros", "robot_state_publisher"}


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
    unknown = imported_top_levels() - set(THIRD_PARTY) - ROS_PACKAGES
    assert not unknown, f"new third-party imports {sorted(unknown)}: declare them in " \
                        "package.xml and setup.py, then add them to THIRD_PARTY"


def test_package_xml_declares_every_import_with_a_rosdep_key_that_exists():
    exec_deps = package_xml()["exec_depend"]
    ours = set(yaml.safe_load((REPO / "rosdep" / "sfs_ros.yaml").read_text()))
    imported = imported_top_levels()
    for module, (key, _) in THIRD_PARTY.items():
        assert module in imported, f"{module} is no longer imported: drop it from THIRD_PARTY"
        assert key in exec_deps, f"package.xml: no exec_depend {key} (import {module})"
    for module in imported & ROS_PACKAGES:
        assert module in exec_deps, f"package.xml: no exec_depend {module}"
    assert LAUNCH_PACKAGES <= exec_deps
    python_keys = {k for deps in package_xml().values() for k in deps
                   if k.startswith("python3-")}
    assert python_keys <= ROSDISTRO_KEYS | ours, sorted(python_keys - ROSDISTRO_KEYS - ours)
    # Ours never redefine a rosdistro key, and each installs from PyPI on Debian and Ubuntu.
    assert not ours & ROSDISTRO_KEYS
    for key, rule in yaml.safe_load((REPO / "rosdep" / "sfs_ros.yaml").read_text()).items():
        assert key in exec_deps, f"rosdep/sfs_ros.yaml defines {key}, package.xml does not use it"
        for os_name in ("debian", "ubuntu"):
            assert rule[os_name]["pip"]["packages"], (key, os_name)


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
    for module in (imported_top_levels() & ROS_PACKAGES) - WITH_RCLPY:
        assert "ros-kilted-" + module.replace("_", "-") in wheels, module
    assert "rosbags" in wheels or "rosbags" in requirement_bounds()
