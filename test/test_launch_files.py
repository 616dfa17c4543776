"""The launch files start what ``sfs-cell`` starts (``bringup.cell_nodes``), read with ast.

``launch`` and ``launch_ros`` are not on PyPI, so the files are parsed with
``ast`` and their ``Node(...)`` actions evaluated here for the few
constructs they use (strings, lists, tuples, dicts, names assigned in the file and
``**`` of such a dict, ``str``, ``os.path.join``, ``PathJoinSubstitution``,
``LaunchConfiguration`` (with a ``default``: of an argument ``launch`` itself reads),
``IfCondition`` of ``EqualsSubstitution`` / ``NotEqualsSubstitution`` (a node
whose condition is false is not started),
``get_package_share_directory``, ``Path(...).read_text()``); anything else fails
the test, naming the line, rather than being skipped. The package share folder
is a temporary copy of the repository's ``config/*.yaml`` and ``urdf/``, so the
comparison with ``cell_nodes`` is of full paths and values, the cell's state
publisher (its TF) among them.
"""

import ast
import importlib
import os
import re
import shutil
from pathlib import Path

import pytest
import yaml

from sfs_ros import process
from sfs_ros.cli.bringup import DDS_ENVIRONMENT, cell_nodes
from sfs_ros.ros.names import NAMESPACE

REPO = Path(__file__).resolve().parents[1]
LAUNCH_FILES = {"cell.launch.py": False, "mock_cell.launch.py": True}     # file: mock
#: Processes that compose more than one node: a name remap would rename them all.
COMPOSED = {"mock_hardware_node"}


def console_scripts() -> dict[str, str]:
    """``{script: "module:function"}`` of setup.py's ``entry_points``."""
    tree = ast.parse((REPO / "setup.py").read_text())
    setup = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                 and isinstance(n.func, ast.Name) and n.func.id == "setup")
    entry_points = ast.literal_eval(next(k.value for k in setup.keywords
                                         if k.arg == "entry_points"))
    return dict(re.fullmatch(r"\s*(\S+)\s*=\s*(\S+)\s*", line).groups()
                for line in entry_points["console_scripts"])


class LaunchFile:
    """A launch file's ``DeclareLaunchArgument`` and ``Node`` calls, evaluated for given
    launch arguments and package share folder."""

    def __init__(self, path: Path, *, arguments: dict[str, str], share: Path):
        self.path = path
        self.tree = ast.parse(path.read_text(), filename=str(path))
        self.assigned = {n.targets[0].id: n.value for n in ast.walk(self.tree)
                         if isinstance(n, ast.Assign) and len(n.targets) == 1
                         and isinstance(n.targets[0], ast.Name)}
        self.share = share
        self.declared = {self.value(c.args[0]): self.keywords(c)
                         for c in self.calls("DeclareLaunchArgument")}
        self.arguments = {name: kw["default_value"] for name, kw in self.declared.items()
                          if "default_value" in kw} | arguments

    def calls(self, function: str) -> list[ast.Call]:
        """Calls of ``function`` in source order."""
        found = [n for n in ast.walk(self.tree) if isinstance(n, ast.Call)
                 and isinstance(n.func, ast.Name) and n.func.id == function]
        return sorted(found, key=lambda n: (n.lineno, n.col_offset))

    def keywords(self, call: ast.Call) -> dict:
        """The call's keywords, a ``**name`` of a dict assigned in the file among them."""
        found = {}
        for k in call.keywords:
            found.update(self.value(k.value) if k.arg is None else {k.arg: self.value(k.value)})
        return found

    def nodes(self, package: str = "sfs_ros") -> list[dict]:
        """Keywords of the ``Node`` actions of ``package`` that start (condition true)."""
        nodes = [self.keywords(call) for call in self.calls("Node")]
        return [n for n in nodes if n["package"] == package and n.get("condition", True)]

    def packages(self) -> list[str]:
        return [n["package"] for n in map(self.keywords, self.calls("Node"))
                if n.get("condition", True)]

    def value(self, expr: ast.expr):
        if isinstance(expr, ast.Constant):
            return expr.value
        if isinstance(expr, ast.Name) and expr.id in ("KEEP_FREED_MEMORY_ENVIRONMENT",
                                                      "STOP_GRACE_S"):
            return getattr(process, expr.id)                 # imported from sfs_ros.process
        if isinstance(expr, ast.Name) and expr.id in self.assigned:
            return self.value(self.assigned[expr.id])
        if isinstance(expr, ast.List):
            return [self.value(e) for e in expr.elts]
        if isinstance(expr, ast.Tuple):
            return tuple(self.value(e) for e in expr.elts)
        if isinstance(expr, ast.Dict):
            return {self.value(k): self.value(v) for k, v in zip(expr.keys, expr.values)}
        if isinstance(expr, ast.Call) and not expr.keywords and not expr.args \
                and isinstance(expr.func, ast.Attribute) and expr.func.attr == "read_text":
            receiver = expr.func.value
            if isinstance(receiver, ast.Call) and ast.unparse(receiver.func) == "Path" \
                    and len(receiver.args) == 1 and not receiver.keywords:
                return Path(self.value(receiver.args[0])).read_text()
        if isinstance(expr, ast.Call) and ast.unparse(expr.func) == "LaunchConfiguration" \
                and [k.arg for k in expr.keywords] == ["default"]:
            name = self.value(expr.args[0])
            return self.arguments.get(name, self.value(expr.keywords[0].value))
        if isinstance(expr, ast.Call) and not expr.keywords:
            function, args = ast.unparse(expr.func), [self.value(a) for a in expr.args]
            if function == "str":
                return str(*args)
            if function == "os.path.join":
                return os.path.join(*args)
            if function == "PathJoinSubstitution":
                return os.path.join(*args[0])
            if function == "LaunchConfiguration":
                return self.arguments[args[0]]
            if function == "EqualsSubstitution":
                return args[0] == args[1]
            if function == "NotEqualsSubstitution":
                return args[0] != args[1]
            if function == "IfCondition" and isinstance(args[0], bool):
                return args[0]
            if function == "get_package_share_directory" and args == ["sfs_ros"]:
                return str(self.share)
        raise AssertionError(f"{self.path.name}:{expr.lineno}: {ast.unparse(expr)!r} is not "
                             "understood by this test; extend LaunchFile.value")


