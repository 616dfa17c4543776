"""A :class:`~sfs_ros.core.carved_scan.CarvedScan` as a ``sfs_ros_interfaces/CarvedScan``
message and back, bit for bit (the meshing node makes the mesh the offline path makes).

The hull travels as its occupied box, packed a bit a voxel; each silhouette packed a bit a
pixel, but for those the receiver holds already (``masks_held``: the carving node sends
each view's silhouette as it is stored, :func:`view_mask_msg`), and a colour view's
silhouette as carved only where the fusion repaired it (else it is the view's); the
mesher's input as it is (float32 band distances, float64 points); the images that colour
the mesh, and when asked those of every view used (:func:`carried_images`), as rgb8
(sizes: ``bench/bench_handover.py``), but for those the receiver holds already
(``held``: the carving node sends each view's image as it is stored,
:func:`view_image_msg`); the hand-over's thumbnails, for the contact sheet only, as JPEG,
but for the images the receiver holds (it makes those thumbnails itself).
"""

from __future__ import annotations

import array
import json
import math

import cv2
import numpy as np

from sfs_ros.cell_logic.mesh_files import THUMBNAIL_PX, HandOver
from sfs_ros.core.carved_scan import ROLES, CarvedScan, ScanView
from sfs_ros.core.carving.carve import unpack_bits
from sfs_ros.core.carving.hull import occupied_bounds
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.marching import BandDistance
from sfs_ros.core.meshing.meshers import MESHERS, HullCloud
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg
from sfs_ros_interfaces.msg import CarvedView, ViewImage
from sfs_ros_interfaces.srv import CarveScan

__all__ = ["HandOver", "carried_images", "carve_scan_request", "carved_scan_from_msg",
           "carved_scan_to_msg", "view_image_from_msg", "view_image_msg", "view_mask_from_msg",
           "view_mask_msg"]

#: JPEG quality of the views' thumbnails (pictures only: the mesh never sees them).
THUMBNAIL_QUALITY = 90


def _bytes(values: np.ndarray, code: str) -> array.array:
    """A numpy array as the message's array field (one copy, no per-element check)."""
    return array.array(code, np.ascontiguousarray(values).tobytes())


def _bits(mask: np.ndarray) -> array.array:
    return _bytes(np.packbits(mask, axis=None), "B")


def _unbits(data, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``shape`` bool of the bits ``data`` packed (:func:`_bits`), a new array (the unpacked
    0/1 bytes seen as bool); ValueError naming ``what`` if their count is not the shape's."""
    count = int(np.prod(shape))
    packed = np.frombuffer(data, dtype=np.uint8)
    if packed.size != (count + 7) // 8:
        raise ValueError(f"{what} has {packed.size} bytes, expected {(count + 7) // 8} "
                         f"(a bit for each of {shape} cells)")
    return unpack_bits(packed, shape)


def _jpeg(rgb: np.ndarray) -> array.array:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, THUMBNAIL_QUALITY])
    if not ok:
        raise ValueError(f"a thumbnail of {rgb.shape} could not be encoded")
    return _bytes(data, "B")


def _unjpeg(data, name: str) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.shape[1] > THUMBNAIL_PX:
        raise ValueError(f"view {name!r}'s thumbnail_jpeg is not a JPEG of at most "
                         f"{THUMBNAIL_PX} pixels wide")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _view_msg(view: ScanView, mask: np.ndarray, colour_mask: np.ndarray | None,
              image: np.ndarray | None, thumb: np.ndarray | None, held: bool,
              mask_held: bool) -> CarvedView:
    camera = view.camera
    theta, phi = view.angles_rad if view.angles_rad is not None else (math.nan, math.nan)
    msg = CarvedView(name=view.name, role=view.role, orthographic=bool(camera.orthographic),
                     theta_rad=float(theta), phi_rad=float(phi))
    msg.k = np.asarray(camera.K, np.float64).ravel()
    msg.r = np.asarray(camera.R, np.float64).ravel()
    msg.t = np.asarray(camera.t, np.float64).ravel()
    if not mask_held:
        msg.mask_bits = _bits(mask)
    if thumb is not None:
        msg.thumbnail_jpeg = _jpeg(thumb)
    if colour_mask is not None and not np.array_equal(colour_mask, mask):
        msg.colour_mask_bits = _bits(colour_mask)
    if image is not None:
        if held:
            msg.image_held = True
        else:
            msg.image_rgb = _bytes(np.asarray(image, np.uint8), "B")
    return msg


