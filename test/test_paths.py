"""Output names from requests stay inside the output folder."""

import os

import pytest

from sfs_ros.cell_logic.paths import MAX_COMPONENT_BYTES, MAX_NAME_BYTES, confined_path

MESH = (".ply", ".obj", ".stl", ".glb")


@pytest.fixture()
def root(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    return folder


@pytest.mark.parametrize("name, expected", [
    ("scan.ply", "scan.ply"),
    ("Scan.PLY", "Scan.PLY"),
    ("sub/dir/scan.glb", "sub/dir/scan.glb"),
    ("./scan.obj", "scan.obj"),
    ("a//b.stl", "a/b.stl"),
    ("mesh with spaces.ply", "mesh with spaces.ply"),
])
def test_plain_names_resolve_inside_the_folder(root, name, expected):
    path = confined_path(root, name, suffixes=MESH)
    assert path == root.resolve() / expected
    assert path.is_absolute()


@pytest.mark.parametrize("name, problem", [
    ("../x.ply", r"contains '\.\.'"),
    ("a/../../b.ply", r"contains '\.\.'"),
    ("a/../b.ply", r"contains '\.\.'"),  # even when it would stay inside: never needed
    ("/etc/passwd", "absolute path"),
    ("/tmp/x.ply", "absolute path"),
    ("", "empty"),
    ("   ", "empty"),
    ("x\x00.ply", "NUL byte"),
    ("x\n.ply", "control characters"),
    ("..\\x.ply", r"contains '\\'"),
    (".hidden.ply", "hidden component"),
    ("a/.git/x.ply", "hidden component"),
    ("scan.txt", "must end in one of"),
    ("scan", "must end in one of"),
    ("scan.ply.sh", "must end in one of"),
    ("x" * (MAX_COMPONENT_BYTES + 1) + ".ply", "component of"),
    ("a/" * 600 + "x.ply", "too long"),  # 1205 bytes
])
def test_hostile_names_are_refused_with_the_reason(root, name, problem):
    with pytest.raises(ValueError, match=problem):
        confined_path(root, name, suffixes=MESH)


def test_length_limits_are_exact(root):
    longest = "x" * (MAX_COMPONENT_BYTES - 4) + ".ply"
    assert confined_path(root, longest, suffixes=MESH).name == longest
    # Multi-byte characters count in bytes: 128 two-byte letters exceed 255 bytes.
    with pytest.raises(ValueError, match="component of 260 bytes"):
        confined_path(root, "é" * 128 + ".ply", suffixes=MESH)
    deep = "a/" * ((MAX_NAME_BYTES - 5) // 2) + "x.ply"  # at most MAX_NAME_BYTES bytes
    assert confined_path(root, deep, suffixes=MESH).name == "x.ply"


def test_symlink_pointing_outside_is_refused(root, tmp_path):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    os.symlink(outside, root / "link")
    with pytest.raises(ValueError, match="leads outside the output folder"):
        confined_path(root, "link/x.ply", suffixes=MESH)
    # A file symlink: writing would follow it out of the folder.
    os.symlink(outside / "victim.ply", root / "trap.ply")
    with pytest.raises(ValueError, match="leads outside"):
        confined_path(root, "trap.ply", suffixes=MESH)


def test_symlink_staying_inside_is_followed(root):
    (root / "real").mkdir()
    os.symlink(root / "real", root / "alias")
    assert confined_path(root, "alias/x.ply", suffixes=MESH) == root.resolve() / "real" / "x.ply"


def test_root_reached_through_a_symlink_still_confines(root, tmp_path):
    os.symlink(root, tmp_path / "root_alias")
    assert confined_path(tmp_path / "root_alias", "x.ply", suffixes=MESH) == \
        root.resolve() / "x.ply"


def test_folder_named_like_a_mesh_is_refused(root):
    (root / "dir.ply").mkdir()
    with pytest.raises(ValueError, match="names a folder"):
        confined_path(root, "dir.ply", suffixes=MESH)


def test_bad_root_and_bad_arguments(root, tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        confined_path(tmp_path / "missing", "x.ply", suffixes=MESH)
    with pytest.raises(ValueError, match="must be a string"):
        confined_path(root, b"x.ply", suffixes=MESH)
    with pytest.raises(ValueError, match="suffixes must be"):
        confined_path(root, "x.ply", suffixes=())
    with pytest.raises(ValueError, match="suffixes must be"):
        confined_path(root, "x.ply", suffixes="ply")
