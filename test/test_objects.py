"""Synthetic objects: geometry against closed forms, Monte Carlo and their own parts."""

import math

import numpy as np
import pytest
import trimesh

from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import OBJECT_NAMES, make_object

from tolerances import ROUND_OFF

#: Pixels per metre of a 512 px image spanning the 0.12 m object box.
PX_PER_M_512 = 512 / 0.12
#: Monte Carlo tolerance in binomial standard errors. The seeds are fixed, so the
#: tests are deterministic; a correct volume fails 5 sigma for ~1e-6 of seeds.
MC_SIGMAS = 5.0


@pytest.fixture(scope="module")
def objects():
    return {name: make_object(name) for name in OBJECT_NAMES}


def test_names_and_unknown_name():
    assert OBJECT_NAMES == ("sphere", "torus", "mug")
    with pytest.raises(ValueError, match="unknown object 'teapot'"):
        make_object("teapot")


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_rests_on_plate_inside_box(objects, name):
    obj = objects[name]
    lo, hi = obj.bounds
    assert lo[2] == pytest.approx(0.0, abs=ROUND_OFF)
    assert np.all(np.abs(lo[:2]) <= 0.06) and np.all(hi[:2] <= 0.06) and hi[2] <= 0.12
    # Mesh vertices and surface samples are on the true surface, so inside the bounds ...
    for pts in (obj.mesh.vertices, obj.sample_surface(20000, seed=0)):
        assert np.all(pts >= lo - ROUND_OFF) and np.all(pts <= hi + ROUND_OFF)
    # ... and the bounds are tight: samples come within 2 mm of every face of the box
    # (at least ~100 of the 20000 samples fall in each 2 mm slab, see the shapes).
    samples = obj.sample_surface(20000, seed=0)
    assert np.all(samples.min(axis=0) < lo + 0.002) and np.all(samples.max(axis=0) > hi - 0.002)


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_volume_matches_monte_carlo(objects, name):
    obj = objects[name]
    n = 400_000
    lo, hi = obj.bounds
    p = obj.contains(np.random.default_rng(1).uniform(lo, hi, (n, 3))).mean()
    box = float(np.prod(hi - lo))
    sigma = box * math.sqrt(p * (1 - p) / n)
    assert abs(p * box - obj.volume_m3) <= MC_SIGMAS * sigma


def test_closed_form_volumes(objects):
    assert objects["sphere"].volume_m3 == pytest.approx(4 / 3 * math.pi * 0.05 ** 3,
                                                        rel=ROUND_OFF)
    assert objects["torus"].volume_m3 == pytest.approx(2 * math.pi ** 2 * 0.04 * 0.015 ** 2,
                                                       rel=ROUND_OFF)


def test_mug_handle_volume(objects):
    """The quadrature of the handle outside the body, against Monte Carlo in the ring's box
    (about 30x more precise than sampling the whole mug)."""
    mug = objects["mug"]
    body, ring = mug.parts
    extra = mug.volume_m3 - body.volume_m3
    assert 0 < extra < ring.volume_m3 / 2  # the inner half of the ring is inside the body
    n = 1_000_000
    lo, hi = ring.bounds
    pts = np.random.default_rng(2).uniform(lo, hi, (n, 3))
    p = (mug.contains(pts) & (body.signed_distance(pts) > 0)).mean()
    box = float(np.prod(hi - lo))
    assert abs(p * box - extra) <= MC_SIGMAS * box * math.sqrt(p * (1 - p) / n)


def test_mug_ring_inner_half_inside_body(objects):
    body, ring = objects["mug"].parts
    pts = ring.sample_surface(20000, np.random.default_rng(3))
    inner = pts[pts[:, 0] <= ring.center[0]]
    assert len(inner) > 5000 and np.all(body.signed_distance(inner) < 0)


def test_sphere_mesh_volume_one_sided(objects):
    """An inscribed convex mesh lies between the balls of radius r - deficit and r."""
    sphere = objects["sphere"]
    mesh = sphere.mesh
    centre, r = np.array([0, 0, 0.05]), 0.05
    plane_distance = np.abs(np.einsum("ij,ij->i", mesh.face_normals,
                                      mesh.vertices[mesh.faces[:, 0]] - centre))
    r_in = plane_distance.min()
    assert 4 / 3 * math.pi * r_in ** 3 < mesh.volume < sphere.volume_m3
    assert r - r_in <= sphere.mesh_error_m


