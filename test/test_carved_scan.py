"""The reconstruction in two halves: carving and meshing, in one process or through a message.

The cell's carving node hands a carved scan to its meshing node as a
``sfs_ros_interfaces/CarvedScan`` message; meshing the message must give the
mesh the offline path gives, byte for byte, for every mesher and with colour.
"""

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from sfs_ros.cell_logic.mesh_files import THUMBNAIL_PX, thumbnail
from sfs_ros.core.exchange.views import read_image
from sfs_ros.core.mesh_scan import mesh_scan
from sfs_ros.core.meshing.meshers import MESHERS, mesher
from sfs_ros.core.pipeline import ReconstructionParams, carve_scan, reconstruct
from sfs_ros.ros.carved_scan_msg import (
    HandOver,
    carried_images,
    carved_scan_from_msg,
    carved_scan_to_msg,
    view_mask_from_msg,
    view_mask_msg,
)
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg
from sfs_ros_interfaces.msg import ViewImage

HAND_OVER = HandOver(scan_name="scan_007", session_dir="/data/scan_007", views_received=24,
                     frame_id="sfs_turntable")
#: A thumbnail is a JPEG of quality 90 on the wire: mean |error| per channel (0..255) on the
#: rendered mug's image, scaled down as the carving node does; a few units, far from the
#: 128 of an unrelated image.
THUMBNAIL_ERROR_MAX = 4.0


def _without_times(report: dict) -> str:
    return json.dumps({k: v for k, v in report.items() if k != "timings_s"})


@pytest.fixture(scope="module", params=list(MESHERS))
def halves(request, mug_views):
    """(offline reconstruction, the carving, the carving through a serialised message)."""
    params = ReconstructionParams(resolution=64, mesher=request.param, colour=True)
    carved = carve_scan(mug_views, params)
    wire = serialize_message(carved_scan_to_msg(carved, HAND_OVER, stamp=_stamp()))
    received, hand_over = carved_scan_from_msg(deserialize_message(wire, CarvedScanMsg))
    return reconstruct(mug_views, params), carved, received, hand_over, len(wire)


def _stamp() -> Time:
    return Time(sec=12, nanosec=34)


def test_meshing_the_message_gives_the_offline_mesh_byte_for_byte(halves):
    offline, _, received, _, _ = halves
    result = mesh_scan(received)
    assert result.vertices.tobytes() == offline.vertices.tobytes()
    assert result.faces.tobytes() == offline.faces.tobytes()
    assert offline.vertex_colors is not None
    assert result.vertex_colors.tobytes() == offline.vertex_colors.tobytes()
    assert _without_times(result.report) == _without_times(offline.report)


def test_the_message_carries_the_carving_exactly(halves):
    _, carved, received, hand_over, _ = halves
    assert replace(hand_over, thumbnails={}) == HAND_OVER and hand_over.thumbnails == {}
    assert np.array_equal(received.occupancy, carved.occupancy)
    assert received.grid.shape == carved.grid.shape
    assert received.grid.voxel_size == carved.grid.voxel_size
    assert [(v.name, v.role, v.angles_rad) for v in received.views] == \
        [(v.name, v.role, v.angles_rad) for v in carved.views]
    assert all(v.angles_rad is not None for v in carved.views)
    for got, sent in zip(received.views, carved.views):
        assert np.array_equal(got.camera.K, sent.camera.K)
        assert np.array_equal(got.camera.R, sent.camera.R)
        assert np.array_equal(got.camera.t, sent.camera.t)
    assert all(np.array_equal(a, b) for a, b in zip(received.masks, carved.masks))
    assert received.colour_views == carved.colour_views and carved.colour_views
    assert all(np.array_equal(a, b) for a, b in zip(received.colour_images,
                                                     carved.colour_images))
    assert received.taken == {}          # the masks as taken stay with the carving


