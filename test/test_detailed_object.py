"""The detailed test object (the chair): its volume, surface and silhouette holes."""

import math

import cv2
import numpy as np

from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import make_object

#: Monte Carlo standard deviations allowed: never exceeded in practice (p ~ 1e-9).
MC_SIGMAS = 6.0


def test_volume_inside_test_and_mesh_agree():
    """The volume (the parts' sum: they meet along faces only) against Monte Carlo with the
    inside test and against the rendering mesh (closed parts: their volumes add up)."""
    chair = make_object("chair")
    lo, hi = chair.bounds
    assert np.all(lo >= [-0.06, -0.06, 0.0]) and np.all(hi <= [0.06, 0.06, 0.12])
    n = 400_000
    p = chair.contains(np.random.default_rng(1).uniform(lo, hi, (n, 3))).mean()
    box = float(np.prod(hi - lo))
    assert abs(p * box - chair.volume_m3) <= MC_SIGMAS * box * math.sqrt(p * (1 - p) / n)
    area = sum(part.area_m2 for part in chair.parts)
    assert abs(chair.mesh.volume - chair.volume_m3) <= area * chair.mesh_error_m + 1e-12


def test_surface_samples_lie_on_the_outer_surface():
    # No sample on a face where two parts meet (the seat under a leg): there the union's
    # inside is on both sides, so the object's distance there is not zero from outside.
    chair = make_object("chair")
    points = chair.sample_surface(20000, seed=2)
    assert np.abs(chair.signed_distance(points)).max() < 1e-12
    step = 1e-6    # a point a micrometre above a sample on the seat is outside the chair
    on_seat_top = np.isclose(points[:, 2], 0.039, atol=1e-12)
    assert on_seat_top.any()
    assert not chair.contains(points[on_seat_top] + [0.0, 0.0, step]).any()
    under_seat = np.isclose(points[:, 2], 0.035, atol=1e-12)
    assert not chair.contains(points[under_seat] - [0.0, 0.0, step]).any()


def test_silhouettes_have_holes():
    """From the front (the turntable at 180 degrees), the background shows through the
    back's hole and the ring's hole: three pieces, where a solid's silhouette leaves one."""
    chair = make_object("chair")
    rig = RigCalibration(width=320, height=320, projection="pinhole", fx=800.0, fy=800.0,
                         camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.055))
    front = rig_camera(math.pi, math.radians(10.0), rig)
    mask = rasterize_silhouette(chair.mesh.vertices, chair.mesh.faces, front)
    pieces, _ = cv2.connectedComponents((~mask).astype(np.uint8), connectivity=4)
    assert pieces - 1 == 3
