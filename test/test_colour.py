"""Vertex colour from the captured images: closed-form scenes, the mug against its
known colour pattern, and coloured mesh files read back by trimesh and assimp."""

import json
import os
import shutil
import struct
import subprocess

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from sfs_ros.core.exchange.export import export_mesh, load_mesh
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.meshing.colour import (
    HarmonicFill,
    SmoothedFill,
    fill_from_neighbours,
    spread_views,
    vertex_colours,
    vertex_normals,
)
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import rasterize_silhouette, render_image
from sfs_ros.core.segmentation.segment import segment

RED, GREEN, BLUE = (200, 30, 30), (30, 200, 30), (30, 30, 200)
#: Noise-free renders of constant colours: bilinear sampling and blending of a
#: constant give that constant; only rounding to uint8 remains.
ROUNDING = 1
#: The mug (320 x 240 px, 49 views, 128^3 grid of 0.84 mm voxels), measured:
#: albedo images, vertices within a voxel of the true surface 0.88 mean / 1.67 p95
#: (camera noise of 2 grey levels averaged over ~14 views, rounding, and the
#: colour gradient of up to 9 levels/mm over the hull's sub-voxel offset);
#: all seen vertices 2.64 / 19.67 (the hull's dome 1-4 mm above the flat top,
#: where each view sees a different point of the true top); the vertices the
#: handle or the body hides from some view 0.79 / 2.00, and 12.3 / 57.7 without
#: the z-buffer test; shaded images 38.7 mean (the shading is baked in).
MUG_ON_SURFACE = (1.2, 2.5)
MUG_SEEN = (3.5, 24.0)
MUG_OCCLUDED = (1.2, 3.0)


