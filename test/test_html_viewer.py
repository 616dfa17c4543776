"""The HTML viewer: a self-contained page, and what headless Chromium (Debian's package) draws.

Every page is opened twice: with WebGL (software, SwiftShader) and with WebGL
disabled, so the 2-D canvas fallback draws it. The expected pixels follow from
the page's camera in closed form (:func:`project`).
"""

import base64
import json
import math
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from sfs_ros.core.pictures.html_viewer import (
    AMBIENT,
    BACKGROUND_RGB,
    DEFAULT_RGB,
    FIT,
    FOV_RAD,
    HOME_AZIMUTH_RAD,
    HOME_ELEVATION_RAD,
    html_viewer,
    write_html_viewer,
)

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync",
                  "--virtual-time-budget=5000"]  # animation frames (redraws) run; idle time is free
RENDERER_FLAGS = {"WebGL": ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
                  "Canvas 2D": ["--disable-webgl"]}
#: Portrait window: the mesh fits the width, clear of the two info lines at the top.
WIDTH, HEIGHT = 320, 480
INFO_ROWS = 80  # rows 0..79 may hold the info text


def chromium() -> str:
    path = shutil.which("chromium")
    if path is None:
        pytest.fail("chromium is not installed: run `bash scripts/setup.sh --test` "
                    "(it installs Debian's chromium package)", pytrace=False)
    return path


