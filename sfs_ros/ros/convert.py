"""Conversions between numpy arrays / core objects and standard ROS 2 messages.

No cv_bridge or sensor_msgs_py: both are short here, and cv_bridge ties
itself to another numpy. Message byte fields are ``array.array('B')``;
images and clouds are filled with one copy (``array.frombytes``) and read back
without copying (``np.frombuffer``: the returned arrays are views of the
message's buffer, writable, so copy them before changing them).

Stamps: a ``builtin_interfaces/Time`` message or a ``(sec, nanosec)`` pair.
Reading images and joint states needs no ROS: :func:`msg_to_image`,
:func:`angles_from_joint_state` and :data:`JOINT_NAMES` are
:mod:`sfs_ros.cell_logic.message_fields`' (the bag reader's too), named here as well.
Angles in radians, points in metres.
"""

from __future__ import annotations

import array
import operator

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray, Quaternion
from scipy.ndimage import convolve
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState, PointCloud2, PointField
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from sfs_ros.cell_logic.intrinsics import DriverIntrinsics
from sfs_ros.cell_logic.message_fields import (
    IMAGE_ENCODINGS,
    JOINT_NAMES,
    angles_from_joint_state,
    image_rows,
    msg_to_image,
    stamp_key,
)
from sfs_ros.core.exchange.errors import ViewError
from sfs_ros.core.exchange.limits import MAX_IMAGE_PIXELS, decode_image_bytes
from sfs_ros.core.geometry.camera import Camera

__all__ = [
    "JOINT_NAMES", "header", "image_to_msg", "msg_to_image", "joint_state",
    "angles_from_joint_state", "camera_info", "points_to_cloud", "cloud_to_points",
    "mesh_to_marker", "mesh_to_shape", "shape_to_mesh", "camera_poses", "health",
    "DRIVER_ENCODINGS", "driver_frame", "bayer_to_rgb", "yuv422_to_rgb",
    "camera_info_intrinsics",
]

def header(*, stamp, frame_id: str) -> Header:
    """``std_msgs/Header`` from a stamp (Time or (sec, nanosec)) and a frame id."""
    sec, nanosec = stamp_key(stamp)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=str(frame_id))


def _bytes_array(data: np.ndarray) -> array.array:
    """``array('B')`` holding the bytes of ``data`` (one copy; C order)."""
    out = array.array("B")
    out.frombytes(np.ascontiguousarray(data).reshape(-1).view(np.uint8))  # also for 0 elements
    return out


def image_to_msg(image, *, stamp, frame_id: str, encoding: str | None = None) -> Image:
    """``sensor_msgs/Image`` from an array.

    image : (H, W, 3) uint8 (``rgb8``; ``encoding="bgr8"`` if its channels are
        in BGR order), (H, W) uint8 (``mono8``), (H, W) uint16 (``mono16``,
        little-endian) or (H, W) bool (a mask: ``mono8`` with 0 / 255).
    encoding : optional; must agree with the array when given.
    """
    image = np.asarray(image)
    if image.dtype == np.bool_:
        image = image.view(np.uint8) * np.uint8(255)
    if image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8:
        allowed = ("rgb8", "bgr8")
    elif image.ndim == 2 and image.dtype == np.uint8:
        allowed = ("mono8",)
    elif image.ndim == 2 and image.dtype == np.uint16:
        allowed = ("mono16",)
    else:
        raise ValueError(f"image must be (H, W, 3) uint8, (H, W) uint8 / uint16 or (H, W) bool, "
                         f"got shape {image.shape} dtype {image.dtype}")
    encoding = allowed[0] if encoding is None else encoding
    if encoding not in allowed:
        raise ValueError(f"encoding {encoding!r} does not fit an image of shape {image.shape} "
                         f"dtype {image.dtype}; expected one of {allowed}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"image must not be empty, got shape {image.shape}")
    msg = Image(header=header(stamp=stamp, frame_id=frame_id), height=image.shape[0],
                width=image.shape[1], encoding=encoding, is_bigendian=0,
                step=image.shape[1] * image.itemsize * (3 if image.ndim == 3 else 1))
    msg.data = _bytes_array(image.astype(image.dtype.newbyteorder("<"), copy=False))
    return msg


#: Bayer encodings -> the colours of the 2 x 2 tile, row by row.
_BAYER = {"bayer_rggb8": "rggb", "bayer_bggr8": "bggr", "bayer_gbrg8": "gbrg",
          "bayer_grbg8": "grbg"}
#: YUV 4:2:2 encodings -> byte order of a pair of pixels (ROS's ``yuv422`` is UYVY).
_YUV422 = {"yuv422": "uyvy", "uyvy": "uyvy", "yuyv": "yuyv", "yuv422_yuy2": "yuyv"}
#: Encodings with an alpha channel -> the order of their colour channels.
_ALPHA = {"rgba8": (0, 1, 2), "bgra8": (2, 1, 0)}
#: Every encoding :func:`driver_frame` takes (the cell's own, then the converted ones).
DRIVER_ENCODINGS = (*IMAGE_ENCODINGS, *_ALPHA, *_BAYER, *_YUV422)
#: Bilinear interpolation of a Bayer mosaic: each colour is the weighted mean of the
#: samples of that colour in the 3 x 3 neighbourhood (normalised by the weights present).
_BILINEAR = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]])


