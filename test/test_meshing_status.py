"""The meshing node's choices, products and status without ROS: a request's options over the
node's settings, the products that cannot be made, the figures it reports."""

from types import SimpleNamespace

import pytest

from sfs_ros.cell_logic.after_answer import products_after
from sfs_ros.cell_logic.mesh_options import MeshOptions, mesh_options
from sfs_ros.cell_logic.meshing_status import MeshingStatus


@pytest.mark.parametrize("options, default, coloured", [
    (MeshOptions(), True, True),
    (MeshOptions(), False, False),
    (MeshOptions(colour=False), True, False),
    (MeshOptions(colour=True), False, True),
    (MeshOptions(colour=True, output_name="part.STL"), True, False),   # STL has no colours
    (MeshOptions(output_name="part.ply"), True, True),
])
def test_the_mesh_is_coloured_as_asked_else_as_the_node_says(options, default, coloured):
    assert options.coloured(default) is coloured


def test_texture_and_refinement_follow_the_request_else_the_node(tmp_path):
    asked = mesh_options(tmp_path, texture="yes", refine="no")
    assert asked.textured(False) and not asked.refined(True)
    empty = mesh_options(tmp_path)
    assert empty.textured(True) and not empty.refined(False)


def test_products_that_cannot_be_made_are_left_out_with_the_reason(tmp_path):
    # A carved scan that carries no colour images: no texture; and no image held of its one
    # view used: no refined mesh. Neither is made; each says why.
    carved = SimpleNamespace(colour_views=[], colour_images=[],
                             views=[SimpleNamespace(name="view_000_a.png", role="used")])
    made = SimpleNamespace(result=None, summary={"path": str(tmp_path / "m.ply"),
                                                 "report_path": str(tmp_path / "m.json")})
    products, notes = products_after(carved, carved, made, tmp_path, {}, texture=True,
                                     refine=True)
    assert products == []
    assert [level for level, _ in notes] == ["error", "warning"]
    assert notes[0][1].startswith("no texture: the carved scan carries no colour images")
    assert notes[1][1].startswith("no refined mesh: the images of 1 of the 1 views used")
    assert notes[1][1].endswith(f"the hull's mesh {tmp_path / 'm.ply'} is written")
    assert products_after(carved, carved, made, tmp_path, {}, texture=False,
                          refine=False) == ([], [])


def test_the_status_counts_meshes_and_failures_and_clears_the_problem():
    status = MeshingStatus()
    status.failed()
    status.report("reconstruction failed: no carved scan")
    assert status.diagnostics() == ({"reconstructions": 0, "reconstruction_failures": 1,
                                     "images_held": 0, "images_carried": 0},
                                    "reconstruction failed: no carved scan")
    status.meshed("/out/scan_001.ply", "/out/scan_001", images_held=5, images_carried=2)
    assert status.status() == {"session_dir": "/out/scan_001", "reconstructions": 1,
                               "mesh_path": "/out/scan_001.ply", "problem": ""}
    assert status.diagnostics()[0] == {"reconstructions": 1, "reconstruction_failures": 1,
                                       "images_held": 5, "images_carried": 2}
