"""The products after the answer from the cell: the carving and meshing nodes as separate OS
processes, a scan of the mug painted with a fine pattern sent as masks, joint states and
captured images; ``reconstruct_mesh`` asked for a texture (or the refinement below the
hull) answers with the mesh and names the textured model (the refined mesh), made after
the answer."""

import json
from pathlib import Path

import numpy as np
import pytest
import test_carving_meshing_nodes as carving_meshing
import trimesh
from sensor_msgs.msg import Image
from test_carving_meshing_nodes import PLAN, RESOLUTION, RIG, Cell, _stamp

from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction
from sfs_ros.core.exchange.export import load_mesh, mesh_bytes
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.mesh_scan import mesh_scan
from sfs_ros.core.refinement import refine_carved_scan
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import fine_color_at
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan
from sfs_ros.ros import capture_qos
from sfs_ros.ros.cell_client import mesh_summary, wait_for_product
from sfs_ros.ros.convert import image_to_msg
from sfs_ros.ros.names import TYPED_SERVICES
from sfs_ros.ros.pairing import view_key
from sfs_ros_interfaces.srv import Reconstruct

#: That module's fixtures: the mug, the output folder, the nodes' parameters.
mug, out_dir, params_file = carving_meshing.mug, carving_meshing.out_dir, carving_meshing.params_file

#: The textured model may take this long after the answer on a loaded 2-core machine
#: (a second or two on a quiet one).
TEXTURE_TIMEOUT_S = 240.0
RECONSTRUCT_TIMEOUT_S = 240.0
#: A request to a restarted node is sent again after this long without an answer (one sent
#: before the node's service is matched is lost).
RESEND_AFTER_S = 30.0


class TexturingCell(Cell):
    """:class:`Cell` that also publishes the captured images and asks ``reconstruct_mesh``."""

    def __init__(self, params_file):
        super().__init__(params_file)
        node = self.probe.node
        self.image_pub = node.create_publisher(Image, "capture/image", capture_qos(100))
        self.typed = node.create_client(Reconstruct, TYPED_SERVICES["reconstruct_mesh"])
        self.probe.spin_until(self.typed.service_is_ready, what="reconstruct_mesh",
                              process=self.process)
        self.probe.spin_until(lambda: self.image_pub.get_subscription_count() > 0,
                              what="the carving node's capture/image subscription",
                              process=self.process)

    def reconstruct(self, **fields) -> Reconstruct.Response:
        future = self.typed.call_async(Reconstruct.Request(**fields))
        self.probe.spin_until(future.done, timeout=RECONSTRUCT_TIMEOUT_S,
                              what="reconstruct_mesh answer", process=self.process)
        return future.result()


@pytest.fixture(scope="module")
def cell(start_node_for_module, params_file):
    return start_node_for_module(TexturingCell, params_file)


@pytest.fixture(scope="module")
def painted(mug):
    """The mug painted with :func:`fine_color_at`, at the planned angles (no error)."""
    return simulate_scan(mug, RIG, PLAN, seed=2, surface_color=fine_color_at, ambient=1.0,
                         angle_error_rad=0.0)


@pytest.fixture(scope="module")
def masks(painted, mug):
    return [rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces,
                                 rig_camera(capture.theta_rad, capture.phi_rad, RIG))
            for capture in painted]


@pytest.fixture(scope="module")
def scanned(cell, painted, masks):
    """The painted scan sent to the nodes: masks, joint states and captured images."""
    for i, (capture, mask) in enumerate(zip(painted, masks)):
        stamp = _stamp(i)
        cell.image_pub.publish(image_to_msg(capture.image, stamp=stamp,
                                            frame_id="camera_optical", encoding="rgb8"))
        cell.send(stamp, mask, capture.theta_rad, capture.phi_rad)
    cell.wait_values(f"{len(PLAN)} carved views", scan_views=len(PLAN), carved=len(PLAN))
    return cell