def bayer_to_rgb(raw, pattern: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a Bayer mosaic, bilinear demosaicing.

    raw : (H, W) uint8, one colour sample per pixel; pattern : the 2 x 2 tile's colours
    row by row, ``"rggb"``, ``"bggr"``, ``"gbrg"`` or ``"grbg"``. A pixel keeps its own
    sample; the other two colours are the mean of the nearest samples of that colour
    (weights 2 beside, 1 diagonal), so a uniform colour comes back exactly.
    """
    raw = np.asarray(raw)
    if raw.ndim != 2 or raw.dtype != np.uint8:
        raise ValueError(f"a Bayer mosaic must be (H, W) uint8, got {raw.shape} {raw.dtype}")
    if sorted(pattern) != sorted("rggb"):
        raise ValueError(f"Bayer pattern must be one of rggb, bggr, gbrg, grbg, got {pattern!r}")
    h, w = raw.shape
    tile = np.array(list(pattern)).reshape(2, 2)
    colours = np.tile(tile, ((h + 1) // 2, (w + 1) // 2))[:h, :w]
    samples = raw.astype(np.float64)
    out = np.empty((h, w, 3), dtype=np.uint8)
    for channel, name in enumerate("rgb"):
        where = (colours == name).astype(np.float64)
        weight = convolve(where, _BILINEAR, mode="constant")
        mean = convolve(samples * where, _BILINEAR, mode="constant") / np.maximum(weight, 1e-12)
        value = np.where(where > 0, samples, mean)
        out[:, :, channel] = np.clip(np.rint(value), 0, 255).astype(np.uint8)
    return out


def yuv422_to_rgb(pairs, order: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of YUV 4:2:2 data, ITU-R BT.601 video range (Y 16..235, U and
    V 16..240 around 128: what webcams send).

    pairs : (H, W * 2) uint8, two bytes a pixel, W even; order : ``"uyvy"`` (U Y0 V Y1,
    ROS's ``yuv422``) or ``"yuyv"`` (Y0 U Y1 V, ``yuv422_yuy2``); each U, V pair is shared
    by two neighbouring pixels.
    """
    pairs = np.asarray(pairs)
    if pairs.ndim != 2 or pairs.dtype != np.uint8 or pairs.shape[1] % 4:
        raise ValueError(f"YUV 4:2:2 data must be (H, 2 W) uint8 with W even, got "
                         f"{pairs.shape} {pairs.dtype}")
    if order not in ("uyvy", "yuyv"):
        raise ValueError(f"YUV 4:2:2 order must be uyvy or yuyv, got {order!r}")
    groups = pairs.reshape(pairs.shape[0], -1, 4).astype(np.float64)
    u, y0, v, y1 = (groups[..., i] for i in ((0, 1, 2, 3) if order == "uyvy" else (1, 0, 3, 2)))
    y = np.stack([y0, y1], axis=-1).reshape(pairs.shape[0], -1) - 16.0
    u = np.repeat(u, 2, axis=1) - 128.0
    v = np.repeat(v, 2, axis=1) - 128.0
    rgb = np.stack([1.164 * y + 1.596 * v, 1.164 * y - 0.392 * u - 0.813 * v,
                    1.164 * y + 2.017 * u], axis=-1)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def driver_frame(msg, *, max_pixels: int = MAX_IMAGE_PIXELS) -> Image:
    """A camera driver's frame as an ``Image`` the cell reads (rgb8, bgr8, mono8, mono16),
    same header.

    msg : ``sensor_msgs/Image`` in any of :data:`DRIVER_ENCODINGS` (rgb8, bgr8, mono8 and
    mono16 are returned as they are; rgba8 / bgra8 lose their alpha; Bayer mosaics are
    demosaiced and YUV 4:2:2 converted to rgb8), or ``sensor_msgs/CompressedImage`` (JPEG or
    PNG, decoded within the readers' limits,
    :func:`sfs_ros.core.exchange.limits.decode_image_bytes`: at most ``max_pixels``).
    Raises ValueError naming what was wrong and what is expected.
    """
    if isinstance(msg, CompressedImage):
        try:
            pixels = decode_image_bytes(msg.data, f"compressed image (format {msg.format!r})",
                                        max_pixels=max_pixels)
        except ViewError as exc:
            raise ValueError(str(exc)) from None
        return image_to_msg(pixels, stamp=msg.header.stamp, frame_id=msg.header.frame_id)
    encoding = msg.encoding
    if encoding in IMAGE_ENCODINGS:
        return msg
    if int(msg.width) * int(msg.height) > max_pixels:
        raise ValueError(f"image is {msg.width}x{msg.height} pixels; at most "
                         f"{max_pixels / 1e6:g} megapixels are taken")
    if encoding in _ALPHA:
        pixels = image_rows(msg, 4).reshape(msg.height, msg.width, 4)[:, :, list(_ALPHA[encoding])]
    elif encoding in _BAYER:
        pixels = bayer_to_rgb(image_rows(msg, 1), _BAYER[encoding])
    elif encoding in _YUV422:
        if msg.width % 2:
            raise ValueError(f"a {encoding} image must have an even width, got {msg.width}")
        pixels = yuv422_to_rgb(image_rows(msg, 2), _YUV422[encoding])
    else:
        raise ValueError(f"unsupported image encoding {encoding!r}; expected one of "
                         f"{', '.join(DRIVER_ENCODINGS)}")
    return image_to_msg(pixels, stamp=msg.header.stamp, frame_id=msg.header.frame_id)


def camera_info_intrinsics(msg: CameraInfo) -> DriverIntrinsics:
    """The intrinsics of a driver's ``sensor_msgs/CameraInfo``: size, ``K``, and ``D`` as
    plumb_bob's five coefficients (``plumb_bob`` with 5, or ``rational_polynomial`` with
    8 whose last three are 0; none = no distortion). ValueError naming the field."""
    k = [float(v) for v in msg.k]
    if len(k) != 9 or k[1] != 0.0 or k[3] != 0.0 or k[6:] != [0.0, 0.0, 1.0]:
        raise ValueError(f"camera_info K must be [fx, 0, cx, 0, fy, cy, 0, 0, 1], got {k}")
    d = [float(v) for v in msg.d]
    model = msg.distortion_model
    if not d:
        d = [0.0] * 5
    elif model == "plumb_bob" and len(d) == 5:
        pass
    elif model == "rational_polynomial" and len(d) == 8 and not any(d[5:]):
        d = d[:5]
    else:
        raise ValueError(f"camera_info distortion {model!r} with {len(d)} coefficients "
                         f"{d} is not one the rig holds; expected plumb_bob with 5 (k1, k2, "
                         "p1, p2, k3), or rational_polynomial with k4 = k5 = k6 = 0")
    return DriverIntrinsics(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5], tuple(d))


