"""Lewiner's marching cubes over the band (``lewiner.march_band``) against scikit-image's:
the same vertices and faces, in the same order, as ``measure.marching_cubes(volume, 0,
allow_degenerate=False, mask=...)`` visiting the cubes with a corner in the band, each
vertex then moved onto its grid edge's crossing by a search of the band's voxels (the
reference below: scikit-image's output, placed independently of the kernel)."""

import numpy as np
import pytest
from skimage import measure

from sfs_ros.core.meshing.lewiner import march_band
from sfs_ros.core.meshing.marching import (
    _CROSSING_MARGIN,
    band_voxel_indices,
    crossing_edges,
    crossing_ends,
)
from sfs_ros.core.meshing.mesh_checks import check_mesh

PAD = 2.0


def dense_volume(crop, voxels, distance, pad=PAD):
    """The volume the band stands for, written out: the negated ``distance`` at the band's
    ``voxels``, ``pad`` where ``crop`` is occupied off it, ``-pad`` elsewhere (float32)."""
    volume = np.where(crop, np.float32(pad), np.float32(-pad)).astype(np.float32)
    volume[tuple(np.asarray(voxels).T)] = -np.asarray(distance, np.float32)
    return volume


def band_mask(shape, voxels):
    """scikit-image's mask of the cubes with a corner in the band: it visits the cube of
    corners ``p .. p + 1`` when the mask holds at ``p + 1``."""
    cubes = np.zeros(shape, bool)
    for d in np.ndindex(2, 2, 2):
        ahead = voxels + d
        ahead = ahead[np.all(ahead < shape, axis=1)]
        cubes[tuple(ahead.T)] = True
    return cubes


def placed_on_crossings(verts, shape, voxels, ordinal, crossings):
    """scikit-image's float32 vertices (n, 3), each one lying on a grid edge (one
    coordinate further than 1e-4 from an integer, the others nearer) moved to the edge's
    crossing, found by a binary search of the band's voxels at the edge's lower end (the
    edge ahead of it), else at its upper end (the edge behind it)."""
    keys = np.ravel_multi_index(tuple(voxels.T), shape)
    out = verts.astype(np.float64)
    nearest = np.round(out)
    off = np.abs(out - nearest)
    axis = np.argmax(off, axis=1)
    rows = np.arange(len(out))
    on_edge = (off[rows, axis] > 1e-4) & (np.sort(off, axis=1)[:, 1] < 1e-4)
    lower = nearest.astype(np.int64)
    lower[rows, axis] = np.floor(out[rows, axis]).astype(np.int64)
    on_edge &= np.all(lower >= 0, axis=1) & np.all(lower < np.array(shape) - 1, axis=1)
    which = np.full(len(out), -1, np.int64)
    for end, column in ((0, axis), (1, axis + 3)):
        voxel = np.where(on_edge[:, None], lower, 0)
        voxel[rows, axis] += end
        key = np.ravel_multi_index(tuple(voxel.T), shape)
        at = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
        found = on_edge & (which < 0) & (keys[at] == key)
        which[found] = ordinal[at[found], column[found]]
    moved = which >= 0
    fraction = np.clip(crossings[which[moved]].astype(np.float64), _CROSSING_MARGIN,
                       1.0 - _CROSSING_MARGIN)
    out[rows[moved], axis[moved]] = lower[rows[moved], axis[moved]] + fraction
    return out


def reference(crop, voxels, distance, crossings):
    """scikit-image's mesh of the band's volume (the negated ``distance`` at the band's
    voxels, ``+-PAD`` by ``crop`` off it), placed on ``crossings`` (None: as it is)."""
    volume = dense_volume(crop, voxels, distance)
    verts, faces, _, _ = measure.marching_cubes(volume, 0.0, allow_degenerate=False,
                                                mask=band_mask(crop.shape, voxels))
    if crossings is None:
        return verts.astype(np.float64), faces.astype(np.int64)
    ordinal, _ = crossing_edges(crop, voxels, distance)
    return placed_on_crossings(verts, crop.shape, voxels, ordinal, crossings), faces


def ours(crop, voxels, distance, crossings, slabs):
    ordinal = None
    if crossings is not None:
        ordinal, _ = crossing_edges(crop, voxels, distance)
    return march_band(crop, PAD, voxels, -distance, ordinal, crossings,
                      margin=_CROSSING_MARGIN, slabs=slabs)


def assert_same_mesh(crop, voxels, distance, crossings=None, slabs=1):
    got = ours(crop, voxels, distance, crossings, slabs)
    try:
        expected = reference(crop, voxels, distance, crossings)
    except RuntimeError:    # scikit-image's "no surface found" (none in the band's cubes)
        assert len(got[0]) == 0 and got[1].shape == (0, 3)
        return got
    for a, b in zip(expected, got):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    return got


