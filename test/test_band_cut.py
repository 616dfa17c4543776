"""The band's graph cut against OpenCV's GrabCut with the same frozen colour models.

:func:`band_cut` builds GrabCut's energy over the undecided pixels alone; its minimum cut
must be the one ``cv2.grabCut(..., 1, GC_EVAL_FREEZE_MODEL)`` finds over the whole
image, where the sure pixels are nodes too. The pictures are soft-edged, noisy discs
and a shaded blob on a graded backdrop, so the band holds pixels each way and a
smoothness that matters.
"""

import cv2
import numpy as np
import pytest

from sfs_ros.core.segmentation.band_cut import band_cut, gmm_likelihood, grabcut_beta

from painted import painted


def _picture(seed: int, h: int = 150, w: int = 190) -> tuple[np.ndarray, np.ndarray]:
    """(h, w, 3) uint8 picture and (h, w) bool truth: a shaded ellipse with a bite out of
    it, blurred edge, on a graded noisy backdrop."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = ((xx - 95) / 60) ** 2 + ((yy - 75) / 45) ** 2 < 1
    truth &= np.hypot(xx - 140, yy - 50) > 18
    return painted(truth, seed), truth


def _band_labels(truth: np.ndarray, reach: int) -> np.ndarray:
    """Sure object / backdrop away from the outline, undecided within ``reach`` of it:
    probable object inside, probable backdrop outside."""
    square = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    t = truth.astype(np.uint8)
    band = (cv2.dilate(t, square) > 0) & (cv2.erode(t, square) == 0)
    labels = np.where(truth, cv2.GC_FGD, cv2.GC_BGD).astype(np.uint8)
    labels[band & truth] = cv2.GC_PR_FGD
    labels[band & ~truth] = cv2.GC_PR_BGD
    return labels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_band_is_cut_as_grabcut_cuts_the_whole_image(seed):
    image, truth = _picture(seed)
    # Colour models learnt by GrabCut itself from a loose start.
    start = _band_labels(truth, 8)
    models = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)
    cv2.grabCut(image, start.copy(), None, *models, 2, cv2.GC_INIT_WITH_MASK)
    labels = _band_labels(truth, 4)
    expected = labels.copy()
    cv2.grabCut(image, expected, None, models[0].copy(), models[1].copy(), 1,
                cv2.GC_EVAL_FREEZE_MODEL)
    got = labels.copy()
    band_cut(image, got, models)
    decided = (labels == cv2.GC_PR_FGD) | (labels == cv2.GC_PR_BGD)
    assert np.count_nonzero(expected[decided] != labels[decided]) > 20   # the cut moved pixels
    # Equal cuts could be told apart differently; none has come up in these pictures.
    assert np.array_equal(got, expected)


def test_sure_pixels_stay_and_nothing_undecided_is_left_alone():
    image, truth = _picture(3)
    labels = np.where(truth, cv2.GC_FGD, cv2.GC_BGD).astype(np.uint8)
    models = np.zeros((1, 65)), np.zeros((1, 65))
    before = labels.copy()
    band_cut(image, labels, models)   # no undecided pixel: the models are never read
    assert np.array_equal(labels, before)


def test_grabcut_beta_and_the_mixture_density_in_closed_form():
    # Two pixels of colours 0 and 10 (each channel): GrabCut's count of neighbour pairs,
    # 4 w h - 3 w - 3 h + 2, is 1 for a 1 x 2 image, and its squared difference 300.
    image = np.array([[[0, 0, 0], [10, 10, 10]]], np.uint8)
    assert grabcut_beta(image) == pytest.approx(1.0 / (2.0 * 300.0))
    assert grabcut_beta(np.zeros((4, 4, 3), np.uint8)) == 0.0
    # One component of weight 1, mean 10, identity covariance: exp(-|d|^2 / 2).
    model = np.zeros(65)
    model[0] = 1.0
    model[5:8] = 10.0
    model[20:29] = np.eye(3).ravel()
    colours = np.array([[10.0, 10.0, 10.0], [11.0, 10.0, 12.0]])
    assert gmm_likelihood(model[None], colours) == pytest.approx([1.0, np.exp(-2.5)])
