"""Rebuilding the views of a bag as the carving node received them.

:func:`read_bag` gives the masks with their joint states, paired by stamp, one
by one, in recorded order, to a :class:`~sfs_ros.cell_logic.live_reconstruction.LiveReconstruction`
built from the recorded reconstruction parameters, exactly as the
carving node did; its session folder (in a temporary folder, removed
with the view set) is then read as any session. A bag holding several scans
gives its last (as the node, the scan node resetting it at each ``scan/start``):
scans are told apart by the recorder's ``sfs/scan`` records
(:mod:`.layout`); in a bag without them (recorded before they existed), by the
scan number in the scan node's diagnostics. A bag with captures but no masks has its
images segmented with the recorded segmentation parameters first, as the
segmentation node did. Unlike the nodes' bounded buffers, the reader pairs any
two halves of a view however far apart they are in the bag. A recording
started after a scan began lacks that scan's earlier views (``with_scan`` in
the recorder starts in time).
"""

from __future__ import annotations

import json
import logging
import shutil
import struct
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.exchange.session import read_session, write_session
from ...core.exchange.views import ViewError, ViewSet
from ...core.geometry.rig import RigCalibration
from ...core.segmentation.segment import SegmentationParams, segment
from ...core.settings import RESOLUTION
from ..live_reconstruction import DuplicateViewError, LiveReconstruction
from ..message_fields import angles_from_joint_state, msg_to_image, scan_report, stamp_key, view_key
from .layout import PARAMETERS_FORMAT, PARAMETERS_TOPIC, SCAN_TOPIC, STORE, TOPICS
from .reading import Bag, BagMessage, open_bag

__all__ = ["BagViewSet", "read_bag"]

#: Image encodings taken: masks are mono8 (0 / 255); captures RGB, BGR or grey.
MASK_ENCODINGS, CAPTURE_ENCODINGS = ("mono8",), ("rgb8", "bgr8", "mono8")

_log = logging.getLogger(__name__)


@dataclass
class BagViewSet(ViewSet):
    """The views of a bag (:func:`read_bag`): a :class:`ViewSet` plus the recorded
    carving node's ``resolution`` and ``mesher``."""

    resolution: int | None = None
    mesher: str | None = None

    @property
    def recorded_settings(self) -> dict:
        """The recorded ``resolution`` and ``mesher`` (those the bag has)."""
        recorded = {"resolution": self.resolution, "mesher": self.mesher}
        return {name: value for name, value in recorded.items() if value is not None}


def _decode(message: BagMessage, expected: str):
    """The message deserialized; ValueError if it is of another type or its bytes are not
    a valid CDR message of its type."""
    if message.msgtype != expected:
        raise ValueError(f"type {message.msgtype}, expected {expected}")
    try:
        return STORE.deserialize_cdr(message.data, message.msgtype)
    except Exception as exc:  # noqa: BLE001 - corrupt bytes: SerdeError, IndexError, SystemError...
        raise ValueError(f"its {len(message.data)} bytes are not a valid {expected} message "
                         f"({type(exc).__name__}: {str(exc)[:120]})") from None


def _parameters(bag: Bag) -> dict:
    """The last recorded parameters document; ViewError if there is none usable."""
    topic = bag.topic(PARAMETERS_TOPIC)
    documents = list(bag.messages([topic])) if topic else []
    if not documents:
        raise ViewError(f"bag {bag.path} has no {PARAMETERS_TOPIC} message: expected a bag "
                        "recorded by sfs-recorder, which stores the rig calibration there")
    try:
        document = json.loads(_decode(documents[-1], TOPICS[PARAMETERS_TOPIC][0]).data)
    except ValueError as exc:
        raise ViewError(f"bag {bag.path}: {PARAMETERS_TOPIC} is not readable: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != PARAMETERS_FORMAT \
            or document.get("version") != 1:
        raise ViewError(f"bag {bag.path}: {PARAMETERS_TOPIC} is not a {PARAMETERS_FORMAT} "
                        "version 1 document")
    if "session" not in document or "reconstruction" not in document:
        why = document.get("unavailable", {}).get("reconstruction", "not recorded")
        raise ViewError(f"bag {bag.path} has no parameters of the carving node ({why}); "
                        "expected them to place the cameras")
    return document


def _check_resolution(value) -> None:
    """TypeError / ValueError unless ``value`` is a resolution the carving node takes
    (an int in :data:`~sfs_ros.core.settings.RESOLUTION`'s range)."""
    low, high = RESOLUTION.bounds
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"reconstruction resolution is {value!r}, not an integer")
    if not low <= value <= high:
        raise ValueError(f"reconstruction resolution {value} is outside {low}..{high}")