def look_at(eye, *, size=(160, 120), f_px=300.0, orthographic=False) -> Camera:
    """Camera at ``eye`` (metres) aimed at the origin, image right ~ +X or +Y.

    Orthographic: the scale (pixels per metre) of the pinhole at the origin.
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = -eye / np.linalg.norm(eye)
    up = np.array([0.0, 1.0, 0.0]) if abs(forward[2]) > 0.9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(forward, right), forward])
    f = f_px / np.linalg.norm(eye) if orthographic else f_px
    K = [[f, 0.0, (size[0] - 1) / 2], [0.0, f, (size[1] - 1) / 2], [0.0, 0.0, 1.0]]
    return Camera(K=K, R=R, t=-R @ eye, width=size[0], height=size[1], orthographic=orthographic)


def sphere(radius, centre=(0.0, 0.0, 0.0), subdivisions=4):
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices) + centre, np.asarray(mesh.faces, dtype=np.int64)


def albedo_images(vertices, faces, colours, cameras, noise_sigma=0.0):
    """Unshaded renders (``ambient=1``), the noise seeded per view."""
    return [render_image(vertices, faces, c, vertex_colors=colours, ambient=1.0,
                         noise_sigma=noise_sigma, seed=n) for n, c in enumerate(cameras)]


@pytest.mark.parametrize("orthographic", [False, True])
def test_sphere_halves_take_their_colour(orthographic):
    vertices, faces = sphere(0.05)
    colours = np.where(vertices[:, :1] > 0, RED, BLUE)
    axes = np.vstack([np.eye(3), -np.eye(3)])
    cameras = [look_at(0.5 * a, orthographic=orthographic) for a in axes]
    result = vertex_colours(vertices, faces, albedo_images(vertices, faces, colours, cameras),
                            cameras)
    # Six axis views see every point of a sphere within 55 degrees of its normal.
    assert result.n_views.min() >= 1 and result.stats["filled"] == 0
    assert result.n_hidden.sum() == 0  # a convex object hides nothing from itself
    # Faces straddling x = 0 blend both colours: leave out a band of one edge
    # (4.1 mm at most) plus the two pixels bilinear sampling may reach (at most
    # 1.7 mm each, 5.8 mm on the surface at 55 degrees) on either side.
    far = np.abs(vertices[:, 0]) > 0.0041 + 0.0058
    assert far.sum() > 0.6 * len(vertices)
    error = np.abs(result.colours.astype(int) - colours)[far]
    assert error.max() <= ROUNDING


def segment_hits_sphere(points, eye, centre, radius):
    """(n,) distance from ``centre`` to each segment points -> eye, minus ``radius`` (metres)."""
    d = eye - points
    t = np.clip(np.einsum("ij,ij->i", centre - points, d) / np.einsum("ij,ij->i", d, d), 0, 1)
    return np.linalg.norm(points + t[:, None] * d - centre, axis=1) - radius


def test_occluded_point_takes_its_colour_only_from_the_views_that_see_it():
    # A green ball with a small red ball in front of it, seen from A (straight
    # on: the red ball hides part of the green one) and from B (45 degrees aside).
    back_v, back_f = sphere(0.04)
    front_centre = np.array([0.0, -0.08, 0.0])
    front_v, front_f = sphere(0.015, front_centre, subdivisions=3)
    vertices = np.vstack([back_v, front_v])
    faces = np.vstack([back_f, front_f + len(back_v)])
    colours = np.vstack([np.tile(GREEN, (len(back_v), 1)), np.tile(RED, (len(front_v), 1))])
    eye_a, eye_b = np.array([0.0, -0.5, 0.0]), 0.5 * np.array([-1.0, -1.0, 0.0]) / np.sqrt(2)
    cameras = [look_at(eye_a), look_at(eye_b)]
    images = albedo_images(vertices, faces, colours, cameras)

    # Ground truth by ray casting, with a 2 mm margin (two pixels) around the red ball.
    normals = vertex_normals(back_v, back_f)
    to_b = (eye_b - back_v) / np.linalg.norm(eye_b - back_v, axis=1, keepdims=True)
    hidden_from_a = segment_hits_sphere(back_v, eye_a, front_centre, 0.015) < -0.002
    seen_by_b = (segment_hits_sphere(back_v, eye_b, front_centre, 0.015) > 0.002) \
        & (np.einsum("ij,ij->i", normals, to_b) > 0.5)
    case = np.flatnonzero(hidden_from_a & seen_by_b)
    assert len(case) >= 20

    result = vertex_colours(vertices, faces, images, cameras)
    assert np.all(result.n_views[case] == 1)
    # Hidden by the z-buffer test, except next to the red ball's outline in A,
    # where the edge ramp (4.5 px) already drops view A.
    assert np.mean(result.n_hidden[case] == 1) > 0.8
    assert np.abs(result.colours[case].astype(int) - GREEN).max() <= ROUNDING
    # Without the z-buffer test view A paints them with the red ball in front.
    baseline = vertex_colours(vertices, faces, images, cameras, occlusion=False)
    assert np.all(baseline.n_views[case] == 2)
    assert baseline.colours[case, 0].mean() > 100


def test_unseen_vertices_take_the_colour_of_their_neighbours():
    vertices, faces = sphere(0.05, subdivisions=3)
    # A ball that no view sees, behind the camera: a component with no seen vertex.
    lost_v, lost_f = sphere(0.01, (0.0, 0.0, 1.0), subdivisions=1)
    all_v, all_f = np.vstack([vertices, lost_v]), np.vstack([faces, lost_f + len(vertices)])
    camera = look_at((0.0, 0.0, 0.5))
    image = albedo_images(vertices, faces, np.tile(BLUE, (len(vertices), 1)), [camera])
    result = vertex_colours(all_v, all_f, image, [camera])
    # One view from above sees the upper cap; the harmonic fill of a constant is
    # that constant, and the unseen ball takes the mean of the seen colours.
    unseen = result.n_views == 0
    assert np.all(unseen[len(vertices):]) and unseen[:len(vertices)].sum() > len(vertices) // 2
    assert result.stats["filled"] == unseen.sum()
    assert np.abs(result.colours.astype(int) - BLUE).max() <= ROUNDING
    # The caller hears once that every view is blended (the fill, one core's work, follows).
    calls = []
    again = vertex_colours(all_v, all_f, image, [camera], on_blended=lambda: calls.append(1))
    assert calls == [1] and np.array_equal(again.colours, result.colours)


def _grid(nx: int, ny: int) -> tuple:
    """A grid of nx x ny vertices cut into triangles along one diagonal: (x, y) (ny, nx)
    float, faces (m, 3) int64, the border vertices (ny * nx,) bool."""
    x, y = np.meshgrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float))
    index = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = (index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:])
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    border = np.zeros((ny, nx), bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    return x, y, faces, border.ravel()


def _edge_energy(colours: np.ndarray, faces: np.ndarray) -> float:
    """The sum over the mesh's edges (each once) of the squared colour difference."""
    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    return float(((colours[edges[:, 0]] - colours[edges[:, 1]]) ** 2).sum())