@pytest.fixture()
def share(tmp_path):
    """A package share folder ``.../share/sfs_ros`` with copies of the repository's config
    and URDF."""
    folder = tmp_path / "share" / "sfs_ros"
    (folder / "config").mkdir(parents=True)
    for path in (REPO / "config").glob("*.yaml"):
        shutil.copy(path, folder / "config")
    shutil.copytree(REPO / "urdf", folder / "urdf")
    return folder


def _yaml_value(share: Path, name: str, key: str):
    return yaml.safe_load((share / "config" / name).read_text())["/**"]["ros__parameters"][key]


#: Launch arguments of the real cell beyond output_dir and namespace, by case.
REAL_CASES = {"defaults": {}, "port and device": {"port": "/dev/ttyUSB3",
                                                  "camera_device": "/dev/video2"},
              "another driver": {"camera_topic": "/usb_cam/image_raw"},
              "site params": {"params_file": "site.yaml"}}


#: Launch arguments of the mock cell beyond output_dir and namespace, by case (another
#: driver: a real camera with the simulated motion, as sfs-cell --mock --camera-topic).
MOCK_CASES = {case: REAL_CASES[case] for case in ("defaults", "another driver", "site params")}


@pytest.mark.parametrize("filename, mock, case",
                         [("mock_cell.launch.py", True, case) for case in MOCK_CASES]
                         + [("cell.launch.py", False, case) for case in REAL_CASES])
