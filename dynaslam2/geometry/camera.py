"""Rectified stereo pinhole camera: projection (paper's pi_i), back-projection, KITTI P matrices."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynaslam2.errors import InputError


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo rig (or RGB-D with a virtual baseline): left camera intrinsics + baseline.

    `width`, `height` in pixels; `baseline` in metres (right camera at +baseline along x).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    width: int
    height: int

    def __post_init__(self) -> None:
        vals = np.array([self.fx, self.fy, self.cx, self.cy, self.baseline], dtype=float)
        if not np.all(np.isfinite(vals)):
            raise InputError(f"calibration: non-finite intrinsics or baseline {vals.tolist()}")
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"calibration: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.baseline <= 0:
            raise InputError(f"calibration: baseline must be positive, got {self.baseline}")
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"calibration: image size must be positive, got {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def bf(self) -> float:
        """Baseline times fx: disparity = bf / z."""
        return self.baseline * self.fx

    def project(self, X_c: np.ndarray) -> np.ndarray:
        """(N, 3) points in the left camera frame -> (N, 2) pixels (u, v)."""
        X_c = np.asarray(X_c, dtype=float)
        inv_z = 1.0 / X_c[:, 2]
        return np.stack([self.fx * X_c[:, 0] * inv_z + self.cx, self.fy * X_c[:, 1] * inv_z + self.cy], -1)

    def project_stereo(self, X_c: np.ndarray) -> np.ndarray:
        """(N, 3) points -> (N, 3) stereo measurements (u, v, u_R), the paper's pi_i in eq. (1)-(2)."""
        X_c = np.asarray(X_c, dtype=float)
        uv = self.project(X_c)
        u_r = uv[:, 0] - self.bf / X_c[:, 2]
        return np.concatenate([uv, u_r[:, None]], -1)

    def project_stereo_jacobian(self, X_c: np.ndarray) -> np.ndarray:
        """(N, 3) points -> (N, 3, 3) Jacobians d(u, v, u_R) / d X_c of `project_stereo`."""
        X_c = np.asarray(X_c, dtype=float)
        x, y, z = X_c[:, 0], X_c[:, 1], X_c[:, 2]
        J = np.zeros((len(X_c), 3, 3))
        J[:, 0, 0] = J[:, 2, 0] = self.fx / z
        J[:, 0, 2] = -self.fx * x / z**2
        J[:, 1, 1] = self.fy / z
        J[:, 1, 2] = -self.fy * y / z**2
        J[:, 2, 2] = -(self.fx * x - self.bf) / z**2
        return J

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """(N, 2) pixels with (N,) z-depths -> (N, 3) points in the left camera frame."""
        uv = np.asarray(uv, dtype=float)
        z = np.asarray(depth, dtype=float)
        return np.stack([(uv[:, 0] - self.cx) * z / self.fx, (uv[:, 1] - self.cy) * z / self.fy, z], -1)

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels inside the image (with an optional margin)."""
        return (
            (uv[:, 0] >= margin)
            & (uv[:, 0] <= self.width - 1 - margin)
            & (uv[:, 1] >= margin)
            & (uv[:, 1] <= self.height - 1 - margin)
        )

    def projection_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """KITTI-style (P_left, P_right): K[I|0] and K[I|(-fx*B, 0, 0)]."""
        P_left = np.hstack([self.K, np.zeros((3, 1))])
        P_right = P_left.copy()
        P_right[0, 3] = -self.bf
        return P_left, P_right

    @classmethod
    def from_projection_matrices(
        cls, P_left: np.ndarray, P_right: np.ndarray, width: int, height: int, source: str = "calibration"
    ) -> "StereoCamera":
        """Rectified rig from two 3x4 projection matrices; rejects non-rectified or non-finite ones."""
        P_left = np.asarray(P_left, dtype=float).reshape(3, 4)
        P_right = np.asarray(P_right, dtype=float).reshape(3, 4)
        if not (np.all(np.isfinite(P_left)) and np.all(np.isfinite(P_right))):
            raise InputError(f"{source}: non-finite values in the projection matrices")
        K_l, K_r = P_left[:, :3], P_right[:, :3]
        if not np.allclose(K_l, K_r, rtol=1e-6, atol=1e-6):
            raise InputError(f"{source}: left and right intrinsics differ; expected a rectified stereo pair")
        if abs(K_l[0, 1]) > 1e-9 or abs(K_l[1, 0]) > 1e-9 or not np.allclose(K_l[2], [0, 0, 1]):
            raise InputError(f"{source}: projection matrix is not of the form K[I|t] with zero skew")
        fx = K_l[0, 0]
        # Offsets relative to the left camera (KITTI's P2/P3 carry a common offset from cam0).
        t_rel = (P_right[:, 3] - P_left[:, 3]) / fx
        if abs(t_rel[1]) > 1e-6 * max(1.0, abs(t_rel[0])) or abs(P_right[2, 3] - P_left[2, 3]) > 1e-6:
            raise InputError(f"{source}: the right camera is not displaced along x only; expected a rectified pair")
        baseline = -t_rel[0]
        if not baseline > 0:
            raise InputError(f"{source}: baseline must be positive (right camera to the right), got {baseline:.6g} m")
        return cls(fx, K_l[1, 1], K_l[0, 2], K_l[1, 2], baseline, int(width), int(height))
