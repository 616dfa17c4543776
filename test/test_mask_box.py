"""The box of a mask's foreground (:func:`sfs_ros.core.mask_box.foreground_box`)."""

import numpy as np

from sfs_ros.core.mask_box import foreground_box


def _mask(*pixels: tuple[int, int], shape=(40, 60)) -> np.ndarray:
    mask = np.zeros(shape, bool)
    for row, col in pixels:
        mask[row, col] = True
    return mask


def test_the_box_spans_the_first_and_last_rows_and_columns_set():
    assert foreground_box(_mask((5, 20), (12, 7), (9, 33))) == (slice(5, 13), slice(7, 34))


def test_the_box_of_several_masks_holds_the_pixels_of_each():
    box = foreground_box(_mask((5, 20)), _mask((30, 2)), _mask())
    assert box == (slice(5, 31), slice(2, 21))


def test_a_margin_widens_the_box_and_the_frame_clips_it():
    assert foreground_box(_mask((1, 58), (20, 30)), margin_px=3) == (slice(0, 24), slice(27, 60))


def test_empty_masks_have_no_box():
    assert foreground_box(_mask(), _mask()) is None


def test_the_box_has_plain_int_bounds():
    rows, cols = foreground_box(_mask((3, 4)), margin_px=1)
    assert all(type(v) is int for v in (rows.start, rows.stop, cols.start, cols.stop))
