"""The rig calibration as node parameters, shared by every node that needs it.

The carving node turns encoder angles into cameras with it, the camera
node publishes its intrinsics as ``CameraInfo``, and the mock camera renders
with it. One file, ``config/rig.yaml`` (``/**:`` so every node reads it),
holds the values for the whole cell.

:data:`RIG_PARAMS` defines them (names, defaults, ranges). A node that takes a
new calibration while it runs declares :data:`WRITABLE_RIG_PARAMS` (the same
parameters, settable) and keeps a :class:`RigParameters`: a change is checked
as the whole :class:`RigCalibration` it would give (several parameters set at
once, ``SetParametersAtomically``, are checked together), the image size stays
the one the node started with, and nothing changes while the cell's scan node
reports a scan under way (``starting``, ``running``, ``waiting`` or
``paused``, on ``/diagnostics``); a refusal gives the reason and keeps the old
rig.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from sfs_ros.cell_logic.message_fields import scan_report
from sfs_ros.core.geometry.rig import CONVENTIONS, RigCalibration
from sfs_ros.ros.names import DIAGNOSTICS
from sfs_ros.ros.params import Param, ParameterError, check, read

__all__ = ["RIG_PARAMS", "WRITABLE_RIG_PARAMS", "FIXED_WHILE_RUNNING", "SCANNING_STATES",
           "RigParameters", "rig_calibration"]

_RIG = RigCalibration()

#: Parameters of :class:`RigCalibration` (all read-only: they define the scan).
RIG_PARAMS: list[Param] = [
    Param("projection", _RIG.projection, "Camera model of the rig.",
          choices=("orthographic", "pinhole"), read_only=True),
    Param("width", _RIG.width, "Image width, pixels.", bounds=(1, 100000), read_only=True),
    Param("height", _RIG.height, "Image height, pixels.", bounds=(1, 100000), read_only=True),
    Param("fx", _RIG.fx, "Pinhole: focal length, pixels; orthographic: pixels per metre.",
          bounds=(1e-9, 1e9), read_only=True),
    Param("fy", _RIG.fy, "As fx, vertically.", bounds=(1e-9, 1e9), read_only=True),
    Param("cx", -1.0, "Principal point x, pixels.", bounds=(-1.0, 1e6), read_only=True,
          constraints="below 0 = image centre"),
    Param("cy", -1.0, "Principal point y, pixels.", bounds=(-1.0, 1e6), read_only=True,
          constraints="below 0 = image centre"),
    Param("camera_distance_m", _RIG.camera_distance_m, "Distance from the C-arm centre to the "
          "camera centre, metres.", bounds=(1e-6, 1000.0), read_only=True),
    Param("aim_point_m", [float(v) for v in _RIG.aim_point_m], "C-arm centre [x, y, z] in the "
          "lab frame, metres.", read_only=True, constraints="three values"),
    Param("theta_zero_rad", _RIG.theta_zero_rad, "Turntable encoder reading at its true zero, "
          "radians.", read_only=True),
    Param("phi_zero_rad", _RIG.phi_zero_rad, "Carriage encoder reading at its true zero, "
          "radians.", read_only=True),
    Param("convention", _RIG.convention, "Angle convention of the rig.", choices=CONVENTIONS,
          read_only=True),
    Param("distortion", list(_RIG.distortion), "Lens distortion [k1, k2, p1, p2, k3] "
          "(OpenCV plumb_bob), pinhole only.", read_only=True, constraints="five values"),
    Param("axis_point_m", list(_RIG.axis_point_m), "Where the turntable axis crosses the lab "
          "plane z = 0, [x, y], metres.", read_only=True, constraints="two values"),
    Param("axis_tilt_x_rad", _RIG.axis_tilt_x_rad, "Tilt of the turntable axis about lab X, "
          "radians.", bounds=(-0.5, 0.5), read_only=True),
    Param("axis_tilt_y_rad", _RIG.axis_tilt_y_rad, "Tilt of the turntable axis about lab Y, "
          "radians.", bounds=(-0.5, 0.5), read_only=True),
    Param("mount_rotation_rad", list(_RIG.mount_rotation_rad), "Rotation vector of the camera "
          "on its carriage, radians.", read_only=True, constraints="three values"),
]

#: Rig parameters a running node keeps at their start-up values: its frames have that size.
FIXED_WHILE_RUNNING = ("width", "height")

#: :data:`RIG_PARAMS` settable at run time, between scans (:class:`RigParameters`).
WRITABLE_RIG_PARAMS: list[Param] = [
    replace(p, read_only=False, constraints="; ".join(filter(None, [
        p.constraints, "fixed while the node runs" if p.name in FIXED_WHILE_RUNNING else
        "between scans, checked with the other rig parameters as one rig"])))
    for p in RIG_PARAMS]

#: States of the scan node (its diagnostics' ``state``) in which the rig may not change.
SCANNING_STATES = ("starting", "running", "waiting", "paused")
#: States in which the scan node has views of its scan captured or to come (``starting``
#: is not one: it asks the reconstruction for its new scan then).
CAPTURING_STATES = ("running", "waiting", "paused")


def rig_calibration(values: dict) -> RigCalibration:
    """:class:`RigCalibration` from the values of :data:`RIG_PARAMS`; :class:`ParameterError`."""
    for name, size in (("aim_point_m", 3), ("distortion", 5), ("axis_point_m", 2),
                       ("mount_rotation_rad", 3)):
        if len(values[name]) != size:
            raise ParameterError(name, f"got {values[name]!r}, expected {size} values")
    try:
        return RigCalibration(
            width=values["width"], height=values["height"], projection=values["projection"],
            fx=values["fx"], fy=values["fy"],
            cx=None if values["cx"] < 0 else values["cx"],
            cy=None if values["cy"] < 0 else values["cy"],
            camera_distance_m=values["camera_distance_m"],
            aim_point_m=tuple(values["aim_point_m"]),
            theta_zero_rad=values["theta_zero_rad"], phi_zero_rad=values["phi_zero_rad"],
            convention=values["convention"], distortion=tuple(values["distortion"]),
            axis_point_m=tuple(values["axis_point_m"]),
            axis_tilt_x_rad=values["axis_tilt_x_rad"], axis_tilt_y_rad=values["axis_tilt_y_rad"],
            mount_rotation_rad=tuple(values["mount_rotation_rad"]))
    except ValueError as exc:
        raise ParameterError("calibration", str(exc)) from None


class RigParameters:
    """The rig of a running node that declared :data:`WRITABLE_RIG_PARAMS`: checks changes
    to them as one rig and keeps the current :class:`RigCalibration`.

    node : Node
        Its rig parameters declared already (e.g. ``declare(node, [..., *WRITABLE_RIG_PARAMS])``).
    on_change : callable, optional
        Called with the new :class:`RigCalibration` once a change is accepted (in the thread
        that set it).

    A change is refused, with the reason and the old rig kept, when a value is
    invalid (type, range, choices), the rig it would give is invalid, ``width`` or
    ``height`` differs from the start-up value, or the scan node of the node's
    namespace reports a scan in one of :data:`SCANNING_STATES` (``/diagnostics``; before
    its first report, none is assumed). Setting the current values again is always
    accepted. Raises :class:`ParameterError` if the declared values do not make a rig.
    """

    def __init__(self, node: Node, *, on_change: Callable[[RigCalibration], None] | None = None):
        self._node = node
        self._by_name = {p.name: p for p in WRITABLE_RIG_PARAMS}
        self._lock = threading.Lock()
        self._calibration = rig_calibration(read(node, WRITABLE_RIG_PARAMS))
        self._started = {name: getattr(self._calibration, name) for name in FIXED_WHILE_RUNNING}
        self._on_change = on_change
        self._scan: tuple[int, str] | None = None      # (scan number, state) last reported
        node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 10)
        node.add_on_set_parameters_callback(self._check)
        node.add_post_set_parameters_callback(self._changed)

    @property
    def calibration(self) -> RigCalibration:
        """The current rig."""
        with self._lock:
            return self._calibration

    def scanning(self) -> str:
        """Why the rig may not change now (the scan under way), or ""."""
        scan = self.scan_in(SCANNING_STATES)
        if scan is None:
            return ""
        return (f"the scan node reports scan {scan[0]} {scan[1]}: the rig changes between "
                "scans (once the scan is done or cancelled), for the next one")

    def scan_in(self, states: tuple) -> tuple[int, str] | None:
        """``(scan number, state)`` the scan node last reported if its state is one of
        ``states``, else None (also before its first report)."""
        with self._lock:
            scan = self._scan
        return scan if scan is not None and scan[1] in states else None

    def _on_diagnostics(self, array: DiagnosticArray) -> None:
        report = scan_report(array, self._node.get_namespace())
        if report is not None:
            with self._lock:
                self._scan = report

    def _check(self, changes: list) -> SetParametersResult:
        """Set-parameters callback: the refusal of a change to the rig, if any."""
        values = read(self._node, WRITABLE_RIG_PARAMS)
        changed = False
        for change in changes:
            param = self._by_name.get(change.name)
            if param is None:
                continue
            value = list(change.value) if isinstance(param.default, list) else change.value
            reason = check(param, value)
            if reason is not None:
                return _refused(str(ParameterError(param.name, reason)))
            changed |= value != values[param.name]
            values[param.name] = value
        if not changed:
            return SetParametersResult(successful=True)
        try:
            rig = rig_calibration(values)
        except ParameterError as exc:
            return _refused(f"rig refused: {exc}")
        for name, started in self._started.items():
            if values[name] != started:
                return _refused(f"rig refused: invalid parameter '{name}': got {values[name]}, "
                                f"expected {started}: fixed while the node runs (its frames "
                                "have that size); start the node with the new size")
        busy = self.scanning()
        if busy and rig != self.calibration:
            return _refused(f"rig refused: {busy}")
        return SetParametersResult(successful=True)

    def _changed(self, changes: list) -> None:
        """Post-set callback: take the rig the accepted change gives."""
        if not any(change.name in self._by_name for change in changes):
            return
        rig = rig_calibration(read(self._node, WRITABLE_RIG_PARAMS))
        with self._lock:
            if rig == self._calibration:
                return
            self._calibration = rig
        if self._on_change is not None:
            self._on_change(rig)


def _refused(reason: str) -> SetParametersResult:
    return SetParametersResult(successful=False, reason=reason)