def screenshot(page: Path, renderer: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB screenshot of ``page``, checking ``renderer`` drew it."""
    with tempfile.TemporaryDirectory(dir=page.parent) as tmp:
        png = Path(tmp) / "shot.png"
        profile = Path(tmp) / "profile"
        profile.mkdir()
        done = subprocess.run(
            [chromium(), *CHROMIUM_FLAGS, *RENDERER_FLAGS[renderer], f"--user-data-dir={profile}",
             f"--screenshot={png}", f"--window-size={WIDTH},{HEIGHT}", "--dump-dom",
             page.as_uri()], capture_output=True, text=True, timeout=120)
        assert png.exists(), f"no screenshot (exit {done.returncode}): {done.stderr[-2000:]}"
        assert f'data-renderer="{renderer}"' in done.stdout, done.stdout[-2000:]
        return cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)


def object_pixels(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels differing from the background (the info rows blanked out)."""
    out = np.abs(image.astype(int) - BACKGROUND_RGB).max(axis=2) > 12
    out[:INFO_ROWS] = False
    return out


def frame(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Orbit centre (bounding-box centre) and bounding-sphere radius about it, metres."""
    center = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    return center, float(np.linalg.norm(vertices - center, axis=1).max())


def project(points, vertices, *, az=HOME_AZIMUTH_RAD, el=HOME_ELEVATION_RAD, zoom=1.0,
            width=WIDTH, height=HEIGHT) -> np.ndarray:
    """(n, 2) pixel (column, row) of object-frame ``points`` (n, 3) in the page's view.

    Perspective camera at azimuth ``az`` and elevation ``el`` (radians) about the
    orbit centre, Z up on screen, at the distance where the bounding sphere of
    ``vertices`` spans FIT of the smaller window side, divided by ``zoom``.
    """
    center, radius = frame(vertices)
    t = math.tan(FOV_RAD / 2)
    d = radius / math.sin(math.atan(FIT * min(width, height) / height * t)) / zoom
    back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.cross([0, 0, 1], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    rel = np.asarray(points, float) - (center + d * back)
    depth = -rel @ back
    x = (rel @ right) / depth / t * height / width
    y = (rel @ up) / depth / t
    # NDC to pixel indices: pixel i covers [i, i + 1).
    return np.column_stack([(1 + x) * width / 2 - 0.5, (1 - y) * height / 2 - 0.5])


def sphere_headlight(offset_px: float, sphere) -> float:
    """n . l where the ray ``offset_px`` right of the window centre meets ``sphere`` (centred)."""
    _, radius = frame(sphere.vertices)
    t = math.tan(FOV_RAD / 2)
    d = radius / math.sin(math.atan(FIT * min(WIDTH, HEIGHT) / HEIGHT * t))
    cos_a = 1 / math.hypot(1, offset_px * 2 * t / HEIGHT)  # angle between the ray and the axis
    s = d * cos_a - math.sqrt(radius ** 2 - d ** 2 * (1 - cos_a ** 2))  # eye to the surface
    return (d - s * cos_a) / radius


def dominant(image: np.ndarray, channel: int) -> np.ndarray:
    """(H, W) bool: pixels whose ``channel`` is over 3x each other one (a shaded pure colour)."""
    rgb = image.astype(float)
    others = np.delete(rgb, channel, axis=2).max(axis=2)
    return (rgb[..., channel] > 40) & (rgb[..., channel] > 3 * others)


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    mesh.apply_translation((0.1, -0.2, 0.3))  # anywhere: the view centres it
    return mesh


@pytest.mark.parametrize("renderer", ["WebGL", "Canvas 2D"])
def test_sphere_is_centred_framed_and_lit_from_the_eye(tmp_path, sphere, renderer):
    page = write_html_viewer(tmp_path / "sphere.html", sphere.vertices, sphere.faces)
    image = screenshot(page, renderer)
    assert image.shape == (HEIGHT, WIDTH, 3)
    inside = object_pixels(image)
    corners = [image[-20:, :20], image[-20:, -20:], image[INFO_ROWS:INFO_ROWS + 20, -20:]]
    assert all(np.all(c == BACKGROUND_RGB) for c in corners)

    # Centred on the orbit axis, the sphere's silhouette is a disc of radius FIT * 160 px.
    rows, cols = np.nonzero(inside)
    radius_px = FIT * min(WIDTH, HEIGHT) / 2
    assert abs(cols.mean() - (WIDTH / 2 - 0.5)) < 1.0 and abs(rows.mean() - (HEIGHT / 2 - 0.5)) < 1.0
    # The polyhedron lies between its insphere and the sphere (its vertices are on it);
    # anti-aliased edge pixels add up to about a pixel.
    inradius = np.abs(np.einsum("ij,ij->i", sphere.face_normals,
                                sphere.triangles[:, 0] - sphere.center_mass)).min()
    measured = math.sqrt(inside.sum() / math.pi)
    assert radius_px * inradius / 0.05 - 1.0 <= measured <= radius_px + 1.0

    # Headlight: the disc's centre faces the eye (full colour), its rim is darker.
    # Facets tilt the normal by up to ~2 degrees (flat shading on the 2-D canvas).
    centre = image[HEIGHT // 2, WIDTH // 2].astype(float)
    assert np.all(np.abs(centre - DEFAULT_RGB) <= 6)
    for fraction in (0.5, 0.9):
        col = round(WIDTH / 2 + fraction * radius_px)
        shade = image[HEIGHT // 2, col].astype(float) / DEFAULT_RGB
        expected = AMBIENT + (1 - AMBIENT) * sphere_headlight(col + 0.5 - WIDTH / 2, sphere)
        assert np.all(np.abs(shade - expected) < 0.04), (fraction, shade, expected)


#: A red sphere at the origin, a green cube out along +X, a blue one up along +Z.
PART_CENTRES = np.array([[0, 0, 0], [0.07, 0, 0], [0, 0, 0.07]])
PART_COLOURS = np.array([[230, 30, 30], [30, 200, 30], [30, 30, 230]], np.uint8)


@pytest.fixture(scope="module")
def parts():
    """(mesh, (n, 3) uint8 vertex colours) of the three parts."""
    meshes = [trimesh.creation.icosphere(subdivisions=3, radius=0.03),
              trimesh.creation.box(extents=(0.016,) * 3), trimesh.creation.box(extents=(0.016,) * 3)]
    for mesh, centre in zip(meshes, PART_CENTRES):
        mesh.apply_translation(centre)
    return (trimesh.util.concatenate(meshes),
            np.repeat(PART_COLOURS, [len(m.vertices) for m in meshes], axis=0))


def part_centroids(image: np.ndarray) -> np.ndarray:
    """(3, 2) mean pixel (column, row) of the red, green and blue pixels."""
    found = []
    for channel in range(3):
        rows, cols = np.nonzero(dominant(image, channel) & object_pixels(image))
        assert len(rows) > 100, f"colour {PART_COLOURS[channel]} not drawn"
        found.append((cols.mean(), rows.mean()))
    return np.array(found)


#: Centroids of the silhouettes vs projected centres, pixels: perspective shifts
#: them by well under a pixel at these sizes, and no part hides another.
CENTROID_TOLERANCE_PX = 3.0


@pytest.mark.parametrize("renderer", ["WebGL", "Canvas 2D"])
def test_parts_are_where_the_camera_puts_them_in_their_colours(tmp_path, parts, renderer):
    mesh, colors = parts
    page = write_html_viewer(tmp_path / "parts.html", mesh.vertices, mesh.faces,
                             vertex_colors=colors)
    image = screenshot(page, renderer)
    found = part_centroids(image)
    expected = project(PART_CENTRES, mesh.vertices)
    assert np.abs(found - expected).max() < CENTROID_TOLERANCE_PX, (found, expected)
    sphere_at, x_cube_at, z_cube_at = found
    assert x_cube_at[0] > sphere_at[0] + 40   # +X is to the right
    assert z_cube_at[1] < sphere_at[1] - 40   # +Z is up
    # Nothing but the three colours and their anti-aliased edges.
    coloured = dominant(image, 0) | dominant(image, 1) | dominant(image, 2)
    assert coloured.sum() > 0.9 * object_pixels(image).sum()


@pytest.mark.parametrize("reset", [False, True])
def test_drag_orbits_wheel_zooms_double_click_resets(tmp_path, parts, reset):
    mesh, colors = parts
    dx, dy, wheel = 60, 20, -200  # pixels of drag; wheel units (0.002 per unit, exponential)
    events = f"""<script>
      const c = document.querySelector("canvas");
      const at = (type, x, y) => c.dispatchEvent(new PointerEvent(type, {{clientX: x, clientY: y}}));
      at("pointerdown", 100, 200); at("pointermove", {100 + dx}, {200 + dy}); at("pointerup", 0, 0);
      c.dispatchEvent(new WheelEvent("wheel", {{deltaY: {wheel}, cancelable: true}}));
      {'c.dispatchEvent(new MouseEvent("dblclick"));' if reset else ''}
    </script></body>"""
    page = tmp_path / "events.html"
    page.write_text(html_viewer(mesh.vertices, mesh.faces, vertex_colors=colors)
                    .replace("</body>", events))
    found = part_centroids(screenshot(page, "WebGL"))
    # The script: azimuth -= 0.01 rad per pixel right, elevation += 0.01 rad per pixel
    # down, zoom *= exp(-0.002 * deltaY); a reset returns to the home view.
    moved = {} if reset else {"az": HOME_AZIMUTH_RAD - 0.01 * dx, "el": HOME_ELEVATION_RAD + 0.01 * dy,
                              "zoom": math.exp(-0.002 * wheel)}
    expected = project(PART_CENTRES, mesh.vertices, **moved)
    assert np.abs(found - expected).max() < CENTROID_TOLERANCE_PX, (found, expected)


def test_200k_faces_draw_without_webgl(tmp_path):
    # (About 2.6 s on a 2-core machine, start-up included: a figure, not a bar; the
    # screenshot's own deadline only bounds a hang.)
    torus = trimesh.creation.torus(0.05, 0.02, major_sections=400, minor_sections=250)
    assert len(torus.faces) == 200_000
    page = write_html_viewer(tmp_path / "torus.html", torus.vertices, torus.faces)
    image = screenshot(page, "Canvas 2D")
    # The ring's outer radius, 0.07 m, is the bounding sphere's: its width on screen is
    # that of the sphere's disc, FIT of the window, less 1 % as the ring's widest points
    # are hardly nearer the eye than the centre; anti-aliasing adds a pixel each side.
    cols = np.nonzero(object_pixels(image).any(axis=0))[0]
    assert 0.99 * FIT * WIDTH - 2 <= cols[-1] - cols[0] + 1 <= FIT * WIDTH + 2


def test_page_is_self_contained_and_embeds_the_mesh(sphere):
    colors = np.arange(3 * len(sphere.vertices), dtype=np.uint8).reshape(-1, 3)
    page = html_viewer(sphere.vertices, sphere.faces, vertex_colors=colors, title="a <mug> & co")
    for external in ("http:", "https:", "src=", "href=", "url(", "@import"):
        assert external not in page
    assert "<title>a &lt;mug&gt; &amp; co</title>" in page and "<mug>" not in page
    data = json.loads(re.search(r'<script type="application/json" id="mesh">(.*?)</script>',
                                page, re.S).group(1))

    def decoded(key, dtype):
        return np.frombuffer(base64.b64decode(data[key]), dtype=dtype).reshape(-1, 3)

    assert np.array_equal(decoded("vertices", "<f4"), sphere.vertices.astype(np.float32))
    assert np.array_equal(decoded("faces", "<u4"), sphere.faces)
    assert np.array_equal(decoded("colors", np.uint8), colors)
    assert np.allclose(data["center"], (0.1, -0.2, 0.3)) and math.isclose(data["radius"], 0.05)


def test_write_replaces_the_file_atomically(tmp_path, sphere):
    path = tmp_path / "mesh.html"
    path.write_text("old")
    assert write_html_viewer(path, sphere.vertices, sphere.faces) == path
    assert path.read_text().startswith("<!DOCTYPE html>")
    assert [p.name for p in tmp_path.iterdir()] == ["mesh.html"]  # no temporary left


@pytest.mark.parametrize("kwargs, message", [
    ({"faces": np.zeros((0, 3), int)}, "empty mesh"),
    ({"faces": [[0, 1, 9999]]}, "face indices"),
    ({"vertices": [[0, 0, float("nan")]] * 3}, "NaN"),
    ({"vertex_colors": np.zeros((3, 3), np.uint8)}, r"\(2562, 3\) uint8"),
    ({"vertex_colors": np.zeros((2562, 3))}, "dtype float64"),
])
def test_bad_input_is_a_clear_error(sphere, kwargs, message):
    args = {"vertices": sphere.vertices, "faces": sphere.faces, **kwargs}
    with pytest.raises(ValueError, match=message):
        html_viewer(args.pop("vertices"), args.pop("faces"), **args)


def test_cli_writes_a_viewer_of_the_mesh(tmp_path, mug_session):
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "sfs_ros.cli.reconstruct", str(mug_session), "-o",
         str(out / "mug.ply"), "-r", "48", "--html", str(out / "view" / "mug.html"), "-q"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "mug.report.json").read_text())
    assert report["html"] == str(out / "view" / "mug.html")
    assert "<title>mug.ply</title>" in (out / "view" / "mug.html").read_text()
    image = screenshot(out / "view" / "mug.html", "WebGL")
    rows, cols = np.nonzero(object_pixels(image))
    # The mug (body and handle) fills most of the bounding sphere's disc, about the centre.
    assert abs(cols.mean() - WIDTH / 2) < 0.15 * WIDTH and abs(rows.mean() - HEIGHT / 2) < 0.15 * WIDTH
    assert len(rows) > 0.3 * math.pi * (FIT * WIDTH / 2) ** 2