def _mesher_fields(msg: CarvedScanMsg, mesher_input) -> None:
    if isinstance(mesher_input, BandDistance):
        msg.band_voxels = int(mesher_input.band_voxels)
        msg.band_distance = _bytes(np.asarray(mesher_input.values, np.float32), "f")
        if mesher_input.crossings is not None:
            msg.band_crossings = _bytes(np.asarray(mesher_input.crossings, np.float32), "f")
    elif isinstance(mesher_input, HullCloud):
        msg.cloud_points = _bytes(np.asarray(mesher_input.points, np.float64), "d")
        msg.cloud_normals = _bytes(np.asarray(mesher_input.normals, np.float64), "d")
        msg.cloud_stats_json = json.dumps(mesher_input.stats)
    else:
        raise ValueError(f"no message fields for a mesher input of type "
                         f"{type(mesher_input).__name__}")


def carved_scan_to_msg(carved: CarvedScan, hand_over: HandOver, *, stamp,
                       held=frozenset(), masks_held: dict | None = None,
                       images: dict | None = None) -> CarvedScanMsg:
    """The message of ``carved`` (its ``taken`` masks stay behind), stamped ``stamp``,
    with the images that colour the mesh and ``images`` ({view name: (H, W, 3) uint8} of
    further views, as :meth:`LiveReconstruction.colour_image` gives them); the images of
    the views named in ``held``, and their thumbnails, are left out (the receiver holds
    them), and so are the silhouettes of ``masks_held`` ({view name: (H, W) bool} the
    receiver holds) where they are the view's."""
    box = occupied_bounds(carved.occupancy)
    if box is None:
        raise ValueError("the carved hull is empty: nothing to hand over")
    lo, hi = box
    height, width = carved.masks[0].shape if carved.masks else (0, 0)
    msg = CarvedScanMsg(scan_name=hand_over.scan_name, session_dir=hand_over.session_dir,
                        views_received=int(hand_over.views_received),
                        image_width=int(width), image_height=int(height),
                        voxel_size_m=float(carved.grid.voxel_size), mesher=carved.mesher,
                        report_json=json.dumps(carved.report))
    msg.header.stamp = stamp
    msg.header.frame_id = hand_over.frame_id
    msg.grid_min = np.asarray(carved.grid.bounds_min, np.float64)
    msg.grid_max = np.asarray(carved.grid.bounds_max, np.float64)
    msg.occupied_min = lo.astype(np.uint32)
    msg.occupied_size = (hi - lo).astype(np.uint32)
    msg.occupied_bits = _bits(carved.occupancy[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]])
    _mesher_fields(msg, carved.mesher_input)
    colour_masks = dict(zip(carved.colour_views, carved.colour_masks))
    colour_images = dict(zip(carved.colour_views, carved.colour_images))
    images = images or {}
    # The receiver makes the thumbnails of the images it holds.
    masks_held = masks_held or {}
    msg.views = [_view_msg(view, mask, colour_masks.get(i),
                           colour_images.get(i, images.get(view.name)),
                           None if view.name in held else hand_over.thumbnails.get(view.name),
                           view.name in held,
                           np.array_equal(masks_held.get(view.name), mask))
                 for i, (view, mask) in enumerate(zip(carved.views, carved.masks))]
    msg.colour_views = _bytes(np.asarray(carved.colour_views, np.uint32), "I")
    return msg


def _grid_and_occupancy(msg: CarvedScanMsg) -> tuple[VoxelGrid, np.ndarray]:
    grid = VoxelGrid(np.array(msg.grid_min, np.float64), np.array(msg.grid_max, np.float64),
                     float(msg.voxel_size_m))
    lo = np.array(msg.occupied_min, np.int64)
    size = np.array(msg.occupied_size, np.int64)
    if np.any(size < 1) or np.any(lo + size > np.array(grid.shape)):
        raise ValueError(f"occupied box {lo.tolist()} + {size.tolist()} is not inside the "
                         f"grid of {list(grid.shape)} voxels")
    occupancy = np.zeros(grid.shape, bool)
    occupancy[lo[0]:lo[0] + size[0], lo[1]:lo[1] + size[1], lo[2]:lo[2] + size[2]] = \
        _unbits(msg.occupied_bits, tuple(size.tolist()), "occupied_bits")
    return grid, occupancy


