"""The backdrop of a whole scan: a plate wholly in one view's frame is backdrop there, the
object reaching another view's frame is not, drawn scenes with exact object masks."""

import cv2
import numpy as np

from sfs_ros.core.metrics import silhouette_iou
from sfs_ros.core.segmentation.backdrop import (
    band_samples,
    fit_backdrop,
    fit_scan_backdrop,
)
from sfs_ros.core.segmentation.segment import SegmentationParams, scan_backdrop_changes, segment

BLACK, PLATE, CLAY = (8, 8, 10), (128, 128, 134), (205, 160, 110)
SIGMA = 3.0  # the graph cut's sure-backdrop distance, the reach used for "one colour"
#: Beyond this distance from the backdrop a pixel starts as probable object.
OBJECT_SIGMA = SegmentationParams().object_sigma


def view(plate_centre, plate_axes, object_box, seed, size=(240, 320)):
    """An (H, W, 3) uint8 picture of a clay block on a grey elliptic plate before a black
    backdrop (noise 2 grey levels) and the block's exact (H, W) bool mask."""
    image = np.zeros((*size, 3), np.uint8)
    image[:] = BLACK
    cv2.ellipse(image, plate_centre, plate_axes, 0, 0, 360, PLATE, -1)
    x0, y0, x1, y1 = object_box
    image[y0:y1, x0:x1] = CLAY
    noisy = image + np.random.default_rng(seed).normal(0, 2.0, image.shape)
    mask = np.zeros(size, bool)
    mask[y0:y1, x0:x1] = True
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8), mask


def scan():
    """Eight views: six with the plate reaching the bottom of the frame, one seeing it
    wholly in the frame (from low down: a thin ellipse), one with the block cut by the
    right edge of the frame."""
    views = [view((160, 230), (200, 80), (130, 60, 190, 200), seed) for seed in range(6)]
    views.append(view((160, 170), (110, 25), (135, 70, 185, 175), 6))    # plate in frame
    views.append(view((160, 230), (200, 80), (250, 40, 320, 200), 7))    # block out of frame
    return views


def test_the_scan_backdrop_holds_the_plate_and_not_the_object():
    views = scan()
    model = fit_scan_backdrop([band_samples(image) for image, _ in views])
    near = model.distance(np.array([BLACK, PLATE, CLAY], np.uint8))
    assert near[0] < SIGMA and near[1] < SIGMA
    assert near[2] > OBJECT_SIGMA   # the block's colour reaches the frame of one view in eight


def test_a_plate_wholly_in_the_frame_is_backdrop():
    views = scan()
    samples = [band_samples(image) for image, _ in views]
    model = fit_scan_backdrop(samples)
    image, truth = views[6]
    own = fit_backdrop(samples=samples[6])
    assert own.distance(np.array([PLATE], np.uint8))[0] > OBJECT_SIGMA   # its border: black
    assert scan_backdrop_changes(samples[6], model)
    alone = silhouette_iou(segment(image).mask, truth)
    together = silhouette_iou(segment(image, scan_backdrop=model).mask, truth)
    # Alone the plate is object (block 50 x 105 px, plate ellipse about 8 600 px); with
    # the scan's backdrop the mask is the block's to a pixel along its outline (IoU of a
    # 50 x 105 block with one a pixel smaller all round: 0.94).
    assert alone < 0.5
    assert together > 0.94


def test_the_object_at_the_frame_is_left_out_of_that_views_backdrop():
    views = scan()
    samples = [band_samples(image) for image, _ in views]
    model = fit_scan_backdrop(samples)
    image, truth = views[7]
    own = fit_backdrop(samples=samples[7])
    adapted = own.adapted_to(model, samples[7], SIGMA, OBJECT_SIGMA)
    clay = np.array([CLAY], np.uint8)
    assert own.distance(clay)[0] < SIGMA             # the block holds over a tenth of its band
    assert adapted.distance(clay)[0] > OBJECT_SIGMA
    assert silhouette_iou(segment(image, scan_backdrop=model).mask, truth) > 0.94


def test_views_that_agree_with_the_scan_are_segmented_as_alone():
    views = scan()
    samples = [band_samples(image) for image, _ in views]
    model = fit_scan_backdrop(samples)
    for image, _ in views[:6]:
        assert not scan_backdrop_changes(band_samples(image), model)
        assert np.array_equal(segment(image).mask, segment(image, scan_backdrop=model).mask)


def test_a_colour_the_border_shows_a_little_of_is_not_added():
    # A dark cloth reaching the frame by 3 % of the border band, too little to be one of
    # the view's clusters (it keeps those that hold 90 %), is a colour the view saw: the
    # scan's cluster of it is not added (only a colour the border does not reach is).
    cloth = (40, 36, 44)
    views = scan()
    image = views[0][0].copy()
    image[:40, :12] = cloth
    image[:10, :40] = cloth
    samples = band_samples(image)
    others = [band_samples(np.where(np.arange(320)[None, :, None] < 60, cloth, v).astype(np.uint8))
              for v, _ in views[:6]]
    model = fit_scan_backdrop(others)
    assert model.distance(np.array([cloth], np.uint8))[0] < SIGMA
    own = fit_backdrop(samples=samples)
    assert own.distance(np.array([cloth], np.uint8))[0] > SIGMA
    added = own.adapted_to(model, samples, SIGMA, OBJECT_SIGMA)
    assert added.distance(np.array([cloth], np.uint8))[0] > SIGMA


def test_the_segmentation_keeps_the_model_its_border_gives():
    # The check of whether the scan's backdrop changes a view reuses the model the view's
    # segmentation learnt: the one its border's samples give, so the check's answer stands.
    views = scan()
    model = fit_scan_backdrop([band_samples(image) for image, _ in views])
    for image, _ in views:
        samples = band_samples(image)
        own = segment(image).border_backdrop
        again = fit_backdrop(samples=samples)
        assert np.array_equal(own.means, again.means)
        assert np.array_equal(own.inverse_covariances, again.inverse_covariances)
        assert scan_backdrop_changes(samples, model, own=own) \
            == scan_backdrop_changes(samples, model)
    assert segment(views[0][0], SegmentationParams(method="threshold")).border_backdrop is None