def test_the_message_is_sized_for_the_wire(halves):
    """A bit a voxel of the occupied box, a bit a pixel of each mask (and of each colour
    view's silhouette as carved where the fusion repaired it), the colour images raw, the
    mesher's input as it is (but the band's voxels, which the meshing finds again): within
    10 % of that sum (headers, names, report)."""
    _, carved, _, _, size = halves
    lo = np.argwhere(carved.occupancy).min(axis=0)
    hi = np.argwhere(carved.occupancy).max(axis=0) + 1
    pixels = carved.masks[0].size
    mesher_input = carved.mesher_input
    repaired = sum(not np.array_equal(mask, carved.masks[i])
                   for i, mask in zip(carved.colour_views, carved.colour_masks))
    payload = (np.prod(hi - lo) / 8 + (len(carved.masks) + repaired) * pixels / 8
               + len(carved.colour_views) * pixels * 3
               + sum(np.asarray(a).nbytes for name, a in vars(mesher_input).items()
                     if isinstance(a, np.ndarray) and name != "voxels"))
    assert payload <= size <= 1.1 * payload + 64_000


def test_thumbnails_cross_for_the_contact_sheet(halves, mug_views):
    _, carved, _, _, _ = halves
    name = carved.views[3].name
    image = thumbnail(read_image(next(v for v in mug_views.views if v.name == name).image_path))
    assert image.shape[1] == THUMBNAIL_PX
    msg = carved_scan_to_msg(carved, replace(HAND_OVER, thumbnails={name: image}),
                             stamp=_stamp())
    _, hand_over = carved_scan_from_msg(deserialize_message(serialize_message(msg),
                                                            CarvedScanMsg))
    [(got_name, got)] = hand_over.thumbnails.items()
    assert got_name == name and got.shape == image.shape
    assert np.abs(got.astype(int) - image).mean() <= THUMBNAIL_ERROR_MAX


def test_thumbnails_of_the_images_the_receiver_holds_are_left_out_and_its_own_taken(
        halves, mug_views):
    """The receiver makes the thumbnails of the images it holds (as they come): the carved
    scan carries only the others'."""
    _, carved, _, _, _ = halves
    held_name, other = carved.views[3].name, carved.views[5].name
    images = {v.name: thumbnail(read_image(v.image_path)) for v in mug_views.views
              if v.name in (held_name, other)}
    msg = carved_scan_to_msg(carved, replace(HAND_OVER, thumbnails=images), stamp=_stamp(),
                             held=frozenset({held_name}))
    sent = {v.name: len(v.thumbnail_jpeg) for v in msg.views}
    assert sent[held_name] == 0 and sent[other] > 0
    own = np.full_like(images[held_name], 7)
    _, hand_over = carved_scan_from_msg(msg, {held_name: carved.colour_images[0]},
                                        {held_name: own})
    assert set(hand_over.thumbnails) == {held_name, other}
    assert hand_over.thumbnails[held_name] is own
    assert np.abs(hand_over.thumbnails[other].astype(int) - images[other]).mean() \
        <= THUMBNAIL_ERROR_MAX


def test_images_the_receiver_holds_are_left_out_and_the_mesh_is_the_same(halves):
    """The meshing node holds the colour images the carving node sent as the views were
    stored: the carved scan leaves those out, and meshing it with them gives the mesh
    the offline path makes; the message shrinks by the images' bytes."""
    offline, carved, _, _, full_size = halves
    held = {carved.views[i].name: image for i, image in zip(carved.colour_views,
                                                              carved.colour_images)}
    kept_back = next(iter(held))                    # one image the receiver missed
    held_names = frozenset(held) - {kept_back}
    wire = serialize_message(carved_scan_to_msg(carved, HAND_OVER, stamp=_stamp(),
                                                held=held_names))
    msg = deserialize_message(wire, CarvedScanMsg)
    sent = {v.name: (v.image_held, len(v.image_rgb)) for v in msg.views}
    assert all(sent[name] == (True, 0) for name in held_names)
    assert sent[kept_back] == (False, held[kept_back].size)
    assert full_size - len(wire) == sum(held[name].nbytes for name in held_names)
    received, _ = carved_scan_from_msg(msg, {name: held[name] for name in held_names})
    result = mesh_scan(received)
    assert result.vertices.tobytes() == offline.vertices.tobytes()
    assert result.vertex_colors.tobytes() == offline.vertex_colors.tobytes()
    missing = sorted(held_names)[0]
    with pytest.raises(ValueError, match=re.escape(f"view {missing!r}'s image was left out")):
        carved_scan_from_msg(msg, {n: held[n] for n in held_names if n != missing})


