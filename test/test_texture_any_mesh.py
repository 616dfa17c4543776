"""``sfs-texture`` on a given mesh, and texture quality apart from shape: the TRUE meshes of
synthetic objects painted with a fine 3-D pattern, textured from a session without the
held-out views, drawn into those views and compared with their images (PSNR inside the
true silhouette) side by side with a nearest-view projective texture and with the mesh's
vertex colours; clear errors for a file that is no mesh, a mesh without faces, and a
mesh outside the views; the viewer of a textured mesh showing its texture in Chromium."""

import cv2
import numpy as np
import pytest
import trimesh
from test_html_viewer import object_pixels, screenshot

from sfs_ros.cli.texture import main as texture_main
from sfs_ros.core.exchange.export import export_mesh
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.meshing.colour import spread_views, vertex_colours
from sfs_ros.core.pictures.html_viewer import write_html_viewer
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import fine_color_at, make_object
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan
from sfs_ros.core.texture import TexturedMesh, texture_from_views
from sfs_ros.core.texture.evaluation import held_out_psnr, nearest_view_texture

from conftest import TEST_PLAN, TEST_RIG

#: Views kept out of the session (one per ring and the top view): the truth.
HELD_OUT = (3, 21, 38, 48)


def painted_scan(name: str, folder):
    """The object ``name`` painted with :func:`fine_color_at` (5 mm period: 5.8 px in the
    views, finer than most faces), unshaded: its captures, and a session folder of all
    but the held-out views."""
    obj = make_object(name)
    captures = simulate_scan(obj, TEST_RIG, TEST_PLAN, seed=1, surface_color=fine_color_at,
                             ambient=1.0)
    kept = [c for i, c in enumerate(captures) if i not in HELD_OUT]
    session = write_session(folder / "session", [(c.name, c.image) for c in kept],
                            [(c.theta_rad, c.phi_rad) for c in kept], TEST_RIG,
                            bounds_m=carving_box(obj))
    return obj, captures, session


def read_textured_glb(path) -> TexturedMesh:
    """The textured .glb back in the object frame (Z up) as a :class:`TexturedMesh`."""
    mesh = trimesh.load(path, force="mesh", process=False)
    assert mesh.visual.kind == "texture"
    v = np.asarray(mesh.vertices)
    image = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
    return TexturedMesh(vertices=np.column_stack([v[:, 0], -v[:, 2], v[:, 1]]),
                        faces=np.asarray(mesh.faces), uv=np.asarray(mesh.visual.uv),
                        texture=image, source_vertex=np.arange(len(v)),
                        face_view=np.zeros(len(mesh.faces), np.int64), stats={})


def mean_psnr(obj, captures, vertices, faces, **colouring) -> float:
    """Mean PSNR (dB) over the held-out views, inside the true silhouette (every pixel of
    it: the mesh is the true one, so no outline pixel mixes two surfaces)."""
    values = []
    for i in HELD_OUT:
        camera = rig_camera(captures[i].theta_rad, captures[i].phi_rad, TEST_RIG)
        truth = rasterize_silhouette(obj.mesh.vertices, obj.mesh.faces, camera)
        values.append(held_out_psnr(vertices, faces, camera, captures[i].image, truth,
                                    **colouring))
    return float(np.mean(values))


