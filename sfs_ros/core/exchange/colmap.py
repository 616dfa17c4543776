"""COLMAP's text model as an input: ``cameras.txt`` + ``images.txt`` with the images.

Read (COLMAP's documented text format; ``#`` lines are comments):

* ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line, models

  ======================  ==========================  ===========================
  model                   parameters                  lens (OpenCV ``plumb_bob``)
  ======================  ==========================  ===========================
  ``SIMPLE_PINHOLE``      ``f cx cy``                 none
  ``PINHOLE``             ``fx fy cx cy``             none
  ``SIMPLE_RADIAL``       ``f cx cy k``               ``k1 = k``
  ``RADIAL``              ``f cx cy k1 k2``           ``k1, k2``
  ``OPENCV``              ``fx fy cx cy k1 k2 p1 p2``  ``k1, k2, p1, p2``
  ======================  ==========================  ===========================

  COLMAP puts the centre of the top-left pixel at (0.5, 0.5): ``cx``, ``cy``
  become ours (integer values at pixel centres) by subtracting 0.5. Other models
  (fisheye, full OpenCV, ...) are an error naming the model.
* ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID
  NAME`` (the world-to-camera rotation as a unit quaternion and translation, in
  OpenCV axes, as ours) and the image's 2-D points (ignored, may be empty).
  Lines are told apart by their structure: a line of ``X Y POINT3D_ID`` number
  triples (or a blank one) is an image's points, any other line an image, so a
  points line left out or a stray blank line moves no image to another line.
* the images: ``NAME`` relative to an ``images/`` folder beside the text files,
  or beside their folder or its parent (COLMAP's ``sparse/0`` layout), the first
  that exists; read only from inside the folder that holds ``images/`` (neither
  ``images/`` nor an image may be a symbolic link leading out of it).

``points3D.txt`` is not read. Units are COLMAP's: the model's own scale and frame
(give ``--bounds`` in them, or let the box be estimated). Lens distortion is
undistorted once before carving (:mod:`sfs_ros.core.geometry.lens`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera
from .limits import brief, confined_path, read_text
from .views import View, ViewError, ViewSet

__all__ = ["MODELS", "read_colmap"]

#: Camera models read: name -> (parameter names, in order).
MODELS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy"),
          "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"), "RADIAL": ("f", "cx", "cy", "k1", "k2"),
          "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")}
CAMERAS_FILE, IMAGES_FILE = "cameras.txt", "images.txt"


def _lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of the lines that are not comments (blank lines kept)."""
    return [(n, line.strip()) for n, line in enumerate(read_text(path, "COLMAP file")
                                                         .splitlines(), start=1)
            if not line.lstrip().startswith("#")]


def _floats(fields: list[str], where: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in fields])
    except ValueError:
        raise ViewError(f"{where}: expected numbers, got {brief(' '.join(fields))}") from None
    if not np.all(np.isfinite(values)):
        raise ViewError(f"{where}: values must be finite, got {brief(' '.join(fields))}")
    return values


