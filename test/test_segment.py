"""Segmentation on synthetic captures with a known ground-truth silhouette.

Most tests here check the threshold method's own steps (background field,
hysteresis, connectivity test, holes); the default graph cut is scored on the
hostile cell in ``test_segment_scene.py``.
"""

import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from sfs_ros.core.segmentation.segment import (
    PRESETS,
    Segmentation,
    SegmentationParams,
    _enclosed_patches,
    estimate_background,
    segment,
)

#: The threshold method, whose steps these tests check one by one.
THRESHOLD = "threshold"

H, W = 240, 320
# The object: an ellipse with a large hole (a handle: real, must stay open) and
# a small hole (a blemish: must be filled).
CENTRE = (150.0, 120.0)          # (x, y) pixels
AXES = (80.0, 62.0)              # semi-axes, pixels
BIG_HOLE = ((185.0, 118.0), 20.0)     # centre, radius: ~1250 px, ~8 % of the object
SMALL_HOLE = ((110.0, 100.0), 3.0)    # ~29 px, ~0.2 % of the object
FILL_FRACTION = 0.01                  # holes under 1 % of the object area are filled

# Tolerances. Edges are hard (no anti-aliasing) and the noise is small against
# the contrast, so the mask may differ from the truth only in a 1-pixel band
# along the outline (the opening/closing radius). Outline ~ 2*pi*(71 + 20)
# ~ 570 px against ~14 000 px of object: IoU >= 1 - 570 / 14 000 ~ 0.96.
IOU_MIN = 0.95
BAND_PX = 1
# Background: within 3 grey levels of the truth (noise sigma 4 averaged over
# thousands of border pixels; the gradient is what the estimate must absorb).
BACKGROUND_TOL = 3.0


def _disk(shape, centre, radius):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius ** 2


def ground_truth(shape=(H, W), centre=CENTRE):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    body = ((xx - centre[0]) / AXES[0]) ** 2 + ((yy - centre[1]) / AXES[1]) ** 2 <= 1
    dx, dy = centre[0] - CENTRE[0], centre[1] - CENTRE[1]
    big = _disk(shape, (BIG_HOLE[0][0] + dx, BIG_HOLE[0][1] + dy), BIG_HOLE[1])
    small = _disk(shape, (SMALL_HOLE[0][0] + dx, SMALL_HOLE[0][1] + dy), SMALL_HOLE[1])
    return body & ~big & ~small, body & ~big  # truth as seen, truth after filling


def render(background, *, object_rgb=(200, 120, 60), shade=(0.35, 1.0), gradient=12.0,
           noise=4.0, specks=True, centre=CENTRE, shape=(H, W), seed=0):
    """A shaded object on a background with a gentle gradient + vignetting, noise and specks.

    Returns (image uint8 (H, W, 3), true background field (H, W, 3) float64, truth mask).
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = ((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2
    sign = 1.0 if np.mean(background) < 128 else -1.0  # the gradient stays inside 0..255
    field = np.asarray(background, np.float64) + sign * gradient * (
        0.5 * (xx / w) + 0.5 * (1 - 2 * r2))[..., None]
    image = field.copy()
    truth, _ = ground_truth(shape, centre)
    # Lambert-like shading: dark on the left, lit on the right.
    light = np.clip((xx - (centre[0] - AXES[0])) / (2 * AXES[0]), 0, 1)
    level = shade[0] + (shade[1] - shade[0]) * light
    image[truth] = (np.asarray(object_rgb, np.float64) * level[truth, None])
    if specks:
        for x, y, s in ((20, 20, 3), (290, 30, 4), (40, 200, 5), (300, 215, 2), (260, 180, 3)):
            image[y:y + s, x:x + s] = 255 - np.asarray(background)
    image += rng.normal(0, noise, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8), field, truth


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def within_band(mask, truth, band=BAND_PX):
    """Pixels of ``mask`` / ``truth`` farther than ``band`` from the other's outline."""
    return (int((mask & ~binary_dilation(truth, iterations=band)).sum()),
            int((truth & ~binary_dilation(mask, iterations=band)).sum()))


