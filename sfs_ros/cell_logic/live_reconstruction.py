"""One scan on the reconstruction side: silhouettes arrive one by one while the rig moves.

:class:`LiveReconstruction` carves each arriving mask into a voxel hull at
once (a preview that grows sharper with every view), writes every view to a
session folder as it arrives, and on request runs the full reconstruction
(:func:`sfs_ros.core.pipeline.reconstruct`) on the views received so far, with the
masks received (the images are not read back nor segmented again).

Persistence and the final reconstruction share one path: each mask is stored
as a black-and-white PNG (object 255, background 0) in a scan session folder
(:mod:`sfs_ros.core.exchange.session`) whose ``session.yaml`` holds the rig
calibration, the carving box and :data:`MASK_SEGMENTATION`, segmentation
parameters under which :func:`sfs_ros.core.segmentation.segment.segment` returns such an
image's mask unchanged (a fixed threshold at half scale against a black
background, no morphology, no blob or hole filtering, no dilation). The
reconstruction reads that folder's views (cameras, box) and takes the received
masks, which are what segmenting the stored images gives; so a crash loses nothing and
``sfs-reconstruct SCAN_FOLDER -o mesh.ply`` (same resolution) later gives
the same mesh as :meth:`LiveReconstruction.reconstruct`.

The scan being received is marked open (an empty file ``.open`` in its
session folder) until :meth:`LiveReconstruction.reset`; a restarted process
takes it up with :meth:`LiveReconstruction.reopen` (its views read back and
carved again), so a view sent again after the restart is known and not
stored twice. A view that cannot be stored (``OSError``: a full disk) leaves
the folder as it was (no half-written image, row or folder) and can be added
again.

Output folder layout::

    OUTPUT_DIR/
      scan_001/            # one session folder per scan (session.yaml, views.csv, images/)
      scan_001.ply         # meshes, named by the request (default: the scan's name)
      scan_001.report.json # the pipeline's report beside each mesh
      scan_001.png         # and a picture of the mesh,
      scan_001.html        # a page that shows it in a browser (no network needed),
      scan_001.views.png   # and a contact sheet of the views (mask outline, angles, IoU)
"""

from __future__ import annotations

import re
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ..core.carved_scan import CarvedScan
from ..core.carving.bounds import BoxCarve
from ..core.carving.carve import Carver, unpack_bits
from ..core.carving.hull import surface_voxels
from ..core.carving.resolution import BYTES_PER_VOXEL
from ..core.exchange.limits import MAX_WAITING_BYTES
from ..core.exchange.session import (
    append_view,
    appended_view,
    read_session,
    stored_view_name,
    view_key_of,
    write_session,
)
from ..core.exchange.views import ViewSet, as_bounds
from ..core.geometry.grid import VoxelGrid
from ..core.geometry.lens import ideal_camera, is_distorted, undistort_image, undistort_mask
from ..core.geometry.rig import RigCalibration, rig_camera
from ..core.meshing.hull_distance import DistanceImages
from ..core.meshing.meshers import MESHER
from ..core.pipeline import (
    ComputedOnArrival,
    ExpectedCarves,
    ReconstructionParams,
    carve_scan,
)
from ..core.result_files import SheetViews
from ..core.segmentation.segment import SegmentationParams
from ..core.settings import RESOLUTION
from .mesh_files import HandOver, mask_to_rgb, mesh_paths, thumbnail, write_mesh
from .paths import check_scan_name_format

__all__ = ["MASK_SEGMENTATION", "DuplicateViewError", "AddedView", "LiveReconstruction",
           "surface_points", "mask_to_rgb", "check_scan_name"]

#: Segmentation under which a 0/255 mask image segments to exactly that mask.
MASK_SEGMENTATION = SegmentationParams(
    method="threshold", background=(0, 0, 0), background_model="constant", threshold=0.5,
    weak_ratio=1.0,
    open_px=0, close_px=0, min_blob_fraction=0.0, fill_holes_max_fraction=0.0, dilate_px=0,
    min_area_fraction=0.0)

