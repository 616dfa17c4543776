"""A camera driver's intrinsics (its ``camera_info``) against the rig's, without ROS.

A driver such as ``usb_cam`` or a GenICam driver publishes its calibration
(``K``, ``D``, the image size) on ``camera_info`` beside its images. The scan
node reads it and, by its ``intrinsics_source``, either compares it with the
rig the reconstruction carves with (``rig``: a disagreement is a WARN naming
the parameters and the differences) or takes it as the truth for the scan
(``driver``: :func:`rig_update` gives the rig parameters to set).

Differences (:func:`intrinsics_differences`): ``fx``, ``fy``, ``cx``, ``cy``
relative to the rig's value (0.02 = 2 %); each distortion coefficient
``k1, k2, p1, p2, k3`` as the absolute difference (they are dimensionless);
the size as the number of pixels of difference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["DriverIntrinsics", "DISTORTION_NAMES", "intrinsics_differences",
           "describe_differences", "largest_difference", "rig_update", "rig_intrinsics"]

#: The plumb_bob coefficients, in ``D``'s order.
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class DriverIntrinsics:
    """A pinhole camera's intrinsics as a driver publishes them.

    width, height : int, pixels. fx, fy, cx, cy : float, pixels.
    distortion : five floats ``(k1, k2, p1, p2, k3)`` (OpenCV plumb_bob).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] = (0.0,) * 5

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        values = (self.fx, self.fy, self.cx, self.cy, *self.distortion)
        if len(self.distortion) != 5 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"intrinsics must be finite with five distortion coefficients, "
                             f"got fx {self.fx}, fy {self.fy}, cx {self.cx}, cy {self.cy}, "
                             f"distortion {list(self.distortion)}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be > 0 pixels, got fx {self.fx}, fy {self.fy}"
                             " (an uncalibrated driver publishes K = 0)")


def rig_intrinsics(values: dict) -> DriverIntrinsics:
    """The intrinsics of rig parameter values (``width``, ``height``, ``fx``, ``fy``,
    ``cx``, ``cy`` (below 0 = the image centre, (size - 1) / 2), ``distortion``)."""
    width, height = int(values["width"]), int(values["height"])
    cx = (width - 1) / 2.0 if values["cx"] < 0 else float(values["cx"])
    cy = (height - 1) / 2.0 if values["cy"] < 0 else float(values["cy"])
    return DriverIntrinsics(width, height, float(values["fx"]), float(values["fy"]), cx, cy,
                            tuple(float(v) for v in values["distortion"]))


def intrinsics_differences(rig: DriverIntrinsics, driver: DriverIntrinsics) -> dict[str, float]:
    """``{name: difference}`` of every parameter (module docstring: relative for ``fx``,
    ``fy``, ``cx``, ``cy``; absolute for the distortion coefficients and, in pixels, for
    ``width`` and ``height``)."""
    out = {"width": float(driver.width - rig.width), "height": float(driver.height - rig.height)}
    for name in ("fx", "fy", "cx", "cy"):
        ours = getattr(rig, name)
        out[name] = (getattr(driver, name) - ours) / ours if ours else math.inf
    for name, ours, theirs in zip(DISTORTION_NAMES, rig.distortion, driver.distortion):
        out[name] = theirs - ours
    return out


def describe_differences(differences: dict[str, float], tolerance: float) -> str:
    """The parameters that differ by more than ``tolerance`` (relative, or absolute for the
    distortion), each with its difference, e.g. ``"fx +2.00 %, fy +2.00 %"``; "" when none
    does (a size that differs always counts)."""
    parts = []
    for name, value in differences.items():
        if name in ("width", "height"):
            if value:
                parts.append(f"{name} {value:+.0f} px")
        elif name in DISTORTION_NAMES:
            if abs(value) > tolerance:
                parts.append(f"{name} {value:+.4f}")
        elif abs(value) > tolerance:
            parts.append(f"{name} {100 * value:+.2f} %")
    return ", ".join(parts)


def largest_difference(differences: dict[str, float]) -> float:
    """The largest relative difference of ``fx``, ``fy``, ``cx``, ``cy`` (a number >= 0)."""
    return max(abs(differences[name]) for name in ("fx", "fy", "cx", "cy"))


def rig_update(driver: DriverIntrinsics) -> dict:
    """The rig parameters that make the rig's intrinsics the driver's: ``fx``, ``fy``,
    ``cx``, ``cy`` (pixels) and ``distortion`` (five floats)."""
    return {"fx": float(driver.fx), "fy": float(driver.fy), "cx": float(driver.cx),
            "cy": float(driver.cy), "distortion": [float(v) for v in driver.distortion]}