@pytest.mark.parametrize("background, object_rgb, shade", [
    ((245, 245, 240), (200, 120, 60), (0.3, 1.0)),   # white: dark faces are easy, ...
    ((240, 240, 245), (150, 150, 150), (0.4, 1.3)),  # ... light faces approach the backdrop
    ((12, 10, 14), (220, 215, 200), (0.25, 1.0)),    # black: dark faces approach the backdrop
])
@pytest.mark.parametrize("model", ["constant", "smooth"])
def test_mask_matches_truth(background, object_rgb, shade, model):
    image, _, _ = render(background, object_rgb=object_rgb, shade=shade)
    _, filled_truth = ground_truth()
    params = SegmentationParams(method=THRESHOLD,
                                background_model=model, fill_holes_max_fraction=FILL_FRACTION,
                                dilate_px=0)
    result = segment(image, params)
    assert isinstance(result, Segmentation)
    assert result.mask.dtype == bool and result.mask.shape == (H, W)
    assert not result.empty and not result.touches_border
    assert iou(result.mask, filled_truth) > IOU_MIN
    extra, missing = within_band(result.mask, filled_truth)
    assert extra == 0 and missing == 0
    assert result.n_blobs_removed >= 1   # the larger specks survive the opening
    assert result.holes_filled == 1      # the small hole, never the big one
    big_hole = _disk((H, W), BIG_HOLE[0], BIG_HOLE[1] - BAND_PX - 0.5)  # inside the band
    assert not result.mask[big_hole].any()
    assert result.foreground_fraction == pytest.approx(result.mask.mean())


@pytest.mark.parametrize("background", [(245, 245, 240), (12, 10, 14)])
def test_background_estimate(background):
    image, field, _ = render(background)
    smooth = segment(image, SegmentationParams(method=THRESHOLD, background_model="smooth"))
    # The smooth model reports the mean of its field: the mean of the true field.
    np.testing.assert_allclose(smooth.background_rgb, field.reshape(-1, 3).mean(axis=0),
                               atol=BACKGROUND_TOL)
    # The constant model reports the border mode: within the border's spread.
    border = np.concatenate([field[0], field[-1], field[:, 0], field[:, -1]])
    constant = estimate_background(image)
    assert np.all(constant >= border.min(axis=0) - BACKGROUND_TOL)
    assert np.all(constant <= border.max(axis=0) + BACKGROUND_TOL)


def test_smooth_background_absorbs_strong_vignetting():
    # A 60-level vignette on a white backdrop (the corners at ~190, the centre
    # at 240) against a flat grey object 0.2-0.3 below the local backdrop: a
    # single background colour calls the dark corners object, the fitted
    # quadratic field does not.
    image, _, _ = render((240, 240, 240), object_rgb=(150, 150, 150), shade=(0.9, 1.0),
                         gradient=60.0)
    _, filled_truth = ground_truth()
    params = dict(fill_holes_max_fraction=FILL_FRACTION, dilate_px=0)
    smooth = segment(image, SegmentationParams(method=THRESHOLD, background_model="smooth", **params))
    constant = segment(image, SegmentationParams(method=THRESHOLD, background_model="constant", **params))
    assert iou(smooth.mask, filled_truth) > IOU_MIN
    assert within_band(smooth.mask, filled_truth) == (0, 0)
    assert iou(constant.mask, filled_truth) < 0.9


def test_background_estimate_survives_object_on_the_border():
    # The object covers a third of the top edge: the border mode ignores it.
    image, _, _ = render((245, 245, 240), centre=(150.0, 40.0), gradient=0.0, specks=False)
    np.testing.assert_allclose(estimate_background(image), (245, 245, 240), atol=BACKGROUND_TOL)
    result = segment(image, SegmentationParams(method=THRESHOLD, dilate_px=0))
    truth, _ = ground_truth(centre=(150.0, 40.0))
    assert result.touches_border
    assert iou(result.mask, truth) > IOU_MIN


