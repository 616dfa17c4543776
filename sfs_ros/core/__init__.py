"""The reconstruction core: pure algorithms, no ROS imports.

Usable from a notebook or a script: cameras and the rig model, a synthetic
renderer, segmentation, voxel carving, the cloud of points, two meshers,
export and metrics.
"""
