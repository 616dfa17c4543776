"""Bring-up: ``sfs_ros.cli.bringup.cell_nodes`` and ``sfs-cell`` running the mock cell.

``sfs-cell`` runs as a separate process (``python -m sfs_ros.cli.cell``) with
the environment of the harness (its ROS domain, localhost discovery) and a
namespace of its own, so that its nodes meet no other test's.
"""

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from std_srvs.srv import Trigger

import sfs_ros
from sfs_ros.cli import bringup
from sfs_ros.cli.bringup import (
    DDS_ENVIRONMENT,
    Cell,
    cell_nodes,
    default_config_dir,
    node_environment,
    stop_process,
)
from sfs_ros.ros.names import NAMESPACE as NAMESPACE_DEFAULT
from sfs_ros.ros.names import SERVICES

from ros_harness import NAMESPACE, SOURCE_ROOT, NodeProcess, RosProbe

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"
#: Five node processes importing rclpy, numpy, OpenCV and numba on a loaded 2-core machine.
CELL_UP_TIMEOUT_S = 120.0
#: sfs-cell stops its nodes one after the other, each with SIGINT.
CELL_STOP_TIMEOUT_S = 120.0
MOCK = [("mock_hardware", "mock_hardware_node",
         ["rig.yaml", "frames.yaml", "camera.yaml", "mock_hardware.yaml"]),
        ("motor", "motor_node", ["motor.yaml"])]
REAL = [("camera", "camera_node", ["rig.yaml", "frames.yaml", "camera.yaml"]),
        ("motor", "motor_node", ["motor.yaml"])]
#: After the hardware: the node that brings the managed ones (motor, camera) up in order.
MANAGER = [("lifecycle_manager", "lifecycle_manager_node", [])]
REST = [("state_publisher", "tf_node", ["rig.yaml", "frames.yaml"]),
        ("segmentation", "segmentation_node", ["rig.yaml", "segmentation.yaml"]),
        ("carving", "carving_node", ["rig.yaml", "frames.yaml", "carving.yaml"]),
        ("meshing", "meshing_node", ["frames.yaml", "meshing.yaml"]),
        ("recorder", "recorder_node", ["recorder.yaml"]),
        ("calibration", "calibration_node", ["calibration.yaml"]),
        ("scan", "scan_node", ["scan.yaml"])]


def config_copy(folder: Path, *, without: str = "") -> Path:
    """A copy of the repository's config folder, less the file ``without``."""
    folder.mkdir(parents=True)
    for path in CONFIG.glob("*.yaml"):
        if path.name != without:
            shutil.copy(path, folder)
    return folder