def test_reconstruct_names_the_textured_model_and_writes_it_after(scanned, out_dir):
    cell = scanned
    answer = cell.reconstruct(texture="yes", colour="no", output_name="painted.ply")
    assert answer.success, answer.message
    summary = mesh_summary(answer)
    # The images came for the texture alone: the mesh is not coloured.
    assert summary["coloured_from_views"] == 0
    textured = Path(answer.textured_path)
    assert textured.name == "painted.textured.glb"
    assert textured.parent == Path(answer.mesh_path).parent
    assert textured.resolve().is_relative_to(out_dir.resolve())
    assert wait_for_product(summary, timeout_s=TEXTURE_TIMEOUT_S) == textured
    model = trimesh.load(textured, force="mesh", process=False)
    assert model.visual.kind == "texture"
    atlas = np.asarray(model.visual.material.baseColorTexture.convert("RGB"))
    assert min(atlas.shape[:2]) >= 64
    # The pattern's channels swing over [30, 200]: the atlas is no flat colour.
    assert atlas.reshape(-1, 3).std(axis=0).min() > 20
    report = json.loads(Path(answer.report_path).read_text())
    assert report["textured_path"] == str(textured)
    assert report["texture"]["faces"] == answer.n_faces == len(model.faces)


@pytest.fixture(scope="module")
def librarys_refined(painted, masks, mug, tmp_path_factory):
    """The refined mesh the library makes of the painted views and images in one process
    (carving as the carving node does, refining, meshing)."""
    live = LiveReconstruction(RIG, carving_box(mug), output_dir=tmp_path_factory.mktemp("live"),
                              resolution=RESOLUTION)
    for i, (capture, mask) in enumerate(zip(painted, masks)):
        key = view_key(_stamp(i))
        live.add_view(key, mask, capture.theta_rad, capture.phi_rad)
        live.add_colour_image(key, capture.image)
    images = dict(live.colour_image(view_key(_stamp(i))) for i in range(len(painted)))
    return mesh_scan(refine_carved_scan(live.carve(colour=False), images))


def test_reconstruct_names_the_refined_mesh_and_writes_the_librarys_after(scanned,
                                                                         librarys_refined):
    """The refined mesh the meshing node writes after its answer, from the images it held
    as the views were stored (or, for those it did not hold, the carved scan's), is the
    library's, byte for byte."""
    answer = scanned.reconstruct(refine="yes", colour="no", output_name="carved.ply")
    assert answer.success, answer.message
    summary = mesh_summary(answer)
    refined = Path(answer.refined_mesh_path)
    assert refined.name == "carved.refined.ply" and not answer.textured_path
    assert wait_for_product(summary, "refined_mesh_path",
                            timeout_s=TEXTURE_TIMEOUT_S) == refined
    expected = librarys_refined
    assert refined.read_bytes() == mesh_bytes(expected.vertices, expected.faces, refined)
    report = json.loads(Path(answer.report_path).read_text())
    assert report["refined_mesh_path"] == str(refined)
    assert report["refinement"]["applied"]
    # Below the hull: the refinement only removes voxels.
    hull_vertices, hull_faces = load_mesh(answer.mesh_path)
    volume = report["refined_mesh"]["volume_m3"]
    assert 0 < volume <= trimesh.Trimesh(hull_vertices, hull_faces).volume


@pytest.fixture(scope="module")
def meshing_restarted(scanned, params_file):
    """The meshing node killed (SIGKILL) after the scan and started again: it holds none
    of the scan's images (a module fixture: the new node outlives the test)."""
    cell = scanned
    cell.kill_meshing(params_file)
    cell.wait_meshing_up()
    return cell


def test_a_meshing_node_started_after_the_scan_refines_from_the_carved_scans_images(
        meshing_restarted, librarys_refined):
    """A meshing node that held none of the views' images asks the carving node for them
    all with the carved scan: its refined mesh is the library's, byte for byte."""
    cell = meshing_restarted
    answer = cell.probe.call_resending(
        cell.typed, Reconstruct.Request(refine="yes", colour="no", output_name="again.ply"),
        resend_after_s=RESEND_AFTER_S, attempts=4, process=cell.meshing,
        timeout=RECONSTRUCT_TIMEOUT_S)
    assert answer.success, answer.message
    refined = Path(answer.refined_mesh_path)
    assert refined.name == "again.refined.ply"
    assert wait_for_product(mesh_summary(answer), "refined_mesh_path",
                            timeout_s=TEXTURE_TIMEOUT_S) == refined
    expected = librarys_refined
    assert refined.read_bytes() == mesh_bytes(expected.vertices, expected.faces, refined)
    # The new node's diagnostics: every colour image came in the carved scan.
    cell.probe.spin_until(lambda: cell.last_values("meshing").get("reconstructions") == "1",
                          what="the new meshing node's diagnostics", process=cell.meshing)
    values = cell.last_values("meshing")
    assert (values["images_held"], values["images_carried"]) == ("0", str(len(PLAN)))