def _mesher_input(msg: CarvedScanMsg):
    if msg.mesher not in MESHERS:
        raise ValueError(f"mesher {msg.mesher!r} is not one of {tuple(MESHERS)}")
    if msg.mesher == "marching-cubes":
        crossings = np.frombuffer(msg.band_crossings, np.float32).copy()
        return BandDistance(values=np.frombuffer(msg.band_distance, np.float32).copy(),
                            band_voxels=int(msg.band_voxels),
                            crossings=crossings if len(crossings) else None)
    points = np.frombuffer(msg.cloud_points, np.float64)
    normals = np.frombuffer(msg.cloud_normals, np.float64)
    if points.size % 3 or normals.size != points.size:
        raise ValueError(f"cloud of {points.size} point and {normals.size} normal "
                         "coordinates: expected (n, 3) each")
    return HullCloud(points=points.reshape(-1, 3).copy(), normals=normals.reshape(-1, 3).copy(),
                     stats=json.loads(msg.cloud_stats_json or "{}"))


def _view(view: CarvedView, width: int, height: int,
          masks_held: dict) -> tuple[ScanView, np.ndarray]:
    if view.role not in ROLES:
        raise ValueError(f"view {view.name!r} has role {view.role!r}, expected one of {ROLES}")
    camera = Camera(K=np.array(view.k, np.float64).reshape(3, 3),
                    R=np.array(view.r, np.float64).reshape(3, 3),
                    t=np.array(view.t, np.float64), width=width, height=height,
                    orthographic=bool(view.orthographic))
    if len(view.mask_bits):
        mask = _unbits(view.mask_bits, (height, width), f"view {view.name!r}'s mask_bits")
    else:
        mask = masks_held.get(view.name)
        if mask is None or mask.shape != (height, width):
            raise ValueError(f"view {view.name!r}'s mask_bits was left out as held, but no "
                             f"{width} x {height} silhouette of it is held")
    angles = None if math.isnan(view.theta_rad) else (view.theta_rad, view.phi_rad)
    return ScanView(view.name, camera, view.role, angles), mask


def _colour(view: CarvedView, view_mask: np.ndarray, width: int, height: int,
            held: dict) -> tuple[np.ndarray, np.ndarray]:
    mask = _unbits(view.colour_mask_bits, (height, width),
                   f"view {view.name!r}'s colour_mask_bits") \
        if len(view.colour_mask_bits) else view_mask
    return mask, _image(view, width, height, held)


def _image(view: CarvedView, width: int, height: int, held: dict) -> np.ndarray:
    if view.image_held:
        image = held.get(view.name)
        if image is None or image.shape != (height, width, 3):
            raise ValueError(f"view {view.name!r}'s image was left out as held, but no "
                             f"{width} x {height} image of it is held")
        return image
    image = np.frombuffer(view.image_rgb, np.uint8)
    if image.size != height * width * 3:
        raise ValueError(f"view {view.name!r}'s image_rgb has {image.size} bytes, expected "
                         f"{height * width * 3} ({width} x {height} rgb8)")
    return image.reshape(height, width, 3).copy()


def carried_images(msg: CarvedScanMsg, held: dict | None = None) -> dict[str, np.ndarray]:
    """{view name: (H, W, 3) uint8} of every view of a carved scan message that has an
    image, in it or left out as held (``held`` as :func:`carved_scan_from_msg`'s);
    ValueError as that function's for an image that does not add up."""
    width, height = int(msg.image_width), int(msg.image_height)
    return {view.name: _image(view, width, height, held or {}) for view in msg.views
            if view.image_held or len(view.image_rgb)}


def carved_scan_from_msg(msg: CarvedScanMsg, held: dict | None = None,
                         held_thumbnails: dict | None = None,
                         masks_held: dict | None = None) -> tuple[CarvedScan, HandOver]:
    """The carved scan of a message, and what it says of its scan; ValueError naming the
    field that does not add up. ``held``: {view name: (H, W, 3) uint8} of the images
    left out of the message (``image_held``); ``held_thumbnails``: {view name: (h, w, 3)
    uint8} of the views whose thumbnail the message leaves out (a view with neither
    shows its image or its mask on the contact sheet); ``masks_held``: {view name: (H, W)
    bool} of the silhouettes it leaves out (an empty ``mask_bits``)."""
    width, height = int(msg.image_width), int(msg.image_height)
    grid, occupancy = _grid_and_occupancy(msg)
    views, masks = zip(*[_view(v, width, height, masks_held or {}) for v in msg.views]) \
        if msg.views else ((), ())
    colour_views = [int(i) for i in msg.colour_views]
    if any(i >= len(msg.views) for i in colour_views):
        raise ValueError(f"colour_views {colour_views} name views beyond the "
                         f"{len(msg.views)} given")
    colours = [_colour(msg.views[i], masks[i], width, height, held or {})
               for i in colour_views]
    carved = CarvedScan(grid=grid, occupancy=occupancy, mesher=msg.mesher,
                        mesher_input=_mesher_input(msg), views=list(views), masks=list(masks),
                        colour_views=colour_views, colour_masks=[m for m, _ in colours],
                        colour_images=[image for _, image in colours],
                        report=json.loads(msg.report_json or "{}"))
    thumbnails = {v.name: _unjpeg(v.thumbnail_jpeg, v.name) if len(v.thumbnail_jpeg)
                  else held_thumbnails[v.name] for v in msg.views
                  if len(v.thumbnail_jpeg) or v.name in (held_thumbnails or {})}
    return carved, HandOver(scan_name=msg.scan_name, session_dir=msg.session_dir,
                            views_received=int(msg.views_received),
                            frame_id=msg.header.frame_id, thumbnails=thumbnails)


