"""A contact sheet of a scan session: every view at a glance, bad ones marked.

One tile per view, in input order, row by row. A tile holds the view's image
scaled to ``tile_px`` wide with the outline of its silhouette mask drawn on it
(green, every contour: holes such as a handle's too), and a label band: the
view name, the encoder angles theta and phi in degrees, and the silhouette IoU
of the mesh reprojected into the view. A view whose IoU is below ``bad_iou`` or
unknown, or that was rejected, gets a red frame, a pink label band and its IoU
or reason in red; good views a grey frame. A header line counts them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real
from pathlib import Path

import cv2
import numpy as np

from ..exchange.files import write_atomic
from ..workers import map_in_threads
from .preview import png_bytes

__all__ = ["OUTLINE_RGB", "WARNING_RGB", "FRAME_RGB", "BACKGROUND_RGB", "SheetLayout",
           "contact_sheet", "write_contact_sheet"]

OUTLINE_RGB = (0, 230, 0)        #: mask outline
WARNING_RGB = (220, 0, 0)        #: frame and text of a bad view
FRAME_RGB = (190, 190, 190)      #: frame of a good view
BACKGROUND_RGB = (255, 255, 255)  #: sheet, label band of a good view, letterboxing
_BAD_BAND_RGB = (255, 225, 225)  # label band of a bad view
_TEXT_RGB = (20, 20, 20)
_NO_IMAGE_RGB = (150, 150, 150)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _fit(text: str, width_px: int, scale: float) -> str:
    """``text`` in ASCII (Hershey fonts have no other glyphs), cut with '...' to ``width_px``."""
    text = text.encode("ascii", "replace").decode("ascii")
    if cv2.getTextSize(text, _FONT, scale, 1)[0][0] <= width_px:
        return text
    while text and cv2.getTextSize(text + "...", _FONT, scale, 1)[0][0] > width_px:
        text = text[:-1]
    return text + "..."


def _wrap(text: str, width_px: int, scale: float, lines: int) -> list[str]:
    """``text`` broken at spaces into at most ``lines`` lines of ``width_px``, the last cut."""
    out, words = [], text.split()
    while words and len(out) < lines - 1:
        n = len(words)
        while n > 1 and cv2.getTextSize(" ".join(words[:n]), _FONT, scale, 1)[0][0] > width_px:
            n -= 1
        out.append(" ".join(words[:n]))
        words = words[n:]
    return out + [" ".join(words)] if words else out


def _fits(mask_shape: tuple, image_shape: tuple) -> bool:
    """Whether a mask of ``mask_shape`` (H, W) outlines an image of ``image_shape``: the same
    size, or the image scaled down from it (the same aspect to within a pixel)."""
    (mh, mw), (ih, iw) = mask_shape[:2], image_shape
    return len(mask_shape) == 2 and ih <= mh and abs(iw * mh - mw * ih) <= mh


def _check_view(i: int, name: str, image, mask, angles, iou, reason) -> tuple:
    """One view's entries, validated: (image, mask, angles, iou, reason)."""
    where = f"view {i} ({name!r})"
    if image is not None:
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
            raise ValueError(f"{where}: image must be (H, W, 3) uint8 RGB or None, got "
                             f"shape {image.shape} dtype {image.dtype}")
    if mask is not None:
        mask = np.asarray(mask)
        if image is None or mask.dtype != bool or not _fits(mask.shape, image.shape[:2]):
            raise ValueError(f"{where}: mask must be None or (H, W) bool of its image's size "
                             f"{None if image is None else image.shape[:2]} (or of the image "
                             f"it was scaled down from), got shape {mask.shape} dtype "
                             f"{mask.dtype}")
    if angles is not None:
        angles = tuple(angles)
        if len(angles) != 2 or not all(isinstance(a, Real) and math.isfinite(a) for a in angles):
            raise ValueError(f"{where}: angles must be None or (theta_rad, phi_rad), "
                             f"finite numbers, got {angles!r}")
    if iou is not None and not (isinstance(iou, Real) and 0.0 <= iou <= 1.0):
        raise ValueError(f"{where}: IoU must be None or a number in [0, 1], got {iou!r}")
    if reason is not None and not isinstance(reason, str):
        raise ValueError(f"{where}: rejection reason must be None or a str, got {reason!r}")
    return image, mask, angles, iou, reason


