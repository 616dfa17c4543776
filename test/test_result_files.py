"""One writer of a reconstruction's files: mesh, report, preview, viewer, contact sheet."""

import json
import os
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import trimesh

import sfs_ros.core.exchange.files as files_module
from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.result_files import SheetViews, add_pictures, report_path_for, write_result

#: PLY stores float32 coordinates: below 0.1 m, rounding is < 1e-8 m.
ATOL_M = 1e-8


@pytest.fixture(scope="module")
def result():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    report = {"mesh": {"n_faces": len(sphere.faces)},
              "views": {"used": ["a.png"], "rejected": [{"view": "b.png", "reason": "too dark"}]},
              "silhouette_iou": {"per_view": [{"view": "a.png", "silhouette_iou": 0.97}]}}
    return SimpleNamespace(vertices=np.asarray(sphere.vertices), faces=np.asarray(sphere.faces),
                           report=report)


def sheet_views():
    mask = np.zeros((40, 60), bool)
    mask[10:30, 20:40] = True
    image = np.full((40, 60, 3), 90, np.uint8)
    return SheetViews(names=["a.png", "b.png"], images=[image, None], masks=[mask, None],
                      angles_rad=[(0.0, 0.5), None])


def test_every_file_asked_for_is_written_and_named_in_the_report(tmp_path, result):
    colours = np.tile(np.array([[200, 30, 30]], np.uint8), (len(result.vertices), 1))
    written = write_result(result, tmp_path / "out" / "m.ply", vertex_colors=colours,
                           extra={"session": "s"}, preview=tmp_path / "pics" / "m.png",
                           html=tmp_path / "m.html", contact_sheet=tmp_path / "m.views.png",
                           sheet_views=sheet_views())
    assert written.report == tmp_path / "out" / "m.report.json" == report_path_for(written.mesh)
    document = json.loads(written.report.read_text())
    assert document == written.document
    assert list(document)[:3] == ["output", "units", "session"]
    assert document["output"] == str(tmp_path / "out" / "m.ply") and document["units"] == "m"
    assert document["mesh"] == result.report["mesh"]
    for key in ("preview", "html", "contact_sheet"):
        assert document[key] == str(getattr(written, key)) and getattr(written, key).is_file()
    vertices, faces, stored = load_mesh(written.mesh, with_colors=True)
    assert np.allclose(vertices, result.vertices, atol=ATOL_M)
    assert np.array_equal(faces, result.faces) and np.all(stored[:, :3] == (200, 30, 30))
    sheet = cv2.imread(str(written.contact_sheet))
    assert sheet is not None and sheet.shape[0] > 40     # two tiles and a header line


def test_without_options_only_the_mesh_and_report_are_written(tmp_path, result):
    written = write_result(result, tmp_path / "m.obj", units="mm")
    assert (written.preview, written.html, written.contact_sheet) == (None, None, None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.obj", "m.report.json"]
    assert not {"preview", "html", "contact_sheet"} & set(written.document)
    vertices, _ = load_mesh(written.mesh, units="mm")
    assert np.allclose(vertices, result.vertices, atol=1e-6)   # OBJ: 8 decimals of mm


def test_pictures_added_later_come_before_the_report_that_names_them(tmp_path, result,
                                                                     monkeypatch):
    first = write_result(result, tmp_path / "m.ply", extra={"session": "s"})
    mesh_bytes = first.mesh.read_bytes()
    order = []
    real_replace = os.replace
    monkeypatch.setattr(files_module.os, "replace",
                        lambda src, dst, **dir_fds: (order.append(os.path.basename(dst)),
                                                     real_replace(src, dst, **dir_fds)))
    later = add_pictures(first, result, preview=tmp_path / "m.png", html=tmp_path / "m.html",
                         contact_sheet=tmp_path / "m.views.png", sheet_views=sheet_views())
    # The pictures, then the report again; the mesh is left as it was.
    assert order == ["m.png", "m.html", "m.views.png", "m.report.json"]
    assert first.mesh.read_bytes() == mesh_bytes and later.mesh == first.mesh
    document = json.loads(first.report.read_text())
    assert document == later.document == {**first.document, "preview": str(tmp_path / "m.png"),
                                          "html": str(tmp_path / "m.html"),
                                          "contact_sheet": str(tmp_path / "m.views.png")}
    assert later.preview.is_file() and later.html.is_file() and later.contact_sheet.is_file()
    with pytest.raises(ValueError, match="sheet_views"):
        add_pictures(first, result, contact_sheet=tmp_path / "x.png")


def test_the_report_is_renamed_into_place_after_the_mesh(tmp_path, result, monkeypatch):
    order = []
    real_replace = os.replace
    monkeypatch.setattr(files_module.os, "replace",
                        lambda src, dst, **dir_fds: (order.append(os.path.basename(dst)),
                                                     real_replace(src, dst, **dir_fds)))
    write_result(result, tmp_path / "m.ply", preview=tmp_path / "m.png")
    assert order == ["m.ply", "m.png", "m.report.json"]


def test_a_mesh_that_cannot_be_written_leaves_no_report_beside_it(tmp_path, result):
    """The mesh's name is a folder: the error names the mesh, and the report of an earlier
    run is gone rather than left describing a mesh that was not written, and no picture
    of it is written either."""
    (tmp_path / "m.ply").mkdir()
    (tmp_path / "m.report.json").write_text('{"output": "an earlier mesh"}')
    with pytest.raises(IsADirectoryError, match=str(tmp_path / "m.ply")):
        write_result(result, tmp_path / "m.ply", preview=tmp_path / "m.png")
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


def test_a_failed_write_keeps_the_previous_mesh_and_report_together(tmp_path, result,
                                                                    monkeypatch):
    first = write_result(result, tmp_path / "m.ply", extra={"run": 1})
    before = (first.mesh.read_bytes(), first.report.read_bytes())
    fsyncs = []

    def fail_on_report(fd):    # staged in order: mesh, then report
        fsyncs.append(fd)
        if len(fsyncs) == 2:
            raise OSError("disk full")

    monkeypatch.setattr(files_module.os, "fsync", fail_on_report)
    scaled = SimpleNamespace(vertices=result.vertices * 2, faces=result.faces,
                             report=result.report)
    with pytest.raises(OSError, match="disk full"):
        write_result(scaled, tmp_path / "m.ply", extra={"run": 2})
    assert (first.mesh.read_bytes(), first.report.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply", "m.report.json"]


@pytest.mark.parametrize("kwargs, message", [
    ({"contact_sheet": "s.png"}, "needs sheet_views"),
    ({"vertex_colors": "red", "mesh": "m.stl"}, "STL cannot store vertex colours"),
    ({"mesh": "m.xyz"}, "unsupported mesh file suffix"),
    ({"units": "cm"}, "units must be one of"),
])
def test_bad_options_are_refused_before_anything_is_written(tmp_path, result, kwargs, message):
    mesh = tmp_path / kwargs.pop("mesh", "m.ply")
    if "contact_sheet" in kwargs:
        kwargs["contact_sheet"] = tmp_path / kwargs["contact_sheet"]
    with pytest.raises(ValueError, match=message):
        write_result(result, mesh, preview=tmp_path / "p.png", **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_sheet_views_of_unequal_lengths_are_refused():
    with pytest.raises(ValueError, match=r"as many images, masks and angles as names \(2\)"):
        SheetViews(names=["a", "b"], images=[None], masks=[None, None],
                   angles_rad=[None, None])