@pytest.mark.parametrize("mock", [True, False])
def test_cell_nodes_in_start_order_with_their_files_and_overrides(mock, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # The real cell needs no mock_hardware.yaml.
    config = CONFIG if mock else config_copy(tmp_path / "config", without="mock_hardware.yaml")
    specs = cell_nodes(config, "out", mock=mock)           # a relative output folder
    # Each node's own files, then the site's (by default overrides.yaml, which sets nothing).
    assert [(s.name, s.module, [Path(p).name for p in s.params_files]) for s in specs] == \
        [(name, module, files + ["overrides.yaml"]) for name, module, files in
         (MOCK if mock else REAL) + MANAGER + REST]
    assert all(Path(p).parent == config for s in specs for p in s.params_files)

    output = tmp_path.resolve() / "out"                    # made absolute
    # The managed nodes wait unconfigured; the manager brings them up, in its order.
    managed = {"autostart": "false"}
    hardware = [{"port_link": str(output / "ttyMOCK"), **managed},
                {"port": str(output / "ttyMOCK"), **managed}, {"nodes": "[camera,motor]"}]
    assert [s.overrides for s in specs] == (
        hardware if mock else [managed, managed, {"nodes": "[motor,camera]"}]) + [
        {}, {}, {"output_dir": str(output)}, {"output_dir": str(output)},
        {"output_dir": str(output)},
        {"output_dir": str(output), "plan_file": str(config / "calibration_plan.yaml")},
        {"plan_file": str(config / "scan_plan.yaml"),
         "progress_dir": str(output / "scan_progress")}]
    recording = cell_nodes(config, "out", mock=mock, record=True)
    assert [s.name for s in recording] == [s.name for s in specs]
    assert recording[-3].overrides == {"output_dir": str(output), "with_scan": "true"}

    scan = specs[-1]
    assert scan.command("/cell1") == [
        sys.executable, "-P", "-m", "sfs_ros.nodes.scan_node", "--ros-args", "-r", "__ns:=/cell1",
        "--params-file", str(config / "scan.yaml"),
        "--params-file", str(config / "overrides.yaml"),
        "-p", f"plan_file:={config / 'scan_plan.yaml'}",
        "-p", f"progress_dir:={output / 'scan_progress'}"]



def test_the_nodes_import_the_sfs_ros_that_starts_them(tmp_path):
    # A working folder holding another sfs_ros (a source tree beside an installed
    # package): a plain ``python -m`` would import that one, a node started like the
    # cell's imports the running one, whichever it is.
    decoy = tmp_path / "sfs_ros"
    decoy.mkdir()
    (decoy / "__init__.py").write_text("raise ImportError('the working folder\'s copy')\n")
    show = "import sfs_ros; print(sfs_ros.__file__)"
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    plain = subprocess.run([sys.executable, "-c", show], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=60)
    assert "the working folder's copy" in plain.stderr
    node = subprocess.run([sys.executable, "-P", "-c", show], cwd=tmp_path,
                          env=node_environment(env), capture_output=True, text=True, timeout=60)
    assert node.returncode == 0, node.stderr
    assert Path(node.stdout.strip()).resolve() == Path(sfs_ros.__file__).resolve()


def test_real_cell_options_port_camera_device_camera_topic_and_site_params(tmp_path):
    config = config_copy(tmp_path / "config", without="mock_hardware.yaml")
    site = tmp_path / "site.yaml"
    site.write_text("/**:\n  ros__parameters: {}\n")
    specs = {s.name: s for s in cell_nodes(config, tmp_path / "out", mock=False,
                                           params_file=site, port="/dev/ttyUSB3",
                                           camera_device="/dev/video2")}
    assert all(s.params_files[-1] == str(site) for s in specs.values())
    assert specs["motor"].overrides == {"port": "/dev/ttyUSB3", "autostart": "false"}
    assert specs["camera"].overrides == {"device": "/dev/video2", "autostart": "false"}
    assert specs["scan"].remaps == {}

    # Another driver's camera: no camera node; the scan node streams from its topic.
    other = cell_nodes(config, tmp_path / "out", mock=False, camera_topic="/usb_cam/image_raw")
    assert [s.name for s in other] == ["motor", "lifecycle_manager", "state_publisher",
                                       "segmentation", "carving", "meshing", "recorder",
                                       "calibration", "scan"]
    assert other[1].overrides == {"nodes": "[motor]"}
    # An integrator's own launch drives the transitions: no manager.
    manual = cell_nodes(config, tmp_path / "out", mock=False, manual_lifecycle=True)
    assert "lifecycle_manager" not in [s.name for s in manual]
    assert all(s.overrides["autostart"] == "false" for s in manual[:2])
    scan = other[-1]
    assert scan.overrides["camera_trigger"] == "stream"
    assert scan.command("/sfs")[5:9] == ["-r", "__ns:=/sfs", "-r",
                                         "image_raw:=/usb_cam/image_raw"]


def test_a_camera_topic_with_the_mock_cell_keeps_the_mock_controller_without_its_camera(
        tmp_path):
    specs = {s.name: s for s in cell_nodes(CONFIG, tmp_path / "out", mock=True,
                                           camera_topic="/desk_cam/image_raw")}
    assert specs["mock_hardware"].overrides["camera"] == "false"
    assert "camera" not in specs
    assert specs["scan"].overrides["camera_trigger"] == "stream"
    assert specs["scan"].remaps == {"image_raw": "/desk_cam/image_raw"}
    plain = {s.name: s for s in cell_nodes(CONFIG, tmp_path / "out", mock=True)}
    assert "camera" not in plain["mock_hardware"].overrides


@pytest.mark.parametrize("options, error", [
    ({"mock": True, "port": "/dev/ttyUSB0"}, "port: only for the real hardware"),
    ({"mock": False, "camera_device": "1", "camera_topic": "/cam/image_raw"},
     "camera_device and camera_topic: one or the other"),
])
def test_cell_nodes_refuses_options_that_do_not_fit(options, error, tmp_path):
    with pytest.raises(ValueError, match=error):
        cell_nodes(CONFIG, tmp_path / "out", **options)


@pytest.mark.parametrize("given, namespace", [("/cell1", "/cell1"), ("cell1", "/cell1"),
                                              ("/a/b/", "/a/b"), ("", ""), ("/", "")])
def test_the_cells_namespace_is_made_absolute(given, namespace):
    # rcl refuses a relative __ns remap: "sfs-cell --namespace cell1" means /cell1.
    cell = Cell([], namespace=given, log=None)
    assert cell.namespace == namespace


def test_the_cell_is_in_its_own_namespace_by_default():
    assert Cell([], log=None).namespace == NAMESPACE_DEFAULT == "/sfs"


def test_cell_nodes_names_a_missing_site_params_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="params file missing: .*nowhere.yaml"):
        cell_nodes(CONFIG, tmp_path / "out", mock=True, params_file=tmp_path / "nowhere.yaml")


