"""Extending by one module and one table entry: a mesher and an input format added here
are offered by ``sfs-reconstruct``'s help, listed by ``doc/reference.md``'s generator and
work end to end; the help, the page and the nodes' parameters say exactly what the
tables and the settings hold."""

import re
from pathlib import Path

import numpy as np
import pytest

from sfs_ros.cell_logic import bag_input
from sfs_ros.cli import reconstruct as cli
from sfs_ros.cli.reference import DEFAULT_PATH, PROG, reference_text
from sfs_ros.core.exchange.export import MESH_FORMATS, load_mesh
from sfs_ros.core.exchange.inputs import INPUT_FORMATS, InputFormat, accepted_inputs, load_views
from sfs_ros.core.exchange.views import View, ViewError, ViewSet
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.meshing.meshers import MESHER, MESHERS, Mesher
from sfs_ros.core.pipeline import ReconstructionParams
from sfs_ros.core.settings import BOUNDS_M, COLOUR, MAX_MEMORY, RESOLUTION, Setting

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--no-consensus", "--no-consistency-check", "-q"]


# ---- a mesher: the box around the hull, "margin" voxels wider ------------------------------

MARGIN = Setting("margin", "Voxels added around the hull's box.", int, "--margin",
                 bounds=(0, 8), default=0, unit="voxels", metavar="VOXELS")


def _prepare_box(occupancy, grid, _hull, *, margin: int) -> np.ndarray:
    """(2, 3) corners of the occupied voxels' cells, ``margin`` voxels wider, metres."""
    ijk = np.argwhere(occupancy)
    low = grid.index_to_world(ijk.min(axis=0))[0] - (0.5 + margin) * grid.voxel_size
    high = grid.index_to_world(ijk.max(axis=0))[0] + (0.5 + margin) * grid.voxel_size
    return np.stack([low, high])