@pytest.mark.parametrize("namespace", [None, "/cell1"])
def test_launch_file_starts_the_nodes_of_cell_nodes(filename, mock, case, namespace, share,
                                                    tmp_path):
    output_dir = str(tmp_path.resolve() / "scans")
    given = dict(REAL_CASES[case])
    if "params_file" in given:
        site = tmp_path.resolve() / given["params_file"]
        site.write_text("/**:\n  ros__parameters: {}\n")
        given["params_file"] = str(site)
    arguments = {"output_dir": output_dir, **given} | (
        {} if namespace is None else {"namespace": namespace})
    launch = LaunchFile(REPO / "launch" / filename, arguments=arguments, share=share)
    script = {target: name for name, target in console_scripts().items()}
    # The real cell's port and camera device arguments default to the config files' values:
    # by default they change nothing, as sfs-cell without --port / --camera-device.
    camera = ({"camera_topic": given["camera_topic"]} if "camera_topic" in given else
              {"camera_device": given.get("camera_device",
                                          _yaml_value(share, "camera.yaml", "device"))})
    hardware = ({"camera_topic": given.get("camera_topic")} if mock else {
        "port": given.get("port", _yaml_value(share, "motor.yaml", "port")), **camera})
    specs = cell_nodes(share / "config", output_dir, mock=mock,
                       params_file=given.get("params_file"), **hardware)

    # What the launch file starts, as (executable, params files then the overrides dict,
    # remaps).
    started = [(n["executable"], n["parameters"], dict(n.get("remappings", [])))
               for n in launch.nodes()]
    assert started == [(script[f"sfs_ros.nodes.{spec.module}:main"],
                        spec.params_files + ([_typed(spec.overrides)] if spec.overrides else []),
                        spec.remaps) for spec in specs]

    for spec, node in zip(specs, launch.nodes()):
        assert node["package"] == "sfs_ros"
        # The carving and meshing nodes start with malloc's settings, as by sfs-cell.
        assert node.get("additional_env", {}) == spec.environment
        # Supervised as by sfs-cell: a node that ends by itself is started again.
        assert node["respawn"] is True and node["respawn_delay"] > 0
        assert node["namespace"] == (namespace or NAMESPACE)   # sfs-cell's default too
        # A name is only a no-op remap to the node's own name; none for a composed process.
        if spec.module in COMPOSED:
            assert node.get("name") is None, spec.module
        else:
            module = importlib.import_module(f"sfs_ros.nodes.{spec.module}")
            assert node.get("name") in (None, module.NODE_NAME), spec.module
    if mock:        # the motor opens the mock's link
        overrides = {k: v for n in launch.nodes() for entry in n["parameters"]
                     if isinstance(entry, dict) for k, v in entry.items()}
        assert overrides["port_link"] == overrides["port"] == os.path.join(output_dir, "ttyMOCK")
    if "camera_topic" in given:     # no camera node of ours; the scan streams the driver's
        assert "camera" not in [n.get("name") for n in launch.nodes()]
        assert specs[-1].overrides["camera_trigger"] == "stream"
        assert launch.nodes()[-1]["remappings"] == [("image_raw", given["camera_topic"])]
        managed = [n for n in launch.nodes() if n["executable"] == "sfs-lifecycle-manager"]
        assert [n["parameters"][-1]["nodes"] for n in managed] == [["motor"]]
        if mock:    # nor the mock's camera: its process runs the controller alone
            (hardware,) = [n for n in launch.nodes() if n["executable"] == "sfs-mock-hardware"]
            assert hardware["parameters"][-1]["camera"] is False


def _typed(overrides: dict[str, str]) -> dict:
    """``-p`` overrides as a launch file's parameters give them: the lifecycle's
    ``autostart`` and the mock's ``camera`` bools, the manager's ``nodes`` a list (the
    others strings in both)."""
    return {name: yaml.safe_load(value) if name in ("autostart", "camera", "nodes") else value
            for name, value in overrides.items()}


#: Launch arguments each file declares; only output_dir is required.
ARGUMENTS = {"mock_cell.launch.py": {"output_dir", "namespace", "params_file", "camera_topic"},
             "cell.launch.py": {"output_dir", "namespace", "params_file", "port",
                                "camera_device", "camera_topic"}}


@pytest.mark.parametrize("filename", LAUNCH_FILES)
def test_launch_arguments_output_dir_required_namespace_sfs_by_default(filename, share):
    launch = LaunchFile(REPO / "launch" / filename, arguments={}, share=share)
    assert set(launch.declared) == ARGUMENTS[filename]
    assert "default_value" not in launch.declared["output_dir"]          # required
    assert launch.declared["namespace"]["default_value"] == NAMESPACE
    assert launch.declared["params_file"]["default_value"] == \
        str(share / "config" / "overrides.yaml")
    assert all(kw.get("description") for kw in launch.declared.values())
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description"
               for n in launch.tree.body)