def test_every_views_image_crosses_when_asked_and_colours_nothing_more(halves, mug_views):
    """The refinement reads the image of every view used: given them all, the carved scan
    carries each (but those the receiver holds), :func:`carried_images` gives back every
    one bit for bit, and the mesh and its colours stay the offline path's."""
    offline, carved, _, _, _ = halves
    used = [view.name for view in carved.views if view.role == "used"]
    colour_names = {carved.views[i].name for i in carved.colour_views}
    # Any images of the right size will do: these are the views' own files.
    images = {v.name: read_image(v.image_path) for v in mug_views.views if v.name in used}
    further = [name for name in used if name not in colour_names]
    assert further                                  # the mug has views that colour nothing
    held_name = further[0]
    msg = deserialize_message(serialize_message(carved_scan_to_msg(
        carved, HAND_OVER, stamp=_stamp(), images=images, held=frozenset({held_name}))),
        CarvedScanMsg)
    sent = {v.name: (v.image_held, len(v.image_rgb)) for v in msg.views}
    assert sent[held_name] == (True, 0)
    assert all(sent[name] == (False, images[name].size) for name in further[1:])
    got = carried_images(msg, {held_name: images[held_name]})
    assert sorted(got) == sorted(used)
    colour_images = {carved.views[i].name: image
                     for i, image in zip(carved.colour_views, carved.colour_images)}
    for name in used:
        expected = colour_images.get(name, images[name])
        assert got[name].tobytes() == np.asarray(expected, np.uint8).tobytes(), name
    received, _ = carved_scan_from_msg(msg, {held_name: images[held_name]})
    result = mesh_scan(received)
    assert result.vertices.tobytes() == offline.vertices.tobytes()
    assert result.vertex_colors.tobytes() == offline.vertex_colors.tobytes()
    with pytest.raises(ValueError, match=re.escape(f"view {held_name!r}'s image was left out")):
        carried_images(msg)


def test_silhouettes_the_receiver_holds_are_left_out_and_the_mesh_is_the_same(halves):
    """The meshing node holds each view's silhouette as the carving node sent it when the
    view was stored: the carved scan leaves out those that are the carving's, and a
    colour view's silhouette as carved where it is the view's (the fusion repaired
    nothing); meshing it gives the mesh the offline path makes."""
    offline, carved, _, _, full_size = halves
    masks = {view.name: mask for view, mask in zip(carved.views, carved.masks)}
    other = carved.views[1].name                     # one the receiver holds another of
    held = {**masks, other: ~masks[other]}
    kept_back = carved.views[0].name                 # and one it missed
    del held[kept_back]
    wire = serialize_message(carved_scan_to_msg(carved, HAND_OVER, stamp=_stamp(),
                                                masks_held=held))
    msg = deserialize_message(wire, CarvedScanMsg)
    sent = {v.name: len(v.mask_bits) for v in msg.views}
    packed = (masks[kept_back].size + 7) // 8
    assert sent[kept_back] == packed and sent[other] == packed
    assert all(sent[name] == 0 for name in held if name != other)
    assert all(len(msg.views[i].colour_mask_bits) == 0 for i in carved.colour_views
               if np.array_equal(carved.colour_masks[carved.colour_views.index(i)],
                                 carved.masks[i]))
    assert full_size - len(wire) == (len(held) - 1) * packed
    received, _ = carved_scan_from_msg(msg, masks_held={n: masks[n] for n in held})
    for got, mask in zip(received.masks, carved.masks):
        assert np.array_equal(got, mask)
    for got, mask in zip(received.colour_masks, carved.colour_masks):
        assert np.array_equal(got, mask)
    result = mesh_scan(received)
    assert result.vertices.tobytes() == offline.vertices.tobytes()
    assert result.vertex_colors.tobytes() == offline.vertex_colors.tobytes()
    assert _without_times(result.report) == _without_times(offline.report)
    missing = sorted(set(held) - {other})[0]
    with pytest.raises(ValueError, match=re.escape(f"view {missing!r}'s mask_bits was left "
                                                   "out as held")):
        carved_scan_from_msg(msg, masks_held={n: masks[n] for n in held if n != missing})


