"""Scan session folder: the images of one scan with their encoder angles or cameras.

Layout::

    SESSION/
      session.yaml
      views.csv
      images/
        view_000.png
        ...

``session.yaml`` (YAML mapping; unknown keys are an error)::

    format: sfs_ros-session          # required, exactly this
    version: 1                       # required
    rig:                             # required: RigCalibration fields, all optional
      width: 640                     #   image size, pixels
      height: 480
      projection: pinhole            #   or orthographic
      fx: 1400.0                     #   pixels (orthographic: pixels per metre)
      fy: 1400.0
      cx: null                       #   principal point, pixels; null = image centre
      cy: null
      camera_distance_m: 0.6         #   C-arm centre to camera centre
      aim_point_m: [0.0, 0.0, 0.04]  #   C-arm centre, lab frame
      theta_zero_rad: 0.0            #   encoder readings at the true zero of each axis
      phi_zero_rad: 0.0
      convention: physical           #   or paper
      distortion: [0.0, 0.0, 0.0, 0.0, 0.0]  # lens (k1, k2, p1, p2, k3), OpenCV plumb_bob
      axis_point_m: [0.0, 0.0]       #   turntable axis (see RigCalibration), as
      axis_tilt_x_rad: 0.0           #   sfs-calibrate writes them
      axis_tilt_y_rad: 0.0
      mount_rotation_rad: [0.0, 0.0, 0.0]
    bounds_m: [[xmin, ymin, zmin], [xmax, ymax, zmax]]   # optional carving box, metres
    segmentation: {threshold: 0.2}   # optional SegmentationParams fields

``views.csv`` (comma-separated, one header line, then one row per image;
``image`` is a path relative to ``images/``, using ``/``, and names the view).
The header is one of two forms:

* ``image,theta_rad,phi_rad``: encoder readings at the shutter, radians; the
  camera comes from ``rig``. A row with a NaN or infinite angle, or with a
  carriage angle outside [-90, 90] degrees after removing ``phi_zero_rad``,
  is reported as a rejected view; the other views still load.
* ``image,p11,p12,p13,p14,p21,...,p34``: a pinhole 3x4 projection matrix per
  view, row by row, mapping object-frame metres to pixels (integer values at
  pixel centres, origin top-left); ``rig`` gives only the image size and the
  lens ``distortion`` (the matrix is the ideal pinhole; the images are as the
  lens formed them). A row with a non-finite or singular matrix is a rejected view.

``images/`` holds exactly the images listed in ``views.csv`` (any format
OpenCV reads; files whose names start with ``.`` are ignored). A listed
image that is missing, or an image that is not listed, is an error: the
table does not match the images.

Writing (:func:`write_session`) stores PNG files and writes ``session.yaml``
last, so an interrupted write never leaves a folder that reads as a session.
:func:`append_view` adds one image and one row to an existing angles session
without rewriting earlier rows.
"""

from __future__ import annotations

import csv
import dataclasses
import errno
import io
import math
import os
import re
import shutil
from pathlib import Path, PurePosixPath

import numpy as np
import yaml

from ..geometry.camera import Camera
from ..geometry.rig import MAX_ENCODER_RAD, RigCalibration, rig_camera
from .files import write_atomic
from .limits import brief, confined_path, load_yaml, printable, read_text
from .views import IMAGE_SUFFIXES, View, ViewError, ViewSet, as_bounds

__all__ = ["FORMAT", "VERSION", "SESSION_FILE", "VIEWS_FILE", "IMAGES_DIR", "ANGLE_COLUMNS",
           "MATRIX_COLUMNS", "read_session", "write_session", "append_view", "appended_view",
           "stored_view_name", "view_key_of"]