@pytest.mark.parametrize("filename", LAUNCH_FILES)
def test_launch_files_set_the_middleware_environment_of_sfs_cell(filename, share):
    launch = LaunchFile(REPO / "launch" / filename, arguments={}, share=share)
    settings = {}
    for call in launch.calls("SetEnvironmentVariable"):
        name, value = (launch.value(call.args[0]), call.args[1])
        # EnvironmentVariable(NAME, default_value=...): a value the user set wins, as in
        # sfs-cell; otherwise the default.
        assert ast.unparse(value.func) == "EnvironmentVariable"
        assert launch.value(value.args[0]) == name
        settings[name] = launch.keywords(value)["default_value"]
    assert settings == DDS_ENVIRONMENT | process.PROCESS_ENVIRONMENT


@pytest.mark.parametrize("filename", LAUNCH_FILES)
def test_launch_files_give_each_node_the_stop_grace_of_sfs_cell(filename, share):
    # launch's own default (5 s after SIGINT, then SIGTERM) would cut a node finishing its
    # queued work, as 10 s once cut the meshing node in sfs-cell.
    launch = LaunchFile(REPO / "launch" / filename, arguments={"output_dir": "out"},
                        share=share)
    grace = str(process.STOP_GRACE_S)
    assert [(n["sigterm_timeout"], n["sigkill_timeout"]) for n in launch.nodes()] == \
        [(grace, grace)] * len(launch.nodes())
    # ros2 launch ... sigterm_timeout:=S sigkill_timeout:=K wins, as for launch's default.
    given = LaunchFile(REPO / "launch" / filename, share=share,
                       arguments={"output_dir": "out", "sigterm_timeout": "7",
                                  "sigkill_timeout": "3"})
    assert {(n["sigterm_timeout"], n["sigkill_timeout"]) for n in given.nodes()} == {("7", "3")}


def test_every_executable_is_a_console_script(share):
    scripts = console_scripts()
    for filename in LAUNCH_FILES:
        launch = LaunchFile(REPO / "launch" / filename, arguments={"output_dir": "out"},
                            share=share)
        for node in launch.nodes():
            assert node["executable"] in scripts, (filename, node["executable"])


@pytest.mark.parametrize("filename", LAUNCH_FILES)
@pytest.mark.parametrize("namespace", [None, "/cell1"])
def test_our_state_publisher_gives_the_tf_in_the_configured_frames(filename, namespace, share):
    arguments = {"output_dir": "out"} | ({} if namespace is None else {"namespace": namespace})
    launch = LaunchFile(REPO / "launch" / filename, arguments=arguments, share=share)
    # No robot_state_publisher (not on PyPI): the cell's own, as sfs-cell starts it.
    assert set(launch.packages()) == {"sfs_ros"}
    (node,) = [n for n in launch.nodes() if n["executable"] == "sfs-state-publisher"]
    assert console_scripts()["sfs-state-publisher"] == "sfs_ros.nodes.tf_node:main"
    # In the cell's namespace, so its relative joint_states is the motor node's.
    assert node["namespace"] == (namespace or NAMESPACE)
    assert node["parameters"][:2] == [str(share / "config" / "rig.yaml"),
                                      str(share / "config" / "frames.yaml")]
    # Every node that stamps a frame reads the same frames file.
    stamping = [n for n in launch.nodes() if n["executable"] in
                {"sfs-state-publisher", "sfs-carving", "sfs-meshing", "sfs-camera",
                 "sfs-mock-hardware"}]
    assert len(stamping) == 4
    assert all(str(share / "config" / "frames.yaml") in n["parameters"] for n in stamping)


def test_installed_share_folders_are_the_ones_the_launch_files_read():
    """setup.py installs launch/, config/ and urdf/ under share/sfs_ros, where
    get_package_share_directory finds them (checked for real by scripts/colcon_check.sh)."""
    tree = ast.parse((REPO / "setup.py").read_text())
    data_files = next(ast.unparse(k.value) for n in ast.walk(tree) if isinstance(n, ast.Call)
                      and isinstance(n.func, ast.Name) and n.func.id == "setup"
                      for k in n.keywords if k.arg == "data_files")
    for folder, pattern in (("launch", "launch/*.launch.py"), ("config", "config/*.yaml"),
                            ("urdf", "urdf/*.urdf")):
        assert f"'share/' + package_name + '/{folder}', glob('{pattern}')" in data_files, folder
