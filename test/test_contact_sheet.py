"""The contact sheet: one tile per view, mask outlines on the scaled boundary, bad views marked."""

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from sfs_ros.core.pictures.contact_sheet import (
    BACKGROUND_RGB,
    FRAME_RGB,
    OUTLINE_RGB,
    WARNING_RGB,
    SheetLayout,
    contact_sheet,
    write_contact_sheet,
)

ROOT = Path(__file__).resolve().parents[1]
W, H = 320, 240          # image size, pixels
CX, CY, R = 150, 110, 60  # the disc mask: centre and radius, pixels
GREY = 128               # the images' flat colour


def disc(radius=R, cx=CX, cy=CY) -> np.ndarray:
    rows, cols = np.mgrid[:H, :W]
    return (cols - cx) ** 2 + (rows - cy) ** 2 <= radius ** 2


def views(n: int, **overrides) -> dict:
    """Arguments of ``contact_sheet`` for ``n`` flat grey views with a disc mask, all good."""
    args = {"images": [np.full((H, W, 3), GREY, np.uint8)] * n, "masks": [disc()] * n,
            "names": [f"view_{k:03d}.png" for k in range(n)],
            "angles_rad": [(math.radians(22.5 * k), math.radians(15.0)) for k in range(n)],
            "ious": [0.97] * n}
    return {**args, **overrides}


def tile(sheet, layout: SheetLayout, k: int) -> np.ndarray:
    y, x = layout.tile_origin(k)
    return sheet[y:y + layout.tile_h, x:x + layout.tile_w]


def frame_pixels(t: np.ndarray, width: int) -> np.ndarray:
    """(n, 3) pixels of the ring ``width`` wide along the edges of a tile."""
    ring = np.ones(t.shape[:2], bool)
    ring[width:-width, width:-width] = False
    return t[ring]


def test_one_tile_per_view_in_a_grid(tmp_path):
    sheet = contact_sheet(**views(5))
    layout = SheetLayout.of([np.zeros((H, W, 3))] * 5)
    # ceil(sqrt(5)) = 3 columns, 2 rows; tiles 200 px + a 4 px frame each side, 4 px apart.
    assert (layout.columns, layout.rows, layout.box_h) == (3, 2, 150)
    assert layout.tile_w == 208 and layout.tile_h == 150 + 3 * layout.line_px + 8
    # A header line, then two rows of tiles.
    assert sheet.shape == (layout.line_px + 4 + 4 + 2 * (layout.tile_h + 4), 4 + 3 * 212, 3)
    assert sheet.dtype == np.uint8
    for k in range(5):
        assert np.all(frame_pixels(tile(sheet, layout, k), 4) == FRAME_RGB)
    assert np.all(tile(sheet, layout, 5) == BACKGROUND_RGB)  # the sixth place stays empty
    two = contact_sheet(**views(5), columns=2)
    assert two.shape[1] == 4 + 2 * 212 and SheetLayout.of([None] * 5, columns=2).rows == 3
    # The PNG holds the same pixels.
    path = write_contact_sheet(tmp_path / "sheet.png", **views(5))
    assert np.array_equal(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), sheet)


def outline_polar(image_tile: np.ndarray, layout: SheetLayout, scale: float):
    """Distances (thumbnail pixels) and angles (rad) of the outline pixels about the scaled
    disc centre."""
    box = image_tile[layout.pad_px:layout.pad_px + layout.box_h, layout.pad_px:-layout.pad_px]
    rows, cols = np.nonzero(np.all(box == OUTLINE_RGB, axis=2))
    dx, dy = cols - ((CX + 0.5) * scale - 0.5), rows - ((CY + 0.5) * scale - 0.5)  # pixel centres
    return np.hypot(dx, dy), np.arctan2(dy, dx)