def cube_patterns(volume, cubes):
    """The sign patterns (Lewiner's case index: bit c set where corner c is above 0) of
    the cubes scikit-image visits under the mask ``cubes``."""
    n0, n1, n2 = volume.shape
    index = np.zeros((n0 - 1, n1 - 1, n2 - 1), np.int64)
    for c, (di, dj, dk) in enumerate([(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0),
                                      (1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0)]):
        index |= (volume[di:n0 - 1 + di, dj:n1 - 1 + dj, dk:n2 - 1 + dk] > 0).astype(int) << c
    return set(index[cubes[1:, 1:, 1:]].tolist())


def crossings_for(crop, voxels, distance, rng):
    _, m = crossing_edges(crop, voxels, distance)
    return rng.random(m).astype(np.float32)


@pytest.mark.parametrize("seed", range(6))
def test_random_volumes_and_bands_give_scikit_images_mesh(seed):
    # Random signs and values make every sign pattern of a cube occur (and so every case
    # of Lewiner's and its ambiguity tests); random bands make the mask cut cubes
    # anywhere; values of exactly +-1, 0 or 1e-6 (ties in the ambiguity tests; vertices
    # on a corner: degenerate faces merged and dropped).
    rng = np.random.default_rng(seed)
    faces = 0
    patterns = set()
    for trial in range(40):
        shape = tuple(int(n) for n in rng.integers(2, 13, 3))
        crop = rng.random(shape) < rng.uniform(0.2, 0.8)
        voxels = np.argwhere(rng.random(shape) < rng.uniform(0.1, 1.0))
        n = len(voxels)
        distance = [rng.uniform(-PAD, PAD, n), rng.integers(-2, 3, n).astype(float),
                    np.where(rng.random(n) < 0.3, [1e-6, 1e-9][trial % 2],
                             rng.uniform(-PAD, PAD, n))][trial % 3]
        distance = distance.astype(np.float32)
        volume = dense_volume(crop, voxels, distance)
        if volume.min() >= 0 or volume.max() <= 0:
            continue    # no surface
        patterns |= cube_patterns(volume, band_mask(shape, voxels))
        crossings = crossings_for(crop, voxels, distance, rng) if trial % 2 else None
        slabs = 1 + trial % 4       # marched in slabs side by side: the same mesh
        faces += len(assert_same_mesh(crop, voxels, distance, crossings, slabs)[1])
    assert faces > 10_000
    assert len(patterns) == 256


def test_degenerate_faces_are_dropped_as_scikit_image_drops_them():
    # A corner at 1e-9 puts the vertices of its edges on it in float32: faces collapse.
    rng = np.random.default_rng(7)
    crop = rng.random((10, 11, 12)) < 0.5
    voxels = np.argwhere(np.ones(crop.shape, bool))
    distance = np.where(rng.random(len(voxels)) < 0.4, 1e-9,
                        rng.uniform(-PAD, PAD, len(voxels))).astype(np.float32)
    volume = dense_volume(crop, voxels, distance)
    kept = measure.marching_cubes(volume, 0.0, allow_degenerate=False)[1]
    every = measure.marching_cubes(volume, 0.0, allow_degenerate=True)[1]
    assert len(kept) < len(every)
    assert_same_mesh(crop, voxels, distance, crossings_for(crop, voxels, distance, rng))


def ball(shape, radius, centre):
    """Signed distance (voxels, positive outside) to a ball, and the voxels inside."""
    ijk = np.indices(shape).reshape(3, -1).T
    distance = (np.linalg.norm(ijk - centre, axis=1) - radius).reshape(shape)
    return distance.astype(np.float32), distance <= 0


@pytest.mark.parametrize("band", [1, 2])
def test_a_ball_in_its_band_is_scikit_images_mesh_and_closed(band):
    # As the hull mesher builds it: the band of the occupancy's boundary, the distance
    # there, the occupancy's sign off it; crossings placed on the edges the level crosses.
    distance, inside = ball((40, 37, 43), 14.3, np.array([19.2, 18.1, 21.7]))
    voxels = band_voxel_indices(inside, band)
    values = np.clip(distance[tuple(voxels.T)], -PAD, PAD)
    values[values == 0] = np.float32(1e-6)
    rng = np.random.default_rng(band)
    for crossings, slabs in ((None, 1), (crossings_for(inside, voxels, values, rng), 1),
                             (crossings_for(inside, voxels, values, rng), 7)):
        vertices, faces = assert_same_mesh(inside, voxels, values, crossings, slabs)
        report = check_mesh(vertices, faces)
        assert report.watertight and report.vertex_manifold, report
        assert report.consistently_oriented and report.n_components == 1, report
        assert report.genus == 0, report