def joint_state(theta_rad: float, phi_rad: float, *, stamp) -> JointState:
    """``sensor_msgs/JointState`` of the cell: names ``JOINT_NAMES``, positions in radians."""
    return JointState(header=header(stamp=stamp, frame_id=""), name=list(JOINT_NAMES),
                      position=[float(theta_rad), float(phi_rad)])


def camera_info(camera: Camera, *, stamp, frame_id: str) -> CameraInfo:
    """``sensor_msgs/CameraInfo`` of a core :class:`Camera` (its intrinsics only).

    ``frame_id`` names the camera's optical frame; the pose ``R``, ``t``
    belongs in tf, not here. ``plumb_bob`` with the camera's distortion, R = I.

    * pinhole: ``K`` = camera.K, ``P = [K | 0]`` (the standard monocular form);
    * orthographic (not a model CameraInfo knows): ``K`` = camera.K with
      ``fx``, ``fy`` in pixels per metre, and ``P`` the affine projection in the
      camera frame, ``[[fx, s, 0, cx], [0, fy, 0, cy], [0, 0, 0, 1]]``: its last
      row (0, 0, 0, 1) marks it (a pinhole P has P[2, 2] = 1). Tools that
      assume a pinhole camera misread it.
    """
    K = np.asarray(camera.K, dtype=np.float64)
    if camera.orthographic:
        P = np.zeros((3, 4))
        P[:2, :2] = K[:2, :2]
        P[:2, 3] = K[:2, 2]
        P[2, 3] = 1.0
    else:
        P = np.hstack([K, np.zeros((3, 1))])
    return CameraInfo(header=header(stamp=stamp, frame_id=frame_id), height=camera.height,
                      width=camera.width, distortion_model="plumb_bob",
                      d=[float(v) for v in camera.distortion],
                      k=K.ravel(), r=np.eye(3).ravel(), p=P.ravel())