FORMAT = "sfs_ros-session"
VERSION = 1
SESSION_FILE = "session.yaml"
VIEWS_FILE = "views.csv"
IMAGES_DIR = "images"
ANGLE_COLUMNS = ("image", "theta_rad", "phi_rad")
MATRIX_COLUMNS = ("image",) + tuple(f"p{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3, 4))
_YAML_KEYS = ("format", "version", "rig", "bounds_m", "segmentation")
_KEY_AS_FILE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,95}\.png")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")
_NAMED_KEY = re.compile(r"view_\d{3,}_([A-Za-z0-9_.-]{1,64})\.png")


# ---------------------------------------------------------------- reading

def _read_yaml(folder: Path) -> dict:
    path = folder / SESSION_FILE
    if not path.is_file():
        raise ViewError(f"{folder} is not a session folder: {SESSION_FILE} is missing")
    data = load_yaml(path, "session file")
    if not isinstance(data, dict):
        raise ViewError(f"{path} must be a YAML mapping with keys {list(_YAML_KEYS)}")
    unknown = sorted(set(map(str, data)) - set(_YAML_KEYS))
    if unknown:
        raise ViewError(f"{path}: unknown keys {brief(unknown)}; expected some of "
                        f"{list(_YAML_KEYS)}")
    if data.get("format") != FORMAT:
        raise ViewError(f"{path}: format is {brief(data.get('format'))}, expected {FORMAT!r}")
    version = data.get("version")
    if type(version) is not int or version != VERSION:
        raise ViewError(f"{path}: version {brief(version)} is not supported, expected {VERSION}")
    return data


def _rig(data: dict, path: Path) -> RigCalibration:
    rig = data.get("rig")
    if not isinstance(rig, dict):
        raise ViewError(f"{path}: 'rig' must be a mapping of rig calibration fields, got "
                        f"{brief(rig)}")
    try:
        return RigCalibration.from_dict(rig)
    except (ValueError, TypeError) as err:
        raise ViewError(f"{path}: rig: {str(err)[:200]}") from None


def _bounds(data: dict, path: Path) -> np.ndarray | None:
    if data.get("bounds_m") is None:
        return None
    return as_bounds(data["bounds_m"], what=f"{path}: bounds_m")


def _segmentation(data: dict, path: Path) -> dict | None:
    seg = data.get("segmentation")
    if seg is not None and not isinstance(seg, dict):
        raise ViewError(f"{path}: segmentation must be a mapping of segmentation parameters, "
                        f"got {brief(seg)}")
    return seg


def _check_image_name(name: str, where: str) -> str:
    parts = PurePosixPath(name).parts
    if not name or "\\" in name or name.startswith("/") or ".." in parts or name.startswith("."):
        raise ViewError(f"{where}: image {brief(name)} must be a relative path inside "
                        f"{IMAGES_DIR}/ (using '/', no '..')")
    return name


def _read_table(folder: Path) -> tuple[tuple[str, ...], list[tuple[int, list[str]]]]:
    """Header and ``(line number, fields)`` rows of views.csv (blank lines skipped)."""
    path = folder / VIEWS_FILE
    if not path.is_file():
        raise ViewError(f"{folder} is not a session folder: {VIEWS_FILE} is missing")
    reader = csv.reader(io.StringIO(read_text(path, "views table"), newline=""))
    header = None
    rows = []
    try:
        for fields in reader:
            fields = [f.strip() for f in fields]
            if not any(fields):
                continue
            if header is None:
                header = tuple(fields)
            else:
                rows.append((reader.line_num, fields))
    except csv.Error as err:
        raise ViewError(f"{path} line {reader.line_num}: not a CSV table ({err})") from None
    if header not in (ANGLE_COLUMNS, MATRIX_COLUMNS):
        raise ViewError(f"{path}: header {brief(','.join(header or ()))} is neither "
                        f"{','.join(ANGLE_COLUMNS)!r} nor {','.join(MATRIX_COLUMNS[:3])},...,p34")
    return header, rows