#: Config files the cell does not start with: overlays and plans a user chooses to add.
OPTIONAL = {"mock_wrong_world.yaml"}


@pytest.mark.parametrize("missing", sorted(p.name for p in CONFIG.glob("*.yaml")
                                           if p.name not in OPTIONAL))
def test_cell_nodes_names_a_missing_config_file(missing, tmp_path):
    config = config_copy(tmp_path / "config", without=missing)
    with pytest.raises(FileNotFoundError, match=re.escape(str(config / missing))):
        cell_nodes(config, tmp_path / "out", mock=True)


def test_default_config_dir_without_a_ros_installation(monkeypatch):
    # A virtual environment with rclpy from PyPI: ament_index_python is there, no ROS sourced.
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    assert (default_config_dir() / "rig.yaml").is_file()


def test_default_config_dir_prefers_the_ament_index(tmp_path, monkeypatch):
    # As colcon installs the package: a marker in the ament index, the config in share/.
    index = tmp_path / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "sfs_ros").touch()
    config = config_copy(tmp_path / "share" / "sfs_ros" / "config")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    assert default_config_dir() == config


def test_sfs_cell_with_a_config_file_missing_exits_2_naming_it(tmp_path):
    config = config_copy(tmp_path / "config", without="motor.yaml")
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.cell", "--mock", "-o",
                           str(tmp_path / "out"), "--config", str(config)],
                          capture_output=True, text=True, env=_environment(), cwd=tmp_path,
                          timeout=60)
    assert done.returncode == 2
    lines = (done.stdout + done.stderr).strip().splitlines()
    assert len(lines) == 1 and str(config / "motor.yaml") in lines[0], lines


def test_mock_hardware_refuses_a_port_link_in_a_missing_folder(tmp_path):
    # sfs-cell and mock_cell.launch.py create the output folder of the link first; a node
    # given a link elsewhere should refuse it like any invalid parameter.
    link = tmp_path / "no_such_folder" / "ttyMOCK"
    process = NodeProcess("sfs_ros.nodes.mock_hardware_node", parameters={"port_link": link})
    code, lines = process.exit_lines()
    assert code == 2
    assert len(lines) == 1 and "'port_link'" in lines[0], lines


#: A process held in its stop: SIGINT and SIGTERM ignored; asked for its stacks (SIGUSR1) it
#: writes them as a node does and then, unlike a node, exits with 7 (so the test need not
#: wait for the kill); with ``ignore-stacks`` it ignores SIGUSR1 too.
HELD = """
import faulthandler, os, signal, sys
for sig in (signal.SIGINT, signal.SIGTERM):
    signal.signal(sig, signal.SIG_IGN)
if sys.argv[1:] == ["ignore-stacks"]:
    signal.signal(signal.SIGUSR1, signal.SIG_IGN)
else:
    signal.signal(signal.SIGUSR1, lambda *_: os._exit(7))
    faulthandler.register(signal.SIGUSR1, all_threads=True, chain=True)
print("held", flush=True)
while True:
    signal.pause()
"""


def _held(*args: str) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, "-c", HELD, *args], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT)
    assert process.stdout.readline() == b"held\n"
    return process


def test_a_process_held_in_its_stop_is_asked_for_its_stacks(monkeypatch):
    monkeypatch.setattr(bringup, "STACKS_S", 120.0)      # bounds a hang only: it exits on them
    process, said = _held(), []
    assert stop_process(process, grace_s=0.2, held=lambda: said.append("held")) == 7
    output = process.stdout.read().decode()
    assert said == ["held"]
    pause_line = HELD.splitlines().index("    signal.pause()") + 1
    assert f'File "<string>", line {pause_line} in <module>' in output, output


def test_a_process_held_in_its_stop_that_writes_no_stacks_is_killed():
    process = _held("ignore-stacks")
    assert stop_process(process, grace_s=0.2) == -signal.SIGKILL


def _environment() -> dict:
    """The harness's environment (ROS domain, discovery range) importing this ``sfs_ros``."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join(
        filter(None, [str(SOURCE_ROOT), os.environ.get("PYTHONPATH")])))


def _processes_in(namespace: str) -> dict[int, list[str]]:
    """``{pid: command line}`` of the processes started in ``namespace`` (``-r __ns:=...``)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            args = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:                                      # ended meanwhile
            continue
        if f"__ns:={namespace}" in args:
            found[int(entry.name)] = args
    return found