def _check(images, masks, names, angles_rad, ious, rejected, columns, tile_px, bad_iou):
    """Validated lists: names, images, masks, angle pairs, IoUs, reasons."""
    names = [str(n) for n in names]
    if not names:
        raise ValueError("a contact sheet needs at least one view; names is empty")
    per_view = {"images": list(images), "masks": list(masks), "angles_rad": list(angles_rad),
                "ious": list(ious),
                "rejected": [None] * len(names) if rejected is None else list(rejected)}
    for what, values in per_view.items():
        if len(values) != len(names):
            raise ValueError(f"{what} has {len(values)} entries, names has {len(names)}: "
                             f"one per view expected")
    if columns is not None and (isinstance(columns, bool) or not isinstance(columns, int)
                                or columns < 1):
        raise ValueError(f"columns must be None (automatic) or an integer >= 1, got {columns!r}")
    if isinstance(tile_px, bool) or not isinstance(tile_px, int) or tile_px < 64:
        raise ValueError(f"tile_px must be an integer >= 64 pixels, got {tile_px!r}")
    if not (isinstance(bad_iou, Real) and 0.0 <= bad_iou <= 1.0):
        raise ValueError(f"bad_iou must be a number in [0, 1], got {bad_iou!r}")
    views = [_check_view(i, *entries) for i, entries in enumerate(zip(names, *per_view.values()))]
    return (names, *map(list, zip(*views)))


def _thumbnail(image: np.ndarray, mask, box_w: int, box_h: int, thickness: int) -> np.ndarray:
    """(box_h, box_w, 3) uint8: ``image`` scaled to fit, centred, with the outline of ``mask``
    (of the image's size, or of the full image a smaller ``image`` was scaled down from)."""
    h, w = image.shape[:2]
    scale = min(box_w / w, box_h / h)
    tw, th = max(1, round(w * scale)), max(1, round(h * scale))
    thumb = np.ascontiguousarray(cv2.resize(image, (tw, th), interpolation=cv2.INTER_AREA))
    if mask is not None:
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        # Pixel centres map as (x + 0.5) * scale - 0.5; polylines takes 1/16-pixel fixed point.
        mh, mw = mask.shape[:2]
        scaled = [np.round(((c[:, 0] + 0.5) * (tw / mw, th / mh) - 0.5) * 16).astype(np.int32)
                  for c in contours]
        cv2.polylines(thumb, scaled, True, OUTLINE_RGB, thickness, cv2.LINE_8, shift=4)
    box = np.full((box_h, box_w, 3), BACKGROUND_RGB, np.uint8)
    top, left = (box_h - th) // 2, (box_w - tw) // 2
    box[top:top + th, left:left + tw] = thumb
    return box


