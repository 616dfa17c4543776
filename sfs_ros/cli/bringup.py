"""Starting and stopping the cell's nodes as separate processes (no ``ros2 launch`` on PyPI).

:class:`Cell` starts each node as ``python -P -m sfs_ros.nodes.<module>
--ros-args --params-file ...`` with the YAML files of a config folder, importing the
same ``sfs_ros`` as the process that starts it (:func:`node_environment`), in its
own process group (so a Ctrl-C in the terminal reaches the bring-up, which
then stops the nodes in order), copies their output to the terminal with the
node's name in front, and stops them with SIGINT, in reverse order, then
SIGTERM and SIGKILL only for a node that ignores it (a node killed outright
leaves Fast DDS shared-memory files behind; before it is killed, it writes its
threads' stacks to the log, SIGUSR1, to name where its stop was held).

The recorder node (:mod:`sfs_ros.nodes.recorder_node`) writes its bags to
``OUTPUT_DIR/bags/``; the state publisher (:mod:`sfs_ros.nodes.tf_node`) publishes the
cell's TF in the frames of ``frames.yaml``, which the nodes that stamp frames read too.
With ``mock=True`` the hardware is the mock hardware node (simulated controller + mock
camera), whose pseudo-terminal is linked at
``OUTPUT_DIR/ttyMOCK`` for the motor node; otherwise the camera node and the
motor node's ``port`` from ``motor.yaml``, or, with ``camera_topic``, the
frames of any camera driver the user runs (the camera node, or the mock's
camera, is then not started; the scan node takes the streamed frames,
``camera_trigger`` stream).

The motor and camera nodes are managed (lifecycle) nodes started with ``autostart``
false; the lifecycle manager (:mod:`sfs_ros.nodes.lifecycle_manager_node`), started
right after them, configures and activates them in order through their
``change_state`` services (the mock's camera first, whose process has made the
controller's port by then, then the motor; for the real hardware the motor, then the
camera), and again whenever one is started again. With ``manual_lifecycle`` no manager
is started: the nodes stay unconfigured until an integrator's own launch or program
drives their transitions.

Every node gets ``params_file`` last among its files (default
``overrides.yaml`` of the config folder, which sets nothing): a site's own
values, without editing the installed files. A node that holds the rig
(``rig.yaml`` among its files) also gets, after all of them, the rig applied
last to the running cell (:data:`sfs_ros.cell_logic.paths.APPLIED_RIG` in the output
folder, :func:`sfs_ros.ros.rig_apply.apply_rig`) whenever it is started and the
file exists, so a node started again keeps the applied rig; the start says so. The cell runs in the namespace
:data:`sfs_ros.ros.names.NAMESPACE` unless told otherwise. :func:`select_nodes`
picks the part of the cell one host runs, the rest running on another host in the
same ROS domain and namespace.
"""

from __future__ import annotations

import os
import signal
import site
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from sfs_ros.cell_logic.paths import APPLIED_RIG
from sfs_ros.process import KEEP_FREED_MEMORY_ENVIRONMENT, PROCESS_ENVIRONMENT, STOP_GRACE_S
from sfs_ros.ros.names import CONFIGURATION_ERROR, NAMESPACE

__all__ = ["NodeSpec", "Cell", "DDS_ENVIRONMENT", "RestartPolicy", "cell_nodes",
           "default_config_dir", "node_environment", "select_nodes", "stop_process",
           "wait_until_signal"]

#: Middleware settings of the node processes (a variable already set is left as it is).
#: Fast DDS's shared-memory transport can leave a restarted process deaf to the peers that
#: outlived a SIGKILL of its predecessor (a restarted motor node never got the scan node's
#: requests and commands, yet answered a new client at once; eProsima Fast-DDS issues
#: 5053, 5469 and 2811 report the same): the cell's processes talk over UDP on the loopback.
DDS_ENVIRONMENT = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}

#: Seconds a node that did not stop gets to write its threads' stacks (SIGUSR1) before SIGKILL.
STACKS_S = 1.0


