"""Segmentation presets by capture setting: plain data, which a command line's help reads
without loading the segmentation itself (OpenCV, numba)."""

__all__ = ["PRESETS"]

# Threshold-method parameters per capture setting (plain dicts:
# ``SegmentationParams.from_dict``), kept to reproduce earlier results; the
# default graph cut needs none of them.
PRESETS: dict[str, dict] = {
    # Studio backdrops, the paper's setting: automatic threshold, colour distance.
    "white-background": {"method": "threshold", "background": "white"},
    "black-background": {"method": "threshold", "background": "black"},
    # Middlebury dino: white matte object on black; dark shadows on the object
    # are recovered by hysteresis (weak pixels up to 12 px from lit ones) and
    # a wide closing (the dataset's own recipe closes by 7 px).
    "middlebury-dino": {"method": "threshold", "background": "black", "background_model": "constant",
                        "threshold": 0.2, "weak_ratio": 0.4, "grow_px": 12,
                        "close_px": 7, "dilate_px": 1},
    # Middlebury temple: beige object, dark warm-grey cloth behind part of it
    # (up to ~0.3 of full scale). Colour counts four times brightness (the
    # shaded temple is saturated yellow-brown, the cloth nearly grey); the sure
    # threshold sits above the cloth and weak growth is short.
    "middlebury-temple": {"method": "threshold", "background": "black", "background_model": "constant",
                          "threshold": 0.35, "weak_ratio": 0.7, "grow_px": 6,
                          "chroma_weight": 4.0, "close_px": 7, "dilate_px": 1},
}
