"""The colour images a meshing process holds, their thumbnails and the views' silhouettes
(sfs_ros.cell_logic.held_images)."""

import numpy as np

from sfs_ros.cell_logic.held_images import HeldImages
from sfs_ros.cell_logic.mesh_files import THUMBNAIL_PX, thumbnail


def _image(value: int) -> np.ndarray:
    return np.full((480, 640, 3), value, np.uint8)


def test_thumbnails_are_made_as_the_images_come_and_kept_past_the_byte_limit():
    held = HeldImages(max_bytes=_image(0).nbytes)          # room for one image
    held.add("/out/scan_001", "a.png", _image(10))
    held.add("/out/scan_001", "b.png", _image(20))
    session, images, _ = held.snapshot()
    assert session == "/out/scan_001" and list(images) == ["b.png"]
    small = held.thumbnails("/out/scan_001")
    assert sorted(small) == ["a.png", "b.png"]
    assert small["a.png"].shape == (THUMBNAIL_PX * 3 // 4, THUMBNAIL_PX, 3)
    assert np.array_equal(small["b.png"], thumbnail(_image(20)))
    assert held.thumbnails("/out/scan_000") == {}          # another scan's: none


def test_an_image_of_another_scan_replaces_those_held_and_their_thumbnails():
    held = HeldImages(max_bytes=1 << 30)
    held.add("/out/scan_001", "a.png", _image(10))
    held.add_mask("/out/scan_001", "a.png", np.ones((480, 640), bool))
    held.add("/out/scan_002", "c.png", _image(30))
    assert list(held.snapshot()[1]) == ["c.png"]
    assert list(held.thumbnails("/out/scan_002")) == ["c.png"]
    assert held.masks("/out/scan_002", ["a.png", "c.png"]) == {}


def test_silhouettes_are_held_beside_the_images_and_named_with_them():
    held = HeldImages(max_bytes=1 << 30)
    mask = np.zeros((480, 640), bool)
    mask[100:300, 200:333] = True
    held.add("/out/scan_001", "a.png", _image(10))
    held.add_mask("/out/scan_001", "a.png", mask)
    held.add("/out/scan_001", "b.png", _image(20))       # its silhouette not (yet) come
    held.add_mask("/out/scan_001", "c.png", mask)         # nor this one's image
    _, images, with_masks = held.snapshot()
    assert sorted(images) == ["a.png", "b.png"] and with_masks == ["a.png"]
    masks = held.masks("/out/scan_001", ["a.png", "b.png", "c.png"])
    assert sorted(masks) == ["a.png", "c.png"]
    assert masks["a.png"].dtype == bool and np.array_equal(masks["a.png"], mask)
    assert held.masks("/out/scan_000", ["a.png"]) == {}   # another scan's: none
