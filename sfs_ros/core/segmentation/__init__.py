"""Segmentation: the object's silhouette in each image.

* :mod:`.segment`: one image's mask, by a graph cut on a backdrop model (the default) or
  a threshold;
* :mod:`.backdrop`: the backdrop's colour clusters, learnt from the image border, and
  from the borders of all of a scan's views;
* :mod:`.grabcut` and :mod:`.kmeans`: OpenCV's GrabCut and k-means, the same results bit
  for bit, for less work;
* :mod:`.consensus`: a view cut again with the hull of all views as its prior;
* :mod:`.presets`: the threshold method's settings by capture setting (plain data).

Names are imported on first use (:mod:`..lazy_exports`); the function ``segment`` is
taken from its module, :func:`.segment.segment` (the module shares its name)."""

from ..lazy_exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    ".backdrop": ("BackdropModel", "band_samples", "border_band", "fit_backdrop",
                  "fit_scan_backdrop"),
    ".consensus": ("Consensus", "consensus_masks", "resegment", "settled"),
    ".presets": ("PRESETS",),
    ".segment": ("Segmentation", "SegmentationParams", "estimate_background"),
})
