"""Refinement below the visual hull from the colours (:mod:`sfs_ros.core.refinement`), on
small textured renders: 48 views of 320 x 240 on rings at 20, 45 and 70 degrees, scored
against the true shapes (volume IoU on a 1 mm grid, completeness in metres)."""

from functools import lru_cache

import numpy as np
import pytest

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.carving.hull import drop_specks
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.mesh_scan import mesh_scan
from sfs_ros.core.meshing.hull_distance import HullDistance
from sfs_ros.core.meshing.marching import hull_marching_cubes_mesh
from sfs_ros.core.metrics import mesh_occupancy, occupancy_from_contains, volume_iou
from sfs_ros.core.pipeline import ReconstructionParams, carve_scan
from sfs_ros.core.refinement import refine_carved_scan, refine_hull
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan, surface_errors

RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=900.0, fy=900.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
PLAN = ring_plan([20.0, 45.0, 70.0], 16)


@lru_cache(maxsize=2)
def captures_of(name: str, textured: bool = True) -> tuple:
    return tuple(simulate_scan(make_object(name), RIG, PLAN, textured=textured, seed=1,
                               noise_sigma=1.0))


def white_backdrop_masks(captures) -> list[np.ndarray]:
    return [np.any(c.image < 250, axis=2) for c in captures]


def hull_and_refined(name: str, textured: bool = True):
    """(object, hull mesh, refined mesh, refinement report) on a 1.5 mm grid."""
    obj = make_object(name)
    captures = captures_of(name, textured)
    cameras = [rig_camera(c.theta_rad, c.phi_rad, RIG) for c in captures]
    masks = white_backdrop_masks(captures)
    box = carving_box(obj)
    grid = VoxelGrid(box[0], box[1], 0.0015)
    occupancy, _ = drop_specks(carve(grid, cameras, masks))
    hull = HullDistance(cameras, masks, bounds_m=box)
    refined = refine_hull(occupancy, grid, cameras, masks, [c.image for c in captures], hull)
    return (obj, hull_marching_cubes_mesh(occupancy, grid, hull),
            hull_marching_cubes_mesh(refined.occupancy, grid, refined.distance), refined.report)


def iou(obj, mesh) -> float:
    box = carving_box(obj)
    grid = VoxelGrid(box[0], box[1], 0.001)
    return volume_iou(mesh_occupancy(*mesh, grid), occupancy_from_contains(obj.contains, grid))


#: (object, the hull's IoU is below, the refined IoU is above). Measured on these renders:
#: hull 0.32 / 0.23 / 0.71, refined 0.85 / 0.91 / 0.95. The bars sit below 0.90 for the
#: cup: its 5 mm wall is 3 voxels of this 1.5 mm grid and the texture's 2.5 mm cells are
#: 3.7 px here (at full size, 640 x 480 and the default grid from the pixel footprint, the
#: cup reaches 0.92: bench/bench_refine.py, doc/accuracy.md).
CONCAVE = [("cup", 0.40, 0.80), ("bowl", 0.30, 0.88), ("pocket_block", 0.75, 0.93)]


@pytest.mark.parametrize("name, hull_below, refined_above", CONCAVE,
                         ids=[c[0] for c in CONCAVE])
def test_concavities_are_found(name, hull_below, refined_above):
    """The hull fills the concavity; the refinement empties it, and the true surface comes
    at least twice as near the mesh on average (completeness)."""
    obj, hull, refined, report = hull_and_refined(name)
    assert iou(obj, hull) < hull_below
    assert iou(obj, refined) > refined_above
    assert report["removed_fraction_of_hull"] > 0.2
    before, after = surface_errors(obj, *hull, n_samples=4000), \
        surface_errors(obj, *refined, n_samples=4000)
    assert after["completeness_mean_m"] < 0.5 * before["completeness_mean_m"]


@pytest.mark.parametrize("name, textured", [("sphere", False), ("barrel", True),
                                            ("mug", True)])
def test_hull_exact_objects_keep_their_hull(name, textured):
    """Objects whose hull is the object lose no more than 0.005 of volume IoU: the
    untextured sphere's smooth pattern is too flat or too alike along the rays to decide
    (the hull stays), the textured barrel and mug are seen where they are."""
    obj, hull, refined, _ = hull_and_refined(name, textured=textured)
    assert iou(obj, refined) > iou(obj, hull) - 0.005


def test_a_carved_scan_is_refined_as_the_pipeline_would(tmp_path):
    """``refine_carved_scan`` on the carving half's result (as a meshing process receives
    it) hollows the cup, and the meshing half meshes it watertight with the stage timed."""
    captures = captures_of("cup")
    session = write_session(tmp_path / "cup", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], RIG)
    views = load_views(session)
    masks = dict(zip([c.name for c in captures], white_backdrop_masks(captures)))
    carved = carve_scan(views, ReconstructionParams(voxel_size_m=0.0015), masks=masks)
    with pytest.raises(ValueError, match="no image for the used views"):
        refine_carved_scan(carved, {})
    images = {c.name: c.image for c in captures}
    refined = refine_carved_scan(carved, images)
    assert refined.report["refinement"]["applied"]
    assert refined.report["timings_s"]["refinement"] > 0
    obj = make_object("cup")
    hull_mesh, refined_mesh = mesh_scan(carved), mesh_scan(refined)
    assert refined_mesh.report["mesh"]["watertight"]
    assert iou(obj, (hull_mesh.vertices, hull_mesh.faces)) < 0.40
    assert iou(obj, (refined_mesh.vertices, refined_mesh.faces)) > 0.80


def test_views_too_far_apart_to_compare_keep_the_hull():
    """Three views 120 degrees apart have no neighbour to compare with: no depth, the hull
    is kept whole."""
    captures = captures_of("cup")[0:12:4]
    obj = make_object("cup")
    cameras = [rig_camera(c.theta_rad, c.phi_rad, RIG) for c in captures]
    masks = white_backdrop_masks(captures)
    box = carving_box(obj)
    grid = VoxelGrid(box[0], box[1], 0.003)
    occupancy, _ = drop_specks(carve(grid, cameras, masks))
    refined = refine_hull(occupancy, grid, cameras, masks, [c.image for c in captures],
                          HullDistance(cameras, masks, bounds_m=box))
    assert refined.report["views_with_depths"] == 0
    assert np.array_equal(refined.occupancy, occupancy)