def test_the_harmonic_fill_factored_once_reproduces_every_linear_colouring():
    # A grid of 30 x 20 vertices cut into triangles along one diagonal: each inner vertex
    # has six neighbours in three opposite pairs, so a colour linear in (x, y) is the mean
    # of its neighbours' (harmonic), and with the border seen the fill must give it back.
    x, y, faces, seen = _grid(30, 20)
    fill = HarmonicFill.of(seen, faces)                   # before any colour is known
    for slope in ((2.0, -1.0, 0.5), (-3.0, 4.0, 1.0)):
        truth = np.stack([x.ravel() * s + y.ravel() * (1 - s) + 7 for s in slope], axis=1)
        given = np.where(seen[:, None], truth, 0.0)
        filled = fill(given)
        # Exact up to the factorisation's rounding (colours of a few hundred units).
        assert np.abs(filled - truth).max() < 1e-9
        assert np.array_equal(filled, fill_from_neighbours(given, seen, faces))
        assert np.array_equal(filled[seen], given[seen])


def test_the_smoothed_fill_tends_to_the_harmonic_one_and_smooths_at_every_sweep():
    # Each sweep sets every unseen vertex to the mean of its neighbours: the exact minimum
    # of the edge energy over that vertex, so the energy never rises from one sweep to the
    # next, and the sweeps tend to the harmonic fill (its minimum), which gives back any
    # linear colour on this grid (the test above).
    x, y, faces, seen = _grid(30, 20)
    truth = np.stack([2 * x.ravel() - y.ravel() + 7, -3 * x.ravel() + 4 * y.ravel()], axis=1)
    truth = np.concatenate([truth, truth[:, :1] * 0.5], axis=1)
    given = np.where(seen[:, None], truth, 0.0)
    energies, errors = [], []
    for sweeps in (0, 1, 4, 16, 64):
        filled = SmoothedFill.of(seen, faces, sweeps=sweeps)(given)
        assert np.array_equal(filled[seen], given[seen])
        # A weighted mean of the seen colours: within their range (up to rounding).
        low, high = given[seen].min(axis=0) - 1e-9, given[seen].max(axis=0) + 1e-9
        assert np.all(filled >= low) and np.all(filled <= high)
        energies.append(_edge_energy(filled, faces))
        errors.append(np.abs(filled - truth).max())
    assert all(later <= earlier for earlier, later in zip(energies, energies[1:]))
    assert errors[-1] < errors[0]
    # Patches of one vertex each: the harmonic fill itself, solved directly.
    single = SmoothedFill.of(seen, faces, sweeps=0, radius=0)(given)
    assert np.abs(single - truth).max() < 1e-9
    # Converged (a 28 x 18 interior: the slowest mode decays by about 1 - 1e-2 a sweep).
    converged = SmoothedFill.of(seen, faces, sweeps=2000)(given)
    assert np.abs(converged - truth).max() < 1e-6
    assert np.isclose(_edge_energy(converged, faces), _edge_energy(truth, faces))