class MockCell:
    """``sfs-cell --mock`` in a namespace of its own, its output in a file."""

    NODES = [name for name, _, _ in MOCK + MANAGER + REST]

    def __init__(self, tmp_path: Path, name: str):
        self.namespace = f"{NAMESPACE}_{name}"
        tmp_path.mkdir()
        self.output_dir = tmp_path / "out"
        self._log = tmp_path / "sfs-cell.log"
        with self._log.open("wb") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "sfs_ros.cli.cell", "--mock", "-o", str(self.output_dir),
                 "--config", str(CONFIG), "--namespace", self.namespace],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                env=_environment(), cwd=tmp_path)

    def output(self) -> str:
        return self._log.read_text(errors="replace")

    def nodes(self) -> dict[int, list[str]]:
        return _processes_in(self.namespace)

    def wait_up(self) -> None:
        """Until every node has written a line, the mock serves its controller, and the scan
        and reconstruct services are ready."""
        probe = RosProbe()
        try:
            clients = [probe.node.create_client(Trigger, f"{self.namespace}/{SERVICES[name]}")
                       for name in ("scan/start", "reconstruct")]

            def up() -> bool:
                output = self.output()
                return self.process.poll() is not None or (
                    all(f"[{name}] " in output for name in self.NODES)
                    and "simulated GRBL controller" in output
                    and all(c.service_is_ready() for c in clients))

            try:
                probe.spin_until(up, timeout=CELL_UP_TIMEOUT_S, what="the cell")
            except AssertionError as exc:
                raise AssertionError(f"{exc}\nsfs-cell output:\n{self.output()}") from None
            if self.process.poll() is not None:
                raise AssertionError(f"sfs-cell exited with {self.process.returncode} while "
                                     f"starting:\n{self.output()}")
        finally:
            probe.close()

    def wait_exit(self) -> int:
        try:
            return self.process.wait(timeout=CELL_STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"sfs-cell still running {CELL_STOP_TIMEOUT_S:.0f} s later:\n"
                                 f"{self.output()}") from None

    def cleanup(self) -> None:
        """After a failure: stop sfs-cell, then any node it left behind, SIGINT first."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=CELL_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        for pid in self.nodes():
            _stop(pid)


def _stop(pid: int, grace_s: float = 10.0) -> None:
    """SIGINT to process ``pid``, SIGKILL if it is still there ``grace_s`` later."""
    for sig in (signal.SIGINT, signal.SIGKILL):
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + grace_s
        while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
            time.sleep(0.1)


@pytest.fixture()
def start_cell(tmp_path):
    """``start_cell(name)`` -> a :class:`MockCell` in namespace ``<harness namespace>_<name>``."""
    cells = []

    def start(name: str) -> MockCell:
        cells.append(MockCell(tmp_path / name, name))
        return cells[-1]

    yield start
    for cell in cells:
        cell.cleanup()


@pytest.mark.cell
def test_sfs_cell_brings_up_the_mock_cell_and_stops_it_on_sigint(start_cell):
    mock_cell = start_cell("bringup")
    mock_cell.wait_up()
    link = mock_cell.output_dir / "ttyMOCK"
    assert link.is_symlink() and Path(os.readlink(link)).exists()     # the mock's pty
    assert len(mock_cell.nodes()) == len(MockCell.NODES)
    for pid in mock_cell.nodes():           # the middleware settings, unless the user's
        environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        for name, value in DDS_ENVIRONMENT.items():
            assert f"{name}={os.environ.get(name, value)}".encode() in environ

    mock_cell.process.send_signal(signal.SIGINT)
    assert mock_cell.wait_exit() == 0, mock_cell.output()
    assert mock_cell.nodes() == {}, mock_cell.output()
    assert not link.is_symlink() and not link.exists()


@pytest.mark.cell
def test_sfs_cell_restarts_a_node_that_is_killed(start_cell):
    mock_cell = start_cell("node_ends")
    mock_cell.wait_up()

    def segmentation_pids() -> list[int]:
        return [pid for pid, args in mock_cell.nodes().items()
                if "sfs_ros.nodes.segmentation_node" in args]

    [killed] = segmentation_pids()
    os.kill(killed, signal.SIGKILL)
    deadline = time.monotonic() + CELL_UP_TIMEOUT_S  # bounds a hang only
    while segmentation_pids() in ([], [killed]):
        assert time.monotonic() < deadline and mock_cell.process.poll() is None, \
            mock_cell.output()
        time.sleep(0.1)
    lines = [line for line in mock_cell.output().splitlines() if line.startswith("sfs-cell:")]
    assert any("node segmentation ended by itself (exit status -9); restarting it" in line
               for line in lines), lines
    assert len(mock_cell.nodes()) == len(MockCell.NODES)

    mock_cell.process.send_signal(signal.SIGINT)
    assert mock_cell.wait_exit() == 0, mock_cell.output()
    assert mock_cell.nodes() == {}, mock_cell.output()
    assert not (mock_cell.output_dir / "ttyMOCK").is_symlink()