def side_by_side(name: str, tmp_path) -> dict:
    """PSNR of ``sfs-texture`` on the true mesh, of the nearest-view texture and of vertex
    colours, the last two from the same views the texture chose from."""
    obj, captures, session = painted_scan(name, tmp_path)
    export_mesh(obj.mesh.vertices, obj.mesh.faces, tmp_path / "true.ply")
    out = tmp_path / "textured.glb"
    assert texture_main([str(session), str(tmp_path / "true.ply"), "-o", str(out)]) == 0
    textured = read_textured_glb(out)
    kept = [c for i, c in enumerate(captures) if i not in HELD_OUT]
    cameras = [rig_camera(c.theta_rad, c.phi_rad, TEST_RIG) for c in kept]
    chosen = spread_views(cameras, 24)
    images = [kept[k].image for k in chosen]
    views = [cameras[k] for k in chosen]
    nearest = nearest_view_texture(obj.mesh.vertices, obj.mesh.faces, images, views)
    colours = vertex_colours(obj.mesh.vertices, obj.mesh.faces, images, views).colours
    psnr = {"texture": mean_psnr(obj, captures, textured.vertices, textured.faces,
                                 pixel_colors=textured.colour_at),
            "nearest view": mean_psnr(obj, captures, nearest.vertices, nearest.faces,
                                      pixel_colors=nearest.colour_at),
            "vertex colours": mean_psnr(obj, captures, obj.mesh.vertices, obj.mesh.faces,
                                        vertex_colors=colours)}
    print(f"true {name}: " + ", ".join(f"{k} {v:.2f} dB" for k, v in psnr.items()))
    return psnr


def test_texture_of_the_true_cup_beats_the_nearest_view_and_vertex_colours(tmp_path):
    """The cup's inside is hidden from most views by its rim: the nearest view paints it
    with the rim's and the outside's colours, the texture from views that see it."""
    psnr = side_by_side("cup", tmp_path)
    # Measured 32.5 dB against 18.3 (nearest view) and 13.4 (vertex colours, 2,048 faces
    # of 6-10 mm against the pattern's 5 mm period). Deterministic: seeded renders.
    assert psnr["texture"] > psnr["nearest view"] + 1.0, psnr
    assert psnr["texture"] > psnr["vertex colours"] + 6.0, psnr


def test_texture_of_the_true_bowl_beats_the_nearest_view_and_vertex_colours(tmp_path):
    """The bowl (66,048 faces): its inside seen past the rim, the rim's top a few pixels
    wide, its outside at a slant."""
    psnr = side_by_side("bowl", tmp_path)
    # Measured 33.7 dB against 28.5 (nearest view) and 21.1 (vertex colours).
    assert psnr["texture"] > psnr["nearest view"] + 1.0, psnr
    assert psnr["texture"] > psnr["vertex colours"] + 6.0, psnr


def test_texture_of_the_true_mug_beats_the_nearest_view_and_vertex_colours(tmp_path):
    """On the mug (25,600 faces) the views see nearly every face unhidden and frontally:
    the nearest view is the view the texture chooses too; the texture reads it bicubically
    (a pattern of 5.8 px a period lies on a curve between the pixels) and blends the other
    views that see the face well, averaging their noise."""
    psnr = side_by_side("mug", tmp_path)
    # Measured 37.8 dB against 32.6 (nearest view) and 12.8 (vertex colours: the faces
    # are 5-40 mm long, the pattern 5 mm).
    assert psnr["texture"] > psnr["nearest view"] + 1.0, psnr
    assert psnr["texture"] > psnr["vertex colours"] + 15.0, psnr


@pytest.fixture(scope="module")
def cup_session(tmp_path_factory):
    return painted_scan("cup", tmp_path_factory.mktemp("cup"))


def test_the_blend_stays_sharp_on_the_surface_and_blurs_off_it(cup_session):
    """The views agree on the true cup, so its faces keep the unblurred blend; on the cup
    grown by 3 % about the centre of its base (its wall 1.2 mm out, 1.4 px in the views,
    its rim 2.7 mm up) each view puts the 5 mm pattern elsewhere, and the faces take a
    blur."""
    obj, _, session = cup_session
    views = load_views(session, captures=True).views
    centre = np.array([0.0, 0.0, obj.mesh.vertices[:, 2].min()])
    true = texture_from_views(views, obj.mesh.vertices, obj.mesh.faces)
    grown = texture_from_views(views, centre + 1.03 * (obj.mesh.vertices - centre),
                               obj.mesh.faces)
    # Measured 100 % and 0.4 % unblurred (97 % blurred by 1 px); grown by 1 %, 100 %.
    assert true.stats["blur_px"]["0.0"] > 0.95, true.stats["blur_px"]
    assert grown.stats["blur_px"]["0.0"] < 0.5, grown.stats["blur_px"]