#: Longest accepted view key, characters.
MAX_KEY_CHARS = 200
_AUTO_SCAN = re.compile(r"scan_(\d{3,})")
#: The file that marks the session folder of the scan being received.
OPEN_MARKER = ".open"
#: A reconstruction's working memory (see :attr:`LiveReconstruction.working_memory_bytes`):
#: bytes per voxel of the live grid, and bytes besides.
WORKING_MEMORY_PER_VOXEL = 3 * BYTES_PER_VOXEL
WORKING_MEMORY_BASE = 64 << 20


class DuplicateViewError(ValueError):
    """A view key that was already received: the view is not carved again."""


@dataclass(frozen=True)
class AddedView:
    """What :meth:`LiveReconstruction.add_view` did with a view.

    key : str, the view's key; file : Path, its image in the session folder;
    carved : bool, whether it carved the live hull (an empty mask does not);
    reason : str, why not (empty when carved); n_views : int, views received;
    occupied_voxels : int, voxels left in the live hull.
    """

    key: str
    file: Path
    carved: bool
    reason: str
    n_views: int
    occupied_voxels: int


@dataclass(frozen=True)
class _Received:
    name: str
    packed_mask: np.ndarray  # np.packbits of the (H, W) bool mask
    theta_rad: float
    phi_rad: float
    #: np.packbits of the mask undistorted onto the ideal pinhole, where the lens distorts
    #: and the mask is not empty (else None: the mask is its own undistortion, or unused)
    packed_ideal: np.ndarray | None = None


def check_scan_name(output_dir, scan_name: str) -> None:
    """ValueError unless ``scan_name`` can name a new scan folder in ``output_dir``: 1-100
    letters, digits, ``_``, ``-`` or ``.`` (not first) and no such folder yet."""
    check_scan_name_format(scan_name)
    if (Path(output_dir) / scan_name).exists():
        raise ValueError(f"scan folder {Path(output_dir) / scan_name} already exists; "
                         "choose a new scan name")


def surface_points(occupancy: np.ndarray, grid: VoxelGrid, max_points: int) -> np.ndarray:
    """Centres of the occupied voxels with a free 6-neighbour (the grid edge counts as free).

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool, on ``grid``
    grid : VoxelGrid
    max_points : int >= 1
        With more surface voxels, an evenly spaced subset (in index order) of
        this many is returned.

    Returns
    -------
    (n, 3) float64
        Metres, object frame.
    """
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) \
            or max_points < 1:
        raise ValueError(f"max_points must be an integer >= 1, got {max_points!r}")
    occ = np.asarray(occupancy, dtype=bool)
    if occ.shape != grid.shape:
        raise ValueError(f"occupancy has shape {occ.shape}, expected the grid's {grid.shape}")
    ijk = surface_voxels(occ)
    if len(ijk) > max_points:
        ijk = ijk[np.linspace(0, len(ijk) - 1, int(max_points)).round().astype(np.int64)]
    return grid.index_to_world(ijk)


def _check_key(key) -> str:
    if isinstance(key, bool) or not isinstance(key, (str, int, np.integer)):
        raise ValueError(f"view key must be a string or an integer (e.g. a stamp), got "
                         f"{type(key).__name__}")
    key = str(key)
    if not key or len(key) > MAX_KEY_CHARS:
        raise ValueError(f"view key must have 1 to {MAX_KEY_CHARS} characters, got {len(key)}")
    if any(ord(c) < 0x20 or ord(c) == 0x7F for c in key):
        raise ValueError(f"view key {key!r} contains control characters")
    return key


def _check_mask(mask, calibration: RigCalibration) -> np.ndarray:
    """(H, W) bool from a bool, 0/1 or 0/255 array of the rig's size."""
    m = np.asarray(mask)
    expected = (calibration.height, calibration.width)
    if m.shape != expected:
        raise ValueError(f"mask has shape {m.shape}, expected the rig's (height, width) = "
                         f"{expected}")
    if m.dtype == np.bool_:
        return m.copy()
    if not np.issubdtype(m.dtype, np.integer):
        raise ValueError(f"mask must be bool, or integers 0/1 or 0/255, got dtype {m.dtype}")
    values = set(np.unique(m).tolist())
    if not (values <= {0, 1} or values <= {0, 255}):
        raise ValueError(f"mask must hold only 0 and 1 (or 0 and 255), got values "
                         f"{sorted(values)[:6]}")
    return m != 0