def view_image_msg(session_dir: str, name: str, rgb: np.ndarray, *, header) -> ViewImage:
    """A view's colour image (``(H, W, 3)`` uint8, as :meth:`LiveReconstruction.colour_image`
    gives it) as its message, with ``header`` (``std_msgs/Header``: the capture's stamp)."""
    msg = ViewImage(header=header, session_dir=session_dir, view_name=name)
    height, width = rgb.shape[:2]
    msg.image.header = header
    msg.image.height, msg.image.width = int(height), int(width)
    msg.image.encoding, msg.image.step = "rgb8", int(width) * 3
    msg.image.data = _bytes(np.asarray(rgb, np.uint8), "B")
    return msg


def view_mask_msg(session_dir: str, name: str, mask: np.ndarray, *, header) -> ViewImage:
    """A view's silhouette (``(H, W)`` bool on its ideal camera, as the carved scan carries
    it: :meth:`LiveReconstruction.view_mask`) as a view image message: mono8, 255 on the
    object, 0 elsewhere, with ``header`` (the capture's stamp)."""
    msg = ViewImage(header=header, session_dir=session_dir, view_name=name)
    height, width = mask.shape
    msg.image.header = header
    msg.image.height, msg.image.width = int(height), int(width)
    msg.image.encoding, msg.image.step = "mono8", int(width)
    msg.image.data = _bytes(np.asarray(mask, np.uint8) * np.uint8(255), "B")
    return msg


def view_mask_from_msg(msg: ViewImage) -> tuple[str, str, np.ndarray]:
    """``(session folder, view name, (H, W) bool)`` of a view mask message
    (:func:`view_mask_msg`); ValueError for anything but a packed mono8 image of 0 and 255."""
    image = msg.image
    height, width = int(image.height), int(image.width)
    if image.encoding != "mono8" or image.step != width \
            or len(image.data) != height * width or not msg.view_name:
        raise ValueError(f"view mask {msg.view_name!r}: expected a named, packed mono8 image, "
                         f"got {image.encoding!r} {width} x {height}, step {image.step}, "
                         f"{len(image.data)} bytes")
    values = np.frombuffer(image.data, np.uint8).reshape(height, width)
    mask = values == 255
    if np.count_nonzero(mask) + np.count_nonzero(values == 0) != values.size:
        raise ValueError(f"view mask {msg.view_name!r}: expected only 0 and 255")
    return msg.session_dir, msg.view_name, mask


def view_image_from_msg(msg: ViewImage) -> tuple[str, str, np.ndarray]:
    """``(session folder, view name, (H, W, 3) uint8)`` of a view image message;
    ValueError for anything but a packed rgb8 image."""
    image = msg.image
    height, width = int(image.height), int(image.width)
    if image.encoding != "rgb8" or image.step != width * 3 \
            or len(image.data) != height * width * 3 or not msg.view_name:
        raise ValueError(f"view image {msg.view_name!r}: expected a named, packed rgb8 image, "
                         f"got {image.encoding!r} {width} x {height}, step {image.step}, "
                         f"{len(image.data)} bytes")
    return (msg.session_dir, msg.view_name,
            np.frombuffer(image.data, np.uint8).reshape(height, width, 3).copy())


def carve_scan_request(options, colour: bool, images_session: str, images_held: list, *,
                       every_image: bool = False) -> CarveScan.Request:
    """The ``CarveScan`` request of a reconstruction's ``options``
    (:class:`sfs_ros.cell_logic.mesh_options.MeshOptions`; each left empty is the carving node's
    setting), with the images that colour the mesh when ``colour`` and the image of every
    view used when ``every_image``, without those of the views ``images_held`` of the scan
    ``images_session``."""
    return CarveScan.Request(
        resolution=options.resolution or 0,
        bounds_m=[] if options.bounds_m is None else options.bounds_m.ravel().tolist(),
        mesher=options.mesher or "", colour="yes" if colour else "no",
        every_image=bool(every_image), images_session=images_session,
        images_held=images_held)