def _cameras(path: Path) -> dict[str, tuple[int, int, np.ndarray, tuple]]:
    """``{camera id: (width, height, K, distortion)}`` of ``cameras.txt``."""
    from ..geometry.lens import lens_problem  # OpenCV: loaded when a model is read

    cameras = {}
    for n, line in _lines(path):
        if not line:
            continue
        where = f"{path} line {n}"
        fields = line.split()
        if len(fields) < 4:
            raise ViewError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got "
                            f"{brief(line)}")
        camera_id, model = fields[0], fields[1]
        if model not in MODELS:
            raise ViewError(f"{where}: camera model {brief(model)} is not supported; expected "
                            f"one of {', '.join(MODELS)} (undistort the images with COLMAP's "
                            "image_undistorter for others)")
        names = MODELS[model]
        if len(fields) != 4 + len(names):
            raise ViewError(f"{where}: a {model} camera has {len(names)} parameters "
                            f"({' '.join(names)}), got {len(fields) - 4}")
        size = _floats(fields[2:4], where)
        if np.any(size != np.round(size)) or np.any(size < 1):
            raise ViewError(f"{where}: width and height must be whole numbers of pixels, got "
                            f"{fields[2]} {fields[3]}")
        p = dict(zip(names, _floats(fields[4:], where)))
        fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
        K = np.array([[fx, 0.0, p["cx"] - 0.5], [0.0, fy, p["cy"] - 0.5], [0.0, 0.0, 1.0]])
        lens = tuple(float(p.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2")) + (0.0,)
        if camera_id in cameras:
            raise ViewError(f"{where}: camera {brief(camera_id)} is defined twice")
        problem = lens_problem(K, lens, int(size[0]), int(size[1]))
        if problem:
            raise ViewError(f"{where}: {model} camera {brief(camera_id)}: {problem}")
        cameras[camera_id] = (int(size[0]), int(size[1]), K, lens)
    if not cameras:
        raise ViewError(f"{path} defines no camera")
    return cameras


def _is_points_line(fields: list[str]) -> bool:
    """Whether ``fields`` may be an image's 2-D points: ``X Y POINT3D_ID`` triples of
    numbers, each POINT3D_ID a whole number (-1 for none)."""
    if len(fields) % 3:
        return False
    try:
        values = [float(value) for value in fields]
    except ValueError:
        return False
    return all(v.is_integer() for v in values[2::3])


def _image_lines(lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """The image lines of ``images.txt`` told by their structure, not their position.

    After an image line comes at most one line of its 2-D points (:func:`_is_points_line`;
    blank for none); blank lines beyond it are stray and skipped; any other line is an
    image. So a missing points line or a stray blank line moves no image, and an image
    line cut to look like points is still taken as an image (and refused as malformed)."""
    images, points_due = [], False
    for n, line in lines:
        if not line or (points_due and _is_points_line(line.split())):
            points_due = False
        else:
            images.append((n, line))
            points_due = True
    return images


def _image_root(model: Path) -> Path:
    """The folder whose ``images/`` holds the model's images: ``model``, its parent or its
    grandparent, the first that has one."""
    for root in (model, model.parent, model.parent.parent):
        if (root / "images").is_dir():
            return root
    raise ViewError(f"no images/ folder beside the COLMAP model {model} (looked in {model}, "
                    f"{model.parent} and {model.parent.parent})")


def read_colmap(folder: Path | str) -> ViewSet:
    """Load COLMAP's text model in ``folder`` (format in the module docstring).

    Returns
    -------
    ViewSet
        ``source="colmap"``, pinhole cameras with their lens, view names = the
        image names. An image whose pose cannot be used (a zero quaternion) is a
        rejected view.

    Raises
    ------
    ViewError
        Missing files, an unknown camera model, a malformed line, an image of an
        undefined camera, a missing image file, or no usable image.
    """
    from scipy.spatial.transform import Rotation  # loaded when a model is read

    folder = Path(folder)
    for name in (CAMERAS_FILE, IMAGES_FILE):
        if not (folder / name).is_file():
            raise ViewError(f"COLMAP model {folder} has no {name}; expected {CAMERAS_FILE} and "
                            f"{IMAGES_FILE} (the text model: colmap model_converter "
                            "--output_type TXT)")
    cameras = _cameras(folder / CAMERAS_FILE)
    lines = _image_lines(_lines(folder / IMAGES_FILE))
    root = _image_root(folder)
    views, rejected, seen = [], [], set()
    for n, line in lines:
        where = f"{folder / IMAGES_FILE} line {n}"
        fields = line.split()
        if len(fields) < 10:
            raise ViewError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, "
                            f"got {brief(line)}")
        name = " ".join(fields[9:])
        values = _floats(fields[1:8], where)
        if fields[8] not in cameras:
            raise ViewError(f"{where}: image {brief(name)} refers to camera {brief(fields[8])}, "
                            f"which {CAMERAS_FILE} does not define")
        if name in seen:
            raise ViewError(f"{where}: image {brief(name)} is listed twice")
        seen.add(name)
        # Confined to the folder images/ is in, as a session's: neither images/ nor an
        # image may be a link to a place outside it.
        path = confined_path(root, f"images/{name}", where)
        if not path.is_file():
            raise ViewError(f"{where}: image {path} does not exist")
        q = values[:4]
        # (A unit quaternion's parts are within [-1, 1]: checked first, the norm of larger
        # ones could overflow.)
        if np.any(np.abs(q) > 1.001) or not math.isclose(float(np.linalg.norm(q)), 1.0,
                                                          abs_tol=1e-3):
            rejected.append((name, f"rotation quaternion {q.tolist()} is not a unit quaternion"))
            continue
        R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        width, height, K, lens = cameras[fields[8]]
        try:
            camera = Camera(K=K, R=R, t=values[4:], width=width, height=height, distortion=lens)
        except ValueError as err:
            raise ViewError(f"{where}: {err}") from None
        views.append(View(name=name, image_path=path, camera=camera))
    if not views:
        raise ViewError(f"{folder / IMAGES_FILE} lists no usable image"
                        + (f" ({len(rejected)} rejected, first: {rejected[0][0]}: "
                           f"{rejected[0][1]})" if rejected else ""))
    return ViewSet(views=views, source="colmap", rejected=rejected)
