"""Segmentation speed per image (800x800, as NeRF synthetic views, 1024x1024 and 1280x800).

The image: a shaded object with a hole on a backdrop with a gentle gradient,
vignetting, noise and specks (white and black backdrops). Baseline: a plain
fixed threshold on the largest channel difference to a known background (one
numpy expression, no estimation, morphology or connectivity test), measured
in the same run. Ratio = baseline / ours (below 1: ours does more work).
The default (graph cut) is also timed against decoding the same image from a
PNG file in memory, the work every view costs anyway, and, where the Middlebury rings
are beside the repository (``../shared/datasets/middlebury``), on their photographs
against ``cv2.imread`` of each (the time per photograph, each ring best of the repeats).

Run: ``python -m bench.bench_segment`` (``--quick`` for fewer repeats).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sfs_ros.core.segmentation.segment import PRESETS, SegmentationParams, segment

from .timing import best_of, main

SIZES = ((800, 800), (1024, 1024), (1280, 800))  # (width, height)
MIDDLEBURY = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "middlebury"
RINGS = ("dinoSparseRing", "templeSparseRing")
BACKDROPS = {"white": (240, 240, 235), "black": (12, 10, 14)}


def synthetic_image(width: int, height: int, backdrop, seed: int = 0) -> np.ndarray:
    """(height, width, 3) uint8: shaded ellipse with a hole on a graded, noisy backdrop."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    u, v = xx / width - 0.5, yy / height - 0.5
    sign = 1.0 if np.mean(backdrop) < 128 else -1.0
    image = np.asarray(backdrop, np.float32) + sign * 15 * (0.5 * u + 0.5 - (u * u + v * v))[..., None]
    body = (u / 0.3) ** 2 + (v / 0.25) ** 2 <= 1
    hole = ((u - 0.1) / 0.06) ** 2 + (v / 0.06) ** 2 <= 1
    obj = body & ~hole
    shade = 0.3 + 0.7 * np.clip((u + 0.3) / 0.6, 0, 1)
    image[obj] = np.array([210, 170, 120], np.float32) * shade[obj, None]
    for x, y in rng.integers(0, min(width, height), (20, 2)):
        image[y:y + 4, x:x + 4] = 255 - np.asarray(backdrop, np.float32)
    image += rng.normal(0, 3, image.shape).astype(np.float32)
    return np.clip(image, 0, 255).astype(np.uint8)


def plain_threshold(image: np.ndarray, background, threshold: float) -> np.ndarray:
    """The baseline: largest channel difference to a known background above a fixed threshold."""
    diff = np.abs(image.astype(np.int16) - np.asarray(background, np.int16)).max(axis=2)
    return diff > threshold * 255


def run(quick: bool = False) -> list[dict]:
    repeats = 3 if quick else 7
    configs = [("default (graph cut)", {}),
               ("threshold method", {"method": "threshold"}),
               ("middlebury-dino preset", PRESETS["middlebury-dino"]),
               ("middlebury-temple preset", PRESETS["middlebury-temple"])]
    rows = []
    for width, height in SIZES:
        for backdrop_name, backdrop in BACKDROPS.items():
            image = synthetic_image(width, height, backdrop)
            baseline = best_of(lambda: plain_threshold(image, backdrop, 0.2), repeats)
            png = cv2.imencode(".png", image)[1]
            decode = best_of(lambda: cv2.imdecode(png, cv2.IMREAD_UNCHANGED), repeats)
            seconds = best_of(lambda: segment(image), repeats)
            rows.append({"name": f"segment {width}x{height} {backdrop_name}: default vs PNG decode",
                         "seconds": seconds, "baseline_seconds": decode, "ratio": decode / seconds})
            for label, values in configs:
                if backdrop_name == "white" and label.startswith("middlebury"):
                    continue  # the Middlebury presets assume a black backdrop
                params = SegmentationParams.from_dict(values)
                seconds = best_of(lambda: segment(image, params), repeats)
                rows.append({"name": f"segment {width}x{height} {backdrop_name}: {label}",
                             "seconds": seconds, "baseline_seconds": baseline,
                             "ratio": baseline / seconds})
    return rows + middlebury_rows(repeats)


def middlebury_rows(repeats: int) -> list[dict]:
    """The default on each Middlebury ring's photographs against decoding them: seconds
    per photograph; a note instead where the rings are absent."""
    rows = []
    for ring in RINGS:
        files = sorted((MIDDLEBURY / ring).glob("*.png"))
        if not files:
            rows.append({"name": f"segment Middlebury {ring}: not found", "seconds": 0.0,
                         "baseline_seconds": None, "ratio": None,
                         "notes": [f"no photographs under {MIDDLEBURY / ring}: row skipped"]})
            continue
        images = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
        decode = best_of(lambda: [cv2.imread(str(f)) for f in files], repeats) / len(files)
        seconds = best_of(lambda: [segment(image) for image in images], repeats) / len(files)
        rows.append({"name": f"segment {ring} ({len(files)} photos): default vs imread, each",
                     "seconds": seconds, "baseline_seconds": decode, "ratio": decode / seconds})
    return rows


if __name__ == "__main__":
    main(__doc__, run, quick_help="fewer repeats")