def test_white_and_black_hints_and_given_colour():
    image, _, _ = render((245, 245, 240), gradient=0.0)
    np.testing.assert_allclose(estimate_background(image, background="white"), (245, 245, 240),
                               atol=BACKGROUND_TOL)
    given = segment(image, SegmentationParams(method=THRESHOLD, background=(245, 245, 240)))
    np.testing.assert_array_equal(given.background_rgb, (245, 245, 240))
    # Told "black", a white-backdrop image has no dark border pixels: black is assumed
    # and the whole frame is "object" touching the border.
    black = segment(image, SegmentationParams(method=THRESHOLD,
                                              background="black", background_model="constant"))
    assert black.touches_border and black.foreground_fraction > 0.9


def test_hysteresis_keeps_shadows_connected_to_the_object_only():
    # Black backdrop; the object's shaded left part (0.12 of full scale) is
    # below the sure threshold (0.3), above the weak one (0.09). A separate
    # dim patch at the same level is not connected to anything sure.
    image = np.full((H, W, 3), 10, np.uint8)
    image[80:160, 60:120] = 40     # shadowed part of the object
    image[80:160, 120:220] = 200   # lit part
    image[20:50, 250:300] = 40     # dim patch elsewhere
    strong_only = segment(image, SegmentationParams(method=THRESHOLD,
                                                    threshold=0.3, weak_ratio=1.0, dilate_px=0))
    hysteresis = segment(image, SegmentationParams(method=THRESHOLD,
                                                   threshold=0.3, weak_ratio=0.3, grow_px=None,
                                                   dilate_px=0))
    limited = segment(image, SegmentationParams(method=THRESHOLD, threshold=0.3, weak_ratio=0.3, grow_px=10,
                                                dilate_px=0))
    assert strong_only.mask[80:160, 60:120].sum() == 0
    # (Interiors: the opening rounds the corners of the rectangles.)
    assert hysteresis.mask[81:159, 61:219].all()
    assert not hysteresis.mask[20:50, 250:300].any()
    # Limited growth stops 10 px into the shadow.
    assert limited.mask[81:159, 110:120].all() and not limited.mask[80:160, 60:108].any()


def test_keep_largest_only_and_min_blob_fraction():
    image = np.full((H, W, 3), 250, np.uint8)
    image[40:140, 40:140] = 30     # 10 000 px
    image[160:200, 200:240] = 30   # 1 600 px: 16 % of the largest
    params = dict(dilate_px=0, open_px=0, background_model="constant")
    both = segment(image, SegmentationParams(method=THRESHOLD, min_blob_fraction=0.1, **params))
    largest = segment(image, SegmentationParams(method=THRESHOLD, keep_largest_only=True, **params))
    strict = segment(image, SegmentationParams(method=THRESHOLD, min_blob_fraction=0.2, **params))
    assert both.mask.sum() == 11600 and both.n_blobs_removed == 0
    assert largest.mask.sum() == 10000 and largest.n_blobs_removed == 1
    assert strict.mask.sum() == 10000 and strict.n_blobs_removed == 1


def test_dilation_is_conservative():
    image, _, _ = render((12, 10, 14), object_rgb=(220, 215, 200))
    _, filled_truth = ground_truth()
    mask = segment(image, SegmentationParams(method=THRESHOLD,
                                             dilate_px=2, fill_holes_max_fraction=FILL_FRACTION)).mask
    assert mask[filled_truth].all()   # one-sided: the truth is inside the dilated mask
    extra, _ = within_band(mask, filled_truth, band=3)
    assert extra == 0


def test_graph_cut_opens_an_enclosed_hole_on_a_plain_backdrop():
    # Noise-free, on black: every label is decided but the handle's hole, backdrop
    # colour enclosed by object, which the cut must decide (in a window around the
    # object). The hole stays open; the outline within the 1-pixel band.
    image, _, _ = render((12, 12, 12), object_rgb=(200, 200, 200), noise=0.0)
    mask = segment(image).mask
    _, filled_truth = ground_truth()
    assert iou(mask, filled_truth) > IOU_MIN
    assert not mask[_disk((H, W), BIG_HOLE[0], BIG_HOLE[1] - BAND_PX - 0.5)].any()


