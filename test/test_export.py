"""Mesh export: round trips through trimesh, axes, units, atomic writes, and an
independent reader (assimp, the import library behind many 3-D tools)."""

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

import sfs_ros.core.exchange.files as files_module
from sfs_ros.core.exchange.export import SUPPORTED_SUFFIXES, export_mesh, load_mesh
from sfs_ros.core.meshing.mesh_checks import check_mesh

#: Coordinates are stored as float32 in PLY, STL and GLB (and with 8 decimals
#: in OBJ): relative rounding 6e-8 on coordinates below 0.1 m is < 1e-8 m.
ATOL_M = 1e-8
#: assimp prints coordinates with 6 decimals.
ASSIMP_ATOL = 1e-6
COLOURED = [".ply", ".obj", ".glb"]


@pytest.fixture(scope="module")
def torus():
    """Closed outward torus, shifted so that every axis has a distinct range."""
    mesh = trimesh.creation.torus(major_radius=0.05, minor_radius=0.015)
    vertices = np.asarray(mesh.vertices) + [0.01, 0.02, 0.03]
    faces = np.asarray(mesh.faces, dtype=np.int64)
    colors = np.round(255 * (vertices - vertices.min(0)) / np.ptp(vertices, 0)).astype(np.uint8)
    return vertices, faces, colors


def z_up_to_y_up(v):
    return np.column_stack((v[:, 0], v[:, 2], -v[:, 1]))


def raw_load(path):
    """The file's own vertices, faces and mesh (no axis or unit undoing)."""
    mesh = trimesh.load(path, force="mesh", process=False)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), mesh


@pytest.mark.parametrize("suffix", SUPPORTED_SUFFIXES)
@pytest.mark.parametrize("coloured", [False, True])
def test_round_trip(tmp_path, torus, suffix, coloured):
    vertices, faces, colors = torus
    if coloured and suffix == ".stl":
        with pytest.raises(ValueError, match="STL cannot store vertex colours"):
            export_mesh(vertices, faces, tmp_path / "m.stl", vertex_colors=colors)
        return
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}",
                       vertex_colors=colors if coloured else None)
    assert path == tmp_path / f"m{suffix}" and path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left

    v2, f2 = load_mesh(path)
    assert f2.shape == faces.shape
    # Same triangles, corner by corner (STL's soup is re-merged by load_mesh).
    np.testing.assert_allclose(v2[f2], vertices[faces], atol=ATOL_M)
    if suffix != ".stl":
        np.testing.assert_array_equal(f2, faces)
    # Axis conversion is a rotation: the closed mesh is still outward.
    report = check_mesh(v2, f2)
    assert report.watertight and report.outward is True and report.genus == 1

    _, _, mesh = raw_load(path)
    if coloured:
        np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3], colors)


@pytest.mark.parametrize("suffix", SUPPORTED_SUFFIXES)
def test_axes_in_the_file(tmp_path, torus, suffix):
    # glTF (by specification) and OBJ (by convention) are Y up: (x, y, z) is
    # stored as (x, z, -y). PLY and STL stay Z up.
    vertices, faces, _ = torus
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}")
    raw_v, raw_f, _ = raw_load(path)
    expected = z_up_to_y_up(vertices) if suffix in (".glb", ".obj") else vertices
    np.testing.assert_allclose(raw_v[raw_f], expected[faces], atol=ATOL_M)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_millimetres(tmp_path, torus, suffix):
    vertices, faces, _ = torus
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}", units="mm")
    raw_v, raw_f, _ = raw_load(path)
    expected = 1000.0 * (z_up_to_y_up(vertices) if suffix == ".obj" else vertices)
    np.testing.assert_allclose(raw_v[raw_f], expected[faces], atol=1000.0 * ATOL_M)
    v2, f2 = load_mesh(path, units="mm")
    np.testing.assert_allclose(v2[f2], vertices[faces], atol=ATOL_M)


def test_float_colours_and_alpha(tmp_path, torus):
    vertices, faces, colors = torus
    rgba = np.column_stack((colors, np.full(len(colors), 128, dtype=np.uint8)))
    path = export_mesh(vertices, faces, tmp_path / "m.ply", vertex_colors=rgba / 255.0)
    _, _, mesh = raw_load(path)
    np.testing.assert_array_equal(mesh.visual.vertex_colors, rgba)


def test_invalid_arguments(tmp_path, torus):
    vertices, faces, colors = torus
    with pytest.raises(ValueError, match=r"supported: \.ply, \.obj, \.stl, \.glb"):
        export_mesh(vertices, faces, tmp_path / "m.fbx")
    with pytest.raises(ValueError, match="glTF"):
        export_mesh(vertices, faces, tmp_path / "m.glb", units="mm")
    with pytest.raises(ValueError, match="units"):
        export_mesh(vertices, faces, tmp_path / "m.ply", units="inch")
    with pytest.raises(ValueError, match="vertex_colors"):
        export_mesh(vertices, faces, tmp_path / "m.ply", vertex_colors=colors[:10])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        export_mesh(vertices, faces, tmp_path / "m.ply", vertex_colors=colors * 2.0)
    with pytest.raises(ValueError, match="face indices"):
        export_mesh(vertices, faces + len(vertices), tmp_path / "m.ply")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, torus, monkeypatch):
    vertices, faces, _ = torus
    path = export_mesh(vertices, faces, tmp_path / "m.ply")
    before = path.read_bytes()

    def crash(*args):
        raise OSError("disk full")

    monkeypatch.setattr(files_module.os, "fsync", crash)
    with pytest.raises(OSError, match="disk full"):
        export_mesh(vertices * 2.0, faces, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


def assimp_info(path):
    """(faces, min point, max point) as reported by ``assimp info``."""
    exe = shutil.which("assimp")
    if exe is None:
        pytest.fail("the 'assimp' command is missing: install Debian's assimp-utils "
                    "(apt-get install assimp-utils) to run the independent-reader test")
    run = subprocess.run([exe, "info", os.fspath(path)], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, f"assimp could not read {path.name}: {run.stdout[-2000:]}"
    n_faces = int(re.search(r"^Faces:\s+(\d+)", run.stdout, re.M).group(1))
    point = r"\(([-\d.e+]+) ([-\d.e+]+) ([-\d.e+]+)\)"
    lo = re.search(r"^Minimum point\s+" + point, run.stdout, re.M).groups()
    hi = re.search(r"^Maximum point\s+" + point, run.stdout, re.M).groups()
    return n_faces, np.array(lo, dtype=float), np.array(hi, dtype=float)


@pytest.mark.parametrize("suffix", SUPPORTED_SUFFIXES)
def test_assimp_reads_every_format(tmp_path, torus, suffix):
    vertices, faces, colors = torus
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}",
                       vertex_colors=None if suffix == ".stl" else colors)
    n_faces, lo, hi = assimp_info(path)
    assert n_faces == len(faces)
    # assimp reports the file's own axes: Y up for glTF and OBJ.
    expected = z_up_to_y_up(vertices) if suffix in (".glb", ".obj") else vertices
    np.testing.assert_allclose(lo, expected.min(axis=0), atol=ASSIMP_ATOL)
    np.testing.assert_allclose(hi, expected.max(axis=0), atol=ASSIMP_ATOL)
