"""Renderer: silhouettes against exact sphere images, clipping, z-buffer, shading and noise."""

import math

import numpy as np
import pytest

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import (
    rasterize_depth,
    rasterize_faces,
    rasterize_silhouette,
    render_image,
)
from sfs_ros.core.simulation.objects import make_object

from tolerances import HALF_PIXEL_DIAGONAL_PX, ROUND_OFF

CENTRE = np.array([0.0, 0.0, 0.05])
RADIUS = 0.05
#: Relative slack on radii for float rounding of pixel centres lying on a circle.
ROUND = 1e-9
# Every pixel square whose centre is inside a disc of radius R lies inside the disc of
# radius R + HALF_PIXEL_DIAGONAL_PX, and every point of the disc of radius
# R - HALF_PIXEL_DIAGONAL_PX lies in such a square, which bounds centre counts by areas.


@pytest.fixture(scope="module")
def sphere():
    """Sphere mesh and the radius of its inscribed ball (an inscribed convex polyhedron
    lies between the balls of radius r_in and RADIUS)."""
    mesh = make_object("sphere").mesh
    r_in = np.min(np.abs(np.einsum("ij,ij->i", mesh.face_normals,
                                   mesh.vertices[mesh.faces[:, 0]] - CENTRE)))
    return mesh.vertices, mesh.faces, r_in


def pixel_grid(camera):
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(float)
    return u, v


def ball_mask(camera, radius):
    """Exact image of the ball (CENTRE, radius) sampled at pixel centres."""
    u, v = pixel_grid(camera)
    c = camera.to_camera_frame(CENTRE[None])[0]
    K = camera.K
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    if camera.orthographic:
        return (x - c[0]) ** 2 + (y - c[1]) ** 2 <= radius ** 2
    # pinhole: the ray d = (x, y, 1) meets the ball iff its angle to the centre
    # direction is within asin(radius / |c|)
    dc = x * c[0] + y * c[1] + c[2]
    return (dc > 0) & (dc ** 2 >= (x * x + y * y + 1) * (c @ c - radius ** 2))


def assert_sandwiched(mask, camera, r_in):
    assert np.all(mask <= ball_mask(camera, RADIUS * (1 + ROUND)))
    assert np.all(mask >= ball_mask(camera, r_in * (1 - ROUND)))


def test_orthographic_sphere(sphere):
    vertices, faces, r_in = sphere
    calib = RigCalibration(width=400, height=360, fx=3000.0, fy=3000.0, aim_point_m=(0, 0, 0.05))
    camera = rig_camera(0.7, 0.5, calib)
    mask = rasterize_silhouette(vertices, faces, camera)
    assert mask.shape == (360, 400) and mask.dtype == bool
    assert_sandwiched(mask, camera, r_in)
    # area pi r^2 fx^2 up to the pixel-boundary band and the faceting
    R, R_in = RADIUS * 3000.0, r_in * 3000.0
    assert math.pi * (R_in - HALF_PIXEL_DIAGONAL_PX) ** 2 <= mask.sum() \
        <= math.pi * (R + HALF_PIXEL_DIAGONAL_PX) ** 2


def test_pinhole_sphere_on_axis(sphere):
    vertices, faces, r_in = sphere
    d, f = 0.3, 800.0
    calib = RigCalibration(width=320, height=300, projection="pinhole", fx=f, fy=f,
                           camera_distance_m=d, aim_point_m=tuple(CENTRE))
    camera = rig_camera(1.1, 0.8, calib)
    mask = rasterize_silhouette(vertices, faces, camera)
    u, v = pixel_grid(camera)
    rho = np.hypot(u - camera.K[0, 2], v - camera.K[1, 2])

    def image_radius(r):  # a sphere on the optical axis images as a circle
        return f * r / math.sqrt(d * d - r * r)

    R, R_in = image_radius(RADIUS), image_radius(r_in)
    assert np.all(mask[rho > R * (1 + ROUND)] == 0)
    assert np.all(mask[rho < R_in * (1 - ROUND)])
    assert math.pi * (R_in - HALF_PIXEL_DIAGONAL_PX) ** 2 <= mask.sum() \
        <= math.pi * (R + HALF_PIXEL_DIAGONAL_PX) ** 2


