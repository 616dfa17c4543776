"""Removing the small parts of a carved hull, against scipy's 26-connected labelling."""

import numpy as np
import pytest
from scipy import ndimage

from sfs_ros.core.carving.hull import column_runs, drop_specks


def reference(occupancy, min_fraction):
    """The parts by :func:`scipy.ndimage.label` (26 neighbours), the small ones removed."""
    labels, n = ndimage.label(occupancy, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return occupancy, 0
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    keep = sizes >= min_fraction * sizes.max()
    keep[0] = False
    return keep[labels], int(n - keep[1:].sum())


@pytest.mark.parametrize("density", [0.02, 0.1, 0.25, 0.35, 0.6])
@pytest.mark.parametrize("shape", [(17, 23, 29), (1, 40, 40), (40, 1, 3), (9, 9, 1)])
def test_parts_as_scipy_labels_them(density, shape):
    # Sparse random voxels touch mostly through edges and corners, dense ones form a
    # few large parts: both ways of meeting are exercised, and every part's size counts.
    rng = np.random.default_rng(int(density * 100) + sum(shape))
    occupancy = rng.random(shape) < density
    for min_fraction in (0.0, 0.01, 0.2, 0.9, 1.0):
        cleaned, removed = drop_specks(occupancy, min_fraction=min_fraction)
        expected, expected_removed = reference(occupancy, min_fraction)
        np.testing.assert_array_equal(cleaned, expected)
        assert removed == expected_removed


def test_a_block_and_its_specks():
    occupancy = np.zeros((30, 30, 30), bool)
    occupancy[5:20, 5:20, 5:20] = True          # 3375 voxels
    occupancy[25, 25, 25] = True                # a speck
    occupancy[20, 20, 20] = True                # meets the block's corner (19, 19, 19): kept
    occupancy[0:3, 27:30, 0:3] = True           # 27 voxels: 0.8 % of the largest
    cleaned, removed = drop_specks(occupancy)
    truth = occupancy.copy()
    truth[25, 25, 25] = False
    truth[0:3, 27:30, 0:3] = False
    np.testing.assert_array_equal(cleaned, truth)
    assert removed == 2
    # one part, or none: the occupancy comes back as it is
    for alone in (truth, np.zeros((4, 5, 6), bool)):
        assert drop_specks(alone) == (alone, 0)
    with pytest.raises(ValueError, match="min_fraction"):
        drop_specks(occupancy, min_fraction=1.5)


def runs_written_out(occupancy):
    """``column_runs`` of a 3-D bool array, each column's runs read off with numpy: where
    the column, padded with an empty voxel each end, steps up and down."""
    nx, ny, nz = occupancy.shape
    starts, lows, highs = [0], [], []
    for column in occupancy.reshape(nx * ny, nz):
        step = np.diff(np.concatenate([[0], column.astype(np.int8), [0]]))
        up, down = np.flatnonzero(step == 1), np.flatnonzero(step == -1) - 1
        starts.append(starts[-1] + len(up))
        lows += up.tolist()
        highs += down.tolist()
    return np.array(starts), np.array(lows, np.int64), np.array(highs, np.int64)


@pytest.mark.parametrize("shape", [(5, 6, 7), (8, 3, 20), (1, 1, 1), (4, 4, 2), (3, 4, 0)])
def test_the_columns_runs_as_numpy_reads_them(shape):
    # Every density from none to full, so runs start and end at the columns' ends and
    # in between; a Fortran-ordered and a reversed view read as the array they show.
    rng = np.random.default_rng(sum(shape))
    for density in (0.0, 0.3, 0.7, 1.0):
        occupancy = rng.random(shape) < density
        for seen in (occupancy, np.asfortranarray(occupancy), occupancy[:, ::-1]):
            for got, expected in zip(column_runs(seen), runs_written_out(seen)):
                np.testing.assert_array_equal(got, expected)