def _image(msg, encodings: tuple[str, ...]) -> np.ndarray:
    """(H, W, 3) RGB or (H, W) uint8 array of a deserialized ``sensor_msgs/Image`` whose
    encoding is one of ``encodings``."""
    if msg.encoding not in encodings:
        raise ValueError(f"image encoding is {msg.encoding!r}, expected one of {list(encodings)}")
    return msg_to_image(msg)


class _Views:
    """Feeds the bag's views to a LiveReconstruction as the nodes would; notes rejections."""

    def __init__(self, bag: Bag, document: dict, pair: tuple[str, str], folder: Path, *,
                 captures: bool = False):
        try:
            session, recon = document["session"], document["reconstruction"]
            nodes = document.get("nodes", {})
            scan = nodes.get("scan", {})
            self.resets = scan.get("reset_reconstruction", True)
            if not isinstance(self.resets, bool):
                raise TypeError(f"scan reset_reconstruction is {self.resets!r}, not a bool")
            calibration = RigCalibration.from_dict(session["rig"])
            self.segmentation = None
            if pair[0] == "capture/image" and not captures:
                self.segmentation = SegmentationParams.from_dict(session["segmentation"]) \
                    if session.get("segmentation") is not None else SegmentationParams()
            _check_resolution(recon["resolution"])
            # The live grid only stores the views here (the reconstruction is made from the
            # session folder at the resolution asked for): the smallest there is.
            self.live = LiveReconstruction(calibration, session["bounds_m"], output_dir=folder,
                                           resolution=RESOLUTION.bounds[0],
                                           mesher=recon["mesher"])
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            # Recorded parameters of the wrong shape (not mappings where mappings belong).
            raise ViewError(f"bag {bag.path}: the recorded parameters cannot be used: "
                            f"{type(exc).__name__}: {str(exc)[:200]}") from None
        if self.segmentation is not None and session.get("segmentation") is None:
            _log.warning(f"bag {bag.path}: no recorded segmentation parameters; segmenting the "
                         "captures with the defaults")
        self.pair = pair
        self.waiting: dict[str, dict] = {pair[0]: {}, pair[1]: {}}   # stamp -> half
        self.bad: set = set()                                         # stamps given up
        self.rejected: dict[str, str] = {}
        self.scans: list[tuple[Path, int]] = []     # scans' session folders and view counts
        self._scan = None
        # With ``captures``: the last scan's images as they were taken, not its masks.
        self.captures: dict[str, tuple[np.ndarray, tuple[float, float]]] | None = \
            {} if captures else None
        self._folder, self._calibration, self._session = folder, calibration, session

    def take(self, name: str, message: BagMessage) -> None:
        if name in (SCAN_TOPIC, "diagnostics"):
            self._scan_number(name, message)
            return
        try:
            msg = _decode(message, TOPICS[name][0])
            stamp = stamp_key(msg.header.stamp)
        except (ValueError, KeyError, IndexError, struct.error) as exc:
            self.rejected[f"{name} at {message.log_time_ns} ns"] = f"unreadable: {exc}"
            return
        if stamp in self.bad:
            return
        masks = self.segmentation is None and self.captures is None
        try:
            item = angles_from_joint_state(msg) if name == self.pair[1] else _image(
                msg, MASK_ENCODINGS if masks else CAPTURE_ENCODINGS)
        except ValueError as exc:                    # its capture is given up, as the node does
            self.bad.add(stamp)
            for halves in self.waiting.values():
                halves.pop(stamp, None)
            self.rejected[view_key(stamp)] = f"malformed {name}: {exc}"
            return
        other = self.pair[1] if name == self.pair[0] else self.pair[0]
        partner = self.waiting[other].pop(stamp, None)
        if partner is None:
            self.waiting[name][stamp] = item         # a newer copy replaces a waiting one
        elif name == self.pair[0]:
            self._add(stamp, item, partner)
        else:
            self._add(stamp, partner, item)

    def _add(self, stamp, image: np.ndarray, angles: tuple[float, float]) -> None:
        if self.captures is not None:
            rgb = image if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)
            self.captures.setdefault(view_key(stamp), (rgb, angles))    # a resend: kept once
            return
        try:
            mask = image if self.segmentation is None else segment(image, self.segmentation).mask
            self.live.add_view(view_key(stamp), mask, *angles)
        except DuplicateViewError:
            pass                                     # a capture sent again: stored once
        except ValueError as exc:
            self.rejected[view_key(stamp)] = str(exc)

    def _scan_number(self, name: str, message: BagMessage) -> None:
        """A new scan number (an ``sfs/scan`` record, or in an older bag the scan node's
        diagnostics): the scan node reset the reconstruction."""
        try:
            decoded = _decode(message, TOPICS[name][0])
        except (ValueError, KeyError, IndexError, struct.error):
            return
        if name == SCAN_TOPIC:
            scan = int(decoded.data)
        else:
            report = scan_report(decoded)
            if report is None:
                return
            scan = report[0]
        if self._scan is not None and scan != self._scan and self.resets:
            if self.live.n_views:
                self.scans.append((self.live.session_dir, self.live.n_views))
            self.live.reset()
            self.rejected.clear()
            if self.captures is not None:
                self.captures = {}
        self._scan = scan

    def finish(self) -> None:
        """Halves still waiting for their partner are rejected views."""
        for name, other in (self.pair, self.pair[::-1]):
            for stamp in self.waiting[name]:
                self.rejected.setdefault(view_key(stamp), f"{name} without {other} of the same "
                                                      "stamp in the bag")
        if self.live.n_views:
            self.scans.append((self.live.session_dir, self.live.n_views))
        if self.captures:
            names = [f"{key}.png" for key in self.captures]
            folder = write_session(self._folder / "captures",
                                   [(n, rgb) for n, (rgb, _) in zip(names, self.captures.values())],
                                   [angles for _, angles in self.captures.values()],
                                   self._calibration, bounds_m=self._session.get("bounds_m"),
                                   segmentation=self._session.get("segmentation"))
            self.scans.append((folder, len(names)))