@dataclass(frozen=True)
class SheetLayout:
    """Pixel geometry of a contact sheet (every length in pixels).

    A header line on top, then ``rows`` x ``columns`` tiles separated by
    ``pad_px``. A tile is a frame ``pad_px`` wide around a thumbnail box
    ``tile_px`` x ``box_h`` above a label band of ``lines`` text lines: name,
    angles, IoU, and two for the reason when any view was rejected.
    """

    n_views: int
    columns: int
    tile_px: int
    box_h: int
    lines: int

    @classmethod
    def of(cls, images, *, columns=None, tile_px: int = 200, any_rejected: bool = False):
        """The layout for ``images`` (sequence of (h, w, 3) arrays or None, one per view).

        The tallest aspect ratio sets ``box_h`` (3/4 of ``tile_px`` when all are None).
        """
        aspects = [im.shape[0] / im.shape[1] for im in images if im is not None]
        return cls(n_views=len(images), columns=columns or math.ceil(math.sqrt(len(images))),
                   tile_px=tile_px, box_h=max(1, round(tile_px * max(aspects, default=0.75))),
                   lines=5 if any_rejected else 3)

    @property
    def rows(self) -> int:
        return math.ceil(self.n_views / self.columns)

    @property
    def font_scale(self) -> float:
        return self.tile_px / 480

    @property
    def pad_px(self) -> int:
        return max(2, self.tile_px // 50)

    @property
    def line_px(self) -> int:
        (_, text_h), base = cv2.getTextSize("Ag", _FONT, self.font_scale, 1)
        return text_h + base + self.pad_px

    @property
    def baseline_px(self) -> int:
        """Height of a text line's baseline below the line's top."""
        base = cv2.getTextSize("Ag", _FONT, self.font_scale, 1)[1]
        return self.line_px - base - self.pad_px // 2

    @property
    def tile_w(self) -> int:
        return self.tile_px + 2 * self.pad_px

    @property
    def tile_h(self) -> int:
        return self.box_h + self.lines * self.line_px + 2 * self.pad_px

    @property
    def header_h(self) -> int:
        return self.line_px + self.pad_px

    @property
    def width(self) -> int:
        return self.pad_px + self.columns * (self.tile_w + self.pad_px)

    @property
    def height(self) -> int:
        return self.header_h + self.pad_px + self.rows * (self.tile_h + self.pad_px)

    def tile_origin(self, k: int) -> tuple[int, int]:
        """``(y, x)`` of the top-left pixel of tile ``k`` (0-based, row by row)."""
        return (self.header_h + self.pad_px + (k // self.columns) * (self.tile_h + self.pad_px),
                self.pad_px + (k % self.columns) * (self.tile_w + self.pad_px))


def _put(lay: SheetLayout, image: np.ndarray, text: str, row: int, rgb, width: int) -> None:
    """Text line ``row`` (0-based) of ``image``, ``lay.pad_px`` from its left edge, cut to
    ``width`` pixels."""
    cv2.putText(image, _fit(text, width, lay.font_scale),
                (lay.pad_px, row * lay.line_px + lay.baseline_px), _FONT, lay.font_scale, rgb,
                1, cv2.LINE_AA)


def _tile(lay: SheetLayout, thumbnail: np.ndarray | None, name: str, angles, iou, reason,
          bad_iou: float) -> np.ndarray:
    """One view's tile (``lay.tile_h``, ``lay.tile_w``, 3) uint8: its thumbnail, framed in
    red when bad, above its name, angles, IoU and the reason it was rejected."""
    pad, tile_px, width = lay.pad_px, lay.tile_px, lay.tile_px - 2 * lay.pad_px
    bad = reason is not None or iou is None or iou < bad_iou
    tile = np.full((lay.tile_h, lay.tile_w, 3), WARNING_RGB if bad else FRAME_RGB, np.uint8)
    box = tile[pad:pad + lay.box_h, pad:pad + tile_px]
    if thumbnail is None:
        box[:] = _NO_IMAGE_RGB
        _put(lay, box, "no image", lay.box_h // (2 * lay.line_px), _TEXT_RGB, width)
    else:
        box[:] = thumbnail
    band = tile[pad + lay.box_h:-pad, pad:-pad]
    band[:] = _BAD_BAND_RGB if bad else BACKGROUND_RGB
    _put(lay, band, name, 0, _TEXT_RGB, width)
    _put(lay, band, "no encoder angles" if angles is None else
         f"theta {math.degrees(angles[0]):.1f}  phi {math.degrees(angles[1]):.1f} deg",
         1, _TEXT_RGB, width)
    figure = "IoU none" if iou is None else f"IoU {iou:.3f}"
    if reason is not None:
        _put(lay, band, f"REJECTED, {figure}", 2, WARNING_RGB, width)
        for row, text in enumerate(_wrap(reason, width, lay.font_scale, lay.lines - 3), 3):
            _put(lay, band, text, row, WARNING_RGB, width)
    else:
        _put(lay, band, figure + (f" < {bad_iou:.2f}" if bad and iou is not None else ""), 2,
             WARNING_RGB if bad else _TEXT_RGB, width)
    return tile


def contact_sheet(images, masks, names, angles_rad, ious, *, rejected=None, columns=None,
                  tile_px: int = 200, bad_iou: float = 0.9) -> np.ndarray:
    """(H, W, 3) uint8 RGB contact sheet of a session's views (module docstring).

    Parameters
    ----------
    images : sequence of (h, w, 3) uint8 RGB or None
        One per view (sizes may differ); None draws a grey "no image" box.
    masks : sequence of (h, w) bool or None
        Silhouette of each view (True = object), the size of its image; None
        draws no outline.
    names : sequence of str
        View names, shown first in each label.
    angles_rad : sequence of (theta_rad, phi_rad) or None
        Encoder angles of each view, radians, shown in degrees.
    ious : sequence of float in [0, 1] or None
        Silhouette IoU of the mesh reprojected into each view.
    rejected : sequence of str or None, optional
        Why each view was rejected, None for a view that was not.
    columns : int >= 1, optional
        Tiles per row; default ``ceil(sqrt(n_views))``.
    tile_px : int >= 64
        Width of a thumbnail, pixels; its height follows the tallest image
        aspect ratio. Text and lines scale with it.
    bad_iou : float in [0, 1]
        Views with an IoU below this (or none) are marked bad.

    Returns
    -------
    (H, W, 3) uint8 RGB. Tile ``k`` (0-based) is at row ``k // columns``,
    column ``k % columns``; :class:`SheetLayout` gives the pixel geometry.
    """
    names, images, masks, angles_rad, ious, rejected = _check(
        images, masks, names, angles_rad, ious, rejected, columns, tile_px, bad_iou)
    lay = SheetLayout.of(images, columns=columns, tile_px=tile_px,
                         any_rejected=any(r is not None for r in rejected))
    sheet = np.full((lay.height, lay.width, 3), BACKGROUND_RGB, np.uint8)
    # The thumbnails in threads (OpenCV scales and draws outside Python's lock).
    thumbnails = map_in_threads(
        lambda view: None if view[0] is None
        else _thumbnail(*view, tile_px, lay.box_h, max(1, tile_px // 200)), zip(images, masks))
    for k, (thumbnail, name, angles, iou, reason) in enumerate(
            zip(thumbnails, names, angles_rad, ious, rejected)):
        y, x = lay.tile_origin(k)
        sheet[y:y + lay.tile_h, x:x + lay.tile_w] = _tile(lay, thumbnail, name, angles, iou,
                                                          reason, bad_iou)

    scored = [v for v, r in zip(ious, rejected) if v is not None and r is None]
    low = sum(1 for v, r in zip(ious, rejected) if r is None and (v is None or v < bad_iou))
    header = (f"{len(names)} views: {sum(r is not None for r in rejected)} rejected, {low} with "
              f"IoU below {bad_iou:.2f} or none"
              + (f"; mean IoU {np.mean(scored):.3f}" if scored else ""))
    pad = lay.pad_px
    _put(lay, sheet[pad:pad + lay.line_px, pad:], header, 0, _TEXT_RGB, lay.width - 4 * pad)
    return sheet


def write_contact_sheet(path, images, masks, names, angles_rad, ious, **kw) -> Path:
    """Write :func:`contact_sheet` as a PNG to ``path`` atomically; returns the path."""
    return write_atomic(Path(path), png_bytes(contact_sheet(images, masks, names, angles_rad,
                                                            ious, **kw)))