def test_pinhole_sphere_off_axis(sphere):
    """Off the optical axis a sphere images as an ellipse; compare with the exact cone."""
    vertices, faces, r_in = sphere
    calib = RigCalibration(width=320, height=240, projection="pinhole", fx=500.0, fy=520.0,
                           cx=140.0, cy=130.5, camera_distance_m=0.25, aim_point_m=(0.06, 0, 0))
    camera = rig_camera(-0.4, 0.3, calib)
    mask = rasterize_silhouette(vertices, faces, camera)
    assert mask.sum() > 1000
    assert_sandwiched(mask, camera, r_in)


def straddling_floor(z_near, z_far):
    """A 2 m wide floor quad at y = 0.1 (below a camera at the origin looking along +Z)."""
    vertices = np.array([[-1, 0.1, z_near], [1, 0.1, z_near], [1, 0.1, z_far], [-1, 0.1, z_far]],
                        dtype=float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def test_pinhole_triangles_behind_camera():
    f = 100.0
    camera = Camera(K=[[f, 0, 31.5], [0, f, 31.5], [0, 0, 1]], R=np.eye(3), t=np.zeros(3),
                    width=64, height=64)
    vertices, faces = straddling_floor(-1.0, 2.0)
    face_index, _, depth = rasterize_faces(vertices, faces, camera)
    # The ray through (u, v) has d = ((u - 31.5) / f, (v - 31.5) / f, 1) and meets the
    # floor at depth 0.1 / d_y, in front of the camera iff d_y > 0 and within z <= 2
    # iff d_y >= 0.05, i.e. v >= 36.5; |x| <= 1 holds across the image. The part
    # behind the camera must not show above the horizon (projected naively it would).
    u, v = np.meshgrid(np.arange(64.0), np.arange(64.0))
    truth = v >= 36.5
    np.testing.assert_array_equal(face_index >= 0, truth)
    # perspective-correct depth interpolation
    np.testing.assert_allclose(depth[truth], 0.1 * f / (v[truth] - 31.5), rtol=ROUND_OFF)
    # The depth alone is the same z-buffer, bit for bit (+inf where nothing is seen).
    np.testing.assert_array_equal(rasterize_depth(vertices, faces, camera), depth)
    assert np.all(np.isinf(depth[~truth]))
    behind, faces = straddling_floor(-2.0, -1.0)
    assert not rasterize_silhouette(behind, faces, camera).any()


def test_pinhole_vertices_on_the_camera_plane():
    """A floor whose near corners lie on the camera's plane (depth 0, no pixel): the rays
    that meet it are those of ``test_pinhole_triangles_behind_camera``, at the same depth."""
    f = 100.0
    camera = Camera(K=[[f, 0, 31.5], [0, f, 31.5], [0, 0, 1]], R=np.eye(3), t=np.zeros(3),
                    width=64, height=64)
    vertices, faces = straddling_floor(0.0, 2.0)
    depth = rasterize_depth(vertices, faces, camera)
    u, v = np.meshgrid(np.arange(64.0), np.arange(64.0))
    truth = v >= 36.5
    np.testing.assert_array_equal(np.isfinite(depth), truth)
    np.testing.assert_allclose(depth[truth], 0.1 * f / (v[truth] - 31.5), rtol=ROUND_OFF)


def test_shared_edges_and_vertices_on_pixel_centres():
    """A square split along a diagonal through pixel centres covers exactly its pixels."""
    camera = Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=32, height=32,
                    orthographic=True)  # u = x, v = y
    vertices = np.array([[9.5, 9.5, 1], [20.5, 9.5, 1], [20.5, 20.5, 1], [9.5, 20.5, 1]])
    for faces in ([[0, 1, 2], [0, 2, 3]], [[0, 2, 1], [0, 3, 2]]):  # both orientations
        mask = rasterize_silhouette(vertices, np.array(faces), camera)
        truth = np.zeros((32, 32), bool)
        truth[10:21, 10:21] = True
        np.testing.assert_array_equal(mask, truth)
    # a fan of 6 triangles around a vertex on the pixel centre (16, 16)
    angles = np.arange(6) * math.pi / 3
    fan = np.vstack([[16.0, 16.0, 1.0],
                     np.column_stack([16 + 3 * np.cos(angles), 16 + 3 * np.sin(angles),
                                      np.ones(6)])])
    fan_faces = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    assert rasterize_silhouette(fan, fan_faces, camera)[16, 16]