def _numbers(fields: list[str], header: tuple[str, ...], where: str) -> np.ndarray:
    values = []
    for column, text in zip(header[1:], fields[1:]):
        try:
            values.append(float(text))
        except ValueError:
            raise ViewError(f"{where}: {column} {brief(text)} is not a number") from None
    return np.array(values)


def _angle_camera(theta: float, phi: float, rig: RigCalibration) -> tuple[Camera | None, str]:
    """The rig camera, or None and the reason the angles cannot be used."""
    if not (math.isfinite(theta) and math.isfinite(phi)):
        return None, f"encoder angles are not finite (theta_rad={theta}, phi_rad={phi})"
    for name, value in (("theta_rad", theta), ("phi_rad", phi)):
        if abs(value) > MAX_ENCODER_RAD:
            return None, (f"encoder angle {name}={value!r} is beyond any reading: expected a "
                          f"finite angle within +-{MAX_ENCODER_RAD:g} rad")
    carriage = phi - rig.phi_zero_rad
    if abs(carriage) > math.pi / 2 + 1e-9:
        return None, (f"carriage angle phi={math.degrees(carriage):.3f} deg (after the zero "
                      "offset) is outside the C-arm range [-90, 90] deg")
    return rig_camera(theta, phi, rig), ""


def _angle_view(path: Path, name: str, theta: float, phi: float,
                rig: RigCalibration) -> tuple[View | None, str]:
    """The view of an angles row, or None and the reason its angles cannot be used."""
    camera, reason = _angle_camera(theta, phi, rig)
    if camera is None:
        return None, reason
    return View(name=name, image_path=path, camera=camera, theta_rad=theta, phi_rad=phi), ""


def appended_view(view_set: ViewSet, folder: Path | str, name: str, theta_rad: float,
                  phi_rad: float) -> ViewSet:
    """``view_set`` (:func:`read_session` of ``folder``) with the view :func:`append_view`
    added to it, as reading the folder again would give it (usable or rejected), without
    reading it."""
    path = confined_path(Path(folder), f"{IMAGES_DIR}/{name}", "appended view")
    view, reason = _angle_view(path, name, float(theta_rad), float(phi_rad),
                               view_set.calibration)
    if view is None:
        return dataclasses.replace(view_set, rejected=[*view_set.rejected, (name, reason)])
    return dataclasses.replace(view_set, views=[*view_set.views, view])


def _matrix_camera(values: np.ndarray, rig: RigCalibration) -> tuple[Camera | None, str]:
    if not np.all(np.isfinite(values)):
        return None, "projection matrix contains NaN or infinity"
    try:
        camera = Camera.from_projection_matrix(values.reshape(3, 4), rig.width, rig.height)
        return dataclasses.replace(camera, distortion=rig.distortion), ""
    except ValueError as err:
        return None, str(err)


def _image_files(images: Path) -> set[str]:
    """Image files under ``images`` as '/'-separated relative paths (hidden ones skipped)."""
    if not images.is_dir():
        return set()
    found = set()
    for path in images.rglob("*"):
        rel = path.relative_to(images)
        if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES \
                and not any(p.startswith(".") for p in rel.parts):
            found.add(rel.as_posix())
    return found


def stored_view_name(index: int, key: str) -> str:
    """The image file name of the ``index``-th view (from 0) stored under ``key`` (a
    capture's stamp or name): the key itself where it is a safe PNG name, else
    ``view_NNN_<key>.png`` with the key's unsafe characters replaced."""
    if _KEY_AS_FILE.fullmatch(key):
        return key
    return f"view_{index:03d}_{_UNSAFE.sub('_', key)[:64]}.png"


def view_key_of(name: str) -> str:
    """The key of a view from the file name :func:`stored_view_name` gave it."""
    found = _NAMED_KEY.fullmatch(name)
    return found.group(1) if found else name


