"""The reconstruction core: pure algorithms, no ROS imports, usable from a notebook.

The front door names what a script needs::

    from sfs_ros.core import load_views, reconstruct, ReconstructionParams, export_mesh
    result = reconstruct(load_views("session_folder"), ReconstructionParams(resolution=192))
    export_mesh(result.vertices, result.faces, "mesh.ply")

``load_views`` reads every input format of
:data:`sfs_ros.core.exchange.inputs.INPUT_FORMATS`; a rosbag2 recorded by the cell once
``sfs_ros.cell_logic.bag_input`` is imported (it adds the format).

Sub-packages, each naming its public API in its ``__init__``:

* :mod:`.geometry`: cameras, the rig model, the voxel grid;
* :mod:`.carving`: voxel carving, the carving box, view consistency, specks;
* :mod:`.meshing`: cloud of points, advancing front, marching cubes, mesh checks, colour;
* :mod:`.exchange`: views in (session, Middlebury, NeRF), meshes and poses out;
* :mod:`.pictures`: PNG preview, HTML viewer, contact sheet;
* :mod:`.segmentation`: silhouettes: one image's cut, the backdrop, the multi-view consensus;
* :mod:`.simulation`: known objects, scan plans, simulated scans.

At the top: :mod:`.render` (z-buffer renderer),
:mod:`.metrics` (IoU, Chamfer), :mod:`.pipeline` (images to mesh) and
:mod:`.result_files` (a result's mesh, report and pictures).
Names are imported on first use, so ``import sfs_ros.core`` costs nothing.
"""

from importlib import import_module

_FRONT_DOOR = {
    "Camera": ".geometry",
    "RigCalibration": ".geometry",
    "rig_camera": ".geometry",
    "VoxelGrid": ".geometry",
    "carve": ".carving",
    "Carver": ".carving",
    "load_views": ".exchange",
    "ViewSet": ".exchange",
    "View": ".exchange",
    "export_mesh": ".exchange",
    "load_mesh": ".exchange",
    "segment": ".segmentation.segment",
    "SegmentationParams": ".segmentation.segment",
    "reconstruct": ".pipeline",
    "ReconstructionParams": ".pipeline",
    "Reconstruction": ".pipeline",
    "write_result": ".result_files",
    "check_mesh": ".meshing",
    "make_object": ".simulation",
    "simulate_scan": ".simulation",
    "ring_plan": ".simulation",
}

__all__ = sorted(_FRONT_DOOR)


def __getattr__(name: str):
    if name not in _FRONT_DOOR:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(_FRONT_DOOR[name], __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
