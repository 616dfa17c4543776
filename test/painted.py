"""A picture for the graph cuts' tests: an object painted on a backdrop."""

import cv2
import numpy as np


def painted(truth: np.ndarray, seed: int) -> np.ndarray:
    """(h, w, 3) uint8: the object ``truth`` (h, w) bool shaded left to right, its edge
    blurred, on a graded backdrop, with noise of ``seed``."""
    rng = np.random.default_rng(seed)
    h, w = truth.shape
    xx = np.mgrid[0:h, 0:w][1].astype(np.float64)
    image = np.empty((h, w, 3))
    image[:] = (30.0, 35.0, 40.0)
    image += (xx / w * 40.0)[..., None]
    shade = 0.5 + 0.5 * xx / w
    image[truth] = np.array([170.0, 120.0, 80.0]) * shade[truth, None]
    image = cv2.GaussianBlur(image, (5, 5), 1.2)
    image += rng.normal(0.0, 6.0, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