def read_session(folder: Path | str) -> ViewSet:
    """Load a session folder (format in the module docstring) without decoding images.

    Returns
    -------
    ViewSet
        ``source="session"``; ``calibration``, ``bounds_m`` and ``segmentation``
        from ``session.yaml``; views with unusable angles or matrices in ``rejected``.

    Raises
    ------
    ViewError
        Missing or malformed ``session.yaml`` / ``views.csv``, a table that does
        not match the images, or no usable view.
    """
    folder = Path(folder)
    data = _read_yaml(folder)
    yaml_path = folder / SESSION_FILE
    rig = _rig(data, yaml_path)
    header, rows = _read_table(folder)
    table = folder / VIEWS_FILE

    first_line: dict[str, int] = {}
    views, rejected, missing = [], [], []
    for line, fields in rows:
        where = f"{table} line {line}"
        if len(fields) != len(header):
            raise ViewError(f"{where}: {len(fields)} fields, expected {len(header)} "
                            f"({','.join(header[:3])}{',...' if len(header) > 3 else ''})")
        name = _check_image_name(fields[0], where)
        if name in first_line:
            raise ViewError(f"{where}: image {brief(name)} is listed twice (first on line "
                            f"{first_line[name]})")
        first_line[name] = line
        values = _numbers(fields, header, where)
        path = confined_path(folder, f"{IMAGES_DIR}/{name}", f"{where}: image")
        if not path.is_file():
            missing.append(name)
        if header == ANGLE_COLUMNS:
            view, reason = _angle_view(path, name, float(values[0]), float(values[1]), rig)
        else:
            camera, reason = _matrix_camera(values, rig)
            view = None if camera is None else View(name=name, image_path=path, camera=camera)
        if view is None:
            rejected.append((name, reason))
        else:
            views.append(view)

    if missing:
        raise ViewError(f"{table} lists {len(missing)} image(s) missing from {IMAGES_DIR}/: "
                        f"{_some(missing)}")
    unlisted = sorted(_image_files(folder / IMAGES_DIR) - set(first_line))
    if unlisted:
        raise ViewError(f"{folder / IMAGES_DIR} holds {len(unlisted)} image(s) not listed in "
                        f"{table}: {_some(unlisted)} (the table does not match the images)")
    if not views:
        detail = f"; all {len(rejected)} rejected, first: {rejected[0][0]}: {rejected[0][1]}" \
            if rejected else ""
        raise ViewError(f"{table} has no usable view{detail}")
    return ViewSet(views=views, source="session", bounds_m=_bounds(data, yaml_path),
                   segmentation=_segmentation(data, yaml_path), rejected=rejected,
                   calibration=rig)


