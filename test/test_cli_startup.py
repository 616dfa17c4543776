"""The command lines start light: importing one, or asking it for ``--help``, loads none of
the heavy modules (numba, SciPy, trimesh, OpenCV, rclpy), which are imported where
they run. Checked in a fresh interpreter through ``sys.modules``, not by a clock (the
time is measured in ``bench/bench_startup.py``)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Modules whose import costs a large part of a second (or starts ROS).
HEAVY = ("numba", "scipy", "trimesh", "cv2", "rclpy")
#: The command lines whose import and help stay light.
LIGHT_COMMANDS = ("reconstruct", "export", "replay", "bringup", "cell", "ctl")


def loaded_after(code: str) -> dict:
    """Run ``code`` in a fresh interpreter; the heavy modules then loaded and its output."""
    probe = (f"import json, sys\n{code}\n"
             f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))\n")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr[-2000:]
    *output, last = done.stdout.splitlines()
    return {"heavy": json.loads(last), "output": "\n".join(output)}


@pytest.mark.parametrize("command", LIGHT_COMMANDS)
def test_importing_a_command_line_loads_no_heavy_module(command):
    assert loaded_after(f"import sfs_ros.cli.{command}")["heavy"] == []


@pytest.mark.parametrize("command", ["reconstruct", "export", "replay", "texture"])
def test_a_command_lines_help_loads_no_heavy_module(command):
    result = loaded_after(f"import contextlib\nimport sfs_ros.cli.{command} as cli\n"
                          "with contextlib.suppress(SystemExit):\n    cli.main(['--help'])")
    assert result["heavy"] == []
    assert f"usage: sfs-{command}" in result["output"]


def test_the_help_still_lists_what_the_heavy_modules_define():
    """The names the help shows are those the pipeline uses (one source each)."""
    from sfs_ros.cli import reconstruct
    from sfs_ros.core.exchange import export
    from sfs_ros.core.meshing.meshers import MESHERS
    from sfs_ros.core.segmentation.segment import PRESETS
    from sfs_ros.core.settings import RESOLUTION

    text = reconstruct.build_parser().format_help()
    for name in (*MESHERS, *PRESETS, *export.SUPPORTED_SUFFIXES):
        assert name in text, name
    assert RESOLUTION.allowed() in text


def test_a_heavy_module_is_seen_when_it_is_loaded():
    """The probe itself: importing the pipeline does load numba."""
    assert "numba" in loaded_after("import sfs_ros.core.pipeline")["heavy"]