def test_a_view_mask_message_carries_the_silhouette_and_refuses_anything_else(halves):
    _, carved, _, _, _ = halves
    mask = carved.masks[0]
    msg = view_mask_msg("/data/scan_007", "v000.png", mask, header=Header())
    session, name, got = view_mask_from_msg(deserialize_message(serialize_message(msg),
                                                                ViewImage))
    assert (session, name) == ("/data/scan_007", "v000.png")
    assert got.dtype == bool and np.array_equal(got, mask)
    msg.image.data[0] = 7
    with pytest.raises(ValueError, match="expected only 0 and 255"):
        view_mask_from_msg(msg)
    msg.image.encoding = "rgb8"
    with pytest.raises(ValueError, match="expected a named, packed mono8 image"):
        view_mask_from_msg(msg)


def test_a_message_that_does_not_add_up_is_refused_by_name(halves):
    _, carved, _, _, _ = halves
    msg = carved_scan_to_msg(carved, HAND_OVER, stamp=_stamp())
    msg.views[0].mask_bits = msg.views[0].mask_bits[:-1]
    with pytest.raises(ValueError, match="mask_bits has .* bytes, expected"):
        carved_scan_from_msg(msg)
    msg = carved_scan_to_msg(carved, HAND_OVER, stamp=_stamp())
    msg.mesher = "poisson"
    with pytest.raises(ValueError, match="mesher 'poisson' is not one of"):
        carved_scan_from_msg(msg)


def test_every_mesher_has_two_halves_and_takes_its_own_options():
    for name, entry in MESHERS.items():
        assert mesher(name) is entry and callable(entry.prepare) and callable(entry.mesh)
        defaults = {option.name: option.default for option in entry.options}
        assert entry.option_values({}) == defaults
        assert ReconstructionParams(mesher=name, mesher_options=defaults).mesher_options == defaults
    with pytest.raises(ValueError, match="mesher must be one of"):
        mesher("poisson")


def test_a_deferred_evaluation_answers_the_held_out_views_and_completes_the_report_later(
        mug_views):
    held_out = mug_views.views[5].name
    carved = carve_scan(mug_views, ReconstructionParams(resolution=48, colour=True,
                                                        holdout=(held_out,)))
    at_once = mesh_scan(carved)
    later = mesh_scan(carved, defer_evaluation=True)
    assert at_once.evaluation_due is None and later.evaluation_due is not None
    # The mesh and its colours do not wait; the held-out view's IoU (the answer's
    # holdout_iou) is there, the others' come with the call.
    assert later.vertices.tobytes() == at_once.vertices.tobytes()
    assert later.vertex_colors.tobytes() == at_once.vertex_colors.tobytes()
    before = later.report["silhouette_iou"]
    iou = {v["view"]: v["silhouette_iou"] for v in before["per_view"]}
    assert iou.pop(held_out) is not None and set(iou.values()) == {None}
    assert before["mean_used"] is None
    assert before["mean_held_out"] == at_once.report["silhouette_iou"]["mean_held_out"]
    later.evaluation_due()
    assert later.evaluation_due is None
    assert later.report["silhouette_iou"] == at_once.report["silhouette_iou"]
    assert _without_times(later.report) == _without_times(at_once.report)