def node_environment(env: dict) -> dict:
    """``env`` for a node process started as ``python -P -m sfs_ros.nodes...``, in which it
    imports the ``sfs_ros`` this process runs: ``-P`` keeps the working folder off the
    module path (a source tree there would win over the installed package), and the folder
    holding this ``sfs_ros`` goes first on ``PYTHONPATH`` unless it is a site-packages
    folder, which the child searches anyway. One copy of the code then runs in every
    process of a cell, and its compiled kernels are the ones cached (``sfs-warm-up``)."""
    root = str(Path(__file__).resolve().parents[2])
    if root in {str(Path(p).resolve()) for p in site.getsitepackages()}:
        return dict(env)
    return dict(env, PYTHONPATH=os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")])))


def default_config_dir() -> Path:
    """The installed ``share/sfs_ros/config`` (pip or colcon), else the source tree's."""
    candidates = [Path(sys.prefix) / "share" / "sfs_ros" / "config",
                  Path(__file__).resolve().parents[2] / "config"]
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.insert(0, Path(get_package_share_directory("sfs_ros")) / "config")
    except (ImportError, LookupError, OSError):   # no ament index (a plain venv) or no entry
        pass
    for folder in candidates:
        if (folder / "rig.yaml").is_file():
            return folder
    raise FileNotFoundError(f"no sfs_ros config folder (rig.yaml) in "
                            f"{', '.join(map(str, candidates))}: pass --config DIR")


@dataclass
class NodeSpec:
    """One node process: ``module`` under ``sfs_ros.nodes``, its params files (in order,
    later ones win), ``-p name:=value`` overrides, ``-r from:=to`` topic remaps, and
    ``applied_rig``, a params file given after the others when it exists at the start
    ("" = none), and ``environment``, variables it starts with where the cell's
    environment does not set them (glibc's malloc settings, read before any thread)."""

    name: str
    module: str
    params_files: list[str]
    overrides: dict[str, str] = field(default_factory=dict)
    remaps: dict[str, str] = field(default_factory=dict)
    applied_rig: str = ""
    environment: dict[str, str] = field(default_factory=dict)

    def applied_rig_file(self) -> str:
        """``applied_rig`` if it exists now, else ""."""
        return self.applied_rig if self.applied_rig and Path(self.applied_rig).is_file() else ""

    def command(self, namespace: str = "") -> list[str]:
        args = [sys.executable, "-P", "-m", f"sfs_ros.nodes.{self.module}", "--ros-args"]
        if namespace:
            args += ["-r", f"__ns:={namespace}"]
        for name, target in self.remaps.items():
            args += ["-r", f"{name}:={target}"]
        for path in [*self.params_files, self.applied_rig_file()]:
            if path:
                args += ["--params-file", path]
        for name, value in self.overrides.items():
            args += ["-p", f"{name}:={value}"]
        return args


#: The params file every node gets last by default: it sets nothing.
OVERRIDES_FILE = "overrides.yaml"


def cell_nodes(config_dir, output_dir, *, mock: bool, record: bool = False,
               params_file=None, port: str | None = None, camera_device: str | None = None,
               camera_topic: str | None = None,
               manual_lifecycle: bool = False) -> list[NodeSpec]:
    """The cell's node processes in start order (hardware first, the scan node last).

    The recorder is always there (idle until ``recorder/start``); ``record``
    makes it record every scan (``with_scan``). ``params_file``: given to
    every node after its own files (default ``overrides.yaml`` of
    ``config_dir``). The real hardware only (ValueError with ``mock``):
    ``port``, the motor controller's serial port (default: motor.yaml's);
    ``camera_device``, the camera node's ``device`` (default: camera.yaml's).
    ``camera_topic``, the image topic of another camera driver: no camera
    node (with ``mock``, the mock hardware without its camera: a real camera
    with simulated motion), the scan node takes that topic's streamed frames.
    ``manual_lifecycle``: no lifecycle manager; the managed nodes wait unconfigured for
    their transitions.
    """
    config = Path(config_dir)
    output = Path(output_dir).resolve()
    real_only = {"port": port, "camera_device": camera_device}
    given = [name for name, value in real_only.items() if value]
    if mock and given:
        raise ValueError(f"{', '.join(given)}: only for the real hardware (the mock cell has "
                         "its own controller and camera)")
    if camera_device and camera_topic:
        raise ValueError("camera_device and camera_topic: one or the other (our camera node "
                         "on a device, or another driver's topic)")

    def files(*names: str) -> list[str]:
        paths = [config / n for n in names]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"config file(s) missing: {', '.join(missing)}")
        return [str(p) for p in paths]

    site = str(Path(params_file).resolve()) if params_file else files(OVERRIDES_FILE)[0]
    if not Path(site).is_file():
        raise FileNotFoundError(f"params file missing: {site}")

    def spec(name: str, module: str, names: list[str], overrides=None, remaps=None):
        return NodeSpec(name, module, files(*names) + [site], overrides or {}, remaps or {},
                        str(output / APPLIED_RIG) if "rig.yaml" in names else "")

    link = output / "ttyMOCK"
    managed = {"autostart": "false"}
    if mock:
        hardware = [spec("mock_hardware", "mock_hardware_node",
                         ["rig.yaml", "frames.yaml", "camera.yaml", "mock_hardware.yaml"],
                         {"port_link": str(link), **managed,
                          **({"camera": "false"} if camera_topic else {})}),
                    spec("motor", "motor_node", ["motor.yaml"], {"port": str(link), **managed})]
        order = ([] if camera_topic else ["camera"]) + ["motor"]
    else:
        camera = [] if camera_topic else [
            spec("camera", "camera_node", ["rig.yaml", "frames.yaml", "camera.yaml"],
                 {"device": camera_device, **managed} if camera_device else managed)]
        hardware = camera + [spec("motor", "motor_node", ["motor.yaml"],
                                  {"port": port, **managed} if port else managed)]
        order = ["motor"] + ([] if camera_topic else ["camera"])
    if not manual_lifecycle:
        hardware.append(spec("lifecycle_manager", "lifecycle_manager_node", [],
                             {"nodes": f"[{','.join(order)}]"}))
    stream = ({"camera_trigger": "stream"}, {"image_raw": camera_topic}) if camera_topic \
        else ({}, {})
    return hardware + [
        spec("state_publisher", "tf_node", ["rig.yaml", "frames.yaml"]),
        spec("segmentation", "segmentation_node", ["rig.yaml", "segmentation.yaml"]),
        replace(spec("carving", "carving_node", ["rig.yaml", "frames.yaml", "carving.yaml"],
                     {"output_dir": str(output)}), environment=KEEP_FREED_MEMORY_ENVIRONMENT),
        replace(spec("meshing", "meshing_node", ["frames.yaml", "meshing.yaml"],
                     {"output_dir": str(output)}), environment=KEEP_FREED_MEMORY_ENVIRONMENT),
        spec("recorder", "recorder_node", ["recorder.yaml"],
             {"output_dir": str(output), **({"with_scan": "true"} if record else {})}),
        spec("calibration", "calibration_node", ["calibration.yaml"],
             {"output_dir": str(output), "plan_file": files("calibration_plan.yaml")[0]}),
        spec("scan", "scan_node", ["scan.yaml"],
             {"plan_file": files("scan_plan.yaml")[0],
              "progress_dir": str(output / "scan_progress"), **stream[0]}, stream[1]),
    ]