def _mesh_box(_occupancy, _grid, box: np.ndarray) -> tuple:
    corners = np.array([[box[i, 0], box[j, 1], box[k, 2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    # Two triangles a side, counter-clockwise seen from outside (corner index = 4i + 2j + k).
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return corners, faces, {}


BOX = Mesher("box", "The box around the hull.", _prepare_box, _mesh_box, options=(MARGIN,),
             closed=True)


# ---- an input format: a folder of images with their cameras as arrays ----------------------

CAMERA_ARRAYS = "cameras.npz"


def _camera_arrays(path: Path) -> Path | None:
    return path if path.is_dir() and (path / CAMERA_ARRAYS).is_file() else None


def _read_camera_arrays(folder: Path) -> ViewSet:
    """``cameras.npz``: names (n,), K (n, 3, 3), R (n, 3, 3), t (n, 3), size (2,) width,
    height, bounds (2, 3) metres; the images beside it."""
    with np.load(folder / CAMERA_ARRAYS) as arrays:
        width, height = (int(v) for v in arrays["size"])
        views = [View(str(name), folder / str(name), Camera(K, R, t, width, height))
                 for name, K, R, t in zip(arrays["names"], arrays["K"], arrays["R"],
                                          arrays["t"])]
        return ViewSet(views=views, source="camera-arrays", bounds_m=arrays["bounds"])


CAMERA_FOLDER = InputFormat("camera-arrays", f"a folder of images with {CAMERA_ARRAYS}",
                            _camera_arrays, _read_camera_arrays)


def write_camera_arrays(folder: Path, view_set: ViewSet) -> Path:
    folder.mkdir(parents=True)
    for view in view_set.views:
        (folder / view.name).write_bytes(view.image_path.read_bytes())
    cameras = [v.camera for v in view_set.views]
    np.savez(folder / CAMERA_ARRAYS, names=[v.name for v in view_set.views],
             K=[c.K for c in cameras], R=[c.R for c in cameras], t=[c.t for c in cameras],
             size=[cameras[0].width, cameras[0].height], bounds=view_set.bounds_m)
    return folder


def run_cli(argv) -> tuple[int, dict]:
    status = cli.main([str(a) for a in argv])
    output = Path(argv[argv.index("-o") + 1])
    report = output.with_suffix(".report.json")
    return status, (__import__("json").loads(report.read_text()) if report.is_file() else {})


# ---- the tests ----------------------------------------------------------------------------

def test_a_mesher_added_by_one_entry_is_offered_and_meshes_end_to_end(monkeypatch, tmp_path,
                                                                      mug, mug_session):
    monkeypatch.setitem(MESHERS, BOX.name, BOX)
    help_text = cli.build_parser().format_help()
    assert "box" in cli.build_parser()._option_string_actions["--mesher"].choices
    assert "--margin VOXELS" in help_text and "box only:" in help_text
    assert "| `box` | `--margin` |" in reference_text()
    status, report = run_cli([mug_session, "-o", tmp_path / "box.ply", "-m", "box",
                              "--margin", "2", "-r", "48", *FAST])
    assert status == 0
    vertices, faces = load_mesh(tmp_path / "box.ply")
    assert (len(vertices), len(faces)) == (8, 12)
    assert report["mesh"]["watertight"] and report["mesh"]["outward"]
    assert report["parameters"]["mesher_options"] == {"margin": 2}
    # The box is the mug's, 2 voxels wider: give or take the voxel a boundary cell sticks
    # out or falls short by (so at least 1), and the hull's excess over the mug, at most a
    # voxel at the sides, a few over the open top that no view grazes (the highest ring
    # looks down from 65 degrees). The floor is the carving box's (z = 0).
    voxel = report["grid"]["voxel_size_m"]
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    assert np.all((mug.bounds[0][:2] - low[:2]) / voxel > 1.0)
    assert np.all((mug.bounds[0][:2] - low[:2]) / voxel < 4.0)
    assert low[2] == pytest.approx(-2 * voxel)
    assert np.all((high - mug.bounds[1]) / voxel > 1.0)
    assert np.all((high - mug.bounds[1]) / voxel < [4.0, 4.0, 6.0])
    # An option of another mesher is refused by name.
    assert run_cli([mug_session, "-o", tmp_path / "mc.ply", "--margin", "1", *FAST])[0] == 2
    with pytest.raises(ValueError, match="margin is not an option of the marching-cubes"):
        ReconstructionParams(mesher_options={"margin": 1})
    with pytest.raises(ValueError, match="margin must be 0..8 voxels"):
        ReconstructionParams(mesher="box", mesher_options={"margin": 9})


def test_an_input_format_added_by_one_entry_is_read_everywhere(monkeypatch, tmp_path,
                                                               mug_views, mug_session):
    folder = write_camera_arrays(tmp_path / "arrays", mug_views)
    with pytest.raises(ViewError, match="not a recognised input"):
        load_views(folder)
    monkeypatch.setitem(INPUT_FORMATS, CAMERA_FOLDER.name, CAMERA_FOLDER)
    assert CAMERA_FOLDER.description in accepted_inputs()
    assert " ".join(CAMERA_FOLDER.description.split()) in \
        " ".join(cli.build_parser().format_help().split())
    assert f"| `camera-arrays` | {CAMERA_FOLDER.description} |" in reference_text()
    loaded = load_views(folder)
    assert loaded.source == "camera-arrays" and len(loaded.views) == len(mug_views.views)
    # The same cameras and images as the session: the very same mesh.
    options = ["-r", "48", *FAST]
    status, report = run_cli([folder, "-o", tmp_path / "arrays.ply", *options])
    assert status == 0 and report["input"]["source"] == "camera-arrays"
    assert run_cli([mug_session, "-o", tmp_path / "session.ply", *options])[0] == 0
    assert (tmp_path / "arrays.ply").read_bytes() == (tmp_path / "session.ply").read_bytes()


def _listed(text: str) -> list[str]:
    return re.findall(r"\.\w+", text)


def test_the_help_lists_exactly_what_the_tables_hold():
    parser = cli.build_parser()
    actions = parser._option_string_actions
    assert tuple(actions["--mesher"].choices) == tuple(MESHERS) == MESHER.choices()
    options = {o.flag for entry in MESHERS.values() for o in entry.options}
    assert options and options <= set(actions)
    assert _listed(actions["--output"].help.split(":")[-1]) == list(MESH_FORMATS)
    assert bag_input.ROSBAG2.name in INPUT_FORMATS
    inputs = next(a for a in parser._actions if a.dest == "input").help
    assert inputs == accepted_inputs()
    assert all(f.description in inputs for f in INPUT_FORMATS.values())
    for setting in (RESOLUTION, BOUNDS_M, MAX_MEMORY, COLOUR):
        assert actions[setting.flag].help == setting.help()
    assert f"{RESOLUTION.bounds[0]}..{RESOLUTION.bounds[1]}" in actions["--resolution"].help


def test_the_reference_page_is_the_one_the_tables_give():
    page = (ROOT / DEFAULT_PATH).read_text(encoding="utf-8")
    assert page == reference_text(), f"doc/reference.md is stale: run {PROG}"
    for name in (*MESHERS, *INPUT_FORMATS, *MESH_FORMATS):
        assert f"| `{name}` |" in page
    for setting in (RESOLUTION, BOUNDS_M, MESHER, COLOUR, MAX_MEMORY):
        assert f"| `{setting.name}` | `{setting.flag}`" in page


def test_the_nodes_declare_the_settings_as_the_command_line_offers_them():
    from sfs_ros.nodes import carving_node, meshing_node
    carving = {p.name: p for p in carving_node.PARAMS}
    for setting in (RESOLUTION, BOUNDS_M, MESHER, COLOUR, MAX_MEMORY):
        param = carving[setting.name]
        assert (param.default, param.description) == (setting.cell_default, setting.description)
        assert param.bounds == setting.bounds
        assert param.choices == (None if setting.choices is None else setting.choices())
    colour = next(p for p in meshing_node.PARAMS if p.name == COLOUR.name)
    assert (colour.default, colour.description) == (COLOUR.cell_default, COLOUR.description)


def test_a_setting_checks_its_range_and_says_it():
    RESOLUTION.check(RESOLUTION.bounds[0])
    RESOLUTION.check(RESOLUTION.bounds[1])
    for wrong in (RESOLUTION.bounds[0] - 1, RESOLUTION.bounds[1] + 1):
        with pytest.raises(ValueError, match=r"resolution must be 8\.\.2048 voxels"):
            RESOLUTION.check(wrong)
    with pytest.raises(ValueError, match="mesher must be one of marching-cubes, advancing"):
        MESHER.check("poisson")
    with pytest.raises(ValueError, match="block must be >= 1 voxels, got 0"):
        ReconstructionParams(mesher="advancing-front", mesher_options={"block": 0})
