"""Middlebury multi-view stereo data sets (``*_par.txt`` + images).

The par file: the first line is the number of views, then one line per view::

    imgname.png k11 k12 k13 k21 k22 k23 k31 k32 k33 r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3

with ``P = K [R | t]`` mapping world points (metres) to pixels, origin at the
top-left image corner. The images lie beside the par file. The data sets'
bounding boxes are given only in prose (README), so none is loaded.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera
from .limits import brief, confined_path, read_text
from .views import View, ViewError, ViewSet, image_size, nearest_rotation

__all__ = ["read_middlebury", "readme_mask"]

_FIELDS = 22  # name + 9 (K) + 9 (R) + 3 (t)


def read_middlebury(par_file: Path | str) -> ViewSet:
    """Load a Middlebury ``*_par.txt`` and the images beside it.

    The image size is read from the images (all must share it).

    Returns
    -------
    ViewSet
        ``source="middlebury"``, pinhole cameras, no angles, no bounds.

    Raises
    ------
    ViewError
        A malformed par file (naming the line), a count that does not match the
        lines, duplicate or missing images, or images of different sizes.
    """
    par_file = Path(par_file)
    lines = [(n, line.split()) for n, line in
             enumerate(read_text(par_file, "Middlebury camera file").splitlines(), 1)
             if line.strip()]
    if not lines:
        raise ViewError(f"{par_file} is empty; expected a view count and one line per view")
    count_line, count_fields = lines[0]
    if len(count_fields) != 1 or re.fullmatch(r"[0-9]{1,9}", count_fields[0]) is None:
        raise ViewError(f"{par_file} line {count_line}: expected the number of views, "
                        f"got {brief(' '.join(count_fields))}")
    count, rows = int(count_fields[0]), lines[1:]
    if count != len(rows):
        raise ViewError(f"{par_file} declares {count} views but has {len(rows)} view lines")
    if count == 0:
        raise ViewError(f"{par_file} has no views")

    parsed, seen = [], {}
    for line, fields in rows:
        where = f"{par_file} line {line}"
        if len(fields) != _FIELDS:
            raise ViewError(f"{where}: {len(fields)} fields, expected {_FIELDS} "
                            "(name, K 3x3, R 3x3, t 3, row by row)")
        name = fields[0]
        if name in seen:
            raise ViewError(f"{where}: image {brief(name)} is listed twice (first on line {seen[name]})")
        seen[name] = line
        try:
            values = np.array([float(v) for v in fields[1:]])
        except ValueError:
            bad = next(v for v in fields[1:] if not _is_number(v))
            raise ViewError(f"{where}: {brief(bad)} is not a number") from None
        if not np.all(np.isfinite(values)):
            raise ViewError(f"{where}: camera parameters contain NaN or infinity")
        parsed.append((where, name, values))

    size, first = None, None
    views = []
    for where, name, values in parsed:
        path = confined_path(par_file.parent, name, f"{where}: image")
        if not path.is_file():
            raise ViewError(f"{where}: image {path} does not exist")
        this_size = image_size(path)
        if size is None:
            size, first = this_size, name
        elif this_size != size:
            raise ViewError(f"image {path} is {this_size[0]}x{this_size[1]} pixels, expected "
                            f"{size[0]}x{size[1]} like {first}")
        K = values[:9].reshape(3, 3)
        if K[2, 2] == 0:
            raise ViewError(f"{where}: K[2][2] is 0; expected an intrinsic matrix")
        R = nearest_rotation(values[9:18].reshape(3, 3), what=where)
        try:
            camera = Camera(K=K / K[2, 2], R=R, t=values[18:], width=size[0], height=size[1])
        except ValueError as err:
            raise ViewError(f"{where}: {err}") from None
        views.append(View(name=name, image_path=path, camera=camera))
    return ViewSet(views=views, source="middlebury")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def readme_mask(image: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) bool: the silhouette of an (H, W, 3) uint8 photograph by the recipe of the
    data sets' README, a reference the project did not make: the largest of the three
    channels above ``threshold`` of full scale (0.19; the temple's dark cloth passes it,
    0.3 there), dilated by 10 px (21 x 21 square), eroded by 7 px (15 x 15 square),
    blobs under 1 % of the largest dropped."""
    import cv2  # (not needed to read a data set)

    mask = (image.max(axis=2) > threshold * 255).astype(np.uint8)
    mask = cv2.erode(cv2.dilate(mask, np.ones((21, 21), np.uint8)), np.ones((15, 15), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return mask.astype(bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.concatenate([[False], areas >= 0.01 * areas.max()])
    return keep[labels]
