"""The texture atlas fits whatever the mesh: a finely divided rough sphere seen from above
only (its lower half, curved, seen by no view: every such face a chart of its own would not
fit)
and many tiny disconnected faces no view sees, in a small atlas; the agreement test's
smoothing made near the faces it is wanted at."""

import numpy as np
import pytest
import trimesh

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.meshing.colour import view_sight
from sfs_ros.core.render import render_image
from sfs_ros.core.texture import texture_mesh
from sfs_ros.core.texture.atlas import build_atlas, rasterize_atlas
from sfs_ros.core.texture.selection import face_neighbours, farthest_around

#: Side of the atlas the tests allow, texels: far less than one chart with padding per
#: unseen face needs (5 x 5 texels each at least, against 1 for a cell).
MAX_SIZE = 256


def camera_above(azimuth: float, elevation: float, distance: float = 0.4) -> Camera:
    """A 160 x 120 px pinhole camera ``distance`` metres from the origin, looking at it
    from ``elevation`` radians above the XY plane at ``azimuth`` radians."""
    eye = distance * np.array([np.cos(elevation) * np.cos(azimuth),
                               np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])
    return Camera(K=K, R=R, t=-R @ eye, width=160, height=120)


def test_a_fine_sphere_seen_from_above_is_textured_in_a_small_atlas():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.05)   # 20480 faces
    faces = np.asarray(sphere.faces, np.int64)
    # Rough as a refined mesh: each vertex moved along its radius by up to half an edge
    # (1.9 mm), so the normals of neighbouring faces differ widely and an unseen patch
    # cannot be laid flat.
    radius = 0.05 + np.random.default_rng(2).uniform(-1e-3, 1e-3, len(sphere.vertices))
    vertices = np.asarray(sphere.vertices) * (radius / 0.05)[:, None]
    # Colour rising with height: the truth at every point is known.
    colours = np.clip(np.stack([128 + 2000 * vertices[:, 2]] * 3, axis=1), 0, 255)
    cameras = [camera_above(a, np.radians(60)) for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    images = [render_image(vertices, faces, c, vertex_colors=colours.astype(np.uint8), ambient=1.0,
                           noise_sigma=0.0) for c in cameras]
    textured = texture_mesh(vertices, faces, images, cameras, closed=True, max_size=MAX_SIZE)
    unseen = textured.face_view < 0
    # The lower half (and more: the views look down at 60 degrees) is seen by no view.
    assert unseen.mean() > 0.4
    assert max(textured.stats["atlas_size"]) <= MAX_SIZE
    # Seen faces read their views: the truth at their corners, within a few grey levels
    # (bicubic reads of an image whose pixels hold the colour at their centres).
    at_corners = textured.vertex_colours()[textured.faces].astype(float)
    truth = colours[faces]
    assert np.median(np.abs(at_corners - truth)[~unseen]) <= 3.0
    # Unseen faces are coloured from the seen ones (interpolated): within their range.
    seen_range = truth[~unseen]
    assert at_corners[unseen].min() >= seen_range.min() - 1
    assert at_corners[unseen].max() <= seen_range.max() + 1


def test_many_tiny_disconnected_unseen_faces_fit_with_a_texel_each():
    rng = np.random.default_rng(0)
    count = 60000                    # nearly the whole atlas
    origins = rng.uniform(-0.05, 0.05, (count, 3))
    vertices = (origins[:, None, :] + rng.uniform(0, 1e-3, (count, 3, 3))).reshape(-1, 3)
    faces = np.arange(3 * count, dtype=np.int64).reshape(-1, 3)
    labels = np.full(count, -1, np.int64)
    atlas = build_atlas(vertices, faces, labels, face_neighbours(faces), [camera_above(0, 1)],
                        max_size=MAX_SIZE)
    assert max(atlas.shape) <= MAX_SIZE
    claimed = np.bincount(atlas.face_index[atlas.face_index >= 0], minlength=count)
    assert (claimed == 1).all()                 # cells of one texel
    # Each face's corners lie at its texel's centre.
    rows, cols = np.nonzero(atlas.face_index >= 0)
    centre = np.zeros((count, 2))
    centre[atlas.face_index[rows, cols]] = np.stack([cols, rows], axis=1)
    assert np.abs(atlas.corners - centre[:, None, :]).max() <= 1e-9


def test_a_face_in_a_cell_reads_its_own_texel_alone():
    count = 500
    rng = np.random.default_rng(1)
    vertices = (rng.uniform(-0.05, 0.05, (count, 1, 3)) + rng.uniform(0, 1e-3, (count, 3, 3))
                ).reshape(-1, 3)
    faces = np.arange(3 * count, dtype=np.int64).reshape(-1, 3)
    atlas = build_atlas(vertices, faces, np.full(count, -1, np.int64), face_neighbours(faces),
                        [camera_above(0, 1)], max_size=MAX_SIZE)
    claimed = np.bincount(atlas.face_index[atlas.face_index >= 0], minlength=count)
    assert (claimed == 1).all()
    # All three corners at the centre of the face's texel: a bilinear look-up anywhere in
    # the face weighs that texel alone.
    for f in range(0, count, 37):
        for x, y in atlas.corners[f]:
            assert x == round(x) and y == round(y)
            assert atlas.face_index[int(y), int(x)] == f
    # No face's charted triangle claims a texel of another: the cells are off the rasteriser.
    assert rasterize_atlas(atlas.corners, atlas.shape)[2] == 0


def test_seen_charts_that_do_not_fit_are_scaled_down():
    camera = camera_above(0, np.radians(89))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64)
    normals = np.asarray(sphere.face_normals)
    labels = np.where(normals[:, 2] > 0.3, 0, -1).astype(np.int64)     # the top: one chart
    asked = 8.0                                  # 8 texels per pixel: the top alone ~ 400^2
    atlas = build_atlas(vertices, faces, labels, face_neighbours(faces), [camera],
                        texels_per_pixel=asked, max_size=MAX_SIZE)
    assert max(atlas.shape) <= MAX_SIZE
    assert atlas.texels_per_pixel < asked
    # Scaled down no further than the fit needs: the atlas takes nearly the side allowed
    # (the charts' padding and the shelves' ragged ends leave a few texels).
    assert max(atlas.shape) >= 0.9 * MAX_SIZE