def test_empty_mesh_and_bad_input(sphere):
    vertices, faces, _ = sphere
    camera = Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=8, height=6, orthographic=True)
    assert not rasterize_silhouette(np.zeros((0, 3)), np.zeros((0, 3), int), camera).any()
    with pytest.raises(ValueError, match="face indices"):
        rasterize_silhouette(vertices, faces + len(vertices), camera)
    with pytest.raises(ValueError, match=r"vertices must be an \(n, 3\)"):
        rasterize_silhouette(vertices[:, :2], faces, camera)
    with pytest.raises(ValueError, match="integer"):
        rasterize_silhouette(vertices, faces.astype(float), camera)
    bad = vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        rasterize_silhouette(bad, faces, camera)
    with pytest.raises(ValueError, match="ambient"):
        render_image(vertices, faces, camera, ambient=1.5)
    with pytest.raises(ValueError, match="light_dir"):
        render_image(vertices, faces, camera, light_dir=(0, 0, 0))
    with pytest.raises(ValueError, match="vertex_colors"):
        render_image(vertices, faces, camera, vertex_colors=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="background_rgb"):
        render_image(vertices, faces, camera, background_rgb=(0, 0, 300))
    with pytest.raises(ValueError, match="noise_sigma"):
        render_image(vertices, faces, camera, noise_sigma=-1)


@pytest.fixture(scope="module")
def ortho_camera():
    calib = RigCalibration(width=200, height=200, fx=1500.0, fy=1500.0, aim_point_m=(0, 0, 0.05))
    return rig_camera(0.0, 0.0, calib)  # looking along +Y: u = cx + fx X, v = cy - fx (Z - 0.05)


def test_image_background_and_shading(sphere, ortho_camera):
    vertices, faces, _ = sphere
    image = render_image(vertices, faces, ortho_camera, noise_sigma=0.0)
    assert image.shape == (200, 200, 3) and image.dtype == np.uint8
    for corner in (image[0, 0], image[0, -1], image[-1, 0], image[-1, -1]):
        np.testing.assert_array_equal(corner, [255, 255, 255])
    mask = rasterize_silhouette(vertices, faces, ortho_camera)
    np.testing.assert_array_equal(np.any(image != 255, axis=-1), mask)
    grey = image[mask].astype(float).mean(axis=1)
    assert grey.std() > 10 and grey.min() < 0.5 * grey.max()  # shading varies, rims darker


def test_lambert_shading_is_exact(sphere, ortho_camera):
    """Light from the camera, no ambient: intensity = colour * cos(angle) = colour *
    sqrt(1 - (rho / R)^2) at image distance rho from the sphere's centre. Tolerance: 0.5
    for rounding to integers plus 1.5 for interpolated facet normals (measured < 1)."""
    vertices, faces, _ = sphere
    camera = ortho_camera
    image = render_image(vertices, faces, camera, color_rgb=(200, 200, 200), ambient=0.0,
                         light_dir=-camera.forward, noise_sigma=0.0)
    u, v = pixel_grid(camera)
    cu, cv = camera.project(CENTRE[None])[0]
    rho = np.hypot(u - cu, v - cv) / (RADIUS * camera.K[0, 0])
    inner = rho < 0.9
    expected = 200 * np.sqrt(1 - rho[inner] ** 2)
    assert np.max(np.abs(image[inner][:, 0] - expected)) <= 2.0


def test_vertex_colors_interpolated(sphere, ortho_camera):
    vertices, faces, _ = sphere
    camera = ortho_camera
    mask = rasterize_silhouette(vertices, faces, camera)
    flat = np.tile([10, 200, 30], (len(vertices), 1)).astype(np.uint8)
    image = render_image(vertices, faces, camera, vertex_colors=flat, ambient=1.0, noise_sigma=0)
    assert np.all(image[mask] == [10, 200, 30])
    # A colour linear in X is interpolated exactly; the visible point of pixel u has
    # X = (u - cx) / fx. Tolerance 0.5 for rounding to integers (+ float32 slack).
    ramp = np.column_stack([100 + 1000 * vertices[:, 0], np.full(len(vertices), 50.0),
                            np.full(len(vertices), 50.0)])
    image = render_image(vertices, faces, camera, vertex_colors=ramp, ambient=1.0, noise_sigma=0)
    u, _ = pixel_grid(camera)
    expected = 100 + 1000 * (u[mask] - camera.K[0, 2]) / camera.K[0, 0]
    assert np.max(np.abs(image[mask][:, 0] - expected)) <= 0.51