def test_an_object_filling_the_crop_to_its_edge():
    # Band voxels on the crop's last planes: the cubes there are the last ones.
    rng = np.random.default_rng(3)
    crop = np.zeros((6, 7, 8), bool)
    crop[1:, 2:, :] = True
    voxels = band_voxel_indices(crop, 1)
    values = rng.uniform(-1.5, 1.5, len(voxels)).astype(np.float32)
    assert_same_mesh(crop, voxels, values, crossings_for(crop, voxels, values, rng))


def numbered_crossings(crop, voxels, distance):
    """:func:`crossing_edges` written out on the dense volume: each band voxel's edges
    ahead along i, j, k, then behind (those whose lower end is off the band), numbered in
    turn where the ends' signs differ."""
    inside = dense_volume(crop, voxels, distance) > 0
    in_band = np.zeros(crop.shape, bool)
    in_band[tuple(voxels.T)] = True
    ordinal = np.full((len(voxels), 6), -1, np.int64)
    m = 0
    for n, p in enumerate(voxels):
        for s in range(6):
            q = p.copy()
            q[s % 3] += 1 if s < 3 else -1
            if np.any(q < 0) or np.any(q >= crop.shape) or (s >= 3 and in_band[tuple(q)]):
                continue
            if inside[tuple(q)] != inside[tuple(p)]:
                ordinal[n, s] = m
                m += 1
    return ordinal, m


def random_band(rng, *, max_side: int):
    """A random crop (sides 2 to ``max_side``, half occupied), a random band of its voxels
    and distances at them in ``[-PAD, PAD]``, a tenth exactly 0 (float32)."""
    shape = tuple(int(n) for n in rng.integers(2, max_side + 1, 3))
    crop = rng.random(shape) < 0.5
    voxels = np.argwhere(rng.random(shape) < rng.uniform(0.2, 1.0))
    distance = np.where(rng.random(len(voxels)) < 0.1, 0.0,
                        rng.uniform(-PAD, PAD, len(voxels))).astype(np.float32)
    return crop, voxels, distance


@pytest.mark.parametrize("seed", range(3))
def test_crossing_edges_are_numbered_as_on_the_dense_volume(seed):
    rng = np.random.default_rng(seed)
    for _ in range(10):
        crop, voxels, distance = random_band(rng, max_side=9)
        ordinal, m = crossing_edges(crop, voxels, distance)
        expected, expected_m = numbered_crossings(crop, voxels, distance)
        assert m == expected_m
        np.testing.assert_array_equal(ordinal, expected)


@pytest.mark.parametrize("seed", range(3))
def test_crossing_ends_are_the_dense_volumes_at_the_numbered_edges(seed):
    # Each crossing's two ends, in the crossings' order, and the distance there: the band's
    # value, the occupancy's sign (+-pad) off it, as the dense volume holds them.
    rng = np.random.default_rng(10 + seed)
    crossed = 0
    for trial in range(12):
        crop, voxels, distance = random_band(rng, max_side=10)
        pad = [PAD, 3.0][trial % 2]
        numbers = np.full((len(voxels), 6), -7, np.int32)
        lower, upper, at_lower, at_upper = crossing_ends(crop, voxels, distance, pad,
                                                         ordinal=numbers)
        ordinal, m = numbered_crossings(crop, voxels, distance)
        np.testing.assert_array_equal(numbers, ordinal)     # numbered in the same pass
        volume = dense_volume(crop, voxels, distance, pad)
        assert lower.shape == upper.shape == (m, 3) and at_lower.shape == at_upper.shape == (m,)
        assert at_lower.dtype == at_upper.dtype == np.float32
        expected_lower = np.empty((m, 3), np.int64)
        expected_upper = np.empty((m, 3), np.int64)
        for n, s in zip(*np.nonzero(ordinal >= 0)):
            step = np.eye(3, dtype=np.int64)[s % 3]
            ends = (voxels[n], voxels[n] + step) if s < 3 else (voxels[n] - step, voxels[n])
            expected_lower[ordinal[n, s]], expected_upper[ordinal[n, s]] = ends
        np.testing.assert_array_equal(lower, expected_lower)
        np.testing.assert_array_equal(upper, expected_upper)
        np.testing.assert_array_equal(at_lower, -volume[tuple(expected_lower.T)])
        np.testing.assert_array_equal(at_upper, -volume[tuple(expected_upper.T)])
        assert np.all((at_lower < 0) != (at_upper < 0))
        crossed += m
    assert crossed > 500