def test_the_smoothed_fill_keeps_a_constant_and_gives_lost_parts_the_mean():
    # The grid with one corner seen in one colour and one in another; a second grid with
    # no seen vertex (a component no view sees) takes the mean of the seen colours.
    _, _, faces, _ = _grid(12, 9)
    n = 12 * 9
    all_faces = np.concatenate([faces, faces + n])
    seen = np.zeros(2 * n, bool)
    seen[[0, n - 1]] = True
    colours = np.zeros((2 * n, 3))
    colours[0], colours[n - 1] = (10.0, 20.0, 30.0), (10.0, 20.0, 30.0)
    fill = SmoothedFill.of(seen, all_faces)
    # Up to the patches' solve's rounding.
    assert np.abs(fill(colours) - (10.0, 20.0, 30.0)).max() < 1e-9
    colours[n - 1] = (50.0, 0.0, 30.0)
    filled = fill(colours)
    assert np.allclose(filled[n:], (30.0, 10.0, 30.0))
    # Between the two seen colours, a vertex nearer the first nearer its colour.
    assert np.all((filled[:n, 0] >= 10 - 1e-9) & (filled[:n, 0] <= 50 + 1e-9))
    assert filled[1, 0] < filled[n // 2, 0] < filled[n - 2, 0]
    with pytest.raises(ValueError, match="sweeps"):
        SmoothedFill.of(seen, all_faces, radius=-1)


def test_spread_views_takes_the_farthest_directions_first():
    ring = [look_at((np.cos(a), np.sin(a), 0.5)) for a in np.radians(np.arange(0, 360, 45))]
    # From view 0 the farthest is the opposite one (4), then the two at 90 degrees
    # from both (2 and 6, the lower index first): every other view of the ring.
    assert spread_views(ring, 4) == [0, 2, 4, 6]
    assert spread_views(ring, 8) == spread_views(ring, 20) == list(range(8))
    same = [look_at((1.0, 0.0, 0.5))] * 3       # no view is picked twice
    assert spread_views(same, 2) == [0, 1]
    with pytest.raises(ValueError, match="at least 1"):
        spread_views(ring, 0)


def test_invalid_arguments():
    vertices, faces = sphere(0.05, subdivisions=1)
    camera = look_at((0.0, 0.0, 0.5))
    image = np.zeros((camera.height, camera.width, 3), np.uint8)
    with pytest.raises(ValueError, match="at least one view"):
        vertex_colours(vertices, faces, [], [])
    with pytest.raises(ValueError, match="one image per camera"):
        vertex_colours(vertices, faces, [image, image], [camera])
    with pytest.raises(ValueError, match=r"image of view 0 must be \(120, 160, 3\) uint8"):
        vertex_colours(vertices, faces, [image[:-1]], [camera])
    with pytest.raises(ValueError, match="mask of view 0"):
        vertex_colours(vertices, faces, [image], [camera], masks=[np.ones((2, 2), bool)])
    with pytest.raises(ValueError, match="min_cos"):
        vertex_colours(vertices, faces, [image], [camera], min_cos=1.0)
    with pytest.raises(ValueError, match="no vertex is seen"):
        vertex_colours(vertices + [0.0, 0.0, 2.0], faces, [image], [camera])
    with pytest.raises(ValueError, match="coverage comes from the occlusion test"):
        vertex_colours(vertices, faces, [image], [camera], occlusion=False, coverage=True)


@pytest.mark.parametrize("orthographic", [False, True])
def test_the_z_buffers_give_the_silhouettes_of_the_mesh(orthographic):
    vertices, faces = sphere(0.05)
    colours = np.where(vertices[:, :1] > 0, RED, BLUE)
    cameras = [look_at(0.5 * np.array(a), orthographic=orthographic)
               for a in ([1.0, 0.0, 0.0], [0.36, -0.8, 0.48], [0.0, 0.0, -1.0])]
    images = albedo_images(vertices, faces, colours, cameras)
    result = vertex_colours(vertices, faces, images, cameras, coverage=True)
    for camera, packed in zip(cameras, result.coverage):
        drawn = np.unpackbits(packed, count=camera.height * camera.width).astype(bool)
        np.testing.assert_array_equal(drawn.reshape(camera.height, camera.width),
                                      rasterize_silhouette(vertices, faces, camera))
    # The sphere is closed and outward: drawing only the faces turned to each camera
    # gives the same z-buffers, so the same colours and silhouettes, bit for bit.
    closed = vertex_colours(vertices, faces, images, cameras, coverage=True, closed=True)
    np.testing.assert_array_equal(closed.colours, result.colours)
    np.testing.assert_array_equal(closed.n_hidden, result.n_hidden)
    for ours, theirs in zip(closed.coverage, result.coverage):
        np.testing.assert_array_equal(ours, theirs)
    assert vertex_colours(vertices, faces, albedo_images(vertices, faces, colours, cameras),
                          cameras).coverage is None


@pytest.fixture(scope="module")
def mug_colouring(mug, mug_captures, mug_views):
    """Per-vertex errors (0..255, mean over R, G, B) of the coloured mug reconstruction."""
    result = reconstruct(mug_views, ReconstructionParams(resolution=128))
    shaded = {c.name: c.image for c in mug_captures}
    views = [v for v in mug_views.views if v.name in set(result.report["views"]["used"])]
    cameras = [v.camera for v in views]
    images = {"shaded": [shaded[v.name] for v in views],
              "albedo": albedo_images(mug.mesh.vertices, mug.mesh.faces,
                                      mug.color_at(mug.mesh.vertices), cameras, noise_sigma=2.0)}
    masks = [segment(image).mask for image in images["shaded"]]
    # Truth: the pattern at the nearest point of the true surface (samples ~0.25 mm
    # apart, a third of a voxel), not at the vertex, which may lie a voxel outside.
    samples = mug.sample_surface(400_000, seed=0)
    distance_m, nearest = cKDTree(samples).query(result.vertices)
    truth = mug.color_at(samples[nearest]).astype(float)
    out = {"on_surface": distance_m <= result.grid.voxel_size}
    for name, imgs in images.items():
        for occlusion in (True, False):
            colouring = vertex_colours(result.vertices, result.faces, imgs, cameras, masks=masks,
                                       occlusion=occlusion)
            out[name, occlusion] = (colouring, np.abs(colouring.colours - truth).mean(axis=1))
    return out


def mean_p95(errors):
    return errors.mean(), np.percentile(errors, 95)


def test_mug_albedo_colours_match_the_pattern(mug_colouring):
    colouring, error = mug_colouring["albedo", True]
    seen = colouring.n_views > 0
    assert seen.mean() > 0.8  # the rest is the underside on the plate
    mean, p95 = mean_p95(error[seen & mug_colouring["on_surface"]])
    assert mean <= MUG_ON_SURFACE[0] and p95 <= MUG_ON_SURFACE[1]
    mean, p95 = mean_p95(error[seen])
    assert mean <= MUG_SEEN[0] and p95 <= MUG_SEEN[1]


def test_mug_visibility_beats_the_normal_only_baseline(mug_colouring):
    colouring, error = mug_colouring["albedo", True]
    occluded = colouring.n_hidden > 0
    assert occluded.mean() > 0.05  # the handle and the body hide each other
    mean, p95 = mean_p95(error[occluded])
    assert mean <= MUG_OCCLUDED[0] and p95 <= MUG_OCCLUDED[1]
    baseline_mean, _ = mean_p95(mug_colouring["albedo", False][1][occluded])
    assert baseline_mean >= 5 * mean


def test_mug_shaded_images_bake_the_shading_in(mug_colouring):
    # Lambert shading with an ambient of 0.25 darkens by up to 75 %: the error is
    # tens of grey levels, more than ten times the albedo error.
    colouring, shaded = mug_colouring["shaded", True]
    seen = colouring.n_views > 0
    assert shaded[seen].mean() >= 10 * mug_colouring["albedo", True][1][seen].mean()


# --- Export of the colours ---------------------------------------------------

COLOURED = [".ply", ".glb", ".obj"]


@pytest.fixture(scope="module")
def coloured_ball():
    vertices, faces = sphere(0.05, (0.01, 0.02, 0.06), subdivisions=2)
    colours = np.round(255 * (vertices - vertices.min(0)) / np.ptp(vertices, 0)).astype(np.uint8)
    return vertices, faces, colours


def file_axes(vertices, suffix):
    """Our Z-up vertices in the file's axes (glTF and OBJ are Y up)."""
    if suffix in (".glb", ".obj"):
        return np.column_stack((vertices[:, 0], vertices[:, 2], -vertices[:, 1]))
    return vertices


@pytest.mark.parametrize("suffix", COLOURED)
def test_colours_round_trip(tmp_path, coloured_ball, suffix):
    vertices, faces, colours = coloured_ball
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}", vertex_colors=colours)
    v2, f2, c2 = load_mesh(path, with_colors=True)
    np.testing.assert_array_equal(f2, faces)
    np.testing.assert_array_equal(c2[:, :3], colours)
    assert load_mesh(export_mesh(vertices, faces, tmp_path / f"plain{suffix}"),
                     with_colors=True)[2] is None