def test_z_buffer_nearest_wins(ortho_camera):
    """Two spheres one behind the other along the view (+Y): the near one hides the far one."""
    mesh = make_object("sphere").mesh
    near = mesh.vertices + [0.0, -0.02, 0.0]
    far = mesh.vertices + [0.03, 0.2, 0.0]
    red, blue = [250, 0, 0], [0, 0, 250]
    cu, cv = ortho_camera.project(CENTRE[None])[0]
    only_far = int(round(cu + 0.065 * ortho_camera.K[0, 0]))  # X = 65 mm: beyond the near one
    for first, second in (((near, red), (far, blue)), ((far, blue), (near, red))):  # either order
        vertices = np.vstack([first[0], second[0]])
        faces = np.vstack([mesh.faces, mesh.faces + len(first[0])])
        colors = np.vstack([np.tile(first[1], (len(first[0]), 1)),
                            np.tile(second[1], (len(second[0]), 1))])
        image = render_image(vertices, faces, ortho_camera, vertex_colors=colors, ambient=1.0,
                             noise_sigma=0)
        np.testing.assert_array_equal(image[int(cv), int(cu)], red)  # overlap: near sphere
        np.testing.assert_array_equal(image[int(cv), only_far], blue)



@pytest.mark.parametrize("name", ["sphere", "mug"])
def test_closed_mesh_depth_from_the_faces_turned_to_the_camera(name):
    """A ray into a closed outward mesh enters through a face turned towards the camera:
    drawing only those gives the same z-buffer. The mug's handle hides part of its body
    and its inside from some views, so the nearest face is not the only front face on a
    ray. Pinhole views from around and from close by (a wide image of a big object), and
    orthographic ones."""
    mesh = make_object(name).mesh
    vertices, faces = mesh.vertices, mesh.faces
    pinhole = RigCalibration(width=160, height=120, projection="pinhole", fx=150.0, fy=150.0,
                             camera_distance_m=0.3, aim_point_m=(0.0, 0.0, 0.04))
    close = RigCalibration(width=96, height=96, projection="pinhole", fx=40.0, fy=40.0,
                           camera_distance_m=0.12, aim_point_m=(0.0, 0.0, 0.04))
    ortho = RigCalibration(width=120, height=120, fx=900.0, fy=900.0,
                           aim_point_m=(0.0, 0.0, 0.04))
    cameras = [rig_camera(theta, phi, calib) for calib in (pinhole, close, ortho)
               for theta in (0.0, 1.3, 2.9, 4.4) for phi in (0.0, 0.7, 1.4)]
    for camera in cameras:
        full = rasterize_depth(vertices, faces, camera)
        assert np.isfinite(full).sum() > 100
        np.testing.assert_array_equal(rasterize_depth(vertices, faces, camera, closed=True), full)


def test_closed_draws_only_the_faces_turned_to_the_camera():
    """The promise is the caller's: a lone triangle turned away is not drawn with it."""
    camera = Camera(K=[[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]], R=np.eye(3),
                    t=np.zeros(3), width=64, height=64)
    vertices = np.array([[-0.1, -0.1, 1.0], [0.1, -0.1, 1.0], [0.0, 0.1, 1.0]])
    for faces, turned_to_camera in (([[0, 2, 1]], True), ([[0, 1, 2]], False)):
        # outward normal (0, 0, -1): towards the camera at the origin, seen along +Z
        full = rasterize_depth(vertices, np.array(faces), camera)
        assert np.isfinite(full).sum() > 100
        closed = rasterize_depth(vertices, np.array(faces), camera, closed=True)
        np.testing.assert_array_equal(closed, full if turned_to_camera else np.inf)

def test_noise_statistics_and_seed():
    camera = Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=200, height=100,
                    orthographic=True)
    empty = (np.zeros((0, 3)), np.zeros((0, 3), int))
    image = render_image(*empty, camera, background_rgb=(128, 128, 128), noise_sigma=4.0, seed=3)
    values = image.astype(float)
    # 60000 samples: the standard error of the mean is 4 / sqrt(6e4) = 0.016 and of the
    # standard deviation ~0.012; rounding to integers adds 1/12 to the variance.
    assert abs(values.mean() - 128) < 0.1
    assert abs(values.std() - math.sqrt(16 + 1 / 12)) < 0.1
    again = render_image(*empty, camera, background_rgb=(128, 128, 128), noise_sigma=4.0, seed=3)
    np.testing.assert_array_equal(image, again)
    other = render_image(*empty, camera, background_rgb=(128, 128, 128), noise_sigma=4.0, seed=4)
    assert not np.array_equal(image, other)