def _some(names: list[str], limit: int = 5) -> str:
    shown = ", ".join(printable(n) for n in names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


# ---------------------------------------------------------------- writing

def _plain(value):
    """YAML-safe copy: tuples and arrays -> lists, numpy scalars -> Python numbers."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _check_rgb(rgb, calibration: RigCalibration, name: str) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"image {name!r} must be (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
    if rgb.shape[:2] != (calibration.height, calibration.width):
        raise ValueError(f"image {name!r} is {rgb.shape[1]}x{rgb.shape[0]} pixels, expected "
                         f"{calibration.width}x{calibration.height} (the rig's size)")
    return rgb


def _check_new_name(name: str) -> str:
    if not isinstance(name, str) or not name.lower().endswith(".png"):
        raise ValueError(f"view name {name!r} must be a file name ending in '.png'")
    return _check_image_name(name, "view name")


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2  # here, not at the top: reading the formats' names costs no OpenCV

    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"could not encode {path} as PNG")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, data.tobytes())


def _csv_line(fields: list) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(fields)
    return out.getvalue()


def _clear_old_session(folder: Path) -> None:
    """Remove a previous session in ``folder``; refuse to touch anything else."""
    if not folder.exists():
        return
    if not folder.is_dir():
        raise ValueError(f"cannot write a session to {folder}: it is a file")
    ours = {SESSION_FILE, VIEWS_FILE, IMAGES_DIR}
    foreign = sorted(p.name for p in folder.iterdir()
                     if p.name not in ours and not p.name.startswith("."))
    if foreign:
        raise ValueError(f"cannot write a session to {folder}: it holds other files "
                         f"({_some(foreign)}); choose an empty or new folder")
    (folder / SESSION_FILE).unlink(missing_ok=True)  # first: the folder stops being a session
    (folder / VIEWS_FILE).unlink(missing_ok=True)
    if (folder / IMAGES_DIR).is_dir():
        shutil.rmtree(folder / IMAGES_DIR)


def _angle_rows(names: list[str], angles: list) -> list[str]:
    """The lines of an angles table (header first)."""
    rows = [_csv_line(list(ANGLE_COLUMNS))]
    for name, pair in zip(names, angles):
        if len(pair) != 2:
            raise ValueError(f"angles of {name!r} must be (theta_rad, phi_rad), got "
                             f"{pair!r}")
        rows.append(_csv_line([name, repr(float(pair[0])), repr(float(pair[1]))]))
    return rows


def _matrix_rows(names: list[str], cameras: list[Camera],
                 calibration: RigCalibration) -> list[str]:
    """The lines of a matrix table (header first); every camera a pinhole with the rig's
    lens."""
    rows = [_csv_line(list(MATRIX_COLUMNS))]
    for name, camera in zip(names, cameras):
        if camera.orthographic:
            raise ValueError(f"camera of {name!r} is orthographic; a matrix table holds "
                             "pinhole cameras")
        if not np.array_equal(camera.distortion, calibration.distortion):
            raise ValueError(f"camera of {name!r} has lens distortion "
                             f"{camera.distortion.tolist()}, the session's rig "
                             f"{list(calibration.distortion)}; expected one lens per session")
        P = camera.projection_matrix
        rows.append(_csv_line([name] + [repr(float(v)) for v in P.ravel()]))
    return rows


def _session_document(calibration: RigCalibration, bounds_m, segmentation) -> dict:
    """The session file's content: format, rig, and the box and segmentation if given."""
    document = {"format": FORMAT, "version": VERSION, "rig": _plain(calibration.to_dict())}
    if bounds_m is not None:
        document["bounds_m"] = as_bounds(bounds_m, what="bounds_m").tolist()
    if segmentation is not None:
        if dataclasses.is_dataclass(segmentation):
            segmentation = dataclasses.asdict(segmentation)
        if not isinstance(segmentation, dict):
            raise ValueError("segmentation must be a dict or SegmentationParams, "
                             f"got {type(segmentation).__name__}")
        document["segmentation"] = _plain(segmentation)
    return document


def write_session(folder: Path | str, images: list[tuple[str, np.ndarray]],
                  angles: list[tuple[float, float]] | None, calibration: RigCalibration, *,
                  cameras: list[Camera] | None = None, bounds_m=None,
                  segmentation=None) -> Path:
    """Write a scan as a session folder (replacing a previous session there).

    Parameters
    ----------
    folder : path-like
        Created if needed. A previous session in it is replaced; a folder
        holding anything else is refused.
    images : list of (str, (H, W, 3) uint8)
        ``(name, RGB image)``; names end in ``.png`` and become the file names
        under ``images/``; every image has the calibration's size.
    angles : list of (float, float), or None with ``cameras``
        ``(theta_rad, phi_rad)`` encoder readings per image, radians (stored
        as given; unusable ones are rejected when the session is read).
    calibration : RigCalibration
        With ``cameras``, only its image size and lens ``distortion`` are used.
    cameras : list of Camera, optional, keyword-only
        Pinhole cameras instead of angles: a table of 3x4 projection matrices;
        their lens distortion must be the calibration's (one lens per session).
    bounds_m : (2, 3) array-like or None
        Carving box ``[min, max]``, metres.
    segmentation : dict, SegmentationParams or None
        Segmentation parameters to store.

    Returns
    -------
    Path
        ``folder``.
    """
    folder = Path(folder)
    if (angles is None) == (cameras is None):
        raise ValueError("give either angles (an angles table) or cameras (a matrix table)")
    per_view = angles if cameras is None else cameras
    if len(images) != len(per_view):
        what = "angle pairs" if cameras is None else "cameras"
        raise ValueError(f"{len(images)} images but {len(per_view)} {what}; expected one per "
                         "image")
    if not images:
        raise ValueError("a session needs at least one image")
    names = [_check_new_name(name) for name, _ in images]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"view names must be unique; repeated: {_some(twice)}")
    rows = (_angle_rows(names, angles) if cameras is None
            else _matrix_rows(names, cameras, calibration))
    document = _session_document(calibration, bounds_m, segmentation)
    checked = [_check_rgb(rgb, calibration, name) for name, (_, rgb) in zip(names, images)]

    _clear_old_session(folder)
    (folder / IMAGES_DIR).mkdir(parents=True, exist_ok=True)
    for name, rgb in zip(names, checked):
        _write_png(folder / IMAGES_DIR / name, rgb)
    write_atomic(folder / VIEWS_FILE, "".join(rows).encode("utf-8"))
    text = yaml.safe_dump(document, sort_keys=False, default_flow_style=None)
    write_atomic(folder / SESSION_FILE, text.encode("utf-8"))
    return folder


