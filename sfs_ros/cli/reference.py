"""``python -m sfs_ros.cli.reference [--check] [PATH]``: write ``doc/reference.md``.

The page is generated from the tables the code reads: the reconstruction's settings
(:mod:`sfs_ros.core.settings`, the mesher's name and the meshers' options among them),
the meshers (:data:`sfs_ros.core.meshing.meshers.MESHERS`), the input formats
(:data:`sfs_ros.core.exchange.inputs.INPUT_FORMATS`, the cell's rosbag2 included) and
the mesh file formats (:data:`sfs_ros.core.exchange.export.MESH_FORMATS`) and each
node's parameters (the ``PARAMS`` of the modules in :data:`NODE_MODULES`, read as they
were when this module was imported). ``--check``
writes nothing and exits with 1 when the file differs from what the tables give.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..nodes import (
    calibration_node,
    camera_node,
    carving_node,
    lifecycle_manager_node,
    meshing_node,
    mock_hardware_node,
    motor_node,
    recorder_node,
    scan_node,
    segmentation_node,
    tf_node,
)

PROG = "python -m sfs_ros.cli.reference"
#: Where the page lives, from the repository's root.
DEFAULT_PATH = Path("doc/reference.md")
#: The nodes whose parameters the page lists: (node name, its module).
NODE_MODULES = (
    ("motor", motor_node), ("state_publisher", tf_node), ("camera", camera_node),
    ("mock_hardware", mock_hardware_node), ("scan", scan_node),
    ("segmentation", segmentation_node), ("carving", carving_node),
    ("meshing", meshing_node), ("calibration", calibration_node),
    ("recorder", recorder_node), ("lifecycle_manager", lifecycle_manager_node),
)


def _cell(text) -> str:
    return str(text).replace("|", "\\|")


def _setting_row(setting, owner: str = "") -> str:
    flag = f"`{setting.flag}`" + (f" `{setting.metavar}`" if setting.metavar else "")
    node = f"`{setting.name}`" if setting.cell_default is not None else "-"
    cell_default = "-" if setting.cell_default is None else f"`{json.dumps(setting.cell_default)}`"
    meaning = setting.description.rstrip(".") + (f" ({owner} only)." if owner else ".")
    values = setting.allowed() or ("on / off" if setting.kind is bool
                                   else f"{setting.length} numbers" if setting.length
                                   else setting.metavar or setting.kind.__name__)
    return (f"| `{setting.name}` | {flag} | {node} | {_cell(values)} | "
            f"{_cell(setting.default_words())} | {cell_default} | {_cell(meaning)} |")


def _settings_section() -> list[str]:
    from ..core.meshing.meshers import MESHER, MESHERS
    from ..core.settings import BOUNDS_M, COLOUR, MAX_MEMORY, RESOLUTION
    rows = [_setting_row(s) for s in (RESOLUTION, BOUNDS_M, MESHER, COLOUR, MAX_MEMORY)]
    rows += [_setting_row(option, entry.name)
             for entry in MESHERS.values() for option in entry.options]
    return ["## Reconstruction settings", "",
            "The same setting under its name in `sfs-reconstruct`, the carving and meshing "
            "nodes' parameters (`ros2 param describe`) and `ReconstructionParams` "
            "(`sfs_ros.core.settings`; a mesher's own options with the mesher). The offline "
            "default may come from the input; the cell's must be a value before the first "
            "view arrives.", "",
            "| setting | `sfs-reconstruct` | node parameter | values | default "
            "(`sfs-reconstruct`) | default (cell) | meaning |",
            "|---|---|---|---|---|---|---|", *rows, ""]


def _meshers_section() -> list[str]:
    from ..core.meshing.meshers import MESHERS
    rows = []
    for entry in MESHERS.values():
        options = ", ".join(f"`{o.flag}`" for o in entry.options) or "-"
        rows.append(f"| `{entry.name}` | {options} | {'yes' if entry.closed else 'checked'} | "
                    f"{_cell(entry.description)} |")
    return ["## Meshers", "",
            "`sfs-reconstruct --mesher`, the carving node's `mesher`; the first is the "
            "default (`sfs_ros.core.meshing.meshers.MESHERS`).", "",
            "| mesher | options | closed by construction | what |", "|---|---|---|---|",
            *rows, ""]


def _inputs_section() -> list[str]:
    from ..cell_logic import bag_input  # noqa: F401 - adds the rosbag2 to the input formats
    from ..core.exchange.inputs import INPUT_FORMATS
    rows = [f"| `{f.name}` | {_cell(f.description)} |" for f in INPUT_FORMATS.values()]
    return ["## Input formats", "",
            "What `load_views` and `sfs-reconstruct INPUT` read, tried in this order "
            "(`sfs_ros.core.exchange.inputs.INPUT_FORMATS`).", "",
            "| format | the input |", "|---|---|", *rows, ""]


def _mesh_formats_section() -> list[str]:
    from ..core.exchange.export import MESH_FORMATS
    rows = [f"| `{f.suffix}` | {f.name} | {'yes' if f.vertex_colours else 'no'} | "
            f"{'yes' if f.textured else 'no'} | {', '.join(f.units)} | {_cell(f.description)} |"
            for f in MESH_FORMATS.values()]
    return ["## Mesh file formats", "",
            "What `export_mesh`, `sfs-reconstruct -o` and the nodes' mesh names write, by "
            "suffix (`sfs_ros.core.exchange.export.MESH_FORMATS`).", "",
            "| suffix | format | vertex colours | texture | units | what |",
            "|---|---|---|---|---|---|", *rows, ""]


def _param_row(param) -> str:
    values = []
    if param.bounds is not None:
        values.append(f"{param.bounds[0]}..{param.bounds[1]}")
    if param.choices is not None:
        values.append("one of " + ", ".join(param.choices))
    if param.constraints:
        values.append(param.constraints)
    return (f"| `{param.name}` | `{json.dumps(param.default)}` | "
            f"{_cell('; '.join(values) or '-')} | {'start' if param.read_only else 'run time'} | "
            f"{_cell(param.description)} |")


def _node_params_section() -> list[str]:
    lines = ["## Node parameters", "",
             "Each node's `PARAMS` (`sfs_ros/nodes/<module>.py`), as `ros2 param describe` "
             "shows them; `config/*.yaml` hold them in `--params-file` form. *Set* says "
             "whether a parameter is read at start only or may be set at run time. Topics "
             "and services: [the cell](cell.md#nodes-topics-and-services); what each node "
             "does: [the nodes](nodes.md).", ""]
    for node, module in NODE_MODULES:
        lines += [f"### `{node}` (`{module.__name__}`)", "",
                  "| parameter | default | values | set | meaning |", "|---|---|---|---|---|",
                  *(_param_row(p) for p in module.PARAMS), ""]
    return lines


def reference_text() -> str:
    """The text of ``doc/reference.md``, from the tables as they are now."""
    lines = ["# Reference: settings, meshers, input and mesh formats, node parameters", "",
             "[Back to the README](../README.md)", "",
             f"Generated by `{PROG}` from the tables the code reads; "
             "`test/test_reference.py` fails when this page is stale. How to add a mesher, "
             "an input format or a mesh format: [the architecture](architecture.md#extending).",
             "",
             *_settings_section(), *_meshers_section(), *_inputs_section(),
             *_mesh_formats_section(), *_node_params_section()]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("path", type=Path, nargs="?", default=DEFAULT_PATH,
                   help=f"the page (default: {DEFAULT_PATH})")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit with 1 when the page is stale")
    args = p.parse_args(argv)
    text = reference_text()
    if args.check:
        current = args.path.read_text(encoding="utf-8") if args.path.is_file() else ""
        if current != text:
            print(f"{args.path} is stale: run {PROG} {args.path}", file=sys.stderr)
            return 1
        return 0
    args.path.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