#: Nodes that must run on the same host: the mock hardware's pseudo-terminal
#: (``OUTPUT_DIR/ttyMOCK``) is the motor node's serial port.
SAME_HOST = (("mock_hardware", "motor"),)


def select_nodes(specs: list[NodeSpec], *, only=(), without=()) -> list[NodeSpec]:
    """The part of ``specs`` to run on this host, in their order: the nodes named in
    ``only`` (all if empty), less those in ``without``.

    ValueError naming the valid nodes for a name not among ``specs``, for ``only`` and
    ``without`` together or a selection left empty, and for a pair of :data:`SAME_HOST`
    split between hosts."""
    names = [s.name for s in specs]
    unknown = [n for n in [*only, *without] if n not in names]
    if unknown:
        raise ValueError(f"no node {', '.join(unknown)} in this cell; its nodes are "
                         f"{', '.join(names)}")
    if only and without:
        raise ValueError("only and without: one or the other")
    chosen = [s for s in specs if (not only or s.name in only) and s.name not in without]
    if not chosen:
        raise ValueError(f"no node left to start (the cell's nodes are {', '.join(names)})")
    picked = {s.name for s in chosen}
    for pair in SAME_HOST:
        if set(pair) <= set(names) and len(set(pair) & picked) == 1:
            raise ValueError(f"{' and '.join(pair)} run on the same host (the motor node's "
                             "port is the mock's pseudo-terminal): start both or neither")
    return chosen