def append_view(folder: Path | str, name: str, rgb: np.ndarray, theta_rad: float,
                phi_rad: float) -> Path:
    """Add one image with its encoder readings to an existing angles session.

    The PNG is written first (atomically), then one row is appended to
    ``views.csv``; earlier rows are never rewritten. When a write fails
    (``OSError``, e.g. a full disk) the table is cut back to its earlier
    rows and the image removed, so the same view can be appended later.

    Parameters
    ----------
    folder : path-like
        A session folder whose ``views.csv`` has the ``image,theta_rad,phi_rad`` header.
    name : str
        New view name ending in ``.png`` (not yet in the session).
    rgb : (H, W, 3) uint8
        The image, of the rig's size.
    theta_rad, phi_rad : float
        Encoder readings at the shutter, radians.

    Returns
    -------
    Path
        The image file written.
    """
    folder = Path(folder)
    rig = _rig(_read_yaml(folder), folder / SESSION_FILE)
    header, rows = _read_table(folder)
    if header != ANGLE_COLUMNS:
        raise ValueError(f"{folder / VIEWS_FILE} lists projection matrices; views can only be "
                         f"appended to a session with the {','.join(ANGLE_COLUMNS)!r} header")
    name = _check_new_name(name)
    path = folder / IMAGES_DIR / name
    if name in {fields[0] for _, fields in rows} or path.exists():
        raise ValueError(f"view {name!r} is already in the session {folder}")
    rgb = _check_rgb(rgb, rig, name)
    _write_png(path, rgb)
    table = folder / VIEWS_FILE
    try:
        with table.open("rb+", buffering=0) as f:   # unbuffered: a failed write raises here
            size = f.seek(0, os.SEEK_END)
            f.seek(-1, os.SEEK_END)
            row = (("\n" if f.read(1) != b"\n" else "")
                   + _csv_line([name, repr(float(theta_rad)), repr(float(phi_rad))]))
            try:
                data = row.encode("utf-8")
                if f.write(data) != len(data):
                    raise OSError(errno.ENOSPC, f"{table}: the row was written in part")
                os.fsync(f.fileno())
            except OSError:
                f.truncate(size)    # no half row left behind (a full disk)
                raise
    except OSError:
        path.unlink(missing_ok=True)   # nor an image without its row: the view can come again
        raise
    return path