def test_colours_as_each_format_stores_them(tmp_path, coloured_ball):
    vertices, faces, colours = coloured_ball
    ply = export_mesh(vertices, faces, tmp_path / "m.ply", vertex_colors=colours).read_bytes()
    header = ply[:ply.index(b"end_header")].decode()
    assert all(f"property uchar {c}" in header for c in ("red", "green", "blue"))
    obj = export_mesh(vertices, faces, tmp_path / "m.obj", vertex_colors=colours).read_text()
    first = np.array([line.split()[1:] for line in obj.splitlines() if line.startswith("v ")],
                     dtype=float)
    assert first.shape == (len(vertices), 6)  # v x y z r g b, r g b in [0, 1]
    np.testing.assert_allclose(first[:, 3:] * 255, colours, atol=0.01)
    glb = export_mesh(vertices, faces, tmp_path / "m.glb", vertex_colors=colours).read_bytes()
    json_length = struct.unpack_from("<I", glb, 12)[0]
    gltf = json.loads(glb[20:20 + json_length])
    assert "COLOR_0" in gltf["meshes"][0]["primitives"][0]["attributes"]
    # STL has no colour: asking for it is an error (tested in test_export), a plain
    # STL reads back without colours.
    assert load_mesh(export_mesh(vertices, faces, tmp_path / "m.stl"), with_colors=True)[2] is None