class LiveReconstruction:
    """The reconstruction side of one scan: incremental hull, persisted views, final mesh.

    Parameters
    ----------
    calibration : RigCalibration
        Turns each view's encoder angles into its camera; masks have its size.
    bounds_m : (2, 3) array-like
        Carving box ``[min, max]``, metres, object frame.
    output_dir : path-like, keyword-only
        Folder for the scan session folders, meshes and reports (created if
        needed). Only one :class:`LiveReconstruction` should write to it.
    resolution : int
        Voxels along the longest side of the box, for the live hull and the
        final reconstruction alike (default: the cell's,
        :data:`sfs_ros.core.settings.RESOLUTION`).
    mesher : str
        A name in :data:`sfs_ros.core.meshing.meshers.MESHERS`.
    max_misses : int
        A voxel survives when at most this many views miss it.
    check_consistency : bool
        Let the final reconstruction drop views inconsistent with the others
        (the live hull uses every non-empty mask).
    scan_name : str or None
        Name of the first scan's session folder; None: ``scan_NNN``, the
        next number after those in ``output_dir``.
    """

    def __init__(self, calibration: RigCalibration, bounds_m, *, output_dir,
                 resolution: int = RESOLUTION.cell_default, mesher: str = MESHER.cell_default,
                 max_misses: int = 0,
                 check_consistency: bool = True, scan_name: str | None = None):
        if not isinstance(calibration, RigCalibration):
            raise ValueError(f"calibration must be a RigCalibration, got "
                             f"{type(calibration).__name__}")
        self.calibration = calibration
        self.bounds_m = as_bounds(bounds_m, what="bounds_m")
        self.params = ReconstructionParams(resolution=resolution, mesher=mesher,
                                           max_misses=max_misses,
                                           check_consistency=check_consistency)
        self.grid = VoxelGrid.cube(self.bounds_m[0], self.bounds_m[1], resolution)
        self.output_dir = Path(output_dir)
        self.output_dir.mkdir(parents=True, exist_ok=True)
        self._pictures_due = None   # the last reconstruction's pictures, when deferred
        self.reset(scan_name)

    # ------------------------------------------------------------ state

    def reset(self, scan_name: str | None = None) -> None:
        """Start a new scan: empty hull, no views; the next view opens a new session folder.

        Earlier scans' folders stay on disk. ``scan_name`` as in the constructor;
        ValueError if that folder already exists.
        """
        if scan_name is not None:
            check_scan_name(self.output_dir, scan_name)
        self._requested_name = scan_name
        self.close()
        self._carver = Carver(self.grid, max_misses=self.params.max_misses)
        self._precomputed = ComputedOnArrival(distances=DistanceImages(), box=BoxCarve(self.bounds_m))
        self._expected = ExpectedCarves(self.bounds_m, self.params.resolution,
                                        self.params.max_misses, self._precomputed.box,
                                        known=self._precomputed.distances
                                        if self.params.mesher == "marching-cubes" else None)
        self._views: dict[str, _Received] = {}
        self._colour_images: dict[str, np.ndarray] = {}
        self._thumbnails: dict[str, np.ndarray] = {}   # of the images, made as they came
        self._colour_waiting: dict[str, int] = {}   # keys of images without a view yet, oldest first
        self._mesh: tuple[np.ndarray, np.ndarray] | None = None
        self._colours: np.ndarray | None = None

    def close(self) -> None:
        """End the scan being received: its session folder (if any) is no longer marked
        open, so no later start takes it up again; the next view opens a new one."""
        if getattr(self, "_session", None) is not None:
            (self._session / OPEN_MARKER).unlink(missing_ok=True)
        self._session: Path | None = None
        self._view_set: ViewSet | None = None      # the session as read back, kept up to date

    @property
    def working_memory_bytes(self) -> int:
        """Memory a scan and its reconstruction are expected to take at their peak, bytes:
        :data:`WORKING_MEMORY_PER_VOXEL` per voxel of the live grid and
        :data:`WORKING_MEMORY_BASE`, as measured in the cell's node (twice as much
        touched in advance bought no speed: ``doc/changelog.md``, 4 December, evening).
        The final grid is the tight box at the same resolution: at most the live grid's
        voxels."""
        return WORKING_MEMORY_BASE + WORKING_MEMORY_PER_VOXEL * int(np.prod(self.grid.shape))

    @property
    def n_views(self) -> int:
        """Views received in this scan."""
        return len(self._views)

    @property
    def keys(self) -> list[str]:
        """Keys of the views received, in arrival order."""
        return list(self._views)

    @property
    def session_dir(self) -> Path | None:
        """This scan's session folder; None until the first view arrives."""
        return self._session

    @property
    def last_mesh(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(vertices (n, 3) float64 metres, faces (m, 3) int64)`` of this scan's latest
        :meth:`reconstruct`, for publishing; None before one."""
        return self._mesh

    @property
    def last_colours(self) -> np.ndarray | None:
        """(n, 3) uint8 RGB per vertex of :attr:`last_mesh`, when it was coloured; else None."""
        return self._colours

    @property
    def occupancy(self) -> np.ndarray:
        """(nx, ny, nz) bool on :attr:`grid`: the live hull of the non-empty masks so far."""
        return self._carver.occupancy

    def view_keys(self) -> list[str]:
        """The keys of every view received, in order."""
        return list(self._views)

    def views(self) -> list[tuple[str, np.ndarray, float, float]]:
        """``(key, mask (H, W) bool, theta_rad, phi_rad)`` of every view received, in order."""
        return [(key, self._unpacked(v.packed_mask), v.theta_rad, v.phi_rad)
                for key, v in self._views.items()]

    def _unpacked(self, packed: np.ndarray) -> np.ndarray:
        """(H, W) bool of a mask packed by ``np.packbits``, the rig's size (its own array:
        the unpacked 0/1 bytes seen as bool, not copied)."""
        return unpack_bits(packed, (self.calibration.height, self.calibration.width))

    # ------------------------------------------------------------ views

    def _file_name(self, key: str) -> str:
        return stored_view_name(len(self._views), key)

    def _open_session(self, name: str, rgb: np.ndarray, theta: float, phi: float) -> Path:
        """Create this scan's session folder holding its first view."""
        if self._requested_name is not None:
            candidates = [self._requested_name]
        else:
            numbers = [int(m.group(1)) for p in self.output_dir.iterdir()
                       if (m := _AUTO_SCAN.fullmatch(p.name))]
            start = max(numbers, default=0) + 1
            candidates = [f"scan_{n:03d}" for n in range(start, start + 100)]
        for candidate in candidates:
            folder = self.output_dir / candidate
            try:
                folder.mkdir()  # claims the name, also against another process
            except FileExistsError:
                continue
            try:
                write_session(folder, [(name, rgb)], [(theta, phi)], self.calibration,
                              bounds_m=self.bounds_m, segmentation=MASK_SEGMENTATION)
                (folder / OPEN_MARKER).touch()
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)   # ours, half written
                raise
            return folder
        raise ValueError(f"cannot create a scan folder in {self.output_dir}: "
                         f"{', '.join(candidates[:3])}... exist")

    def add_view(self, key, mask, theta_rad: float, phi_rad: float) -> AddedView:
        """Take one silhouette: store it in the session folder, then carve the live hull.

        Parameters
        ----------
        key : str or int
            Identifies the view (a name or a capture stamp); each key is taken once.
        mask : (H, W) bool, or 0/1 or 0/255 integers
            Silhouette, True = object, of the rig's size.
        theta_rad, phi_rad : float
            Encoder readings at the shutter, radians.

        Returns
        -------
        AddedView
            An empty mask is stored but does not carve (the reconstruction
            rejects it too).

        Raises
        ------
        DuplicateViewError
            ``key`` was already received (nothing is stored or carved).
        ValueError
            A bad key, mask or angles (nothing is stored or carved).
        """
        key = _check_key(key)
        if key in self._views:
            raise DuplicateViewError(f"view {key!r} was already received (stored as "
                                     f"{self._views[key].name}); it is not carved twice")
        mask = _check_mask(mask, self.calibration)
        theta, phi = float(theta_rad), float(phi_rad)
        camera = rig_camera(theta, phi, self.calibration)  # ValueError for unusable angles
        name = self._file_name(key)
        rgb = mask_to_rgb(mask)
        if self._session is None:
            self._session = self._open_session(name, rgb, theta, phi)
            self._view_set = read_session(self._session)
        else:
            append_view(self._session, name, rgb, theta, phi)
            self._view_set = appended_view(self._view_set, self._session, name, theta, phi)
        carved = bool(mask.any())
        # Stored as taken; carved as the ideal pinhole (the mask undistorted once).
        self._views[key] = _Received(name, np.packbits(mask, axis=None), theta, phi,
                                     self._carve_view(camera, mask) if carved else None)
        self._colour_waiting.pop(key, None)        # its image, if it came first, is a view's
        return AddedView(key=key, file=self._session / "images" / name, carved=carved,
                         reason="" if carved else "empty mask: no object to carve with",
                         n_views=len(self._views),
                         occupied_voxels=int(np.count_nonzero(self._carver.occupancy)))

    def _carve_view(self, camera, mask: np.ndarray) -> np.ndarray | None:
        """Carve the live hull with a non-empty mask (H, W) bool as ``camera`` took it,
        undistorted onto the ideal pinhole's pixel grid, and compute what the final
        reconstruction will need of it (:class:`ComputedOnArrival`): its distance image,
        its part in the coarse carve that refines the box and in the carves of the grid the
        reconstruction is expected to choose (:class:`ExpectedCarves`). The undistorted mask,
        packed, where the lens distorts (else None)."""
        ideal, undistorted = ideal_camera(camera), undistort_mask(mask, camera)
        self._carver.add_view(ideal, undistorted)
        self._precomputed.distances.add(undistorted)
        self._precomputed.box.add(ideal, undistorted)
        self._expected.add(ideal, undistorted)
        return np.packbits(undistorted, axis=None) if is_distorted(camera) else None

    def reopen(self) -> str:
        """Take up the scan that was being received (the newest session folder marked open
        in ``output_dir``): read its views back and carve them again. Returns what was done,
        for the log; nothing is taken up when no folder is open or it cannot be read (the
        next view then opens a new one).

        A view's key is taken back from its file name (a stamp key, or a name
        ending in ``.png``, as :meth:`add_view` stored it).
        """
        marked = [p.parent for p in self.output_dir.glob(f"*/{OPEN_MARKER}")
                  if p.parent.is_dir() and not p.parent.is_symlink()]
        if not marked:
            return "no open scan to take up"
        folder = max(marked, key=lambda p: (p / OPEN_MARKER).stat().st_mtime_ns)
        try:
            view_set = read_session(folder)
        except (ValueError, OSError) as exc:
            return f"open scan {folder} not taken up: {exc}"
        self.reset()
        self._session, self._view_set = folder, view_set
        for view in view_set.views:
            image = cv2.imread(str(view.image_path), cv2.IMREAD_GRAYSCALE)
            if image is None or view.theta_rad is None:
                continue
            mask = image > 127
            key = view_key_of(view.name)
            self._views[key] = _Received(view.name, np.packbits(mask, axis=None),
                                         view.theta_rad, view.phi_rad,
                                         self._carve_view(view.camera, mask) if mask.any()
                                         else None)
        return f"took up the open scan {folder} with its {len(self._views)} views"

    def add_colour_image(self, key, rgb) -> None:
        """Keep the captured image of view ``key`` (before or after its mask): the final
        mesh is coloured from the images of the views it used.

        rgb : (H, W, 3) uint8, the rig's size. Kept in memory for this scan (a
        restarted node gets the captures again from the scan node's resends). Images
        whose view has not come are kept up to
        :data:`~sfs_ros.core.exchange.limits.MAX_WAITING_BYTES` together: past that the
        oldest of them is given up (its view, when it comes, is coloured by the others).
        """
        key = _check_key(key)
        rgb = np.asarray(rgb)
        expected = (self.calibration.height, self.calibration.width, 3)
        if rgb.shape != expected or rgb.dtype != np.uint8:
            raise ValueError(f"image of view {key!r} is {rgb.shape} {rgb.dtype}, expected "
                             f"{expected} uint8 RGB (the rig's size)")
        self._colour_images[key] = rgb
        self._thumbnails[key] = thumbnail(rgb)
        if key in self._views:
            return
        self._colour_waiting.pop(key, None)
        self._colour_waiting[key] = rgb.nbytes
        waiting = sum(self._colour_waiting.values())
        for old in list(self._colour_waiting):
            if waiting <= MAX_WAITING_BYTES:
                break
            waiting -= self._colour_waiting.pop(old)
            del self._colour_images[old], self._thumbnails[old]

    def _sheet_views(self, masks: dict) -> SheetViews:
        """Every view received: its captured image (the mask where none was kept) and mask
        (``masks``: {key: (H, W) bool} of every view received)."""
        keys, received = list(self._views), list(self._views.values())
        masks = [masks[k] for k in keys]
        images = [self._colour_images[k] if k in self._colour_images else mask_to_rgb(m)
                  for k, m in zip(keys, masks)]
        return SheetViews(names=[v.name for v in received], images=images, masks=masks,
                          angles_rad=[(v.theta_rad, v.phi_rad) for v in received])

    def write_pictures(self) -> bool:
        """Write the pictures of the last :meth:`reconstruct` made with ``pictures=False``
        (then its report again, naming them); whether there were any to write. OSError
        if they cannot be written (the mesh and report stay; not tried again)."""
        due, self._pictures_due = self._pictures_due, None
        if due is None:
            return False
        due()
        return True

    def colour_image(self, key) -> tuple[str, np.ndarray] | None:
        """``(view name, (H, W, 3) uint8 RGB)`` of view ``key``: its captured image
        undistorted onto its ideal camera, as :meth:`carve` hands it over when the view
        colours the mesh; None until both the view and its image have come (or the view's
        angles were refused)."""
        key = _check_key(key)
        received, rgb = self._views.get(key), self._colour_images.get(key)
        if received is None or rgb is None:
            return None
        for view in reversed(self._view_set.views):
            if view.name == received.name:
                return view.name, undistort_image(rgb, view.camera)
        return None

    def view_mask(self, key) -> tuple[str, np.ndarray] | None:
        """``(view name, (H, W) bool)`` of view ``key``: its silhouette undistorted onto its
        ideal camera, as :meth:`carve` hands it over (the received masks are not segmented
        again); None for a view not received or with an empty mask (it carves nothing)."""
        received = self._views.get(_check_key(key))
        if received is None or not received.packed_mask.any():
            return None
        return received.name, self._ideal(received)

    def colour_images(self, names) -> dict[str, np.ndarray]:
        """{view name: (H, W, 3) uint8 RGB} of :meth:`colour_image` for the views named
        ``names`` (those not received or without an image left out)."""
        wanted = set(names)
        found = (self.colour_image(key) for key, received in self._views.items()
                 if received.name in wanted)
        return dict(item for item in found if item is not None)

    def view_masks(self, names) -> dict[str, np.ndarray]:
        """{view name: (H, W) bool} of :meth:`view_mask` for the views named ``names`` (the
        names not received or with an empty mask left out)."""
        wanted = set(names)
        return {v.name: self._ideal(v) for v in self._views.values()
                if v.name in wanted and v.packed_mask.any()}

    def _ideal(self, received: _Received) -> np.ndarray:
        return self._unpacked(received.packed_mask if received.packed_ideal is None
                              else received.packed_ideal)

    def hull_points(self, max_points: int = 100_000) -> np.ndarray:
        """(n, 3) float64 surface voxel centres of the live hull, metres (see
        :func:`surface_points`); empty (0, 3) until a non-empty mask has carved."""
        if self._carver.n_views == 0:
            return np.zeros((0, 3))
        return surface_points(self._carver.occupancy, self.grid, max_points)

    # ------------------------------------------------------------ final mesh

    def carve(self, *, resolution: int | None = None, bounds_m=None, mesher: str | None = None,
              colour: bool | None = None) -> CarvedScan:
        """The carving half of :meth:`reconstruct` on the views received so far: the hull and
        what its meshing needs (:func:`sfs_ros.core.pipeline.carve_scan`). Options as
        :meth:`reconstruct`'s; ``colour`` None or True: the images kept go with it.

        Raises ValueError: no views yet, or a carving that cannot be made."""
        if self._session is None:
            raise ValueError("no views received yet")
        view_set = self._view_set
        if bounds_m is not None:
            view_set = replace(view_set, bounds_m=as_bounds(bounds_m, what="bounds_m"))
        params = replace(self.params, resolution=resolution or self.params.resolution,
                         mesher=mesher or self.params.mesher)
        # The masks received are what segmenting their stored images gives
        # (MASK_SEGMENTATION): the pipeline takes them as they are. A view whose image
        # never came takes no part in the colour.
        images = {self._views[key].name: rgb for key, rgb in self._colour_images.items()
                  if key in self._views}
        masks = {self._views[key].name: mask for key, mask, _, _ in self.views()}
        undistorted = {v.name: self._unpacked(v.packed_ideal) for v in self._views.values()
                       if v.packed_ideal is not None}
        return carve_scan(view_set, replace(params, colour=bool(images) and colour is not False),
                          masks=masks, images=images,
                          precomputed=replace(self._precomputed, undistorted_masks=undistorted,
                                              carves=self._expected.carves,
                                              band=self._expected.band))

    def hand_over(self) -> HandOver:
        """What goes with this scan's carving: its name, session folder, views received and
        the thumbnails of the captured images kept."""
        if self._session is None:
            raise ValueError("no views received yet")
        return HandOver(scan_name=self._session.name, session_dir=str(self._session),
                        views_received=len(self._views),
                        thumbnails={self._views[key].name: jpeg
                                    for key, jpeg in self._thumbnails.items()
                                    if key in self._views})

    def reconstruct(self, name: str | None = None, *, pictures: bool = True,
                    resolution: int | None = None, bounds_m=None, mesher: str | None = None,
                    colour: bool | None = None) -> dict:
        """Run the full pipeline on the views received so far and write the mesh:
        :meth:`carve`, then :func:`sfs_ros.cell_logic.mesh_files.write_mesh`.

        Parameters
        ----------
        name : str or None
            Mesh file name inside ``output_dir`` (format from the suffix, one of
            :data:`sfs_ros.core.exchange.export.MESH_FORMATS`; see :func:`.paths.confined_path` for what
            is refused); None: ``<scan name>.ply``. The report, a picture, a viewer
            and a contact sheet go beside it (:mod:`sfs_ros.cell_logic.mesh_files`).
            Existing files are replaced.
        pictures : bool, keyword-only
            Write the picture, viewer and contact sheet now (the default); False:
            only the mesh and its report, the pictures when :meth:`write_pictures`
            is called (the report then names them).
        resolution, bounds_m, mesher : keyword-only, None = this scan's
            For this mesh only: voxels along the box's longest side, the carving box
            (2, 3) metres, the mesher. The views stored are carved again at that grid;
            what the live scan computed as the views arrived is used where it applies
            (the same mesh either way, only slower for another box).
        colour : bool or None, keyword-only
            False: no colour; None or True: coloured when images were kept (not into
            an .stl).

        Returns
        -------
        dict
            JSON-ready summary (:func:`sfs_ros.cell_logic.mesh_files.write_mesh`); its
            ``coloured_from_views`` is 0 without images (:meth:`add_colour_image`).

        Raises
        ------
        ValueError
            No views yet, a refused name, or a reconstruction that cannot be
            made (the pipeline's one-line reason).
        """
        start = time.perf_counter()
        if self._session is None:
            raise ValueError("no views received yet")
        name = name or f"{self._session.name}.ply"
        mesh_paths(self.output_dir, name)       # a refused name is refused before the work
        carved = self.carve(resolution=resolution, bounds_m=bounds_m, mesher=mesher,
                            colour=None if Path(name).suffix.lower() != ".stl" and colour
                            is not False else False)
        masks = {key: mask for key, mask, _, _ in self.views()}
        made = write_mesh(carved, self.hand_over(), self.output_dir, name, pictures=pictures,
                          sheet_views=self._sheet_views(masks))
        self._pictures_due = made.pictures_due
        self._mesh = (made.result.vertices, made.result.faces)
        self._colours = made.result.vertex_colors
        return {**made.summary, "seconds": time.perf_counter() - start}