def test_enclosed_patches_are_backdrop_colours_ringed_by_object_colours():
    """A patch of a backdrop colour is enclosed when it misses the frame and more than
    half its outline is object colour; one of ``_SPECK_PX`` pixels or more is a guess."""
    far = np.zeros((30, 40), bool)                   # object colours
    nearest = np.zeros((30, 40), np.int64)           # each pixel's backdrop colour
    edge = np.zeros((30, 40), bool)
    edge[:2], edge[-2:], edge[:, :2], edge[:, -2:] = True, True, True, True
    far[5:20, 5:20] = True
    far[9:14, 9:14] = False                          # a hole of colour 0 in an object
    nearest[24:27, 30:33] = 1                        # colour 1 on open backdrop of colour 0
    far[5:8, 30:33] = True
    far[6, 31] = False                               # a one-pixel hole: a speck
    enclosed, guessed = _enclosed_patches(nearest, far, 2, edge)
    expected = np.zeros((30, 40), bool)
    expected[9:14, 9:14] = expected[6, 31] = True
    np.testing.assert_array_equal(enclosed, expected)
    assert guessed
    far[9:14, 9:14] = True                           # the speck alone is no guess
    enclosed, guessed = _enclosed_patches(nearest, far, 2, edge)
    assert enclosed.sum() == 1 and not guessed


def test_grey_input_matches_rgb():
    image, _, _ = render((12, 12, 12), object_rgb=(200, 200, 200), noise=0.0)
    grey = image[:, :, 0]
    np.testing.assert_array_equal(segment(grey).mask, segment(np.dstack([grey] * 3)).mask)


@pytest.mark.parametrize("image", [
    np.zeros((H, W, 3), np.uint8),
    np.full((H, W, 3), 255, np.uint8),
    np.clip(np.random.default_rng(1).normal(128, 4, (H, W, 3)), 0, 255).astype(np.uint8),
])
def test_no_object_is_empty_not_an_error(image):
    result = segment(image)
    assert result.empty and not result.mask.any()
    assert result.foreground_fraction == 0.0 and not result.touches_border


@pytest.mark.parametrize("image, words", [
    (np.zeros((H, W, 3), np.float32), "dtype float32"),
    (np.zeros((H, W, 3), np.uint16), "dtype uint16"),
    (np.zeros((H, W, 2), np.uint8), "shape (240, 320, 2)"),
    (np.zeros((H * W,), np.uint8), "shape (76800,)"),
    (np.zeros((4, 4), np.uint8), "at least 8x8"),
])
def test_bad_images_are_rejected(image, words):
    with pytest.raises(ValueError, match="expected|must") as info:
        segment(image)
    assert words in str(info.value)


@pytest.mark.parametrize("values, words", [
    ({"background": "grey"}, "background"),
    ({"background": (255, 255)}, "3 values"),
    ({"background": (0, 0, 300)}, "0..255"),
    ({"background_model": "spline"}, "background_model"),
    ({"threshold": 0.0}, "threshold"),
    ({"threshold": 1.5}, "threshold"),
    ({"threshold_range": (0.5, 0.1)}, "threshold_range"),
    ({"weak_ratio": 0.0}, "weak_ratio"),
    ({"grow_px": -1}, "grow_px"),
    ({"grow_px": 2.5}, "grow_px"),
    ({"chroma_weight": -1.0}, "chroma_weight"),
    ({"close_px": -2}, "close_px"),
    ({"open_px": True}, "open_px"),
    ({"min_blob_fraction": 1.5}, "min_blob_fraction"),
    ({"fill_holes_max_fraction": -0.1}, "fill_holes_max_fraction"),
    ({"min_area_fraction": 1.0}, "min_area_fraction"),
    ({"border_fraction": 0.5}, "border_fraction"),
    ({"keep_largest_only": "yes"}, "keep_largest_only"),
    ({"method": "otsu"}, "method"),
    ({"object_sigma": 0.0}, "object_sigma"),
    ({"close_fraction": 0.5}, "close_fraction"),
    ({"ignore_alpha": 1}, "ignore_alpha"),
    ({"alpha_threshold": 255}, "alpha_threshold"),
])
def test_bad_params_are_rejected(values, words):
    with pytest.raises(ValueError, match=words):
        SegmentationParams(**values)