_CLOUD_FIELDS = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                 for i, n in enumerate("xyz")]
_FIELD_DTYPES = {PointField.FLOAT32: np.float32, PointField.FLOAT64: np.float64}


def points_to_cloud(points, *, stamp, frame_id: str) -> PointCloud2:
    """``sensor_msgs/PointCloud2`` (unorganised, float32 x, y, z) of points (n, 3), metres."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got shape {points.shape}")
    n = len(points)
    msg = PointCloud2(header=header(stamp=stamp, frame_id=frame_id), height=1, width=n,
                      fields=list(_CLOUD_FIELDS), is_bigendian=False, point_step=12,
                      row_step=12 * n, is_dense=bool(np.isfinite(points).all()))
    msg.data = _bytes_array(points.astype("<f4"))
    return msg


def cloud_to_points(msg: PointCloud2) -> np.ndarray:
    """Points (n, 3) float64 of a ``PointCloud2`` with float32 or float64 fields x, y, z.

    Any ``point_step`` / field offsets / extra fields, organised or not
    (``height`` > 1: rows in order; row padding skipped), either byte order.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        raise ValueError(f"cloud has no field(s) {missing}; fields are {sorted(fields)}")
    order = ">" if msg.is_bigendian else "<"
    formats = []
    for n in "xyz":
        f = fields[n]
        if f.datatype not in _FIELD_DTYPES or f.count != 1:
            raise ValueError(f"cloud field {n!r} must be one float32 or float64, got datatype "
                             f"{f.datatype} count {f.count}")
        formats.append(np.dtype(_FIELD_DTYPES[f.datatype]).newbyteorder(order))
    h, w, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    if step * w > row_step or len(msg.data) < h * row_step:
        raise ValueError(f"cloud sizes do not add up: {h} rows of {w} points of {step} bytes, "
                         f"row_step {row_step}, {len(msg.data)} data bytes")
    point = np.dtype({"names": list("xyz"), "formats": formats,
                      "offsets": [fields[n].offset for n in "xyz"], "itemsize": step})
    if h * w == 0:
        return np.zeros((0, 3))
    rows = np.frombuffer(msg.data, np.uint8, count=h * row_step).reshape(h, row_step)
    records = np.ascontiguousarray(rows[:, :w * step]).view(point).reshape(-1)
    return np.stack([records[n].astype(np.float64) for n in "xyz"], axis=1)


def _mesh_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be (n, 3), got shape {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be (m, 3) integers, got shape {faces.shape} "
                         f"dtype {faces.dtype}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"face indices must be in [0, {len(vertices)}), got "
                         f"[{faces.min()}, {faces.max()}]")
    return vertices, faces.astype(np.int64)


def _points(vertices: np.ndarray) -> list[Point]:
    return [Point(x=x, y=y, z=z) for x, y, z in vertices.tolist()]


