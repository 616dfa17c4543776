"""Our GrabCut and k-means against OpenCV's: the same labels, bit for bit.

:func:`grabcut` promises ``cv2.grabCut(..., GC_INIT_WITH_MASK)``'s labels: the same
k-means start from the same random generator, the same colour models and the same
minimum cut. Each case runs both from the same seed of OpenCV's generator. The
pictures: a shaded, soft-edged blob with a bite out of it on a graded noisy backdrop
(a smoothness that matters, colours each way), a posterised one (a handful of colours:
covariances GrabCut must widen), a flat one (no contrast at all) and labels that leave
a side fewer pixels than GrabCut has Gaussians.
"""

import cv2
import numpy as np
import pytest

from sfs_ros.core.segmentation.grabcut import grabcut
from sfs_ros.core.segmentation.kmeans import OpenCVRandom, distinct_colours, kmeans_colours

from painted import painted


def _picture(seed: int, h: int = 90, w: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(h, w, 3) uint8 picture and (h, w) bool truth: a shaded ellipse with a bite out of
    it, blurred edge, on a graded noisy backdrop."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = ((xx - w / 2) / (0.3 * w)) ** 2 + ((yy - h / 2) / (0.3 * h)) ** 2 < 1
    truth &= np.hypot(xx - 0.7 * w, yy - 0.35 * h) > 0.1 * w
    return painted(truth, seed), truth


def _loose_labels(truth: np.ndarray, seed: int) -> np.ndarray:
    """A start as loose as the segmentation's: the frame sure backdrop, a widened guess
    probable object, the rest probable backdrop, a few sure object pixels."""
    rng = np.random.default_rng(seed)
    guess = cv2.dilate(truth.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    labels = np.where(guess, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    labels[:3] = labels[-3:] = labels[:, :3] = labels[:, -3:] = cv2.GC_BGD
    inside = np.argwhere(cv2.erode(truth.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
    for y, x in inside[rng.choice(len(inside), 5, replace=False)]:
        labels[y, x] = cv2.GC_FGD
    return labels


def _both(image: np.ndarray, labels: np.ndarray, iterations: int, seed: int):
    """(OpenCV's labels, ours) from the same start and the same seed; the colour models
    must be OpenCV's too."""
    theirs, ours = labels.copy(), labels.copy()
    models = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(seed)
    cv2.grabCut(image, theirs, None, *models, iterations, cv2.GC_INIT_WITH_MASK)
    our_models = grabcut(image, ours, iterations, OpenCVRandom(seed))
    for model, ours_model in zip(models, our_models):
        assert np.array_equal(ours_model, model)
    return theirs, ours


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("iterations", [1, 4])
def test_the_labels_are_opencvs(seed, iterations):
    image, truth = _picture(seed)
    theirs, ours = _both(image, _loose_labels(truth, seed), iterations, seed)
    assert np.array_equal(ours, theirs)
    # Not a trivial agreement: the cut decided the outline, and close to the truth.
    chosen = (ours == cv2.GC_PR_FGD) | (ours == cv2.GC_FGD)
    assert (chosen & truth).sum() / (chosen | truth).sum() > 0.9


def test_a_posterised_picture_widens_its_covariances_as_opencv_does():
    image, truth = _picture(4)
    image = (image // 64) * 64  # a handful of colours: some Gaussians hold a single colour
    theirs, ours = _both(image, _loose_labels(truth, 4), 4, 4)
    assert np.array_equal(ours, theirs)


def test_a_flat_picture_and_a_side_of_three_pixels():
    flat = np.full((40, 50, 3), 90, np.uint8)
    labels = np.full((40, 50), cv2.GC_PR_BGD, np.uint8)
    labels[20, 20:23] = cv2.GC_PR_FGD  # three object pixels: k-means with 3 clusters
    theirs, ours = _both(flat, labels, 2, 5)
    assert np.array_equal(ours, theirs)
    image, truth = _picture(6, 40, 50)
    theirs, ours = _both(image, labels, 3, 6)
    assert np.array_equal(ours, theirs)


def test_labels_without_both_sides_are_refused():
    image, _ = _picture(7, 20, 20)
    with pytest.raises(ValueError, match="both backdrop and object"):
        grabcut(image, np.full((20, 20), cv2.GC_PR_BGD, np.uint8), 1, OpenCVRandom())
    with pytest.raises(ValueError, match=r"\(h, w, 3\) uint8 image"):
        grabcut(image[..., 0], np.full((20, 20), cv2.GC_PR_BGD, np.uint8), 1, OpenCVRandom())


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("k, criteria", [(5, (cv2.TERM_CRITERIA_MAX_ITER, 10, 0.0)),
                                         (6, (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER,
                                              20, 0.5)),
                                         (1, (cv2.TERM_CRITERIA_MAX_ITER, 10, 0.0))])
def test_the_kmeans_is_opencvs_and_draws_as_much(seed, k, criteria):
    """Our k-means against ``cv2.kmeans`` (k-means++ start, one attempt) on a picture's
    colours, twice in a row from one seed: the same labels, so the same draws too."""
    image, _ = _picture(seed)
    pixels = image.reshape(-1, 3)
    random = OpenCVRandom(seed)
    cv2.setRNGSeed(seed)
    for samples in (pixels[::3], pixels[1::2]):
        _, theirs, _ = cv2.kmeans(samples.astype(np.float32), k, None, criteria, 1,
                                  cv2.KMEANS_PP_CENTERS)
        colours, colour_of = distinct_colours(np.ascontiguousarray(samples))
        eps = criteria[2] if criteria[0] & cv2.TERM_CRITERIA_EPS else None
        ours = kmeans_colours(colours, colour_of, k, random, max_iterations=criteria[1],
                              epsilon=eps)
        assert np.array_equal(ours, theirs.ravel())


def _kmeans_both(samples: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) labels of (n, 3) uint8 ``samples`` in ``k`` clusters by ``cv2.kmeans`` (k-means++,
    10 iterations) and by ours, both drawing from a generator seeded with ``seed``."""
    cv2.setRNGSeed(seed)
    _, theirs, _ = cv2.kmeans(samples.astype(np.float32), k, None,
                              (cv2.TERM_CRITERIA_MAX_ITER, 10, 0.0), 1, cv2.KMEANS_PP_CENTERS)
    colours, colour_of = distinct_colours(samples)
    return theirs.ravel(), kmeans_colours(colours, colour_of, k, OpenCVRandom(seed),
                                          max_iterations=10)


def test_the_kmeans_sums_past_single_precision_as_opencv_does():
    """200 000 samples of 230..255 in two clusters: one holds at least 100 000, its sums
    of a channel pass 2^24, where OpenCV's single-precision sums round; ours sum such a
    cluster sample by sample as it does: the same labels."""
    rng = np.random.default_rng(7)
    samples = rng.integers(230, 256, (200_000, 3), dtype=np.uint8)
    for seed in range(3):
        theirs, ours = _kmeans_both(samples, 2, seed)
        assert np.array_equal(ours, theirs)


def test_an_emptied_cluster_is_refilled_as_opencv_does():
    """Three colours for five clusters: k-means++ draws a colour twice, one of the two
    clusters stays empty and takes the farthest sample of the largest."""
    samples = np.full((400, 3), 90, np.uint8)
    samples[::7] = (10, 20, 30)
    samples[::11] = (200, 10, 10)
    for seed in range(6):
        theirs, ours = _kmeans_both(samples, 5, seed)
        assert np.array_equal(ours, theirs)
        # Five clusters out of three colours: some colour is split, as OpenCV splits it.
        assert len(np.unique(ours)) == 5
