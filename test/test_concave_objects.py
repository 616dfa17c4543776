"""The concave test objects and their textured renders (cup, bowl, pocketed block, barrel)."""

import math

import numpy as np
import pytest

from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.meshing.marching import marching_cubes_mesh
from sfs_ros.core.metrics import occupancy_from_contains
from sfs_ros.core.render import rasterize_depth, render_image, solid_colors
from sfs_ros.core.simulation.concave import solid_texture
from sfs_ros.core.simulation.objects import CONCAVE_OBJECT_NAMES, make_object
from sfs_ros.core.simulation.synthetic import distance_to_mesh, surface_errors

#: Monte Carlo standard deviations allowed: never exceeded in practice (p ~ 1e-9).
MC_SIGMAS = 6.0


@pytest.fixture(scope="module")
def objects():
    return {name: make_object(name) for name in CONCAVE_OBJECT_NAMES}


@pytest.mark.parametrize("name", CONCAVE_OBJECT_NAMES)
def test_volume_inside_test_and_mesh_agree(objects, name):
    """The exact volume against Monte Carlo with the inside test, and against the mesh
    (inscribed: smaller by at most area * mesh_error_m)."""
    obj = objects[name]
    lo, hi = obj.bounds
    n = 400_000
    p = obj.contains(np.random.default_rng(1).uniform(lo, hi, (n, 3))).mean()
    box = float(np.prod(hi - lo))
    assert abs(p * box - obj.volume_m3) <= MC_SIGMAS * box * math.sqrt(p * (1 - p) / n)
    mesh = obj.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert abs(mesh.volume - obj.volume_m3) <= obj.parts[0].area_m2 * obj.mesh_error_m + 1e-12


@pytest.mark.parametrize("name", CONCAVE_OBJECT_NAMES)
def test_surface_samples_lie_on_the_surface(objects, name):
    obj = objects[name]
    points = obj.sample_surface(5000, seed=2)
    assert np.abs(obj.signed_distance(points)).max() < 1e-12


def test_errors_of_a_fine_mesh_of_the_truth(objects):
    """Marching cubes of the true cup's occupancy on a 1 mm grid lies within about half a
    voxel of the truth both ways (the staircase, smoothed), and the exact distance to a
    mesh is that of its nearest face."""
    cup = objects["cup"]
    grid = VoxelGrid.cube(cup.bounds[0] - 0.003, cup.bounds[1] + 0.003, 100)
    vertices, faces = marching_cubes_mesh(occupancy_from_contains(cup.contains, grid), grid)
    errors = surface_errors(cup, vertices, faces, n_samples=5000)
    assert errors["accuracy_p90_m"] < 0.6 * grid.voxel_size
    assert errors["completeness_p90_m"] < 0.6 * grid.voxel_size
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])
    points = np.array([[0.2, 0.2, 0.5], [2.0, 0.0, 0.0], [-1.0, -1.0, 0.0]])
    assert np.allclose(distance_to_mesh(points, *square), [0.5, 1.0, math.sqrt(2)])


def test_texture_is_a_colour_per_lattice_cell():
    points = np.array([[0.0001, 0.0001, 0.0001], [0.0024, 0.0024, 0.0024], [0.0026, 0.0, 0.0]])
    rgb = solid_texture(points)
    assert np.array_equal(rgb[0], rgb[1]) and not np.array_equal(rgb[0], rgb[2])
    many = solid_texture(np.random.default_rng(0).uniform(-0.05, 0.05, (20000, 3)))
    assert many.min() >= 40 and many.max() <= 220 and many.std(axis=0).min() > 40


def test_the_renderer_sees_into_the_cup(objects):
    """From straight above, the centre pixel sees the cup's floor (z = 12 mm), not the
    hull's top (z = 90 mm): the z-buffer keeps the nearest of the surfaces along the ray."""
    # The centre pixel looks down the middle of a texture cell (2.5 mm; 0.6 mm per pixel).
    rig = RigCalibration(width=64, height=64, projection="pinhole", fx=1000.0, fy=1000.0,
                         camera_distance_m=0.6, aim_point_m=(0.00125, 0.00125, 0.04))
    camera = rig_camera(0.0, math.pi / 2, rig)
    cup = objects["cup"]
    depth = rasterize_depth(cup.mesh.vertices, cup.mesh.faces, camera)
    assert depth[32, 32] == pytest.approx(0.6 + 0.04 - 0.012, abs=1e-6)
    image = render_image(cup.mesh.vertices, cup.mesh.faces, camera, noise_sigma=0.0,
                         pixel_colors=solid_colors(cup.mesh.vertices, cup.mesh.faces,
                                                   cup.texture_at),
                         light_dir=(0.0, 0.0, 1.0), ambient=1.0)
    floor_point = np.array([[0.00125, 0.00125, 0.012]])
    assert np.abs(image[32, 32].astype(int) - cup.texture_at(floor_point)[0]).max() <= 1
