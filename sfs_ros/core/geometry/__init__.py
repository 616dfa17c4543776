"""Cameras, the rig model and the voxel grid: where things are and how they project."""

from .camera import Camera
from .grid import MAX_VOXELS, VoxelGrid
from .rig import CONVENTIONS, RigCalibration, rig_camera, rig_rotation

__all__ = ["CONVENTIONS", "MAX_VOXELS", "Camera", "RigCalibration", "VoxelGrid", "rig_camera",
           "rig_rotation"]