def _checked(bag: Bag, name: str) -> str | None:
    """The absolute name of relative topic ``name`` if the bag has it with messages;
    ViewError if it has another type than :data:`TOPICS` says."""
    topic = bag.topic(name)
    if topic is None or not bag.counts.get(topic):
        return None
    if bag.topics[topic] != TOPICS[name][0]:
        raise ViewError(f"bag {bag.path}: topic {topic} has type {bag.topics[topic]}, "
                        f"expected {TOPICS[name][0]}")
    return topic


def _view_topics(bag: Bag) -> tuple[str, str]:
    """``(images, joint states)`` relative topics of the views: the masks, else the captures."""
    for images, joints in (("capture/mask", "capture/mask_joint_state"),
                           ("capture/image", "capture/joint_state")):
        topic = _checked(bag, images)
        if topic is None:
            continue
        if _checked(bag, joints) is None:
            raise ViewError(f"bag {bag.path} has {bag.counts[topic]} messages on {topic} but "
                            f"none on {bag.namespace}/{joints}: expected the joint states "
                            "(turntable and carriage angles) under the same stamps")
        return images, joints
    raise ViewError(f"bag {bag.path} holds no views: no messages on capture/mask nor "
                    f"capture/image under namespace '{bag.namespace or '/'}' (topics: "
                    f"{', '.join(sorted(bag.topics)) or 'none'})")


