"""The ``mesh`` marker a viewer takes: a large coloured mesh simplified within the triangle
budget (vertex clustering), its message under 5 MB and valid for RViz."""

import numpy as np
import pytest
import trimesh
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker

from sfs_ros.core.meshing.decimate import decimate
from sfs_ros.ros.convert import mesh_to_marker

#: The meshing node's default ``display_triangles``.
BUDGET = 10000
RADIUS_M = 0.05


@pytest.fixture(scope="module")
def sphere():
    """A sphere of 327 680 triangles (the mock mug at 192^3 has 265 000), coloured
    by position."""
    mesh = trimesh.creation.icosphere(subdivisions=7)
    colours = np.rint(127.5 * (mesh.vertices + 1.0)).astype(np.uint8)
    return mesh.vertices * RADIUS_M, np.asarray(mesh.faces), colours


def test_a_large_mesh_becomes_a_marker_rviz_takes_under_5_mb(sphere):
    vertices, faces, colours = sphere
    v, f, c = decimate(vertices, faces, BUDGET, colours)
    assert BUDGET / 2 <= len(f) <= BUDGET
    marker = mesh_to_marker(v, f, stamp=(5, 0), frame_id="turntable", vertex_colors=c)
    size = len(serialize_message(marker))
    assert size < 5_000_000, size
    assert marker.type == Marker.TRIANGLE_LIST and marker.action == Marker.ADD
    assert marker.header.frame_id == "turntable"
    assert len(marker.points) % 3 == 0 and len(marker.colors) == len(marker.points)
    q = marker.pose.orientation
    assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
    assert (marker.scale.x, marker.scale.y, marker.scale.z) == (1.0, 1.0, 1.0)
    points = np.array([(p.x, p.y, p.z) for p in marker.points])
    assert np.isfinite(points).all()


def test_the_simplified_copy_keeps_the_shape_and_the_colours(sphere):
    vertices, faces, colours = sphere
    v, f, c = decimate(vertices, faces, BUDGET, colours)
    # Every merged vertex is a mean of vertices within one cell (under 2 mm here) of the
    # sphere, and its colour the mean of theirs: the colour still follows the position.
    assert np.abs(np.linalg.norm(v, axis=1) - RADIUS_M).max() < 2e-4
    expected = np.rint(127.5 * (v / RADIUS_M + 1.0))
    assert np.abs(c.astype(float) - expected).max() <= 3
    assert f.min() >= 0 and f.max() < len(v)
    assert (f[:, 0] != f[:, 1]).all() and (f[:, 1] != f[:, 2]).all()


def test_a_mesh_within_the_budget_is_left_as_it_is_and_bad_input_is_named():
    mesh = trimesh.creation.box()
    v, f, c = decimate(mesh.vertices, mesh.faces, 100)
    assert np.array_equal(f, mesh.faces) and c is None
    with pytest.raises(ValueError, match="max_faces must be at least 1"):
        decimate(mesh.vertices, mesh.faces, 0)
    with pytest.raises(ValueError, match=r"colours must be \(8, 3\)"):
        decimate(mesh.vertices, mesh.faces, 4, np.zeros((3, 3), np.uint8))