def test_from_dict():
    params = SegmentationParams.from_dict({"background": [10, 20, 30], "threshold": 0.2,
                                           "threshold_range": [0.1, 0.3]})
    assert params.background == (10, 20, 30) and params.threshold_range == (0.1, 0.3)
    assert params.method == "threshold"  # threshold options without a method keep their meaning
    assert SegmentationParams.from_dict({"dilate_px": 1}).method == "graph-cut"
    assert SegmentationParams.from_dict({"method": "graph-cut", "threshold": 0.2}).method \
        == "graph-cut"
    with pytest.raises(ValueError, match="unknown segmentation parameter.*'thresh'"):
        SegmentationParams.from_dict({"thresh": 0.2})
    with pytest.raises(ValueError, match="dict"):
        SegmentationParams.from_dict([("threshold", 0.2)])
    for name, values in PRESETS.items():
        assert isinstance(SegmentationParams.from_dict(values), SegmentationParams), name
    with pytest.raises(ValueError, match="SegmentationParams"):
        segment(np.zeros((H, W), np.uint8), {"threshold": 0.2})


def test_graph_cut_runs_only_where_something_is_left_to_decide(monkeypatch):
    import sfs_ros.core.segmentation.segment as seg

    cuts = []
    real = seg.grabcut

    def counted(*args):
        cuts.append(1)
        return real(*args)

    monkeypatch.setattr(seg, "grabcut", counted)
    # A plain ellipse, strongly coloured, on a flat white backdrop: every pixel is either
    # far from the backdrop or sure backdrop, so the first labels are the answer.
    yy, xx = np.mgrid[0:H, 0:W]
    body = ((xx - CENTRE[0]) / AXES[0]) ** 2 + ((yy - CENTRE[1]) / AXES[1]) ** 2 <= 1
    image = np.full((H, W, 3), 245.0)
    image[body] = (200, 120, 60)
    image = np.clip(np.rint(image + np.random.default_rng(0).normal(0, 4.0, image.shape)),
                    0, 255).astype(np.uint8)
    skipped = segment(image).mask
    assert cuts == []
    monkeypatch.setattr(seg, "_DECIDED_FRACTION", -1.0)  # never decided: always cut
    cut = segment(image).mask
    # The cut changes at most 0.1 % of the object's pixels here (measured: 7 of 15 600,
    # single pixels on the outline): skipping it loses nothing.
    assert cuts == [1] and np.count_nonzero(cut ^ skipped) <= 1e-3 * body.sum()
    monkeypatch.setattr(seg, "_DECIDED_FRACTION", 0.02)
    cuts.clear()
    # With a handle's hole, backdrop enclosed by the object and started as object, the
    # first labels hold a guess: the cut is asked.
    image, _, _ = render((245, 245, 240), specks=False, gradient=0.0)
    segment(image)
    assert cuts == [1]


@pytest.mark.parametrize("shape", [(800, 800), (480, 640), (101, 57), (9, 9), (5, 30), (3, 3)])
@pytest.mark.parametrize("fraction", [0.0, 0.02, 0.3, 0.5])
def test_the_backdrop_band_is_read_in_the_order_of_its_mask(shape, fraction):
    # The backdrop clusters sample every n-th band pixel, so the band's pixels must come
    # in the order of the full-image mask's indexing, exactly (random colours: any
    # misplaced pixel shows).
    from sfs_ros.core.segmentation.backdrop import _band_pixels, border_band

    image = np.random.default_rng(1).integers(0, 256, (*shape, 3), dtype=np.uint8)
    np.testing.assert_array_equal(_band_pixels(image, fraction),
                                  image[border_band(*shape, fraction)])