def test_outline_lies_on_the_scaled_mask_boundary():
    ring = disc() & ~disc(radius=20)  # a hole, like a mug's handle, is outlined too
    sheet = contact_sheet(**views(1, masks=[ring]))
    layout = SheetLayout.of([np.zeros((H, W, 3))])
    scale = 200 / W
    distance, angle = outline_polar(tile(sheet, layout, 0), layout, scale)
    outer = distance > 2 * 20 * scale
    # Boundary pixels of a digital disc of radius r lie at (r - 1, r], those around a
    # hole of radius r at (r, r + 1]; drawn 1 px wide
    # on the thumbnail, the outline strays by at most a pixel from the scaled contour.
    assert np.all((distance[outer] >= (R - 1) * scale - 1) & (distance[outer] <= R * scale + 1))
    assert np.all((distance[~outer] >= 20 * scale - 1) & (distance[~outer] <= 21 * scale + 1))
    # Both contours are closed: every 10-degree sector holds outline pixels of each.
    for part in (outer, ~outer):
        assert len(np.unique(((angle[part] + math.pi) // math.radians(10)).astype(int))) == 36
    # Inside the outline the thumbnail is the image, unchanged (flat grey).
    box = tile(sheet, layout, 0)[4:4 + 150, 4:-4]
    assert np.all(box[round(CY * scale), round(CX * scale) + 25] == GREY)


def test_bad_and_rejected_views_are_framed_in_warning_colour():
    n = 6
    args = views(n, ious=[0.97, 0.5, None, 0.97, None, 0.91])
    args["rejected"] = [None, None, None, "silhouette inconsistent with the other views", "unreadable", None]
    args["images"] = args["images"][:4] + [None, args["images"][5]]
    args["masks"] = args["masks"][:4] + [None, args["masks"][5]]
    sheet = contact_sheet(**args, bad_iou=0.9)
    layout = SheetLayout.of(args["images"], any_rejected=True)
    assert layout.lines == 5  # two lines for the reason
    bad = [False, True, True, True, True, False]  # IoU 0.5 < 0.9, none, rejected twice
    for k in range(n):
        t = tile(sheet, layout, k)
        assert np.all(frame_pixels(t, layout.pad_px) == (WARNING_RGB if bad[k] else FRAME_RGB)), k
        band = t[layout.pad_px + layout.box_h:-layout.pad_px, layout.pad_px:-layout.pad_px]
        lines = [band[i * layout.line_px:(i + 1) * layout.line_px] for i in range(layout.lines)]
        # Name, angles and IoU lines carry text (dark or red pixels); the reason line only
        # for a rejected view; the IoU line is red exactly for bad views.
        dark = [np.count_nonzero(line.max(axis=2) < 160) for line in lines]
        red = [np.count_nonzero((line[..., 0] > 150) & (line[..., 1] < 90)) for line in lines]
        assert dark[0] > 30 and dark[1] > 30 and (dark[2] > 30) != bad[k], (k, dark)
        assert (red[2] > 30) == bad[k] and (red[3] > 30) == (args["rejected"][k] is not None)
        assert (red[4] > 30) == (k == 3)  # the long reason wraps onto a second line
    # The missing image is a grey box without an outline.
    box = tile(sheet, layout, 4)[layout.pad_px:layout.pad_px + layout.box_h, layout.pad_px:-layout.pad_px]
    assert not np.any(np.all(box == OUTLINE_RGB, axis=2))


def test_label_text_fits_and_names_the_view():
    long = "a_very_long_view_name_that_cannot_fit_in_one_tile_0001.png"
    sheet = contact_sheet(**views(2, names=["v.png", long]))
    layout = SheetLayout.of([np.zeros((H, W, 3))] * 2)

    def ink_width(line: np.ndarray) -> int:
        cols = np.nonzero((line.max(axis=2) < 160).any(axis=0))[0]
        return cols[-1] - cols[0] + 1

    bands = [tile(sheet, layout, k)[layout.pad_px + layout.box_h:-layout.pad_px,
                                    layout.pad_px:-layout.pad_px] for k in range(2)]
    # The short name is printed whole: as wide as the same text put on a blank line.
    blank = np.full((layout.line_px, 200, 3), 255, np.uint8)
    cv2.putText(blank, "v.png", (layout.pad_px, layout.baseline_px), cv2.FONT_HERSHEY_SIMPLEX,
                layout.font_scale, (0, 0, 0), 1, cv2.LINE_AA)
    assert ink_width(bands[0][:layout.line_px]) == ink_width(blank)
    # The long one is cut to the tile's text width, not much less.
    assert 0.8 * 200 < ink_width(bands[1][:layout.line_px]) <= 200 - 2 * layout.pad_px


@pytest.mark.parametrize("overrides, message", [
    ({"names": []}, "at least one view"),
    ({"ious": [0.9]}, "ious has 1 entries, names has 2"),
    ({"images": [np.zeros((H, W), np.uint8)] * 2}, r"\(H, W, 3\) uint8"),
    ({"masks": [disc()[:10]] * 2}, "mask must be"),
    ({"masks": [disc().astype(np.uint8)] * 2}, "dtype uint8"),
    ({"images": [None, None]}, "mask must be None"),
    ({"angles_rad": [(0.0,), (0.0, 1.0)]}, "theta_rad, phi_rad"),
    ({"angles_rad": [(0.0, float("nan"))] * 2}, "finite"),
    ({"ious": [1.5, 0.9]}, r"in \[0, 1\]"),
    ({"rejected": [None]}, "rejected has 1"),
    ({"columns": 0}, "columns"),
    ({"tile_px": 32}, "tile_px"),
    ({"bad_iou": 2.0}, "bad_iou"),
])
def test_bad_input_is_a_clear_error(overrides, message):
    args = views(2)
    options = {k: overrides.pop(k) for k in ("rejected", "columns", "tile_px", "bad_iou")
               if k in overrides}
    with pytest.raises(ValueError, match=message):
        contact_sheet(**{**args, **overrides}, **options)


def test_cli_writes_the_sessions_contact_sheet(tmp_path, mug_session):
    images = mug_session / "images"
    (images / "view_002.png").write_bytes(b"not a png")              # unreadable
    empty = cv2.imread(str(images / "view_010.png"))
    empty[:] = empty[0, 0]                                            # no object
    cv2.imwrite(str(images / "view_010.png"), empty)
    table = mug_session / "views.csv"
    lines = table.read_text().splitlines()
    lines[1] = "view_000.png,nan,0.3"                                 # rejected while loading
    table.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "sfs_ros.cli.reconstruct", str(mug_session), "-o", str(out / "mug.ply"),
         "-r", "48", "--contact-sheet", str(out / "sheets" / "mug.png"), "-q"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "mug.report.json").read_text())
    assert report["contact_sheet"] == str(out / "sheets" / "mug.png")
    assert {r["view"] for r in report["views"]["rejected"]} == {"view_000.png", "view_002.png",
                                                                "view_010.png"}
    sheet = cv2.cvtColor(cv2.imread(str(out / "sheets" / "mug.png")), cv2.COLOR_BGR2RGB)
    # Views in input order, then the one rejected while loading: 49 tiles, 7 x 7.
    names = [f"view_{k:03d}.png" for k in range(1, 49)] + ["view_000.png"]
    layout = SheetLayout.of([np.zeros((240, 320, 3))] * 49, any_rejected=True)
    assert sheet.shape == (layout.height, layout.width, 3) and layout.columns == 7
    ious = {p["view"]: p["silhouette_iou"] for p in report["silhouette_iou"]["per_view"]}
    for k, name in enumerate(names):
        t = tile(sheet, layout, k)
        bad = name in ("view_000.png", "view_002.png", "view_010.png") or ious[name] < 0.9
        assert np.all(frame_pixels(t, layout.pad_px) == (WARNING_RGB if bad else FRAME_RGB)), name
        outlined = np.any(np.all(t == OUTLINE_RGB, axis=2))
        assert outlined == (name not in ("view_000.png", "view_002.png", "view_010.png")), name