def test_farthest_around_is_the_farthest_finite_depth_of_nine_pixels():
    zbuf = np.full((4, 4), np.inf)
    zbuf[:2, :2] = [[1.0, 2.0], [4.0, 3.0]]
    inf = np.inf
    expected = np.array([[4.0, 4.0, 3.0, inf],
                         [4.0, 4.0, 3.0, inf],
                         [4.0, 4.0, 3.0, inf],
                         [inf, inf, inf, inf]])
    np.testing.assert_array_equal(farthest_around(zbuf), expected)


def test_a_point_between_pixel_centres_is_hidden_only_behind_all_four():
    """A step in an orthographic z-buffer: columns up to 49 show a surface at depth 1 m,
    columns from 50 one 3 footprints nearer (below the depth steps that make an edge). A
    point of the far surface a fraction ``a`` of a pixel right of column 49, facing the
    camera (tolerance: one footprint), lies ``3 a`` footprints behind the z-buffer read
    bilinearly: that reading hides it for ``a > 1/3``. It lies behind the nearer surface
    at one, two or none of the four pixel centres around it, not all: it is seen. At
    column 50.5 the nine pixels around column 50 reach the far surface and those around
    51 do not: the reading is 1.5 footprints in front, hidden; from column 51 on, hidden
    either way."""
    f = 1000.0                                    # pixels per metre: a 1 mm footprint
    camera = Camera(K=np.array([[f, 0, 0], [0, f, 0], [0, 0, 1]]), R=np.eye(3),
                    t=np.zeros(3), width=100, height=100, orthographic=True)
    zbuf = np.full((100, 100), 1.0)
    zbuf[:, 50:] = 1.0 - 3.0 / f
    fractions = np.array([0.1, 0.25, 0.3, 0.4, 0.6, 0.9, 1.5, 2.5])
    points = np.stack([(49.0 + fractions) / f, np.full(len(fractions), 50.3 / f),
                       np.ones(len(fractions))], axis=1)
    normals = np.tile([0.0, 0.0, -1.0], (len(fractions), 1))
    blended = view_sight(camera, points, normals, zbuf, None).hidden
    behind_all = view_sight(camera, points, normals, zbuf, None,
                            depth_zbuf=farthest_around(zbuf)).hidden
    np.testing.assert_array_equal(blended, 3 * np.minimum(fractions, 1.0) > 1.0)
    np.testing.assert_array_equal(behind_all, fractions >= 1.5)