def assimp_ply_colours(path, tmp_path):
    """(positions (k, 3), colours (k, 3) uint8) of the vertices assimp reads from ``path``,
    through ``assimp export`` to ASCII PLY (assimp may split vertices per face)."""
    exe = shutil.which("assimp")
    if exe is None:
        pytest.fail("the 'assimp' command is missing: install Debian's assimp-utils "
                    "(apt-get install assimp-utils) to run the independent-reader test")
    out = tmp_path / f"assimp_{path.suffix[1:]}.ply"
    run = subprocess.run([exe, "export", os.fspath(path), os.fspath(out), "-fply"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, f"assimp could not convert {path.name}: {run.stdout[-2000:]}"
    lines = out.read_text().splitlines()
    end = lines.index("end_header")
    n = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    names = [line.split()[2] for line in lines[:end] if line.startswith("property ")
             and not line.startswith("property list")]
    table = np.array([line.split()[:len(names)] for line in lines[end + 1:end + 1 + n]], float)
    rgb = [names.index(c) for c in ("red", "green", "blue")]
    return table[:, :3], table[:, rgb].astype(np.uint8)


@pytest.mark.parametrize("suffix", COLOURED)
def test_assimp_reads_the_colours(tmp_path, coloured_ball, suffix):
    vertices, faces, colours = coloured_ball
    path = export_mesh(vertices, faces, tmp_path / f"m{suffix}", vertex_colors=colours)
    points, rgb = assimp_ply_colours(path, tmp_path)
    # Match assimp's vertices to ours by position (in the file's axes; assimp
    # prints 9 significant digits of float32 coordinates).
    distance, index = cKDTree(file_axes(vertices, suffix)).query(points)
    assert distance.max() < 1e-6 and len(np.unique(index)) == len(vertices)
    # OBJ stores c / 255 with 8 decimals, a hair below c for some c; assimp keeps
    # colours as floats and its PLY writer truncates them to uchar: c - 1.
    atol = 1 if suffix == ".obj" else 0
    np.testing.assert_allclose(rgb, colours[index], atol=atol, rtol=0)
