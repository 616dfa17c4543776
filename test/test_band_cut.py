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

from sfs_ros.core.segmentation.band_cut import band_cut, frozen_data_term, grabcut_beta

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


def _mixture(weights, means, covariances) -> np.ndarray:
    """A (1, 65) GrabCut model from 5 weights, 5 x 3 means and 5 x 3 x 3 covariances."""
    return np.concatenate([np.ravel(weights), np.ravel(means), np.ravel(covariances)])[None]


def _density(model: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """The mixture's density at (n, 3) colours, as written (without (2 pi)^-3/2)."""
    model = model.ravel()
    weights, means, covs = model[:5], model[5:20].reshape(5, 3), model[20:65].reshape(5, 3, 3)
    out = np.zeros(len(colours))
    for k in np.flatnonzero(weights > 0):
        diff = colours - means[k]
        mahalanobis = np.einsum("ni,ij,nj->n", diff, np.linalg.inv(covs[k]), diff)
        out += weights[k] / np.sqrt(np.linalg.det(covs[k])) * np.exp(-0.5 * mahalanobis)
    return out


def test_grabcut_beta_and_the_data_term_in_closed_form():
    # Two pixels of colours 0 and 10 (each channel): GrabCut's count of neighbour pairs,
    # 4 w h - 3 w - 3 h + 2, is 1 for a 1 x 2 image, and its squared difference 300.
    image = np.array([[[0, 0, 0], [10, 10, 10]]], np.uint8)
    assert grabcut_beta(image) == pytest.approx(1.0 / (2.0 * 300.0))
    assert grabcut_beta(np.zeros((4, 4, 3), np.uint8)) == 0.0
    # One component each, identity covariances, the backdrop's mean at 0 and the object's
    # at 10: -log P(c | backdrop) + log P(c | object) = (|c|^2 - |c - 10|^2) / 2.
    eye = np.tile(np.eye(3), (5, 1, 1))
    one = np.array([1.0, 0, 0, 0, 0])
    backdrop = _mixture(one, np.zeros((5, 3)), eye)
    thing = _mixture(one, np.full((5, 3), 10.0), eye)
    colours = np.array([[10, 10, 10], [11, 10, 12], [0, 0, 0], [5, 5, 5]], np.uint8)
    c = colours.astype(np.float64)
    expected = 0.5 * ((c ** 2).sum(axis=1) - ((c - 10) ** 2).sum(axis=1))
    assert frozen_data_term((backdrop, thing), colours) == pytest.approx(expected, abs=1e-9)
    # A colour a model gives no probability at all (its density underflows): past any
    # finite weight, towards the other side; neither: no pull.
    far = np.array([[255, 255, 255]], np.uint8)
    narrow = _mixture(one, np.zeros((5, 3)), eye * 1e-2)
    wide = _mixture(one, np.zeros((5, 3)), eye * 1e4)
    assert frozen_data_term((narrow, wide), far)[0] == 1e300
    assert frozen_data_term((wide, narrow), far)[0] == -1e300
    assert frozen_data_term((narrow, narrow), far)[0] == 0.0


def test_the_data_term_is_the_mixtures_densities():
    # Five components each, learnt by GrabCut on a picture, at every colour of it.
    image, truth = _picture(4)
    models = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)
    cv2.grabCut(image, _band_labels(truth, 8), None, *models, 2, cv2.GC_INIT_WITH_MASK)
    colours = image.reshape(-1, 3)
    expected = -np.log(_density(models[0], colours.astype(np.float64))) \
        + np.log(_density(models[1], colours.astype(np.float64)))
    assert np.count_nonzero(models[0][0, :5] > 0) == 5
    np.testing.assert_allclose(frozen_data_term(models, colours), expected, rtol=1e-9, atol=1e-9)
