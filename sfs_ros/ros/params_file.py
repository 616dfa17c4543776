"""A ROS parameters file checked by rcl's own parser before it is written.

rcl (``rcl_yaml_param_parser``, libyaml) is stricter than PyYAML in places (lists
of one type, no empty values, the ``node: ros__parameters:`` structure), and a
node given a file it refuses does not start: :func:`check_params_file` has rcl
read the text, as ``--params-file``, through a context of its own that starts
nothing on the network.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

__all__ = ["check_params_file"]


def check_params_file(data: bytes, what: str) -> None:
    """ValueError naming ``what`` unless rcl reads ``data`` as a parameters file."""
    import rclpy
    from rclpy._rclpy_pybind11 import RCLError

    with tempfile.TemporaryDirectory(prefix="sfs_params_") as folder:
        path = Path(folder) / "params.yaml"
        try:
            path.write_bytes(data)
        except OSError as exc:
            raise OSError(exc.errno, f"{exc.strerror} (a copy of {what} for rcl to read)",
                          str(path)) from None
        context = rclpy.Context()
        try:
            rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context)
        except RCLError as exc:
            reason = str(exc).split("Error: ", 1)[-1].split(", at ")[0]
            raise ValueError(f"{what} would not be read by ROS as a parameters file "
                             f"({reason}); nothing written") from None
        rclpy.shutdown(context=context)