def mesh_to_marker(vertices, faces, *, stamp, frame_id: str,
                   color=(0.8, 0.8, 0.8, 1.0), vertex_colors=None, marker_id: int = 0,
                   ns: str = "mesh") -> Marker:
    """``visualization_msgs/Marker`` TRIANGLE_LIST of a mesh (3 points per face, in face order).

    vertices : (n, 3) float64, metres; faces : (m, 3) int vertex indices.
    color : (r, g, b, a) floats in [0, 1]: the whole mesh's colour, or
    vertex_colors : (n, 3) uint8 RGB, optional: one colour per corner (``colors``,
        which RViz and Foxglove interpolate across each face).

    One ``Point`` is built per vertex and the list repeats those objects per
    face corner (the message serialises each entry; do not mutate them): a
    fraction of the time of a new Point per corner (``doc/benchmarks.md``).
    """
    vertices, faces = _mesh_arrays(vertices, faces)
    rgba = [float(c) for c in color]
    if len(rgba) != 4 or not all(0.0 <= c <= 1.0 for c in rgba):
        raise ValueError(f"color must be (r, g, b, a) in [0, 1], got {color!r}")
    marker = Marker(header=header(stamp=stamp, frame_id=frame_id), ns=ns, id=int(marker_id),
                    type=Marker.TRIANGLE_LIST, action=Marker.ADD,
                    color=ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 1.0
    if len(faces):
        pick = operator.itemgetter(*faces.ravel().tolist())
        corners = pick(_points(vertices))
        marker.points = list(corners) if isinstance(corners, tuple) else [corners]
        if vertex_colors is not None:
            rgb = np.asarray(vertex_colors)
            if rgb.shape != vertices.shape or rgb.dtype != np.uint8:
                raise ValueError(f"vertex_colors must be ({len(vertices)}, 3) uint8, got "
                                 f"{rgb.shape} {rgb.dtype}")
            palette = [ColorRGBA(r=r / 255, g=g / 255, b=b / 255, a=rgba[3])
                       for r, g, b in rgb.tolist()]
            colors = pick(palette)
            marker.colors = list(colors) if isinstance(colors, tuple) else [colors]
    return marker


def camera_poses(cameras, *, stamp, frame_id: str) -> PoseArray:
    """``geometry_msgs/PoseArray`` of the cameras' poses in the world (object) frame.

    Body axes (REP 103 ``camera_link``): x along the viewing direction, y to
    the image's left, z to its top, so RViz's and Foxglove's pose arrows point
    where each camera looks (the optical frame would point them sideways).
    """
    msg = PoseArray(header=header(stamp=stamp, frame_id=frame_id))
    for camera in cameras:
        optical_to_world = camera.R.T                       # columns: x right, y down, z forward
        body = optical_to_world @ _OPTICAL_TO_BODY
        x, y, z, w = _quaternion(body)
        cx, cy, cz = camera.center.tolist()
        msg.poses.append(Pose(position=Point(x=cx, y=cy, z=cz),
                              orientation=Quaternion(x=x, y=y, z=z, w=w)))
    return msg


#: Body axes in optical coordinates: x = optical z, y = -optical x, z = -optical y.
_OPTICAL_TO_BODY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` unit quaternion of a rotation matrix (w >= 0)."""
    # A writable copy: SciPy 1.11 (Ubuntu 24.04's) refuses read-only arrays.
    x, y, z, w = Rotation.from_matrix(np.array(R, dtype=np.float64)).as_quat()
    return (x, y, z, w) if w >= 0 else (-x, -y, -z, -w)


def mesh_to_shape(vertices, faces) -> Mesh:
    """``shape_msgs/Mesh`` of vertices (n, 3) float64 metres and faces (m, 3) int indices."""
    vertices, faces = _mesh_arrays(vertices, faces)
    if len(vertices) > 2 ** 32:
        raise ValueError(f"shape_msgs/Mesh indices are uint32: {len(vertices)} vertices "
                         f"is too many")
    mesh = Mesh(vertices=_points(vertices))
    mesh.triangles = [MeshTriangle(vertex_indices=row) for row in faces.astype(np.uint32)]
    return mesh


def shape_to_mesh(msg: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) float64 and faces (m, 3) int64 of a ``shape_msgs/Mesh``."""
    vertices = np.array([(p.x, p.y, p.z) for p in msg.vertices], dtype=np.float64).reshape(-1, 3)
    faces = np.array([t.vertex_indices for t in msg.triangles], dtype=np.int64).reshape(-1, 3)
    return vertices, faces


def health(problem: str, warning: str, ok: str) -> tuple[bytes, str]:
    """``(level, message)`` of a status: ERROR with ``problem`` if there is one, else WARN
    with ``warning`` if there is one, else OK with ``ok``."""
    if problem:
        return DiagnosticStatus.ERROR, problem
    if warning:
        return DiagnosticStatus.WARN, warning
    return DiagnosticStatus.OK, ok


def diagnostic_array(name: str, level, message: str, values: dict, *, stamp,
                     hardware_id: str = "") -> DiagnosticArray:
    """``diagnostic_msgs/DiagnosticArray`` holding one status; ``values`` become key/value strings."""
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    array = DiagnosticArray(status=[status])
    array.header.stamp = stamp
    return array