def test_backdrop_distance_is_the_smallest_mahalanobis_distance():
    # Closed form in float64 against the float32 kernels: r^T A r for r up to 255 grey
    # levels and A up to 1/16 (the 4-level noise floor) is below 1.3e4; float32 keeps
    # about 7 digits, so 1e-5 relative plus 1e-3 of a standard deviation bounds the
    # rounding of a handful of operations.
    from sfs_ros.core.segmentation.backdrop import BackdropModel

    rng = np.random.default_rng(7)
    means = rng.uniform(0, 255, (4, 3))
    roots = rng.normal(0, 0.1, (4, 3, 3))
    inverses = roots @ roots.transpose(0, 2, 1) + np.eye(3) / 400.0  # symmetric, positive
    model = BackdropModel(means, inverses)
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    r = image.reshape(-1, 1, 3).astype(np.float64) - model.means.astype(np.float64)
    squared = np.einsum("nki,kij,nkj->nk", r, model.inverse_covariances.astype(np.float64), r)
    truth = np.sqrt(squared.min(axis=1)).reshape(37, 53)
    distance = model.distance(image)
    assert distance.shape == (37, 53) and distance.dtype == np.float32
    np.testing.assert_allclose(distance, truth, rtol=1e-5, atol=1e-3)
    nearest, index = model.nearest(image)
    np.testing.assert_allclose(nearest, truth, rtol=1e-5, atol=1e-3)
    ordered = np.sort(squared, axis=1)
    clear = (ordered[:, 1] - ordered[:, 0] > 1e-3 * ordered[:, 1]).reshape(37, 53)
    assert clear.mean() > 0.9
    np.testing.assert_array_equal(index[clear], squared.argmin(axis=1).reshape(37, 53)[clear])
    # (n, 3) pixels and a strided view read the same colours
    np.testing.assert_array_equal(model.distance(image.reshape(-1, 3)), distance.ravel())
    np.testing.assert_array_equal(model.distance(image[:, ::2]), distance[:, ::2])


def random_blobs(shape, seed):
    """(H, W) uint8 0/1: a few random discs and bars, some reaching the image's edges and
    corners (where the closing reads the edge pixels repeated), on an empty frame."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    mask = np.zeros(shape, bool)
    for _ in range(4):
        cx, cy = rng.uniform(-5, w + 5), rng.uniform(-5, h + 5)
        mask |= np.hypot(xx - cx, yy - cy) < rng.uniform(2, 12)
    x0, y0 = rng.integers(0, w - 3), rng.integers(0, h - 3)
    mask[y0:y0 + rng.integers(1, 4), x0:] = True          # a bar out to the right edge
    mask &= rng.random(shape) > 0.05                       # pin-holes and cracks to close
    return mask.astype(np.uint8)


@pytest.mark.parametrize("seed", range(12))
def test_close_mask_on_its_box_is_the_whole_frames_closing(seed):
    # The definition: the whole frame extended by its edge pixels, closed with a disk,
    # cut back. The box version must give every pixel the same value.
    import cv2

    from sfs_ros.core.segmentation.segment import close_mask

    shape = (37 + seed, 53 + 2 * seed)
    mask = random_blobs(shape, seed)
    for radius in range(0, 7):
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        padded = cv2.copyMakeBorder(mask, radius, radius, radius, radius, cv2.BORDER_REPLICATE)
        whole = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, k)[radius:radius + shape[0],
                                                              radius:radius + shape[1]]
        np.testing.assert_array_equal(close_mask(mask, radius), whole, err_msg=f"radius {radius}")
    empty = np.zeros(shape, np.uint8)
    np.testing.assert_array_equal(close_mask(empty, 3), empty)


@pytest.mark.parametrize("seed", range(12))
def test_band_redecided_on_its_box_is_the_whole_frames(seed):
    # The definition: the pixels within ``reach`` (a square) of the outline, found on the
    # whole frame, take ``distance > _EDGE_SIGMA``; the rest keep their value.
    import cv2

    from sfs_ros.core.segmentation.segment import _EDGE_SIGMA, _redecide_band

    shape = (41 + seed, 47 + 3 * seed)
    mask = random_blobs(shape, seed)
    distance = np.random.default_rng(seed).uniform(0, 3, shape).astype(np.float32)
    for reach in (1, 2, 4):
        square = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
        band = (cv2.dilate(mask, square) > 0) & (cv2.erode(mask, square) == 0)
        expected = mask.copy()
        expected[band] = distance[band] > _EDGE_SIGMA
        ours = mask.copy()
        _redecide_band(ours, distance, reach)
        np.testing.assert_array_equal(ours, expected, err_msg=f"reach {reach}")