def test_torus_mesh_volume(objects):
    """Mesh and true surface are within mesh_error_m, so the volumes differ by at most
    area * mesh_error_m."""
    torus = objects["torus"]
    part = torus.parts[0]
    assert abs(torus.mesh.volume - torus.volume_m3) <= part.area_m2 * torus.mesh_error_m


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_meshes_closed_outward_and_accurate(objects, name):
    obj = objects[name]
    assert obj.mesh_error_m * PX_PER_M_512 < 0.25  # well under a pixel at 512 px
    for part in obj.parts:
        mesh = part.mesh()
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
        pts = trimesh.sample.sample_surface(mesh, 50000, seed=4)[0]
        assert np.max(np.abs(part.signed_distance(pts))) <= obj.mesh_error_m


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_surface_samples_on_outer_surface(objects, name):
    obj = objects[name]
    samples = obj.sample_surface(20000, seed=5)
    assert samples.shape == (20000, 3)
    distances = np.array([part.signed_distance(samples) for part in obj.parts])
    # on some part's surface, and inside no part: on the union's boundary
    assert np.all(np.min(np.abs(distances), axis=0) < ROUND_OFF)
    assert np.all(distances > -ROUND_OFF)
    np.testing.assert_array_equal(samples, obj.sample_surface(20000, seed=5))
    assert obj.sample_surface(0, seed=5).shape == (0, 3)


def test_surface_samples_uniform(objects):
    n = 40000
    # sphere: mean at the centre, each coordinate has standard deviation r / sqrt(3)
    s = objects["sphere"].sample_surface(n, seed=6)
    assert np.all(np.abs(s.mean(axis=0) - [0, 0, 0.05]) <= MC_SIGMAS * 0.05 / math.sqrt(3 * n))
    # torus: the outer half (distance from axis > R) holds 1/2 + r / (pi R) of the area
    t = objects["torus"].sample_surface(n, seed=6)
    frac = 0.5 + 0.015 / (math.pi * 0.04)
    got = np.mean(np.hypot(t[:, 0], t[:, 1]) > 0.04)
    assert abs(got - frac) <= MC_SIGMAS * math.sqrt(frac * (1 - frac) / n)


def _pixel(camera, point):
    u, v = camera.project(np.array([point]))[0]
    return int(round(v)), int(round(u))


def test_holes_show_in_silhouettes(objects):
    calib = RigCalibration(width=256, height=256, fx=2000.0, fy=2000.0, aim_point_m=(0, 0, 0.045))
    side = rig_camera(0.0, 0.0, calib)        # looking along +Y, image right = +X
    top = rig_camera(0.0, math.pi / 2, calib)  # looking down
    mug = objects["mug"].mesh
    mask = rasterize_silhouette(mug.vertices, mug.faces, side)
    # handle hole at x = 37 mm (ring centre 27 mm, hole radius 15 mm, body radius 32 mm),
    # with the body on its left and the handle's outer arc on its right
    assert not mask[_pixel(side, (0.037, 0, 0.045))]
    assert mask[_pixel(side, (0.020, 0, 0.045))] and mask[_pixel(side, (0.049, 0, 0.045))]
    torus = objects["torus"].mesh
    from_top = rasterize_silhouette(torus.vertices, torus.faces, top)
    assert not from_top[_pixel(top, (0, 0, 0.015))] and from_top[_pixel(top, (0.04, 0, 0.015))]
    from_side = rasterize_silhouette(torus.vertices, torus.faces, side)
    assert from_side[_pixel(side, (0, 0, 0.015))]


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_color_pattern_smooth_and_varied(objects, name):
    obj = objects[name]
    pts = obj.sample_surface(5000, seed=7)
    rgb = obj.color_at(pts)
    assert rgb.dtype == np.uint8 and rgb.shape == (5000, 3)
    assert rgb.min() >= 30 and rgb.max() <= 200
    assert np.all(rgb.astype(float).std(axis=0) > 10)
    # Lipschitz: stripes change by at most 170 * 2 pi / 0.06 m per metre, the height
    # gradient by 170 / height; +1 for rounding to integers.
    step = np.random.default_rng(8).normal(size=pts.shape)
    step *= 0.001 / np.linalg.norm(step, axis=1, keepdims=True)  # 1 mm in random directions
    moved = obj.color_at(pts + step).astype(float)
    height = obj.bounds[1, 2] - obj.bounds[0, 2]
    bound = 0.001 * 170 * max(2 * math.pi / 0.06, 1 / height) + 1
    assert np.max(np.abs(moved - rgb)) <= bound


def test_color_at_validates():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        make_object("sphere").color_at(np.zeros((4, 2)))