def test_errors_name_what_is_wrong(tmp_path, cup_session, capsys):
    obj, _, session = cup_session
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nnonsense\n")
    points = tmp_path / "points.ply"
    points.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                      "property float y\nproperty float z\nend_header\n0 0 0.01\n"
                      "0.01 0 0.01\n0 0.01 0.01\n")
    far = tmp_path / "far.ply"
    export_mesh(obj.mesh.vertices + [5.0, 0.0, 0.0], obj.mesh.faces, far)
    millimetres = tmp_path / "millimetres.ply"
    export_mesh(obj.mesh.vertices, obj.mesh.faces, millimetres, units="mm")
    out = str(tmp_path / "out.glb")
    for mesh, options, message in [
            (garbage, [], "could not be read as a .ply mesh"),
            (points, [], "has no faces: a triangle mesh is needed"),
            (far, [], "the mesh lies outside the views: 0 % of its vertices"),
            (millimetres, [], "is it in the views' object frame and unit?"),
            (tmp_path / "missing.ply", [], "is not a file"),
            (far, ["-o", str(tmp_path / "out.ply")], "must end in .obj or .glb")]:
        assert texture_main([str(session), str(mesh), "-o", out, *options]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "out.glb").exists()


def test_writes_obj_with_its_material_atlas_and_viewer(tmp_path, cup_session):
    obj, _, session = cup_session
    export_mesh(obj.mesh.vertices, obj.mesh.faces, tmp_path / "cup.glb")
    out = tmp_path / "out" / "cup.obj"
    assert texture_main([str(session), str(tmp_path / "cup.glb"), "-o", str(out),
                         "--html", str(tmp_path / "out" / "cup.html")]) == 0
    assert {p.name for p in out.parent.iterdir()} == {"cup.obj", "cup.mtl", "cup.png",
                                                     "cup.html"}
    mesh = trimesh.load(out, force="mesh", process=False)
    assert mesh.visual.kind == "texture" and len(mesh.faces) == len(obj.mesh.faces)
    assert '"texture": "iVBOR' in (out.parent / "cup.html").read_text()


def test_the_viewer_of_a_textured_mesh_shows_its_texture(tmp_path, cup_session):
    """Headless Chromium (WebGL, software) draws the page ``sfs-texture --html`` wrote for
    the cup: the object's pixels carry the 5 mm pattern (hues varying from pixel to
    pixel), where the page of the same mesh without colours shades one default colour."""
    obj, _, session = cup_session
    export_mesh(obj.mesh.vertices, obj.mesh.faces, tmp_path / "cup.ply")
    page = tmp_path / "cup.html"
    assert texture_main([str(session), str(tmp_path / "cup.ply"), "-o",
                         str(tmp_path / "cup.glb"), "--html", str(page)]) == 0
    plain = write_html_viewer(tmp_path / "plain.html", obj.mesh.vertices, obj.mesh.faces)

    def look(image):
        inside = object_pixels(image)
        rgb = image[inside].astype(float) + 1.0
        hue = rgb / rgb.sum(axis=1, keepdims=True)      # chromaticity: shading cancels
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
        inner = cv2.erode(inside.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        detail = np.abs(cv2.Laplacian(grey, cv2.CV_32F))[inner]
        return inside.sum(), float(hue.std(axis=0).max()), float(np.mean(detail))

    textured_pixels, textured_hues, textured_detail = look(screenshot(page, "WebGL"))
    plain_pixels, plain_hues, plain_detail = look(screenshot(plain, "WebGL"))
    # The same framing: the same mesh covers the same pixels (within its outline's).
    assert abs(textured_pixels - plain_pixels) < 0.05 * plain_pixels
    # The pattern's channels swing over [30, 200] out of phase: the share of a channel in
    # a pixel's sum spreads over pixels, where one colour shaded keeps one share (up to
    # rounding and the outline's blend with the background); its detail (mean
    # |Laplacian|) is many times the smooth shading's.
    assert textured_hues > 3 * plain_hues, (textured_hues, plain_hues)
    assert textured_detail > 3 * plain_detail, (textured_detail, plain_detail)
