"""Camera models: orthographic (the paper's) and pinhole ``P = K [R | t]``.

Both share one parameterisation so every stage (renderer, carver, metrics)
treats them alike:

* ``R`` (3, 3) and ``t`` (3,) take a world point ``X`` (metres) into the camera
  frame ``Xc = R @ X + t``, OpenCV axes: x right, y down, z forward.
* ``K`` (3, 3) holds ``fx, fy, cx, cy``. For the pinhole model ``fx`` is in
  pixels (focal length / pixel pitch); for the orthographic model it is the
  image scale in pixels per metre.
* Pixel coordinates ``(u, v)``: origin at the top-left corner of the image,
  ``u`` to the right, ``v`` down, integer values at pixel centres.

Projection:

* pinhole: ``u = fx * xc / zc + s * yc / zc + cx``, ``v = fy * yc / zc + cy``
* orthographic: ``u = fx * xc + s * yc + cx``, ``v = fy * yc + cy``

(``s`` = ``K[0, 1]``, the skew, zero for most cameras.)

Lens distortion: a pinhole camera may carry OpenCV ``plumb_bob`` coefficients
``distortion = (k1, k2, p1, p2, k3)``. :meth:`Camera.project` and
:attr:`Camera.projection_matrix` stay the ideal (undistorted) pinhole;
:meth:`Camera.project_distorted` gives the pixels the lens really forms
(:func:`distort_normalized` between the division by depth and ``K``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Camera", "distort_normalized", "MAX_DISTORTION", "MAX_IMAGE_SIDE_PX",
           "MAX_INTRINSIC", "MAX_TRANSLATION_M"]

#: Largest image side a camera may have, pixels.
MAX_IMAGE_SIDE_PX = 65535
#: Largest magnitude of an intrinsic value (focal length, principal point, skew), pixels.
MAX_INTRINSIC = 1e9
#: Largest camera translation, metres: further than any cell or data set puts a camera.
MAX_TRANSLATION_M = 1e6
#: Largest magnitude of a lens distortion coefficient (as the rig's).
MAX_DISTORTION = 1e3


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera producing ``width`` x ``height`` images.

    Parameters
    ----------
    K : (3, 3) float64
        Intrinsics (pixels; pixels per metre for the orthographic model).
    R : (3, 3) float64
        Rotation world -> camera.
    t : (3,) float64
        Translation world -> camera, metres.
    width, height : int
        Image size in pixels.
    orthographic : bool
        True for the orthographic (parallel) projection, False for pinhole.
    distortion : (5,) float64, optional
        Lens distortion ``(k1, k2, p1, p2, k3)`` (pinhole only); zeros by default.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    orthographic: bool = False
    distortion: np.ndarray | None = None

    def __post_init__(self) -> None:
        D = np.zeros(5) if self.distortion is None else np.array(self.distortion, np.float64)
        if D.shape != (5,) or not np.all(np.isfinite(D)) or np.abs(D).max() > MAX_DISTORTION:
            raise ValueError(f"camera distortion must be 5 finite values (k1, k2, p1, p2, k3) "
                             f"within +-{MAX_DISTORTION:g}, got {self.distortion!r}")
        if self.orthographic and np.any(D):
            raise ValueError("an orthographic camera cannot carry lens distortion")
        K = np.array(self.K, dtype=np.float64)
        R = np.array(self.R, dtype=np.float64)
        t = np.array(self.t, dtype=np.float64).reshape(-1)
        if K.shape != (3, 3) or R.shape != (3, 3) or t.shape != (3,):
            raise ValueError(
                f"camera needs K (3, 3), R (3, 3), t (3,); got K {K.shape}, "
                f"R {R.shape}, t {t.shape}")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise ValueError("camera parameters contain NaN or infinity")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(
                "camera R is not a rotation (expected orthonormal with det +1)")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"camera focal lengths must be > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
        if np.abs(K).max() > MAX_INTRINSIC or np.abs(t).max() > MAX_TRANSLATION_M:
            raise ValueError(f"camera intrinsics beyond {MAX_INTRINSIC:g} pixels or translation "
                             f"beyond {MAX_TRANSLATION_M:g} m: not a real camera")
        if not (0 < int(self.width) <= MAX_IMAGE_SIDE_PX and 0 < int(self.height) <= MAX_IMAGE_SIDE_PX):
            raise ValueError(f"image size must be 1..{MAX_IMAGE_SIDE_PX} pixels a side, got "
                             f"{self.width}x{self.height}")
        for name, value in (("K", K), ("R", R), ("t", t), ("distortion", D)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "orthographic", bool(self.orthographic))

    @classmethod
    def from_projection_matrix(cls, P: np.ndarray, width: int, height: int) -> "Camera":
        """Decompose a finite pinhole ``P`` (3, 4) into ``K [R | t]`` (RQ decomposition)."""
        P = np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4) or not np.all(np.isfinite(P)):
            raise ValueError(f"projection matrix must be a finite (3, 4) array, got {P.shape}")
        M = P[:, :3]
        if abs(np.linalg.det(M)) < 1e-12:
            raise ValueError("projection matrix has a singular left 3x3 block (not a finite camera)")
        # RQ decomposition of M via QR of the flipped transpose.
        flip = np.eye(3)[::-1]
        q, r = np.linalg.qr((flip @ M).T)
        K = flip @ r.T @ flip
        R = flip @ q.T
        signs = np.diag(np.sign(np.diag(K)))
        K, R = K @ signs, signs @ R
        t = np.linalg.solve(K, P[:, 3])
        if np.linalg.det(R) < 0:
            R, t = -R, -t
        return cls(K=K / K[2, 2], R=R, t=t, width=width, height=height, orthographic=False)

    @property
    def projection_matrix(self) -> np.ndarray:
        """(3, 4) matrix mapping homogeneous world points to homogeneous pixels.

        For the orthographic model its last row is ``(0, 0, 0, 1)``.
        """
        Rt = np.hstack([self.R, self.t[:, None]])
        if not self.orthographic:
            return self.K @ Rt
        A = np.zeros((3, 4))
        A[:2, :] = self.K[:2, :2] @ Rt[:2, :]
        A[:2, 3] += self.K[:2, 2]
        A[2, 3] = 1.0
        return A

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit viewing direction in world coordinates (camera +z)."""
        return self.R[2].copy()

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres (pinhole: the optical centre;
        orthographic: the point on the optical axis with zero depth)."""
        return -self.R.T @ self.t

    def to_camera_frame(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 3) -> camera-frame points (n, 3), metres."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return points @ self.R.T + self.t

    def depth(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance of world points (n, 3) along the viewing direction, metres."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return points @ self.R[2] + self.t[2]

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 3), metres -> pixel coordinates (n, 2) as ``(u, v)``.

        Pinhole points at or behind the camera plane (depth <= 0) map to NaN.
        """
        P = self.projection_matrix
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        h = points @ P[:, :3].T + P[:, 3]
        if self.orthographic:
            return h[:, :2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = h[:, :2] / h[:, 2:3]
        uv[h[:, 2] <= 0] = np.nan
        return uv

    def project_distorted(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 3), metres -> pixels (n, 2) through the lens distortion.

        Equal to :meth:`project` for a camera without distortion; points at or
        behind the camera plane map to NaN.
        """
        if self.orthographic or not np.any(self.distortion):
            return self.project(points)
        xc = self.to_camera_frame(points)
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = xc[:, :2] / xc[:, 2:3]
        xy[xc[:, 2] <= 0] = np.nan
        xy = distort_normalized(xy, self.distortion)
        return xy @ self.K[:2, :2].T + self.K[:2, 2]


def distort_normalized(xy: np.ndarray, distortion) -> np.ndarray:
    """Apply OpenCV ``plumb_bob`` distortion to normalised image points.

    Parameters
    ----------
    xy : (n, 2) float64
        Ideal normalised coordinates ``(x / z, y / z)`` in the camera frame.
    distortion : (5,) float
        ``(k1, k2, p1, p2, k3)``.

    Returns
    -------
    (n, 2) float64
        Distorted normalised coordinates (multiply by ``K`` for pixels).
    """
    k1, k2, p1, p2, k3 = np.asarray(distortion, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)