def test_the_agreement_smoothing_near_the_wanted_faces_equals_the_full_sums():
    # A sphere of 5120 faces, a few far-apart blobs of faces wanted (values there alone):
    # the ring sums at the wanted faces, made on the faces within half the rings of them,
    # equal the sums over the whole mesh's adjacency (face and its neighbours), ring after
    # ring; the faces not wanted are left zero.
    from scipy import sparse

    from sfs_ros.core.texture.agreement import _smoothed

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    faces = np.asarray(sphere.faces, np.int64)
    neighbours = face_neighbours(faces)
    m = len(faces)
    centroids = np.asarray(sphere.triangles_center)
    wanted = np.zeros(m, bool)
    for direction in ([1, 0, 0], [0, -1, 0], [0, 0, 1]):
        wanted |= centroids @ np.array(direction, float) > 0.045
    values = np.random.default_rng(3).uniform(0, 1, (m, 5)) * wanted[:, None]
    rows = np.repeat(np.arange(m), 3)
    keep = neighbours.ravel() >= 0
    adjacency = sparse.csr_matrix((np.ones(int(keep.sum())), (rows[keep], neighbours.ravel()[keep])),
                                  shape=(m, m)) + sparse.identity(m, format="csr")
    for rings in (1, 4, 7):
        full = values.copy()
        for _ in range(rings):
            full = adjacency @ full
        near = _smoothed(values, neighbours, rings, wanted)
        # Float sums in another order: equal to a few units in the last place.
        np.testing.assert_allclose(near[wanted], full[wanted], rtol=1e-12)
        assert not near[~wanted].any()
        # The neighbourhood matters: ring sums reach faces that are not wanted.
        assert full[~wanted].any()


def test_unseen_faces_around_a_vertex_share_its_cell_and_its_colour():
    # An icosahedron no view sees (20 faces): the faces whose lowest corner is one vertex
    # share one cell, read at that vertex; every face's corners at its cell's centre.
    icosahedron = trimesh.creation.icosphere(subdivisions=0)
    faces = np.asarray(icosahedron.faces, np.int64)
    vertices = np.asarray(icosahedron.vertices) * 0.05
    labels = np.full(len(faces), -1, np.int64)
    atlas = build_atlas(vertices, faces, labels, face_neighbours(faces), [camera_above(0, 1)],
                        max_size=MAX_SIZE)
    lowest = faces.min(axis=1)
    claimed = atlas.face_index >= 0
    assert claimed.sum() == len(np.unique(lowest))
    for r, c in zip(*np.nonzero(claimed)):
        face = atlas.face_index[r, c]
        # The texel reads its cell's vertex alone.
        assert atlas.barycentric[r, c] @ vertices[faces[face]] == pytest.approx(
            vertices[lowest[face]])
        sharing = lowest == lowest[face]
        assert np.abs(atlas.corners[sharing] - [c, r]).max() <= 1e-9
    # The faces of a cell are one chart: their shared corners are one vertex each.
    assert len(np.unique(atlas.chart)) == len(np.unique(lowest))