class Cell:
    """The node processes of :func:`cell_nodes`; a context manager that stops them on exit.

    specs : list of NodeSpec
    namespace : str
        ROS namespace of every node ("" or "/" = the root; made absolute: "cell1" is
        "/cell1").
    log : file, optional
        Where the nodes' output lines go, prefixed with ``[name]``; None = discarded.
    env : dict, optional
        Environment of the processes (default: this process's), plus
        :data:`DDS_ENVIRONMENT` and :data:`~sfs_ros.process.PROCESS_ENVIRONMENT` where it
        does not set those variables, each node's own ``environment`` likewise, and the
        module path of :func:`node_environment`.
    """

    def __init__(self, specs: list[NodeSpec], *, namespace: str = NAMESPACE, log=sys.stdout,
                 env: dict | None = None):
        self.specs = specs
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self._log = log
        self._env = node_environment(DDS_ENVIRONMENT | PROCESS_ENVIRONMENT | dict(
            os.environ if env is None else env, PYTHONUNBUFFERED="1"))
        self._log_lock = threading.Lock()
        self.processes: dict[str, subprocess.Popen] = {}
        self._readers: list[threading.Thread] = []

    def start(self) -> Cell:
        for spec in self.specs:
            self.start_node(spec.name)
        return self

    def environment_of(self, name: str) -> dict:
        """The environment the node called ``name`` starts with: the cell's, and the node's
        own ``environment`` where the cell's does not set those variables."""
        spec = next(s for s in self.specs if s.name == name)
        return spec.environment | self._env

    def start_node(self, name: str) -> None:
        """Start (or start again) the node called ``name``."""
        spec = next(s for s in self.specs if s.name == name)
        if spec.applied_rig_file():
            self._say(f"sfs-cell: {name} starts with the rig applied last, "
                      f"{spec.applied_rig_file()}")
        process = subprocess.Popen(spec.command(self.namespace), stdin=subprocess.DEVNULL,
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   env=self.environment_of(name), start_new_session=True)
        self.processes[name] = process
        reader = threading.Thread(target=self._copy_output, args=(name, process), daemon=True)
        reader.start()
        self._readers.append(reader)

    def _copy_output(self, name: str, process: subprocess.Popen) -> None:
        for line in iter(process.stdout.readline, b""):
            self._say(f"[{name}] {line.decode(errors='replace').rstrip()}")
        process.stdout.close()

    def _say(self, line: str) -> None:
        """One line to the log (none: discarded)."""
        if self._log is not None:
            with self._log_lock:
                self._log.write(line + "\n")
                self._log.flush()

    def exited(self) -> dict[str, int]:
        """``{name: exit code}`` of the nodes that have ended."""
        return {n: p.returncode for n, p in self.processes.items() if p.poll() is not None}

    def stop_node(self, name: str, grace_s: float = STOP_GRACE_S) -> int:
        """Stop the node called ``name`` (:func:`stop_process`); the exit code."""
        return stop_process(self.processes[name], grace_s, held=lambda: self._say(
            f"sfs-cell: {name} did not stop within {grace_s:g} s of SIGINT nor of SIGTERM: "
            "its threads' stacks follow, then it is killed"))

    def stop(self) -> dict[str, int]:
        """Stop every node, the last started first; ``{name: exit code}``."""
        codes = {name: self.stop_node(name) for name in reversed(list(self.processes))}
        for reader in self._readers:
            reader.join(timeout=2.0)
        return codes

    def __enter__(self) -> Cell:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def stop_process(process: subprocess.Popen, grace_s: float,
                 held: Callable[[], None] | None = None) -> int:
    """SIGINT, then SIGTERM after ``grace_s``; a process still running ``grace_s`` later
    is held in its stop: ``held()`` is called, the process is asked for its threads'
    stacks (SIGUSR1; a node writes them to its output and runs on) and killed
    :data:`STACKS_S` later. The exit code."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        if process.poll() is None:
            process.send_signal(sig)
            _wait(process, grace_s)
    if process.poll() is None:
        if held is not None:
            held()
        process.send_signal(signal.SIGUSR1)
        _wait(process, STACKS_S)
        process.kill()
    return process.wait()


def _wait(process: subprocess.Popen, seconds: float) -> None:
    """Wait up to ``seconds`` for ``process`` to end."""
    try:
        process.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        pass


@dataclass
class RestartPolicy:
    """When a node that ended by itself is started again: exponential back-off, and a
    crash loop gives up.

    The n-th restart within ``window_s`` waits ``min(first_delay_s * 2**(n-1),
    max_delay_s)`` seconds; more than ``max_restarts`` restarts within
    ``window_s`` is a crash loop (None: give up).
    """

    first_delay_s: float = 0.5
    max_delay_s: float = 30.0
    max_restarts: int = 5
    window_s: float = 120.0
    _restarts: dict[str, list[float]] = field(default_factory=dict)

    def delay(self, name: str, now_s: float) -> float | None:
        """Seconds to wait before restarting ``name`` (which just ended at ``now_s``), or None."""
        recent = [t for t in self._restarts.get(name, []) if now_s - t < self.window_s]
        if len(recent) >= self.max_restarts:
            return None
        self._restarts[name] = recent + [now_s]
        return min(self.first_delay_s * 2 ** len(recent), self.max_delay_s)


def _supervise(cell: Cell, stopping: threading.Event, policy: RestartPolicy, log) -> int:
    """Restart nodes that end by themselves until ``stopping`` is set; 1 after a crash loop,
    :data:`~sfs_ros.ros.names.CONFIGURATION_ERROR` when a node ended refusing its
    configuration (started again, it would refuse it again)."""
    pending: dict[str, float] = {}  # name -> monotonic time of the restart
    while not stopping.wait(0.2):
        now = time.monotonic()
        for name, code in cell.exited().items():
            if name in pending:
                continue
            if code == CONFIGURATION_ERROR:
                print(f"sfs-cell: node {name} refused its configuration (exit status {code}, "
                      "its reason above); not restarting it, stopping the cell", file=log,
                      flush=True)
                return CONFIGURATION_ERROR
            wait = policy.delay(name, now)
            if wait is None:
                print(f"sfs-cell: node {name} ended {policy.max_restarts} times within "
                      f"{policy.window_s:.0f} s (last exit status {code}); stopping the cell",
                      file=log, flush=True)
                return 1
            print(f"sfs-cell: node {name} ended by itself (exit status {code}); restarting it "
                  f"in {wait:.1f} s", file=log, flush=True)
            pending[name] = now + wait
        for name, when in list(pending.items()):
            if now >= when:
                cell.start_node(name)
                del pending[name]
    return 0


def wait_until_signal(cell: Cell, *, policy: RestartPolicy | None = None,
                      stopping: threading.Event | None = None, log=sys.stderr) -> int:
    """Supervise the cell until SIGINT/SIGTERM (or ``stopping``); then stop it. Exit status.

    A node that ends by itself is started again after a back-off
    (:class:`RestartPolicy`); a restarted segmentation, carving or meshing node
    gets every capture without a receipt again (the scan node resends them). A
    crash loop stops the cell with status 1; a node that exits with
    :data:`~sfs_ros.ros.names.CONFIGURATION_ERROR` (its parameters refused) is not started again: the cell
    stops with that status.
    """
    stopping = stopping or threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stopping.set())
    status = _supervise(cell, stopping, policy or RestartPolicy(), log)
    codes = cell.stop()
    unclean = {n: c for n, c in codes.items() if c not in (0, -signal.SIGINT)}
    if unclean and not status:
        print(f"sfs-cell: node(s) did not stop cleanly: {unclean}", file=log)
        status = 1
    return status