def _capture_topics(bag: Bag) -> tuple[str, str]:
    """``(images, joint states)`` relative topics of the captured images: a board scan's
    (``calibration/*``), else the object's (``capture/*``; a board scanned as an object in
    bags recorded before board scans had their own topics)."""
    for pair in (("calibration/image", "calibration/joint_state"),
                 ("capture/image", "capture/joint_state")):
        if _checked(bag, pair[0]) is not None:
            return pair
    raise ViewError(f"bag {bag.path} holds no captured images on calibration/image nor "
                    "capture/image")


def read_bag(path, *, captures: bool = False) -> BagViewSet:
    """The views of the bag at ``path`` (a rosbag2 folder, or its .mcap / .db3 file), as
    the carving node received them (module docstring); with ``captures``, the
    last scan's captured images with their angles instead (for calibration and export
    to other tools): a board scan's on ``calibration/image`` when the bag has them, else
    those on ``capture/image``.

    Returns
    -------
    BagViewSet
        ``source="session"`` (read from the session folder the views were stored in);
        ``calibration``, ``bounds_m`` from the recorded reconstruction parameters,
        ``segmentation`` the one that leaves stored masks unchanged; ``rejected``
        holds the views the node would have refused or that the bag lacks a half of;
        ``resolution`` and ``mesher`` the node's.

    Raises
    ------
    ViewError
        One line: not a bag, no recorded parameters, no views, a topic of the wrong
        type, images without their joint-state topic. A bag that ends early gives
        the views read before its end and a warning (logging).
    """
    bag = open_bag(path)
    for topic, msgtype in sorted(bag.topics.items()):
        if msgtype not in STORE.types:
            _log.warning(f"bag {bag.path}: topic {topic} has type {msgtype}, unknown here: "
                         "skipped")
    document = _parameters(bag)
    pair = _capture_topics(bag) if captures else _view_topics(bag)
    # Scans are told apart by the sfs/scan records; in bags without them, by diagnostics.
    scans = SCAN_TOPIC if _checked(bag, SCAN_TOPIC) else "diagnostics"
    names = [*pair, scans] if _checked(bag, scans) else list(pair)
    folder = Path(tempfile.mkdtemp(prefix="sfs_bag_"))
    try:
        views = _Views(bag, document, pair, folder, captures=captures)
        for message in bag.messages([bag.topic(n) for n in names]):
            views.take(bag.relative(message.topic), message)
        views.finish()
        if not views.scans:
            first = next(iter(views.rejected.items()), None)
            detail = f"; first rejected: {first[0]}: {first[1]}" if first else ""
            raise ViewError(f"bag {bag.path} holds no usable view on {pair[0]} with "
                            f"{pair[1]}{detail}")
        session, n_views = views.scans[-1]
        if len(views.scans) > 1:
            earlier = sum(n for _, n in views.scans[:-1])
            _log.warning(f"bag {bag.path} holds {len(views.scans)} scans: using the last "
                         f"({n_views} views), not the {earlier} views of the earlier ones")
        loaded = read_session(session)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    recon = document["reconstruction"]
    view_set = BagViewSet(views=loaded.views, source=loaded.source, bounds_m=loaded.bounds_m,
                          segmentation=loaded.segmentation, calibration=loaded.calibration,
                          rejected=[*views.rejected.items(), *loaded.rejected],
                          resolution=recon["resolution"], mesher=recon["mesher"])
    weakref.finalize(view_set, shutil.rmtree, folder, True)
    return view_set
